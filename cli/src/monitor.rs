//! `hydrometra monitor`: a live, readable view of hydrometrad's status in the terminal, or one
//! status as JSON (`--once --json`) for scripts and tests.

use std::io::Write;
use std::time::{Duration, Instant};

use anyhow::Context;
use clap::Args;
use hydrometra_ipc::status::{self, link_down_reason, link_state, scene_stage, scene_state};
use hydrometra_ipc::{alarms, hydraulic_flags, ServiceNames, Status};
use hydrometra_sim::units::pa_to_mmhg;
use iceoryx2::prelude::*;
use iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenError;

/// Arguments of `hydrometra monitor`.
#[derive(Args, Debug, Clone)]
pub struct MonitorArgs {
    /// Prefix of the daemon's services.
    #[arg(long, value_name = "PREFIX", default_value = hydrometra_ipc::DEFAULT_SERVICE_PREFIX)]
    pub service_prefix: String,
    /// Print one status and exit.
    #[arg(long)]
    pub once: bool,
    /// Print JSON instead of the human view (one object; with --once, or one per refresh).
    #[arg(long)]
    pub json: bool,
    /// Give up after this many seconds without a status (default: 10 with --once, else wait).
    #[arg(long, value_name = "SECS")]
    pub timeout: Option<f64>,
    /// Refresh interval of the live view, ms.
    #[arg(long, value_name = "MS", default_value_t = 200)]
    pub refresh_ms: u64,
}

/// Why the link is down, in words a technician can act on; `None` while there is no reason.
pub fn link_down_text(s: &Status) -> Option<String> {
    use link_down_reason as r;
    let d = s.link_down_detail;
    Some(match s.link_down_reason {
        r::NONE => return None,
        r::DEVICE_NOT_FOUND => {
            "device not found: check the device path, the cable and the udev rule \
             (the daemon's log names the path)"
                .into()
        }
        r::USB_DEVICE_NOT_FOUND => "no USB serial device with the configured ids".into(),
        r::PERMISSION_DENIED => {
            let group = (d != r::DETAIL_UNKNOWN).then(|| {
                hydrometra_drivers::transport::group_name(d).unwrap_or_else(|| format!("gid {d}"))
            });
            match group {
                Some(g) => format!(
                    "permission denied: add the daemon's user to group `{g}` \
                     (sudo usermod -aG {g} USER), then restart it"
                ),
                None => "permission denied on the rig device".into(),
            }
        }
        r::DEVICE_BUSY => "device busy: another program has the rig open".into(),
        r::OPEN_FAILED => "cannot open the rig device (see the daemon's log)".into(),
        r::NO_HANDSHAKE => "the device does not answer the handshake (is it the rig?)".into(),
        r::INCOMPATIBLE_VERSION => format!(
            "the rig speaks wire protocol v{d}, this host v{}: update the firmware or the daemon",
            hydrometra_drivers::wire::PROTOCOL_VERSION
        ),
        r::TIMEOUT => "no valid frame for 1 s (hung firmware); reopening".into(),
        r::LOST => "the port failed or hung up (cable pulled?)".into(),
        other => format!("unknown reason {other}"),
    })
}

/// A status as a JSON object: every field, plus readable derived values (`*_mmhg`, names).
pub fn status_json(s: &Status) -> serde_json::Value {
    serde_json::json!({
        "schema_version": s.schema_version,
        "size_bytes": s.size_bytes,
        "sequence": s.sequence,
        "run_id": s.run_id,
        "sim_time_s": s.sim_time_s,
        "publish_monotonic_ns": s.publish_monotonic_ns,
        "link_state": s.link_state,
        "link_state_name": link_state::name(s.link_state),
        "link": {
            "frames": s.link_frames,
            "crc_errors": s.link_crc_errors,
            "malformed": s.link_malformed,
            "sequence_gaps": s.link_sequence_gaps,
            "resyncs": s.link_resyncs,
            "reconnects": s.link_reconnects,
            "clamped_values": s.link_clamped_values,
            "device_faults": s.link_device_faults,
            "down_reason": s.link_down_reason,
            "down_reason_name": link_down_reason::name(s.link_down_reason),
            "down_detail": s.link_down_detail,
            "down_text": link_down_text(s),
        },
        "last_sample_age_s": finite(s.last_sample_age_s),
        "rig_device_time_us": s.rig_device_time_us,
        "rig_sequence": s.rig_sequence,
        "rig_valve_in_opening": s.rig_valve_in_opening,
        "rig_valve_out_opening": s.rig_valve_out_opening,
        "rig_pump_set_pressure_pa": s.rig_pump_set_pressure_pa,
        "valve_in_opening": s.valve_in_opening,
        "valve_out_opening": s.valve_out_opening,
        "pump_set_pressure_pa": s.pump_set_pressure_pa,
        "pump_set_pressure_mmhg": pa_to_mmhg(s.pump_set_pressure_pa),
        "scope_tip_position_m": s.scope_tip_position_m,
        "scope_view_direction": s.scope_view_direction,
        "scope_orientation_wxyz": s.scope_orientation_wxyz,
        "scope_pose_valid": s.scope_pose_valid != 0,
        "buttons": s.buttons,
        "safe_state": s.safe_state != 0,
        "alarm_bits": s.alarm_bits,
        "alarms": alarms::names(s.alarm_bits),
        "tick_rate_hz": s.tick_rate_hz,
        "ticks": s.ticks,
        "deadline_misses": s.deadline_misses,
        "tick_work_max_s": s.tick_work_max_s,
        "latency_p50_s": finite(s.latency_p50_s),
        "latency_p99_s": finite(s.latency_p99_s),
        "latency_max_s": finite(s.latency_max_s),
        "latency_samples": s.latency_samples,
        "statuses_dropped": s.statuses_dropped,
        "status_gap_max_s": s.status_gap_max_s,
        "realtime_mode": hydrometra_ipc::status::realtime_mode::name(s.realtime_mode),
        "hydraulics": hydraulics_json(s),
        "scene": scene_json(s),
    })
}

/// The scene's state and per-stage counters (keyed by stage name).
fn scene_json(s: &Status) -> serde_json::Value {
    let stages: serde_json::Map<String, serde_json::Value> = scene_stage::NAMES
        .iter()
        .enumerate()
        .map(|(i, name)| {
            let stage = serde_json::json!({
                "runs": s.scene_stage_runs[i],
                "skips": s.scene_stage_skips[i],
                "p99_s": finite(s.scene_stage_p99_s[i]),
            });
            (name.to_string(), stage)
        })
        .collect();
    serde_json::json!({
        "state": s.scene_state,
        "state_name": scene_state::name(s.scene_state),
        "frames": s.scene_frames,
        "step_p99_s": finite(s.scene_step_p99_s),
        "view_clarity": finite(s.view_clarity),
        "cavity_surface_volume_ml": s.cavity_surface_volume_m3 * 1e6,
        "degradation": s.scene_degradation,
        "frames_late": s.scene_frames_late,
        "frames_skipped": s.scene_frames_skipped,
        "stages": stages,
    })
}

/// The scene block of the human view: state, frames, clarity, and each stage's runs, skips and
/// p99 (a stage that never ran shows "-").
fn render_scene(w: &mut String, s: &Status) {
    use std::fmt::Write as _;
    let _ = writeln!(
        w,
        "SCENE         {}   frames {}   step p99 {}   view clarity {}   cavity surface {:5.2} ml",
        scene_state::name(s.scene_state).to_uppercase(),
        s.scene_frames,
        ms(s.scene_step_p99_s),
        if s.view_clarity.is_finite() {
            format!("{:3.0} %", 100.0 * s.view_clarity)
        } else {
            "-".into()
        },
        s.cavity_surface_volume_m3 * 1e6
    );
    let _ = writeln!(
        w,
        "  degradation level {} (0 full quality)   frames late {}   frame slots skipped {}",
        s.scene_degradation, s.scene_frames_late, s.scene_frames_skipped
    );
    let _ = write!(w, "  stage           ");
    for name in scene_stage::NAMES {
        let _ = write!(w, "{name:>12}");
    }
    let _ = writeln!(w);
    let rows: [(&str, &dyn Fn(usize) -> String); 3] = [
        ("runs", &|i| s.scene_stage_runs[i].to_string()),
        ("skips", &|i| s.scene_stage_skips[i].to_string()),
        ("p99", &|i| {
            let p = s.scene_stage_p99_s[i];
            if s.scene_stage_runs[i] > 0 && p.is_finite() {
                format!("{:.3} ms", p * 1e3)
            } else {
                "-".into()
            }
        }),
    ];
    for (label, cell) in rows {
        let _ = write!(w, "  {label:<16}");
        for i in 0..scene_stage::NAMES.len() {
            let _ = write!(w, "{:>12}", cell(i));
        }
        let _ = writeln!(w);
    }
    let _ = writeln!(w);
}

fn hydraulics_json(s: &Status) -> serde_json::Value {
    serde_json::json!({
            "active": s.hydraulic_flags & hydraulic_flags::ACTIVE != 0,
            "flags": s.hydraulic_flags,
            "perforated": s.hydraulic_flags & hydraulic_flags::PERFORATED != 0,
            "pump_stopped": s.hydraulic_flags & hydraulic_flags::PUMP_STOPPED != 0,
            "cavity_pressure_pa": s.cavity_pressure_pa,
            "cavity_pressure_mmhg": pa_to_mmhg(s.cavity_pressure_pa),
            "cavity_volume_ml": s.cavity_volume_m3 * 1e6,
            "inflow_ml_per_min": ml_min(s.inflow_m3_per_s),
            "outflow_ml_per_min": ml_min(s.outflow_m3_per_s),
            "leak_ml_per_min": ml_min(s.leak_m3_per_s),
            "absorption_ml_per_min": ml_min(s.absorption_m3_per_s),
            "perforation_ml_per_min": ml_min(s.perforation_m3_per_s),
            "inflow_port_velocity_m_per_s": s.inflow_port_velocity_m_per_s,
            "outflow_port_velocity_m_per_s": s.outflow_port_velocity_m_per_s,
            "fluid_in_ml": s.fluid_in_m3 * 1e6,
            "fluid_collected_ml": s.fluid_collected_m3 * 1e6,
            "deficit_ml": s.deficit_m3 * 1e6,
            "deficit_rate_ml_per_min": ml_min(s.deficit_rate_m3_per_s),
            "deficit_limit_ml": s.deficit_limit_m3 * 1e6,
            "deficit_warning_stage": s.deficit_warning_stage,
            "procedure_id": s.procedure_id,
            "procedure_time_s": s.procedure_time_s,
    })
}

fn ml_min(flow_m3_per_s: f64) -> f64 {
    flow_m3_per_s * 6e7
}

fn finite(v: f64) -> serde_json::Value {
    if v.is_finite() {
        serde_json::json!(v)
    } else {
        serde_json::Value::Null
    }
}

fn ms(s: f64) -> String {
    if s.is_finite() {
        format!("{:7.3} ms", s * 1e3)
    } else {
        "      - ms".into()
    }
}

/// The human view of one status.
pub fn render(s: &Status, rate_hz: f64, note: &str) -> String {
    let mut out = String::new();
    let w = &mut out;
    use std::fmt::Write as _;
    let _ = writeln!(
        w,
        "hydrometra monitor   run {:016x}   status #{}   {:.1} Hz{}",
        s.run_id, s.sequence, rate_hz, note
    );
    let _ = writeln!(
        w,
        "sim time      {:10.3} s     ticks {} at {:.0} Hz, deadline misses {}",
        s.sim_time_s, s.ticks, s.tick_rate_hz, s.deadline_misses
    );
    let _ = writeln!(w);
    let age = if s.last_sample_age_s.is_finite() {
        format!("{:.1} ms", s.last_sample_age_s * 1e3)
    } else {
        "never".into()
    };
    let _ = writeln!(
        w,
        "RIG LINK      {:<13} last sample {} ago (rig seq {}, device t {:.3} s)",
        link_state::name(s.link_state).to_uppercase(),
        age,
        s.rig_sequence,
        s.rig_device_time_us as f64 * 1e-6
    );
    if let Some(text) = link_down_text(s) {
        let _ = writeln!(
            w,
            "  down: {} - {text}",
            link_down_reason::name(s.link_down_reason)
        );
    }
    let _ = writeln!(w, "  frames {}  crc errors {}  malformed {}  seq gaps {}  resyncs {}  reconnects {}  clamped {}  device faults {}",
        s.link_frames, s.link_crc_errors, s.link_malformed, s.link_sequence_gaps, s.link_resyncs, s.link_reconnects, s.link_clamped_values, s.link_device_faults);
    let _ = writeln!(w);
    let _ = writeln!(
        w,
        "INPUTS                 rig        simulation{}",
        if s.safe_state != 0 {
            "   (SAFE STATE: valves closed, pump stopped)"
        } else {
            ""
        }
    );
    let _ = writeln!(
        w,
        "  inflow valve     {:6.1} %    {:6.1} %",
        s.rig_valve_in_opening * 100.0,
        s.valve_in_opening * 100.0
    );
    let _ = writeln!(
        w,
        "  outflow valve    {:6.1} %    {:6.1} %",
        s.rig_valve_out_opening * 100.0,
        s.valve_out_opening * 100.0
    );
    let _ = writeln!(
        w,
        "  pump set         {:6.1} mmHg {:6.1} mmHg",
        pa_to_mmhg(s.rig_pump_set_pressure_pa),
        pa_to_mmhg(s.pump_set_pressure_pa)
    );
    let p = s.scope_tip_position_m;
    let d = s.scope_view_direction;
    let _ = writeln!(
        w,
        "  scope tip        ({:6.1}, {:6.1}, {:6.1}) mm  view ({:+.2}, {:+.2}, {:+.2})  {}",
        p[0] * 1e3,
        p[1] * 1e3,
        p[2] * 1e3,
        d[0],
        d[1],
        d[2],
        if s.scope_pose_valid != 0 {
            "valid"
        } else {
            "INVALID"
        }
    );
    let _ = writeln!(w, "  buttons          {:#06x}", s.buttons);
    let _ = writeln!(w);
    if s.hydraulic_flags & hydraulic_flags::ACTIVE != 0 {
        let flag = |bit: u64, text: &'static str| {
            if s.hydraulic_flags & bit != 0 {
                text
            } else {
                ""
            }
        };
        let _ = writeln!(
            w,
            "HYDRAULICS    cavity {:6.1} mmHg  {:5.2} ml   procedure {} ({:.0} s){}{}{}",
            pa_to_mmhg(s.cavity_pressure_pa),
            s.cavity_volume_m3 * 1e6,
            s.procedure_id,
            s.procedure_time_s,
            flag(hydraulic_flags::PERFORATED, "  PERFORATED"),
            flag(hydraulic_flags::PUMP_STOPPED, "  PUMP STOPPED"),
            flag(hydraulic_flags::RESTORED, "  (restored)")
        );
        let _ = writeln!(
            w,
            "  flows ml/min     in {:6.1}  out {:6.1}  leak {:5.1}  absorbed {:5.1}  perforation {:6.1}",
            ml_min(s.inflow_m3_per_s),
            ml_min(s.outflow_m3_per_s),
            ml_min(s.leak_m3_per_s),
            ml_min(s.absorption_m3_per_s),
            ml_min(s.perforation_m3_per_s)
        );
        let _ = writeln!(
            w,
            "  port jets        in {:4.2} m/s  out {:4.2} m/s",
            s.inflow_port_velocity_m_per_s, s.outflow_port_velocity_m_per_s
        );
        let _ = writeln!(
            w,
            "  FLUID DEFICIT {:7.1} ml of {:.0} ml ({:.0} %)  rate {:6.1} ml/min  warning stage {}   in {:.1} ml, collected {:.1} ml",
            s.deficit_m3 * 1e6,
            s.deficit_limit_m3 * 1e6,
            if s.deficit_limit_m3 > 0.0 { 100.0 * s.deficit_m3 / s.deficit_limit_m3 } else { 0.0 },
            ml_min(s.deficit_rate_m3_per_s),
            s.deficit_warning_stage,
            s.fluid_in_m3 * 1e6,
            s.fluid_collected_m3 * 1e6
        );
        let _ = writeln!(w);
    }
    if s.scene_state != scene_state::NONE {
        render_scene(w, s);
    }
    let names = alarms::names(s.alarm_bits);
    let _ = writeln!(
        w,
        "ALARMS        {}",
        if names.is_empty() {
            "none".to_string()
        } else {
            names.join(", ")
        }
    );
    let _ = writeln!(w);
    let _ = writeln!(
        w,
        "LATENCY rig sample -> status   p50 {}  p99 {}  max {}  (n {})",
        ms(s.latency_p50_s),
        ms(s.latency_p99_s),
        ms(s.latency_max_s),
        s.latency_samples
    );
    let _ = writeln!(
        w,
        "  longest tick {}   longest gap between statuses {}   statuses dropped {}   scheduling {}",
        ms(s.tick_work_max_s),
        ms(s.status_gap_max_s),
        s.statuses_dropped,
        hydrometra_ipc::status::realtime_mode::name(s.realtime_mode)
    );
    out
}

type StatusSubscriber = iceoryx2::port::subscriber::Subscriber<ipc::Service, Status, ()>;

/// Opens the status service and a subscriber, retrying while the daemon is not there.
fn connect(
    node: &Node<ipc::Service>,
    names: &ServiceNames,
    deadline: Option<Instant>,
    quiet: bool,
) -> anyhow::Result<Option<StatusSubscriber>> {
    let mut told = false;
    loop {
        match status::open(node, names) {
            Ok(service) => {
                let subscriber = service.subscriber_builder().create().map_err(|e| {
                    anyhow::anyhow!("cannot subscribe to {}: {e:?}", names.full("status"))
                })?;
                return Ok(Some(subscriber));
            }
            Err(PublishSubscribeOpenError::DoesNotExist) => {
                if !told && !quiet {
                    eprintln!("waiting for hydrometrad on {} ...", names.full("status"));
                    told = true;
                }
            }
            Err(PublishSubscribeOpenError::IncompatibleTypes) => anyhow::bail!(
                "{} exists but carries another payload type than {} (schema v{}): the daemon \
                 speaks another schema version",
                names.full("status"),
                // SAFETY: only reads the name to print it; the layout it vouches for is the ipc
                // crate's (checked against docs/ipc.md by its layout test).
                unsafe { <Status as ZeroCopySend>::type_name() },
                hydrometra_ipc::SCHEMA_VERSION
            ),
            Err(e) => anyhow::bail!("cannot open {}: {e:?}", names.full("status")),
        }
        if deadline.is_some_and(|d| Instant::now() >= d) {
            return Ok(None);
        }
        if node.wait(Duration::from_millis(100)).is_err() {
            return Ok(None); // Ctrl-C
        }
    }
}

/// Runs the monitor.
pub fn run(args: &MonitorArgs) -> anyhow::Result<()> {
    let names = ServiceNames::new(&args.service_prefix)?;
    set_log_level_from_env_or(LogLevel::Error);
    let timeout = args.timeout.or(if args.once { Some(10.0) } else { None });
    let timeout = match timeout {
        Some(t) if t.is_finite() && t > 0.0 => Some(Duration::from_secs_f64(t)),
        Some(t) => anyhow::bail!("--timeout {t}: expected a positive number of seconds"),
        None => None,
    };
    let node = NodeBuilder::new()
        .create::<ipc::Service>()
        .context("cannot create an iceoryx2 node")?;
    let started = Instant::now();
    let deadline = timeout.map(|t| started + t);
    let refresh = Duration::from_millis(args.refresh_ms.clamp(10, 10_000));
    let mut stdout = std::io::stdout();
    let live = !args.once && !args.json;

    'reconnect: loop {
        let Some(subscriber) = connect(&node, &names, deadline, args.json)? else {
            anyhow::bail!(
                "no status from hydrometrad on {} within the timeout",
                names.full("status")
            );
        };
        let mut latest: Option<Status> = None;
        let mut last_data = Instant::now();
        let mut rate = (Instant::now(), 0u64, 0.0f64); // window start, count, rate
        loop {
            let mut got = 0u64;
            while let Some(sample) = subscriber.receive().context("receive failed")? {
                latest = Some(*sample);
                got += 1;
            }
            if got > 0 {
                last_data = Instant::now();
                rate.1 += got;
            }
            let window = rate.0.elapsed().as_secs_f64();
            if window >= 1.0 {
                rate = (Instant::now(), 0, rate.1 as f64 / window);
            }
            if let Some(s) = latest {
                if args.once {
                    if args.json {
                        writeln!(stdout, "{}", status_json(&s))?;
                    } else {
                        write!(stdout, "{}", render(&s, rate.2, ""))?;
                    }
                    return Ok(());
                }
                let silent = last_data.elapsed();
                if args.json {
                    if got > 0 {
                        writeln!(stdout, "{}", status_json(&s))?;
                    }
                } else if live {
                    let note = if silent > Duration::from_secs(1) {
                        format!(
                            "   NO STATUS FOR {:.1} s (daemon stopped?)",
                            silent.as_secs_f64()
                        )
                    } else {
                        String::new()
                    };
                    // Home, clear, redraw: refreshes in place.
                    write!(stdout, "\x1b[H\x1b[2J{}", render(&s, rate.2, &note))?;
                }
                stdout.flush()?;
                if silent > Duration::from_secs(3) {
                    // The daemon may have restarted with a new service: subscribe again.
                    continue 'reconnect;
                }
            } else if deadline.is_some_and(|d| Instant::now() >= d) {
                anyhow::bail!(
                    "no status from hydrometrad on {} within the timeout",
                    names.full("status")
                );
            }
            if node
                .wait(refresh.min(Duration::from_millis(if latest.is_none() {
                    20
                } else {
                    1000
                })))
                .is_err()
            {
                return Ok(()); // Ctrl-C / SIGTERM
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_reason_a_link_is_down_is_shown_with_what_to_do() {
        let s = Status {
            link_down_reason: link_down_reason::PERMISSION_DENIED,
            link_down_detail: 0, // gid 0 is `root` on every Linux system
            ..Status::default()
        };
        let view = render(&s, 0.0, "");
        assert!(
            view.contains("permission-denied") && view.contains("group `root`"),
            "{view}"
        );
        let j = status_json(&s);
        assert_eq!(j["link"]["down_reason_name"], "permission-denied");
        let s = Status {
            link_down_reason: link_down_reason::INCOMPATIBLE_VERSION,
            link_down_detail: 2,
            ..Status::default()
        };
        assert!(render(&s, 0.0, "").contains("wire protocol v2"));
        assert!(!render(&Status::default(), 0.0, "").contains("down:"));
    }

    #[test]
    fn json_and_view_show_clinical_units_and_names() {
        let s = Status {
            pump_set_pressure_pa: 100.0 * hydrometra_units::PA_PER_MMHG,
            rig_pump_set_pressure_pa: 100.0 * hydrometra_units::PA_PER_MMHG,
            link_state: link_state::STALE,
            alarm_bits: alarms::RIG_LINK_LOST | alarms::RIG_SAFE_STATE,
            ..Status::default()
        };
        let j = status_json(&s);
        assert!((j["pump_set_pressure_mmhg"].as_f64().unwrap() - 100.0).abs() < 1e-9);
        assert_eq!(j["link_state_name"], "stale");
        assert_eq!(
            j["alarms"],
            serde_json::json!(["rig-link-lost", "rig-safe-state"])
        );
        assert!(j["latency_p99_s"].is_null(), "NaN becomes null in JSON");
        let view = render(&s, 1000.0, "");
        assert!(
            view.contains("STALE") && view.contains("100.0 mmHg") && view.contains("SAFE STATE"),
            "{view}"
        );
        assert!(!view.contains("SCENE"), "no scene block without a scene");
    }

    #[test]
    fn the_scene_block_shows_state_clarity_and_every_stage() {
        let mut s = Status {
            scene_state: scene_state::RUNNING,
            scene_frames: 1234,
            view_clarity: 0.87,
            cavity_surface_volume_m3: 4.5e-6,
            ..Status::default()
        };
        s.scene_stage_runs[scene_stage::FLUID] = 1000;
        s.scene_stage_skips[scene_stage::FLUID] = 234;
        s.scene_stage_p99_s[scene_stage::FLUID] = 0.0021;
        let view = render(&s, 1000.0, "");
        assert!(
            view.contains("RUNNING") && view.contains("1234") && view.contains("87 %"),
            "{view}"
        );
        assert!(view.contains("2.100 ms") && view.contains("234"), "{view}");
        for name in scene_stage::NAMES {
            assert!(view.contains(name), "{name} missing:\n{view}");
        }
        let j = status_json(&s);
        assert_eq!(j["scene"]["state_name"], "running");
        assert_eq!(j["scene"]["stages"]["fluid"]["skips"], 234);
        assert!((j["scene"]["cavity_surface_volume_ml"].as_f64().unwrap() - 4.5).abs() < 1e-9);
    }
}
