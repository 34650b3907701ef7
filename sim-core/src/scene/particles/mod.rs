//! Blood, bubble and fragment particles advected by the flow (`docs/particles.md`).
//!
//! Particles live in fixed-capacity arrays (the budget, allocated once); positions are kept in
//! grid units (cell `(i, j, k)` spans `[i, i+1) x [j, j+1) x [k, k+1)`). Each step builds the
//! cell-centred velocity `v = v_f (+ the vortex overlay)` once, then moves every particle with
//! the explicit midpoint rule (RK2) in as many substeps as keep it under one cell per substep
//! (`max_substeps` at most), plus its slip: the velocity relative to the fluid relaxes
//! exponentially (time `tau`) to the terminal settling or rise velocity along gravity, integrated
//! exactly over the step. A substep that ends in a non-fluid cell slides (one axis reverted) or
//! stays; a particle entering an outflow-hole cell or the open os leaves the cavity.
//!
//! The files: `spec` (the `[particles]` table), `slip` (drag and settling), `system` (storage
//! and the step), `kernel` and `sweep` (the per-particle step and its sweep over a task; `block8`
//! its eight-lane twin; the four-lane operations are `crate::simd::v4`'s), `inputs` (what the
//! stage reads), `sources` (classes and emission), `output` (VTK), `traverse` (the time to traverse), and here the scene's stage.

#[cfg(target_arch = "x86_64")]
mod block8;
mod inputs;
mod kernel;
mod output;
mod slip;
mod sources;
mod spec;
mod sweep;
mod system;
mod traverse;

use std::time::Instant;

pub use inputs::ParticleInputs;
pub use output::{particles_xml, VtkFlavour};
pub use slip::{drag_coefficient, terminal_slip, SlipFluid, GRAVITY_M_S2};
pub use spec::{
    BleedingSourceSpec, BloodSpec, BubbleSpec, FragmentSpec, GravitySpec, ParticleKind,
    ParticleSpec,
};
pub use system::{kinds_from_labels, ParticleClass, ParticleCounts, ParticleSystem};
pub use traverse::{
    inflow_face_points, time_to_traverse, Traverse, TRAVERSE_OFFSET_VOXELS, TRAVERSE_SUBGRID,
};

use super::clarity::ClarityTracker;
use super::counters::StageCounters;
use super::dispersion;
use sources::Sources;
use system::WALK_STREAM;

/// The particle stage of a scene.
#[derive(Debug, Clone, Default)]
pub struct Particles {
    spec: ParticleSpec,
    system: Option<ParticleSystem>,
    sources: Option<Sources>,
    clarity: Option<f64>,
    tracker: ClarityTracker,
    /// The share of the budget in use (`SceneQuality::particle_budget_share`).
    budget_share: f64,
}

impl Particles {
    /// The stage for a scene's `[particles]` table.
    pub fn new(spec: ParticleSpec) -> Self {
        let tracker = ClarityTracker::new(spec.view.clear_threshold);
        Self {
            spec,
            tracker,
            budget_share: 1.0,
            ..Self::default()
        }
    }
    /// Uses `share` of the budget from now on (`ParticleSystem::set_budget_share`).
    pub fn set_budget_share(&mut self, share: f64) {
        self.budget_share = share;
        if let Some(sys) = &mut self.system {
            sys.set_budget_share(share);
        }
    }
    /// The particles, once the stage has run.
    pub fn system(&self) -> Option<&ParticleSystem> {
        self.system.as_ref()
    }
    /// The clarity of the scope's view after the last step (1 clear, 0 opaque); `None` without a
    /// scope.
    pub fn clarity(&self) -> Option<f64> {
        self.clarity
    }
    /// The clarity's history: time obscured, time to clear after the last bleed.
    pub fn tracker(&self) -> &ClarityTracker {
        &self.tracker
    }
    /// The particles as VTK PolyData (a document with no points before the first step).
    pub fn vtp_string(&self) -> String {
        particles_xml(self.system.as_ref(), VtkFlavour::PolyData)
    }
    /// The particles as a VTK UnstructuredGrid of vertex cells (no points before the first
    /// step); what `hydrometra scene run` writes into its ParaView series.
    pub fn vtu_string(&self) -> String {
        particles_xml(self.system.as_ref(), VtkFlavour::UnstructuredGrid)
    }

    /// Emits this step's particles, advances every particle by `dt_s` in the flow and takes the
    /// clarity of the scope's view; counts a run, or a skip when the scene has no source and no
    /// particle is alive.
    pub fn step(&mut self, inputs: &ParticleInputs<'_>, dt_s: f64, counters: &mut StageCounters) {
        let t = Instant::now();
        if self.advance(inputs, dt_s) {
            counters.ran_since(t);
        } else {
            counters.skipped();
        }
    }

    /// [`Particles::step`]'s work; returns whether it ran.
    fn advance(&mut self, inputs: &ParticleInputs<'_>, dt_s: f64) -> bool {
        let alive = self.system.as_ref().is_some_and(|s| !s.is_empty());
        if !self.spec.emits() && !alive {
            return false;
        }
        if self.system.is_none() {
            let Some((system, sources)) = self.init(inputs) else {
                return false;
            };
            (self.system, self.sources) = (Some(system), Some(sources));
        }
        let (Some(sys), Some(sources)) = (self.system.as_mut(), self.sources.as_mut()) else {
            return false;
        };
        let t = inputs.time_s;
        sources.emit(&self.spec, sys, inputs, t, dt_s);
        let view = inputs.scope.map(|sc| self.spec.view.cone(sc.tip_m, sc.dir));
        sys.set_eddy_diffusivity(if self.spec.eddy_dispersion {
            dispersion::jet_eddy_diffusivity_m2_s(
                inputs.inflow_m3_per_s,
                inputs.inflow.channel_area_m2,
            )
        } else {
            0.0
        });
        self.clarity = sys.step(
            inputs.solver,
            inputs.kinds,
            inputs.overlay,
            dt_s,
            view.as_ref(),
        );
        let bleed_end = self
            .spec
            .blood
            .sources
            .iter()
            .map(|s| s.onset_s + s.duration_s)
            .fold(f64::NEG_INFINITY, f64::max);
        if let Some(c) = self.clarity {
            self.tracker
                .update(t, c, bleed_end.is_finite().then_some(bleed_end));
        }
        true
    }

    /// The system on the solver's grid with the spec's classes (slipping in the solver's fluid),
    /// and the sources placed on the cavity.
    fn init(&self, inputs: &ParticleInputs<'_>) -> Option<(ParticleSystem, Sources)> {
        let spec = &self.spec;
        let g = spec.gravity.unit().ok()?;
        let mut sys = ParticleSystem::new(inputs.solver.grid(), spec.budget, spec.max_substeps, g);
        let fluid = SlipFluid::of(inputs.solver.params());
        let sources = Sources::new(spec, &mut sys, &inputs.cavity, fluid)?;
        sys.seed_walk(spec.seed ^ WALK_STREAM);
        sys.set_budget_share(self.budget_share);
        Some((sys, sources))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fluid::{FluidGrid, FluidParams, FluidSolver};
    use crate::scene::{CavityView, InflowPort, VoxelBox, VoxelKind};

    /// The particles settle in the fluid the solver simulates: every class's terminal slip and
    /// relaxation time come from the solver's density and viscosity (kinematic times density),
    /// whatever they are, and the blood droplet's settling is Stokes's law,
    /// `w = (rho_p - rho_f) g d^2 / (18 mu)`, over Schiller-Naumann's `1 + 0.15 Re^0.687`.
    #[test]
    fn particles_slip_in_the_fluid_solvers_density_and_viscosity() {
        let grid = VoxelBox {
            dims: [4, 4, 4],
            origin_m: [0.0; 3],
            spacing_m: 1e-3,
        };
        let kinds = vec![VoxelKind::Solid; grid.cell_count()];
        let mut spec = ParticleSpec::default();
        spec.bubbles.per_ml = 1.0; // a source, so the stage sets up its classes
        let mut settling = Vec::new();
        for (rho_f, nu) in [(1000.0, 1e-6), (1030.0, 3e-6)] {
            let params = FluidParams {
                density_kg_m3: rho_f,
                viscosity_m2_s: nu,
                ..FluidParams::default()
            };
            let fluid_grid = FluidGrid::new(grid.dims, grid.spacing_m, grid.origin_m, [false; 3])
                .expect("a valid grid");
            let solver = FluidSolver::new(fluid_grid, params).expect("valid parameters");
            let inputs = ParticleInputs {
                time_s: 0.01,
                solver: &solver,
                grid,
                kinds: &kinds,
                cavity: CavityView {
                    triangles: &[],
                    positions_m: &[],
                    topology_revision: 1,
                    cap_triangles: 0,
                    pressure_pa: 0.0,
                },
                inflow: InflowPort {
                    cells: &[],
                    grid,
                    direction: None,
                    channel_area_m2: 1e-6,
                },
                scope: None,
                overlay: None,
                inflow_m3_per_s: 0.0,
            };
            let mut stage = Particles::new(spec.clone());
            stage.step(&inputs, 0.01, &mut StageCounters::default());
            let classes = stage.system().expect("the stage ran").classes();
            let mu = rho_f * nu;
            let b = &spec.blood;
            let d = b.droplet_diameter_mm * 1e-3;
            let blood = classes[0];
            assert_eq!(blood.kind, ParticleKind::Blood);
            assert_eq!(
                (blood.settle_m_s, blood.tau_s),
                terminal_slip(d, b.density_kg_m3, rho_f, mu)
            );
            // Stokes's law with Schiller-Naumann's correction at the droplet's Reynolds number
            // (0.3 % at Re = 0.004): the balance the drag law must hold in this fluid.
            let stokes = (b.density_kg_m3 - rho_f) * GRAVITY_M_S2 * d * d / (18.0 * mu);
            let w = blood.settle_m_s;
            let re = rho_f * w.abs() * d / mu;
            let balanced = w * (1.0 + 0.15 * re.powf(0.687));
            assert!(
                (balanced - stokes).abs() <= 1e-9 * stokes.abs(),
                "{w} (balanced {balanced}) vs Stokes {stokes}"
            );
            // The bubbles too (the first size class).
            let bs = &spec.bubbles;
            let d = (bs.min_diameter_mm + (bs.max_diameter_mm - bs.min_diameter_mm) / 16.0) * 1e-3;
            assert_eq!(
                (classes[1].settle_m_s, classes[1].tau_s),
                terminal_slip(d, bs.density_kg_m3, rho_f, mu)
            );
            settling.push(blood.settle_m_s);
        }
        // Three times the viscosity and a denser fluid: the droplet sinks far slower.
        assert!(settling[1] < 0.5 * settling[0], "{settling:?}");
    }
}
