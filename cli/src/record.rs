//! `hydrometra record info FILE` and `hydrometra debrief FILE --out DIR` (docs/recording.md,
//! docs/debrief.md).

use std::path::PathBuf;

use anyhow::{bail, Result};
use clap::{Args, Subcommand};
use hydrometra_sim::units::mmhg_to_pa;

use hydrometra_record::debrief::{self, DebriefSettings};
use hydrometra_record::reader::Recording;

/// Recording tools.
#[derive(Subcommand, Debug)]
pub enum RecordCommand {
    /// Summarise a recording: duration, channels, message counts, gaps, the recorder's drops.
    Info(InfoArgs),
}

/// Arguments of `hydrometra record info`.
#[derive(Args, Debug)]
pub struct InfoArgs {
    /// The recording (MCAP).
    pub file: PathBuf,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Arguments of `hydrometra debrief`.
#[derive(Args, Debug)]
pub struct DebriefArgs {
    /// The recording (MCAP).
    pub file: PathBuf,
    /// Output directory for metrics.json, report.md and the SVG plots.
    #[arg(long, default_value = "debrief")]
    pub out: PathBuf,
    /// Cavity pressure at or above which the cavity counts as distended, mmHg.
    #[arg(long, value_name = "MMHG", default_value_t = 40.0)]
    pub distended_mmhg: f64,
}

/// Runs a `hydrometra record` subcommand.
pub fn run(cmd: RecordCommand) -> Result<()> {
    match cmd {
        RecordCommand::Info(a) => info(&a),
    }
}

/// A gap worth reporting: three expected periods without a message.
const GAP_FACTOR: f64 = 3.0;

fn info(a: &InfoArgs) -> Result<()> {
    let rec = Recording::load(&a.file)?;
    let (first, last) = rec.span_ns().unwrap_or((0, 0));
    let duration_s = last.saturating_sub(first) as f64 * 1e-9;
    let mut channels = serde_json::Map::new();
    for (topic, c) in &rec.channels {
        let span = c.last_ns.saturating_sub(c.first_ns) as f64 * 1e-9;
        let rate = if span > 0.0 {
            (c.messages.saturating_sub(1)) as f64 / span
        } else {
            0.0
        };
        let max_gap_s = c.max_gap_ns as f64 * 1e-9;
        let gap = rate > 0.0 && max_gap_s > GAP_FACTOR / rate;
        channels.insert(
            topic.clone(),
            serde_json::json!({
                "schema": c.schema,
                "encoding": c.encoding,
                "messages": c.messages,
                "mean_rate_hz": rate,
                "max_gap_s": max_gap_s,
                "max_gap_at_s": c.max_gap_at_ns.saturating_sub(first) as f64 * 1e-9,
                "gap": gap,
            }),
        );
    }
    let drops = rec
        .events
        .iter()
        .rev()
        .find(|(_, e)| e.kind == "recording_stopped")
        .map(|(_, e)| e.detail.clone());
    let summary = serde_json::json!({
        "file": a.file.display().to_string(),
        "duration_s": duration_s,
        "procedure_id": rec.metadata.get("procedure_id"),
        "daemon_version": rec.metadata.get("daemon_version"),
        "rig_mode": rec.metadata.get("rig_mode"),
        "finished": rec.truncated.is_none(),
        "truncated_reason": rec.truncated,
        "channels": channels,
        "skipped_messages": rec.skipped,
        "stopped": drops,
    });
    if a.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
        return Ok(());
    }
    println!("{}", a.file.display());
    println!(
        "  duration {duration_s:.2} s, procedure {}, rig {}, {}",
        rec.metadata.get("procedure_id").map_or("?", |s| s.as_str()),
        rec.metadata.get("rig_mode").map_or("?", |s| s.as_str()),
        match &rec.truncated {
            None => "finished".to_string(),
            Some(why) => format!("NOT finished (read up to the last complete chunk: {why})"),
        }
    );
    for (topic, c) in &channels {
        println!(
            "  {topic:<10} {:>8} msgs  {:>7.1} Hz  max gap {:.3} s at {:.1} s{}",
            c["messages"],
            c["mean_rate_hz"].as_f64().unwrap_or(0.0),
            c["max_gap_s"].as_f64().unwrap_or(0.0),
            c["max_gap_at_s"].as_f64().unwrap_or(0.0),
            if c["gap"].as_bool().unwrap_or(false) {
                "  GAP"
            } else {
                ""
            }
        );
    }
    if let Some(d) = drops {
        println!("  stopped: {d}");
    }
    Ok(())
}

/// Runs `hydrometra debrief`.
pub fn debrief(a: &DebriefArgs) -> Result<()> {
    if !(a.distended_mmhg.is_finite() && a.distended_mmhg > 0.0) {
        bail!(
            "--distended-mmhg {}: expected a pressure > 0 mmHg",
            a.distended_mmhg
        );
    }
    let rec = Recording::load(&a.file)?;
    let settings = DebriefSettings {
        distended_pa: mmhg_to_pa(a.distended_mmhg),
        ..DebriefSettings::default()
    };
    let m = debrief::metrics(&rec, &settings).map_err(anyhow::Error::msg)?;
    debrief::write_report(&rec, &m, &a.out)?;
    println!(
        "{}: fluid in {:.0} ml, collected {:.0} ml, deficit {:.0} ml (limit {:.0} ml), {:.1} s above \
         the overpressure threshold, {} alarm changes -> {}",
        a.file.display(),
        m.fluid_in_ml,
        m.fluid_collected_ml,
        m.deficit_ml,
        m.deficit_limit_ml,
        m.time_above_overpressure_s,
        m.alarms.len(),
        a.out.join("report.md").display()
    );
    Ok(())
}
