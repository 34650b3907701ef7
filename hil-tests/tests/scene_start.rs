//! The cavity pressure when the scene's atlas arrives: the 1 kHz hydraulics run on the
//! parameters' compliance curve while the scene prepares, then on the atlas's P-V curve; status
//! must show one continuous, physical pressure through the swap (issue: the pressure jumped from
//! +4.6 to -21.4 mmHg in one tick and stayed negative for 1.6 s).

use std::time::Duration;

use hydrometra_hil_tests::{assert_contiguous, unique_prefix, Daemon, StatusReader};
use hydrometra_ipc::status::scene_state;
use hydrometra_sim::units::pa_to_mmhg;

/// The largest change of the cavity pressure between two statuses 1 ms apart that the
/// hydraulics can produce in this scenario's first seconds (the inflow valve opening towards
/// the pump's 90 mmHg), with margin: a swap of curves under the cavity's volume was 26 mmHg.
const MAX_STEP_MMHG: f64 = 1.0;

#[test]
fn the_cavity_pressure_stays_continuous_and_physical_when_the_atlas_arrives() {
    let prefix = unique_prefix("scene-start");
    let daemon = Daemon::start(
        &prefix,
        &[
            "--emulated",
            "default",
            "--scene",
            "default",
            "--no-record",
            "--new-procedure",
        ],
    );
    let reader = StatusReader::connect(&prefix, Duration::from_secs(20));
    let mut statuses = reader.until("the scene ready", Duration::from_secs(180), |s| {
        s.scene_state == scene_state::RUNNING || s.scene_state == scene_state::IDLE
    });
    statuses.extend(reader.collect_for(Duration::from_secs(3)));
    let ready = statuses
        .iter()
        .position(|s| s.scene_state == scene_state::RUNNING || s.scene_state == scene_state::IDLE)
        .expect("the scene became ready");
    assert!(
        statuses[..ready]
            .iter()
            .any(|s| s.scene_state == scene_state::PREPARING),
        "no status while the scene prepared: the swap was not observed"
    );
    // Contiguous around the swap, so every tick-to-tick step is seen.
    let around = &statuses[ready.saturating_sub(500)..(ready + 2000).min(statuses.len())];
    assert_contiguous(around);
    let mut worst_step = 0.0f64;
    for w in statuses.windows(2) {
        if w[1].sequence != w[0].sequence + 1 {
            continue;
        }
        let (a, b) = (
            pa_to_mmhg(w[0].cavity_pressure_pa),
            pa_to_mmhg(w[1].cavity_pressure_pa),
        );
        worst_step = worst_step.max((b - a).abs());
        assert!(
            (b - a).abs() <= MAX_STEP_MMHG,
            "cavity pressure jumps {a:.2} -> {b:.2} mmHg between statuses {} and {} (scene \
             state {} -> {}):\n{}",
            w[0].sequence,
            w[1].sequence,
            w[0].scene_state,
            w[1].scene_state,
            daemon.log()
        );
    }
    // Physical: the outflow is closed and the pump pushes; leak and absorption only drain
    // towards 0, so the gauge pressure never goes below it.
    let lowest = statuses
        .iter()
        .map(|s| pa_to_mmhg(s.cavity_pressure_pa))
        .fold(f64::INFINITY, f64::min);
    assert!(lowest >= -0.01, "cavity pressure down to {lowest:.3} mmHg");
    let at = &statuses[ready];
    eprintln!(
        "atlas arrived at status {} ({:.2} s): {:.3} mmHg, {:.4} ml; largest step between \
         statuses {worst_step:.4} mmHg, lowest pressure {lowest:.3} mmHg over {} statuses",
        at.sequence,
        at.sim_time_s,
        pa_to_mmhg(at.cavity_pressure_pa),
        at.cavity_volume_m3 * 1e6,
        statuses.len()
    );
}
