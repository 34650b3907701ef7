//! What the simulation loop reads from the rig, behind a trait so the loop can be tested with a
//! scripted source and run on the real transport.

use std::time::Instant;

use hydrometra_drivers::transport::{LinkStatus, RigLink};

/// One look at the rig link: state, counters, the latest calibrated sample and why the link is
/// down. The transport's allocation-free status, used as it is.
pub type RigView = LinkStatus;

/// A source of rig views, polled once per simulation tick (must be cheap).
pub trait RigSource: Send + Sync {
    /// The view at `now` (the sample's age is taken against it): a loop that has just read the
    /// clock passes that reading instead of reading it again.
    fn view_at(&self, now: Instant) -> RigView;

    /// The current view.
    fn view(&self) -> RigView {
        self.view_at(Instant::now())
    }
}

impl RigSource for RigLink {
    fn view_at(&self, now: Instant) -> RigView {
        self.status_at(now)
    }
}
