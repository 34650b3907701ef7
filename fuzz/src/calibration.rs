//! The calibration TOML reader (`Calibration::from_toml_str`, what `Calibration::load` runs).
//!
//! Properties: an error starts with `calibration <origin>:` and says where: a parse error has the
//! TOML line, a range error the dotted key; an accepted file is normalised (unit rotation and view
//! axis, counts within 12 bits, limits in their documented ranges), survives writing and reading
//! back, and calibrates any raw sample to in-range values.

use std::time::Instant;

use hydrometra_drivers::calibration::{Calibration, CalibrationError, PA_PER_MMHG};
use hydrometra_drivers::wire::{SensorSample, RAW_FULL_SCALE};

const ORIGIN: &str = "fuzz-calibration.toml";

fn norm(v: &[f64]) -> f64 {
    v.iter().map(|c| c * c).sum::<f64>().sqrt()
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-12 * a.abs().max(b.abs()).max(1.0)
}

/// The calibration target.
pub fn check(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    match Calibration::from_toml_str(text, ORIGIN) {
        Err(e) => {
            let msg = e.to_string();
            assert!(msg.starts_with(&format!("calibration {ORIGIN}: ")), "{msg}");
            match e {
                CalibrationError::Parse { .. } => {
                    assert!(
                        crate::position::names_a_line(&msg),
                        "parse error without a line: {msg}"
                    )
                }
                CalibrationError::Invalid { key, .. } => {
                    assert!(
                        !key.is_empty() && msg.contains(&format!("key `{key}`")),
                        "{msg}"
                    )
                }
                CalibrationError::Io { .. } => panic!("I/O error from text: {msg}"),
            }
        }
        Ok(cal) => {
            let t = &cal.tracker;
            assert!((norm(&t.rotation_wxyz) - 1.0).abs() < 1e-12, "{t:?}");
            assert!((norm(&t.view_axis) - 1.0).abs() < 1e-12, "{t:?}");
            for v in [cal.valve_in, cal.valve_out] {
                assert!(v.raw_open <= RAW_FULL_SCALE && v.raw_closed <= RAW_FULL_SCALE);
                assert_ne!(v.raw_open, v.raw_closed);
            }
            // Written and read back: the same calibration (normalising is idempotent to 1e-12).
            let written = toml::to_string(&cal).unwrap_or_else(|e| panic!("{cal:?}: {e}"));
            let back = Calibration::from_toml_str(&written, ORIGIN)
                .unwrap_or_else(|e| panic!("written calibration rejected: {e}\n{written}"));
            let numbers = |c: &Calibration| {
                let t = &c.tracker;
                let mut v = vec![c.pump.full_scale_mmhg];
                v.extend(t.rotation_wxyz);
                v.extend(t.translation_mm);
                v.extend(t.tip_offset_mm);
                v.extend(t.view_axis);
                v.extend([
                    c.limits.clamp_tolerance,
                    c.limits.quaternion_norm_tolerance,
                    c.limits.max_position_mm,
                ]);
                v
            };
            assert!(
                numbers(&cal)
                    .iter()
                    .zip(numbers(&back))
                    .all(|(a, b)| close(*a, b)),
                "round trip changed {cal:?} into {back:?}"
            );
            assert_eq!(
                (cal.calibration_id, cal.valve_in, cal.valve_out),
                (back.calibration_id, back.valve_in, back.valve_out)
            );
            check_samples(&cal, data);
        }
    }
}

/// Calibrates samples made from the input's bytes (edge counts, NaN and huge poses included).
fn check_samples(cal: &Calibration, data: &[u8]) {
    let full_scale_pa = cal.pump.full_scale_mmhg * PA_PER_MMHG;
    let now = Instant::now();
    let seeds = [0u16, 1, RAW_FULL_SCALE, RAW_FULL_SCALE + 1, u16::MAX];
    let floats = [0.0f32, 1.0, -1.0, f32::NAN, f32::INFINITY, 1e30, 0.5];
    for (i, &raw) in seeds.iter().enumerate() {
        let b = data.get(i).copied().unwrap_or(0) as usize;
        let sample = SensorSample {
            device_time_us: i as u64,
            valve_in_raw: raw,
            valve_out_raw: seeds[(i + b) % seeds.len()],
            pump_raw: seeds[(i + 2 * b) % seeds.len()],
            pose_valid: b.is_multiple_of(2),
            position_mm: [floats[b % 7], floats[(b / 7) % 7], 10.0],
            orientation_wxyz: [floats[(b + 1) % 7], 0.0, floats[(b + 3) % 7], 0.0],
            buttons: 0,
        };
        let s = cal.apply(&sample, 0, now, None).state;
        assert!((0.0..=1.0).contains(&s.valve_in_opening), "{s:?}");
        assert!((0.0..=1.0).contains(&s.valve_out_opening), "{s:?}");
        assert!(
            (0.0..=full_scale_pa).contains(&s.pump_set_pressure_pa),
            "{s:?}"
        );
        if s.scope.valid {
            assert!(
                s.scope.tip_position_m.iter().all(|c| c.is_finite()),
                "{s:?}"
            );
            assert!((norm(&s.scope.view_direction) - 1.0).abs() < 1e-9, "{s:?}");
        }
    }
}
