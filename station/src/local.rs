//! A rig on this machine: a thread following the hydrometrad's iceoryx2 services into the rig's
//! feed (`hydrometra_remote::follow`), and a thread forwarding control requests to its control
//! service.

use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::thread::JoinHandle;

use hydrometra_ipc::control::{self, ControlResponse};
use hydrometra_ipc::ServiceNames;
use hydrometra_remote::follow::{self, FollowRates};
use iceoryx2::prelude::*;

use crate::feed::RigFeed;
use crate::hub::Rig;
use crate::rates::Rates;

/// Starts the thread following the daemon on `names`; it ends when `stop` is set.
pub fn spawn_source(
    names: ServiceNames,
    rig: Arc<Rig>,
    rates: Rates,
    stop: Arc<AtomicBool>,
) -> std::io::Result<JoinHandle<()>> {
    std::thread::Builder::new()
        .name(format!("station-rig{}", rig.info.index))
        .spawn(move || {
            let paces = FollowRates {
                status_hz: rates.status_hz,
                scene_hz: rates.scene_hz,
                flow_hz: rates.flow_hz,
            };
            let mut feed = RigFeed { rig, rates };
            follow::run(&names, paces, &mut feed, &stop);
        })
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
