//! Restriction and prolongation between a level and the next coarser one.

use super::level::Level;

/// The grid transfers between a level and the next coarser one, dispatched like [`SpanOp`]: each
/// coarse row of fluid cells meets four fine rows, whose cells pair up along x.
struct Transfer<'a> {
    fine: &'a Level,
    coarse: &'a Level,
    /// The coarse rows to transfer.
    rows: &'a [[u32; 4]],
    /// Padded index of element 0 of the output.
    off: usize,
    /// Restriction: the coarse right-hand side to write (`Some(scale, b)`); prolongation: the fine
    /// unknowns to correct.
    restrict: Option<(f32, &'a mut [f32])>,
    fine_x: Option<&'a mut [f32]>,
}

impl crate::simd::Kernel for Transfer<'_> {
    type Output = ();

    #[inline(always)]
    fn run(self) {
        let (fine, coarse, off) = (self.fine, self.coarse, self.off);
        let (fsy, fsz) = (fine.sy, fine.sz);
        let (mut restrict, mut fine_x) = (self.restrict, self.fine_x);
        for &[j, k, i0, i1] in self.rows {
            let (j, k, i0, i1) = (j as usize, k as usize, i0 as usize, i1 as usize);
            let c = coarse.pad(i0, j, k)..coarse.pad(i1, j, k);
            let f0 = fine.pad(2 * i0, 2 * j, 2 * k);
            let n2 = 2 * (i1 - i0);
            let rows = [f0, f0 + fsy, f0 + fsz, f0 + fsz + fsy];
            if let Some((scale, b)) = restrict.as_mut() {
                let b = &mut b[c.start - off..c.end - off];
                b.fill(0.0);
                for f in rows {
                    for (bv, r2) in b.iter_mut().zip(fine.r[f..f + n2].chunks_exact(2)) {
                        *bv += r2[0] + r2[1];
                    }
                }
                for (bv, &m) in b.iter_mut().zip(&coarse.mask[c.clone()]) {
                    *bv *= m * *scale;
                }
            }
            if let Some(x) = fine_x.as_mut() {
                let xc = &coarse.x[c.clone()];
                for f in rows {
                    let xs = x[f - off..f - off + n2].chunks_exact_mut(2);
                    let ms = fine.mask[f..f + n2].chunks_exact(2);
                    for ((x2, m2), &v) in xs.zip(ms).zip(xc) {
                        x2[0] += m2[0] * v;
                        x2[1] += m2[1] * v;
                    }
                }
            }
        }
    }
}

/// Runs a transfer over all coarse rows; on a `parallel` coarse level in two halves split at a
/// coarse plane (the fine rows of the two halves then lie in separate fine planes).
pub(super) fn transfer(fine: &Level, coarse: &Level, restrict: Option<f32>, out: &mut [f32]) {
    let rows = &coarse.row_spans[..];
    let whole = |rows, off, out: &mut [f32]| {
        let (restrict, fine_x) = match restrict {
            Some(scale) => (Some((scale, out)), None),
            None => (None, Some(out)),
        };
        crate::simd::dispatch(Transfer {
            fine,
            coarse,
            rows,
            off,
            restrict,
            fine_x,
        })
    };
    // The coarse plane whose fine planes start nearest the fine level's own split, so each
    // thread transfers the fine cells its kernels work on (the middle coarse row instead put a
    // band of fine planes on the other core every V-cycle).
    let split = fine.split_at();
    let k_mid = if fine.parallel && split < fine.mask.len() {
        // Padded plane `split / sz` is interior plane `split / sz - 1`; its coarse plane rounds up.
        (split / fine.sz / 2) as u32
    } else {
        rows.get(rows.len() / 2).map_or(0, |r| r[1])
    };
    let m = rows.partition_point(|r| r[1] < k_mid);
    if !coarse.parallel || m == 0 || m == rows.len() {
        return whole(rows, 0, out);
    }
    let k = k_mid as usize;
    let mid = if restrict.is_some() {
        coarse.sz * (k + 1)
    } else {
        fine.sz * (2 * k + 1)
    };
    let (a, b) = out.split_at_mut(mid);
    let (ra, rb) = rows.split_at(m);
    crate::fork_join::join(|| whole(ra, 0, a), || whole(rb, mid, b));
}

/// [`transfer`] over all coarse rows on one thread, compiled for the baseline only: the reference
/// of the AVX2 compilation in the tests.
#[cfg(test)]
pub(super) fn transfer_portable(
    fine: &Level,
    coarse: &Level,
    restrict: Option<f32>,
    out: &mut [f32],
) {
    use crate::simd::Kernel;
    let (restrict, fine_x) = match restrict {
        Some(scale) => (Some((scale, out)), None),
        None => (None, Some(out)),
    };
    Transfer {
        fine,
        coarse,
        rows: &coarse.row_spans,
        off: 0,
        restrict,
        fine_x,
    }
    .run()
}

/// `coarse.b = scale * (sum of the children's residuals)` on the coarse fluid cells.
pub(super) fn restrict(fine: &Level, coarse: &mut Level, scale: f32) {
    let mut b = std::mem::take(&mut coarse.b);
    transfer(fine, coarse, Some(scale), &mut b);
    coarse.b = b;
}

/// `fine.x += coarse.x` of the parent on every fine fluid cell.
pub(super) fn prolongate(coarse: &Level, fine: &mut Level) {
    let mut x = std::mem::take(&mut fine.x);
    transfer(fine, coarse, None, &mut x);
    fine.x = x;
}
