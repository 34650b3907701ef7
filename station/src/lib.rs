//! `hydrometra station`: the instructor's live web page of one or several hydrometrad rigs
//! (docs/station.md).
//!
//! A pipeline of small stages: sources ([`local`]: a daemon on this machine over iceoryx2) fill
//! each rig's slots in the [`hub`] with [`frame`]s at the page's rates (the flow reduced by
//! [`flow`]); the [`server`] streams the newest frames to every browser over a WebSocket and
//! serves the embedded page, control requests and the [`recordings`]' debriefs, guarded by the
//! [`auth`] token.

#![warn(missing_docs)]

pub mod args;
pub mod auth;
pub mod bench;
pub mod browser;
pub mod classroom;
pub mod cpu;
pub mod error;
pub mod feed;
pub mod flow;
pub mod frame;
pub mod hub;
pub mod layout;
pub mod local;
pub mod rates;
pub mod recordings;
pub mod serve;
pub mod server;

pub use args::{ServeArgs, StationArgs, StationCommand, DEFAULT_LISTEN};
pub use error::StationError;
pub use rates::Rates;
pub use serve::{run, serve};
