//! Daemon lifecycle: clean shutdown on SIGINT/SIGTERM releases shared memory; after SIGKILL a
//! restarted daemon cleans the dead node and serves again; renderers that stall or die never
//! block it; a second daemon on the same prefix and a reader of another schema are refused.

use std::process::{Command, Stdio};
use std::time::Duration;

use hydrometra_hil_tests::*;
use hydrometra_ipc::{events, status, ServiceNames, Status};
use iceoryx2::prelude::*;
use iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenError;

fn wait_live(reader: &StatusReader) -> Status {
    *reader
        .until("a live status", Duration::from_secs(10), |s| {
            s.safe_state == 0
        })
        .last()
        .unwrap()
}

fn clean_shutdown_on(signal: i32, tag: &str) {
    let prefix = unique_prefix(tag);
    let mut daemon = Daemon::start(&prefix, &["--emulated", "default"]);
    {
        let reader = StatusReader::connect(&prefix, Duration::from_secs(10));
        wait_live(&reader);
        assert_eq!(node_of_process(daemon.pid()), NodePresence::Alive);
        // The reader stays subscribed while the daemon stops: it must not hold the daemon up.
        daemon.signal(signal);
        let exit = daemon
            .wait_exit(Duration::from_secs(5))
            .expect("exits within 5 s");
        assert!(exit.success(), "exit status {exit:?}\n{}", daemon.log());
    }
    // Everything the daemon owned is gone: its node and both services.
    assert_eq!(node_of_process(daemon.pid()), NodePresence::Absent);
    assert_eq!(
        services_exist(&prefix),
        (false, false),
        "services left behind"
    );
    let log = daemon.log();
    assert!(
        log.contains("shutting down") && log.contains("releasing shared memory"),
        "{log}"
    );
}

#[test]
fn sigterm_shuts_down_cleanly_and_releases_shared_memory() {
    clean_shutdown_on(libc::SIGTERM, "sigterm");
}

#[test]
fn sigint_shuts_down_cleanly_and_releases_shared_memory() {
    clean_shutdown_on(libc::SIGINT, "sigint");
}

#[test]
fn after_kill_9_a_restarted_daemon_cleans_up_and_serves_a_new_subscriber() {
    let prefix = unique_prefix("kill9");
    let mut first = Daemon::start(&prefix, &["--emulated", "default"]);
    let old_run = {
        let reader = StatusReader::connect(&prefix, Duration::from_secs(10));
        wait_live(&reader).run_id
    };
    first.signal(libc::SIGKILL);
    first.wait_exit(Duration::from_secs(5)).expect("killed");
    // The killed daemon's node is left behind, dead, with its services.
    assert_eq!(node_of_process(first.pid()), NodePresence::Dead);

    let second = Daemon::start(&prefix, &["--emulated", "default"]);
    let reader = StatusReader::connect(&prefix, Duration::from_secs(10));
    let statuses = reader.until("a status of the new run", Duration::from_secs(10), |s| {
        s.run_id != old_run && s.safe_state == 0
    });
    let new = *statuses.last().unwrap();
    reader.collect_for(Duration::from_millis(100)); // past a possible history-sample gap
    let more = reader.collect_for(Duration::from_millis(300));
    assert!(
        more.len() > 100,
        "the new daemon serves: {} statuses in 0.3 s",
        more.len()
    );
    assert!(more.iter().all(|s| s.run_id == new.run_id));
    assert_contiguous(&more);
    // Cleaned up: by the new daemon's start-up cleanup (any iceoryx2 process may do it first,
    // e.g. another test's daemon; what matters is that it is gone and the service works).
    assert_eq!(
        node_of_process(first.pid()),
        NodePresence::Absent,
        "dead node not cleaned"
    );
    assert!(
        second.log().contains("hydrometrad running"),
        "{}",
        second.log()
    );
}

#[test]
fn a_renderer_subscribed_across_a_kill_9_and_restart_keeps_receiving() {
    let prefix = unique_prefix("survivor");
    let mut first = Daemon::start(&prefix, &["--emulated", "default"]);
    let reader = StatusReader::connect(&prefix, Duration::from_secs(10));
    let old_run = wait_live(&reader).run_id;
    first.signal(libc::SIGKILL);
    first.wait_exit(Duration::from_secs(5)).expect("killed");
    // As systemd would: restart while the renderer stays subscribed.
    let _second = Daemon::start(&prefix, &["--emulated", "default"]);
    let statuses = reader.until(
        "the restarted daemon's status",
        Duration::from_secs(10),
        |s| s.run_id != old_run && s.safe_state == 0,
    );
    let new_run = statuses.last().unwrap().run_id;
    // The first status of the new run may be the history sample, delivered before the new
    // publisher saw this subscriber: settle, then expect a contiguous stream.
    reader.collect_for(Duration::from_millis(100));
    let more = reader.collect_for(Duration::from_millis(300));
    assert!(more.len() > 100 && more.iter().all(|s| s.run_id == new_run));
    assert_contiguous(&more);
}

#[test]
fn stalled_and_killed_renderers_never_block_the_daemon() {
    let prefix = unique_prefix("stall");
    let names = ServiceNames::new(&prefix).unwrap();
    let _daemon = Daemon::start(
        &prefix,
        &["--emulated", "default", "--status-rate-hz", "500"],
    );
    let reader = StatusReader::connect(&prefix, Duration::from_secs(10));
    wait_live(&reader);

    // A renderer that subscribes and listens for events but never reads or waits.
    let stalled_node = test_node();
    let stalled_service = status::open(&stalled_node, &names).unwrap();
    let _stalled_sub = stalled_service
        .subscriber_builder()
        .buffer_size(1)
        .create()
        .unwrap();
    let event_service = events::open(&stalled_node, &names).unwrap();
    let _stalled_listener = event_service.listener_builder().create().unwrap();
    // Renderers that die without cleaning up: monitors killed with SIGKILL.
    for _ in 0..3 {
        let mut monitor = Command::new(binary("hydrometra"))
            .args(["monitor", "--json", "--service-prefix", &prefix])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        std::thread::sleep(Duration::from_millis(300));
        monitor.kill().unwrap();
        monitor.wait().unwrap();
    }

    reader.drain();
    let window = Duration::from_secs(3);
    let statuses = reader.collect_for(window);
    assert_contiguous(&statuses);
    let rate = statuses.len() as f64 / window.as_secs_f64();
    assert!(
        (rate - 500.0).abs() <= 50.0,
        "{rate:.1} statuses/s with stalled and dead renderers"
    );
    let last = statuses.last().unwrap();
    assert_eq!(last.statuses_dropped, 0, "the publisher kept up");
}

#[test]
fn a_second_daemon_on_the_same_prefix_is_refused_with_a_clear_error() {
    let prefix = unique_prefix("twice");
    let _first = Daemon::start(&prefix, &["--emulated", "default"]);
    let reader = StatusReader::connect(&prefix, Duration::from_secs(10));
    wait_live(&reader);
    let mut second = Daemon::start(&prefix, &["--emulated", "default"]);
    let exit = second
        .wait_exit(Duration::from_secs(10))
        .expect("second daemon exits");
    assert!(!exit.success());
    let log = second.log();
    assert!(
        log.contains("another hydrometrad") && log.contains(&prefix),
        "{log}"
    );
    // The first one still serves.
    assert!(reader.collect_for(Duration::from_millis(200)).len() > 50);
}

/// A reader built against another schema version: same service name, other type.
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[repr(C)]
#[type_name("hydrometra.v2.Status")]
struct StatusV2 {
    schema_version: u32,
    size_bytes: u32,
    sequence: u64,
}

#[test]
fn a_subscriber_of_another_schema_version_is_refused() {
    let prefix = unique_prefix("schema");
    let _daemon = Daemon::start(&prefix, &["--emulated", "default"]);
    let reader = StatusReader::connect(&prefix, Duration::from_secs(10));
    wait_live(&reader);
    let names = ServiceNames::new(&prefix).unwrap();
    let node = test_node();
    let result = node
        .service_builder(names.status())
        .publish_subscribe::<StatusV2>()
        .open();
    assert!(
        matches!(result, Err(PublishSubscribeOpenError::IncompatibleTypes)),
        "{:?}",
        result.err()
    );
    // Same layout but an old name is refused as well: the type name carries the version.
    #[derive(Debug, Clone, Copy, ZeroCopySend)]
    #[repr(C)]
    #[type_name("hydrometra.v0.Status")]
    struct Renamed(Status);
    let renamed = node
        .service_builder(names.status())
        .publish_subscribe::<Renamed>()
        .open();
    assert!(matches!(
        renamed,
        Err(PublishSubscribeOpenError::IncompatibleTypes)
    ));
}
