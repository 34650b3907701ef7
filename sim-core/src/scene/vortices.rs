//! Rankine vortices superimposed on the resolved flow (the paper's turbulence at high flow rates).
//! Not built yet: the stage exists in the pipeline and its counters, and does nothing.

use super::Scene;

/// The vortex stage.
#[derive(Debug, Clone, Default)]
pub struct Vortices {}

impl Vortices {
    /// Advances the vortices after the fluid step; returns whether the stage ran.
    pub(crate) fn step(&mut self, _scene: &mut Scene, _dt_s: f64) -> bool {
        false
    }

    /// Adds the display-only overlay to cell-centred velocities (x fastest, one per cell).
    pub(crate) fn overlay_into(&self, _scene: &Scene, _out: &mut [[f32; 3]]) {}
}
