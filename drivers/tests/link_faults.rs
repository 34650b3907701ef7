//! End to end: the emulated rig goes through every fault it can inject while the transport keeps
//! (or regains) the link; counters, state transitions and the calibrated state are checked.

use std::time::{Duration, Instant};

use hydrometra_drivers::calibration::{Calibration, PA_PER_MMHG};
use hydrometra_drivers::emulator::{EmulatedRig, EmulatorOptions, Fault, Scenario};
use hydrometra_drivers::state::{LinkCounters, LinkState};
use hydrometra_drivers::transport::{DeviceTarget, LinkConfig, LinkSnapshot, RigLink};

/// A calibrated rig whose tracker frame is rotated and shifted against the organ frame, so the
/// test exercises the full calibration in both directions.
const CALIBRATION: &str = r#"
calibration_id = 42
[valve_in]
raw_closed = 3900
raw_open = 150
[valve_out]
raw_closed = 300
raw_open = 3800
[pump]
raw_zero = 100
raw_full_scale = 4000
full_scale_mmhg = 150.0
[tracker]
rotation_wxyz = [0.9238795325112867, 0.0, 0.3826834323650898, 0.0]
translation_mm = [-120.0, 40.0, 300.0]
tip_offset_mm = [0.0, 0.0, 180.0]
"#;

struct Harness {
    rig: EmulatedRig,
    link: RigLink,
    scenario: Scenario,
    calibration: Calibration,
}

impl Harness {
    /// Polls the snapshot every 2 ms until `done` holds; returns the distinct link states seen.
    fn wait_for(
        &self,
        what: &str,
        timeout: Duration,
        done: impl Fn(&LinkSnapshot) -> bool,
    ) -> (LinkSnapshot, Vec<LinkState>) {
        let deadline = Instant::now() + timeout;
        let mut states: Vec<LinkState> = Vec::new();
        loop {
            let snap = self.link.snapshot();
            if states.last() != Some(&snap.link_state) {
                states.push(snap.link_state);
            }
            if done(&snap) {
                return (snap, states);
            }
            assert!(
                Instant::now() < deadline,
                "timed out waiting for {what}; states {states:?}; last {snap:?}; emulator {:?}",
                self.rig.stats()
            );
            std::thread::sleep(Duration::from_millis(2));
        }
    }

    /// Waits for `n` more frames and checks the newest sample against the scenario.
    fn flowing(&self, what: &str, n: u64) -> LinkSnapshot {
        let start = self.link.snapshot().counters.frames;
        let (snap, _) = self.wait_for(what, Duration::from_secs(5), |s| {
            s.counters.frames >= start + n && s.link_state == LinkState::Connected
        });
        self.assert_matches_scenario(&snap);
        snap
    }

    fn assert_matches_scenario(&self, snap: &LinkSnapshot) {
        let s = snap.latest.expect("a sample");
        let e = self.scenario.sample_at(s.device_time_us as f64 * 1e-6);
        // Quantisation of the 12-bit channels: one count of each calibrated span.
        let valve_in_step = 1.0 / 3750.0;
        let valve_out_step = 1.0 / 3500.0;
        let pump_step_pa = 150.0 * PA_PER_MMHG / 3900.0;
        assert!(
            (s.valve_in_opening - e.valve_in).abs() <= valve_in_step,
            "{s:?} vs {e:?}"
        );
        assert!(
            (s.valve_out_opening - e.valve_out).abs() <= valve_out_step,
            "{s:?} vs {e:?}"
        );
        assert!((s.pump_set_pressure_pa - e.pump_mmhg * PA_PER_MMHG).abs() <= pump_step_pa);
        // f32 on the wire at ~400 mm from the tracker origin: ~5e-5 mm; allow 1e-3 mm.
        for i in 0..3 {
            assert!(
                (s.scope.tip_position_m[i] - e.tip_mm[i] * 1e-3).abs() < 1e-6,
                "{s:?}"
            );
            assert!(
                (s.scope.view_direction[i] - e.view_dir[i]).abs() < 1e-5,
                "{s:?}"
            );
        }
        assert!(s.scope.valid);
    }
}

fn delta(a: &LinkCounters, b: &LinkCounters) -> LinkCounters {
    LinkCounters {
        frames: b.frames - a.frames,
        crc_errors: b.crc_errors - a.crc_errors,
        malformed: b.malformed - a.malformed,
        sequence_gaps: b.sequence_gaps - a.sequence_gaps,
        resyncs: b.resyncs - a.resyncs,
        reconnects: b.reconnects - a.reconnects,
        clamped_values: b.clamped_values - a.clamped_values,
        device_faults: b.device_faults - a.device_faults,
    }
}

#[test]
fn transport_recovers_from_every_injected_fault() {
    let calibration = Calibration::from_toml_str(CALIBRATION, "test calibration").unwrap();
    let scenario = Scenario::builtin("default").unwrap();
    let options = EmulatorOptions {
        calibration: calibration.clone(),
        ..EmulatorOptions::default()
    };
    let rig = EmulatedRig::start(scenario.clone(), options).unwrap();
    let link = RigLink::spawn(LinkConfig::new(
        DeviceTarget::Path(rig.device_path().to_path_buf()),
        calibration.clone(),
    ))
    .unwrap();
    let h = Harness {
        rig,
        link,
        scenario,
        calibration,
    };
    let (_, states) = h.wait_for("first connection", Duration::from_secs(5), |s| {
        s.link_state == LinkState::Connected && s.latest.is_some()
    });
    assert_eq!(states.last(), Some(&LinkState::Connected));
    let base = h.flowing("initial samples", 50);
    assert_eq!(base.device.as_ref().unwrap().calibration_id, 42);
    assert_eq!(base.counters.crc_errors + base.counters.malformed, 0);
    assert_eq!(base.counters.clamped_values, 0);
    let _ = &h.calibration;

    // Byte chunking: frames split in 1..=3-byte writes lose nothing.
    h.rig.inject(Fault::Chunking { max_bytes: 3 });
    let before = h.link.snapshot().counters;
    let after = h.flowing("chunked frames", 100).counters;
    h.rig.inject(Fault::Chunking { max_bytes: 0 });
    let d = delta(&before, &after);
    assert_eq!(
        (d.crc_errors, d.malformed, d.sequence_gaps, d.reconnects),
        (0, 0, 0, 0),
        "{d:?}"
    );

    // Garbage burst: rejected, counted, one recovery, and no valid frame lost (leading delimiter).
    let before = h.link.snapshot().counters;
    h.rig.inject(Fault::GarbageBurst { bytes: 300 });
    let (_, _) = h.wait_for("garbage garbage_bytes", Duration::from_secs(2), |_| {
        h.rig.stats().garbage_bytes >= 300
    });
    let after = h.flowing("frames after garbage", 20).counters;
    let d = delta(&before, &after);
    assert!(d.crc_errors + d.malformed >= 1, "{d:?}");
    assert_eq!(d.resyncs, 1, "{d:?}");
    assert_eq!((d.sequence_gaps, d.reconnects), (0, 0), "{d:?}");

    // Bit flips: each corrupted frame is exactly one CRC error and one missing sequence number.
    let before = h.link.snapshot().counters;
    h.rig.inject(Fault::BitFlips { count: 5 });
    h.wait_for("5 corrupted frames", Duration::from_secs(2), |_| {
        h.rig.stats().frames_corrupted >= 5
    });
    let after = h.flowing("frames after bit flips", 20).counters;
    let d = delta(&before, &after);
    assert_eq!(
        (d.crc_errors, d.malformed, d.sequence_gaps),
        (5, 0, 5),
        "{d:?}"
    );
    assert!((1..=5).contains(&d.resyncs), "{d:?}");

    // Dropped frames: counted as sequence gaps only.
    let before = h.link.snapshot().counters;
    h.rig.inject(Fault::DropFrames { count: 7 });
    h.wait_for("7 dropped frames", Duration::from_secs(2), |_| {
        h.rig.stats().frames_dropped >= 7
    });
    let after = h.flowing("frames after drops", 20).counters;
    let d = delta(&before, &after);
    assert_eq!(
        (d.crc_errors, d.malformed, d.sequence_gaps, d.reconnects),
        (0, 0, 7, 0),
        "{d:?}"
    );

    // Device fault report.
    h.rig.inject(Fault::FaultReport {
        code: 3,
        severity: 2,
        detail: 99,
    });
    h.wait_for("device fault counted", Duration::from_secs(2), |s| {
        s.counters.device_faults == 1
    });

    // Heartbeat stop (hung firmware, port open): Stale after 100 ms, dropped after 1 s,
    // reconnected with a fresh handshake once the firmware answers again.
    let before = h.link.snapshot().counters;
    let handshakes = h.rig.stats().handshakes;
    h.rig.inject(Fault::HeartbeatStop {
        duration: Duration::from_millis(1500),
    });
    let t0 = Instant::now();
    let (_, states) = h.wait_for("stale", Duration::from_secs(1), |s| {
        s.link_state == LinkState::Stale
    });
    let stale_after = t0.elapsed();
    assert!(
        stale_after >= Duration::from_millis(90),
        "stale after {stale_after:?}"
    );
    eprintln!("stale reported {stale_after:?} after the hang began");
    assert_eq!(states.first(), Some(&LinkState::Connected));
    let (snap, states2) = h.wait_for("reconnect after hang", Duration::from_secs(6), |s| {
        s.counters.reconnects == before.reconnects + 1 && s.link_state == LinkState::Connected
    });
    // Stale -> (port dropped after 1 s) Disconnected/Handshaking ... -> Connected, in that order.
    assert_eq!(states, vec![LinkState::Connected, LinkState::Stale]);
    assert_eq!(states2.first(), Some(&LinkState::Stale), "{states2:?}");
    assert_eq!(states2.last(), Some(&LinkState::Connected), "{states2:?}");
    assert!(states2.contains(&LinkState::Handshaking), "{states2:?}");
    assert!(
        !states2[..states2.len() - 1].contains(&LinkState::Connected),
        "no early reconnect while the firmware hangs: {states2:?}"
    );
    assert!(h.rig.stats().handshakes > handshakes);
    h.assert_matches_scenario(&snap);
    h.flowing("samples after hang", 20);

    // Unplug and replug: disconnect detected, no busy loop while the device is gone, reconnect.
    let before = h.link.snapshot().counters;
    h.rig.inject(Fault::Unplug {
        duration: Duration::from_millis(1200),
    });
    let t0 = Instant::now();
    h.wait_for("disconnect", Duration::from_secs(2), |s| {
        s.link_state == LinkState::Disconnected
    });
    let detect = t0.elapsed();
    assert!(
        detect < Duration::from_millis(200),
        "unplug detected after {detect:?}"
    );
    let cpu0 = h.link.io_thread_cpu_time();
    assert!(
        cpu0 > Duration::ZERO,
        "the CPU-time probe must work on this platform"
    );
    std::thread::sleep(Duration::from_millis(800));
    let cpu1 = h.link.io_thread_cpu_time();
    eprintln!(
        "unplug detected after {detect:?}; I/O thread CPU over 800 ms unplugged: {:?}",
        cpu1 - cpu0
    );
    assert!(
        h.rig.stats().replugs == 0,
        "replugged too early for the CPU measurement"
    );
    // A busy loop would burn ~800 ms; backoff sleeps cost a few hundred microseconds.
    assert!(
        cpu1 - cpu0 < Duration::from_millis(40),
        "I/O thread used {:?} while unplugged",
        cpu1 - cpu0
    );
    let (snap, _) = h.wait_for("reconnect after replug", Duration::from_secs(6), |s| {
        s.counters.reconnects == before.reconnects + 1 && s.link_state == LinkState::Connected
    });
    h.assert_matches_scenario(&snap);
    h.flowing("samples after replug", 20);

    // Wrong protocol version on the next two handshakes: Incompatible, then connected again.
    let before = h.link.snapshot().counters;
    h.rig.inject(Fault::WrongVersion { count: 2 });
    h.rig.inject(Fault::Unplug {
        duration: Duration::from_millis(100),
    });
    let (snap, states) = h.wait_for(
        "reconnect after wrong version",
        Duration::from_secs(8),
        |s| s.counters.reconnects == before.reconnects + 1 && s.link_state == LinkState::Connected,
    );
    assert!(states.contains(&LinkState::Incompatible), "{states:?}");
    assert_eq!(h.rig.stats().wrong_version_hellos, 2);
    h.assert_matches_scenario(&snap);
    let end = h.flowing("samples after wrong version", 20);

    // Totals agree with what the emulator injected.
    let st = h.rig.stats();
    assert_eq!(st.frames_corrupted, 5);
    assert_eq!(st.frames_dropped, 7);
    assert_eq!(end.counters.reconnects, 3);
    assert_eq!(end.counters.clamped_values, 0);
    let Harness { rig, link, .. } = h;
    link.shutdown();
    rig.stop();
}
