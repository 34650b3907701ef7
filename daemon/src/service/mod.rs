//! hydrometrad: configuration, the rig input, the fixed-rate simulation loop (which publishes
//! status) and the supervisor that ties them together (signals, systemd, periodic logs).
//!
//! Two sides: the real-time threads (rig I/O, the 1 kHz loop, the scene thread)
//! are dedicated OS threads that never wait on anything else; the control plane (signals,
//! supervision, the control service's handlers) runs on a current-thread tokio runtime on the
//! main thread at normal priority, and reaches the real-time side only through atomics,
//! `try_lock` slots and channels the real-time side polls.

pub mod config;
pub mod control;
pub mod hydraulics;
pub mod latency;
pub mod notify;
pub mod publisher;
pub mod realtime;
pub mod remote;
pub mod rig_connection;
pub mod rig_source;
pub mod scene;
pub mod scene_pace;
pub mod shm;
pub mod sim;

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use anyhow::Context;
use hydrometra_drivers::emulator::Scenario;
use hydrometra_drivers::state::LinkDownReason;
use hydrometra_drivers::transport::RigLink;
use hydrometra_ipc::ServiceNames;

use config::Config;
use hydrometra_record::recorder::{self, RecorderHandle};
use latency::LatencySummary;
use publisher::StatusPublisher;
use rig_source::RigSource;
use sim::{LoopSettings, SimLoop, Telemetry};

/// How often the supervisor checks the threads, the duration and the watchdog. Signals wake it
/// at once; nothing it checks needs a finer grain, and each check wakes the runtime's thread.
const SUPERVISOR_PERIOD: Duration = Duration::from_millis(100);
/// How often the supervisor removes resources of dead iceoryx2 nodes (crashed renderers). Done
/// here, not on the loop (which publishes), because it walks the file system and would delay a tick.
const DEAD_NODE_CLEANUP_INTERVAL: Duration = Duration::from_secs(5);

/// A node of its own for removing dead nodes' resources off the loop's hot path.
fn janitor_node() -> Option<iceoryx2::node::Node<iceoryx2::prelude::ipc::Service>> {
    use iceoryx2::prelude::*;
    let name = NodeName::new("hydrometrad-janitor").ok()?;
    match NodeBuilder::new()
        .name(&name)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
    {
        Ok(node) => Some(node),
        Err(e) => {
            tracing::warn!("cannot create the dead-node cleanup node ({e:?}); crashed renderers' resources stay until restart");
            None
        }
    }
}

/// The loop stage that raises `recording-failed` while the recorder is stopped by an error.
struct RecorderAlarm(Arc<AtomicBool>);

impl sim::Stage for RecorderAlarm {
    fn name(&self) -> &'static str {
        "recorder-alarm"
    }
    fn step(&mut self, _inputs: &sim::SimInputs, _dt_s: f64) {}
    fn write_status(&self, status: &mut hydrometra_ipc::Status) {
        if self.0.load(Ordering::Relaxed) {
            status.alarm_bits |= hydrometra_ipc::alarms::RECORDING_FAILED;
        }
    }
}

/// Figures of a finished run.
#[derive(Debug, Clone, Copy)]
pub struct RunSummary {
    /// Ticks executed.
    pub ticks: u64,
    /// Deadline misses.
    pub deadline_misses: u64,
    /// Statuses published.
    pub statuses_published: u64,
    /// Statuses dropped between loop and publisher (0 since the loop publishes itself).
    pub statuses_dropped: u64,
    /// Rig-sample-to-status latency.
    pub latency: LatencySummary,
    /// Wall time of the run.
    pub elapsed: Duration,
}

fn summary(telemetry: &Telemetry, elapsed: Duration) -> RunSummary {
    RunSummary {
        ticks: telemetry.ticks.load(Ordering::Relaxed),
        deadline_misses: telemetry.deadline_misses.load(Ordering::Relaxed),
        statuses_published: telemetry.statuses_published.load(Ordering::Relaxed),
        statuses_dropped: telemetry.statuses_dropped.load(Ordering::Relaxed),
        latency: telemetry.latency_summary(),
        elapsed,
    }
}

fn ms(s: f64) -> String {
    if s.is_nan() {
        "-".into()
    } else {
        format!("{:.3}", s * 1e3)
    }
}

/// Logs a one-line summary: the line the benchmarks quote.
pub fn log_summary(what: &str, s: &RunSummary) {
    tracing::info!(
        "{what}: {:.1} s, ticks {} (deadline misses {}), statuses {} (dropped {}), \
         rig-sample-to-status latency ms p50 {} p99 {} max {} (n {})",
        s.elapsed.as_secs_f64(),
        s.ticks,
        s.deadline_misses,
        s.statuses_published,
        s.statuses_dropped,
        ms(s.latency.p50_s),
        ms(s.latency.p99_s),
        ms(s.latency.max_s),
        s.latency.count
    );
}

/// Logs why the rig link is down, once per change of reason (not on every retry).
#[derive(Default)]
struct LinkReasonLog {
    last: Option<LinkDownReason>,
}

impl LinkReasonLog {
    fn update(&mut self, link: &RigLink) {
        let reason = link.status().down_reason;
        if reason == self.last {
            return;
        }
        self.last = reason;
        // Off the real-time threads: the snapshot allocates for the message.
        match (reason, link.snapshot().last_error) {
            (Some(r), Some(message)) => tracing::warn!(reason = ?r, "rig link down: {message}"),
            (Some(r), None) => tracing::warn!(reason = ?r, "rig link down"),
            (None, _) => tracing::info!("rig link up: the last failure is cleared"),
        }
    }
}

/// A run id that differs between daemon starts.
fn new_run_id() -> u64 {
    let nanos = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0);
    nanos ^ (u64::from(std::process::id()) << 32)
}

/// The emulated rig's scenario (`rig.emulated.scenario`), resolved once for the emulator and the
/// hydraulics stage; `None` for a real rig.
pub fn emulated_scenario(config: &Config) -> anyhow::Result<Option<Scenario>> {
    if config.rig.mode != config::RigMode::Emulated {
        return Ok(None);
    }
    let spec = &config.rig.emulated.scenario;
    Scenario::resolve(spec)
        .map(Some)
        .with_context(|| format!("rig.emulated.scenario = {spec:?}"))
}

/// The scene the configuration asks for (parsed at once: a bad scene is a start-up error), with
/// `[paths] atlas` as its atlas file when set.
pub fn scene_desc(config: &Config) -> anyhow::Result<Option<hydrometra_sim::scene::SceneDesc>> {
    if !config.scene.enabled {
        return Ok(None);
    }
    let mut desc = hydrometra_sim::scene::SceneDesc::load(&config.scene.scene)
        .with_context(|| format!("[scene] scene = {:?}", config.scene.scene))?;
    if let Some(atlas) = &config.paths.atlas {
        desc.atlas.file = Some(atlas.clone());
    }
    Ok(Some(desc))
}

/// The stages the 1 kHz loop steps every tick, in order: the hydraulics (which hand their state
/// to the scene thread through `feed`) and the copy of the scene's figures into status. The
/// scene itself (deformation, voxelization, fluid, particles) runs on its own thread.
/// `scenario` is the emulated rig's.
pub fn build_stages(
    config: &Config,
    scenario: Option<&Scenario>,
    scene: Option<(&hydrometra_sim::scene::SceneDesc, Arc<scene::SceneFeed>)>,
    procedure: Arc<hydraulics::ProcedureControl>,
) -> anyhow::Result<Vec<Box<dyn sim::Stage>>> {
    let h = &config.hydraulics;
    // A replay reproduces the recorded procedure: the recorded configuration's scenario case and
    // hydraulic parameters, a new procedure, no procedure record (docs/recording.md).
    let replayed = replayed_config(config)?;
    let source = replayed.as_ref().unwrap_or(config);
    let replayed_scenario = match &replayed {
        Some(r) => emulated_scenario(r)?,
        None => None,
    };
    let scenario = if replayed.is_some() {
        replayed_scenario.as_ref()
    } else {
        scenario
    };
    let (case, case_period_s) = match scenario {
        Some(scenario) => (
            hydraulics::case_script(scenario)?,
            scenario.looping.then(|| scenario.duration_s()),
        ),
        None => Default::default(),
    };
    let h_params = &source.hydraulics.params;
    let mut params = case.params.clone().unwrap_or_else(|| h_params.clone());
    if let Some((desc, _)) = &scene {
        // The port areas are the scope's (one source): the status port velocities then match the
        // jet the flow field carries.
        params.inflow.port_area_mm2 = desc.hydraulics.inflow.port_area_mm2;
        params.outflow.port_area_mm2 = desc.hydraulics.outflow.port_area_mm2;
    }
    let feed = scene.map(|(_, feed)| feed);
    let stage = hydraulics::HydraulicsStage::start(hydraulics::HydraulicsSetup {
        params,
        case,
        case_period_s,
        record: if replayed.is_some() {
            None
        } else {
            h.record_path(&config.paths)
        },
        save_interval: Duration::from_millis(h.save_interval_ms),
        new_procedure: h.new_procedure || replayed.is_some(),
        scene: feed.clone(),
        control: procedure,
    })?;
    let mut stages: Vec<Box<dyn sim::Stage>> = vec![Box::new(stage)];
    if let Some(feed) = feed {
        stages.push(Box::new(scene::SceneStatusStage(feed)));
    }
    Ok(stages)
}

/// The scene's line for the log and systemd `STATUS=`: its state, atlas progress while
/// preparing, and the rig-sample-to-flow latency.
fn scene_status_line(
    feed: &scene::SceneFeed,
    thread: Option<&scene::SceneThread>,
) -> Option<String> {
    use hydrometra_ipc::status::scene_state;
    let thread = thread?;
    let state = feed.figures.state();
    let name = scene_state::name(state);
    Some(if state == scene_state::PREPARING {
        let done = thread.log.atlas_levels_done.load(Ordering::Relaxed);
        let all = thread.log.atlas_levels.load(Ordering::Relaxed);
        format!("scene preparing (atlas level {done}/{all})")
    } else {
        let l = thread.log.flow_latency();
        // The solver's two-thread split: halves the helper thread ran, and joins its guard ran in
        // one thread because the helper did not pay (the second core taken by another process, or
        // joins too small to be worth waking a parked helper).
        use hydrometra_sim::{guard_serial_joins, helper_tasks};
        format!(
            "scene {name}: positions {}, flow fields {} (rig-sample-to-flow ms p50 {} p99 {} max {}, n {}), publish errors {}, solver halves on the helper thread {}, joins in one thread (the helper did not pay) {}",
            thread.log.positions_published.load(Ordering::Relaxed),
            thread.log.flows_published.load(Ordering::Relaxed),
            ms(l.p50_s),
            ms(l.p99_s),
            ms(l.max_s),
            l.count,
            thread.log.publish_errors.load(Ordering::Relaxed),
            helper_tasks(),
            guard_serial_joins(),
        )
    })
}

/// In replay mode, the configuration the recording was made with (its `config_toml` metadata).
fn replayed_config(config: &Config) -> anyhow::Result<Option<Config>> {
    if config.rig.mode != config::RigMode::Replay {
        return Ok(None);
    }
    let Some(file) = &config.rig.replay.file else {
        return Ok(None);
    };
    let recording = hydrometra_record::reader::Recording::load(file)
        .with_context(|| format!("rig.replay.file = {}", file.display()))?;
    match recording.metadata.get("config_toml") {
        Some(text) => {
            let origin = format!("{} (recorded configuration)", file.display());
            Ok(Some(Config::from_toml_str(text, &origin)?))
        }
        None => {
            tracing::warn!(file = %file.display(), "the recording carries no configuration; replaying with this one's hydraulics");
            Ok(None)
        }
    }
}

/// Starts the recorder if `[record]` asks for it and a directory is known.
fn start_recorder(
    config: &Config,
) -> anyhow::Result<Option<(RecorderHandle, recorder::RecorderTaps)>> {
    let rec = &config.record;
    if !rec.enabled {
        return Ok(None);
    }
    let Some(dir) = rec.resolved_dir(&config.paths) else {
        tracing::warn!(
            "procedures are not recorded: set [record] dir or [paths] state_dir (or --record-dir)"
        );
        return Ok(None);
    };
    let mut metadata = std::collections::BTreeMap::new();
    metadata.insert("daemon_version".into(), env!("CARGO_PKG_VERSION").into());
    metadata.insert(
        "rig_mode".into(),
        format!("{:?}", config.rig.mode).to_lowercase(),
    );
    metadata.insert(
        "record_status_rate_hz".into(),
        rec.status_rate_hz.to_string(),
    );
    metadata.insert(
        "tick_rate_hz".into(),
        config.sim_loop.tick_rate_hz.to_string(),
    );
    if let Ok(text) = toml::to_string(config) {
        metadata.insert("config_toml".into(), text);
    }
    let settings = recorder::RecorderSettings {
        dir: dir.clone(),
        start_recording: true,
        flush_interval: Duration::from_millis(rec.flush_interval_ms),
        metadata,
    };
    let (handle, taps) = RecorderHandle::spawn(settings, rec.status_every(&config.sim_loop))
        .with_context(|| format!("cannot start the recorder in {}", dir.display()))?;
    tracing::info!(dir = %dir.display(), "recording procedures");
    Ok(Some((handle, taps)))
}

/// Runs the daemon until SIGINT/SIGTERM or `duration` elapses; returns the run's figures.
pub fn run(config: &Config, duration: Option<Duration>) -> anyhow::Result<RunSummary> {
    let names = ServiceNames::new(&config.ipc.service_prefix)?;
    // Before any thread starts: every thread inherits its creator's CPUs and policy, so the main
    // thread is on the non-real-time CPUs except while it starts the rig and the loop.
    let loop_config = &config.sim_loop;
    let placement = realtime::Placement::plan(
        loop_config.isolate_realtime_cpu,
        loop_config.realtime_cpu,
        loop_config.realtime_priority,
        loop_config.fallback_nice,
    );
    placement.enter_rest("main");
    // The scene's parallel work (rayon, and the solver's fork-join, which runs serially in a pool
    // of one) gets the CPUs the loop does not have.
    if let Err(e) = rayon::ThreadPoolBuilder::new()
        .num_threads(placement.rest_cpu_count())
        .thread_name(|i| format!("hm-rayon-{i}"))
        .build_global()
    {
        tracing::debug!("rayon's pool was already built: {e}");
    }
    // The control plane's runtime: one thread (this one), so no worker thread inherits the
    // real-time policy applied below; `spawn_blocking` threads start later, at normal priority.
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("cannot start the control plane's tokio runtime")?;
    let stop = Arc::new(AtomicBool::new(false));
    let signals = {
        let _entered = runtime.enter();
        use tokio::signal::unix::{signal, SignalKind};
        let interrupt = signal(SignalKind::interrupt()).context("cannot handle SIGINT")?;
        let terminate = signal(SignalKind::terminate()).context("cannot handle SIGTERM")?;
        (interrupt, terminate)
    };
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        // A second signal while shutting down (`stop` set by the first) exits at once (code 1).
        signal_hook::flag::register_conditional_shutdown(sig, 1, stop.clone())
            .context("cannot install signal handlers")?;
    }
    let systemd = notify::Systemd::from_env();
    let started = Instant::now();

    let scenario = emulated_scenario(config)?;
    let desc = scene_desc(config)?;
    let feed = Arc::new(scene::SceneFeed::default());
    let procedure = Arc::new(hydraulics::ProcedureControl::default());
    let stages = build_stages(
        config,
        scenario.as_ref(),
        desc.as_ref().map(|d| (d, feed.clone())),
        procedure.clone(),
    )?;
    // The recorder runs with the rest: it starts before the main thread enters the real-time
    // side.
    let (recorder, taps) = match start_recorder(config)? {
        Some((handle, taps)) => (Some(Arc::new(handle)), Some(taps)),
        None => (None, None),
    };
    // The rig I/O thread (which timestamps samples), the emulated rig and the loop (which
    // publishes status) inherit the real-time side from the main thread.
    let realtime_mode = placement.enter_realtime("main");
    let mut stages = stages;
    if let Some(r) = &recorder {
        stages.push(Box::new(RecorderAlarm(r.failed_flag())));
    }
    let (rx_tap, status_tap) = match taps {
        Some(t) => (Some(t.rx), Some(t.status)),
        None => (None, None),
    };
    let rig = rig_connection::RigConnection::start(&config.rig, scenario, rx_tap)?;
    let telemetry = Arc::new(Telemetry::default());
    let settings = LoopSettings {
        tick: Duration::from_secs_f64(1.0 / config.sim_loop.tick_rate_hz),
        ticks_per_status: config.sim_loop.ticks_per_status(),
        safe_state_timeout: Duration::from_millis(config.rig.safe_state_timeout_ms),
        run_id: new_run_id(),
    };
    let sim_stop = Arc::new(AtomicBool::new(false));
    // The loop's thread owns the status publisher (iceoryx2 ports are not `Send`) and reports
    // whether it could create it before the loop starts.
    let (ready_tx, ready_rx) = std::sync::mpsc::channel::<Result<(), String>>();
    let sim = {
        let source: Arc<dyn RigSource> = rig.source();
        let (sim_stop, telemetry, names) = (sim_stop.clone(), telemetry.clone(), names.clone());
        std::thread::Builder::new()
            .name("hm-sim".into())
            .spawn(move || {
                let mut publisher = match StatusPublisher::create(&names, status_tap) {
                    Ok(p) => {
                        let _ = ready_tx.send(Ok(()));
                        p
                    }
                    Err(e) => {
                        let _ = ready_tx.send(Err(format!("{e:#}")));
                        return;
                    }
                };
                let mut sim_loop = SimLoop::new(settings);
                for stage in stages {
                    sim_loop = sim_loop.with_stage(stage);
                }
                sim_loop.run(&*source, &mut publisher, &sim_stop, &telemetry);
                publisher.finish(&telemetry);
            })
            .context("cannot start the simulation thread")?
    };
    // Everything the main thread starts from here on (the scene, control, the tokio runtime's
    // blocking threads) runs with the rest.
    placement.enter_rest("main");
    placement.report(realtime_mode);
    // The supervisor says when to poll; stopped when `run` returns (after the loop has stopped).
    let keep_awake = if loop_config.keep_realtime_cpu_awake {
        placement.keep_realtime_cpu_awake()
    } else {
        None
    };
    telemetry
        .realtime_mode
        .store(realtime_mode as u64, Ordering::Relaxed);
    match ready_rx.recv() {
        Ok(Ok(())) => {}
        Ok(Err(message)) => {
            let _ = sim.join();
            rig.shutdown();
            return Err(anyhow::anyhow!(message));
        }
        Err(_) => {
            let _ = sim.join();
            rig.shutdown();
            anyhow::bail!("simulation thread ended during setup");
        }
    }

    // The scene thread starts after the loop: it prepares its atlas (maybe building it for a
    // minute or two) while status and hydraulics already run.
    let scene_stop = Arc::new(AtomicBool::new(false));
    let scene_thread = match desc {
        Some(desc) => Some(scene::SceneThread::spawn(
            scene::SceneSettings {
                desc,
                cache_dir: config.scene.cache_dir(&config.paths),
                rate_hz: config.scene.rate_hz,
                names: names.clone(),
            },
            feed.clone(),
            telemetry.clone(),
            scene_stop.clone(),
        )?),
        None => None,
    };

    let (jobs_tx, jobs_rx) = tokio::sync::mpsc::channel(control::JOB_QUEUE);
    let control_thread = control::ControlThread::spawn(names.clone(), jobs_tx);
    let control_thread = match control_thread {
        Ok(t) => Some(t),
        Err(e) => {
            // Status and the scene go on; only remote control is missing.
            tracing::error!("no control service: {e:#}");
            None
        }
    };
    let remote = remote::start(&config.remote, &names);
    let context = Arc::new(control::ControlContext {
        procedure,
        scene: scene_thread.as_ref().map(|_| feed.clone()),
        recorder: recorder.clone(),
    });

    tracing::info!(
        tick_rate_hz = config.sim_loop.tick_rate_hz,
        status_rate_hz = config.sim_loop.status_rate_hz,
        prefix = %names.prefix(),
        "hydrometrad running"
    );
    systemd.ready(&format!("publishing on {}", names.prefix()));

    let mut supervisor = Supervisor {
        janitor: janitor_node(),
        last_cleanup: Instant::now(),
        log_interval: Duration::from_secs_f64(config.sim_loop.log_interval_s),
        next_log: Instant::now() + Duration::from_secs_f64(config.sim_loop.log_interval_s),
        last_watchdog: Instant::now(),
        watchdog_marks: (0, 0),
        link_reason: LinkReasonLog::default(),
        systemd: &systemd,
        telemetry: &telemetry,
        rig: &rig,
        sim: &sim,
        feed: &feed,
        scene_thread: scene_thread.as_ref(),
        control_thread: control_thread.as_ref(),
        keep_awake: keep_awake.as_ref(),
        safe_state_timeout: Duration::from_millis(config.rig.safe_state_timeout_ms),
        started,
        duration,
    };
    runtime.block_on(async {
        let (mut interrupt, mut terminate) = signals;
        let handlers = tokio::spawn(control::serve(jobs_rx, context));
        let mut tick = tokio::time::interval(SUPERVISOR_PERIOD);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            tokio::select! {
                _ = interrupt.recv() => {
                    tracing::info!("SIGINT");
                    break;
                }
                _ = terminate.recv() => {
                    tracing::info!("SIGTERM");
                    break;
                }
                _ = tick.tick() => {
                    if !supervisor.tick() {
                        break;
                    }
                }
            }
        }
        stop.store(true, Ordering::Relaxed);
        handlers.abort();
    });
    drop(supervisor);
    drop(remote);

    tracing::info!("shutting down");
    systemd.stopping();
    if let Some(t) = control_thread {
        t.shutdown();
    }
    // The handlers are gone with the runtime; the recorder handle is ours alone again.
    drop(runtime);
    scene_stop.store(true, Ordering::Relaxed);
    if let Some(t) = scene_thread {
        t.join(&feed);
    }
    sim_stop.store(true, Ordering::Relaxed);
    if sim.join().is_err() {
        tracing::error!("simulation thread panicked");
    }
    rig.shutdown();
    if let Some(recorder) = recorder {
        let r = match Arc::try_unwrap(recorder) {
            Ok(handle) => handle.shutdown(),
            Err(shared) => {
                // Not expected: the last holder's drop finishes the file.
                shared.status()
            }
        };
        tracing::info!(
            files = r.files_finished,
            rx_dropped = r.rx_dropped,
            status_dropped = r.status_dropped,
            "recorder stopped"
        );
    }
    let s = summary(&telemetry, started.elapsed());
    log_summary("stopped", &s);
    Ok(s)
}

/// Whether a procedure is live, so the real-time CPU is kept awake ([`realtime::KeepAwake`]):
/// a valve is open on a fresh sample, or the scene has work (running, not idle at rest). At rest
/// (valves closed, the scene idle or absent) the core may sleep.
fn procedure_is_live(inputs: &sim::SimInputs, scene_state: Option<u64>) -> bool {
    use hydrometra_ipc::status::scene_state::RUNNING;
    let valve_open =
        !inputs.safe_state && (inputs.valve_in_opening > 0.0 || inputs.valve_out_opening > 0.0);
    valve_open || scene_state == Some(RUNNING)
}

/// The periodic checks of the control plane: the threads, the duration, the systemd watchdog,
/// dead renderers' resources and the periodic log line.
struct Supervisor<'a> {
    janitor: Option<iceoryx2::node::Node<iceoryx2::prelude::ipc::Service>>,
    last_cleanup: Instant,
    log_interval: Duration,
    next_log: Instant,
    last_watchdog: Instant,
    watchdog_marks: (u64, u64),
    link_reason: LinkReasonLog,
    systemd: &'a notify::Systemd,
    telemetry: &'a Telemetry,
    rig: &'a rig_connection::RigConnection,
    sim: &'a std::thread::JoinHandle<()>,
    feed: &'a scene::SceneFeed,
    scene_thread: Option<&'a scene::SceneThread>,
    control_thread: Option<&'a control::ControlThread>,
    keep_awake: Option<&'a realtime::KeepAwake>,
    safe_state_timeout: Duration,
    started: Instant,
    duration: Option<Duration>,
}

impl Supervisor<'_> {
    /// One round of checks; false when the daemon must stop.
    fn tick(&mut self) -> bool {
        self.link_reason.update(&self.rig.source());
        if let Some(awake) = self.keep_awake {
            let view = self.rig.source().view();
            let live = procedure_is_live(
                &sim::inputs_from(&view, self.safe_state_timeout),
                self.scene_thread.map(|_| self.feed.figures.state()),
            );
            if awake.set_wanted(live) {
                tracing::debug!(live, "real-time CPU kept awake: {live}");
            }
        }
        if self.duration.is_some_and(|d| self.started.elapsed() >= d) {
            return false;
        }
        if self.sim.is_finished() {
            tracing::error!("simulation thread ended unexpectedly");
            return false;
        }
        if self.control_thread.is_some_and(|t| t.is_finished()) {
            tracing::error!("control thread ended unexpectedly; remote control is gone");
            self.control_thread = None;
        }
        let telemetry = self.telemetry;
        if let Some(interval) = self.systemd.watchdog_interval() {
            if self.last_watchdog.elapsed() >= interval {
                // Only a daemon that still ticks and publishes feeds the watchdog.
                let marks = (
                    telemetry.ticks.load(Ordering::Relaxed),
                    telemetry.statuses_published.load(Ordering::Relaxed),
                );
                if marks.0 > self.watchdog_marks.0 && marks.1 > self.watchdog_marks.1 {
                    self.systemd.watchdog();
                    self.watchdog_marks = marks;
                } else {
                    tracing::warn!(
                        "no progress since the last watchdog ping; not feeding the watchdog"
                    );
                }
                self.last_watchdog = Instant::now();
            }
        }
        if self.last_cleanup.elapsed() >= DEAD_NODE_CLEANUP_INTERVAL {
            self.last_cleanup = Instant::now();
            if let Some(cleaned) = self.janitor.as_ref().map(|n| n.try_cleanup_dead_nodes()) {
                if cleaned.cleanups > 0 {
                    tracing::info!(
                        removed = cleaned.cleanups,
                        "removed resources of dead iceoryx2 nodes"
                    );
                }
            }
        }
        if Instant::now() >= self.next_log {
            self.next_log += self.log_interval;
            let s = summary(telemetry, self.started.elapsed());
            let view = self.rig.source().view();
            tracing::info!(
                link = ?view.link_state,
                frames = view.counters.frames,
                crc_errors = view.counters.crc_errors,
                reconnects = view.counters.reconnects,
                "rig link"
            );
            log_summary("running", &s);
            let scene_line = scene_status_line(self.feed, self.scene_thread);
            if let Some(line) = &scene_line {
                tracing::info!("{line}");
            }
            self.systemd.status(&format!(
                "link {:?}; latency p99 {} ms; deadline misses {}{}",
                view.link_state,
                ms(s.latency.p99_s),
                s.deadline_misses,
                scene_line.map(|l| format!("; {l}")).unwrap_or_default()
            ));
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use hydrometra_ipc::status::scene_state;

    #[test]
    fn the_procedure_is_live_with_a_valve_open_or_the_scene_at_work_and_at_rest_otherwise() {
        let rest = sim::SimInputs {
            valve_in_opening: 0.0,
            valve_out_opening: 0.0,
            pump_set_pressure_pa: 12_000.0,
            scope: sim::INITIAL_SCOPE,
            safe_state: false,
            sample_received_at: None,
        };
        let inflow = sim::SimInputs {
            valve_in_opening: 0.3,
            ..rest
        };
        let outflow = sim::SimInputs {
            valve_out_opening: 0.3,
            ..rest
        };
        let safe = sim::SimInputs {
            safe_state: true,
            ..inflow
        };
        assert!(!procedure_is_live(&rest, None));
        assert!(!procedure_is_live(&rest, Some(scene_state::IDLE)));
        assert!(!procedure_is_live(&rest, Some(scene_state::PREPARING)));
        assert!(procedure_is_live(&rest, Some(scene_state::RUNNING)));
        assert!(procedure_is_live(&inflow, None));
        assert!(procedure_is_live(&outflow, Some(scene_state::IDLE)));
        // A stale or lost link closes the valves (safe state): at rest.
        assert!(!procedure_is_live(&safe, None));
    }
}
