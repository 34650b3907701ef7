//! `hydrometra control ...`: requests to a running hydrometrad over its control service
//! (`<prefix>/control`, docs/ipc.md "Control").

use std::time::Duration;

use anyhow::{bail, Result};
use clap::{Args, Subcommand};
use hydrometra_ipc::control::{self, command, result, ControlResponse};
use hydrometra_ipc::{ServiceNames, DEFAULT_SERVICE_PREFIX};
use iceoryx2::prelude::*;

/// Control commands.
#[derive(Subcommand, Debug)]
pub enum ControlCommand {
    /// Start a new procedure: the fluid deficit and its alarms reset (deliberately: the ended
    /// procedure's deficit is logged and recorded), the recording rotates to a new file.
    NewProcedure(ClientArgs),
    /// Switch the running daemon to another scene: a built-in name ("default", "myoma-figo1", "bleed") or a
    /// scene file. The atlas is prepared in the background (status `scene_state` preparing).
    LoadScene {
        /// Built-in name or scene file.
        #[arg(value_name = "NAME|FILE")]
        scene: String,
        #[command(flatten)]
        client: ClientArgs,
    },
    /// The recorder: start or stop recording, or show what it does.
    #[command(subcommand)]
    Record(RecordControl),
}

/// `hydrometra control record ...`.
#[derive(Subcommand, Debug)]
pub enum RecordControl {
    /// Start recording (a new file) if not recording.
    Start(ClientArgs),
    /// Finish the open file and stop recording.
    Stop(ClientArgs),
    /// Show whether the daemon records, and where.
    Status(ClientArgs),
}

/// Where the daemon is and how long to wait for it.
#[derive(Args, Debug)]
pub struct ClientArgs {
    /// Prefix of the daemon's iceoryx2 services.
    #[arg(long, value_name = "PREFIX", default_value = DEFAULT_SERVICE_PREFIX)]
    pub service_prefix: String,
    /// Give up after this many seconds without a response.
    #[arg(long, value_name = "SECS", default_value_t = control::RESPONSE_TIMEOUT.as_secs_f64())]
    pub timeout: f64,
    /// Print the response as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Runs a `control` subcommand; fails (exit code 1) unless the daemon answers `ok`.
pub fn run(cmd: ControlCommand) -> Result<()> {
    let (code, argument, client) = match cmd {
        ControlCommand::NewProcedure(c) => (command::NEW_PROCEDURE, String::new(), c),
        ControlCommand::LoadScene { scene, client } => {
            // A file is named for the daemon, whose working directory may differ from ours.
            let path = std::path::Path::new(&scene);
            let scene = match path.is_file().then(|| path.canonicalize()) {
                Some(Ok(abs)) => abs.display().to_string(),
                _ => scene,
            };
            (command::LOAD_SCENE, scene, client)
        }
        ControlCommand::Record(RecordControl::Start(c)) => {
            (command::RECORD_START, String::new(), c)
        }
        ControlCommand::Record(RecordControl::Stop(c)) => (command::RECORD_STOP, String::new(), c),
        ControlCommand::Record(RecordControl::Status(c)) => {
            (command::RECORD_STATUS, String::new(), c)
        }
    };
    if !(client.timeout.is_finite() && client.timeout > 0.0) {
        bail!(
            "--timeout {}: expected a positive number of seconds",
            client.timeout
        );
    }
    // iceoryx2's start-up notes are noise here; IOX2_LOG_LEVEL raises it for debugging.
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);
    let names = ServiceNames::new(&client.service_prefix)?;
    let response = request(
        &names,
        code,
        &argument,
        Duration::from_secs_f64(client.timeout),
    )?;
    if client.json {
        println!("{}", serde_json::to_string_pretty(&to_json(&response))?);
    } else if response.result == result::OK {
        println!("{}", response.message());
    }
    if response.result != result::OK {
        bail!(
            "{} refused ({}): {}",
            command::name(code),
            result::name(response.result),
            response.message()
        );
    }
    Ok(())
}

/// Sends one request and waits up to `timeout` for its response.
pub fn request(
    names: &ServiceNames,
    code: u32,
    argument: &str,
    timeout: Duration,
) -> Result<ControlResponse> {
    let node = NodeBuilder::new()
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .map_err(|e| anyhow::anyhow!("cannot create an iceoryx2 node: {e:?}"))?;
    Ok(control::request(&node, names, code, argument, timeout)?)
}

fn to_json(r: &ControlResponse) -> serde_json::Value {
    serde_json::json!({
        "command": command::name(r.command),
        "result": result::name(r.result),
        "result_code": r.result,
        "message": r.message(),
        "procedure_id": r.procedure_id,
        "recording": r.recording == 1,
        "recording_path": r.recording_path(),
        "recorded_messages": r.recorded_messages,
        "recordings_finished": r.recordings_finished,
    })
}
