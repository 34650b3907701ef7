//! Face classification derived from the cell labels: which faces the solver updates (active), which
//! carry a prescribed normal velocity (fixed), which are extrapolated for sampling, and the viscous
//! stencil of every active face. Updated only when a label changes, near the changed cells, into
//! reused buffers.

use super::grid::FluidGrid;
use super::sample::Layout;
use super::CellLabel;

/// "No such index".
pub(crate) const NONE: u32 = u32::MAX;
/// Stencil entry flag: the neighbour is a fixed face read from the full array, not a variable.
pub(crate) const CONST_BIT: u32 = 1 << 31;

/// Face classes.
pub(crate) const OTHER: u8 = 0;
pub(crate) const ACTIVE: u8 = 1;
pub(crate) const FIXED: u8 = 2;
pub(crate) const EXT1: u8 = 3;
pub(crate) const EXT2: u8 = 4;

/// An active face off the plain 7-point stencil, packed (its `nbr` and `self_diag`) so the
/// explicit step reads one record per face rather than four sparse arrays.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Irregular {
    /// Compact and full index.
    pub n: u32,
    pub idx: u32,
    pub nbr: [u32; 6],
    pub self_diag: f32,
}

/// Everything the solver needs to know about the faces of one velocity component.
#[derive(Default, Debug)]
pub(crate) struct FaceSet {
    /// Face-array dimensions of the component (`Layout::fdims`).
    pub fdims: [usize; 3],
    /// Class of every face (full array).
    pub class: Vec<u8>,
    /// Full index of each active face.
    pub active: Vec<u32>,
    /// Compact index of each face (NONE unless active).
    pub compact: Vec<u32>,
    /// Viscous stencil: full index of an active neighbour, `CONST_BIT | full` for a fixed one, NONE
    /// when the neighbour is a ghost or a zero-gradient (outflow) one. Full indices, not compact
    /// ones, so an update carries a face's stencil over unchanged (`compact` maps them).
    pub stencil: Vec<[u32; 6]>,
    /// Diagonal of the negative Laplacian (6, plus one per wall ghost, minus one per outflow side).
    pub diag: Vec<f32>,
    /// The stencil as full face indices for the explicit step: the neighbour's full index (active or
    /// fixed), or the face itself where the stencil has NONE; `self_diag` is `diag` plus the number
    /// of such self entries, so `sum(full[nbr]) - self_diag u` is the stencil without branches.
    pub nbr: Vec<[u32; 6]>,
    pub self_diag: Vec<f32>,
    /// Runs `[full, compact, len]` of consecutive active faces (consecutive in both arrays), each
    /// within one x row of faces (so its cells are consecutive too).
    pub runs: Vec<[u32; 3]>,
    /// Runs as in `runs` of faces whose stencil is the plain 7-point one (six in-array neighbours
    /// at the structured offsets, `self_diag` 6), and the compact indices of all other active
    /// faces: the explicit step walks the former as contiguous rows (vectorised) and gathers only
    /// the latter.
    pub regular: Vec<[u32; 3]>,
    pub irregular: Vec<Irregular>,
    /// Wall ghosts: (compact face, cell a, cell b, opposite face): the wall velocity is the mean of the
    /// prescribed velocities of `Velocity` cells among a and b (zero for solids and outside); the
    /// opposite face (full index, NONE if it is not active or fixed) is the second point of the
    /// quadratic wall extrapolation.
    pub ghosts: Vec<[u32; 4]>,
    /// Fixed faces: (full face, cell a, cell b) as for ghosts. Cells that are not `Velocity` cells
    /// are stored as NONE here and in `ghosts` (they contribute nothing to the wall velocity, and
    /// labels cannot change without a rebuild), and the faces with a `Velocity` cell come first.
    pub fixed: Vec<[u32; 3]>,
    /// Number of fixed faces beside a `Velocity` cell (the others stay at zero between rebuilds).
    pub fixed_moving: usize,
    /// Extrapolation layers: faces next to active faces, and next to those.
    pub ext1: Vec<u32>,
    pub ext2: Vec<u32>,
    /// Sources of the extrapolated faces (ext1 then ext2): `ext_src[ext_start[n]..ext_start[n+1]]`.
    pub ext_start: Vec<u32>,
    pub ext_src: Vec<u32>,
    /// The same per layer (ext1, ext2) grouped by number of sources k (0 to 6): the faces, and
    /// their sources k at a time (same order). A fixed count per loop has no mispredicted exits,
    /// and within a layer no face reads another, so the order among groups is free.
    pub ext_groups: [[(Vec<u32>, Vec<u32>); 7]; 2],
    /// The faces the last rebuild tracked (active, fixed and extrapolated) that this one does not:
    /// the solver zeroes their velocities.
    pub dropped: Vec<u32>,
    /// Scratch: the faces the dirty faces were tracked before this update.
    previous: Vec<u32>,
    /// The cells beside each active face (lower, upper; NONE = outside), from the classification.
    active_cells: Vec<[u32; 2]>,
    /// Position of each face in its extrapolation layer (full array; NONE unless extrapolated):
    /// carries a face's sources over an update, as `compact` carries an active face's results.
    ext_pos: Vec<u32>,
    /// The faces (coordinates) this update computes again, and for each face whether it is listed
    /// there (full array): 0 not (all 0 between updates), [`NEAR`] within one face of a changed
    /// cell's faces, [`FAR`] two faces from them (only its second-layer class and sources can
    /// change). All [`NEAR`] in a build from scratch (`full`).
    dirty: Vec<[u32; 3]>,
    marked: Vec<u8>,
    full: bool,
    /// Per face row (`fj + d1 fk`): whether it holds a dirty face. A clean row's entries of every
    /// list are carried over as whole slices.
    row_dirty: Vec<bool>,
    /// Per face row, where its entries start in each list ([`ROW_LISTS`] order); one more entry
    /// holds the lengths. Every list is in index order, so a row's entries are contiguous.
    row_at: Vec<[u32; ROW_LISTS]>,
    /// The fixed faces in index order with their `Velocity` cells (before the partition).
    fixed_in_order: Vec<[u32; 3]>,
    /// Per active face (and per face of each layer) the position it had before this update
    /// (NONE: computed again).
    reuse: Vec<u32>,
    ext_reuse: [Vec<u32>; 2],
    /// The last build's per-face results, read by the update for the faces it carries over.
    carried: Carried,
}

/// The per-face results of a build, kept while the next update carries them over.
#[derive(Default, Debug)]
struct Carried {
    row_at: Vec<[u32; ROW_LISTS]>,
    fixed_in_order: Vec<[u32; 3]>,
    ext1: Vec<u32>,
    ext2: Vec<u32>,
    runs: Vec<[u32; 3]>,
    regular: Vec<[u32; 3]>,
    irregular: Vec<Irregular>,
    active: Vec<u32>,
    active_cells: Vec<[u32; 2]>,
    stencil: Vec<[u32; 6]>,
    diag: Vec<f32>,
    nbr: Vec<[u32; 6]>,
    self_diag: Vec<f32>,
    ghosts: Vec<[u32; 4]>,
    ext1_len: usize,
    ext_start: Vec<u32>,
    ext_src: Vec<u32>,
}

/// How far (in faces along each axis) the faces an update computes again reach beyond the faces of
/// the changed cells: a face's stencil reads the labels of its neighbours' cells and, like its
/// extrapolation sources, its neighbours' classes, and a second-layer face is one face from a
/// first-layer face, which is one face from an active face (a change of class two faces away
/// changes it).
const DIRTY_REACH: usize = 2;
/// The lists `FaceSet::row_at` indexes: active, ext1, ext2, fixed (in index order), runs,
/// regular, irregular.
const ROW_LISTS: usize = 7;
/// Levels of `FaceSet::marked`.
const NEAR: u8 = 1;
const FAR: u8 = 2;

/// Labels as of the last topology build, and the cells and cell rows whose labels changed since:
/// what an incremental update starts from.
#[derive(Default, Debug)]
pub(crate) struct LabelDiff {
    seen: Vec<u8>,
    changed: Vec<u32>,
    cells: Vec<u32>,
}

impl LabelDiff {
    /// Compares the labels with those of the last call, x row (`nx` cells) by x row, and keeps
    /// them: true when there was a previous call of the same size, and then [`LabelDiff::rows`]
    /// and [`LabelDiff::cells`] tell what changed (false: everything did).
    pub fn update(&mut self, labels: &[CellLabel], nx: usize) -> bool {
        self.changed.clear();
        self.cells.clear();
        if self.seen.len() != labels.len() || nx == 0 {
            self.seen.clear();
            self.seen.extend(labels.iter().map(|&l| l as u8));
            return false;
        }
        for (r, (now, seen)) in labels
            .chunks_exact(nx)
            .zip(self.seen.chunks_exact_mut(nx))
            .enumerate()
        {
            // An OR of differences (no early exit) vectorises.
            let differ = now
                .iter()
                .zip(seen.iter())
                .fold(0u8, |acc, (&l, &s)| acc | (l as u8 ^ s));
            if differ != 0 {
                for (i, (s, &l)) in seen.iter_mut().zip(now).enumerate() {
                    if *s != l as u8 {
                        *s = l as u8;
                        self.cells.push((r * nx + i) as u32);
                    }
                }
                self.changed.push(r as u32);
            }
        }
        true
    }

    /// The rows (`j + ny k`) whose labels the last [`LabelDiff::update`] found changed.
    pub fn rows(&self) -> &[u32] {
        &self.changed
    }

    /// The cells (linear indices) whose labels the last [`LabelDiff::update`] found changed.
    pub fn cells(&self) -> &[u32] {
        &self.cells
    }
}

/// The six neighbours of face `idx` (coordinates `f`, component `c`) in stencil-slot order
/// (-x, +x, -y, +y, -z, +z), as [`neighbour_index`] finds them; `strides` are the face array's.
/// A face off every end of the array takes the plain offsets without a test per slot.
#[inline(always)]
fn neighbours(
    layout: &Layout,
    c: usize,
    f: [usize; 3],
    idx: usize,
    strides: [usize; 3],
) -> [Option<usize>; 6] {
    let fd = layout.fdims[c];
    if (0..3).all(|a| f[a] > 0 && f[a] + 1 < fd[a]) {
        let [sx, sy, sz] = strides;
        [
            Some(idx - sx),
            Some(idx + sx),
            Some(idx - sy),
            Some(idx + sy),
            Some(idx - sz),
            Some(idx + sz),
        ]
    } else {
        std::array::from_fn(|slot| {
            let dir = if slot % 2 == 0 { -1 } else { 1 };
            neighbour_index(layout, c, f, idx, slot / 2, dir)
        })
    }
}

/// Adds face `idx` (compact index `n`) to `runs` (`[full, compact, len]`, see
/// [`FaceSet::runs`]): it lengthens the last run when it follows that run's last face in both
/// arrays within one x row of `row_len` faces, else it starts a run.
pub(crate) fn extend_runs(runs: &mut Vec<[u32; 3]>, idx: u32, n: u32, row_len: usize) {
    match runs.last_mut() {
        Some(r)
            if r[0] + r[2] == idx
                && r[1] + r[2] == n
                && !(idx as usize).is_multiple_of(row_len) =>
        {
            r[2] += 1
        }
        _ => runs.push([idx, n, 1]),
    }
}

/// The x range `[first, end)` of the open (fluid or outflow) cells of every cell row `(j, k)`
/// (index `j + ny k`; `[0, 0]` when the row has none): the only rows whose faces can be active or
/// fixed, so a rebuild costs the fluid region, not the box.
pub(crate) fn open_row_ranges(grid: &FluidGrid, out: &mut Vec<[u32; 2]>) {
    let nx = grid.dims()[0];
    out.clear();
    out.extend(grid.labels().chunks_exact(nx).map(open_row_range));
}

/// [`open_row_ranges`] after the rows `changed` (from [`LabelDiff`]; None: all of them) changed.
pub(crate) fn update_open_row_ranges(
    grid: &FluidGrid,
    changed: Option<&[u32]>,
    out: &mut Vec<[u32; 2]>,
) {
    let [nx, ny, nz] = grid.dims();
    match changed {
        Some(changed) if out.len() == ny * nz => {
            for &row in changed {
                let row = row as usize;
                out[row] = open_row_range(&grid.labels()[row * nx..(row + 1) * nx]);
            }
        }
        _ => open_row_ranges(grid, out),
    }
}

/// The smallest x range `[first, end)` holding both (an empty range, `first >= end`, holds none).
pub(crate) fn range_hull(a: [u32; 2], b: [u32; 2]) -> [u32; 2] {
    match (a[0] < a[1], b[0] < b[1]) {
        (false, _) => b,
        (_, false) => a,
        _ => [a[0].min(b[0]), a[1].max(b[1])],
    }
}

/// The x range of the open cells of one cell row (`[0, 0]`: none).
fn open_row_range(row: &[CellLabel]) -> [u32; 2] {
    let open = |l: &CellLabel| matches!(l, CellLabel::Fluid | CellLabel::Outflow);
    match row.iter().position(open) {
        Some(first) => {
            let last = row.iter().rposition(open).unwrap_or(first); // ok: `first` is open
            [first as u32, last as u32 + 1]
        }
        None => [0, 0],
    }
}

/// The face coordinates along one axis (`n` faces, wrapping when `periodic`) within
/// [`DIRTY_REACH`] of faces `at` and `at + extra`, each once, with whether it is within one face
/// of them (on a periodic axis shorter than the span, a face is near if any of its images is).
fn dirty_span(
    at: usize,
    extra: usize,
    n: usize,
    periodic: bool,
) -> impl Iterator<Item = (usize, bool)> {
    let (r, n_i) = (DIRTY_REACH as i64, n as i64);
    let (first, last) = (at as i64, at as i64 + extra as i64);
    let (lo, hi) = (first - r, last + r);
    let (lo, hi) = if periodic {
        (lo, hi.min(lo + n_i - 1))
    } else {
        (lo.max(0), hi.min(n_i - 1))
    };
    // Faces first - 1 ..= last + 1 are near: `window` positions from first - 1.
    let window = last - first + 3;
    (lo..=hi).map(move |x| {
        let from = x - (first - 1);
        let near = if periodic {
            window >= n_i || from.rem_euclid(n_i) < window
        } else {
            (0..window).contains(&from)
        };
        (x.rem_euclid(n_i) as usize, near)
    })
}

#[cfg(test)]
fn label_of(grid: &FluidGrid, cell: Option<[usize; 3]>) -> (CellLabel, u32) {
    match cell {
        Some(c) => {
            let idx = grid.index(c);
            (grid.label_at(idx), idx as u32)
        }
        None => (CellLabel::Solid, NONE),
    }
}

/// The two cells beside face `f` of component `c` (None = outside): the reference the rebuild's
/// stride arithmetic must match.
#[cfg(test)]
fn face_cells(
    grid: &FluidGrid,
    c: usize,
    f: [usize; 3],
) -> (Option<[usize; 3]>, Option<[usize; 3]>) {
    let dims = grid.dims();
    let upper = (f[c] < dims[c]).then_some(f);
    let lower = if f[c] == 0 {
        grid.neighbour(f, c, -1)
    } else {
        let mut l = f;
        l[c] -= 1;
        Some(l)
    };
    // Periodic: face 0's upper is cell 0 (f itself), lower is cell n-1.
    (lower, upper)
}

/// Linear indices of the two cells beside face `f` of component `c` (lower, upper; NONE =
/// outside), as [`face_cells`] finds them but by stride arithmetic: the rebuild asks this for every
/// visited face and every tangential stencil neighbour.
#[inline]
fn face_cell_indices(dims: [usize; 3], periodic: [bool; 3], c: usize, f: [usize; 3]) -> (u32, u32) {
    let stride = [1, dims[0], dims[0] * dims[1]][c];
    // For the top face of a non-periodic axis this is one past the box along `c` (never read).
    let at = f[0] + dims[0] * (f[1] + dims[1] * f[2]);
    let upper = if f[c] < dims[c] { at as u32 } else { NONE };
    let lower = if f[c] > 0 {
        (at - stride) as u32
    } else if periodic[c] {
        // Periodic: face 0's lower cell is cell n-1.
        (at + (dims[c] - 1) * stride) as u32
    } else {
        NONE
    };
    (lower, upper)
}

/// Label of the cell with linear index `cell`, Solid for NONE (outside the box).
#[inline]
fn label_or_solid(labels: &[CellLabel], cell: u32) -> CellLabel {
    labels
        .get(cell as usize)
        .copied()
        .unwrap_or(CellLabel::Solid)
}

/// Class of a face from the labels of its two cells: fixed between a wall and an open cell,
/// active between non-walls of which one is fluid.
#[inline]
fn face_class(lower: CellLabel, upper: CellLabel) -> u8 {
    let open = |l: CellLabel| matches!(l, CellLabel::Fluid | CellLabel::Outflow);
    if lower.is_wall() || upper.is_wall() {
        if open(lower) || open(upper) {
            FIXED
        } else {
            OTHER
        }
    } else if lower == CellLabel::Fluid || upper == CellLabel::Fluid {
        ACTIVE
    } else {
        OTHER
    }
}

/// Index of the neighbour face of face `idx` (coordinates `f`, component c) along axis `d`,
/// direction `dir` (None beyond a non-periodic end; a periodic axis wraps).
#[inline]
pub(crate) fn neighbour_index(
    layout: &Layout,
    c: usize,
    f: [usize; 3],
    idx: usize,
    d: usize,
    dir: i32,
) -> Option<usize> {
    let fd = layout.fdims[c];
    let n = fd[d];
    let stride = match d {
        0 => 1,
        1 => fd[0],
        _ => fd[0] * fd[1],
    };
    if dir < 0 {
        if f[d] == 0 {
            layout.periodic[d].then(|| idx + (n - 1) * stride)
        } else {
            Some(idx - stride)
        }
    } else if f[d] + 1 >= n {
        layout.periodic[d].then(|| idx - (n - 1) * stride)
    } else {
        Some(idx + stride)
    }
}

/// Coordinates of the neighbour face [`neighbour_index`] finds (which must exist): one step along
/// axis `d`, wrapped on a periodic axis.
#[cfg(test)]
pub(crate) fn neighbour_coords(
    layout: &Layout,
    c: usize,
    f: [usize; 3],
    d: usize,
    dir: i32,
) -> [usize; 3] {
    let n = layout.fdims[c][d];
    let mut g = f;
    g[d] = if dir < 0 {
        if f[d] == 0 {
            n - 1
        } else {
            f[d] - 1
        }
    } else if f[d] + 1 >= n {
        0
    } else {
        f[d] + 1
    };
    g
}

/// Wall velocity component `c` of a pair of non-fluid cells (mean over `Velocity` cells).
pub(crate) fn wall_velocity(grid: &FluidGrid, c: usize, a: u32, b: u32) -> f32 {
    let mut sum = 0.0;
    let mut n = 0;
    for cell in [a, b] {
        if cell != NONE && grid.label_at(cell as usize) == CellLabel::Velocity {
            sum += grid.velocity_at(cell as usize)[c];
            n += 1;
        }
    }
    if n == 0 {
        0.0
    } else {
        sum / n as f32
    }
}

impl FaceSet {
    /// The cells beside each active face (lower, upper; NONE = outside), as [`face_cells`] finds
    /// them, in the order of `active`.
    #[cfg(test)]
    pub fn active_cells(&self) -> &[[u32; 2]] {
        &self.active_cells
    }

    /// Rebuilds this component's face set from the labels from scratch, visiting only the faces of
    /// every face: the reference of [`FaceSet::update`].
    #[cfg(test)]
    pub fn rebuild(&mut self, grid: &FluidGrid, layout: &Layout, c: usize) {
        self.update(grid, layout, c, None);
    }

    /// Brings the face set up to date with the labels after the cells `changed` changed (linear
    /// indices, from [`LabelDiff`]; None: all of them). Only the faces near a changed cell are
    /// classified again and their stencils and extrapolation sources computed; the other faces'
    /// are carried over, their compact indices renumbered. The result equals a
    /// [`FaceSet::rebuild`] from scratch field by field. The class, compact and layer-position
    /// arrays stay box-sized and are reset only at the faces computed again.
    pub fn update(&mut self, grid: &FluidGrid, layout: &Layout, c: usize, changed: Option<&[u32]>) {
        let nf = layout.face_count(c);
        let d = layout.fdims[c];
        self.previous.clear();
        self.dropped.clear();
        let resized = self.class.len() != nf || self.fdims != d;
        if resized {
            self.fdims = d;
            self.class.clear();
            self.class.resize(nf, OTHER);
            self.compact.clear();
            self.compact.resize(nf, NONE);
            self.ext_pos.clear();
            self.ext_pos.resize(nf, NONE);
            self.marked.clear();
            self.marked.resize(nf, 0);
        }
        let cdims = grid.dims();
        self.mark_dirty(layout, c, cdims, if resized { None } else { changed });
        let face_index =
            |f: [u32; 3]| f[0] as usize + d[0] * (f[1] as usize + d[1] * f[2] as usize);

        // Forget the dirty faces (remembering the tracked ones for `dropped`): their classes are
        // found again below, the clean faces' stay.
        let full = self.full;
        let level = move |marked: &[u8], idx: usize| if full { NEAR } else { marked[idx] };
        for &f in &self.dirty {
            let idx = face_index(f);
            let near = level(&self.marked, idx) == NEAR;
            if self.class[idx] != OTHER && (near || self.class[idx] == EXT2) {
                self.class[idx] = OTHER;
                self.previous.push(idx as u32);
                self.ext_pos[idx] = NONE;
            }
            if near {
                self.compact[idx] = NONE;
                self.ext_pos[idx] = NONE;
            }
        }

        // The last build's per-face results move aside (buffers swapped, not allocated).
        let mut old = std::mem::take(&mut self.carried);
        std::mem::swap(&mut old.active, &mut self.active);
        std::mem::swap(&mut old.active_cells, &mut self.active_cells);
        std::mem::swap(&mut old.stencil, &mut self.stencil);
        std::mem::swap(&mut old.diag, &mut self.diag);
        std::mem::swap(&mut old.nbr, &mut self.nbr);
        std::mem::swap(&mut old.self_diag, &mut self.self_diag);
        std::mem::swap(&mut old.ghosts, &mut self.ghosts);
        std::mem::swap(&mut old.ext_start, &mut self.ext_start);
        std::mem::swap(&mut old.ext_src, &mut self.ext_src);
        std::mem::swap(&mut old.row_at, &mut self.row_at);
        std::mem::swap(&mut old.fixed_in_order, &mut self.fixed_in_order);
        std::mem::swap(&mut old.ext1, &mut self.ext1);
        std::mem::swap(&mut old.ext2, &mut self.ext2);
        std::mem::swap(&mut old.runs, &mut self.runs);
        std::mem::swap(&mut old.regular, &mut self.regular);
        std::mem::swap(&mut old.irregular, &mut self.irregular);
        old.ext1_len = old.ext1.len();
        self.row_at.clear();
        self.fixed_in_order.clear();
        self.active.clear();
        self.active_cells.clear();
        self.reuse.clear();
        self.fixed.clear();
        self.stencil.clear();
        self.diag.clear();
        self.nbr.clear();
        self.self_diag.clear();
        self.runs.clear();
        self.regular.clear();
        self.irregular.clear();
        self.ghosts.clear();
        self.ext1.clear();
        self.ext2.clear();
        for v in &mut self.ext_reuse {
            v.clear();
        }
        self.ext_start.clear();
        self.ext_src.clear();

        let labels = grid.labels();
        let cell_periodic = grid.periodic();
        // Classes of the dirty faces: active and fixed ones first, then the layers.
        for &f in &self.dirty {
            if level(&self.marked, face_index(f)) != NEAR {
                continue;
            }
            let f = f.map(|x| x as usize);
            let (li, ui) = face_cell_indices(cdims, cell_periodic, c, f);
            let class = face_class(label_or_solid(labels, li), label_or_solid(labels, ui));
            self.class[f[0] + d[0] * (f[1] + d[1] * f[2])] = class;
        }
        let fstride = [1, d[0], d[0] * d[1]];
        // Layers: the OTHER faces next to a face of the layer inside (the neighbour relation is
        // symmetric). Within a layer no face reads another's new class.
        for (layer, from) in [(EXT1, ACTIVE), (EXT2, EXT1)] {
            for &f in &self.dirty {
                let f = f.map(|x| x as usize);
                let idx = f[0] + d[0] * (f[1] + d[1] * f[2]);
                if self.class[idx] != OTHER || (layer == EXT1 && level(&self.marked, idx) != NEAR) {
                    continue;
                }
                let next_to_inside = neighbours(layout, c, f, idx, fstride)
                    .into_iter()
                    .flatten()
                    .any(|g| self.class[g] == from);
                if next_to_inside {
                    self.class[idx] = layer;
                }
            }
        }

        // The lists in index order. A clean row's entries are the last build's, as whole slices
        // (its faces get their new compact indices and layer positions); a dirty row's come from
        // its classes (eight at a time: most rows hold no tracked face), where a face carried over
        // still holds its previous compact index (or layer position): the dirty faces were reset
        // to NONE.
        let rows = d[1] * d[2];
        let mut row = 0;
        while row < rows {
            if !self.row_dirty[row] {
                // A stretch of clean rows: their entries are contiguous in every old list, so
                // they move as one slice per list.
                let end = self.clean_stretch_end(row);
                let (from, to) = (old.row_at[row], old.row_at[end]);
                let now = self.list_lengths();
                for at in &old.row_at[row..end] {
                    self.row_at
                        .push(std::array::from_fn(|l| now[l] + (at[l] - from[l])));
                }
                row = end;
                let span = |l: usize| from[l] as usize..to[l] as usize;
                let (a, n0) = (span(0), self.active.len() as u32);
                for (k, &idx) in old.active[a.clone()].iter().enumerate() {
                    self.compact[idx as usize] = n0 + k as u32;
                }
                self.active.extend_from_slice(&old.active[a.clone()]);
                self.active_cells
                    .extend_from_slice(&old.active_cells[a.clone()]);
                self.reuse.extend(a.start as u32..a.end as u32);
                for l in 0..2 {
                    let (q, list, was) = if l == 0 {
                        (span(1), &mut self.ext1, &old.ext1)
                    } else {
                        (span(2), &mut self.ext2, &old.ext2)
                    };
                    let p0 = list.len() as u32;
                    for (k, &idx) in was[q.clone()].iter().enumerate() {
                        self.ext_pos[idx as usize] = p0 + k as u32;
                    }
                    list.extend_from_slice(&was[q.clone()]);
                    let at = if l == 0 { 0 } else { old.ext1_len as u32 };
                    self.ext_reuse[l].extend((q.start as u32..q.end as u32).map(|q| at + q));
                }
                self.fixed_in_order
                    .extend_from_slice(&old.fixed_in_order[span(3)]);
                continue;
            }
            self.row_at.push(self.list_lengths());
            let (fj, fk) = (row % d[1], row / d[1]);
            let base = d[0] * row;
            row += 1;
            for (w, chunk) in self.class[base..base + d[0]].chunks(8).enumerate() {
                let empty = match <[u8; 8]>::try_from(chunk) {
                    Ok(word) => u64::from_ne_bytes(word) == 0,
                    Err(_) => chunk.iter().all(|&cl| cl == OTHER),
                };
                if empty {
                    continue;
                }
                for (b, &cl) in chunk.iter().enumerate() {
                    let i = 8 * w + b;
                    let idx = base + i;
                    match cl {
                        ACTIVE => {
                            let m = self.compact[idx];
                            self.compact[idx] = self.active.len() as u32;
                            self.active.push(idx as u32);
                            self.reuse.push(m);
                            self.active_cells.push(if m == NONE {
                                let (li, ui) =
                                    face_cell_indices(cdims, cell_periodic, c, [i, fj, fk]);
                                [li, ui]
                            } else {
                                old.active_cells[m as usize]
                            });
                        }
                        FIXED => {
                            let (li, ui) = face_cell_indices(cdims, cell_periodic, c, [i, fj, fk]);
                            self.fixed_in_order.push([idx as u32, li, ui]);
                        }
                        EXT1 | EXT2 => {
                            let l = usize::from(cl == EXT2);
                            let list = if l == 0 {
                                &mut self.ext1
                            } else {
                                &mut self.ext2
                            };
                            let q = self.ext_pos[idx];
                            self.ext_pos[idx] = list.len() as u32;
                            list.push(idx as u32);
                            let at = if l == 0 { 0 } else { old.ext1_len as u32 };
                            self.ext_reuse[l].push(if q == NONE { NONE } else { at + q });
                        }
                        _ => {}
                    }
                }
            }
        }
        self.row_at.push(self.list_lengths());

        // Viscous stencils. A tangential neighbour's cells are the face's own shifted by one cell
        // along that axis (wrapped on a periodic one).
        let [cnx, cny, cnz] = cdims;
        let cstride = [1, cnx, cnx * cny];
        let shift = |cell: u32, a: usize, dir: i32| -> u32 {
            if cell == NONE {
                return NONE;
            }
            let (cell, n) = (cell as usize, [cnx, cny, cnz][a]);
            let at = (cell / cstride[a]) % n;
            let to = if dir < 0 {
                if at == 0 {
                    cell + (n - 1) * cstride[a]
                } else {
                    cell - cstride[a]
                }
            } else if at + 1 == n {
                cell - (n - 1) * cstride[a]
            } else {
                cell + cstride[a]
            };
            to as u32
        };
        let mut old_ghost = 0;
        let total = self.active.len();
        let mut next = 0;
        while next < total {
            let n = next;
            let m = self.reuse[n];
            if m != NONE {
                // Carried over, a stretch of consecutive faces at a time: the same stencils (full
                // indices), the same ghosts.
                let m = m as usize;
                let mut len = 1;
                while n + len < total && self.reuse[n + len] as usize == m + len {
                    len += 1;
                }
                self.stencil.extend_from_slice(&old.stencil[m..m + len]);
                self.diag.extend_from_slice(&old.diag[m..m + len]);
                self.self_diag.extend_from_slice(&old.self_diag[m..m + len]);
                self.nbr.extend_from_slice(&old.nbr[m..m + len]);
                while old
                    .ghosts
                    .get(old_ghost)
                    .is_some_and(|g| (g[0] as usize) < m)
                {
                    old_ghost += 1;
                }
                let shift = (n as u32).wrapping_sub(m as u32);
                while let Some(g) = old
                    .ghosts
                    .get(old_ghost)
                    .filter(|g| (g[0] as usize) < m + len)
                {
                    self.ghosts
                        .push([g[0].wrapping_add(shift), g[1], g[2], g[3]]);
                    old_ghost += 1;
                }
                next += len;
                continue;
            }
            next += 1;
            let idx = self.active[n] as usize;
            let f = layout.face_coords(c, idx);
            let [li0, ui0] = self.active_cells[n];
            let interior = (0..3).all(|a| f[a] > 0 && f[a] + 1 < d[a]);
            let nbs = neighbours(layout, c, f, idx, fstride);
            let mut st = [NONE; 6];
            let mut diag = 6.0f32;
            for (d, &cs) in cstride.iter().enumerate() {
                for (s, dir) in [-1i32, 1].into_iter().enumerate() {
                    let slot = 2 * d + s;
                    let opposite = || {
                        nbs[slot ^ 1]
                            .filter(|&o| matches!(self.class[o], ACTIVE | FIXED))
                            .map_or(NONE, |o| o as u32)
                    };
                    let Some(gi) = nbs[slot] else {
                        // Beyond a non-periodic tangential boundary: wall at rest.
                        diag += 1.0;
                        self.ghosts.push([n as u32, NONE, NONE, opposite()]);
                        continue;
                    };
                    if d == c {
                        match self.class[gi] {
                            ACTIVE => st[slot] = gi as u32,
                            FIXED => st[slot] = CONST_BIT | gi as u32,
                            _ => diag -= 1.0, // outflow-outflow: zero gradient
                        }
                        continue;
                    }
                    let (li, ui) = if interior {
                        let o = cs;
                        let step = |x: u32| match x {
                            NONE => NONE,
                            x if dir < 0 => x - o as u32,
                            x => x + o as u32,
                        };
                        (step(li0), step(ui0))
                    } else {
                        (shift(li0, d, dir), shift(ui0, d, dir))
                    };
                    let (ll, ul) = (label_or_solid(labels, li), label_or_solid(labels, ui));
                    if ll.is_wall() && ul.is_wall() {
                        diag += 1.0;
                        // Only `Velocity` cells are kept (see `ghosts`).
                        let moving = |i: u32| {
                            if i != NONE && labels[i as usize] == CellLabel::Velocity {
                                i
                            } else {
                                NONE
                            }
                        };
                        self.ghosts
                            .push([n as u32, moving(li), moving(ui), opposite()]);
                    } else if ll == CellLabel::Fluid || ul == CellLabel::Fluid {
                        st[slot] = match self.class[gi] {
                            ACTIVE => gi as u32,
                            _ => CONST_BIT | gi as u32,
                        };
                    } else {
                        diag -= 1.0;
                    }
                }
            }
            let mut nbr = [idx as u32; 6];
            let mut selfs = 0.0f32;
            for (slot, &e) in nbr.iter_mut().zip(&st) {
                if e == NONE {
                    selfs += 1.0;
                } else {
                    *slot = e & !CONST_BIT;
                }
            }
            self.stencil.push(st);
            self.diag.push(diag);
            self.self_diag.push(diag + selfs);
            self.nbr.push(nbr);
        }

        // Runs of active faces, and of regular ones (see `regular`), row by row (a run never
        // crosses a row): a clean row's are the last build's, shifted to its new compact indices.
        let offs = fstride;
        let mut row = 0;
        loop {
            let now = [
                self.runs.len() as u32,
                self.regular.len() as u32,
                self.irregular.len() as u32,
            ];
            if row == rows {
                self.row_at[row][4..].copy_from_slice(&now);
                break;
            }
            if !self.row_dirty[row] {
                // A stretch of clean rows, as above.
                let end = self.clean_stretch_end(row);
                let (from, to) = (old.row_at[row], old.row_at[end]);
                for (at, was) in self.row_at[row..end].iter_mut().zip(&old.row_at[row..end]) {
                    for l in 0..3 {
                        at[4 + l] = now[l] + (was[4 + l] - from[4 + l]);
                    }
                }
                let shift = self.row_at[row][0].wrapping_sub(from[0]);
                row = end;
                let moved = |r: &[u32; 3]| [r[0], r[1].wrapping_add(shift), r[2]];
                let span = |l: usize| from[l] as usize..to[l] as usize;
                self.runs.extend(old.runs[span(4)].iter().map(moved));
                self.regular.extend(old.regular[span(5)].iter().map(moved));
                self.irregular
                    .extend(old.irregular[span(6)].iter().map(|f| Irregular {
                        n: f.n.wrapping_add(shift),
                        ..*f
                    }));
                continue;
            }
            self.row_at[row][4..].copy_from_slice(&now);
            let (a0, a1) = (
                self.row_at[row][0] as usize,
                self.row_at[row + 1][0] as usize,
            );
            row += 1;
            for n in a0..a1 {
                let idx = self.active[n];
                let push = |runs: &mut Vec<[u32; 3]>| extend_runs(runs, idx, n as u32, d[0]);
                push(&mut self.runs);
                let i = idx as usize;
                let plain = self.self_diag[n] == 6.0
                    && (0..6).all(|slot| {
                        let o = offs[slot / 2];
                        let want = if slot % 2 == 0 {
                            i.checked_sub(o)
                        } else {
                            Some(i + o)
                        };
                        want == Some(self.nbr[n][slot] as usize)
                    });
                if plain {
                    push(&mut self.regular);
                } else {
                    self.irregular.push(Irregular {
                        n: n as u32,
                        idx,
                        nbr: self.nbr[n],
                        self_diag: self.self_diag[n],
                    });
                }
            }
        }

        // Keep only `Velocity` cells in the wall-velocity pairs (again for carried faces: their
        // cells did not change), moving fixed faces first, so the per-step wall updates skip
        // label lookups and still walls.
        let moving = |i: u32| i != NONE && grid.label_at(i as usize) == CellLabel::Velocity;
        for f in &mut self.fixed_in_order {
            for cell in &mut f[1..] {
                if !moving(*cell) {
                    *cell = NONE;
                }
            }
        }
        // A stable partition (one pass each way), not a sort: only the two groups matter.
        let still = |f: &[u32; 3]| f[1] == NONE && f[2] == NONE;
        self.fixed.clear();
        self.fixed
            .extend(self.fixed_in_order.iter().filter(|f| !still(f)));
        self.fixed
            .extend(self.fixed_in_order.iter().filter(|f| still(f)));
        self.fixed_moving = self
            .fixed
            .iter()
            .take_while(|f| f[1] != NONE || f[2] != NONE)
            .count();

        // Sources of the layers' faces: the tracked neighbours (active or fixed) of a first-layer
        // face, the first-layer neighbours of a second-layer face, in slot order; carried over
        // where the face was in the same layer before and its row is clean.
        if !self.ext1.is_empty() || !self.ext2.is_empty() {
            self.ext_start.push(0);
        }
        for (l, from) in [ACTIVE, EXT1].into_iter().enumerate() {
            let faces = if l == 0 { &self.ext1 } else { &self.ext2 };
            let reuse = &self.ext_reuse[l];
            let mut next = 0;
            while next < faces.len() {
                let (idx, q) = (faces[next], reuse[next]);
                if q != NONE {
                    // A stretch of consecutive carried faces: their sources in one slice.
                    let q = q as usize;
                    let mut len = 1;
                    while next + len < faces.len() && reuse[next + len] as usize == q + len {
                        len += 1;
                    }
                    let (s0, s1) = (old.ext_start[q], old.ext_start[q + len]);
                    let shift = (self.ext_src.len() as u32).wrapping_sub(s0);
                    self.ext_src
                        .extend_from_slice(&old.ext_src[s0 as usize..s1 as usize]);
                    self.ext_start.extend(
                        old.ext_start[q + 1..=q + len]
                            .iter()
                            .map(|&e| e.wrapping_add(shift)),
                    );
                    next += len;
                    continue;
                }
                next += 1;
                {
                    let f = layout.face_coords(c, idx as usize);
                    for gi in neighbours(layout, c, f, idx as usize, fstride)
                        .into_iter()
                        .flatten()
                    {
                        let cl = self.class[gi];
                        if cl == from || (from == ACTIVE && cl == FIXED) {
                            self.ext_src.push(gi as u32);
                        }
                    }
                }
                self.ext_start.push(self.ext_src.len() as u32);
            }
        }
        self.carried = old;
        for g in self.ext_groups.iter_mut().flatten() {
            g.0.clear();
            g.1.clear();
        }
        for (n, &idx) in self.ext1.iter().chain(&self.ext2).enumerate() {
            let layer = usize::from(n >= self.ext1.len());
            let (s0, s1) = (self.ext_start[n] as usize, self.ext_start[n + 1] as usize);
            // At most six sources (one per neighbour slot).
            let g = &mut self.ext_groups[layer][s1 - s0];
            g.0.push(idx);
            g.1.extend_from_slice(&self.ext_src[s0..s1]);
        }
        for &idx in &self.previous {
            if self.class[idx as usize] == OTHER {
                self.dropped.push(idx);
            }
        }
        for &f in &self.dirty {
            self.marked[face_index(f)] = 0;
        }
    }

    /// The end of the stretch of clean face rows that starts at `row` (clean): the next dirty row,
    /// or the number of rows. Both passes of an update carry such a stretch over as one slice per
    /// list, so they must find the same stretches.
    fn clean_stretch_end(&self, row: usize) -> usize {
        let rows = self.row_dirty.len();
        (row + 1..rows).find(|&r| self.row_dirty[r]).unwrap_or(rows)
    }

    /// The lengths of the lists [`FaceSet::row_at`] indexes that are built with the classes
    /// (active, ext1, ext2, fixed); the runs' three are filled in later.
    fn list_lengths(&self) -> [u32; ROW_LISTS] {
        let n = |len: usize| len as u32;
        [
            n(self.active.len()),
            n(self.ext1.len()),
            n(self.ext2.len()),
            n(self.fixed_in_order.len()),
            0,
            0,
            0,
        ]
    }

    /// Lists the faces an update computes again: those within [`DIRTY_REACH`] of a face beside a
    /// changed cell (the faces with the cell's coordinates and the next along `c`, whose lower
    /// cell it is); every face for a build from scratch.
    fn mark_dirty(
        &mut self,
        layout: &Layout,
        c: usize,
        cdims: [usize; 3],
        changed: Option<&[u32]>,
    ) {
        let d = self.fdims;
        self.dirty.clear();
        self.full = changed.is_none();
        self.row_dirty.clear();
        self.row_dirty.resize(d[1] * d[2], self.full);
        let Some(changed) = changed else {
            for fk in 0..d[2] {
                for fj in 0..d[1] {
                    self.dirty
                        .extend((0..d[0]).map(|i| [i as u32, fj as u32, fk as u32]));
                }
            }
            return;
        };
        let [nx, ny, _] = cdims;
        let p = layout.periodic;
        for &cell in changed {
            let cell = cell as usize;
            let at = [cell % nx, (cell / nx) % ny, cell / (nx * ny)];
            for (fk, near_k) in dirty_span(at[2], usize::from(c == 2), d[2], p[2]) {
                for (fj, near_j) in dirty_span(at[1], usize::from(c == 1), d[1], p[1]) {
                    self.row_dirty[fj + d[1] * fk] = true;
                    let base = d[0] * (fj + d[1] * fk);
                    for (i, near_i) in dirty_span(at[0], usize::from(c == 0), d[0], p[0]) {
                        let level = if near_i && near_j && near_k {
                            NEAR
                        } else {
                            FAR
                        };
                        let m = &mut self.marked[base + i];
                        if *m == 0 {
                            self.dirty.push([i as u32, fj as u32, fk as u32]);
                        }
                        if *m == 0 || level < *m {
                            *m = level;
                        }
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fresh(grid: &FluidGrid, layout: &Layout, c: usize) -> FaceSet {
        let mut set = FaceSet::default();
        set.rebuild(grid, layout, c);
        set
    }

    fn tracked(set: &FaceSet) -> Vec<u32> {
        let fixed = set.fixed.iter().map(|f| f[0]);
        let mut all: Vec<u32> = set.active.iter().copied().chain(fixed).collect();
        all.extend(set.ext1.iter().chain(&set.ext2));
        all.sort_unstable();
        all
    }

    /// One random relabelling of the kinds a moving wall makes: scattered cells, a whole x row or
    /// a plane (a row emptying or filling entirely), a slab of the box's first or last rows (the
    /// edges, where periodic axes wrap), or a wall advancing by one layer of cells.
    fn relabel(grid: &mut FluidGrid, rng: &mut fastrand::Rng, labels: &[CellLabel]) {
        let dims = grid.dims();
        let l = labels[rng.usize(..labels.len())];
        let mut set = |cell: [usize; 3], l: CellLabel| grid.set_label(cell, l).unwrap();
        let edge = |rng: &mut fastrand::Rng, n: usize| if rng.bool() { 0 } else { n - 1 };
        match rng.u8(..6) {
            0 => {
                for _ in 0..rng.usize(1..12) {
                    let cell = dims.map(|n| rng.usize(..n));
                    set(cell, labels[rng.usize(..labels.len())]);
                }
            }
            1 => {
                let (j, k) = (rng.usize(..dims[1]), rng.usize(..dims[2]));
                for i in 0..dims[0] {
                    set([i, j, k], l);
                }
            }
            2 | 3 => {
                // A plane normal to a random axis, on the box's edge half of the time.
                let a = rng.usize(..3);
                let at = if rng.bool() {
                    edge(rng, dims[a])
                } else {
                    rng.usize(..dims[a])
                };
                for n in 0..dims.iter().product::<usize>() {
                    let cell = grid_coords(dims, n);
                    if cell[a] == at {
                        set(cell, l);
                    }
                }
            }
            4 => {
                // A wall advancing along y or z: each column's first non-wall cell becomes wall.
                let a = 1 + rng.usize(..2);
                let wall = [CellLabel::Solid, CellLabel::Velocity][rng.usize(..2)];
                let (b, nb) = if a == 1 { (2, dims[2]) } else { (1, dims[1]) };
                for i in 0..dims[0] {
                    for t in 0..nb {
                        let mut cell = [i, 0, 0];
                        cell[b] = t;
                        let first_open = (0..dims[a]).find(|&x| {
                            cell[a] = x;
                            !grid.label(cell).unwrap().is_wall()
                        });
                        if let Some(x) = first_open {
                            cell[a] = x;
                            grid.set_label(cell, wall).unwrap();
                        }
                    }
                }
            }
            _ => {
                // A block of fluid opening somewhere (the fluid region appearing).
                let lo = dims.map(|n| rng.usize(..n));
                let hi = [0, 1, 2].map(|a| (lo[a] + rng.usize(1..4)).min(dims[a]));
                for k in lo[2]..hi[2] {
                    for j in lo[1]..hi[1] {
                        for i in lo[0]..hi[0] {
                            set([i, j, k], CellLabel::Fluid);
                        }
                    }
                }
            }
        }
    }

    fn grid_coords(dims: [usize; 3], n: usize) -> [usize; 3] {
        [
            n % dims[0],
            (n / dims[0]) % dims[1],
            n / (dims[0] * dims[1]),
        ]
    }

    /// The update recomputes only the faces near the changed cells and carries the others
    /// over: after every relabelling of a random sequence (including rows emptying and
    /// filling, walls advancing and the box's edges) it must equal a build from scratch, field
    /// by field, and report as dropped exactly the faces no longer tracked.
    #[test]
    fn an_update_after_relabelling_equals_a_fresh_build() {
        let labels = [
            CellLabel::Fluid,
            CellLabel::Solid,
            CellLabel::Velocity,
            CellLabel::Outflow,
        ];
        // Small boxes (most faces on an end of the array) and a larger one (interior faces).
        for (seed, (periodic, dims)) in [
            ([false; 3], [9, 7, 6]),
            ([true, false, true], [9, 7, 6]),
            ([false, true, false], [9, 7, 6]),
            ([false; 3], [16, 13, 12]),
            ([true, true, false], [14, 12, 11]),
            ([false, true, true], [11, 9, 10]),
            ([false; 3], [5, 4, 3]),
            ([false, true, false], [7, 1, 6]),
            ([false, true, false], [7, 2, 6]),
            ([true, false, true], [1, 5, 2]),
        ]
        .into_iter()
        .enumerate()
        {
            let mut rng = fastrand::Rng::with_seed(11 + seed as u64);
            let mut grid = FluidGrid::new(dims, 1e-3, [0.0; 3], periodic).unwrap();
            // Start mostly solid: a sparse fluid region, as in the uterine scene.
            for k in 0..dims[2] {
                for j in 0..dims[1] {
                    for i in 0..dims[0] {
                        let l = if rng.f32() < 0.6 {
                            CellLabel::Solid
                        } else {
                            labels[rng.usize(..labels.len())]
                        };
                        grid.set_label([i, j, k], l).unwrap();
                    }
                }
            }
            let layout = Layout::new(dims, periodic);
            let mut rows = Vec::new();
            let mut diff = LabelDiff::default();
            let mut sets: [FaceSet; 3] = Default::default();
            for step in 0..120 {
                if step > 0 {
                    relabel(&mut grid, &mut rng, &labels);
                }
                let diffed = diff.update(grid.labels(), dims[0]);
                assert_eq!(diffed, step > 0);
                update_open_row_ranges(&grid, diffed.then(|| diff.rows()), &mut rows);
                let changed = diffed.then(|| diff.cells());
                let mut want_rows = Vec::new();
                open_row_ranges(&grid, &mut want_rows);
                assert_eq!(rows, want_rows, "open row ranges, step {step}");
                for (c, set) in sets.iter_mut().enumerate() {
                    let before = tracked(set);
                    set.update(&grid, &layout, c, changed);
                    let want = fresh(&grid, &layout, c);
                    let at = format!("component {c}, {periodic:?} {dims:?}, step {step}");
                    assert_eq!(set.class, want.class, "class, {at}");
                    assert_eq!(set.compact, want.compact, "compact, {at}");
                    assert_eq!(set.active, want.active, "active, {at}");
                    assert_eq!(set.active_cells, want.active_cells, "{at}");
                    assert_eq!(set.fixed, want.fixed, "fixed, {at}");
                    assert_eq!(set.fixed_moving, want.fixed_moving, "{at}");
                    assert_eq!(set.stencil, want.stencil, "stencil, {at}");
                    assert_eq!(set.diag, want.diag, "diag, {at}");
                    assert_eq!(set.nbr, want.nbr, "nbr, {at}");
                    assert_eq!(set.self_diag, want.self_diag, "{at}");
                    assert_eq!(set.runs, want.runs, "runs, {at}");
                    assert_eq!(set.regular, want.regular, "{at}");
                    assert_eq!(
                        format!("{:?}", set.irregular),
                        format!("{:?}", want.irregular),
                        "irregular, {at}"
                    );
                    assert_eq!(set.ghosts, want.ghosts, "ghosts, {at}");
                    assert_eq!(set.ext1, want.ext1, "ext1, {at}");
                    assert_eq!(set.ext2, want.ext2, "ext2, {at}");
                    assert_eq!(set.ext_pos, want.ext_pos, "layer positions, {at}");
                    assert_eq!(set.ext_start, want.ext_start, "{at}");
                    assert_eq!(set.ext_src, want.ext_src, "ext sources, {at}");
                    for (a, b) in set
                        .ext_groups
                        .iter()
                        .flatten()
                        .zip(want.ext_groups.iter().flatten())
                    {
                        assert_eq!(a, b, "{at}");
                    }
                    let now = tracked(set);
                    let mut dropped = set.dropped.clone();
                    dropped.sort_unstable();
                    let expected: Vec<u32> = before
                        .into_iter()
                        .filter(|f| now.binary_search(f).is_err())
                        .collect();
                    assert_eq!(dropped, expected, "dropped faces, {at}");
                }
            }
        }
    }

    #[test]
    fn neighbour_index_and_coords_step_one_face_and_wrap_on_periodic_axes() {
        for periodic in [[false; 3], [true, true, true], [true, false, true]] {
            let layout = Layout::new([4, 3, 5], periodic);
            for c in 0..3 {
                for idx in 0..layout.face_count(c) {
                    let f = layout.face_coords(c, idx);
                    for d in 0..3 {
                        let n = layout.fdims[c][d] as i64;
                        for dir in [-1i32, 1] {
                            let g = f[d] as i64 + dir as i64;
                            let want = if (0..n).contains(&g) || periodic[d] {
                                let mut h = f;
                                h[d] = g.rem_euclid(n) as usize;
                                Some(layout.face_index(c, h))
                            } else {
                                None
                            };
                            assert_eq!(neighbour_index(&layout, c, f, idx, d, dir), want);
                            if let Some(w) = want {
                                let g = neighbour_coords(&layout, c, f, d, dir);
                                assert_eq!(layout.face_index(c, g), w);
                            }
                        }
                    }
                }
            }
        }
    }

    /// The scan a fresh build makes: every face of the array classified (the reference the
    /// row-restricted classification must match).
    #[test]
    fn the_row_restricted_classification_matches_a_scan_of_every_face() {
        for periodic in [[false; 3], [true, true, true]] {
            let mut rng = fastrand::Rng::with_seed(3);
            let dims = [6, 5, 4];
            let mut grid = FluidGrid::new(dims, 1e-3, [0.0; 3], periodic).unwrap();
            for n in 0..grid.cell_count() {
                let cell = grid.coords(n);
                let l = [
                    CellLabel::Fluid,
                    CellLabel::Solid,
                    CellLabel::Outflow,
                    CellLabel::Velocity,
                ][rng.usize(..4)];
                grid.set_label(cell, l).unwrap();
            }
            let layout = Layout::new(dims, periodic);
            for c in 0..3 {
                let set = fresh(&grid, &layout, c);
                for idx in 0..layout.face_count(c) {
                    let (lo, up) = face_cells(&grid, c, layout.face_coords(c, idx));
                    let (ll, _) = label_of(&grid, lo);
                    let (ul, _) = label_of(&grid, up);
                    let open = |l: CellLabel| matches!(l, CellLabel::Fluid | CellLabel::Outflow);
                    let want_active = !ll.is_wall()
                        && !ul.is_wall()
                        && (ll == CellLabel::Fluid || ul == CellLabel::Fluid);
                    let want_fixed = (ll.is_wall() || ul.is_wall()) && (open(ll) || open(ul));
                    assert_eq!(set.class[idx] == ACTIVE, want_active, "face {idx} c {c}");
                    assert_eq!(set.class[idx] == FIXED, want_fixed, "face {idx} c {c}");
                    if let Ok(n) = set.active.binary_search(&(idx as u32)) {
                        let (_, li) = label_of(&grid, lo);
                        let (_, ui) = label_of(&grid, up);
                        assert_eq!(set.active_cells()[n], [li, ui], "face {idx} c {c}");
                    }
                }
            }
        }
    }

    /// The stencils and extrapolation layers by the definitions, face by face over the whole
    /// array (cells by [`face_cells`], neighbours by [`neighbour_index`] and
    /// [`neighbour_coords`]): the reference for the rebuild's shortcuts (kept cells shifted to a
    /// tangential neighbour, plain offsets off the array's ends, layers found from the inside).
    #[test]
    fn stencils_and_layers_match_their_definitions() {
        for (periodic, dims) in [
            ([false; 3], [12, 10, 9]),
            ([true, false, true], [10, 9, 8]),
            ([false, true, true], [9, 11, 10]),
        ] {
            let mut rng = fastrand::Rng::with_seed(17);
            let mut grid = FluidGrid::new(dims, 1e-3, [0.0; 3], periodic).unwrap();
            for n in 0..grid.cell_count() {
                let l = if rng.f32() < 0.3 {
                    CellLabel::Fluid
                } else {
                    [CellLabel::Solid, CellLabel::Velocity, CellLabel::Outflow][rng.usize(..3)]
                };
                grid.set_label(grid.coords(n), l).unwrap();
            }
            let layout = Layout::new(dims, periodic);
            for c in 0..3 {
                let set = fresh(&grid, &layout, c);
                let labels_of = |f: [usize; 3]| {
                    let (lo, up) = face_cells(&grid, c, f);
                    (label_of(&grid, lo), label_of(&grid, up))
                };
                let nf = layout.face_count(c);
                for (n, &idx) in set.active.iter().enumerate() {
                    let idx = idx as usize;
                    let f = layout.face_coords(c, idx);
                    let (mut st, mut diag) = ([NONE; 6], 6.0f32);
                    for (slot, entry_of_slot) in st.iter_mut().enumerate() {
                        let (d, dir) = (slot / 2, if slot % 2 == 0 { -1 } else { 1 });
                        let Some(gi) = neighbour_index(&layout, c, f, idx, d, dir) else {
                            diag += 1.0;
                            continue;
                        };
                        let cl = set.class[gi];
                        let entry = |cl| match cl {
                            ACTIVE => gi as u32,
                            _ => CONST_BIT | gi as u32,
                        };
                        if d == c {
                            match cl {
                                ACTIVE | FIXED => *entry_of_slot = entry(cl),
                                _ => diag -= 1.0,
                            }
                            continue;
                        }
                        let ((ll, _), (ul, _)) = labels_of(neighbour_coords(&layout, c, f, d, dir));
                        if ll.is_wall() && ul.is_wall() {
                            diag += 1.0;
                        } else if ll == CellLabel::Fluid || ul == CellLabel::Fluid {
                            *entry_of_slot = entry(cl);
                        } else {
                            diag -= 1.0;
                        }
                    }
                    assert_eq!(set.stencil[n], st, "stencil of face {idx}, c {c}");
                    assert_eq!(set.diag[n], diag, "diagonal of face {idx}, c {c}");
                }
                // Layers: faces neither active nor fixed beside the layer inside, in index order,
                // with their sources in slot order.
                let nbrs = |idx: usize| {
                    let f = layout.face_coords(c, idx);
                    (0..6).filter_map(move |slot| {
                        let dir = if slot % 2 == 0 { -1 } else { 1 };
                        neighbour_index(&layout, c, f, idx, slot / 2, dir)
                    })
                };
                let tracked = |i: usize| matches!(set.class[i], ACTIVE | FIXED);
                let ext1: Vec<u32> = (0..nf)
                    .filter(|&i| !tracked(i) && nbrs(i).any(|g| set.class[g] == ACTIVE))
                    .map(|i| i as u32)
                    .collect();
                let in1 = |i: usize| ext1.binary_search(&(i as u32)).is_ok();
                let ext2: Vec<u32> = (0..nf)
                    .filter(|&i| !tracked(i) && !in1(i) && nbrs(i).any(in1))
                    .map(|i| i as u32)
                    .collect();
                assert_eq!(set.ext1, ext1, "ext1, c {c}, {periodic:?}");
                assert_eq!(set.ext2, ext2, "ext2, c {c}, {periodic:?}");
                let mut src = Vec::new();
                let mut start = vec![0u32];
                for &i in &ext1 {
                    src.extend(nbrs(i as usize).filter(|&g| tracked(g)).map(|g| g as u32));
                    start.push(src.len() as u32);
                }
                for &i in &ext2 {
                    src.extend(nbrs(i as usize).filter(|&g| in1(g)).map(|g| g as u32));
                    start.push(src.len() as u32);
                }
                assert_eq!(set.ext_src, src, "sources, c {c}, {periodic:?}");
                assert_eq!(set.ext_start, start, "source starts, c {c}, {periodic:?}");
            }
        }
    }
}
