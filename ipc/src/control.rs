//! The control service `<prefix>/control`: request-response, one [`ControlRequest`] answered by
//! one [`ControlResponse`] (docs/ipc.md, "Control"). An instructor's UI or the `hydrometra
//! control` CLI starts a new procedure, loads a scene and drives the recorder through it.
//!
//! ```no_run
//! use hydrometra_ipc::control::{self, command, ControlRequest};
//! use hydrometra_ipc::ServiceNames;
//! use iceoryx2::prelude::*;
//!
//! # fn main() -> Result<(), Box<dyn core::error::Error>> {
//! let node = NodeBuilder::new().create::<ipc::Service>()?;
//! let client = control::open(&node, &ServiceNames::default())?.client_builder().create()?;
//! let pending = client.send_copy(ControlRequest::new(command::RECORD_STATUS, "")?)?;
//! let deadline = std::time::Instant::now() + control::RESPONSE_TIMEOUT;
//! while std::time::Instant::now() < deadline {
//!     if let Some(response) = pending.receive()? {
//!         println!("{}: {}", response.result, response.message());
//!         break;
//!     }
//!     std::thread::sleep(core::time::Duration::from_millis(5));
//! }
//! # Ok(())
//! # }
//! ```

use core::time::Duration;

use iceoryx2::node::Node;
use iceoryx2::prelude::ZeroCopySend;
use iceoryx2::service::builder::request_response::{
    RequestResponseOpenError, RequestResponseOpenOrCreateError,
};
use iceoryx2::service::port_factory::request_response::PortFactory;
use iceoryx2::service::Service;

use crate::names::{suffix, ServiceNames};

/// Bytes of [`ControlRequest::argument`].
pub const ARGUMENT_CAPACITY: usize = 256;
/// Bytes of [`ControlResponse::message`] and [`ControlResponse::recording_path`].
pub const TEXT_CAPACITY: usize = 256;

/// How long a client waits for the response before it gives up: every request is answered well
/// within it (the daemon answers a request it could not complete within 2 s with
/// [`result::FAILED`]).
pub const RESPONSE_TIMEOUT: Duration = Duration::from_secs(5);

/// Request commands ([`ControlRequest::command`]).
pub mod command {
    /// Starts a new procedure: the fluid deficit and its alarms reset, the recording rotates.
    pub const NEW_PROCEDURE: u32 = 1;
    /// Switches the scene to the one the argument names (a built-in name or a scene file).
    pub const LOAD_SCENE: u32 = 2;
    /// Starts recording (a new file) if not recording.
    pub const RECORD_START: u32 = 3;
    /// Finishes the open recording and stops recording.
    pub const RECORD_STOP: u32 = 4;
    /// Reports the recorder's state only.
    pub const RECORD_STATUS: u32 = 5;

    /// The command's name in docs/ipc.md (`"unknown"` for others).
    pub fn name(command: u32) -> &'static str {
        match command {
            NEW_PROCEDURE => "new_procedure",
            LOAD_SCENE => "load_scene",
            RECORD_START => "record_start",
            RECORD_STOP => "record_stop",
            RECORD_STATUS => "record_status",
            _ => "unknown",
        }
    }
}

/// Result codes ([`ControlResponse::result`]).
pub mod result {
    /// Done (or, for `load_scene`, accepted: the scene prepares in the background).
    pub const OK: u32 = 0;
    /// The request is malformed (unknown command, other schema version, argument not UTF-8 or
    /// longer than its field, an argument where none is expected or none where one is), or the
    /// scene file it names is invalid; the message says which.
    pub const BAD_REQUEST: u32 = 1;
    /// What the argument names does not exist: no such built-in scene, no such scene file.
    pub const NOT_FOUND: u32 = 2;
    /// The daemon runs without what the command needs (no scene, no recorder configured).
    pub const UNAVAILABLE: u32 = 3;
    /// The daemon tried and failed, or could not confirm it in time; the message says why.
    pub const FAILED: u32 = 4;
    /// Too many requests in flight; retry.
    pub const BUSY: u32 = 5;

    /// The code's name in docs/ipc.md (`"unknown"` for others).
    pub fn name(result: u32) -> &'static str {
        match result {
            OK => "ok",
            BAD_REQUEST => "bad_request",
            NOT_FOUND => "not_found",
            UNAVAILABLE => "unavailable",
            FAILED => "failed",
            BUSY => "busy",
            _ => "unknown",
        }
    }
}

/// The argument does not fit [`ControlRequest::argument`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ArgumentTooLong {
    /// Its length, bytes.
    pub len: usize,
}

impl core::fmt::Display for ArgumentTooLong {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "control request argument of {} bytes; at most {ARGUMENT_CAPACITY} fit",
            self.len
        )
    }
}

impl std::error::Error for ArgumentTooLong {}

/// A request to the daemon, 272 bytes.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[type_name("hydrometra.v1.ControlRequest")]
pub struct ControlRequest {
    /// [`crate::SCHEMA_VERSION`].
    pub schema_version: u32,
    /// One of [`command`].
    pub command: u32,
    /// Bytes of `argument` in use.
    pub argument_len: u32,
    /// 0.
    pub reserved0: u32,
    /// UTF-8 argument (the scene for `load_scene`), `argument_len` bytes, the rest 0.
    pub argument: [u8; ARGUMENT_CAPACITY],
}

impl ControlRequest {
    /// A request of `command` with `argument` (empty for commands without one).
    pub fn new(command: u32, argument: &str) -> Result<Self, ArgumentTooLong> {
        let bytes = argument.as_bytes();
        if bytes.len() > ARGUMENT_CAPACITY {
            return Err(ArgumentTooLong { len: bytes.len() });
        }
        let mut a = [0u8; ARGUMENT_CAPACITY];
        a[..bytes.len()].copy_from_slice(bytes);
        Ok(Self {
            schema_version: crate::SCHEMA_VERSION,
            command,
            argument_len: bytes.len() as u32,
            reserved0: 0,
            argument: a,
        })
    }

    /// The argument, if `argument_len` fits and the bytes are UTF-8.
    pub fn argument(&self) -> Option<&str> {
        let bytes = self.argument.get(..self.argument_len as usize)?;
        core::str::from_utf8(bytes).ok()
    }
}

/// The daemon's answer to one request, 560 bytes.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[type_name("hydrometra.v1.ControlResponse")]
pub struct ControlResponse {
    /// [`crate::SCHEMA_VERSION`].
    pub schema_version: u32,
    /// The request's command.
    pub command: u32,
    /// One of [`result`].
    pub result: u32,
    /// 1 while the recorder writes a file (after the command took effect).
    pub recording: u32,
    /// Id of the current procedure (status `procedure_id`; after `new_procedure`, the new one).
    pub procedure_id: u64,
    /// Messages written to the open (or last) recording.
    pub recorded_messages: u64,
    /// Recordings finished since the daemon started.
    pub recordings_finished: u64,
    /// Bytes of `message` in use.
    pub message_len: u32,
    /// Bytes of `recording_path` in use.
    pub recording_path_len: u32,
    /// UTF-8 message for a human: what was done, or why not.
    pub message: [u8; TEXT_CAPACITY],
    /// UTF-8 path of the open (or last) recording on the daemon's host; empty without one.
    pub recording_path: [u8; TEXT_CAPACITY],
}

/// Copies the longest prefix of `text` that fits `out` and ends on a character boundary.
fn fill(out: &mut [u8; TEXT_CAPACITY], text: &str) -> u32 {
    let mut end = text.len().min(TEXT_CAPACITY);
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    *out = [0; TEXT_CAPACITY];
    out[..end].copy_from_slice(&text.as_bytes()[..end]);
    end as u32
}

fn text(bytes: &[u8; TEXT_CAPACITY], len: u32) -> String {
    let end = (len as usize).min(TEXT_CAPACITY);
    String::from_utf8_lossy(&bytes[..end]).into_owned()
}

impl ControlResponse {
    /// A response to `command` with `result` and `message` (cut at [`TEXT_CAPACITY`] bytes).
    pub fn new(command: u32, result: u32, message: &str) -> Self {
        let mut r = Self {
            schema_version: crate::SCHEMA_VERSION,
            command,
            result,
            recording: 0,
            procedure_id: 0,
            recorded_messages: 0,
            recordings_finished: 0,
            message_len: 0,
            recording_path_len: 0,
            message: [0; TEXT_CAPACITY],
            recording_path: [0; TEXT_CAPACITY],
        };
        r.message_len = fill(&mut r.message, message);
        r
    }

    /// Sets the recording path (cut at [`TEXT_CAPACITY`] bytes).
    pub fn set_recording_path(&mut self, path: &str) {
        self.recording_path_len = fill(&mut self.recording_path, path);
    }

    /// The message.
    pub fn message(&self) -> String {
        text(&self.message, self.message_len)
    }

    /// The recording path (empty without one).
    pub fn recording_path(&self) -> String {
        text(&self.recording_path, self.recording_path_len)
    }
}

/// Quality of service of the control service (see `docs/ipc.md`).
pub mod qos {
    /// Servers: the daemon.
    pub const MAX_SERVERS: usize = 1;
    /// Clients at once (UIs, CLIs, tests).
    pub const MAX_CLIENTS: usize = 8;
    /// Requests one client may have in flight.
    pub const MAX_ACTIVE_REQUESTS_PER_CLIENT: usize = 4;
    /// Responses buffered per request (one is sent).
    pub const MAX_RESPONSE_BUFFER_SIZE: usize = 2;
    /// Nodes that may hold the service open at once.
    pub const MAX_NODES: usize = 32;
}

/// The control service's port factory.
pub type ControlService<S> = PortFactory<S, ControlRequest, (), ControlResponse, ()>;

fn name(names: &ServiceNames) -> Result<iceoryx2::prelude::ServiceName, String> {
    names
        .service(suffix::CONTROL)
        .map_err(|e| format!("{}: {e:?}", names.full(suffix::CONTROL)))
}

/// Why the control service could not be created or opened.
#[derive(Debug)]
pub enum ControlServiceError {
    /// The prefix does not form a valid name.
    Name(String),
    /// iceoryx2 refused to create or open it.
    OpenOrCreate(RequestResponseOpenOrCreateError),
    /// iceoryx2 refused to open it (`DoesNotExist`: no daemon on this prefix).
    Open(RequestResponseOpenError),
}

impl core::fmt::Display for ControlServiceError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Name(e) => write!(f, "invalid service name: {e}"),
            Self::OpenOrCreate(e) => write!(f, "cannot create or open the service: {e:?}"),
            Self::Open(e) => write!(f, "cannot open the service: {e:?}"),
        }
    }
}

impl std::error::Error for ControlServiceError {}

/// The service as the daemon creates it (or re-opens it after a restart).
pub fn create<S: Service>(
    node: &Node<S>,
    names: &ServiceNames,
) -> Result<ControlService<S>, ControlServiceError> {
    node.service_builder(&name(names).map_err(ControlServiceError::Name)?)
        .request_response::<ControlRequest, ControlResponse>()
        .max_servers(qos::MAX_SERVERS)
        .max_clients(qos::MAX_CLIENTS)
        .max_active_requests_per_client(qos::MAX_ACTIVE_REQUESTS_PER_CLIENT)
        .max_response_buffer_size(qos::MAX_RESPONSE_BUFFER_SIZE)
        .max_nodes(qos::MAX_NODES)
        .open_or_create()
        .map_err(ControlServiceError::OpenOrCreate)
}

/// The service as a client opens it: `DoesNotExist` while no daemon serves this prefix.
pub fn open<S: Service>(
    node: &Node<S>,
    names: &ServiceNames,
) -> Result<ControlService<S>, ControlServiceError> {
    node.service_builder(&name(names).map_err(ControlServiceError::Name)?)
        .request_response::<ControlRequest, ControlResponse>()
        .open()
        .map_err(ControlServiceError::Open)
}

/// Why a request got no response ([`request`]).
#[derive(Debug)]
pub enum RequestError {
    /// No daemon serves the prefix: the service does not exist, or it has no server.
    NoDaemon(String),
    /// The argument does not fit the request.
    Argument(ArgumentTooLong),
    /// iceoryx2 failed to open the service, create the client, send or receive.
    Ipc(String),
    /// No response within the timeout.
    Timeout(String),
}

impl core::fmt::Display for RequestError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::NoDaemon(m) | Self::Ipc(m) | Self::Timeout(m) => f.write_str(m),
            Self::Argument(e) => write!(f, "{e}"),
        }
    }
}

impl std::error::Error for RequestError {}

/// Sends one request on `node` and waits (polling every 5 ms, blocking the calling thread) up to
/// `timeout` for its response.
pub fn request<S: Service>(
    node: &Node<S>,
    names: &ServiceNames,
    code: u32,
    argument: &str,
    timeout: Duration,
) -> Result<ControlResponse, RequestError> {
    use iceoryx2::service::builder::request_response::RequestResponseOpenError as OpenError;
    let full = names.full(suffix::CONTROL);
    let no_daemon = |why: &str| {
        RequestError::NoDaemon(format!(
            "no hydrometrad answers on {full}: is it running, with --service-prefix {}? ({why})",
            names.prefix()
        ))
    };
    let service = match open(node, names) {
        Ok(s) => s,
        Err(ControlServiceError::Open(OpenError::DoesNotExist)) => {
            return Err(no_daemon("the service does not exist"))
        }
        Err(e) => return Err(RequestError::Ipc(format!("opening {full}: {e}"))),
    };
    let client = service
        .client_builder()
        .create()
        .map_err(|e| RequestError::Ipc(format!("cannot create a client of {full}: {e:?}")))?;
    let request = ControlRequest::new(code, argument).map_err(RequestError::Argument)?;
    let pending = client
        .send_copy(request)
        .map_err(|e| RequestError::Ipc(format!("cannot send the request to {full}: {e:?}")))?;
    if pending.number_of_server_connections() == 0 {
        return Err(no_daemon("the service has no server"));
    }
    let deadline = std::time::Instant::now() + timeout;
    loop {
        match pending.receive() {
            Ok(Some(response)) => return Ok(*response),
            Ok(None) => {}
            Err(e) => {
                return Err(RequestError::Ipc(format!(
                    "cannot receive the response from {full}: {e:?}"
                )))
            }
        }
        if std::time::Instant::now() >= deadline {
            return Err(RequestError::Timeout(format!(
                "no hydrometrad answers on {full}: is it running, with --service-prefix {}?: \
                 no response within {:.1} s",
                names.prefix(),
                timeout.as_secs_f64()
            )));
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn arguments_round_trip_and_overlong_ones_are_refused() {
        let r = ControlRequest::new(command::LOAD_SCENE, "myoma-figo1").unwrap();
        assert_eq!(r.argument(), Some("myoma-figo1"));
        assert_eq!(
            ControlRequest::new(command::LOAD_SCENE, &"x".repeat(257)),
            Err(ArgumentTooLong { len: 257 })
        );
        let mut bad = r;
        bad.argument_len = 999;
        assert_eq!(bad.argument(), None);
    }

    #[test]
    fn messages_are_cut_on_a_character_boundary() {
        let long = "é".repeat(200); // 400 bytes
        let r = ControlResponse::new(command::NEW_PROCEDURE, result::OK, &long);
        assert_eq!(r.message_len, 256);
        assert_eq!(r.message(), "é".repeat(128));
        let r = ControlResponse::new(command::NEW_PROCEDURE, result::OK, &"é".repeat(129));
        assert!(r.message_len <= 256 && r.message().chars().all(|c| c == 'é'));
    }
}
