//! hydrometrad on the emulated default scenario: a subscriber receives status with contiguous
//! sequence numbers at the configured rate, with fields matching the scenario.

use std::time::Duration;

use hydrometra_drivers::emulator::Scenario;
use hydrometra_hil_tests::*;
use hydrometra_ipc::status::link_state;

#[test]
fn status_arrives_at_the_configured_rate_with_contiguous_sequence_and_scenario_values() {
    let prefix = unique_prefix("stream");
    let status_rate_hz = 200.0;
    let _daemon = Daemon::start(
        &prefix,
        &[
            "--emulated",
            "default",
            "--tick-rate-hz",
            "1000",
            "--status-rate-hz",
            "200",
        ],
    );
    let reader = StatusReader::connect(&prefix, Duration::from_secs(10));
    reader.until("a connected rig", Duration::from_secs(10), |s| {
        s.link_state == link_state::CONNECTED && s.safe_state == 0
    });

    let window = Duration::from_secs(5);
    let statuses = reader.collect_for(window);
    assert_contiguous(&statuses);
    // Rate over the 5 s window, counted by the subscriber, within 10 %.
    let rate = statuses.len() as f64 / window.as_secs_f64();
    assert!(
        (rate - status_rate_hz).abs() <= 0.1 * status_rate_hz,
        "received {rate:.1} statuses/s, configured {status_rate_hz}"
    );
    // The same rate by the publisher's own clock, and sim time advancing in step.
    let (first, last) = (statuses[0], statuses[statuses.len() - 1]);
    let n = (last.sequence - first.sequence) as f64;
    let publish_span_s = (last.publish_monotonic_ns - first.publish_monotonic_ns) as f64 * 1e-9;
    assert!((n / publish_span_s - status_rate_hz).abs() <= 0.1 * status_rate_hz);
    assert!(((last.sim_time_s - first.sim_time_s) / publish_span_s - 1.0).abs() < 0.1);

    let scenario = Scenario::builtin("default").expect("built-in default scenario");
    let mut checked = 0;
    for s in &statuses {
        assert_eq!(s.schema_version, hydrometra_ipc::SCHEMA_VERSION);
        assert_eq!(
            s.size_bytes as usize,
            std::mem::size_of::<hydrometra_ipc::Status>()
        );
        assert_eq!(s.run_id, first.run_id);
        assert_eq!(s.tick_rate_hz, 1000.0);
        assert_safe_state_rule(s, 0.1, 0.01);
        if s.link_state == link_state::CONNECTED && s.safe_state == 0 {
            assert_matches_scenario(s, &scenario);
            assert_eq!(s.alarm_bits & hydrometra_ipc::alarms::RIG_LINK_LOST, 0);
            checked += 1;
        }
    }
    // The emulated rig is healthy: (nearly) every status is live.
    assert!(
        checked as f64 >= 0.95 * statuses.len() as f64,
        "{checked} of {}",
        statuses.len()
    );
    assert_eq!(
        (
            last.link_crc_errors,
            last.link_sequence_gaps,
            last.link_reconnects
        ),
        (0, 0, 0)
    );
    // ~250 frames/s over the window.
    let frames = (last.link_frames - first.link_frames) as f64 / publish_span_s;
    assert!((frames - 250.0).abs() < 25.0 + 5.0, "{frames} frames/s");
    // Latency figures are measured and ordered.
    assert!(last.latency_samples > 500);
    assert!(last.latency_p50_s > 0.0 && last.latency_p50_s <= last.latency_p99_s);
    assert!(last.latency_p99_s <= last.latency_max_s);
    assert_eq!(last.ticks, last.ticks.max(first.ticks));
}

#[test]
fn monitor_once_json_prints_the_live_status() {
    let prefix = unique_prefix("monitor");
    let _daemon = Daemon::start(&prefix, &["--emulated", "default"]);
    let reader = StatusReader::connect(&prefix, Duration::from_secs(10));
    reader.until("a connected rig", Duration::from_secs(10), |s| {
        s.safe_state == 0
    });
    let j = monitor_once_json(&prefix);
    assert_eq!(j["schema_version"], 1);
    assert_eq!(j["link_state_name"], "connected");
    assert_eq!(j["safe_state"], false);
    let scenario = Scenario::builtin("default").unwrap();
    let e = scenario.sample_at(j["rig_device_time_us"].as_f64().unwrap() * 1e-6);
    assert!((j["pump_set_pressure_mmhg"].as_f64().unwrap() - e.pump_mmhg).abs() < 0.1);
    assert!((j["valve_in_opening"].as_f64().unwrap() - e.valve_in).abs() < 1e-3);
    assert!(j["sequence"].as_u64().unwrap() > 0);
}

#[test]
fn monitor_without_a_daemon_fails_with_a_clear_message() {
    let prefix = unique_prefix("nodaemon");
    let out = std::process::Command::new(binary("hydrometra"))
        .args([
            "monitor",
            "--once",
            "--timeout",
            "0.5",
            "--service-prefix",
            &prefix,
        ])
        .output()
        .expect("run hydrometra monitor");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("no status from hydrometrad") && err.contains(&prefix),
        "{err}"
    );
}

#[test]
fn monitor_live_view_refreshes_in_place_with_new_statuses() {
    let prefix = unique_prefix("live");
    let _daemon = Daemon::start(&prefix, &["--emulated", "default"]);
    let reader = StatusReader::connect(&prefix, Duration::from_secs(10));
    reader.until("a connected rig", Duration::from_secs(10), |s| {
        s.safe_state == 0
    });
    let child = std::process::Command::new(binary("hydrometra"))
        .args([
            "monitor",
            "--refresh-ms",
            "100",
            "--service-prefix",
            &prefix,
        ])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("run hydrometra monitor");
    std::thread::sleep(Duration::from_millis(1200));
    // SAFETY: kill(2) on our child; SIGINT ends the monitor like Ctrl-C.
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success(), "monitor exits cleanly on Ctrl-C");
    let text = String::from_utf8_lossy(&out.stdout);
    // Each refresh homes the cursor and clears: several frames, with growing status numbers.
    let frames: Vec<&str> = text
        .split("\x1b[H\x1b[2J")
        .filter(|f| !f.is_empty())
        .collect();
    assert!(frames.len() >= 5, "{} frames", frames.len());
    let numbers: Vec<u64> = frames
        .iter()
        .filter_map(|f| {
            f.split("status #")
                .nth(1)?
                .split_whitespace()
                .next()?
                .parse()
                .ok()
        })
        .collect();
    assert!(numbers.windows(2).all(|w| w[1] > w[0]), "{numbers:?}");
    let last = frames.last().unwrap();
    for needle in [
        "RIG LINK      CONNECTED",
        "pump set",
        "mmHg",
        "LATENCY",
        "ALARMS",
    ] {
        assert!(last.contains(needle), "{needle} missing in\n{last}");
    }
}
