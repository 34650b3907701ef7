//! A rig the daemon cannot open: it runs in the safe state, logs why once per change of reason
//! (not once per retry), and `hydrometra monitor` shows the reason.

use std::time::Duration;

use hydrometra_hil_tests::*;

#[test]
fn a_missing_device_is_named_in_the_log_once_and_shown_by_the_monitor() {
    let prefix = unique_prefix("nodev");
    let daemon = Daemon::start(&prefix, &["--device", "/dev/does-not-exist"]);
    // The transport retries with backoff (50 ms doubling to 2 s): 4 s are about 7 attempts.
    std::thread::sleep(Duration::from_secs(4));

    let j = monitor_once_json(&prefix);
    assert_eq!(j["link_state_name"], "disconnected", "{j}");
    assert_eq!(j["safe_state"], true, "{j}");
    assert_eq!(j["link"]["down_reason_name"], "device-not-found", "{j}");
    let text = j["link"]["down_text"].as_str().unwrap_or_default();
    assert!(text.contains("device not found"), "{j}");

    let log = daemon.log();
    let down = daemon.log_lines_with("/dev/does-not-exist");
    assert_eq!(down.len(), 1, "one line per change of reason:\n{log}");
    assert!(
        down[0].contains("rig link down") && down[0].contains("No such file or directory"),
        "{log}"
    );
}
