//! The emulator's scenario TOML reader (`Scenario::from_toml_str`, what `Scenario::load` runs),
//! keyframes and `[faults]` table.
//!
//! Properties: an error starts with `scenario <origin>` and says where (a parse error the TOML
//! line, a range error the line of the value, within the file, and the key path); an accepted
//! scenario has strictly increasing finite times and unit view directions, and its interpolated
//! state at any time (negative, past the end, NaN, infinite) is within the documented ranges.

use hydrometra_drivers::emulator::{Scenario, ScenarioError};

const ORIGIN: &str = "fuzz-scenario.toml";

/// The scenario target.
pub fn check(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    match Scenario::from_toml_str(text, ORIGIN) {
        Err(e) => {
            let msg = e.to_string();
            assert!(msg.starts_with(&format!("scenario {ORIGIN}")), "{msg}");
            match e {
                ScenarioError::Parse { .. } => {
                    assert!(
                        crate::position::names_a_line(&msg),
                        "parse error without a line: {msg}"
                    )
                }
                ScenarioError::Invalid { line, key, .. } => {
                    let lines = text.lines().count().max(1);
                    assert!(line >= 1 && line <= lines, "line {line} of {lines}: {msg}");
                    assert!(
                        !key.is_empty() && msg.contains(&format!("key `{key}`")),
                        "{msg}"
                    );
                }
                ScenarioError::Io { .. } | ScenarioError::NotFound { .. } => {
                    panic!("file error from text: {msg}")
                }
            }
        }
        Ok(s) => {
            assert!(!s.keyframes.is_empty());
            assert!(s.keyframes.windows(2).all(|w| w[0].t_s < w[1].t_s));
            let d = s.duration_s();
            for t in [
                -1.0,
                0.0,
                d * 0.37,
                d * 0.5,
                d,
                d * 2.6,
                1e300,
                f64::NAN,
                f64::INFINITY,
                f64::NEG_INFINITY,
            ] {
                let m = s.sample_at(t);
                assert!((0.0..=1.0).contains(&m.valve_in), "t {t}: {m:?}");
                assert!((0.0..=1.0).contains(&m.valve_out), "t {t}: {m:?}");
                assert!((0.0..=300.0).contains(&m.pump_mmhg), "t {t}: {m:?}");
                assert!(m.tip_mm.iter().all(|c| c.abs() <= 500.0), "t {t}: {m:?}");
                let n = m.view_dir.iter().map(|c| c * c).sum::<f64>().sqrt();
                assert!((n - 1.0).abs() < 1e-9, "t {t}: view_dir {:?}", m.view_dir);
            }
            for ev in &s.faults.events {
                assert!(ev.at_s.is_finite() && ev.at_s >= 0.0, "{ev:?}");
            }
            assert!(s.faults.chunk_max_bytes <= 4096);
        }
    }
}
