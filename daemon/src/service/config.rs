//! hydrmetrad's configuration: a TOML file, then command-line overrides, then validation.
//!
//! Every error names the file (or flag), the key, the value and what was expected.

use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The commented default configuration printed by `hydrometrad --print-default-config`.
pub const DEFAULT_CONFIG_TOML: &str = include_str!("default-config.toml");

/// A configuration error: where, which key, which value, what was expected.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("config {path}: cannot read: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The TOML is malformed or has an unknown key or a value of the wrong type. The message from
    /// the TOML parser names the line, column and key.
    #[error("config {origin}: {message}")]
    Parse {
        /// File path or other origin.
        origin: String,
        /// Parser message (line, column, key, expected type).
        message: String,
    },
    /// A value is well-typed but out of range or inconsistent.
    #[error("config {origin}: key `{key}` = {value}: expected {expected}")]
    Invalid {
        /// File path, `--flag` or `defaults`.
        origin: String,
        /// Dotted key, e.g. `loop.tick_rate_hz`.
        key: String,
        /// The offending value as written.
        value: String,
        /// What would have been accepted.
        expected: String,
    },
}

/// Where the rig's samples come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RigMode {
    /// A serial device path (`rig.device`).
    Device,
    /// A USB device found by VID/PID/serial number (`[rig.usb]`).
    Usb,
    /// An in-process emulated rig on a pseudo-terminal (`[rig.emulated]`).
    Emulated,
    /// An in-process rig on a pseudo-terminal playing a recording (`[rig.replay]`).
    Replay,
}

/// `[rig.replay]`: play a recording's rig bytes as a live device (docs/recording.md).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ReplayConfig {
    /// The recording (MCAP).
    pub file: Option<PathBuf>,
    /// Playback speed, times real time (1 reproduces the recorded procedure).
    pub speed: f64,
}

impl Default for ReplayConfig {
    fn default() -> Self {
        Self {
            file: None,
            speed: 1.0,
        }
    }
}

/// `[record]`: one MCAP recording per procedure (docs/recording.md).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RecordConfig {
    /// Record procedures.
    pub enabled: bool,
    /// Directory of the recordings; default `<paths.state_dir>/recordings`, else
    /// `$STATE_DIRECTORY/recordings` (systemd); without any, nothing is recorded.
    pub dir: Option<PathBuf>,
    /// Statuses recorded per second (divides `loop.status_rate_hz`).
    pub status_rate_hz: f64,
    /// The open chunk is written to the file this often, ms: what a kill -9 may lose.
    pub flush_interval_ms: u64,
}

impl Default for RecordConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            dir: None,
            status_rate_hz: 100.0,
            flush_interval_ms: 500,
        }
    }
}

impl RecordConfig {
    /// The recordings directory, if recording is on and a directory is known.
    pub fn resolved_dir(&self, paths: &PathsConfig) -> Option<PathBuf> {
        if !self.enabled {
            return None;
        }
        self.dir
            .clone()
            .or_else(|| paths.state_dir.as_ref().map(|d| d.join("recordings")))
            .or_else(|| {
                std::env::var_os("STATE_DIRECTORY")
                    .filter(|v| !v.is_empty())
                    // systemd may pass several directories separated by ':'; take the first.
                    .and_then(|v| {
                        v.to_str()
                            .map(|s| s.split(':').next().unwrap_or(s).to_owned())
                    })
                    .map(|d| PathBuf::from(d).join("recordings"))
            })
    }

    /// Published statuses per recorded one.
    pub fn status_every(&self, loop_config: &LoopConfig) -> u64 {
        (loop_config.status_rate_hz / self.status_rate_hz)
            .round()
            .max(1.0) as u64
    }
}

/// `[rig.usb]`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct UsbConfig {
    /// USB vendor id.
    pub vid: u16,
    /// USB product id.
    pub pid: u16,
    /// USB serial number; any when unset.
    pub serial_number: Option<String>,
}

/// `[rig.emulated]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EmulatedConfig {
    /// Built-in scenario name or scenario file path.
    pub scenario: String,
    /// Emulated sample rate, Hz.
    pub sample_rate_hz: f64,
}

impl Default for EmulatedConfig {
    fn default() -> Self {
        Self {
            scenario: "default".into(),
            sample_rate_hz: 250.0,
        }
    }
}

/// `[rig]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RigConfig {
    /// Where samples come from.
    pub mode: RigMode,
    /// Serial device path for [`RigMode::Device`].
    pub device: PathBuf,
    /// Calibration file; documented defaults when unset.
    pub calibration: Option<PathBuf>,
    /// Sample age after which the safe inputs apply, ms.
    pub safe_state_timeout_ms: u64,
    /// For [`RigMode::Usb`].
    pub usb: Option<UsbConfig>,
    /// For [`RigMode::Emulated`].
    pub emulated: EmulatedConfig,
    /// For [`RigMode::Replay`].
    pub replay: ReplayConfig,
}

impl Default for RigConfig {
    fn default() -> Self {
        Self {
            mode: RigMode::Device,
            device: PathBuf::from("/dev/hydrometra-rig"),
            calibration: None,
            safe_state_timeout_ms: 100,
            usb: None,
            emulated: EmulatedConfig::default(),
            replay: ReplayConfig::default(),
        }
    }
}

/// `[loop]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LoopConfig {
    /// Simulation tick rate, Hz.
    pub tick_rate_hz: f64,
    /// Status publication rate, Hz (divides the tick rate).
    pub status_rate_hz: f64,
    /// Periodic log interval, s.
    pub log_interval_s: f64,
    /// SCHED_FIFO priority of the simulation thread (which publishes status) and the rig I/O
    /// thread (1..=99); 0: normal scheduling. Falls back to `fallback_nice`, then normal
    /// scheduling, with a warning, when not permitted.
    pub realtime_priority: u8,
    /// Nice value the rig I/O and loop threads ask for when SCHED_FIFO is refused (-20..=0;
    /// 0 asks for nothing).
    pub fallback_nice: i32,
    /// Give the rig I/O and the loop a CPU of their own and keep every other thread of the
    /// daemon off it (with two or more CPUs).
    pub isolate_realtime_cpu: bool,
    /// That CPU (default: the last one the process may use).
    pub realtime_cpu: Option<usize>,
    /// Keep that CPU from halting while the loop sleeps (a `SCHED_IDLE` thread polls on it), so
    /// its timer wakes the loop on time on a virtual machine (docs/daemon.md).
    pub keep_realtime_cpu_awake: bool,
}

impl Default for LoopConfig {
    fn default() -> Self {
        Self {
            tick_rate_hz: 1000.0,
            status_rate_hz: 1000.0,
            log_interval_s: 10.0,
            realtime_priority: 10,
            fallback_nice: -10,
            isolate_realtime_cpu: true,
            realtime_cpu: None,
            keep_realtime_cpu_awake: true,
        }
    }
}

impl LoopConfig {
    /// Ticks between two statuses.
    pub fn ticks_per_status(&self) -> u64 {
        (self.tick_rate_hz / self.status_rate_hz).round().max(1.0) as u64
    }
}

/// `[ipc]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IpcConfig {
    /// Prefix of all service names.
    pub service_prefix: String,
}

impl Default for IpcConfig {
    fn default() -> Self {
        Self {
            service_prefix: hydrometra_ipc::DEFAULT_SERVICE_PREFIX.into(),
        }
    }
}

/// `[paths]`: inputs of later stages.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PathsConfig {
    /// Case file.
    pub case: Option<PathBuf>,
    /// Deformation atlas.
    pub atlas: Option<PathBuf>,
    /// State that survives restarts.
    pub state_dir: Option<PathBuf>,
}

/// `[hydraulics]`: the hydraulic model and the procedure record (docs/hydraulics.md).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HydraulicsConfig {
    /// The procedure record (survives restarts); default `<paths.state_dir>/procedure.rec`, and
    /// not persisted when neither is set.
    pub record: Option<PathBuf>,
    /// How often the record is written while the procedure runs, ms (also on every alarm change).
    pub save_interval_ms: u64,
    /// `[hydraulics.params]`: the model's parameters; a scenario's `[hydraulics.params]`
    /// replaces them for that case.
    pub params: hydrometra_sim::hydraulics::HydraulicParams,
    /// `--new-procedure`: start a new procedure instead of restoring the record (not a file key).
    #[serde(skip)]
    pub new_procedure: bool,
}

impl Default for HydraulicsConfig {
    fn default() -> Self {
        Self {
            record: None,
            save_interval_ms: 200,
            params: hydrometra_sim::hydraulics::HydraulicParams::default(),
            new_procedure: false,
        }
    }
}

impl HydraulicsConfig {
    /// The record path: `record`, else `<state_dir>/procedure.rec`, else none.
    pub fn record_path(&self, paths: &PathsConfig) -> Option<PathBuf> {
        hydrometra_sim::hydraulics::record_path(self.record.as_deref(), paths.state_dir.as_deref())
    }
}

/// `[scene]`: the scene the daemon runs (cavity deformation, voxelization, fluid, particles) on
/// its own thread, and where its atlas is cached.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SceneConfig {
    /// Run a scene at all (false: status and hydraulics only, no mesh, flow or particles).
    pub enabled: bool,
    /// A built-in scene name (`default`, `myoma-figo1`, `bleed`) or a scene file (docs/scene.md).
    pub scene: String,
    /// Scene frames per second (positions and particles every frame, flow every fluid step).
    pub rate_hz: f64,
    /// Where built atlases are cached under their key; default `<paths.state_dir>/atlas`, else
    /// `$XDG_CACHE_HOME/hydrometra/atlas`, else `~/.cache/hydrometra/atlas`.
    pub atlas_cache_dir: Option<PathBuf>,
}

impl Default for SceneConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            scene: "default".into(),
            rate_hz: 60.0,
            atlas_cache_dir: None,
        }
    }
}

impl SceneConfig {
    /// The atlas cache directory: `atlas_cache_dir`, else `<state_dir>/atlas`, else the user's
    /// cache directory; none when no home is known.
    pub fn cache_dir(&self, paths: &PathsConfig) -> Option<PathBuf> {
        if let Some(d) = &self.atlas_cache_dir {
            return Some(d.clone());
        }
        if let Some(d) = &paths.state_dir {
            return Some(d.join("atlas"));
        }
        let xdg = std::env::var_os("XDG_CACHE_HOME").filter(|v| !v.is_empty());
        let base = xdg
            .map(PathBuf::from)
            .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache")))?;
        Some(base.join("hydrometra").join("atlas"))
    }
}

/// The whole configuration.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    /// `[rig]`.
    pub rig: RigConfig,
    /// `[loop]`.
    #[serde(rename = "loop")]
    pub sim_loop: LoopConfig,
    /// `[ipc]`.
    pub ipc: IpcConfig,
    /// `[paths]`.
    pub paths: PathsConfig,
    /// `[hydraulics]`.
    pub hydraulics: HydraulicsConfig,
    /// `[record]`.
    pub record: RecordConfig,
    /// `[scene]`.
    pub scene: SceneConfig,
    /// `[remote]`: the services forwarded to zenoh (docs/station.md); off by default.
    pub remote: hydrometra_remote::RemoteConfig,
}

/// Command-line overrides, applied after the file.
#[derive(Debug, Clone, Default)]
pub struct Overrides {
    /// `--device PATH`: mode = device with this path.
    pub device: Option<PathBuf>,
    /// `--emulated SCENARIO`: mode = emulated with this scenario.
    pub emulated: Option<String>,
    /// `--service-prefix P`.
    pub service_prefix: Option<String>,
    /// `--tick-rate-hz`.
    pub tick_rate_hz: Option<f64>,
    /// `--status-rate-hz`.
    pub status_rate_hz: Option<f64>,
    /// `--procedure-record PATH`.
    pub procedure_record: Option<PathBuf>,
    /// `--new-procedure`.
    pub new_procedure: bool,
    /// `--replay FILE`: mode = replay of this recording.
    pub replay: Option<PathBuf>,
    /// `--replay-speed X`.
    pub replay_speed: Option<f64>,
    /// `--record-dir DIR`: record into DIR (turns recording on).
    pub record_dir: Option<PathBuf>,
    /// `--no-record`: record nothing.
    pub no_record: bool,
    /// `--scene NAME|FILE`.
    pub scene: Option<String>,
    /// `--no-scene`.
    pub no_scene: bool,
    /// `--scene-rate-hz`.
    pub scene_rate_hz: Option<f64>,
    /// `--atlas-cache-dir DIR`.
    pub atlas_cache_dir: Option<PathBuf>,
}

impl Config {
    /// Parses and validates TOML text; `origin` names it in errors.
    pub fn from_toml_str(text: &str, origin: &str) -> Result<Self, ConfigError> {
        let config: Config = toml::from_str(text).map_err(|e| ConfigError::Parse {
            origin: origin.to_string(),
            message: e.to_string().trim_end().replace('\n', "\n  "),
        })?;
        config.validate(origin)?;
        Ok(config)
    }

    /// Reads, parses and validates a file.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_toml_str(&text, &path.display().to_string())
    }

    /// Applies command-line overrides and validates the result, naming the flag on error.
    pub fn apply(&mut self, o: &Overrides) -> Result<(), ConfigError> {
        let sources = [o.device.is_some(), o.emulated.is_some(), o.replay.is_some()];
        if sources.iter().filter(|&&b| b).count() > 1 {
            return Err(invalid(
                "command line",
                "--device/--emulated/--replay",
                "more than one given",
                "at most one of --device PATH, --emulated SCENARIO and --replay FILE",
            ));
        }
        if let Some(file) = &o.replay {
            self.rig.mode = RigMode::Replay;
            self.rig.replay.file = Some(file.clone());
        }
        if let Some(speed) = o.replay_speed {
            self.rig.replay.speed = speed;
        }
        if let Some(dir) = &o.record_dir {
            self.record.enabled = true;
            self.record.dir = Some(dir.clone());
        }
        if o.no_record {
            self.record.enabled = false;
        }
        if let Some(device) = &o.device {
            self.rig.mode = RigMode::Device;
            self.rig.device = device.clone();
        }
        if let Some(scenario) = &o.emulated {
            self.rig.mode = RigMode::Emulated;
            self.rig.emulated.scenario = scenario.clone();
        }
        if let Some(prefix) = &o.service_prefix {
            self.ipc.service_prefix = prefix.clone();
        }
        if let Some(rate) = o.tick_rate_hz {
            self.sim_loop.tick_rate_hz = rate;
        }
        if let Some(rate) = o.status_rate_hz {
            self.sim_loop.status_rate_hz = rate;
        }
        if let Some(record) = &o.procedure_record {
            self.hydraulics.record = Some(record.clone());
        }
        self.hydraulics.new_procedure |= o.new_procedure;
        if let Some(scene) = &o.scene {
            self.scene.scene = scene.clone();
            self.scene.enabled = true;
        }
        if o.no_scene {
            self.scene.enabled = false;
        }
        if let Some(rate) = o.scene_rate_hz {
            self.scene.rate_hz = rate;
        }
        if let Some(dir) = &o.atlas_cache_dir {
            self.scene.atlas_cache_dir = Some(dir.clone());
        }
        self.validate("command line")
    }

    /// Checks ranges and consistency.
    pub fn validate(&self, origin: &str) -> Result<(), ConfigError> {
        self.remote
            .validate()
            .map_err(|(key, value, expected)| invalid(origin, &key, &value, &expected))?;
        let l = &self.sim_loop;
        check_range(
            origin,
            "loop.tick_rate_hz",
            l.tick_rate_hz,
            1.0,
            10_000.0,
            "Hz",
        )?;
        check_range(
            origin,
            "loop.status_rate_hz",
            l.status_rate_hz,
            1.0,
            l.tick_rate_hz,
            "Hz (at most loop.tick_rate_hz)",
        )?;
        let ratio = l.tick_rate_hz / l.status_rate_hz;
        if (ratio - ratio.round()).abs() > 1e-9 {
            return Err(invalid(
                origin,
                "loop.status_rate_hz",
                &l.status_rate_hz.to_string(),
                &format!(
                    "a rate that divides loop.tick_rate_hz = {} (status every N ticks)",
                    l.tick_rate_hz
                ),
            ));
        }
        if !(-20..=0).contains(&l.fallback_nice) {
            return Err(invalid(
                origin,
                "loop.fallback_nice",
                &l.fallback_nice.to_string(),
                "a nice value in -20..=0 (0 asks for none)",
            ));
        }
        if let Some(cpu) = l.realtime_cpu {
            if cpu >= libc::CPU_SETSIZE as usize {
                return Err(invalid(
                    origin,
                    "loop.realtime_cpu",
                    &cpu.to_string(),
                    "a CPU number below 1024",
                ));
            }
        }
        check_range(
            origin,
            "loop.log_interval_s",
            l.log_interval_s,
            0.1,
            3600.0,
            "s",
        )?;
        let timeout = self.rig.safe_state_timeout_ms;
        if !(10..=10_000).contains(&timeout) {
            return Err(invalid(
                origin,
                "rig.safe_state_timeout_ms",
                &timeout.to_string(),
                "a timeout in 10..=10000 ms",
            ));
        }
        let h = &self.hydraulics;
        if !(10..=60_000).contains(&h.save_interval_ms) {
            return Err(invalid(
                origin,
                "hydraulics.save_interval_ms",
                &h.save_interval_ms.to_string(),
                "an interval in 10..=60000 ms",
            ));
        }
        if let Err(e) = h.params.validate(origin) {
            return Err(match e {
                hydrometra_sim::hydraulics::ParamsError::Invalid {
                    key,
                    value,
                    expected,
                    ..
                } => invalid(
                    origin,
                    &format!("hydraulics.params.{key}"),
                    &value,
                    expected,
                ),
                other => invalid(
                    origin,
                    "hydraulics.params",
                    &other.to_string(),
                    "valid parameters",
                ),
            });
        }
        check_range(
            origin,
            "scene.rate_hz",
            self.scene.rate_hz,
            1.0,
            self.sim_loop.tick_rate_hz,
            "Hz (at most loop.tick_rate_hz)",
        )?;
        if self.scene.enabled && self.scene.scene.trim().is_empty() {
            return Err(invalid(
                origin,
                "scene.scene",
                "\"\"",
                "a built-in scene name such as \"default\" or a scene file path",
            ));
        }
        let e = &self.rig.emulated;
        check_range(
            origin,
            "rig.emulated.sample_rate_hz",
            e.sample_rate_hz,
            1.0,
            5_000.0,
            "Hz",
        )?;
        if e.scenario.trim().is_empty() {
            return Err(invalid(
                origin,
                "rig.emulated.scenario",
                "\"\"",
                "a built-in scenario name such as \"default\" or a scenario file path",
            ));
        }
        let r = &self.rig.replay;
        if !(r.speed.is_finite() && r.speed > 0.0 && r.speed <= 1000.0) {
            return Err(invalid(
                origin,
                "rig.replay.speed",
                &r.speed.to_string(),
                "a factor in (0, 1000] (1 = real time)",
            ));
        }
        if self.rig.mode == RigMode::Replay && r.file.is_none() {
            return Err(invalid(
                origin,
                "rig.mode",
                "\"replay\"",
                "rig.replay.file (or --replay FILE) when mode = \"replay\"",
            ));
        }
        let rec = &self.record;
        check_range(
            origin,
            "record.status_rate_hz",
            rec.status_rate_hz,
            0.1,
            l.status_rate_hz,
            "Hz (at most loop.status_rate_hz)",
        )?;
        if !(50..=1000).contains(&rec.flush_interval_ms) {
            return Err(invalid(
                origin,
                "record.flush_interval_ms",
                &rec.flush_interval_ms.to_string(),
                "an interval in 50..=1000 ms (a kill -9 loses at most this much)",
            ));
        }
        if self.rig.mode == RigMode::Usb && self.rig.usb.is_none() {
            return Err(invalid(
                origin,
                "rig.mode",
                "\"usb\"",
                "a [rig.usb] table with vid and pid when mode = \"usb\"",
            ));
        }
        if self.rig.mode == RigMode::Device && self.rig.device.as_os_str().is_empty() {
            return Err(invalid(
                origin,
                "rig.device",
                "\"\"",
                "a serial device path",
            ));
        }
        hydrometra_ipc::ServiceNames::new(&self.ipc.service_prefix).map_err(|e| {
            invalid(
                origin,
                "ipc.service_prefix",
                &format!("{:?}", self.ipc.service_prefix),
                &format!(
                    "{} ({})",
                    "a '/'-separated service name prefix such as \"hydrometra/v1\"", e.reason
                ),
            )
        })?;
        Ok(())
    }
}

fn invalid(origin: &str, key: &str, value: &str, expected: &str) -> ConfigError {
    ConfigError::Invalid {
        origin: origin.into(),
        key: key.into(),
        value: value.into(),
        expected: expected.into(),
    }
}

fn check_range(
    origin: &str,
    key: &str,
    v: f64,
    lo: f64,
    hi: f64,
    unit: &str,
) -> Result<(), ConfigError> {
    if v.is_finite() && v >= lo && v <= hi {
        Ok(())
    } else {
        Err(invalid(
            origin,
            key,
            &v.to_string(),
            &format!("a number in {lo}..={hi} {unit}"),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn printed_default_config_parses_to_the_defaults() {
        let parsed = Config::from_toml_str(DEFAULT_CONFIG_TOML, "default").unwrap();
        assert_eq!(parsed, Config::default());
        assert_eq!(Config::default().sim_loop.ticks_per_status(), 1);
    }

    #[test]
    fn unknown_key_error_names_the_key_and_line() {
        let err = Config::from_toml_str(
            "[loop]\ntick_rate_hz = 500.0\ntick_rte = 3\n",
            "/etc/h.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("/etc/h.toml"), "{err}");
        assert!(err.contains("tick_rte"), "{err}");
        assert!(err.contains("line 3"), "{err}");
    }

    #[test]
    fn wrong_type_error_names_the_key() {
        let err = Config::from_toml_str("[loop]\ntick_rate_hz = \"fast\"\n", "c.toml")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("tick_rate_hz") && err.contains("line 2"),
            "{err}"
        );
    }

    #[test]
    fn out_of_range_values_name_key_value_and_expectation() {
        let cases = [
            ("[loop]\ntick_rate_hz = 0.0\n", "loop.tick_rate_hz", "0"),
            (
                "[loop]\nstatus_rate_hz = 300.0\n",
                "loop.status_rate_hz",
                "300",
            ),
            (
                "[loop]\nstatus_rate_hz = 2000.0\n",
                "loop.status_rate_hz",
                "2000",
            ),
            (
                "[rig]\nsafe_state_timeout_ms = 1\n",
                "rig.safe_state_timeout_ms",
                "1",
            ),
            (
                "[ipc]\nservice_prefix = \"a//b\"\n",
                "ipc.service_prefix",
                "\"a//b\"",
            ),
            ("[rig]\nmode = \"usb\"\n", "rig.mode", "\"usb\""),
        ];
        for (text, key, value) in cases {
            match Config::from_toml_str(text, "c.toml") {
                Err(ConfigError::Invalid {
                    key: k,
                    value: v,
                    expected,
                    origin,
                }) => {
                    assert_eq!(
                        (k.as_str(), v.as_str(), origin.as_str()),
                        (key, value, "c.toml")
                    );
                    assert!(!expected.is_empty());
                }
                other => panic!("{text}: expected an Invalid error, got {other:?}"),
            }
        }
    }

    #[test]
    fn overrides_win_over_the_file_and_are_validated() {
        let mut c =
            Config::from_toml_str("[rig]\nmode = \"device\"\ndevice = \"/dev/ttyACM0\"\n", "c")
                .unwrap();
        c.apply(&Overrides {
            emulated: Some("default".into()),
            service_prefix: Some("test/1".into()),
            status_rate_hz: Some(250.0),
            ..Default::default()
        })
        .unwrap();
        assert_eq!(c.rig.mode, RigMode::Emulated);
        assert_eq!(c.ipc.service_prefix, "test/1");
        assert_eq!(c.sim_loop.ticks_per_status(), 4);
        let err = c
            .apply(&Overrides {
                tick_rate_hz: Some(-5.0),
                ..Default::default()
            })
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("command line") && err.contains("loop.tick_rate_hz"),
            "{err}"
        );
        let both = Overrides {
            device: Some("/dev/x".into()),
            emulated: Some("default".into()),
            ..Default::default()
        };
        assert!(c.clone().apply(&both).is_err());
    }

    #[test]
    fn usb_table_parses_hex_ids() {
        let c = Config::from_toml_str(
            "[rig]\nmode = \"usb\"\n[rig.usb]\nvid = 0x1209\npid = 0x4853\n",
            "c",
        )
        .unwrap();
        assert_eq!(
            c.rig.usb,
            Some(UsbConfig {
                vid: 0x1209,
                pid: 0x4853,
                serial_number: None
            })
        );
    }

    #[test]
    fn hydraulics_keys_are_validated_and_the_record_path_defaults_to_the_state_dir() {
        let err = Config::from_toml_str(
            "[hydraulics.params.pump]\nmax_flow_ml_per_min = -1\n",
            "c.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("c.toml") && err.contains("hydraulics.params.pump.max_flow_ml_per_min"),
            "{err}"
        );
        let err = Config::from_toml_str("[hydraulics]\nsave_interval_ms = 0\n", "c.toml")
            .unwrap_err()
            .to_string();
        assert!(err.contains("hydraulics.save_interval_ms"), "{err}");
        let err = Config::from_toml_str("[hydraulics]\nrecrd = \"x\"\n", "c.toml")
            .unwrap_err()
            .to_string();
        assert!(err.contains("recrd") && err.contains("line 2"), "{err}");
        let c = Config::from_toml_str("[paths]\nstate_dir = \"/var/lib/hm\"\n", "c").unwrap();
        assert_eq!(
            c.hydraulics.record_path(&c.paths),
            Some(PathBuf::from("/var/lib/hm/procedure.rec"))
        );
        assert_eq!(
            Config::default()
                .hydraulics
                .record_path(&PathsConfig::default()),
            None
        );
    }
}
