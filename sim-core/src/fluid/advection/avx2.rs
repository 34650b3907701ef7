//! The advection trace eight faces at a time with AVX2 + FMA, and the centred velocity eight
//! cells at a time: raw intrinsics (gathers, lane transposes), which the compiler cannot
//! vectorise from the scalar code (`crate::simd`, "One dispatch style"). Each kernel does the
//! scalar path's operations in its order (no FMA), so it equals its reference (`passes.rs`,
//! `centred.rs`) to the bit (`tests.rs`). The faces of a run are consecutive along x, so a vector
//! is eight faces of one run; the centred velocity is gathered lane-wise from the `V4` array
//! (`4 cell + component`).

use std::arch::x86_64::*;

use super::geometry::{Axis, Geometry};
use super::plan::BLOCK;
use super::trace::Pass;
use crate::simd::V4;

/// Vectors (of eight faces) per chunk of the trace's split loops.
const CHUNK_VECTORS: usize = 4;

/// An [`Axis`] broadcast to eight lanes, its strides times `scale`.
#[derive(Clone, Copy)]
struct AxisV {
    periodic: bool,
    /// The upper sample is always the next one in memory (clamped axis, n > 1, stride 1).
    pairs: bool,
    /// Offset from the lower to the upper sample, the same in every lane (`step` on a clamped
    /// axis, where `locate` keeps the lower index at most n - 2), or `None` (periodic).
    fixed_step: Option<i32>,
    shift: __m256,
    last: __m256,
    top: __m256i,
    stride: __m256i,
    step: __m256i,
    n: __m256,
    inv_n: __m256,
    n_last: __m256i,
}

impl AxisV {
    #[target_feature(enable = "avx2,fma")]
    fn new(a: &Axis, scale: u32) -> Self {
        Self {
            periodic: a.periodic,
            pairs: !a.periodic && a.n > 1 && a.stride * scale == 1,
            fixed_step: (!a.periodic).then_some((a.step * scale) as i32),
            shift: _mm256_set1_ps(a.shift),
            last: _mm256_set1_ps(a.last),
            top: _mm256_set1_epi32(a.top as i32),
            stride: _mm256_set1_epi32((a.stride * scale) as i32),
            step: _mm256_set1_epi32((a.step * scale) as i32),
            n: _mm256_set1_ps(a.n as f32),
            inv_n: _mm256_set1_ps(1.0 / a.n as f32),
            n_last: _mm256_set1_epi32(a.n - 1),
        }
    }

    /// [`Axis::locate`] for eight positions. Every index lands in `[0, n)` whatever the input
    /// (NaN and infinities included): that is what keeps the gathers in bounds.
    #[target_feature(enable = "avx2,fma")]
    fn locate(&self, p: __m256) -> (__m256i, __m256i, __m256) {
        let zero = _mm256_setzero_ps();
        let s = _mm256_sub_ps(p, self.shift);
        if self.periodic {
            let fl = _mm256_floor_ps(s);
            let t = _mm256_sub_ps(s, fl);
            // fl mod n in floats (exact below 2^24; the quotient may be off by one, fixed
            // below), then clamped so NaN, infinities and huge values still give an index.
            let q = _mm256_floor_ps(_mm256_mul_ps(fl, self.inv_n));
            let mut r = _mm256_fnmadd_ps(q, self.n, fl);
            let neg = _mm256_cmp_ps::<_CMP_LT_OQ>(r, zero);
            r = _mm256_add_ps(r, _mm256_and_ps(neg, self.n));
            let over = _mm256_cmp_ps::<_CMP_GE_OQ>(r, self.n);
            r = _mm256_sub_ps(r, _mm256_and_ps(over, self.n));
            // max returns its second operand for a NaN: NaN -> 0.
            let r = _mm256_min_ps(
                _mm256_max_ps(r, zero),
                _mm256_sub_ps(self.n, _mm256_set1_ps(1.0)),
            );
            let i0 = _mm256_cvttps_epi32(r);
            let wrap = _mm256_cmpeq_epi32(i0, self.n_last);
            let i1 = _mm256_andnot_si256(wrap, _mm256_add_epi32(i0, _mm256_set1_epi32(1)));
            (
                _mm256_mullo_epi32(i0, self.stride),
                _mm256_mullo_epi32(i1, self.stride),
                t,
            )
        } else {
            // max returns its second operand for a NaN: NaN -> 0.
            let s = _mm256_min_ps(_mm256_max_ps(s, zero), self.last);
            let i0 = _mm256_min_epi32(_mm256_cvttps_epi32(s), self.top);
            let o0 = _mm256_mullo_epi32(i0, self.stride);
            (
                o0,
                _mm256_add_epi32(o0, self.step),
                _mm256_sub_ps(s, _mm256_cvtepi32_ps(i0)),
            )
        }
    }
}

/// `a + t (b - a)`. Here and in the trace: no FMA, the scalar code's operations in its
/// order, so both paths round alike (FMA gains nothing in this gather-bound kernel, and
/// bit-equal results keep the fallback an exact reference).
#[target_feature(enable = "avx2,fma")]
fn lerp(a: __m256, b: __m256, t: __m256) -> __m256 {
    _mm256_add_ps(a, _mm256_mul_ps(t, _mm256_sub_ps(b, a)))
}

/// `x - s v`.
#[target_feature(enable = "avx2,fma")]
fn sub_scaled(x: __m256, s: __m256, v: __m256) -> __m256 {
    _mm256_sub_ps(x, _mm256_mul_ps(s, v))
}

/// Largest lane of `v` (for the debug checks of gather indices).
#[target_feature(enable = "avx2,fma")]
fn max_lane(v: __m256i) -> i32 {
    let mut a = [0i32; 8];
    // SAFETY: `a` has room for eight lanes.
    unsafe { _mm256_storeu_si256(a.as_mut_ptr().cast(), v) };
    a.into_iter().max().unwrap_or(0)
}

/// Smallest lane of `v`.
#[target_feature(enable = "avx2,fma")]
fn min_lane(v: __m256i) -> i32 {
    let mut a = [0i32; 8];
    // SAFETY: `a` has room for eight lanes.
    unsafe { _mm256_storeu_si256(a.as_mut_ptr().cast(), v) };
    a.into_iter().min().unwrap_or(0)
}

/// Gathers `base[idx]`.
///
/// # Safety
/// Every lane of `idx` must be in `[0, len)`, `len` being the number of f32 readable at `base`.
#[target_feature(enable = "avx2,fma")]
#[inline]
unsafe fn gather(base: *const f32, len: usize, idx: __m256i) -> __m256 {
    debug_assert!(min_lane(idx) >= 0 && (max_lane(idx) as usize) < len);
    // SAFETY: in bounds by the caller's contract.
    unsafe { _mm256_i32gather_ps::<4>(base, idx) }
}

/// `update_centred` (`centred.rs`) on one row, eight cells at a time while the upper x face of all
/// eight is in the row (`x[i + 1]`, no wrap): the same operations as the scalar loop, so the
/// same values. Returns the number of cells done (a multiple of eight).
///
/// # Safety
/// The CPU must have AVX2 and FMA.
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn centred_row(
    row: &mut [V4],
    x: &[f32],
    y: [&[f32]; 2],
    z: [&[f32]; 2],
) -> usize {
    let n = row.len().min(x.len().saturating_sub(1));
    let n = n
        .min(y[0].len())
        .min(y[1].len())
        .min(z[0].len())
        .min(z[1].len());
    let half = _mm256_set1_ps(0.5);
    let zero = _mm256_setzero_ps();
    let mut i = 0;
    while i + 8 <= n {
        // SAFETY: i + 8 <= n, so every load (x up to i + 8 inclusive) and store is inside its
        // slice (n is below all their lengths, and below x.len() - 1).
        unsafe {
            let ld = |s: &[f32], o: usize| _mm256_loadu_ps(s.as_ptr().add(o));
            let vx = _mm256_mul_ps(half, _mm256_add_ps(ld(x, i), ld(x, i + 1)));
            let vy = _mm256_mul_ps(half, _mm256_add_ps(ld(y[0], i), ld(y[1], i)));
            let vz = _mm256_mul_ps(half, _mm256_add_ps(ld(z[0], i), ld(z[1], i)));
            // Eight (x, y, z, 0) cells from the three lane vectors.
            let t0 = _mm256_unpacklo_ps(vx, vy);
            let t1 = _mm256_unpackhi_ps(vx, vy);
            let t2 = _mm256_unpacklo_ps(vz, zero);
            let t3 = _mm256_unpackhi_ps(vz, zero);
            let r0 = _mm256_shuffle_ps::<0x44>(t0, t2); // cells 0 | 4
            let r1 = _mm256_shuffle_ps::<0xEE>(t0, t2); // cells 1 | 5
            let r2 = _mm256_shuffle_ps::<0x44>(t1, t3); // cells 2 | 6
            let r3 = _mm256_shuffle_ps::<0xEE>(t1, t3); // cells 3 | 7
            let out = row.as_mut_ptr().add(i).cast::<f32>();
            _mm256_storeu_ps(out, _mm256_permute2f128_ps::<0x20>(r0, r1));
            _mm256_storeu_ps(out.add(8), _mm256_permute2f128_ps::<0x20>(r2, r3));
            _mm256_storeu_ps(out.add(16), _mm256_permute2f128_ps::<0x31>(r0, r1));
            _mm256_storeu_ps(out.add(24), _mm256_permute2f128_ps::<0x31>(r2, r3));
        }
        i += 8;
    }
    i
}

/// Stores the eight lanes of `v`.
#[target_feature(enable = "avx2,fma")]
#[inline]
fn lanes_i32(v: __m256i) -> [i32; 8] {
    let mut a = [0i32; 8];
    // SAFETY: `a` has room for eight lanes.
    unsafe { _mm256_storeu_si256(a.as_mut_ptr().cast(), v) };
    a
}

/// Four registers each holding two `V4`, `r[p] = [lane p | lane p + 4]`, to three registers of
/// eight lanes (x, y, z) in lane order.
#[target_feature(enable = "avx2,fma")]
#[inline]
fn transpose(r: [__m256; 4]) -> [__m256; 3] {
    let t0 = _mm256_unpacklo_ps(r[0], r[1]);
    let t1 = _mm256_unpackhi_ps(r[0], r[1]);
    let t2 = _mm256_unpacklo_ps(r[2], r[3]);
    let t3 = _mm256_unpackhi_ps(r[2], r[3]);
    [
        _mm256_shuffle_ps::<0x44>(t0, t2),
        _mm256_shuffle_ps::<0xEE>(t0, t2),
        _mm256_shuffle_ps::<0x44>(t1, t3),
    ]
}

/// The centred velocity field for the vector trace. Zen 3 runs a gather as ~40 micro-ops,
/// so the `V4` of a cell is one 16-byte load instead, two faces per register (lanes p and
/// p + 4, which `transpose` turns back into lane order): 4-lane lerps on two faces at once.
#[derive(Clone, Copy)]
pub(super) struct Centred {
    ax: [AxisV; 3],
    ptr: *const V4,
    len: usize,
    /// Per pair p, the lane indices `[p; 4] ++ [p + 4; 4]` (weights to the pair layout).
    pair: [__m256i; 4],
    /// Without a periodic axis, the offsets in bytes of the eight corners from the first (x
    /// fastest, then y, then z).
    corner_bytes: Option<[usize; 8]>,
}

impl Centred {
    #[target_feature(enable = "avx2,fma")]
    pub(super) fn new(geo: &Geometry, v: &[V4]) -> Self {
        // The centred grid has one sample per cell (`Axis::new` with the cell dims), so the
        // offsets `locate` returns are cells of `v`.
        assert_eq!(v.len(), geo.dims.iter().product::<usize>());
        Self {
            ax: std::array::from_fn(|a| AxisV::new(&geo.centred.ax[a], 1)),
            ptr: v.as_ptr(),
            len: v.len(),
            pair: std::array::from_fn(|p| {
                let (a, b) = (p as i32, p as i32 + 4);
                _mm256_setr_epi32(a, a, a, a, b, b, b, b)
            }),
            corner_bytes: corner_offsets(geo.centred.ax.map(|a| AxisV::new(&a, 1).fixed_step))
                .map(|o| o.map(|o| o as usize * std::mem::size_of::<V4>())),
        }
    }

    /// The `V4` of cells `lo` (low half) and `hi` (high half).
    ///
    /// # Safety
    /// Both must be below `len`.
    #[target_feature(enable = "avx2,fma")]
    #[inline]
    unsafe fn pair_at(&self, lo: i32, hi: i32) -> __m256 {
        debug_assert!(lo >= 0 && hi >= 0 && (lo.max(hi) as usize) < self.len);
        // SAFETY: both cells are in `v` (the caller's contract); `V4` is 16 bytes.
        unsafe {
            _mm256_loadu2_m128(
                self.ptr.add(hi as usize).cast(),
                self.ptr.add(lo as usize).cast(),
            )
        }
    }

    /// The mean of the `V4` at cells `a` and `b` per lane (the velocity at a face).
    ///
    /// # Safety
    /// All lanes must be cells (below `len`).
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn mean(&self, a: __m256i, b: __m256i) -> [__m256; 3] {
        let (a, b) = (lanes_i32(a), lanes_i32(b));
        let half = _mm256_set1_ps(0.5);
        let r: [__m256; 4] = std::array::from_fn(|p| {
            // SAFETY: cells by the caller's contract.
            let (va, vb) = unsafe { (self.pair_at(a[p], a[p + 4]), self.pair_at(b[p], b[p + 4])) };
            lerp(va, vb, half)
        });
        transpose(r)
    }

    /// [`Geometry::centred`] at eight points.
    ///
    /// # Safety
    /// The CPU must have AVX2 and FMA. Not a `target_feature` function, so that it can be
    /// `inline(always)` (the callers are, and the intrinsics inline there): called twice per
    /// face, it must not be a call with its vectors passed through memory.
    #[inline(always)]
    pub(super) unsafe fn sample(&self, p: [__m256; 3]) -> [__m256; 3] {
        // SAFETY: the CPU has AVX2 and FMA (the caller's contract); the loads are in bounds
        // as said at each.
        unsafe {
            let (x0, x1, tx) = self.ax[0].locate(p[0]);
            let (y0, y1, ty) = self.ax[1].locate(p[1]);
            let (z0, z1, tz) = self.ax[2].locate(p[2]);
            let mut out = [_mm256_setzero_ps(); 4];
            // Pair p (lanes p and p + 4) lerped from its eight corners `$v(p, k)` (rows (y, z)
            // 00, 10, 01, 11, each at x0 and x1).
            macro_rules! pairs {
                ($v:expr) => {
                    for (p, o) in out.iter_mut().enumerate() {
                        let g = |k: usize| ($v)(p, k);
                        let wx = _mm256_permutevar8x32_ps(tx, self.pair[p]);
                        let wy = _mm256_permutevar8x32_ps(ty, self.pair[p]);
                        let wz = _mm256_permutevar8x32_ps(tz, self.pair[p]);
                        let c0 = lerp(lerp(g(0), g(1), wx), lerp(g(2), g(3), wx), wy);
                        let c1 = lerp(lerp(g(4), g(5), wx), lerp(g(6), g(7), wx), wy);
                        *o = lerp(c0, c1, wz);
                    }
                };
            }
            if let Some(off) = self.corner_bytes {
                // No periodic axis: the corners are fixed offsets from the first, one index per
                // lane instead of eight (and the loads address `first + offset` directly).
                let first = lanes_i32(_mm256_add_epi32(_mm256_add_epi32(y0, z0), x0));
                pairs!(|p: usize, k: usize| {
                    debug_assert!((first[p].max(first[p + 4]) as usize) < self.len);
                    // In bounds: `locate` keeps each lower index at most n - 2 on a clamped
                    // axis (0 for a single cell, whose step is 0), so every corner is a cell.
                    let lo = self.ptr.add(first[p] as usize).byte_add(off[k]);
                    let hi = self.ptr.add(first[p + 4] as usize).byte_add(off[k]);
                    _mm256_loadu2_m128(hi.cast(), lo.cast())
                });
            } else {
                let rows = [
                    _mm256_add_epi32(y0, z0),
                    _mm256_add_epi32(y1, z0),
                    _mm256_add_epi32(y0, z1),
                    _mm256_add_epi32(y1, z1),
                ];
                let corner: [[i32; 8]; 8] = std::array::from_fn(|k| {
                    lanes_i32(_mm256_add_epi32(
                        rows[k / 2],
                        if k % 2 == 0 { x0 } else { x1 },
                    ))
                });
                // In bounds: `locate` keeps every axis index in range, so the corners are cells.
                pairs!(|p: usize, k: usize| self.pair_at(corner[k][p], corner[k][p + 4]));
            }
            transpose(out)
        }
    }
}

/// The offsets of the eight corners of a trilinear stencil from the first (x fastest, then y,
/// then z), if every axis has a fixed step ([`AxisV::fixed_step`]).
fn corner_offsets(steps: [Option<i32>; 3]) -> Option<[i32; 8]> {
    let [sx, sy, sz] = [steps[0]?, steps[1]?, steps[2]?];
    Some(std::array::from_fn(|k| {
        let bit = |b: usize, s: i32| if k >> b & 1 == 1 { s } else { 0 };
        bit(0, sx) + bit(1, sy) + bit(2, sz)
    }))
}

/// [`Geometry::sample`] of component `c` at eight points: (value, min, max).
///
/// # Safety
/// The CPU must have AVX2 and FMA, and `field` must be a full face array of component `c`
/// (`layout.face_count(c)` values). Not a `target_feature` function, so that it can be
/// `inline(always)`, as [`Centred::sample`].
#[inline(always)]
unsafe fn sample_face<const BOUNDS: bool>(
    ax: &[AxisV; 3],
    field: &[f32],
    p: [__m256; 3],
) -> (__m256, __m256, __m256) {
    // SAFETY: the CPU has AVX2 and FMA (the caller's contract); the loads are in bounds as
    // said at each.
    unsafe {
        let (x0, x1, tx) = ax[0].locate(p[0]);
        let (y0, y1, ty) = ax[1].locate(p[1]);
        let (z0, z1, tz) = ax[2].locate(p[2]);
        let r = [
            _mm256_add_epi32(y0, z0),
            _mm256_add_epi32(y1, z0),
            _mm256_add_epi32(y0, z1),
            _mm256_add_epi32(y1, z1),
        ];
        let (ptr, len) = (field.as_ptr(), field.len());
        let s: [__m256; 8] = if ax[0].pairs {
            // x1 = x0 + 1 in every lane: one 8-byte load per row and face instead of gathers
            // (~40 micro-ops each on Zen 3), then even/odd floats split into x0 and x1 lanes.
            // Faces are loaded in the order (0, 1, 4, 5) and (2, 3, 6, 7) so that the in-lane
            // shuffles come out in lane order.
            let mut s = [_mm256_setzero_ps(); 8];
            // Row q's eight pairs from `$at(q, lane)`, the address of the lower float.
            macro_rules! rows {
                ($at:expr) => {
                    for q in 0..4 {
                        let ld = |l: usize| {
                            let at: *const f32 = ($at)(q, l);
                            // In bounds: `locate` keeps x0 <= n - 2 on a clamped axis with
                            // n > 1 (`pairs`), so both floats of each pair are faces of the
                            // array (its length is the caller's contract).
                            at.cast::<i64>().read_unaligned()
                        };
                        let a = _mm256_castsi256_ps(_mm256_setr_epi64x(ld(0), ld(1), ld(4), ld(5)));
                        let b = _mm256_castsi256_ps(_mm256_setr_epi64x(ld(2), ld(3), ld(6), ld(7)));
                        s[2 * q] = _mm256_shuffle_ps::<0x88>(a, b);
                        s[2 * q + 1] = _mm256_shuffle_ps::<0xDD>(a, b);
                    }
                };
            }
            if let (Some(sy), Some(sz)) = (ax[1].fixed_step, ax[2].fixed_step) {
                // Clamped y and z: the rows are fixed offsets from the first, one index per lane
                // instead of four (and the loads address `first + offset` directly).
                let first = lanes_i32(_mm256_add_epi32(r[0], x0));
                let f32_bytes = std::mem::size_of::<f32>();
                let off = [0, sy, sz, sy + sz].map(|o| o as usize * f32_bytes);
                rows!(|q: usize, l: usize| {
                    debug_assert!(first[l] >= 0 && first[l] as usize + off[q] / 4 + 1 < len);
                    ptr.add(first[l] as usize).byte_add(off[q])
                });
            } else {
                let i = r.map(|r| lanes_i32(_mm256_add_epi32(r, x0)));
                rows!(|q: usize, l: usize| {
                    debug_assert!(i[q][l] >= 0 && (i[q][l] as usize) + 1 < len);
                    ptr.add(i[q][l] as usize)
                });
            }
            s
        } else {
            // In bounds: `locate` keeps each axis index below that axis' face count, so the
            // offsets index faces of the array (the caller's contract gives its length).
            std::array::from_fn(|k| {
                gather(
                    ptr,
                    len,
                    _mm256_add_epi32(r[k / 2], if k % 2 == 0 { x0 } else { x1 }),
                )
            })
        };
        let (mut lo, mut hi) = (_mm256_setzero_ps(), _mm256_setzero_ps());
        if BOUNDS {
            lo = s[0];
            hi = s[0];
            for &v in &s[1..] {
                lo = _mm256_min_ps(lo, v);
                hi = _mm256_max_ps(hi, v);
            }
        }
        let c0 = lerp(lerp(s[0], s[1], tx), lerp(s[2], s[3], tx), ty);
        let c1 = lerp(lerp(s[4], s[5], tx), lerp(s[6], s[7], tx), ty);
        (lerp(c0, c1, tz), lo, hi)
    }
}

/// [`Pass::block`] eight faces at a time: `each(position within the block, valid lanes,
/// values, min, max)`.
///
/// # Safety
/// The CPU must have AVX2 and FMA.
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn block<const BOUNDS: bool>(
    pass: &Pass,
    b: usize,
    mut each: impl FnMut(usize, usize, &[f32; 8], &[f32; 8], &[f32; 8]),
) {
    // SAFETY: the caller's contract.
    unsafe { trace::<BOUNDS, false>(pass, b, |o, m, v, lo, hi, _| each(o, m, v, lo, hi)) }
}

/// [`Pass::block`] eight faces at a time, and with `FORWARD` also the forward trace's foot
/// points (the trace of the same pass with `-dt_cells`, to the bit): `each(position within
/// the block, valid lanes, values, min, max, forward foot x, y, z)`. The two traces share the
/// velocity at the face and run side by side (their gathers overlap).
///
/// # Safety
/// The CPU must have AVX2 and FMA.
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn trace<const BOUNDS: bool, const FORWARD: bool>(
    pass: &Pass,
    b: usize,
    mut each: impl FnMut(usize, usize, &[f32; 8], &[f32; 8], &[f32; 8], &[[f32; 8]; 3]),
) {
    let plan = pass.plan;
    let runs = &plan.runs[plan.block_runs[b] as usize..plan.block_runs[b + 1] as usize];
    let base = b * BLOCK;
    let geo = pass.geo;
    let centred = Centred::new(geo, pass.vc);
    let dims = geo.dims.map(|d| d as i32);
    let dt = _mm256_set1_ps(pass.dt_cells);
    let half_dt = _mm256_set1_ps(0.5 * pass.dt_cells);
    // The forward trace's steps, as a pass with `-dt_cells` would compute them.
    let dt_f = _mm256_set1_ps(-pass.dt_cells);
    let half_dt_f = _mm256_set1_ps(0.5 * -pass.dt_cells);
    let lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    let (mut vo, mut lo, mut hi) = ([0f32; 8], [0f32; 8], [0f32; 8]);
    let mut fo = [[0f32; 8]; 3];
    // The gathers' bounds rest on this (a cheap check per block, not a debug assertion).
    check_sources(pass);
    for run in runs {
        let c = run.c as usize;
        let src = pass.src[c];
        let fax: [AxisV; 3] = std::array::from_fn(|a| AxisV::new(&geo.faces[c].ax[a], 1));
        let f = run.f.map(|v| v as i32);
        let len = run.len as i32;
        let o = run.compact as usize - base;
        // The cells beside each face (`Geometry::face_cells`): `base` is the cell with the
        // face's coordinates, the lower one is a stride below (wrapped or clamped at 0),
        // and the far boundary face of a non-periodic axis takes the last cell on both sides.
        let n_c = _mm256_set1_epi32(dims[c]);
        let stride_c = _mm256_set1_epi32(geo.centred.ax[c].stride as i32);
        let wrap_c = if geo.periodic[c] {
            _mm256_mullo_epi32(_mm256_set1_epi32(dims[c] - 1), stride_c)
        } else {
            _mm256_setzero_si256()
        };
        let row = dims[0] * (f[1] + dims[1] * f[2]);
        let pos_y = _mm256_set1_ps(f[1] as f32 + if c == 1 { 0.0 } else { 0.5 });
        let pos_z = _mm256_set1_ps(f[2] as f32 + if c == 2 { 0.0 } else { 0.5 });
        let sh_x = if c == 0 { 0.0 } else { 0.5 };
        // Three short loops over a chunk of vectors, as in the scalar trace: each vector's
        // work is a long chain (gathers -> midpoint -> gathers -> foot -> gathers) of more
        // micro-ops than the reorder window holds, so independent chains must be adjacent.
        let mut k = 0;
        while k < len {
            let nv = ((len - k) as usize).div_ceil(8).min(CHUNK_VECTORS);
            let mut pos = [[_mm256_setzero_ps(); 3]; CHUNK_VECTORS];
            let mut pts = [[_mm256_setzero_ps(); 3]; CHUNK_VECTORS];
            let mut pts_f = [[_mm256_setzero_ps(); 3]; CHUNK_VECTORS];
            for j in 0..nv {
                let k = k + 8 * j as i32;
                // Lanes past the run repeat its last face (valid indices; results dropped).
                let fx = _mm256_min_epi32(
                    _mm256_add_epi32(_mm256_set1_epi32(f[0] + k), lane),
                    _mm256_set1_epi32(f[0] + len - 1),
                );
                let fc = if c == 0 { fx } else { _mm256_set1_epi32(f[c]) };
                let cell = _mm256_add_epi32(fx, _mm256_set1_epi32(row));
                let below = _mm256_sub_epi32(cell, stride_c);
                let at_zero = _mm256_cmpeq_epi32(fc, _mm256_setzero_si256());
                let at_top = _mm256_cmpgt_epi32(fc, _mm256_sub_epi32(n_c, _mm256_set1_epi32(1)));
                let c_lo = _mm256_blendv_epi8(below, _mm256_add_epi32(cell, wrap_c), at_zero);
                let c_hi = _mm256_blendv_epi8(cell, below, at_top);
                pos[j] = [
                    _mm256_add_ps(_mm256_cvtepi32_ps(fx), _mm256_set1_ps(sh_x)),
                    pos_y,
                    pos_z,
                ];
                // SAFETY: `c_lo`, `c_hi` are cells of the grid (the face coordinates are in
                // range and the boundary cases are clamped or wrapped as above).
                let v = unsafe { centred.mean(c_lo, c_hi) };
                for a in 0..3 {
                    pts[j][a] = sub_scaled(pos[j][a], half_dt, v[a]);
                    if FORWARD {
                        pts_f[j][a] = sub_scaled(pos[j][a], half_dt_f, v[a]);
                    }
                }
            }
            for j in 0..nv {
                // SAFETY: the CPU has AVX2 and FMA (this function's contract).
                let vm = unsafe { centred.sample(pts[j]) };
                let vm_f = if FORWARD {
                    // SAFETY: as above.
                    unsafe { centred.sample(pts_f[j]) }
                } else {
                    vm
                };
                for a in 0..3 {
                    pts[j][a] = sub_scaled(pos[j][a], dt, vm[a]);
                    if FORWARD {
                        pts_f[j][a] = sub_scaled(pos[j][a], dt_f, vm_f[a]);
                    }
                }
            }
            for (j, p) in pts[..nv].iter().enumerate() {
                let k = k + 8 * j as i32;
                // SAFETY: `src` is the full face array of component c (checked above).
                let (v, l, h) = unsafe { sample_face::<BOUNDS>(&fax, src, *p) };
                // SAFETY: the arrays have room for eight lanes.
                unsafe {
                    _mm256_storeu_ps(vo.as_mut_ptr(), v);
                    if BOUNDS {
                        _mm256_storeu_ps(lo.as_mut_ptr(), l);
                        _mm256_storeu_ps(hi.as_mut_ptr(), h);
                    }
                    if FORWARD {
                        for (a, fa) in fo.iter_mut().enumerate() {
                            _mm256_storeu_ps(fa.as_mut_ptr(), pts_f[j][a]);
                        }
                    }
                }
                each(
                    o + k as usize,
                    (len - k).min(8) as usize,
                    &vo,
                    &lo,
                    &hi,
                    &fo,
                );
            }
            k += 8 * nv as i32;
        }
    }
}

/// Asserts that every source of `pass` is a full face array of its component (what keeps the
/// gathers of [`sample_face`] in bounds).
fn check_sources(pass: &Pass) {
    for c in 0..3 {
        let faces = pass.geo.faces[c]
            .ax
            .iter()
            .map(|a| a.n as usize)
            .product::<usize>();
        assert_eq!(
            pass.src[c].len(),
            faces,
            "advection source {c} is not a full face array"
        );
    }
}

/// Eight lanes of `s` from `k` (`m` valid, the rest zero).
///
/// # Safety
/// The CPU must have AVX. Not a `target_feature` function, so that it can be
/// `inline(always)`, as [`Centred::sample`].
#[inline(always)]
unsafe fn load8(s: &[f32], k: usize, m: usize) -> __m256 {
    let mut a = [0f32; 8];
    let s = if m == 8 {
        &s[k..k + 8]
    } else {
        a[..m].copy_from_slice(&s[k..k + m]);
        &a
    };
    // SAFETY: `s` has eight floats; the CPU has AVX (the caller's contract).
    unsafe { _mm256_loadu_ps(s.as_ptr()) }
}

/// [`Pass::maccormack_correct`] on block `b`, eight faces at a time (the same operations as
/// the scalar loop, so the same values): `foot`, `lo`, `hi` and `out` are the block's slices.
///
/// # Safety
/// The CPU must have AVX2 and FMA.
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn correct(
    pass: &Pass,
    b: usize,
    orig: [&[f32]; 3],
    foot: [&[f32]; 3],
    [lo, hi]: [&[f32]; 2],
    out: &mut [f32],
) {
    let plan = pass.plan;
    let runs = &plan.runs[plan.block_runs[b] as usize..plan.block_runs[b + 1] as usize];
    let base = b * BLOCK;
    let half = _mm256_set1_ps(0.5);
    let abs_mask = _mm256_castsi256_ps(_mm256_set1_epi32(0x7fff_ffff));
    let inf = _mm256_set1_ps(f32::INFINITY);
    let mut r = [0f32; 8];
    check_sources(pass);
    for run in runs {
        let c = run.c as usize;
        let src = pass.src[c];
        let fax: [AxisV; 3] = std::array::from_fn(|a| AxisV::new(&pass.geo.faces[c].ax[a], 1));
        let (len, o, full) = (
            run.len as usize,
            run.compact as usize - base,
            run.full as usize,
        );
        let orig = &orig[c][full..full + len];
        let mut k = 0;
        while k < len {
            let (m, n) = ((len - k).min(8), o + k);
            // SAFETY: the CPU has AVX2 and FMA (this function's contract), and `src` is the
            // full face array of component c (checked above).
            let (hat, u0, l, h, back) = unsafe {
                let p = [
                    load8(foot[0], n, m),
                    load8(foot[1], n, m),
                    load8(foot[2], n, m),
                ];
                let (hat, u0) = (load8(out, n, m), load8(orig, k, m));
                let (l, h) = (load8(lo, n, m), load8(hi, n, m));
                (hat, u0, l, h, sample_face::<false>(&fax, src, p).0)
            };
            let v = _mm256_add_ps(hat, _mm256_mul_ps(half, _mm256_sub_ps(u0, back)));
            let finite = _mm256_cmp_ps::<_CMP_LT_OQ>(_mm256_and_ps(v, abs_mask), inf);
            let w = _mm256_blendv_ps(v, l, _mm256_cmp_ps::<_CMP_LT_OQ>(v, l));
            let w = _mm256_blendv_ps(w, h, _mm256_cmp_ps::<_CMP_GT_OQ>(w, h));
            let res = _mm256_blendv_ps(hat, w, finite);
            if m == 8 {
                let s = &mut out[n..n + 8];
                // SAFETY: `s` has eight floats.
                unsafe { _mm256_storeu_ps(s.as_mut_ptr(), res) };
            } else {
                // SAFETY: `r` has eight floats.
                unsafe { _mm256_storeu_ps(r.as_mut_ptr(), res) };
                out[n..n + m].copy_from_slice(&r[..m]);
            }
            k += m;
        }
    }
}
