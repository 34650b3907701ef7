//! The deformation stage: the cavity surface replayed from the atlas at the hydraulics' pressure
//! (positions and `dx/dp`), only when the pressure moved by more than the scene's tolerance.

use std::time::Instant;

use super::counters::StageCounters;
use super::error::SceneError;
use super::surface::CavitySurface;
use super::types::CavityView;
use crate::atlas::Atlas;
use crate::hydraulics::HydraulicState;

/// The replayed cavity surface.
pub struct Deformation {
    surface: CavitySurface,
    /// The atlas of the cavity surface's vertices alone (what a step replays).
    surface_atlas: Atlas,
    /// The atlas's first level: pressure (Pa) and cavity volume (m^3).
    first_level: (f64, f64),
    /// A pressure change below this replays nothing, Pa.
    tolerance_pa: f64,
    /// The hydraulic pressure the surface was last replayed for, Pa.
    deformed_at_pa: f64,
    /// The volume the surface enclosed after the last replay, m^3.
    enclosed_volume_m3: f64,
    /// Changes when the triangles change (they do not: the replay moves vertices only).
    topology_revision: u64,
}

impl Deformation {
    /// The stage for `surface` (replayed at the atlas's highest pressure, for the grid's box) and
    /// its `surface_atlas`; `atlas` is the whole organ's (its first level bounds the replay).
    pub fn new(
        surface: CavitySurface,
        surface_atlas: Atlas,
        atlas: &Atlas,
        tolerance_pa: f64,
    ) -> Self {
        Self {
            surface,
            surface_atlas,
            first_level: (atlas.pressure_pa[0], atlas.cavity_volume_m3[0]),
            tolerance_pa,
            deformed_at_pa: f64::NAN,
            enclosed_volume_m3: 0.0,
            topology_revision: 1,
        }
    }

    /// The surface as last replayed.
    pub fn surface(&self) -> &CavitySurface {
        &self.surface
    }

    /// The cavity surface as published.
    pub fn cavity(&self) -> CavityView<'_> {
        CavityView {
            triangles: self.surface.triangles(),
            positions_m: self.surface.positions_m(),
            topology_revision: self.topology_revision,
            cap_triangles: self.surface.cap_triangles(),
            pressure_pa: self.surface.pressure_pa(),
        }
    }

    /// The volume the surface enclosed after the last replay, m^3 (0 before the first).
    pub fn enclosed_volume_m3(&self) -> f64 {
        self.enclosed_volume_m3
    }

    /// Replays the surface at `hydraulics`' cavity pressure if it moved by more than the
    /// tolerance (a non-finite pressure counts as 0); returns whether it did.
    pub fn step(
        &mut self,
        hydraulics: &HydraulicState,
        counters: &mut StageCounters,
    ) -> Result<bool, SceneError> {
        let t = Instant::now();
        let p = hydraulics.cavity_pressure_pa;
        let p = if p.is_finite() { p } else { 0.0 };
        let moved =
            (p - self.deformed_at_pa).abs() > self.tolerance_pa || self.deformed_at_pa.is_nan();
        if moved {
            self.surface.replay_compact(&self.surface_atlas, p)?;
            self.deformed_at_pa = p;
            self.enclosed_volume_m3 = self.surface.enclosed_volume_m3();
            if p < self.first_level.0 {
                self.match_volume_below_the_atlas(p, hydraulics.cavity_volume_m3)?;
            }
            counters.ran_since(t);
        } else {
            counters.skipped();
        }
        Ok(moved)
    }

    /// Below the atlas's first level (suction) the hydraulics continue the P-V curve's first
    /// segment; the surface's volume is not linear in its extrapolated positions, so the replay
    /// pressure is corrected by a few secant steps until the surface holds the hydraulics' volume
    /// `target` (within 0.01 %), one source of truth for what the renderer sees.
    fn match_volume_below_the_atlas(&mut self, p: f64, target: f64) -> Result<(), SceneError> {
        if !(target.is_finite() && target > 0.0) {
            return Ok(());
        }
        let (mut a, mut va) = (p, self.surface.enclosed_volume_m3());
        let (mut b, mut vb) = self.first_level;
        for _ in 0..6 {
            if (va - target).abs() <= 1e-4 * target || va == vb {
                break;
            }
            let c = a + (target - va) * (b - a) / (vb - va);
            if !c.is_finite() {
                break;
            }
            self.surface.replay_compact(&self.surface_atlas, c)?;
            (b, vb) = (a, va);
            (a, va) = (c, self.surface.enclosed_volume_m3());
        }
        self.enclosed_volume_m3 = va;
        Ok(())
    }
}
