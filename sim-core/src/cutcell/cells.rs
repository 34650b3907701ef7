//! The fluid of a box of cells as layers of closed surfaces (the cavity, the scope's sheath, the
//! regions of a case file), each marking what it encloses as fluid or solid over what lies
//! below it; with the small-cell rule applied.

use super::fractions::{FractionStats, Span, SurfaceFractions};
use super::small::{self, NO_TARGET};
use super::{check_box, CutCellError, Orientation};
use crate::scene::voxelize::VoxelBox;

/// What a layer's enclosed region (or the background) is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    /// Fluid.
    Fluid,
    /// Solid.
    Solid,
}

impl Phase {
    fn fraction(self) -> f64 {
        match self {
            Phase::Fluid => 1.0,
            Phase::Solid => 0.0,
        }
    }
}

/// One closed surface of a [`CutCells`].
#[derive(Debug, Clone)]
pub struct Layer {
    /// Its name, for errors.
    pub name: String,
    /// Its triangles (closed, consistently oriented).
    pub triangles: Vec<[u32; 3]>,
    /// How many vertices its positions hold.
    pub vertex_count: usize,
    /// Which way its normals point.
    pub orientation: Orientation,
    /// What its enclosed region becomes.
    pub inside: Phase,
}

/// The small-fraction rule's parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SmallCellParams {
    /// Cells with a fluid volume fraction in `(0, this)` are merged into a neighbour
    /// ([`super::small`]).
    pub min_volume_fraction: f64,
    /// Fractions within this of 0 or 1 are rounding (the exact fractions carry about 1e-16 of it
    /// where a surface passes a cell's corner or lies in a face): in the stabilised output such
    /// faces are 0 or 1, and such cells empty (their dust of volume, at most this much per cell,
    /// is dropped rather than merged).
    pub round_off_fraction: f64,
    /// Faces open by less than this are closed in the stabilised output (the solver's faces and
    /// the ports'). A face a thousandth open carries a thousandth of a whole face's flux at the
    /// same speed, but the projection sets its velocity from the pressures on its two sides
    /// whatever its area: between the slivers of a collapsing slit, whose pressures differ by
    /// what their wall pieces push through a few per cent of open face, such faces reached 71 m/s
    /// in the scene's soak (`sim-core/tests/scene_soak.rs`), 12.9 m/s once closed, below the
    /// fastest port's 13.5 m/s.
    pub min_face_fraction: f64,
}

impl Default for SmallCellParams {
    fn default() -> Self {
        Self {
            min_volume_fraction: 0.1,
            round_off_fraction: 1e-12,
            min_face_fraction: 1e-3,
        }
    }
}

impl SmallCellParams {
    /// A face's stabilised open fraction: 0 below `min_face_fraction`, 1 within
    /// `round_off_fraction` of 1, else the exact fraction. The one rule for the solver's faces
    /// and the ports' (`CavityFractions::port_face_fraction`).
    #[inline]
    pub(crate) fn stabilised_face(&self, v: f64) -> f64 {
        if v < self.min_face_fraction {
            0.0
        } else {
            round_off(v, self.round_off_fraction)
        }
    }
}

/// What one call did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CutCellStats {
    /// The layers' work, summed.
    pub layers: FractionStats,
    /// Rows whose fractions were combined anew.
    pub rows_combined: usize,
    /// Rows whose small-cell rule was applied anew.
    pub rows_stabilised: usize,
    /// Rows in which anything published changed ([`CutCells::changed_rows`]).
    pub changed_rows: usize,
    /// Cells cut by more than one layer's surface (their fractions are approximate), now.
    pub approximate_cells: usize,
    /// Small cells merged into a neighbour, now.
    pub merged_cells: usize,
    /// Small cells with no neighbour to merge into, now.
    pub unmerged_small_cells: usize,
}

// Row stages, as bits of `row_flags`.
const COMBINE: u8 = 1;
const INTERFACE: u8 = 2;
const DECIDE: u8 = 4;
const STABILISE: u8 = 8;
const CHANGED: u8 = 16;

const NOT_SMALL: u8 = 0;
const MERGED: u8 = 1;
const UNMERGED: u8 = 2;

/// The fluid fractions of a box of cells bounded by layers of closed surfaces, incremental.
///
/// The fluid indicator starts as the background and each layer in order makes what it encloses
/// fluid (union) or solid (subtraction). Per layer the fractions are exact
/// ([`SurfaceFractions`]); they combine per cell and per face as `max(phi, f)` (fluid) or
/// `max(0, phi - f)` (solid), which is exact wherever at most one of the two is fractional,
/// i.e. in every cell no more than one surface cuts. Where two surfaces cut the same cell the
/// result assumes the two pieces nested and the cell is counted in
/// [`CutCellStats::approximate_cells`] (the error is at most that cell's smaller fraction; such
/// cells line the curve where the surfaces cross, so their total error falls as `h^2`).
#[derive(Debug, Clone)]
pub struct CutCells {
    cells: VoxelBox,
    background: Phase,
    params: SmallCellParams,
    layers: Vec<(SurfaceFractions, Phase)>,
    volume: Vec<f64>,
    faces: [Vec<f64>; 3],
    interface: Vec<[f64; 3]>,
    approximate: Vec<bool>,
    approximate_count: usize,
    targets: Vec<u32>,
    /// Per cell: [`NOT_SMALL`], [`MERGED`] or [`UNMERGED`] (for the counts).
    small_state: Vec<u8>,
    merged_count: usize,
    unmerged_count: usize,
    stabilised_volume: Vec<f64>,
    stabilised_faces: [Vec<f64>; 3],
    row_flags: Vec<u8>,
    stage_rows: [Vec<u32>; 4],
    changed_rows: Vec<u32>,
    /// Strips to combine: `[y-strips, z-strips]`.
    strip_flags: [Vec<bool>; 2],
    strips: [Vec<u32>; 2],
    /// Where in each row or strip a stage has work: the positions whose inputs changed (a cell
    /// whose inputs are as they were keeps its value, so the rest of the row is skipped).
    combine_span: Vec<Span>,
    strip_span: [Vec<Span>; 2],
    interface_span: Vec<Span>,
    decide_span: Vec<Span>,
    stabilise_span: Vec<Span>,
    /// What a stage's rows and strips changed, per row or strip: written by the two halves of
    /// the stage, then read in the order they were listed.
    strip_changed: [Vec<Span>; 2],
    row_combined: Vec<(Span, Span, bool)>,
    row_changed: Vec<Span>,
    /// Per layer `k`, the work of a stage's rows or strips (for the split in two halves).
    layer_work: Vec<u64>,
    initialised: bool,
}

impl CutCells {
    /// Fractions on `cells` for `layers` over `background`; nothing is computed until the first
    /// [`CutCells::update`] or [`CutCells::full`].
    pub fn new(
        cells: VoxelBox,
        background: Phase,
        layers: Vec<Layer>,
        params: SmallCellParams,
    ) -> Result<Self, CutCellError> {
        check_box(&cells)?;
        if !(params.min_volume_fraction >= 0.0 && params.min_volume_fraction <= 1.0) {
            return Err(CutCellError::Box(format!(
                "min_volume_fraction = {}: expected a value in [0, 1]",
                params.min_volume_fraction
            )));
        }
        if !(params.round_off_fraction >= 0.0 && params.round_off_fraction < 0.5) {
            return Err(CutCellError::Box(format!(
                "round_off_fraction = {}: expected a value in [0, 0.5)",
                params.round_off_fraction
            )));
        }
        if !(params.min_face_fraction >= 0.0 && params.min_face_fraction < 0.5) {
            return Err(CutCellError::Box(format!(
                "min_face_fraction = {}: expected a value in [0, 0.5)",
                params.min_face_fraction
            )));
        }
        let layers = layers
            .into_iter()
            .map(|l| {
                SurfaceFractions::new(&l.name, cells, l.triangles, l.vertex_count, l.orientation)
                    .map(|f| (f, l.inside))
            })
            .collect::<Result<Vec<_>, _>>()?;
        let [nx, ny, nz] = cells.dims;
        let n = cells.cell_count();
        let b = background.fraction();
        let faces = [
            vec![b; (nx + 1) * ny * nz],
            vec![b; nx * (ny + 1) * nz],
            vec![b; nx * ny * (nz + 1)],
        ];
        let rows = ny * nz;
        Ok(Self {
            cells,
            background,
            params,
            layers,
            volume: vec![b; n],
            stabilised_faces: faces.clone(),
            faces,
            interface: vec![[0.0; 3]; n],
            approximate: vec![false; n],
            approximate_count: 0,
            targets: vec![NO_TARGET; n],
            small_state: vec![NOT_SMALL; n],
            merged_count: 0,
            unmerged_count: 0,
            stabilised_volume: vec![b; n],
            row_flags: vec![0; rows],
            stage_rows: std::array::from_fn(|_| Vec::with_capacity(rows)),
            changed_rows: Vec::with_capacity(rows),
            strip_flags: [vec![false; (ny + 1) * nz], vec![false; ny * (nz + 1)]],
            strips: [
                Vec::with_capacity((ny + 1) * nz),
                Vec::with_capacity(ny * (nz + 1)),
            ],
            combine_span: vec![Span::EMPTY; rows],
            strip_span: [
                vec![Span::EMPTY; (ny + 1) * nz],
                vec![Span::EMPTY; ny * (nz + 1)],
            ],
            interface_span: vec![Span::EMPTY; rows],
            decide_span: vec![Span::EMPTY; rows],
            stabilise_span: vec![Span::EMPTY; rows],
            strip_changed: [
                vec![Span::EMPTY; (ny + 1) * nz],
                vec![Span::EMPTY; ny * (nz + 1)],
            ],
            row_combined: vec![(Span::EMPTY, Span::EMPTY, false); rows],
            row_changed: vec![Span::EMPTY; rows],
            layer_work: vec![0; nz + 1],
            initialised: false,
        })
    }

    /// The box.
    pub fn cells(&self) -> &VoxelBox {
        &self.cells
    }
    /// The layers' own exact fractions, in order.
    pub fn layer(&self, l: usize) -> &SurfaceFractions {
        &self.layers[l].0
    }
    /// What lies under the layers.
    pub fn background(&self) -> Phase {
        self.background
    }
    /// What layer `l`'s enclosed region becomes.
    pub fn layer_phase(&self, l: usize) -> Phase {
        self.layers[l].1
    }
    /// How many layers.
    pub fn layer_count(&self) -> usize {
        self.layers.len()
    }
    /// The small-cell parameters.
    pub fn params(&self) -> &SmallCellParams {
        &self.params
    }
    /// Per cell (x fastest), the exact fluid volume fraction in `[0, 1]`.
    pub fn volume_fractions(&self) -> &[f64] {
        &self.volume
    }
    /// Per face normal to `axis`, the exact open (fluid) area fraction in `[0, 1]`; face
    /// `(i, j, k)` lies between cells `(i-1, j, k)` and `(i, j, k)` along the axis, x fastest,
    /// `dims[axis] + 1` faces along it (the box's boundary faces included).
    pub fn face_fractions(&self, axis: usize) -> &[f64] {
        &self.faces[axis]
    }
    /// Per cell, the area vector of the fluid's boundary inside it (the walls), `integral of n dA
    /// / h^2` with `n` out of the fluid: `-sum over faces of +-A_f e_f`, so every cell's faces and
    /// walls close exactly.
    pub fn wall_areas(&self) -> &[[f64; 3]] {
        &self.interface
    }
    /// Per cell, whether more than one layer's surface cuts it (its fractions are approximate).
    pub fn approximate(&self) -> &[bool] {
        &self.approximate
    }
    /// Per cell, the cell it is merged into ([`NO_TARGET`]: none) by the small-cell rule.
    pub fn merge_targets(&self) -> &[u32] {
        &self.targets
    }
    /// The flux, m^3/s into the fluid, that cell `n`'s walls push when they move at
    /// `velocity_m_s`: `-h^2 W . v` with `W` its [`CutCells::wall_areas`] (out of the fluid), so
    /// a wall moving into the fluid pushes fluid in. Over a closed surface moving rigidly the
    /// cells' fluxes sum to zero (the walls' areas do, up to rounding).
    pub fn wall_flux_m3_per_s(&self, n: usize, velocity_m_s: [f64; 3]) -> f64 {
        let h = self.cells.spacing_m;
        let w = self.interface[n];
        -h * h * (w[0] * velocity_m_s[0] + w[1] * velocity_m_s[1] + w[2] * velocity_m_s[2])
    }
    /// The cell whose fluid carries the walls of cell `n` once the small-cell rule applied: `n`
    /// itself, or the cell it was merged into (its volume moved there, and so do its walls'
    /// fluxes). The one rule for placing wall fluxes on the stabilised fractions
    /// (`FluidGrid::set_boundary_flux_m3_per_s`).
    pub fn wall_carrier(&self, n: usize) -> usize {
        match self.targets[n] {
            NO_TARGET => n,
            t => t as usize,
        }
    }
    /// Per cell, the fluid volume fraction after the small-cell rule: 0 for a merged cell or one
    /// holding only rounding (at most `round_off_fraction`), its own plus what merged into it
    /// otherwise (may exceed 1). Sums to the exact fractions' sum less that rounding.
    pub fn stabilised_volume_fractions(&self) -> &[f64] {
        &self.stabilised_volume
    }
    /// The face fractions with rounding removed (below `round_off_fraction` 0, above `1 -
    /// round_off_fraction` 1).
    pub fn stabilised_face_fractions(&self, axis: usize) -> &[f64] {
        &self.stabilised_faces[axis]
    }
    /// The rows `j + ny k` in which the last call changed any cell's or face's value.
    pub fn changed_rows(&self) -> &[u32] {
        &self.changed_rows
    }

    /// Computes everything from the layers' positions (one slice per layer).
    pub fn full(&mut self, positions_m: &[&[[f32; 3]]]) -> Result<CutCellStats, CutCellError> {
        self.check(positions_m)?;
        let mut stats = CutCellStats::default();
        for (l, p) in self.layers.iter_mut().zip(positions_m) {
            add(&mut stats.layers, l.0.full(p)?);
        }
        self.initialised = true;
        let [nx, ny, nz] = self.cells.dims;
        for r in 0..ny * nz {
            self.flag_row(r, COMBINE | INTERFACE);
            self.combine_span[r] = Span::new(0, nx);
            self.interface_span[r] = Span::new(0, nx - 1);
        }
        for s in 0..2 {
            for u in 0..self.strip_flags[s].len() {
                mark(u, &mut self.strip_flags[s], &mut self.strips[s]);
                self.strip_span[s][u] = Span::new(0, nx - 1);
            }
        }
        self.finish(&mut stats);
        Ok(stats)
    }

    /// Moves the layers to new positions (one slice per layer; see
    /// [`SurfaceFractions::update`] for `threshold_m`) and updates what their moved triangles
    /// reach. Bit for bit the result of [`CutCells::full`] at the held positions. Positions are
    /// checked for every layer before anything changes.
    pub fn update(
        &mut self,
        positions_m: &[&[[f32; 3]]],
        threshold_m: f64,
    ) -> Result<CutCellStats, CutCellError> {
        if !self.initialised {
            return self.full(positions_m);
        }
        self.check(positions_m)?;
        let mut stats = CutCellStats::default();
        for (l, p) in positions_m.iter().enumerate() {
            let s = self.layers[l].0.update(p, threshold_m)?;
            add(&mut stats.layers, s);
            let f = &self.layers[l].0;
            for (&r, &span) in f.changed_rows().iter().zip(f.changed_row_spans()) {
                flag(
                    &mut self.row_flags,
                    &mut self.stage_rows,
                    r as usize,
                    COMBINE,
                );
                self.combine_span[r as usize].join(span);
            }
            for (s, changed) in [f.changed_ystrips(), f.changed_zstrips()]
                .into_iter()
                .enumerate()
            {
                for (&u, &span) in changed.iter().zip(f.changed_strip_spans(s)) {
                    mark(u as usize, &mut self.strip_flags[s], &mut self.strips[s]);
                    self.strip_span[s][u as usize].join(span);
                }
            }
        }
        self.finish(&mut stats);
        Ok(stats)
    }

    fn check(&self, positions_m: &[&[[f32; 3]]]) -> Result<(), CutCellError> {
        if positions_m.len() != self.layers.len() {
            return Err(CutCellError::Box(format!(
                "{} position sets for {} layers",
                positions_m.len(),
                self.layers.len()
            )));
        }
        for (l, p) in self.layers.iter().zip(positions_m) {
            l.0.check_positions(p)?;
        }
        Ok(())
    }

    fn flag_row(&mut self, r: usize, bits: u8) {
        flag(&mut self.row_flags, &mut self.stage_rows, r, bits);
    }

    /// Combines the flagged rows and strips, then applies the small-cell rule where their
    /// values changed. Each stage works only on the cells whose inputs changed: a cell's walls
    /// follow its faces, its merge target its own and its face neighbours' volumes and its faces,
    /// its stabilised volume its own and its neighbours' volumes and targets. Each stage computes
    /// its rows (strips) in two halves on the two cores (a row writes only its own cells and faces,
    /// and reads only what earlier stages wrote), then flags what they changed in one pass, in the
    /// order the rows were listed: the same values and lists as one pass doing both.
    fn finish(&mut self, stats: &mut CutCellStats) {
        let [nx, ny, nz] = self.cells.dims;
        self.changed_rows.clear();
        // Strips: their faces, and the walls and merges of the cells on both sides.
        for axis in [1, 2] {
            let strips = std::mem::take(&mut self.strips[axis - 1]);
            // y-strip `j + (ny + 1) k`, z-strip `j + ny k`: the rows `row - step` and `row`
            // lie on the two sides of the strip's plane.
            let (width, step) = if axis == 1 { (ny + 1, 1) } else { (ny, ny) };
            self.combine_strips(axis, &strips, width);
            for &u in &strips {
                let u = u as usize;
                self.strip_flags[axis - 1][u] = false;
                self.strip_span[axis - 1][u] = Span::EMPTY;
                let changed = self.strip_changed[axis - 1][u];
                if !changed.is_empty() {
                    let (j, k) = (u % width, u / width);
                    let (plane, extent) = if axis == 1 { (j, ny) } else { (k, nz) };
                    let row = j + ny * k;
                    if plane > 0 {
                        self.faces_changed(row - step, changed);
                    }
                    if plane < extent {
                        self.faces_changed(row, changed);
                    }
                }
            }
            self.strips[axis - 1] = strips;
            self.strips[axis - 1].clear();
        }
        // Rows: volumes and x-faces.
        let rows = std::mem::take(&mut self.stage_rows[0]);
        self.combine_rows(&rows);
        for &r in &rows {
            let r = r as usize;
            self.row_flags[r] &= !COMBINE;
            self.combine_span[r] = Span::EMPTY;
            let (faces, volumes, approx) = self.row_combined[r];
            if !faces.is_empty() || !volumes.is_empty() || approx {
                self.row_flags[r] |= CHANGED;
            }
            if !faces.is_empty() {
                // x-face `f` lies between cells `f - 1` and `f`.
                let cells = Span::new(
                    faces.lo.saturating_sub(1) as usize,
                    faces.hi.min(nx as u32 - 1) as usize,
                );
                self.faces_changed(r, cells);
            }
            if !volumes.is_empty() {
                self.spread(r, volumes, DECIDE);
                self.spread(r, volumes, STABILISE);
            }
        }
        stats.rows_combined = rows.len();
        self.stage_rows[0] = rows;
        self.stage_rows[0].clear();
        // Walls.
        let rows = std::mem::take(&mut self.stage_rows[1]);
        self.interface_rows(&rows);
        for &r in &rows {
            let r = r as usize;
            self.row_flags[r] &= !INTERFACE;
            self.interface_span[r] = Span::EMPTY;
            if !self.row_changed[r].is_empty() {
                self.row_flags[r] |= CHANGED;
            }
        }
        self.stage_rows[1] = rows;
        self.stage_rows[1].clear();
        // Merges; a changed target changes the stabilised volumes around it.
        let rows = std::mem::take(&mut self.stage_rows[2]);
        self.decide_rows(&rows);
        for &r in &rows {
            let r = r as usize;
            self.row_flags[r] &= !DECIDE;
            self.decide_span[r] = Span::EMPTY;
            let changed = self.row_changed[r];
            if !changed.is_empty() {
                self.row_flags[r] |= CHANGED;
                self.spread(r, changed, STABILISE);
            }
        }
        self.stage_rows[2] = rows;
        self.stage_rows[2].clear();
        let rows = std::mem::take(&mut self.stage_rows[3]);
        self.stabilise_rows(&rows);
        for &r in &rows {
            let r = r as usize;
            self.row_flags[r] &= !STABILISE;
            self.stabilise_span[r] = Span::EMPTY;
            if !self.row_changed[r].is_empty() {
                self.row_flags[r] |= CHANGED;
            }
        }
        stats.rows_stabilised = rows.len();
        self.stage_rows[3] = rows;
        self.stage_rows[3].clear();
        for r in 0..self.row_flags.len() {
            // Only rows touched above can carry the bit; the scan is over one byte per row.
            if self.row_flags[r] & CHANGED != 0 {
                self.row_flags[r] &= !CHANGED;
                self.changed_rows.push(r as u32);
            }
        }
        stats.changed_rows = self.changed_rows.len();
        stats.approximate_cells = self.approximate_count;
        stats.merged_cells = self.merged_count;
        stats.unmerged_small_cells = self.unmerged_count;
    }

    /// The faces of cells `cells` of row `r` changed: their walls and merge targets are due.
    fn faces_changed(&mut self, r: usize, cells: Span) {
        self.flag_row(r, INTERFACE | DECIDE | CHANGED);
        self.interface_span[r].join(cells);
        self.decide_span[r].join(cells);
    }

    /// Flags for `stage` the cells of row `r`'s `cells` and their face neighbours: `cells`
    /// widened by one in the row, the same cells in the four neighbour rows.
    fn spread(&mut self, r: usize, cells: Span, stage: u8) {
        let [nx, ny, nz] = self.cells.dims;
        let (j, k) = (r % ny, r / ny);
        let wide = Span::new(
            cells.lo.saturating_sub(1) as usize,
            (cells.hi as usize + 1).min(nx - 1),
        );
        self.stage_span(r, wide, stage);
        if j > 0 {
            self.stage_span(r - 1, cells, stage);
        }
        if j + 1 < ny {
            self.stage_span(r + 1, cells, stage);
        }
        if k > 0 {
            self.stage_span(r - ny, cells, stage);
        }
        if k + 1 < nz {
            self.stage_span(r + ny, cells, stage);
        }
    }

    fn stage_span(&mut self, r: usize, cells: Span, stage: u8) {
        self.flag_row(r, stage);
        let spans = if stage == DECIDE {
            &mut self.decide_span
        } else {
            &mut self.stabilise_span
        };
        spans[r].join(cells);
    }

    /// Combines the faces of `strips` (normal to `axis`, `width` strips a layer) at the positions
    /// of their spans, in two halves of layers; per strip, where its faces changed
    /// (`strip_changed`).
    fn combine_strips(&mut self, axis: usize, strips: &[u32], width: usize) {
        let nx = self.cells.dims[0];
        let spans = &self.strip_span[axis - 1];
        let at = width * split_layer(strips, width, spans, &mut self.layer_work);
        let combine = Combine {
            background: self.background,
            params: self.params,
            layers: &self.layers,
        };
        let (faces, faces_b) = self.faces[axis].split_at_mut(nx * at);
        let (stable, stable_b) = self.stabilised_faces[axis].split_at_mut(nx * at);
        let (changed, changed_b) = self.strip_changed[axis - 1].split_at_mut(at);
        let run = |lo: usize, faces: &mut [f64], stable: &mut [f64], changed: &mut [Span]| {
            for u in in_half(strips, lo, changed.len()) {
                let base = nx * u;
                let mut c = Span::EMPTY;
                for i in spans[u].range(nx - 1) {
                    let f = base + i;
                    let (v, _) = combine.value(|l| l.face_fractions(axis)[f]);
                    let a = store(&mut faces[f - nx * lo], v);
                    let b = store(&mut stable[f - nx * lo], combine.params.stabilised_face(v));
                    if a | b {
                        c.add(i);
                    }
                }
                changed[u - lo] = c;
            }
        };
        crate::fork_join::join(
            || run(0, faces, stable, changed),
            || run(at, faces_b, stable_b, changed_b),
        );
    }

    /// Combines the volumes and `nx + 1` x-faces of `rows` at the positions of their spans
    /// (cell `i` and face `i`), in two halves of layers; per row, where faces and volumes changed
    /// and whether a cell's approximation did (`row_combined`).
    fn combine_rows(&mut self, rows: &[u32]) {
        let [nx, ny, _] = self.cells.dims;
        let spans = &self.combine_span;
        let at = ny * split_layer(rows, ny, spans, &mut self.layer_work);
        let combine = Combine {
            background: self.background,
            params: self.params,
            layers: &self.layers,
        };
        let (fx, fx_b) = self.faces[0].split_at_mut((nx + 1) * at);
        let (sx, sx_b) = self.stabilised_faces[0].split_at_mut((nx + 1) * at);
        let (volume, volume_b) = self.volume.split_at_mut(nx * at);
        let (approx, approx_b) = self.approximate.split_at_mut(nx * at);
        let (combined, combined_b) = self.row_combined.split_at_mut(at);
        // Returns the change in the count of approximate cells.
        let run = |lo: usize,
                   fx: &mut [f64],
                   sx: &mut [f64],
                   volume: &mut [f64],
                   approximate: &mut [bool],
                   combined: &mut [(Span, Span, bool)]|
         -> isize {
            let mut count = 0;
            for r in in_half(rows, lo, combined.len()) {
                let span = spans[r];
                let mut faces = Span::EMPTY;
                let base = (nx + 1) * r;
                for i in span.range(nx) {
                    let f = base + i;
                    let (v, _) = combine.value(|l| l.face_fractions(0)[f]);
                    let idx = f - (nx + 1) * lo;
                    let a = store(&mut fx[idx], v);
                    let b = store(&mut sx[idx], combine.params.stabilised_face(v));
                    if a | b {
                        faces.add(i);
                    }
                }
                let mut volumes = Span::EMPTY;
                let mut approx_changed = false;
                for i in span.range(nx - 1) {
                    let n = nx * r + i;
                    let (v, approx) = combine.value(|l| l.volume_fractions()[n]);
                    let idx = n - nx * lo;
                    if store(&mut volume[idx], v) {
                        volumes.add(i);
                    }
                    if approx != approximate[idx] {
                        approximate[idx] = approx;
                        count += if approx { 1 } else { -1 };
                        approx_changed = true;
                    }
                }
                combined[r - lo] = (faces, volumes, approx_changed);
            }
            count
        };
        let (a, b) = crate::fork_join::join(
            || run(0, fx, sx, volume, approx, combined),
            || run(at, fx_b, sx_b, volume_b, approx_b, combined_b),
        );
        self.approximate_count = self.approximate_count.saturating_add_signed(a + b);
    }

    /// The walls of `rows`' cells in their spans from their faces, in two halves of layers; per
    /// row, where any changed (`row_changed`).
    fn interface_rows(&mut self, rows: &[u32]) {
        let [nx, ny, _] = self.cells.dims;
        let spans = &self.interface_span;
        let at = ny * split_layer(rows, ny, spans, &mut self.layer_work);
        let (fx, fy, fz) = (&self.faces[0], &self.faces[1], &self.faces[2]);
        let (interface, interface_b) = self.interface.split_at_mut(nx * at);
        let (changed, changed_b) = self.row_changed.split_at_mut(at);
        let run = |lo: usize, interface: &mut [[f64; 3]], changed: &mut [Span]| {
            for r in in_half(rows, lo, changed.len()) {
                let (j, k) = (r % ny, r / ny);
                let mut c = Span::EMPTY;
                for i in spans[r].range(nx - 1) {
                    let x = i + (nx + 1) * r;
                    let y = i + nx * (j + (ny + 1) * k);
                    let z = i + nx * r;
                    let s = [
                        -(fx[x + 1] - fx[x]),
                        -(fy[y + nx] - fy[y]),
                        -(fz[z + nx * ny] - fz[z]),
                    ];
                    let slot = &mut interface[nx * (r - lo) + i];
                    if slot.map(f64::to_bits) != s.map(f64::to_bits) {
                        *slot = s;
                        c.add(i);
                    }
                }
                changed[r - lo] = c;
            }
        };
        crate::fork_join::join(
            || run(0, interface, changed),
            || run(at, interface_b, changed_b),
        );
    }

    /// The merge targets of `rows`' cells in their spans, and the counts, in two halves of
    /// layers; per row, where any target changed (`row_changed`).
    fn decide_rows(&mut self, rows: &[u32]) {
        let [nx, ny, _] = self.cells.dims;
        let spans = &self.decide_span;
        let at = ny * split_layer(rows, ny, spans, &mut self.layer_work);
        let theta = self.params.min_volume_fraction;
        let dust = self.params.round_off_fraction;
        let (cells, volume, faces) = (&self.cells, &self.volume, &self.faces);
        let (targets, targets_b) = self.targets.split_at_mut(nx * at);
        let (small_state, small_state_b) = self.small_state.split_at_mut(nx * at);
        let (changed, changed_b) = self.row_changed.split_at_mut(at);
        // Returns the changes in the counts of merged and unmerged cells.
        let run = |lo: usize,
                   targets: &mut [u32],
                   small_state: &mut [u8],
                   changed: &mut [Span]|
         -> [isize; 2] {
            let mut counts = [0isize; 2];
            for r in in_half(rows, lo, changed.len()) {
                let (j, k) = (r % ny, r / ny);
                let mut c = Span::EMPTY;
                for i in spans[r].range(nx - 1) {
                    let n = nx * r + i;
                    let idx = n - nx * lo;
                    let t = small::target(cells, volume, faces, theta, dust, (i, j, k));
                    if t != targets[idx] {
                        c.add(i);
                        targets[idx] = t;
                    }
                    let v = volume[n];
                    let state = if !(v > dust && v < theta) {
                        NOT_SMALL
                    } else if t == NO_TARGET {
                        UNMERGED
                    } else {
                        MERGED
                    };
                    let old = small_state[idx];
                    if state != old {
                        for (s, d) in [(old, -1), (state, 1)] {
                            match s {
                                MERGED => counts[0] += d,
                                UNMERGED => counts[1] += d,
                                _ => {}
                            }
                        }
                        small_state[idx] = state;
                    }
                }
                changed[r - lo] = c;
            }
            counts
        };
        let (a, b) = crate::fork_join::join(
            || run(0, targets, small_state, changed),
            || run(at, targets_b, small_state_b, changed_b),
        );
        self.merged_count = self.merged_count.saturating_add_signed(a[0] + b[0]);
        self.unmerged_count = self.unmerged_count.saturating_add_signed(a[1] + b[1]);
    }

    /// The stabilised volumes of `rows`' cells in their spans, in two halves of layers; per
    /// row, where any changed (`row_changed`).
    fn stabilise_rows(&mut self, rows: &[u32]) {
        let [nx, ny, _] = self.cells.dims;
        let spans = &self.stabilise_span;
        let at = ny * split_layer(rows, ny, spans, &mut self.layer_work);
        let dust = self.params.round_off_fraction;
        let (cells, volume, targets) = (&self.cells, &self.volume, &self.targets);
        let (stable, stable_b) = self.stabilised_volume.split_at_mut(nx * at);
        let (changed, changed_b) = self.row_changed.split_at_mut(at);
        let run = |lo: usize, stable: &mut [f64], changed: &mut [Span]| {
            for r in in_half(rows, lo, changed.len()) {
                let (j, k) = (r % ny, r / ny);
                let mut c = Span::EMPTY;
                for i in spans[r].range(nx - 1) {
                    let v = small::stabilised(cells, volume, targets, dust, (i, j, k));
                    if store(&mut stable[nx * (r - lo) + i], v) {
                        c.add(i);
                    }
                }
                changed[r - lo] = c;
            }
        };
        crate::fork_join::join(|| run(0, stable, changed), || run(at, stable_b, changed_b));
    }
}

/// The entries of `units` (rows or strips, in their order) that fall in the half of the box
/// starting at unit `lo` with `len` units: each half of a split loop visits only its own.
fn in_half(units: &[u32], lo: usize, len: usize) -> impl Iterator<Item = usize> + '_ {
    units
        .iter()
        .map(|&u| u as usize)
        .filter(move |&u| u >= lo && u - lo < len)
}

/// What the combination of the layers reads.
struct Combine<'a> {
    background: Phase,
    params: SmallCellParams,
    layers: &'a [(SurfaceFractions, Phase)],
}

impl Combine<'_> {
    /// The combination of the layers' values `value(layer)` over the background, and whether it
    /// is approximate (a fractional layer over a fractional value).
    #[inline]
    fn value(&self, value: impl Fn(&SurfaceFractions) -> f64) -> (f64, bool) {
        let mut phi = self.background.fraction();
        let mut approx = false;
        for (l, phase) in self.layers {
            let f = value(l);
            approx |= (phi > 0.0 && phi < 1.0) && (f > 0.0 && f < 1.0);
            phi = match phase {
                Phase::Fluid => phi.max(f),
                Phase::Solid => (phi - f).max(0.0),
            };
        }
        (phi, approx)
    }
}

/// The layer `k` that splits `units` (`width` a layer; rows or strips) into two halves of about
/// equal work, a unit's work taken as its span's length; `work` holds a layer's sum (scratch, at
/// least one entry a layer).
fn split_layer(units: &[u32], width: usize, spans: &[Span], work: &mut [u64]) -> usize {
    work.fill(0);
    for &u in units {
        let s = spans[u as usize];
        let len = if s.is_empty() { 0 } else { s.hi - s.lo + 1 };
        work[u as usize / width] += u64::from(len) + 1;
    }
    let total: u64 = work.iter().sum();
    let mut below = 0;
    for (k, &w) in work.iter().enumerate() {
        if 2 * below >= total {
            return k;
        }
        below += w;
    }
    work.len()
}

/// `v` with rounding removed: below `eps` 0, above `1 - eps` 1 (the stabilised faces' rule).
#[inline]
pub(crate) fn round_off(v: f64, eps: f64) -> f64 {
    if v < eps {
        0.0
    } else if v > 1.0 - eps {
        1.0
    } else {
        v
    }
}

#[inline]
fn store(slot: &mut f64, v: f64) -> bool {
    if slot.to_bits() != v.to_bits() {
        *slot = v;
        true
    } else {
        false
    }
}

fn mark(u: usize, flags: &mut [bool], list: &mut Vec<u32>) {
    if !flags[u] {
        flags[u] = true;
        list.push(u as u32);
    }
}

/// Sets `bits` on row `r`, listing it for each stage bit newly set.
fn flag(flags: &mut [u8], lists: &mut [Vec<u32>; 4], r: usize, bits: u8) {
    for (s, bit) in [COMBINE, INTERFACE, DECIDE, STABILISE]
        .into_iter()
        .enumerate()
    {
        if bits & bit != 0 && flags[r] & bit == 0 {
            lists[s].push(r as u32);
        }
    }
    flags[r] |= bits;
}

fn add(sum: &mut FractionStats, s: FractionStats) {
    sum.moved_vertices += s.moved_vertices;
    sum.moved_triangles += s.moved_triangles;
    sum.rows += s.rows;
    sum.strips += s.strips;
    sum.changed_cells += s.changed_cells;
    sum.changed_faces += s.changed_faces;
}
