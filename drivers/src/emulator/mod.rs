//! The emulated rig: behaves like the firmware on a pseudo-terminal, playing a [`Scenario`] and
//! injecting [`Fault`]s, so the whole stack runs without hardware.
//!
//! ```no_run
//! use hydrometra_drivers::emulator::{EmulatedRig, EmulatorOptions, Scenario};
//! use hydrometra_drivers::transport::{DeviceTarget, LinkConfig, RigLink};
//! use hydrometra_drivers::calibration::Calibration;
//! let scenario = Scenario::builtin("default").ok_or("no built-in scenario \"default\"")?;
//! let rig = EmulatedRig::start(scenario, EmulatorOptions::default())?;
//! let link = RigLink::spawn(LinkConfig::new(
//!     DeviceTarget::Path(rig.device_path().to_path_buf()),
//!     Calibration::default(),
//! ))?;
//! let state = link.wait_for_sample(None, std::time::Duration::from_secs(2));
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

mod device;
pub mod faults;
pub mod replay;
pub mod scenario;
mod scenario_error;
mod shared;

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Instant;

use tracing::warn;

pub use faults::{Fault, FaultEvent, FaultPlan};
pub use replay::{ReplayItem, ReplayScript};
pub use scenario::{Keyframe, Scenario, ScenarioError, ScenarioSample};
use shared::EmuShared;
pub use shared::{EmulatorError, EmulatorOptions, EmulatorStats, ReplayError};

/// A running emulated rig.
pub struct EmulatedRig {
    device_path: PathBuf,
    origin: Instant,
    owns_link_dir: Option<PathBuf>,
    shared: Arc<EmuShared>,
    faults: mpsc::Sender<Fault>,
    thread: Option<JoinHandle<()>>,
}

impl EmulatedRig {
    /// Creates the pseudo-terminal and its symlink and starts the firmware thread.
    pub fn start(
        scenario: Scenario,
        options: EmulatorOptions,
    ) -> Result<EmulatedRig, EmulatorError> {
        if !(options.sample_rate_hz.is_finite() && (1.0..=1000.0).contains(&options.sample_rate_hz))
        {
            return Err(EmulatorError::InvalidOption {
                field: "sample_rate_hz",
                value: options.sample_rate_hz.to_string(),
                expected: "a rate in [1, 1000] Hz (docs/rig-protocol.md)",
            });
        }
        if !(options.heartbeat_hz.is_finite() && (0.5..=100.0).contains(&options.heartbeat_hz)) {
            return Err(EmulatorError::InvalidOption {
                field: "heartbeat_hz",
                value: options.heartbeat_hz.to_string(),
                expected: "a rate in [0.5, 100] Hz",
            });
        }
        if !(options.host_timeout_s.is_finite() && options.host_timeout_s > 0.0) {
            return Err(EmulatorError::InvalidOption {
                field: "host_timeout_s",
                value: options.host_timeout_s.to_string(),
                expected: "a time > 0 s",
            });
        }
        let (device_path, owns_link_dir, shared) = new_device_parts(options.link_path.clone())?;
        let (tx, rx) = mpsc::channel();
        let mut device = device::Device::new(
            scenario,
            options,
            device_path.clone(),
            Arc::clone(&shared),
            rx,
        );
        let origin = device.origin();
        // Plug in before returning, so the path exists as soon as `start` returns.
        device.plug()?;
        let thread = std::thread::Builder::new()
            .name("rig-emulator".into())
            .spawn(move || device.run())
            .map_err(EmulatorError::Spawn)?;
        Ok(EmulatedRig {
            device_path,
            origin,
            owns_link_dir,
            shared,
            faults: tx,
            thread: Some(thread),
        })
    }

    /// Plays a recorded byte stream as a live device (see [`replay`]) on a pseudo-terminal at
    /// `link_path` (a private temporary path if `None`), `speed` times real time.
    pub fn start_replay(
        script: ReplayScript,
        speed: f64,
        link_path: Option<PathBuf>,
    ) -> Result<EmulatedRig, EmulatorError> {
        let (device_path, owns_link_dir, shared) = new_device_parts(link_path)?;
        let (tx, _rx) = mpsc::channel();
        let mut device =
            replay::ReplayDevice::new(script, speed, device_path.clone(), Arc::clone(&shared))?;
        let origin = device.origin();
        device.plug()?;
        let thread = std::thread::Builder::new()
            .name("rig-replay".into())
            .spawn(move || device.run())
            .map_err(EmulatorError::Spawn)?;
        Ok(EmulatedRig {
            device_path,
            origin,
            owns_link_dir,
            shared,
            faults: tx,
            thread: Some(thread),
        })
    }

    /// The path the host opens: a symlink to the current pseudo-terminal (re-pointed on replug).
    pub fn device_path(&self) -> &Path {
        &self.device_path
    }

    /// The host instant at which the emulated device time was 0: a sample's `device_time_us`
    /// after this instant is when the emulator took it (for latency measurements).
    pub fn device_time_origin(&self) -> Instant {
        self.origin
    }

    /// Injects a fault now.
    pub fn inject(&self, fault: Fault) {
        // The receiver lives as long as the thread; after a stop there is nothing to inject into.
        let _ = self.faults.send(fault);
    }

    /// What the emulator has done so far.
    pub fn stats(&self) -> EmulatorStats {
        *self.shared.stats.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Stops the firmware thread, closes the pseudo-terminal and removes the symlink.
    pub fn stop(mut self) {
        self.stop_inner();
    }

    fn stop_inner(&mut self) {
        self.shared.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            if t.join().is_err() {
                warn!("emulator thread panicked");
            }
        }
        if let Some(dir) = self.owns_link_dir.take() {
            let _ = std::fs::remove_dir_all(dir);
        }
    }
}

impl Drop for EmulatedRig {
    fn drop(&mut self) {
        self.stop_inner();
    }
}

/// The device path (and the private directory holding it, if we made one) and the shared state
/// of a new emulated device.
type DeviceParts = (PathBuf, Option<PathBuf>, Arc<EmuShared>);

fn new_device_parts(link_path: Option<PathBuf>) -> Result<DeviceParts, EmulatorError> {
    let (device_path, owns_link_dir) = match link_path {
        Some(p) => (p, None),
        None => {
            let dir = private_link_dir()?;
            (dir.join("rig"), Some(dir))
        }
    };
    let shared = Arc::new(EmuShared {
        stop: AtomicBool::new(false),
        stats: Mutex::new(EmulatorStats::default()),
    });
    Ok((device_path, owns_link_dir, shared))
}

fn private_link_dir() -> Result<PathBuf, EmulatorError> {
    use std::sync::atomic::AtomicU64;
    static NEXT: AtomicU64 = AtomicU64::new(0);
    let n = NEXT.fetch_add(1, Ordering::Relaxed);
    let dir = std::env::temp_dir().join(format!("hydrometra-rig-{}-{n}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(|e| EmulatorError::Link {
        path: dir.display().to_string(),
        message: e.to_string(),
    })?;
    Ok(dir)
}
