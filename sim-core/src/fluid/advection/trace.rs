//! One advection pass's inputs ([`Pass`]) and its scalar kernels, a block of faces at a time:
//! the RK2 trace with the foot-point sample (and, for MacCormack, the forward foot) and
//! MacCormack's correction. They are the fallback where the CPU has no AVX2 and the reference
//! the AVX2 kernels (`avx2.rs`) equal to the bit (`tests.rs`).

use super::geometry::Geometry;
use super::plan::{Plan, BLOCK};
use crate::simd::{v4, V4};

/// Faces per chunk of the trace's split loops.
const CHAIN: usize = 64;

/// Read-only inputs of one advection pass.
pub(crate) struct Pass<'a> {
    pub geo: &'a Geometry,
    pub plan: &'a Plan,
    /// Padded cell-centred velocity for the trace.
    pub vc: &'a [V4],
    /// Fields sampled at the foot points, per component.
    pub src: [&'a [f32]; 3],
    /// dt / h; negative for the forward trace of MacCormack.
    pub dt_cells: f32,
}

impl Pass<'_> {
    /// [`Pass::block`] one face at a time (the fallback, and the reference of the AVX2 kernel).
    #[inline(always)]
    pub(super) fn block_scalar<const BOUNDS: bool>(
        &self,
        b: usize,
        mut each: impl FnMut(usize, (f32, f32, f32)),
    ) {
        let geo = self.geo;
        self.trace_scalar::<false>(
            b,
            |c, src, p| geo.sample::<BOUNDS>(c, src, p),
            |n, r, _| each(n, r),
        )
    }

    /// [`Pass::block_scalar`] with the foot-point sampler `sample(component, field, point)`.
    #[inline(always)]
    pub(super) fn block_scalar_with(
        &self,
        b: usize,
        sample: impl Fn(usize, &[f32], V4) -> (f32, f32, f32),
        mut each: impl FnMut(usize, (f32, f32, f32)),
    ) {
        self.trace_scalar::<false>(b, sample, |n, r, _| each(n, r))
    }

    /// [`Pass::block_scalar_with`], and with `FORWARD` also the foot point of the forward trace
    /// (the trace of this pass with `-dt_cells`, to the bit; zero without `FORWARD`):
    /// `each(position within the block, sample, forward foot)`.
    #[inline(always)]
    pub(super) fn trace_scalar<const FORWARD: bool>(
        &self,
        b: usize,
        sample: impl Fn(usize, &[f32], V4) -> (f32, f32, f32),
        mut each: impl FnMut(usize, (f32, f32, f32), V4),
    ) {
        let plan = self.plan;
        let runs = &plan.runs[plan.block_runs[b] as usize..plan.block_runs[b + 1] as usize];
        let base = b * BLOCK;
        let (geo, v, dt) = (self.geo, self.vc, self.dt_cells);
        let dt_f = -dt;
        for run in runs {
            let c = run.c as usize;
            let f0 = run.f.map(|v| v as usize);
            let src = self.src[c];
            let o = run.compact as usize - base;
            let sh: [f32; 3] = std::array::from_fn(|a| if a == c { 0.0 } else { 0.5 });
            let mut x0 = v4::new(
                f0[0] as f32 + sh[0],
                f0[1] as f32 + sh[1],
                f0[2] as f32 + sh[2],
            );
            let step = v4::new(1.0, 0.0, 0.0);
            // Three short loops over a chunk instead of one long one: each face's work is a
            // chain of dependent loads (velocity -> midpoint -> velocity -> foot -> samples),
            // and independent iterations let the CPU overlap many chains.
            let len = run.len as usize;
            let mut start = 0;
            while start < len {
                let n = (len - start).min(CHAIN);
                let mut pts = [v4::zero(); CHAIN];
                let mut pts_f = [v4::zero(); CHAIN];
                let mut x = x0;
                for i in 0..n {
                    // At the face the centred field is the mean of the two cells beside it.
                    let (lo, hi) = geo.face_cells(c, [f0[0] + start + i, f0[1], f0[2]]);
                    let vf = v4::lerp(v[lo], v[hi], v4::splat(0.5));
                    pts[i] = v4::sub_scaled(x, 0.5 * dt, vf);
                    if FORWARD {
                        pts_f[i] = v4::sub_scaled(x, 0.5 * dt_f, vf);
                    }
                    x = v4::add(x, step);
                }
                let mut x = x0;
                for i in 0..n {
                    pts[i] = v4::sub_scaled(x, dt, geo.centred(v, pts[i]));
                    if FORWARD {
                        pts_f[i] = v4::sub_scaled(x, dt_f, geo.centred(v, pts_f[i]));
                    }
                    x = v4::add(x, step);
                }
                for i in 0..n {
                    each(o + start + i, sample(c, src, pts[i]), pts_f[i]);
                }
                x0 = x;
                start += n;
            }
        }
    }

    /// [`Pass::maccormack_correct`] on block `b` one face at a time (the fallback, and the
    /// reference of the AVX2 kernel): `foot`, `lo`, `hi` and `out` are the block's slices.
    pub(super) fn correct_scalar(
        &self,
        b: usize,
        orig: [&[f32]; 3],
        [xs, ys, zs]: [&[f32]; 3],
        [ls, hs]: [&[f32]; 2],
        os: &mut [f32],
    ) {
        let (plan, base) = (self.plan, b * BLOCK);
        let runs = &plan.runs[plan.block_runs[b] as usize..plan.block_runs[b + 1] as usize];
        for run in runs {
            let c = run.c as usize;
            let (o, full) = (run.compact as usize - base, run.full as usize);
            for i in 0..run.len as usize {
                let n = o + i;
                let p = v4::new(xs[n], ys[n], zs[n]);
                let (back, _, _) = self.geo.sample::<false>(c, self.src[c], p);
                os[n] = maccormack_value(os[n], orig[c][full + i], back, ls[n], hs[n]);
            }
        }
    }
}

/// MacCormack's corrected value of a face: `hat + (u - back) / 2` (`hat` the backward step's
/// value, `u` the value before the step, `back` the forward step of `hat`), clamped to the
/// backward step's samples `[lo, hi]`; `hat` where that is not finite.
#[inline(always)]
fn maccormack_value(hat: f32, u: f32, back: f32, lo: f32, hi: f32) -> f32 {
    let v = hat + 0.5 * (u - back);
    if !v.is_finite() {
        return hat;
    }
    // `f32::clamp`'s order without its panic on NaN bounds.
    let v = if v < lo { lo } else { v };
    if v > hi {
        hi
    } else {
        v
    }
}
