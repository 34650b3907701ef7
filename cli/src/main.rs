//! `hydrometra`: the engineer's CLI (anatomy, precompute, rig tools, fluid cases, benchmarks).

mod anatomy;
mod control;
mod converge;
mod fem;
mod fluid;
mod hydraulics;
mod monitor;
mod precompute;
mod procedure;
mod record;
mod rig;
mod scenario;
mod scene;
mod scene_setup;

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
    Control(control::ControlCommand),
    /// Serve the instructor's live web page of one or several rigs (docs/station.md).
    Station(hydrometra_station::StationArgs),
    /// Show hydrometrad's live status (link, inputs, alarms, timing) in the terminal.
    Monitor(monitor::MonitorArgs),
    /// Hydraulic model tools (offline simulation of a scenario).
    #[command(subcommand)]
    Hydraulics(hydraulics::HydraulicsCommand),
    /// The procedure's fluid deficit record: show it, or start a new procedure.
    #[command(subcommand)]
    Procedure(procedure::ProcedureCommand),
    /// Rig tools: emulate the rig on a pseudo-terminal, probe a rig.
    #[command(subcommand)]
    Rig(rig::RigCommand),
    /// Procedure recordings: summarise one.
    #[command(subcommand)]
    Record(record::RecordCommand),
    /// Debrief a recorded procedure: fluid-handling metrics (metrics.json) and a report with plots.
    Debrief(record::DebriefArgs),
    /// Fluid solver: run case files, benchmark, soak.
    #[command(subcommand)]
    Fluid(fluid::FluidCommand),
    /// Generate a parametric uterus mesh (VTU, JSON summary, mesh JSON).
    Anatomy(anatomy::AnatomyArgs),
    /// Run the FEM pressure sweep of an anatomy and write the deformation atlas, VTU/PVD series
    /// and P-V curve.
    Precompute(precompute::PrecomputeArgs),
    /// The coupled scene: print the default, prepare its atlas, run it offline, benchmark it.
    #[command(subcommand)]
    Scene(scene::SceneCommand),
    /// FEM verification cases (thick sphere).
    #[command(subcommand)]
    Fem(fem::FemCommand),
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
        Command::Control(cmd) => control::run(cmd),
        Command::Station(args) => Ok(hydrometra_station::run(args)?),
        Command::Monitor(args) => monitor::run(&args),
        Command::Hydraulics(command) => hydraulics::run(command),
        Command::Procedure(command) => procedure::run(command),
        Command::Rig(cmd) => rig::run(cmd),
        Command::Record(cmd) => record::run(cmd),
        Command::Debrief(args) => record::debrief(&args),
        Command::Fluid(cmd) => fluid::run(cmd),
        Command::Anatomy(args) => anatomy::run(&args),
        Command::Precompute(args) => precompute::run(&args),
        Command::Fem(cmd) => fem::run(&cmd),
        Command::Scene(cmd) => scene::run(cmd),
    }
}
