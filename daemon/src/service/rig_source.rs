//! What the simulation loop reads from the rig, behind a trait so the loop can be tested with a
//! scripted source and run on the real transport.

use hydrometra_drivers::state::{LinkCounters, LinkState, RigState};
use std::time::Duration;

/// One look at the rig link: state, counters and the latest calibrated sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigView {
    /// Link state.
    pub link_state: LinkState,
    /// Cumulative counters.
    pub counters: LinkCounters,
    /// Last calibrated sample (kept after a loss).
    pub latest: Option<RigState>,
    /// Age of `latest` now.
    pub last_sample_age: Option<Duration>,
}

impl RigView {
    /// A link that has never produced anything.
    pub fn disconnected() -> Self {
        Self {
            link_state: LinkState::Disconnected,
            counters: LinkCounters::default(),
            latest: None,
            last_sample_age: None,
        }
    }
}

/// A source of rig views, polled once per simulation tick (must be cheap).
pub trait RigSource: Send + Sync {
    /// The current view.
    fn view(&self) -> RigView;
}
