//! Safeguarded Newton iteration for a scalar non-decreasing function on a bracket.
//!
//! Newton converges quadratically where the function is smooth; wherever a Newton step would leave
//! the bracket or fails to halve it, a bisection step is taken instead, so convergence is guaranteed
//! even across the kinks of the circuit (a valve's flow clamped at zero, the pump at its flow limit,
//! absorption starting at its threshold).

/// Outcome of [`solve_bracketed`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Root {
    /// The root estimate.
    pub x: f64,
    /// Function evaluations used.
    pub iterations: u32,
    /// Steps that fell back to bisection.
    pub bisections: u32,
    /// False when the iteration limit was reached before the tolerance (the best estimate is returned).
    pub converged: bool,
}

/// Maximum iterations; bisection alone halves a 1e9 Pa bracket to 1e-9 Pa in 60 steps.
const MAX_ITERATIONS: u32 = 200;

/// Finds `x` in `[lo, hi]` with `f(x) = 0` for a non-decreasing `f` with `f(lo) <= 0 <= f(hi)`.
///
/// `x0` is the first guess (clamped into the bracket; the midpoint if NaN). `f_df` returns the
/// value and the derivative. Stops when `|f(x)| <= f_tol`, or when the bracket
/// is narrower than `x_tol_abs + x_tol_rel * |x|` (the fallback when rounding keeps `|f|` above
/// `f_tol`).
pub fn solve_bracketed(
    mut f_df: impl FnMut(f64) -> (f64, f64),
    x0: f64,
    mut lo: f64,
    mut hi: f64,
    f_tol: f64,
    x_tol_abs: f64,
    x_tol_rel: f64,
) -> Root {
    let mut x = if x0.is_nan() {
        0.5 * (lo + hi)
    } else {
        x0.clamp(lo, hi)
    };
    let mut iterations = 0;
    let mut bisections = 0;
    // Previous step length: a Newton step must at least halve it, or bisection takes over.
    let mut last_step = hi - lo;
    while iterations < MAX_ITERATIONS {
        iterations += 1;
        let (fx, dfx) = f_df(x);
        if fx.abs() <= f_tol {
            return Root {
                x,
                iterations,
                bisections,
                converged: true,
            };
        }
        if fx < 0.0 {
            lo = x;
        } else {
            hi = x;
        }
        let tol = x_tol_abs + x_tol_rel * x.abs();
        if hi - lo <= tol {
            return Root {
                x,
                iterations,
                bisections,
                converged: true,
            };
        }
        let newton = x - fx / dfx;
        let newton_ok = dfx > 0.0
            && newton.is_finite()
            && newton > lo
            && newton < hi
            && (newton - x).abs() <= 0.5 * last_step.abs();
        let next = if newton_ok {
            newton
        } else {
            bisections += 1;
            0.5 * (lo + hi)
        };
        last_step = next - x;
        x = next;
    }
    Root {
        x,
        iterations,
        bisections,
        converged: false,
    }
}

/// Expands `[lo, hi]` geometrically until `f(lo) <= 0 <= f(hi)`; `None` if that fails within
/// 1100 doublings (which means `f` never changes sign on finite numbers).
pub fn expand_bracket(
    mut f: impl FnMut(f64) -> f64,
    mut lo: f64,
    mut hi: f64,
) -> Option<(f64, f64)> {
    let mut step = (hi - lo).abs().max(1.0);
    for _ in 0..1100 {
        if f(lo) <= 0.0 {
            break;
        }
        hi = lo;
        lo -= step;
        step *= 2.0;
        if !lo.is_finite() {
            return None;
        }
    }
    let mut step = (hi - lo).abs().max(1.0);
    for _ in 0..1100 {
        if f(hi) >= 0.0 {
            return Some((lo, hi));
        }
        lo = hi;
        hi += step;
        step *= 2.0;
        if !hi.is_finite() {
            return None;
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_cube_root_quadratically() {
        let root = solve_bracketed(
            |x| (x * x * x - 2.0, 3.0 * x * x),
            f64::NAN,
            0.0,
            10.0,
            0.0,
            1e-14,
            1e-14,
        );
        assert!(root.converged);
        assert!((root.x - 2f64.cbrt()).abs() < 1e-13);
        assert!(root.iterations < 40, "{root:?}");
    }

    #[test]
    fn converges_on_a_kinked_function() {
        // Piecewise linear with a kink at 1 and a flat derivative estimate on one side.
        let f = |x: f64| {
            if x < 1.0 {
                (0.001 * (x - 1.0) - 0.5, 0.001)
            } else {
                (1000.0 * (x - 1.0) - 0.5, 1000.0)
            }
        };
        let root = solve_bracketed(f, f64::NAN, -1e6, 1e6, 0.0, 1e-12, 1e-15);
        assert!(root.converged);
        assert!((root.x - 1.0005).abs() < 1e-10, "{root:?}");
    }

    #[test]
    fn expands_a_bracket_that_misses_the_root() {
        let (lo, hi) = expand_bracket(|x| x - 1e6, -1.0, 1.0).unwrap();
        assert!(lo <= 1e6 && hi >= 1e6);
        let (lo, hi) = expand_bracket(|x| x + 1e6, -1.0, 1.0).unwrap();
        assert!(lo <= -1e6 && hi >= -1e6);
        assert!(expand_bracket(|_| 1.0, -1.0, 1.0).is_none());
    }
}
