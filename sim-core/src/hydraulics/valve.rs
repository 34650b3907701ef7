//! Valve characteristic: relative conductance against the calibrated opening.
//!
//! A valve's hydraulic conductance is `G(theta) = G_open * f(theta)` for an opening `theta` in [0, 1]
//! (0 shut, 1 fully open). `f` is monotone with `f(0) = 0` and `f(1) = 1`, so a shut valve passes
//! nothing and a fully open one passes its rated conductance.

use serde::{Deserialize, Serialize};

/// The documented curve `f(theta)` of relative conductance against opening.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ValveCurve {
    /// `f = theta`.
    Linear,
    /// `f = theta^2`: a plug valve whose open area grows with rotation; fine control near shut.
    Quadratic,
    /// Modified equal percentage: `f = (R^theta - 1) / (R - 1)` with rangeability `R > 1`
    /// (`valve_rangeability` in the parameters); equal steps of opening give equal relative changes of
    /// flow over most of the range, and `f(0) = 0` exactly.
    EqualPercentage,
}

impl ValveCurve {
    /// Relative conductance `f(theta)` in [0, 1]. The opening is clamped to [0, 1]; NaN counts as shut.
    pub fn relative_conductance(self, opening: f64, rangeability: f64) -> f64 {
        let theta = sanitize_opening(opening);
        let f = match self {
            ValveCurve::Linear => theta,
            ValveCurve::Quadratic => theta * theta,
            ValveCurve::EqualPercentage => {
                // exp_m1 keeps precision near theta = 0; rangeability > 1 is validated.
                let ln_r = rangeability.ln();
                (theta * ln_r).exp_m1() / ln_r.exp_m1()
            }
        };
        f.clamp(0.0, 1.0)
    }
}

/// Clamps an opening to [0, 1]; NaN (a failed sensor) is treated as shut, the safe state.
pub fn sanitize_opening(opening: f64) -> f64 {
    if opening.is_nan() {
        0.0
    } else {
        opening.clamp(0.0, 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn curves_pass_through_shut_and_open_and_are_monotone() {
        for curve in [
            ValveCurve::Linear,
            ValveCurve::Quadratic,
            ValveCurve::EqualPercentage,
        ] {
            assert_eq!(curve.relative_conductance(0.0, 20.0), 0.0);
            assert!((curve.relative_conductance(1.0, 20.0) - 1.0).abs() < 1e-15);
            let mut last = 0.0;
            for i in 1..=1000 {
                let f = curve.relative_conductance(i as f64 / 1000.0, 20.0);
                assert!(f > last, "{curve:?} not increasing at {i}");
                last = f;
            }
        }
    }

    #[test]
    fn curves_match_their_formulas() {
        assert!((ValveCurve::Quadratic.relative_conductance(0.3, 0.0) - 0.09).abs() < 1e-15);
        let r: f64 = 20.0;
        let expected = (r.powf(0.5) - 1.0) / (r - 1.0);
        assert!(
            (ValveCurve::EqualPercentage.relative_conductance(0.5, r) - expected).abs() < 1e-14
        );
    }

    #[test]
    fn out_of_range_and_nan_openings_are_clamped() {
        let c = ValveCurve::Linear;
        assert_eq!(c.relative_conductance(f64::NAN, 20.0), 0.0);
        assert_eq!(c.relative_conductance(-3.0, 20.0), 0.0);
        assert_eq!(c.relative_conductance(7.0, 20.0), 1.0);
        assert_eq!(c.relative_conductance(f64::INFINITY, 20.0), 1.0);
        assert_eq!(c.relative_conductance(f64::NEG_INFINITY, 20.0), 0.0);
    }
}
