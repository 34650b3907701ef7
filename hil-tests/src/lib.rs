//! Helpers for end-to-end tests that run the real binaries: start `hydrometrad` on the emulated
//! rig under a unique service prefix, read its status over iceoryx2, signal and restart it.

pub mod host;
pub mod station;

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};

use hydrometra_ipc::{status, ServiceNames, Status};
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenError;

/// The Python that runs the scene examples: `$PYTHON` or `python3`, which must import iceoryx2
/// and numpy (`.ci/setup` installs both); panics saying so otherwise.
pub fn python_with_numpy() -> String {
    let python = std::env::var("PYTHON").unwrap_or_else(|_| "python3".into());
    let ok = Command::new(&python)
        .args(["-c", "import iceoryx2, numpy"])
        .status()
        .is_ok_and(|s| s.success());
    assert!(
        ok,
        "{python} cannot import iceoryx2 and numpy: run .ci/setup"
    );
    python
}

/// Path of a workspace binary built next to the test executable (`target/<profile>/NAME`,
/// honouring `CARGO_TARGET_DIR`). Panics with the build command when it is missing.
pub fn binary(name: &str) -> PathBuf {
    let exe = std::env::current_exe().expect("current_exe");
    // target/<profile>/deps/<test> -> target/<profile>/<name>; a binary of this crate
    // (target/<profile>/hm-soak) finds its siblings beside it.
    let parent = exe.parent().expect("an executable in a directory");
    let dir = if parent.ends_with("deps") {
        parent.parent().expect("target/<profile>/deps")
    } else {
        parent
    };
    let path = dir.join(name);
    assert!(
        path.is_file(),
        "{name} not found at {}: build the binaries first with `cargo build --workspace --bins --tests` \
         (same profile and CARGO_TARGET_DIR as the tests)",
        path.display()
    );
    path
}

/// The workspace root (for example and scenario files).
pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("hil-tests lives in the workspace")
        .to_path_buf()
}

/// A service prefix no other test (or test run) uses.
pub fn unique_prefix(tag: &str) -> String {
    static N: AtomicU32 = AtomicU32::new(0);
    format!(
        "hydrometra-test-{}-{}-{tag}/v1",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    )
}

/// A fresh temporary directory for one test.
pub fn temp_dir(tag: &str) -> PathBuf {
    static N: AtomicU32 = AtomicU32::new(0);
    let dir = std::env::temp_dir().join(format!(
        "hydrometra-hil-{}-{}-{tag}",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    ));
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

/// The built-in default scenario's text with extra TOML appended (e.g. a `[faults]` table),
/// written to a file in `dir`.
pub fn scenario_file(dir: &Path, extra_toml: &str) -> PathBuf {
    let base = std::fs::read_to_string(workspace_root().join("drivers/scenarios/default.toml"))
        .expect("drivers/scenarios/default.toml");
    let path = dir.join("scenario.toml");
    std::fs::write(&path, format!("{base}\n{extra_toml}\n")).expect("write scenario");
    path
}

/// Runs `hydrometra ARGS...` to completion and returns its stdout; panics with its stderr if it
/// fails.
pub fn hydrometra(args: &[&str]) -> String {
    let out = Command::new(binary("hydrometra"))
        .args(args)
        .output()
        .expect("run hydrometra");
    assert!(
        out.status.success(),
        "hydrometra {args:?} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// One status as `hydrometra monitor --once --json` prints it (waiting up to 10 s for one).
pub fn monitor_once_json(prefix: &str) -> serde_json::Value {
    let out = hydrometra(&[
        "monitor",
        "--once",
        "--json",
        "--timeout",
        "10",
        "--service-prefix",
        prefix,
    ]);
    serde_json::from_str(&out).unwrap_or_else(|e| panic!("monitor printed no JSON ({e}): {out}"))
}

/// The atlas cache every hil-test shares (`target/hil-atlas`), holding the atlas of `scene`
/// (a built-in name or file): built once, in this process, by the first test that needs it;
/// tests running in parallel (nextest: one process per test) wait on a lock file instead of
/// building it twice.
pub fn shared_atlas_cache(scene: &str) -> PathBuf {
    use hydrometra_sim::scene::{prepare, SceneDesc};
    let exe = std::env::current_exe().expect("current_exe");
    // target/<profile>/deps/<test> -> target/hil-atlas
    let dir = exe
        .ancestors()
        .nth(3)
        .expect("test executable in target/<profile>/deps")
        .join("hil-atlas");
    std::fs::create_dir_all(&dir).expect("atlas cache dir");
    let desc = SceneDesc::load(scene).unwrap_or_else(|e| panic!("scene {scene}: {e}"));
    let lock = std::fs::File::create(dir.join(".lock")).expect("atlas cache lock file");
    lock.lock().expect("lock the atlas cache");
    if !prepare::cache_path(&desc, &dir).is_file() {
        let started = Instant::now();
        eprintln!(
            "building the shared test atlas of {scene} in {}",
            dir.display()
        );
        prepare::load_or_build(&desc, Some(&dir), &mut |_, _, _, _| {})
            .unwrap_or_else(|e| panic!("building the atlas of {scene}: {e}"));
        eprintln!("atlas built in {:.1} s", started.elapsed().as_secs_f64());
    }
    drop(lock);
    dir
}

/// A running `hydrometrad` child process; killed (SIGKILL) on drop if still running.
pub struct Daemon {
    child: Child,
    /// The service prefix it publishes under.
    pub prefix: String,
    log: PathBuf,
}

impl Daemon {
    /// Starts `hydrometrad --service-prefix PREFIX ARGS...` with its log in a temp file. Without
    /// `--scene` in `args` the daemon runs no scene (`--no-scene`: status and hydraulics only);
    /// with it, the scene's atlas comes from the shared test cache ([`shared_atlas_cache`]).
    pub fn start(prefix: &str, args: &[&str]) -> Daemon {
        Daemon::spawn(prefix, args, false)
    }

    /// [`Daemon::start`] without the privilege of real-time scheduling: `CAP_SYS_NICE` dropped
    /// from the child's capability bounding set (so root loses it at `execve`) and
    /// `RLIMIT_RTPRIO` and `RLIMIT_NICE` set to 0, as for a user the systemd unit did not
    /// start. Where the bounding set cannot be changed the child may keep the capability:
    /// check the mode it reports.
    pub fn start_unprivileged(prefix: &str, args: &[&str]) -> Daemon {
        Daemon::spawn(prefix, args, true)
    }

    fn spawn(prefix: &str, args: &[&str], unprivileged: bool) -> Daemon {
        let log = temp_dir("daemon-log").join("hydrometrad.log");
        let log_file = std::fs::File::create(&log).expect("log file");
        let mut command = Command::new(binary("hydrometrad"));
        match args.iter().position(|a| *a == "--scene") {
            Some(i) => {
                let scene = args.get(i + 1).expect("--scene NAME");
                command
                    .arg("--atlas-cache-dir")
                    .arg(shared_atlas_cache(scene));
            }
            None => {
                command.arg("--no-scene");
            }
        }
        if unprivileged {
            use std::os::unix::process::CommandExt;
            // SAFETY: the closure runs in the forked child before exec and only makes system
            // calls (prctl, setrlimit), which are async-signal-safe; it touches no memory of the
            // parent's other threads.
            unsafe {
                command.pre_exec(|| {
                    // CAP_SYS_NICE (linux/capability.h; not in the libc crate). EPERM without
                    // CAP_SETPCAP: the child keeps what it had.
                    const CAP_SYS_NICE: libc::c_ulong = 23;
                    libc::prctl(libc::PR_CAPBSET_DROP, CAP_SYS_NICE, 0, 0, 0);
                    let none = libc::rlimit {
                        rlim_cur: 0,
                        rlim_max: 0,
                    };
                    if libc::setrlimit(libc::RLIMIT_RTPRIO, &none) != 0
                        || libc::setrlimit(libc::RLIMIT_NICE, &none) != 0
                    {
                        return Err(std::io::Error::last_os_error());
                    }
                    Ok(())
                });
            }
        }
        let child = command
            .arg("--service-prefix")
            .arg(prefix)
            .args(args)
            .env("RUST_LOG", "info")
            .env_remove("NOTIFY_SOCKET")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(log_file)
            .spawn()
            .expect("spawn hydrometrad");
        Daemon {
            child,
            prefix: prefix.to_string(),
            log,
        }
    }

    /// Process id.
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Sends a signal (libc signal number).
    pub fn signal(&self, signal: i32) {
        // SAFETY: plain kill(2) on our own child's pid.
        let rc = unsafe { libc::kill(self.child.id() as i32, signal) };
        assert_eq!(rc, 0, "kill({}, {signal})", self.child.id());
    }

    /// Waits up to `timeout` for the process to exit.
    pub fn wait_exit(&mut self, timeout: Duration) -> Option<ExitStatus> {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(status) = self.child.try_wait().expect("try_wait") {
                return Some(status);
            }
            if Instant::now() >= deadline {
                return None;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    /// The lines of the daemon's log so far that contain `needle`.
    pub fn log_lines_with(&self, needle: &str) -> Vec<String> {
        self.log()
            .lines()
            .filter(|l| l.contains(needle))
            .map(str::to_string)
            .collect()
    }

    /// The daemon's log so far.
    pub fn log(&self) -> String {
        let mut s = String::new();
        if let Ok(mut f) = std::fs::File::open(&self.log) {
            let _ = f.read_to_string(&mut s);
        }
        s
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

/// An iceoryx2 node for tests: no signal handlers (the test harness owns signals).
pub fn test_node() -> Node<ipc::Service> {
    NodeBuilder::new()
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .expect("iceoryx2 node")
}

/// A daemon on the emulated default rig (status at 100 Hz) running the built-in default scene file
/// as `edit` changes it (written to a temporary directory named after `tag`), once its scene runs.
/// Returns the daemon's service prefix, the daemon and a status reader.
pub fn daemon_on_edited_default_scene(
    tag: &str,
    edit: impl FnOnce(&str) -> String,
) -> (String, Daemon, StatusReader) {
    let base =
        std::fs::read_to_string(workspace_root().join("sim-core/src/scene/scenes/default.toml"))
            .expect("the default scene");
    let scene = temp_dir(tag).join("scene.toml");
    std::fs::write(&scene, edit(&base)).expect("write the scene");
    let scene = scene.to_str().expect("utf-8 temp path");
    let prefix = unique_prefix(tag);
    let daemon = Daemon::start(
        &prefix,
        &[
            "--scene",
            scene,
            "--emulated",
            "default",
            "--status-rate-hz",
            "100",
        ],
    );
    let reader = StatusReader::connect(&prefix, Duration::from_secs(10));
    reader.until("the scene running", Duration::from_secs(120), |s| {
        s.scene_state == status::scene_state::RUNNING
    });
    (prefix, daemon, reader)
}

/// A subscriber to a daemon's status.
pub struct StatusReader {
    // Field order matters: ports drop before the node.
    subscriber: Subscriber<ipc::Service, Status, ()>,
    /// Received but not yet handed out (after `until` matched mid-batch).
    pending: std::cell::RefCell<std::collections::VecDeque<Status>>,
    /// The node, for tests that open more services.
    pub node: Node<ipc::Service>,
}

impl StatusReader {
    /// Subscribes to the status under `prefix`, waiting up to `timeout` for the service.
    pub fn connect(prefix: &str, timeout: Duration) -> StatusReader {
        let names = ServiceNames::new(prefix).expect("prefix");
        let node = test_node();
        let deadline = Instant::now() + timeout;
        let service = loop {
            match status::open(&node, &names) {
                Ok(s) => break s,
                Err(PublishSubscribeOpenError::DoesNotExist) if Instant::now() < deadline => {
                    std::thread::sleep(Duration::from_millis(20))
                }
                Err(e) => panic!("cannot open {}: {e:?}", names.full("status")),
            }
        };
        let subscriber = service.subscriber_builder().create().expect("subscriber");
        StatusReader {
            subscriber,
            pending: Default::default(),
            node,
        }
    }

    /// Every status received so far (non-blocking).
    pub fn drain(&self) -> Vec<Status> {
        let mut out: Vec<Status> = self.pending.borrow_mut().drain(..).collect();
        while let Some(s) = self.subscriber.receive().expect("receive") {
            out.push(*s);
        }
        out
    }

    /// Every status received during `duration` (polling every 2 ms, well inside the buffer).
    pub fn collect_for(&self, duration: Duration) -> Vec<Status> {
        let deadline = Instant::now() + duration;
        let mut out = Vec::new();
        while Instant::now() < deadline {
            out.extend(self.drain());
            std::thread::sleep(Duration::from_millis(2));
        }
        out.extend(self.drain());
        out
    }

    /// Collects statuses until one satisfies `pred`; returns all collected, the match last.
    /// Panics with `what` after `timeout`.
    pub fn until(
        &self,
        what: &str,
        timeout: Duration,
        pred: impl Fn(&Status) -> bool,
    ) -> Vec<Status> {
        let deadline = Instant::now() + timeout;
        let mut out = Vec::new();
        loop {
            let mut batch = self.drain().into_iter();
            while let Some(s) = batch.next() {
                out.push(s);
                if pred(&s) {
                    self.pending.borrow_mut().extend(batch);
                    return out;
                }
            }
            assert!(
                Instant::now() < deadline,
                "timed out after {timeout:?} waiting for {what}; last status: {:?}",
                out.last()
            );
            std::thread::sleep(Duration::from_millis(2));
        }
    }
}

/// Asserts that sequence numbers increase by exactly one (no gaps, no repeats).
pub fn assert_contiguous(statuses: &[Status]) {
    for w in statuses.windows(2) {
        assert_eq!(
            w[1].sequence,
            w[0].sequence + 1,
            "sequence jumps from {} to {} (run ids {:x} / {:x})",
            w[0].sequence,
            w[1].sequence,
            w[0].run_id,
            w[1].run_id
        );
    }
}

/// The safe-state invariant every status must hold: inputs derived from a sample older than the
/// safe-state timeout (plus one status period of slack for the age measured at publication) are
/// never presented as live: the status is in the safe state with valves closed and pump stopped.
pub fn assert_safe_state_rule(s: &Status, timeout_s: f64, slack_s: f64) {
    let stale = !s.last_sample_age_s.is_finite() || s.last_sample_age_s > timeout_s + slack_s;
    let lost = s.link_state != status::link_state::CONNECTED;
    if stale || lost {
        assert_eq!(
            s.safe_state, 1,
            "stale/lost link but not in the safe state: {s:?}"
        );
    }
    if s.safe_state == 1 {
        assert_eq!(
            (
                s.valve_in_opening,
                s.valve_out_opening,
                s.pump_set_pressure_pa
            ),
            (0.0, 0.0, 0.0),
            "safe state with non-safe inputs: {s:?}"
        );
        assert_ne!(s.alarm_bits & hydrometra_ipc::alarms::RIG_SAFE_STATE, 0);
        assert_ne!(s.alarm_bits & hydrometra_ipc::alarms::RIG_LINK_LOST, 0);
        assert_eq!(s.scope_pose_valid, 0);
    }
}

/// Asserts that a live (not safe-state) status carries the scenario's values at the sample's
/// device time, within one count of the rig's 12-bit channels (as calibrated by default).
pub fn assert_matches_scenario(s: &Status, scenario: &hydrometra_drivers::emulator::Scenario) {
    use hydrometra_drivers::calibration::PA_PER_MMHG;
    assert_eq!(s.safe_state, 0, "not live: {s:?}");
    let e = scenario.sample_at(s.rig_device_time_us as f64 * 1e-6);
    // One ADC count of the default calibration's spans, with margin (~3600-4095 counts).
    let valve_step = 1.0 / 3000.0;
    let pump_step_pa = 200.0 * PA_PER_MMHG / 3000.0;
    let ctx = || format!("status {s:?}\nscenario {e:?}");
    assert!(
        (s.rig_valve_in_opening - e.valve_in).abs() <= valve_step,
        "{}",
        ctx()
    );
    assert!(
        (s.rig_valve_out_opening - e.valve_out).abs() <= valve_step,
        "{}",
        ctx()
    );
    assert!(
        (s.rig_pump_set_pressure_pa - e.pump_mmhg * PA_PER_MMHG).abs() <= pump_step_pa,
        "{}",
        ctx()
    );
    // Live: the simulation uses exactly what the rig reported.
    assert_eq!(s.valve_in_opening, s.rig_valve_in_opening);
    assert_eq!(s.valve_out_opening, s.rig_valve_out_opening);
    assert_eq!(s.pump_set_pressure_pa, s.rig_pump_set_pressure_pa);
    for i in 0..3 {
        // f32 on the wire: well below a micrometre at cavity distances.
        assert!(
            (s.scope_tip_position_m[i] - e.tip_mm[i] * 1e-3).abs() < 1e-6,
            "{}",
            ctx()
        );
        assert!(
            (s.scope_view_direction[i] - e.view_dir[i]).abs() < 1e-5,
            "{}",
            ctx()
        );
    }
    assert_eq!(s.scope_pose_valid, u32::from(e.pose_valid), "{}", ctx());
    assert_eq!(s.buttons, e.buttons, "{}", ctx());
}

/// How a node of a given process appears in iceoryx2's node list.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NodePresence {
    /// Not listed.
    Absent,
    /// Listed, process alive.
    Alive,
    /// Listed, process dead, resources not yet cleaned.
    Dead,
}

/// Whether process `pid` holds an iceoryx2 node, and in which state.
pub fn node_of_process(pid: u32) -> NodePresence {
    use iceoryx2::node::{NodeState, NodeView};
    let mut presence = NodePresence::Absent;
    Node::<ipc::Service>::list(Config::global_config(), |state| {
        let (details, found) = match &state {
            NodeState::Alive(v) => (v.details().clone(), NodePresence::Alive),
            NodeState::Dead(v) => (v.details().clone(), NodePresence::Dead),
            _ => (None, NodePresence::Absent),
        };
        if details.is_some_and(|d| d.process_id().value() as u32 == pid) {
            presence = found;
            return CallbackProgression::Stop;
        }
        CallbackProgression::Continue
    })
    .expect("list iceoryx2 nodes");
    presence
}

/// Whether the daemon's status and event services exist under `prefix`.
pub fn services_exist(prefix: &str) -> (bool, bool) {
    let names = ServiceNames::new(prefix).expect("prefix");
    let config = Config::global_config();
    let status =
        ipc::Service::does_exist(names.status(), config, MessagingPattern::PublishSubscribe)
            .expect("status service lookup");
    let events = ipc::Service::does_exist(names.events(), config, MessagingPattern::Event)
        .expect("event service lookup");
    (status, events)
}
