//! The scene: hydraulics, deformation, voxelization, ports and fluid coupled in one real-time
//! pipeline behind one [`Scene::step`].
//!
//! ```text
//!  RigInputs ──► hydraulics ──► deformation ──► voxelize ──► ports ──► fluid ──► vortices ──► particles
//!  (valves,      (pressure,     (atlas replay    (cavity      (labels,   (MAC      (overlay or  (blood,
//!   pump,         flows,         of the cavity    surface ->   port and   grid      injected)    bubbles,
//!   scope)        volume, dV/dt) surface, dx/dp)  cell states) wall vel.) step)                  fragments)
//! ```
//! Every stage decides whether it has work (the pressure moved, a vertex or the scope moved more
//! than a fraction of a voxel, a port flows or the field is not at rest) and reports runs, skips
//! and times in [`StepReport::counters`]. The hydraulics may run inside the scene (the offline
//! runner) or in another loop that hands the scene its newest state (the daemon's 1 kHz loop):
//! [`HydraulicsInput`]. The flux the fluid sees through the ports and moving walls equals the
//! hydraulics' flows over the frame (see [`FluxBalance`]); `docs/scene.md` specifies it all.
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
pub mod desc;
pub mod dispersion;
mod error;
pub mod particles;
mod ports;
pub mod prepare;
mod random;
pub mod surface;
mod types;
mod vortex_potential;
pub mod vortices;
pub mod voxelize;

use std::time::Instant;

pub use counters::{Counters, Stage, StageCounters};
pub use desc::SceneDesc;
pub use error::SceneError;
pub use ports::{ScopeGeometry, ScopePart};
pub use prepare::SceneAssets;
pub use surface::CavitySurface;
pub use types::{
    CavityView, FluxBalance, HydraulicsInput, RigInputs, SceneInputs, ScopePose, StepReport,
    VoxelKind, WholeBoxCheck,
};
pub use voxelize::{VoxelBox, Voxelizer};

use crate::atlas::Atlas;
use crate::fluid::{
    range_hull, step_along, CellLabel, FluidError, FluidGrid, FluidParams, FluidSolver,
};
use crate::hydraulics::{HydraulicModel, HydraulicState};
use ports::{unit, FACE_NORMALS};
use types::BoundaryCell;
use voxelize::{state, NO_TRIANGLE};

/// The flow field on the voxel grid.
pub struct FlowField<'a> {
    scene: &'a Scene,
    solver: &'a FluidSolver,
}

impl FlowField<'_> {
    /// Cells per axis.
    pub fn dims(&self) -> [usize; 3] {
        self.scene.cells.dims
    }
    /// Centre of cell (0, 0, 0), m.
    pub fn first_centre_m(&self) -> [f64; 3] {
        self.scene.cells.centre_m(0, 0, 0)
    }
    /// Cell edge, m.
    pub fn spacing_m(&self) -> f64 {
        self.scene.cells.spacing_m
    }
    /// Kind of every cell, x fastest.
    pub fn kinds(&self) -> &[VoxelKind] {
        &self.scene.kinds
    }
    /// Cell-centred velocities (m/s) into `out` (one per cell, x fastest): the mean of the faces
    /// in fluid and open cells, the prescribed velocity in ports and walls, zero elsewhere;
    /// plus the vortex overlay where it is display-only.
    pub fn velocities_into(&self, out: &mut [[f32; 3]]) {
        let [nx, ny, nz] = self.dims();
        let grid = self.solver.grid();
        let mut n = 0;
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    if n >= out.len() {
                        return;
                    }
                    out[n] = match self.scene.kinds[n] {
                        VoxelKind::Fluid | VoxelKind::Open => {
                            self.solver.centred_velocity_m_s([i, j, k])
                        }
                        // The jet out of the channel (the rim cell imposes its share of it).
                        VoxelKind::Inflow => self.scene.inflow_jet_m_per_s,
                        VoxelKind::Outflow | VoxelKind::Wall => grid.velocity_at(n),
                        _ => [0.0; 3],
                    };
                    n += 1;
                }
            }
        }
        if let Some(v) = &self.scene.vortices {
            v.overlay_into(self.scene, out);
        }
    }
    /// The fluid solver (face velocities, pressure, sampling).
    pub fn solver(&self) -> &FluidSolver {
        self.solver
    }
}

/// Hydraulic figures at the end of the previous frame.
#[derive(Debug, Clone, Copy)]
struct HydraulicMark {
    time_s: f64,
    pressure_pa: f64,
    volume_m3: f64,
    inflow_m3: f64,
    outflow_m3: f64,
    lost_m3: f64,
}

fn mark(h: &HydraulicState) -> HydraulicMark {
    let t = &h.totals;
    HydraulicMark {
        time_s: h.time_s,
        pressure_pa: h.cavity_pressure_pa,
        volume_m3: h.cavity_volume_m3,
        inflow_m3: t.inflow_m3,
        outflow_m3: t.outflow_m3,
        lost_m3: t.leak_m3 + t.absorbed_m3 + t.perforation_m3,
    }
}

/// Replaces the entries of `list` (by cell index) in the rows `rows` (sorted) with `fresh` (the
/// rows' new entries, by cell index), through the scratch `next`: the rows' runs are found by
/// bisection and the rest is copied in runs.
fn splice_rows(
    list: &mut Vec<BoundaryCell>,
    next: &mut Vec<BoundaryCell>,
    fresh: &[BoundaryCell],
    rows: &[u32],
    nx: usize,
) {
    next.clear();
    let (mut from, mut f) = (0, 0);
    for &row in rows {
        let (start, end) = (row as usize * nx, (row as usize + 1) * nx);
        let a = from + list[from..].partition_point(|b| (b.cell as usize) < start);
        let b = a + list[a..].partition_point(|b| (b.cell as usize) < end);
        let g = f + fresh[f..].partition_point(|b| (b.cell as usize) < end);
        next.extend_from_slice(&list[from..a]);
        next.extend_from_slice(&fresh[f..g]);
        (from, f) = (b, g);
    }
    next.extend_from_slice(&list[from..]);
    std::mem::swap(list, next);
}

/// Adds `row` to `rows` unless `marks` says it is there already.
fn mark_row(row: usize, marks: &mut [bool], rows: &mut Vec<u32>) {
    if !marks[row] {
        marks[row] = true;
        rows.push(row as u32);
    }
}

/// The coupled pipeline.
pub struct Scene {
    desc: SceneDesc,
    atlas: Atlas,
    /// The atlas of the cavity surface's vertices alone (what a step replays).
    surface_atlas: Atlas,
    surface: CavitySurface,
    voxelizer: Voxelizer,
    cells: VoxelBox,
    kinds: Vec<VoxelKind>,
    labels: Vec<CellLabel>,
    fluid: Option<FluidSolver>,
    hydraulics: HydraulicModel,
    hydraulic_state: HydraulicState,
    last: Option<HydraulicMark>,
    scope: Option<ScopeGeometry>,
    scope_built: Option<ScopeGeometry>,
    inflow: Vec<BoundaryCell>,
    /// Share of the last inflow cell's fluid-facing area that the channel covers, (0, 1]: the
    /// port's area on the grid is the channel's, not a whole number of faces.
    inflow_rim_fraction: f64,
    /// The jet velocity of the inflow cells (published; the rim cell imposes its share of it).
    inflow_jet_m_per_s: [f32; 3],
    outflow: Vec<BoundaryCell>,
    walls: Vec<BoundaryCell>,
    open: Vec<BoundaryCell>,
    candidates: Vec<(f64, BoundaryCell, f64)>,
    wall_velocity: Vec<[f32; 3]>,
    labels_dirty: bool,
    /// Per row `j + ny k`, the x range `[first, end)` of cells that are not solid after the last
    /// [`Scene::compose_labels`].
    kind_extent: Vec<[u32; 2]>,
    /// Rows to recompose at the next composition (the voxelizer changed them; a composition adds
    /// those whose scope cells changed), marked per row.
    pending_rows: Vec<u32>,
    row_pending: Vec<bool>,
    /// The built scope's cells (the sheath's rasterization) and the part each lies in, by cell
    /// index; scratch for the next pose's.
    scope_cells: Vec<(u32, ScopePart)>,
    scope_cells_next: Vec<(u32, ScopePart)>,
    /// Fluid cells per row, and in all.
    row_fluid: Vec<u32>,
    fluid_cells: usize,
    /// The tip layer's cells with a face on fluid (the inflow port's candidates), by cell index
    /// like the other boundary lists.
    tips: Vec<BoundaryCell>,
    /// Scratch for listing rows anew: the rows and their marks, their new walls, open cells,
    /// hole-band cells and tip cells, a spliced list.
    relisted_rows: Vec<u32>,
    row_relisted: Vec<bool>,
    fresh: [Vec<BoundaryCell>; 4],
    spliced: Vec<BoundaryCell>,
    /// The hydraulic pressure the surface was last replayed for, Pa.
    deformed_at_pa: f64,
    topology_revision: u64,
    report: StepReport,
    /// Rankine vortices (issue: vortices and particles), present when the scene asks.
    pub(crate) vortices: Option<vortices::Vortices>,
    /// Particles, present when the scene asks.
    pub(crate) particles: Option<particles::Particles>,
}

impl Scene {
    /// Builds the scene's stages: the grid box covers the cavity at the atlas's highest pressure
    /// (plus a cell of wall), clipped to the region of interest.
    pub fn new(desc: SceneDesc, assets: SceneAssets) -> Result<Self, SceneError> {
        desc.validate()?;
        let SceneAssets { mesh, atlas } = assets;
        let mut surface = CavitySurface::new(&mesh)?;
        let top = atlas.pressure_pa[atlas.level_count() - 1];
        let surface_atlas = surface.compact_atlas(&atlas)?;
        surface.replay_compact(&surface_atlas, top)?;
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
        let voxelizer = Voxelizer::new(cells, surface.triangles().to_vec(), surface.vertex_count());
        let fluid = if desc.stages.fluid {
            // All solid at first: the first step labels the cavity.
            let mut grid = FluidGrid::new(dims, h, cells.origin_m, [false; 3])?;
            let far = cells.origin_m.map(|o| o + 1.0);
            grid.fill_box(cells.origin_m, far, CellLabel::Solid, [0.0; 3]);
            let params = FluidParams {
                advection: desc.fluid.advection,
                tolerance: desc.fluid.divergence_tolerance,
                max_cfl: desc.fluid.max_cfl.is_finite().then_some(desc.fluid.max_cfl),
                ..FluidParams::default()
            };
            Some(FluidSolver::new(grid, params)?)
        } else {
            None
        };
        let compliance = prepare::compliance_of(&atlas).map_err(|e| {
            SceneError::Prepare(format!("{}: the atlas's P-V curve: {e}", desc.origin))
        })?;
        let hydraulics =
            HydraulicModel::with_compliance(desc.hydraulics.clone(), Box::new(compliance))?;
        let hydraulic_state = *hydraulics.state();
        let n = cells.cell_count();
        let rows = cells.dims[1] * cells.dims[2];
        let mut counters = Counters::default();
        for s in [Stage::Deformation, Stage::Voxelize] {
            counters.get_mut(s).present = true;
        }
        counters.get_mut(Stage::Ports).present = fluid.is_some();
        counters.get_mut(Stage::Fluid).present = fluid.is_some();
        counters.get_mut(Stage::Vortices).present = desc.stages.vortices;
        counters.get_mut(Stage::Particles).present = desc.stages.particles;
        let vortices = desc
            .stages
            .vortices
            .then(|| vortices::Vortices::new(desc.vortices.clone()));
        let particles = desc
            .stages
            .particles
            .then(|| particles::Particles::new(desc.particles.clone()));
        Ok(Self {
            surface,
            voxelizer,
            cells,
            kinds: vec![VoxelKind::Solid; n],
            labels: vec![CellLabel::Solid; n],
            fluid,
            hydraulics,
            hydraulic_state,
            last: None,
            scope: None,
            scope_built: None,
            // Boundary lists hold at most every cell: reserved once, never grown per frame.
            inflow: Vec::with_capacity(n),
            inflow_rim_fraction: 1.0,
            inflow_jet_m_per_s: [0.0; 3],
            outflow: Vec::with_capacity(n),
            walls: Vec::with_capacity(n),
            open: Vec::with_capacity(n),
            candidates: Vec::with_capacity(n),
            wall_velocity: vec![[0.0; 3]; n],
            labels_dirty: true,
            kind_extent: vec![[0, 0]; rows],
            // Every row composes the first time.
            pending_rows: (0..rows as u32).collect(),
            row_pending: vec![true; rows],
            scope_cells: Vec::with_capacity(n),
            scope_cells_next: Vec::with_capacity(n),
            row_fluid: vec![0; rows],
            fluid_cells: 0,
            tips: Vec::with_capacity(n),
            relisted_rows: Vec::with_capacity(rows),
            row_relisted: vec![false; rows],
            fresh: std::array::from_fn(|_| Vec::with_capacity(n)),
            spliced: Vec::with_capacity(n),
            deformed_at_pa: f64::NAN,
            topology_revision: 1,
            report: StepReport {
                counters,
                ..StepReport::default()
            },
            vortices,
            particles,
            desc,
            atlas,
            surface_atlas,
        })
    }

    /// The description.
    pub fn desc(&self) -> &SceneDesc {
        &self.desc
    }
    /// The atlas.
    pub fn atlas(&self) -> &Atlas {
        &self.atlas
    }
    /// The last step's report.
    pub fn report(&self) -> &StepReport {
        &self.report
    }
    /// The hydraulic state the last step followed.
    pub fn hydraulic_state(&self) -> &HydraulicState {
        &self.hydraulic_state
    }
    /// The scene's own hydraulic model (stepped under [`HydraulicsInput::Own`]).
    pub fn hydraulic_model(&mut self) -> &mut HydraulicModel {
        &mut self.hydraulics
    }
    /// The voxel box.
    pub fn cells(&self) -> &VoxelBox {
        &self.cells
    }
    /// The voxelizer (cell states of the cavity surface).
    pub fn voxelizer(&self) -> &Voxelizer {
        &self.voxelizer
    }
    /// The scope as last placed, if ever.
    pub fn scope(&self) -> Option<&ScopeGeometry> {
        self.scope.as_ref()
    }
    /// The cavity surface.
    pub fn cavity(&self) -> CavityView<'_> {
        CavityView {
            triangles: self.surface.triangles(),
            positions_m: self.surface.positions_m(),
            topology_revision: self.topology_revision,
            cap_triangles: self.surface.cap_triangles(),
            pressure_pa: self.surface.pressure_pa(),
        }
    }
    /// The cavity surface (its replay state and topology).
    pub fn cavity_surface(&self) -> &CavitySurface {
        &self.surface
    }
    /// The flow field, if the scene has a fluid stage.
    pub fn flow(&self) -> Option<FlowField<'_>> {
        self.fluid.as_ref().map(|solver| FlowField {
            scene: self,
            solver,
        })
    }
    /// The particles, if the scene has them.
    pub fn particles(&self) -> Option<&particles::Particles> {
        self.particles.as_ref()
    }
    /// The vortices, if the scene has them.
    pub fn vortices(&self) -> Option<&vortices::Vortices> {
        self.vortices.as_ref()
    }

    /// Advances the scene by `dt_s` seconds.
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

        // 1. Hydraulics.
        let t = Instant::now();
        match inputs.hydraulics {
            HydraulicsInput::Own => {
                let hin = &inputs.rig.hydraulic;
                // The daemon's 1 kHz tick: the same substeps offline.
                let n = (dt_s / 1e-3).ceil().max(1.0) as usize;
                for _ in 0..n {
                    self.hydraulics.step(hin, dt_s / n as f64);
                }
                self.hydraulic_state = *self.hydraulics.state();
                let c = self.report.counters.get_mut(Stage::Hydraulics);
                c.present = true;
                c.ran(ms(t));
            }
            HydraulicsInput::External(state) => {
                self.hydraulic_state = *state;
                self.report.counters.get_mut(Stage::Hydraulics).skipped();
            }
        }
        let now = mark(&self.hydraulic_state);
        let (flux_targets, dpdt) = self.frame_flows(now, dt_s);
        self.last = Some(now);
        self.report.cavity_volume_m3 = now.volume_m3;

        // 2. Deformation.
        let t = Instant::now();
        let p = self.hydraulic_state.cavity_pressure_pa;
        let p = if p.is_finite() { p } else { 0.0 };
        let moved = (p - self.deformed_at_pa).abs() > self.desc.skip.pressure_tolerance_pa
            || self.deformed_at_pa.is_nan();
        if moved {
            self.surface.replay_compact(&self.surface_atlas, p)?;
            self.deformed_at_pa = p;
            self.report.surface_volume_m3 = self.surface.enclosed_volume_m3();
            if p < self.atlas.pressure_pa[0] {
                self.match_volume_below_the_atlas(p)?;
            }
            self.report.counters.get_mut(Stage::Deformation).ran(ms(t));
        } else {
            self.report.counters.get_mut(Stage::Deformation).skipped();
        }
        self.report.cavity_pressure_pa = self.surface.pressure_pa();

        // 3. Voxelization.
        let t = Instant::now();
        let threshold = self.desc.skip.voxel_move_fraction * self.cells.spacing_m;
        // The surface moves only when it is deformed: otherwise no vertex can have moved since
        // the last update, and the scan over every vertex is skipped (the scene at rest).
        let stats = if moved {
            self.voxelizer.update(self.surface.positions_m(), threshold)
        } else {
            voxelize::VoxelizeStats::default()
        };
        if stats.moved_vertices > 0 {
            if stats.changed_cells > 0 {
                self.labels_dirty = true;
                for m in 0..self.voxelizer.changed_rows().len() {
                    self.mark_pending(self.voxelizer.changed_rows()[m] as usize);
                }
            }
            self.report.counters.get_mut(Stage::Voxelize).ran(ms(t));
        } else {
            self.report.counters.get_mut(Stage::Voxelize).skipped();
        }

        // The scope.
        if inputs.rig.scope.valid {
            let s = &inputs.rig.scope;
            if let Some(dir) = unit(s.view_direction) {
                if s.tip_position_m.iter().all(|v| v.is_finite()) {
                    self.scope = Some(ScopeGeometry {
                        tip_m: s.tip_position_m,
                        dir,
                        radius_m: 0.5e-3 * self.desc.scope.sheath_outer_diameter_mm,
                        holes_m: self.desc.scope.outflow_holes_from_tip_mm.map(|v| v * 1e-3),
                    });
                }
            }
        }
        if self.scope_moved() {
            self.labels_dirty = true;
        }

        if self.fluid.is_none() {
            self.finish(started);
            return Ok(&self.report);
        }

        // 4. Ports: labels (when the cavity or the scope moved) and boundary velocities.
        let t = Instant::now();
        let relabel = self.labels_dirty;
        if relabel {
            self.compose_labels(false)?;
            self.labels_dirty = false;
        }
        // Boundaries move fluid when some flow exceeds one face's worth at the rest speed.
        let floor = self.desc.skip.rest_speed_m_s * self.cells.spacing_m * self.cells.spacing_m;
        let flows_on = [flux_targets.0, flux_targets.1, flux_targets.3]
            .iter()
            .any(|q| q.abs() > floor);
        if relabel || flows_on || self.report.flux.wall_flux_scale != 0.0 {
            self.set_boundary_velocities(flux_targets, dpdt);
            self.report.counters.get_mut(Stage::Ports).ran(ms(t));
        } else {
            self.report.counters.get_mut(Stage::Ports).skipped();
        }

        // 5. Fluid.
        let t = Instant::now();
        let min_cells = self.desc.fluid.min_fluid_cells;
        let rest = self.desc.skip.rest_speed_m_s;
        let solver = self
            .fluid
            .as_mut()
            .ok_or_else(|| SceneError::Prepare("no fluid".into()))?;
        let fluid_cells = self.report.fluid_cells;
        self.report.fluid_idle = fluid_cells < min_cells;
        let at_rest = !flows_on && !relabel && solver.max_speed_m_s() < rest;
        if self.report.fluid_idle || at_rest || dt_s == 0.0 {
            self.report.fluid = None;
            self.report.counters.get_mut(Stage::Fluid).skipped();
        } else {
            let stats = solver.step(dt_s)?;
            self.report.fluid = Some(stats);
            self.report.counters.get_mut(Stage::Fluid).ran(ms(t));
            self.measure_fluxes(flux_targets);
            self.report.flux.closed_region_mismatch_m3_per_s = stats.closed_region_flux_m3_per_s;
        }

        // 6. Vortices and particles (after the fluid).
        let t = Instant::now();
        let ran = match self.vortices.take() {
            Some(mut v) => {
                let ran = v.step(self, dt_s);
                self.vortices = Some(v);
                Some(ran)
            }
            None => None,
        };
        match ran {
            Some(true) => self.report.counters.get_mut(Stage::Vortices).ran(ms(t)),
            Some(false) => self.report.counters.get_mut(Stage::Vortices).skipped(),
            None => {}
        }
        let t = Instant::now();
        let ran = match self.particles.take() {
            Some(mut p) => {
                let ran = p.step(&*self, dt_s);
                self.particles = Some(p);
                Some(ran)
            }
            None => None,
        };
        match ran {
            Some(true) => self.report.counters.get_mut(Stage::Particles).ran(ms(t)),
            Some(false) => self.report.counters.get_mut(Stage::Particles).skipped(),
            None => {}
        }

        self.finish(started);
        Ok(&self.report)
    }

    /// Below the atlas's first level (suction) the hydraulics continue the P-V curve's first
    /// segment; the surface's volume is not linear in its extrapolated positions, so the replay
    /// pressure is corrected by a few secant steps until the surface holds the hydraulics' volume
    /// (within 0.01 %), one source of truth for what the renderer sees.
    fn match_volume_below_the_atlas(&mut self, p: f64) -> Result<(), SceneError> {
        let target = self.hydraulic_state.cavity_volume_m3;
        if !(target.is_finite() && target > 0.0) {
            return Ok(());
        }
        let (mut a, mut va) = (p, self.surface.enclosed_volume_m3());
        let (mut b, mut vb) = (self.atlas.pressure_pa[0], self.atlas.cavity_volume_m3[0]);
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
        self.report.surface_volume_m3 = va;
        Ok(())
    }

    fn finish(&mut self, started: Instant) {
        self.report.counters.step.ran(ms(started));
        for s in Stage::ALL {
            let c = self.report.counters.get_mut(s);
            if !c.present {
                c.ran_last = false;
            }
        }
    }

    /// Frame-mean flows `(in, out, losses, dV/dt)` in m^3/s from the cumulative totals, and
    /// `dp/dt` (Pa/s). The first frame, a new procedure or a zero `dt` give the instantaneous
    /// flows.
    fn frame_flows(&self, now: HydraulicMark, dt_s: f64) -> ((f64, f64, f64, f64), f64) {
        let f = &self.hydraulic_state.flows;
        let instantaneous = (
            f.inflow_m3_per_s,
            f.outflow_m3_per_s,
            f.leak_m3_per_s + f.absorption_m3_per_s + f.perforation_m3_per_s,
            f.net_m3_per_s(),
        );
        match self.last {
            Some(prev) if now.time_s > prev.time_s && now.inflow_m3 >= prev.inflow_m3 => {
                let dt = now.time_s - prev.time_s;
                let q_in = (now.inflow_m3 - prev.inflow_m3) / dt;
                let q_out = (now.outflow_m3 - prev.outflow_m3) / dt;
                let lost = (now.lost_m3 - prev.lost_m3) / dt;
                let dvdt = (now.volume_m3 - prev.volume_m3) / dt;
                (
                    (q_in, q_out, lost, dvdt),
                    (now.pressure_pa - prev.pressure_pa) / dt,
                )
            }
            Some(prev) if dt_s > 0.0 && now.time_s == prev.time_s => {
                // The external model did not advance: nothing flowed.
                ((0.0, 0.0, 0.0, 0.0), 0.0)
            }
            _ => (instantaneous, 0.0),
        }
    }

    fn scope_moved(&self) -> bool {
        match (self.scope, self.scope_built) {
            (None, _) => false,
            (Some(_), None) => true,
            (Some(a), Some(b)) => {
                let h = self.cells.spacing_m;
                let f = self.desc.skip.scope_move_fraction.max(1e-6);
                let dx = (0..3)
                    .map(|i| (a.tip_m[i] - b.tip_m[i]).powi(2))
                    .sum::<f64>()
                    .sqrt();
                let cos = (0..3).map(|i| a.dir[i] * b.dir[i]).sum::<f64>();
                // The far end of the 200 mm sheath moves by L sin(angle): only the part in the
                // grid matters, so the angle is compared over the grid's diagonal.
                let diag = (0..3)
                    .map(|i| (self.cells.dims[i] as f64 * h).powi(2))
                    .sum::<f64>()
                    .sqrt();
                let sin = (1.0 - cos.min(1.0) * cos.min(1.0)).max(0.0).sqrt();
                dx > f * h || sin * diag > f * h
            }
        }
    }

    /// Marks row `row` for recomposition by the next [`Scene::compose_labels`].
    fn mark_pending(&mut self, row: usize) {
        mark_row(row, &mut self.row_pending, &mut self.pending_rows);
    }

    /// Marks row `row` for listing its boundary cells anew in this composition.
    fn mark_relisted(&mut self, row: usize) {
        mark_row(row, &mut self.row_relisted, &mut self.relisted_rows);
    }

    /// Rasterizes the scope at its pose now (the cells whose centres lie in the sheath, and
    /// their parts) and compares it with the built one row by row: a row whose scope cells
    /// differ is recomposed; one whose cells are the same but lie in other parts (tip layer, hole
    /// band) keeps its kinds and has its boundary cells listed anew; any other keeps both.
    fn rasterize_scope(&mut self) {
        let cells = self.cells;
        let [nx, ny, nz] = cells.dims;
        let h = cells.spacing_m;
        let x0 = cells.origin_m[0];
        self.scope_cells_next.clear();
        if let Some(sc) = self.scope {
            let y0 = cells.origin_m[1];
            for k in 0..nz {
                let z = cells.centre_m(0, 0, k)[2];
                let Some((j0, j1)) = sc.slab_rows(z, y0, h, ny) else {
                    continue;
                };
                for j in j0..=j1 {
                    let c = cells.centre_m(0, j, k);
                    if let Some((a, b)) = sc.row_span(c[1], c[2], x0, h, nx) {
                        let base = cells.index(0, j, k);
                        for i in a..=b {
                            let part = sc.part(cells.centre_m(i, j, k), h);
                            if part != ScopePart::None {
                                self.scope_cells_next.push(((base + i) as u32, part));
                            }
                        }
                    }
                }
            }
        }
        let (mut a, mut b) = (0, 0);
        let row_of = |c: &(u32, ScopePart)| c.0 as usize / nx;
        while a < self.scope_cells.len() || b < self.scope_cells_next.len() {
            let row = match (self.scope_cells.get(a), self.scope_cells_next.get(b)) {
                (Some(x), Some(y)) => row_of(x).min(row_of(y)),
                (Some(x), None) => row_of(x),
                (None, Some(y)) => row_of(y),
                (None, None) => break,
            };
            let run = |list: &[(u32, ScopePart)], from: usize| {
                from + list[from..].iter().take_while(|c| row_of(c) == row).count()
            };
            let (ea, eb) = (run(&self.scope_cells, a), run(&self.scope_cells_next, b));
            let (was, now) = (&self.scope_cells[a..ea], &self.scope_cells_next[b..eb]);
            if was.len() != now.len() || was.iter().zip(now).any(|(x, y)| x.0 != y.0) {
                self.mark_pending(row);
            } else if was != now {
                self.mark_relisted(row);
            }
            (a, b) = (ea, eb);
        }
        std::mem::swap(&mut self.scope_cells, &mut self.scope_cells_next);
    }

    /// Kinds and labels from the voxelizer and the scope, and the boundary cell lists.
    /// Incremental in rows: only the pending rows (those the voxelizer changed since the last
    /// composition, and, when the scope moved, those whose scope cells changed) are
    /// recomposed, each over the x range that is or was off solid, and only their cells' labels
    /// go to the solver; only their rows and the four rows beside each (a cell's fluid faces look
    /// one row across) are listed anew for the boundary cells. Every other row composes as before,
    /// so the kinds, lists and labels equal those of a pass over every cell of the box (`whole`,
    /// which [`Scene::relabel_whole_box`] checks them against).
    fn compose_labels(&mut self, whole: bool) -> Result<(), SceneError> {
        let cells = self.cells;
        let [nx, ny, nz] = cells.dims;
        let h = cells.spacing_m;
        let all = [0, nx as u32];
        // 1. The rows to recompose.
        if whole {
            for row in 0..ny * nz {
                self.mark_pending(row);
            }
        }
        if whole || self.scope != self.scope_built {
            self.rasterize_scope();
        }
        self.scope_built = self.scope;
        // The ports' cells are sheath again until the ports are chosen anew below, and move no
        // fluid (the ports chosen below get their velocities in `set_boundary_velocities`; a cell
        // that stays sheath would otherwise keep injecting its old port velocity).
        for b in self.inflow.iter().chain(&self.outflow) {
            self.kinds[b.cell as usize] = VoxelKind::Scope;
            if let Some(solver) = self.fluid.as_mut() {
                let at = b.at.map(|x| x as usize);
                still(
                    &mut self.wall_velocity,
                    solver.grid_mut(),
                    b.cell as usize,
                    at,
                )?;
            }
        }

        // 2. Kinds and labels of the pending rows; their boundary rows.
        let states = self.voxelizer.states();
        let owners = self.voxelizer.owners();
        let extents = self.voxelizer.row_extents();
        let caps = self.surface.cap_triangles() as u32;
        let mut changed = 0;
        // In row order, as a pass over the box visits them (the solver sees the same sequence).
        self.pending_rows.sort_unstable();
        for m in 0..self.pending_rows.len() {
            let row = self.pending_rows[m] as usize;
            self.row_pending[row] = false;
            let (j, k) = (row % ny, row / ny);
            let base = cells.index(0, j, k);
            let last = self.kind_extent[row];
            let vox = extents[row];
            // Cavity first.
            let mut fluid = 0u32;
            let [a, b] = if whole { all } else { range_hull(last, vox) };
            for n in base + a as usize..base + b as usize {
                let kind = match states[n] {
                    state::INSIDE => VoxelKind::Fluid,
                    state::BAND if owners[n] < caps => VoxelKind::Open,
                    state::BAND => VoxelKind::Wall,
                    _ => VoxelKind::Solid,
                };
                fluid += u32::from(kind == VoxelKind::Fluid);
                self.kinds[n] = kind;
            }
            // The scope on top.
            let mut now = vox;
            let first = self.scope_cells.partition_point(|c| (c.0 as usize) < base);
            for &(n, _) in &self.scope_cells[first..] {
                let n = n as usize;
                if n >= base + nx {
                    break;
                }
                fluid -= u32::from(self.kinds[n] == VoxelKind::Fluid);
                self.kinds[n] = VoxelKind::Scope;
                let i = (n - base) as u32;
                now = range_hull(now, [i, i + 1]);
            }
            self.kind_extent[row] = now;
            self.fluid_cells = self.fluid_cells + fluid as usize - self.row_fluid[row] as usize;
            self.row_fluid[row] = fluid;
            // Labels into the solver, and cells that stopped being walls move no more.
            if let Some(solver) = self.fluid.as_mut() {
                let g = solver.grid_mut();
                let [a, b] = if whole { all } else { range_hull(last, now) };
                for i in a as usize..b as usize {
                    let n = base + i;
                    let label = match self.kinds[n] {
                        VoxelKind::Fluid => CellLabel::Fluid,
                        VoxelKind::Open => CellLabel::Outflow,
                        VoxelKind::Solid => CellLabel::Solid,
                        _ => CellLabel::Velocity,
                    };
                    if self.labels[n] != label {
                        self.labels[n] = label;
                        g.set_label([i, j, k], label)?;
                        changed += 1;
                    }
                    // Only walls keep a velocity here (`set_boundary_velocities` sets it anew
                    // each step); a sheath cell over an old wall cell moves no fluid.
                    if self.kinds[n] != VoxelKind::Wall {
                        still(&mut self.wall_velocity, g, n, [i, j, k])?;
                    }
                }
            }
            let beside = [
                step_along(row, j, ny, 1, false),
                step_along(row, k, nz, ny, false),
            ];
            for r in std::iter::once(row).chain(beside.into_iter().flatten().flatten()) {
                mark_row(r, &mut self.row_relisted, &mut self.relisted_rows);
            }
        }
        self.pending_rows.clear();
        self.report.relabelled_cells = changed;

        // 3. The boundary cells of those rows (walls beside fluid, port candidates at the tip and
        // in the hole band), by cell index, into the kept list in place of the rows' old ones.
        self.relisted_rows.sort_unstable();
        for f in &mut self.fresh {
            f.clear();
        }
        for m in 0..self.relisted_rows.len() {
            let row = self.relisted_rows[m] as usize;
            let (j, k) = (row % ny, row / ny);
            let [a, b] = if whole { all } else { self.kind_extent[row] };
            for i in a as usize..b as usize {
                let n = cells.index(i, j, k);
                // Into walls, open, hole band, tip layer.
                let list = match self.kinds[n] {
                    VoxelKind::Wall => 0,
                    VoxelKind::Open => 1,
                    VoxelKind::Scope => {
                        match self.scope.map(|sc| sc.part(cells.centre_m(i, j, k), h)) {
                            Some(ScopePart::Holes) => 2,
                            Some(ScopePart::Tip) => 3,
                            _ => continue,
                        }
                    }
                    _ => continue,
                };
                let faces = self.fluid_faces(i, j, k);
                if faces != 0 {
                    self.fresh[list].push(BoundaryCell {
                        cell: n as u32,
                        at: [i, j, k].map(|x| x as u32),
                        faces,
                    });
                }
            }
        }
        let kept = [
            &mut self.walls,
            &mut self.open,
            &mut self.outflow,
            &mut self.tips,
        ];
        for (list, fresh) in kept.into_iter().zip(&self.fresh) {
            splice_rows(list, &mut self.spliced, fresh, &self.relisted_rows, nx);
        }
        for &row in &self.relisted_rows {
            self.row_relisted[row as usize] = false;
        }
        self.relisted_rows.clear();

        // 4. The inflow port's candidates.
        self.inflow.clear();
        self.candidates.clear();
        if let Some(sc) = self.scope {
            for &b in &self.tips {
                let g = face_weight(b.faces, sc.dir);
                let (_, r) = sc.axial_radial(cells.centre_m_of(b.cell));
                self.candidates.push((r, b, g));
            }
        }
        // The inflow port: the tip cells whose fluid faces look forward, nearest the axis first,
        // until their fluid-facing area reaches the channel's; the last one (the rim) counts
        // with the share of its area that completes the channel's, so the port's area on the
        // grid is the channel's at any voxel size and the jet leaves at the hydraulics' port
        // velocity. Fewer forward faces than the channel's area: tissue covers part of the tip.
        // Unstable (no scratch buffer on the heap), with the cells' order (that of `tips`) among
        // equal distances: the order of a stable sort.
        self.candidates
            .sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cell.cmp(&b.1.cell)));
        let area = self.desc.scope.inflow_channel_area_mm2 * 1e-6;
        let face = h * h;
        let mut g = 0.0;
        self.inflow_rim_fraction = 1.0;
        for c in &self.candidates {
            let gc = c.2 * face;
            if gc <= 0.0 {
                continue; // its fluid faces look sideways or back: no jet along the view
            }
            self.inflow.push(c.1);
            if g + gc >= area {
                self.inflow_rim_fraction = (area - g) / gc;
                g = area;
                break;
            }
            g += gc;
        }
        self.report.flux.inflow_open_fraction = if area > 0.0 { g / area } else { 0.0 };
        for b in &self.inflow {
            self.kinds[b.cell as usize] = VoxelKind::Inflow;
        }
        for b in &self.outflow {
            self.kinds[b.cell as usize] = VoxelKind::Outflow;
        }
        self.report.fluid_cells = self.fluid_cells;
        self.report.grid_fluid_volume_m3 = self.fluid_cells as f64 * h * h * h;
        Ok(())
    }

    /// Recomposes the kind and label of every cell of the box for the scope pose of the last
    /// composition, visiting every cell, and says what that changed: nothing when the
    /// row-incremental compositions of the steps before were complete. For verification; the
    /// kinds, lists and labels end as a step leaves them.
    pub fn relabel_whole_box(&mut self) -> Result<WholeBoxCheck, SceneError> {
        let kinds = self.kinds.clone();
        let lists = [&self.inflow, &self.outflow, &self.walls, &self.open].map(|l| l.clone());
        let (fluid_cells, rim) = (self.fluid_cells, self.inflow_rim_fraction);
        // A pose that moved less than the threshold since is not composed yet (by design).
        let scope = std::mem::replace(&mut self.scope, self.scope_built);
        let composed = self.compose_labels(true);
        self.scope = scope;
        composed?;
        let now = [&self.inflow, &self.outflow, &self.walls, &self.open];
        Ok(WholeBoxCheck {
            labels_changed: self.report.relabelled_cells,
            kinds_changed: kinds
                .iter()
                .zip(&self.kinds)
                .filter(|(a, b)| a != b)
                .count(),
            lists_changed: lists.iter().zip(now).any(|(a, b)| a != b)
                || rim != self.inflow_rim_fraction,
            fluid_cells_changed: fluid_cells != self.fluid_cells,
        })
    }

    /// Bits of the faces of cell `(i, j, k)` that border fluid.
    fn fluid_faces(&self, i: usize, j: usize, k: usize) -> u8 {
        let c = &self.cells;
        let [nx, ny, _] = c.dims;
        let (at, n) = ([i, j, k], c.index(i, j, k));
        let stride = [1, nx, nx * ny];
        let mut bits = 0u8;
        for a in 0..3 {
            let beside = step_along(n, at[a], c.dims[a], stride[a], false);
            for (s, m) in beside.into_iter().enumerate() {
                if m.is_some_and(|m| self.kinds[m] == VoxelKind::Fluid) {
                    bits |= 1 << (2 * a + s);
                }
            }
        }
        bits
    }

    /// Port and wall velocities with exact fluxes: `targets = (in, out, losses, dV/dt)`.
    fn set_boundary_velocities(&mut self, targets: (f64, f64, f64, f64), dpdt: f64) {
        let (q_in, q_out, _losses, dvdt) = targets;
        let cells = self.cells;
        let h2 = cells.spacing_m * cells.spacing_m;
        let coords = |b: &BoundaryCell| b.at.map(|x| x as usize);
        let Some(solver) = self.fluid.as_mut() else {
            return;
        };
        let flux = &mut self.report.flux;
        // Inflow: u d, u = Q_in / G_in.
        flux.inflow_blocked = false;
        flux.outflow_blocked = false;
        if let Some(sc) = self.scope_built {
            // The port's open area: whole cells and the rim's share (the channel's area when
            // the tip is clear of tissue).
            let last = self.inflow.len().saturating_sub(1);
            let share = |m: usize| {
                if m == last {
                    self.inflow_rim_fraction
                } else {
                    1.0
                }
            };
            let g_in: f64 = self
                .inflow
                .iter()
                .enumerate()
                .map(|(m, b)| share(m) * face_weight(b.faces, sc.dir))
                .sum::<f64>()
                * h2;
            let u = if g_in > 0.0 { q_in / g_in } else { 0.0 };
            flux.inflow_blocked = g_in <= 0.0 && q_in > 0.0;
            flux.inflow_jet_speed_m_per_s = u;
            self.inflow_jet_m_per_s = sc.dir.map(|d| (u * d) as f32);
            for (m, b) in self.inflow.iter().enumerate() {
                let v = sc.dir.map(|d| (share(m) * u * d) as f32);
                self.wall_velocity[b.cell as usize] = v;
                let _ = solver.grid_mut().set_velocity(coords(b), v);
            }
            // Outflow holes: -u r_hat, u = Q_out / G_out.
            let mut g_out = 0.0;
            for b in &self.outflow {
                let r = radial(&sc, cells.centre_m_of(b.cell));
                g_out += face_weight(b.faces, r) * h2;
            }
            let u = if g_out > 0.0 { q_out / g_out } else { 0.0 };
            flux.outflow_blocked = g_out <= 0.0 && q_out > 0.0;
            for b in &self.outflow {
                let r = radial(&sc, cells.centre_m_of(b.cell));
                let v = r.map(|c| (-u * c) as f32);
                self.wall_velocity[b.cell as usize] = v;
                let _ = solver.grid_mut().set_velocity(coords(b), v);
            }
        } else {
            flux.inflow_blocked = q_in > 0.0;
            flux.outflow_blocked = q_out > 0.0;
            flux.inflow_jet_speed_m_per_s = 0.0;
            self.inflow_jet_m_per_s = [0.0; 3];
        }
        // Walls: dx/dp dp/dt at the owning triangle, scaled so that the flux into the walls is
        // dV/dt exactly.
        let owners = self.voxelizer.owners();
        let tris = self.surface.triangles();
        let dxdp = self.surface.dxdp_m_per_pa();
        let mut raw_out = 0.0; // flux out of the fluid into the walls, raw
        for b in &self.walls {
            let t = owners[b.cell as usize];
            let v = if t == NO_TRIANGLE {
                [0.0; 3]
            } else {
                let [a, bb, c] = tris[t as usize].map(|i| dxdp[i as usize]);
                std::array::from_fn(|x| (a[x] + bb[x] + c[x]) as f64 / 3.0 * dpdt)
            };
            // Out of the fluid = -(v . n_into_fluid).
            raw_out -= face_weight(b.faces, v) * h2;
            self.wall_velocity[b.cell as usize] = v.map(|x| x as f32);
        }
        let scale = if dvdt == 0.0 {
            0.0
        } else if raw_out * dvdt > 0.0 && (raw_out / dvdt).abs() > 1e-3 {
            dvdt / raw_out
        } else {
            // The atlas's wall motion does not carry dV/dt's sign here (a staircase artefact or
            // an external pressure jump): a uniform normal motion instead.
            let mut area = 0.0;
            for b in &self.walls {
                let n = face_normal_sum(b.faces);
                self.wall_velocity[b.cell as usize] = n.map(|x| -x as f32);
                area += face_weight(b.faces, n) * h2;
            }
            if area > 0.0 {
                dvdt / area
            } else {
                0.0
            }
        };
        flux.wall_flux_scale = scale;
        for b in &self.walls {
            let v = self.wall_velocity[b.cell as usize].map(|x| (x as f64 * scale) as f32);
            self.wall_velocity[b.cell as usize] = v;
            let _ = solver.grid_mut().set_velocity(coords(b), v);
        }
        flux.hydraulic_inflow_m3_per_s = q_in;
        flux.hydraulic_outflow_m3_per_s = q_out;
        flux.hydraulic_losses_m3_per_s = targets.2;
        flux.hydraulic_dvdt_m3_per_s = dvdt;
    }

    /// Measures the fluxes through the boundary cells' fluid faces after a step.
    fn measure_fluxes(&mut self, _targets: (f64, f64, f64, f64)) {
        let Some(solver) = self.fluid.as_ref() else {
            return;
        };
        let cells = self.cells;
        let h2 = cells.spacing_m * cells.spacing_m;
        // Flux out of the fluid into boundary cell b.
        let out_of_fluid = |b: &BoundaryCell| -> f64 {
            let c = b.at.map(|x| x as usize);
            let mut s = 0.0;
            for f in 0..6 {
                if b.faces >> f & 1 == 1 {
                    // Face f of the boundary cell; its normal points into the fluid.
                    let u = solver.cell_face_velocity_m_s(c, f) as f64;
                    let sign = if f % 2 == 1 { 1.0 } else { -1.0 };
                    s -= sign * u * h2;
                }
            }
            s
        };
        let flux = &mut self.report.flux;
        flux.fluid_inflow_m3_per_s = -self.inflow.iter().map(out_of_fluid).sum::<f64>();
        flux.fluid_outflow_m3_per_s = self.outflow.iter().map(out_of_fluid).sum();
        flux.fluid_wall_m3_per_s = self.walls.iter().map(out_of_fluid).sum();
        flux.fluid_open_m3_per_s = self.open.iter().map(out_of_fluid).sum();
    }
}

impl VoxelBox {
    /// Centre of the cell with linear index `n`, m.
    pub fn centre_m_of(&self, n: u32) -> [f64; 3] {
        let n = n as usize;
        let [nx, ny, _] = self.dims;
        self.centre_m(n % nx, (n / nx) % ny, n / (nx * ny))
    }
}

/// Sum over the set faces of `v . n` (n: the face's unit normal from the cell into the fluid).
fn face_weight(faces: u8, v: [f64; 3]) -> f64 {
    let mut s = 0.0;
    for (f, n) in FACE_NORMALS.iter().enumerate() {
        if faces >> f & 1 == 1 {
            s += v[0] * n[0] + v[1] * n[1] + v[2] * n[2];
        }
    }
    s
}

/// Sum of the unit normals of the set faces.
fn face_normal_sum(faces: u8) -> [f64; 3] {
    let mut s = [0.0; 3];
    for (f, n) in FACE_NORMALS.iter().enumerate() {
        if faces >> f & 1 == 1 {
            for a in 0..3 {
                s[a] += n[a];
            }
        }
    }
    s
}

/// Unit vector from the scope's axis to `p` (perpendicular to the axis).
fn radial(sc: &ScopeGeometry, p: [f64; 3]) -> [f64; 3] {
    let q: [f64; 3] = std::array::from_fn(|a| p[a] - sc.tip_m[a]);
    let s = q[0] * sc.dir[0] + q[1] * sc.dir[1] + q[2] * sc.dir[2];
    let r: [f64; 3] = std::array::from_fn(|a| q[a] - s * sc.dir[a]);
    unit(r).unwrap_or([0.0; 3])
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// Cell `n` (at `at`) moves no fluid: its prescribed velocity is zeroed where it had one (a cell
/// that left the ports or the walls; those that are ports or walls get theirs in
/// `set_boundary_velocities` each step).
fn still(
    wall_velocity: &mut [[f32; 3]],
    grid: &mut FluidGrid,
    n: usize,
    at: [usize; 3],
) -> Result<(), FluidError> {
    if wall_velocity[n] != [0.0; 3] {
        wall_velocity[n] = [0.0; 3];
        grid.set_velocity(at, [0.0; 3])?;
    }
    Ok(())
}
