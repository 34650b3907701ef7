//! The daemon's side of the classroom: a thread of its own (not real-time, its own zenoh
//! runtime) that follows the daemon's iceoryx2 services like any renderer and publishes decimated
//! copies to zenoh, congestion control "drop": a stalled network loses copies, it never reaches
//! back into the daemon. Control requests from the network are answered only with
//! `allow_control`, one at a time, through the daemon's own control service.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, TrySendError};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use hydrometra_ipc::control::{self, result, ControlRequest, ControlResponse};
use hydrometra_ipc::field::FlowFieldHeader;
use hydrometra_ipc::mesh::{MeshPositionsHeader, MeshTopologyHeader};
use hydrometra_ipc::particles::{Particle, ParticlesHeader};
use hydrometra_ipc::{ServiceNames, Status};
use iceoryx2::prelude::*;
use zenoh::pubsub::Publisher;
use zenoh::qos::CongestionControl;
use zenoh::query::Query;
use zenoh::Wait;

use crate::config::RemoteConfig;
use crate::follow::{self, FollowRates, Sink};
use crate::keys::{self, service};
use crate::session::{self, SessionSettings};
use crate::wire::{bytes_of, encode_slice, read_exact};

/// The topology is re-published this often, for stations that join later.
pub const TOPOLOGY_REPEAT: Duration = Duration::from_secs(2);
/// Control requests waiting for the daemon at most; more are answered `busy`.
pub const CONTROL_QUEUE: usize = 4;

/// The running forwarder; stops on drop.
pub struct Forwarder {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl Drop for Forwarder {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The session settings of a `[remote]` section.
pub fn settings(c: &RemoteConfig) -> SessionSettings {
    SessionSettings {
        mode: c.mode,
        connect: c.connect.clone(),
        listen: c.listen.clone(),
        multicast_scouting: c.multicast_scouting,
        config_file: c.zenoh_config.clone(),
    }
}

/// Starts forwarding the daemon's services on `names` as `config` says.
pub fn spawn(config: RemoteConfig, names: ServiceNames) -> std::io::Result<Forwarder> {
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    let thread = std::thread::Builder::new()
        .name("remote-zenoh".into())
        .spawn(move || {
            let zenoh = match session::open(&settings(&config)) {
                Ok(s) => s,
                Err(e) => {
                    tracing::error!("remote: {e}; the services are not published to zenoh");
                    return;
                }
            };
            tracing::info!(
                rig = config.rig_id,
                root = config.key_root,
                "remote: publishing to zenoh"
            );
            let _control = config
                .allow_control
                .then(|| serve_control(&zenoh, &config, &names))
                .flatten();
            let mut sink = ZenohSink::new(&zenoh, &config);
            let rates = FollowRates {
                status_hz: config.status_rate_hz,
                scene_hz: config.scene_rate_hz,
                flow_hz: config.flow_rate_hz,
            };
            follow::run(&names, rates, &mut sink, &flag);
            drop(sink);
            let _ = zenoh.close().wait();
        })?;
    Ok(Forwarder {
        stop,
        thread: Some(thread),
    })
}

struct ZenohSink {
    status: Option<Publisher<'static>>,
    topology: Option<Publisher<'static>>,
    positions: Option<Publisher<'static>>,
    flow: Option<Publisher<'static>>,
    particles: Option<Publisher<'static>>,
    last_topology: Option<(Vec<u8>, Instant)>,
    put_errors: u64,
}

impl ZenohSink {
    fn new(zenoh: &zenoh::Session, c: &RemoteConfig) -> Self {
        let publisher = |name: &str, svc: &str| -> Option<Publisher<'static>> {
            if !c.publishes(name) {
                return None;
            }
            let key = keys::key(&c.key_root, &c.rig_id, svc);
            zenoh
                .declare_publisher(key.clone())
                .congestion_control(CongestionControl::Drop)
                .wait()
                .map_err(|e| tracing::error!("remote: cannot publish {key}: {e}"))
                .ok()
        };
        Self {
            status: publisher("status", service::STATUS),
            topology: publisher("cavity", service::TOPOLOGY),
            positions: publisher("cavity", service::POSITIONS),
            flow: publisher("flow", service::FLOW),
            particles: publisher("particles", service::PARTICLES),
            last_topology: None,
            put_errors: 0,
        }
    }

    fn put(&mut self, which: fn(&Self) -> &Option<Publisher<'static>>, bytes: Vec<u8>) {
        let failed = which(self)
            .as_ref()
            .is_some_and(|p| p.put(bytes).wait().is_err());
        if failed {
            self.put_errors += 1;
            if self.put_errors.is_power_of_two() {
                tracing::warn!(errors = self.put_errors, "remote: zenoh put failed");
            }
        }
    }
}

impl Sink for ZenohSink {
    fn status(&mut self, s: &Status, due: bool) {
        if !due {
            return;
        }
        self.put(|z| &z.status, bytes_of(s).to_vec());
        // Re-send the topology now and then: zenoh keeps no history for a late station.
        if let Some((bytes, at)) = self.last_topology.take() {
            if at.elapsed() >= TOPOLOGY_REPEAT {
                self.put(|z| &z.topology, bytes.clone());
                self.last_topology = Some((bytes, Instant::now()));
            } else {
                self.last_topology = Some((bytes, at));
            }
        }
    }

    fn topology(&mut self, h: &MeshTopologyHeader, indices: &[u32]) {
        let bytes = encode_slice(h, indices);
        self.put(|z| &z.topology, bytes.clone());
        self.last_topology = Some((bytes, Instant::now()));
    }

    fn positions(&mut self, h: &MeshPositionsHeader, xyz: &[f32]) {
        self.put(|z| &z.positions, encode_slice(h, xyz));
    }

    fn flow(&mut self, h: &FlowFieldHeader, bytes: &[u8]) {
        self.put(|z| &z.flow, encode_slice(h, bytes));
    }

    fn particles(&mut self, h: &ParticlesHeader, particles: &[Particle]) {
        let mut hdr = *h;
        hdr.particle_count = particles.len() as u32;
        self.put(|z| &z.particles, encode_slice(&hdr, particles));
    }
}

/// Declares the control queryable and its worker; `None` (logged) if zenoh refuses.
fn serve_control(
    zenoh: &zenoh::Session,
    c: &RemoteConfig,
    names: &ServiceNames,
) -> Option<(zenoh::query::Queryable<()>, JoinHandle<()>)> {
    let key = keys::key(&c.key_root, &c.rig_id, service::CONTROL);
    let (tx, rx) = sync_channel::<Query>(CONTROL_QUEUE);
    let worker = {
        let names = names.clone();
        std::thread::Builder::new()
            .name("remote-control".into())
            .spawn(move || control_worker(&names, rx))
            .map_err(|e| tracing::error!("remote: control worker: {e}"))
            .ok()?
    };
    let queryable = zenoh
        .declare_queryable(key.clone())
        .callback(move |query| match tx.try_send(query) {
            Ok(()) => {}
            Err(TrySendError::Full(q)) | Err(TrySendError::Disconnected(q)) => {
                let busy = ControlResponse::new(0, result::BUSY, "too many control requests");
                let _ = q
                    .reply(q.key_expr().clone(), bytes_of(&busy).to_vec())
                    .wait();
            }
        })
        .wait()
        .map_err(|e| tracing::error!("remote: cannot serve {key}: {e}"))
        .ok()?;
    tracing::info!(key, "remote: control allowed over zenoh");
    Some((queryable, worker))
}

/// Answers the queued control requests through the daemon's control service.
fn control_worker(names: &ServiceNames, queries: Receiver<Query>) {
    let node = NodeBuilder::new()
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>();
    for q in queries {
        let request = q
            .payload()
            .and_then(|p| read_exact::<ControlRequest>(&p.to_bytes()));
        let answer = match (&node, request) {
            (_, None) => ControlResponse::new(
                0,
                result::BAD_REQUEST,
                "expected a 272-byte hydrometra.v1.ControlRequest (docs/ipc.md)",
            ),
            (Err(e), Some(r)) => ControlResponse::new(
                r.command,
                result::FAILED,
                &format!("no iceoryx2 node: {e:?}"),
            ),
            (Ok(node), Some(r)) => {
                let argument = r.argument().unwrap_or("\u{fffd}").to_string();
                tracing::info!(
                    command = control::command::name(r.command),
                    "remote: control request from zenoh"
                );
                control::request(node, names, r.command, &argument, control::RESPONSE_TIMEOUT)
                    .unwrap_or_else(|e| {
                        ControlResponse::new(r.command, result::FAILED, &e.to_string())
                    })
            }
        };
        let _ = q
            .reply(q.key_expr().clone(), bytes_of(&answer).to_vec())
            .wait();
    }
}
