//! The cell-centred velocity the traces follow: the mean of the faces around each cell, on the
//! rows near open cells only (or every cell), with an AVX2 path per row.

use super::super::sample::Layout;
#[cfg(target_arch = "x86_64")]
use super::avx2;
use crate::simd::{v4, V4};

/// How far (cells, along every axis) from an open (fluid or outflow) cell the centred velocity
/// can be non-zero. Only tracked faces hold velocity (see `FluidSolver::set_velocity_field`): a
/// fixed face touches an open cell; an active face lies between two open cells, and the
/// extrapolation layers reach two face steps from it. A cell averages the two faces on its sides
/// along each axis, so a cell that reads a face two steps beyond the active face between open
/// cells `i - 1` and `i` lies at `i - 3` or `i + 2`: two cells from an open cell. The test
/// `centred_velocity_on_the_open_rows_equals_the_whole_box` fails with 1.
pub(crate) const CENTRED_REACH: usize = 2;

/// The cells whose centred velocity [`update_centred`] computes: per cell row `j + ny k` the x
/// range `[first, end)` (empty: `first >= end`), and the z-slab that splits the work in halves.
#[derive(Clone, Debug, Default)]
pub(crate) struct CentredRows {
    pub ranges: Vec<[u32; 2]>,
    pub split_k: usize,
    /// Scratch: the ranges before the update, and the ranges dilated along y only.
    prev: Vec<[u32; 2]>,
    along_y: Vec<[u32; 2]>,
}

impl CentredRows {
    /// The rows' open ranges `open` (per cell row, `[0, 0]`: none) dilated by [`CENTRED_REACH`]
    /// cells along x, y and z (a box, so it holds the reach in any direction); the cells that
    /// leave the ranges are zeroed in `centred` (those that join hold zero: nothing wrote them
    /// since they last left).
    pub fn update(&mut self, open: &[[u32; 2]], dims: [usize; 3], centred: &mut [V4]) {
        let [nx, ny, nz] = dims;
        let r = CENTRED_REACH;
        let hull = super::super::topology::range_hull;
        // Along y, then along z, then widened along x.
        let tmp = &mut self.along_y;
        tmp.clear();
        tmp.resize(ny * nz, [0, 0]);
        for k in 0..nz {
            for j in 0..ny {
                let rows = j.saturating_sub(r)..(j + r + 1).min(ny);
                tmp[j + ny * k] = rows.fold([0, 0], |h, jj| hull(h, open[jj + ny * k]));
            }
        }
        std::mem::swap(&mut self.ranges, &mut self.prev);
        self.ranges.clear();
        for k in 0..nz {
            for j in 0..ny {
                let slabs = k.saturating_sub(r)..(k + r + 1).min(nz);
                let [a, b] = slabs.fold([0, 0], |h, kk| hull(h, tmp[j + ny * kk]));
                self.ranges.push(if a < b {
                    [a.saturating_sub(r as u32), (b + r as u32).min(nx as u32)]
                } else {
                    [0, 0]
                });
            }
        }
        // The z-slab before which half the work lies: a row's cells and its fixed cost.
        let slab_cells = |k: usize| -> usize {
            let ranges = &self.ranges[ny * k..ny * (k + 1)];
            ranges
                .iter()
                .filter(|&&[a, b]| a < b)
                .map(|&[a, b]| (b - a) as usize + ROW_COST)
                .sum()
        };
        let cells: usize = (0..nz).map(slab_cells).sum();
        let mut done = 0;
        self.split_k = (0..nz)
            .find(|&k| {
                done += slab_cells(k);
                2 * done >= cells
            })
            .map_or(nz, |k| k + 1);
        // Cells that left the ranges.
        if self.prev.len() == self.ranges.len() {
            for (row, (&[oa, ob], &[na, nb])) in self.prev.iter().zip(&self.ranges).enumerate() {
                let base = nx * row;
                let mut zero = |a: u32, b: u32| {
                    if a < b {
                        centred[base + a as usize..base + b as usize].fill(v4::zero());
                    }
                };
                if na >= nb {
                    zero(oa, ob);
                } else {
                    zero(oa, ob.min(na));
                    zero(oa.max(nb), ob);
                }
            }
        } else {
            centred.fill(v4::zero());
        }
    }
}

/// The fixed cost of a row of [`update_centred`], in cells: its halves, balanced by cells alone,
/// took 88 and 44 us on the 0.6 mm scene, the fragmented end of the cavity (many short rows) in
/// the first; 32 gave 70 / 54 us, 64 gives 46-49 / 47-49 us (BENCHMARKS.md, "Residual maximum and
/// the split, session 13").
const ROW_COST: usize = 64;

/// Averages the face velocities to the (padded) cell centres, row by row (z-slabs in parallel if
/// `parallel`): every cell, or only the cells of `rows` (not on a periodic layout).
pub(crate) fn update_centred(
    layout: &Layout,
    dims: [usize; 3],
    u: [&[f32]; 3],
    out: &mut [V4],
    rows: Option<&CentredRows>,
    parallel: bool,
) {
    let [nx, ny, nz] = dims;
    let fd = layout.fdims;
    let p = layout.periodic;
    debug_assert!(rows.is_none() || p == [false; 3]);
    let slab = |(k, slab): (usize, &mut [V4])| {
        let k1 = if k + 1 == nz && p[2] { 0 } else { k + 1 };
        for j in 0..ny {
            let [a, b] = match rows {
                Some(r) => r.ranges[j + ny * k].map(|v| v as usize),
                None => [0, nx],
            };
            if a >= b {
                continue;
            }
            let j1 = if j + 1 == ny && p[1] { 0 } else { j + 1 };
            let row = &mut slab[nx * j..nx * (j + 1)];
            let r0 = fd[0][0] * (j + fd[0][1] * k);
            let x = &u[0][r0..r0 + fd[0][0]];
            let y0 = &u[1][nx * (j + fd[1][1] * k)..][..nx];
            let y1 = &u[1][nx * (j1 + fd[1][1] * k)..][..nx];
            let z0 = &u[2][nx * (j + ny * k)..][..nx];
            let z1 = &u[2][nx * (j + ny * k1)..][..nx];
            // The AVX2 rows do the full groups of eight cells whose upper x face is in the row.
            let mut done = a;
            #[cfg(target_arch = "x86_64")]
            if crate::simd::avx2_fma() {
                let (xs, ys, zs) = (&x[a..], [&y0[a..b], &y1[a..b]], [&z0[a..b], &z1[a..b]]);
                // SAFETY: the CPU has AVX2 and FMA (checked by `available`).
                done += unsafe { avx2::centred_row(&mut row[a..b], xs, ys, zs) };
            }
            for (i, cell) in row.iter_mut().enumerate().take(b).skip(done) {
                // The last x face wraps to the first on a periodic axis.
                let xh = if i + 1 < x.len() { x[i + 1] } else { x[0] };
                *cell = v4::new(
                    0.5 * (x[i] + xh),
                    0.5 * (y0[i] + y1[i]),
                    0.5 * (z0[i] + z1[i]),
                );
            }
        }
    };
    let slabs = |first: usize, out: &mut [V4]| {
        for (k, sl) in out.chunks_mut(nx * ny).enumerate() {
            slab((first + k, sl));
        }
    };
    let mid = rows.map_or(nz / 2, |r| r.split_k);
    if parallel && nz >= 2 && mid > 0 && mid < nz {
        let (a, b) = out.split_at_mut(mid * nx * ny);
        crate::fork_join::join(|| slabs(0, a), || slabs(mid, b));
    } else {
        slabs(0, out);
    }
}
