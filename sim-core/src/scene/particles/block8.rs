//! The particle kernel's common case, eight particles at a time on AVX2 and FMA: each particle's
//! numbers in one lane of eight-lane vectors (the positions and slips transposed on load and
//! store), so the slip, the sample weights and indices, the midpoint rule, the substep count,
//! the landing cell's bounds and index and the clarity's cone weight cost one instruction per
//! eight particles. Only the samples' loads and blends (the x pairs of
//! [`lane::blend_x_pairs`]) and the landing cell's kind stay per particle.
//!
//! Every operation is the one-at-a-time path's ([`Kernel::advance_one`]) in the same order, so
//! the particles move bit for bit as there. A particle whose one substep ends in a wall or an
//! outlet lands there ([`Kernel::land`]); those that need more substeps wait until eight are
//! collected and take them side by side ([`substeps`]).
// Axes and lanes by index: the same index runs over several arrays of lanes.
#![allow(clippy::needless_range_loop)]

use std::arch::x86_64::*;

use super::kernel::{ClassSums, Cone, Kernel, BLOCK, KEEP, SUBSTEP_CELLS};
use crate::scene::VoxelKind;
use crate::simd::{v4, v4 as lane, V4};

/// Eight lanes of the one-at-a-time path's 0, 1/2, dt, dt/2 and grid constants.
struct Consts {
    zero: __m256,
    half: __m256,
    one: __m256,
    dt: __m256,
    half_dt: __m256,
    /// 1 / SUBSTEP_CELLS and the most substeps.
    per_cell: __m256,
    max_sub: __m256,
    /// Largest sample position and largest lower sample index per axis (the sampler's).
    smax: [__m256; 3],
    imax: [__m256; 3],
    /// Index strides along y and z.
    nx: __m256i,
    nxny: __m256i,
    /// The grid's dimensions (the landing cell's bounds).
    dims: [__m256; 3],
}

/// Moves the particles `[0, end)` of `pos`, `slip`, `class` (they start in fluid cells) as
/// [`Kernel::advance_one`] would, whole blocks only: those that stay in the fluid in one
/// substep are done block by block; the others (more substeps, or a wall or an outlet) wait
/// until eight are collected and continue from their start side by side ([`substeps`]). Writes
/// their fates, adds the cone weights of those that stay to `sums`; returns how many left and
/// how many particles it moved (`end` rounded down to whole blocks).
///
/// The kernel's sampler must hold the whole grid with x pairs ([`Kernel::blocks`]).
#[target_feature(enable = "avx2,fma")]
pub(super) fn run(
    k: &Kernel<'_>,
    end: usize,
    pos: &mut [[f32; 3]],
    slip: &mut [[f32; 3]],
    class: &[u8],
    fate: &mut [u8],
    sums: &mut ClassSums,
) -> (usize, usize) {
    let c = Consts::new(k);
    let end = end
        .min(pos.len())
        .min(slip.len())
        .min(class.len())
        .min(fate.len())
        / BLOCK
        * BLOCK;
    let mut waiting = Waiting::default();
    let mut left = 0;
    for g in (0..end).step_by(BLOCK) {
        let (Some(pb), Some(wb), Some(cb)) = (
            pos.get_mut(g..g + BLOCK)
                .and_then(|b| <&mut [[f32; 3]; BLOCK]>::try_from(b).ok()),
            slip.get_mut(g..g + BLOCK)
                .and_then(|b| <&mut [[f32; 3]; BLOCK]>::try_from(b).ok()),
            class.get(g..g + BLOCK),
        ) else {
            break;
        };
        let p = load3(pb);
        let w0 = load3(wb);
        let (wt, e, disp) = class_factors(k, cb);
        // The slip (`Kernel::slip_step`): displacement wt dt + (w0 - wt) disp, end wt + (w0 - wt) e.
        let dw: [__m256; 3] = std::array::from_fn(|a| _mm256_sub_ps(w0[a], wt[a]));
        let sd: [__m256; 3] = std::array::from_fn(|a| {
            _mm256_add_ps(_mm256_mul_ps(dw[a], disp), _mm256_mul_ps(wt[a], c.dt))
        });
        let w1: [__m256; 3] =
            std::array::from_fn(|a| _mm256_add_ps(_mm256_mul_ps(dw[a], e), wt[a]));
        let k1 = sample(&c, k, p, ALL);
        // One substep: its count (`Kernel::substeps`) is one.
        let one = _mm256_cmp_ps::<_CMP_EQ_OQ>(c.substeps(k1, sd), c.one);
        let one = _mm256_movemask_ps(one) as u32;
        // The midpoint rule's one substep (`Kernel::substeps_lanes` with one substep).
        let mid: [__m256; 3] = std::array::from_fn(|a| {
            let half_sd = _mm256_add_ps(_mm256_mul_ps(sd[a], c.half), c.zero);
            _mm256_add_ps(
                _mm256_mul_ps(c.half_dt, k1[a]),
                _mm256_add_ps(p[a], half_sd),
            )
        });
        let k2 = sample(&c, k, mid, one);
        let q: [__m256; 3] = std::array::from_fn(|a| {
            _mm256_add_ps(
                _mm256_mul_ps(c.dt, k2[a]),
                _mm256_add_ps(p[a], _mm256_add_ps(sd[a], c.zero)),
            )
        });
        let fluid = c.in_fluid(k, q);
        let done = one & fluid;
        let done_v = lane_mask(done);
        store3(
            pb,
            std::array::from_fn(|a| _mm256_blendv_ps(p[a], q[a], done_v)),
        );
        store3(wb, w1);
        if let Some(fb) = fate.get_mut(g..g + BLOCK) {
            fb.fill(KEEP);
        }
        if let Some(cone) = &k.cone {
            let w = cone_weights(cone, q);
            for (l, (&wl, &cl)) in w.iter().zip(cb).enumerate() {
                if done >> l & 1 != 0 {
                    sums[cl as usize] += wl;
                }
            }
        }
        if done != ALL {
            let (p, k1, sd) = (lanes3(p), lanes3(k1), lanes3(sd));
            let q = lanes3(q);
            for l in (0..BLOCK).filter(|l| done >> l & 1 == 0) {
                if one >> l & 1 != 0 {
                    // One substep into a wall or an outlet: `Kernel::land` past its fluid case
                    // (a slide, or the outlet's fate), as the substeps would end.
                    let at = |v: &[[f32; BLOCK]; 3]| lane::new4(v[0][l], v[1][l], v[2][l], 0.0);
                    let (end, f) = k.land(at(&p), at(&q));
                    let e = v4::lanes(end);
                    let e = [e[0], e[1], e[2]];
                    if let (Some(pl), Some(fl)) = (pos.get_mut(g + l), fate.get_mut(g + l)) {
                        (*pl, *fl) = (e, f);
                    }
                    left += k.tally(f, cb[l], e, sums);
                    continue;
                }
                let w = &mut waiting;
                let m = w.n;
                w.at[m] = g + l;
                for a in 0..3 {
                    (w.p[a][m], w.k1[a][m], w.sd[a][m]) = (p[a][l], k1[a][l], sd[a][l]);
                }
                w.n += 1;
                if w.n == BLOCK {
                    left += substeps(&c, k, &mut waiting, pos, class, fate, sums);
                }
            }
        }
    }
    if waiting.n > 0 {
        left += substeps(&c, k, &mut waiting, pos, class, fate, sums);
    }
    (left, end)
}

/// Every lane.
const ALL: u32 = 0xff;

/// Up to eight particles that continue from their start `p` with the fluid velocity `k1` there
/// and the slip displacement `sd` over the step (the first `n` lanes; index `at` of the task).
#[derive(Default)]
struct Waiting {
    n: usize,
    at: [usize; BLOCK],
    p: [[f32; BLOCK]; 3],
    k1: [[f32; BLOCK]; 3],
    sd: [[f32; BLOCK]; 3],
}

/// The substeps of the `waiting` particles side by side ([`Kernel::substeps_lanes`], each lane
/// as if alone: the same operations in the same order): their ends and fates written at their
/// indices, tallied; returns how many left, and empties `waiting`.
#[target_feature(enable = "avx2,fma")]
#[inline]
fn substeps(
    c: &Consts,
    k: &Kernel<'_>,
    w: &mut Waiting,
    pos: &mut [[f32; 3]],
    class: &[u8],
    fate: &mut [u8],
    sums: &mut ClassSums,
) -> usize {
    let n = std::mem::take(&mut w.n).min(BLOCK);
    let filled = (1u32 << n) - 1;
    let (mut k1, sd) = (load_lanes3(&w.k1), load_lanes3(&w.sd));
    let subs = c.substeps(k1, sd);
    // The per-substep factors of `Kernel::substeps_lanes`.
    let inv = _mm256_div_ps(c.one, subs);
    let hs = _mm256_mul_ps(c.dt, inv);
    let half_hs = _mm256_mul_ps(c.half_dt, inv);
    let half_inv = _mm256_mul_ps(c.half, inv);
    let half_sd = sd.map(|x| _mm256_add_ps(_mm256_mul_ps(x, half_inv), c.zero));
    let sd = sd.map(|x| _mm256_add_ps(_mm256_mul_ps(x, inv), c.zero));
    let most = lanes_i32(_mm256_cvttps_epi32(subs))[..n]
        .iter()
        .copied()
        .max()
        .unwrap_or(0);
    let mut fates = [KEEP; BLOCK];
    // The lanes still in the cavity (fate KEEP).
    let mut live = filled;
    for sub in 0..most {
        let more = _mm256_cmp_ps::<_CMP_LT_OQ>(_mm256_set1_ps(sub as f32), subs);
        let on = _mm256_movemask_ps(more) as u32 & live;
        if on == 0 {
            break;
        }
        let p = load_lanes3(&w.p);
        if sub > 0 {
            k1 = sample(c, k, p, on);
        }
        let mid: [__m256; 3] = std::array::from_fn(|a| {
            _mm256_add_ps(
                _mm256_mul_ps(half_hs, k1[a]),
                _mm256_add_ps(p[a], half_sd[a]),
            )
        });
        let k2 = sample(c, k, mid, on);
        let q: [__m256; 3] = std::array::from_fn(|a| {
            _mm256_add_ps(_mm256_mul_ps(hs, k2[a]), _mm256_add_ps(p[a], sd[a]))
        });
        let fluid = c.in_fluid(k, q);
        let moved = lane_mask(on & fluid);
        w.p = lanes3(std::array::from_fn(|a| _mm256_blendv_ps(p[a], q[a], moved)));
        let walls = on & !fluid;
        if walls == 0 {
            continue;
        }
        let q = lanes3(q);
        for l in (0..BLOCK).filter(|l| walls >> l & 1 != 0) {
            // `Kernel::land` past its fluid case: an outlet, or a slide along the wall.
            let (pl, ql) = (w.lane(l, &w.p), w.lane(l, &q));
            let (end, f) = k.land(pl, ql);
            let e = v4::lanes(end);
            for a in 0..3 {
                w.p[a][l] = e[a];
            }
            fates[l] = f;
            if f != KEEP {
                live &= !(1 << l);
            }
        }
    }
    let mut left = 0;
    for l in 0..n {
        let (at, f) = (w.at[l], fates[l]);
        let e = [w.p[0][l], w.p[1][l], w.p[2][l]];
        let (Some(p), Some(fr), Some(&cl)) = (pos.get_mut(at), fate.get_mut(at), class.get(at))
        else {
            continue;
        };
        (*p, *fr) = (e, f);
        left += k.tally(f, cl, e, sums);
    }
    left
}

impl Waiting {
    /// Lane `l` of `v` as a position.
    #[target_feature(enable = "avx2,fma")]
    #[inline]
    fn lane(&self, l: usize, v: &[[f32; BLOCK]; 3]) -> V4 {
        lane::new4(v[0][l], v[1][l], v[2][l], 0.0)
    }
}

impl Consts {
    #[target_feature(enable = "avx2,fma")]
    #[inline]
    fn new(k: &Kernel<'_>) -> Self {
        let f = &k.field;
        let (smax, imax, dims) = (v4_lanes(f.smax), v4_lanes(f.imax), v4_lanes(k.fdims));
        let splat3 = |v: [f32; 4]| [0, 1, 2].map(|a| _mm256_set1_ps(v[a]));
        Self {
            zero: _mm256_setzero_ps(),
            half: _mm256_set1_ps(0.5),
            one: _mm256_set1_ps(1.0),
            dt: _mm256_set1_ps(k.dt),
            half_dt: _mm256_set1_ps(0.5 * k.dt),
            per_cell: _mm256_set1_ps(1.0 / SUBSTEP_CELLS),
            max_sub: _mm256_set1_ps(k.max_sub as f32),
            smax: splat3(smax),
            imax: splat3(imax),
            nx: _mm256_set1_epi32(f.stride[1] as i32),
            nxny: _mm256_set1_epi32(f.stride[2] as i32),
            dims: splat3(dims),
        }
    }

    /// [`Kernel::substeps`] per lane (as floats): travel / SUBSTEP_CELLS, rounded up, in
    /// `[1, max_sub]`, the travel the largest |k1 dt| + |sd| over the axes (a NaN travel takes
    /// one substep: max returns its second operand).
    #[target_feature(enable = "avx2,fma")]
    #[inline]
    fn substeps(&self, k1: [__m256; 3], sd: [__m256; 3]) -> __m256 {
        let abs = _mm256_castsi256_ps(_mm256_set1_epi32(0x7fff_ffff));
        let t: [__m256; 3] = std::array::from_fn(|a| {
            let d = _mm256_add_ps(_mm256_mul_ps(k1[a], self.dt), self.zero);
            _mm256_add_ps(_mm256_and_ps(d, abs), _mm256_and_ps(sd[a], abs))
        });
        let travel = _mm256_max_ps(_mm256_max_ps(t[0], t[1]), t[2]);
        let x = _mm256_min_ps(
            _mm256_max_ps(_mm256_mul_ps(travel, self.per_cell), self.one),
            self.max_sub,
        );
        _mm256_ceil_ps(x)
    }

    /// The lanes whose `q` lies in a fluid cell ([`Kernel::kind_at`]: inside the grid, then the
    /// cell's kind), as bits.
    #[inline(always)]
    fn in_fluid(&self, k: &Kernel<'_>, q: [__m256; 3]) -> u32 {
        // SAFETY: (the intrinsics) the caller has AVX2 (inlined into `run`).
        let (inside, cells) = unsafe {
            // In [0, dims) along every axis (a NaN fails).
            let mut inside = _mm256_cmp_ps::<_CMP_GE_OQ>(q[0], self.zero);
            for a in 0..3 {
                if a > 0 {
                    inside = _mm256_and_ps(inside, _mm256_cmp_ps::<_CMP_GE_OQ>(q[a], self.zero));
                }
                inside = _mm256_and_ps(inside, _mm256_cmp_ps::<_CMP_LT_OQ>(q[a], self.dims[a]));
            }
            let i = [
                _mm256_cvttps_epi32(q[0]),
                _mm256_cvttps_epi32(q[1]),
                _mm256_cvttps_epi32(q[2]),
            ];
            (_mm256_movemask_ps(inside) as u32, index::<0>(self, i))
        };
        let mut fluid = 0u32;
        for (l, &n) in cells.iter().enumerate() {
            if inside >> l & 1 != 0 && k.kinds.get(n as usize).copied() == Some(VoxelKind::Fluid) {
                fluid |= 1 << l;
            }
        }
        fluid
    }
}

/// The per-class slip factors of eight particles (`Kernel::slip_step`): terminal slip per axis,
/// decay and displacement factor, broadcast when the eight share a class.
#[target_feature(enable = "avx2,fma")]
#[inline]
fn class_factors(k: &Kernel<'_>, cb: &[u8]) -> ([__m256; 3], __m256, __m256) {
    let of = |c: u8| {
        k.class_step
            .get(c as usize)
            .copied()
            .unwrap_or(([0.0; 3], 0.0, 0.0))
    };
    let first = cb.first().copied().unwrap_or(0);
    if cb.iter().all(|&c| c == first) {
        let (wt, e, disp) = of(first);
        return (
            wt.map(|x| _mm256_set1_ps(x)),
            _mm256_set1_ps(e),
            _mm256_set1_ps(disp),
        );
    }
    let mut wt = [[0.0f32; BLOCK]; 3];
    let (mut e, mut disp) = ([0.0f32; BLOCK], [0.0f32; BLOCK]);
    for (l, &c) in cb.iter().take(BLOCK).enumerate() {
        let (w, el, dl) = of(c);
        for a in 0..3 {
            wt[a][l] = w[a];
        }
        (e[l], disp[l]) = (el, dl);
    }
    (load_lanes3(&wt), load_lanes(&e), load_lanes(&disp))
}

/// The field at eight positions (`Sampler::sample` with the FMA x pairs, lane by lane), per
/// axis; zero in the lanes not `active`. (Inlined into [`run`], which has AVX2 and FMA; no
/// closures here: those would be compiled without them.)
#[inline(always)]
fn sample(c: &Consts, k: &Kernel<'_>, p: [__m256; 3], active: u32) -> [__m256; 3] {
    // SAFETY: (all intrinsics here) the caller has AVX2 and FMA (a `target_feature` function).
    unsafe {
        // `lane::locate`: s clamped to [0, smax] (max returns its second operand for a NaN),
        // its lower sample index at most imax, the weight s - i.
        let mut t = [c.zero; 3];
        let mut i = [_mm256_setzero_si256(); 3];
        for a in 0..3 {
            let s = _mm256_min_ps(
                _mm256_max_ps(_mm256_sub_ps(p[a], c.half), c.zero),
                c.smax[a],
            );
            let fl = _mm256_min_ps(_mm256_cvtepi32_ps(_mm256_cvttps_epi32(s)), c.imax[a]);
            t[a] = _mm256_sub_ps(s, fl);
            i[a] = _mm256_cvttps_epi32(fl);
        }
        // Byte offsets of the lower samples.
        let base = index::<4>(c, i);
        // The weights from memory: one broadcast load per weight and lane (from registers, two
        // shuffles each).
        let t = std::hint::black_box(lanes3(t));
        let [tx, ty, tz] = &t;
        let f = &k.field;
        let [_, sy, sz] = f.step;
        let first = f.field.as_ptr();
        let mut aos = [lane::splat(0.0); BLOCK];
        for (l, out) in aos.iter_mut().enumerate() {
            if active >> l & 1 == 0 {
                continue;
            }
            // SAFETY: `Kernel::blocks`: the field holds the whole grid, and the lower index is
            // at most n - 2 along x and at most max(n - 2, 0) along y and z, so the pairs at
            // `base + {0, sy} + {0, sz}` end at most at the grid's last cell.
            let at = first.byte_add(base[l] as usize).cast::<f32>();
            let pairs = [
                _mm256_loadu_ps(at),
                _mm256_loadu_ps(at.add(4 * sy)),
                _mm256_loadu_ps(at.add(4 * sz)),
                _mm256_loadu_ps(at.add(4 * (sy + sz))),
            ];
            *out = lane::blend_x_pairs(
                pairs,
                _mm256_broadcast_ss(&ty[l]),
                _mm256_broadcast_ss(&tz[l]),
                _mm_broadcast_ss(&tx[l]),
            );
        }
        // Transposed: [u, v, w, 0] per particle to u, v, w per lane.
        let r04 = _mm256_insertf128_ps::<1>(_mm256_castps128_ps256(aos[0]), aos[4]);
        let r15 = _mm256_insertf128_ps::<1>(_mm256_castps128_ps256(aos[1]), aos[5]);
        let r26 = _mm256_insertf128_ps::<1>(_mm256_castps128_ps256(aos[2]), aos[6]);
        let r37 = _mm256_insertf128_ps::<1>(_mm256_castps128_ps256(aos[3]), aos[7]);
        let (t0, t1) = (_mm256_unpacklo_ps(r04, r15), _mm256_unpacklo_ps(r26, r37));
        let (t2, t3) = (_mm256_unpackhi_ps(r04, r15), _mm256_unpackhi_ps(r26, r37));
        [
            _mm256_shuffle_ps::<0b01_00_01_00>(t0, t1),
            _mm256_shuffle_ps::<0b11_10_11_10>(t0, t1),
            _mm256_shuffle_ps::<0b01_00_01_00>(t2, t3),
        ]
    }
}

/// Cell indices `i + nx j + nx ny k` of eight whole-number triples (`lane::index`), times
/// `2^SHIFT` (every cell's byte offset in the field fits a `u32`, [`Kernel::blocks`]).
#[inline(always)]
fn index<const SHIFT: i32>(c: &Consts, i: [__m256i; 3]) -> [u32; BLOCK] {
    let mut out = [0u32; BLOCK];
    // SAFETY: the caller has AVX2; the store writes the whole `[u32; 8]`.
    unsafe {
        let n = _mm256_add_epi32(
            _mm256_add_epi32(i[0], _mm256_mullo_epi32(i[1], c.nx)),
            _mm256_mullo_epi32(i[2], c.nxny),
        );
        _mm256_storeu_si256(out.as_mut_ptr().cast(), _mm256_slli_epi32::<SHIFT>(n));
    }
    out
}

/// [`Cone::weight`] of eight positions (the same operations).
#[target_feature(enable = "avx2,fma")]
#[inline]
fn cone_weights(cone: &Cone, p: [__m256; 3]) -> [f32; BLOCK] {
    let d: [__m256; 3] = std::array::from_fn(|a| _mm256_sub_ps(p[a], _mm256_set1_ps(cone.tip[a])));
    let dot = |b: [__m256; 3]| {
        _mm256_add_ps(
            _mm256_add_ps(_mm256_mul_ps(d[0], b[0]), _mm256_mul_ps(d[1], b[1])),
            _mm256_mul_ps(d[2], b[2]),
        )
    };
    let along = dot(cone.dir.map(|x| _mm256_set1_ps(x)));
    let r2 = dot(d);
    let inside = _mm256_and_ps(
        _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_GT_OQ>(along, _mm256_setzero_ps()),
            _mm256_cmp_ps::<_CMP_LE_OQ>(along, _mm256_set1_ps(cone.depth)),
        ),
        _mm256_cmp_ps::<_CMP_GE_OQ>(
            _mm256_mul_ps(along, along),
            _mm256_mul_ps(_mm256_set1_ps(cone.cos2), r2),
        ),
    );
    // f32::max(r2, near2) is near2 for a NaN r2, as max_ps with r2 first.
    let w = _mm256_div_ps(
        _mm256_set1_ps(1.0),
        _mm256_max_ps(r2, _mm256_set1_ps(cone.near2)),
    );
    lanes(_mm256_and_ps(w, inside))
}

/// The lanes of `bits` as a mask (all ones where set).
#[inline(always)]
fn lane_mask(bits: u32) -> __m256 {
    // SAFETY: the caller has AVX2.
    unsafe {
        let each = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
        _mm256_castsi256_ps(_mm256_cmpeq_epi32(
            _mm256_and_si256(_mm256_set1_epi32(bits as i32), each),
            each,
        ))
    }
}

/// The eight lanes.
#[inline(always)]
fn lanes(v: __m256) -> [f32; BLOCK] {
    let mut out = [0.0f32; BLOCK];
    // SAFETY: the caller has AVX (as every function here: inlined into `run`); the store writes
    // the whole `[f32; 8]`.
    unsafe { _mm256_storeu_ps(out.as_mut_ptr(), v) };
    out
}

#[inline(always)]
fn lanes3(v: [__m256; 3]) -> [[f32; BLOCK]; 3] {
    [lanes(v[0]), lanes(v[1]), lanes(v[2])]
}

#[inline(always)]
fn lanes_i32(v: __m256i) -> [i32; BLOCK] {
    let mut out = [0i32; BLOCK];
    // SAFETY: the caller has AVX; the store writes the whole `[i32; 8]`.
    unsafe { _mm256_storeu_si256(out.as_mut_ptr().cast(), v) };
    out
}

#[inline(always)]
fn load_lanes(v: &[f32; BLOCK]) -> __m256 {
    // SAFETY: the caller has AVX; the load reads the whole `[f32; 8]`.
    unsafe { _mm256_loadu_ps(v.as_ptr()) }
}

/// [`lanes3`]'s inverse.
#[inline(always)]
fn load_lanes3(v: &[[f32; BLOCK]; 3]) -> [__m256; 3] {
    [load_lanes(&v[0]), load_lanes(&v[1]), load_lanes(&v[2])]
}

/// The lanes of a four-lane vector.
#[target_feature(enable = "avx2,fma")]
#[inline]
fn v4_lanes(v: V4) -> [f32; 4] {
    let mut out = [0.0f32; 4];
    // SAFETY: SSE; the store writes the whole `[f32; 4]`.
    unsafe { _mm_storeu_ps(out.as_mut_ptr(), v) };
    out
}

/// Eight `[x, y, z]` as x, y and z per lane (a 3 x 8 transpose in shuffles).
#[target_feature(enable = "avx2,fma")]
#[inline]
fn load3(b: &[[f32; 3]; BLOCK]) -> [__m256; 3] {
    let m = b.as_ptr().cast::<f32>();
    // SAFETY: the caller has AVX; the six four-float loads read the 24 floats of b[..8].
    unsafe {
        let half = |a: usize, c: usize| {
            _mm256_insertf128_ps::<1>(
                _mm256_castps128_ps256(_mm_loadu_ps(m.add(4 * a))),
                _mm_loadu_ps(m.add(4 * c)),
            )
        };
        // [x0 y0 z0 x1], [y1 z1 x2 y2], [z2 x3 y3 z3] in the lower halves, 4..7 in the upper.
        let (m03, m14, m25) = (half(0, 3), half(1, 4), half(2, 5));
        let xy = _mm256_shuffle_ps::<{ shuf(2, 1, 3, 2) }>(m14, m25);
        let yz = _mm256_shuffle_ps::<{ shuf(1, 0, 2, 1) }>(m03, m14);
        [
            _mm256_shuffle_ps::<{ shuf(2, 0, 3, 0) }>(m03, xy),
            _mm256_shuffle_ps::<{ shuf(3, 1, 2, 0) }>(yz, xy),
            _mm256_shuffle_ps::<{ shuf(3, 0, 3, 1) }>(yz, m25),
        ]
    }
}

/// [`load3`]'s inverse: x, y and z per lane to eight `[x, y, z]`.
#[target_feature(enable = "avx2,fma")]
#[inline]
fn store3(b: &mut [[f32; 3]; BLOCK], [x, y, z]: [__m256; 3]) {
    let m = b.as_mut_ptr().cast::<f32>();
    // SAFETY: the caller has AVX; the six four-float stores write the 24 floats of b[..8].
    unsafe {
        let rxy = _mm256_shuffle_ps::<{ shuf(2, 0, 2, 0) }>(x, y);
        let ryz = _mm256_shuffle_ps::<{ shuf(3, 1, 3, 1) }>(y, z);
        let rzx = _mm256_shuffle_ps::<{ shuf(3, 1, 2, 0) }>(z, x);
        let r03 = _mm256_shuffle_ps::<{ shuf(2, 0, 2, 0) }>(rxy, rzx);
        let r14 = _mm256_shuffle_ps::<{ shuf(3, 1, 2, 0) }>(ryz, rxy);
        let r25 = _mm256_shuffle_ps::<{ shuf(3, 1, 3, 1) }>(rzx, ryz);
        for (a, r) in [r03, r14, r25].into_iter().enumerate() {
            _mm_storeu_ps(m.add(4 * a), _mm256_castps256_ps128(r));
            _mm_storeu_ps(m.add(4 * (a + 3)), _mm256_extractf128_ps::<1>(r));
        }
    }
}

/// `_MM_SHUFFLE(d, c, b, a)`: lanes a and b from the first operand, c and d from the second.
const fn shuf(d: i32, c: i32, b: i32, a: i32) -> i32 {
    d << 6 | c << 4 | b << 2 | a
}
