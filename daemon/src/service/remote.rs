//! `[remote]`: the daemon's services forwarded to zenoh (docs/station.md, "Classroom over
//! zenoh") by `hydrometra_remote::forwarder`, a thread of its own that reads the services like
//! any renderer, so a stalled network never reaches the real-time loop.

use hydrometra_ipc::ServiceNames;
use hydrometra_remote::forwarder::{self, Forwarder};
use hydrometra_remote::RemoteConfig;

/// Starts forwarding if `[remote] enabled`; `None` when off or if the thread cannot start (the
/// daemon runs on without it, logged).
pub fn start(config: &RemoteConfig, names: &ServiceNames) -> Option<Forwarder> {
    if !config.enabled {
        return None;
    }
    forwarder::spawn(config.clone(), names.clone())
        .map_err(|e| tracing::error!("remote: cannot start the zenoh forwarder: {e}"))
        .ok()
}
