//! The status publisher: the iceoryx2 node, the status service and the event notifier, owned by
//! the 1 kHz loop's thread (iceoryx2 ports are not `Send`), which stamps and sends each status
//! itself and measures latency at publication.
//!
//! It used to be a thread of its own fed by a channel; handing every status over woke that
//! thread 1000 times a second (a futex wake in the loop and a context switch each time: about a
//! third of the daemon's CPU at rest, BENCHMARKS.md "Idle CPU"). A loan, a copy of 648 bytes, a
//! send and a notify cost a few µs and never block (full subscriber buffers discard, a stalled
//! listener loses wake-ups), so the loop does them inline.

use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use hydrometra_ipc::{events, status, ServiceNames};
use iceoryx2::node::{Node, NodeBuilder};
use iceoryx2::port::backpressure_strategy::BackpressureStrategy;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::prelude::{ipc, NodeName, SignalHandlingMode};
use iceoryx2::service::port_factory::{event, publish_subscribe};

use super::latency::LatencySummary;
use super::sim::{StatusFrame, StatusSink, Telemetry};
use hydrometra_record::recorder::StatusTap;

/// Host `CLOCK_MONOTONIC`, ns (the clock `Instant` uses on Linux), comparable across processes.
pub use hydrometra_drivers::transport::monotonic_ns;

/// How often the latency percentiles in status are recomputed from the histogram (walking it
/// costs tens of µs: not on every sample).
pub const LATENCY_SUMMARY_INTERVAL: Duration = Duration::from_millis(100);

/// The status service's publisher and the event notifier, on the loop's thread.
pub struct StatusPublisher {
    publisher: Publisher<ipc::Service, hydrometra_ipc::Status, ()>,
    notifier: Notifier<ipc::Service>,
    _status_service: publish_subscribe::PortFactory<ipc::Service, hydrometra_ipc::Status, ()>,
    _event_service: event::PortFactory<ipc::Service>,
    _node: Node<ipc::Service>,
    status_tap: Option<StatusTap>,
    sequence: u64,
    summary: LatencySummary,
    summary_at: Option<Instant>,
    /// Publication time of the last status, and the longest gap between two so far, ns.
    last_publish_ns: Option<u64>,
    gap_max_ns: u64,
}

impl StatusPublisher {
    /// Creates the node and services, or says why they could not be created.
    pub fn create(names: &ServiceNames, status_tap: Option<StatusTap>) -> anyhow::Result<Self> {
        let prefix = names.prefix().to_string();
        let node_name =
            NodeName::new("hydrometrad").map_err(|e| anyhow::anyhow!("node name: {e:?}"))?;
        let node = NodeBuilder::new()
            .name(&node_name)
            // Signals are the supervisor's business; iceoryx2 must not install its own handlers.
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<ipc::Service>()
            .map_err(|e| anyhow::anyhow!("cannot create the iceoryx2 node: {e:?}"))?;
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
        // Refuse now, with how much is needed, rather than die of SIGBUS once renderers fill
        // the segments (docs/daemon.md, "Failure behaviour").
        super::shm::check(
            std::path::Path::new(super::shm::SHM_DIR),
            "the status, event and control services",
            &super::shm::daemon_services(),
            0,
        )?;
        let status_service = status::create(&node, names).map_err(|e| {
            anyhow::anyhow!(
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
                anyhow::anyhow!(
                    "cannot publish on {}: {e:?} (is another hydrometrad running with service \
                     prefix {prefix:?}?)",
                    names.full(hydrometra_ipc::names::suffix::STATUS)
                )
            })?;
        let event_service = events::create(&node, names).map_err(|e| {
            anyhow::anyhow!(
                "cannot create or open service {}: {e:?}",
                names.full(hydrometra_ipc::names::suffix::EVENTS)
            )
        })?;
        let notifier = event_service
            .notifier_builder()
            .create()
            .map_err(|e| anyhow::anyhow!("cannot create the event notifier: {e:?}"))?;
        tracing::info!(prefix = %prefix, "publishing status on {}", names.full("status"));
        Ok(Self {
            publisher,
            notifier,
            _status_service: status_service,
            _event_service: event_service,
            _node: node,
            status_tap,
            sequence: 0,
            summary: LatencySummary::EMPTY,
            summary_at: None,
            last_publish_ns: None,
            gap_max_ns: 0,
        })
    }

    /// Sends the shutdown event; the ports, services and node drop after it, releasing their
    /// shared memory. `telemetry` gets the exact final latency figures.
    pub fn finish(self, telemetry: &Telemetry) {
        if self
            .notifier
            .notify_with_custom_event_id(events::SHUTDOWN)
            .is_err()
        {
            tracing::debug!("could not send the shutdown event");
        }
        if let Ok(h) = telemetry.latency.lock() {
            telemetry.store_latency_summary(&h.summary());
        }
        tracing::info!(
            published = self.sequence,
            "publisher stopped; releasing shared memory"
        );
    }
}

impl StatusSink for StatusPublisher {
    fn publish(&mut self, frame: StatusFrame, telemetry: &Telemetry) -> bool {
        let mut status = frame.status;
        status.sequence = self.sequence;
        status.latency_p50_s = self.summary.p50_s;
        status.latency_p99_s = self.summary.p99_s;
        status.latency_max_s = self.summary.max_s;
        status.latency_samples = self.summary.count;
        status.publish_monotonic_ns = monotonic_ns();
        if let Some(last) = self.last_publish_ns {
            let gap = status.publish_monotonic_ns.saturating_sub(last);
            self.gap_max_ns = self.gap_max_ns.max(gap);
        }
        self.last_publish_ns = Some(status.publish_monotonic_ns);
        status.status_gap_max_s = self.gap_max_ns as f64 * 1e-9;
        let sent = self
            .publisher
            .loan_uninit()
            .map(|sample| sample.write_payload(status))
            .map_err(|e| format!("{e:?}"))
            .and_then(|sample| sample.send().map_err(|e| format!("{e:?}")));
        match sent {
            Ok(_) => {
                // Non-blocking hand-over to the recorder (drops are counted, never waited for).
                if let Some(tap) = self.status_tap.as_mut() {
                    tap.offer(&status);
                }
                self.sequence += 1;
                telemetry
                    .statuses_published
                    .store(self.sequence, Ordering::Relaxed);
                if let Some(received_at) = frame.new_sample_received_at {
                    let now = Instant::now();
                    let latency = now.saturating_duration_since(received_at);
                    // Only this thread locks the histogram while the loop runs: never contended.
                    if let Ok(mut h) = telemetry.latency.lock() {
                        h.record(latency);
                        let due = self
                            .summary_at
                            .is_none_or(|at| now.duration_since(at) >= LATENCY_SUMMARY_INTERVAL);
                        if due {
                            self.summary = h.summary();
                            self.summary_at = Some(now);
                            telemetry.store_latency_summary(&self.summary);
                        }
                    }
                }
                // A listener that stalls only loses wake-ups: notify never blocks.
                if self
                    .notifier
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
        true
    }
}
