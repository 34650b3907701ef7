//! Procedure recordings (docs/recording.md, docs/debrief.md): record -> replay round trip through
//! the real link, a kill -9 while recording, the Python `mcap` reader, and the debrief's metrics on
//! a procedure whose answers are derived by hand.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use hydrometra_drivers::calibration::Calibration;
use hydrometra_drivers::emulator::{EmulatedRig, EmulatorOptions, Scenario};
use hydrometra_drivers::framing::FrameDecoder;
use hydrometra_drivers::state::RigState;
use hydrometra_drivers::transport::{monotonic_ns, DeviceTarget, LinkConfig, RigLink};
use hydrometra_drivers::wire::Message;
use hydrometra_ipc::{alarms, Status};
use hydrometra_record::debrief::{self, DebriefSettings};
use hydrometra_record::reader::Recording;
use hydrometra_record::recorder::{RecorderHandle, RecorderSettings, RecorderTaps};

fn temp_dir(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!(
        "hydrometra-rec-{tag}-{}-{}",
        std::process::id(),
        monotonic_ns()
    ));
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

fn recorder(dir: &Path) -> (RecorderHandle, RecorderTaps) {
    RecorderHandle::spawn(
        RecorderSettings {
            dir: dir.to_path_buf(),
            start_recording: true,
            flush_interval: Duration::from_millis(200),
            metadata: Default::default(),
        },
        1,
    )
    .expect("recorder")
}

/// The only .mcap file in `dir`.
fn only_recording(dir: &Path) -> PathBuf {
    let files: Vec<PathBuf> = std::fs::read_dir(dir)
        .expect("read dir")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "mcap"))
        .collect();
    assert_eq!(files.len(), 1, "recordings in {}: {files:?}", dir.display());
    files[0].clone()
}

/// The calibrated samples the host's link derives from the recorded bytes: the recorded reads go
/// through the same decoder and calibration, from the first device hello on (as the transport
/// does). `received_at` is one fixed instant so that only recorded content is compared.
fn calibrated_samples(rec: &Recording, calibration: &Calibration, now: Instant) -> Vec<RigState> {
    let mut decoder = FrameDecoder::new();
    let mut established = false;
    let mut out: Vec<RigState> = Vec::new();
    for r in &rec.rx {
        let mut frames = Vec::new();
        decoder.push_slice(&r.bytes, |f| frames.push(f));
        for frame in frames.into_iter().flatten() {
            match frame.message {
                Message::DeviceHello(_) => established = true,
                Message::Sample(s) if established => {
                    let state = calibration.apply(&s, frame.sequence, now, out.last()).state;
                    out.push(state);
                }
                _ => {}
            }
        }
    }
    out
}

/// Feeds a status every 50 ms so the recorder opens its file and keeps it (it is named after the
/// status's procedure); returns when `done` says so.
fn feed_statuses(taps: &mut RecorderTaps, until: impl Fn() -> bool, timeout: Duration) {
    let started = Instant::now();
    let mut seq = 0;
    while !until() && started.elapsed() < timeout {
        let s = Status {
            sequence: seq,
            procedure_id: 7,
            publish_monotonic_ns: monotonic_ns(),
            ..Status::default()
        };
        taps.status.offer(&s);
        seq += 1;
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn record_then_replay_through_the_real_link_gives_the_same_calibrated_samples() {
    let calibration = Calibration::default();
    // 1. Record 2.5 s of the default scenario through the real link.
    let dir1 = temp_dir("rt1");
    let (rec1, mut taps1) = recorder(&dir1);
    let scenario = Scenario::builtin("default").expect("built-in scenario");
    let rig = EmulatedRig::start(scenario, EmulatorOptions::default()).expect("emulator");
    let mut cfg = LinkConfig::new(
        DeviceTarget::Path(rig.device_path().to_path_buf()),
        calibration.clone(),
    );
    cfg.rx_tap = Some(taps1.rx.clone());
    let link = RigLink::spawn(cfg).expect("link");
    let t0 = Instant::now();
    feed_statuses(
        &mut taps1,
        || t0.elapsed() > Duration::from_millis(2500),
        Duration::from_secs(10),
    );
    let live_first = link.snapshot();
    link.shutdown();
    rig.stop();
    let status1 = rec1.shutdown();
    assert_eq!(status1.rx_dropped, 0);
    let file1 = only_recording(&dir1);
    let recorded = Recording::load(&file1).expect("load recording 1");
    assert!(recorded.truncated.is_none(), "{:?}", recorded.truncated);
    let stamp = Instant::now();
    let samples1 = calibrated_samples(&recorded, &calibration, stamp);
    assert!(
        samples1.len() > 400,
        "2.5 s at 250 Hz should record > 400 samples, got {}",
        samples1.len()
    );
    // The live link's latest sample (taken while the link still ran) is in the recording, with
    // the same calibrated content.
    let live_last = live_first.latest.expect("live sample");
    let same = samples1
        .iter()
        .find(|s| s.sequence == live_last.sequence)
        .expect("the live link's latest sample was recorded");
    assert_eq!(
        RigState {
            received_at: same.received_at,
            ..live_last
        },
        *same
    );
    let rec_last = samples1.last().expect("recorded sample");

    // 2. Replay it as a live device into a fresh link, recording what that link reads.
    let dir2 = temp_dir("rt2");
    let (rec2, mut taps2) = recorder(&dir2);
    let replay = EmulatedRig::start_replay(recorded.replay_script(), 1.0, None).expect("replay");
    let mut cfg = LinkConfig::new(
        DeviceTarget::Path(replay.device_path().to_path_buf()),
        calibration.clone(),
    );
    cfg.rx_tap = Some(taps2.rx.clone());
    let link = RigLink::spawn(cfg).expect("link");
    feed_statuses(
        &mut taps2,
        || replay.stats().replay_done,
        Duration::from_secs(15),
    );
    assert!(replay.stats().replay_done, "the replay did not finish");
    // Let the link read the last bytes.
    std::thread::sleep(Duration::from_millis(100));
    let live = link.snapshot();
    link.shutdown();
    replay.stop();
    rec2.shutdown();
    let replayed = Recording::load(&only_recording(&dir2)).expect("load recording 2");
    let samples2 = calibrated_samples(&replayed, &calibration, stamp);
    assert_eq!(samples2.len(), samples1.len(), "sample count");
    for (i, (a, b)) in samples1.iter().zip(&samples2).enumerate() {
        assert_eq!(a, b, "calibrated sample {i} differs");
    }
    // What the replayed link itself holds at the end is the recording's last sample.
    let last = live.latest.expect("replayed link got samples");
    assert_eq!(last.sequence, rec_last.sequence);
    assert_eq!(last.pump_set_pressure_pa, rec_last.pump_set_pressure_pa);
    assert_eq!(last.scope, rec_last.scope);
    assert_eq!(live.counters.crc_errors, 0);
    let _ = std::fs::remove_dir_all(dir1);
    let _ = std::fs::remove_dir_all(dir2);
}

#[test]
fn kill_9_while_recording_leaves_a_readable_file_missing_at_most_the_last_second() {
    let dir = temp_dir("kill");
    let prefix = format!("hydrometra-test/rec-kill-{}", std::process::id());
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_hydrometrad"))
        // No scene: these tests are about the recorder, and a scene would build its atlas in
        // the background (minutes of CPU) and load the machine under the real-time loop.
        .args([
            "--emulated",
            "default",
            "--no-scene",
            "--service-prefix",
            &prefix,
            "--record-dir",
        ])
        .arg(&dir)
        .env("RUST_LOG", "warn")
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("spawn hydrometrad");
    // Record ~3 s of a running procedure.
    std::thread::sleep(Duration::from_secs(3));
    let killed_at_ns = monotonic_ns();
    child.kill().expect("SIGKILL");
    let _ = child.wait();
    let file = only_recording(&dir);
    let rec = Recording::load(&file).expect("the killed recording opens");
    assert!(
        rec.truncated.is_some(),
        "a killed recording has no summary; the reader should say where it stopped"
    );
    let (_, last) = rec.statuses.last().expect("statuses were recorded");
    let lost_s = killed_at_ns.saturating_sub(last.publish_monotonic_ns) as f64 * 1e-9;
    assert!(
        lost_s <= 1.0,
        "the last recorded status is {lost_s:.3} s older than the kill"
    );
    let last_rx = rec.rx.last().expect("rig bytes were recorded");
    let lost_rx_s = killed_at_ns.saturating_sub(last_rx.host_monotonic_ns) as f64 * 1e-9;
    assert!(lost_rx_s <= 1.0, "rig bytes: {lost_rx_s:.3} s lost");
    assert!(rec.statuses.len() > 100, "{} statuses", rec.statuses.len());
    let _ = std::fs::remove_dir_all(dir);
}

/// A procedure whose metrics are known by hand: 10 s at 100 statuses/s with a fixed inflow of
/// 300 ml/min and outflow of 240 ml/min, overpressure from 2 s to 5 s, the cavity at 50 mmHg from
/// 1 s to 8 s, a perforation from 6 s losing 60 ml/min, the inflow valve opened once (at 3 s), the
/// pump turned twice (at 4 s and 7 s), and the scope tip moving at 1 cm/s along x.
fn hand_procedure() -> Vec<Status> {
    let dt = 0.01;
    let n = 1001;
    let t0_ns = monotonic_ns();
    let ml = 1e-6;
    let per_min = 1.0 / 60.0;
    (0..n)
        .map(|i| {
            let t = i as f64 * dt;
            let q_in = 300.0 * ml * per_min;
            let q_out = 240.0 * ml * per_min;
            let perforated = t >= 6.0 - 1e-9;
            let mut alarm_bits = 0;
            if (2.0 - 1e-9..5.0 - 1e-9).contains(&t) {
                alarm_bits |= alarms::OVERPRESSURE;
            }
            Status {
                sequence: i,
                procedure_id: 42,
                publish_monotonic_ns: t0_ns + (t * 1e9).round() as u64,
                link_state: hydrometra_ipc::status::link_state::CONNECTED,
                fluid_in_m3: q_in * t,
                fluid_collected_m3: q_out * t,
                deficit_m3: (q_in - q_out) * t,
                deficit_rate_m3_per_s: q_in - q_out + if perforated { 1e-7 } else { 0.0 },
                deficit_limit_m3: 2500.0 * ml,
                cavity_pressure_pa: if (1.0 - 1e-9..8.0 - 1e-9).contains(&t) {
                    hydrometra_sim::units::mmhg_to_pa(50.0)
                } else {
                    0.0
                },
                alarm_bits,
                hydraulic_flags: 1 | if perforated { 1 << 1 } else { 0 },
                perforation_m3_per_s: if perforated { 60.0 * ml * per_min } else { 0.0 },
                rig_valve_in_opening: if t >= 3.0 - 1e-9 { 0.6 } else { 0.1 },
                rig_valve_out_opening: 0.3,
                rig_pump_set_pressure_pa: hydrometra_sim::units::mmhg_to_pa(if t >= 7.0 - 1e-9 {
                    80.0
                } else if t >= 4.0 - 1e-9 {
                    100.0
                } else {
                    60.0
                }),
                scope_pose_valid: 1,
                scope_tip_position_m: [0.01 * t, 0.02, 0.03],
                ..Status::default()
            }
        })
        .collect()
}

/// Records `statuses` through the recorder (every one, no decimation); returns the file.
fn record_statuses(dir: &Path, statuses: &[Status]) -> PathBuf {
    let (handle, mut taps) = recorder(dir);
    let mut refused = 0;
    for s in statuses {
        let deadline = Instant::now() + Duration::from_secs(5);
        while !taps.status.offer(s) {
            refused += 1;
            assert!(Instant::now() < deadline, "recorder not draining");
            std::thread::sleep(Duration::from_millis(5));
        }
    }
    let st = handle.shutdown();
    assert_eq!(
        st.status_dropped, refused,
        "every refused offer is counted as a drop"
    );
    only_recording(dir)
}

#[test]
fn debrief_metrics_match_a_procedure_derived_by_hand() {
    let dir = temp_dir("debrief");
    let statuses = hand_procedure();
    let file = record_statuses(&dir, &statuses);
    let rec = Recording::load(&file).expect("load");
    assert_eq!(rec.statuses.len(), statuses.len());
    let m = debrief::metrics(&rec, &DebriefSettings::default()).expect("metrics");
    let close = |what: &str, got: f64, want: f64, tol: f64| {
        assert!(
            (got - want).abs() <= tol,
            "{what}: got {got}, expected {want} (tolerance {tol})"
        );
    };
    // Volumes: 300 and 240 ml/min for 10 s (exact up to float rounding).
    close("duration", m.duration_s, 10.0, 1e-6);
    close("fluid in", m.fluid_in_ml, 50.0, 1e-9);
    close("collected", m.fluid_collected_ml, 40.0, 1e-9);
    close("deficit", m.deficit_ml, 10.0, 1e-9);
    close("deficit limit", m.deficit_limit_ml, 2500.0, 1e-9);
    close(
        "peak deficit rate",
        m.peak_deficit_rate_ml_per_min,
        60.0 + 6.0,
        1e-6,
    );
    close("peak rate at", m.peak_deficit_rate_at_s, 6.0, 1e-6);
    // Durations are left Riemann sums over 10 ms statuses: exact at these step times.
    close(
        "time above overpressure",
        m.time_above_overpressure_s,
        3.0,
        1e-6,
    );
    close("time distended", m.time_distended_s, 7.0, 1e-6);
    close("max pressure", m.max_cavity_pressure_mmhg, 50.0, 1e-9);
    assert_eq!(m.valve_in_adjustments, 1);
    assert_eq!(m.valve_out_adjustments, 0);
    assert_eq!(m.pump_adjustments, 2);
    assert!(m.perforation.occurred);
    close(
        "perforation at",
        m.perforation.at_s.unwrap_or(-1.0),
        6.0,
        1e-6,
    );
    close("perforation volume", m.perforation.volume_ml, 4.0, 1e-6);
    close("scope path", m.scope_path_length_m, 0.1, 1e-9);
    let overpressure: Vec<(f64, bool)> = m
        .alarms
        .iter()
        .filter(|a| a.name == "overpressure")
        .map(|a| (a.t_s, a.raised))
        .collect();
    assert_eq!(overpressure.len(), 2);
    close("overpressure raised", overpressure[0].0, 2.0, 1e-6);
    close("overpressure cleared", overpressure[1].0, 5.0, 1e-6);
    assert!(overpressure[0].1 && !overpressure[1].1);
    assert!(m.view.time_to_first_clear_view_s.is_none() && m.view.unavailable.is_some());
    // The report is written with its plots.
    let out = dir.join("out");
    debrief::write_report(&rec, &m, &out).expect("report");
    for f in [
        "metrics.json",
        "report.md",
        "pressure.svg",
        "flows.svg",
        "deficit.svg",
        "alarms.svg",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).expect("read"))
            .expect("metrics.json parses");
    assert_eq!(json["pump_adjustments"], 2);
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn python_mcap_reads_a_recording_and_decodes_status_with_the_ipc_md_layout() {
    let dir = temp_dir("python");
    let statuses = hand_procedure();
    let file = record_statuses(&dir, &statuses);
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let python = std::env::var("PYTHON").unwrap_or_else(|_| "python3".into());
    let out = std::process::Command::new(&python)
        .arg(root.join("record/examples/python/read_recording.py"))
        .arg(&file)
        .arg("--ipc-doc")
        .arg(root.join("docs/ipc.md"))
        .arg("--json")
        .output()
        .unwrap_or_else(|e| panic!("{python} is required for this test (.ci/setup): {e}"));
    assert!(
        out.status.success(),
        "reading the recording with the Python mcap package failed (pip install mcap; .ci/setup \
         installs it):\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON from Python");
    assert_eq!(v["profile"], "hydrometra");
    assert_eq!(v["channels"]["/status"], statuses.len());
    let last = statuses.last().expect("statuses");
    let py = &v["last_status"];
    assert_eq!(py["sequence"], last.sequence);
    assert_eq!(py["procedure_id"], last.procedure_id);
    assert_eq!(py["alarm_bits"], last.alarm_bits);
    assert_eq!(py["size_bytes"], std::mem::size_of::<Status>());
    for (name, want) in [
        ("deficit_m3", last.deficit_m3),
        ("fluid_in_m3", last.fluid_in_m3),
        ("rig_pump_set_pressure_pa", last.rig_pump_set_pressure_pa),
        ("perforation_m3_per_s", last.perforation_m3_per_s),
    ] {
        assert_eq!(py[name].as_f64(), Some(want), "{name}");
    }
    assert_eq!(
        py["scope_tip_position_m"][0].as_f64(),
        Some(last.scope_tip_position_m[0])
    );
    let _ = std::fs::remove_dir_all(dir);
}

/// Linear interpolation of `(t, v)` samples (sorted by t) at `t`.
fn interpolate(series: &[(f64, f64)], t: f64) -> Option<f64> {
    let i = series.partition_point(|p| p.0 < t);
    let (a, b) = (series.get(i.checked_sub(1)?)?, series.get(i)?);
    let w = if b.0 > a.0 {
        (t - a.0) / (b.0 - a.0)
    } else {
        0.0
    };
    Some(a.1 + w * (b.1 - a.1))
}

fn run_daemon(args: &[&str], record_dir: &Path, tag: &str) -> PathBuf {
    let prefix = format!("hydrometra-test/rec-{tag}-{}", std::process::id());
    let status = std::process::Command::new(env!("CARGO_BIN_EXE_hydrometrad"))
        .args(args)
        .args(["--no-scene", "--service-prefix", &prefix, "--record-dir"])
        .arg(record_dir)
        .env("RUST_LOG", "warn")
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::null())
        .status()
        .expect("run hydrometrad");
    assert!(status.success(), "hydrometrad {args:?} failed: {status}");
    only_recording(record_dir)
}

#[test]
fn hydrometrad_replay_reproduces_the_recorded_deficit_and_pressure_trajectory() {
    let (dir_a, dir_b) = (temp_dir("traj-a"), temp_dir("traj-b"));
    let recorded = run_daemon(&["--emulated", "default", "--duration", "12"], &dir_a, "a");
    let recorded_s = recorded.to_string_lossy().to_string();
    let replayed = run_daemon(
        &["--replay", &recorded_s, "--duration", "12.5"],
        &dir_b,
        "b",
    );
    let (a, b) = (
        Recording::load(&recorded).expect("recorded"),
        Recording::load(&replayed).expect("replayed"),
    );
    let series = |r: &Recording, f: fn(&Status) -> f64| -> Vec<(f64, f64)> {
        r.statuses
            .iter()
            .map(|(_, s)| (s.procedure_time_s, f(s)))
            .collect()
    };
    let pressure = |s: &Status| hydrometra_sim::units::pa_to_mmhg(s.cavity_pressure_pa);
    let deficit = |s: &Status| s.deficit_m3 * 1e6;
    let (pa, pb) = (series(&a, pressure), series(&b, pressure));
    let (da, db) = (series(&a, deficit), series(&b, deficit));
    // The worst differences with the replay's clock shifted by `shift` s.
    let compare = |shift: f64| {
        let (mut worst_p, mut worst_d, mut compared) = (0.0f64, 0.0f64, 0usize);
        for (&(t, p), &(_, d)) in pa.iter().zip(&da) {
            if t > 11.5 {
                break;
            }
            if let (Some(pb), Some(db)) = (interpolate(&pb, t + shift), interpolate(&db, t + shift))
            {
                worst_p = worst_p.max((p - pb).abs());
                worst_d = worst_d.max((d - db).abs());
                compared += 1;
            }
        }
        (worst_p, worst_d, compared)
    };
    // Tolerances (docs/recording.md): the replayed rig's first sample arrives some ms earlier or
    // later relative to the daemon's start than the recorded one did (handshake and scheduling
    // jitter, tens of ms on a loaded machine), which shifts the whole input history by that much.
    // That one shift is estimated (the one that best aligns the pressure, within 0.25 s, 1 ms
    // steps) and reported; the trajectories must then agree.
    let shift = (-250..=250)
        .map(|ms| ms as f64 * 1e-3)
        .min_by(|&a, &b| compare(a).0.total_cmp(&compare(b).0))
        .unwrap_or(0.0);
    let (worst_p, worst_d, compared) = compare(shift);
    let (unaligned_p, _, _) = compare(0.0);
    eprintln!(
        "replay vs recording over {compared} statuses: input shift {:.0} ms; |dp| max {worst_p:.3} mmHg \
         ({unaligned_p:.3} unaligned), |d deficit| max {worst_d:.3} ml",
        shift * 1e3
    );
    assert!(compared > 1000, "{compared} statuses compared");
    assert!(
        shift.abs() < 0.25,
        "the replay is {shift} s off the recording"
    );
    assert!(worst_p <= 0.5, "pressure differs by {worst_p} mmHg");
    assert!(worst_d <= 0.1, "deficit differs by {worst_d} ml");
    let _ = std::fs::remove_dir_all(dir_a);
    let _ = std::fs::remove_dir_all(dir_b);
}
