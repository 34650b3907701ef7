//! `hydrometra station`: the instructor's live web page of one or several hydrometrad rigs
//! (docs/station.md).
//!
//! A pipeline of small stages: sources ([`local`]: a daemon on this machine over iceoryx2) fill
//! each rig's slots in the [`hub`] with [`frame`]s at the page's rates (the flow reduced by
//! [`flow`]); the [`server`] streams the newest frames to every browser over a WebSocket and
//! serves the embedded page, control requests and the [`recordings`]' debriefs, guarded by the
//! [`auth`] token.

#![warn(missing_docs)]

pub mod auth;
pub mod bench;
pub mod browser;
pub mod classroom;
pub mod feed;
pub mod flow;
pub mod frame;
pub mod hub;
pub mod layout;
pub mod local;
pub mod recordings;
pub mod server;

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use clap::{Args, Subcommand};
use hydrometra_ipc::ServiceNames;

/// Default address: loopback only.
pub const DEFAULT_LISTEN: &str = "127.0.0.1:8737";

/// `hydrometra station`: serve the page, or benchmark it.
#[derive(Args, Debug, Clone)]
#[command(args_conflicts_with_subcommands = true)]
pub struct StationArgs {
    /// `bench`: measure the station (see docs/station.md, "Benchmark").
    #[command(subcommand)]
    pub command: Option<StationCommand>,
    /// Serving the page.
    #[command(flatten)]
    pub serve: ServeArgs,
}

/// Subcommands of `hydrometra station`.
#[derive(Subcommand, Debug, Clone)]
pub enum StationCommand {
    /// Measure rig sample -> page latency, the daemon's figures with and without a station, and
    /// the station's CPU use (starts its own daemons, stations and headless Chromium).
    Bench(bench::BenchArgs),
}

/// How the station serves: where it listens, which rigs it shows, at which rates.
#[derive(Args, Debug, Clone)]
pub struct ServeArgs {
    /// Address to listen on. Any other than loopback needs a token.
    #[arg(long, value_name = "ADDR:PORT", default_value = DEFAULT_LISTEN)]
    pub listen: SocketAddr,
    /// Show the hydrometrad on this machine with this iceoryx2 service prefix (repeat for
    /// several daemons). Default: "hydrometra/v1", unless --zenoh is given.
    #[arg(long, value_name = "PREFIX")]
    pub service_prefix: Vec<String>,
    /// The access token (control always needs it; viewing needs it off loopback). Prefer
    /// --token-file or the HYDROMETRA_STATION_TOKEN variable: a flag is visible to other users.
    #[arg(long, value_name = "TOKEN")]
    pub token: Option<String>,
    /// Read the token from the first line of this file.
    #[arg(long, value_name = "PATH", conflicts_with = "token")]
    pub token_file: Option<PathBuf>,
    /// The recordings directory of the local daemon (default: the directory of the daemon's
    /// open or last recording, asked over its control service).
    #[arg(long, value_name = "DIR")]
    pub recordings_dir: Option<PathBuf>,
    /// Rates and sizes of what the page is sent.
    #[command(flatten)]
    pub rates: Rates,
    /// Rigs over zenoh (the classroom).
    #[command(flatten)]
    pub zenoh: classroom::ZenohArgs,
    /// Seconds of plot history kept per rig (a page opened later starts with it).
    #[arg(long, value_name = "SECS", default_value_t = 600.0)]
    pub history_s: f64,
}

/// Rates and sizes of the frames sent to the page.
#[derive(Args, Debug, Clone, Copy)]
pub struct Rates {
    /// Status frames per second, per rig.
    #[arg(long, value_name = "HZ", default_value_t = 30.0)]
    pub status_hz: f64,
    /// Cavity positions and particle frames per second, per rig (at most the scene's rate).
    #[arg(long, value_name = "HZ", default_value_t = 30.0)]
    pub scene_hz: f64,
    /// Flow frames per second, per rig.
    #[arg(long, value_name = "HZ", default_value_t = 10.0)]
    pub flow_hz: f64,
    /// Flow arrows at most (the field is averaged over blocks of cells to fit).
    #[arg(long, value_name = "N", default_value_t = 3000)]
    pub max_arrows: usize,
    /// Particles at most per frame (an evenly spaced subset of more).
    #[arg(long, value_name = "N", default_value_t = 4096)]
    pub max_particles: usize,
}

impl Default for Rates {
    fn default() -> Self {
        Self {
            status_hz: 30.0,
            scene_hz: 30.0,
            flow_hz: 10.0,
            max_arrows: 3000,
            max_particles: 4096,
        }
    }
}

/// Why the station could not start or stopped.
#[derive(Debug, thiserror::Error)]
pub enum StationError {
    /// A flag is wrong.
    #[error("{0}")]
    Usage(String),
    /// The token.
    #[error(transparent)]
    Token(#[from] auth::TokenError),
    /// I/O (binding the address, starting threads).
    #[error("{context}: {source}")]
    Io {
        /// What was being done.
        context: String,
        /// The error.
        source: std::io::Error,
    },
    /// The benchmark failed.
    #[error("bench: {0}")]
    Bench(String),
}

fn io(context: impl Into<String>) -> impl FnOnce(std::io::Error) -> StationError {
    let context = context.into();
    move |source| StationError::Io { context, source }
}

/// Host `CLOCK_MONOTONIC`, ns (the clock of status `publish_monotonic_ns`).
pub fn monotonic_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes the struct we pass; CLOCK_MONOTONIC always exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// CPU time (user + system) this process used so far, s.
pub fn process_cpu_s() -> f64 {
    // SAFETY: getrusage fills the zeroed struct we pass.
    let mut u: libc::rusage = unsafe { core::mem::zeroed() };
    unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut u) };
    let tv = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    tv(u.ru_utime) + tv(u.ru_stime)
}

/// Runs `hydrometra station` (until SIGINT/SIGTERM) or its benchmark.
pub fn run(args: StationArgs) -> Result<(), StationError> {
    match args.command {
        Some(StationCommand::Bench(b)) => bench::run(&b),
        None => serve(args.serve),
    }
}

/// Serves the page until SIGINT or SIGTERM.
pub fn serve(args: ServeArgs) -> Result<(), StationError> {
    if !(args.history_s.is_finite() && args.history_s > 0.0) {
        return Err(StationError::Usage(format!(
            "--history-s {}: expected a positive number of seconds",
            args.history_s
        )));
    }
    for (flag, hz) in [
        ("--status-hz", args.rates.status_hz),
        ("--scene-hz", args.rates.scene_hz),
        ("--flow-hz", args.rates.flow_hz),
    ] {
        if !(hz.is_finite() && (0.1..=1000.0).contains(&hz)) {
            return Err(StationError::Usage(format!(
                "{flag} {hz}: expected 0.1 to 1000 per second"
            )));
        }
    }
    let loopback = args.listen.ip().is_loopback();
    let given = auth::configured(
        args.token.as_deref(),
        args.token_file.as_deref(),
        std::env::var(auth::TOKEN_ENV).ok(),
    )?;
    let token = match given {
        Some(t) => t,
        None if loopback => auth::generate().map_err(io("generating a token"))?,
        None => return Err(auth::TokenError::Missing(args.listen.to_string()).into()),
    };
    let hub = hub::Hub::new(args.history_s);
    let state = server::AppState::new(hub.clone(), token.clone(), loopback);
    let stop = Arc::new(AtomicBool::new(false));
    let prefixes = if args.service_prefix.is_empty() && !args.zenoh.zenoh {
        vec![hydrometra_ipc::DEFAULT_SERVICE_PREFIX.to_string()]
    } else {
        args.service_prefix.clone()
    };
    let mut threads = Vec::new();
    for prefix in &prefixes {
        let names = ServiceNames::new(prefix)
            .map_err(|e| StationError::Usage(format!("--service-prefix: {e}")))?;
        let rig = hub.add_rig(
            names.prefix().to_string(),
            format!("iceoryx2 {}", names.prefix()),
            true,
            true,
        );
        let (jobs_tx, jobs_rx) = std::sync::mpsc::channel::<local::ControlJob>();
        threads
            .push(local::spawn_control(names.clone(), jobs_rx).map_err(io("starting a thread"))?);
        threads.push(
            local::spawn_source(names, rig.clone(), args.rates, stop.clone())
                .map_err(io("starting a thread"))?,
        );
        let jobs = std::sync::Mutex::new(jobs_tx);
        let route: server::ControlRoute = Arc::new(move |command, argument| {
            let (reply, rx) = tokio::sync::oneshot::channel();
            let job = local::ControlJob {
                command,
                argument,
                reply,
            };
            // A stopped control thread drops the job; the caller sees the route stop.
            let _ = jobs.lock().unwrap_or_else(|p| p.into_inner()).send(job);
            rx
        });
        let recordings = match (&args.recordings_dir, prefixes.len()) {
            (Some(dir), 1) => server::RecordingsDir::Fixed(dir.clone()),
            _ => server::RecordingsDir::FromDaemon,
        };
        state.set_backend(
            rig.info.index,
            server::Backend {
                control: Some(route),
                recordings: Some(recordings),
            },
        );
    }
    let _classroom = if args.zenoh.zenoh {
        Some(classroom::start(
            &args.zenoh,
            hub.clone(),
            state.clone(),
            args.rates,
        )?)
    } else {
        None
    };
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name("station-io")
        .enable_all()
        .build()
        .map_err(io("starting the runtime"))?;
    let result = runtime.block_on(async {
        let listener = server::bind(args.listen)
            .await
            .map_err(io(format!("--listen {}", args.listen)))?;
        let addr = listener.local_addr().map_err(io("local address"))?;
        // The one line a script or test reads: where the page is (the fragment never reaches a
        // server or a log).
        println!("station: http://{addr}/#token={}", token.reveal());
        tracing::info!(%addr, local_rigs = prefixes.len(), zenoh = args.zenoh.zenoh, "station serving");
        // Open WebSockets never end by themselves: stop serving at the signal, not after them.
        tokio::select! {
            r = axum::serve(listener, server::router(state)) => r.map_err(io("serving")),
            _ = shutdown_signal() => Ok(()),
        }
    });
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    result
}

async fn shutdown_signal() {
    use tokio::signal::unix::{signal, SignalKind};
    match (
        signal(SignalKind::interrupt()),
        signal(SignalKind::terminate()),
    ) {
        (Ok(mut i), Ok(mut t)) => {
            tokio::select! {
                _ = i.recv() => {}
                _ = t.recv() => {}
            }
        }
        _ => std::future::pending::<()>().await,
    }
    tracing::info!("station stopping");
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(subcommand)]
        command: Top,
    }

    #[derive(clap::Subcommand)]
    enum Top {
        Station(StationArgs),
    }

    fn parse(args: &[&str]) -> StationArgs {
        let Top::Station(s) = Cli::try_parse_from(args).unwrap().command;
        s
    }

    #[test]
    fn the_default_address_is_loopback_only() {
        let s = parse(&["hydrometra", "station"]);
        assert!(s.command.is_none());
        assert_eq!(s.serve.listen, DEFAULT_LISTEN.parse().unwrap());
        assert!(s.serve.listen.ip().is_loopback());
        let b = parse(&["hydrometra", "station", "bench", "--pairs", "2"]);
        assert!(matches!(b.command, Some(StationCommand::Bench(ref a)) if a.pairs == 2));
    }
}
