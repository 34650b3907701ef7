//! The fluid stage: one step of the MAC-grid solver ([`FluidSolver`]) on the labels and boundary
//! velocities the ports stage set, skipped while the cavity holds too few fluid cells or the
//! field is at rest with nothing driving it.

use std::time::Instant;

use super::counters::StageCounters;
use super::error::SceneError;
use crate::fluid::{FluidSolver, StepStats};

/// What the fluid stage reads besides the solver's own state.
#[derive(Debug, Clone, Copy)]
pub struct FluidDrive {
    /// Fluid cells of the current labels.
    pub fluid_cells: usize,
    /// The labels changed in this frame.
    pub relabelled: bool,
    /// A port or a wall carries flow in this frame.
    pub boundaries_flow: bool,
}

/// What one step of the fluid stage did.
#[derive(Debug, Clone, Copy)]
pub struct FluidStep {
    /// Too few fluid cells: the stage idles.
    pub idle: bool,
    /// The solver's counters, when it stepped.
    pub stats: Option<StepStats>,
}

/// The fluid solver and when it runs.
pub struct FluidStage {
    solver: FluidSolver,
    /// Fewer fluid cells than this: the stage idles.
    min_fluid_cells: usize,
    /// A field slower than this everywhere, with nothing driving it, is at rest, m/s.
    rest_speed_m_s: f64,
    /// The solver's substep bound as configured (`cap_substeps` lowers it, never raises it).
    configured_max_substeps: usize,
}

impl FluidStage {
    /// The stage around `solver`.
    pub fn new(solver: FluidSolver, min_fluid_cells: usize, rest_speed_m_s: f64) -> Self {
        let configured_max_substeps = solver.params().max_substeps;
        Self {
            solver,
            min_fluid_cells,
            rest_speed_m_s,
            configured_max_substeps,
        }
    }

    /// At most `cap` substeps per step from now on (`None`: as configured). A capped step can run
    /// above the CFL bound: the semi-Lagrangian advection stays stable, only less accurate.
    pub fn cap_substeps(&mut self, cap: Option<usize>) -> Result<(), SceneError> {
        let n = cap.map_or(self.configured_max_substeps, |c| {
            c.clamp(1, self.configured_max_substeps)
        });
        if self.solver.params().max_substeps != n {
            let mut params = self.solver.params().clone();
            params.max_substeps = n;
            self.solver.set_params(params)?;
        }
        Ok(())
    }

    /// The solver.
    pub fn solver(&self) -> &FluidSolver {
        &self.solver
    }

    /// The solver, to set labels and boundary velocities or to add a field.
    pub fn solver_mut(&mut self) -> &mut FluidSolver {
        &mut self.solver
    }

    /// Steps the solver by `dt_s` unless it idles (too few fluid cells), rests (no boundary
    /// flow, no relabelling, the field slower than the rest speed) or `dt_s` is zero.
    pub fn step(
        &mut self,
        drive: FluidDrive,
        dt_s: f64,
        counters: &mut StageCounters,
    ) -> Result<FluidStep, SceneError> {
        let t = Instant::now();
        let idle = drive.fluid_cells < self.min_fluid_cells;
        let at_rest = !drive.boundaries_flow
            && !drive.relabelled
            && self.solver.max_speed_m_s() < self.rest_speed_m_s;
        if idle || at_rest || dt_s == 0.0 {
            counters.skipped();
            return Ok(FluidStep { idle, stats: None });
        }
        let stats = self.solver.step(dt_s)?;
        counters.ran_since(t);
        Ok(FluidStep {
            idle,
            stats: Some(stats),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fluid::{FluidGrid, FluidParams};

    /// A step far above the CFL bound splits into substeps as configured; capped, it takes at
    /// most the cap and stays finite, and uncapping restores the configured
    /// bound (never above it).
    #[test]
    fn capping_the_substeps_bounds_them_and_uncapping_restores_the_configuration() {
        let (n, h) = (12, 1e-3);
        let grid = FluidGrid::new([n, n, n], h, [0.0; 3], [false; 3]).unwrap();
        let params = FluidParams {
            max_cfl: Some(1.0),
            max_substeps: 6,
            ..FluidParams::default()
        };
        let solver = FluidSolver::new(grid, params).unwrap();
        // A swirl of 0.5 m/s, set again before each step: a 100 ms step moves it 50 cells (CFL
        // 50, far above every bound).
        let swirl = |c: usize, p: [f64; 3]| match c {
            0 => -0.5 * (p[1] - 0.006) / 0.006,
            1 => 0.5 * (p[0] - 0.006) / 0.006,
            _ => 0.0,
        };
        let mut stage = FluidStage::new(solver, 1, 0.0);
        let dt_s = 0.1;
        let step = |stage: &mut FluidStage| {
            stage.solver_mut().set_velocity_field(swirl);
            stage.solver_mut().step(dt_s).unwrap().substeps
        };
        assert_eq!(step(&mut stage), 6);
        for (cap, want) in [(Some(1), 1), (Some(3), 3), (Some(100), 6), (Some(0), 1)] {
            stage.cap_substeps(cap).unwrap();
            assert_eq!(stage.solver().params().max_substeps, want, "{cap:?}");
            assert_eq!(step(&mut stage), want, "{cap:?}");
            assert!(stage.solver().max_speed_m_s().is_finite());
        }
        stage.cap_substeps(None).unwrap();
        assert_eq!(step(&mut stage), 6);
    }
}
