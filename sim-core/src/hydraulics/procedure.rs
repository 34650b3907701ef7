//! The procedure's identity and the volumes accumulated since it started: what the model keeps and
//! the procedure record persists ([`super::model`] and [`super::record`] both use this file).

use serde::{Deserialize, Serialize};

/// Volumes accumulated since the procedure started, m^3 (each non-decreasing).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct CumulativeVolumes {
    /// Delivered by the pump into the cavity.
    pub inflow_m3: f64,
    /// Collected by the suction canister.
    pub outflow_m3: f64,
    /// Leaked through the cervix.
    pub leak_m3: f64,
    /// Part of the leak caught by the drape and counted as collected.
    pub leak_collected_m3: f64,
    /// Absorbed into the circulation.
    pub absorbed_m3: f64,
    /// Lost through a perforation.
    pub perforation_m3: f64,
}

impl CumulativeVolumes {
    /// Everything measured as collected: outflow plus the collected part of the leak.
    pub fn collected_m3(&self) -> f64 {
        self.outflow_m3 + self.leak_collected_m3
    }
}

/// Identity of the current procedure (set by the daemon; sim-core has no clock).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct ProcedureInfo {
    /// Procedure id, chosen by the caller (e.g. its start time in ms).
    pub id: u64,
    /// Wall-clock start, ms since the Unix epoch.
    pub started_unix_ms: u64,
}
