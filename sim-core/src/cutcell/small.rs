//! The small-cell rule: a cell with a fluid volume fraction in `(round_off, min_volume_fraction)`
//! is merged into the face neighbour, among those with at least `min_volume_fraction`, with which
//! it shares the largest open face (ties: the first of -x, +x, -y, +y, -z, +z); its volume moves
//! there, so the stabilised volumes sum to the exact ones. A small cell with no such neighbour (a
//! slit thinner than the threshold everywhere around it) stays as it is, unmerged. A cell holding
//! no more than `round_off` (rounding where a surface passes a corner or lies in a face) is empty
//! in the stabilised output, its dust dropped.

use crate::scene::voxelize::VoxelBox;

/// No merge target.
pub const NO_TARGET: u32 = u32::MAX;

/// The six face neighbours of cell `(i, j, k)` in the rule's order, with the index of the face
/// between them along its axis: `(axis, neighbour cell, face index)`; `None` outside the box.
#[inline]
pub(crate) fn neighbours(
    cells: &VoxelBox,
    i: usize,
    j: usize,
    k: usize,
) -> [Option<(usize, usize, usize)>; 6] {
    let [nx, ny, nz] = cells.dims;
    let n = cells.index(i, j, k);
    let fx = |i: usize| i + (nx + 1) * (j + ny * k);
    let fy = |j: usize| i + nx * (j + (ny + 1) * k);
    let fz = |k: usize| i + nx * (j + ny * k);
    [
        (i > 0).then(|| (0, n - 1, fx(i))),
        (i + 1 < nx).then(|| (0, n + 1, fx(i + 1))),
        (j > 0).then(|| (1, n - nx, fy(j))),
        (j + 1 < ny).then(|| (1, n + nx, fy(j + 1))),
        (k > 0).then(|| (2, n - nx * ny, fz(k))),
        (k + 1 < nz).then(|| (2, n + nx * ny, fz(k + 1))),
    ]
}

/// The merge target of cell `(i, j, k)` ([`NO_TARGET`] when it is not small or has no
/// neighbour to merge into).
#[inline]
pub(crate) fn target(
    cells: &VoxelBox,
    volume: &[f64],
    faces: &[Vec<f64>; 3],
    min_volume_fraction: f64,
    round_off: f64,
    (i, j, k): (usize, usize, usize),
) -> u32 {
    let v = volume[cells.index(i, j, k)];
    if !(v > round_off && v < min_volume_fraction) {
        return NO_TARGET;
    }
    let mut best = NO_TARGET;
    // A face open by rounding alone does not connect.
    let mut best_area = round_off;
    for (axis, m, f) in neighbours(cells, i, j, k).into_iter().flatten() {
        let a = faces[axis][f];
        if volume[m] >= min_volume_fraction && a > best_area {
            best_area = a;
            best = m as u32;
        }
    }
    best
}

/// The stabilised volume of cell `(i, j, k)`: its own unless merged away or rounding, plus that
/// of every neighbour merged into it, in the rule's neighbour order.
#[inline]
pub(crate) fn stabilised(
    cells: &VoxelBox,
    volume: &[f64],
    targets: &[u32],
    round_off: f64,
    (i, j, k): (usize, usize, usize),
) -> f64 {
    let [nx, ny, nz] = cells.dims;
    let n = cells.index(i, j, k);
    let own = volume[n];
    let mut v = if targets[n] == NO_TARGET && own > round_off {
        own
    } else {
        0.0
    };
    // The neighbours of [`neighbours`], in its order, by cell alone: this runs for every cell of
    // every row near a change (each frame the scene's surface moves), the faces are not needed.
    let me = n as u32;
    let (sy, sz) = (nx, nx * ny);
    let mut add = |m: usize| {
        if targets[m] == me {
            v += volume[m];
        }
    };
    if i > 0 {
        add(n - 1);
    }
    if i + 1 < nx {
        add(n + 1);
    }
    if j > 0 {
        add(n - sy);
    }
    if j + 1 < ny {
        add(n + sy);
    }
    if k > 0 {
        add(n - sz);
    }
    if k + 1 < nz {
        add(n + sz);
    }
    v
}
