//! Parameters of the hydraulic circuit and the deficit monitor: TOML with documented defaults.
//!
//! Clinical units at this edge (mmHg, ml, ml/min, mm^2), converted to SI by the accessors.
//! Conductances are given in ml/min per mmHg of pressure drop. Every default is explained in
//! `docs/hydraulics.md`.

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::compliance::AnalyticCompliance;
use super::valve::ValveCurve;
use crate::units::{ml_per_min_to_m3_per_s, ml_to_m3, mmhg_to_pa, PA_PER_MMHG};

/// The most warning stages `deficit.warning_fractions` may configure: the status publishes one
/// alarm bit per stage (docs/ipc.md, "Alarm bits"), and a stage without a bit would be an alarm no
/// renderer sees.
pub const MAX_WARNING_STAGES: usize = 3;

/// Errors loading or validating [`HydraulicParams`].
#[derive(Debug, thiserror::Error)]
pub enum ParamsError {
    /// The file could not be read.
    #[error("cannot read hydraulic parameters {path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// TOML syntax error, unknown key or wrong type (the message names line, column and key).
    #[error("{origin}: {message}")]
    Parse {
        /// File name or other origin of the text.
        origin: String,
        /// The parser's message.
        message: String,
    },
    /// A value is out of its allowed range.
    #[error("{origin}: `{key}` = {value} is invalid: expected {expected}")]
    Invalid {
        /// File name or other origin.
        origin: String,
        /// Dotted key, e.g. `pump.max_flow_ml_per_min`.
        key: &'static str,
        /// The offending value as written.
        value: String,
        /// What was expected.
        expected: &'static str,
    },
}

/// The pressure-controlled distension pump.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PumpParams {
    /// Highest set pressure accepted from the rig; higher settings are clamped. Default 150 mmHg.
    pub max_pressure_mmhg: f64,
    /// Flow limit of the pump. Default 500 ml/min (pumps: 50-800 ml/min).
    pub max_flow_ml_per_min: f64,
}

impl Default for PumpParams {
    fn default() -> Self {
        Self {
            max_pressure_mmhg: 150.0,
            max_flow_ml_per_min: 500.0,
        }
    }
}

/// One line of the circuit (clinical units): tubing in series with a valve, ending in a port.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineParams {
    /// Conductance of the tubing and scope channel, ml/min per mmHg.
    pub tubing_conductance_ml_per_min_per_mmhg: f64,
    /// Conductance of the fully open valve, ml/min per mmHg.
    pub valve_conductance_ml_per_min_per_mmhg: f64,
    /// Relative conductance against opening.
    pub valve_curve: ValveCurve,
    /// Rangeability of the `equal_percentage` curve.
    pub valve_rangeability: f64,
    /// Port cross-section at the scope tip, mm^2.
    pub port_area_mm2: f64,
}

impl LineParams {
    /// Series conductance of tubing and valve at an opening, m^3/(s Pa); 0 when the valve is shut.
    pub fn conductance_m3_per_s_pa(&self, opening: f64) -> f64 {
        let g_tube = conductance_si(self.tubing_conductance_ml_per_min_per_mmhg);
        let g_valve = conductance_si(self.valve_conductance_ml_per_min_per_mmhg)
            * self
                .valve_curve
                .relative_conductance(opening, self.valve_rangeability);
        if g_valve <= 0.0 {
            0.0
        } else {
            g_tube * g_valve / (g_tube + g_valve)
        }
    }

    /// Port area, m^2.
    pub fn port_area_m2(&self) -> f64 {
        self.port_area_mm2 * 1e-6
    }
}

/// Inflow line: pump -> tubing -> inflow valve -> scope inflow port.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct InflowParams {
    /// Conductance of the tubing and the scope's inflow channel, ml/min per mmHg. Default 20.
    pub tubing_conductance_ml_per_min_per_mmhg: f64,
    /// Conductance of the fully open inflow valve, ml/min per mmHg. Default 10.
    pub valve_conductance_ml_per_min_per_mmhg: f64,
    /// Valve curve. Default `quadratic`.
    pub valve_curve: ValveCurve,
    /// Rangeability `R` of the `equal_percentage` curve (> 1). Default 20.
    pub valve_rangeability: f64,
    /// Inflow port cross-section at the scope tip, mm^2. Default 2.8 (2 m/s at ~340 ml/min).
    pub port_area_mm2: f64,
}

impl Default for InflowParams {
    fn default() -> Self {
        Self {
            tubing_conductance_ml_per_min_per_mmhg: 20.0,
            valve_conductance_ml_per_min_per_mmhg: 10.0,
            valve_curve: ValveCurve::Quadratic,
            valve_rangeability: 20.0,
            port_area_mm2: 2.8,
        }
    }
}

impl InflowParams {
    /// The line's parameters.
    pub fn line(&self) -> LineParams {
        LineParams {
            tubing_conductance_ml_per_min_per_mmhg: self.tubing_conductance_ml_per_min_per_mmhg,
            valve_conductance_ml_per_min_per_mmhg: self.valve_conductance_ml_per_min_per_mmhg,
            valve_curve: self.valve_curve,
            valve_rangeability: self.valve_rangeability,
            port_area_mm2: self.port_area_mm2,
        }
    }
}

/// Outflow line: scope outflow port -> outflow valve -> tubing -> suction canister.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OutflowParams {
    /// Gauge pressure of the suction at the canister, mmHg (<= 0). Default -30 mmHg.
    pub suction_pressure_mmhg: f64,
    /// Conductance of the tubing and the scope's outflow channel, ml/min per mmHg. Default 20.
    pub tubing_conductance_ml_per_min_per_mmhg: f64,
    /// Conductance of the fully open outflow valve, ml/min per mmHg. Default 5.
    pub valve_conductance_ml_per_min_per_mmhg: f64,
    /// Valve curve. Default `quadratic`.
    pub valve_curve: ValveCurve,
    /// Rangeability `R` of the `equal_percentage` curve (> 1). Default 20.
    pub valve_rangeability: f64,
    /// Outflow port cross-section at the scope tip, mm^2. Default 2.8.
    pub port_area_mm2: f64,
}

impl Default for OutflowParams {
    fn default() -> Self {
        Self {
            suction_pressure_mmhg: -30.0,
            tubing_conductance_ml_per_min_per_mmhg: 20.0,
            valve_conductance_ml_per_min_per_mmhg: 5.0,
            valve_curve: ValveCurve::Quadratic,
            valve_rangeability: 20.0,
            port_area_mm2: 2.8,
        }
    }
}

impl OutflowParams {
    /// The line's parameters.
    pub fn line(&self) -> LineParams {
        LineParams {
            tubing_conductance_ml_per_min_per_mmhg: self.tubing_conductance_ml_per_min_per_mmhg,
            valve_conductance_ml_per_min_per_mmhg: self.valve_conductance_ml_per_min_per_mmhg,
            valve_curve: self.valve_curve,
            valve_rangeability: self.valve_rangeability,
            port_area_mm2: self.port_area_mm2,
        }
    }
}

/// The analytic cavity pressure-volume curve (see [`AnalyticCompliance`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CavityParams {
    /// Volume of the collapsed cavity, ml. Default 0.3 ml.
    pub residual_volume_ml: f64,
    /// Pressure at which the walls separate, mmHg. Default 40 mmHg (references: 25-50).
    pub separation_pressure_mmhg: f64,
    /// Width of the separation step, mmHg. Default 8 mmHg.
    pub separation_width_mmhg: f64,
    /// Volume gained when the walls separate, ml. Default 3 ml.
    pub separation_volume_ml: f64,
    /// Compliance of the stretched wall, ml per mmHg. Default 0.01 ml/mmHg.
    pub tail_compliance_ml_per_mmhg: f64,
    /// Cavity pressure when the model starts, mmHg. Default 0 (collapsed).
    pub initial_pressure_mmhg: f64,
}

impl Default for CavityParams {
    fn default() -> Self {
        Self {
            residual_volume_ml: 0.3,
            separation_pressure_mmhg: 40.0,
            separation_width_mmhg: 8.0,
            separation_volume_ml: 3.0,
            tail_compliance_ml_per_mmhg: 0.01,
            initial_pressure_mmhg: 0.0,
        }
    }
}

impl CavityParams {
    /// The analytic curve in SI units.
    pub fn compliance(&self) -> AnalyticCompliance {
        AnalyticCompliance {
            residual_volume_m3: ml_to_m3(self.residual_volume_ml),
            separation_pressure_pa: mmhg_to_pa(self.separation_pressure_mmhg),
            separation_width_pa: mmhg_to_pa(self.separation_width_mmhg),
            separation_volume_m3: ml_to_m3(self.separation_volume_ml),
            tail_compliance_m3_per_pa: ml_to_m3(self.tail_compliance_ml_per_mmhg) / PA_PER_MMHG,
        }
    }
}

/// Leakage through the cervix around the scope.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CervixParams {
    /// Leak conductance, ml/min per mmHg of cavity pressure. Default 0.2.
    pub leak_conductance_ml_per_min_per_mmhg: f64,
    /// Fraction of the leak caught by the under-buttock drape and measured as collected, [0, 1].
    /// Default 0: the leak counts fully towards the deficit (the conservative choice).
    pub leak_collected_fraction: f64,
}

impl Default for CervixParams {
    fn default() -> Self {
        Self {
            leak_conductance_ml_per_min_per_mmhg: 0.2,
            leak_collected_fraction: 0.0,
        }
    }
}

/// Absorption (intravasation) into the circulation above a threshold pressure.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AbsorptionParams {
    /// Pressure above which fluid enters the circulation: the mean arterial pressure. Default 80 mmHg.
    pub threshold_pressure_mmhg: f64,
    /// Absorption per mmHg above the threshold, ml/min per mmHg. Default 2.
    pub conductance_ml_per_min_per_mmhg: f64,
}

impl Default for AbsorptionParams {
    fn default() -> Self {
        Self {
            threshold_pressure_mmhg: 80.0,
            conductance_ml_per_min_per_mmhg: 2.0,
        }
    }
}

/// The perforation: a sudden large leak into the peritoneal cavity.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PerforationParams {
    /// Leak conductance once perforated, ml/min per mmHg. Default 30.
    pub conductance_ml_per_min_per_mmhg: f64,
}

impl Default for PerforationParams {
    fn default() -> Self {
        Self {
            conductance_ml_per_min_per_mmhg: 30.0,
        }
    }
}

/// Deficit limit by distension medium and patient (references.md 3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DeficitLimit {
    /// Hypotonic media (glycine, sorbitol), healthy patient: 1000 ml.
    Hypotonic,
    /// Isotonic media (saline), healthy patient: 2500 ml.
    Isotonic,
    /// Hypotonic media, elderly or comorbid patient: 750 ml.
    HypotonicAtRisk,
    /// Isotonic media, elderly or comorbid patient: 1500 ml.
    IsotonicAtRisk,
    /// The paper's simulator: 1500 ml.
    Paper,
    /// `deficit.custom_limit_ml`.
    Custom,
}

impl DeficitLimit {
    /// The limit in ml (`custom_ml` for [`DeficitLimit::Custom`]).
    pub fn limit_ml(self, custom_ml: f64) -> f64 {
        match self {
            DeficitLimit::Hypotonic => 1000.0,
            DeficitLimit::Isotonic => 2500.0,
            DeficitLimit::HypotonicAtRisk => 750.0,
            DeficitLimit::IsotonicAtRisk => 1500.0,
            DeficitLimit::Paper => 1500.0,
            DeficitLimit::Custom => custom_ml,
        }
    }
}

/// Limits, warnings and alarms on the fluid deficit.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DeficitParams {
    /// Which limit applies. Default `isotonic` (saline, 2500 ml).
    pub limit: DeficitLimit,
    /// The limit when `limit = "custom"`, ml.
    pub custom_limit_ml: f64,
    /// Warning stages as fractions of the limit, strictly increasing in (0, 1), at most
    /// [`MAX_WARNING_STAGES`]. Default [0.5, 0.75, 0.9]; reaching 1.0 terminates the procedure.
    pub warning_fractions: Vec<f64>,
    /// Deficit rate that raises the rate alarm (suspected perforation), ml/min. Default 150.
    pub rate_alarm_ml_per_min: f64,
    /// Time constant of the exponential average of the deficit rate, s. Default 5 s.
    pub rate_time_constant_s: f64,
    /// The rate alarm clears when the averaged rate falls below this fraction of the alarm rate.
    /// Default 0.8 (hysteresis against chatter).
    pub rate_alarm_clear_fraction: f64,
    /// Cavity pressure above which the overpressure flag is set, mmHg. Default 120.
    pub overpressure_mmhg: f64,
    /// Stop the pump while the procedure is terminated (as real fluid management systems do).
    /// Default true.
    pub stop_pump_when_terminated: bool,
}

impl Default for DeficitParams {
    fn default() -> Self {
        Self {
            limit: DeficitLimit::Isotonic,
            custom_limit_ml: 1500.0,
            warning_fractions: vec![0.5, 0.75, 0.9],
            rate_alarm_ml_per_min: 150.0,
            rate_time_constant_s: 5.0,
            rate_alarm_clear_fraction: 0.8,
            overpressure_mmhg: 120.0,
            stop_pump_when_terminated: true,
        }
    }
}

impl DeficitParams {
    /// The active limit, ml.
    pub fn limit_ml(&self) -> f64 {
        self.limit.limit_ml(self.custom_limit_ml)
    }
}

/// All parameters of the hydraulic model; `Default` gives the documented defaults.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(default, deny_unknown_fields)]
pub struct HydraulicParams {
    /// The pump.
    pub pump: PumpParams,
    /// The inflow line.
    pub inflow: InflowParams,
    /// The outflow line.
    pub outflow: OutflowParams,
    /// The analytic cavity curve (used unless an atlas curve is supplied).
    pub cavity: CavityParams,
    /// Cervical leak.
    pub cervix: CervixParams,
    /// Absorption.
    pub absorption: AbsorptionParams,
    /// Perforation.
    pub perforation: PerforationParams,
    /// Deficit limits and alarms.
    pub deficit: DeficitParams,
}

/// ml/min per mmHg -> m^3/(s Pa).
pub fn conductance_si(ml_per_min_per_mmhg: f64) -> f64 {
    ml_per_min_to_m3_per_s(ml_per_min_per_mmhg) / PA_PER_MMHG
}

impl HydraulicParams {
    /// Parses and validates TOML text; `origin` names the text in errors (e.g. the file path).
    pub fn from_toml_str(text: &str, origin: &str) -> Result<Self, ParamsError> {
        let params: HydraulicParams = toml::from_str(text).map_err(|e| ParamsError::Parse {
            origin: origin.to_string(),
            message: e.to_string(),
        })?;
        params.validate(origin)?;
        Ok(params)
    }

    /// Reads, parses and validates a TOML file.
    pub fn load(path: &Path) -> Result<Self, ParamsError> {
        let text = std::fs::read_to_string(path).map_err(|source| ParamsError::Io {
            path: path.display().to_string(),
            source,
        })?;
        Self::from_toml_str(&text, &path.display().to_string())
    }

    /// The defaults as commented-free TOML (for `--print-default-config`-style output).
    pub fn default_toml() -> String {
        // ok: serialising plain numbers, bools and enums cannot fail.
        toml::to_string_pretty(&Self::default()).unwrap_or_default()
    }

    /// Checks every value's range; the error names the key.
    pub fn validate(&self, origin: &str) -> Result<(), ParamsError> {
        let err = |key: &'static str, value: f64, expected: &'static str| ParamsError::Invalid {
            origin: origin.to_string(),
            key,
            value: value.to_string(),
            expected,
        };
        let positive = |key: &'static str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(err(key, v, "a finite number > 0"))
            }
        };
        let non_negative = |key: &'static str, v: f64| {
            if v.is_finite() && v >= 0.0 {
                Ok(())
            } else {
                Err(err(key, v, "a finite number >= 0"))
            }
        };
        let fraction = |key: &'static str, v: f64| {
            if (0.0..=1.0).contains(&v) {
                Ok(())
            } else {
                Err(err(key, v, "a fraction in [0, 1]"))
            }
        };
        let finite = |key: &'static str, v: f64| {
            if v.is_finite() {
                Ok(())
            } else {
                Err(err(key, v, "a finite number"))
            }
        };

        positive("pump.max_pressure_mmhg", self.pump.max_pressure_mmhg)?;
        positive("pump.max_flow_ml_per_min", self.pump.max_flow_ml_per_min)?;

        let lines: [(LineParams, [&'static str; 4]); 2] = [
            (
                self.inflow.line(),
                [
                    "inflow.tubing_conductance_ml_per_min_per_mmhg",
                    "inflow.valve_conductance_ml_per_min_per_mmhg",
                    "inflow.valve_rangeability",
                    "inflow.port_area_mm2",
                ],
            ),
            (
                self.outflow.line(),
                [
                    "outflow.tubing_conductance_ml_per_min_per_mmhg",
                    "outflow.valve_conductance_ml_per_min_per_mmhg",
                    "outflow.valve_rangeability",
                    "outflow.port_area_mm2",
                ],
            ),
        ];
        for (line, keys) in lines {
            positive(keys[0], line.tubing_conductance_ml_per_min_per_mmhg)?;
            positive(keys[1], line.valve_conductance_ml_per_min_per_mmhg)?;
            if !(line.valve_rangeability.is_finite() && line.valve_rangeability > 1.0) {
                return Err(err(keys[2], line.valve_rangeability, "a finite number > 1"));
            }
            positive(keys[3], line.port_area_mm2)?;
        }
        let suction = self.outflow.suction_pressure_mmhg;
        if !(-760.0..=0.0).contains(&suction) {
            return Err(err(
                "outflow.suction_pressure_mmhg",
                suction,
                "a gauge pressure in [-760, 0] mmHg",
            ));
        }

        positive("cavity.residual_volume_ml", self.cavity.residual_volume_ml)?;
        finite(
            "cavity.separation_pressure_mmhg",
            self.cavity.separation_pressure_mmhg,
        )?;
        positive(
            "cavity.separation_width_mmhg",
            self.cavity.separation_width_mmhg,
        )?;
        non_negative(
            "cavity.separation_volume_ml",
            self.cavity.separation_volume_ml,
        )?;
        positive(
            "cavity.tail_compliance_ml_per_mmhg",
            self.cavity.tail_compliance_ml_per_mmhg,
        )?;
        finite(
            "cavity.initial_pressure_mmhg",
            self.cavity.initial_pressure_mmhg,
        )?;

        non_negative(
            "cervix.leak_conductance_ml_per_min_per_mmhg",
            self.cervix.leak_conductance_ml_per_min_per_mmhg,
        )?;
        fraction(
            "cervix.leak_collected_fraction",
            self.cervix.leak_collected_fraction,
        )?;
        finite(
            "absorption.threshold_pressure_mmhg",
            self.absorption.threshold_pressure_mmhg,
        )?;
        non_negative(
            "absorption.conductance_ml_per_min_per_mmhg",
            self.absorption.conductance_ml_per_min_per_mmhg,
        )?;
        non_negative(
            "perforation.conductance_ml_per_min_per_mmhg",
            self.perforation.conductance_ml_per_min_per_mmhg,
        )?;

        let d = &self.deficit;
        if d.limit == DeficitLimit::Custom {
            positive("deficit.custom_limit_ml", d.custom_limit_ml)?;
        }
        let mut last = 0.0;
        for &w in &d.warning_fractions {
            if !(w > last && w < 1.0) {
                return Err(err(
                    "deficit.warning_fractions",
                    w,
                    "fractions strictly increasing in (0, 1)",
                ));
            }
            last = w;
        }
        // The message below spells the number out.
        const _: () = assert!(MAX_WARNING_STAGES == 3);
        if d.warning_fractions.len() > MAX_WARNING_STAGES {
            return Err(err(
                "deficit.warning_fractions",
                d.warning_fractions.len() as f64,
                "at most 3 warning stages (one status alarm bit each)",
            ));
        }
        positive("deficit.rate_alarm_ml_per_min", d.rate_alarm_ml_per_min)?;
        positive("deficit.rate_time_constant_s", d.rate_time_constant_s)?;
        fraction(
            "deficit.rate_alarm_clear_fraction",
            d.rate_alarm_clear_fraction,
        )?;
        finite("deficit.overpressure_mmhg", d.overpressure_mmhg)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_validate_and_round_trip_through_toml() {
        let p = HydraulicParams::default();
        p.validate("defaults").unwrap();
        let text = HydraulicParams::default_toml();
        let back = HydraulicParams::from_toml_str(&text, "round trip").unwrap();
        assert_eq!(back, p);
        // An empty file is all defaults.
        assert_eq!(HydraulicParams::from_toml_str("", "empty").unwrap(), p);
    }

    #[test]
    fn defaults_are_inside_the_clinical_ranges() {
        let p = HydraulicParams::default();
        assert!((50.0..=800.0).contains(&p.pump.max_flow_ml_per_min));
        assert!((15.0..=150.0).contains(&p.pump.max_pressure_mmhg));
        assert!((70.0..=100.0).contains(&p.absorption.threshold_pressure_mmhg));
        assert!((25.0..=50.0).contains(&p.cavity.separation_pressure_mmhg));
        assert_eq!(p.deficit.limit_ml(), 2500.0);
    }

    #[test]
    fn limits_by_media_type() {
        let text = "[deficit]\nlimit = \"hypotonic_at_risk\"\n";
        let p = HydraulicParams::from_toml_str(text, "t").unwrap();
        assert_eq!(p.deficit.limit_ml(), 750.0);
        for (name, ml) in [
            ("hypotonic", 1000.0),
            ("isotonic", 2500.0),
            ("isotonic_at_risk", 1500.0),
            ("paper", 1500.0),
        ] {
            let p = HydraulicParams::from_toml_str(&format!("deficit.limit = \"{name}\""), "t")
                .unwrap();
            assert_eq!(p.deficit.limit_ml(), ml, "{name}");
        }
        let p = HydraulicParams::from_toml_str(
            "[deficit]\nlimit = \"custom\"\ncustom_limit_ml = 1200\n",
            "t",
        )
        .unwrap();
        assert_eq!(p.deficit.limit_ml(), 1200.0);
    }

    #[test]
    fn errors_name_the_key_and_value() {
        let e = HydraulicParams::from_toml_str("[pump]\nmax_flow_ml_per_min = -5\n", "cfg.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("cfg.toml") && e.contains("pump.max_flow_ml_per_min") && e.contains("-5"),
            "{e}"
        );
        let e = HydraulicParams::from_toml_str("[deficit]\nwarning_fractions = [0.5, 0.4]\n", "c")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("deficit.warning_fractions") && e.contains("0.4"),
            "{e}"
        );
        let e = HydraulicParams::from_toml_str(
            "[deficit]\nwarning_fractions = [0.2, 0.4, 0.6, 0.8]\n",
            "c",
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("deficit.warning_fractions") && e.contains("at most 3"),
            "{e}"
        );
        assert!(
            HydraulicParams::from_toml_str("[deficit]\nwarning_fractions = [0.3, 0.9]\n", "c")
                .is_ok()
        );
        let e = HydraulicParams::from_toml_str("[outflow]\nsuction_pressure_mmhg = 20\n", "c")
            .unwrap_err()
            .to_string();
        assert!(e.contains("outflow.suction_pressure_mmhg"), "{e}");
        let e = HydraulicParams::from_toml_str("[inflow]\nport_area_mm2 = 0\n", "c")
            .unwrap_err()
            .to_string();
        assert!(e.contains("inflow.port_area_mm2"), "{e}");
        // Unknown keys and wrong types are parse errors naming the key and the line.
        let e = HydraulicParams::from_toml_str("[pump]\nmax_flow = 5\n", "c")
            .unwrap_err()
            .to_string();
        assert!(e.contains("max_flow") && e.contains("line 2"), "{e}");
        let e = HydraulicParams::from_toml_str("[deficit]\nlimit = \"saline\"\n", "c")
            .unwrap_err()
            .to_string();
        assert!(e.contains("saline") && e.contains("line 2"), "{e}");
    }
}
