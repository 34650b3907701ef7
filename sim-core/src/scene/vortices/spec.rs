//! The `[vortices]` table of a scene: how many vortices, where they act, their core and strength.

use serde::{Deserialize, Serialize};

/// Where the vortices act.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum VortexMode {
    /// Display and particles only: the solver's state is untouched.
    #[default]
    Overlay,
    /// Added to the solver's face velocities (discretely divergence-free).
    Injected,
}

/// The `[vortices]` table of a scene.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VortexSpec {
    /// Most vortices at once (the paper: up to 100).
    pub max_count: usize,
    /// Overlay or injected.
    pub mode: VortexMode,
    /// No vortices below this inflow, ml/min.
    pub threshold_ml_min: f64,
    /// `max_count` vortices from this inflow, ml/min; linear in between.
    pub full_flow_ml_min: f64,
    /// Core radius, mm (raised to `min_core_voxels` voxels).
    pub core_radius_mm: f64,
    /// Smallest core radius in voxels (a core the grid cannot resolve is invisible).
    pub min_core_voxels: f64,
    /// Peak tangential speed (at `r = R`) over the resolved speed at the centre.
    pub intensity: f64,
    /// Upper bound of the peak tangential speed, m/s.
    pub max_peak_speed_m_s: f64,
    /// Seed of the placement.
    pub seed: u64,
}

impl Default for VortexSpec {
    fn default() -> Self {
        Self {
            max_count: 100,
            mode: VortexMode::Overlay,
            threshold_ml_min: 100.0,
            full_flow_ml_min: 400.0,
            core_radius_mm: 1.2,
            min_core_voxels: 1.0,
            intensity: 0.5,
            max_peak_speed_m_s: 1.0,
            seed: 1,
        }
    }
}

impl VortexSpec {
    /// Checks every range; the message names the key.
    pub fn validate(&self) -> Result<(), String> {
        let pos = |v: f64| v.is_finite() && v > 0.0;
        if self.max_count > 10_000 {
            return Err(format!(
                "`vortices.max_count` = {}: expected at most 10000",
                self.max_count
            ));
        }
        if !(self.threshold_ml_min.is_finite() && self.threshold_ml_min >= 0.0) {
            return Err(format!(
                "`vortices.threshold_ml_min` = {}: expected a flow >= 0",
                self.threshold_ml_min
            ));
        }
        if !(self.full_flow_ml_min.is_finite() && self.full_flow_ml_min > self.threshold_ml_min) {
            return Err(format!(
                "`vortices.full_flow_ml_min` = {}: expected a finite flow above `threshold_ml_min` ({})",
                self.full_flow_ml_min, self.threshold_ml_min
            ));
        }
        for (key, v) in [
            ("core_radius_mm", self.core_radius_mm),
            ("min_core_voxels", self.min_core_voxels),
            ("max_peak_speed_m_s", self.max_peak_speed_m_s),
        ] {
            if !pos(v) {
                return Err(format!(
                    "`vortices.{key}` = {v}: expected a finite value > 0"
                ));
            }
        }
        if !(self.intensity.is_finite() && self.intensity >= 0.0) {
            return Err(format!(
                "`vortices.intensity` = {}: expected a finite value >= 0",
                self.intensity
            ));
        }
        Ok(())
    }

    /// Vortices wanted at an inflow of `inflow_m3_per_s`: none below the threshold, `max_count`
    /// from the full flow, linear in between (rounded).
    pub fn target_count(&self, inflow_m3_per_s: f64) -> usize {
        let q = inflow_m3_per_s * 6e7;
        if !(q.is_finite() && q > self.threshold_ml_min) {
            return 0;
        }
        let f = ((q - self.threshold_ml_min) / (self.full_flow_ml_min - self.threshold_ml_min))
            .clamp(0.0, 1.0);
        (f * self.max_count as f64).round() as usize
    }

    /// The core radius on a grid of spacing `h_m`, m.
    pub fn core_radius_m(&self, h_m: f64) -> f64 {
        (self.core_radius_mm * 1e-3).max(self.min_core_voxels * h_m)
    }
}
