//! Serial transport: a dedicated I/O thread that opens the rig, handshakes, decodes and calibrates
//! samples, detects disconnects and reconnects with backoff.
//!
//! Timing rules (also in `docs/rig-protocol.md`): the host sends a heartbeat every 100 ms; a sample
//! older than 100 ms makes the link [`LinkState::Stale`] (the daemon then treats the valves as
//! closed); no valid frame for 1 s drops the port and reconnects; a device hello must answer a host
//! hello within 250 ms (4 attempts); reconnect backoff starts at 50 ms and doubles up to 2 s.

use std::io::{ErrorKind, Write};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use tracing::{debug, info, warn};

use crate::calibration::Calibration;
use crate::framing::FrameDecoder;
use crate::port_reader::PortReader;
use crate::state::{LinkCounters, LinkDownReason, LinkState, RigState};
use crate::tap::Tap;
use crate::wire::{
    encode_frame, FrameError, Heartbeat, HostHello, Message, SensorSample, MAX_ENCODED_LEN,
    PROTOCOL_VERSION,
};

/// USB vendor id of the rig (pid.codes; matches `udev/70-hydrometra-rig.rules`).
pub const RIG_USB_VID: u16 = 0x1209;
/// USB product id of the rig (matches `udev/70-hydrometra-rig.rules`).
pub const RIG_USB_PID: u16 = 0x0001;
/// The stable device path the udev rule creates.
pub const RIG_DEVICE_PATH: &str = "/dev/hydrometra-rig";

/// Which device to open.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum DeviceTarget {
    /// A device node or a symlink to one (re-resolved on every reconnect).
    Path(PathBuf),
    /// The first USB serial device with this vendor and product id (and serial number, if given).
    Usb {
        /// USB vendor id.
        vid: u16,
        /// USB product id.
        pid: u16,
        /// USB serial number string, if the match must be exact.
        serial_number: Option<String>,
    },
}

impl std::fmt::Display for DeviceTarget {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            DeviceTarget::Path(p) => write!(f, "{}", p.display()),
            DeviceTarget::Usb {
                vid,
                pid,
                serial_number,
            } => {
                write!(f, "usb {vid:04x}:{pid:04x}")?;
                if let Some(s) = serial_number {
                    write!(f, " serial {s}")?;
                }
                Ok(())
            }
        }
    }
}

/// Transport configuration. [`LinkConfig::new`] gives the documented defaults.
#[derive(Debug, Clone)]
pub struct LinkConfig {
    /// The device to open.
    pub target: DeviceTarget,
    /// Raw-to-SI calibration applied to every sample.
    pub calibration: Calibration,
    /// Baud rate (ignored by USB CDC-ACM devices and pseudo-terminals). Default 115200.
    pub baud_rate: u32,
    /// Open the port exclusively (TIOCEXCL + flock). Default true.
    pub exclusive: bool,
    /// A sample older than this makes the link `Stale`. Default 100 ms.
    pub stale_after: Duration,
    /// No valid frame for this long drops the port and reconnects. Default 1 s.
    pub link_timeout: Duration,
    /// Time a device hello may take to answer a host hello. Default 250 ms.
    pub handshake_timeout: Duration,
    /// Host hellos sent before giving up on a port and reconnecting. Default 4.
    pub handshake_attempts: u32,
    /// Host heartbeat period. Default 100 ms.
    pub heartbeat_period: Duration,
    /// First reconnect delay. Default 50 ms.
    pub backoff_initial: Duration,
    /// Longest reconnect delay (the delay doubles after each failure). Default 2 s.
    pub backoff_max: Duration,
    /// Longest single wait for input (rounded up to whole ms); bounds shutdown and timer
    /// latency. Default 10 ms.
    pub read_timeout: Duration,
    /// Where the I/O thread copies every chunk of bytes it reads, as read, for a recorder.
    /// Default none.
    pub rx_tap: Option<RxTap>,
}

impl LinkConfig {
    /// The documented defaults for `target`.
    pub fn new(target: DeviceTarget, calibration: Calibration) -> Self {
        Self {
            target,
            calibration,
            baud_rate: 115_200,
            exclusive: true,
            stale_after: Duration::from_millis(100),
            link_timeout: Duration::from_secs(1),
            handshake_timeout: Duration::from_millis(250),
            handshake_attempts: 4,
            heartbeat_period: Duration::from_millis(100),
            backoff_initial: Duration::from_millis(50),
            backoff_max: Duration::from_secs(2),
            read_timeout: Duration::from_millis(10),
            rx_tap: None,
        }
    }
}

/// Size of one [`RxChunk`]: the I/O thread's read buffer, so one read is one chunk.
pub const RX_CHUNK_MAX_BYTES: usize = 512;

/// One read from the port: the bytes exactly as received, before framing, with the host time.
#[derive(Clone, Copy)]
pub struct RxChunk {
    /// Host `CLOCK_MONOTONIC` when the read returned, ns (the clock `Instant` uses on Linux).
    pub host_monotonic_ns: u64,
    /// Number of valid bytes in `bytes`.
    pub len: u16,
    /// The bytes; only `..len` are valid.
    pub bytes: [u8; RX_CHUNK_MAX_BYTES],
}

impl RxChunk {
    /// The received bytes.
    pub fn data(&self) -> &[u8] {
        &self.bytes[..usize::from(self.len).min(RX_CHUNK_MAX_BYTES)]
    }
}

impl std::fmt::Debug for RxChunk {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RxChunk")
            .field("host_monotonic_ns", &self.host_monotonic_ns)
            .field("len", &self.len)
            .finish()
    }
}

/// The receive tap: the I/O thread offers every read to it, never blocking (see [`crate::tap`]).
pub type RxTap = Tap<RxChunk>;

impl RxTap {
    /// Offers one read; never blocks. Returns false when it was dropped (full or no receiver).
    pub fn offer_bytes(&self, host_monotonic_ns: u64, data: &[u8]) -> bool {
        let mut chunk = RxChunk {
            host_monotonic_ns,
            len: 0,
            bytes: [0; RX_CHUNK_MAX_BYTES],
        };
        let n = data.len().min(RX_CHUNK_MAX_BYTES);
        chunk.bytes[..n].copy_from_slice(&data[..n]);
        chunk.len = n as u16;
        self.offer(chunk)
    }
}

/// Host `CLOCK_MONOTONIC`, ns: the clock of [`RxChunk::host_monotonic_ns`] and of `Instant`.
pub fn monotonic_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; CLOCK_MONOTONIC is always supported on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    (ts.tv_sec as u64).saturating_mul(1_000_000_000) + ts.tv_nsec as u64
}

/// Identity of the connected rig, from its device hello.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceInfo {
    /// Protocol version the device speaks.
    pub protocol_version: u8,
    /// Firmware version `major.minor.patch`.
    pub firmware_version: String,
    /// Serial number (non-printable bytes replaced).
    pub serial_number: String,
    /// Capability bits (`wire::capabilities`).
    pub capabilities: u32,
    /// Calibration id reported by the rig.
    pub calibration_id: u32,
    /// Sample rate the device announced, Hz.
    pub sample_rate_hz: u16,
}

/// A consistent copy of the link's state.
#[derive(Debug, Clone, PartialEq)]
pub struct LinkSnapshot {
    /// Current link state (`Stale` once the latest sample is older than `stale_after`).
    pub link_state: LinkState,
    /// Cumulative counters.
    pub counters: LinkCounters,
    /// The device of the current or last session.
    pub device: Option<DeviceInfo>,
    /// Last calibrated sample (kept after a loss).
    pub latest: Option<RigState>,
    /// Age of `latest`.
    pub last_sample_age: Option<Duration>,
    /// The raw sample behind `latest`, as received (for calibrating and diagnosing the rig).
    pub latest_raw: Option<SensorSample>,
    /// Why the last open or session failed (cleared by a successful handshake).
    pub last_error: Option<String>,
    /// The kind of `last_error`.
    pub down_reason: Option<LinkDownReason>,
}

/// The allocation-free part of a [`LinkSnapshot`]: what the simulation loop reads every tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LinkStatus {
    /// Current link state (`Stale` once the latest sample is older than `stale_after`).
    pub link_state: LinkState,
    /// Cumulative counters.
    pub counters: LinkCounters,
    /// Last calibrated sample (kept after a loss).
    pub latest: Option<RigState>,
    /// Age of `latest`.
    pub last_sample_age: Option<Duration>,
    /// Why the link is down (the last failure; `None` after a successful handshake or before the
    /// first attempt). The message is in [`LinkSnapshot::last_error`].
    pub down_reason: Option<LinkDownReason>,
}

impl LinkStatus {
    /// A link that has never produced anything.
    pub fn disconnected() -> Self {
        Self {
            link_state: LinkState::Disconnected,
            counters: LinkCounters::default(),
            latest: None,
            last_sample_age: None,
            down_reason: None,
        }
    }
}

/// The transport could not start.
#[derive(Debug, thiserror::Error)]
pub enum TransportError {
    /// The I/O thread could not be spawned.
    #[error("cannot spawn the rig I/O thread: {0}")]
    Spawn(std::io::Error),
    /// A configuration value is unusable.
    #[error("invalid link configuration: {field} = {value}: expected {expected}")]
    InvalidConfig {
        /// Field name.
        field: &'static str,
        /// The value.
        value: String,
        /// What is allowed.
        expected: &'static str,
    },
}

struct Inner {
    link_state: LinkState,
    counters: LinkCounters,
    device: Option<DeviceInfo>,
    latest: Option<RigState>,
    latest_raw: Option<SensorSample>,
    last_error: Option<String>,
    down_reason: Option<LinkDownReason>,
    stopping: bool,
    /// Threads in [`RigLink::wait_for_sample`]: a sample wakes the condition variable only when
    /// somebody waits (a wake is a system call, 250 a second for nobody otherwise).
    sample_waiters: u32,
}

struct Shared {
    inner: Mutex<Inner>,
    sample_cv: Condvar,
    stop_cv: Condvar,
    stop: AtomicBool,
    io_cpu_ns: AtomicU64,
    stale_after: Duration,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, Inner> {
        // A panic elsewhere must not take the link down with it: the data stays consistent
        // because every critical section only assigns whole values.
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// Handle to the rig link; the I/O thread runs until [`RigLink::shutdown`] or drop.
pub struct RigLink {
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
}

impl RigLink {
    /// Starts the I/O thread. A missing device is not an error: it keeps retrying with backoff.
    pub fn spawn(config: LinkConfig) -> Result<RigLink, TransportError> {
        for (field, d) in [
            ("stale_after", config.stale_after),
            ("link_timeout", config.link_timeout),
            ("handshake_timeout", config.handshake_timeout),
            ("heartbeat_period", config.heartbeat_period),
            ("backoff_initial", config.backoff_initial),
            ("read_timeout", config.read_timeout),
        ] {
            if d.is_zero() {
                return Err(TransportError::InvalidConfig {
                    field,
                    value: format!("{d:?}"),
                    expected: "a non-zero duration",
                });
            }
        }
        if config.backoff_max < config.backoff_initial {
            return Err(TransportError::InvalidConfig {
                field: "backoff_max",
                value: format!("{:?}", config.backoff_max),
                expected: "at least backoff_initial",
            });
        }
        let shared = Arc::new(Shared {
            inner: Mutex::new(Inner {
                link_state: LinkState::Disconnected,
                counters: LinkCounters::default(),
                device: None,
                latest: None,
                latest_raw: None,
                last_error: None,
                down_reason: None,
                stopping: false,
                sample_waiters: 0,
            }),
            sample_cv: Condvar::new(),
            stop_cv: Condvar::new(),
            stop: AtomicBool::new(false),
            io_cpu_ns: AtomicU64::new(0),
            stale_after: config.stale_after,
        });
        let thread_shared = Arc::clone(&shared);
        let thread = std::thread::Builder::new()
            .name("rig-io".into())
            .spawn(move || IoThread::new(config, thread_shared).run())
            .map_err(TransportError::Spawn)?;
        Ok(RigLink {
            shared,
            thread: Some(thread),
        })
    }

    /// A consistent copy of state, counters and the latest sample; cheap (one mutex lock).
    pub fn snapshot(&self) -> LinkSnapshot {
        let inner = self.shared.lock();
        let status = self.status_of(&inner, Instant::now());
        LinkSnapshot {
            link_state: status.link_state,
            counters: status.counters,
            device: inner.device.clone(),
            latest: status.latest,
            last_sample_age: status.last_sample_age,
            latest_raw: inner.latest_raw,
            last_error: inner.last_error.clone(),
            down_reason: inner.down_reason,
        }
    }

    /// The part of [`snapshot`](Self::snapshot) a real-time consumer needs, without allocating:
    /// safe to call every tick of a 1 kHz loop.
    pub fn status(&self) -> LinkStatus {
        self.status_at(Instant::now())
    }

    /// [`status`](Self::status) with the sample's age and staleness taken at `now`, for a loop
    /// that has just read the clock.
    pub fn status_at(&self, now: Instant) -> LinkStatus {
        let inner = self.shared.lock();
        self.status_of(&inner, now)
    }

    fn status_of(&self, inner: &Inner, now: Instant) -> LinkStatus {
        let age = inner
            .latest
            .as_ref()
            .map(|s| now.saturating_duration_since(s.received_at));
        let link_state = match (inner.link_state, age) {
            (LinkState::Connected, Some(a)) if a > self.shared.stale_after => LinkState::Stale,
            (s, _) => s,
        };
        LinkStatus {
            link_state,
            counters: inner.counters,
            latest: inner.latest,
            last_sample_age: age,
            down_reason: inner.down_reason,
        }
    }

    /// Blocks until a sample received after `newer_than` (any sample if `None`) is available, or
    /// `timeout` passes; returns that sample or `None`.
    pub fn wait_for_sample(
        &self,
        newer_than: Option<Instant>,
        timeout: Duration,
    ) -> Option<RigState> {
        let deadline = Instant::now() + timeout;
        let is_new = |s: &Option<RigState>| match (s, newer_than) {
            (Some(s), Some(t)) => s.received_at > t,
            (Some(_), None) => true,
            (None, _) => false,
        };
        let mut inner = self.shared.lock();
        loop {
            if is_new(&inner.latest) {
                return inner.latest;
            }
            let now = Instant::now();
            if now >= deadline || inner.stopping {
                return None;
            }
            inner.sample_waiters += 1;
            inner = self
                .shared
                .sample_cv
                .wait_timeout(inner, deadline - now)
                .map(|(g, _)| g)
                .unwrap_or_else(|e| e.into_inner().0);
            inner.sample_waiters -= 1;
        }
    }

    /// CPU time consumed by the I/O thread so far (Linux; zero elsewhere). Lets tests and the
    /// daemon's telemetry prove that a dead port is not busy-polled.
    pub fn io_thread_cpu_time(&self) -> Duration {
        Duration::from_nanos(self.shared.io_cpu_ns.load(Ordering::Relaxed))
    }

    /// Stops and joins the I/O thread.
    pub fn shutdown(mut self) {
        self.stop_thread();
    }

    fn stop_thread(&mut self) {
        self.shared.stop.store(true, Ordering::SeqCst);
        {
            let mut inner = self.shared.lock();
            inner.stopping = true;
        }
        self.shared.stop_cv.notify_all();
        self.shared.sample_cv.notify_all();
        if let Some(t) = self.thread.take() {
            if t.join().is_err() {
                warn!("rig I/O thread panicked");
            }
        }
    }
}

impl Drop for RigLink {
    fn drop(&mut self) {
        self.stop_thread();
    }
}

/// How often a session refreshes the I/O thread's CPU-time probe: reading a thread's CPU clock
/// is a system call (no vDSO), too dear for every sample of a 250 Hz rig.
const CPU_PROBE_INTERVAL: Duration = Duration::from_millis(100);

/// CPU time of the calling thread.
fn thread_cpu_time_ns() -> u64 {
    #[cfg(target_os = "linux")]
    {
        let mut ts = libc::timespec {
            tv_sec: 0,
            tv_nsec: 0,
        };
        // SAFETY: clock_gettime writes into the timespec we own; the clock id is valid on Linux.
        let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
        if rc == 0 {
            return (ts.tv_sec as u64) * 1_000_000_000 + ts.tv_nsec as u64;
        }
    }
    0
}

enum SessionEnd {
    Shutdown,
    Lost(LinkDownReason, String),
    Incompatible(u8),
}

struct IoThread {
    config: LinkConfig,
    shared: Arc<Shared>,
    decoder: FrameDecoder,
    tx_sequence: u32,
    sessions: u64,
    nonce: u32,
    started: Instant,
}

impl IoThread {
    fn new(config: LinkConfig, shared: Arc<Shared>) -> Self {
        // The nonce only pairs a device hello with our host hello; the clock is random enough.
        let nonce = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.subsec_nanos())
            .unwrap_or(1);
        Self {
            config,
            shared,
            decoder: FrameDecoder::new(),
            tx_sequence: 0,
            sessions: 0,
            nonce,
            started: Instant::now(),
        }
    }

    fn stopping(&self) -> bool {
        self.shared.stop.load(Ordering::SeqCst)
    }

    fn update_cpu(&self) {
        self.shared
            .io_cpu_ns
            .store(thread_cpu_time_ns(), Ordering::Relaxed);
    }

    fn set_down(&self, reason: LinkDownReason, message: String) {
        let mut inner = self.shared.lock();
        inner.down_reason = Some(reason);
        inner.last_error = Some(message);
    }

    fn set_state(&self, state: LinkState) {
        let mut inner = self.shared.lock();
        if inner.link_state != state {
            debug!(from = ?inner.link_state, to = ?state, "rig link state");
            inner.link_state = state;
        }
    }

    /// Sleeps for the backoff delay unless shutdown is requested; returns false on shutdown.
    fn sleep_backoff(&self, delay: Duration) -> bool {
        let inner = self.shared.lock();
        let (inner, _) = self
            .shared
            .stop_cv
            .wait_timeout_while(inner, delay, |i| !i.stopping)
            .unwrap_or_else(|e| e.into_inner());
        let stopping = inner.stopping;
        drop(inner);
        self.update_cpu();
        !stopping
    }

    fn run(mut self) {
        let mut backoff = self.config.backoff_initial;
        while !self.stopping() {
            self.update_cpu();
            let port = match self.open() {
                Ok(p) => p,
                Err((reason, e)) => {
                    debug!(target_device = %self.config.target, error = %e, ?backoff, "rig not available");
                    self.set_down(reason, e);
                    if !self.sleep_backoff(backoff) {
                        break;
                    }
                    backoff = (backoff * 2).min(self.config.backoff_max);
                    continue;
                }
            };
            self.set_state(LinkState::Handshaking);
            self.decoder.reset();
            let (end, established) = self.session(port);
            match end {
                SessionEnd::Shutdown => break,
                SessionEnd::Lost(kind, reason) => {
                    self.set_down(kind, reason.clone());
                    if established {
                        warn!(target_device = %self.config.target, %reason, "rig link lost");
                        backoff = self.config.backoff_initial;
                    } else {
                        debug!(target_device = %self.config.target, %reason, "rig session failed");
                    }
                    self.set_state(LinkState::Disconnected);
                }
                SessionEnd::Incompatible(version) => {
                    self.set_down(
                        LinkDownReason::IncompatibleVersion { version },
                        format!(
                            "{}: the device speaks wire protocol version {version}, this host \
                             speaks {PROTOCOL_VERSION}: update the rig firmware or hydrometrad",
                            self.config.target
                        ),
                    );
                    warn!(target_device = %self.config.target, version, ours = PROTOCOL_VERSION,
                        "rig speaks an incompatible protocol version");
                    self.set_state(LinkState::Incompatible);
                }
            }
            if !self.sleep_backoff(backoff) {
                break;
            }
            backoff = (backoff * 2).min(self.config.backoff_max);
        }
        self.set_state(LinkState::Disconnected);
    }

    fn open(&self) -> Result<serialport::TTYPort, (LinkDownReason, String)> {
        let path = match &self.config.target {
            DeviceTarget::Path(p) => p.to_string_lossy().into_owned(),
            DeviceTarget::Usb {
                vid,
                pid,
                serial_number,
            } => find_usb_port(*vid, *pid, serial_number.as_deref())
                .map_err(|e| (LinkDownReason::UsbDeviceNotFound, e))?,
        };
        serialport::new(&path, self.config.baud_rate)
            .timeout(self.config.read_timeout)
            .exclusive(self.config.exclusive)
            .open_native()
            .map_err(|e| open_failure(&path, &e))
    }

    fn send(&mut self, port: &mut serialport::TTYPort, message: &Message) -> Result<(), String> {
        let mut buf = [0u8; MAX_ENCODED_LEN];
        let n = encode_frame(self.tx_sequence, message, &mut buf)
            .map_err(|_| "frame buffer too small".to_string())?;
        self.tx_sequence = self.tx_sequence.wrapping_add(1);
        match port.write_all(&buf[..n]) {
            Ok(()) => Ok(()),
            // A device that does not drain its input is caught by the frame timeout instead.
            Err(e) if e.kind() == ErrorKind::TimedOut => Ok(()),
            Err(e) => Err(format!("write failed: {e}")),
        }
    }

    fn session(&mut self, mut port: serialport::TTYPort) -> (SessionEnd, bool) {
        let mut established = false;
        let end = self.session_inner(&mut port, &mut established);
        // Clear TIOCEXCL so the same node can be reopened (the tty outlives our descriptor,
        // e.g. a pseudo-terminal whose master stays open).
        if self.config.exclusive {
            #[cfg(target_os = "linux")]
            {
                use std::os::fd::AsRawFd;
                // SAFETY: TIOCNXCL takes no argument; the descriptor is open and owned by `port`.
                unsafe {
                    libc::ioctl(port.as_raw_fd(), libc::TIOCNXCL);
                }
            }
        }
        drop(port);
        (end, established)
    }

    fn session_inner(
        &mut self,
        port: &mut serialport::TTYPort,
        established: &mut bool,
    ) -> SessionEnd {
        let cfg = self.config.clone();
        self.nonce = self
            .nonce
            .wrapping_mul(1_664_525)
            .wrapping_add(1_013_904_223);
        let hello = Message::HostHello(HostHello {
            protocol_version: PROTOCOL_VERSION,
            nonce: self.nonce,
        });
        if let Err(e) = self.send(port, &hello) {
            return SessionEnd::Lost(LinkDownReason::Lost, e);
        }
        let mut hello_sent_at = Instant::now();
        let mut attempts = 1;
        let mut last_frame_at = Instant::now();
        let mut last_heartbeat_at = Instant::now();
        let mut expected_seq: Option<u32> = None;
        let mut reader = match PortReader::new(port, cfg.read_timeout) {
            Ok(r) => r,
            Err(e) => {
                return SessionEnd::Lost(
                    LinkDownReason::Lost,
                    format!("cannot wait for the port's input: {e}"),
                )
            }
        };
        let mut buf = [0u8; RX_CHUNK_MAX_BYTES];
        let mut frames = Vec::with_capacity(16);
        self.update_cpu();
        let mut cpu_probed_at = Instant::now();
        loop {
            if self.stopping() {
                return SessionEnd::Shutdown;
            }
            match reader.read(&mut buf) {
                Ok(0) => {}
                Ok(n) => {
                    if let Some(tap) = &cfg.rx_tap {
                        tap.offer_bytes(monotonic_ns(), &buf[..n]);
                    }
                    frames.clear();
                    self.decoder.push_slice(&buf[..n], |r| frames.push(r));
                    let now = Instant::now();
                    for r in frames.drain(..) {
                        match r {
                            Ok(frame) => {
                                last_frame_at = now;
                                if let Some(end) =
                                    self.on_frame(frame, now, established, &mut expected_seq)
                                {
                                    self.publish_decoder_stats();
                                    return end;
                                }
                            }
                            Err(FrameError::UnsupportedVersion { version, .. })
                                if !*established =>
                            {
                                self.publish_decoder_stats();
                                return SessionEnd::Incompatible(version);
                            }
                            Err(e) => debug!(error = %e, "rejected rig frame"),
                        }
                    }
                    self.publish_decoder_stats();
                }
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => {
                    return SessionEnd::Lost(LinkDownReason::Lost, format!("read failed: {e}"))
                }
            }
            let now = Instant::now();
            if now - cpu_probed_at >= CPU_PROBE_INTERVAL {
                self.update_cpu();
                cpu_probed_at = now;
            }
            if !*established {
                if now - hello_sent_at > cfg.handshake_timeout {
                    if attempts >= cfg.handshake_attempts {
                        return SessionEnd::Lost(
                            LinkDownReason::NoHandshake,
                            format!(
                                "{}: no device hello after {attempts} host hellos (is it the rig?)",
                                self.config.target
                            ),
                        );
                    }
                    if let Err(e) = self.send(port, &hello) {
                        return SessionEnd::Lost(LinkDownReason::Lost, e);
                    }
                    attempts += 1;
                    hello_sent_at = now;
                }
                continue;
            }
            if now - last_frame_at > cfg.link_timeout {
                return SessionEnd::Lost(
                    LinkDownReason::Timeout,
                    format!("no valid frame for {} ms", cfg.link_timeout.as_millis()),
                );
            }
            if now - last_heartbeat_at >= cfg.heartbeat_period {
                last_heartbeat_at = now;
                let uptime_ms = self.started.elapsed().as_millis() as u32; // wraps by design
                if let Err(e) = self.send(port, &Message::Heartbeat(Heartbeat { uptime_ms })) {
                    return SessionEnd::Lost(LinkDownReason::Lost, e);
                }
            }
            let mut inner = self.shared.lock();
            if inner.link_state == LinkState::Connected {
                if let Some(latest) = &inner.latest {
                    if now.saturating_duration_since(latest.received_at) > cfg.stale_after {
                        inner.link_state = LinkState::Stale;
                    }
                }
            }
        }
    }

    fn publish_decoder_stats(&self) {
        let s = self.decoder.stats();
        let mut inner = self.shared.lock();
        inner.counters.frames = s.frames;
        inner.counters.crc_errors = s.crc_errors;
        inner.counters.malformed = s.malformed;
        inner.counters.resyncs = s.resyncs;
    }

    fn on_frame(
        &mut self,
        frame: crate::wire::Frame,
        now: Instant,
        established: &mut bool,
        expected_seq: &mut Option<u32>,
    ) -> Option<SessionEnd> {
        match frame.message {
            Message::DeviceHello(h) => {
                if h.nonce != self.nonce {
                    debug!(
                        nonce = h.nonce,
                        "device hello for another host hello; ignored"
                    );
                    return None;
                }
                if h.protocol_version != PROTOCOL_VERSION {
                    return Some(SessionEnd::Incompatible(h.protocol_version));
                }
                let info = DeviceInfo {
                    protocol_version: h.protocol_version,
                    firmware_version: format!(
                        "{}.{}.{}",
                        h.firmware_version.0, h.firmware_version.1, h.firmware_version.2
                    ),
                    serial_number: h
                        .serial_number_bytes()
                        .iter()
                        .map(|&b| if b.is_ascii_graphic() { b as char } else { '?' })
                        .collect(),
                    capabilities: h.capabilities,
                    calibration_id: h.calibration_id,
                    sample_rate_hz: h.sample_rate_hz,
                };
                let expected_cal = self.config.calibration.calibration_id;
                if expected_cal != 0 && expected_cal != h.calibration_id {
                    warn!(
                        device = h.calibration_id,
                        expected = expected_cal,
                        "rig reports a different calibration id than the calibration file"
                    );
                }
                if !*established {
                    *established = true;
                    self.sessions += 1;
                    info!(serial = %info.serial_number, firmware = %info.firmware_version,
                        "rig connected");
                    let mut inner = self.shared.lock();
                    if self.sessions > 1 {
                        inner.counters.reconnects += 1;
                    }
                    inner.device = Some(info);
                    inner.link_state = LinkState::Connected;
                    inner.last_error = None;
                    inner.down_reason = None;
                }
                *expected_seq = Some(frame.sequence.wrapping_add(1));
                None
            }
            _ if !*established => None, // Leftovers of an earlier session.
            Message::Sample(sample) => {
                self.track_sequence(frame.sequence, expected_seq);
                let mut inner = self.shared.lock();
                let outcome = self.config.calibration.apply(
                    &sample,
                    frame.sequence,
                    now,
                    inner.latest.as_ref(),
                );
                inner.counters.clamped_values += u64::from(outcome.clamped_values);
                inner.latest = Some(outcome.state);
                inner.latest_raw = Some(sample);
                inner.link_state = LinkState::Connected;
                let waiting = inner.sample_waiters > 0;
                drop(inner);
                if waiting {
                    self.shared.sample_cv.notify_all();
                }
                None
            }
            Message::Heartbeat(_) => {
                self.track_sequence(frame.sequence, expected_seq);
                None
            }
            Message::FaultReport(f) => {
                self.track_sequence(frame.sequence, expected_seq);
                warn!(
                    code = f.code,
                    severity = f.severity,
                    detail = f.detail,
                    "rig fault report"
                );
                self.shared.lock().counters.device_faults += 1;
                None
            }
            Message::HostHello(_) => None,
        }
    }

    fn track_sequence(&self, sequence: u32, expected: &mut Option<u32>) {
        if let Some(exp) = *expected {
            let gap = sequence.wrapping_sub(exp);
            // A forward jump is lost frames; a backward one (device restarted) just re-anchors.
            if gap != 0 && gap < u32::MAX / 2 {
                self.shared.lock().counters.sequence_gaps += u64::from(gap);
            }
        }
        *expected = Some(sequence.wrapping_add(1));
    }
}

/// Classifies a failed open and says what to do about it.
fn open_failure(path: &str, e: &serialport::Error) -> (LinkDownReason, String) {
    use serialport::ErrorKind as K;
    match e.kind() {
        K::Io(ErrorKind::NotFound) => (
            LinkDownReason::DeviceNotFound,
            format!(
                "{path}: no such device ({e}): check the path, the cable and the udev rule \
                 (docs/rig-protocol.md)"
            ),
        ),
        K::Io(ErrorKind::PermissionDenied) => {
            let gid = device_gid(path);
            let group = gid.map(|g| group_name(g).unwrap_or_else(|| format!("gid {g}")));
            let advice = match &group {
                Some(group) => format!(
                    "the device belongs to group `{group}`: add the user that runs this program \
                     to it (`sudo usermod -aG {group} $USER`, then log in again or restart the \
                     service)"
                ),
                None => "give the user that runs this program read-write access to it".into(),
            };
            (
                LinkDownReason::PermissionDenied { gid },
                format!("{path}: permission denied ({e}); {advice}"),
            )
        }
        K::NoDevice => (
            LinkDownReason::DeviceBusy,
            format!("{path}: busy ({e}): another program has the rig open"),
        ),
        _ => (
            LinkDownReason::OpenFailed,
            format!("{path}: cannot open: {e}"),
        ),
    }
}

/// Group id of a device node (following symlinks).
fn device_gid(path: &str) -> Option<u32> {
    use std::os::unix::fs::MetadataExt;
    std::fs::metadata(path).ok().map(|m| m.gid())
}

/// The name of a group id, from the system's group database.
pub fn group_name(gid: u32) -> Option<String> {
    // SAFETY: `group` is plain C data (integers and pointers) that getgrgid_r fills; all zeros is
    // a valid value of it.
    let mut group: libc::group = unsafe { std::mem::zeroed() };
    let mut buf = vec![0 as libc::c_char; 4096];
    let mut result: *mut libc::group = std::ptr::null_mut();
    // SAFETY: every pointer refers to storage we own for the duration of the call; on success
    // `result` points to `group`, whose `gr_name` points into `buf` (a NUL-terminated string).
    let rc = unsafe { libc::getgrgid_r(gid, &mut group, buf.as_mut_ptr(), buf.len(), &mut result) };
    if rc != 0 || result.is_null() || group.gr_name.is_null() {
        return None;
    }
    // SAFETY: see above.
    let name = unsafe { std::ffi::CStr::from_ptr(group.gr_name) };
    Some(name.to_string_lossy().into_owned())
}

fn find_usb_port(vid: u16, pid: u16, serial: Option<&str>) -> Result<String, String> {
    let ports = serialport::available_ports().map_err(|e| format!("cannot list ports: {e}"))?;
    ports
        .into_iter()
        .find(|p| match &p.port_type {
            serialport::SerialPortType::UsbPort(u) => {
                u.vid == vid
                    && u.pid == pid
                    && serial.is_none_or(|s| u.serial_number.as_deref() == Some(s))
            }
            _ => false,
        })
        .map(|p| p.port_name)
        .ok_or_else(|| {
            format!(
                "no USB serial device {vid:04x}:{pid:04x}{}",
                serial
                    .map(|s| format!(" with serial {s}"))
                    .unwrap_or_default()
            )
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_missing_device_is_reported_as_not_found_with_its_path() {
        let path = "/dev/hydrometra-test-does-not-exist";
        let link = RigLink::spawn(LinkConfig::new(
            DeviceTarget::Path(path.into()),
            Calibration::default(),
        ))
        .unwrap();
        let deadline = Instant::now() + Duration::from_secs(5);
        while link.status().down_reason.is_none() {
            assert!(Instant::now() < deadline, "no reason after 5 s");
            std::thread::sleep(Duration::from_millis(5));
        }
        let snap = link.snapshot();
        link.shutdown();
        assert_eq!(snap.link_state, LinkState::Disconnected);
        assert_eq!(snap.down_reason, Some(LinkDownReason::DeviceNotFound));
        let e = snap.last_error.unwrap_or_default();
        assert!(
            e.contains(path) && e.contains("No such file or directory"),
            "{e}"
        );
    }

    #[test]
    fn permission_denied_names_the_group_that_owns_the_device() {
        use std::os::unix::fs::MetadataExt;
        // As root nothing is denied, so the classification is fed the error open(2) gives.
        let path = std::env::temp_dir().join(format!("hm-perm-{}", std::process::id()));
        std::fs::write(&path, b"").unwrap();
        let gid = std::fs::metadata(&path).unwrap().gid();
        let denied = serialport::Error::new(
            serialport::ErrorKind::Io(ErrorKind::PermissionDenied),
            "Permission denied",
        );
        let (reason, message) = open_failure(path.to_str().unwrap(), &denied);
        std::fs::remove_file(&path).unwrap();
        assert_eq!(reason, LinkDownReason::PermissionDenied { gid: Some(gid) });
        let group = group_name(gid).expect("the file's group has a name");
        assert!(
            message.contains(&format!("group `{group}`"))
                && message.contains(&format!("usermod -aG {group}"))
                && message.contains("Permission denied"),
            "{message}"
        );
        assert_eq!(group_name(0).as_deref(), Some("root"));
    }
}
