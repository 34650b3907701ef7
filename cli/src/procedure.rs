//! `hydrometra procedure ...`: inspect the persisted procedure and start a new one.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use hydrometra_sim::hydraulics::{record_path, reset_request_path, ProcedureRecord};
use serde::Deserialize;

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
        let keys = match &self.config {
            Some(path) => RecordKeys::load(path)?,
            None => RecordKeys::default(),
        };
        record_path(keys.hydraulics.record.as_deref(), keys.paths.state_dir.as_deref())
            .context("no procedure record: give --record PATH or a --config with [hydraulics] record or [paths] state_dir")
    }
}

/// The two keys of hydrometrad's configuration that locate the procedure record; every other
/// table and key is hydrometrad's business (it validates the whole file when it starts).
#[derive(Debug, Default, Deserialize)]
struct RecordKeys {
    #[serde(default)]
    hydraulics: HydraulicsKeys,
    #[serde(default)]
    paths: PathsKeys,
}

#[derive(Debug, Default, Deserialize)]
struct HydraulicsKeys {
    record: Option<PathBuf>,
}

#[derive(Debug, Default, Deserialize)]
struct PathsKeys {
    state_dir: Option<PathBuf>,
}

impl RecordKeys {
    fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("config {}: cannot read", path.display()))?;
        toml::from_str(&text).with_context(|| format!("config {}", path.display()))
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

#[cfg(test)]
mod tests {
    use super::*;

    fn located(toml_text: &str) -> Option<PathBuf> {
        let keys: RecordKeys = toml::from_str(toml_text).expect("parses");
        record_path(
            keys.hydraulics.record.as_deref(),
            keys.paths.state_dir.as_deref(),
        )
    }

    #[test]
    fn the_record_is_found_where_hydrometrad_keeps_it() {
        assert_eq!(
            located("[paths]\nstate_dir = \"/var/lib/hm\"\n[loop]\ntick_rate_hz = 1000.0\n"),
            Some(PathBuf::from("/var/lib/hm/procedure.rec"))
        );
        assert_eq!(
            located(
                "[paths]\nstate_dir = \"/var/lib/hm\"\n[hydraulics]\nrecord = \"/tmp/p.rec\"\n"
            ),
            Some(PathBuf::from("/tmp/p.rec"))
        );
        // hydrometrad's shipped default configuration reads, and persists nothing.
        let default = std::fs::read_to_string(
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../daemon/src/service/default-config.toml"),
        )
        .expect("the daemon's default configuration");
        assert_eq!(located(&default), None);
    }

    #[test]
    fn a_record_key_of_the_wrong_type_is_named() {
        let dir = std::env::temp_dir().join(format!("hm-cli-procedure-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        let config = dir.join("bad.toml");
        std::fs::write(&config, "[hydraulics]\nrecord = 5\n").expect("write");
        let args = RecordArgs {
            record: None,
            config: Some(config.clone()),
        };
        let e = format!("{:#}", args.path().unwrap_err());
        assert!(e.contains("bad.toml") && e.contains("record"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
