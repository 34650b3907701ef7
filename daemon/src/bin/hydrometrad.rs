//! `hydrometrad`: the real-time hydrometra simulation service.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::Context;
use clap::Parser;
use hydrometra_daemon::service::{self, config};

/// The hydrometra simulation daemon: reads the rig, runs the simulation at a fixed rate and
/// publishes status, cavity mesh, flow field and particles over iceoryx2 shared memory.
///
/// Flags override the configuration file. Stop with SIGINT or SIGTERM; shared memory is released.
#[derive(Parser, Debug)]
#[command(name = "hydrometrad", version, about, long_about = None)]
struct Args {
    /// Configuration file (TOML); the built-in defaults when omitted.
    #[arg(long, value_name = "PATH")]
    config: Option<PathBuf>,
    /// Read the rig on this serial device (overrides `rig.mode`/`rig.device`).
    #[arg(long, value_name = "PATH")]
    device: Option<PathBuf>,
    /// Run an emulated rig in-process on a pseudo-terminal, playing SCENARIO (a built-in name such
    /// as "default", or a scenario file).
    #[arg(long, value_name = "SCENARIO")]
    emulated: Option<String>,
    /// Prefix of the iceoryx2 service names (default "hydrometra/v1").
    #[arg(long, value_name = "PREFIX")]
    service_prefix: Option<String>,
    /// Simulation tick rate, Hz (overrides `loop.tick_rate_hz`).
    #[arg(long, value_name = "HZ")]
    tick_rate_hz: Option<f64>,
    /// Status publication rate, Hz; must divide the tick rate (overrides `loop.status_rate_hz`).
    #[arg(long, value_name = "HZ")]
    status_rate_hz: Option<f64>,
    /// Stop cleanly after this many seconds (for tests and benchmarks).
    #[arg(long, value_name = "SECS")]
    duration: Option<f64>,
    /// The procedure record (fluid deficit that survives restarts); overrides `[hydraulics] record`.
    #[arg(long, value_name = "PATH")]
    procedure_record: Option<std::path::PathBuf>,
    /// Start a new procedure (deficit 0) instead of restoring the saved one.
    #[arg(long)]
    new_procedure: bool,
    /// Play a recording's rig bytes as a live device (pseudo-terminal, the normal link) and
    /// re-run the recorded procedure with the recorded configuration (docs/recording.md).
    #[arg(long, value_name = "FILE")]
    replay: Option<PathBuf>,
    /// Speed of --replay, times real time (1 reproduces the recorded procedure).
    #[arg(long, value_name = "X")]
    replay_speed: Option<f64>,
    /// Record procedures into DIR (overrides `[record] dir`; turns recording on).
    #[arg(long, value_name = "DIR")]
    record_dir: Option<PathBuf>,
    /// Record nothing (overrides `[record] enabled`).
    #[arg(long, conflicts_with = "record_dir")]
    no_record: bool,
    /// The scene: a built-in name ("default", "myoma-figo1", "bleed") or a scene file (overrides
    /// `[scene] scene`).
    #[arg(long, value_name = "NAME|FILE")]
    scene: Option<String>,
    /// Run no scene: status and hydraulics only (overrides `[scene] enabled`).
    #[arg(long, conflicts_with = "scene")]
    no_scene: bool,
    /// Scene frames per second (overrides `[scene] rate_hz`).
    #[arg(long, value_name = "HZ")]
    scene_rate_hz: Option<f64>,
    /// Where built atlases are cached (overrides `[scene] atlas_cache_dir`).
    #[arg(long, value_name = "DIR")]
    atlas_cache_dir: Option<PathBuf>,
    /// Print the default configuration (commented TOML) and exit.
    #[arg(long)]
    print_default_config: bool,
}

fn main() -> anyhow::Result<()> {
    // The real-time threads (rig I/O, simulation loop, publisher) log too: they only queue the
    // line; a worker thread writes it to stderr, so a slow journal or terminal never stalls a
    // tick. The queue drops lines when full rather than block. The guard flushes it on return.
    let (log_writer, _log_flush) = tracing_appender::non_blocking(std::io::stderr());
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .with_writer(log_writer)
        .init();
    // iceoryx2 logs through tracing; its start-up notes ("no config file loaded") are noise for
    // an operator. IOX2_LOG_LEVEL raises it for debugging.
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);
    let args = Args::parse();
    if args.print_default_config {
        print!("{}", config::DEFAULT_CONFIG_TOML);
        return Ok(());
    }
    let mut config = match &args.config {
        Some(path) => config::Config::load(path)?,
        None => config::Config::default(),
    };
    config.apply(&config::Overrides {
        device: args.device,
        emulated: args.emulated,
        service_prefix: args.service_prefix,
        tick_rate_hz: args.tick_rate_hz,
        status_rate_hz: args.status_rate_hz,
        procedure_record: args.procedure_record,
        new_procedure: args.new_procedure,
        replay: args.replay,
        replay_speed: args.replay_speed,
        record_dir: args.record_dir,
        no_record: args.no_record,
        scene: args.scene,
        no_scene: args.no_scene,
        scene_rate_hz: args.scene_rate_hz,
        atlas_cache_dir: args.atlas_cache_dir,
    })?;
    let duration = match args.duration {
        Some(s) if s.is_finite() && s > 0.0 => Some(Duration::from_secs_f64(s)),
        Some(s) => anyhow::bail!("--duration {s}: expected a positive number of seconds"),
        None => None,
    };
    service::run(&config, duration).context("hydrometrad failed")?;
    Ok(())
}
