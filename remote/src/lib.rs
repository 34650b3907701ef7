//! `hydrometra-remote`: hydrometra over Eclipse Zenoh, for a teaching room of rigs watched from
//! another machine (docs/station.md, "Classroom over zenoh").
//!
//! - [`keys`]: the key expressions (`<root>/<rig id>/status`, ...), one copy.
//! - [`wire`]: payloads: the renderer contract's bytes (docs/ipc.md), header then slice.
//! - [`config`]: the daemon's `[remote]` section (off by default).
//! - [`follow`]: reading a daemon's iceoryx2 services from a non-real-time thread, paced.
//! - [`session`]: a zenoh session from that section (mode, endpoints, a zenoh config file).
//! - [`forwarder`]: the daemon's side, a non-real-time thread that reads the daemon's own iceoryx2
//!   services as a subscriber and publishes decimated copies; control only where allowed.
//! - [`watch`]: the station's side, subscribing to every rig (or the named ones).
#![warn(missing_docs)]

pub mod config;
pub mod follow;
pub mod forwarder;
pub mod keys;
pub mod session;
pub mod watch;
pub mod wire;

pub use config::RemoteConfig;
