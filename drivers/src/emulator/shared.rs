//! What the emulator's parts share: its options, its errors, its counters and the state its
//! device thread shares with the handle.

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::Mutex;

use super::faults::FaultPlan;
use crate::calibration::Calibration;

/// Emulator settings. `Default`: 250 Hz samples, 10 Hz heartbeats, default calibration, no faults.
#[derive(Debug, Clone)]
pub struct EmulatorOptions {
    /// Sample rate, Hz (1..=1000).
    pub sample_rate_hz: f64,
    /// Device heartbeat rate, Hz (0.5..=100).
    pub heartbeat_hz: f64,
    /// Where to put a symlink to the pseudo-terminal; a private temporary path if `None`.
    pub link_path: Option<PathBuf>,
    /// Faults to inject (merged with the scenario's own `[faults]`).
    pub faults: FaultPlan,
    /// Calibration used backwards: scenario values are turned into the raw counts and tracker
    /// pose that this calibration maps back to them.
    pub calibration: Calibration,
    /// Serial number reported in the device hello.
    pub serial_number: String,
    /// Firmware version reported in the device hello.
    pub firmware_version: (u8, u8, u16),
    /// Host silence after which the device stops streaming and waits for a new hello, s.
    pub host_timeout_s: f64,
    /// Seed of the fault-injection random numbers.
    pub seed: u64,
}

impl Default for EmulatorOptions {
    fn default() -> Self {
        Self {
            sample_rate_hz: 250.0,
            heartbeat_hz: 10.0,
            link_path: None,
            faults: FaultPlan::default(),
            calibration: Calibration::default(),
            serial_number: "EMU-0001".into(),
            firmware_version: (1, 0, 0),
            host_timeout_s: 1.0,
            seed: 0x5EED,
        }
    }
}

/// The emulator could not start.
#[derive(Debug, thiserror::Error)]
pub enum EmulatorError {
    /// No pseudo-terminal could be created.
    #[error("cannot create a pseudo-terminal: {0}")]
    Pty(#[from] serialport::Error),
    /// The symlink could not be created.
    #[error("cannot create link {path}: {message}")]
    Link {
        /// The link path.
        path: String,
        /// What went wrong.
        message: String,
    },
    /// An option is out of range.
    #[error("invalid emulator option {field} = {value}: expected {expected}")]
    InvalidOption {
        /// Option name.
        field: &'static str,
        /// The value.
        value: String,
        /// What is allowed.
        expected: &'static str,
    },
    /// The emulator thread could not be spawned.
    #[error("cannot spawn the emulator thread: {0}")]
    Spawn(std::io::Error),
    /// The recording cannot be replayed.
    #[error("cannot replay: {0}")]
    Replay(#[from] ReplayError),
}

/// What the emulator has done so far (lets tests compare the host's counters exactly).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct EmulatorStats {
    /// Frames written completely (all types).
    pub frames_sent: u64,
    /// Sample frames written.
    pub samples_sent: u64,
    /// Sample frames dropped on purpose.
    pub frames_dropped: u64,
    /// Frames sent with one bit flipped.
    pub frames_corrupted: u64,
    /// Garbage bytes written.
    pub garbage_bytes: u64,
    /// Host hellos answered with a valid v1 device hello.
    pub handshakes: u64,
    /// Host hellos answered with a wrong protocol version.
    pub wrong_version_hellos: u64,
    /// Unplug events.
    pub unplugs: u64,
    /// Replug events.
    pub replugs: u64,
    /// Heartbeat-stop (hang) events.
    pub hangs: u64,
    /// Fault reports sent.
    pub fault_reports: u64,
    /// Whether a host session is active (host hello seen, host not timed out).
    pub session_active: bool,
    /// Whether the device is plugged in.
    pub plugged: bool,
    /// A replay has written its last recorded byte (always false for a scenario).
    pub replay_done: bool,
}

/// What the emulator's thread and its handle share.
pub(crate) struct EmuShared {
    /// Set by the handle: the thread ends.
    pub(super) stop: AtomicBool,
    /// Written by the thread, read by the handle.
    pub(super) stats: Mutex<EmulatorStats>,
}

/// The recording cannot be replayed.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    /// No device hello anywhere: nothing to answer a host hello with.
    #[error("the recording holds no device hello (the rig never completed a handshake in it)")]
    NoHello,
    /// The speed is not a positive finite factor.
    #[error("invalid replay speed {0}: expected a factor > 0 (1 = real time)")]
    Speed(f64),
}
