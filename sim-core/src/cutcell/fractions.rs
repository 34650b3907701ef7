//! The exact fractions of one closed surface on a box of cells, recomputed row by row.
//!
//! Three kinds of work unit, each a pure function of the positions of the triangles that can
//! reach it, visited in triangle order (so an incremental update equals a full recomputation bit
//! for bit):
//! - the **row** `(j, k)` (the prism `y in (j, j+1]`, `z in (k, k+1]`, all x): its cells' volumes,
//!   interface area vectors and the x-faces between them;
//! - the **z-strip** `(j, k)` (plane `z = k`, `y in (j, j+1]`): the z-faces `(i, j, k)`;
//! - the **y-strip** `(j, k)` (plane `y = j`, `z in (k, k+1]`): the y-faces `(i, j, k)`.
//!
//! In a row, each triangle is clipped to the prism and cut along x into cells. With outward
//! normals `n`, the divergence theorem for the field `(x - x_i, 0, 0)` on the part of cell `i`
//! inside the surface gives its volume as the pieces' `integral of (x - x_i) n_x dA` plus `h` times
//! the inside area of the cell's right face; for the field `(1, 0, 0)` on the part of the row left
//! of a face, that face's inside area is minus the pieces' `integral of n_x dA` left of it (the
//! pieces left of the box included). A strip is the same one dimension lower: the triangles'
//! cross-section with the plane, clipped to the strip, gives each face as `integral of (x - x_i)
//! n_x dl` plus `h` times the inside length of the face's right edge, that length being minus the
//! cross-section's `integral of n_x dl` left of it. Everything is exact for the polygonal surface
//! up to rounding; the tie rule of [`super::clip`] decides what lies exactly on a grid plane.
//!
//! The units of an update are computed in two halves, the layers `k` below a split and the rest,
//! on the two cores: a unit writes only its own cells and faces, so which thread computes it
//! changes nothing.

use super::clip::{self, cell_of, Clipper, Segment, P3};
use super::{CutCellError, Orientation};
use crate::scene::voxelize::VoxelBox;

/// Rows (and planes) per side of a bin of the triangle index.
const BIN: usize = 4;

// A triangle in an update, as bits of `tri_update`: a vertex moved, its reach changed, its bins
// changed.
const MOVED: u8 = 1;
const REACH_CHANGED: u8 = 2;
const REBIN: u8 = 4;

/// How far from the box a vertex may lie, in cells (beyond, positions are refused: the clipping
/// arithmetic stays far from overflow and its rounding far below the cells' size).
pub const MAX_CELLS_AWAY: f64 = 1e6;

/// Per triangle, per axis, the cells `ceil(min) - 1 ..= ceil(max) - 1` its box reaches, clamped
/// to `[-1, n]`; the planes it straddles are `lo + 1 ..= hi`.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Reach {
    lo: [i32; 3],
    hi: [i32; 3],
}

impl Reach {
    const NONE: Reach = Reach {
        lo: [0; 3],
        hi: [-1; 3],
    };
}

/// The positions along a row or strip where values changed, inclusive (`lo > hi`: none). In a
/// row, position `i` is cell `i` and x-face `i` (`0 ..= nx`); in a strip, face `i`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Span {
    pub lo: u32,
    pub hi: u32,
}

impl Span {
    pub const EMPTY: Span = Span {
        lo: u32::MAX,
        hi: 0,
    };

    /// Positions `lo ..= hi`.
    #[inline]
    pub fn new(lo: usize, hi: usize) -> Span {
        Span {
            lo: lo as u32,
            hi: hi as u32,
        }
    }
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.lo > self.hi
    }
    /// Adds position `p`.
    #[inline]
    pub fn add(&mut self, p: usize) {
        self.lo = self.lo.min(p as u32);
        self.hi = self.hi.max(p as u32);
    }
    /// Adds every position of `other`.
    #[inline]
    pub fn join(&mut self, other: Span) {
        self.lo = self.lo.min(other.lo);
        self.hi = self.hi.max(other.hi);
    }
    /// The positions `lo ..= hi` as a range, `hi` capped at `max` (empty when none).
    #[inline]
    pub fn range(&self, max: usize) -> std::ops::Range<usize> {
        if self.is_empty() {
            0..0
        } else {
            self.lo as usize..(self.hi as usize).min(max) + 1
        }
    }
}

/// What one call did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FractionStats {
    /// Vertices taken at new positions.
    pub moved_vertices: usize,
    /// Triangles with a moved vertex.
    pub moved_triangles: usize,
    /// Rows recomputed.
    pub rows: usize,
    /// Strips (y and z) recomputed.
    pub strips: usize,
    /// Cells whose volume fraction or interface changed.
    pub changed_cells: usize,
    /// Faces whose open fraction changed.
    pub changed_faces: usize,
}

/// The exact fractions of the region enclosed by one closed, consistently oriented triangle
/// surface: per cell the enclosed volume fraction and interface area vector, per MAC face the
/// enclosed area fraction; incremental in the vertices' moves.
#[derive(Debug, Clone)]
pub struct SurfaceFractions {
    name: String,
    cells: VoxelBox,
    triangles: Vec<[u32; 3]>,
    /// +1 for outward normals, -1 for inward.
    sign: f64,
    /// Held positions in cell units (relative to the box's corner), and the metres they came from.
    pos: Vec<P3>,
    pos_m: Vec<[f32; 3]>,
    initialised: bool,
    reach: Vec<Reach>,
    bins_dims: [usize; 2],
    /// Per bin of `BIN x BIN` (row or plane) indices `(j, k)`, the triangles reaching it, sorted.
    bins: Vec<Vec<u32>>,
    volume: Vec<f64>,
    interface: Vec<[f64; 3]>,
    faces: [Vec<f64>; 3],
    row_dirty: Vec<bool>,
    dirty_rows: Vec<u32>,
    changed_rows: Vec<u32>,
    /// Per changed row, where it changed.
    changed_row_spans: Vec<Span>,
    /// The same for the strips: `[y-strips, z-strips]`.
    strip_dirty: [Vec<bool>; 2],
    dirty_strips: [Vec<u32>; 2],
    changed_strips: [Vec<u32>; 2],
    changed_strip_spans: [Vec<Span>; 2],
    // Scratch, reused.
    moved: Vec<bool>,
    /// Per triangle, during an update: [`MOVED`], [`REACH_CHANGED`], [`REBIN`].
    tri_update: Vec<u8>,
    /// The rows' sums, per cell (the rows are summed together, triangle by triangle): the
    /// pieces' x-moments and area vectors, and per row the x-area of the pieces left of the box.
    row_moment: Vec<f64>,
    row_area: Vec<[f64; 3]>,
    row_left: Vec<f64>,
    /// Per row, y-strip and z-strip, what its last recomputation changed (read in the order the
    /// units were marked).
    results: [Vec<Changed>; 3],
    /// Per layer `k`, the work of its dirty units (for the split of the units in two halves).
    layer_work: Vec<u64>,
    /// The two halves' scratch.
    scratch: [Scratch; 2],
}

#[inline]
fn unit(x: f64) -> f64 {
    // NaN to 0 (it cannot arise from validated positions, but a fraction is never NaN).
    if x > 0.0 {
        x.min(1.0)
    } else {
        0.0
    }
}

#[inline]
fn store(slot: &mut f64, value: f64) -> usize {
    if slot.to_bits() != value.to_bits() {
        *slot = value;
        1
    } else {
        0
    }
}

impl SurfaceFractions {
    /// The fractions of the surface `triangles` (indices into the positions later passed, which
    /// hold `vertex_count` vertices) on `cells`; `name` appears in errors. The surface must be
    /// closed and consistently oriented (every directed edge `a -> b` matched by a `b -> a`);
    /// `orientation` says whether its normals point out of the enclosed region or into it.
    /// Nothing is computed until the first [`SurfaceFractions::update`] or
    /// [`SurfaceFractions::full`].
    pub fn new(
        name: &str,
        cells: VoxelBox,
        triangles: Vec<[u32; 3]>,
        vertex_count: usize,
        orientation: Orientation,
    ) -> Result<Self, CutCellError> {
        super::check_box(&cells)?;
        super::mesh::check_closed(&triangles, vertex_count).map_err(|what| {
            CutCellError::Surface {
                surface: name.to_string(),
                what,
            }
        })?;
        let [nx, ny, nz] = cells.dims;
        let n = cells.cell_count();
        let bins_dims = [(ny + 1).div_ceil(BIN), (nz + 1).div_ceil(BIN)];
        let t = triangles.len();
        Ok(Self {
            name: name.to_string(),
            cells,
            sign: match orientation {
                Orientation::Outward => 1.0,
                Orientation::Inward => -1.0,
            },
            pos: vec![[0.0; 3]; vertex_count],
            pos_m: vec![[0.0; 3]; vertex_count],
            initialised: false,
            reach: vec![Reach::NONE; t],
            bins_dims,
            bins: vec![Vec::new(); bins_dims[0] * bins_dims[1]],
            volume: vec![0.0; n],
            interface: vec![[0.0; 3]; n],
            faces: [
                vec![0.0; (nx + 1) * ny * nz],
                vec![0.0; nx * (ny + 1) * nz],
                vec![0.0; nx * ny * (nz + 1)],
            ],
            row_dirty: vec![false; ny * nz],
            dirty_rows: Vec::with_capacity(ny * nz),
            changed_rows: Vec::with_capacity(ny * nz),
            changed_row_spans: Vec::with_capacity(ny * nz),
            strip_dirty: [vec![false; (ny + 1) * nz], vec![false; ny * (nz + 1)]],
            dirty_strips: [
                Vec::with_capacity((ny + 1) * nz),
                Vec::with_capacity(ny * (nz + 1)),
            ],
            changed_strips: [
                Vec::with_capacity((ny + 1) * nz),
                Vec::with_capacity(ny * (nz + 1)),
            ],
            changed_strip_spans: [
                Vec::with_capacity((ny + 1) * nz),
                Vec::with_capacity(ny * (nz + 1)),
            ],
            moved: vec![false; vertex_count],
            tri_update: vec![0; t],
            row_moment: vec![0.0; n],
            row_area: vec![[0.0; 3]; n],
            row_left: vec![0.0; ny * nz],
            results: [
                vec![Changed::NONE; ny * nz],
                vec![Changed::NONE; (ny + 1) * nz],
                vec![Changed::NONE; ny * (nz + 1)],
            ],
            layer_work: vec![0; nz + 1],
            scratch: [Scratch::new(nx, t), Scratch::new(nx, t)],
            triangles,
        })
    }

    /// The surface's name.
    pub fn name(&self) -> &str {
        &self.name
    }
    /// The box.
    pub fn cells(&self) -> &VoxelBox {
        &self.cells
    }
    /// The triangles.
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }
    /// The positions (m) the fractions were computed from.
    pub fn positions_m(&self) -> &[[f32; 3]] {
        &self.pos_m
    }
    /// Per cell (x fastest), the fraction of its volume the surface encloses, in `[0, 1]`.
    pub fn volume_fractions(&self) -> &[f64] {
        &self.volume
    }
    /// Per cell, the area vector of the surface inside it, `integral of n dA / h^2` with `n` the
    /// normal pointing out of the enclosed region (for every cell, the enclosed areas of its
    /// faces and this close: `sum over faces of +-A_f e_f + S = 0`).
    pub fn interface_areas(&self) -> &[[f64; 3]] {
        &self.interface
    }
    /// The enclosed area fractions of the faces normal to `axis` (0, 1, 2): face `(i, j, k)` lies
    /// between cells `(i-1, j, k)` and `(i, j, k)` along the axis (`dims[axis] + 1` faces along it,
    /// the box's boundary faces included), x fastest.
    pub fn face_fractions(&self, axis: usize) -> &[f64] {
        &self.faces[axis]
    }
    /// The rows `j + ny k` whose cells' volumes, interfaces or x-faces the last call changed.
    pub fn changed_rows(&self) -> &[u32] {
        &self.changed_rows
    }
    /// Per row of [`Self::changed_rows`], where in it the values changed.
    pub(crate) fn changed_row_spans(&self) -> &[Span] {
        &self.changed_row_spans
    }
    /// Per strip of [`Self::changed_ystrips`] (`s = 0`) or [`Self::changed_zstrips`] (`s = 1`),
    /// where in it the faces changed.
    pub(crate) fn changed_strip_spans(&self, s: usize) -> &[Span] {
        &self.changed_strip_spans[s]
    }
    /// The y-strips `j + (ny + 1) k` (y-faces `(., j, k)`) the last call changed.
    pub fn changed_ystrips(&self) -> &[u32] {
        &self.changed_strips[0]
    }
    /// The z-strips `j + ny k` (z-faces `(., j, k)`) the last call changed.
    pub fn changed_zstrips(&self) -> &[u32] {
        &self.changed_strips[1]
    }

    /// The held positions in cell units (relative to the box's corner).
    pub(crate) fn cell_positions(&self) -> &[P3] {
        &self.pos
    }
    /// Which way the normals point.
    pub(crate) fn orientation(&self) -> Orientation {
        if self.sign > 0.0 {
            Orientation::Outward
        } else {
            Orientation::Inward
        }
    }

    fn to_cells(&self, p: [f32; 3]) -> P3 {
        let h = self.cells.spacing_m;
        std::array::from_fn(|a| (p[a] as f64 - self.cells.origin_m[a]) / h)
    }

    /// Refuses positions that are the wrong number, not finite or implausibly far.
    pub(crate) fn check_positions(&self, positions_m: &[[f32; 3]]) -> Result<(), CutCellError> {
        if positions_m.len() != self.pos.len() {
            return Err(CutCellError::Surface {
                surface: self.name.clone(),
                what: format!(
                    "{} positions for {} vertices",
                    positions_m.len(),
                    self.pos.len()
                ),
            });
        }
        for (v, p) in positions_m.iter().enumerate() {
            let c = self.to_cells(*p);
            let far = (0..3).any(|a| {
                !(c[a] >= -MAX_CELLS_AWAY && c[a] <= self.cells.dims[a] as f64 + MAX_CELLS_AWAY)
            });
            if far {
                return Err(CutCellError::Vertex {
                    surface: self.name.clone(),
                    vertex: v,
                    position_m: *p,
                    what: if p.iter().all(|x| x.is_finite()) {
                        format!("more than {MAX_CELLS_AWAY:e} cells from the box")
                    } else {
                        "not a finite position".to_string()
                    },
                });
            }
        }
        Ok(())
    }

    fn reach_of(&self, t: usize) -> Reach {
        let v = self.triangles[t].map(|i| self.pos[i as usize]);
        let mut r = Reach::NONE;
        for a in 0..3 {
            let lo = v[0][a].min(v[1][a]).min(v[2][a]);
            let hi = v[0][a].max(v[1][a]).max(v[2][a]);
            // A triangle in a grid plane with the region above also reaches the cell above
            // (where it belongs) and the plane (whose face it closes).
            let hi = if clip::flat_below_region(&v, a, self.sign).is_some() {
                hi + 1.0
            } else {
                hi
            };
            let n = self.cells.dims[a] as f64;
            r.lo[a] = cell_of(lo).clamp(-1.0, n) as i32;
            r.hi[a] = cell_of(hi).clamp(-1.0, n) as i32;
        }
        r
    }

    /// The bins a reach covers: rows and planes `lo ..= hi` in y and z; none when the triangle
    /// lies right of the box or beyond it in y or z.
    fn bin_span(&self, r: &Reach) -> Option<([usize; 2], [usize; 2])> {
        let [nx, ny, nz] = self.cells.dims.map(|d| d as i32);
        let j0 = r.lo[1].max(0);
        let j1 = r.hi[1].min(ny);
        let k0 = r.lo[2].max(0);
        let k1 = r.hi[2].min(nz);
        if r.lo[0] >= nx || j0 > j1 || k0 > k1 {
            return None;
        }
        let b = BIN as i32;
        Some((
            [(j0 / b) as usize, (k0 / b) as usize],
            [(j1 / b) as usize, (k1 / b) as usize],
        ))
    }

    fn unbin(&mut self, t: usize) {
        if let Some((lo, hi)) = self.bin_span(&self.reach[t]) {
            for bk in lo[1]..=hi[1] {
                for bj in lo[0]..=hi[0] {
                    let bin = &mut self.bins[bj + self.bins_dims[0] * bk];
                    if let Ok(at) = bin.binary_search(&(t as u32)) {
                        bin.remove(at);
                    }
                }
            }
        }
    }

    fn bin(&mut self, t: usize) {
        if let Some((lo, hi)) = self.bin_span(&self.reach[t]) {
            for bk in lo[1]..=hi[1] {
                for bj in lo[0]..=hi[0] {
                    let bin = &mut self.bins[bj + self.bins_dims[0] * bk];
                    if let Err(at) = bin.binary_search(&(t as u32)) {
                        bin.insert(at, t as u32);
                    }
                }
            }
        }
    }

    /// Marks every unit a triangle of reach `r` can touch.
    fn mark(&mut self, r: Reach) {
        let [nx, ny, nz] = self.cells.dims.map(|d| d as i32);
        if r.lo[0] >= nx {
            return;
        }
        let rows_j = (r.lo[1].max(0), r.hi[1].min(ny - 1));
        let rows_k = (r.lo[2].max(0), r.hi[2].min(nz - 1));
        let planes_j = ((r.lo[1] + 1).max(0), r.hi[1].min(ny));
        let planes_k = ((r.lo[2] + 1).max(0), r.hi[2].min(nz));
        let ny = ny as usize;
        for k in rows_k.0..=rows_k.1 {
            for j in rows_j.0..=rows_j.1 {
                mark_unit(
                    j as usize + ny * k as usize,
                    &mut self.row_dirty,
                    &mut self.dirty_rows,
                );
            }
            for j in planes_j.0..=planes_j.1 {
                mark_unit(
                    j as usize + (ny + 1) * k as usize,
                    &mut self.strip_dirty[0],
                    &mut self.dirty_strips[0],
                );
            }
        }
        for k in planes_k.0..=planes_k.1 {
            for j in rows_j.0..=rows_j.1 {
                mark_unit(
                    j as usize + ny * k as usize,
                    &mut self.strip_dirty[1],
                    &mut self.dirty_strips[1],
                );
            }
        }
    }

    /// Computes everything from scratch at `positions_m` (one per vertex).
    pub fn full(&mut self, positions_m: &[[f32; 3]]) -> Result<FractionStats, CutCellError> {
        self.check_positions(positions_m)?;
        for (v, p) in positions_m.iter().enumerate() {
            self.pos[v] = self.to_cells(*p);
            self.pos_m[v] = *p;
        }
        for bin in &mut self.bins {
            bin.clear();
        }
        for t in 0..self.triangles.len() {
            self.reach[t] = self.reach_of(t);
            self.bin(t);
        }
        // Room for the bins to grow as the surface moves, so updates do not allocate.
        for bin in &mut self.bins {
            let more = bin.len() + 8;
            bin.reserve(more);
        }
        self.initialised = true;
        let [ystrips, zstrips] = &mut self.strip_dirty;
        let [ylist, zlist] = &mut self.dirty_strips;
        for (flags, list) in [
            (&mut self.row_dirty, &mut self.dirty_rows),
            (ystrips, ylist),
            (zstrips, zlist),
        ] {
            let units = flags.len();
            list.clear();
            for (u, f) in flags.iter_mut().enumerate().take(units) {
                *f = true;
                list.push(u as u32);
            }
        }
        let mut stats = self.process();
        stats.moved_vertices = positions_m.len();
        stats.moved_triangles = self.triangles.len();
        Ok(stats)
    }

    /// Takes the new position of every vertex that moved more than `threshold_m` from its held
    /// position (any move when `threshold_m <= 0`) and recomputes the units the moved triangles'
    /// old and new reaches cover. The first call computes everything. Positions that are not
    /// finite or lie more than [`MAX_CELLS_AWAY`] cells from the box are refused (nothing changes).
    pub fn update(
        &mut self,
        positions_m: &[[f32; 3]],
        threshold_m: f64,
    ) -> Result<FractionStats, CutCellError> {
        if !self.initialised {
            return self.full(positions_m);
        }
        self.check_positions(positions_m)?;
        let t2 = threshold_m * threshold_m;
        let mut moved_vertices = 0;
        for (v, p) in positions_m.iter().enumerate() {
            let q = self.pos_m[v];
            let d2: f64 = (0..3).map(|a| (p[a] as f64 - q[a] as f64).powi(2)).sum();
            let m = if threshold_m > 0.0 { d2 > t2 } else { *p != q };
            self.moved[v] = m;
            moved_vertices += m as usize;
        }
        self.changed_rows.clear();
        self.changed_row_spans.clear();
        self.changed_strips.iter_mut().for_each(Vec::clear);
        self.changed_strip_spans.iter_mut().for_each(Vec::clear);
        if moved_vertices == 0 {
            return Ok(FractionStats::default());
        }
        let mut moved_triangles = 0;
        for t in 0..self.triangles.len() {
            let m = self.triangles[t].iter().any(|&v| self.moved[v as usize]);
            self.tri_update[t] = if m { MOVED } else { 0 };
            if m {
                moved_triangles += 1;
                let old = self.reach[t];
                self.mark(old);
            }
        }
        for (v, p) in positions_m.iter().enumerate() {
            if self.moved[v] {
                self.pos[v] = self.to_cells(*p);
                self.pos_m[v] = *p;
            }
        }
        // A moved triangle whose reach is as it was marks nothing new, and one whose bins are as
        // they were stays in them: most of them, the surface moving by a fraction of a cell per
        // frame. Every triangle leaves its old bins before any enters its new ones, so a bin
        // never holds more than before or after the move (its room was reserved).
        for t in 0..self.triangles.len() {
            if self.tri_update[t] & MOVED == 0 {
                continue;
            }
            let new = self.reach_of(t);
            if new != self.reach[t] {
                self.tri_update[t] |= REACH_CHANGED;
                if self.bin_span(&new) != self.bin_span(&self.reach[t]) {
                    self.unbin(t);
                    self.tri_update[t] |= REBIN;
                }
                self.reach[t] = new;
            }
        }
        for t in 0..self.triangles.len() {
            let u = self.tri_update[t];
            if u & REBIN != 0 {
                self.bin(t);
            }
            if u & REACH_CHANGED != 0 {
                let new = self.reach[t];
                self.mark(new);
            }
        }
        let mut stats = self.process();
        stats.moved_vertices = moved_vertices;
        stats.moved_triangles = moved_triangles;
        Ok(stats)
    }

    /// Recomputes the dirty units in two halves of the box on the two cores (the solver's
    /// fork-join: with a rayon pool of one thread, one after the other), then lists what changed.
    fn process(&mut self) -> FractionStats {
        let ks = self.split_layer();
        {
            let shared = Shared {
                cells: &self.cells,
                triangles: &self.triangles,
                sign: self.sign,
                pos: &self.pos,
                reach: &self.reach,
                bins: &self.bins,
                bins_dims: self.bins_dims,
                row_dirty: &self.row_dirty,
                dirty_rows: &self.dirty_rows,
                dirty_strips: [&self.dirty_strips[0], &self.dirty_strips[1]],
            };
            let [results_rows, results_y, results_z] = &mut self.results;
            let [faces_x, faces_y, faces_z] = &mut self.faces;
            let outputs = Outputs {
                k0: 0,
                row_moment: &mut self.row_moment,
                row_area: &mut self.row_area,
                row_left: &mut self.row_left,
                volume: &mut self.volume,
                interface: &mut self.interface,
                faces: [faces_x, faces_y, faces_z],
                results: [results_rows, results_y, results_z],
            };
            let (lower, upper) = outputs.split(ks, self.cells.dims);
            let [a, b] = &mut self.scratch;
            // Every unit reads only the shared state and writes only its own outputs, so the
            // two halves give what one pass over the units would, bit for bit.
            crate::fork_join::join(
                || run_half(&shared, lower, a),
                || run_half(&shared, upper, b),
            );
        }
        // The units' results in the order they were marked, as one pass would list them.
        let mut stats = FractionStats::default();
        self.changed_rows.clear();
        self.changed_row_spans.clear();
        for &u in &self.dirty_rows {
            self.row_dirty[u as usize] = false;
            let c = self.results[0][u as usize];
            if c.cells + c.faces > 0 {
                self.changed_rows.push(u);
                self.changed_row_spans.push(c.span);
            }
            stats.changed_cells += c.cells as usize;
            stats.changed_faces += c.faces as usize;
        }
        stats.rows = self.dirty_rows.len();
        self.dirty_rows.clear();
        // y-strips (`j + (ny + 1) k`), then z-strips (`j + ny k`).
        for s in 0..2 {
            self.changed_strips[s].clear();
            self.changed_strip_spans[s].clear();
            for &u in &self.dirty_strips[s] {
                self.strip_dirty[s][u as usize] = false;
                let c = self.results[s + 1][u as usize];
                if c.faces > 0 {
                    self.changed_strips[s].push(u);
                    self.changed_strip_spans[s].push(c.span);
                }
                stats.changed_faces += c.faces as usize;
            }
            stats.strips += self.dirty_strips[s].len();
            self.dirty_strips[s].clear();
        }
        stats
    }

    /// The layer `k` that splits the dirty units into two halves of about equal work: the layers
    /// below it (their rows and y-strips, the z-strips on their planes) and the rest. A unit's work
    /// is taken as the triangles of its bin, those it tests: a count of rows alone would not
    /// weigh a row crossed by many triangles above one crossed by few.
    fn split_layer(&mut self) -> usize {
        let [_, ny, nz] = self.cells.dims;
        let (bins, bins_dims) = (&self.bins, self.bins_dims);
        let bin_len = |j: usize, k: usize| bins[j / BIN + bins_dims[0] * (k / BIN)].len() as u64;
        let work = &mut self.layer_work;
        work.fill(0);
        for (units, width) in [
            (&self.dirty_rows, ny),
            (&self.dirty_strips[0], ny + 1),
            (&self.dirty_strips[1], ny),
        ] {
            for &u in units {
                let (j, k) = (u as usize % width, u as usize / width);
                work[k] += bin_len(j, k);
            }
        }
        let total: u64 = work.iter().sum();
        let mut below = 0;
        for (k, &w) in work.iter().enumerate() {
            if 2 * below >= total {
                return k.min(nz);
            }
            below += w;
        }
        nz
    }
}

/// The surface's state every unit reads, shared by the two halves of
/// [`SurfaceFractions::process`].
struct Shared<'a> {
    cells: &'a VoxelBox,
    triangles: &'a [[u32; 3]],
    sign: f64,
    pos: &'a [P3],
    reach: &'a [Reach],
    bins: &'a [Vec<u32>],
    bins_dims: [usize; 2],
    row_dirty: &'a [bool],
    dirty_rows: &'a [u32],
    dirty_strips: [&'a [u32]; 2],
}

impl Shared<'_> {
    /// The triangles of the bin of `(j, k)` whose reach passes `keep`, in index order, into
    /// `candidates`.
    fn gather(&self, j: usize, k: usize, candidates: &mut Vec<u32>, keep: impl Fn(&Reach) -> bool) {
        candidates.clear();
        let bin = &self.bins[j / BIN + self.bins_dims[0] * (k / BIN)];
        for &t in bin {
            if keep(&self.reach[t as usize]) {
                candidates.push(t);
            }
        }
    }
}

/// What recomputing one unit changed: cells and faces, and where.
#[derive(Debug, Clone, Copy)]
struct Changed {
    cells: u32,
    faces: u32,
    span: Span,
}

impl Changed {
    const NONE: Changed = Changed {
        cells: 0,
        faces: 0,
        span: Span::EMPTY,
    };
}

/// One half's scratch (preallocated, reused every update).
#[derive(Debug, Clone)]
struct Scratch {
    candidates: Vec<u32>,
    acc_moment: Vec<f64>,
    acc_area: Vec<[f64; 3]>,
    clipper: Clipper,
    /// A triangle clipped to a y-slab, clipped on by `clipper` to each row of the slab.
    slab_clipper: Clipper,
}

impl Scratch {
    fn new(nx: usize, triangles: usize) -> Self {
        Self {
            candidates: Vec::with_capacity(triangles),
            acc_moment: vec![0.0; nx],
            acc_area: vec![[0.0; 3]; nx],
            clipper: Clipper::default(),
            slab_clipper: Clipper::default(),
        }
    }
}

/// The outputs of the units of the layers from `k0` on (rows and y-strips `(., k)`, z-strips on
/// planes `k`): each array from the first entry of layer `k0` on.
struct Outputs<'a> {
    k0: usize,
    row_moment: &'a mut [f64],
    row_area: &'a mut [[f64; 3]],
    row_left: &'a mut [f64],
    volume: &'a mut [f64],
    interface: &'a mut [[f64; 3]],
    faces: [&'a mut [f64]; 3],
    /// Per row, y-strip and z-strip, what its recomputation changed.
    results: [&'a mut [Changed]; 3],
}

impl<'a> Outputs<'a> {
    /// The outputs of layers `k0 .. k` and of `k ..` (`k0 <= k <= nz`).
    fn split(self, k: usize, [nx, ny, _]: [usize; 3]) -> (Outputs<'a>, Outputs<'a>) {
        let layers = k - self.k0;
        // Units below `k`: rows and z-strips `j + ny k`, y-strips `j + (ny + 1) k`.
        let (rows, ystrips) = (ny * layers, (ny + 1) * layers);
        let (row_moment, row_moment_b) = self.row_moment.split_at_mut(nx * rows);
        let (row_area, row_area_b) = self.row_area.split_at_mut(nx * rows);
        let (row_left, row_left_b) = self.row_left.split_at_mut(rows);
        let (volume, volume_b) = self.volume.split_at_mut(nx * rows);
        let (interface, interface_b) = self.interface.split_at_mut(nx * rows);
        let [fx, fy, fz] = self.faces;
        let (fx, fx_b) = fx.split_at_mut((nx + 1) * rows);
        let (fy, fy_b) = fy.split_at_mut(nx * ystrips);
        let (fz, fz_b) = fz.split_at_mut(nx * rows);
        let [rr, ry, rz] = self.results;
        let (rr, rr_b) = rr.split_at_mut(rows);
        let (ry, ry_b) = ry.split_at_mut(ystrips);
        let (rz, rz_b) = rz.split_at_mut(rows);
        (
            Outputs {
                k0: self.k0,
                row_moment,
                row_area,
                row_left,
                volume,
                interface,
                faces: [fx, fy, fz],
                results: [rr, ry, rz],
            },
            Outputs {
                k0: k,
                row_moment: row_moment_b,
                row_area: row_area_b,
                row_left: row_left_b,
                volume: volume_b,
                interface: interface_b,
                faces: [fx_b, fy_b, fz_b],
                results: [rr_b, ry_b, rz_b],
            },
        )
    }
}

/// Recomputes the dirty units whose outputs `out` holds: the rows' sums, the rows, the strips.
fn run_half(sh: &Shared, mut out: Outputs, scratch: &mut Scratch) {
    let [_, ny, _] = sh.cells.dims;
    sum_rows(sh, &mut out, scratch);
    let r0 = ny * out.k0;
    for &u in sh.dirty_rows {
        let u = u as usize;
        if u < r0 || u - r0 >= out.results[0].len() {
            continue;
        }
        out.results[0][u - r0] = process_row(sh, &mut out, u % ny, u / ny);
    }
    for s in 0..2 {
        let width = if s == 0 { ny + 1 } else { ny };
        let u0 = width * out.k0;
        for &u in sh.dirty_strips[s] {
            let u = u as usize;
            if u < u0 || u - u0 >= out.results[s + 1].len() {
                continue;
            }
            out.results[s + 1][u - u0] =
                process_strip(sh, &mut out, scratch, s + 1, u % width, u / width);
        }
    }
}

/// Sums the pieces of every triangle in the dirty rows of `out` into their rows' sums. The
/// triangles go in index order, each clipped to a y-slab once and then to the slab's dirty rows,
/// so every row gets the pieces and sums a row alone would, in the same order.
fn sum_rows(sh: &Shared, out: &mut Outputs, scratch: &mut Scratch) {
    let [nx, ny, nz] = sh.cells.dims;
    let r0 = ny * out.k0;
    let rows = out.row_left.len();
    for &u in sh.dirty_rows {
        let u = u as usize;
        if u < r0 || u - r0 >= rows {
            continue;
        }
        let l = u - r0;
        out.row_moment[nx * l..nx * (l + 1)].fill(0.0);
        out.row_area[nx * l..nx * (l + 1)].fill([0.0; 3]);
        out.row_left[l] = 0.0;
    }
    if rows == 0 {
        return;
    }
    // This half's layers.
    let (klo, khi) = (out.k0 as i32, (out.k0 + rows / ny) as i32 - 1);
    let sign = sh.sign;
    let (nxi, nyi, nzi) = (nx as i32, ny as i32, nz as i32);
    for t in 0..sh.triangles.len() {
        let r = sh.reach[t];
        // A row's triangles: those whose reach covers it and starts left of the box's end.
        let (j0, j1) = (r.lo[1].max(0), r.hi[1].min(nyi - 1));
        let (k0, k1) = (r.lo[2].max(0).max(klo), r.hi[2].min(nzi - 1).min(khi));
        if r.lo[0] >= nxi || j0 > j1 || k0 > k1 {
            continue;
        }
        let dirty = |j: i32| (k0..=k1).any(|k| sh.row_dirty[j as usize + ny * k as usize]);
        if !(j0..=j1).any(dirty) {
            continue;
        }
        let v = sh.triangles[t].map(|i| sh.pos[i as usize]);
        // A triangle in a y- or z-plane with the region above belongs to the row above.
        let flat_y = clip::flat_below_region(&v, 1, sign);
        let flat_z = clip::flat_below_region(&v, 2, sign);
        let forced = clip::flat_below_region(&v, 0, sign);
        for j in j0..=j1 {
            let y0 = j as f64;
            if flat_y.is_some_and(|m| m != y0) || !dirty(j) {
                continue;
            }
            let slab = &mut scratch.slab_clipper;
            slab.start(v[0], v[1], v[2]);
            if flat_y.is_none() {
                slab.clip_slab(1, y0, y0 + 1.0);
            }
            if slab.poly().n == 0 {
                continue;
            }
            for k in k0..=k1 {
                let z0 = k as f64;
                let row = j as usize + ny * k as usize;
                if !sh.row_dirty[row] || flat_z.is_some_and(|m| m != z0) {
                    continue;
                }
                let clipper = &mut scratch.clipper;
                clipper.start_from(scratch.slab_clipper.poly());
                if flat_z.is_none() {
                    clipper.clip_slab(2, z0, z0 + 1.0);
                }
                if clipper.poly().n == 0 {
                    continue;
                }
                let l = row - r0;
                let base = nx * l;
                let left = &mut out.row_left[l];
                let (area, moments) = (&mut *out.row_area, &mut *out.row_moment);
                clipper.split_along_x(nx, forced, |c, piece| {
                    if piece.n < 3 {
                        return;
                    }
                    if c < 0 {
                        *left += piece.area_and_x_moment(0.0).0[0];
                        return;
                    }
                    let (s, moment) = piece.area_and_x_moment(c as f64);
                    let a = &mut area[base + c as usize];
                    a[0] += s[0];
                    a[1] += s[1];
                    a[2] += s[2];
                    moments[base + c as usize] += moment;
                });
            }
        }
    }
}

/// Stores row `(j, k)` of `out` from its sums ([`sum_rows`]); how many cells and faces changed,
/// and where.
fn process_row(sh: &Shared, out: &mut Outputs, j: usize, k: usize) -> Changed {
    let [nx, ny, _] = sh.cells.dims;
    let l = j + ny * k - ny * out.k0;
    let left = out.row_left[l];
    let sign = sh.sign;
    let base = nx * l;
    let fbase = (nx + 1) * l;
    let (mut cells, mut faces) = (0, 0);
    let fx = &mut *out.faces[0];
    // The face at x = 0: what the pieces left of the box leave open.
    let mut span = Span::EMPTY;
    let mut face = -left;
    if store(&mut fx[fbase], unit(sign * face)) > 0 {
        faces += 1;
        span.add(0);
    }
    for i in 0..nx {
        let s = out.row_area[base + i];
        let next = face - s[0];
        let volume = out.row_moment[base + i] + next;
        face = next;
        if store(&mut fx[fbase + i + 1], unit(sign * next)) > 0 {
            faces += 1;
            span.add(i + 1);
        }
        let mut changed = store(&mut out.volume[base + i], unit(sign * volume));
        let s = s.map(|x| sign * x);
        let slot = &mut out.interface[base + i];
        if slot.map(f64::to_bits) != s.map(f64::to_bits) {
            *slot = s;
            changed = 1;
        }
        if changed > 0 {
            cells += 1;
            span.add(i);
        }
    }
    Changed { cells, faces, span }
}

/// Recomputes the strip `(a, b)` normal to `axis` into `out`: for axis 1 the y-strip on plane
/// `y = a` across `z in (b, b+1]`, for axis 2 the z-strip on plane `z = b` across `y in (a, a+1]`;
/// how many faces changed, and where.
fn process_strip(
    sh: &Shared,
    out: &mut Outputs,
    scratch: &mut Scratch,
    axis: usize,
    a: usize,
    b: usize,
) -> Changed {
    let [nx, ny, _] = sh.cells.dims;
    let nxi = nx as i32;
    // (plane, the strip's row index across it, the axis across).
    let (plane, across, across_axis) = if axis == 1 { (a, b, 2) } else { (b, a, 1) };
    let (pi, ci) = (plane as i32, across as i32);
    let Scratch {
        candidates,
        acc_moment,
        acc_area,
        clipper,
        ..
    } = scratch;
    // The bin of the unit's (j, k).
    sh.gather(a, b, candidates, |r| {
        r.lo[axis] < pi
            && pi <= r.hi[axis]
            && r.lo[across_axis] <= ci
            && ci <= r.hi[across_axis]
            && r.lo[0] < nxi
    });
    acc_moment.fill(0.0);
    // Per face: `acc_area[i][0]`, the x-component of the outward normal times length of the
    // cross-section; `acc_area[i][1]`, the (raw, negative outward) area of the triangles in
    // the plane with the region above, which close the face (the tie rule's exception).
    for s in acc_area.iter_mut() {
        s[0] = 0.0;
        s[1] = 0.0;
    }
    let mut left = 0.0;
    let m = plane as f64;
    let lo = across as f64;
    let nxf = nx as f64;
    // In the plane's coordinates (axis + 1, axis + 2) the region lies left of a section
    // `p -> q`: its outward normal times length is (d_(axis+2), -d_(axis+1)). The x-component:
    // plane z (x, y): d_y; plane y (z, x): -d_z.
    let nx_dl = |s: &Segment| -> f64 {
        if axis == 2 {
            s.q[1] - s.p[1]
        } else {
            -(s.q[2] - s.p[2])
        }
    };
    for &t in candidates.iter() {
        let ids = sh.triangles[t as usize];
        let v = ids.map(|i| sh.pos[i as usize]);
        if clip::flat_below_region(&v, axis, sh.sign) == Some(m) {
            clipper.start(v[0], v[1], v[2]);
            clipper.clip_slab(across_axis, lo, lo + 1.0);
            if clipper.poly().n < 3 {
                continue;
            }
            clipper.split_along_x(nx, None, |c, piece| {
                if c >= 0 && piece.n >= 3 {
                    acc_area[c as usize][1] += piece.area_and_x_moment(0.0).0[axis];
                }
            });
            continue;
        }
        let Some(seg) = clip::plane_section(&ids, &v, axis, m) else {
            continue;
        };
        let Some(seg) = clip::clip_segment(&seg, across_axis, lo, lo + 1.0) else {
            continue;
        };
        let (xa, xb) = (seg.p[0].min(seg.q[0]), seg.p[0].max(seg.q[0]));
        let c0 = cell_of(xa);
        let c1 = cell_of(xb);
        if c0 >= nxf {
            continue;
        }
        if c1 < 0.0 {
            left += nx_dl(&seg);
            continue;
        }
        if c0 == c1 {
            let l = nx_dl(&seg);
            acc_area[c0 as usize][0] += l;
            acc_moment[c0 as usize] += l * (0.5 * (seg.p[0] + seg.q[0]) - c0);
            continue;
        }
        if c0 < 0.0 {
            if let Some(piece) = clip::clip_segment(&seg, 0, f64::NEG_INFINITY, 0.0) {
                left += nx_dl(&piece);
            }
        }
        let mut c = c0.max(0.0);
        while c <= c1 && c < nxf {
            if let Some(piece) = clip::clip_segment(&seg, 0, c, c + 1.0) {
                let l = nx_dl(&piece);
                acc_area[c as usize][0] += l;
                acc_moment[c as usize] += l * (0.5 * (piece.p[0] + piece.q[0]) - c);
            }
            c += 1.0;
        }
    }
    let sign = sh.sign;
    // The strip's index (`j + (ny + 1) k` or `j + ny k`) less the first of this half's.
    let (u, width) = if axis == 1 {
        (plane + (ny + 1) * across, ny + 1)
    } else {
        (across + ny * plane, ny)
    };
    let fbase = nx * (u - width * out.k0);
    let f = &mut *out.faces[axis];
    let mut faces = 0;
    let mut span = Span::EMPTY;
    let mut edge = -left;
    for i in 0..nx {
        let next = edge - acc_area[i][0];
        let area = acc_moment[i] + next + acc_area[i][1];
        edge = next;
        if store(&mut f[fbase + i], unit(sign * area)) > 0 {
            faces += 1;
            span.add(i);
        }
    }
    Changed {
        cells: 0,
        faces,
        span,
    }
}

fn mark_unit(u: usize, flags: &mut [bool], list: &mut Vec<u32>) {
    if !flags[u] {
        flags[u] = true;
        list.push(u as u32);
    }
}
