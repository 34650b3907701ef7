//! `hydrometra rig`: run the emulated rig on a pseudo-terminal, or probe a (real or emulated) rig.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context, Result};
use clap::{Args, Subcommand};
use hydrometra_drivers::calibration::{Calibration, PA_PER_MMHG};
use hydrometra_drivers::emulator::{EmulatedRig, EmulatorOptions, Scenario};
use hydrometra_drivers::transport::{
    DeviceTarget, LinkConfig, LinkSnapshot, RigLink, RIG_DEVICE_PATH,
};
use hydrometra_drivers::wire::PROTOCOL_VERSION;

/// Rig tools.
#[derive(Subcommand, Debug)]
pub enum RigCommand {
    /// Emulate the rig firmware on a pseudo-terminal, playing a scenario (with its faults).
    Emulate(EmulateArgs),
    /// Connect to a rig, handshake, and print the link counters and latest calibrated state.
    Probe(ProbeArgs),
}

/// Arguments of `hydrometra rig emulate`.
#[derive(Args, Debug)]
pub struct EmulateArgs {
    /// Scenario TOML file, or the name of a built-in scenario (`default`).
    #[arg(long, value_name = "FILE|NAME", default_value = "default")]
    pub scenario: String,
    /// Create a symlink to the pseudo-terminal here (replaced if it is already a symlink).
    #[arg(long, value_name = "PATH")]
    pub link: Option<PathBuf>,
    /// Sample rate, Hz.
    #[arg(long, value_name = "HZ", default_value_t = 250.0)]
    pub rate: f64,
    /// Device heartbeat rate, Hz.
    #[arg(long, value_name = "HZ", default_value_t = 10.0)]
    pub heartbeat_hz: f64,
    /// Calibration file used backwards to produce raw counts (default: the built-in defaults).
    #[arg(long, value_name = "FILE")]
    pub calibration: Option<PathBuf>,
    /// Serial number reported in the device hello.
    #[arg(long, default_value = "EMU-0001")]
    pub serial: String,
    /// Stop after this many seconds (default: run until interrupted).
    #[arg(long, value_name = "S")]
    pub seconds: Option<f64>,
    /// Play a recording's rig bytes instead of a scenario (docs/recording.md); stops when the
    /// recording ends (or after --seconds).
    #[arg(long, value_name = "FILE", conflicts_with = "scenario")]
    pub replay: Option<PathBuf>,
    /// Speed of --replay, times real time.
    #[arg(long, value_name = "X", default_value_t = 1.0, requires = "replay")]
    pub speed: f64,
}

/// Arguments of `hydrometra rig probe`.
#[derive(Args, Debug)]
pub struct ProbeArgs {
    /// Device path (e.g. /dev/hydrometra-rig, /tmp/rig).
    #[arg(
        long,
        value_name = "PATH",
        conflicts_with = "usb",
        required_unless_present = "usb"
    )]
    pub device: Option<PathBuf>,
    /// USB device as VID:PID or VID:PID:SERIAL (hexadecimal ids), instead of --device.
    #[arg(long, value_name = "VID:PID[:SERIAL]")]
    pub usb: Option<String>,
    /// How long to listen, seconds.
    #[arg(long, value_name = "S", default_value_t = 2.0)]
    pub seconds: f64,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
    /// Calibration file (default: the built-in defaults).
    #[arg(long, value_name = "FILE")]
    pub calibration: Option<PathBuf>,
}

/// Runs a `hydrometra rig` subcommand.
pub fn run(cmd: RigCommand) -> Result<()> {
    match cmd {
        RigCommand::Emulate(a) => emulate(a),
        RigCommand::Probe(a) => probe(a),
    }
}

fn load_calibration(path: &Option<PathBuf>) -> Result<Calibration> {
    match path {
        Some(p) => Ok(Calibration::load(p)?),
        None => Ok(Calibration::default()),
    }
}

fn positive_seconds(flag: &str, s: f64) -> Result<Duration> {
    if !(s.is_finite() && s > 0.0 && s <= 1.0e6) {
        bail!("{flag} {s}: expected a number of seconds in (0, 1e6]");
    }
    Ok(Duration::from_secs_f64(s))
}

fn emulate(a: EmulateArgs) -> Result<()> {
    let run_for = a
        .seconds
        .map(|s| positive_seconds("--seconds", s))
        .transpose()?;
    if let Some(file) = &a.replay {
        return replay(file, a.speed, a.link.clone(), run_for);
    }
    let scenario = Scenario::resolve(&a.scenario)?;
    let options = EmulatorOptions {
        sample_rate_hz: a.rate,
        heartbeat_hz: a.heartbeat_hz,
        link_path: a.link.clone(),
        calibration: load_calibration(&a.calibration)?,
        serial_number: a.serial.clone(),
        ..EmulatorOptions::default()
    };
    let name = scenario.name.clone();
    let (duration, looping) = (scenario.duration_s(), scenario.looping);
    let faults = scenario.faults.events.len();
    let rig = EmulatedRig::start(scenario, options).context("starting the emulated rig")?;
    let target = std::fs::read_link(rig.device_path())
        .map(|t| t.display().to_string())
        .unwrap_or_else(|_| "?".into());
    println!(
        "emulated rig (protocol v{PROTOCOL_VERSION}) at {} -> {target}: scenario {name:?} \
         ({duration:.1} s{}), {} Hz, {faults} scheduled fault(s)",
        rig.device_path().display(),
        if looping { ", looping" } else { "" },
        a.rate
    );
    let started = Instant::now();
    let mut last_report = Instant::now();
    loop {
        std::thread::sleep(Duration::from_millis(100));
        if run_for.is_some_and(|d| started.elapsed() >= d) {
            break;
        }
        if last_report.elapsed() >= Duration::from_secs(10) {
            last_report = Instant::now();
            let s = rig.stats();
            tracing::info!(
                session = s.session_active,
                samples = s.samples_sent,
                handshakes = s.handshakes,
                "emulated rig"
            );
        }
    }
    rig.stop();
    Ok(())
}

fn replay(
    file: &std::path::Path,
    speed: f64,
    link: Option<PathBuf>,
    run_for: Option<Duration>,
) -> Result<()> {
    let recording = hydrometra_record::reader::Recording::load(file)?;
    let script = recording.replay_script();
    let length_s = script.duration_s() / speed;
    let rig = EmulatedRig::start_replay(script, speed, link)
        .with_context(|| format!("cannot replay {}", file.display()))?;
    println!(
        "replaying {} at {} (speed {speed}x, {length_s:.1} s from the host's hello)",
        file.display(),
        rig.device_path().display()
    );
    let started = Instant::now();
    loop {
        std::thread::sleep(Duration::from_millis(100));
        if run_for.is_some_and(|d| started.elapsed() >= d) || rig.stats().replay_done {
            break;
        }
    }
    let s = rig.stats();
    println!(
        "replay {}: {} handshakes, {} runs written",
        if s.replay_done { "finished" } else { "stopped" },
        s.handshakes,
        s.frames_sent
    );
    rig.stop();
    Ok(())
}

fn parse_usb(spec: &str) -> Result<DeviceTarget> {
    let mut parts = spec.splitn(3, ':');
    let hex = |what: &str, v: Option<&str>| -> Result<u16> {
        let v =
            v.ok_or_else(|| anyhow!("--usb {spec}: missing {what}; expected VID:PID[:SERIAL]"))?;
        u16::from_str_radix(v.trim_start_matches("0x"), 16)
            .map_err(|_| anyhow!("--usb {spec}: {what} {v:?} is not a 16-bit hexadecimal id"))
    };
    let vid = hex("vendor id", parts.next())?;
    let pid = hex("product id", parts.next())?;
    Ok(DeviceTarget::Usb {
        vid,
        pid,
        serial_number: parts.next().map(str::to_string),
    })
}

fn probe(a: ProbeArgs) -> Result<()> {
    let listen = positive_seconds("--seconds", a.seconds)?;
    let target = match (&a.device, &a.usb) {
        (Some(p), None) => DeviceTarget::Path(p.clone()),
        (None, Some(u)) => parse_usb(u)?,
        (None, None) => DeviceTarget::Path(PathBuf::from(RIG_DEVICE_PATH)),
        (Some(_), Some(_)) => {
            bail!("give either --device PATH or --usb VID:PID[:SERIAL], not both")
        }
    };
    let config = LinkConfig::new(target.clone(), load_calibration(&a.calibration)?);
    let link = RigLink::spawn(config)?;
    std::thread::sleep(listen);
    let snap = link.snapshot();
    link.shutdown();
    if a.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&snapshot_json(&target, &snap))?
        );
    } else {
        print_text(&target, &snap);
    }
    if snap.latest.is_none() {
        bail!(
            "no sample from {target} within {} s (link state {:?}{})",
            a.seconds,
            snap.link_state,
            snap.last_error
                .as_deref()
                .map(|e| format!("; last error: {e}"))
                .unwrap_or_default()
        );
    }
    Ok(())
}

fn snapshot_json(target: &DeviceTarget, s: &LinkSnapshot) -> serde_json::Value {
    let c = &s.counters;
    serde_json::json!({
        "device_target": target.to_string(),
        "link_state": format!("{:?}", s.link_state),
        "device": s.device.as_ref().map(|d| serde_json::json!({
            "protocol_version": d.protocol_version,
            "firmware_version": d.firmware_version,
            "serial_number": d.serial_number,
            "capabilities": d.capabilities,
            "calibration_id": d.calibration_id,
            "sample_rate_hz": d.sample_rate_hz,
        })),
        "counters": {
            "frames": c.frames,
            "crc_errors": c.crc_errors,
            "malformed": c.malformed,
            "sequence_gaps": c.sequence_gaps,
            "resyncs": c.resyncs,
            "reconnects": c.reconnects,
            "clamped_values": c.clamped_values,
            "device_faults": c.device_faults,
        },
        "last_sample_age_s": s.last_sample_age.map(|d| d.as_secs_f64()),
        "last_error": s.last_error,
        "latest_raw": s.latest_raw.map(|r| serde_json::json!({
            "valve_in_raw": r.valve_in_raw,
            "valve_out_raw": r.valve_out_raw,
            "pump_raw": r.pump_raw,
            "pose_valid": r.pose_valid,
            "position_mm": r.position_mm,
            "orientation_wxyz": r.orientation_wxyz,
        })),
        "latest": s.latest.map(|r| serde_json::json!({
            "device_time_us": r.device_time_us,
            "sequence": r.sequence,
            "valve_in_opening": r.valve_in_opening,
            "valve_out_opening": r.valve_out_opening,
            "pump_set_pressure_pa": r.pump_set_pressure_pa,
            "scope": {
                "tip_position_m": r.scope.tip_position_m,
                "view_direction": r.scope.view_direction,
                "orientation_wxyz": r.scope.orientation,
                "valid": r.scope.valid,
            },
            "buttons": r.buttons,
        })),
    })
}

fn print_text(target: &DeviceTarget, s: &LinkSnapshot) {
    println!("device        {target}");
    println!("link state    {:?}", s.link_state);
    if let Some(e) = &s.last_error {
        println!("last error    {e}");
    }
    if let Some(d) = &s.device {
        println!(
            "rig           serial {} firmware {} protocol v{} calibration id {} caps {:#x} {} Hz",
            d.serial_number,
            d.firmware_version,
            d.protocol_version,
            d.calibration_id,
            d.capabilities,
            d.sample_rate_hz
        );
    }
    let c = &s.counters;
    println!(
        "counters      frames {} crc_errors {} malformed {} sequence_gaps {} resyncs {} \
         reconnects {} clamped_values {} device_faults {}",
        c.frames,
        c.crc_errors,
        c.malformed,
        c.sequence_gaps,
        c.resyncs,
        c.reconnects,
        c.clamped_values,
        c.device_faults
    );
    match (&s.latest, s.last_sample_age) {
        (Some(r), Some(age)) => {
            println!(
                "latest        seq {} device time {:.6} s, age {:.1} ms",
                r.sequence,
                r.device_time_us as f64 * 1e-6,
                age.as_secs_f64() * 1e3
            );
            println!(
                "valve_in      {:.4} (opening, 0 closed .. 1 open)",
                r.valve_in_opening
            );
            println!("valve_out     {:.4}", r.valve_out_opening);
            println!(
                "pump set      {:.1} Pa ({:.1} mmHg)",
                r.pump_set_pressure_pa,
                r.pump_set_pressure_pa / PA_PER_MMHG
            );
            let p = r.scope.tip_position_m;
            let v = r.scope.view_direction;
            println!(
                "scope tip     [{:.5}, {:.5}, {:.5}] m, view [{:.4}, {:.4}, {:.4}], valid {}",
                p[0], p[1], p[2], v[0], v[1], v[2], r.scope.valid
            );
            println!("buttons       {:#010b}", r.buttons);
            if let Some(raw) = &s.latest_raw {
                println!(
                    "raw           valve_in {} valve_out {} pump {} counts; marker {:?} mm {:?} (tracker frame)",
                    raw.valve_in_raw,
                    raw.valve_out_raw,
                    raw.pump_raw,
                    raw.position_mm,
                    raw.orientation_wxyz
                );
            }
        }
        _ => println!("latest        no sample"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn usb_targets_parse_and_bad_ones_say_what_is_wrong() {
        assert_eq!(
            parse_usb("1209:0001").unwrap(),
            DeviceTarget::Usb {
                vid: 0x1209,
                pid: 0x0001,
                serial_number: None
            }
        );
        assert_eq!(
            parse_usb("0x1209:BEEF:RIG:7").unwrap(),
            DeviceTarget::Usb {
                vid: 0x1209,
                pid: 0xBEEF,
                serial_number: Some("RIG:7".into())
            }
        );
        let e = parse_usb("1209").unwrap_err().to_string();
        assert!(e.contains("missing product id"), "{e}");
        let e = parse_usb("12g9:0001").unwrap_err().to_string();
        assert!(e.contains("vendor id") && e.contains("12g9"), "{e}");
        let e = parse_usb("1209:10000").unwrap_err().to_string();
        assert!(e.contains("product id"), "{e}");
    }
}
