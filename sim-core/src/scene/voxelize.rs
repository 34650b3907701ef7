//! Conservative, incremental voxelization of a closed triangle surface.
//!
//! A cell is **inside** when its whole box lies inside the surface: its centre is inside (winding
//! number of an x-ray through the centre, non-zero) and no triangle touches the box. A cell that a
//! triangle touches is **band** (the wall; it keeps the lowest index of the triangles touching it,
//! for the wall velocity); every other cell is **outside**.
//!
//! Robustness:
//! - The band test clips each triangle to the closed slab of a row of cells (`j <= y <= j+1`,
//!   `k <= z <= k+1`, widened by [`EPS`] cells) and takes the x-extent of the clipped polygon: exact
//!   up to rounding, widened, so a sliver or a zero-area triangle still marks every cell it touches.
//! - The crossing test evaluates each edge function from the edge's endpoints in vertex-index order
//!   (so two triangles sharing an edge get the same number with opposite signs) with a symbolic
//!   perturbation of the ray point for ties (`p + (eps, eps^2)` in y, z): a ray through an edge or a
//!   vertex crosses a watertight surface exactly once, whatever the rounding.
//! - The crossing's x is a convex combination of the vertices' x with the (same-signed) edge
//!   functions as weights, so a triangle nearly parallel to the ray cannot produce a stray x. Only
//!   band cells can sit within rounding of a crossing, and band cells are never inside.
//!
//! Incremental: the surface is held at its *voxel positions*; [`Voxelizer::update`] moves a vertex's
//! voxel position only when the vertex moved more than a threshold since (to its position, or a lead
//! beyond it along the move: [`Voxelizer::update_leading`]), and re-tests only the rows
//! of cells that the moved triangles' old and new boxes cover. Because every row is computed by the
//! same function of the voxel positions, the result equals [`Voxelizer::full`] of those positions
//! after any sequence of moves (tested). The rows of a call are re-tested in two halves of the box
//! on the two cores, each row by that same function, so the split changes nothing.

use std::time::Instant;

use super::counters::StageCounters;
use crate::rounding::floor;

/// Widening of the band test, in cells.
pub const EPS: f64 = 1e-6;

/// Cell states.
pub mod state {
    /// Outside the surface.
    pub const OUTSIDE: u8 = 0;
    /// Touched by a triangle (the wall band).
    pub const BAND: u8 = 1;
    /// Entirely inside the surface.
    pub const INSIDE: u8 = 2;
}

/// No triangle.
pub const NO_TRIANGLE: u32 = u32::MAX;

pub use super::types::VoxelBox;

/// What one call did.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct VoxelizeStats {
    /// Vertices whose voxel position moved.
    pub moved_vertices: usize,
    /// Triangles re-rasterized.
    pub moved_triangles: usize,
    /// Rows of cells re-tested.
    pub rows: usize,
    /// Cells whose state changed.
    pub changed_cells: usize,
}

/// Per-triangle range of cells (inclusive) its box touches.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct CellRange {
    lo: [i32; 3],
    hi: [i32; 3],
}

impl CellRange {
    const EMPTY: CellRange = CellRange {
        lo: [0; 3],
        hi: [-1; 3],
    };
    /// Empty in (y, z): no row of the box. The x range is not clamped (a triangle beyond either
    /// end of the rows still crosses them).
    fn is_empty(&self) -> bool {
        (1..3).any(|a| self.hi[a] < self.lo[a])
    }
}

/// Rows per side of a bin of the (y, z) triangle index.
const BIN: usize = 4;

/// The voxelizer of one closed surface on one box.
#[derive(Debug, Clone)]
pub struct Voxelizer {
    cells: VoxelBox,
    triangles: Vec<[u32; 3]>,
    /// Voxel positions in cell units (relative to the box's corner).
    pos: Vec<[f64; 3]>,
    /// The positions in metres the voxel positions were taken from.
    pos_m: Vec<[f32; 3]>,
    initialised: bool,
    range: Vec<CellRange>,
    bins_dims: [usize; 2],
    bins: Vec<Vec<u32>>,
    state: Vec<u8>,
    owner: Vec<u32>,
    /// Per row `j + ny k`, the x range `[first, end)` of its cells off [`state::OUTSIDE`]
    /// (`[0, 0]`: none).
    extent: Vec<[u32; 2]>,
    // Scratch, reused.
    moved: Vec<bool>,
    tri_moved: Vec<bool>,
    tri_rebin: Vec<bool>,
    row_dirty: Vec<bool>,
    dirty_rows: Vec<u32>,
    /// The rows in which the last call changed a cell's state or owner.
    changed_rows: Vec<u32>,
    /// What the last call did.
    last: VoxelizeStats,
    /// Per row, how many of its cells its last re-test changed.
    row_changed: Vec<u32>,
    /// Per layer `k`, the work of its dirty rows (for the split of the rows in two halves).
    layer_work: Vec<u64>,
    /// The two halves' scratch.
    scratch: [RowScratch; 2],
}

/// One half's scratch for re-testing rows (preallocated, reused every update).
#[derive(Debug, Clone)]
struct RowScratch {
    state: Vec<u8>,
    owner: Vec<u32>,
    crossings: Vec<(f64, i32)>,
}

impl RowScratch {
    fn new(nx: usize) -> Self {
        Self {
            state: vec![state::OUTSIDE; nx],
            owner: vec![NO_TRIANGLE; nx],
            crossings: Vec::with_capacity(64),
        }
    }
}

/// What every row's re-test reads, shared by the two halves of [`Voxelizer::process_rows`].
struct Shared<'a> {
    cells: &'a VoxelBox,
    triangles: &'a [[u32; 3]],
    pos: &'a [[f64; 3]],
    range: &'a [CellRange],
    bins: &'a [Vec<u32>],
    bins_dims: [usize; 2],
    dirty_rows: &'a [u32],
}

/// The outputs of the rows from `row0` on: every array from the first entry of row `row0` on.
struct RowOutputs<'a> {
    row0: usize,
    state: &'a mut [u8],
    owner: &'a mut [u32],
    extent: &'a mut [[u32; 2]],
    changed: &'a mut [u32],
}

impl<'a> RowOutputs<'a> {
    /// The outputs of rows `row0 .. row` and of `row ..` (rows `nx` cells long).
    fn split(self, row: usize, nx: usize) -> (RowOutputs<'a>, RowOutputs<'a>) {
        let rows = row - self.row0;
        let (state, state_b) = self.state.split_at_mut(nx * rows);
        let (owner, owner_b) = self.owner.split_at_mut(nx * rows);
        let (extent, extent_b) = self.extent.split_at_mut(rows);
        let (changed, changed_b) = self.changed.split_at_mut(rows);
        (
            RowOutputs {
                row0: self.row0,
                state,
                owner,
                extent,
                changed,
            },
            RowOutputs {
                row0: row,
                state: state_b,
                owner: owner_b,
                extent: extent_b,
                changed: changed_b,
            },
        )
    }
}

impl Voxelizer {
    /// A voxelizer for `triangles` (indices into the positions later passed) on `cells`.
    pub fn new(cells: VoxelBox, triangles: Vec<[u32; 3]>, vertex_count: usize) -> Self {
        let n = cells.cell_count();
        let bins_dims = [cells.dims[1].div_ceil(BIN), cells.dims[2].div_ceil(BIN)];
        let t = triangles.len();
        Self {
            cells,
            pos: vec![[0.0; 3]; vertex_count],
            pos_m: vec![[0.0; 3]; vertex_count],
            initialised: false,
            range: vec![CellRange::EMPTY; t],
            bins_dims,
            bins: vec![Vec::new(); bins_dims[0] * bins_dims[1]],
            state: vec![state::OUTSIDE; n],
            owner: vec![NO_TRIANGLE; n],
            extent: vec![[0, 0]; cells.dims[1] * cells.dims[2]],
            moved: vec![false; vertex_count],
            tri_moved: vec![false; t],
            tri_rebin: vec![false; t],
            row_dirty: vec![false; cells.dims[1] * cells.dims[2]],
            dirty_rows: Vec::with_capacity(cells.dims[1] * cells.dims[2]),
            changed_rows: Vec::with_capacity(cells.dims[1] * cells.dims[2]),
            last: VoxelizeStats::default(),
            row_changed: vec![0; cells.dims[1] * cells.dims[2]],
            layer_work: vec![0; cells.dims[2]],
            scratch: [
                RowScratch::new(cells.dims[0]),
                RowScratch::new(cells.dims[0]),
            ],
            triangles,
        }
    }

    /// The box.
    pub fn cells(&self) -> &VoxelBox {
        &self.cells
    }
    /// The triangles.
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }
    /// Per-cell state ([`state`]).
    pub fn states(&self) -> &[u8] {
        &self.state
    }
    /// Per-cell lowest index of a triangle touching it ([`NO_TRIANGLE`] off the band).
    pub fn owners(&self) -> &[u32] {
        &self.owner
    }
    /// Per row `j + ny k` of the box, the x range `[first, end)` of its cells that are not
    /// [`state::OUTSIDE`] (`[0, 0]` when there is none): every cell beyond it is outside.
    pub fn row_extents(&self) -> &[[u32; 2]] {
        &self.extent
    }
    /// The rows `j + ny k` in which the last [`Voxelizer::update`] or [`Voxelizer::full`] changed
    /// a cell's state or owner, in the order they were re-tested: every other row is as before.
    pub fn changed_rows(&self) -> &[u32] {
        &self.changed_rows
    }
    /// What the last [`Voxelizer::step`] did (nothing when it had no surface to take).
    pub fn last_stats(&self) -> VoxelizeStats {
        self.last
    }
    /// The positions (m) the current labels were computed from.
    pub fn voxel_positions_m(&self) -> &[[f32; 3]] {
        &self.pos_m
    }

    fn to_cells(&self, p: [f32; 3]) -> [f64; 3] {
        let h = self.cells.spacing_m;
        std::array::from_fn(|a| (p[a] as f64 - self.cells.origin_m[a]) / h)
    }

    fn triangle_range(&self, t: usize) -> CellRange {
        let [a, b, c] = self.triangles[t].map(|v| self.pos[v as usize]);
        let mut r = CellRange::EMPTY;
        for ax in 0..3 {
            let lo = a[ax].min(b[ax]).min(c[ax]) - EPS;
            let hi = a[ax].max(b[ax]).max(c[ax]) + EPS;
            if !(lo.is_finite() && hi.is_finite()) {
                return CellRange::EMPTY;
            }
            let n = self.cells.dims[ax] as f64;
            r.lo[ax] = floor(lo).clamp(-1.0, n) as i32;
            r.hi[ax] = floor(hi).clamp(-1.0, n) as i32;
            if ax > 0 {
                r.lo[ax] = r.lo[ax].max(0);
                r.hi[ax] = r.hi[ax].min(self.cells.dims[ax] as i32 - 1);
            }
        }
        r
    }

    fn bin_range(&self, r: &CellRange) -> Option<([usize; 2], [usize; 2])> {
        if r.is_empty() {
            return None;
        }
        Some((
            [r.lo[1] as usize / BIN, r.lo[2] as usize / BIN],
            [r.hi[1] as usize / BIN, r.hi[2] as usize / BIN],
        ))
    }

    fn unbin(&mut self, t: usize) {
        if let Some((lo, hi)) = self.bin_range(&self.range[t]) {
            for bz in lo[1]..=hi[1] {
                for by in lo[0]..=hi[0] {
                    let bin = &mut self.bins[by + self.bins_dims[0] * bz];
                    if let Some(at) = bin.iter().position(|&x| x as usize == t) {
                        bin.swap_remove(at);
                    }
                }
            }
        }
    }

    fn bin(&mut self, t: usize) {
        if let Some((lo, hi)) = self.bin_range(&self.range[t]) {
            for bz in lo[1]..=hi[1] {
                for by in lo[0]..=hi[0] {
                    self.bins[by + self.bins_dims[0] * bz].push(t as u32);
                }
            }
        }
    }

    fn mark_rows(&mut self, r: CellRange) {
        if r.is_empty() {
            return;
        }
        let ny = self.cells.dims[1];
        for k in r.lo[2]..=r.hi[2] {
            for j in r.lo[1]..=r.hi[1] {
                let row = j as usize + ny * k as usize;
                if !self.row_dirty[row] {
                    self.row_dirty[row] = true;
                    self.dirty_rows.push(row as u32);
                }
            }
        }
    }

    /// Voxelizes from scratch at `positions_m` (one per vertex).
    pub fn full(&mut self, positions_m: &[[f32; 3]]) -> VoxelizeStats {
        assert_eq!(positions_m.len(), self.pos.len(), "one position per vertex");
        for (v, p) in positions_m.iter().enumerate() {
            self.pos[v] = self.to_cells(*p);
            self.pos_m[v] = *p;
        }
        for bin in &mut self.bins {
            bin.clear();
        }
        for t in 0..self.triangles.len() {
            self.range[t] = self.triangle_range(t);
            self.bin(t);
        }
        self.initialised = true;
        self.dirty_rows.clear();
        for (row, d) in self.row_dirty.iter_mut().enumerate() {
            *d = true;
            self.dirty_rows.push(row as u32);
        }
        let mut stats = self.process_rows();
        stats.moved_vertices = positions_m.len();
        stats.moved_triangles = self.triangles.len();
        stats
    }

    /// Moves the voxel position of every vertex that moved more than `threshold_m` since its last
    /// voxel position, and re-tests the rows the moved triangles touch (old and new positions).
    /// The first call voxelizes fully.
    pub fn update(&mut self, positions_m: &[[f32; 3]], threshold_m: f64) -> VoxelizeStats {
        self.update_leading(positions_m, threshold_m, 0.0)
    }

    /// [`Voxelizer::update`], with each moved vertex's voxel position placed `lead_m` beyond its
    /// position along its move since its last voxel position (`0 <= lead_m < threshold_m`). A
    /// surface moving steadily then lies on both sides of its voxel positions, within
    /// `threshold_m` of them as before, but the voxel positions move about every
    /// `threshold_m + lead_m` of travel instead of every `threshold_m`, and the volume they
    /// enclose lags the surface's by about nothing on average instead of half the threshold.
    /// The result is still [`Voxelizer::full`] of the voxel positions.
    pub fn update_leading(
        &mut self,
        positions_m: &[[f32; 3]],
        threshold_m: f64,
        lead_m: f64,
    ) -> VoxelizeStats {
        if !self.initialised {
            return self.full(positions_m);
        }
        assert_eq!(positions_m.len(), self.pos.len(), "one position per vertex");
        let t2 = (threshold_m * threshold_m) as f32;
        let mut moved_vertices = 0;
        for (v, p) in positions_m.iter().enumerate() {
            let q = self.pos_m[v];
            let d2 = (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2);
            // A NaN distance (a vertex that became NaN) counts as moved: it then touches no cell.
            let far = d2.partial_cmp(&t2) != Some(std::cmp::Ordering::Less)
                && d2.partial_cmp(&t2) != Some(std::cmp::Ordering::Equal);
            let m = far || (threshold_m <= 0.0 && *p != q);
            self.moved[v] = m;
            if m {
                moved_vertices += 1;
            }
        }
        if moved_vertices == 0 {
            self.changed_rows.clear();
            return VoxelizeStats::default();
        }
        let mut moved_triangles = 0;
        for t in 0..self.triangles.len() {
            let m = self.triangles[t].iter().any(|&v| self.moved[v as usize]);
            self.tri_moved[t] = m;
            if m {
                moved_triangles += 1;
                let old = self.range[t];
                self.mark_rows(old);
            }
        }
        let lead_m = if lead_m > 0.0 && lead_m < threshold_m {
            lead_m as f32
        } else {
            0.0
        };
        for (v, p) in positions_m.iter().enumerate() {
            if self.moved[v] {
                let held = if lead_m > 0.0 {
                    let q = self.pos_m[v];
                    let d: [f32; 3] = std::array::from_fn(|a| p[a] - q[a]);
                    let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                    if len.is_finite() && len > 0.0 {
                        std::array::from_fn(|a| p[a] + d[a] * (lead_m / len))
                    } else {
                        *p
                    }
                } else {
                    *p
                };
                self.pos[v] = self.to_cells(held);
                self.pos_m[v] = held;
            }
        }
        // A moved triangle whose range is as it was marks no new row, and one whose bins are as
        // they were stays in them (most of them: the surface moves by a fraction of a cell per
        // frame; a bin's order does not matter). Every triangle leaves its old bins before any
        // enters its new ones.
        for t in 0..self.triangles.len() {
            if !self.tri_moved[t] {
                continue;
            }
            let new = self.triangle_range(t);
            if new == self.range[t] {
                self.tri_moved[t] = false;
                continue;
            }
            if self.bin_range(&new) != self.bin_range(&self.range[t]) {
                self.unbin(t);
                self.tri_rebin[t] = true;
            }
            self.range[t] = new;
        }
        for t in 0..self.triangles.len() {
            if self.tri_rebin[t] {
                self.tri_rebin[t] = false;
                self.bin(t);
            }
            if self.tri_moved[t] {
                let new = self.range[t];
                self.mark_rows(new);
            }
        }
        let mut stats = self.process_rows();
        stats.moved_vertices = moved_vertices;
        stats.moved_triangles = moved_triangles;
        stats
    }

    /// The voxelize stage of a scene step: [`Voxelizer::update_leading`] with the surface's
    /// `positions_m` when it was deformed (`None`: no vertex can have moved since the last update,
    /// and the scan over every vertex is skipped, the scene at rest). Returns the rows whose cell
    /// states changed (empty when none did).
    pub fn step(
        &mut self,
        deformed: Option<&[[f32; 3]]>,
        threshold_m: f64,
        lead_m: f64,
        counters: &mut StageCounters,
    ) -> &[u32] {
        let t = Instant::now();
        let stats = match deformed {
            Some(positions_m) => self.update_leading(positions_m, threshold_m, lead_m),
            None => VoxelizeStats::default(),
        };
        self.last = stats;
        if stats.moved_vertices > 0 {
            counters.ran_since(t);
        } else {
            counters.skipped();
        }
        if stats.moved_vertices > 0 && stats.changed_cells > 0 {
            &self.changed_rows
        } else {
            &[]
        }
    }

    fn process_rows(&mut self) -> VoxelizeStats {
        let [nx, ny, nz] = self.cells.dims;
        // Two halves of the box, the layers below `ks` and the rest, of about equal work (a row's
        // work taken as the triangles of its bin, those it tests), on the two cores.
        let work = &mut self.layer_work;
        work.fill(0);
        for &row in &self.dirty_rows {
            let (j, k) = (row as usize % ny, row as usize / ny);
            work[k] += self.bins[j / BIN + self.bins_dims[0] * (k / BIN)].len() as u64;
        }
        let total: u64 = work.iter().sum();
        let mut below = 0;
        let ks = work
            .iter()
            .position(|&w| {
                let half = 2 * below >= total;
                below += w;
                half
            })
            .unwrap_or(nz);
        {
            let shared = Shared {
                cells: &self.cells,
                triangles: &self.triangles,
                pos: &self.pos,
                range: &self.range,
                bins: &self.bins,
                bins_dims: self.bins_dims,
                dirty_rows: &self.dirty_rows,
            };
            let outputs = RowOutputs {
                row0: 0,
                state: &mut self.state,
                owner: &mut self.owner,
                extent: &mut self.extent,
                changed: &mut self.row_changed,
            };
            let (lower, upper) = outputs.split(ny * ks, nx);
            let [a, b] = &mut self.scratch;
            // Each row reads only the shared state and writes only its own cells, so the halves
            // give what one pass over the rows would, bit for bit.
            crate::fork_join::join(
                || process_half(&shared, lower, a),
                || process_half(&shared, upper, b),
            );
        }
        let mut stats = VoxelizeStats::default();
        self.changed_rows.clear();
        for &row in &self.dirty_rows {
            self.row_dirty[row as usize] = false;
            let changed = self.row_changed[row as usize] as usize;
            if changed > 0 {
                self.changed_rows.push(row);
            }
            stats.changed_cells += changed;
        }
        stats.rows = self.dirty_rows.len();
        self.dirty_rows.clear();
        stats
    }
}

/// Re-tests the dirty rows whose outputs `out` holds.
fn process_half(sh: &Shared, mut out: RowOutputs, scratch: &mut RowScratch) {
    let ny = sh.cells.dims[1];
    for &row in sh.dirty_rows {
        let row = row as usize;
        if row < out.row0 || row - out.row0 >= out.changed.len() {
            continue;
        }
        out.changed[row - out.row0] = process_row(sh, &mut out, scratch, row % ny, row / ny);
    }
}

/// Re-tests row `(j, k)` of `out`; returns how many of its cells changed.
fn process_row(
    sh: &Shared,
    out: &mut RowOutputs,
    scratch: &mut RowScratch,
    j: usize,
    k: usize,
) -> u32 {
    let nx = sh.cells.dims[0];
    let RowScratch {
        state: row_state,
        owner: row_owner,
        crossings,
    } = scratch;
    row_state.fill(state::OUTSIDE);
    row_owner.fill(NO_TRIANGLE);
    crossings.clear();
    let bin = &sh.bins[(j / BIN) + sh.bins_dims[0] * (k / BIN)];
    let (py, pz) = (j as f64 + 0.5, k as f64 + 0.5);
    for &t in bin {
        let t = t as usize;
        let r = sh.range[t];
        if (j as i32) < r.lo[1]
            || (j as i32) > r.hi[1]
            || (k as i32) < r.lo[2]
            || (k as i32) > r.hi[2]
        {
            continue;
        }
        let tri = sh.triangles[t];
        let v = tri.map(|i| sh.pos[i as usize]);
        // Band: the triangle clipped to the row's slab, its x-extent.
        if let Some((x0, x1)) = clip_x_extent(
            &v,
            j as f64 - EPS,
            j as f64 + 1.0 + EPS,
            k as f64 - EPS,
            k as f64 + 1.0 + EPS,
        ) {
            let lo = floor(x0 - EPS).max(0.0);
            let hi = floor(x1 + EPS).min(nx as f64 - 1.0);
            if lo <= hi {
                for i in lo as usize..=hi as usize {
                    row_state[i] = state::BAND;
                    if (t as u32) < row_owner[i] {
                        row_owner[i] = t as u32;
                    }
                }
            }
        }
        // Crossing of the x-ray through the cell centres.
        if let Some(c) = crossing(&tri, &v, py, pz) {
            crossings.push(c);
        }
    }
    if !crossings.is_empty() {
        crossings.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        let mut winding = 0i32;
        let mut next = 0;
        for (i, s) in row_state.iter_mut().enumerate() {
            let x = i as f64 + 0.5;
            while next < crossings.len() && crossings[next].0 < x {
                winding += crossings[next].1;
                next += 1;
            }
            if winding != 0 && *s == state::OUTSIDE {
                *s = state::INSIDE;
            }
        }
    }
    let l = j + sh.cells.dims[1] * k - out.row0;
    let base = nx * l;
    let first = row_state.iter().position(|&s| s != state::OUTSIDE);
    out.extent[l] = match first {
        Some(a) => {
            let b = row_state.iter().rposition(|&s| s != state::OUTSIDE);
            [a as u32, b.unwrap_or(a) as u32 + 1]
        }
        None => [0, 0],
    };
    let mut changed = 0;
    for i in 0..nx {
        let (s, o) = (row_state[i], row_owner[i]);
        if out.state[base + i] != s || out.owner[base + i] != o {
            changed += 1;
            out.state[base + i] = s;
            out.owner[base + i] = o;
        }
    }
    changed
}

/// The x-extent of triangle `v` clipped to `y0 <= y <= y1`, `z0 <= z <= z1`, if not empty.
fn clip_x_extent(v: &[[f64; 3]; 3], y0: f64, y1: f64, z0: f64, z1: f64) -> Option<(f64, f64)> {
    // Quick accept: the whole triangle inside the slab.
    let inside = |p: &[f64; 3]| p[1] >= y0 && p[1] <= y1 && p[2] >= z0 && p[2] <= z1;
    if v.iter().all(inside) {
        let lo = v[0][0].min(v[1][0]).min(v[2][0]);
        let hi = v[0][0].max(v[1][0]).max(v[2][0]);
        return Some((lo, hi));
    }
    // Two polygon buffers used in turn (no copy between the passes).
    let mut bufs = [[[0.0f64; 3]; 9]; 2];
    bufs[0][..3].copy_from_slice(v);
    let mut cur = 0;
    let mut n = 3;
    // Planes as (axis, bound, keep >= bound?).
    for (axis, bound, ge) in [(1, y0, true), (1, y1, false), (2, z0, true), (2, z1, false)] {
        let keep = |p: &[f64; 3]| {
            if ge {
                p[axis] >= bound
            } else {
                p[axis] <= bound
            }
        };
        // Every vertex kept: the pass would return the polygon as it is.
        if bufs[cur][..n].iter().all(keep) {
            continue;
        }
        let [b0, b1] = &mut bufs;
        let (a, b) = if cur == 0 { (&*b0, b1) } else { (&*b1, b0) };
        let mut m = 0;
        for s in 0..n {
            let p = a[s];
            let q = a[if s + 1 == n { 0 } else { s + 1 }];
            let (kp, kq) = (keep(&p), keep(&q));
            if kp {
                b[m] = p;
                m += 1;
            }
            if kp != kq {
                let t = (bound - p[axis]) / (q[axis] - p[axis]);
                let t = if t.is_finite() {
                    t.clamp(0.0, 1.0)
                } else {
                    0.0
                };
                let mut x: [f64; 3] = std::array::from_fn(|c| p[c] + t * (q[c] - p[c]));
                x[axis] = bound;
                b[m] = x;
                m += 1;
            }
        }
        n = m;
        if n == 0 {
            return None;
        }
        cur ^= 1;
    }
    let mut lo = f64::INFINITY;
    let mut hi = f64::NEG_INFINITY;
    for p in &bufs[cur][..n] {
        lo = lo.min(p[0]);
        hi = hi.max(p[0]);
    }
    Some((lo, hi))
}

/// Sign of the edge function of edge `(ia, a) -> (ib, b)` at `(py, pz)` perturbed by
/// `(eps, eps^2)`, evaluated from the endpoints in vertex-index order so both triangles sharing the
/// edge see the same value.
#[inline]
fn edge_sign(ia: u32, a: &[f64; 3], ib: u32, b: &[f64; 3], py: f64, pz: f64) -> (i32, f64) {
    let (flip, p, q) = if ia < ib { (1, a, b) } else { (-1, b, a) };
    // orient(p, q, x) = (q.y - p.y)(x.z - p.z) - (q.z - p.z)(x.y - p.y)
    let dy = q[1] - p[1];
    let dz = q[2] - p[2];
    let f = dy * (pz - p[2]) - dz * (py - p[1]);
    let s = if f > 0.0 {
        1
    } else if f < 0.0 {
        -1
    } else if dz != 0.0 {
        // d/dy of f is -dz.
        if -dz > 0.0 {
            1
        } else {
            -1
        }
    } else if dy > 0.0 {
        1
    } else if dy < 0.0 {
        -1
    } else {
        0
    };
    (flip * s, flip as f64 * f)
}

/// Where the x-ray through `(py, pz)` crosses triangle `tri` (positions `v`), with the sign of the
/// triangle's (y, z) orientation.
#[inline]
fn crossing(tri: &[u32; 3], v: &[[f64; 3]; 3], py: f64, pz: f64) -> Option<(f64, i32)> {
    // Quick reject on the (y, z) box.
    let (ymin, ymax) = (
        v[0][1].min(v[1][1]).min(v[2][1]),
        v[0][1].max(v[1][1]).max(v[2][1]),
    );
    let (zmin, zmax) = (
        v[0][2].min(v[1][2]).min(v[2][2]),
        v[0][2].max(v[1][2]).max(v[2][2]),
    );
    if py < ymin || py > ymax || pz < zmin || pz > zmax {
        return None;
    }
    // Edge k is opposite vertex k: (1, 2), (2, 0), (0, 1).
    let (s0, w0) = edge_sign(tri[1], &v[1], tri[2], &v[2], py, pz);
    let (s1, w1) = edge_sign(tri[2], &v[2], tri[0], &v[0], py, pz);
    let (s2, w2) = edge_sign(tri[0], &v[0], tri[1], &v[1], py, pz);
    if s0 == 0 || s0 != s1 || s1 != s2 {
        return None;
    }
    let sum = w0 + w1 + w2;
    let x = if sum != 0.0 && sum.is_finite() {
        (w0 * v[0][0] + w1 * v[1][0] + w2 * v[2][0]) / sum
    } else {
        (v[0][0] + v[1][0] + v[2][0]) / 3.0
    };
    Some((x, s0))
}
