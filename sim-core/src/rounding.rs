//! `floor` and `ceil` without a call: on the default x86-64 target (no SSE4.1) `f64::floor` and
//! `f64::ceil` are calls into the soft-float `libm`, a few dozen instructions each, and the cut
//! cells and the voxelizer round every clipped piece's coordinates to cells each frame.
//!
//! The value is the same as the standard library's for every input, except that a result of
//! zero is `+0.0` where `floor`/`ceil` may give `-0.0` (`ceil(-0.5)`); both compare, clamp and
//! convert to integers alike, which is all the callers do with them.

/// From this magnitude on every `f64` is an integer (2^52).
const INTEGRAL: f64 = 4_503_599_627_370_496.0;

/// `x.floor()` (up to the sign of a zero result).
#[inline]
pub(crate) fn floor(x: f64) -> f64 {
    if x.abs() < INTEGRAL {
        // Truncation towards zero, exact below 2^52.
        let t = x as i64 as f64;
        if t > x {
            t - 1.0
        } else {
            t
        }
    } else {
        // Integral already, infinite or NaN.
        x.floor()
    }
}

/// `x.ceil()` (up to the sign of a zero result).
#[inline]
pub(crate) fn ceil(x: f64) -> f64 {
    if x.abs() < INTEGRAL {
        let t = x as i64 as f64;
        if t < x {
            t + 1.0
        } else {
            t
        }
    } else {
        x.ceil()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn floor_and_ceil_equal_the_standard_ones() {
        let mut xs = vec![
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.0,
            -1.0,
            1.0 - f64::EPSILON,
            -1.0 + f64::EPSILON,
            2.5,
            -2.5,
            1e-300,
            -1e-300,
            INTEGRAL - 0.5,
            -(INTEGRAL - 0.5),
            INTEGRAL,
            -INTEGRAL,
            1e300,
            -1e300,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::MAX,
            f64::MIN,
        ];
        // A spread of magnitudes and fractions, and the neighbours of integers.
        let mut s = 0x9e37_79b9_7f4a_7c15u64;
        for _ in 0..10_000 {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            let x = f64::from_bits(s);
            if x.is_finite() {
                xs.push(x);
            }
            let y = (s % 2_000_001) as f64 / 1000.0 - 1000.0;
            xs.extend([y, y + 1e-9, y - 1e-9, y.round()]);
        }
        for x in xs {
            let (f, c) = (floor(x), ceil(x));
            assert!(f == x.floor(), "floor({x:e}) = {f:e}");
            assert!(c == x.ceil(), "ceil({x:e}) = {c:e}");
        }
        assert!(floor(f64::NAN).is_nan() && ceil(f64::NAN).is_nan());
    }
}
