//! The advection passes over all active faces, block by block in two halves on two threads:
//! semi-Lagrangian (with or without the clamping bounds), MacCormack's fused trace and
//! correction, BFECC's error estimate, clamping, monotone cubic. Each block runs the AVX2 kernel
//! (`avx2.rs`) where the CPU has it, else the scalar one (`trace.rs`).

#[cfg(target_arch = "x86_64")]
use super::avx2;
use super::plan::{split_block, BLOCK};
use super::trace::Pass;
use crate::simd::v4;

impl Pass<'_> {
    /// For every face of block `b`: traces it back (RK2 midpoint rule through the centred
    /// velocity) and samples its component of `src` at the foot point, then calls
    /// `each(position within the block, (value, min, max))` (min/max only when `BOUNDS`).
    #[inline(always)]
    pub(super) fn block<const BOUNDS: bool>(
        &self,
        b: usize,
        mut each: impl FnMut(usize, (f32, f32, f32)),
    ) {
        #[cfg(target_arch = "x86_64")]
        if crate::simd::avx2_fma() {
            // SAFETY: the CPU has AVX2 and FMA (checked by `available`).
            unsafe {
                avx2::block::<BOUNDS>(self, b, |o, m, v, lo, hi| {
                    for i in 0..m {
                        each(o + i, (v[i], lo[i], hi[i]));
                    }
                })
            };
            return;
        }
        self.block_scalar::<BOUNDS>(b, each)
    }

    /// Semi-Lagrangian values at every active face into `out` (concatenated compact order).
    pub fn semi_lagrangian(&self, out: &mut [f32], parallel: bool) {
        let task = |(b, os): (usize, &mut [f32])| {
            #[cfg(target_arch = "x86_64")]
            if crate::simd::avx2_fma() {
                // SAFETY: the CPU has AVX2 and FMA (checked by `available`).
                unsafe { avx2::block::<false>(self, b, |o, m, v, _, _| put(os, o, v, m)) };
                return;
            }
            self.block_scalar::<false>(b, |n, r| os[n] = r.0)
        };
        let blocks = |first: usize, out: &mut [f32]| {
            for (b, os) in out.chunks_mut(BLOCK).enumerate() {
                task((first + b, os));
            }
        };
        match split_block(out.len(), parallel) {
            Some(mid) => {
                let (a, b) = out.split_at_mut(mid * BLOCK);
                crate::fork_join::join(|| blocks(0, a), || blocks(mid, b));
            }
            None => blocks(0, out),
        }
    }

    /// As [`Pass::semi_lagrangian`], also writing the min and max of the samples used.
    pub fn semi_lagrangian_bounds(
        &self,
        out: &mut [f32],
        lo: &mut [f32],
        hi: &mut [f32],
        parallel: bool,
    ) {
        type Slices<'s> = ((&'s mut [f32], &'s mut [f32]), &'s mut [f32]);
        let task = |(b, ((os, ls), hs)): (usize, Slices)| {
            self.block::<true>(b, |n, r| (os[n], ls[n], hs[n]) = r)
        };
        let blocks = |first: usize, out: &mut [f32], lo: &mut [f32], hi: &mut [f32]| {
            let chunks = out.chunks_mut(BLOCK).zip(lo.chunks_mut(BLOCK));
            for (b, s) in chunks.zip(hi.chunks_mut(BLOCK)).enumerate() {
                task((first + b, s));
            }
        };
        match split_block(out.len(), parallel) {
            Some(mid) => {
                let at = mid * BLOCK;
                let ((o0, o1), (l0, l1), (h0, h1)) = (
                    out.split_at_mut(at),
                    lo.split_at_mut(at),
                    hi.split_at_mut(at),
                );
                crate::fork_join::join(|| blocks(0, o0, l0, h0), || blocks(mid, o1, l1, h1));
            }
            None => blocks(0, out, lo, hi),
        }
    }

    /// MacCormack's backward step and forward trace, in one pass: `hat` gets the semi-Lagrangian
    /// values at every active face, `lo` and `hi` the min and max of the samples they used, and
    /// `foot` (x, y, z) the foot points of the forward trace (this pass with `-dt_cells`), all in
    /// concatenated compact order. [`Pass::maccormack_correct`] finishes the step.
    pub fn maccormack_trace(
        &self,
        hat: &mut [f32],
        [lo, hi]: [&mut [f32]; 2],
        foot: [&mut [f32]; 3],
        parallel: bool,
    ) {
        let [fx, fy, fz] = foot;
        for_blocks(
            [hat, lo, hi, fx, fy, fz],
            [],
            parallel,
            |b, [os, ls, hs, xs, ys, zs], []| {
                #[cfg(target_arch = "x86_64")]
                if crate::simd::avx2_fma() {
                    // SAFETY: the CPU has AVX2 and FMA (checked by `available`).
                    unsafe {
                        avx2::trace::<true, true>(self, b, |o, m, v, lo, hi, f| {
                            put(os, o, v, m);
                            put(ls, o, lo, m);
                            put(hs, o, hi, m);
                            put(xs, o, &f[0], m);
                            put(ys, o, &f[1], m);
                            put(zs, o, &f[2], m);
                        })
                    };
                    return;
                }
                let geo = self.geo;
                self.trace_scalar::<true>(
                    b,
                    |c, src, p| geo.sample::<true>(c, src, p),
                    |n, r, f| {
                        (os[n], ls[n], hs[n]) = r;
                        [xs[n], ys[n], zs[n], _] = v4::lanes(f);
                    },
                )
            },
        );
    }

    /// MacCormack's correction, this pass sampling the backward step's field in `src` (`u` off
    /// the active faces) at the forward feet `foot` of [`Pass::maccormack_trace`]: `out` holds the
    /// backward step's values on entry and the corrected values clamped to `[lo, hi]` on return
    /// (`maccormack_value` in `trace.rs`). `orig` is the full face arrays before the step.
    pub fn maccormack_correct(
        &self,
        orig: [&[f32]; 3],
        foot: [&[f32]; 3],
        [lo, hi]: [&[f32]; 2],
        out: &mut [f32],
        parallel: bool,
    ) {
        let [fx, fy, fz] = foot;
        for_blocks(
            [out],
            [fx, fy, fz, lo, hi],
            parallel,
            |b, [os], [xs, ys, zs, ls, hs]| {
                #[cfg(target_arch = "x86_64")]
                if crate::simd::avx2_fma() {
                    // SAFETY: the CPU has AVX2 and FMA (checked by `available`).
                    unsafe { avx2::correct(self, b, orig, [xs, ys, zs], [ls, hs], os) };
                    return;
                }
                self.correct_scalar(b, orig, [xs, ys, zs], [ls, hs], os)
            },
        );
    }
}

/// The first `m` of `v` to `out` from `o`: a fixed-size copy for whole vectors (one store, no
/// memcpy call).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn put(out: &mut [f32], o: usize, v: &[f32; 8], m: usize) {
    if m == 8 {
        out[o..o + 8].copy_from_slice(v);
    } else {
        out[o..o + m].copy_from_slice(&v[..m]);
    }
}

/// Runs `task(block, output blocks, input blocks)` over the blocks of the concatenated compact
/// arrays `outs` and `ins` (all of one length), in two halves on two threads if `parallel`.
fn for_blocks<const M: usize, const N: usize>(
    outs: [&mut [f32]; M],
    ins: [&[f32]; N],
    parallel: bool,
    task: impl Fn(usize, [&mut [f32]; M], [&[f32]; N]) + Sync,
) {
    let len = outs.first().map_or(0, |o| o.len());
    debug_assert!(outs.iter().all(|o| o.len() == len) && ins.iter().all(|i| i.len() == len));
    let run = |first: usize, mut outs: [&mut [f32]; M], ins: [&[f32]; N]| {
        let len = outs.first().map_or(0, |o| o.len());
        for (b, s) in (0..len).step_by(BLOCK).enumerate() {
            let e = (s + BLOCK).min(len);
            task(
                first + b,
                outs.each_mut().map(|o| &mut o[s..e]),
                ins.map(|i| &i[s..e]),
            );
        }
    };
    match split_block(len, parallel) {
        Some(mid) => {
            let at = mid * BLOCK;
            let mut halves = outs.map(|o| o.split_at_mut(at));
            let a = std::array::from_fn(|i| std::mem::take(&mut halves[i].0));
            let b = std::array::from_fn(|i| std::mem::take(&mut halves[i].1));
            let (ia, ib) = (ins.map(|i| &i[..at]), ins.map(|i| &i[at..]));
            crate::fork_join::join(|| run(0, a, ia), || run(mid, b, ib));
        }
        None => run(0, outs, ins),
    }
}

impl Pass<'_> {
    /// BFECC's error estimate (this pass traces forward and samples the backward-step field in
    /// `src`): `w` holds the field before the step on entry and `w + (w - forward) / 2` on return
    /// (unchanged where that is not finite).
    pub fn bfecc_source(&self, w: &mut [f32], parallel: bool) {
        for_blocks([w], [], parallel, |b, [ws], []| {
            self.block::<false>(b, |n, (fwd, _, _)| {
                let v = ws[n] + 0.5 * (ws[n] - fwd);
                if v.is_finite() {
                    ws[n] = v;
                }
            })
        });
    }

    /// Semi-Lagrangian values clamped to `[lo, hi]` into `out` (unchanged where not finite).
    pub fn clamped(&self, out: &mut [f32], lo: &[f32], hi: &[f32], parallel: bool) {
        for_blocks([out], [lo, hi], parallel, |b, [os], [ls, hs]| {
            self.block::<false>(b, |n, (v, _, _)| {
                if v.is_finite() {
                    // max/min (not clamp): no panic on inverted or NaN bounds.
                    os[n] = v.max(ls[n]).min(hs[n]);
                }
            })
        });
    }

    /// Monotone tricubic semi-Lagrangian values (`Geometry::sample_cubic`) into `out`.
    pub fn cubic(&self, out: &mut [f32], parallel: bool) {
        let geo = self.geo;
        for_blocks([out], [], parallel, |b, [os], []| {
            self.block_scalar_with(
                b,
                |c, src, p| geo.sample_cubic(c, src, p),
                |n, (v, _, _)| os[n] = v,
            )
        });
    }
}
