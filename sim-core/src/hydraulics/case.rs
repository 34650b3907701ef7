//! The hydraulic part of a case: events on the scenario clock and the case's own parameters.
//!
//! A scenario file (see `docs/rig-emulator.md`) may carry a `[hydraulics]` table that
//! the rig ignores and the daemon reads:
//!
//! ```toml
//! [hydraulics]
//! perforation_at_s = 100.0        # optional: the wall perforates 100 s into the scenario
//! [hydraulics.params.deficit]     # optional: this case's parameters (same keys as the daemon's
//! limit = "custom"                #   [hydraulics] config; omitted keys keep their defaults);
//! custom_limit_ml = 300.0         #   when present they replace the daemon's parameters
//! ```
//! A perforation cannot be sent over the rig's wire (a real rig has no such sensor): it is a case
//! event that the daemon applies on the scenario clock (looping with the scenario; the perforation
//! then stays until a new procedure).

use serde::Deserialize;

use super::params::{HydraulicParams, ParamsError};

/// The `[hydraulics]` table of a scenario.
#[derive(Debug, Clone, PartialEq, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CaseScript {
    /// Scenario time (s, on the looped clock) from which the cavity is perforated.
    pub perforation_at_s: Option<f64>,
    /// The case's parameters, replacing the daemon's when present.
    pub params: Option<HydraulicParams>,
}

#[derive(Deserialize)]
struct ScenarioHydraulicsOnly {
    hydraulics: Option<CaseScript>,
}

impl CaseScript {
    /// Reads the `[hydraulics]` table from a whole scenario file's text (other tables ignored);
    /// errors name the origin, line and key. No table: the empty script.
    pub fn from_scenario_toml(text: &str, origin: &str) -> Result<Self, ParamsError> {
        let file: ScenarioHydraulicsOnly =
            toml::from_str(text).map_err(|e| ParamsError::Parse {
                origin: origin.to_string(),
                message: e.to_string(),
            })?;
        let script = file.hydraulics.unwrap_or_default();
        script.validate(origin)?;
        Ok(script)
    }

    /// The script of a scenario whose `[hydraulics]` table was parsed already (the rig emulator's
    /// `Scenario::hydraulics`): no table, the empty script.
    pub fn from_scenario_table(
        table: Option<&toml::Table>,
        origin: &str,
    ) -> Result<Self, ParamsError> {
        match table {
            Some(table) => Self::from_table(table, origin),
            None => Ok(Self::default()),
        }
    }

    /// Reads an already parsed `[hydraulics]` table (errors name the key, not the line).
    pub fn from_table(table: &toml::Table, origin: &str) -> Result<Self, ParamsError> {
        let script: CaseScript =
            table
                .clone()
                .try_into()
                .map_err(|e: toml::de::Error| ParamsError::Parse {
                    origin: format!("{origin} [hydraulics]"),
                    message: e.to_string(),
                })?;
        script.validate(origin)?;
        Ok(script)
    }

    fn validate(&self, origin: &str) -> Result<(), ParamsError> {
        if let Some(t) = self.perforation_at_s {
            if !(t.is_finite() && t >= 0.0) {
                return Err(ParamsError::Invalid {
                    origin: origin.to_string(),
                    key: "hydraulics.perforation_at_s",
                    value: t.to_string(),
                    expected: "a scenario time >= 0 s",
                });
            }
        }
        if let Some(p) = &self.params {
            p.validate(&format!("{origin} [hydraulics.params]"))?;
        }
        Ok(())
    }

    /// Whether the case has perforated by scenario time `t_s` (the caller wraps looping time).
    pub fn perforated_at(&self, t_s: f64) -> bool {
        self.perforation_at_s.is_some_and(|p| t_s >= p)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_the_table_from_a_scenario_and_ignores_the_rest() {
        let text = r#"
name = "x"
[[keyframe]]
t_s = 0.0
[hydraulics]
perforation_at_s = 12.5
[hydraulics.params.deficit]
limit = "custom"
custom_limit_ml = 300.0
"#;
        let s = CaseScript::from_scenario_toml(text, "case.toml").unwrap();
        assert_eq!(s.perforation_at_s, Some(12.5));
        assert_eq!(s.params.as_ref().unwrap().deficit.limit_ml(), 300.0);
        assert_eq!(s.params.as_ref().unwrap().pump.max_flow_ml_per_min, 500.0);
        assert!(!s.perforated_at(12.4) && s.perforated_at(12.5));
        let table: toml::Table = toml::from_str(text).unwrap();
        let from_table =
            CaseScript::from_table(table["hydraulics"].as_table().unwrap(), "case.toml").unwrap();
        assert_eq!(from_table, s);
        assert_eq!(
            CaseScript::from_scenario_toml("name = \"y\"", "c").unwrap(),
            CaseScript::default()
        );
    }

    #[test]
    fn errors_name_the_line_and_key() {
        let e = CaseScript::from_scenario_toml("[hydraulics]\nperforation_s = 3\n", "case.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("case.toml") && e.contains("perforation_s") && e.contains("line 2"),
            "{e}"
        );
        let e = CaseScript::from_scenario_toml("[hydraulics]\nperforation_at_s = -3\n", "c")
            .unwrap_err()
            .to_string();
        assert!(e.contains("hydraulics.perforation_at_s"), "{e}");
        let e = CaseScript::from_scenario_toml(
            "[hydraulics.params.pump]\nmax_flow_ml_per_min = 0\n",
            "c",
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("pump.max_flow_ml_per_min"), "{e}");
    }
}
