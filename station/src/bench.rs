//! `hydrometra station bench`: rig sample -> page latency (the page acknowledges every status it
//! shows), the daemon's deadline misses and status latency with a station and a page attached and
//! without (interleaved runs, each on a fresh `hydrometrad --emulated default`), and the station's
//! own CPU use. Timing figures are only meaningful on a quiet machine.

use std::io::{BufRead, BufReader, Read, Write};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use clap::Args;
use hydrometra_ipc::status::scene_state;
use hydrometra_ipc::{status, ServiceNames, Status};
use iceoryx2::prelude::*;
use serde_json::{json, Value};

use crate::browser::{Chromium, DEFAULT_CHROMIUM};
use crate::error::StationError;

/// `hydrometra station bench` flags.
#[derive(Args, Debug, Clone)]
pub struct BenchArgs {
    /// Pairs of runs, one with a station and a page and one without, in alternating order.
    #[arg(long, value_name = "N", default_value_t = 3)]
    pub pairs: usize,
    /// Seconds measured per run, once the daemon's scene runs.
    #[arg(long, value_name = "SECS", default_value_t = 30.0)]
    pub seconds: f64,
    /// The Chromium binary.
    #[arg(long, value_name = "PATH", default_value = DEFAULT_CHROMIUM)]
    pub chromium: PathBuf,
    /// The daemon's scene.
    #[arg(long, value_name = "NAME|FILE", default_value = "default")]
    pub scene: String,
    /// The daemon's atlas cache (a prepared scene starts in seconds).
    #[arg(long, value_name = "DIR")]
    pub atlas_cache_dir: Option<PathBuf>,
    /// Print one JSON object per run and a summary object instead of a table.
    #[arg(long)]
    pub json: bool,
}

fn fail(e: impl std::fmt::Display) -> StationError {
    StationError::Bench(e.to_string())
}

/// A child process stopped with SIGINT (then killed) on drop.
struct Proc(Child);

impl Drop for Proc {
    fn drop(&mut self) {
        // SAFETY: kill(2) on our own child.
        unsafe { libc::kill(self.0.id() as i32, libc::SIGINT) };
        let deadline = Instant::now() + Duration::from_secs(5);
        while Instant::now() < deadline {
            if let Ok(Some(_)) = self.0.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// A binary next to this one (`hydrometrad` beside `hydrometra`).
fn sibling(name: &str) -> Result<PathBuf, StationError> {
    let exe = std::env::current_exe().map_err(fail)?;
    let path = exe
        .parent()
        .map(|d| d.join(name))
        .ok_or_else(|| fail("no directory of the current executable"))?;
    if path.is_file() {
        Ok(path)
    } else {
        Err(fail(format!(
            "{} not found: build it (cargo build --release --bins)",
            path.display()
        )))
    }
}

/// CPU time (user + system) of process `pid`, s.
fn cpu_s(pid: u32) -> Option<f64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    // Fields 14 and 15 of proc(5), counted from after the command name (field 3 is index 0).
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    // SAFETY: sysconf has no preconditions.
    let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) } as f64;
    Some(ticks / hz)
}

/// One HTTP/1.0 request to the station; the JSON body of its answer.
fn http(addr: &str, method: &str, path: &str, token: &str) -> Result<Value, StationError> {
    let mut s = std::net::TcpStream::connect(addr).map_err(fail)?;
    s.set_read_timeout(Some(Duration::from_secs(10)))
        .map_err(fail)?;
    write!(
        s,
        "{method} {path} HTTP/1.0\r\nHost: {addr}\r\nAuthorization: Bearer {token}\r\n\
         Content-Length: 0\r\n\r\n"
    )
    .map_err(fail)?;
    let mut text = String::new();
    s.read_to_string(&mut text).map_err(fail)?;
    let body = text
        .split_once("\r\n\r\n")
        .map(|(_, b)| b)
        .ok_or_else(|| fail(format!("{path}: no HTTP body")))?;
    serde_json::from_str(body).map_err(|e| fail(format!("{path}: {e}: {body}")))
}

/// What one run measured.
#[derive(Debug, Clone, Default)]
struct RunResult {
    with_station: bool,
    ticks: u64,
    deadline_misses: u64,
    status_latency_p99_s: f64,
    longest_status_gap_s: f64,
    page_latency: Option<Value>,
    station_cpu_percent: Option<f64>,
}

impl RunResult {
    fn json(&self) -> Value {
        json!({
            "with_station": self.with_station,
            "ticks": self.ticks,
            "deadline_misses": self.deadline_misses,
            "deadline_miss_percent": 100.0 * self.deadline_misses as f64 / self.ticks.max(1) as f64,
            "status_latency_p99_ms": self.status_latency_p99_s * 1e3,
            "longest_status_gap_ms": self.longest_status_gap_s * 1e3,
            "page_latency": self.page_latency,
            "station_cpu_percent_of_one_core": self.station_cpu_percent,
        })
    }
}

/// Runs the benchmark.
pub fn run(args: &BenchArgs) -> Result<(), StationError> {
    if args.pairs == 0 || !(args.seconds.is_finite() && args.seconds > 0.0) {
        return Err(StationError::Usage(
            "--pairs and --seconds must be positive".into(),
        ));
    }
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(fail)?;
    let mut results = Vec::new();
    for pair in 0..args.pairs {
        // Alternate which goes first, so drift in the machine's load hits both alike.
        let order = if pair % 2 == 0 {
            [false, true]
        } else {
            [true, false]
        };
        for with in order {
            let r = one_run(args, &runtime, results.len(), with)?;
            if args.json {
                println!("{}", r.json());
            } else {
                eprintln!("run {}: {}", results.len(), r.json());
            }
            results.push(r);
        }
    }
    let summary = summarize(&results);
    if args.json {
        println!("{summary}");
    } else {
        print_table(&results, &summary);
    }
    Ok(())
}

fn summarize(results: &[RunResult]) -> Value {
    let side = |with: bool| {
        let rs: Vec<_> = results.iter().filter(|r| r.with_station == with).collect();
        let ticks: u64 = rs.iter().map(|r| r.ticks).sum();
        let misses: u64 = rs.iter().map(|r| r.deadline_misses).sum();
        let worst = |f: fn(&RunResult) -> f64| rs.iter().map(|r| f(r)).fold(0.0, f64::max);
        json!({
            "runs": rs.len(),
            "deadline_miss_percent": 100.0 * misses as f64 / ticks.max(1) as f64,
            "worst_status_latency_p99_ms": worst(|r| r.status_latency_p99_s) * 1e3,
            "worst_status_gap_ms": worst(|r| r.longest_status_gap_s) * 1e3,
        })
    };
    let with: Vec<_> = results.iter().filter(|r| r.with_station).collect();
    let worst_page_p99 = with
        .iter()
        .filter_map(|r| r.page_latency.as_ref()?["p99_s"].as_f64())
        .fold(0.0, f64::max);
    let worst_cpu = with
        .iter()
        .filter_map(|r| r.station_cpu_percent)
        .fold(0.0, f64::max);
    json!({
        "summary": true,
        "without_station": side(false),
        "with_station": side(true),
        "worst_page_latency_p99_ms": worst_page_p99 * 1e3,
        "worst_station_cpu_percent_of_one_core": worst_cpu,
    })
}

fn print_table(results: &[RunResult], summary: &Value) {
    println!(
        "{:>3} {:>8} {:>9} {:>8} {:>13} {:>11} {:>12} {:>9}",
        "run", "station", "ticks", "misses", "status p99 ms", "max gap ms", "page p99 ms", "CPU %"
    );
    for (i, r) in results.iter().enumerate() {
        let page = r
            .page_latency
            .as_ref()
            .and_then(|p| p["p99_s"].as_f64())
            .map_or("-".into(), |v| format!("{:.1}", v * 1e3));
        let cpu = r
            .station_cpu_percent
            .map_or("-".into(), |v| format!("{v:.1}"));
        println!(
            "{:>3} {:>8} {:>9} {:>8} {:>13.3} {:>11.2} {:>12} {:>9}",
            i,
            if r.with_station { "yes" } else { "no" },
            r.ticks,
            r.deadline_misses,
            r.status_latency_p99_s * 1e3,
            r.longest_status_gap_s * 1e3,
            page,
            cpu
        );
    }
    println!("{summary:#}");
}

fn one_run(
    args: &BenchArgs,
    runtime: &tokio::runtime::Runtime,
    index: usize,
    with: bool,
) -> Result<RunResult, StationError> {
    let prefix = format!("hydrometra-bench-{}-{index}/v1", std::process::id());
    let mut daemon = Command::new(sibling("hydrometrad")?);
    daemon.args([
        "--emulated",
        "default",
        "--scene",
        &args.scene,
        "--service-prefix",
        &prefix,
        "--no-record",
    ]);
    if let Some(dir) = &args.atlas_cache_dir {
        daemon.arg("--atlas-cache-dir").arg(dir);
    }
    let _daemon = Proc(
        daemon
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .map_err(fail)?,
    );
    let names = ServiceNames::new(&prefix).map_err(fail)?;
    let node = NodeBuilder::new()
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .map_err(|e| fail(format!("{e:?}")))?;
    let deadline = Instant::now() + Duration::from_secs(900);
    let service = loop {
        match status::open(&node, &names) {
            Ok(s) => break s,
            Err(_) if Instant::now() < deadline => std::thread::sleep(Duration::from_millis(50)),
            Err(e) => return Err(fail(format!("hydrometrad never published status: {e:?}"))),
        }
    };
    let sub = service
        .subscriber_builder()
        .create()
        .map_err(|e| fail(format!("{e:?}")))?;
    let drain = || -> Vec<Status> {
        let mut v = Vec::new();
        while let Ok(Some(s)) = sub.receive() {
            v.push(*s);
        }
        v
    };
    // The scene must run (atlas loaded or built) before anything is measured.
    loop {
        if drain()
            .iter()
            .any(|s| matches!(s.scene_state, scene_state::RUNNING | scene_state::IDLE))
        {
            break;
        }
        if Instant::now() > deadline {
            return Err(fail("the daemon's scene never ran"));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let token = crate::auth::generate().map_err(fail)?;
    let mut attached = None;
    if with {
        let mut station = Command::new(std::env::current_exe().map_err(fail)?)
            .args([
                "station",
                "--listen",
                "127.0.0.1:0",
                "--service-prefix",
                &prefix,
                "--token",
                token.reveal(),
            ])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .map_err(fail)?;
        let url = read_url(&mut station)?;
        let station = Proc(station);
        let addr = url
            .trim_start_matches("http://")
            .split('/')
            .next()
            .unwrap_or("")
            .to_string();
        let chromium = runtime.block_on(async {
            let mut c = Chromium::launch(&args.chromium, 1600, 1000).await?;
            c.open(&url).await?;
            c.wait_for(
                "window.hydrometraStation && window.hydrometraStation.statusFrames > 10",
                Duration::from_secs(60),
            )
            .await?;
            Ok::<_, String>(c)
        });
        let chromium = chromium.map_err(fail)?;
        http(&addr, "POST", "/api/stats/reset", token.reveal())?;
        attached = Some((station, chromium, addr));
    }
    let _ = drain();
    let cpu0 = attached.as_ref().and_then(|(p, _, _)| cpu_s(p.0.id()));
    let start = Instant::now();
    let mut first: Option<Status> = None;
    let mut last: Option<Status> = None;
    let mut longest_gap_ns = 0u64;
    while start.elapsed().as_secs_f64() < args.seconds {
        for s in drain() {
            if let Some(l) = &last {
                longest_gap_ns =
                    longest_gap_ns.max(s.publish_monotonic_ns - l.publish_monotonic_ns);
            }
            first.get_or_insert(s);
            last = Some(s);
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    let wall = start.elapsed().as_secs_f64();
    let (Some(first), Some(last)) = (first, last) else {
        return Err(fail("no status during the run"));
    };
    let mut r = RunResult {
        with_station: with,
        ticks: last.ticks - first.ticks,
        deadline_misses: last.deadline_misses - first.deadline_misses,
        status_latency_p99_s: last.latency_p99_s,
        longest_status_gap_s: longest_gap_ns as f64 * 1e-9,
        ..Default::default()
    };
    if let Some((station, _chromium, addr)) = &attached {
        let stats = http(addr, "GET", "/api/stats", token.reveal())?;
        r.page_latency = Some(stats["page_latency"].clone());
        if let (Some(c0), Some(c1)) = (cpu0, cpu_s(station.0.id())) {
            r.station_cpu_percent = Some(100.0 * (c1 - c0) / wall);
        }
    }
    Ok(r)
}

/// The URL line `hydrometra station` prints when it serves.
pub fn read_url(child: &mut Child) -> Result<String, StationError> {
    let out = child
        .stdout
        .take()
        .ok_or_else(|| fail("station stdout not piped"))?;
    let mut line = String::new();
    BufReader::new(out).read_line(&mut line).map_err(fail)?;
    line.trim()
        .strip_prefix("station: ")
        .map(str::to_string)
        .ok_or_else(|| fail(format!("station printed {line:?} instead of its URL")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn this_process_has_a_cpu_time() {
        let t = cpu_s(std::process::id()).unwrap();
        assert!((0.0..1e6).contains(&t));
    }
}
