//! What the simulation loop reads from the rig, behind a trait so the loop can be tested with a
//! scripted source and run on the real transport.

use hydrometra_drivers::transport::{LinkStatus, RigLink};

/// One look at the rig link: state, counters, the latest calibrated sample and why the link is
/// down. The transport's allocation-free status, used as it is.
pub type RigView = LinkStatus;

/// A source of rig views, polled once per simulation tick (must be cheap).
pub trait RigSource: Send + Sync {
    /// The current view.
    fn view(&self) -> RigView;
}

impl RigSource for RigLink {
    fn view(&self) -> RigView {
        self.status()
    }
}
