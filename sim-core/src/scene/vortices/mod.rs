//! Rankine vortices superimposed on the resolved flow: the paper's turbulent look at high flow
//! rates (`docs/particles.md` specifies the model; the paper's section 3, "vortices").
//!
//! Each vortex has a centre `c`, a unit axis `n` (the curl of the resolved velocity at `c`), a core
//! radius `R` and a circulation `Gamma`. Its velocity is `g(s) v_theta(r) e_theta` with
//! `s = (x - c).n`, `r` the distance from the axis and `e_theta = n x r_hat`: exactly
//! divergence-free for any radial profile and axial window. `v_theta` is Rankine's
//! (`Gamma r / (2 pi R^2)` inside the core, `Gamma / (2 pi r)` outside) out to `1.5 R`, tapered
//! to zero at `2.5 R`; `g` is 1 for `|s| <= R` and tapers to zero at `2 R`, so a vortex touches only
//! a few cells. On the MAC grid the field is the discrete curl of an edge-centred vector potential
//! `A = g(s) Psi(r) n` (`Psi' = -v_theta`), zero on every edge that touches a non-fluid cell: the
//! face velocities are then discretely divergence-free in every cell (div curl = 0 identically)
//! and no flux crosses a wall, a port or the open os.
//!
//! Two modes: `overlay` keeps the solver's state untouched and offers the field to the particles
//! and the display; `injected` adds, each step, the change of the field (new minus last injected)
//! to the solver's face velocities, so the solver carries and dissipates it.

mod field;
mod potential;
mod spec;

use std::time::Instant;

pub use field::{VortexField, VortexStats};
pub use potential::{Vortex, AXIAL_END_CORES, AXIAL_FLAT_CORES, CUTOFF_CORES, RANKINE_EXACT_CORES};
pub use spec::{VortexMode, VortexSpec};

use super::counters::StageCounters;
use crate::fluid::FluidSolver;

/// The vortex stage of a scene.
#[derive(Debug, Clone, Default)]
pub struct Vortices {
    spec: VortexSpec,
    field: Option<VortexField>,
}

impl Vortices {
    /// The stage for a scene's `[vortices]` table.
    pub fn new(spec: VortexSpec) -> Self {
        Self { spec, field: None }
    }

    /// The vortices and their field, once the stage has run.
    pub fn field(&self) -> Option<&VortexField> {
        self.field.as_ref()
    }

    /// The display-only field's face velocities (overlay mode), for the particles.
    pub fn overlay_faces(&self) -> Option<[&[f32]; 3]> {
        let f = self.field.as_ref()?;
        (self.spec.mode == VortexMode::Overlay && !f.vortices().is_empty())
            .then(|| std::array::from_fn(|c| f.face_velocities(c)))
    }

    /// Advances the vortices after the fluid step, as many as the inflow `inflow_m3_per_s` asks
    /// for ([`VortexSpec::target_count`]), injecting their field into `solver` in injected mode;
    /// counts a run, or a skip below the flow-rate threshold with no vortex left.
    pub fn step(
        &mut self,
        inflow_m3_per_s: f64,
        solver: &mut FluidSolver,
        dt_s: f64,
        counters: &mut StageCounters,
    ) {
        let t = Instant::now();
        if self.advance(inflow_m3_per_s, solver, dt_s) {
            counters.ran_since(t);
        } else {
            counters.skipped();
        }
    }

    /// [`Vortices::step`]'s work; returns whether it ran.
    fn advance(&mut self, inflow_m3_per_s: f64, solver: &mut FluidSolver, dt_s: f64) -> bool {
        let target = self.spec.target_count(inflow_m3_per_s);
        if target == 0 && self.field.as_ref().is_none_or(|f| f.vortices().is_empty()) {
            return false;
        }
        if self.field.is_none() {
            match VortexField::new(self.spec.clone(), solver) {
                Ok(f) => self.field = Some(f),
                Err(e) => {
                    tracing::warn!("vortices disabled: {e}");
                    return false;
                }
            }
        }
        let Some(field) = self.field.as_mut() else {
            return false;
        };
        field.step(solver, target, dt_s);
        if self.spec.mode == VortexMode::Injected {
            field.inject(solver);
        }
        true
    }

    /// Adds the display-only overlay to cell-centred velocities (x fastest, one per cell).
    pub fn overlay_into(&self, out: &mut [[f32; 3]]) {
        if self.spec.mode == VortexMode::Overlay {
            if let Some(f) = &self.field {
                f.overlay_into(out);
            }
        }
    }
}
