//! The control plane's request-response service `<prefix>/control` (docs/ipc.md, "Control"):
//! new procedure, load scene, and the recorder.
//!
//! Two halves, because iceoryx2 ports are not `Send` while the handlers want the tokio runtime:
//!
//! - [`ControlThread`] (`hm-control`, normal priority) owns the iceoryx2 node, the server port
//!   and every request in flight (an `ActiveRequest` is tied to its port's thread). It polls the
//!   server every [`IDLE_POLL_PERIOD`] ([`POLL_PERIOD`] while requests are in flight), checks
//!   each request's form, hands it to the runtime as a [`Job`] (`try_send`: a full queue
//!   answers `busy`) and sends the response when the job's oneshot answers. It never blocks on
//!   a handler.
//! - [`serve`] runs on the daemon's tokio runtime and runs one task per job: the handlers wait
//!   (asynchronously) for the real-time side to confirm, e.g. for the 1 kHz loop to show the new
//!   procedure id, with a deadline of [`HANDLER_TIMEOUT`].
//!
//! Neither half is ever waited on by a real-time thread: the handlers reach them through
//! atomics and `try_lock` slots ([`ProcedureControl`], [`SceneFeed::request_scene`]) and the
//! recorder's command channel.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::Context;
use hydrometra_ipc::control::{self, command, result, ControlRequest, ControlResponse};
use hydrometra_ipc::status::scene_state;
use hydrometra_ipc::ServiceNames;
use hydrometra_sim::scene::{SceneDesc, SceneError};
use iceoryx2::prelude::{ipc, NodeBuilder, NodeName, SignalHandlingMode};
use tokio::sync::{mpsc, oneshot};

use super::hydraulics::ProcedureControl;
use super::scene::SceneFeed;
use hydrometra_record::recorder::{RecorderHandle, RecorderStatus};

/// How often the control thread looks for requests while none is in flight: a request waits at
/// most this long before its handler starts. Control is a human's command, so 50 ms is
/// immediate enough; each poll wakes the thread (20 wakes a second at rest, not 100).
pub const IDLE_POLL_PERIOD: Duration = Duration::from_millis(50);
/// How often it looks for requests and finished jobs while requests are in flight, so an answer
/// leaves within this of its handler's.
pub const POLL_PERIOD: Duration = Duration::from_millis(10);
/// A handler that has not finished within this is answered `failed` (below the clients'
/// [`control::RESPONSE_TIMEOUT`]).
pub const HANDLER_TIMEOUT: Duration = Duration::from_secs(2);
/// Jobs queued for the runtime at once; more are answered `busy`.
pub const JOB_QUEUE: usize = 16;
/// How often a handler re-checks whether its effect is visible.
const CONFIRM_POLL: Duration = Duration::from_millis(5);

/// A well-formed request.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Request {
    /// `new_procedure`.
    NewProcedure,
    /// `load_scene NAME|FILE`.
    LoadScene(String),
    /// `record_start`.
    RecordStart,
    /// `record_stop`.
    RecordStop,
    /// `record_status`.
    RecordStatus,
}

impl Request {
    /// Checks a request's form: the schema version, a known command, and its argument (UTF-8,
    /// present exactly when the command takes one). The error is the `bad_request` message.
    pub fn decode(r: &ControlRequest) -> Result<Request, String> {
        let bad = |message: String| message;
        if r.schema_version != hydrometra_ipc::SCHEMA_VERSION {
            return Err(bad(format!(
                "schema_version {} is not spoken here (this daemon speaks {})",
                r.schema_version,
                hydrometra_ipc::SCHEMA_VERSION
            )));
        }
        let Some(argument) = r.argument() else {
            return Err(bad(format!(
                "argument_len {} with argument bytes that are not UTF-8 or longer than {} bytes",
                r.argument_len,
                control::ARGUMENT_CAPACITY
            )));
        };
        let none = |request: Request| {
            if argument.is_empty() {
                Ok(request)
            } else {
                Err(bad(format!(
                    "{} takes no argument (got {argument:?})",
                    command::name(r.command)
                )))
            }
        };
        match r.command {
            command::NEW_PROCEDURE => none(Request::NewProcedure),
            command::RECORD_START => none(Request::RecordStart),
            command::RECORD_STOP => none(Request::RecordStop),
            command::RECORD_STATUS => none(Request::RecordStatus),
            command::LOAD_SCENE if argument.trim().is_empty() => Err(bad(
                "load_scene needs a scene: a built-in name or a scene file path".into(),
            )),
            command::LOAD_SCENE => Ok(Request::LoadScene(argument.trim().to_string())),
            other => Err(bad(format!("unknown command {other} (known: 1-5)"))),
        }
    }

    fn command(&self) -> u32 {
        match self {
            Request::NewProcedure => command::NEW_PROCEDURE,
            Request::LoadScene(_) => command::LOAD_SCENE,
            Request::RecordStart => command::RECORD_START,
            Request::RecordStop => command::RECORD_STOP,
            Request::RecordStatus => command::RECORD_STATUS,
        }
    }
}

/// A request handed to the runtime, with where its response goes.
#[derive(Debug)]
pub struct Job {
    /// The request.
    pub request: Request,
    /// The response, taken by the control thread.
    pub reply: oneshot::Sender<ControlResponse>,
}

/// What the handlers act on.
pub struct ControlContext {
    /// The hydraulics' procedure.
    pub procedure: Arc<ProcedureControl>,
    /// The scene hand-over; `None` when the daemon runs no scene.
    pub scene: Option<Arc<SceneFeed>>,
    /// The recorder; `None` when nothing is recorded.
    pub recorder: Option<Arc<RecorderHandle>>,
}

/// Runs the handlers until the control thread is gone: one task per job, so a slow one (a
/// recorder confirming a stop) never delays the others.
pub async fn serve(mut jobs: mpsc::Receiver<Job>, context: Arc<ControlContext>) {
    while let Some(job) = jobs.recv().await {
        let context = context.clone();
        tokio::spawn(async move {
            let command = job.request.command();
            let name = command::name(command);
            let response =
                match tokio::time::timeout(HANDLER_TIMEOUT, handle(job.request.clone(), &context))
                    .await
                {
                    Ok(r) => r,
                    Err(_) => ControlResponse::new(
                        command,
                        result::FAILED,
                        &format!(
                            "{name}: not confirmed within {} s; see the daemon's log",
                            HANDLER_TIMEOUT.as_secs_f64()
                        ),
                    ),
                };
            let level_ok = response.result == result::OK;
            if level_ok {
                tracing::info!(request = ?job.request, "control: {}", response.message());
            } else {
                tracing::warn!(
                    request = ?job.request,
                    result = result::name(response.result),
                    "control: {}",
                    response.message()
                );
            }
            // The control thread is gone only when the daemon stops.
            let _ = job.reply.send(response);
        });
    }
}

/// Waits (asynchronously) until `done` holds or `timeout` passes; true if it held.
async fn until(timeout: Duration, mut done: impl FnMut() -> bool) -> bool {
    let deadline = tokio::time::Instant::now() + timeout;
    loop {
        if done() {
            return true;
        }
        if tokio::time::Instant::now() >= deadline {
            return false;
        }
        tokio::time::sleep(CONFIRM_POLL).await;
    }
}

fn with_recorder(mut r: ControlResponse, status: &RecorderStatus) -> ControlResponse {
    r.recording = u32::from(status.recording);
    r.recorded_messages = status.messages;
    r.recordings_finished = status.files_finished;
    if let Some(path) = &status.path {
        r.set_recording_path(&path.display().to_string());
    }
    r
}

fn path_of(status: &RecorderStatus) -> String {
    status
        .path
        .as_ref()
        .map_or_else(|| "-".into(), |p| p.display().to_string())
}

const NO_RECORDER: &str = "nothing is recorded: hydrometrad runs with --no-record or without a \
                           recordings directory (--record-dir DIR, [record] dir or [paths] state_dir)";

async fn handle(request: Request, context: &ControlContext) -> ControlResponse {
    let command = request.command();
    let respond = |code: u32, message: &str| {
        let mut r = ControlResponse::new(command, code, message);
        r.procedure_id = context.procedure.procedure_id();
        match &context.recorder {
            Some(rec) => with_recorder(r, &rec.status()),
            None => r,
        }
    };
    match request {
        Request::NewProcedure => {
            let (old_id, old_deficit_m3) = (
                context.procedure.procedure_id(),
                context.procedure.deficit_m3(),
            );
            let old_path = context.recorder.as_ref().map(|r| r.status());
            context.procedure.request_new_procedure();
            if !until(HANDLER_TIMEOUT, || {
                context.procedure.procedure_id() != old_id
            })
            .await
            {
                return respond(
                    result::FAILED,
                    "the simulation loop did not start the new procedure in time",
                );
            }
            let new_id = context.procedure.procedure_id();
            let mut message = format!(
                "procedure {new_id} started; procedure {old_id} ended with a deficit of {:.1} ml",
                old_deficit_m3 * 1e6
            );
            // The recorder rotates by itself when status shows the new procedure id.
            if let (Some(rec), Some(old)) = (&context.recorder, old_path) {
                if !old.recording {
                    message = format!("{message}; not recording");
                } else {
                    let rotated = until(Duration::from_millis(1500), || {
                        let s = rec.status();
                        s.recording && s.path != old.path
                    })
                    .await;
                    let now = rec.status();
                    message = if rotated {
                        format!("{message}; recording to {}", path_of(&now))
                    } else if now.recording {
                        format!("{message}; the recording did not rotate yet")
                    } else {
                        format!("{message}; not recording")
                    };
                }
            }
            respond(result::OK, &message)
        }
        Request::LoadScene(spec) => {
            // A scene file is read here (small), off the runtime's thread.
            let loaded = {
                let spec = spec.clone();
                tokio::task::spawn_blocking(move || SceneDesc::load(&spec)).await
            };
            let desc = match loaded {
                Ok(Ok(desc)) => desc,
                Ok(Err(e @ (SceneError::UnknownScene { .. } | SceneError::Io { .. }))) => {
                    return respond(result::NOT_FOUND, &format!("load_scene {spec}: {e}"))
                }
                Ok(Err(e)) => {
                    return respond(result::BAD_REQUEST, &format!("load_scene {spec}: {e}"))
                }
                Err(e) => return respond(result::FAILED, &format!("load_scene {spec}: {e}")),
            };
            let Some(feed) = &context.scene else {
                return respond(
                    result::UNAVAILABLE,
                    "hydrometrad runs without a scene (--no-scene or [scene] enabled = false); \
                     restart it with --scene NAME|FILE",
                );
            };
            let (name, key) = (desc.name.clone(), desc.atlas_key());
            // A scene being prepared finishes first (an atlas build cannot be interrupted).
            let busy = feed.figures.state() == scene_state::PREPARING;
            feed.request_scene(desc);
            // Otherwise the scene thread takes it after its current frame.
            let taken = !busy
                && until(Duration::from_millis(500), || {
                    feed.figures.state() == scene_state::PREPARING
                })
                .await;
            let when = if taken {
                "preparing now"
            } else {
                "queued behind the current preparation"
            };
            respond(
                result::OK,
                &format!(
                    "loading scene {name} (atlas {key}): {when}; status scene_state is preparing \
                     (1) until it runs, then the scene services publish the new scene"
                ),
            )
        }
        Request::RecordStart | Request::RecordStop | Request::RecordStatus => {
            let Some(rec) = &context.recorder else {
                return respond(result::UNAVAILABLE, NO_RECORDER);
            };
            let before = rec.status();
            match request {
                Request::RecordStart if before.recording => respond(
                    result::OK,
                    &format!("already recording to {}", path_of(&before)),
                ),
                Request::RecordStart => {
                    rec.start();
                    if until(Duration::from_millis(1500), || rec.status().recording).await {
                        let now = rec.status();
                        respond(result::OK, &format!("recording to {}", path_of(&now)))
                    } else {
                        let why = rec
                            .status()
                            .last_error
                            .unwrap_or_else(|| "no file opened in time".into());
                        respond(result::FAILED, &format!("recording did not start: {why}"))
                    }
                }
                Request::RecordStop if !before.recording => respond(result::OK, "not recording"),
                Request::RecordStop => {
                    rec.stop();
                    if until(Duration::from_millis(1500), || !rec.status().recording).await {
                        let now = rec.status();
                        respond(
                            result::OK,
                            &format!(
                                "recording stopped; {} finished ({} messages)",
                                path_of(&now),
                                now.messages
                            ),
                        )
                    } else {
                        respond(result::FAILED, "the recorder did not stop in time")
                    }
                }
                _ => {
                    let message = match (&before.recording, &before.last_error) {
                        (true, _) => format!(
                            "recording to {} ({} messages)",
                            path_of(&before),
                            before.messages
                        ),
                        (false, Some(e)) => format!("not recording; last error: {e}"),
                        (false, None) => {
                            format!("not recording; last file {}", path_of(&before))
                        }
                    };
                    respond(result::OK, &message)
                }
            }
        }
    }
}

/// The control thread.
pub struct ControlThread {
    handle: JoinHandle<()>,
    stop: Arc<AtomicBool>,
}

impl ControlThread {
    /// Creates the service and its server on a thread of its own; returns once it serves (or
    /// with the reason it cannot).
    pub fn spawn(names: ServiceNames, jobs: mpsc::Sender<Job>) -> anyhow::Result<Self> {
        let stop = Arc::new(AtomicBool::new(false));
        let (ready_tx, ready_rx) = std::sync::mpsc::sync_channel(1);
        let handle = {
            let stop = stop.clone();
            std::thread::Builder::new()
                .name("hm-control".into())
                .spawn(move || serve_requests(&names, &jobs, &stop, ready_tx))
                .context("cannot start the control thread")?
        };
        match ready_rx.recv() {
            Ok(Ok(())) => Ok(Self { handle, stop }),
            Ok(Err(e)) => {
                let _ = handle.join();
                Err(e)
            }
            Err(_) => {
                let _ = handle.join();
                anyhow::bail!("the control thread ended before it served")
            }
        }
    }

    /// Answers what is in flight with `failed` and ends the thread.
    pub fn shutdown(self) {
        self.stop.store(true, Ordering::Relaxed);
        if self.handle.join().is_err() {
            tracing::error!("control thread panicked");
        }
    }

    /// Whether the thread has ended.
    pub fn is_finished(&self) -> bool {
        self.handle.is_finished()
    }
}

fn serve_requests(
    names: &ServiceNames,
    jobs: &mpsc::Sender<Job>,
    stop: &AtomicBool,
    ready: std::sync::mpsc::SyncSender<anyhow::Result<()>>,
) {
    let created = (|| -> anyhow::Result<_> {
        let node_name =
            NodeName::new("hydrometrad-control").map_err(|e| anyhow::anyhow!("{e:?}"))?;
        let node = NodeBuilder::new()
            .name(&node_name)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<ipc::Service>()
            .map_err(|e| anyhow::anyhow!("cannot create the control node: {e:?}"))?;
        let full = names.full(hydrometra_ipc::names::suffix::CONTROL);
        let service = control::create(&node, names).with_context(|| full.clone())?;
        let server = service.server_builder().create().map_err(|e| {
            anyhow::anyhow!("cannot serve {full}: {e:?} (another hydrometrad on this prefix?)")
        })?;
        Ok((node, server, full))
    })();
    let (_node, server, full) = match created {
        Ok(c) => {
            let _ = ready.send(Ok(()));
            c
        }
        Err(e) => {
            let _ = ready.send(Err(e));
            return;
        }
    };
    tracing::info!(service = %full, "control service ready");
    let mut in_flight = Vec::new();
    let mut receive_errors = 0u64;
    while !stop.load(Ordering::Relaxed) {
        loop {
            match server.receive() {
                Ok(Some(active)) => {
                    let request: ControlRequest = *active.payload();
                    let decoded = Request::decode(&request);
                    let pending = match decoded {
                        Err(message) => Err(ControlResponse::new(
                            request.command,
                            result::BAD_REQUEST,
                            &message,
                        )),
                        Ok(request) => {
                            let (reply, answer) = oneshot::channel();
                            let command = request.command();
                            match jobs.try_send(Job { request, reply }) {
                                Ok(()) => Ok(answer),
                                Err(_) => Err(ControlResponse::new(
                                    command,
                                    result::BUSY,
                                    "too many control requests in flight; retry",
                                )),
                            }
                        }
                    };
                    match pending {
                        Ok(answer) => in_flight.push((active, answer, request.command)),
                        Err(response) => {
                            if response.result != result::BUSY {
                                tracing::warn!(
                                    command = request.command,
                                    "control: {}",
                                    response.message()
                                );
                            }
                            send(&active, response);
                        }
                    }
                }
                Ok(None) => break,
                Err(e) => {
                    receive_errors += 1;
                    if receive_errors < 10 {
                        tracing::warn!("control service: cannot receive a request: {e:?}");
                    }
                    break;
                }
            }
        }
        in_flight.retain_mut(|(active, answer, command)| match answer.try_recv() {
            Ok(response) => {
                send(active, response);
                false
            }
            Err(oneshot::error::TryRecvError::Empty) => true,
            Err(oneshot::error::TryRecvError::Closed) => {
                send(
                    active,
                    ControlResponse::new(*command, result::FAILED, "the daemon is stopping"),
                );
                false
            }
        });
        std::thread::sleep(if in_flight.is_empty() {
            IDLE_POLL_PERIOD
        } else {
            POLL_PERIOD
        });
    }
    let started = Instant::now();
    for (active, _, command) in in_flight.drain(..) {
        send(
            &active,
            ControlResponse::new(command, result::FAILED, "the daemon is stopping"),
        );
    }
    tracing::debug!(
        seconds = started.elapsed().as_secs_f64(),
        "control service stopped"
    );
}

fn send(
    active: &iceoryx2::active_request::ActiveRequest<
        ipc::Service,
        ControlRequest,
        (),
        ControlResponse,
        (),
    >,
    response: ControlResponse,
) {
    // A client that left only misses its answer.
    if let Err(e) = active.send_copy(response) {
        tracing::debug!("control: cannot send the response: {e:?}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn request(command: u32, argument: &str) -> ControlRequest {
        ControlRequest::new(command, argument).unwrap()
    }

    #[test]
    fn malformed_requests_get_a_bad_request_response_naming_the_problem() {
        let unknown = Request::decode(&request(99, "")).unwrap_err();
        assert!(unknown.contains("unknown command 99"));
        let extra = Request::decode(&request(command::NEW_PROCEDURE, "x")).unwrap_err();
        assert!(extra.contains("takes no argument"));
        let missing = Request::decode(&request(command::LOAD_SCENE, " ")).unwrap_err();
        assert!(missing.contains("needs a scene"));
        let mut version = request(command::RECORD_STATUS, "");
        version.schema_version = 2;
        assert!(Request::decode(&version)
            .unwrap_err()
            .contains("schema_version 2"));
        let mut utf8 = request(command::LOAD_SCENE, "ab");
        utf8.argument[0] = 0xff;
        assert!(Request::decode(&utf8).unwrap_err().contains("not UTF-8"));
        assert_eq!(
            Request::decode(&request(command::LOAD_SCENE, "default")),
            Ok(Request::LoadScene("default".into()))
        );
    }

    #[test]
    fn load_scene_of_an_unknown_name_is_not_found_and_without_a_scene_unavailable() {
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        let with_scene = ControlContext {
            procedure: Arc::new(ProcedureControl::default()),
            scene: Some(Arc::new(SceneFeed::default())),
            recorder: None,
        };
        let r = runtime.block_on(handle(Request::LoadScene("no-such".into()), &with_scene));
        assert_eq!(r.result, result::NOT_FOUND, "{}", r.message());
        assert!(r.message().contains("no built-in scene `no-such`"));
        let without = ControlContext {
            scene: None,
            ..with_scene
        };
        let r = runtime.block_on(handle(Request::LoadScene("default".into()), &without));
        assert_eq!(r.result, result::UNAVAILABLE);
        let r = runtime.block_on(handle(Request::LoadScene("no-such".into()), &without));
        assert_eq!(r.result, result::NOT_FOUND, "the name is checked first");
        let r = runtime.block_on(handle(Request::RecordStart, &without));
        assert_eq!(r.result, result::UNAVAILABLE);
    }
}
