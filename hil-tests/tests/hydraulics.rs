//! The hydraulics stage end to end on the built-in default scenario: emulated rig -> hydrometrad ->
//! status subscriber. The cavity pressure rises when the inflow opens, the deficit grows during the
//! scripted perforation (with the rate alarm), the procedure terminates at the case's 300 ml limit
//! (~130 s into the scenario), the deficit survives kill -9 and a restart, and a reset request
//! starts a new procedure.

use std::time::Duration;

use hydrometra_hil_tests::*;
use hydrometra_ipc::hydraulic_flags::{ACTIVE, PERFORATED, PUMP_STOPPED, RESTORED};
use hydrometra_ipc::{alarms, Status};
use hydrometra_units::PA_PER_MMHG;

fn mmhg(s: &Status) -> f64 {
    s.cavity_pressure_pa / PA_PER_MMHG
}

fn ml(m3: f64) -> f64 {
    m3 * 1e6
}

fn last(v: Vec<Status>) -> Status {
    *v.last().expect("at least one status")
}

#[test]
fn default_scenario_distends_perforates_terminates_survives_a_crash_and_resets() {
    let dir = temp_dir("hydraulics");
    let record = dir.join("procedure.rec");
    let record_arg = record.to_str().expect("utf-8 temp path").to_string();
    let prefix = unique_prefix("hydraulics");
    let args = [
        "--emulated",
        "default",
        "--status-rate-hz",
        "100",
        "--procedure-record",
        &record_arg,
    ];
    let mut daemon = Daemon::start(&prefix, &args);
    let reader = StatusReader::connect(&prefix, Duration::from_secs(10));

    // Before the inflow opens (scenario t < 1 s: valves shut) the cavity is collapsed.
    let first = last(
        reader.until("a live hydraulic status", Duration::from_secs(10), |s| {
            s.safe_state == 0 && s.hydraulic_flags & ACTIVE != 0
        }),
    );
    assert!(
        first.valve_in_opening < 0.2,
        "inflow already open: {first:?}"
    );
    assert!(
        mmhg(&first) < 10.0,
        "cavity at {} mmHg before inflow",
        mmhg(&first)
    );
    assert_eq!(
        first.hydraulic_flags & RESTORED,
        0,
        "fresh record: nothing to restore"
    );

    // Inflow opens (t = 0..8 s): the cavity distends past wall separation (~40 mmHg).
    let distended = last(
        reader.until("distension above 60 mmHg", Duration::from_secs(20), |s| {
            mmhg(s) > 60.0
        }),
    );
    assert!(distended.valve_in_opening > 0.2 && distended.inflow_m3_per_s > 0.0);
    assert!(
        distended.deficit_m3 < 20e-6,
        "deficit {} ml before the perforation",
        ml(distended.deficit_m3)
    );

    // The scripted perforation at 75 s: pressure collapses, the deficit climbs, the rate alarm rises.
    let perforated = last(
        reader.until("the perforation", Duration::from_secs(90), |s| {
            s.hydraulic_flags & PERFORATED != 0
        }),
    );
    let before = perforated.deficit_m3;
    let during = last(
        reader.until("deficit +50 ml", Duration::from_secs(20), |s| {
            s.deficit_m3 > before + 50e-6
        }),
    );
    assert!(during.perforation_m3_per_s > 0.0);
    assert!(
        mmhg(&during) < 30.0,
        "perforated cavity at {} mmHg",
        mmhg(&during)
    );
    assert!(
        during.alarm_bits & alarms::DEFICIT_RATE != 0,
        "no rate alarm at {} ml/min",
        during.deficit_rate_m3_per_s * 6e7
    );

    // The case's 300 ml limit: terminated, pump stopped, inflow zero.
    let terminated = last(reader.until("termination", Duration::from_secs(90), |s| {
        s.alarm_bits & alarms::PROCEDURE_TERMINATED != 0
    }));
    assert!((ml(terminated.deficit_limit_m3) - 300.0).abs() < 1e-6);
    assert!(ml(terminated.deficit_m3) >= 300.0);
    assert!(terminated.alarm_bits & alarms::DEFICIT_LIMIT != 0);
    // The default three warning stages, each with its bit (docs/ipc.md, "Alarm bits").
    assert_eq!(terminated.deficit_warning_stage, 3);
    let stage_bits =
        alarms::DEFICIT_WARNING_50 | alarms::DEFICIT_WARNING_75 | alarms::DEFICIT_WARNING_90;
    assert_eq!(terminated.alarm_bits & stage_bits, stage_bits);
    assert_ne!(terminated.hydraulic_flags & PUMP_STOPPED, 0);
    let still = last(
        reader.until("the pump stopped", Duration::from_secs(2), |s| {
            s.inflow_m3_per_s == 0.0
        }),
    );
    assert!(
        still.alarm_bits & alarms::PROCEDURE_TERMINATED != 0,
        "latch released"
    );

    // Crash: kill -9, then a new daemon on the same record resumes the terminated procedure.
    std::thread::sleep(Duration::from_millis(500)); // at least two save intervals
    let saved = last(reader.until("a status", Duration::from_secs(2), |_| true));
    daemon.signal(libc::SIGKILL);
    daemon.wait_exit(Duration::from_secs(5)).expect("killed");
    drop(reader);
    let prefix2 = unique_prefix("hydraulics-restart");
    let _daemon2 = Daemon::start(&prefix2, &args);
    let reader = StatusReader::connect(&prefix2, Duration::from_secs(10));
    let restored = last(
        reader.until("the restored procedure", Duration::from_secs(10), |s| {
            s.hydraulic_flags & ACTIVE != 0
        }),
    );
    assert_ne!(restored.hydraulic_flags & RESTORED, 0);
    assert_eq!(restored.procedure_id, saved.procedure_id);
    assert!(restored.alarm_bits & alarms::PROCEDURE_TERMINATED != 0);
    assert!(
        (restored.deficit_m3 - saved.deficit_m3).abs() < 1e-6,
        "deficit {} ml before the crash, {} ml after",
        ml(saved.deficit_m3),
        ml(restored.deficit_m3)
    );
    assert!(restored.fluid_in_m3 >= saved.fluid_in_m3 - 1e-9);

    // Reset: `hydrometra procedure reset` starts a new procedure within the save interval.
    hydrometra(&["procedure", "reset", "--record", &record_arg]);
    let fresh = last(
        reader.until("a new procedure", Duration::from_secs(5), |s| {
            s.procedure_id != saved.procedure_id
        }),
    );
    assert!(
        fresh.deficit_m3 < 1e-6,
        "deficit {} ml after reset",
        ml(fresh.deficit_m3)
    );
    assert_eq!(fresh.alarm_bits & alarms::PROCEDURE_TERMINATED, 0);
    assert_eq!(
        fresh.hydraulic_flags & (PERFORATED | PUMP_STOPPED | RESTORED),
        0
    );
    let _ = std::fs::remove_dir_all(&dir);
}
