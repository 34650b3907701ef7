//! `hydrometra-drivers`: everything that knows the training rig and nothing of the simulation.
//!
//! The calibrated rig state in [`state`] is the contract with the daemon: SI units, organ frame.
#![cfg_attr(not(feature = "std"), no_std)]
#![warn(missing_docs)]

#[cfg(feature = "std")]
pub mod state;
