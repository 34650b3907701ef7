//! Cavity compliance: the pressure-volume curve of the distended uterine cavity.
//!
//! The hydraulic model needs only the cavity volume as a function of the cavity pressure and its
//! derivative (the compliance). The FEM atlas supplies its own curve through [`CavityCompliance`];
//! until then [`AnalyticCompliance`] is the default.

use serde::{Deserialize, Serialize};

use super::solve::{expand_bracket, solve_bracketed};

/// A cavity pressure-volume curve.
///
/// Contract (the hydraulic solver relies on it): for every finite pressure the volume is finite and
/// positive, non-decreasing in pressure, and `compliance_m3_per_pa` is its derivative (finite,
/// `>= 0`). The curve must be defined for all pressures, also outside the range it was measured or
/// computed on (extend it, e.g. with the end slopes), because suction can pull the cavity below
/// atmospheric pressure and a transient can overshoot. The volume should grow without bound or at
/// least beyond any volume the circuit can reach, so every volume has a pressure.
pub trait CavityCompliance: Send + Sync + std::fmt::Debug {
    /// Cavity volume (m^3) at a gauge pressure (Pa).
    fn volume_m3(&self, pressure_pa: f64) -> f64;

    /// `dV/dp` (m^3/Pa) at a gauge pressure (Pa).
    fn compliance_m3_per_pa(&self, pressure_pa: f64) -> f64;

    /// The pressure at which the cavity holds `volume_m3`, or `None` if no finite pressure does
    /// (volume below the collapsed limit or above the curve's supremum). The default inverts
    /// [`volume_m3`](Self::volume_m3) numerically.
    fn pressure_pa(&self, volume_m3: f64) -> Option<f64> {
        if !volume_m3.is_finite() {
            return None;
        }
        let f = |p: f64| self.volume_m3(p) - volume_m3;
        let (lo, hi) = expand_bracket(f, -1000.0, 1000.0)?;
        let root = solve_bracketed(
            |p| (self.volume_m3(p) - volume_m3, self.compliance_m3_per_pa(p)),
            f64::NAN,
            lo,
            hi,
            1e-15 * volume_m3.abs(),
            1e-9,
            1e-14,
        );
        Some(root.x)
    }
}

/// The analytic default: a smooth curve with a wall-separation step and a stiffer tail.
///
/// ```text
/// V(p) = V_res + dV_sep * S((p - p_sep) / w_sep) + C_tail * w_tail * softplus(p / w_tail)
/// S(x) = 1 / (1 + e^-x),   softplus(x) = ln(1 + e^x),   w_tail = 10 mmHg
/// ```
/// Below `p_sep` the walls touch and the cavity holds only `V_res`; around `p_sep` (~40 mmHg) the
/// walls separate and the volume rises by `dV_sep` over a few `w_sep`; above, the wall is stretched
/// and the compliance tends to `C_tail`. For `p -> -inf` the volume tends to `V_res` (collapsed),
/// for `p -> +inf` it grows linearly. With the defaults the cavity holds 0.39 ml at 0 mmHg, 2.2 ml at
/// 40 mmHg and 4.8 ml at 150 mmHg, inside the CT range of 0.6-11.4 ml at 150 mmHg (references.md 3).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AnalyticCompliance {
    /// Residual volume of the collapsed cavity, m^3.
    pub residual_volume_m3: f64,
    /// Wall-separation pressure, Pa.
    pub separation_pressure_pa: f64,
    /// Width of the separation step, Pa.
    pub separation_width_pa: f64,
    /// Volume gained by the separation step, m^3.
    pub separation_volume_m3: f64,
    /// Compliance of the stretched wall at high pressure, m^3/Pa.
    pub tail_compliance_m3_per_pa: f64,
}

/// Width of the softplus that switches the tail compliance on around 0 Pa (10 mmHg).
const TAIL_WIDTH_PA: f64 = 1333.22;

/// Numerically stable logistic function.
fn logistic(x: f64) -> f64 {
    if x >= 0.0 {
        1.0 / (1.0 + (-x).exp())
    } else {
        let e = x.exp();
        e / (1.0 + e)
    }
}

/// Numerically stable `ln(1 + e^x)`.
fn softplus(x: f64) -> f64 {
    if x > 0.0 {
        x + (-x).exp().ln_1p()
    } else {
        x.exp().ln_1p()
    }
}

impl CavityCompliance for AnalyticCompliance {
    fn volume_m3(&self, pressure_pa: f64) -> f64 {
        let s = logistic((pressure_pa - self.separation_pressure_pa) / self.separation_width_pa);
        self.residual_volume_m3
            + self.separation_volume_m3 * s
            + self.tail_compliance_m3_per_pa * TAIL_WIDTH_PA * softplus(pressure_pa / TAIL_WIDTH_PA)
    }

    fn compliance_m3_per_pa(&self, pressure_pa: f64) -> f64 {
        let s = logistic((pressure_pa - self.separation_pressure_pa) / self.separation_width_pa);
        self.separation_volume_m3 * s * (1.0 - s) / self.separation_width_pa
            + self.tail_compliance_m3_per_pa * logistic(pressure_pa / TAIL_WIDTH_PA)
    }
}

/// A constant compliance `V = V_0 + C p` (for analytic tests; unbounded in both directions).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LinearCompliance {
    /// Volume at zero gauge pressure, m^3.
    pub volume_at_zero_m3: f64,
    /// Constant compliance, m^3/Pa (> 0).
    pub compliance_m3_per_pa: f64,
}

impl CavityCompliance for LinearCompliance {
    fn volume_m3(&self, pressure_pa: f64) -> f64 {
        self.volume_at_zero_m3 + self.compliance_m3_per_pa * pressure_pa
    }

    fn compliance_m3_per_pa(&self, _pressure_pa: f64) -> f64 {
        self.compliance_m3_per_pa
    }

    fn pressure_pa(&self, volume_m3: f64) -> Option<f64> {
        let p = (volume_m3 - self.volume_at_zero_m3) / self.compliance_m3_per_pa;
        p.is_finite().then_some(p)
    }
}

/// Errors building a tabulated curve.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ComplianceError {
    /// Fewer than two points.
    #[error("a tabulated P-V curve needs at least 2 points, got {0}")]
    TooFewPoints(usize),
    /// A point is not finite or the curve is not strictly increasing.
    #[error(
        "P-V point {index} (p = {pressure_pa} Pa, V = {volume_m3} m^3) must be finite and \
         strictly greater than the previous point in both pressure and volume"
    )]
    NotIncreasing {
        /// Index of the offending point.
        index: usize,
        /// Its pressure, Pa.
        pressure_pa: f64,
        /// Its volume, m^3.
        volume_m3: f64,
    },
}

/// A tabulated curve (e.g. the atlas's cavity volume per pressure level): piecewise linear between
/// the points, extended beyond them with the first and last segment slopes.
#[derive(Debug, Clone, PartialEq)]
pub struct TabulatedCompliance {
    pressures_pa: Vec<f64>,
    volumes_m3: Vec<f64>,
}

impl TabulatedCompliance {
    /// Builds the curve from points sorted by pressure, strictly increasing in pressure and volume.
    pub fn new(points: &[(f64, f64)]) -> Result<Self, ComplianceError> {
        if points.len() < 2 {
            return Err(ComplianceError::TooFewPoints(points.len()));
        }
        for (index, &(p, v)) in points.iter().enumerate() {
            let bad = !p.is_finite()
                || !v.is_finite()
                || (index > 0 && (p <= points[index - 1].0 || v <= points[index - 1].1));
            if bad {
                return Err(ComplianceError::NotIncreasing {
                    index,
                    pressure_pa: p,
                    volume_m3: v,
                });
            }
        }
        Ok(Self {
            pressures_pa: points.iter().map(|p| p.0).collect(),
            volumes_m3: points.iter().map(|p| p.1).collect(),
        })
    }

    /// Index `i` of the segment `[p_i, p_i+1]` used for a pressure (end segments extend outward).
    fn segment(&self, pressure_pa: f64) -> usize {
        let n = self.pressures_pa.len();
        let i = self.pressures_pa.partition_point(|&p| p <= pressure_pa);
        i.clamp(1, n - 1) - 1
    }

    fn slope(&self, i: usize) -> f64 {
        (self.volumes_m3[i + 1] - self.volumes_m3[i])
            / (self.pressures_pa[i + 1] - self.pressures_pa[i])
    }
}

impl CavityCompliance for TabulatedCompliance {
    fn volume_m3(&self, pressure_pa: f64) -> f64 {
        let i = self.segment(pressure_pa);
        self.volumes_m3[i] + self.slope(i) * (pressure_pa - self.pressures_pa[i])
    }

    fn compliance_m3_per_pa(&self, pressure_pa: f64) -> f64 {
        self.slope(self.segment(pressure_pa))
    }
}
