//! A rig on this machine: a thread that subscribes to a hydrometrad's iceoryx2 services (status
//! and, while a scene runs, the cavity, flow and particle services) and fills the rig's slots at
//! the page's rates; and a thread that forwards control requests to its control service.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use hydrometra_ipc::control::{self, ControlResponse};
use hydrometra_ipc::slice::{self, Flow, Particles, Positions, SliceService, Topology};
use hydrometra_ipc::status::scene_state;
use hydrometra_ipc::{status, ServiceNames, Status};
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;

use crate::frame::{self, kind};
use crate::hub::Rig;
use crate::Rates;

/// How often the source looks for new samples: well inside the status subscriber's buffer (64 at
/// 1 kHz) and a small share of the 100 ms budget from rig sample to page.
const POLL: Duration = Duration::from_millis(4);
/// Without a status for this long the daemon is taken as gone and the services are re-opened.
const SILENCE: Duration = Duration::from_secs(3);
/// How often a missing service is looked for again.
const RETRY: Duration = Duration::from_secs(1);

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

/// When the next frame of one kind is due, at most `hz` per second.
struct Pace {
    period: Duration,
    next: Instant,
}

impl Pace {
    fn new(hz: f64) -> Self {
        Self {
            period: Duration::from_secs_f64(1.0 / hz.max(0.1)),
            next: Instant::now(),
        }
    }

    fn due(&mut self, now: Instant) -> bool {
        if now < self.next {
            return false;
        }
        // On the grid when on time; a period from now when late (no burst to catch up).
        let grid = self.next + self.period;
        self.next = if grid > now { grid } else { now + self.period };
        true
    }
}

/// Starts the source thread of the daemon on `names`; it ends when `stop` is set.
pub fn spawn_source(
    names: ServiceNames,
    rig: Arc<Rig>,
    rates: Rates,
    stop: Arc<AtomicBool>,
) -> std::io::Result<JoinHandle<()>> {
    std::thread::Builder::new()
        .name(format!("station-rig{}", rig.info.index))
        .spawn(move || {
            let node = match NodeBuilder::new()
                .signal_handling_mode(SignalHandlingMode::Disabled)
                .create::<ipc::Service>()
            {
                Ok(n) => n,
                Err(e) => {
                    tracing::error!(error = ?e, "cannot create an iceoryx2 node: rig not shown");
                    return;
                }
            };
            while !stop.load(Ordering::Relaxed) {
                if let Err(why) = follow(&node, &names, &rig, &rates, &stop) {
                    tracing::info!(prefix = names.prefix(), "{why}; retrying");
                }
                std::thread::sleep(RETRY);
            }
        })
}

/// Follows one daemon run until it goes silent or `stop`.
fn follow(
    node: &Node<ipc::Service>,
    names: &ServiceNames,
    rig: &Rig,
    rates: &Rates,
    stop: &AtomicBool,
) -> Result<(), String> {
    let status_sub = status::open(node, names)
        .map_err(|e| format!("no status service ({e:?})"))?
        .subscriber_builder()
        .create()
        .map_err(|e| format!("cannot subscribe to status ({e:?})"))?;
    rig.counters.reconnects.fetch_add(1, Ordering::Relaxed);
    tracing::info!(prefix = names.prefix(), "following hydrometrad");
    let mut scene: Option<SceneSubs> = None;
    let mut next_scene_try = Instant::now();
    let mut run_id = None;
    let mut last_status = Instant::now();
    let mut topology_revision = None;
    let (mut status_pace, mut scene_pace, mut flow_pace, mut particle_pace) = (
        Pace::new(rates.status_hz),
        Pace::new(rates.scene_hz),
        Pace::new(rates.flow_hz),
        Pace::new(rates.scene_hz),
    );
    let index = rig.info.index;
    while !stop.load(Ordering::Relaxed) {
        let now = Instant::now();
        let mut newest: Option<Status> = None;
        while let Some(sample) = status_sub
            .receive()
            .map_err(|e| format!("status receive failed ({e:?})"))?
        {
            if let Some(previous) = newest.replace(*sample) {
                rig.status(&previous, false);
            }
        }
        match newest {
            Some(s) => {
                last_status = now;
                rig.status(&s, status_pace.due(now));
                if run_id.replace(s.run_id).is_some_and(|r| r != s.run_id) {
                    scene = None; // a restarted daemon re-creates its services
                    topology_revision = None;
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
            if let Err(e) = forward_scene(
                subs,
                rig,
                index,
                rates,
                &mut topology_revision,
                [
                    scene_pace.due(now),
                    flow_pace.due(now),
                    particle_pace.due(now),
                ],
            ) {
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

/// Moves the newest scene samples into the rig's slots: the topology whenever it changes, the
/// others when `due` (positions, flow, particles) and, but for the flow, only for a browser.
fn forward_scene(
    subs: &SceneSubs,
    rig: &Rig,
    index: u16,
    rates: &Rates,
    topology_revision: &mut Option<u64>,
    due: [bool; 3],
) -> Result<(), String> {
    if let Some(s) = newest!(subs.topology) {
        let h = *s.user_header();
        if *topology_revision != Some(h.topology_revision) {
            *topology_revision = Some(h.topology_revision);
            rig.put(kind::TOPOLOGY, frame::topology(index, &h, s.payload()));
        }
    }
    let wanted = rig.wanted();
    if let Some(s) = newest!(subs.positions) {
        if due[0] && wanted {
            rig.put(
                kind::POSITIONS,
                frame::positions(index, s.user_header(), s.payload()),
            );
        } else if due[0] {
            rig.counters
                .skipped_no_browser
                .fetch_add(1, Ordering::Relaxed);
        }
    }
    // The flow goes quiet while the fluid rests: its last field must wait for a later browser.
    if let Some(s) = newest!(subs.flow) {
        if due[1] {
            match crate::flow::arrows(s.user_header(), s.payload(), rates.max_arrows) {
                Ok((h, arrows)) => rig.put(kind::FLOW, frame::flow(index, &h, &arrows)),
                Err(e) => {
                    rig.counters.decode_errors.fetch_add(1, Ordering::Relaxed);
                    tracing::debug!("{e}");
                }
            }
        }
    }
    if let Some(s) = newest!(subs.particles) {
        if due[2] && wanted {
            let n = (s.user_header().particle_count as usize).min(s.payload().len());
            rig.put(
                kind::PARTICLES,
                frame::particles(
                    index,
                    s.user_header(),
                    &s.payload()[..n],
                    rates.max_particles,
                ),
            );
        }
    }
    Ok(())
}

/// One control request for a rig and where its answer goes.
pub struct ControlJob {
    /// Command code (`hydrometra_ipc::control::command`).
    pub command: u32,
    /// Its argument.
    pub argument: String,
    /// The answer, or why there is none.
    pub reply: tokio::sync::oneshot::Sender<Result<ControlResponse, String>>,
}

/// Starts the thread that sends the jobs to the daemon's control service, one at a time.
pub fn spawn_control(
    names: ServiceNames,
    jobs: std::sync::mpsc::Receiver<ControlJob>,
) -> std::io::Result<JoinHandle<()>> {
    std::thread::Builder::new()
        .name("station-control".into())
        .spawn(move || {
            let node = NodeBuilder::new()
                .signal_handling_mode(SignalHandlingMode::Disabled)
                .create::<ipc::Service>();
            for job in jobs {
                let answer = match &node {
                    Ok(node) => control::request(
                        node,
                        &names,
                        job.command,
                        &job.argument,
                        control::RESPONSE_TIMEOUT,
                    )
                    .map_err(|e| e.to_string()),
                    Err(e) => Err(format!("cannot create an iceoryx2 node: {e:?}")),
                };
                let _ = job.reply.send(answer);
            }
        })
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
        // A stall of 1 s: one frame, then the grid restarts from then.
        assert!(p.due(t0 + Duration::from_millis(1100)));
        assert!(!p.due(t0 + Duration::from_millis(1150)));
        assert!(p.due(t0 + Duration::from_millis(1200)));
    }
}
