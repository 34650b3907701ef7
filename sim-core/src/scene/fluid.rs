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
}

impl FluidStage {
    /// The stage around `solver`.
    pub fn new(solver: FluidSolver, min_fluid_cells: usize, rest_speed_m_s: f64) -> Self {
        Self {
            solver,
            min_fluid_cells,
            rest_speed_m_s,
        }
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
