//! The emulated firmware: one thread that owns the pseudo-terminal master.

use std::io::{ErrorKind, Read, Write};
use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::sync::{mpsc, Arc};
use std::time::{Duration, Instant};

use serialport::{SerialPort, TTYPort};
use tracing::{debug, info, warn};

use super::shared::{EmuShared, EmulatorError, EmulatorOptions, EmulatorStats};
use super::{Fault, FaultEvent, Scenario};
use crate::calibration::{Calibration, PA_PER_MMHG};
use crate::framing::FrameDecoder;
use crate::wire::{
    capabilities, encode_raw_frame, write_raw_frame_with_version, DeviceHello, FaultReport,
    Heartbeat, Message, SensorSample, MAX_ENCODED_LEN, MAX_FRAME_LEN, PROTOCOL_VERSION,
};

/// Longest time the loop blocks in a read; bounds fault and stop latency.
pub(super) const MAX_WAIT: Duration = Duration::from_millis(5);
/// Write timeout: a host that does not read must not stall the firmware.
pub(super) const WRITE_TIMEOUT: Duration = Duration::from_millis(2);
/// Protocol version announced by the `wrong_version` fault.
const WRONG_VERSION: u8 = PROTOCOL_VERSION + 1;

pub(super) struct Plugged {
    pub(super) master: TTYPort,
    // Kept open so the master never sees a hang-up while no host has the slave open.
    _slave: TTYPort,
}

impl Plugged {
    /// Opens a new pseudo-terminal pair and points the symlink `link_path` at its slave.
    pub(super) fn open(link_path: &std::path::Path) -> Result<Self, EmulatorError> {
        let (master, slave) = TTYPort::pair()?;
        let slave_name = slave.name().ok_or_else(|| EmulatorError::Link {
            path: link_path.display().to_string(),
            message: "the pseudo-terminal has no name".into(),
        })?;
        replace_symlink(link_path, &slave_name)?;
        debug!(link = %link_path.display(), pty = %slave_name, "emulated rig plugged in");
        Ok(Plugged {
            master,
            _slave: slave,
        })
    }
}

pub(super) struct Device {
    scenario: Scenario,
    options: EmulatorOptions,
    link_path: PathBuf,
    shared: Arc<EmuShared>,
    faults: mpsc::Receiver<Fault>,
    events: Vec<FaultEvent>,
    next_event: usize,
    port: Option<Plugged>,
    decoder: FrameDecoder,
    rng: fastrand::Rng,
    started: Instant,
    sequence: u32,
    session_last_host_frame: Option<Instant>,
    hang_until: Option<Instant>,
    replug_at: Option<Instant>,
    chunk_max_bytes: usize,
    pending_flips: u32,
    pending_drops: u32,
    pending_wrong_version: u32,
    next_sample: Instant,
    next_heartbeat: Instant,
}

impl Device {
    pub(super) fn new(
        scenario: Scenario,
        options: EmulatorOptions,
        link_path: PathBuf,
        shared: Arc<EmuShared>,
        faults: mpsc::Receiver<Fault>,
    ) -> Self {
        let mut events: Vec<FaultEvent> = scenario.faults.events.clone();
        events.extend(options.faults.events.iter().copied());
        events.sort_by(|a, b| a.at_s.total_cmp(&b.at_s));
        let chunk_max_bytes = options
            .faults
            .chunk_max_bytes
            .max(scenario.faults.chunk_max_bytes);
        let now = Instant::now();
        Self {
            rng: fastrand::Rng::with_seed(options.seed),
            scenario,
            options,
            link_path,
            shared,
            faults,
            events,
            next_event: 0,
            port: None,
            decoder: FrameDecoder::new(),
            started: now,
            sequence: 0,
            session_last_host_frame: None,
            hang_until: None,
            replug_at: None,
            chunk_max_bytes,
            pending_flips: 0,
            pending_drops: 0,
            pending_wrong_version: 0,
            next_sample: now,
            next_heartbeat: now,
        }
    }

    pub(super) fn origin(&self) -> Instant {
        self.started
    }

    fn stats(&self, f: impl FnOnce(&mut EmulatorStats)) {
        let mut s = self.shared.stats.lock().unwrap_or_else(|e| e.into_inner());
        f(&mut s);
    }

    /// Opens a new pseudo-terminal pair and points the symlink at its slave.
    pub(super) fn plug(&mut self) -> Result<(), EmulatorError> {
        self.port = Some(Plugged::open(&self.link_path)?);
        self.decoder.reset();
        self.session_last_host_frame = None;
        self.stats(|s| {
            s.plugged = true;
            s.session_active = false;
        });
        Ok(())
    }

    fn unplug(&mut self) {
        // Remove the link first so a host never reopens a pty number that gets reused.
        if let Err(e) = std::fs::remove_file(&self.link_path) {
            if e.kind() != ErrorKind::NotFound {
                warn!(link = %self.link_path.display(), error = %e, "cannot remove rig link");
            }
        }
        self.port = None;
        self.session_last_host_frame = None;
        self.stats(|s| {
            s.plugged = false;
            s.session_active = false;
        });
    }

    fn apply(&mut self, fault: Fault, now: Instant) {
        info!(?fault, "emulated rig: injecting fault");
        match fault {
            Fault::GarbageBurst { bytes } => {
                let garbage: Vec<u8> = (0..bytes).map(|_| self.rng.u8(..)).collect();
                if self.write_bytes(&garbage) {
                    self.stats(|s| s.garbage_bytes += bytes as u64);
                }
            }
            Fault::BitFlips { count } => self.pending_flips += count,
            Fault::DropFrames { count } => self.pending_drops += count,
            Fault::HeartbeatStop { duration } => {
                self.hang_until = Some(now + duration);
                self.stats(|s| s.hangs += 1);
            }
            Fault::Unplug { duration } => {
                if self.port.is_some() {
                    self.unplug();
                    self.stats(|s| s.unplugs += 1);
                }
                self.replug_at = Some(now + duration);
            }
            Fault::WrongVersion { count } => self.pending_wrong_version += count,
            Fault::FaultReport {
                code,
                severity,
                detail,
            } => {
                let m = Message::FaultReport(FaultReport {
                    code,
                    severity,
                    detail,
                });
                if self.send(&m, PROTOCOL_VERSION) {
                    self.stats(|s| s.fault_reports += 1);
                }
            }
            Fault::Chunking { max_bytes } => self.chunk_max_bytes = max_bytes,
        }
    }

    pub(super) fn run(mut self) {
        let sample_period = Duration::from_secs_f64(1.0 / self.options.sample_rate_hz);
        let heartbeat_period = Duration::from_secs_f64(1.0 / self.options.heartbeat_hz);
        let host_timeout = Duration::from_secs_f64(self.options.host_timeout_s);
        let mut buf = [0u8; 256];
        while !self.shared.stop.load(Ordering::SeqCst) {
            let now = Instant::now();
            while let Ok(f) = self.faults.try_recv() {
                self.apply(f, now);
            }
            let elapsed_s = (now - self.started).as_secs_f64();
            while let Some(ev) = self.events.get(self.next_event).copied() {
                if ev.at_s > elapsed_s {
                    break;
                }
                self.next_event += 1;
                self.apply(ev.fault, now);
            }
            if self.port.is_none() {
                match self.replug_at {
                    Some(t) if now >= t => match self.plug() {
                        Ok(()) => {
                            self.replug_at = None;
                            self.stats(|s| s.replugs += 1);
                        }
                        Err(e) => {
                            warn!(error = %e, "emulated rig cannot replug; retrying");
                            self.replug_at = Some(now + Duration::from_millis(100));
                        }
                    },
                    Some(t) => std::thread::sleep((t - now).min(MAX_WAIT)),
                    None => std::thread::sleep(MAX_WAIT),
                }
                continue;
            }
            let hung = self.hang_until.is_some_and(|t| now < t);
            let wait = self
                .next_sample
                .min(self.next_heartbeat)
                .saturating_duration_since(now)
                .min(MAX_WAIT);
            let n = match self.read(&mut buf, wait) {
                Ok(n) => n,
                Err(e) => {
                    debug!(error = %e, "emulated rig read failed");
                    std::thread::sleep(wait);
                    0
                }
            };
            let now = Instant::now();
            if !hung && n > 0 {
                let mut frames = Vec::new();
                self.decoder.push_slice(&buf[..n], |r| frames.push(r));
                for frame in frames.into_iter().flatten() {
                    self.on_host_frame(frame.message, now);
                }
            }
            if !hung {
                if let Some(t) = self.session_last_host_frame {
                    if now - t > host_timeout {
                        debug!("emulated rig: host silent; waiting for a new hello");
                        self.session_last_host_frame = None;
                        self.stats(|s| s.session_active = false);
                    }
                }
            }
            let streaming = !hung && self.session_last_host_frame.is_some();
            if now >= self.next_sample {
                self.next_sample = advance(self.next_sample, sample_period, now);
                if streaming {
                    self.send_sample(now);
                }
            }
            if now >= self.next_heartbeat {
                self.next_heartbeat = advance(self.next_heartbeat, heartbeat_period, now);
                if streaming {
                    let uptime_ms = (now - self.started).as_millis() as u32; // wraps by design
                    self.send(
                        &Message::Heartbeat(Heartbeat { uptime_ms }),
                        PROTOCOL_VERSION,
                    );
                }
            }
        }
        self.unplug();
    }

    fn read(&mut self, buf: &mut [u8], wait: Duration) -> std::io::Result<usize> {
        let Some(p) = self.port.as_mut() else {
            return Ok(0);
        };
        p.master.set_timeout(wait).map_err(std::io::Error::other)?;
        match p.master.read(buf) {
            Ok(n) => Ok(n),
            Err(e) if e.kind() == ErrorKind::TimedOut => Ok(0),
            Err(e) => Err(e),
        }
    }

    fn on_host_frame(&mut self, message: Message, now: Instant) {
        match message {
            Message::HostHello(h) => {
                let cal_id = self.options.calibration.calibration_id;
                let rate = self.options.sample_rate_hz.round() as u16;
                if self.pending_wrong_version > 0 {
                    self.pending_wrong_version -= 1;
                    let hello = DeviceHello::new(
                        WRONG_VERSION,
                        self.options.firmware_version,
                        &self.options.serial_number,
                        capabilities::ALL,
                        cal_id,
                        rate,
                        h.nonce,
                    );
                    self.send(&Message::DeviceHello(hello), WRONG_VERSION);
                    self.stats(|s| s.wrong_version_hellos += 1);
                    return;
                }
                let hello = DeviceHello::new(
                    PROTOCOL_VERSION,
                    self.options.firmware_version,
                    &self.options.serial_number,
                    capabilities::ALL,
                    cal_id,
                    rate,
                    h.nonce,
                );
                if self.send(&Message::DeviceHello(hello), PROTOCOL_VERSION) {
                    self.session_last_host_frame = Some(now);
                    self.next_sample = now;
                    self.next_heartbeat = now;
                    self.stats(|s| {
                        s.handshakes += 1;
                        s.session_active = true;
                    });
                }
            }
            Message::Heartbeat(_) if self.session_last_host_frame.is_some() => {
                self.session_last_host_frame = Some(now);
            }
            _ => {}
        }
    }

    fn send_sample(&mut self, now: Instant) {
        let device_time_us = (now - self.started).as_micros() as u64;
        let s = self.scenario.sample_at(device_time_us as f64 * 1e-6);
        let cal = &self.options.calibration;
        let (position_mm, orientation_wxyz) = cal.tracker_pose(s.tip_mm, s.view_dir);
        let sample = SensorSample {
            device_time_us,
            valve_in_raw: Calibration::raw_from_valve_opening(&cal.valve_in, s.valve_in),
            valve_out_raw: Calibration::raw_from_valve_opening(&cal.valve_out, s.valve_out),
            pump_raw: cal.raw_from_pump_pressure_pa(s.pump_mmhg * PA_PER_MMHG),
            pose_valid: s.pose_valid,
            position_mm,
            orientation_wxyz,
            buttons: s.buttons,
        };
        if self.pending_drops > 0 {
            self.pending_drops -= 1;
            self.sequence = self.sequence.wrapping_add(1);
            self.stats(|s| s.frames_dropped += 1);
            return;
        }
        let flip = self.pending_flips > 0;
        if flip {
            self.pending_flips -= 1;
        }
        if self.send_with(&Message::Sample(sample), PROTOCOL_VERSION, flip) {
            self.stats(|s| {
                s.samples_sent += 1;
                if flip {
                    s.frames_corrupted += 1;
                }
            });
        }
    }

    fn send(&mut self, message: &Message, version: u8) -> bool {
        self.send_with(message, version, false)
    }

    /// Encodes and writes one frame; returns true when it was written completely.
    fn send_with(&mut self, message: &Message, version: u8, flip_bit: bool) -> bool {
        let mut raw = [0u8; MAX_FRAME_LEN];
        let Ok(n) = write_raw_frame_with_version(version, self.sequence, message, &mut raw) else {
            return false;
        };
        self.sequence = self.sequence.wrapping_add(1);
        if flip_bit {
            let bit = self.rng.usize(..n * 8);
            raw[bit / 8] ^= 1 << (bit % 8);
        }
        let mut wire = [0u8; MAX_ENCODED_LEN];
        let Ok(m) = encode_raw_frame(&raw[..n], &mut wire) else {
            return false;
        };
        let ok = self.write_bytes(&wire[..m]);
        if ok {
            self.stats(|s| s.frames_sent += 1);
        }
        ok
    }

    fn write_bytes(&mut self, bytes: &[u8]) -> bool {
        let chunk_max = self.chunk_max_bytes;
        let mut chunks: Vec<usize> = Vec::new();
        if chunk_max > 0 {
            let mut left = bytes.len();
            while left > 0 {
                let c = self.rng.usize(1..=chunk_max).min(left);
                chunks.push(c);
                left -= c;
            }
        } else {
            chunks.push(bytes.len());
        }
        let Some(p) = self.port.as_mut() else {
            return false;
        };
        if p.master.set_timeout(WRITE_TIMEOUT).is_err() {
            return false;
        }
        let mut pos = 0;
        for (i, c) in chunks.iter().enumerate() {
            if let Err(e) = p.master.write_all(&bytes[pos..pos + c]) {
                debug!(error = %e, "emulated rig write failed (host not reading?)");
                return false;
            }
            pos += c;
            if i + 1 < chunks.len() {
                // Let the host's read return the partial frame before the rest arrives.
                std::thread::sleep(Duration::from_micros(100));
            }
        }
        true
    }
}

/// Next tick time; after a stall, restarts from `now` instead of sending a burst.
fn advance(tick: Instant, period: Duration, now: Instant) -> Instant {
    let next = tick + period;
    if next + period < now {
        now + period
    } else {
        next
    }
}

pub(super) fn replace_symlink(link: &std::path::Path, target: &str) -> Result<(), EmulatorError> {
    let err = |message: String| EmulatorError::Link {
        path: link.display().to_string(),
        message,
    };
    if let Ok(meta) = std::fs::symlink_metadata(link) {
        if !meta.file_type().is_symlink() {
            return Err(err(
                "exists and is not a symlink; refusing to replace it".into()
            ));
        }
    }
    let mut tmp = link.as_os_str().to_owned();
    tmp.push(format!(".tmp-{}", std::process::id()));
    let tmp = PathBuf::from(tmp);
    let _ = std::fs::remove_file(&tmp);
    std::os::unix::fs::symlink(target, &tmp).map_err(|e| err(e.to_string()))?;
    std::fs::rename(&tmp, link).map_err(|e| err(e.to_string()))
}
