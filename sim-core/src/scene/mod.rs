//! The scene: hydraulics, deformation, voxelization, ports, fluid, vortices and particles coupled
//! in one real-time pipeline behind one [`Scene::step`].
//!
//! ```text
//!  RigInputs ──► hydraulics ──► deformation ──► voxelize ──► ports ──► fluid ──► vortices ──► particles
//!  (valves,      (pressure,     (atlas replay    (cavity      (labels,   (MAC      (overlay or  (blood,
//!   pump,         flows,         of the cavity    surface ->   port and   grid      injected)    bubbles,
//!   scope)        volume, dV/dt) surface, dx/dp)  cell states) wall vel.) step)                  fragments)
//! ```
//! Each stage is a type in a file of its own, and its `step` names what it reads and what it
//! gives (plain records; those several stages share are in `types.rs`, which imports no stage):
//!
//! | stage | reads | gives |
//! |---|---|---|
//! | [`HydraulicStage`] | the rig's [`crate::hydraulics::HydraulicInputs`], [`HydraulicsInput`] | [`FrameFlows`], its [`crate::hydraulics::HydraulicState`] |
//! | [`Deformation`] | the hydraulic state | whether the [`CavitySurface`] moved |
//! | [`Voxelizer`] | the moved surface's positions | the rows whose cell states changed |
//! | [`CavityFractions`] (`[fluid] cut_cells`) | the voxelizer's held positions, the scope pose the labels are composed for | the cells' fluid volume and faces' open area fractions inside the cavity and outside the sheath, the rows they changed in, the reference volume; into the solver |
//! | [`Ports`] | those rows, the [`ScopePose`], [`CavityCells`], [`FrameFlows`] | labels and boundary velocities in the solver, [`FluxBalance`], [`PortsStep`] |
//! | [`FluidStage`] | [`FluidDrive`] | the step of its solver, [`FluidStep`] |
//! | [`vortices::Vortices`] | the inflow, the solver | their field (overlaid or injected) |
//! | [`particles::Particles`] | [`particles::ParticleInputs`] | emission, advection, the view's clarity |
//!
//! No stage takes the scene. Every stage decides whether it has work (the pressure moved, a vertex
//! or the scope moved more than a fraction of a voxel, a port flows or the field is not at rest)
//! and reports runs, skips and times in its [`StageCounters`] ([`StepReport::counters`]). The
//! hydraulics may run inside the scene (the offline runner) or in another loop that hands the
//! scene its newest state (the daemon's 1 kHz loop): [`HydraulicsInput`]. The flux the fluid sees
//! through the ports and moving walls equals the hydraulics' flows over the frame (see
//! [`FluxBalance`]); `docs/scene.md` specifies it all.
//!
//! ```no_run
//! use hydrometra_sim::scene::{prepare, HydraulicsInput, RigInputs, Scene, SceneDesc, SceneInputs};
//! let desc = SceneDesc::builtin("default")?;
//! let (assets, _) = prepare::load_or_build(&desc, None, &mut |_, _, _, _| {})?;
//! let mut scene = Scene::new(desc, assets)?;
//! let mut rig = RigInputs::default();
//! rig.hydraulic.valve_in_opening = 1.0;
//! rig.hydraulic.pump_set_pressure_pa = 12_000.0;
//! for _ in 0..60 {
//!     let report = scene.step(&SceneInputs { rig, hydraulics: HydraulicsInput::Own }, 1.0 / 60.0)?;
//!     println!("{:.1} Pa, {} fluid cells", report.cavity_pressure_pa, report.fluid_cells);
//! }
//! # Ok::<(), hydrometra_sim::scene::SceneError>(())
//! ```

pub mod clarity;
pub mod counters;
mod cut_cells;
mod cut_walls;
mod deformation;
pub mod desc;
pub mod dispersion;
mod error;
mod flow_field;
mod fluid;
mod hydraulics;
pub mod particles;
mod ports;
pub mod prepare;
mod random;
mod scope;
pub mod surface;
mod types;
pub mod vortices;
pub mod voxelize;

use std::time::Instant;

pub use counters::{Counters, Stage, StageCounters};
pub use cut_cells::CavityFractions;
pub use cut_walls::CutWalls;
pub use deformation::Deformation;
pub use desc::SceneDesc;
pub use error::SceneError;
pub use flow_field::FlowField;
pub use fluid::{FluidDrive, FluidStage, FluidStep};
pub use hydraulics::HydraulicStage;
pub use ports::{CavityCells, Ports, PortsStep, MIN_INFLOW_OPEN_FRACTION};
pub use prepare::SceneAssets;
pub use scope::{ScopeDims, ScopeGeometry, ScopePart, SheathMesh};
pub use surface::CavitySurface;
pub use types::{
    BoundaryCell, CavityView, FluxBalance, FrameFlows, HydraulicsInput, InflowPort, RigInputs,
    SceneInputs, SceneQuality, ScopePose, StepReport, VoxelKind, WholeBoxCheck,
};
pub use voxelize::{VoxelBox, Voxelizer};

use crate::atlas::Atlas;
use crate::fluid::{CellLabel, FluidGrid, FluidParams, FluidSolver};
use crate::hydraulics::{HydraulicModel, HydraulicState};
use particles::{ParticleInputs, Particles};
use vortices::Vortices;

/// With cut cells, how far beyond a moved surface vertex (along its move, in units of the
/// `skip.cut_move_fraction` threshold) the voxelizer holds it ([`Voxelizer::update_leading`]).
/// Below 1, so every held position stays within the threshold of the surface.
pub const CUT_LEAD: f64 = 0.9;

/// The coupled pipeline: its stages in order, each owning its state.
pub struct Scene {
    desc: SceneDesc,
    atlas: Atlas,
    hydraulics: HydraulicStage,
    deformation: Deformation,
    voxelizer: Voxelizer,
    /// With `[fluid] cut_cells` and a fluid stage: the fractions of the voxelizer's surface.
    fractions: Option<CavityFractions>,
    /// With the fractions: the fluxes of the walls and the os through the cut cells' pieces.
    cut_walls: Option<CutWalls>,
    ports: Ports,
    /// Present when the scene has a fluid stage (and then the vortices and particles may run).
    fluid: Option<FluidStage>,
    vortices: Option<Vortices>,
    particles: Option<Particles>,
    report: StepReport,
}

impl Scene {
    /// Builds the scene's stages on the grid box of the cavity at the atlas's highest pressure.
    pub fn new(desc: SceneDesc, assets: SceneAssets) -> Result<Self, SceneError> {
        desc.validate()?;
        let SceneAssets { mesh, atlas } = assets;
        let mut surface = CavitySurface::new(&mesh)?;
        let top = atlas.pressure_pa[atlas.level_count() - 1];
        let surface_atlas = surface.compact_atlas(&atlas)?;
        surface.replay_compact(&surface_atlas, top)?;
        let cells = grid_box(&desc, &surface)?;
        let voxelizer = Voxelizer::new(cells, surface.triangles().to_vec(), surface.vertex_count());
        let fluid = if desc.stages.fluid {
            Some(fluid_solver(&desc, &cells)?)
        } else {
            None
        };
        let fractions = if desc.stages.fluid && desc.fluid.cut_cells {
            let tris = surface.triangles().to_vec();
            let sheath = SheathMesh::new(ScopeDims::of(&desc.scope), cells.spacing_m);
            Some(CavityFractions::new(
                cells,
                tris,
                surface.vertex_count(),
                sheath,
            )?)
        } else {
            None
        };
        let compliance = prepare::compliance_of(&atlas).map_err(|e| {
            SceneError::Prepare(format!("{}: the atlas's P-V curve: {e}", desc.origin))
        })?;
        let hydraulics =
            HydraulicModel::with_compliance(desc.hydraulics.clone(), Box::new(compliance))?;
        let mut counters = Counters::default();
        for s in [Stage::Deformation, Stage::Voxelize] {
            counters.get_mut(s).present = true;
        }
        counters.get_mut(Stage::Ports).present = fluid.is_some();
        counters.get_mut(Stage::Fluid).present = fluid.is_some();
        counters.get_mut(Stage::Vortices).present = desc.stages.vortices;
        counters.get_mut(Stage::Particles).present = desc.stages.particles;
        Ok(Self {
            hydraulics: HydraulicStage::new(hydraulics),
            deformation: Deformation::new(
                surface,
                surface_atlas,
                &atlas,
                desc.skip.pressure_tolerance_pa,
            ),
            voxelizer,
            cut_walls: fractions
                .as_ref()
                .map(|_| CutWalls::new(cells.cell_count())),
            fractions,
            ports: Ports::new(cells, &desc),
            fluid: fluid.map(|solver| {
                FluidStage::new(solver, desc.fluid.min_fluid_cells, desc.skip.rest_speed_m_s)
            }),
            vortices: desc
                .stages
                .vortices
                .then(|| Vortices::new(desc.vortices.clone())),
            particles: desc
                .stages
                .particles
                .then(|| Particles::new(desc.particles.clone())),
            report: StepReport {
                counters,
                ..StepReport::default()
            },
            desc,
            atlas,
        })
    }

    /// Advances the scene by `dt_s` seconds: each stage in turn, on what the stages before it
    /// produced.
    pub fn step(&mut self, inputs: &SceneInputs<'_>, dt_s: f64) -> Result<&StepReport, SceneError> {
        let started = Instant::now();
        let dt_s = if dt_s.is_finite() && dt_s > 0.0 {
            dt_s.min(1.0)
        } else {
            0.0
        };
        self.report.frame += 1;
        self.report.time_s += dt_s;
        self.report.relabelled_cells = 0;

        // 1. Hydraulics: the cavity's pressure and volume; the flows the ports must carry.
        let flows = self.hydraulics.step(
            &inputs.rig.hydraulic,
            inputs.hydraulics,
            dt_s,
            self.report.counters.get_mut(Stage::Hydraulics),
        );
        self.report.cavity_volume_m3 = flows.volume_m3;

        // 2. Deformation: the cavity surface replayed from the atlas at that pressure.
        let deformed = self.deformation.step(
            self.hydraulics.state(),
            self.report.counters.get_mut(Stage::Deformation),
        )?;
        let surface = self.deformation.surface();
        self.report.surface_volume_m3 = self.deformation.enclosed_volume_m3();
        self.report.cavity_pressure_pa = surface.pressure_pa();

        // 3. Voxelize: the cell states of the surface where a vertex moved by a voxel fraction;
        // with cut cells, the fractions of the same positions, with a smaller fraction (their
        // volume lags the surface's by up to that many voxels times its area: 0.1 voxel cost
        // 2.5-3.9 % of the cavity's volume while it distended at 1.2 mm).
        let move_fraction = match self.fractions {
            Some(_) => self.desc.skip.cut_move_fraction,
            None => self.desc.skip.voxel_move_fraction,
        };
        let threshold_m = move_fraction * self.voxelizer.cells().spacing_m;
        // With cut cells a vertex's held position goes `CUT_LEAD` of the threshold beyond it
        // along its move: the fractions then straddle the surface and follow it half as often.
        let lead_m = match self.fractions {
            Some(_) => CUT_LEAD * threshold_m,
            None => 0.0,
        };
        let changed_rows = self.voxelizer.step(
            deformed.then(|| surface.positions_m()),
            threshold_m,
            lead_m,
            self.report.counters.get_mut(Stage::Voxelize),
        );

        // 4. Ports: the scope at its pose; the labels of the rows that the cavity or the scope
        // changed; the ports' and walls' velocities for the frame's flows.
        self.ports.track(changed_rows, &inputs.rig.scope);
        if let Some(fractions) = self.fractions.as_mut() {
            // The sheath layer at the pose the labels are composed for: a moved surface changes
            // the fractions, so the labels are composed then too.
            let moved = self.voxelizer.last_stats().moved_vertices > 0;
            let scope = self.ports.scope_to_compose(moved);
            let cut_rows = fractions.step(
                &self.voxelizer,
                scope.as_ref(),
                self.report.counters.get_mut(Stage::Voxelize),
            )?;
            self.ports.track_rows(cut_rows);
            self.report.cavity_less_sheath_volume_m3 = Some(fractions.cavity_less_sheath_m3());
        }
        let Some(fluid) = self.fluid.as_mut() else {
            return Ok(self.finish(started));
        };
        let cavity = CavityCells {
            voxels: &self.voxelizer,
            surface,
            fractions: self.fractions.as_ref(),
        };
        let ports = self.ports.step(
            &cavity,
            &flows,
            fluid.solver_mut(),
            &mut self.report.flux,
            self.report.counters.get_mut(Stage::Ports),
        )?;
        if let Some(n) = ports.relabelled_cells {
            self.report.relabelled_cells = n;
        }
        if let Some(fractions) = self.fractions.as_mut() {
            fractions.send(fluid.solver_mut().grid_mut(), self.ports.scope_cells())?;
        }
        if let (Some(fractions), Some(walls)) = (self.fractions.as_ref(), self.cut_walls.as_mut()) {
            // When the ports stage set its boundaries, or the pieces moved fluid last time.
            if ports.relabelled_cells.is_some() || ports.boundaries_flow || walls.moving() {
                let t = Instant::now();
                let cavity = CavityCells {
                    voxels: &self.voxelizer,
                    surface,
                    fractions: Some(fractions),
                };
                walls.set_fluxes(
                    fractions.cut_cells(),
                    &cavity,
                    self.ports.kinds(),
                    &flows,
                    fluid.solver_mut(),
                    &mut self.report.flux,
                )?;
                // Part of the ports stage's run (its walls).
                self.report
                    .counters
                    .get_mut(Stage::Ports)
                    .extend_last_run_since(t);
            }
        }
        self.report.fluid_cells = self.ports.fluid_cells();
        self.report.grid_fluid_volume_m3 =
            grid_fluid_volume_m3(&self.ports, self.fractions.is_some(), Some(fluid.solver()));

        // 5. Fluid: one solver step on those labels and velocities; the fluxes it carried.
        let drive = FluidDrive {
            fluid_cells: self.ports.fluid_cells(),
            relabelled: ports.relabelled_cells.is_some(),
            boundaries_flow: ports.boundaries_flow,
        };
        let stepped = fluid.step(drive, dt_s, self.report.counters.get_mut(Stage::Fluid))?;
        self.report.fluid_idle = stepped.idle;
        self.report.fluid = stepped.stats;
        if let Some(stats) = stepped.stats {
            self.ports
                .measure_fluxes(fluid.solver(), &mut self.report.flux);
            if let Some(walls) = &self.cut_walls {
                walls.add_to(&mut self.report.flux, &stats);
            }
            self.report.flux.closed_region_mismatch_m3_per_s = stats.closed_region_flux_m3_per_s;
        }

        // 6. Vortices: moved with the flow, as many as the inflow asks for; overlaid or injected.
        let inflow_m3_per_s = self.hydraulics.state().flows.inflow_m3_per_s;
        if let Some(vortices) = self.vortices.as_mut() {
            vortices.step(
                inflow_m3_per_s,
                fluid.solver_mut(),
                dt_s,
                self.report.counters.get_mut(Stage::Vortices),
            );
        }

        // 7. Particles: emitted by the sources, advected by the flow (and the overlay); the
        // clarity of the scope's view.
        if let Some(particles) = self.particles.as_mut() {
            let inputs = ParticleInputs {
                time_s: self.report.time_s,
                solver: fluid.solver(),
                grid: *self.ports.cells(),
                kinds: self.ports.kinds(),
                cavity: self.deformation.cavity(),
                inflow: self.ports.inflow_port(),
                scope: self.ports.scope(),
                overlay: self.vortices.as_ref().and_then(Vortices::overlay_faces),
                inflow_m3_per_s,
            };
            particles.step(
                &inputs,
                dt_s,
                self.report.counters.get_mut(Stage::Particles),
            );
        }

        Ok(self.finish(started))
    }

    /// Closes the frame's counters; the report.
    fn finish(&mut self, started: Instant) -> &StepReport {
        self.report.counters.step.ran_since(started);
        for s in Stage::ALL {
            let c = self.report.counters.get_mut(s);
            if !c.present {
                c.ran_last = false;
            }
        }
        &self.report
    }

    /// The description.
    pub fn desc(&self) -> &SceneDesc {
        &self.desc
    }
    /// The atlas.
    pub fn atlas(&self) -> &Atlas {
        &self.atlas
    }
    /// Lowers (or restores) how much work the stages do: the daemon's overload steps
    /// (docs/daemon.md, "Overload"). The full quality is `SceneQuality::default()`.
    pub fn set_quality(&mut self, quality: SceneQuality) -> Result<(), SceneError> {
        if let Some(fluid) = &mut self.fluid {
            fluid.cap_substeps(quality.max_fluid_substeps)?;
        }
        if let Some(particles) = &mut self.particles {
            particles.set_budget_share(quality.particle_budget_share);
        }
        Ok(())
    }

    /// The last step's report.
    pub fn report(&self) -> &StepReport {
        &self.report
    }
    /// The hydraulic state the last step followed.
    pub fn hydraulic_state(&self) -> &HydraulicState {
        self.hydraulics.state()
    }
    /// The scene's own hydraulic model (stepped under [`HydraulicsInput::Own`]).
    pub fn hydraulic_model(&mut self) -> &mut HydraulicModel {
        self.hydraulics.model_mut()
    }
    /// The voxel box.
    pub fn cells(&self) -> &VoxelBox {
        self.voxelizer.cells()
    }
    /// The voxelizer (cell states of the cavity surface).
    pub fn voxelizer(&self) -> &Voxelizer {
        &self.voxelizer
    }
    /// The cut cells of the cavity surface, with `[fluid] cut_cells` (and a fluid stage).
    pub fn cavity_fractions(&self) -> Option<&CavityFractions> {
        self.fractions.as_ref()
    }
    /// The scope as last placed, if ever.
    pub fn scope(&self) -> Option<&ScopeGeometry> {
        self.ports.scope()
    }
    /// The cavity surface.
    pub fn cavity(&self) -> CavityView<'_> {
        self.deformation.cavity()
    }
    /// The cavity surface (its replay state and topology).
    pub fn cavity_surface(&self) -> &CavitySurface {
        self.deformation.surface()
    }
    /// The flow field, if the scene has a fluid stage.
    pub fn flow(&self) -> Option<FlowField<'_>> {
        self.fluid.as_ref().map(|fluid| FlowField {
            ports: &self.ports,
            solver: fluid.solver(),
            vortices: self.vortices.as_ref(),
            cut: self.fractions.as_ref().map(CavityFractions::cut_cells),
        })
    }
    /// The particles, if the scene has them.
    pub fn particles(&self) -> Option<&Particles> {
        self.particles.as_ref()
    }
    /// The vortices, if the scene has them.
    pub fn vortices(&self) -> Option<&Vortices> {
        self.vortices.as_ref()
    }

    /// Recomposes the kind and label of every cell of the box for the scope pose of the last
    /// composition, visiting every cell, and says what that changed: nothing when the
    /// row-incremental compositions of the steps before were complete. For verification; the
    /// kinds, lists and labels end as a step leaves them.
    pub fn relabel_whole_box(&mut self) -> Result<WholeBoxCheck, SceneError> {
        let cavity = CavityCells {
            voxels: &self.voxelizer,
            surface: self.deformation.surface(),
            fractions: self.fractions.as_ref(),
        };
        let solver = self.fluid.as_mut().map(FluidStage::solver_mut);
        let check = self
            .ports
            .relabel_whole_box(&cavity, solver, &mut self.report.flux)?;
        self.report.relabelled_cells = check.labels_changed;
        self.report.fluid_cells = self.ports.fluid_cells();
        self.report.grid_fluid_volume_m3 = grid_fluid_volume_m3(
            &self.ports,
            self.fractions.is_some(),
            self.fluid.as_ref().map(FluidStage::solver),
        );
        Ok(check)
    }
}

/// The fluid volume the grid carries, m^3: with cut cells the solver's `sum V_i h^3` over its
/// fluid cells, else the whole fluid cells' volume (the same figure, counted by the ports stage).
fn grid_fluid_volume_m3(ports: &Ports, cut: bool, solver: Option<&FluidSolver>) -> f64 {
    match solver {
        Some(solver) if cut => solver.grid().fluid_volume_m3(),
        _ => ports.fluid_volume_m3(),
    }
}

/// The grid box: it covers the cavity `surface` (replayed at the atlas's highest pressure) plus
/// a cell of wall, clipped to the region of interest.
fn grid_box(desc: &SceneDesc, surface: &CavitySurface) -> Result<VoxelBox, SceneError> {
    let h = desc.voxel_m();
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for p in surface.positions_m() {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a] as f64);
            hi[a] = hi[a].max(p[a] as f64);
        }
    }
    if let (Some(rlo), Some(rhi)) = (desc.fluid.roi_min_mm, desc.fluid.roi_max_mm) {
        for a in 0..3 {
            lo[a] = lo[a].max(rlo[a] * 1e-3);
            hi[a] = hi[a].min(rhi[a] * 1e-3);
        }
    }
    if (0..3).any(|a| !(lo[a].is_finite() && hi[a].is_finite() && lo[a] < hi[a])) {
        return Err(SceneError::Description {
            origin: desc.origin.clone(),
            message: format!(
                "`fluid.roi_min_mm`: the region of interest misses the cavity \
                 ({lo:?} .. {hi:?} m)"
            ),
        });
    }
    let dims: [usize; 3] = std::array::from_fn(|a| ((hi[a] - lo[a]) / h).ceil() as usize + 2);
    let cells = VoxelBox {
        dims,
        origin_m: std::array::from_fn(|a| lo[a] - h),
        spacing_m: h,
    };
    if cells.cell_count() > 64_000_000 {
        return Err(SceneError::Description {
            origin: desc.origin.clone(),
            message: format!(
                "`fluid.voxel_mm` = {}: {dims:?} = {} cells is too many",
                desc.fluid.voxel_mm,
                cells.cell_count()
            ),
        });
    }
    Ok(cells)
}

/// The fluid solver on the grid `cells`, every cell solid (the first step labels the cavity).
fn fluid_solver(desc: &SceneDesc, cells: &VoxelBox) -> Result<FluidSolver, SceneError> {
    let mut grid = FluidGrid::new(cells.dims, cells.spacing_m, cells.origin_m, [false; 3])?;
    let far = cells.origin_m.map(|o| o + 1.0);
    grid.fill_box(cells.origin_m, far, CellLabel::Solid, [0.0; 3]);
    let params = FluidParams {
        advection: desc.fluid.advection,
        tolerance: desc.fluid.divergence_tolerance,
        max_cfl: desc.fluid.max_cfl.is_finite().then_some(desc.fluid.max_cfl),
        ..FluidParams::default()
    };
    Ok(FluidSolver::new(grid, params)?)
}
