//! Face classification derived from the cell labels: which faces the solver updates (active), which
//! carry a prescribed normal velocity (fixed), which are extrapolated for sampling, and the viscous
//! stencil of every active face. Updated only when a label changes, near the changed cells, into
//! reused buffers.
//!
//! - `rows.rs`: what changed since the last build (labels, row by row) and the x range of the
//!   open cells of every row;
//! - `faces.rs`: a face's cells, class and neighbours, and the wall velocity of a pair of cells;
//! - `update.rs`: [`FaceSet::update`], the classification, stencils, runs and extrapolation
//!   sources, computed again only near the changed cells.

mod faces;
mod rows;
#[cfg(test)]
mod tests;
mod update;

#[cfg(test)]
pub(crate) use faces::extend_runs;
pub(crate) use faces::{face_cell_indices, neighbour_index, wall_velocity};
pub(crate) use rows::{open_row_ranges, range_hull, update_open_row_ranges, LabelDiff};

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
