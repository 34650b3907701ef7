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
    /// its stabilised volume its own and its neighbours' volumes and targets.
    fn finish(&mut self, stats: &mut CutCellStats) {
        let [nx, ny, nz] = self.cells.dims;
        self.changed_rows.clear();
        // Strips: their faces, and the walls and merges of the cells on both sides.
        for axis in [1, 2] {
            let strips = std::mem::take(&mut self.strips[axis - 1]);
            // y-strip `j + (ny + 1) k`, z-strip `j + ny k`: the rows `row - step` and `row`
            // lie on the two sides of the strip's plane.
            let (width, step) = if axis == 1 { (ny + 1, 1) } else { (ny, ny) };
            for &u in &strips {
                let u = u as usize;
                self.strip_flags[axis - 1][u] = false;
                let span = std::mem::replace(&mut self.strip_span[axis - 1][u], Span::EMPTY);
                let changed = self.combine_faces(axis, nx * u, span);
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
        for &r in &rows {
            let r = r as usize;
            self.row_flags[r] &= !COMBINE;
            let span = std::mem::replace(&mut self.combine_span[r], Span::EMPTY);
            let (faces, volumes, approx) = self.combine_row(r, span);
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
        for &r in &rows {
            let r = r as usize;
            self.row_flags[r] &= !INTERFACE;
            let span = std::mem::replace(&mut self.interface_span[r], Span::EMPTY);
            if self.interface_row(r, span) {
                self.row_flags[r] |= CHANGED;
            }
        }
        self.stage_rows[1] = rows;
        self.stage_rows[1].clear();
        // Merges; a changed target changes the stabilised volumes around it.
        let rows = std::mem::take(&mut self.stage_rows[2]);
        for &r in &rows {
            let r = r as usize;
            self.row_flags[r] &= !DECIDE;
            let span = std::mem::replace(&mut self.decide_span[r], Span::EMPTY);
            let changed = self.decide_row(r, span);
            if !changed.is_empty() {
                self.row_flags[r] |= CHANGED;
                self.spread(r, changed, STABILISE);
            }
        }
        self.stage_rows[2] = rows;
        self.stage_rows[2].clear();
        let rows = std::mem::take(&mut self.stage_rows[3]);
        for &r in &rows {
            let r = r as usize;
            self.row_flags[r] &= !STABILISE;
            let span = std::mem::replace(&mut self.stabilise_span[r], Span::EMPTY);
            if self.stabilise_row(r, span) {
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

    /// Combines the faces normal to `axis` at positions `span` of the `nx` from `base`; where
    /// any changed.
    fn combine_faces(&mut self, axis: usize, base: usize, span: Span) -> Span {
        let nx = self.cells.dims[0];
        let params = self.params;
        let mut changed = Span::EMPTY;
        for i in span.range(nx - 1) {
            let f = base + i;
            let (v, _) = self.combined(|l| l.face_fractions(axis)[f]);
            let a = store(&mut self.faces[axis][f], v);
            let b = store(
                &mut self.stabilised_faces[axis][f],
                params.stabilised_face(v),
            );
            if a | b {
                changed.add(i);
            }
        }
        changed
    }

    /// Combines row `r`'s volumes and `nx + 1` x-faces at positions `span` (cell `i` and face
    /// `i`); where faces and volumes changed, and whether a cell's approximation did.
    fn combine_row(&mut self, r: usize, span: Span) -> (Span, Span, bool) {
        let nx = self.cells.dims[0];
        let params = self.params;
        let mut faces = Span::EMPTY;
        let base = (nx + 1) * r;
        for i in span.range(nx) {
            let f = base + i;
            let (v, _) = self.combined(|l| l.face_fractions(0)[f]);
            let a = store(&mut self.faces[0][f], v);
            let b = store(&mut self.stabilised_faces[0][f], params.stabilised_face(v));
            if a | b {
                faces.add(i);
            }
        }
        let mut volumes = Span::EMPTY;
        let mut approx_changed = false;
        for i in span.range(nx - 1) {
            let n = nx * r + i;
            let (v, approx) = self.combined(|l| l.volume_fractions()[n]);
            if store(&mut self.volume[n], v) {
                volumes.add(i);
            }
            if approx != self.approximate[n] {
                self.approximate[n] = approx;
                if approx {
                    self.approximate_count += 1;
                } else {
                    self.approximate_count -= 1;
                }
                approx_changed = true;
            }
        }
        (faces, volumes, approx_changed)
    }

    /// The combination of the layers' values `value(layer)` over the background, and whether it
    /// is approximate (a fractional layer over a fractional value).
    #[inline]
    fn combined(&self, value: impl Fn(&SurfaceFractions) -> f64) -> (f64, bool) {
        let mut phi = self.background.fraction();
        let mut approx = false;
        for (l, phase) in &self.layers {
            let f = value(l);
            approx |= (phi > 0.0 && phi < 1.0) && (f > 0.0 && f < 1.0);
            phi = match phase {
                Phase::Fluid => phi.max(f),
                Phase::Solid => (phi - f).max(0.0),
            };
        }
        (phi, approx)
    }

    /// The walls of row `r`'s cells `span` from their faces; whether any changed.
    fn interface_row(&mut self, r: usize, span: Span) -> bool {
        let [nx, ny, _] = self.cells.dims;
        let (j, k) = (r % ny, r / ny);
        let (fx, fy, fz) = (&self.faces[0], &self.faces[1], &self.faces[2]);
        let mut changed = false;
        for i in span.range(nx - 1) {
            let x = i + (nx + 1) * r;
            let y = i + nx * (j + (ny + 1) * k);
            let z = i + nx * r;
            let s = [
                -(fx[x + 1] - fx[x]),
                -(fy[y + nx] - fy[y]),
                -(fz[z + nx * ny] - fz[z]),
            ];
            let slot = &mut self.interface[nx * r + i];
            if slot.map(f64::to_bits) != s.map(f64::to_bits) {
                *slot = s;
                changed = true;
            }
        }
        changed
    }

    /// The merge targets of row `r`'s cells `span`, and the counts; where any changed.
    fn decide_row(&mut self, r: usize, span: Span) -> Span {
        let [nx, ny, _] = self.cells.dims;
        let (j, k) = (r % ny, r / ny);
        let theta = self.params.min_volume_fraction;
        let dust = self.params.round_off_fraction;
        let mut changed = Span::EMPTY;
        for i in span.range(nx - 1) {
            let n = nx * r + i;
            let t = small::target(
                &self.cells,
                &self.volume,
                &self.faces,
                theta,
                dust,
                (i, j, k),
            );
            if t != self.targets[n] {
                changed.add(i);
                self.targets[n] = t;
            }
            let v = self.volume[n];
            let state = if !(v > dust && v < theta) {
                NOT_SMALL
            } else if t == NO_TARGET {
                UNMERGED
            } else {
                MERGED
            };
            let old = self.small_state[n];
            if state != old {
                match old {
                    MERGED => self.merged_count -= 1,
                    UNMERGED => self.unmerged_count -= 1,
                    _ => {}
                }
                match state {
                    MERGED => self.merged_count += 1,
                    UNMERGED => self.unmerged_count += 1,
                    _ => {}
                }
                self.small_state[n] = state;
            }
        }
        changed
    }

    /// The stabilised volumes of row `r`'s cells `span`; whether any changed.
    fn stabilise_row(&mut self, r: usize, span: Span) -> bool {
        let [nx, ny, _] = self.cells.dims;
        let (j, k) = (r % ny, r / ny);
        let mut changed = false;
        for i in span.range(nx - 1) {
            let v = small::stabilised(
                &self.cells,
                &self.volume,
                &self.targets,
                self.params.round_off_fraction,
                (i, j, k),
            );
            changed |= store(&mut self.stabilised_volume[nx * r + i], v);
        }
        changed
    }
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
