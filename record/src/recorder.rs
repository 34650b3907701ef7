//! The recorder: a thread of normal priority that drains two non-blocking taps (the rig I/O
//! thread's received bytes, the publisher's statuses) and writes one MCAP file per procedure.
//!
//! Nothing here runs on a real-time thread: the producers only `try_send` into preallocated
//! bounded channels ([`hydrometra_drivers::tap`]), and drops are counted. The file is flushed
//! (the open MCAP chunk closed and written) every `flush_interval`, so a kill -9 loses at most
//! that interval plus one drain period, and leaves a file whose complete chunks read back.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, RecvTimeoutError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use hydrometra_drivers::tap::{tap, Tap, TapReceiver};
use hydrometra_drivers::transport::{monotonic_ns, RxChunk, RxTap};
use hydrometra_ipc::{alarms, status::link_state, Status};

use super::format::{self, AlarmChange, ControlEvent};
use super::RecordError;

/// Chunks the receive tap holds: 4 s of reads at 250 frames/s (one frame per read).
pub const RX_TAP_CAPACITY: usize = 1024;
/// Statuses the status tap holds: 2.5 s at 100 Hz.
pub const STATUS_TAP_CAPACITY: usize = 256;
/// How long the recorder thread sleeps between drains when nothing arrives.
const DRAIN_PERIOD: Duration = Duration::from_millis(20);

/// Recorder settings (from `[record]`).
#[derive(Debug, Clone)]
pub struct RecorderSettings {
    /// Directory of the recordings (created if missing).
    pub dir: PathBuf,
    /// Record from the start (`[record] enabled`); otherwise wait for [`RecorderHandle::start`].
    pub start_recording: bool,
    /// Close and write the open chunk this often (bounds what a kill -9 loses).
    pub flush_interval: Duration,
    /// Key-value pairs written into the file's `hydrometra` metadata record.
    pub metadata: BTreeMap<String, String>,
}

/// The publisher's side of the status tap: forwards every `every`-th status and every status in
/// which the alarms, the link state or the procedure changed. Non-blocking and allocation-free.
#[derive(Debug, Clone)]
pub struct StatusTap {
    tap: Tap<Status>,
    every: u64,
    last: Option<(u64, u32, u64)>,
}

impl StatusTap {
    /// Offers a published status (call after stamping it). Returns false when the tap was full
    /// and the status was dropped (counted).
    pub fn offer(&mut self, status: &Status) -> bool {
        let key = (status.alarm_bits, status.link_state, status.procedure_id);
        let changed = self.last != Some(key);
        if !(changed || status.sequence.is_multiple_of(self.every)) {
            return true;
        }
        // A dropped change is retried with the next status, so none is lost to a full tap.
        let accepted = self.tap.offer(*status);
        if accepted {
            self.last = Some(key);
        }
        accepted
    }
}

/// What the recorder is doing (a copy; cheap).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RecorderStatus {
    /// A file is open and being written.
    pub recording: bool,
    /// The open file, or the last one closed.
    pub path: Option<PathBuf>,
    /// Messages written to the current (or last) file.
    pub messages: u64,
    /// Files finished since start.
    pub files_finished: u64,
    /// Received chunks the I/O thread dropped because the recorder fell behind.
    pub rx_dropped: u64,
    /// Statuses the publisher dropped because the recorder fell behind.
    pub status_dropped: u64,
    /// The last write error, if any (recording stops on an error until the next start).
    pub last_error: Option<String>,
}

enum Command {
    Start,
    Stop,
    Rotate(String),
}

/// Handle to the recorder thread. The control service calls [`start`](Self::start),
/// [`stop`](Self::stop) and [`rotate`](Self::rotate); dropping it (or [`shutdown`](Self::shutdown))
/// finishes the open file.
pub struct RecorderHandle {
    commands: mpsc::Sender<Command>,
    state: Arc<Mutex<RecorderStatus>>,
    failed: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

/// The producers' ends, to hand to the rig link and the publisher.
pub struct RecorderTaps {
    /// For `LinkConfig::rx_tap`.
    pub rx: RxTap,
    /// For the publisher.
    pub status: StatusTap,
}

impl RecorderHandle {
    /// Starts the recorder thread; `status_every` is the status decimation (published statuses
    /// per recorded one, at least 1).
    pub fn spawn(
        settings: RecorderSettings,
        status_every: u64,
    ) -> Result<(RecorderHandle, RecorderTaps), RecordError> {
        std::fs::create_dir_all(&settings.dir).map_err(|source| RecordError::Io {
            path: settings.dir.display().to_string(),
            source,
        })?;
        let (rx_tap, rx_rx) = tap::<RxChunk>(RX_TAP_CAPACITY);
        let (status_tap, status_rx) = tap::<Status>(STATUS_TAP_CAPACITY);
        let (commands, command_rx) = mpsc::channel();
        let state = Arc::new(Mutex::new(RecorderStatus::default()));
        let failed = Arc::new(AtomicBool::new(false));
        let worker = Worker {
            recording: settings.start_recording,
            settings,
            rx: rx_rx,
            statuses: status_rx,
            commands: command_rx,
            state: Arc::clone(&state),
            failed: Arc::clone(&failed),
            file: None,
            pending: Vec::new(),
            files_finished: 0,
        };
        let thread = std::thread::Builder::new()
            .name("hm-recorder".into())
            .spawn(move || worker.run())
            .map_err(|source| RecordError::Io {
                path: "recorder thread".into(),
                source,
            })?;
        Ok((
            RecorderHandle {
                commands,
                state,
                failed,
                thread: Some(thread),
            },
            RecorderTaps {
                rx: rx_tap,
                status: StatusTap {
                    tap: status_tap,
                    every: status_every.max(1),
                    last: None,
                },
            },
        ))
    }

    /// Starts recording (a new file on the next status) if not recording.
    pub fn start(&self) {
        let _ = self.commands.send(Command::Start);
    }

    /// Finishes the open file and stops recording.
    pub fn stop(&self) {
        let _ = self.commands.send(Command::Stop);
    }

    /// Finishes the open file and opens a new one (e.g. for a new procedure); `reason` goes into
    /// the `recording_stopped` event. The recorder also rotates by itself when the status shows
    /// another procedure id.
    pub fn rotate(&self, reason: &str) {
        let _ = self.commands.send(Command::Rotate(reason.to_string()));
    }

    /// A flag that is set while recording is stopped by an error (disk full, unwritable
    /// directory) and cleared when a file opens again: for a real-time reader (no lock).
    pub fn failed_flag(&self) -> Arc<AtomicBool> {
        Arc::clone(&self.failed)
    }

    /// What the recorder is doing.
    pub fn status(&self) -> RecorderStatus {
        self.state.lock().map(|s| s.clone()).unwrap_or_default()
    }

    /// Finishes the open file and ends the thread.
    pub fn shutdown(mut self) -> RecorderStatus {
        self.join();
        self.status()
    }

    fn join(&mut self) {
        // Dropping the command sender ends the thread after its last drain.
        let (dead, _) = mpsc::channel();
        self.commands = dead;
        if let Some(t) = self.thread.take() {
            if t.join().is_err() {
                tracing::error!("recorder thread panicked");
            }
        }
    }
}

impl Drop for RecorderHandle {
    fn drop(&mut self) {
        self.join();
    }
}

struct OpenFile {
    path: PathBuf,
    writer: mcap::Writer<BufWriter<File>>,
    rx_channel: u16,
    status_channel: u16,
    alarm_channel: u16,
    event_channel: u16,
    sequence: u32,
    wall_offset_ns: i128,
    last_flush: Instant,
    messages: u64,
    procedure_id: u64,
    alarm_bits: u64,
    link_state: u32,
}

struct Worker {
    settings: RecorderSettings,
    recording: bool,
    rx: TapReceiver<RxChunk>,
    statuses: TapReceiver<Status>,
    commands: mpsc::Receiver<Command>,
    state: Arc<Mutex<RecorderStatus>>,
    /// Set while recording is stopped by an error (read by the 1 kHz loop for the alarm bit).
    failed: Arc<AtomicBool>,
    file: Option<OpenFile>,
    /// Chunks read while recording is wanted but no file is open yet (before the first status).
    pending: Vec<RxChunk>,
    files_finished: u64,
}

fn mcap_err(path: &Path, e: mcap::McapError) -> RecordError {
    // The MCAP error's own text hides its cause ("I/O error from writing"): name it too (e.g. "No
    // space left on device").
    let mut message = e.to_string();
    let mut source = std::error::Error::source(&e);
    while let Some(cause) = source {
        message.push_str(": ");
        message.push_str(&cause.to_string());
        source = cause.source();
    }
    RecordError::Mcap {
        path: path.display().to_string(),
        message,
    }
}

impl Worker {
    fn run(mut self) {
        loop {
            let mut quit = false;
            loop {
                match self.commands.try_recv() {
                    Ok(Command::Start) => self.recording = true,
                    Ok(Command::Stop) => {
                        self.recording = false;
                        self.finish("stop requested");
                    }
                    Ok(Command::Rotate(reason)) => self.finish(&reason),
                    Err(mpsc::TryRecvError::Empty) => break,
                    Err(mpsc::TryRecvError::Disconnected) => {
                        quit = true;
                        break;
                    }
                }
            }
            // Statuses first: the first one opens the file (it names the procedure).
            match self.statuses.rx.recv_timeout(DRAIN_PERIOD) {
                Ok(s) => self.on_status(s),
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => quit = true,
            }
            while let Ok(s) = self.statuses.rx.try_recv() {
                self.on_status(s);
            }
            while let Ok(c) = self.rx.rx.try_recv() {
                self.on_chunk(c);
            }
            self.maybe_flush();
            self.publish_state();
            if quit {
                break;
            }
        }
        self.finish("daemon stopping");
        self.publish_state();
    }

    fn publish_state(&self) {
        if let Ok(mut s) = self.state.lock() {
            s.recording = self.file.is_some();
            if let Some(f) = &self.file {
                s.path = Some(f.path.clone());
                s.messages = f.messages;
            }
            s.files_finished = self.files_finished;
            s.rx_dropped = self.rx.dropped();
            s.status_dropped = self.statuses.dropped();
        }
    }

    fn fail(&mut self, e: RecordError) {
        tracing::error!(error = %e, "recording stopped; the procedure goes on");
        self.failed.store(true, Ordering::Relaxed);
        self.recording = false;
        self.file = None;
        if let Ok(mut s) = self.state.lock() {
            s.last_error = Some(e.to_string());
        }
    }

    fn on_status(&mut self, status: Status) {
        if let Some(f) = &self.file {
            if status.procedure_id != f.procedure_id && f.procedure_id != 0 {
                self.finish("new procedure");
            }
        }
        if self.file.is_none() && self.recording {
            match self.open(&status) {
                Ok(f) => {
                    tracing::info!(path = %f.path.display(), "recording the procedure");
                    self.failed.store(false, Ordering::Relaxed);
                    self.file = Some(f);
                    for c in std::mem::take(&mut self.pending) {
                        self.on_chunk(c);
                    }
                }
                Err(e) => return self.fail(e),
            }
        }
        let Some(f) = self.file.as_mut() else {
            return;
        };
        let t = f.log_time(status.publish_monotonic_ns);
        let mut result = f.write(f.status_channel, t, format::status_bytes(&status));
        if result.is_ok() && status.alarm_bits != f.alarm_bits {
            let change = AlarmChange {
                sim_time_s: status.sim_time_s,
                procedure_time_s: status.procedure_time_s,
                alarm_bits: status.alarm_bits,
                raised: alarms::names(status.alarm_bits & !f.alarm_bits),
                cleared: alarms::names(f.alarm_bits & !status.alarm_bits),
            };
            f.alarm_bits = status.alarm_bits;
            result = f.write_json(f.alarm_channel, t, &change);
        }
        if result.is_ok() && status.link_state != f.link_state {
            f.link_state = status.link_state;
            result = f.event(t, "link_state", link_state::name(status.link_state));
        }
        if result.is_ok() && f.procedure_id == 0 && status.procedure_id != 0 {
            f.procedure_id = status.procedure_id;
            result = f.event(t, "procedure_changed", &status.procedure_id.to_string());
        }
        if let Err(e) = result {
            self.fail(e);
        }
    }

    fn on_chunk(&mut self, chunk: RxChunk) {
        let Some(f) = self.file.as_mut() else {
            if self.recording && self.pending.len() < RX_TAP_CAPACITY {
                self.pending.push(chunk);
            }
            return;
        };
        let mut payload =
            [0u8; format::RX_HEADER_LEN + hydrometra_drivers::transport::RX_CHUNK_MAX_BYTES];
        let data = chunk.data();
        payload[..format::RX_HEADER_LEN].copy_from_slice(&chunk.host_monotonic_ns.to_le_bytes());
        payload[format::RX_HEADER_LEN..format::RX_HEADER_LEN + data.len()].copy_from_slice(data);
        let t = f.log_time(chunk.host_monotonic_ns);
        if let Err(e) = f.write(
            f.rx_channel,
            t,
            &payload[..format::RX_HEADER_LEN + data.len()],
        ) {
            self.fail(e);
        }
    }

    fn maybe_flush(&mut self) {
        let interval = self.settings.flush_interval;
        let Some(f) = self.file.as_mut() else {
            return;
        };
        if f.last_flush.elapsed() < interval {
            return;
        }
        f.last_flush = Instant::now();
        let drops = (self.rx.dropped(), self.statuses.dropped());
        let r = f.writer.flush().map_err(|e| mcap_err(&f.path, e));
        if let Err(e) = r {
            self.fail(e);
        } else if drops != (0, 0) {
            tracing::debug!(
                rx = drops.0,
                status = drops.1,
                "recorder taps dropped values"
            );
        }
    }

    fn finish(&mut self, reason: &str) {
        let Some(mut f) = self.file.take() else {
            return;
        };
        let t = f.log_time(monotonic_ns());
        let detail = format!(
            "{reason}; taps dropped {} received chunks and {} statuses since the daemon started",
            self.rx.dropped(),
            self.statuses.dropped()
        );
        let r = f.event(t, "recording_stopped", &detail).and_then(|()| {
            f.writer
                .finish()
                .map(|_| ())
                .map_err(|e| mcap_err(&f.path, e))
        });
        match r {
            Ok(()) => {
                self.files_finished += 1;
                tracing::info!(path = %f.path.display(), messages = f.messages, "recording finished");
            }
            Err(e) => tracing::error!(error = %e, "recording could not be finished"),
        }
        if let Ok(mut s) = self.state.lock() {
            s.path = Some(f.path.clone());
            s.messages = f.messages;
        }
    }

    fn open(&self, status: &Status) -> Result<OpenFile, RecordError> {
        let dir = &self.settings.dir;
        let stem = format!("procedure-{}", status.procedure_id);
        let mut path = dir.join(format!("{stem}.mcap"));
        let mut n = 2;
        while path.exists() {
            path = dir.join(format!("{stem}-{n}.mcap"));
            n += 1;
        }
        let file = File::create(&path).map_err(|source| RecordError::Io {
            path: path.display().to_string(),
            source,
        })?;
        let e = |e| mcap_err(&path, e);
        let mut writer = mcap::WriteOptions::new()
            .profile(format::PROFILE)
            .library(concat!("hydrometrad ", env!("CARGO_PKG_VERSION")))
            .compression(Some(mcap::Compression::Lz4))
            .create(BufWriter::new(file))
            .map_err(e)?;
        let binary = format::BINARY_ENCODING;
        let layout = format::LAYOUT_SCHEMA_ENCODING;
        let none = BTreeMap::new();
        let s_rx = writer
            .add_schema(
                format::SCHEMA_RIG_RX,
                layout,
                format::SCHEMA_RIG_RX_TEXT.as_bytes(),
            )
            .map_err(e)?;
        let s_status = writer
            .add_schema(
                format::SCHEMA_STATUS,
                layout,
                format::SCHEMA_STATUS_TEXT.as_bytes(),
            )
            .map_err(e)?;
        let s_alarm = writer
            .add_schema(
                format::SCHEMA_ALARM,
                "jsonschema",
                format::SCHEMA_ALARM_JSON.as_bytes(),
            )
            .map_err(e)?;
        let s_event = writer
            .add_schema(
                format::SCHEMA_EVENT,
                "jsonschema",
                format::SCHEMA_EVENT_JSON.as_bytes(),
            )
            .map_err(e)?;
        let rx_channel = writer
            .add_channel(s_rx, format::TOPIC_RIG_RX, binary, &none)
            .map_err(e)?;
        let status_channel = writer
            .add_channel(s_status, format::TOPIC_STATUS, binary, &none)
            .map_err(e)?;
        let alarm_channel = writer
            .add_channel(s_alarm, format::TOPIC_ALARMS, "json", &none)
            .map_err(e)?;
        let event_channel = writer
            .add_channel(s_event, format::TOPIC_EVENTS, "json", &none)
            .map_err(e)?;
        let mono = monotonic_ns();
        let wall = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map(|d| d.as_nanos() as i128)
            .unwrap_or(0);
        let wall_offset_ns = wall - i128::from(mono);
        let mut metadata = self.settings.metadata.clone();
        metadata.insert("format_version".into(), format::FORMAT_VERSION.to_string());
        metadata.insert("wall_minus_monotonic_ns".into(), wall_offset_ns.to_string());
        metadata.insert("procedure_id".into(), status.procedure_id.to_string());
        metadata.insert("run_id".into(), status.run_id.to_string());
        metadata.insert(
            "status_size_bytes".into(),
            std::mem::size_of::<Status>().to_string(),
        );
        writer
            .write_metadata(&mcap::records::Metadata {
                name: format::METADATA_NAME.into(),
                metadata,
            })
            .map_err(e)?;
        let mut f = OpenFile {
            path: path.clone(),
            writer,
            rx_channel,
            status_channel,
            alarm_channel,
            event_channel,
            sequence: 0,
            wall_offset_ns,
            last_flush: Instant::now(),
            messages: 0,
            procedure_id: status.procedure_id,
            alarm_bits: 0,
            link_state: u32::MAX,
        };
        let t = f.log_time(mono);
        f.event(
            t,
            "recording_started",
            &format!("procedure {}", status.procedure_id),
        )?;
        Ok(f)
    }
}

impl OpenFile {
    fn log_time(&self, monotonic_ns: u64) -> u64 {
        (i128::from(monotonic_ns) + self.wall_offset_ns).max(0) as u64
    }

    fn write(&mut self, channel: u16, t: u64, data: &[u8]) -> Result<(), RecordError> {
        self.sequence = self.sequence.wrapping_add(1);
        self.messages += 1;
        let header = mcap::records::MessageHeader {
            channel_id: channel,
            sequence: self.sequence,
            log_time: t,
            publish_time: t,
        };
        self.writer
            .write_to_known_channel(&header, data)
            .map_err(|e| mcap_err(&self.path, e))
    }

    fn write_json<T: serde::Serialize>(
        &mut self,
        channel: u16,
        t: u64,
        value: &T,
    ) -> Result<(), RecordError> {
        let json = serde_json::to_vec(value).map_err(|e| RecordError::Format {
            path: self.path.display().to_string(),
            message: format!("cannot encode JSON: {e}"),
        })?;
        self.write(channel, t, &json)
    }

    fn event(&mut self, t: u64, kind: &str, detail: &str) -> Result<(), RecordError> {
        let ev = ControlEvent {
            kind: kind.into(),
            detail: detail.into(),
        };
        self.write_json(self.event_channel, t, &ev)
    }
}
