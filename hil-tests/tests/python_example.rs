//! The Python example (`ipc/examples/python/status_subscriber.py`, iceoryx2 0.10 from PyPI) reads
//! every status field exactly as a Rust subscriber sees it.
//!
//! Needs `python3` (or `$PYTHON`) with the `iceoryx2` package (`.ci/setup` installs it); fails,
//! saying so, when either is missing.

use std::collections::HashMap;
use std::process::Command;
use std::time::Duration;

use hydrometra_drivers::emulator::Scenario;
use hydrometra_hil_tests::*;
use hydrometra_ipc::Status;
use serde_json::Value;

fn python() -> String {
    let python = std::env::var("PYTHON").unwrap_or_else(|_| "python3".into());
    let probe = Command::new(&python)
        .args(["-c", "import iceoryx2, sys; print(sys.version.split()[0])"])
        .output();
    match probe {
        Err(e) => panic!(
            "{python} is not available ({e}): this test runs the Python example and needs Python 3 \
             with the iceoryx2 package; run .ci/setup (pip install -r .ci/requirements.txt)"
        ),
        Ok(out) if !out.status.success() => panic!(
            "{python} cannot import iceoryx2: run .ci/setup (pip install 'iceoryx2==0.10.*')\n{}",
            String::from_utf8_lossy(&out.stderr)
        ),
        Ok(_) => python,
    }
}

/// Python prints f64 with shortest round-trip digits; serde_json's default (fast) float parser
/// is exact to within one ulp. So two ulps is the tolerance; integers compare exactly.
fn close(a: f64, b: f64) -> bool {
    a == b || (a - b).abs() <= 2.0 * f64::EPSILON * a.abs().max(b.abs())
}

/// Compares one JSON field with the Rust value.
fn same(json: &Value, field: &str, rust: f64) {
    let v = &json[field];
    if rust.is_nan() {
        assert!(v.is_null(), "{field}: Rust NaN, Python {v}");
    } else {
        let p = v
            .as_f64()
            .unwrap_or_else(|| panic!("{field} missing or not a number: {json}"));
        assert!(close(p, rust), "{field}: Python {v} vs Rust {rust}");
    }
}

fn same_array(json: &Value, field: &str, rust: &[f64]) {
    let arr: Vec<f64> = json[field]
        .as_array()
        .unwrap_or_else(|| panic!("{field} is not an array: {json}"))
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert_eq!(arr.len(), rust.len(), "{field}");
    for (p, r) in arr.iter().zip(rust) {
        assert!(close(*p, *r), "{field}: Python {arr:?} vs Rust {rust:?}");
    }
}

fn compare(j: &Value, s: &Status) {
    let u = |x: u64| x as f64;
    for (field, value) in [
        ("schema_version", u(s.schema_version.into())),
        ("size_bytes", u(s.size_bytes.into())),
        ("sequence", u(s.sequence)),
        ("sim_time_s", s.sim_time_s),
        ("link_frames", u(s.link_frames)),
        ("link_crc_errors", u(s.link_crc_errors)),
        ("link_reconnects", u(s.link_reconnects)),
        ("last_sample_age_s", s.last_sample_age_s),
        ("rig_device_time_us", u(s.rig_device_time_us)),
        ("rig_valve_in_opening", s.rig_valve_in_opening),
        ("rig_valve_out_opening", s.rig_valve_out_opening),
        ("rig_pump_set_pressure_pa", s.rig_pump_set_pressure_pa),
        ("valve_in_opening", s.valve_in_opening),
        ("valve_out_opening", s.valve_out_opening),
        ("pump_set_pressure_pa", s.pump_set_pressure_pa),
        ("alarm_bits", u(s.alarm_bits)),
        ("tick_rate_hz", s.tick_rate_hz),
        ("ticks", u(s.ticks)),
        ("deadline_misses", u(s.deadline_misses)),
        ("tick_work_max_s", s.tick_work_max_s),
        ("latency_p50_s", s.latency_p50_s),
        ("latency_p99_s", s.latency_p99_s),
        ("latency_max_s", s.latency_max_s),
        ("latency_samples", u(s.latency_samples)),
        ("statuses_dropped", u(s.statuses_dropped)),
        ("link_state", u(s.link_state.into())),
        ("rig_sequence", u(s.rig_sequence.into())),
        ("buttons", u(s.buttons.into())),
        ("scope_pose_valid", u(s.scope_pose_valid.into())),
        ("safe_state", u(s.safe_state.into())),
        ("reserved0", u(s.reserved0.into())),
        ("cavity_pressure_pa", s.cavity_pressure_pa),
        ("cavity_volume_m3", s.cavity_volume_m3),
        ("inflow_m3_per_s", s.inflow_m3_per_s),
        ("outflow_m3_per_s", s.outflow_m3_per_s),
        ("leak_m3_per_s", s.leak_m3_per_s),
        ("absorption_m3_per_s", s.absorption_m3_per_s),
        ("perforation_m3_per_s", s.perforation_m3_per_s),
        (
            "inflow_port_velocity_m_per_s",
            s.inflow_port_velocity_m_per_s,
        ),
        (
            "outflow_port_velocity_m_per_s",
            s.outflow_port_velocity_m_per_s,
        ),
        ("fluid_in_m3", s.fluid_in_m3),
        ("fluid_collected_m3", s.fluid_collected_m3),
        ("deficit_m3", s.deficit_m3),
        ("deficit_rate_m3_per_s", s.deficit_rate_m3_per_s),
        ("deficit_limit_m3", s.deficit_limit_m3),
        ("procedure_id", u(s.procedure_id)),
        ("procedure_time_s", s.procedure_time_s),
        ("deficit_warning_stage", u(s.deficit_warning_stage)),
        ("hydraulic_flags", u(s.hydraulic_flags)),
        ("link_down_reason", u(s.link_down_reason.into())),
        ("link_down_detail", u(s.link_down_detail.into())),
    ] {
        same(j, field, value);
    }
    // u64 fields beyond f64's exact range are compared as integers.
    assert_eq!(j["run_id"].as_u64(), Some(s.run_id));
    assert_eq!(
        j["publish_monotonic_ns"].as_u64(),
        Some(s.publish_monotonic_ns)
    );
    same_array(j, "scope_tip_position_m", &s.scope_tip_position_m);
    same_array(j, "scope_view_direction", &s.scope_view_direction);
    same_array(j, "scope_orientation_wxyz", &s.scope_orientation_wxyz);
}

#[test]
fn python_example_reads_every_status_field_like_the_rust_subscriber() {
    let python = python();
    let prefix = unique_prefix("python");
    let _daemon = Daemon::start(
        &prefix,
        &["--emulated", "default", "--status-rate-hz", "100"],
    );
    let reader = StatusReader::connect(&prefix, Duration::from_secs(10));
    reader.until("a live status", Duration::from_secs(10), |s| {
        s.safe_state == 0
    });

    let script = workspace_root().join("ipc/examples/python/status_subscriber.py");
    let child = Command::new(&python)
        .arg(&script)
        .args([
            "--prefix",
            &prefix,
            "--count",
            "30",
            "--json",
            "--timeout",
            "10",
        ])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("start the Python example");
    // The Rust side records every status meanwhile, to compare by sequence number.
    let mut rust: HashMap<u64, Status> = HashMap::new();
    let out = std::thread::scope(|scope| {
        let waiter = scope.spawn(|| child.wait_with_output());
        while !waiter.is_finished() {
            for s in reader.drain() {
                rust.insert(s.sequence, s);
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        waiter.join().unwrap()
    })
    .expect("Python example output");
    for s in reader.drain() {
        rust.insert(s.sequence, s);
    }
    assert!(
        out.status.success(),
        "the Python example failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let lines: Vec<Value> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).expect("one JSON object per line"))
        .collect();
    assert_eq!(lines.len(), 30);

    let scenario = Scenario::builtin("default").unwrap();
    let mut compared = 0;
    let mut previous = None;
    for j in &lines {
        let seq = j["sequence"].as_u64().unwrap();
        assert!(previous.is_none_or(|p| seq > p), "sequence not increasing");
        previous = Some(seq);
        if let Some(s) = rust.get(&seq) {
            compare(j, s);
            if s.safe_state == 0 {
                assert_matches_scenario(s, &scenario);
            }
            compared += 1;
        }
    }
    // The first Python sample may be the history one, older than the Rust subscription.
    assert!(
        compared >= 29,
        "only {compared} of 30 Python statuses seen by Rust too"
    );
    assert_eq!(lines[5]["link_state_name"], "connected");
}
