//! Following a daemon's iceoryx2 services from outside its real-time loop: a thread subscribes to
//! status and, while a scene runs, to the cavity, flow and particle services, and hands the newest
//! samples to a [`Sink`] at the sink's rates. It re-opens what goes away (a restarted daemon, a new
//! scene) and never holds the daemon up: the daemon's publishers drop samples for a subscriber
//! that falls behind (docs/ipc.md, "Quality of service").

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use hydrometra_ipc::field::FlowFieldHeader;
use hydrometra_ipc::mesh::{MeshPositionsHeader, MeshTopologyHeader};
use hydrometra_ipc::particles::{Particle, ParticlesHeader};
use hydrometra_ipc::slice::{self, Flow, Particles, Positions, SliceService, Topology};
use hydrometra_ipc::status::scene_state;
use hydrometra_ipc::{status, ServiceNames, Status};
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;

/// How often the thread looks for new samples: well inside the status subscriber's buffer (64 at
/// 1 kHz) and a small share of a 100 ms budget from rig sample to screen.
pub const POLL: Duration = Duration::from_millis(4);
/// Without a status for this long the daemon is taken as gone and the services are re-opened.
pub const SILENCE: Duration = Duration::from_secs(3);
/// How often a missing service is looked for again.
pub const RETRY: Duration = Duration::from_secs(1);

/// Where the samples go.
pub trait Sink {
    /// Every status received; `due` when one is due at the status rate (the newest of a batch).
    fn status(&mut self, s: &Status, due: bool);
    /// The cavity topology, whenever its revision changes.
    fn topology(&mut self, h: &MeshTopologyHeader, indices: &[u32]);
    /// The newest positions, when due and [`Sink::wants_scene`].
    fn positions(&mut self, h: &MeshPositionsHeader, xyz: &[f32]);
    /// The newest flow field, when due (always: it goes quiet while the fluid rests).
    fn flow(&mut self, h: &FlowFieldHeader, bytes: &[u8]);
    /// The newest particles (`particle_count` of them), when due and [`Sink::wants_scene`].
    fn particles(&mut self, h: &ParticlesHeader, particles: &[Particle]);
    /// Whether positions and particles are wanted now (skipped, and counted by the sink, if not).
    fn wants_scene(&self) -> bool {
        true
    }
    /// A due positions or particle sample was skipped because nobody wanted it.
    fn skipped(&mut self) {}
    /// The daemon's services were (re)opened.
    fn connected(&mut self) {}
}

/// Rates at which samples are handed on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FollowRates {
    /// Statuses per second marked `due`.
    pub status_hz: f64,
    /// Positions and particles per second.
    pub scene_hz: f64,
    /// Flow fields per second.
    pub flow_hz: f64,
}

/// When the next sample of one kind is due, at most `hz` per second.
pub struct Pace {
    period: Duration,
    next: Instant,
}

impl Pace {
    /// Due at once, then every `1 / hz` s.
    pub fn new(hz: f64) -> Self {
        Self {
            period: Duration::from_secs_f64(1.0 / hz.max(0.1)),
            next: Instant::now(),
        }
    }

    /// Whether a sample is due at `now` (and if so, when the next one is).
    pub fn due(&mut self, now: Instant) -> bool {
        if now < self.next {
            return false;
        }
        // On the grid when on time; a period from now when late (no burst to catch up).
        let grid = self.next + self.period;
        self.next = if grid > now { grid } else { now + self.period };
        true
    }
}

type SliceSub<K> =
    Subscriber<ipc::Service, [<K as SliceService>::Element], <K as SliceService>::Header>;

struct SceneSubs {
    topology: SliceSub<Topology>,
    positions: SliceSub<Positions>,
    flow: SliceSub<Flow>,
    particles: SliceSub<Particles>,
}

fn open_scene(node: &Node<ipc::Service>, names: &ServiceNames) -> Option<SceneSubs> {
    fn sub<K: SliceService>(
        node: &Node<ipc::Service>,
        names: &ServiceNames,
    ) -> Option<SliceSub<K>> {
        slice::open::<K, _>(node, names)
            .ok()?
            .subscriber_builder()
            .create()
            .ok()
    }
    Some(SceneSubs {
        topology: sub::<Topology>(node, names)?,
        positions: sub::<Positions>(node, names)?,
        flow: sub::<Flow>(node, names)?,
        particles: sub::<Particles>(node, names)?,
    })
}

/// Follows the daemon on `names` until `stop`, re-opening its services whenever they go away.
/// Runs on the calling thread (iceoryx2 ports are not `Send`).
pub fn run(names: &ServiceNames, rates: FollowRates, sink: &mut dyn Sink, stop: &AtomicBool) {
    let node = match NodeBuilder::new()
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
    {
        Ok(n) => n,
        Err(e) => {
            tracing::error!(error = ?e, prefix = names.prefix(), "cannot create an iceoryx2 node");
            return;
        }
    };
    while !stop.load(Ordering::Relaxed) {
        if let Err(why) = follow_run(&node, names, &rates, sink, stop) {
            tracing::info!(prefix = names.prefix(), "{why}; retrying");
        }
        std::thread::sleep(RETRY);
    }
}

/// The newest sample of a slice subscriber, if any arrived.
macro_rules! newest {
    ($sub:expr) => {{
        let mut last = None;
        while let Some(s) = $sub.receive().map_err(|e| format!("{e:?}"))? {
            last = Some(s);
        }
        last
    }};
}

/// Follows one daemon run until it goes silent or `stop`.
fn follow_run(
    node: &Node<ipc::Service>,
    names: &ServiceNames,
    rates: &FollowRates,
    sink: &mut dyn Sink,
    stop: &AtomicBool,
) -> Result<(), String> {
    let status_sub = status::open(node, names)
        .map_err(|e| format!("no status service ({e:?})"))?
        .subscriber_builder()
        .create()
        .map_err(|e| format!("cannot subscribe to status ({e:?})"))?;
    sink.connected();
    tracing::info!(prefix = names.prefix(), "following hydrometrad");
    let mut scene: Option<SceneSubs> = None;
    let mut next_scene_try = Instant::now();
    let mut run_id = None;
    let mut last_status = Instant::now();
    let mut revision = None;
    let mut status_pace = Pace::new(rates.status_hz);
    let mut paces = [
        Pace::new(rates.scene_hz),
        Pace::new(rates.flow_hz),
        Pace::new(rates.scene_hz),
    ];
    while !stop.load(Ordering::Relaxed) {
        let now = Instant::now();
        let mut newest: Option<Status> = None;
        while let Some(sample) = status_sub
            .receive()
            .map_err(|e| format!("status receive failed ({e:?})"))?
        {
            if let Some(previous) = newest.replace(*sample) {
                sink.status(&previous, false);
            }
        }
        match newest {
            Some(s) => {
                last_status = now;
                sink.status(&s, status_pace.due(now));
                if run_id.replace(s.run_id).is_some_and(|r| r != s.run_id) {
                    scene = None; // a restarted daemon re-creates its services
                    revision = None;
                }
                let live = matches!(s.scene_state, scene_state::RUNNING | scene_state::IDLE);
                if !live {
                    scene = None;
                } else if scene.is_none() && now >= next_scene_try {
                    scene = open_scene(node, names);
                    next_scene_try = now + RETRY;
                }
            }
            None if now.duration_since(last_status) > SILENCE => {
                return Err("no status for 3 s".into());
            }
            None => {}
        }
        if let Some(subs) = &scene {
            let due = paces.each_mut().map(|p| p.due(now));
            if let Err(e) = hand_on(subs, sink, &mut revision, due) {
                tracing::info!(
                    prefix = names.prefix(),
                    "scene services lost ({e}); re-opening"
                );
                scene = None;
            }
        }
        std::thread::sleep(POLL);
    }
    Ok(())
}

/// Hands the newest scene samples to the sink: the topology on a new revision, the others when
/// `due` (positions, flow, particles).
fn hand_on(
    subs: &SceneSubs,
    sink: &mut dyn Sink,
    revision: &mut Option<u64>,
    due: [bool; 3],
) -> Result<(), String> {
    if let Some(s) = newest!(subs.topology) {
        let h = *s.user_header();
        if *revision != Some(h.topology_revision) {
            *revision = Some(h.topology_revision);
            sink.topology(&h, s.payload());
        }
    }
    let wanted = sink.wants_scene();
    if let Some(s) = newest!(subs.positions) {
        match (due[0], wanted) {
            (true, true) => sink.positions(s.user_header(), s.payload()),
            (true, false) => sink.skipped(),
            _ => {}
        }
    }
    if let Some(s) = newest!(subs.flow) {
        if due[1] {
            sink.flow(s.user_header(), s.payload());
        }
    }
    if let Some(s) = newest!(subs.particles) {
        let n = (s.user_header().particle_count as usize).min(s.payload().len());
        match (due[2], wanted) {
            (true, true) => sink.particles(s.user_header(), &s.payload()[..n]),
            (true, false) => sink.skipped(),
            _ => {}
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pace_keeps_its_grid_and_never_bursts_after_a_stall() {
        let mut p = Pace::new(10.0);
        let t0 = p.next;
        assert!(p.due(t0));
        assert!(!p.due(t0 + Duration::from_millis(50)));
        assert!(p.due(t0 + Duration::from_millis(100)));
        // A stall of 1 s: one sample, then the grid restarts from then.
        assert!(p.due(t0 + Duration::from_millis(1100)));
        assert!(!p.due(t0 + Duration::from_millis(1150)));
        assert!(p.due(t0 + Duration::from_millis(1200)));
    }
}
