//! Scenario files: keyframes of what the trainee does with the rig, linearly interpolated.
//!
//! Format (TOML; every unit in the key name):
//! ```toml
//! name = "example"
//! loop = true                 # optional, default false: hold the last keyframe
//! [[keyframe]]
//! t_s = 0.0                   # seconds, strictly increasing
//! valve_in = 0.0              # inflow valve opening in [0, 1]
//! valve_out = 0.0             # outflow valve opening in [0, 1]
//! pump_mmhg = 90.0            # pump set pressure in [0, 300] mmHg
//! tip_mm = [0.0, 0.0, 20.0]   # scope tip, organ frame, mm (+z towards the fundus)
//! view_dir = [0.0, 0.0, 1.0]  # viewing direction, organ frame (normalised)
//! buttons = 0                 # optional, held until the next keyframe
//! pose_valid = true           # optional, held until the next keyframe
//! ```
//! An optional `[faults]` table is a [`FaultPlan`]; an optional `[hydraulics]` table is kept
//! verbatim for other consumers of the scenario.

use std::path::Path;

use serde::Deserialize;
use toml::Spanned;

use super::faults::{FaultPlan, FaultPlanFile};
use super::scenario_error::line_of;
pub use super::scenario_error::ScenarioError;

/// One interpolated scenario state (clinical units, organ frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScenarioSample {
    /// Scenario time after looping, seconds.
    pub t_s: f64,
    /// Inflow valve opening in [0, 1].
    pub valve_in: f64,
    /// Outflow valve opening in [0, 1].
    pub valve_out: f64,
    /// Pump set pressure, mmHg.
    pub pump_mmhg: f64,
    /// Scope tip in the organ frame, mm.
    pub tip_mm: [f64; 3],
    /// Unit viewing direction in the organ frame.
    pub view_dir: [f64; 3],
    /// Buttons held at this time.
    pub buttons: u32,
    /// Whether the tracker sees the scope.
    pub pose_valid: bool,
}

/// A keyframe as validated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Keyframe {
    /// Time, s.
    pub t_s: f64,
    /// Inflow valve opening in [0, 1].
    pub valve_in: f64,
    /// Outflow valve opening in [0, 1].
    pub valve_out: f64,
    /// Pump set pressure, mmHg.
    pub pump_mmhg: f64,
    /// Tip position, organ frame, mm.
    pub tip_mm: [f64; 3],
    /// Unit view direction, organ frame.
    pub view_dir: [f64; 3],
    /// Buttons.
    pub buttons: u32,
    /// Pose validity.
    pub pose_valid: bool,
}

/// A validated scenario.
#[derive(Debug, Clone, PartialEq)]
pub struct Scenario {
    /// Name (file's `name` key, or the origin).
    pub name: String,
    /// Whether time wraps at the last keyframe.
    pub looping: bool,
    /// Keyframes, strictly increasing in time.
    pub keyframes: Vec<Keyframe>,
    /// Faults the scenario asks the emulator to inject.
    pub faults: FaultPlan,
    /// The `[hydraulics]` table, verbatim, for other consumers.
    pub hydraulics: Option<toml::Table>,
    /// Where the scenario came from (`builtin:NAME` or the file path), for error messages.
    pub origin: String,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ScenarioFile {
    name: Option<String>,
    #[serde(rename = "loop", default)]
    looping: bool,
    #[serde(default)]
    keyframe: Vec<KeyframeFile>,
    faults: Option<FaultPlanFile>,
    hydraulics: Option<toml::Table>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct KeyframeFile {
    t_s: Spanned<f64>,
    valve_in: Spanned<f64>,
    valve_out: Spanned<f64>,
    pump_mmhg: Spanned<f64>,
    tip_mm: Spanned<[f64; 3]>,
    view_dir: Spanned<[f64; 3]>,
    #[serde(default)]
    buttons: u32,
    #[serde(default = "default_true")]
    pose_valid: bool,
}

fn default_true() -> bool {
    true
}

const DEFAULT_SCENARIO: &str = include_str!("../../scenarios/default.toml");
const FLAKY_SCENARIO: &str = include_str!("../../scenarios/flaky.toml");

impl Scenario {
    /// Parses and validates a scenario; `origin` names the source in errors.
    pub fn from_toml_str(text: &str, origin: &str) -> Result<Self, ScenarioError> {
        let file: ScenarioFile = toml::from_str(text).map_err(|e| ScenarioError::Parse {
            origin: origin.to_string(),
            message: e.to_string(),
        })?;
        let err = |span: std::ops::Range<usize>, key: String, value: String, expected: &str| {
            ScenarioError::Invalid {
                origin: origin.to_string(),
                line: line_of(text, span.start),
                key,
                value,
                expected: expected.to_string(),
            }
        };
        if file.keyframe.is_empty() {
            return Err(ScenarioError::Invalid {
                origin: origin.to_string(),
                line: 1,
                key: "keyframe".into(),
                value: "none".into(),
                expected: "at least one [[keyframe]] table".into(),
            });
        }
        let mut keyframes = Vec::with_capacity(file.keyframe.len());
        let mut prev_t = f64::NEG_INFINITY;
        for (i, k) in file.keyframe.iter().enumerate() {
            let key = |name: &str| format!("keyframe[{i}].{name}");
            let t = *k.t_s.get_ref();
            if !(t.is_finite() && t >= 0.0 && t > prev_t) {
                return Err(err(
                    k.t_s.span(),
                    key("t_s"),
                    t.to_string(),
                    "a finite time >= 0 s, greater than the previous keyframe's",
                ));
            }
            prev_t = t;
            for (name, v) in [("valve_in", &k.valve_in), ("valve_out", &k.valve_out)] {
                let x = *v.get_ref();
                if !(0.0..=1.0).contains(&x) {
                    return Err(err(
                        v.span(),
                        key(name),
                        x.to_string(),
                        "an opening in [0, 1]",
                    ));
                }
            }
            let p = *k.pump_mmhg.get_ref();
            if !(0.0..=300.0).contains(&p) {
                return Err(err(
                    k.pump_mmhg.span(),
                    key("pump_mmhg"),
                    p.to_string(),
                    "a pressure in [0, 300] mmHg",
                ));
            }
            let tip = *k.tip_mm.get_ref();
            if !tip.iter().all(|c| c.is_finite() && c.abs() <= 500.0) {
                return Err(err(
                    k.tip_mm.span(),
                    key("tip_mm"),
                    format!("{tip:?}"),
                    "finite coordinates within +-500 mm",
                ));
            }
            let dir = *k.view_dir.get_ref();
            let n = dir.iter().map(|c| c * c).sum::<f64>().sqrt();
            if !(n.is_finite() && n > 1e-6) {
                return Err(err(
                    k.view_dir.span(),
                    key("view_dir"),
                    format!("{dir:?}"),
                    "a finite non-zero direction",
                ));
            }
            keyframes.push(Keyframe {
                t_s: t,
                valve_in: *k.valve_in.get_ref(),
                valve_out: *k.valve_out.get_ref(),
                pump_mmhg: p,
                tip_mm: tip,
                view_dir: dir.map(|c| c / n),
                buttons: k.buttons,
                pose_valid: k.pose_valid,
            });
        }
        let faults = match file.faults {
            Some(f) => f.validate(text, origin)?,
            None => FaultPlan::default(),
        };
        Ok(Scenario {
            name: file.name.unwrap_or_else(|| origin.to_string()),
            looping: file.looping,
            keyframes,
            faults,
            hydraulics: file.hydraulics,
            origin: origin.to_string(),
        })
    }

    /// Loads a scenario file.
    pub fn load(path: &Path) -> Result<Self, ScenarioError> {
        let text = std::fs::read_to_string(path).map_err(|source| ScenarioError::Io {
            path: path.display().to_string(),
            source,
        })?;
        Self::from_toml_str(&text, &path.display().to_string())
    }

    /// A scenario shipped with the crate: `"default"` (a looping 150 s procedure) or `"flaky"`
    /// (a slow sweep with every fault scheduled in its first 33 s).
    pub fn builtin(name: &str) -> Option<Scenario> {
        // The embedded files are checked by unit tests, so these parses cannot fail at run time.
        match name {
            "default" => Self::from_toml_str(DEFAULT_SCENARIO, "builtin:default").ok(),
            "flaky" => Self::from_toml_str(FLAKY_SCENARIO, "builtin:flaky").ok(),
            _ => None,
        }
    }

    /// Resolves a scenario argument (`hydrometra rig emulate --scenario`, `hydrometrad --emulated`,
    /// `rig.emulated.scenario`, `hydrometra hydraulics run --scenario`) with one rule: a built-in
    /// name ([`Scenario::builtin_names`]) always means the built-in scenario, whatever files exist
    /// in the working directory; anything else is the path of a scenario file. A file named like a
    /// built-in is loaded by writing it as a path, e.g. `./default`.
    pub fn resolve(spec: &str) -> Result<Scenario, ScenarioError> {
        if let Some(s) = Self::builtin(spec) {
            return Ok(s);
        }
        match std::fs::read_to_string(spec) {
            Ok(text) => Self::from_toml_str(&text, spec),
            Err(source) if source.kind() == std::io::ErrorKind::NotFound => {
                Err(ScenarioError::NotFound {
                    spec: spec.to_string(),
                    builtins: Self::builtin_names().join(", "),
                    source,
                })
            }
            Err(source) => Err(ScenarioError::Io {
                path: spec.to_string(),
                source,
            }),
        }
    }

    /// Names accepted by [`Scenario::builtin`].
    pub fn builtin_names() -> &'static [&'static str] {
        &["default", "flaky"]
    }

    /// Time of the last keyframe, s.
    pub fn duration_s(&self) -> f64 {
        self.keyframes.last().map(|k| k.t_s).unwrap_or(0.0)
    }

    /// The interpolated state at `t_s` seconds after the start (wrapped when looping).
    pub fn sample_at(&self, t_s: f64) -> ScenarioSample {
        // Parsed scenarios are never empty; a hand-built empty one yields a closed, idle rig.
        let (Some(&first), Some(&last)) = (self.keyframes.first(), self.keyframes.last()) else {
            return ScenarioSample {
                t_s,
                valve_in: 0.0,
                valve_out: 0.0,
                pump_mmhg: 0.0,
                tip_mm: [0.0; 3],
                view_dir: [0.0, 0.0, 1.0],
                buttons: 0,
                pose_valid: false,
            };
        };
        let duration = last.t_s;
        let t = if !t_s.is_finite() {
            first.t_s
        } else if self.looping && duration > 0.0 {
            t_s.rem_euclid(duration)
        } else {
            t_s
        };
        let hold = |k: Keyframe| ScenarioSample {
            t_s: t,
            valve_in: k.valve_in,
            valve_out: k.valve_out,
            pump_mmhg: k.pump_mmhg,
            tip_mm: k.tip_mm,
            view_dir: k.view_dir,
            buttons: k.buttons,
            pose_valid: k.pose_valid,
        };
        if t <= first.t_s {
            return hold(first);
        }
        if t >= last.t_s {
            return hold(last);
        }
        let i = self.keyframes.partition_point(|k| k.t_s <= t);
        let (a, b) = (self.keyframes[i - 1], self.keyframes[i]);
        let w = (t - a.t_s) / (b.t_s - a.t_s);
        let lerp = |x: f64, y: f64| x + (y - x) * w;
        let lerp3 =
            |x: [f64; 3], y: [f64; 3]| [lerp(x[0], y[0]), lerp(x[1], y[1]), lerp(x[2], y[2])];
        let dir = lerp3(a.view_dir, b.view_dir);
        let n = dir.iter().map(|c| c * c).sum::<f64>().sqrt();
        // Opposite keyframe directions pass through zero half-way: keep the earlier one there.
        let view_dir = if n > 1e-6 {
            dir.map(|c| c / n)
        } else {
            a.view_dir
        };
        ScenarioSample {
            t_s: t,
            valve_in: lerp(a.valve_in, b.valve_in),
            valve_out: lerp(a.valve_out, b.valve_out),
            pump_mmhg: lerp(a.pump_mmhg, b.pump_mmhg),
            tip_mm: lerp3(a.tip_mm, b.tip_mm),
            view_dir,
            buttons: a.buttons,
            pose_valid: a.pose_valid,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TWO: &str = r#"
name = "two"
loop = true
[[keyframe]]
t_s = 0.0
valve_in = 0.0
valve_out = 1.0
pump_mmhg = 80.0
tip_mm = [0.0, 0.0, 20.0]
view_dir = [0.0, 0.0, 1.0]
buttons = 1
[[keyframe]]
t_s = 10.0
valve_in = 1.0
valve_out = 0.0
pump_mmhg = 100.0
tip_mm = [10.0, 0.0, 60.0]
view_dir = [1.0, 0.0, 0.0]
"#;

    #[test]
    fn interpolates_linearly_and_loops() {
        let s = Scenario::from_toml_str(TWO, "t").unwrap();
        let m = s.sample_at(2.5);
        assert!((m.valve_in - 0.25).abs() < 1e-12);
        assert!((m.valve_out - 0.75).abs() < 1e-12);
        assert!((m.pump_mmhg - 85.0).abs() < 1e-12);
        assert!((m.tip_mm[0] - 2.5).abs() < 1e-12 && (m.tip_mm[2] - 30.0).abs() < 1e-12);
        let d = m.view_dir;
        let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        assert!((n - 1.0).abs() < 1e-12);
        assert!((d[0] / d[2] - 0.25 / 0.75).abs() < 1e-12);
        assert_eq!(m.buttons, 1);
        let wrapped = s.sample_at(12.5);
        assert_eq!(wrapped.valve_in, m.valve_in);
        assert!((wrapped.t_s - 2.5).abs() < 1e-12);
    }

    #[test]
    fn holds_the_last_keyframe_without_loop() {
        let s = Scenario::from_toml_str(&TWO.replace("loop = true", "loop = false"), "t").unwrap();
        assert_eq!(s.sample_at(100.0).valve_in, 1.0);
        assert_eq!(s.sample_at(-1.0).valve_in, 0.0);
    }

    #[test]
    fn errors_name_the_line_and_key() {
        let bad = TWO.replace("valve_in = 1.0", "valve_in = 1.5");
        let e = Scenario::from_toml_str(&bad, "s.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("s.toml") && e.contains("line 14") && e.contains("keyframe[1].valve_in"),
            "{e}"
        );
        let bad = TWO.replace("t_s = 10.0", "t_s = 0.0");
        let e = Scenario::from_toml_str(&bad, "s.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("line 13") && e.contains("keyframe[1].t_s"),
            "{e}"
        );
        let bad = TWO.replace("pump_mmhg = 100.0", "pump_mmgh = 100.0");
        let e = Scenario::from_toml_str(&bad, "s.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 16") && e.contains("pump_mmgh"), "{e}");
        let bad = TWO.replace("view_dir = [1.0, 0.0, 0.0]", "view_dir = [0.0, 0.0, 0.0]");
        let e = Scenario::from_toml_str(&bad, "s.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 18") && e.contains("view_dir"), "{e}");
    }

    #[test]
    fn builtin_default_is_a_believable_procedure() {
        let s = Scenario::builtin("default").expect("default scenario parses");
        assert!(s.looping);
        assert!(
            (120.0..=180.0).contains(&s.duration_s()),
            "{}",
            s.duration_s()
        );
        let mut saw_inflow_open = false;
        let mut saw_rinse = false;
        let mut max_z: f64 = 0.0;
        for k in &s.keyframes {
            assert!((0.0..=110.0).contains(&k.pump_mmhg));
            saw_inflow_open |= k.valve_in > 0.5;
            saw_rinse |= k.valve_in > 0.5 && k.valve_out > 0.3;
            max_z = max_z.max(k.tip_mm[2]);
            // The tip stays inside the cervix/cavity: behind the fundus at ~70 mm.
            assert!(k.tip_mm[2] <= 66.0 && k.tip_mm[2] >= 0.0, "{k:?}");
        }
        assert!(saw_inflow_open && saw_rinse && max_z > 55.0);
        let first = s.keyframes[0];
        let last = s.keyframes[s.keyframes.len() - 1];
        assert_eq!(first.valve_in, last.valve_in);
        assert_eq!(first.tip_mm, last.tip_mm);
    }

    #[test]
    fn builtin_flaky_schedules_every_fault_kind() {
        let s = Scenario::builtin("flaky").expect("flaky scenario parses");
        assert!(s.faults.chunk_max_bytes > 0);
        let kinds: std::collections::HashSet<std::mem::Discriminant<super::super::Fault>> = s
            .faults
            .events
            .iter()
            .map(|e| std::mem::discriminant(&e.fault))
            .collect();
        // Every kind except `chunking`, which the plan sets from the start instead.
        assert_eq!(kinds.len(), 7);
        for name in Scenario::builtin_names() {
            assert!(Scenario::builtin(name).is_some(), "{name}");
        }
        assert!(Scenario::builtin("nope").is_none());
    }

    #[test]
    fn resolve_prefers_the_builtin_name_and_takes_anything_else_as_a_path() {
        let dir = std::env::temp_dir().join(format!("hm-resolve-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        // A file whose path is not a bare built-in name is loaded, even if its stem is one.
        let file = dir.join("default");
        std::fs::write(&file, TWO).unwrap();
        let s = Scenario::resolve(file.to_str().unwrap()).unwrap();
        assert_eq!(
            (s.name.as_str(), s.origin.as_str()),
            ("two", file.to_str().unwrap())
        );
        // The bare name is the built-in, whatever the working directory holds.
        let b = Scenario::resolve("default").unwrap();
        assert_eq!(
            (b.name.as_str(), b.origin.as_str()),
            ("default", "builtin:default")
        );
        assert_eq!(b, Scenario::builtin("default").unwrap());
        // Neither: the message names the argument, the built-ins and the rule.
        let missing = dir.join("nope.toml");
        let e = Scenario::resolve(missing.to_str().unwrap())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("nope.toml") && e.contains("default, flaky") && e.contains("No such file"),
            "{e}"
        );
        // A file that exists but is bad is reported as a bad file, not as "not found".
        std::fs::write(&missing, "name = 3").unwrap();
        let e = Scenario::resolve(missing.to_str().unwrap())
            .unwrap_err()
            .to_string();
        assert!(e.contains("nope.toml") && !e.contains("built-in"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn documented_example_parses_as_described() {
        let doc = include_str!("../../../docs/rig-emulator.md");
        let start = doc.find("```toml").unwrap() + "```toml".len();
        let len = doc[start..].find("```").unwrap();
        let s = Scenario::from_toml_str(&doc[start..start + len], "docs/rig-emulator.md").unwrap();
        assert_eq!(s.name, "example");
        assert_eq!(s.keyframes.len(), 2);
        let m = s.sample_at(15.0); // loops: 15 s -> 5 s, half-way
        assert!((m.valve_in - 0.5).abs() < 1e-12 && (m.pump_mmhg - 95.0).abs() < 1e-12);
        assert_eq!(
            s.faults.events,
            vec![super::super::FaultEvent {
                at_s: 5.0,
                fault: super::super::Fault::GarbageBurst { bytes: 64 }
            }]
        );
    }
}

/// The `[faults]` table as read from a scenario file (the fault kinds themselves are in `faults`).
#[cfg(test)]
mod fault_table_tests {
    use super::*;
    use crate::emulator::faults::Fault;
    use std::time::Duration;

    const BASE: &str = r#"[[keyframe]]
t_s = 0.0
valve_in = 0.0
valve_out = 0.0
pump_mmhg = 80.0
tip_mm = [0.0, 0.0, 20.0]
view_dir = [0.0, 0.0, 1.0]
"#;

    #[test]
    fn every_fault_kind_parses() {
        let text = format!(
            "{BASE}[faults]\nchunk_max_bytes = 3\n\
             [[faults.event]]\nat_s = 9.0\nkind = \"unplug\"\nduration_s = 1.5\n\
             [[faults.event]]\nat_s = 1.0\nkind = \"garbage_burst\"\nbytes = 50\n\
             [[faults.event]]\nat_s = 2.0\nkind = \"bit_flips\"\ncount = 3\n\
             [[faults.event]]\nat_s = 3.0\nkind = \"drop_frames\"\ncount = 4\n\
             [[faults.event]]\nat_s = 4.0\nkind = \"heartbeat_stop\"\nduration_s = 2.0\n\
             [[faults.event]]\nat_s = 5.0\nkind = \"wrong_version\"\ncount = 2\n\
             [[faults.event]]\nat_s = 6.0\nkind = \"fault_report\"\ncode = 7\n\
             [[faults.event]]\nat_s = 7.0\nkind = \"chunking\"\nmax_bytes = 0\n"
        );
        let s = Scenario::from_toml_str(&text, "f").unwrap();
        assert_eq!(s.faults.chunk_max_bytes, 3);
        let kinds: Vec<Fault> = s.faults.events.iter().map(|e| e.fault).collect();
        assert_eq!(
            kinds,
            vec![
                Fault::GarbageBurst { bytes: 50 },
                Fault::BitFlips { count: 3 },
                Fault::DropFrames { count: 4 },
                Fault::HeartbeatStop {
                    duration: Duration::from_secs(2)
                },
                Fault::WrongVersion { count: 2 },
                Fault::FaultReport {
                    code: 7,
                    severity: 1,
                    detail: 0
                },
                Fault::Chunking { max_bytes: 0 },
                Fault::Unplug {
                    duration: Duration::from_millis(1500)
                },
            ]
        );
    }

    #[test]
    fn bad_fault_events_name_line_and_key() {
        let text = format!("{BASE}[faults]\n[[faults.event]]\nat_s = 1.0\nkind = \"unplugg\"\n");
        let e = Scenario::from_toml_str(&text, "f.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("line 11") && e.contains("faults.event[0].kind") && e.contains("unplugg"),
            "{e}"
        );
        let text = format!(
            "{BASE}[faults]\n[[faults.event]]\nat_s = 1.0\nkind = \"bit_flips\"\ncount = -2\n"
        );
        let e = Scenario::from_toml_str(&text, "f.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("line 12") && e.contains("faults.event[0].count"),
            "{e}"
        );
        let text = format!("{BASE}[faults]\n[[faults.event]]\nat_s = 1.0\nkind = \"unplug\"\n");
        let e = Scenario::from_toml_str(&text, "f.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("faults.event[0].duration_s") && e.contains("missing"),
            "{e}"
        );
    }
}
