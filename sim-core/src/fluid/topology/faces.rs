//! A face's two cells and class from the labels, its neighbour faces (wrapped on periodic axes),
//! the runs of consecutive active faces, and the wall velocity of a pair of cells.

use super::super::grid::FluidGrid;
use super::super::sample::Layout;
use super::super::CellLabel;
use super::{ACTIVE, FIXED, NONE, OTHER};

/// The six neighbours of face `idx` (coordinates `f`, component `c`) in stencil-slot order
/// (-x, +x, -y, +y, -z, +z), as [`neighbour_index`] finds them; `strides` are the face array's.
/// A face off every end of the array takes the plain offsets without a test per slot.
#[inline(always)]
pub(super) fn neighbours(
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

#[cfg(test)]
pub(super) fn label_of(grid: &FluidGrid, cell: Option<[usize; 3]>) -> (CellLabel, u32) {
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
pub(super) fn face_cells(
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
pub(crate) fn face_cell_indices(
    dims: [usize; 3],
    periodic: [bool; 3],
    c: usize,
    f: [usize; 3],
) -> (u32, u32) {
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
pub(super) fn label_or_solid(labels: &[CellLabel], cell: u32) -> CellLabel {
    labels
        .get(cell as usize)
        .copied()
        .unwrap_or(CellLabel::Solid)
}

/// Class of a face from the labels of its two cells: fixed between a wall and an open cell,
/// active between non-walls of which one is fluid.
#[inline]
pub(super) fn face_class(lower: CellLabel, upper: CellLabel) -> u8 {
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
