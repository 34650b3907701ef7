//! Serving the page: the rigs' sources, the classroom and the web server, until SIGINT or SIGTERM.

use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use hydrometra_ipc::ServiceNames;

use crate::args::{ServeArgs, StationArgs, StationCommand};
use crate::error::{io, StationError};
use crate::{auth, bench, classroom, hub, local, server};

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
