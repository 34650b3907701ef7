//! The soak benchmark: `hydrometrad` on the emulated rig for hours (by default the `flaky`
//! scenario, which unplugs, garbles and hangs the rig on a schedule, and the `bleed` scene with
//! every stage on), watched from outside through its real interfaces: status over iceoryx2, its
//! memory from `/proc`, its procedure record on disk.
//!
//!     cargo build --release --workspace --bins
//!     target/release/hm-soak --hours 8 --out /tmp/soak
//!
//! Every minute it writes a row to `soak.csv` (wall time, resident memory, ticks, deadline
//! misses, the deficit, scene frames and degradation). At the end it stops the daemon (SIGTERM),
//! reads the procedure record the daemon saved and checks, printing `soak.json`:
//! - memory flat: the resident set's growth from the second hour on (least squares) stays below
//!   `--max-growth-mib-per-h`;
//! - no drift of the loop's clock: over every hour, sim time advanced as the wall clock did within
//!   `--max-rate-drift` (relative; skipped ticks are covered by longer steps, so sim time drifts
//!   only if the loop loses time);
//! - the deficit exact: the deficit the daemon accumulated equals its definition
//!   (in - collected - change of cavity volume) within 1e-9 of the fluid delivered, and status
//!   showed the same deficit as the record.
//!
//! Exit code 0 when all hold, 1 when one fails, 2 on a usage error.

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use hydrometra_hil_tests::{binary, StatusReader};
use hydrometra_sim::hydraulics::ProcedureRecord;

struct Args {
    hours: f64,
    out: PathBuf,
    scene: String,
    scenario: String,
    prefix: String,
    sample_s: f64,
    max_growth_mib_per_h: f64,
    max_rate_drift: f64,
    atlas_cache_dir: Option<String>,
}

fn usage(why: &str) -> ! {
    eprintln!(
        "hm-soak: {why}\nusage: hm-soak --hours H --out DIR [--scene NAME] [--scenario NAME] \
         [--prefix P] [--sample-s S] [--max-growth-mib-per-h X] [--max-rate-drift X] \
         [--atlas-cache-dir DIR]"
    );
    std::process::exit(2);
}

fn parse() -> Args {
    let mut a = Args {
        hours: f64::NAN,
        out: PathBuf::new(),
        scene: "bleed".into(),
        scenario: "flaky".into(),
        prefix: format!("hydrometra-soak/{}", std::process::id()),
        sample_s: 60.0,
        max_growth_mib_per_h: 1.0,
        max_rate_drift: 1e-4,
        atlas_cache_dir: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || {
            it.next()
                .unwrap_or_else(|| usage(&format!("{flag} needs a value")))
        };
        let number = |v: String| -> f64 {
            v.parse()
                .unwrap_or_else(|_| usage(&format!("{flag}: {v:?} is not a number")))
        };
        match flag.as_str() {
            "--hours" => a.hours = number(value()),
            "--out" => a.out = PathBuf::from(value()),
            "--scene" => a.scene = value(),
            "--scenario" => a.scenario = value(),
            "--prefix" => a.prefix = value(),
            "--sample-s" => a.sample_s = number(value()),
            "--max-growth-mib-per-h" => a.max_growth_mib_per_h = number(value()),
            "--max-rate-drift" => a.max_rate_drift = number(value()),
            "--atlas-cache-dir" => a.atlas_cache_dir = Some(value()),
            other => usage(&format!("unknown flag {other}")),
        }
    }
    if a.hours.is_nan() || a.hours <= 0.0 || a.out.as_os_str().is_empty() {
        usage("--hours (> 0) and --out are required");
    }
    if a.sample_s.is_nan() || a.sample_s < 1.0 {
        usage("--sample-s must be at least 1");
    }
    a
}

/// Resident set size of `pid`, bytes.
fn rss_bytes(pid: u32) -> Option<u64> {
    let text = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = text.lines().find(|l| l.starts_with("VmRSS:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Least-squares slope of `y` over `x`.
fn slope(points: &[(f64, f64)]) -> f64 {
    let n = points.len() as f64;
    if n < 2.0 {
        return 0.0;
    }
    let (mx, my) = points
        .iter()
        .fold((0.0, 0.0), |(a, b), (x, y)| (a + x / n, b + y / n));
    let (sxy, sxx) = points.iter().fold((0.0, 0.0), |(a, b), (x, y)| {
        (a + (x - mx) * (y - my), b + (x - mx) * (x - mx))
    });
    if sxx > 0.0 {
        sxy / sxx
    } else {
        0.0
    }
}

struct Row {
    wall_s: f64,
    rss: u64,
    ticks: u64,
    sim_time_s: f64,
    misses: u64,
    tick_rate_hz: f64,
    deficit_m3: f64,
    scene_frames: u64,
    degradation: u32,
    procedure_id: u64,
}

fn main() {
    let args = parse();
    if let Err(e) = std::fs::create_dir_all(&args.out) {
        usage(&format!("cannot create {}: {e}", args.out.display()));
    }
    let record = args.out.join("procedure.rec");
    let _ = std::fs::remove_file(&record);
    let log = args.out.join("hydrometrad.log");
    let log_file = std::fs::File::create(&log).unwrap_or_else(|e| usage(&format!("{e}")));
    let mut command = Command::new(binary("hydrometrad"));
    if let Some(dir) = &args.atlas_cache_dir {
        command.args(["--atlas-cache-dir", dir]);
    }
    let mut daemon = command
        .args([
            "--emulated",
            &args.scenario,
            "--scene",
            &args.scene,
            "--no-record",
        ])
        .args(["--service-prefix", &args.prefix, "--new-procedure"])
        .arg("--procedure-record")
        .arg(&record)
        .env("RUST_LOG", "info")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(log_file)
        .spawn()
        .unwrap_or_else(|e| usage(&format!("cannot start hydrometrad: {e}")));
    let pid = daemon.id();
    let reader = StatusReader::connect(&args.prefix, Duration::from_secs(30));
    let mut csv =
        std::fs::File::create(args.out.join("soak.csv")).unwrap_or_else(|e| usage(&format!("{e}")));
    let _ = writeln!(
        csv,
        "wall_s,rss_mib,ticks,sim_time_s,deadline_misses,tick_rate_hz,deficit_ml,scene_frames,degradation"
    );
    let started = Instant::now();
    let total = Duration::from_secs_f64(args.hours * 3600.0);
    let mut rows: Vec<Row> = Vec::new();
    let mut next = Duration::ZERO;
    let mut last_status = None;
    while started.elapsed() < total {
        // Only the newest status matters: drain the buffer often so it never overflows.
        if let Some(s) = reader.drain().last() {
            last_status = Some(*s);
        }
        if started.elapsed() >= next {
            next += Duration::from_secs_f64(args.sample_s);
            if let (Some(s), Some(rss)) = (last_status, rss_bytes(pid)) {
                let row = Row {
                    wall_s: started.elapsed().as_secs_f64(),
                    rss,
                    ticks: s.ticks,
                    sim_time_s: s.sim_time_s,
                    misses: s.deadline_misses,
                    tick_rate_hz: s.tick_rate_hz,
                    deficit_m3: s.deficit_m3,
                    scene_frames: s.scene_frames,
                    degradation: s.scene_degradation,
                    procedure_id: s.procedure_id,
                };
                let _ = writeln!(
                    csv,
                    "{:.1},{:.3},{},{:.3},{},{},{:.6},{},{}",
                    row.wall_s,
                    row.rss as f64 / 1048576.0,
                    row.ticks,
                    row.sim_time_s,
                    row.misses,
                    row.tick_rate_hz,
                    row.deficit_m3 * 1e6,
                    row.scene_frames,
                    row.degradation
                );
                let _ = csv.flush();
                rows.push(row);
            }
        }
        if daemon.try_wait().ok().flatten().is_some() {
            eprintln!("hm-soak: hydrometrad ended early; see {}", log.display());
            std::process::exit(1);
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let final_status = reader.drain().last().copied().or(last_status);
    // SAFETY: kill(2) on our own child.
    unsafe { libc::kill(pid as i32, libc::SIGTERM) };
    let _ = daemon.wait();
    std::process::exit(judge(&args, &rows, final_status, &record));
}

fn judge(args: &Args, rows: &[Row], status: Option<hydrometra_ipc::Status>, record: &Path) -> i32 {
    let mut failures = Vec::new();
    // Memory: the slope after the first hour (caches, the atlas, the particle arrays settle).
    let settled: Vec<(f64, f64)> = rows
        .iter()
        .filter(|r| r.wall_s >= 3600.0_f64.min(args.hours * 3600.0 / 4.0))
        .map(|r| (r.wall_s / 3600.0, r.rss as f64 / 1048576.0))
        .collect();
    let growth = slope(&settled);
    if growth > args.max_growth_mib_per_h {
        failures.push(format!(
            "resident memory grows {growth:.3} MiB/h (limit {})",
            args.max_growth_mib_per_h
        ));
    }
    // The loop's clock against the wall clock, per hour (or per quarter of a shorter run): sim
    // time covers skipped periods (counted as misses), so it drifts only if the loop does.
    let window_s = 3600.0_f64.min(args.hours * 3600.0 / 4.0);
    let mut rates = Vec::new();
    let mut from = 0;
    for (i, r) in rows.iter().enumerate() {
        if r.wall_s - rows[from].wall_s >= window_s {
            let a = &rows[from];
            let clock = (r.sim_time_s - a.sim_time_s) / (r.wall_s - a.wall_s);
            let ticks_hz = (r.ticks - a.ticks) as f64 / (r.wall_s - a.wall_s);
            rates.push(serde_json::json!({
                "from_s": a.wall_s, "to_s": r.wall_s,
                "sim_over_wall": clock, "ticks_hz": ticks_hz,
            }));
            if (clock - 1.0).abs() > args.max_rate_drift {
                failures.push(format!(
                    "the loop's clock ran at {clock:.6} of the wall clock over [{:.0}, {:.0}] s",
                    a.wall_s, r.wall_s
                ));
            }
            from = i;
        }
    }
    // The deficit: accumulated against its definition, and what status showed.
    let (deficit_m3, balance_m3, fluid_in_m3) = match ProcedureRecord::load(record) {
        Ok(Some(r)) => (
            r.deficit.deficit_m3,
            r.totals.inflow_m3
                - r.totals.collected_m3()
                - (r.cavity_volume_m3 - r.initial_cavity_volume_m3),
            r.totals.inflow_m3,
        ),
        other => {
            failures.push(format!(
                "no procedure record at {}: {other:?}",
                record.display()
            ));
            (f64::NAN, f64::NAN, f64::NAN)
        }
    };
    // NaN (no record) fails as well.
    let deficit_error_m3 = (deficit_m3 - balance_m3).abs();
    if deficit_error_m3.is_nan() || deficit_error_m3 > 1e-9 * fluid_in_m3.max(1e-6) {
        failures.push(format!(
            "deficit {deficit_m3:e} m^3 against its balance {balance_m3:e} m^3"
        ));
    }
    // Status ends a few ticks before the record (written at shutdown): a procedure of its own
    // would show a different deficit.
    if let Some(s) = status {
        if s.deficit_m3 > deficit_m3 + 1e-12 {
            failures.push(format!(
                "status showed a deficit of {:e} m^3, more than the record's {deficit_m3:e}",
                s.deficit_m3
            ));
        }
    }
    let procedures: std::collections::BTreeSet<u64> = rows.iter().map(|r| r.procedure_id).collect();
    if procedures.len() > 1 {
        failures.push(format!(
            "the procedure changed during the soak: {procedures:?}"
        ));
    }
    let first = rows.first();
    let last = rows.last();
    let summary = serde_json::json!({
        "hours": args.hours,
        "scene": args.scene,
        "scenario": args.scenario,
        "samples": rows.len(),
        "rss_mib_first": first.map(|r| r.rss as f64 / 1048576.0),
        "rss_mib_last": last.map(|r| r.rss as f64 / 1048576.0),
        "rss_growth_mib_per_h": growth,
        "clock_per_window": rates,
        "deadline_misses": last.map(|r| r.misses),
        "ticks": last.map(|r| r.ticks),
        "scene_frames": last.map(|r| r.scene_frames),
        "degradation_last": last.map(|r| r.degradation),
        "deficit_ml": deficit_m3 * 1e6,
        "deficit_balance_ml": balance_m3 * 1e6,
        "fluid_in_ml": fluid_in_m3 * 1e6,
        "failures": failures,
    });
    let text = serde_json::to_string_pretty(&summary).unwrap_or_default();
    println!("{text}");
    let _ = std::fs::write(args.out.join("soak.json"), text);
    i32::from(!failures.is_empty())
}
