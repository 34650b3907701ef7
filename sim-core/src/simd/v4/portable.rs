//! [`V4`] as a plain array: the build for targets other than x86-64, and the reference the
//! SSE build is tested against (`super::tests`). Each function is written as the SSE
//! instruction it stands for computes, lane by lane (NaN rules included).

/// Four lanes of f32; a mask has every bit of a true lane set.
pub type V4 = [f32; 4];

/// `[a, b, c, 0]`.
#[inline(always)]
pub fn new(a: f32, b: f32, c: f32) -> V4 {
    [a, b, c, 0.0]
}

/// `[a, b, c, d]`.
#[inline(always)]
pub fn new4(a: f32, b: f32, c: f32, d: f32) -> V4 {
    [a, b, c, d]
}

/// All zero.
#[inline(always)]
pub fn zero() -> V4 {
    [0.0; 4]
}

/// `[x, x, x, x]`.
#[inline(always)]
pub fn splat(x: f32) -> V4 {
    [x; 4]
}

/// `[0, 1, 2, 3]`.
#[inline(always)]
pub fn ramp() -> V4 {
    [0.0, 1.0, 2.0, 3.0]
}

/// The lanes.
#[inline(always)]
pub fn lanes(v: V4) -> [f32; 4] {
    v
}

/// The four floats of `p`.
#[inline(always)]
pub fn load(p: &[f32; 4]) -> V4 {
    *p
}

#[inline(always)]
fn map2(a: V4, b: V4, f: impl Fn(f32, f32) -> f32) -> V4 {
    std::array::from_fn(|l| f(a[l], b[l]))
}

#[inline(always)]
fn mask(t: bool) -> f32 {
    f32::from_bits(if t { u32::MAX } else { 0 })
}

/// `a + b`.
#[inline(always)]
pub fn add(a: V4, b: V4) -> V4 {
    map2(a, b, |a, b| a + b)
}

/// `a - b`.
#[inline(always)]
pub fn sub(a: V4, b: V4) -> V4 {
    map2(a, b, |a, b| a - b)
}

/// `a b`.
#[inline(always)]
pub fn mul(a: V4, b: V4) -> V4 {
    map2(a, b, |a, b| a * b)
}

/// `a b + c` (two roundings, not a fused multiply-add).
#[inline(always)]
pub fn mul_add(a: V4, b: V4, c: V4) -> V4 {
    std::array::from_fn(|l| a[l] * b[l] + c[l])
}

/// `a + t (b - a)`.
#[inline(always)]
pub fn lerp(a: V4, b: V4, t: V4) -> V4 {
    std::array::from_fn(|l| a[l] + t[l] * (b[l] - a[l]))
}

/// `x - s v`.
#[inline(always)]
pub fn sub_scaled(x: V4, s: f32, v: V4) -> V4 {
    std::array::from_fn(|l| x[l] - s * v[l])
}

/// The larger lane of each pair; the second operand where either is NaN.
#[inline(always)]
pub fn max(a: V4, b: V4) -> V4 {
    map2(a, b, |a, b| if a > b { a } else { b })
}

/// The smaller lane of each pair; the second operand where either is NaN.
#[inline(always)]
pub fn min(a: V4, b: V4) -> V4 {
    map2(a, b, |a, b| if a < b { a } else { b })
}

/// `|a|` (the sign bit cleared).
#[inline(always)]
pub fn abs(a: V4) -> V4 {
    a.map(f32::abs)
}

/// Mask of `a < b`.
#[inline(always)]
pub fn lt(a: V4, b: V4) -> V4 {
    map2(a, b, |a, b| mask(a < b))
}

/// Mask of `a <= b`.
#[inline(always)]
pub fn le(a: V4, b: V4) -> V4 {
    map2(a, b, |a, b| mask(a <= b))
}

/// Bitwise and (of masks, or a mask and a value).
#[inline(always)]
pub fn and(a: V4, b: V4) -> V4 {
    map2(a, b, |a, b| f32::from_bits(a.to_bits() & b.to_bits()))
}

/// Mask of `lo <= [0, 1, 2, 3] <= hi`.
#[inline(always)]
pub fn between(lo: f32, hi: f32) -> V4 {
    and(le(splat(lo), ramp()), le(ramp(), splat(hi)))
}

/// One bit per lane (bit `l` of lane `l`'s sign).
#[inline(always)]
pub fn bits(m: V4) -> u32 {
    (0..4).map(|l| (m[l].to_bits() >> 31) << l).sum()
}

/// Largest `|a| + |b|` over the lanes.
#[inline(always)]
pub fn max_abs_sum(a: V4, b: V4) -> f32 {
    (0..4).fold(0.0, |m: f32, l| m.max(a[l].abs() + b[l].abs()))
}

/// Lanes x, y and z of `t`, each broadcast.
#[inline(always)]
pub fn broadcast3(t: V4) -> [V4; 3] {
    [[t[0]; 4], [t[1]; 4], [t[2]; 4]]
}

/// Mask of the non-zero bytes of the four from `i`.
///
/// # Safety
/// `i + 4 <= b.len()` (checked here anyway).
#[inline(always)]
pub unsafe fn nonzero_at(b: &[u8], i: usize) -> V4 {
    std::array::from_fn(|l| mask(b[i + l] != 0))
}

/// The four floats of `s` from `i`.
///
/// # Safety
/// `i + 4 <= s.len()` (checked here anyway).
#[inline(always)]
pub unsafe fn load_at(s: &[f32], i: usize) -> V4 {
    std::array::from_fn(|l| s[i + l])
}

/// Writes the four floats of `s` from `i`.
///
/// # Safety
/// `i + 4 <= s.len()` (checked here anyway).
#[inline(always)]
pub unsafe fn store_at(s: &mut [f32], i: usize, v: V4) {
    s[i..i + 4].copy_from_slice(&v);
}

/// The first (up to) four floats of `s`, zero beyond its end.
#[inline(always)]
pub fn load_padded(s: &[f32]) -> V4 {
    std::array::from_fn(|l| s.get(l).copied().unwrap_or(0.0))
}

/// Linear interpolation in `table` (value, slope per entry) at `t` (in `[0, N]`, or NaN: then
/// entry 0).
#[inline(always)]
pub fn lookup<const N: usize>(table: &[[f32; 2]; N], t: V4) -> V4 {
    t.map(|t| {
        let i = (t as usize).min(N - 1);
        let [v, d] = table[i];
        v + (t - i as f32) * d
    })
}

/// The cell of `p` (grid units) if it lies in `[0, dims)` (a NaN lane fails).
#[inline(always)]
pub fn cell(p: V4, dims: V4, stride: [usize; 3]) -> Option<usize> {
    if !(0..4).all(|a| p[a] >= 0.0 && p[a] < dims[a]) {
        return None;
    }
    Some((0..3).map(|a| (p[a] as usize) * stride[a]).sum())
}

/// The lower corner (index) of the cell-centred samples around `p` and the weights of the
/// upper ones (lanes x, y, z): positions clamp to the outermost samples (`smax`, the lower index
/// to `imax`), a NaN lane lands on sample 0.
#[inline(always)]
pub fn locate(p: V4, smax: V4, imax: V4, stride: [usize; 3]) -> (usize, V4) {
    let mut b = 0;
    let mut t = [0.0; 4];
    for a in 0..4 {
        let s = (p[a] - 0.5).max(0.0).min(smax[a]);
        let i = s.floor().min(imax[a]);
        if a < 3 {
            b += i as usize * stride[a];
        }
        t[a] = s - i;
    }
    (b, t)
}
