//! What the particle stage reads each step.

use crate::fluid::FluidSolver;
use crate::scene::{CavityView, InflowPort, ScopeGeometry, VoxelBox, VoxelKind};

/// What the particle stage reads: the flow after the fluid (and vortex) step and the cavity.
#[derive(Clone, Copy)]
pub struct ParticleInputs<'a> {
    /// Scene time at the end of the step, s.
    pub time_s: f64,
    /// The fluid solver, after its step.
    pub solver: &'a FluidSolver,
    /// The grid's box.
    pub grid: VoxelBox,
    /// Kind of every cell, x fastest.
    pub kinds: &'a [VoxelKind],
    /// The cavity surface (the bleeding sources sit on its wall).
    pub cavity: CavityView<'a>,
    /// The inflow port (bubbles enter beside it; its jet disperses the particles).
    pub inflow: InflowPort<'a>,
    /// The scope, for the clarity of its view (`None` before a pose).
    pub scope: Option<&'a ScopeGeometry>,
    /// The vortices' display-only face velocities, added to the solver's.
    pub overlay: Option<[&'a [f32]; 3]>,
    /// The hydraulics' inflow, m^3/s.
    pub inflow_m3_per_s: f64,
}
