//! [`V4`] in one SSE register (SSE2 is part of the x86-64 baseline, so every x86-64 CPU runs
//! these), and the AVX2 + FMA blends of the particle sampler.
//!
//! Every function but the AVX2 ones and those that read memory takes and returns registers only:
//! its intrinsics have no precondition beyond SSE2, which the target guarantees.

use std::arch::x86_64::*;

/// Four lanes of f32 in one SSE register; a mask has every bit of a true lane set.
pub type V4 = __m128;

/// `[a, b, c, 0]`.
#[inline(always)]
pub fn new(a: f32, b: f32, c: f32) -> V4 {
    // SAFETY: SSE2 (the x86-64 baseline); no pointers.
    unsafe { _mm_set_ps(0.0, c, b, a) }
}

/// `[a, b, c, d]`.
#[inline(always)]
pub fn new4(a: f32, b: f32, c: f32, d: f32) -> V4 {
    // SAFETY: SSE2 (the x86-64 baseline); no pointers.
    unsafe { _mm_set_ps(d, c, b, a) }
}

/// All zero.
#[inline(always)]
pub fn zero() -> V4 {
    // SAFETY: SSE2 (the x86-64 baseline); no pointers.
    unsafe { _mm_setzero_ps() }
}

/// `[x, x, x, x]`.
#[inline(always)]
pub fn splat(x: f32) -> V4 {
    // SAFETY: SSE2 (the x86-64 baseline); no pointers.
    unsafe { _mm_set1_ps(x) }
}

/// `[0, 1, 2, 3]`.
#[inline(always)]
pub fn ramp() -> V4 {
    // SAFETY: SSE2 (the x86-64 baseline); no pointers.
    unsafe { _mm_set_ps(3.0, 2.0, 1.0, 0.0) }
}

/// The lanes.
#[inline(always)]
pub fn lanes(v: V4) -> [f32; 4] {
    bytemuck::cast(v)
}

/// The four floats of `p`.
#[inline(always)]
pub fn load(p: &[f32; 4]) -> V4 {
    // SAFETY: SSE2; `p` is four readable floats (an unaligned load).
    unsafe { _mm_loadu_ps(p.as_ptr()) }
}

/// `a + b`.
#[inline(always)]
pub fn add(a: V4, b: V4) -> V4 {
    // SAFETY: SSE2 (the x86-64 baseline); no pointers.
    unsafe { _mm_add_ps(a, b) }
}

/// `a - b`.
#[inline(always)]
pub fn sub(a: V4, b: V4) -> V4 {
    // SAFETY: SSE2 (the x86-64 baseline); no pointers.
    unsafe { _mm_sub_ps(a, b) }
}

/// `a b`.
#[inline(always)]
pub fn mul(a: V4, b: V4) -> V4 {
    // SAFETY: SSE2 (the x86-64 baseline); no pointers.
    unsafe { _mm_mul_ps(a, b) }
}

/// `a b + c` (two roundings, not a fused multiply-add).
#[inline(always)]
pub fn mul_add(a: V4, b: V4, c: V4) -> V4 {
    // SAFETY: SSE2 (the x86-64 baseline); no pointers.
    unsafe { _mm_add_ps(_mm_mul_ps(a, b), c) }
}

/// `a + t (b - a)`.
#[inline(always)]
pub fn lerp(a: V4, b: V4, t: V4) -> V4 {
    // SAFETY: SSE2 (the x86-64 baseline); no pointers.
    unsafe { _mm_add_ps(a, _mm_mul_ps(t, _mm_sub_ps(b, a))) }
}

/// `x - s v`.
#[inline(always)]
pub fn sub_scaled(x: V4, s: f32, v: V4) -> V4 {
    // SAFETY: SSE2 (the x86-64 baseline); no pointers.
    unsafe { _mm_sub_ps(x, _mm_mul_ps(_mm_set1_ps(s), v)) }
}

/// The larger lane of each pair; the second operand where either is NaN.
#[inline(always)]
pub fn max(a: V4, b: V4) -> V4 {
    // SAFETY: SSE2 (the x86-64 baseline); no pointers.
    unsafe { _mm_max_ps(a, b) }
}

/// The smaller lane of each pair; the second operand where either is NaN.
#[inline(always)]
pub fn min(a: V4, b: V4) -> V4 {
    // SAFETY: SSE2 (the x86-64 baseline); no pointers.
    unsafe { _mm_min_ps(a, b) }
}

/// `|a|` (the sign bit cleared).
#[inline(always)]
pub fn abs(a: V4) -> V4 {
    // SAFETY: SSE2 (the x86-64 baseline); no pointers.
    unsafe { _mm_and_ps(a, _mm_castsi128_ps(_mm_set1_epi32(0x7fff_ffff))) }
}

/// Mask of `a < b`.
#[inline(always)]
pub fn lt(a: V4, b: V4) -> V4 {
    // SAFETY: SSE2 (the x86-64 baseline); no pointers.
    unsafe { _mm_cmplt_ps(a, b) }
}

/// Mask of `a <= b`.
#[inline(always)]
pub fn le(a: V4, b: V4) -> V4 {
    // SAFETY: SSE2 (the x86-64 baseline); no pointers.
    unsafe { _mm_cmple_ps(a, b) }
}

/// Bitwise and (of masks, or a mask and a value).
#[inline(always)]
pub fn and(a: V4, b: V4) -> V4 {
    // SAFETY: SSE2 (the x86-64 baseline); no pointers.
    unsafe { _mm_and_ps(a, b) }
}

/// Mask of `lo <= [0, 1, 2, 3] <= hi`.
#[inline(always)]
pub fn between(lo: f32, hi: f32) -> V4 {
    and(le(splat(lo), ramp()), le(ramp(), splat(hi)))
}

/// One bit per lane (bit `l` of lane `l`'s sign).
#[inline(always)]
pub fn bits(m: V4) -> u32 {
    // SAFETY: SSE2 (the x86-64 baseline); no pointers.
    unsafe { _mm_movemask_ps(m) as u32 }
}

/// Largest `|a| + |b|` over the lanes.
#[inline(always)]
pub fn max_abs_sum(a: V4, b: V4) -> f32 {
    // SAFETY: SSE2 (the x86-64 baseline); no pointers.
    unsafe {
        let m = _mm_castsi128_ps(_mm_set1_epi32(0x7fff_ffff));
        let s = _mm_add_ps(_mm_and_ps(a, m), _mm_and_ps(b, m));
        let s = _mm_max_ps(s, _mm_movehl_ps(s, s));
        _mm_cvtss_f32(_mm_max_ss(s, _mm_shuffle_ps::<0b01>(s, s)))
    }
}

/// Lanes x, y and z of `t`, each broadcast.
#[inline(always)]
pub fn broadcast3(t: V4) -> [V4; 3] {
    // SAFETY: SSE2 (the x86-64 baseline); no pointers.
    unsafe {
        [
            _mm_shuffle_ps::<0b00_00_00_00>(t, t),
            _mm_shuffle_ps::<0b01_01_01_01>(t, t),
            _mm_shuffle_ps::<0b10_10_10_10>(t, t),
        ]
    }
}

/// Mask of the non-zero bytes of the four from `i`.
///
/// # Safety
/// `i + 4 <= b.len()`.
#[inline(always)]
pub unsafe fn nonzero_at(b: &[u8], i: usize) -> V4 {
    // SAFETY: the caller's (an unaligned read of four bytes).
    let w = unsafe { b.as_ptr().add(i).cast::<i32>().read_unaligned() };
    // SAFETY: SSE2 (the x86-64 baseline); no pointers.
    unsafe {
        let z = _mm_setzero_si128();
        let v = _mm_cvtsi32_si128(i32::from_le(w));
        let v = _mm_unpacklo_epi16(_mm_unpacklo_epi8(v, z), z);
        _mm_castsi128_ps(_mm_xor_si128(_mm_cmpeq_epi32(v, z), _mm_set1_epi32(-1)))
    }
}

/// The four floats of `s` from `i`.
///
/// # Safety
/// `i + 4 <= s.len()`.
#[inline(always)]
pub unsafe fn load_at(s: &[f32], i: usize) -> V4 {
    // SAFETY: the caller's (four floats from `i` are in `s`).
    unsafe { _mm_loadu_ps(s.as_ptr().add(i)) }
}

/// Writes the four floats of `s` from `i`.
///
/// # Safety
/// `i + 4 <= s.len()`.
#[inline(always)]
pub unsafe fn store_at(s: &mut [f32], i: usize, v: V4) {
    // SAFETY: the caller's (four floats from `i` are in `s`).
    unsafe { _mm_storeu_ps(s.as_mut_ptr().add(i), v) }
}

/// The first (up to) four floats of `s`, zero beyond its end.
#[inline(always)]
pub fn load_padded(s: &[f32]) -> V4 {
    load(&std::array::from_fn(|l| s.get(l).copied().unwrap_or(0.0)))
}

/// Linear interpolation in `table` (value, slope per entry) at `t` (in `[0, N]`, or NaN: then
/// entry 0). `N` is a power of two: the index is masked to the table, so any `t` stays in bounds.
#[inline(always)]
pub fn lookup<const N: usize>(table: &[[f32; 2]; N], t: V4) -> V4 {
    const { assert!(N.is_power_of_two()) };
    // SAFETY: SSE2 (the x86-64 baseline); the only memory read is `table[n]`, a checked index.
    unsafe {
        // t >= 0: truncation floors; the last interval takes t = N at its end.
        let i = _mm_min_ps(
            _mm_cvtepi32_ps(_mm_cvttps_epi32(t)),
            _mm_set1_ps((N - 1) as f32),
        );
        let f = _mm_sub_ps(t, i);
        let i = _mm_cvttps_epi32(i);
        let at = |l: __m128i| (_mm_cvtsi128_si32(l) as u32 as usize) & (N - 1);
        let pair = |n: usize| _mm_castsi128_ps(_mm_cvtsi64_si128(bytemuck::cast(table[n])));
        let p0 = pair(at(i));
        let p1 = pair(at(_mm_shuffle_epi32::<0b01>(i)));
        let p2 = pair(at(_mm_shuffle_epi32::<0b10>(i)));
        let p3 = pair(at(_mm_shuffle_epi32::<0b11>(i)));
        // [v0 v1 d0 d1], [v2 v3 d2 d3] -> [v0 v1 v2 v3], [d0 d1 d2 d3].
        let (a, b) = (_mm_unpacklo_ps(p0, p1), _mm_unpacklo_ps(p2, p3));
        let (v, d) = (_mm_movelh_ps(a, b), _mm_movehl_ps(b, a));
        _mm_add_ps(v, _mm_mul_ps(f, d))
    }
}

/// `sum_a x_a s_a` as an index (`x` whole numbers in `[0, 2^31)`).
#[inline(always)]
fn index(x: V4, stride: [usize; 3]) -> usize {
    // SAFETY: SSE2 (the x86-64 baseline); no pointers.
    unsafe {
        let i = _mm_cvttps_epi32(x);
        let at = |l: __m128i| _mm_cvtsi128_si32(l) as u32 as usize;
        at(i) * stride[0]
            + at(_mm_shuffle_epi32::<0b01>(i)) * stride[1]
            + at(_mm_shuffle_epi32::<0b10>(i)) * stride[2]
    }
}

/// The cell of `p` (grid units) if it lies in `[0, dims)` (lane 3 of `p` zero, of `dims`
/// positive; a NaN lane fails).
#[inline(always)]
pub fn cell(p: V4, dims: V4, stride: [usize; 3]) -> Option<usize> {
    // SAFETY: SSE2 (the x86-64 baseline); no pointers.
    let ok = unsafe { _mm_and_ps(_mm_cmpge_ps(p, _mm_setzero_ps()), _mm_cmplt_ps(p, dims)) };
    if bits(ok) != 0b1111 {
        return None;
    }
    // In [0, dims): truncation is the floor.
    Some(index(p, stride))
}

/// The lower corner (index) of the cell-centred samples around `p` and the weights of the
/// upper ones (lanes x, y, z): positions clamp to the outermost samples (`smax`, the lower index
/// to `imax`), a NaN lane lands on sample 0.
#[inline(always)]
pub fn locate(p: V4, smax: V4, imax: V4, stride: [usize; 3]) -> (usize, V4) {
    // SAFETY: SSE2 (the x86-64 baseline); no pointers.
    unsafe {
        // max returns its second operand for a NaN.
        let s = _mm_min_ps(
            _mm_max_ps(_mm_sub_ps(p, _mm_set1_ps(0.5)), _mm_setzero_ps()),
            smax,
        );
        // s >= 0: truncation is the floor.
        let i = _mm_min_ps(_mm_cvtepi32_ps(_mm_cvttps_epi32(s)), imax);
        (index(i, stride), _mm_sub_ps(s, i))
    }
}

/// Trilinear interpolation of the samples `first + {0, 1} + {0, sy} + {0, sz}` with weights
/// `t` (lanes x, y, z): the x pairs as eight-lane vectors, blended along y and z, then the
/// two halves along x, each blend a fused multiply-add.
///
/// # Safety
/// The CPU has AVX2 and FMA, and `first + 1 + sy + sz` is in the same allocation as `first`.
#[target_feature(enable = "avx2,fma")]
#[inline]
pub unsafe fn trilinear_x_pairs(first: *const V4, sy: usize, sz: usize, t: V4) -> V4 {
    let f = first.cast::<f32>();
    // SAFETY: the caller's (each pair is two whole elements from an in-bounds index).
    let (p00, p10, p01, p11) = unsafe {
        (
            _mm256_loadu_ps(f),
            _mm256_loadu_ps(f.add(4 * sy)),
            _mm256_loadu_ps(f.add(4 * sz)),
            _mm256_loadu_ps(f.add(4 * (sy + sz))),
        )
    };
    let t8 = _mm256_castps128_ps256(t);
    let ty = _mm256_permutevar8x32_ps(t8, _mm256_set1_epi32(1));
    let tz = _mm256_permutevar8x32_ps(t8, _mm256_set1_epi32(2));
    let tx = _mm_shuffle_ps::<0b00_00_00_00>(t, t);
    // SAFETY: the CPU has AVX2 and FMA (this function's contract).
    unsafe { blend_x_pairs([p00, p10, p01, p11], ty, tz, tx) }
}

/// The blends of [`trilinear_x_pairs`]: the x pairs `[00, y0, 0z, yz]` along y (weight
/// `ty`, every lane), z (`tz`), then the halves along x (`tx`).
///
/// # Safety
/// The CPU has AVX2 and FMA.
#[target_feature(enable = "avx2,fma")]
#[inline]
pub unsafe fn blend_x_pairs(pairs: [__m256; 4], ty: __m256, tz: __m256, tx: V4) -> V4 {
    let [p00, p10, p01, p11] = pairs;
    let lerp8 = |a: __m256, b: __m256, t: __m256| _mm256_fmadd_ps(t, _mm256_sub_ps(b, a), a);
    let y0 = lerp8(p00, p10, ty);
    let y1 = lerp8(p01, p11, ty);
    let yz = lerp8(y0, y1, tz);
    let (lo, hi) = (_mm256_castps256_ps128(yz), _mm256_extractf128_ps::<1>(yz));
    _mm_fmadd_ps(tx, _mm_sub_ps(hi, lo), lo)
}
