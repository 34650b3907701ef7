//! The publisher thread: owns the iceoryx2 node, the status service and the event notifier
//! (iceoryx2 ports are not `Send`), stamps each status and measures latency at publication.

use std::sync::atomic::Ordering;
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use hydrometra_ipc::{events, status, ServiceNames};
use iceoryx2::node::NodeBuilder;
use iceoryx2::port::backpressure_strategy::BackpressureStrategy;
use iceoryx2::prelude::{ipc, NodeName, SignalHandlingMode};

use super::sim::{StatusFrame, Telemetry};
use crate::record::recorder::StatusTap;

/// Host `CLOCK_MONOTONIC`, ns (the clock `Instant` uses on Linux), comparable across processes.
pub use hydrometra_drivers::transport::monotonic_ns;

/// The running publisher thread.
pub struct PublisherThread {
    handle: JoinHandle<()>,
}

impl PublisherThread {
    /// Starts the thread, creates the node and services, and returns once they exist (or with
    /// the reason they could not be created). The thread ends when `frames` hangs up.
    pub fn spawn(
        names: ServiceNames,
        frames: Receiver<StatusFrame>,
        telemetry: Arc<Telemetry>,
        realtime_priority: u8,
        status_tap: Option<StatusTap>,
    ) -> anyhow::Result<Self> {
        let (ready_tx, ready_rx) = std::sync::mpsc::channel::<Result<(), String>>();
        let handle = std::thread::Builder::new()
            .name("hm-publisher".into())
            .spawn(move || {
                super::realtime::apply("hm-publisher", realtime_priority);
                run(names, frames, telemetry, ready_tx, status_tap)
            })?;
        match ready_rx.recv() {
            Ok(Ok(())) => Ok(Self { handle }),
            Ok(Err(message)) => {
                let _ = handle.join();
                Err(anyhow::anyhow!(message))
            }
            Err(_) => {
                let _ = handle.join();
                Err(anyhow::anyhow!("publisher thread ended during setup"))
            }
        }
    }

    /// Waits for the thread to end (after the sim loop dropped its sender).
    pub fn join(self) {
        if self.handle.join().is_err() {
            tracing::error!("publisher thread panicked");
        }
    }
}

fn run(
    names: ServiceNames,
    frames: Receiver<StatusFrame>,
    telemetry: Arc<Telemetry>,
    ready: std::sync::mpsc::Sender<Result<(), String>>,
    mut status_tap: Option<StatusTap>,
) {
    let prefix = names.prefix().to_string();
    let setup = || -> Result<_, String> {
        let node_name = NodeName::new("hydrometrad").map_err(|e| format!("node name: {e:?}"))?;
        let node = NodeBuilder::new()
            .name(&node_name)
            // Signals are the supervisor's business; iceoryx2 must not install its own handlers.
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<ipc::Service>()
            .map_err(|e| format!("cannot create the iceoryx2 node: {e:?}"))?;
        // A daemon killed with SIGKILL leaves its node behind: remove what dead nodes hold before
        // opening the services again.
        let cleaned = node.try_cleanup_dead_nodes();
        if cleaned.cleanups > 0 || cleaned.failed_cleanups > 0 {
            tracing::info!(
                removed = cleaned.cleanups,
                failed = cleaned.failed_cleanups,
                "removed resources of dead iceoryx2 nodes"
            );
        }
        let status_service = status::create(&node, &names).map_err(|e| {
            format!(
                "cannot create or open service {}: {e:?} (a service of another schema version or \
                 with other settings exists under this prefix?)",
                names.full(hydrometra_ipc::names::suffix::STATUS)
            )
        })?;
        let publisher = status_service
            .publisher_builder()
            .backpressure_strategy(BackpressureStrategy::DiscardData)
            .max_loaned_samples(2)
            .create()
            .map_err(|e| {
                format!(
                    "cannot publish on {}: {e:?} (is another hydrometrad running with service \
                     prefix {prefix:?}?)",
                    names.full(hydrometra_ipc::names::suffix::STATUS)
                )
            })?;
        let event_service = events::create(&node, &names).map_err(|e| {
            format!(
                "cannot create or open service {}: {e:?}",
                names.full(hydrometra_ipc::names::suffix::EVENTS)
            )
        })?;
        let notifier = event_service
            .notifier_builder()
            .create()
            .map_err(|e| format!("cannot create the event notifier: {e:?}"))?;
        Ok((node, status_service, publisher, event_service, notifier))
    };
    let (_node, _status_service, publisher, _event_service, notifier) = match setup() {
        Ok(parts) => {
            let _ = ready.send(Ok(()));
            parts
        }
        Err(message) => {
            let _ = ready.send(Err(message));
            return;
        }
    };
    tracing::info!(prefix = %prefix, "publishing status on {}", names.full("status"));

    let mut sequence: u64 = 0;
    let mut summary = super::latency::LatencySummary::EMPTY;
    loop {
        let frame = match frames.recv_timeout(Duration::from_millis(100)) {
            Ok(frame) => frame,
            Err(RecvTimeoutError::Timeout) => continue,
            Err(RecvTimeoutError::Disconnected) => break,
        };
        let mut status = frame.status;
        status.sequence = sequence;
        status.latency_p50_s = summary.p50_s;
        status.latency_p99_s = summary.p99_s;
        status.latency_max_s = summary.max_s;
        status.latency_samples = summary.count;
        status.publish_monotonic_ns = monotonic_ns();
        let sent = publisher
            .loan_uninit()
            .map(|sample| sample.write_payload(status))
            .map_err(|e| format!("{e:?}"))
            .and_then(|sample| sample.send().map_err(|e| format!("{e:?}")));
        match sent {
            Ok(_) => {
                // Non-blocking hand-over to the recorder (drops are counted, never waited for).
                if let Some(tap) = status_tap.as_mut() {
                    tap.offer(&status);
                }
                sequence += 1;
                telemetry
                    .statuses_published
                    .store(sequence, Ordering::Relaxed);
                if let Some(received_at) = frame.new_sample_received_at {
                    let latency = received_at.elapsed();
                    if let Ok(mut h) = telemetry.latency.lock() {
                        h.record(latency);
                        summary = h.summary();
                    }
                }
                // A listener that stalls only loses wake-ups: notify never blocks.
                if notifier
                    .notify_with_custom_event_id(events::STATUS)
                    .is_err()
                {
                    telemetry.publish_errors.fetch_add(1, Ordering::Relaxed);
                }
            }
            Err(e) => {
                let n = telemetry.publish_errors.fetch_add(1, Ordering::Relaxed);
                if n < 10 || n.is_multiple_of(1000) {
                    tracing::warn!(error = %e, "could not publish status");
                }
            }
        }
    }
    if notifier
        .notify_with_custom_event_id(events::SHUTDOWN)
        .is_err()
    {
        tracing::debug!("could not send the shutdown event");
    }
    tracing::info!(
        published = sequence,
        "publisher stopped; releasing shared memory"
    );
    // Ports, services and the node drop here, in reverse order, releasing their shared memory.
}
