//! The 1 kHz loop under the heaviest built-in scene (`bleed`: vortices, bubbles and a bleed's
//! particles at the default voxel size): it never starves. Emulated rig -> `hydrometrad` -> a
//! status subscriber and a positions subscriber, as a renderer would read them.

use std::time::{Duration, Instant};

use hydrometra_hil_tests::host::HostWatch;
use hydrometra_hil_tests::{unique_prefix, Daemon, StatusReader};
use hydrometra_ipc::mesh::MeshPositionsHeader;
use hydrometra_ipc::status::{realtime_mode, scene_state};
use hydrometra_ipc::{slice, ServiceNames};

/// Seconds the loop is measured once the scene runs (the figure).
const MEASURED_S: u64 = 60;

/// Deadline misses at most this share of the ticks, and no two consecutive statuses further
/// apart than `MAX_GAP_S` (docs/daemon.md, "Real-time scheduling"; product target: <= 0.1 %,
/// <= 5 ms on the slower 2-core machine).
const MAX_MISS_SHARE: f64 = 0.001;
const MAX_GAP_S: f64 = 0.005;

/// The targets are judged on the stretches in which the machine kept no `SCHED_FIFO` thread off
/// the loop's CPU (`hydrometra_hil_tests::host`); at least this share of the ticks must be left.
const MIN_JUDGED_SHARE: f64 = 0.5;

/// Where the machine took nothing, the loop ticks at 1 kHz: at least this share of the judged
/// stretches' milliseconds are ticks (the publish stamps' jitter is microseconds a pair). Not
/// over the whole run: the periods a stall of the machine spans are skipped, not replayed
/// (docs/daemon.md, "skipped ticks are covered, not replayed"), so the raw count falls with the
/// machine's stalls.
const MIN_TICK_RATE_SHARE: f64 = 0.99;

#[test]
fn the_loop_keeps_its_deadlines_under_the_heaviest_scene_and_frames_are_never_republished() {
    let prefix = unique_prefix("rt-heavy");
    let daemon = Daemon::start(
        &prefix,
        &["--emulated", "default", "--scene", "bleed", "--no-record"],
    );
    let reader = StatusReader::connect(&prefix, Duration::from_secs(20));
    reader.until("the scene running", Duration::from_secs(180), |s| {
        s.scene_state == scene_state::RUNNING || s.scene_state == scene_state::IDLE
    });
    // A renderer's positions subscriber, read while the statuses are collected.
    let names = ServiceNames::new(&prefix).expect("prefix");
    let positions = slice::open::<slice::Positions, _>(&reader.node, &names)
        .expect("positions service")
        .subscriber_builder()
        .create()
        .expect("positions subscriber");
    let mut frames: Vec<MeshPositionsHeader> = Vec::new();
    let mut statuses = Vec::new();
    let host = HostWatch::start();
    let started = Instant::now();
    while started.elapsed() < Duration::from_secs(MEASURED_S) {
        statuses.extend(reader.drain());
        while let Some(sample) = positions.receive().expect("receive positions") {
            frames.push(*sample.user_header());
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    statuses.extend(reader.drain());
    let (first, last) = (statuses[0], *statuses.last().expect("statuses"));
    let ticks = last.ticks - first.ticks;
    let misses = last.deadline_misses - first.deadline_misses;
    // Each pair of consecutive statuses (where the subscriber has both: it reads every 2 ms into a
    // 64-deep buffer, a gap in its own reading is not the daemon's): its gap, ticks and misses,
    // judged where the machine took nothing from the loop's CPU.
    let record = host.judge(&statuses);
    let (judged_ticks, judged_misses) = (record.judged_ticks, record.judged_misses);
    let (gap_max_s, gap_all_s) = (record.judged_gap_max_s, record.gap_max_s);
    let late = last.scene_frames_late - first.scene_frames_late;
    eprintln!(
        "{MEASURED_S} s under the `bleed` scene ({}): ticks {ticks}, deadline misses {misses} \
         ({:.4} %), longest gap between statuses {:.3} ms over {} consecutive pairs of {} \
         statuses; judged where the machine took nothing from the loop's CPU: {judged_ticks} \
         ticks in {:.3} s, {judged_misses} misses ({:.4} %), longest gap {:.3} ms; scene frames {}, late \
         {late}, degradation level {}, particles stage runs {}; {}",
        realtime_mode::name(last.realtime_mode),
        100.0 * misses as f64 / ticks as f64,
        gap_all_s * 1e3,
        record.pairs,
        statuses.len(),
        record.judged_s,
        100.0 * judged_misses as f64 / judged_ticks.max(1) as f64,
        gap_max_s * 1e3,
        last.scene_frames - first.scene_frames,
        last.scene_degradation,
        last.scene_stage_runs[6] - first.scene_stage_runs[6],
        host.summary(),
    );
    assert!(
        record.pairs as f64 >= 0.95 * statuses.len() as f64,
        "the subscriber missed too many statuses to measure gaps: {} pairs of {}",
        record.pairs,
        statuses.len()
    );
    assert!(
        judged_ticks as f64 >= MIN_TICK_RATE_SHARE * 1e3 * record.judged_s,
        "{judged_ticks} ticks in the {:.3} s where the machine took nothing: the loop starved \
         ({})",
        record.judged_s,
        host.summary()
    );
    assert!(
        judged_ticks as f64 >= MIN_JUDGED_SHARE * ticks as f64,
        "the machine took the loop's CPU in all but {judged_ticks} of {ticks} ticks: too little \
         left to judge the daemon ({})",
        host.summary()
    );
    assert!(
        judged_misses as f64 <= MAX_MISS_SHARE * judged_ticks as f64,
        "deadline misses {judged_misses} of {judged_ticks} ticks while the machine took nothing \
         ({}):\n{}",
        host.summary(),
        daemon.log()
    );
    assert!(
        gap_max_s <= MAX_GAP_S,
        "two statuses {:.3} ms apart while the machine took nothing ({}):\n{}",
        gap_max_s * 1e3,
        host.summary(),
        daemon.log()
    );
    // The scene ran its heavy stages, and every positions frame is new: strictly increasing frame
    // numbers and scene time (a frame is never published twice).
    assert!(
        last.scene_stage_runs[6] > first.scene_stage_runs[6],
        "the particle stage never ran"
    );
    assert!(frames.len() > 100, "{} positions frames", frames.len());
    for w in frames.windows(2) {
        assert!(
            w[1].scene_frame > w[0].scene_frame && w[1].sim_time_s > w[0].sim_time_s,
            "positions frame republished or out of order: {:?} then {:?}",
            w[0],
            w[1]
        );
    }
}

/// Without the privilege (no `CAP_SYS_NICE`, `RLIMIT_RTPRIO` and `RLIMIT_NICE` 0) the daemon says
/// once that it runs degraded and how to grant the privilege, publishes the mode in status, and
/// runs the loop as before.
#[test]
fn without_the_privilege_the_daemon_states_the_degraded_mode_and_runs_on_where_available() {
    let prefix = unique_prefix("rt-unpriv");
    let daemon = Daemon::start_unprivileged(&prefix, &["--emulated", "default"]);
    let reader = StatusReader::connect(&prefix, Duration::from_secs(20));
    let first = *reader
        .until("a status", Duration::from_secs(20), |_| true)
        .last()
        .expect("a status");
    if first.realtime_mode == realtime_mode::FIFO {
        println!(
            "SKIP without_the_privilege_the_daemon_states_the_degraded_mode_and_runs_on_where_available: \
             the child kept CAP_SYS_NICE (no CAP_SETPCAP to drop it)"
        );
        return;
    }
    assert_eq!(
        first.realtime_mode,
        realtime_mode::NORMAL,
        "no privilege: normal scheduling ({})",
        realtime_mode::name(first.realtime_mode)
    );
    std::thread::sleep(Duration::from_secs(2));
    let statuses = reader.drain();
    let last = *statuses.last().expect("statuses");
    assert!(
        last.ticks - first.ticks >= 1_800,
        "{} ticks in 2 s",
        last.ticks - first.ticks
    );
    let stated = daemon.log_lines_with("degraded real-time mode");
    assert_eq!(stated.len(), 1, "said once:\n{}", daemon.log());
    for needed in [
        "SCHED_FIFO priority 10 refused",
        "LimitRTPRIO=10",
        "ulimit -r 10",
    ] {
        assert!(
            stated[0].contains(needed),
            "{needed:?} missing from: {}",
            stated[0]
        );
    }
}
