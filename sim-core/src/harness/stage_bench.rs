//! The cavity that the vortex and particle benchmarks (`benches/particles.rs`) and their
//! instruction-count driver (`examples/stage_costs.rs`) share: the analytic uterine cavity
//! ([`super::analytic_cavity`]) at 1.2 mm with
//! a 1 m/s jet after 30 frames, a scope looking along +z from the cavity's lower middle, and blood
//! particles kept at a fixed count.

use super::analytic_cavity::uterine_cavity;
use crate::fluid::{CellLabel, FluidError, FluidParams, FluidSolver};
use crate::scene::clarity::{View, ViewSpec};
use crate::scene::particles::{kinds_from_labels, ParticleClass, ParticleKind, ParticleSystem};
use crate::scene::VoxelKind;

/// The frame time of the benchmarks, s.
pub const DT_S: f64 = 1.0 / 60.0;

/// The analytic uterine cavity at 1.2 mm, jet 1 m/s, after 30 frames.
pub fn cavity() -> Result<FluidSolver, FluidError> {
    let grid = uterine_cavity(1.2e-3, 1.0)?;
    let params = FluidParams {
        tolerance: 1e-5,
        ..Default::default()
    };
    let mut s = FluidSolver::new(grid, params)?;
    for _ in 0..30 {
        s.step(DT_S)?;
    }
    Ok(s)
}

/// Blood particles in the cavity, refilled to a fixed count at random fluid cells.
pub struct Blood {
    /// The particles.
    pub system: ParticleSystem,
    /// The cell kinds the particles see.
    pub kinds: Vec<VoxelKind>,
    /// The scope's view cone for the clarity figure.
    pub view: View,
    class: u8,
    fluid: Vec<usize>,
    count: usize,
    rng: fastrand::Rng,
}

impl Blood {
    /// `count` blood particles in `s`'s fluid (None if the class cannot be added).
    pub fn new(s: &FluidSolver, count: usize) -> Option<Self> {
        let kinds = kinds_from_labels(s.grid());
        let fluid = (0..kinds.len())
            .filter(|&n| s.grid().label_at(n) == CellLabel::Fluid)
            .collect();
        let [nx, ny, nz] = s.grid().dims();
        let h = s.grid().spacing_m();
        let o = s.grid().origin_m();
        let view = ViewSpec::default().cone(
            [
                o[0] + 0.5 * nx as f64 * h,
                o[1] + 0.5 * ny as f64 * h,
                o[2] + 0.2 * nz as f64 * h,
            ],
            [0.0, 0.0, 1.0],
        );
        let mut system = ParticleSystem::new(s.grid(), count, 8, [0.0, -1.0, 0.0]);
        let class = system.add_class(ParticleClass {
            kind: ParticleKind::Blood,
            settle_m_s: 3e-4,
            tau_s: 1e-4,
            shade_m2: 2e-7,
            diameter_m: 5e-5,
        })?;
        let mut blood = Self {
            system,
            kinds,
            view,
            class,
            fluid,
            count,
            rng: fastrand::Rng::with_seed(0),
        };
        blood.refill(s);
        Some(blood)
    }

    /// Emits at random fluid cells until the count is back (the outlets remove some each step).
    pub fn refill(&mut self, s: &FluidSolver) {
        if self.fluid.is_empty() {
            return;
        }
        while self.system.len() < self.count {
            let n = self.fluid[self.rng.usize(..self.fluid.len())];
            let c = s.grid().cell_centre_m(s.grid().coords(n));
            if !self.system.emit(&self.kinds, self.class, c) {
                return;
            }
        }
    }

    /// Refills, then one particle step with the view's clarity figure.
    pub fn step(&mut self, s: &FluidSolver) -> Option<f64> {
        self.refill(s);
        self.system
            .step(s, &self.kinds, None, DT_S, Some(&self.view))
    }
}
