//! Rig faults seen through the daemon: the status reports a lost link within the safe-state
//! timeout, the simulation keeps running on the safe inputs, and recovers by itself.

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use hydrometra_drivers::emulator::Scenario;
use hydrometra_hil_tests::*;
use hydrometra_ipc::alarms;
use hydrometra_ipc::status::link_state;
use hydrometra_ipc::Status;

/// Safe-state timeout (the default) and the slack for the sample age measured at publication:
/// one status period plus scheduling jitter on a loaded 2-core machine.
const TIMEOUT_S: f64 = 0.100;
const SLACK_S: f64 = 0.020;

fn start(tag: &str, faults: &str) -> (Daemon, StatusReader, Scenario) {
    let dir = temp_dir(tag);
    let path = scenario_file(&dir, faults);
    let scenario = Scenario::load(&path).expect("scenario with faults parses");
    let prefix = unique_prefix(tag);
    let daemon = Daemon::start(&prefix, &["--emulated", path.to_str().unwrap()]);
    let reader = StatusReader::connect(&prefix, Duration::from_secs(10));
    (daemon, reader, scenario)
}

fn live(s: &Status) -> bool {
    s.link_state == link_state::CONNECTED && s.safe_state == 0
}

/// Checks the invariants every status of a run must hold, and the live ones against the scenario.
fn check_all(statuses: &[Status], scenario: &Scenario) {
    // The first status may be the history sample, delivered before the publisher saw the new
    // subscriber: contiguity holds from the second one on.
    assert_contiguous(&statuses[1..]);
    for w in statuses.windows(2) {
        // The simulation keeps running whatever the link does.
        assert!(w[1].sim_time_s > w[0].sim_time_s && w[1].ticks > w[0].ticks);
    }
    for s in statuses {
        assert_safe_state_rule(s, TIMEOUT_S, SLACK_S);
        if live(s) {
            assert_matches_scenario(s, scenario);
        }
    }
}

#[test]
fn unplug_shows_link_lost_runs_on_safe_inputs_and_recovers_on_replug() {
    let (daemon, reader, scenario) = start(
        "unplug",
        "[faults]\n[[faults.event]]\nat_s = 2.0\nkind = \"unplug\"\nduration_s = 1.5\n",
    );
    let mut all = reader.until("a live link", Duration::from_secs(10), live);
    let before = *all.last().unwrap();
    all.extend(reader.until("the link lost", Duration::from_secs(10), |s| {
        s.safe_state == 1
    }));
    let lost = *all.last().unwrap();
    // Reported within the safe-state timeout of the last sample.
    assert!(lost.last_sample_age_s <= TIMEOUT_S + SLACK_S, "{lost:?}");
    assert_ne!(lost.alarm_bits & alarms::RIG_LINK_LOST, 0);
    assert_eq!(lost.run_id, before.run_id);
    // The last rig values stay visible as such, the simulation uses the safe ones.
    assert_eq!(
        (
            lost.valve_in_opening,
            lost.valve_out_opening,
            lost.pump_set_pressure_pa
        ),
        (0.0, 0.0, 0.0)
    );
    all.extend(reader.until("the link back", Duration::from_secs(15), |s| {
        live(s) && s.link_reconnects >= 1
    }));
    let back = *all.last().unwrap();
    // More live statuses after the replug, still matching the scenario.
    all.extend(reader.collect_for(Duration::from_millis(500)));
    check_all(&all, &scenario);
    let outage: Vec<&Status> = all
        .iter()
        .filter(|s| s.sequence >= lost.sequence && s.sequence < back.sequence)
        .collect();
    assert!(
        outage.iter().all(|s| s.safe_state == 1),
        "safe state held through the outage"
    );
    // Unplugged for 1.5 s: the outage seen in status is about that long (reconnect backoff adds).
    let outage_s = back.sim_time_s - lost.sim_time_s;
    assert!((1.3..6.0).contains(&outage_s), "outage {outage_s} s");
    assert!(daemon.log().contains("hydrometrad running"));
}

#[test]
fn a_hung_rig_is_reported_stale_within_the_timeout_and_recovers() {
    // The firmware stops sending (port still open): only the timeout can detect it.
    let (_daemon, reader, scenario) = start(
        "hang",
        "[faults]\n[[faults.event]]\nat_s = 2.0\nkind = \"heartbeat_stop\"\nduration_s = 1.0\n",
    );
    let mut all = reader.until("a live link", Duration::from_secs(10), live);
    all.extend(reader.until("the link lost", Duration::from_secs(10), |s| {
        s.safe_state == 1
    }));
    let lost = *all.last().unwrap();
    assert!(
        lost.last_sample_age_s > TIMEOUT_S - 0.005,
        "lost too early: {lost:?}"
    );
    assert!(
        lost.last_sample_age_s <= TIMEOUT_S + SLACK_S,
        "lost too late: {lost:?}"
    );
    all.extend(reader.until("the link back", Duration::from_secs(15), live));
    all.extend(reader.collect_for(Duration::from_millis(300)));
    check_all(&all, &scenario);
}

#[test]
fn garbage_and_bit_flips_are_counted_without_losing_the_link() {
    let (_daemon, reader, scenario) = start(
        "garbage",
        "[faults]\nchunk_max_bytes = 7\n\
         [[faults.event]]\nat_s = 1.0\nkind = \"garbage_burst\"\nbytes = 200\n\
         [[faults.event]]\nat_s = 1.5\nkind = \"bit_flips\"\ncount = 5\n\
         [[faults.event]]\nat_s = 2.0\nkind = \"garbage_burst\"\nbytes = 300\n",
    );
    let mut all = reader.until("a live link", Duration::from_secs(10), live);
    all.extend(reader.until(
        "CRC errors and resyncs counted",
        Duration::from_secs(10),
        |s| s.link_crc_errors >= 5 && s.link_resyncs >= 1 && s.sim_time_s > 3.0,
    ));
    check_all(&all, &scenario);
    let last = *all.last().unwrap();
    assert_eq!(last.link_reconnects, 0, "garbage must not cost a reconnect");
    // Corrupted frames lose at most a few samples (4 ms each): far below the 100 ms timeout, so
    // the simulation never left the live inputs after the link came up.
    let first_live = all.iter().position(live).unwrap();
    let left = all[first_live..].iter().find(|s| !live(s));
    assert!(left.is_none(), "left the live state on garbage: {left:?}");
}

#[test]
fn a_rig_with_another_protocol_version_is_incompatible_and_accepted_once_it_speaks_v1() {
    // The first three hellos are answered as protocol v2, then the device behaves.
    let (_daemon, reader, scenario) = start(
        "version",
        "[faults]\n[[faults.event]]\nat_s = 0.0\nkind = \"wrong_version\"\ncount = 3\n",
    );
    let mut all = reader.until("the link incompatible", Duration::from_secs(10), |s| {
        s.link_state == link_state::INCOMPATIBLE
    });
    let bad = *all.last().unwrap();
    assert_ne!(bad.alarm_bits & alarms::RIG_INCOMPATIBLE, 0);
    assert_eq!(bad.safe_state, 1);
    assert_eq!(
        bad.link_frames, 0,
        "no sample accepted from an incompatible device"
    );
    all.extend(reader.until("a live link", Duration::from_secs(30), live));
    all.extend(reader.collect_for(Duration::from_millis(300)));
    check_all(&all, &scenario);
    assert!(all
        .iter()
        .filter(|s| s.link_state == link_state::INCOMPATIBLE)
        .all(|s| s.safe_state == 1));
}

#[test]
fn scenario_faults_fire_once_through_the_daemon_as_through_the_standalone_emulator() {
    // One fault report and one run of 10 dropped samples, both after the host has connected.
    let dir = temp_dir("once");
    let path = scenario_file(
        &dir,
        "[faults]\n\
         [[faults.event]]\nat_s = 1.5\nkind = \"fault_report\"\ncode = 7\n\
         [[faults.event]]\nat_s = 2.0\nkind = \"drop_frames\"\ncount = 10\n",
    );
    let path = path.to_str().unwrap();

    // The standalone emulator (`hydrometra rig emulate`) read by `hydrometra rig probe`.
    let link = dir.join("rig");
    let link_arg = link.to_str().unwrap();
    let mut emulator = Command::new(binary("hydrometra"))
        .args(["rig", "emulate", "--scenario", path, "--link", link_arg])
        .args(["--seconds", "8"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("spawn hydrometra rig emulate");
    let deadline = Instant::now() + Duration::from_secs(5);
    while !link.exists() {
        assert!(
            Instant::now() < deadline,
            "the emulator never created {link_arg}"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    let probe = hydrometra(&[
        "rig",
        "probe",
        "--device",
        link_arg,
        "--seconds",
        "4",
        "--json",
    ]);
    let _ = emulator.kill();
    let _ = emulator.wait();
    let probe: serde_json::Value = serde_json::from_str(&probe).expect("probe JSON");
    let counters = &probe["counters"];
    let standalone = (
        counters["device_faults"].as_u64().expect("device_faults"),
        counters["sequence_gaps"].as_u64().expect("sequence_gaps"),
    );
    assert_eq!(standalone, (1, 10), "standalone emulator: {probe}");

    // The daemon's in-process emulated rig playing the same file.
    let prefix = unique_prefix("once");
    let _daemon = Daemon::start(&prefix, &["--emulated", path]);
    let reader = StatusReader::connect(&prefix, Duration::from_secs(10));
    let all = reader.until("4 s of simulation", Duration::from_secs(20), |s| {
        s.sim_time_s > 4.0
    });
    let last = all.last().unwrap();
    assert_eq!(
        (last.link_device_faults, last.link_sequence_gaps),
        standalone,
        "daemon counters differ from the standalone emulator's: {last:?}"
    );
}
