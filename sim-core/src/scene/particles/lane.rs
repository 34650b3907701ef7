//! The few four-lane operations of the particle kernel beyond [`v4`]'s: SSE2 (the x86-64
//! baseline) there, so the three axes of a position take one instruction; element-wise
//! elsewhere. The one place the particles name the crate's SIMD helpers (`v4`, the AVX2 check).

#[cfg(target_arch = "x86_64")]
pub(super) use crate::fluid::avx2::available as avx2_available;
pub(super) use crate::fluid::{v4, V4};
#[cfg(not(target_arch = "x86_64"))]
pub use portable::*;
#[cfg(target_arch = "x86_64")]
pub use sse2::*;

/// SSE2 (the x86-64 baseline): the three axes of a position take one instruction.
#[cfg(target_arch = "x86_64")]
mod sse2 {
    use std::arch::x86_64::*;

    pub use super::v4::{mul, splat, sub};
    use super::V4;

    // SAFETY (every `unsafe` below): SSE2 is part of the x86-64 baseline, and these intrinsics
    // take no pointers.

    /// `[a, b, c, d]`.
    #[inline(always)]
    pub fn new4(a: f32, b: f32, c: f32, d: f32) -> V4 {
        unsafe { _mm_set_ps(d, c, b, a) }
    }
    /// `a b + c`.
    #[inline(always)]
    pub fn mul_add(a: V4, b: V4, c: V4) -> V4 {
        unsafe { _mm_add_ps(_mm_mul_ps(a, b), c) }
    }
    /// `a + t (b - a)`, `t` the same in every lane.
    #[inline(always)]
    pub fn lerp(a: V4, b: V4, t: V4) -> V4 {
        unsafe { _mm_add_ps(a, _mm_mul_ps(t, _mm_sub_ps(b, a))) }
    }
    /// Largest `|a| + |b|` over the lanes.
    #[inline(always)]
    pub fn max_abs_sum(a: V4, b: V4) -> f32 {
        unsafe {
            let m = _mm_castsi128_ps(_mm_set1_epi32(0x7fff_ffff));
            let s = _mm_add_ps(_mm_and_ps(a, m), _mm_and_ps(b, m));
            let s = _mm_max_ps(s, _mm_movehl_ps(s, s));
            _mm_cvtss_f32(_mm_max_ss(s, _mm_shuffle_ps::<0b01>(s, s)))
        }
    }
    /// `sum_a x_a s_a` as an index (`x` whole numbers in `[0, 2^31)`).
    #[inline(always)]
    fn index(x: V4, stride: [usize; 3]) -> usize {
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
        unsafe {
            let ok = _mm_and_ps(_mm_cmpge_ps(p, _mm_setzero_ps()), _mm_cmplt_ps(p, dims));
            if _mm_movemask_ps(ok) != 0b1111 {
                return None;
            }
            // In [0, dims): truncation is the floor.
            Some(index(p, stride))
        }
    }
    /// The lower corner (index) of the cell-centred samples around `p` and the weights of the
    /// upper ones (lanes x, y, z): positions clamp to the outermost samples, a NaN lane lands on
    /// sample 0.
    #[inline(always)]
    pub fn locate(p: V4, smax: V4, imax: V4, stride: [usize; 3]) -> (usize, V4) {
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
    /// Lanes x, y and z of `t`, each broadcast.
    #[inline(always)]
    pub fn broadcast3(t: V4) -> [V4; 3] {
        unsafe {
            [
                _mm_shuffle_ps::<0b00_00_00_00>(t, t),
                _mm_shuffle_ps::<0b01_01_01_01>(t, t),
                _mm_shuffle_ps::<0b10_10_10_10>(t, t),
            ]
        }
    }
    /// Trilinear interpolation of the samples `first + {0, 1} + {0, sy} + {0, sz}` with weights
    /// `t` (lanes x, y, z): the x pairs as eight-lane vectors, blended along y and z, then the
    /// two halves along x.
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
        blend_x_pairs([p00, p10, p01, p11], ty, tz, tx)
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
}

/// Element-wise (portable fallback).
#[cfg(not(target_arch = "x86_64"))]
mod portable {
    pub use super::v4::{mul, splat, sub};
    use super::V4;

    /// `[a, b, c, d]`.
    #[inline(always)]
    pub fn new4(a: f32, b: f32, c: f32, d: f32) -> V4 {
        [a, b, c, d]
    }
    /// `a b + c`.
    #[inline(always)]
    pub fn mul_add(a: V4, b: V4, c: V4) -> V4 {
        std::array::from_fn(|l| a[l] * b[l] + c[l])
    }
    /// `a + t (b - a)`, `t` the same in every lane.
    #[inline(always)]
    pub fn lerp(a: V4, b: V4, t: V4) -> V4 {
        std::array::from_fn(|l| a[l] + t[l] * (b[l] - a[l]))
    }
    /// Largest `|a| + |b|` over the lanes.
    #[inline(always)]
    pub fn max_abs_sum(a: V4, b: V4) -> f32 {
        (0..4).fold(0.0, |m: f32, l| m.max(a[l].abs() + b[l].abs()))
    }
    /// The cell of `p` (grid units) if it lies in `[0, dims)`.
    #[inline(always)]
    pub fn cell(p: V4, dims: V4, stride: [usize; 3]) -> Option<usize> {
        if !(0..3).all(|a| p[a] >= 0.0 && p[a] < dims[a]) {
            return None;
        }
        Some((0..3).map(|a| (p[a] as usize) * stride[a]).sum())
    }
    /// The lower corner (index) of the cell-centred samples around `p` and the weights of the
    /// upper ones (lanes x, y, z).
    #[inline(always)]
    pub fn locate(p: V4, smax: V4, imax: V4, stride: [usize; 3]) -> (usize, V4) {
        let mut b = 0;
        let mut t = [0.0; 4];
        for a in 0..3 {
            let s = (p[a] - 0.5).max(0.0).min(smax[a]);
            let i = s.floor().min(imax[a]);
            b += i as usize * stride[a];
            t[a] = s - i;
        }
        (b, t)
    }
    /// Lanes x, y and z of `t`, each broadcast.
    #[inline(always)]
    pub fn broadcast3(t: V4) -> [V4; 3] {
        [[t[0]; 4], [t[1]; 4], [t[2]; 4]]
    }
}
