//! Four-lane f32 vectors for positions, velocities and node rows (the fourth lane of a position
//! is zero): one SSE register on x86-64, where building them element-wise would go through memory
//! (a stalled store-to-load forward per face) and LLVM would drop the fourth lane and emit scalar
//! code; a plain array elsewhere. The advection trace, the particle kernel and the vortex node
//! kernel share these operations.
//!
//! The SSE build ([`sse`]) is tested against the portable one ([`portable`]) operation by
//! operation: equal to the bit, NaN rules included, on random and special values.

#[cfg(any(test, not(target_arch = "x86_64")))]
// On x86-64 only the tests build it, as the reference; they need not call every function.
#[cfg_attr(target_arch = "x86_64", allow(dead_code))]
pub mod portable;
#[cfg(target_arch = "x86_64")]
pub mod sse;

#[cfg(not(target_arch = "x86_64"))]
pub use portable::*;
#[cfg(target_arch = "x86_64")]
pub use sse::*;

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use super::{portable as p, sse as s};

    /// Random lanes: mostly in [-4, 4), some whole numbers, zeros of both signs, infinities and
    /// NaN.
    fn value(rng: &mut fastrand::Rng) -> f32 {
        match rng.u32(0..20) {
            0 => f32::NAN,
            1 => f32::INFINITY,
            2 => f32::NEG_INFINITY,
            3 => 0.0,
            4 => -0.0,
            5 => rng.i32(-3..4) as f32,
            _ => rng.f32() * 8.0 - 4.0,
        }
    }

    fn lanes(rng: &mut fastrand::Rng) -> [f32; 4] {
        std::array::from_fn(|_| value(rng))
    }

    /// Equal to the bit, or both NaN (the SSE instructions and Rust's NaN payloads may differ).
    fn same(a: [f32; 4], b: [f32; 4]) -> bool {
        a.iter()
            .zip(&b)
            .all(|(x, y)| x.to_bits() == y.to_bits() || (x.is_nan() && y.is_nan()))
    }

    #[test]
    fn every_sse_operation_equals_the_portable_one() {
        let mut rng = fastrand::Rng::with_seed(17);
        for _ in 0..20_000 {
            let (a, b, c) = (lanes(&mut rng), lanes(&mut rng), lanes(&mut rng));
            let (va, vb, vc) = (s::load(&a), s::load(&b), s::load(&c));
            let x = value(&mut rng);
            let cases: [(&str, [f32; 4], [f32; 4]); 16] = [
                (
                    "new",
                    s::lanes(s::new(a[0], a[1], a[2])),
                    p::new(a[0], a[1], a[2]),
                ),
                (
                    "new4",
                    s::lanes(s::new4(a[0], a[1], a[2], a[3])),
                    p::new4(a[0], a[1], a[2], a[3]),
                ),
                ("splat", s::lanes(s::splat(x)), p::splat(x)),
                ("add", s::lanes(s::add(va, vb)), p::add(a, b)),
                ("sub", s::lanes(s::sub(va, vb)), p::sub(a, b)),
                ("mul", s::lanes(s::mul(va, vb)), p::mul(a, b)),
                (
                    "mul_add",
                    s::lanes(s::mul_add(va, vb, vc)),
                    p::mul_add(a, b, c),
                ),
                ("lerp", s::lanes(s::lerp(va, vb, vc)), p::lerp(a, b, c)),
                (
                    "sub_scaled",
                    s::lanes(s::sub_scaled(va, x, vb)),
                    p::sub_scaled(a, x, b),
                ),
                ("max", s::lanes(s::max(va, vb)), p::max(a, b)),
                ("min", s::lanes(s::min(va, vb)), p::min(a, b)),
                ("abs", s::lanes(s::abs(va)), p::abs(a)),
                ("lt", s::lanes(s::lt(va, vb)), p::lt(a, b)),
                ("le", s::lanes(s::le(va, vb)), p::le(a, b)),
                (
                    "and",
                    s::lanes(s::and(s::lt(va, vb), vc)),
                    p::and(p::lt(a, b), c),
                ),
                (
                    "between",
                    s::lanes(s::between(a[0], a[1])),
                    p::between(a[0], a[1]),
                ),
            ];
            for (name, got, want) in cases {
                assert!(
                    same(got, want),
                    "{name}({a:?}, {b:?}, {c:?}, {x}): {got:?} vs {want:?}"
                );
            }
            assert_eq!(s::bits(va), p::bits(a), "bits({a:?})");
            let t = s::broadcast3(va);
            let want = p::broadcast3(a);
            assert!(
                (0..3).all(|k| same(s::lanes(t[k]), want[k])),
                "broadcast3({a:?})"
            );
            // Sums of magnitudes: finite lanes (the NaN order of the two reductions differs).
            let fin = |v: [f32; 4]| v.map(|x| if x.is_finite() { x } else { 1.5 });
            let (fa, fb) = (fin(a), fin(b));
            assert_eq!(
                s::max_abs_sum(s::load(&fa), s::load(&fb)).to_bits(),
                p::max_abs_sum(fa, fb).to_bits(),
                "max_abs_sum({fa:?}, {fb:?})"
            );
        }
        assert!(same(s::lanes(s::ramp()), p::ramp()));
        assert!(same(s::lanes(s::zero()), p::zero()));
    }

    #[test]
    fn sse_memory_operations_equal_the_portable_ones() {
        let mut rng = fastrand::Rng::with_seed(19);
        let floats: Vec<f32> = (0..37).map(|_| value(&mut rng)).collect();
        let bytes: Vec<u8> = (0..37).map(|_| [0, 0, 1, 255][rng.usize(0..4)]).collect();
        for i in 0..=floats.len() - 4 {
            // SAFETY: i + 4 <= len, for both slices.
            unsafe {
                let (sv, pv) = (s::load_at(&floats, i), p::load_at(&floats, i));
                assert!(same(s::lanes(sv), pv), "load_at {i}");
                let (sm, pm) = (s::nonzero_at(&bytes, i), p::nonzero_at(&bytes, i));
                assert!(same(s::lanes(sm), pm), "nonzero_at {i}");
                let (mut a, mut b) = (vec![0f32; floats.len()], vec![0f32; floats.len()]);
                s::store_at(&mut a, i, sv);
                p::store_at(&mut b, i, pv);
                assert!(
                    a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()),
                    "store_at"
                );
            }
        }
        for n in 0..=5 {
            let f = &floats[..n.min(floats.len())];
            assert!(
                same(s::lanes(s::load_padded(f)), p::load_padded(f)),
                "load_padded {n}"
            );
        }
    }

    /// The table lookup at positions in `[0, N]` (ends included) and NaN, and the grid helpers
    /// of the particle sampler on points inside, on and outside a 5 x 1 x 4 grid.
    #[test]
    fn sse_lookup_and_grid_helpers_equal_the_portable_ones() {
        let mut rng = fastrand::Rng::with_seed(23);
        let table: [[f32; 2]; 16] = std::array::from_fn(|_| [rng.f32(), rng.f32() - 0.5]);
        for _ in 0..5000 {
            let t: [f32; 4] = std::array::from_fn(|_| match rng.u32(0..10) {
                0 => f32::NAN,
                1 => 16.0,
                2 => rng.u32(0..16) as f32,
                _ => rng.f32() * 16.0,
            });
            let got = s::lanes(s::lookup(&table, s::load(&t)));
            assert!(same(got, p::lookup(&table, t)), "lookup {t:?}");
        }
        let dims = [5usize, 1, 4];
        let stride = [1, 5, 5];
        let fdims = p::new4(5.0, 1.0, 4.0, 1.0);
        let smax = p::new(4.0, 0.0, 3.0);
        let imax = p::new(3.0, 0.0, 2.0);
        for _ in 0..5000 {
            let q: [f32; 3] = std::array::from_fn(|a| match rng.u32(0..10) {
                0 => f32::NAN,
                1 => rng.u32(0..=dims[a] as u32) as f32,
                _ => rng.f32() * (dims[a] as f32 + 4.0) - 2.0,
            });
            let pt = p::new(q[0], q[1], q[2]);
            let v = s::load(&pt);
            assert_eq!(
                s::cell(v, s::load(&fdims), stride),
                p::cell(pt, fdims, stride),
                "cell {q:?}"
            );
            let (sb, st) = s::locate(v, s::load(&smax), s::load(&imax), stride);
            let (pb, pt2) = p::locate(pt, smax, imax, stride);
            assert_eq!(sb, pb, "locate {q:?}");
            assert!(same(s::lanes(st), pt2), "locate weights {q:?}");
        }
    }

    /// The particle sampler's AVX2 + FMA trilinear interpolation against the portable blends
    /// (x, then y, then z, each rounded twice): the FMA blends round once each and in another
    /// order, so they differ by a few units in the last place of the largest sample. Six blends,
    /// each off by at most one ulp of its magnitude (bounded by the largest |sample| m), and
    /// their errors carried through weights in [0, 1]: within 8 ulp of m, far below the 2^-10 of
    /// m a wrong corner or weight would show.
    #[test]
    fn avx2_trilinear_is_the_portable_trilinear_within_rounding_where_available() {
        if !crate::simd::avx2_fma() {
            eprintln!("SKIP avx2_trilinear_is_the_portable_trilinear: no AVX2 + FMA");
            return;
        }
        let mut rng = fastrand::Rng::with_seed(29);
        let (nx, ny, nz) = (4usize, 3usize, 3usize);
        let field: Vec<super::V4> = (0..nx * ny * nz)
            .map(|_| s::new4(rng.f32() * 2.0 - 1.0, rng.f32(), -rng.f32(), 0.0))
            .collect();
        let (sy, sz) = (nx, nx * ny);
        for _ in 0..5000 {
            let first =
                rng.usize(0..nx - 1) + sy * rng.usize(0..ny - 1) + sz * rng.usize(0..nz - 1);
            let t = [rng.f32(), rng.f32(), rng.f32()];
            // SAFETY: the CPU has AVX2 and FMA (checked above); `first + 1 + sy + sz` is a cell
            // (each lower index is below its axis' last).
            let got = unsafe {
                s::trilinear_x_pairs(field.as_ptr().add(first), sy, sz, s::new(t[0], t[1], t[2]))
            };
            let at = |o: usize| s::lanes(field[first + o]);
            let w = t.map(p::splat);
            let c00 = p::lerp(at(0), at(1), w[0]);
            let c10 = p::lerp(at(sy), at(sy + 1), w[0]);
            let c01 = p::lerp(at(sz), at(sz + 1), w[0]);
            let c11 = p::lerp(at(sy + sz), at(sy + sz + 1), w[0]);
            let want = p::lerp(p::lerp(c00, c10, w[1]), p::lerp(c01, c11, w[1]), w[2]);
            let got = s::lanes(got);
            for l in 0..4 {
                // The largest sample of this lane.
                let m = [0, 1, sy, sy + 1, sz, sz + 1, sy + sz, sy + sz + 1]
                    .map(|o| at(o)[l].abs())
                    .into_iter()
                    .fold(0f32, f32::max);
                assert!(
                    (got[l] - want[l]).abs() <= 8.0 * f32::EPSILON * m,
                    "lane {l} at {t:?}: {} vs {}",
                    got[l],
                    want[l]
                );
            }
        }
    }
}
