//! The systemd unit (udev/hydrometrad.service) and the daemon's side of it: READY=1, WATCHDOG=1
//! at half the watchdog interval, STOPPING=1 on SIGTERM, over a real NOTIFY_SOCKET.

use std::collections::HashMap;
use std::os::unix::net::UnixDatagram;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use hydrometra_hil_tests::*;

fn unit_file() -> (String, HashMap<String, String>) {
    let path = workspace_root().join("udev/hydrometrad.service");
    let text = std::fs::read_to_string(&path).expect("udev/hydrometrad.service");
    let mut keys = HashMap::new();
    let mut section = String::new();
    for line in text.lines().map(str::trim) {
        if line.starts_with('#') || line.is_empty() {
            continue;
        }
        if line.starts_with('[') {
            section = line.trim_matches(['[', ']']).to_string();
            continue;
        }
        let (k, v) = line
            .split_once('=')
            .unwrap_or_else(|| panic!("not key=value: {line}"));
        keys.insert(format!("{section}.{k}"), v.to_string());
    }
    (text, keys)
}

#[test]
fn unit_is_notify_with_watchdog_restart_unprivileged_and_keeps_ipc() {
    let (_, k) = unit_file();
    let get = |key: &str| {
        k.get(key)
            .map(String::as_str)
            .unwrap_or_else(|| panic!("{key} missing"))
    };
    assert_eq!(get("Service.Type"), "notify");
    assert_eq!(get("Service.Restart"), "on-failure");
    assert_eq!(get("Service.RemoveIPC"), "no");
    assert_eq!(get("Service.NotifyAccess"), "main");
    let watchdog_s: f64 = get("Service.WatchdogSec")
        .trim_end_matches('s')
        .parse()
        .unwrap();
    assert!((0.5..=30.0).contains(&watchdog_s));
    let user = get("Service.User");
    assert!(!user.is_empty() && user != "root" && user != "0");
    assert!(get("Service.SupplementaryGroups").contains("dialout"));
    assert!(get("Service.ExecStart").contains("hydrometrad --config"));
    assert_eq!(get("Install.WantedBy"), "multi-user.target");
}

#[test]
fn unit_passes_systemd_analyze_verify_where_available() {
    let Ok(probe) = Command::new("systemd-analyze").arg("--version").output() else {
        eprintln!(
            "SKIP unit_passes_systemd_analyze_verify_where_available: systemd-analyze not \
             installed (the key checks run in their own test)"
        );
        return;
    };
    assert!(probe.status.success());
    // Point ExecStart at the built binary: verify checks that the command is executable.
    let (text, _) = unit_file();
    let text = text.replace(
        "/usr/local/bin/hydrometrad",
        binary("hydrometrad").to_str().unwrap(),
    );
    let dir = temp_dir("unit");
    let path = dir.join("hydrometrad.service");
    std::fs::write(&path, text).unwrap();
    let out = Command::new("systemd-analyze")
        .args(["verify", "--man=no"])
        .arg(&path)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    let ours: Vec<&str> = stderr
        .lines()
        .filter(|l| l.contains("hydrometrad.service"))
        .collect();
    assert!(
        out.status.success() && ours.is_empty(),
        "systemd-analyze verify:\n{stderr}"
    );
}

#[test]
fn daemon_notifies_ready_feeds_the_watchdog_and_announces_stopping() {
    let dir = temp_dir("notify");
    let socket_path = dir.join("notify.sock");
    let socket = UnixDatagram::bind(&socket_path).unwrap();
    socket
        .set_read_timeout(Some(Duration::from_millis(100)))
        .unwrap();
    let prefix = unique_prefix("notify");
    let mut child = Command::new(binary("hydrometrad"))
        .args(["--emulated", "default", "--service-prefix", &prefix])
        .env("NOTIFY_SOCKET", &socket_path)
        .env("WATCHDOG_USEC", "400000") // ping expected every 200 ms
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut messages: Vec<(Instant, String)> = Vec::new();
    let mut buf = [0u8; 4096];
    let started = Instant::now();
    while started.elapsed() < Duration::from_millis(1500) {
        if let Ok(n) = socket.recv(&mut buf) {
            messages.push((
                Instant::now(),
                String::from_utf8_lossy(&buf[..n]).into_owned(),
            ));
        }
    }
    // SAFETY: kill(2) on our child.
    unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
    let deadline = Instant::now() + Duration::from_secs(5);
    while Instant::now() < deadline {
        if let Ok(n) = socket.recv(&mut buf) {
            messages.push((
                Instant::now(),
                String::from_utf8_lossy(&buf[..n]).into_owned(),
            ));
        }
        if child.try_wait().unwrap().is_some() {
            break;
        }
    }
    let status = child.wait().unwrap();
    assert!(status.success());
    let has = |m: &str| messages.iter().position(|(_, s)| s.lines().any(|l| l == m));
    let ready = has("READY=1").expect("READY=1 sent");
    let stopping = has("STOPPING=1").expect("STOPPING=1 sent");
    assert!(ready < stopping);
    let pings: Vec<Instant> = messages
        .iter()
        .filter(|(_, s)| s.lines().any(|l| l == "WATCHDOG=1"))
        .map(|(t, _)| *t)
        .collect();
    // ~1.5 s at one ping per 200 ms: at least 4 even with start-up time and a loaded machine,
    // and never more than one per 150 ms on average (not a busy loop).
    assert!(
        pings.len() >= 4 && pings.len() <= 11,
        "{} watchdog pings",
        pings.len()
    );
    for w in pings.windows(2) {
        assert!(
            w[1] - w[0] < Duration::from_millis(400),
            "a gap that would trip the watchdog"
        );
    }
}
