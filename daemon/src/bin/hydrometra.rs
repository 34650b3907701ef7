//! `hydrometra`: the engineer's CLI (anatomy, precompute, rig tools, fluid cases, benchmarks).

use anyhow::Result;
use clap::{Parser, Subcommand};

/// The engineer's CLI for hydrometra.
#[derive(Parser, Debug)]
#[command(name = "hydrometra", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Print the versions of the wire protocol and IPC schema this build speaks.
    Version,
    /// Control a running hydrometrad: new procedure, load a scene, the recorder.
    #[command(subcommand)]
    Control(hydrometra_daemon::cli::control::ControlCommand),
    /// Serve the instructor's live web page of one or several rigs (docs/station.md).
    Station(hydrometra_station::StationArgs),
    /// Show hydrometrad's live status (link, inputs, alarms, timing) in the terminal.
    Monitor(hydrometra_daemon::cli::monitor::MonitorArgs),
    /// Hydraulic model tools (offline simulation of a scenario).
    #[command(subcommand)]
    Hydraulics(hydrometra_daemon::cli::hydraulics::HydraulicsCommand),
    /// The procedure's fluid deficit record: show it, or start a new procedure.
    #[command(subcommand)]
    Procedure(hydrometra_daemon::cli::procedure::ProcedureCommand),
    /// Rig tools: emulate the rig on a pseudo-terminal, probe a rig.
    #[command(subcommand)]
    Rig(hydrometra_daemon::cli::rig::RigCommand),
    /// Procedure recordings: summarise one.
    #[command(subcommand)]
    Record(hydrometra_daemon::cli::record::RecordCommand),
    /// Debrief a recorded procedure: fluid-handling metrics (metrics.json) and a report with plots.
    Debrief(hydrometra_daemon::cli::record::DebriefArgs),
    /// Fluid solver: run case files, benchmark, soak.
    #[command(subcommand)]
    Fluid(hydrometra_daemon::cli::fluid::FluidCommand),
    /// Generate a parametric uterus mesh (VTU, JSON summary, mesh JSON).
    Anatomy(hydrometra_daemon::cli::anatomy::AnatomyArgs),
    /// Run the FEM pressure sweep of an anatomy and write the deformation atlas, VTU/PVD series
    /// and P-V curve.
    Precompute(hydrometra_daemon::cli::precompute::PrecomputeArgs),
    /// The coupled scene: print the default, prepare its atlas, run it offline, benchmark it.
    #[command(subcommand)]
    Scene(hydrometra_daemon::cli::scene::SceneCommand),
    /// FEM verification cases (thick sphere).
    #[command(subcommand)]
    Fem(hydrometra_daemon::cli::fem::FemCommand),
}

fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    match cli.command {
        Command::Version => {
            println!("hydrometra {}", env!("CARGO_PKG_VERSION"));
            Ok(())
        }
        Command::Control(cmd) => hydrometra_daemon::cli::control::run(cmd),
        Command::Station(args) => Ok(hydrometra_station::run(args)?),
        Command::Monitor(args) => hydrometra_daemon::cli::monitor::run(&args),
        Command::Hydraulics(command) => hydrometra_daemon::cli::hydraulics::run(command),
        Command::Procedure(command) => hydrometra_daemon::cli::procedure::run(command),
        Command::Rig(cmd) => hydrometra_daemon::cli::rig::run(cmd),
        Command::Record(cmd) => hydrometra_daemon::cli::record::run(cmd),
        Command::Debrief(args) => hydrometra_daemon::cli::record::debrief(&args),
        Command::Fluid(cmd) => hydrometra_daemon::cli::fluid::run(cmd),
        Command::Anatomy(args) => hydrometra_daemon::cli::anatomy::run(&args),
        Command::Precompute(args) => hydrometra_daemon::cli::precompute::run(&args),
        Command::Fem(cmd) => hydrometra_daemon::cli::fem::run(&cmd),
        Command::Scene(cmd) => hydrometra_daemon::cli::scene::run(cmd),
    }
}
