//! The rig input of the daemon: the transport (`RigLink`) on a real device, or on the pty of an
//! in-process emulated rig so the whole path (bytes, framing, calibration) runs.

use std::sync::Arc;

use anyhow::Context;
use hydrometra_drivers::calibration::Calibration;
use hydrometra_drivers::emulator::{EmulatedRig, EmulatorOptions, Scenario};
use hydrometra_drivers::transport::{DeviceTarget, LinkConfig, RigLink, RxTap};

use super::config::{RigConfig, RigMode};

/// The running rig input.
pub struct RigConnection {
    link: Arc<RigLink>,
    emulator: Option<EmulatedRig>,
}

impl RigConnection {
    /// Starts the emulator (if configured, playing `scenario`, which `rig.emulated.scenario`
    /// names) and the transport. A missing device is not an error: the transport keeps retrying
    /// and status reports the link as disconnected, and why. `rx_tap`, if given, receives every
    /// read of the transport (the recorder's).
    pub fn start(
        config: &RigConfig,
        scenario: Option<Scenario>,
        rx_tap: Option<RxTap>,
    ) -> anyhow::Result<Self> {
        let calibration = match &config.calibration {
            Some(path) => Calibration::load(path)
                .with_context(|| format!("rig.calibration = {}", path.display()))?,
            None => Calibration::default(),
        };
        let (target, emulator) = match config.mode {
            RigMode::Device => (DeviceTarget::Path(config.device.clone()), None),
            RigMode::Usb => {
                let usb = config
                    .usb
                    .as_ref()
                    .context("rig.mode = \"usb\" needs a [rig.usb] table with vid and pid")?;
                (
                    DeviceTarget::Usb {
                        vid: usb.vid,
                        pid: usb.pid,
                        serial_number: usb.serial_number.clone(),
                    },
                    None,
                )
            }
            RigMode::Emulated => {
                let scenario = match scenario {
                    Some(s) => s,
                    None => Scenario::resolve(&config.emulated.scenario).with_context(|| {
                        format!("rig.emulated.scenario = {:?}", config.emulated.scenario)
                    })?,
                };
                let options = EmulatorOptions {
                    sample_rate_hz: config.emulated.sample_rate_hz,
                    // The scenario's own `[faults]` are played by the emulator from the scenario;
                    // passing them here as well would inject every fault twice.
                    // The emulated rig converts the scenario's SI values to raw counts with the
                    // same calibration the transport uses to convert them back.
                    calibration: calibration.clone(),
                    ..EmulatorOptions::default()
                };
                let rig = EmulatedRig::start(scenario, options)
                    .context("cannot start the emulated rig")?;
                tracing::info!(pty = %rig.device_path().display(), scenario = %config.emulated.scenario, "emulated rig started");
                (
                    DeviceTarget::Path(rig.device_path().to_path_buf()),
                    Some(rig),
                )
            }
            RigMode::Replay => {
                let file = config
                    .replay
                    .file
                    .as_ref()
                    .context("rig.mode = \"replay\" needs rig.replay.file")?;
                let recording = hydrometra_record::reader::Recording::load(file)
                    .with_context(|| format!("rig.replay.file = {}", file.display()))?;
                let script = recording.replay_script();
                let rig = EmulatedRig::start_replay(script, config.replay.speed, None)
                    .with_context(|| format!("cannot replay {}", file.display()))?;
                tracing::info!(pty = %rig.device_path().display(), file = %file.display(),
                    speed = config.replay.speed, "replaying a recorded rig");
                (
                    DeviceTarget::Path(rig.device_path().to_path_buf()),
                    Some(rig),
                )
            }
        };
        let mut link_config = LinkConfig::new(target, calibration);
        link_config.rx_tap = rx_tap;
        let link = RigLink::spawn(link_config).context("cannot start the rig transport")?;
        Ok(Self {
            link: Arc::new(link),
            emulator,
        })
    }

    /// The source the simulation loop polls.
    pub fn source(&self) -> Arc<RigLink> {
        self.link.clone()
    }

    /// Stops the transport (after every other holder of [`RigConnection::source`] dropped it) and the
    /// emulator.
    pub fn shutdown(self) {
        match Arc::try_unwrap(self.link) {
            Ok(link) => link.shutdown(),
            Err(_) => tracing::warn!("rig link still shared at shutdown; its thread ends on drop"),
        }
        if let Some(emulator) = self.emulator {
            emulator.stop();
        }
    }
}
