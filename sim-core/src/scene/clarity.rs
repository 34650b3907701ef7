//! View clarity: how much the particles obscure the scope's view (`docs/particles.md`).
//!
//! The figure is `exp(-tau_mean)`, `tau_mean` the optical depth averaged over the rays of the
//! view cone (apex at the scope's tip, half angle `half_angle_deg`, out to `depth_mm`): a
//! particle at distance `r` inside the cone adds `s / (r^2 Omega)`, `Omega` the cone's solid
//! angle and `s` its obscuring weight (`kappa V` for a blood puff of volume `V` in whole blood of
//! attenuation `kappa`, Beer-Lambert; the projected area for opaque bubbles and fragments).
//! Distances under `near_mm` count as `near_mm` (the lens's near limit). 1 is a clear view.

use serde::{Deserialize, Serialize};

/// The `[particles.view]` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ViewSpec {
    /// Half opening angle of the view cone, degrees.
    pub half_angle_deg: f64,
    /// How far the view reaches, mm.
    pub depth_mm: f64,
    /// Near limit, mm.
    pub near_mm: f64,
    /// The view counts as clear from this clarity on.
    pub clear_threshold: f64,
}

impl Default for ViewSpec {
    fn default() -> Self {
        Self {
            half_angle_deg: 35.0,
            depth_mm: 40.0,
            near_mm: 2.0,
            clear_threshold: 0.9,
        }
    }
}

impl ViewSpec {
    /// Checks every range; the message names the key.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.half_angle_deg > 0.0 && self.half_angle_deg < 90.0) {
            return Err(format!(
                "`particles.view.half_angle_deg` = {}: expected 0 < angle < 90",
                self.half_angle_deg
            ));
        }
        for (k, v) in [("depth_mm", self.depth_mm), ("near_mm", self.near_mm)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!(
                    "`particles.view.{k}` = {v}: expected a finite length > 0"
                ));
            }
        }
        if !(self.clear_threshold > 0.0 && self.clear_threshold < 1.0) {
            return Err(format!(
                "`particles.view.clear_threshold` = {}: expected 0 < threshold < 1",
                self.clear_threshold
            ));
        }
        Ok(())
    }

    /// The cone from a scope pose (`dir` unit).
    pub fn cone(&self, tip_m: [f64; 3], dir: [f64; 3]) -> View {
        View {
            tip_m,
            dir,
            cos_half_angle: self.half_angle_deg.to_radians().cos(),
            depth_m: self.depth_mm * 1e-3,
            near_m: self.near_mm * 1e-3,
        }
    }
}

/// Derived figures of the clarity over time.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ClarityTracker {
    threshold: f64,
    obscured_since_s: Option<f64>,
    /// Length of the last finished obscured episode, s.
    pub last_obscured_s: Option<f64>,
    /// Time from the end of the last bleed to the view's clearing, s.
    pub time_to_clear_s: Option<f64>,
    /// Lowest clarity seen.
    pub min_clarity: Option<f64>,
}

impl ClarityTracker {
    /// A tracker; the view is clear from `threshold` on.
    pub fn new(threshold: f64) -> Self {
        Self {
            threshold,
            ..Self::default()
        }
    }

    /// Feeds the clarity at `time_s`; `bleed_end_s` is when the bleeding stops (if it does).
    pub fn update(&mut self, time_s: f64, clarity: f64, bleed_end_s: Option<f64>) {
        self.min_clarity = Some(self.min_clarity.map_or(clarity, |m| m.min(clarity)));
        if clarity < self.threshold {
            if self.obscured_since_s.is_none() {
                self.obscured_since_s = Some(time_s);
            }
            return;
        }
        if let Some(since) = self.obscured_since_s.take() {
            self.last_obscured_s = Some(time_s - since);
            if let Some(end) = bleed_end_s {
                if time_s >= end && self.time_to_clear_s.is_none() {
                    self.time_to_clear_s = Some(time_s - end);
                }
            }
        }
    }
}

/// A view cone for the clarity figure.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct View {
    /// Apex (the scope's tip), m.
    pub tip_m: [f64; 3],
    /// Unit view direction.
    pub dir: [f64; 3],
    /// Cosine of the half opening angle.
    pub cos_half_angle: f64,
    /// How far the view reaches, m.
    pub depth_m: f64,
    /// Distances below this count as this (the lens's near limit), m.
    pub near_m: f64,
}

impl View {
    /// The cone's solid angle, sr.
    pub fn solid_angle_sr(&self) -> f64 {
        std::f64::consts::TAU * (1.0 - self.cos_half_angle)
    }
}
