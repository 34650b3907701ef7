//! Rigs watched over zenoh (`--zenoh`): every rig publishing under the key root (or only the
//! `--rig` ids) gets a panel as its first sample arrives; control goes out as a zenoh query, which
//! a rig answers only where its `[remote] allow_control` is set.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use clap::Args;
use hydrometra_ipc::control::{self, ControlRequest};
use hydrometra_remote::config::Mode;
use hydrometra_remote::follow::Sink;
use hydrometra_remote::session::{self, SessionSettings};
use hydrometra_remote::watch::{self, Update};
use zenoh::Wait;

use crate::error::StationError;
use crate::feed::RigFeed;
use crate::hub::Hub;
use crate::rates::Rates;
use crate::server::{AppState, Backend, ControlRoute};

/// `--zenoh` and its settings.
#[derive(Args, Debug, Clone)]
pub struct ZenohArgs {
    /// Watch the rigs that publish to zenoh (the classroom; docs/station.md).
    #[arg(long)]
    pub zenoh: bool,
    /// Join as a zenoh `peer` (finds the rigs on the LAN) or as a `client` of a router.
    #[arg(long, value_name = "peer|client", default_value = "peer", value_parser = parse_mode)]
    pub zenoh_mode: Mode,
    /// Connect to this zenoh endpoint (repeat), e.g. tcp/192.168.1.20:7447 (a router or a rig).
    #[arg(long, value_name = "ENDPOINT")]
    pub zenoh_connect: Vec<String>,
    /// Listen on this zenoh endpoint (repeat), e.g. tcp/0.0.0.0:7447 for the rigs to connect to.
    #[arg(long, value_name = "ENDPOINT")]
    pub zenoh_listen: Vec<String>,
    /// No UDP multicast scouting (connect/listen endpoints only).
    #[arg(long)]
    pub zenoh_no_multicast: bool,
    /// A zenoh configuration file (JSON5): access control, TLS, user and password.
    #[arg(long, value_name = "PATH")]
    pub zenoh_config: Option<PathBuf>,
    /// First segment of the rigs' keys.
    #[arg(long, value_name = "ROOT", default_value = hydrometra_remote::keys::DEFAULT_ROOT)]
    pub zenoh_root: String,
    /// Show only this rig id (repeat); default: every rig under the root.
    #[arg(long = "rig", value_name = "ID")]
    pub rigs: Vec<String>,
}

fn parse_mode(s: &str) -> Result<Mode, String> {
    match s {
        "peer" => Ok(Mode::Peer),
        "client" => Ok(Mode::Client),
        _ => Err(format!("{s:?}: expected peer or client")),
    }
}

/// The zenoh side of a running station; stops when dropped.
pub struct Classroom {
    _subscribers: Vec<zenoh::pubsub::Subscriber<()>>,
    session: Arc<zenoh::Session>,
}

impl Drop for Classroom {
    fn drop(&mut self) {
        let _ = self.session.close().wait();
    }
}

/// Opens the session and subscribes; rigs appear in `hub` as they publish.
pub fn start(
    args: &ZenohArgs,
    hub: Arc<Hub>,
    state: Arc<AppState>,
    rates: Rates,
) -> Result<Classroom, StationError> {
    hydrometra_remote::keys::check_root(&args.zenoh_root)
        .map_err(|e| StationError::Usage(format!("--zenoh-root: {e}")))?;
    for r in &args.rigs {
        hydrometra_remote::keys::check_rig_id(r)
            .map_err(|e| StationError::Usage(format!("--rig: {e}")))?;
    }
    let settings = SessionSettings {
        mode: args.zenoh_mode,
        connect: args.zenoh_connect.clone(),
        listen: args.zenoh_listen.clone(),
        multicast_scouting: !args.zenoh_no_multicast,
        config_file: args.zenoh_config.clone(),
    };
    let session = Arc::new(
        session::open(&settings).map_err(|e| StationError::Usage(format!("--zenoh: {e}")))?,
    );
    let feeds: Mutex<HashMap<String, Arc<Mutex<RigFeed>>>> = Mutex::new(HashMap::new());
    let root = args.zenoh_root.clone();
    let s2 = session.clone();
    let on: watch::OnUpdate = Arc::new(move |id: &str, update: Result<Update, &str>| {
        let feed = {
            let mut map = feeds.lock().unwrap_or_else(|p| p.into_inner());
            map.entry(id.to_string())
                .or_insert_with(|| {
                    let rig =
                        hub.add_rig(id.to_string(), format!("zenoh {root}/{id}"), true, false);
                    state.set_backend(
                        rig.info.index,
                        Backend {
                            control: Some(route(s2.clone(), root.clone(), id.to_string())),
                            recordings: None,
                        },
                    );
                    tracing::info!(rig = id, "classroom: a new rig");
                    Arc::new(Mutex::new(RigFeed { rig, rates }))
                })
                .clone()
        };
        let mut f = feed.lock().unwrap_or_else(|p| p.into_inner());
        match update {
            // The rig's forwarder paces what it sends; the station shows all of it.
            Ok(Update::Status(s)) => f.status(&s, true),
            Ok(Update::Topology(h, t)) => f.topology(&h, &t),
            Ok(Update::Flow(h, b)) => f.flow(&h, &b),
            Ok(Update::Positions(h, p)) if f.wants_scene() => f.positions(&h, &p),
            Ok(Update::Particles(h, p)) if f.wants_scene() => f.particles(&h, &p),
            Ok(_) => f.skipped(),
            Err(service) => {
                f.rig
                    .counters
                    .decode_errors
                    .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                tracing::debug!(rig = id, service, "classroom: undecodable payload");
            }
        }
    });
    let subscribers = watch::subscribe(&session, &args.zenoh_root, &args.rigs, on)
        .map_err(|e| StationError::Usage(format!("--zenoh: {e}")))?;
    Ok(Classroom {
        _subscribers: subscribers,
        session,
    })
}

/// Control of a zenoh rig: a query on its control key, from a thread of its own.
fn route(session: Arc<zenoh::Session>, root: String, rig: String) -> ControlRoute {
    Arc::new(move |command, argument| {
        let (tx, rx) = tokio::sync::oneshot::channel();
        let (session, root, rig) = (session.clone(), root.clone(), rig.clone());
        let spawned = std::thread::Builder::new()
            .name("station-zenoh-control".into())
            .spawn(move || {
                let answer = ControlRequest::new(command, &argument)
                    .map_err(|e| e.to_string())
                    .and_then(|req| {
                        watch::control(
                            &session,
                            &root,
                            &rig,
                            &req,
                            control::RESPONSE_TIMEOUT - Duration::from_millis(500),
                        )
                    });
                let _ = tx.send(answer);
            });
        if let Err(e) = spawned {
            tracing::error!("classroom: control thread: {e}");
        }
        rx
    })
}
