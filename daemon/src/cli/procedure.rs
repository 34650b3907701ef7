//! `hydrometra procedure ...`: inspect the persisted procedure and start a new one.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use hydrometra_sim::hydraulics::ProcedureRecord;

use crate::service::config::Config;
use crate::service::hydraulics::reset_request_path;

/// Procedure commands.
#[derive(Subcommand, Debug)]
pub enum ProcedureCommand {
    /// Print the saved procedure (deficit, volumes, alarms) as JSON.
    Show(RecordArgs),
    /// Start a new procedure: the running hydrometrad resets the deficit within its save interval
    /// (or at its next start, if it is not running).
    Reset(RecordArgs),
}

/// Where the procedure record is.
#[derive(Args, Debug)]
pub struct RecordArgs {
    /// The procedure record file.
    #[arg(long, value_name = "PATH", conflicts_with = "config")]
    pub record: Option<PathBuf>,
    /// Take the record path from this hydrometrad config file (`[hydraulics] record` or
    /// `[paths] state_dir`).
    #[arg(long, value_name = "PATH")]
    pub config: Option<PathBuf>,
}

impl RecordArgs {
    fn path(&self) -> Result<PathBuf> {
        if let Some(r) = &self.record {
            return Ok(r.clone());
        }
        let config = match &self.config {
            Some(path) => Config::load(path)?,
            None => Config::default(),
        };
        config
            .hydraulics
            .record_path(&config.paths)
            .context("no procedure record: give --record PATH or a --config with [hydraulics] record or [paths] state_dir")
    }
}

/// Runs a `procedure` subcommand.
pub fn run(command: ProcedureCommand) -> Result<()> {
    match command {
        ProcedureCommand::Show(args) => {
            let path = args.path()?;
            match ProcedureRecord::load(&path)? {
                Some(r) => println!("{}", serde_json::to_string_pretty(&r)?),
                None => println!("no procedure saved at {}", path.display()),
            }
            Ok(())
        }
        ProcedureCommand::Reset(args) => {
            let path = args.path()?;
            let request = reset_request_path(&path);
            std::fs::write(&request, b"new procedure requested\n")
                .with_context(|| format!("writing the reset request {}", request.display()))?;
            println!(
                "requested a new procedure ({}); hydrometrad applies it within its save interval",
                request.display()
            );
            Ok(())
        }
    }
}
