//! Calibration: raw rig counts and tracker poses to SI values in the organ frame.
//!
//! Loaded from a TOML file (keys, units and defaults in `docs/calibration.md`). Every value that
//! comes off the wire is checked: out-of-range counts are clamped, non-finite or non-unit poses are
//! rejected, and each such event is counted by the caller through [`CalibrationOutcome`].

use std::path::Path;
use std::time::Instant;

use nalgebra::{Quaternion, Unit, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::state::{RigState, ScopePose};
use crate::wire::{SensorSample, RAW_FULL_SCALE};

/// One mmHg in pascals (clinical unit at the edge of the calibration file); the workspace's one
/// copy, from `hydrometra-units`.
pub use hydrometra_units::PA_PER_MMHG;

/// A bad calibration file or value.
#[derive(Debug, thiserror::Error)]
pub enum CalibrationError {
    /// The file could not be read.
    #[error("cannot read calibration file {path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The OS error.
        source: std::io::Error,
    },
    /// The TOML does not parse or has unknown keys or wrong types (the message names line and key).
    #[error("calibration {origin}: {message}")]
    Parse {
        /// File name or other origin.
        origin: String,
        /// The parser's message, with line and column.
        message: String,
    },
    /// A value is out of its allowed range.
    #[error("calibration {origin}: key `{key}` = {value}: expected {expected}")]
    Invalid {
        /// File name or other origin.
        origin: String,
        /// Dotted key.
        key: String,
        /// The offending value.
        value: String,
        /// What is allowed.
        expected: String,
    },
}

/// Potentiometer calibration of one valve.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ValveCalibration {
    /// Raw counts with the valve fully closed (opening 0).
    pub raw_closed: u16,
    /// Raw counts with the valve fully open (opening 1). May be below `raw_closed`.
    pub raw_open: u16,
}

impl Default for ValveCalibration {
    fn default() -> Self {
        Self {
            raw_closed: 200,
            raw_open: 3900,
        }
    }
}

/// Pump set-pressure potentiometer calibration (linear).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PumpCalibration {
    /// Raw counts at 0 mmHg.
    pub raw_zero: u16,
    /// Raw counts at `full_scale_mmhg`.
    pub raw_full_scale: u16,
    /// Set pressure at `raw_full_scale`, mmHg.
    pub full_scale_mmhg: f64,
}

impl Default for PumpCalibration {
    fn default() -> Self {
        Self {
            raw_zero: 0,
            raw_full_scale: 4095,
            full_scale_mmhg: 200.0,
        }
    }
}

/// Tracker frame to organ frame, plus the scope geometry.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrackerCalibration {
    /// Rotation from the tracker frame to the organ frame, quaternion `[w, x, y, z]`.
    pub rotation_wxyz: [f64; 4],
    /// Position of the tracker origin in the organ frame, mm.
    pub translation_mm: [f64; 3],
    /// Scope tip relative to the tracked marker, in the marker's frame, mm.
    pub tip_offset_mm: [f64; 3],
    /// Viewing axis of the scope in the marker's frame (normalised on load).
    pub view_axis: [f64; 3],
}

impl Default for TrackerCalibration {
    fn default() -> Self {
        Self {
            rotation_wxyz: [1.0, 0.0, 0.0, 0.0],
            translation_mm: [0.0; 3],
            tip_offset_mm: [0.0; 3],
            view_axis: [0.0, 0.0, 1.0],
        }
    }
}

/// Plausibility limits applied to every sample.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CalibrationLimits {
    /// How far (as a fraction of the range) a valve or pump value may fall outside [0, 1] of its
    /// range before the clamp is counted as an out-of-range event.
    pub clamp_tolerance: f64,
    /// Largest accepted `| |q| - 1 |` of a tracker quaternion; beyond it the pose is rejected.
    pub quaternion_norm_tolerance: f64,
    /// Largest accepted distance of the tracked marker from the tracker origin, mm.
    pub max_position_mm: f64,
}

impl Default for CalibrationLimits {
    fn default() -> Self {
        Self {
            clamp_tolerance: 0.02,
            quaternion_norm_tolerance: 0.05,
            max_position_mm: 2000.0,
        }
    }
}

/// The rig calibration. `Default` is the documented uncalibrated rig (see `docs/calibration.md`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(default, deny_unknown_fields)]
pub struct Calibration {
    /// Calibration id the rig is expected to report (0: accept any).
    pub calibration_id: u32,
    /// Inflow valve.
    pub valve_in: ValveCalibration,
    /// Outflow valve.
    pub valve_out: ValveCalibration,
    /// Pump set pressure.
    pub pump: PumpCalibration,
    /// Tracker to organ frame and scope geometry.
    pub tracker: TrackerCalibration,
    /// Plausibility limits.
    pub limits: CalibrationLimits,
}

/// A calibrated sample plus how many values had to be clamped or rejected.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CalibrationOutcome {
    /// The calibrated state.
    pub state: RigState,
    /// Values clamped beyond the tolerance or rejected (NaN, non-unit quaternion, far position).
    pub clamped_values: u32,
}

fn invalid(
    origin: &str,
    key: &str,
    value: impl std::fmt::Debug,
    expected: &str,
) -> CalibrationError {
    CalibrationError::Invalid {
        origin: origin.to_string(),
        key: key.to_string(),
        value: format!("{value:?}"),
        expected: expected.to_string(),
    }
}

impl Calibration {
    /// Parses and validates a calibration from TOML text; `origin` names the source in errors.
    pub fn from_toml_str(text: &str, origin: &str) -> Result<Self, CalibrationError> {
        let cal: Calibration = toml::from_str(text).map_err(|e| CalibrationError::Parse {
            origin: origin.to_string(),
            message: e.to_string(),
        })?;
        cal.validated(origin)
    }

    /// Loads and validates a calibration file.
    pub fn load(path: &Path) -> Result<Self, CalibrationError> {
        let text = std::fs::read_to_string(path).map_err(|source| CalibrationError::Io {
            path: path.display().to_string(),
            source,
        })?;
        Self::from_toml_str(&text, &path.display().to_string())
    }

    /// Checks ranges and normalises the quaternion and view axis.
    pub fn validated(mut self, origin: &str) -> Result<Self, CalibrationError> {
        for (name, v) in [("valve_in", self.valve_in), ("valve_out", self.valve_out)] {
            for (k, raw) in [("raw_closed", v.raw_closed), ("raw_open", v.raw_open)] {
                if raw > RAW_FULL_SCALE {
                    return Err(invalid(origin, &format!("{name}.{k}"), raw, "0..=4095"));
                }
            }
            if v.raw_closed == v.raw_open {
                return Err(invalid(
                    origin,
                    &format!("{name}.raw_open"),
                    v.raw_open,
                    "a value different from raw_closed",
                ));
            }
        }
        let p = self.pump;
        for (k, raw) in [
            ("raw_zero", p.raw_zero),
            ("raw_full_scale", p.raw_full_scale),
        ] {
            if raw > RAW_FULL_SCALE {
                return Err(invalid(origin, &format!("pump.{k}"), raw, "0..=4095"));
            }
        }
        if p.raw_zero == p.raw_full_scale {
            return Err(invalid(
                origin,
                "pump.raw_full_scale",
                p.raw_full_scale,
                "a value different from raw_zero",
            ));
        }
        if !(p.full_scale_mmhg.is_finite() && p.full_scale_mmhg > 0.0 && p.full_scale_mmhg <= 500.0)
        {
            return Err(invalid(
                origin,
                "pump.full_scale_mmhg",
                p.full_scale_mmhg,
                "a pressure in (0, 500] mmHg",
            ));
        }
        let t = &mut self.tracker;
        let q = t.rotation_wxyz;
        let qn = q.iter().map(|c| c * c).sum::<f64>().sqrt();
        if !(qn.is_finite() && (qn - 1.0).abs() <= 1e-3) {
            return Err(invalid(
                origin,
                "tracker.rotation_wxyz",
                q,
                "a unit quaternion [w, x, y, z] (norm within 1e-3 of 1)",
            ));
        }
        t.rotation_wxyz = q.map(|c| c / qn);
        for (k, v) in [
            ("tracker.translation_mm", t.translation_mm),
            ("tracker.tip_offset_mm", t.tip_offset_mm),
        ] {
            if !v.iter().all(|c| c.is_finite() && c.abs() <= 10_000.0) {
                return Err(invalid(origin, k, v, "finite values within +-10000 mm"));
            }
        }
        let a = t.view_axis;
        let an = a.iter().map(|c| c * c).sum::<f64>().sqrt();
        if !(an.is_finite() && an > 1e-6) {
            return Err(invalid(
                origin,
                "tracker.view_axis",
                a,
                "a finite non-zero vector",
            ));
        }
        t.view_axis = a.map(|c| c / an);
        let l = self.limits;
        for (k, v, lo, hi) in [
            ("limits.clamp_tolerance", l.clamp_tolerance, 0.0, 1.0),
            (
                "limits.quaternion_norm_tolerance",
                l.quaternion_norm_tolerance,
                0.0,
                0.5,
            ),
            ("limits.max_position_mm", l.max_position_mm, 1.0, 100_000.0),
        ] {
            if !(v.is_finite() && v >= lo && v <= hi) {
                return Err(invalid(origin, k, v, &format!("a value in [{lo}, {hi}]")));
            }
        }
        Ok(self)
    }

    fn rotation(&self) -> UnitQuaternion<f64> {
        let [w, x, y, z] = self.tracker.rotation_wxyz;
        UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z))
    }

    fn view_axis(&self) -> Unit<Vector3<f64>> {
        Unit::new_normalize(Vector3::from(self.tracker.view_axis))
    }

    /// Valve opening in [0, 1] from raw counts, and whether it was clamped beyond the tolerance.
    pub fn valve_opening(valve: &ValveCalibration, raw: u16, tolerance: f64) -> (f64, bool) {
        let span = f64::from(valve.raw_open) - f64::from(valve.raw_closed);
        let x = (f64::from(raw) - f64::from(valve.raw_closed)) / span;
        clamp_unit(x, raw > RAW_FULL_SCALE, tolerance)
    }

    /// Raw counts for a valve opening (inverse of [`Self::valve_opening`]; used by the emulator).
    pub fn raw_from_valve_opening(valve: &ValveCalibration, opening: f64) -> u16 {
        let span = f64::from(valve.raw_open) - f64::from(valve.raw_closed);
        to_raw(f64::from(valve.raw_closed) + opening.clamp(0.0, 1.0) * span)
    }

    /// Pump set pressure in Pa from raw counts, and whether it was clamped beyond the tolerance.
    pub fn pump_pressure_pa(&self, raw: u16) -> (f64, bool) {
        let p = &self.pump;
        let span = f64::from(p.raw_full_scale) - f64::from(p.raw_zero);
        let x = (f64::from(raw) - f64::from(p.raw_zero)) / span;
        let (x, clamped) = clamp_unit(x, raw > RAW_FULL_SCALE, self.limits.clamp_tolerance);
        (x * p.full_scale_mmhg * PA_PER_MMHG, clamped)
    }

    /// Raw counts for a pump set pressure in Pa (inverse of [`Self::pump_pressure_pa`]).
    pub fn raw_from_pump_pressure_pa(&self, pressure_pa: f64) -> u16 {
        let p = &self.pump;
        let x = (pressure_pa / (p.full_scale_mmhg * PA_PER_MMHG)).clamp(0.0, 1.0);
        let span = f64::from(p.raw_full_scale) - f64::from(p.raw_zero);
        to_raw(f64::from(p.raw_zero) + x * span)
    }

    /// Scope pose in the organ frame from the tracker's marker pose, or `None` if the pose is not
    /// finite, the quaternion is not unit within tolerance, or the marker is implausibly far.
    pub fn organ_pose(
        &self,
        position_mm: [f32; 3],
        orientation_wxyz: [f32; 4],
    ) -> Option<ScopePose> {
        let p = Vector3::from(position_mm.map(f64::from));
        let [w, x, y, z] = orientation_wxyz.map(f64::from);
        let q = Quaternion::new(w, x, y, z);
        let qn = q.norm();
        if !(p.iter().all(|c| c.is_finite()) && qn.is_finite()) {
            return None;
        }
        if (qn - 1.0).abs() > self.limits.quaternion_norm_tolerance
            || p.norm() > self.limits.max_position_mm
        {
            return None;
        }
        let q_organ = self.rotation() * UnitQuaternion::from_quaternion(q);
        let marker = self.rotation() * p + Vector3::from(self.tracker.translation_mm);
        let tip_mm = marker + q_organ * Vector3::from(self.tracker.tip_offset_mm);
        let view = q_organ * self.view_axis();
        let qc = q_organ.quaternion();
        Some(ScopePose {
            tip_position_m: [tip_mm.x * 1e-3, tip_mm.y * 1e-3, tip_mm.z * 1e-3],
            view_direction: [view.x, view.y, view.z],
            orientation: [qc.w, qc.i, qc.j, qc.k],
            valid: true,
        })
    }

    /// The tracker's marker pose that [`Self::organ_pose`] maps to a tip position (organ frame, mm)
    /// and view direction (used by the emulator). Roll about the view axis is chosen arbitrarily.
    pub fn tracker_pose(&self, tip_mm: [f64; 3], view_direction: [f64; 3]) -> ([f32; 3], [f32; 4]) {
        let axis = self.view_axis();
        let dir = Vector3::from(view_direction);
        let q_organ = if dir.norm() > 1e-9 {
            let dir = Unit::new_normalize(dir);
            UnitQuaternion::rotation_between_axis(&axis, &dir).unwrap_or_else(|| {
                // Antiparallel: half a turn about any axis perpendicular to the view axis.
                let perp = if axis.x.abs() < 0.9 {
                    Vector3::x()
                } else {
                    Vector3::y()
                };
                let perp = Unit::new_normalize(axis.cross(&perp));
                UnitQuaternion::from_axis_angle(&perp, std::f64::consts::PI)
            })
        } else {
            UnitQuaternion::identity()
        };
        let marker = Vector3::from(tip_mm) - q_organ * Vector3::from(self.tracker.tip_offset_mm);
        let r_inv = self.rotation().inverse();
        let p = r_inv * (marker - Vector3::from(self.tracker.translation_mm));
        let q = (r_inv * q_organ).into_inner();
        (
            [p.x as f32, p.y as f32, p.z as f32],
            [q.w as f32, q.i as f32, q.j as f32, q.k as f32],
        )
    }

    /// Calibrates one raw sample. An invalid or rejected pose keeps the previous pose's values
    /// (or the frame origin looking along +z) with `valid = false`.
    pub fn apply(
        &self,
        sample: &SensorSample,
        sequence: u32,
        received_at: Instant,
        previous: Option<&RigState>,
    ) -> CalibrationOutcome {
        let tol = self.limits.clamp_tolerance;
        let mut clamped_values = 0;
        let (valve_in_opening, c1) = Self::valve_opening(&self.valve_in, sample.valve_in_raw, tol);
        let (valve_out_opening, c2) =
            Self::valve_opening(&self.valve_out, sample.valve_out_raw, tol);
        let (pump_set_pressure_pa, c3) = self.pump_pressure_pa(sample.pump_raw);
        clamped_values += u32::from(c1) + u32::from(c2) + u32::from(c3);
        let fallback = previous.map(|s| s.scope).unwrap_or(ScopePose {
            tip_position_m: [0.0; 3],
            view_direction: [0.0, 0.0, 1.0],
            orientation: [1.0, 0.0, 0.0, 0.0],
            valid: false,
        });
        let scope = if sample.pose_valid {
            match self.organ_pose(sample.position_mm, sample.orientation_wxyz) {
                Some(p) => p,
                None => {
                    clamped_values += 1;
                    ScopePose {
                        valid: false,
                        ..fallback
                    }
                }
            }
        } else {
            ScopePose {
                valid: false,
                ..fallback
            }
        };
        CalibrationOutcome {
            state: RigState {
                device_time_us: sample.device_time_us,
                received_at,
                sequence,
                valve_in_opening,
                valve_out_opening,
                pump_set_pressure_pa,
                scope,
                buttons: sample.buttons,
            },
            clamped_values,
        }
    }
}

fn clamp_unit(x: f64, raw_out_of_range: bool, tolerance: f64) -> (f64, bool) {
    let outside = raw_out_of_range || x < -tolerance || x > 1.0 + tolerance;
    (x.clamp(0.0, 1.0), outside)
}

fn to_raw(counts: f64) -> u16 {
    counts.round().clamp(0.0, f64::from(RAW_FULL_SCALE)) as u16
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> SensorSample {
        SensorSample {
            device_time_us: 5,
            valve_in_raw: 2050,
            valve_out_raw: 200,
            pump_raw: 2048,
            pose_valid: true,
            position_mm: [1.0, 2.0, 3.0],
            orientation_wxyz: [1.0, 0.0, 0.0, 0.0],
            buttons: 3,
        }
    }

    const ROTATED: &str = r#"
        calibration_id = 7
        [valve_in]
        raw_closed = 3900
        raw_open = 100
        [tracker]
        # 90 degrees about +x: tracker +y maps to organ +z.
        rotation_wxyz = [0.7071067811865476, 0.7071067811865476, 0.0, 0.0]
        translation_mm = [10.0, -5.0, 20.0]
        tip_offset_mm = [0.0, 0.0, 150.0]
    "#;

    #[test]
    fn default_valve_and_pump_mapping_is_linear_between_documented_points() {
        let c = Calibration::default();
        let o = c.apply(&sample(), 1, Instant::now(), None);
        assert!((o.state.valve_in_opening - 0.5).abs() < 1e-12);
        assert_eq!(o.state.valve_out_opening, 0.0);
        let expected_pa = 2048.0 / 4095.0 * 200.0 * PA_PER_MMHG;
        assert!((o.state.pump_set_pressure_pa - expected_pa).abs() < 1e-9);
        assert_eq!(o.clamped_values, 0);
        assert_eq!(o.state.scope.tip_position_m, [1e-3, 2e-3, 3e-3]);
    }

    #[test]
    fn out_of_range_counts_are_clamped_and_counted() {
        let c = Calibration::default();
        let mut s = sample();
        s.valve_in_raw = 4095; // (4095-200)/3700 = 1.053 > 1 + 0.02
        s.valve_out_raw = 60000; // beyond 12 bits
        s.pump_raw = 4095; // exactly full scale: not a clamp
        let o = c.apply(&s, 1, Instant::now(), None);
        assert_eq!(o.state.valve_in_opening, 1.0);
        assert_eq!(o.state.valve_out_opening, 1.0);
        assert_eq!(o.clamped_values, 2);
        // Within tolerance: clamped silently.
        s.valve_in_raw = 150; // -0.0135
        s.valve_out_raw = 200;
        let o = c.apply(&s, 1, Instant::now(), None);
        assert_eq!(o.state.valve_in_opening, 0.0);
        assert_eq!(o.clamped_values, 0);
    }

    #[test]
    fn nan_and_non_unit_poses_are_rejected_and_keep_the_previous_pose() {
        let c = Calibration::default();
        let first = c.apply(&sample(), 1, Instant::now(), None).state;
        for (pos, q) in [
            ([f32::NAN, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]),
            ([0.0, 0.0, 0.0], [f32::INFINITY, 0.0, 0.0, 0.0]),
            ([0.0, 0.0, 0.0], [0.5, 0.0, 0.0, 0.0]),
            ([5000.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]),
        ] {
            let mut s = sample();
            s.position_mm = pos;
            s.orientation_wxyz = q;
            let o = c.apply(&s, 2, Instant::now(), Some(&first));
            assert_eq!(o.clamped_values, 1, "{pos:?} {q:?}");
            assert!(!o.state.scope.valid);
            assert_eq!(o.state.scope.tip_position_m, first.scope.tip_position_m);
            assert!(o.state.scope.tip_position_m.iter().all(|v| v.is_finite()));
        }
    }

    #[test]
    fn rotated_frame_with_tip_offset_matches_hand_computed_pose() {
        let c = Calibration::from_toml_str(ROTATED, "test").unwrap();
        assert_eq!(c.calibration_id, 7);
        // Marker at tracker (0, 10, 0), identity orientation in the tracker frame.
        let pose = c
            .organ_pose([0.0, 10.0, 0.0], [1.0, 0.0, 0.0, 0.0])
            .unwrap();
        // Rx(90): (0,10,0) -> (0,0,10); + translation -> (10,-5,30); tip offset (0,0,150) in the
        // marker frame, rotated by Rx(90) -> (0,-150,0). Tip = (10,-155,30) mm.
        let expect = [0.010, -0.155, 0.030];
        for (got, want) in pose.tip_position_m.iter().zip(expect) {
            assert!((got - want).abs() < 1e-9, "{pose:?}");
        }
        // View axis +z rotated by Rx(90) is -y.
        let v = pose.view_direction;
        assert!((v[0]).abs() < 1e-9 && (v[1] + 1.0).abs() < 1e-9 && v[2].abs() < 1e-9);
        // Inverted valve potentiometer: raw 3900 closed, 100 open.
        let (x, _) = Calibration::valve_opening(&c.valve_in, 1050, 0.02);
        assert!((x - 0.75).abs() < 1e-12);
    }

    #[test]
    fn tracker_pose_inverts_organ_pose() {
        let c = Calibration::from_toml_str(ROTATED, "test").unwrap();
        for (tip, dir) in [
            ([0.0, 0.0, 45.0], [0.0, 0.0, 1.0]),
            ([3.0, -2.0, 60.0], [0.3, -0.2, 0.9]),
            ([0.0, 0.0, 30.0], [0.0, 0.0, -1.0]),
        ] {
            let (p, q) = c.tracker_pose(tip, dir);
            let pose = c.organ_pose(p, q).unwrap();
            let n = (dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]).sqrt();
            for i in 0..3 {
                // f32 on the wire: ~1e-4 mm at 150 mm.
                assert!(
                    (pose.tip_position_m[i] * 1e3 - tip[i]).abs() < 1e-3,
                    "{pose:?}"
                );
                assert!(
                    (pose.view_direction[i] - dir[i] / n).abs() < 1e-5,
                    "{pose:?}"
                );
            }
        }
    }

    #[test]
    fn bad_files_name_the_key_value_and_expectation() {
        let e = Calibration::from_toml_str("[valve_in]\nraw_closed = 5000\n", "rig.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("rig.toml") && e.contains("valve_in.raw_closed") && e.contains("5000"),
            "{e}"
        );
        let e = Calibration::from_toml_str("[pump]\nfull_scale_mmhg = nan\n", "rig.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("pump.full_scale_mmhg"), "{e}");
        let e =
            Calibration::from_toml_str("[tracker]\nrotation_wxyz = [1.0, 1.0, 0.0, 0.0]\n", "r")
                .unwrap_err()
                .to_string();
        assert!(e.contains("tracker.rotation_wxyz"), "{e}");
        let e = Calibration::from_toml_str("\n[pump]\nfull_scale = 3\n", "rig.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 3") && e.contains("full_scale"), "{e}");
    }

    #[test]
    fn documented_defaults_are_the_defaults() {
        let doc = include_str!("../../docs/calibration.md");
        let start = doc.find("```toml").unwrap() + "```toml".len();
        let len = doc[start..].find("```").unwrap();
        let documented = Calibration::from_toml_str(&doc[start..start + len], "docs").unwrap();
        assert_eq!(documented, Calibration::default());
        assert_eq!(
            Calibration::from_toml_str("", "empty").unwrap(),
            Calibration::default()
        );
    }

    #[test]
    fn protocol_document_sample_example_calibrates_as_stated() {
        let s = SensorSample {
            device_time_us: 1_234_567,
            valve_in_raw: 2050,
            valve_out_raw: 200,
            pump_raw: 1843,
            pose_valid: true,
            position_mm: [10.0, -2.5, 45.0],
            orientation_wxyz: [1.0, 0.0, 0.0, 0.0],
            buttons: 1,
        };
        let o = Calibration::default().apply(&s, 7, Instant::now(), None);
        assert!((o.state.valve_in_opening - 0.5).abs() < 1e-12);
        assert!((o.state.pump_set_pressure_pa - 12_000.6).abs() < 0.05);
        assert!((o.state.pump_set_pressure_pa / PA_PER_MMHG - 90.01).abs() < 0.005);
        assert_eq!(o.state.scope.tip_position_m, [0.010, -0.0025, 0.045]);
    }
}
