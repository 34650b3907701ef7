//! The scene thread: prepares the scene's atlas (loaded, cached or built in the background), then
//! steps the scene pipeline (deformation, voxelization, ports, fluid, vortices, particles) at its
//! own rate on the newest rig inputs and hydraulic state of the 1 kHz loop, and publishes the
//! cavity mesh, the flow field and the particles over iceoryx2 (docs/ipc.md).
//!
//! The 1 kHz loop never waits for this thread: it offers its newest state with `try_lock` (a
//! tick that finds the slot busy, for the few hundred ns the scene takes to copy it, leaves the
//! offer to the next tick), and reads the scene's figures for status from atomics. The scene
//! thread runs at normal priority (never SCHED_FIFO), so it cannot preempt the loop.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use hydrometra_ipc::field::{fraction_to_u8, FlowFieldHeader, FlowLayout};
use hydrometra_ipc::mesh::{MeshPositionsHeader, MeshTopologyHeader};
use hydrometra_ipc::particles::ParticlesHeader;
use hydrometra_ipc::slice::{self, SliceService};
use hydrometra_ipc::status::scene_state;
use hydrometra_ipc::{events, ServiceNames, Status, SCHEMA_VERSION};
use hydrometra_sim::hydraulics::{CavityCompliance, HydraulicInputs, HydraulicState};
use hydrometra_sim::scene::{
    prepare, HydraulicsInput, RigInputs, Scene, SceneDesc, SceneInputs, ScopePose, Stage,
};
use iceoryx2::port::backpressure_strategy::BackpressureStrategy;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::{ipc, AllocationStrategy, NodeBuilder, NodeName, SignalHandlingMode};

use super::latency::{LatencyHistogram, LatencySummary};
use super::scene_pace::{self, Pacer, Slot};
use super::sim::{SimInputs, Stage as LoopStage, Telemetry};

/// Stages in the status arrays, in [`Stage::ALL`] order (`hydrometra_ipc::status::scene_stage`).
const STAGES: usize = 7;
/// Samples a publisher may hold on loan at once: one being written, one spare.
const MAX_LOANED: usize = 2;
/// Most particles one frame publishes: the particle service is sized for the scene's budget up
/// to this (32 B each; /dev/shm holds about 20 samples per publisher); a larger population is
/// published as an evenly spaced subset.
pub const PARTICLES_PUBLISHED_MAX: usize = 16_384;

/// What the 1 kHz loop hands the scene: its newest inputs and hydraulic state.
#[derive(Debug, Clone, Copy)]
pub struct FeedSnapshot {
    /// The inputs of the loop's tick (the rig's or the safe ones).
    pub inputs: SimInputs,
    /// The hydraulic state after that tick.
    pub hydraulics: HydraulicState,
    /// The case's perforation event is active.
    pub perforation: bool,
    /// Counts offers, so the scene sees whether anything new arrived.
    pub offers: u64,
}

/// The scene's figures for status, written by the scene thread, read by the loop (atomics: the
/// loop never waits; fields of one frame may be mixed with the next, which status tolerates).
#[derive(Debug, Default)]
pub struct SceneFigures {
    state: AtomicU64,
    frames: AtomicU64,
    runs: [AtomicU64; STAGES],
    skips: [AtomicU64; STAGES],
    p99_s_bits: [AtomicU64; STAGES],
    step_p99_s_bits: AtomicU64,
    view_clarity_bits: AtomicU64,
    surface_volume_m3_bits: AtomicU64,
    inflow_open_fraction_bits: AtomicU64,
    degradation: AtomicU64,
    frames_late: AtomicU64,
    frames_skipped: AtomicU64,
}

impl SceneFigures {
    /// The scene state (`hydrometra_ipc::status::scene_state`).
    pub fn state(&self) -> u64 {
        self.state.load(Ordering::Relaxed)
    }
    fn set_state(&self, state: u64) {
        self.state.store(state, Ordering::Relaxed);
    }
    /// Stores the pacer's level and counters.
    fn write_pace(&self, pacer: &Pacer) {
        self.degradation
            .store(u64::from(pacer.level()), Ordering::Relaxed);
        self.frames_late.store(pacer.frames_late, Ordering::Relaxed);
        self.frames_skipped
            .store(pacer.frames_skipped, Ordering::Relaxed);
    }
    /// Copies the figures into a status.
    pub fn write_status(&self, s: &mut Status) {
        s.scene_state = self.state();
        s.scene_frames = self.frames.load(Ordering::Relaxed);
        for k in 0..STAGES {
            s.scene_stage_runs[k] = self.runs[k].load(Ordering::Relaxed);
            s.scene_stage_skips[k] = self.skips[k].load(Ordering::Relaxed);
            s.scene_stage_p99_s[k] = f64::from_bits(self.p99_s_bits[k].load(Ordering::Relaxed));
        }
        s.scene_step_p99_s = f64::from_bits(self.step_p99_s_bits.load(Ordering::Relaxed));
        s.view_clarity = f64::from_bits(self.view_clarity_bits.load(Ordering::Relaxed));
        s.cavity_surface_volume_m3 =
            f64::from_bits(self.surface_volume_m3_bits.load(Ordering::Relaxed));
        s.inflow_port_open_fraction =
            f64::from_bits(self.inflow_open_fraction_bits.load(Ordering::Relaxed));
        s.scene_degradation = self.degradation.load(Ordering::Relaxed) as u32;
        s.scene_frames_late = self.frames_late.load(Ordering::Relaxed);
        s.scene_frames_skipped = self.frames_skipped.load(Ordering::Relaxed);
    }
}

/// The hand-over between the 1 kHz loop and the scene thread.
#[derive(Debug)]
pub struct SceneFeed {
    snapshot: Mutex<Option<FeedSnapshot>>,
    compliance: Mutex<Option<Box<dyn CavityCompliance>>>,
    /// Set when `compliance` holds one for the loop to take.
    compliance_ready: AtomicBool,
    /// A scene the control plane asked for, taken by the scene thread between frames.
    scene_request: Mutex<Option<SceneDesc>>,
    /// Figures for status.
    pub figures: SceneFigures,
    offers: AtomicU64,
}

impl Default for SceneFeed {
    fn default() -> Self {
        let figures = SceneFigures::default();
        figures
            .view_clarity_bits
            .store(f64::NAN.to_bits(), Ordering::Relaxed);
        figures
            .surface_volume_m3_bits
            .store(f64::NAN.to_bits(), Ordering::Relaxed);
        figures
            .inflow_open_fraction_bits
            .store(f64::NAN.to_bits(), Ordering::Relaxed);
        Self {
            snapshot: Mutex::new(None),
            compliance: Mutex::new(None),
            compliance_ready: AtomicBool::new(false),
            scene_request: Mutex::new(None),
            figures,
            offers: AtomicU64::new(0),
        }
    }
}

impl SceneFeed {
    /// Called by the loop every tick: never waits (a busy slot leaves it to the next tick).
    pub fn offer(&self, inputs: &SimInputs, hydraulics: &HydraulicState, perforation: bool) {
        if let Ok(mut slot) = self.snapshot.try_lock() {
            let offers = self.offers.fetch_add(1, Ordering::Relaxed) + 1;
            *slot = Some(FeedSnapshot {
                inputs: *inputs,
                hydraulics: *hydraulics,
                perforation,
                offers,
            });
        }
    }

    /// Called by the scene thread: the newest snapshot (holds the lock for a copy only).
    fn latest(&self) -> Option<FeedSnapshot> {
        self.snapshot.lock().map(|s| *s).unwrap_or(None)
    }

    /// Called by the loop: the atlas's compliance once the scene has it (never waits).
    pub fn take_compliance(&self) -> Option<Box<dyn CavityCompliance>> {
        // One load per tick while there is nothing to take (every tick but one).
        if !self.compliance_ready.load(Ordering::Acquire) {
            return None;
        }
        let mut slot = self.compliance.try_lock().ok()?;
        // Cleared under the lock `give_compliance` sets it under: a newer one is never missed.
        self.compliance_ready.store(false, Ordering::Release);
        slot.take()
    }

    /// Called by the control plane: the scene thread switches to `desc` after its current frame
    /// (or its current preparation). A newer request replaces one not yet taken.
    pub fn request_scene(&self, desc: SceneDesc) {
        match self.scene_request.lock() {
            Ok(mut slot) => *slot = Some(desc),
            Err(poisoned) => *poisoned.into_inner() = Some(desc),
        }
    }

    /// Called by the scene thread between frames (never waits).
    fn take_scene_request(&self) -> Option<SceneDesc> {
        self.scene_request
            .try_lock()
            .ok()
            .and_then(|mut r| r.take())
    }

    fn give_compliance(&self, c: Box<dyn CavityCompliance>) {
        if let Ok(mut slot) = self.compliance.lock() {
            *slot = Some(c);
            self.compliance_ready.store(true, Ordering::Release);
        }
    }
}

/// The loop stage that copies the scene's figures into every status (it steps nothing).
pub struct SceneStatusStage(pub Arc<SceneFeed>);

impl LoopStage for SceneStatusStage {
    fn name(&self) -> &'static str {
        "scene-status"
    }
    fn step(&mut self, _inputs: &SimInputs, _dt_s: f64) {}
    fn write_status(&self, status: &mut Status) {
        self.0.figures.write_status(status);
    }
}

/// What the scene thread runs.
pub struct SceneSettings {
    /// The scene.
    pub desc: SceneDesc,
    /// The atlas cache directory.
    pub cache_dir: Option<PathBuf>,
    /// Frames per second.
    pub rate_hz: f64,
    /// Service names.
    pub names: ServiceNames,
}

/// Figures of the scene thread the supervisor logs.
#[derive(Debug, Default)]
pub struct SceneLog {
    /// Rig-sample-to-flow-field latency: for every published flow field, the age of the newest
    /// rig sample it reflects (samples superseded before a scene frame are reflected by none).
    pub flow_latency: Mutex<LatencyHistogram>,
    /// Flow fields published.
    pub flows_published: AtomicU64,
    /// Positions published.
    pub positions_published: AtomicU64,
    /// Failed loans or sends.
    pub publish_errors: AtomicU64,
    /// Atlas build progress: levels done (of `atlas_levels`).
    pub atlas_levels_done: AtomicU64,
    /// Levels of the atlas being built (0 when not building).
    pub atlas_levels: AtomicU64,
}

impl SceneLog {
    /// The flow latency summary.
    pub fn flow_latency(&self) -> LatencySummary {
        self.flow_latency
            .lock()
            .map(|h| h.summary())
            .unwrap_or(LatencySummary::EMPTY)
    }
}

/// The running scene thread.
pub struct SceneThread {
    handle: JoinHandle<()>,
    /// Figures for the log.
    pub log: Arc<SceneLog>,
}

impl SceneThread {
    /// Starts the thread; it sets the `preparing` state at once.
    pub fn spawn(
        settings: SceneSettings,
        feed: Arc<SceneFeed>,
        telemetry: Arc<Telemetry>,
        stop: Arc<AtomicBool>,
    ) -> anyhow::Result<Self> {
        feed.figures.set_state(scene_state::PREPARING);
        let log = Arc::new(SceneLog::default());
        let handle = {
            let log = log.clone();
            std::thread::Builder::new()
                .name("hm-scene".into())
                .spawn(move || {
                    // The scene must never compete with the 1 kHz loop at real-time priority.
                    if let Err(e) = super::realtime::set_current_thread_normal() {
                        tracing::warn!("hm-scene: {e}");
                    }
                    if let Err(e) = run(settings, &feed, &telemetry, &stop, &log) {
                        feed.figures.set_state(scene_state::FAILED);
                        tracing::error!("scene stopped: {e:#}; status and hydraulics go on");
                    }
                })?
        };
        Ok(Self { handle, log })
    }

    /// Whether the thread has ended.
    pub fn is_finished(&self) -> bool {
        self.handle.is_finished()
    }

    /// Waits for the thread, unless it is still building an atlas (which cannot be interrupted:
    /// the process exit ends it; the cache file is written by rename, never half).
    pub fn join(self, feed: &SceneFeed) {
        if feed.figures.state() == scene_state::PREPARING {
            tracing::info!("abandoning the atlas build (it starts again on the next start)");
            return;
        }
        if self.handle.join().is_err() {
            tracing::error!("scene thread panicked");
        }
    }
}

/// The scene's publishers and its notifier (iceoryx2 ports are not `Send`: they live here).
struct Ports {
    _node: iceoryx2::node::Node<ipc::Service>,
    topology: Publisher<ipc::Service, [u32], MeshTopologyHeader>,
    positions: Publisher<ipc::Service, [f32], MeshPositionsHeader>,
    flow: Publisher<ipc::Service, [u8], FlowFieldHeader>,
    particles: Publisher<ipc::Service, [hydrometra_ipc::particles::Particle], ParticlesHeader>,
    notifier: iceoryx2::port::notifier::Notifier<ipc::Service>,
}

fn publisher<K: SliceService>(
    node: &iceoryx2::node::Node<ipc::Service>,
    names: &ServiceNames,
    max_len: usize,
) -> anyhow::Result<Publisher<ipc::Service, [K::Element], K::Header>> {
    let service = slice::create::<K, _>(node, names)
        .map_err(|e| anyhow::anyhow!("{}: {e}", names.full(K::SUFFIX)))?;
    service
        .publisher_builder()
        .initial_max_slice_len(max_len.max(1))
        // Sized once from the scene: never grows (so /dev/shm use is known up front).
        .allocation_strategy(AllocationStrategy::Static)
        .backpressure_strategy(BackpressureStrategy::DiscardData)
        .max_loaned_samples(MAX_LOANED)
        .create()
        .map_err(|e| {
            anyhow::anyhow!(
                "cannot publish on {}: {e:?} (another hydrometrad on this prefix?)",
                names.full(K::SUFFIX)
            )
        })
}

fn ports(
    names: &ServiceNames,
    vertices: usize,
    triangles: usize,
    cells: usize,
    particles: usize,
) -> anyhow::Result<Ports> {
    let needs = [
        (
            "cavity/topology",
            slice::shared_memory_bytes::<slice::Topology>(3 * triangles),
        ),
        (
            "cavity/positions",
            slice::shared_memory_bytes::<slice::Positions>(3 * vertices),
        ),
        (
            "flow",
            slice::shared_memory_bytes::<slice::Flow>(FlowLayout::new(cells).total_bytes),
        ),
        (
            "particles",
            slice::shared_memory_bytes::<slice::Particles>(particles),
        ),
    ];
    let reserved = super::shm::daemon_services().iter().map(|s| s.1).sum();
    super::shm::check(
        std::path::Path::new(super::shm::SHM_DIR),
        "the scene's services",
        &needs,
        reserved,
    )?;
    let node_name = NodeName::new("hydrometrad-scene").map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let node = NodeBuilder::new()
        .name(&node_name)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .map_err(|e| anyhow::anyhow!("cannot create the scene's iceoryx2 node: {e:?}"))?;
    let topology = publisher::<slice::Topology>(&node, names, 3 * triangles)?;
    let positions = publisher::<slice::Positions>(&node, names, 3 * vertices)?;
    let flow = publisher::<slice::Flow>(&node, names, FlowLayout::new(cells).total_bytes)?;
    let particles = publisher::<slice::Particles>(&node, names, particles)?;
    let notifier = events::create(&node, names)
        .map_err(|e| anyhow::anyhow!("{}: {e:?}", names.full("events")))?
        .notifier_builder()
        .create()
        .map_err(|e| anyhow::anyhow!("cannot create the scene's event notifier: {e:?}"))?;
    Ok(Ports {
        _node: node,
        topology,
        positions,
        flow,
        particles,
        notifier,
    })
}

fn rig_inputs(s: &FeedSnapshot) -> RigInputs {
    let i = &s.inputs;
    RigInputs {
        hydraulic: HydraulicInputs {
            valve_in_opening: i.valve_in_opening,
            valve_out_opening: i.valve_out_opening,
            pump_set_pressure_pa: i.pump_set_pressure_pa,
            perforation: s.perforation,
        },
        scope: ScopePose {
            tip_position_m: i.scope.tip_position_m,
            view_direction: i.scope.view_direction,
            valid: i.scope.valid,
        },
    }
}

/// Why a scene's frames ended.
enum SceneEnd {
    /// The daemon stops.
    Stop,
    /// The control plane asked for another scene.
    Load(Box<SceneDesc>),
}

/// Runs the configured scene, then every scene the control plane asks for. A scene that fails
/// to prepare leaves the state `failed` until the next request (status and hydraulics go on).
fn run(
    settings: SceneSettings,
    feed: &SceneFeed,
    telemetry: &Telemetry,
    stop: &AtomicBool,
    log: &SceneLog,
) -> anyhow::Result<()> {
    let SceneSettings {
        desc,
        cache_dir,
        rate_hz,
        names,
    } = settings;
    let mut next = Some(desc);
    // Topology revisions go on across scenes, so a renderer sees every switch as a change.
    let mut revision_base = 0u64;
    while !stop.load(Ordering::Relaxed) {
        let Some(desc) = next.take().or_else(|| feed.take_scene_request()) else {
            std::thread::sleep(Duration::from_millis(50));
            continue;
        };
        feed.figures.set_state(scene_state::PREPARING);
        let name = desc.name.clone();
        match run_scene(
            desc,
            cache_dir.as_deref(),
            rate_hz,
            &names,
            (feed, telemetry, stop, log),
            &mut revision_base,
        ) {
            Ok(SceneEnd::Stop) => break,
            Ok(SceneEnd::Load(desc)) => {
                tracing::info!(from = %name, to = %desc.name, "switching the scene");
                next = Some(*desc);
            }
            Err(e) => {
                feed.figures.set_state(scene_state::FAILED);
                tracing::error!(
                    scene = %name,
                    "scene stopped: {e:#}; status and hydraulics go on (load another scene with \
                     `hydrometra control load-scene`)"
                );
            }
        }
    }
    feed.figures.set_state(scene_state::NONE);
    Ok(())
}

/// Prepares one scene and steps it until the daemon stops or another scene is asked for; its
/// services live as long as this call.
fn run_scene(
    desc: SceneDesc,
    cache_dir: Option<&std::path::Path>,
    rate_hz: f64,
    names: &ServiceNames,
    (feed, telemetry, stop, log): (&SceneFeed, &Telemetry, &AtomicBool, &SceneLog),
    revision_base: &mut u64,
) -> anyhow::Result<SceneEnd> {
    let started = Instant::now();
    tracing::info!(
        scene = %desc.name,
        key = %desc.atlas_key(),
        cache = ?cache_dir,
        "preparing the scene (a missing atlas is built now: 1-3 min on 2 cores)"
    );
    log.atlas_levels
        .store(desc.atlas.levels as u64, Ordering::Relaxed);
    let mut progress = |done: usize, total: usize, p_pa: f64, v_m3: f64| {
        log.atlas_levels_done.store(done as u64, Ordering::Relaxed);
        tracing::info!(
            "building the atlas: level {done}/{total}, {:.1} mmHg, cavity {:.2} ml",
            hydrometra_sim::units::pa_to_mmhg(p_pa),
            v_m3 * 1e6
        );
    };
    let (assets, source) = prepare::load_or_build(&desc, cache_dir, &mut progress)?;
    match &source {
        prepare::AtlasSource::Built {
            cached,
            cache_problem,
        } => tracing::info!(
            cached = ?cached,
            why = cache_problem.as_deref().unwrap_or("no cache directory"),
            seconds = started.elapsed().as_secs_f64(),
            "atlas built"
        ),
        other => tracing::info!(source = ?other, "atlas loaded"),
    }
    // One source of truth for V(p): the 1 kHz hydraulics switch to the atlas's P-V curve.
    feed.give_compliance(Box::new(assets.compliance()?));
    let mut scene = Scene::new(desc, assets)?;
    let (vertices, triangles) = {
        let c = scene.cavity();
        (c.positions_m.len(), c.triangles.len())
    };
    let cells = scene.cells().cell_count();
    let max_particles = if scene.particles().is_some() {
        scene.desc().particles.budget.min(PARTICLES_PUBLISHED_MAX)
    } else {
        0
    };
    let ports = ports(names, vertices, triangles, cells, max_particles)?;
    tracing::info!(
        vertices,
        triangles,
        cells,
        flow_bytes = FlowLayout::new(cells).total_bytes,
        seconds = started.elapsed().as_secs_f64(),
        "scene ready; publishing cavity/topology, cavity/positions, flow, particles"
    );

    let period = Duration::from_secs_f64(1.0 / rate_hz);
    let mut velocities = vec![[0.0f32; 3]; cells];
    let mut flow_payload = Vec::with_capacity(FlowLayout::new(cells).total_bytes);
    let mut published_revision = None;
    let mut flow_ever = false;
    let mut last_reflected: Option<Instant> = None;
    let mut last_time_s: Option<f64> = None;
    let mut sim_time_s = 0.0;
    let mut pacer = Pacer::new(period, Instant::now());
    let end = loop {
        if stop.load(Ordering::Relaxed) {
            break SceneEnd::Stop;
        }
        if let Some(desc) = feed.take_scene_request() {
            break SceneEnd::Load(Box::new(desc));
        }
        let now = Instant::now();
        if now < pacer.next_due() {
            std::thread::sleep(pacer.next_due() - now);
        }
        let snapshot = feed.latest();
        let began = Instant::now();
        let (late, slot) = pacer.begin(began, snapshot.map_or(0, |s| s.offers));
        feed.figures.write_pace(&pacer);
        let (Some(snapshot), Slot::Step) = (snapshot, slot) else {
            // The loop advanced no time since the last frame (or has not ticked yet): nothing
            // new to show, and a frame is never published twice.
            continue;
        };
        // The scene follows the hydraulics' clock, so dt is what the hydraulics advanced.
        let dt_s = match last_time_s {
            Some(t) => (snapshot.hydraulics.time_s - t).max(0.0),
            None => period.as_secs_f64(),
        };
        last_time_s = Some(snapshot.hydraulics.time_s);
        sim_time_s += dt_s;
        let frame_late_s = late.as_secs_f64();
        let inputs = SceneInputs {
            rig: rig_inputs(&snapshot),
            hydraulics: HydraulicsInput::External(&snapshot.hydraulics),
        };
        let status_sequence = telemetry
            .statuses_published
            .load(Ordering::Relaxed)
            .saturating_sub(1);
        let has_particles = scene.particles().is_some();
        let report = match scene.step(&inputs, dt_s) {
            Ok(r) => r,
            Err(e) => {
                let n = log.publish_errors.fetch_add(1, Ordering::Relaxed);
                if n < 10 {
                    tracing::warn!("scene step failed: {e}");
                }
                continue;
            }
        };
        let fluid_ran = report.counters.get(Stage::Fluid).ran_last;
        let surface_volume_m3 = report.surface_volume_m3;
        write_figures(&feed.figures, report, has_particles);
        if let Some(clarity) = scene.particles().and_then(|p| p.clarity()) {
            feed.figures
                .view_clarity_bits
                .store(clarity.to_bits(), Ordering::Relaxed);
        }
        feed.figures
            .surface_volume_m3_bits
            .store(surface_volume_m3.to_bits(), Ordering::Relaxed);

        let cavity = scene.cavity();
        let errors = &log.publish_errors;
        // Hands the history sample (the topology, the last flow field) to subscribers that came
        // since the last send: a publisher that sends rarely must do it itself.
        for updated in [
            ports.topology.update_connections(),
            ports.flow.update_connections(),
        ] {
            if updated.is_err() {
                errors.fetch_add(1, Ordering::Relaxed);
            }
        }
        if published_revision != Some(cavity.topology_revision) {
            let tris = cavity.triangles;
            let sent = ports
                .topology
                .loan_slice_uninit(3 * tris.len())
                .map(|mut sample| {
                    *sample.user_header_mut() = MeshTopologyHeader {
                        schema_version: SCHEMA_VERSION,
                        vertex_count: cavity.positions_m.len() as u32,
                        triangle_count: tris.len() as u32,
                        reserved0: 0,
                        topology_revision: *revision_base + cavity.topology_revision,
                    };
                    sample.write_from_fn(|n| tris[n / 3][n % 3])
                })
                .map_err(|e| format!("{e:?}"))
                .and_then(|s| s.send().map_err(|e| format!("{e:?}")));
            if count(sent, errors, "cavity/topology") {
                published_revision = Some(cavity.topology_revision);
                notify(&ports, events::MESH_TOPOLOGY, errors);
            }
        }
        let pos = cavity.positions_m;
        let sent = ports
            .positions
            .loan_slice_uninit(3 * pos.len())
            .map(|mut sample| {
                *sample.user_header_mut() = MeshPositionsHeader {
                    schema_version: SCHEMA_VERSION,
                    vertex_count: pos.len() as u32,
                    status_sequence,
                    sim_time_s,
                    topology_revision: *revision_base + cavity.topology_revision,
                    cavity_pressure_pa: cavity.pressure_pa,
                    scene_frame: pacer.frames,
                    frame_late_s,
                };
                sample.write_from_fn(|n| pos[n / 3][n % 3])
            })
            .map_err(|e| format!("{e:?}"))
            .and_then(|s| s.send().map_err(|e| format!("{e:?}")));
        if count(sent, errors, "cavity/positions") {
            log.positions_published.fetch_add(1, Ordering::Relaxed);
            notify(&ports, events::MESH_POSITIONS, errors);
        }

        if let Some(flow) = scene.flow().filter(|_| fluid_ran || !flow_ever) {
            flow.velocities_into(&mut velocities);
            let kinds = flow.kinds();
            let dims = flow.dims();
            let layout = FlowLayout::new(kinds.len());
            let v = &velocities;
            let mut header = FlowFieldHeader {
                schema_version: SCHEMA_VERSION,
                dims: dims.map(|d| d as u32),
                origin_m: flow.first_centre_m(),
                spacing_m: flow.spacing_m(),
                status_sequence,
                sim_time_s,
                scene_frame: pacer.frames,
                frame_late_s,
                ..FlowFieldHeader::default()
            };
            layout.write_offsets(&mut header);
            layout.fill(
                &mut flow_payload,
                |c| kinds.get(c).map_or(0, |k| *k as u8),
                |c| v.get(c).copied().unwrap_or_default(),
                |c| fraction_to_u8(flow.fluid_fraction(c)),
            );
            let sent = ports
                .flow
                .loan_slice_uninit(layout.total_bytes)
                .map(|mut sample| {
                    *sample.user_header_mut() = header;
                    // `fill` sizes the payload to the layout the sample was loaned with.
                    sample.write_from_slice(&flow_payload)
                })
                .map_err(|e| format!("{e:?}"))
                .and_then(|s| s.send().map_err(|e| format!("{e:?}")));
            if count(sent, errors, "flow") {
                flow_ever = true;
                log.flows_published.fetch_add(1, Ordering::Relaxed);
                notify(&ports, events::FLOW_FIELD, errors);
                let reflected = snapshot.inputs.sample_received_at;
                if fluid_ran && reflected.is_some() && reflected != last_reflected {
                    last_reflected = reflected;
                    if let (Some(at), Ok(mut h)) = (reflected, log.flow_latency.lock()) {
                        h.record(at.elapsed());
                    }
                }
            }
        }

        // Particles: every alive one, or an evenly spaced subset of PARTICLES_PUBLISHED_MAX
        // (empty frames for a scene without the particle stage).
        let view_clarity = f64::from_bits(feed.figures.view_clarity_bits.load(Ordering::Relaxed));
        let system = scene.particles().and_then(|p| p.system());
        let alive = system.map_or(0, |s| s.len());
        let published = alive.min(max_particles);
        let sent = ports
            .particles
            .loan_slice_uninit(published)
            .map(|mut sample| {
                *sample.user_header_mut() = ParticlesHeader {
                    schema_version: SCHEMA_VERSION,
                    particle_count: published as u32,
                    status_sequence,
                    sim_time_s,
                    view_clarity,
                    scene_frame: pacer.frames,
                    frame_late_s,
                };
                sample.write_from_fn(|i| match system {
                    Some(s) => {
                        let n = i * alive / published.max(1);
                        let (p, v) = (s.position_m(n), s.velocity_m_per_s(n));
                        hydrometra_ipc::particles::Particle {
                            position_m: p.map(|x| x as f32),
                            velocity_m_per_s: v.map(|x| x as f32),
                            kind: s.class_of(n).kind as u32,
                            age_s: s.age_s(n) as f32,
                        }
                    }
                    None => hydrometra_ipc::particles::Particle::default(),
                })
            })
            .map_err(|e| format!("{e:?}"))
            .and_then(|s| s.send().map_err(|e| format!("{e:?}")));
        if count(sent, errors, "particles") {
            notify(&ports, events::PARTICLES, errors);
        }
        if let Some(level) = pacer.end(began.elapsed(), Instant::now()) {
            if let Err(e) = scene.set_quality(scene_pace::quality_at(level)) {
                tracing::warn!(level, error = %e, "could not set the scene's quality");
            }
            tracing::info!(
                level,
                period_ms = pacer.period().as_secs_f64() * 1e3,
                "scene frames {} their period: degradation level {level} (docs/daemon.md, \"Overload\")",
                if level > 0 { "overrun" } else { "fit" }
            );
        }
        feed.figures.write_pace(&pacer);
    };
    *revision_base += scene.cavity().topology_revision;
    Ok(end)
}

/// Counts a failed publication (logged the first times only); true when it was sent.
fn count<T>(sent: Result<T, String>, errors: &AtomicU64, service: &str) -> bool {
    match sent {
        Ok(_) => true,
        Err(e) => {
            let n = errors.fetch_add(1, Ordering::Relaxed);
            if n < 10 || n.is_multiple_of(1000) {
                tracing::warn!(service, error = %e, "could not publish");
            }
            false
        }
    }
}

fn notify(ports: &Ports, id: iceoryx2::port::event_id::EventId, errors: &AtomicU64) {
    // A listener that stalls only loses wake-ups: notify never blocks.
    if ports.notifier.notify_with_custom_event_id(id).is_err() {
        errors.fetch_add(1, Ordering::Relaxed);
    }
}

fn write_figures(f: &SceneFigures, report: &hydrometra_sim::scene::StepReport, particles: bool) {
    let c = &report.counters;
    for (k, stage) in Stage::ALL.iter().enumerate().take(STAGES) {
        let s = c.get(*stage);
        // The p99 (a selection over the recent runs) changes only when the stage ran: at rest
        // most stages skip every frame.
        if f.runs[k].swap(s.runs, Ordering::Relaxed) != s.runs {
            f.p99_s_bits[k].store((s.p99_ms() * 1e-3).to_bits(), Ordering::Relaxed);
        }
        f.skips[k].store(s.skips, Ordering::Relaxed);
    }
    f.step_p99_s_bits
        .store((c.step.p99_ms() * 1e-3).to_bits(), Ordering::Relaxed);
    // Before the frame count: a status that shows this frame's count shows its open fraction.
    f.inflow_open_fraction_bits.store(
        report.flux.inflow_open_fraction.to_bits(),
        Ordering::Relaxed,
    );
    f.frames.store(report.frame, Ordering::Relaxed);
    let fluid = c.get(Stage::Fluid);
    let state = if fluid.present && fluid.ran_last {
        scene_state::RUNNING
    } else {
        scene_state::IDLE
    };
    f.set_state(state);
    if !particles {
        f.view_clarity_bits
            .store(f64::NAN.to_bits(), Ordering::Relaxed);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_loop_takes_each_compliance_once_and_never_misses_a_newer_one() {
        use hydrometra_sim::hydraulics::LinearCompliance;
        let feed = SceneFeed::default();
        let curve = |volume_at_zero_m3: f64| {
            Box::new(LinearCompliance {
                volume_at_zero_m3,
                compliance_m3_per_pa: 1e-10,
            })
        };
        assert!(feed.take_compliance().is_none());
        feed.give_compliance(curve(1e-6));
        // A busy slot leaves it for the next tick.
        let guard = feed.compliance.lock().unwrap();
        assert!(feed.take_compliance().is_none());
        drop(guard);
        let first = feed.take_compliance().expect("the atlas's compliance");
        assert_eq!(first.volume_m3(0.0), 1e-6);
        assert!(feed.take_compliance().is_none(), "taken once");
        // A newer scene's curve is taken too.
        feed.give_compliance(curve(2e-6));
        let second = feed.take_compliance().expect("the newer compliance");
        assert_eq!(second.volume_m3(0.0), 2e-6);
        assert!(feed.take_compliance().is_none());
    }

    #[test]
    fn the_loop_never_waits_for_the_feed() {
        let feed = SceneFeed::default();
        let inputs = crate::service::sim::inputs_from(
            &crate::service::rig_source::RigView::disconnected(),
            Duration::from_millis(100),
        );
        let h = HydraulicState::default();
        feed.offer(&inputs, &h, false);
        assert_eq!(feed.latest().map(|s| s.offers), Some(1));
        // While the scene holds the slot, an offer returns at once and is dropped.
        let guard = feed.snapshot.lock().unwrap();
        feed.offer(&inputs, &h, true);
        drop(guard);
        let s = feed.latest().unwrap();
        assert_eq!((s.offers, s.perforation), (1, false));
        feed.offer(&inputs, &h, true);
        assert_eq!(
            feed.latest().map(|s| (s.offers, s.perforation)),
            Some((2, true))
        );
    }
}
