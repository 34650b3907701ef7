//! The ports stage: the cell labels of the cavity and the scope, the scope's ports and the moving
//! walls, and their flux-exact velocities.
//!
//! Each cell's kind comes from the voxelizer's cell states (inside: fluid; in the band of a
//! triangle: the moving wall, or the open os for the cap's triangles) with the scope's sheath on
//! top ([`ScopeGeometry::part`]). The **inflow port** is the tip layer's cells with a face on
//! fluid, nearest the axis first, as many as bring the port's fluid-facing area (faces weighted
//! by `d . n`) to the channel's; the **outflow holes** are the hole band's sheath cells with a
//! face on fluid. Labels are composed row-incrementally, only where the cavity or the scope moved.
//!
//! A port's velocity is set so that its flux equals the hydraulics' flow exactly: the inflow cells
//! move at `u d` with `u = Q_in / G_in`, `G_in = sum over their fluid faces of (d . n) h^2`; the
//! hole cells at `-u r_hat` (into the sheath) with `u = Q_out / G_out`, `G_out = sum (r_hat . n) h^2`.
//! `n` is the unit normal of the face from the port cell into the fluid. The walls move at the
//! atlas's `dx/dp dp/dt`, scaled so that their flux is the hydraulics' `dV/dt`.

use std::time::Instant;

use super::counters::StageCounters;
use super::cut_cells::CavityFractions;
use super::desc::SceneDesc;
use super::error::SceneError;
use super::scope::{unit, ScopeDims, ScopeGeometry, ScopePart, FACE_NORMALS};
use super::surface::CavitySurface;
use super::types::{
    BoundaryCell, FluxBalance, FrameFlows, InflowPort, ScopePose, VoxelKind, WholeBoxCheck,
};
use super::voxelize::{state, VoxelBox, Voxelizer, NO_TRIANGLE};
use crate::fluid::{
    holds_fluid, range_hull, step_along, CellLabel, FluidError, FluidGrid, FluidSolver,
};

/// The least part of the inflow channel's area that must open on fluid on the grid for the tip to
/// inject its jet (`FluxBalance::inflow_open_fraction`); below it the tip counts as in tissue
/// (`inflow_blocked`). The jet leaves at `Q_in / (fraction x channel area)`: with cut cells a
/// tip pressed into the collapsing wall kept slivers of open face, down to 0.0001 of the channel,
/// and injected jets of up to 2,958 m/s (`scene_soak.rs`). A tenth bounds the jet at ten times the
/// channel's own speed. Whole cells meet it only where the tip's forward faces left on fluid
/// weigh (`d . n`) less than a tenth of the channel's area.
pub const MIN_INFLOW_OPEN_FRACTION: f64 = 0.1;

/// The cavity as the ports stage reads it: the voxelizer's cell states and the surface they
/// belong to.
#[derive(Clone, Copy)]
pub struct CavityCells<'a> {
    /// Cell states, owning triangles and row extents of the cavity surface.
    pub voxels: &'a Voxelizer,
    /// The surface (its cap triangles, triangles and `dx/dp`).
    pub surface: &'a CavitySurface,
    /// With cut cells (`[fluid] cut_cells`), each cell's fluid volume fraction of the same
    /// surface (a cell holding fluid is fluid, `fluid::holds_fluid`, cut or whole) and the open
    /// fractions of the ports' faces (a port's face carries its open part's flux).
    pub fractions: Option<&'a CavityFractions>,
}

/// What one step of the ports stage did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PortsStep {
    /// The labels were composed anew (the cavity or the scope moved): solver labels changed.
    pub relabelled_cells: Option<usize>,
    /// Some port or wall carries more than one face's worth of flow at the rest speed: the
    /// boundaries move fluid.
    pub boundaries_flow: bool,
}

/// The cell kinds and labels, the ports and the walls.
pub struct Ports {
    cells: VoxelBox,
    /// Outer radius of the sheath, m.
    sheath_radius_m: f64,
    /// Hole band, m behind the tip: `[near, far]`.
    holes_m: [f64; 2],
    /// The inflow channel's area, m^2.
    inflow_channel_area_m2: f64,
    /// The sheath is a layer of the cut cells (`[fluid] cut_cells`): cells of its plain part
    /// that hold fluid are fluid.
    cut_sheath: bool,
    /// The scope moves the labels when it moved by this fraction of a voxel.
    scope_move_fraction: f64,
    /// Boundaries move fluid from this speed, m/s.
    rest_speed_m_s: f64,
    kinds: Vec<VoxelKind>,
    labels: Vec<CellLabel>,
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
    /// [`Ports::compose_labels`].
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
}

impl Ports {
    /// The stage for the grid `cells` and the scene's scope and skip settings: every cell solid,
    /// every row to be composed.
    pub fn new(cells: VoxelBox, desc: &SceneDesc) -> Self {
        let n = cells.cell_count();
        let rows = cells.dims[1] * cells.dims[2];
        let scope = ScopeDims::of(&desc.scope);
        Self {
            cells,
            sheath_radius_m: scope.radius_m,
            holes_m: scope.holes_m,
            inflow_channel_area_m2: scope.channel_area_m2,
            cut_sheath: desc.stages.fluid && desc.fluid.cut_cells,
            scope_move_fraction: desc.skip.scope_move_fraction.max(1e-6),
            rest_speed_m_s: desc.skip.rest_speed_m_s,
            kinds: vec![VoxelKind::Solid; n],
            labels: vec![CellLabel::Solid; n],
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
        }
    }

    /// The grid's box.
    pub fn cells(&self) -> &VoxelBox {
        &self.cells
    }
    /// Kind of every cell, x fastest (as of the last composition).
    pub fn kinds(&self) -> &[VoxelKind] {
        &self.kinds
    }
    /// The scope as last placed, if ever.
    pub fn scope(&self) -> Option<&ScopeGeometry> {
        self.scope.as_ref()
    }
    /// The inflow port's cells and their faces on fluid.
    pub fn inflow(&self) -> &[BoundaryCell] {
        &self.inflow
    }
    /// The inflow port as the particles see it.
    pub fn inflow_port(&self) -> InflowPort<'_> {
        InflowPort {
            cells: &self.inflow,
            grid: self.cells,
            direction: self.scope.map(|sc| sc.dir),
            channel_area_m2: self.inflow_channel_area_m2,
        }
    }
    /// The jet velocity of the inflow cells, m/s.
    pub fn inflow_jet_m_per_s(&self) -> [f32; 3] {
        self.inflow_jet_m_per_s
    }
    /// Fluid cells after the last composition.
    pub fn fluid_cells(&self) -> usize {
        self.fluid_cells
    }
    /// Volume of the fluid cells, m^3 (the conservative voxelization's volume).
    pub fn fluid_volume_m3(&self) -> f64 {
        let h = self.cells.spacing_m;
        self.fluid_cells as f64 * h * h * h
    }

    /// The pose the next step composes the labels for (with `compose`, the labels are composed
    /// whatever else moved): the cut-cell sheath layer is placed there, so the fractions and the
    /// scope's cells describe one pose.
    pub fn scope_to_compose(&mut self, compose: bool) -> Option<ScopeGeometry> {
        self.labels_dirty |= compose;
        if self.labels_dirty {
            self.scope
        } else {
            self.scope_built
        }
    }

    /// The built scope's cells (those whose centres lie in the sheath) and their parts, by cell
    /// index.
    pub fn scope_cells(&self) -> &[(u32, ScopePart)] {
        &self.scope_cells
    }

    /// Notes rows of cells whose cavity states or fractions changed: recomposed at the next step.
    pub fn track_rows(&mut self, changed_rows: &[u32]) {
        if !changed_rows.is_empty() {
            self.labels_dirty = true;
            for &row in changed_rows {
                self.mark_pending(row as usize);
            }
        }
    }

    /// Notes what moved since the last step: the rows whose cell states the voxelizer changed
    /// (recomposed at the next step) and the scope's pose (placed when valid; its labels move
    /// when it moved by more than the threshold).
    pub fn track(&mut self, changed_rows: &[u32], pose: &ScopePose) {
        self.track_rows(changed_rows);
        if pose.valid {
            if let Some(dir) = unit(pose.view_direction) {
                if pose.tip_position_m.iter().all(|v| v.is_finite()) {
                    self.scope = Some(ScopeGeometry {
                        tip_m: pose.tip_position_m,
                        dir,
                        radius_m: self.sheath_radius_m,
                        holes_m: self.holes_m,
                    });
                }
            }
        }
        if self.scope_moved() {
            self.labels_dirty = true;
        }
    }

    /// Composes the labels when the cavity or the scope moved (into the solver's grid), and sets
    /// the ports' and walls' velocities for the frame's `flows` when the labels changed or a
    /// boundary carries flow (or did in the last frame). Writes the port figures of `flux`.
    pub fn step(
        &mut self,
        cavity: &CavityCells<'_>,
        flows: &FrameFlows,
        solver: &mut FluidSolver,
        flux: &mut FluxBalance,
        counters: &mut StageCounters,
    ) -> Result<PortsStep, SceneError> {
        let t = Instant::now();
        let relabelled_cells = if self.labels_dirty {
            let changed = self.compose_labels(false, cavity, Some(&mut *solver), flux)?;
            self.labels_dirty = false;
            Some(changed)
        } else {
            None
        };
        // Boundaries move fluid when some flow exceeds one face's worth at the rest speed.
        let floor = self.rest_speed_m_s * self.cells.spacing_m * self.cells.spacing_m;
        let boundaries_flow = [
            flows.inflow_m3_per_s,
            flows.outflow_m3_per_s,
            flows.dvdt_m3_per_s,
        ]
        .iter()
        .any(|q| q.abs() > floor);
        if relabelled_cells.is_some() || boundaries_flow || flux.wall_flux_scale != 0.0 {
            let owners = cavity.voxels.owners();
            self.set_boundary_velocities(flows, cavity, owners, solver, flux);
            counters.ran_since(t);
        } else {
            counters.skipped();
        }
        Ok(PortsStep {
            relabelled_cells,
            boundaries_flow,
        })
    }

    /// Whether the scope moved enough since the labels were composed for it to matter: its tip
    /// or the part of the sheath in the grid by more than `scope_move_fraction` of a voxel.
    fn scope_moved(&self) -> bool {
        match (self.scope, self.scope_built) {
            (None, _) => false,
            (Some(_), None) => true,
            (Some(a), Some(b)) => {
                let h = self.cells.spacing_m;
                let f = self.scope_move_fraction;
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

    /// Marks row `row` for recomposition by the next [`Ports::compose_labels`].
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
            // With the cut sheath a cell's kind depends on its part (the plain part's cells
            // holding fluid are fluid), so a row whose cells changed parts is recomposed.
            let moved_cells =
                was.len() != now.len() || was.iter().zip(now).any(|(x, y)| x.0 != y.0);
            if moved_cells || (self.cut_sheath && was != now) {
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
    /// which [`Ports::relabel_whole_box`] checks them against). Returns how many solver labels
    /// changed.
    fn compose_labels(
        &mut self,
        whole: bool,
        cavity: &CavityCells<'_>,
        mut solver: Option<&mut FluidSolver>,
        flux: &mut FluxBalance,
    ) -> Result<usize, SceneError> {
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
            if let Some(solver) = solver.as_deref_mut() {
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
        let states = cavity.voxels.states();
        let owners = cavity.voxels.owners();
        let extents = cavity.voxels.row_extents();
        let caps = cavity.surface.cap_triangles() as u32;
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
                // With cut cells the fraction decides what is fluid (every cell holding fluid is
                // inside or band, so within the row's range), the os's cells too (their pieces
                // carry the losses: `CutWalls`); without, the os is open.
                let kind = match (states[n], cavity.fractions.map(|f| &f.fractions().volume)) {
                    (state::BAND, None) if owners[n] < caps => VoxelKind::Open,
                    (_, Some(v)) if holds_fluid(v[n]) => VoxelKind::Fluid,
                    (state::INSIDE, None) => VoxelKind::Fluid,
                    (state::BAND, _) => VoxelKind::Wall,
                    _ => VoxelKind::Solid,
                };
                fluid += u32::from(kind == VoxelKind::Fluid);
                self.kinds[n] = kind;
            }
            // The scope on top. With cut cells the sheath is a layer of the fractions: a cell of
            // its plain part that holds fluid beside it is that fluid's; the tip layer and the
            // hole band stay whole cells for the ports.
            let mut now = vox;
            let first = self.scope_cells.partition_point(|c| (c.0 as usize) < base);
            for &(n, part) in &self.scope_cells[first..] {
                let n = n as usize;
                if n >= base + nx {
                    break;
                }
                let i = (n - base) as u32;
                now = range_hull(now, [i, i + 1]);
                let cut_fluid = self.cut_sheath
                    && cavity.fractions.is_some()
                    && part == ScopePart::Sheath
                    && self.kinds[n] == VoxelKind::Fluid;
                if cut_fluid {
                    continue;
                }
                fluid -= u32::from(self.kinds[n] == VoxelKind::Fluid);
                self.kinds[n] = VoxelKind::Scope;
            }
            self.kind_extent[row] = now;
            self.fluid_cells = self.fluid_cells + fluid as usize - self.row_fluid[row] as usize;
            self.row_fluid[row] = fluid;
            // Labels into the solver, and cells that stopped being walls move no more.
            if let Some(solver) = solver.as_deref_mut() {
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
                let g = port_face_weight(&b, sc.dir, cells.dims, cavity.fractions);
                let (_, r) = sc.axial_radial(cells.centre_m_of(b.cell));
                self.candidates.push((r, b, g));
            }
        }
        // The inflow port: the tip cells whose fluid faces look forward, nearest the axis first,
        // until their fluid-facing area (with cut cells, its open part) reaches the channel's; the
        // last one (the rim) counts with the share of its area that completes the channel's, so the
        // port's area on the grid is the channel's at any voxel size and the jet leaves at the
        // hydraulics' port velocity. Fewer forward faces than the channel's area: tissue covers
        // part of the tip. Unstable (no scratch buffer on the heap), with the cells' order (that of
        // `tips`) among equal distances: the order of a stable sort.
        self.candidates
            .sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cell.cmp(&b.1.cell)));
        let area = self.inflow_channel_area_m2;
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
        flux.inflow_open_fraction = if area > 0.0 { g / area } else { 0.0 };
        for b in &self.inflow {
            self.kinds[b.cell as usize] = VoxelKind::Inflow;
        }
        for b in &self.outflow {
            self.kinds[b.cell as usize] = VoxelKind::Outflow;
        }
        Ok(changed)
    }

    /// Recomposes the kind and label of every cell of the box for the scope pose of the last
    /// composition, visiting every cell, and says what that changed: nothing when the
    /// row-incremental compositions of the steps before were complete. For verification; the
    /// kinds, lists and labels end as a step leaves them.
    pub fn relabel_whole_box(
        &mut self,
        cavity: &CavityCells<'_>,
        solver: Option<&mut FluidSolver>,
        flux: &mut FluxBalance,
    ) -> Result<WholeBoxCheck, SceneError> {
        let kinds = self.kinds.clone();
        let lists = [&self.inflow, &self.outflow, &self.walls, &self.open].map(|l| l.clone());
        let (fluid_cells, rim) = (self.fluid_cells, self.inflow_rim_fraction);
        // A pose that moved less than the threshold since is not composed yet (by design).
        let scope = std::mem::replace(&mut self.scope, self.scope_built);
        let composed = self.compose_labels(true, cavity, solver, flux);
        self.scope = scope;
        let labels_changed = composed?;
        let now = [&self.inflow, &self.outflow, &self.walls, &self.open];
        Ok(WholeBoxCheck {
            labels_changed,
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

    /// Port and wall velocities with exact fluxes: the frame's `flows`. With cut cells (`cut`)
    /// the walls are still: their pieces in the cut cells move the fluid (`CutWalls`).
    fn set_boundary_velocities(
        &mut self,
        flows: &FrameFlows,
        cavity: &CavityCells<'_>,
        owners: &[u32],
        solver: &mut FluidSolver,
        flux: &mut FluxBalance,
    ) {
        let (q_in, q_out, dvdt) = (
            flows.inflow_m3_per_s,
            flows.outflow_m3_per_s,
            flows.dvdt_m3_per_s,
        );
        let dpdt = flows.dpdt_pa_per_s;
        let (surface, cut) = (cavity.surface, cavity.fractions);
        let cells = self.cells;
        let open = |b: &BoundaryCell, v: [f64; 3]| port_face_weight(b, v, cells.dims, cut);
        let h2 = cells.spacing_m * cells.spacing_m;
        let coords = |b: &BoundaryCell| b.at.map(|x| x as usize);
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
                .map(|(m, b)| share(m) * open(b, sc.dir))
                .sum::<f64>()
                * h2;
            let open_port =
                g_in > 0.0 && g_in >= MIN_INFLOW_OPEN_FRACTION * self.inflow_channel_area_m2;
            let u = if open_port { q_in / g_in } else { 0.0 };
            flux.inflow_blocked = !open_port && q_in > 0.0;
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
                g_out += open(b, r) * h2;
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
        flux.hydraulic_inflow_m3_per_s = q_in;
        flux.hydraulic_outflow_m3_per_s = q_out;
        flux.hydraulic_losses_m3_per_s = flows.losses_m3_per_s;
        flux.hydraulic_dvdt_m3_per_s = dvdt;
        if cut.is_some() {
            for b in &self.walls {
                let _ = still(
                    &mut self.wall_velocity,
                    solver.grid_mut(),
                    b.cell as usize,
                    coords(b),
                );
            }
            return;
        }
        // Walls: dx/dp dp/dt at the owning triangle, scaled so that the flux into the walls is
        // dV/dt exactly.
        let tris = surface.triangles();
        let dxdp = surface.dxdp_m_per_pa();
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
    }

    /// Measures the fluxes through the ports' and walls' fluid faces after a fluid step (with cut
    /// cells, through their open parts).
    pub fn measure_fluxes(&self, solver: &FluidSolver, flux: &mut FluxBalance) {
        let cells = self.cells;
        let h2 = cells.spacing_m * cells.spacing_m;
        // Flux out of the fluid into boundary cell b.
        let out_of_fluid = |b: &BoundaryCell| -> f64 {
            let c = b.at.map(|x| x as usize);
            let mut s = 0.0;
            for f in 0..6 {
                if b.faces >> f & 1 == 1 {
                    // Face f of the boundary cell; its normal points into the fluid; with cut
                    // cells only its open part carries flux.
                    let u = solver.cell_face_velocity_m_s(c, f) as f64
                        * solver.cell_face_open_fraction(c, f) as f64;
                    let sign = if f % 2 == 1 { 1.0 } else { -1.0 };
                    s -= sign * u * h2;
                }
            }
            s
        };
        flux.fluid_inflow_m3_per_s = -self.inflow.iter().map(out_of_fluid).sum::<f64>();
        flux.fluid_outflow_m3_per_s = self.outflow.iter().map(out_of_fluid).sum();
        flux.fluid_wall_m3_per_s = self.walls.iter().map(out_of_fluid).sum();
        flux.fluid_open_m3_per_s = self.open.iter().map(out_of_fluid).sum();
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

/// The area (in faces) through which port cell `b` moves fluid along `v`: [`face_weight`] of its
/// fluid faces, with cut cells (`cut`) each weighted by its open fraction (the part tissue does
/// not cover). The one rule for choosing the inflow port's cells and for setting the ports'
/// velocities, so the port's area on the grid is the one its velocity is computed for.
fn port_face_weight(
    b: &BoundaryCell,
    v: [f64; 3],
    dims: [usize; 3],
    cut: Option<&CavityFractions>,
) -> f64 {
    match cut {
        Some(cut) => open_face_weight(b, v, dims, cut),
        None => face_weight(b.faces, v),
    }
}

/// [`face_weight`] with each face of the port cell `b` weighted by its open area fraction
/// ([`CavityFractions::port_face_fraction`]; the grid of `dims` cells, not periodic).
fn open_face_weight(b: &BoundaryCell, v: [f64; 3], dims: [usize; 3], cut: &CavityFractions) -> f64 {
    let mut s = 0.0;
    for (f, n) in FACE_NORMALS.iter().enumerate() {
        if b.faces >> f & 1 == 1 {
            let a = f / 2;
            let mut at = b.at.map(|x| x as usize);
            at[a] += f % 2;
            let mut d = dims;
            d[a] += 1;
            let area = cut.port_face_fraction(a, at[0] + d[0] * (at[1] + d[1] * at[2])) as f64;
            s += area * (v[0] * n[0] + v[1] * n[1] + v[2] * n[2]);
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
