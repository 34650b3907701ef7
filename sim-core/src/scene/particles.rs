//! Blood, bubble and fragment particles advected by the flow, and the view-clarity figure.
//! Not built yet: the stage exists in the pipeline and its counters, and does nothing.

use super::Scene;

/// The particle stage.
#[derive(Debug, Clone, Default)]
pub struct Particles {}

impl Particles {
    /// Advances the particles after the fluid (and vortex) step; returns whether the stage ran.
    pub(crate) fn step(&mut self, _scene: &Scene, _dt_s: f64) -> bool {
        false
    }
}
