//! Faults a teaching room produces at the shared-memory side and on the recordings disk: renderers
//! killed while they hold every scene service, renderers that never read, a `/dev/shm` too small
//! for the daemon's services, a recordings disk that fills up. The procedure (status, the deficit)
//! goes on through all of them.

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use hydrometra_hil_tests::host::HostWatch;
use hydrometra_hil_tests::{
    assert_contiguous, binary, temp_dir, unique_prefix, Daemon, StatusReader,
};
use hydrometra_ipc::status::scene_state;
use hydrometra_ipc::{alarms, Status};

/// A renderer (`hm-hold-renderer`) subscribed to status and every scene service, holding one
/// borrowed sample of each once it printed `holding`.
///
/// A renderer started right after another was SIGKILLed can find a service missing while
/// iceoryx2 removes the dead one's node (seen in runs of 100 renderers on a loaded machine): like
/// any renderer (docs/ipc.md) it opens again, at most [`OPEN_ATTEMPTS`] times over about 3 s. If it
/// never can, the panic says whether `daemon` is still running and shows its log: twice in CI
/// the status service stayed missing for every attempt, cause not found yet.
fn holding_renderer(daemon: &mut Daemon, read: bool) -> Child {
    let mut last = String::new();
    for attempt in 0..OPEN_ATTEMPTS {
        match try_holding_renderer(&daemon.prefix, read) {
            Ok(child) => return child,
            Err(stderr) => last = stderr,
        }
        std::thread::sleep(Duration::from_millis(100 << attempt));
    }
    let state = match daemon.wait_exit(Duration::ZERO) {
        Some(status) => format!("the daemon had exited ({status})"),
        None => "the daemon was still running".to_string(),
    };
    panic!(
        "the renderer never held the services: {last}; {state}; its log:\n{}",
        daemon.log()
    );
}

const OPEN_ATTEMPTS: u32 = 5;

fn try_holding_renderer(prefix: &str, read: bool) -> Result<Child, String> {
    let mut command = Command::new(binary("hm-hold-renderer"));
    command.arg(prefix);
    if read {
        command.arg("--read");
    }
    let mut child = command
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn hm-hold-renderer");
    let stdout = child.stdout.take().expect("stdout");
    let mut line = String::new();
    let n = BufReader::new(stdout).read_line(&mut line).unwrap_or(0);
    if n == 0 || line.trim() != "holding" {
        let _ = child.kill();
        let out = child.wait_with_output().expect("renderer output");
        return Err(String::from_utf8_lossy(&out.stderr).into_owned());
    }
    Ok(child)
}

fn wait_running(reader: &StatusReader) {
    reader.until("the scene running", Duration::from_secs(180), |s| {
        s.scene_state == scene_state::RUNNING || s.scene_state == scene_state::IDLE
    });
}

/// Misses and ticks since the status before, where the machine kept no `SCHED_FIFO` thread off the
/// loop's CPU in between (`hydrometra_hil_tests::host`: a loop whose CPU is not running misses
/// whatever the daemon does); `None` where it did.
fn judged(a: &Status, b: &Status, host: &HostWatch) -> Option<(u64, u64)> {
    (!host.interfered_between(a.publish_monotonic_ns, b.publish_monotonic_ns))
        .then(|| (b.deadline_misses - a.deadline_misses, b.ticks - a.ticks))
}

/// Misses and ticks over a stretch of statuses, judged as [`judged`] says.
fn misses(statuses: &[Status], host: &HostWatch) -> (u64, u64) {
    statuses
        .windows(2)
        .filter_map(|w| judged(&w[0], &w[1], host))
        .fold((0, 0), |acc, d| (acc.0 + d.0, acc.1 + d.1))
}

/// 100 renderers in a row subscribe to status and all four scene services, hold a sample of each
/// and die by SIGKILL. Interleaved with quiet stretches of the same length: the daemon's misses
/// while renderers die are no worse than without (within the product's 0.1 % target), status stays
/// contiguous, the scene keeps publishing, and every renderer could subscribe (the dead ones'
/// resources are reclaimed).
#[test]
fn renderers_killed_while_holding_every_scene_service_never_disturb_the_daemon() {
    use std::sync::atomic::{AtomicBool, AtomicU8, Ordering};
    use std::sync::Arc;
    let prefix = unique_prefix("shm-kill");
    let host = HostWatch::start();
    let mut daemon = Daemon::start(
        &prefix,
        &["--emulated", "default", "--scene", "default", "--no-record"],
    );
    // A status reader of its own thread, tagging each status with the phase it arrived in (0
    // quiet, 1 renderers dying): the main thread's spawns would otherwise overflow its buffer.
    let phase = Arc::new(AtomicU8::new(2));
    let done = Arc::new(AtomicBool::new(false));
    let collector = {
        let (prefix, phase, done) = (prefix.clone(), phase.clone(), done.clone());
        std::thread::spawn(move || {
            let reader = StatusReader::connect(&prefix, Duration::from_secs(20));
            wait_running(&reader);
            phase.store(0, Ordering::Release);
            let mut out: Vec<(u8, Status)> = Vec::new();
            while !done.load(Ordering::Acquire) {
                let p = phase.load(Ordering::Acquire);
                out.extend(reader.drain().into_iter().map(|s| (p, s)));
                std::thread::sleep(Duration::from_millis(2));
            }
            out
        })
    };
    while phase.load(Ordering::Acquire) == 2 {
        std::thread::sleep(Duration::from_millis(20));
    }
    for _ in 0..10 {
        phase.store(1, Ordering::Release);
        let started = Instant::now();
        for _ in 0..10 {
            let mut renderer = holding_renderer(&mut daemon, false);
            renderer.kill().expect("SIGKILL");
            renderer.wait().expect("reap");
        }
        let took = started.elapsed();
        phase.store(0, Ordering::Release);
        std::thread::sleep(took);
    }
    done.store(true, Ordering::Release);
    let all = collector.join().expect("the status collector");
    let statuses: Vec<Status> = all.iter().map(|(_, s)| *s).collect();
    assert_contiguous(&statuses);
    // Each status's misses and ticks since the one before, to the phase it arrived in.
    let (mut kill, mut quiet) = ((0u64, 0u64), (0u64, 0u64));
    for w in all.windows(2) {
        let ((_, a), (p, b)) = (w[0], w[1]);
        let Some(d) = judged(&a, &b, &host) else {
            continue;
        };
        let slot = if p == 1 { &mut kill } else { &mut quiet };
        *slot = (slot.0 + d.0, slot.1 + d.1);
    }
    let share = |(m, t): (u64, u64)| m as f64 / t.max(1) as f64;
    eprintln!(
        "100 renderers killed while holding every service: misses {} in {} ticks ({:.4} %) \
         against {} in {} quiet ({:.4} %), where the machine took nothing from the loop's CPU \
         ({})",
        kill.0,
        kill.1,
        100.0 * share(kill),
        quiet.0,
        quiet.1,
        100.0 * share(quiet),
        host.summary()
    );
    assert!(
        share(kill) <= (2.0 * share(quiet)).max(0.001),
        "misses while renderers die: {kill:?}, quiet {quiet:?}:\n{}",
        daemon.log()
    );
    // The scene went on, and a renderer that reads gets fresh frames.
    let (first, last) = (statuses[0], *statuses.last().expect("statuses"));
    assert!(last.scene_frames > first.scene_frames + 100);
    let mut healthy = holding_renderer(&mut daemon, true);
    std::thread::sleep(Duration::from_millis(500));
    assert!(
        healthy.try_wait().expect("try_wait").is_none(),
        "the healthy renderer died"
    );
    let _ = healthy.kill();
    let _ = healthy.wait();
    assert!(
        !daemon.log().contains("could not publish"),
        "the scene's publishers failed:\n{}",
        daemon.log()
    );
}

/// A renderer that subscribes to every service and never reads again (its buffers full, one
/// sample of each borrowed for good): interleaved 2 s stretches with and without it, status stays
/// contiguous, the daemon's misses with it are no worse than without, and the scene keeps its
/// frame rate.
#[test]
fn a_renderer_that_never_reads_does_not_slow_the_daemon() {
    let prefix = unique_prefix("shm-stall");
    let host = HostWatch::start();
    let mut daemon = Daemon::start(
        &prefix,
        &["--emulated", "default", "--scene", "default", "--no-record"],
    );
    let reader = StatusReader::connect(&prefix, Duration::from_secs(20));
    wait_running(&reader);
    let window = Duration::from_secs(2);
    let (mut with, mut without) = ((0, 0), (0, 0));
    let mut frames_with = 0;
    for _ in 0..5 {
        let mut stalled = holding_renderer(&mut daemon, false);
        reader.drain();
        let statuses = reader.collect_for(window);
        assert_contiguous(&statuses);
        let (m, t) = misses(&statuses, &host);
        with = (with.0 + m, with.1 + t);
        frames_with += statuses.last().map_or(0, |s| s.scene_frames) - statuses[0].scene_frames;
        let _ = stalled.kill();
        let _ = stalled.wait();
        reader.drain();
        let statuses = reader.collect_for(window);
        let (m, t) = misses(&statuses, &host);
        without = (without.0 + m, without.1 + t);
    }
    let share = |(m, t): (u64, u64)| m as f64 / t.max(1) as f64;
    eprintln!(
        "a renderer that never reads: misses {} in {} ticks with it, {} in {} without (where the \
         machine took nothing from the loop's CPU; {}); {} scene frames in 10 s with it",
        with.0,
        with.1,
        without.0,
        without.1,
        host.summary(),
        frames_with
    );
    assert!(
        with.1 >= 5_000,
        "{} ticks judged of 10 s: the machine took the rest ({})",
        with.1,
        host.summary()
    );
    assert!(
        share(with) <= (2.0 * share(without)).max(0.001),
        "misses with a stalled renderer {with:?}, without {without:?}"
    );
    // 60 Hz nominal; at least the deepest degradation level's half rate.
    assert!(
        frames_with >= 280,
        "{frames_with} scene frames in 10 s beside a stalled renderer"
    );
}

/// Where iceoryx2 keeps its node and service records (its default `global.root-path`).
const ICEORYX2_ROOT: &str = "/tmp/iceoryx2";

/// Runs `hydrometrad ARGS` with `mounts` (tmpfs size, mount point) in a private mount namespace
/// (util-linux `unshare`, root or CAP_SYS_ADMIN); `None` where that is not possible here.
///
/// A private `/dev/shm` comes with a private [`ICEORYX2_ROOT`]: a daemon that sees the machine's
/// service records but not their shared memory takes every other process's services for broken
/// and removes their records, and the renderers of a daemon running beside it (the renderer-kill
/// test) then found its status service gone for good (twice in CI, reproduced here).
fn in_private_mounts(mounts: &[(&str, &Path)], args: &[&str]) -> Option<Command> {
    let probe = Command::new("unshare")
        .args(["--mount", "--propagation", "private", "true"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status();
    if !probe.is_ok_and(|s| s.success()) {
        return None;
    }
    let mut script = String::new();
    if mounts.iter().any(|(_, at)| *at == Path::new("/dev/shm")) {
        script.push_str(&format!(
            "mkdir -p {ICEORYX2_ROOT} && mount -t tmpfs -o size=16m tmpfs {ICEORYX2_ROOT} || exit 97; "
        ));
    }
    for (size, at) in mounts {
        script.push_str(&format!(
            "mount -t tmpfs -o size={size} tmpfs '{}' || exit 97; ",
            at.display()
        ));
    }
    script.push_str("exec \"$@\"");
    let mut command = Command::new("unshare");
    command
        .args([
            "--mount",
            "--propagation",
            "private",
            "sh",
            "-c",
            &script,
            "sh",
        ])
        .arg(binary("hydrometrad"))
        .args(args)
        .env("RUST_LOG", "info")
        .env_remove("NOTIFY_SOCKET");
    Some(command)
}

/// `/dev/shm` too small for the status service: the daemon refuses to start with an error that
/// names `/dev/shm`, how much is free and how much its services need; with room for status but not
/// for the scene, status and the hydraulics run and the scene fails with the same kind of error.
#[test]
fn a_too_small_dev_shm_is_refused_with_how_much_is_needed_where_available() {
    let prefix = unique_prefix("shm-small");
    let shm = Path::new("/dev/shm");
    let Some(mut command) = in_private_mounts(
        &[("256k", shm)],
        &[
            "--emulated",
            "default",
            "--no-scene",
            "--no-record",
            "--service-prefix",
            &prefix,
            "--duration",
            "5",
        ],
    ) else {
        println!("SKIP a_too_small_dev_shm_is_refused_with_how_much_is_needed_where_available: no private mount namespace here");
        return;
    };
    let out = command.output().expect("run hydrometrad");
    let log = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success(),
        "started with a 256 kB /dev/shm:\n{log}"
    );
    assert_ne!(
        out.status.code(),
        Some(97),
        "the tmpfs could not be mounted:\n{log}"
    );
    assert!(
        log.contains("/dev/shm has 0.2 MiB free")
            && log.contains("the status, event and control services need about"),
        "{log}"
    );

    // Room for status (about 1 MB) but not for the scene's flow service (about 11 MB).
    let dir = temp_dir("shm-small");
    let log_path = dir.join("daemon.log");
    let prefix = unique_prefix("shm-small-scene");
    let cache = hydrometra_hil_tests::shared_atlas_cache("default");
    let cache = cache.display().to_string();
    let mut command = in_private_mounts(
        &[("4m", shm)],
        &[
            "--emulated",
            "default",
            "--scene",
            "default",
            "--atlas-cache-dir",
            &cache,
            "--no-record",
            "--service-prefix",
            &prefix,
            "--duration",
            "8",
        ],
    )
    .expect("the namespace worked above");
    let out = command
        .stderr(std::fs::File::create(&log_path).expect("log"))
        .output()
        .expect("run hydrometrad");
    let log = std::fs::read_to_string(&log_path).unwrap_or_default();
    assert!(out.status.success(), "the daemon stopped:\n{log}");
    assert!(
        log.contains("scene stopped")
            && log.contains("the scene's services need about")
            && log.contains("flow"),
        "{log}"
    );
    // Status ran the whole time: the final summary's status count (at 1 kHz for 8 s).
    let published: u64 = log
        .lines()
        .find(|l| l.contains("stopped: ") && l.contains("ticks"))
        .and_then(|l| l.split("statuses ").nth(1))
        .and_then(|r| r.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or(0);
    assert!(published >= 7_000, "{published} statuses in 8 s:\n{log}");
}

/// The recordings disk fills up during a recording: the recording stops with an error naming the
/// file and the cause, status raises `recording-failed`, and the procedure and its deficit go on.
#[test]
fn a_full_recordings_disk_stops_the_recording_and_the_procedure_goes_on_where_available() {
    let prefix = unique_prefix("disk-full");
    let dir = temp_dir("disk-full");
    let recordings = dir.join("recordings");
    std::fs::create_dir_all(&recordings).expect("recordings dir");
    let log_path = dir.join("daemon.log");
    let rec = recordings.display().to_string();
    let Some(mut command) = in_private_mounts(
        &[("96k", &recordings)],
        &[
            "--emulated",
            "default",
            "--no-scene",
            "--service-prefix",
            &prefix,
            "--record-dir",
            &rec,
            "--duration",
            "20",
        ],
    ) else {
        println!("SKIP a_full_recordings_disk_stops_the_recording_and_the_procedure_goes_on_where_available: no private mount namespace here");
        return;
    };
    let mut child = command
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&log_path).expect("log"))
        .spawn()
        .expect("spawn hydrometrad");
    let reader = StatusReader::connect(&prefix, Duration::from_secs(20));
    let failed = reader.until("recording-failed", Duration::from_secs(18), |s| {
        s.alarm_bits & alarms::RECORDING_FAILED != 0
    });
    let at_failure = *failed.last().expect("status");
    let after = reader.collect_for(Duration::from_secs(1));
    let _ = child.wait();
    let log = std::fs::read_to_string(&log_path).unwrap_or_default();
    assert_contiguous(&after);
    let last = *after.last().expect("statuses after the failure");
    assert_eq!(
        last.procedure_id, at_failure.procedure_id,
        "the procedure changed"
    );
    assert!(
        last.fluid_in_m3 > at_failure.fluid_in_m3 && last.deficit_m3 >= at_failure.deficit_m3,
        "the hydraulics stopped: {at_failure:?} -> {last:?}"
    );
    assert!(
        log.contains("recording stopped; the procedure goes on")
            && log.contains("No space left on device")
            && log.contains(&rec),
        "{log}"
    );
}
