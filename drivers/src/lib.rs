//! `hydrometra-drivers`: everything that knows the training rig and nothing of the simulation.
//!
//! - [`wire`] and [`framing`]: the wire protocol v1 codec (`docs/rig-protocol.md`); builds without
//!   `std` (`--no-default-features`) so rig firmware written in Rust can reuse it.
//! - [`calibration`]: raw counts and tracker poses to SI values in the organ frame.
//! - [`transport`]: the serial link with its own I/O thread, handshake, heartbeats and reconnect.
//! - [`emulator`]: a firmware stand-in on a pseudo-terminal that plays scenarios and injects faults.
//!
//! The calibrated rig state in [`state`] is the contract with the daemon: SI units, organ frame.
#![cfg_attr(not(feature = "std"), no_std)]
#![warn(missing_docs)]

pub mod framing;
pub mod wire;

#[cfg(feature = "std")]
pub mod calibration;
#[cfg(feature = "std")]
pub mod emulator;
#[cfg(feature = "std")]
mod port_reader;
#[cfg(feature = "std")]
pub mod state;
#[cfg(feature = "std")]
pub mod tap;
#[cfg(feature = "std")]
pub mod transport;
