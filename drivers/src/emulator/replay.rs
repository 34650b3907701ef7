//! Replay of a recorded rig byte stream as a live device on a pseudo-terminal.
//!
//! A recording holds every chunk of bytes the host read from the rig, with the host time of the
//! read ([`crate::transport::RxChunk`]). [`ReplayScript::from_chunks`] cuts that stream at the
//! frame delimiters (0x00) into runs, each timed by the read that completed it. The replay device
//! then behaves like the firmware: it waits for a host hello, answers with the recorded device
//! hello (carrying the new host's nonce, everything else as recorded), and from then on writes
//! every later run, byte for byte as recorded (samples, heartbeats, fault reports, and garbage or
//! corrupted frames alike), at its recorded time relative to the recorded hello, divided by the
//! speed. So the host's decoder, calibration and link supervision see the recorded bytes again.
//!
//! Differences from the recorded session, by construction: the device hello is re-encoded (new
//! nonce, so a new CRC); a run is written whole at the time its last byte was read, so the
//! original split of frames across reads is not reproduced; later device hellos in the recording
//! (the rig reconnected) are not replayed: the recorded silence before them is, and the device
//! answers any host hello at any time with the first recorded hello.

use std::io::{ErrorKind, Read, Write};
use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};

use serialport::SerialPort;
use tracing::{debug, info};

use super::device::{Plugged, MAX_WAIT, WRITE_TIMEOUT};
pub use super::shared::ReplayError;
use super::shared::{EmuShared, EmulatorError, EmulatorStats};
use crate::framing::FrameDecoder;
use crate::wire::{
    encode_frame, parse_raw_frame, DeviceHello, Message, MAX_ENCODED_LEN, MAX_FRAME_LEN,
};

/// One step of a replay.
#[derive(Debug, Clone, PartialEq)]
pub enum ReplayItem {
    /// A device hello the rig sent (answered, with a new nonce, to every host hello).
    Hello {
        /// Host time of the read that completed it, ns.
        host_ns: u64,
        /// The frame's sequence number.
        sequence: u32,
        /// The hello as recorded.
        hello: DeviceHello,
    },
    /// Bytes written as recorded: a run up to and including a delimiter, or the unterminated tail.
    Bytes {
        /// Host time of the read that completed the run, ns.
        host_ns: u64,
        /// The bytes.
        bytes: Vec<u8>,
    },
}

impl ReplayItem {
    /// Host time of the item, ns.
    pub fn host_ns(&self) -> u64 {
        match self {
            ReplayItem::Hello { host_ns, .. } | ReplayItem::Bytes { host_ns, .. } => *host_ns,
        }
    }
}

/// A recorded byte stream cut into replay steps.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ReplayScript {
    /// Steps in recorded order.
    pub items: Vec<ReplayItem>,
}

impl ReplayScript {
    /// Cuts received chunks `(host time ns, bytes)` into runs at the 0x00 delimiters. Runs of
    /// delimiters alone are kept with the next run, so no byte is lost or reordered.
    pub fn from_chunks<'a>(chunks: impl IntoIterator<Item = (u64, &'a [u8])>) -> Self {
        let mut items = Vec::new();
        let mut run: Vec<u8> = Vec::new();
        let mut last_ns = 0;
        for (host_ns, bytes) in chunks {
            last_ns = host_ns;
            for &b in bytes {
                run.push(b);
                if b != 0 || run.iter().all(|&x| x == 0) {
                    continue;
                }
                items.push(classify(host_ns, std::mem::take(&mut run)));
            }
        }
        if !run.is_empty() {
            items.push(ReplayItem::Bytes {
                host_ns: last_ns,
                bytes: run,
            });
        }
        Self { items }
    }

    /// The first recorded device hello and its index.
    pub fn first_hello(&self) -> Option<(usize, u64, u32, DeviceHello)> {
        self.items.iter().enumerate().find_map(|(i, it)| match it {
            ReplayItem::Hello {
                host_ns,
                sequence,
                hello,
            } => Some((i, *host_ns, *sequence, *hello)),
            ReplayItem::Bytes { .. } => None,
        })
    }

    /// Recorded time from the first hello to the last item, s (the replay's length at 1x).
    pub fn duration_s(&self) -> f64 {
        match (self.first_hello(), self.items.last()) {
            (Some((_, t0, _, _)), Some(last)) => last.host_ns().saturating_sub(t0) as f64 * 1e-9,
            _ => 0.0,
        }
    }
}

/// A complete run (delimiters included): a device hello, or bytes to write as they are.
fn classify(host_ns: u64, run: Vec<u8>) -> ReplayItem {
    let body: Vec<u8> = run[..run.len() - 1]
        .iter()
        .copied()
        .skip_while(|&b| b == 0)
        .collect();
    if body.len() <= MAX_ENCODED_LEN {
        let mut raw = [0u8; MAX_FRAME_LEN];
        if let Ok(n) = cobs::decode(&body, &mut raw) {
            if let Ok(frame) = parse_raw_frame(&raw[..n]) {
                if let Message::DeviceHello(hello) = frame.message {
                    return ReplayItem::Hello {
                        host_ns,
                        sequence: frame.sequence,
                        hello,
                    };
                }
            }
        }
    }
    ReplayItem::Bytes {
        host_ns,
        bytes: run,
    }
}

pub(super) struct ReplayDevice {
    script: ReplayScript,
    speed: f64,
    link_path: PathBuf,
    shared: Arc<EmuShared>,
    port: Option<Plugged>,
    decoder: FrameDecoder,
    started: Instant,
}

impl ReplayDevice {
    pub(super) fn new(
        script: ReplayScript,
        speed: f64,
        link_path: PathBuf,
        shared: Arc<EmuShared>,
    ) -> Result<Self, ReplayError> {
        if !(speed.is_finite() && speed > 0.0) {
            return Err(ReplayError::Speed(speed));
        }
        if script.first_hello().is_none() {
            return Err(ReplayError::NoHello);
        }
        Ok(Self {
            script,
            speed,
            link_path,
            shared,
            port: None,
            decoder: FrameDecoder::new(),
            started: Instant::now(),
        })
    }

    pub(super) fn origin(&self) -> Instant {
        self.started
    }

    pub(super) fn plug(&mut self) -> Result<(), EmulatorError> {
        self.port = Some(Plugged::open(&self.link_path)?);
        self.stats(|s| s.plugged = true);
        Ok(())
    }

    fn stats(&self, f: impl FnOnce(&mut EmulatorStats)) {
        let mut s = self.shared.stats.lock().unwrap_or_else(|e| e.into_inner());
        f(&mut s);
    }

    pub(super) fn run(mut self) {
        let Some((hello_index, hello_ns, hello_seq, hello)) = self.script.first_hello() else {
            return;
        };
        // (replay start, next item) once the first host hello has been answered.
        let mut playing: Option<(Instant, usize)> = None;
        let mut buf = [0u8; 256];
        let mut host_frames = Vec::with_capacity(8);
        while !self.shared.stop.load(Ordering::SeqCst) {
            let wait = match playing {
                Some((t0, next)) => match self.script.items.get(next) {
                    Some(item) => (t0 + self.offset(item.host_ns(), hello_ns))
                        .saturating_duration_since(Instant::now())
                        .min(MAX_WAIT),
                    None => MAX_WAIT,
                },
                None => MAX_WAIT,
            };
            let n = self.read(&mut buf, wait.max(Duration::from_micros(100)));
            host_frames.clear();
            self.decoder.push_slice(&buf[..n], |r| host_frames.push(r));
            for frame in host_frames.drain(..).flatten() {
                if let Message::HostHello(h) = frame.message {
                    let mut answer = hello;
                    answer.nonce = h.nonce;
                    if self.write_message(hello_seq, &Message::DeviceHello(answer)) {
                        self.stats(|s| {
                            s.handshakes += 1;
                            s.session_active = true;
                            s.frames_sent += 1;
                        });
                        if playing.is_none() {
                            info!("replay: host connected; playing the recording");
                            playing = Some((Instant::now(), hello_index + 1));
                        }
                    }
                }
            }
            let Some((t0, mut next)) = playing else {
                continue;
            };
            let now = Instant::now();
            while let Some(item) = self.script.items.get(next) {
                if t0 + self.offset(item.host_ns(), hello_ns) > now {
                    break;
                }
                if let ReplayItem::Bytes { bytes, .. } = item {
                    let bytes = bytes.clone();
                    if self.write_bytes(&bytes) {
                        self.stats(|s| s.frames_sent += 1);
                    }
                }
                next += 1;
            }
            if next >= self.script.items.len() {
                self.stats(|s| s.replay_done = true);
            }
            playing = Some((t0, next));
        }
        if let Err(e) = std::fs::remove_file(&self.link_path) {
            if e.kind() != ErrorKind::NotFound {
                debug!(error = %e, "cannot remove the replay link");
            }
        }
        self.stats(|s| {
            s.plugged = false;
            s.session_active = false;
        });
    }

    /// Replay time of a recorded time, relative to the recorded hello.
    fn offset(&self, host_ns: u64, hello_ns: u64) -> Duration {
        Duration::from_secs_f64(host_ns.saturating_sub(hello_ns) as f64 * 1e-9 / self.speed)
    }

    fn read(&mut self, buf: &mut [u8], wait: Duration) -> usize {
        let Some(p) = self.port.as_mut() else {
            std::thread::sleep(wait);
            return 0;
        };
        if p.master.set_timeout(wait).is_err() {
            std::thread::sleep(wait);
            return 0;
        }
        match p.master.read(buf) {
            Ok(n) => n,
            Err(e) if e.kind() == ErrorKind::TimedOut => 0,
            Err(e) => {
                debug!(error = %e, "replay: read failed");
                std::thread::sleep(wait);
                0
            }
        }
    }

    fn write_message(&mut self, sequence: u32, message: &Message) -> bool {
        let mut wire = [0u8; MAX_ENCODED_LEN];
        match encode_frame(sequence, message, &mut wire) {
            Ok(n) => self.write_bytes(&wire[..n]),
            Err(_) => false,
        }
    }

    fn write_bytes(&mut self, bytes: &[u8]) -> bool {
        let Some(p) = self.port.as_mut() else {
            return false;
        };
        if p.master.set_timeout(WRITE_TIMEOUT).is_err() {
            return false;
        }
        match p.master.write_all(bytes) {
            Ok(()) => true,
            Err(e) => {
                debug!(error = %e, "replay: write failed (host not reading?)");
                false
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::wire::{encode_frame, Heartbeat, SensorSample};

    fn frame(seq: u32, m: &Message) -> Vec<u8> {
        let mut w = [0u8; MAX_ENCODED_LEN];
        let n = encode_frame(seq, m, &mut w).unwrap_or(0);
        w[..n].to_vec()
    }

    #[test]
    fn script_keeps_every_byte_and_finds_the_hello() {
        let hello = DeviceHello::new(1, (1, 2, 3), "SN-7", 0x1f, 42, 250, 99);
        let sample = Message::Sample(SensorSample {
            device_time_us: 5,
            valve_in_raw: 1,
            valve_out_raw: 2,
            pump_raw: 3,
            pose_valid: true,
            position_mm: [1.0, 2.0, 3.0],
            orientation_wxyz: [1.0, 0.0, 0.0, 0.0],
            buttons: 0,
        });
        let mut stream = vec![0x55, 0x66]; // leftovers before the hello: garbage
        stream.extend(frame(7, &Message::DeviceHello(hello)));
        stream.extend(frame(8, &sample));
        stream.extend([0x13, 0x37, 0x00]); // a garbage run
        stream.extend(frame(9, &Message::Heartbeat(Heartbeat { uptime_ms: 3 })));
        stream.extend([0x01, 0x02]); // unterminated tail
                                     // Split into reads of 5 bytes at 1 ms each.
        let chunks: Vec<(u64, &[u8])> = stream
            .chunks(5)
            .enumerate()
            .map(|(i, c)| (i as u64 * 1_000_000, c))
            .collect();
        let script = ReplayScript::from_chunks(chunks);
        let (i, _, seq, h) = script.first_hello().expect("hello found");
        assert_eq!((seq, h), (7, hello));
        // Everything but the hello is written back byte for byte, in order.
        let mut replayed = Vec::new();
        for (j, item) in script.items.iter().enumerate() {
            match item {
                ReplayItem::Bytes { bytes, .. } => replayed.extend(bytes),
                ReplayItem::Hello { .. } => {
                    assert_eq!(j, i);
                    replayed.extend(frame(7, &Message::DeviceHello(hello)));
                }
            }
        }
        // Delimiters are padding: only runs of them may differ (the re-encoded hello brings its
        // own leading delimiter).
        let collapse = |v: &[u8]| {
            let mut out: Vec<u8> = Vec::new();
            for &b in v {
                if !(b == 0 && out.last() == Some(&0)) {
                    out.push(b);
                }
            }
            out
        };
        assert_eq!(collapse(&replayed), collapse(&stream));
        // Times never go backwards and each run is timed by the read that completed it.
        let times: Vec<u64> = script.items.iter().map(|x| x.host_ns()).collect();
        assert!(times.windows(2).all(|w| w[0] <= w[1]));
    }
}
