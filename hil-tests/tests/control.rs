//! The control service end to end: emulated rig (built-in `default` scenario) -> hydrometrad ->
//! `hydrometra control ...` (and the Python example written from docs/ipc.md). A new procedure
//! resets the deficit in status and rotates the recording; a scene that does not exist is
//! refused with `not_found` and malformed requests with `bad_request` while the daemon goes on;
//! load-scene switches a running scene; record stop/start change what the recorder
//! reports; a client without a daemon fails fast and says so. Every test has its own service
//! prefix.

use std::path::Path;
use std::process::{Command, Output};
use std::time::{Duration, Instant};

use hydrometra_hil_tests::*;
use hydrometra_ipc::hydraulic_flags::ACTIVE;
use hydrometra_ipc::Status;
use serde_json::Value;

/// Runs `hydrometra control ARGS... --service-prefix PREFIX --json`.
fn control(prefix: &str, args: &[&str]) -> Output {
    Command::new(binary("hydrometra"))
        .arg("control")
        .args(args)
        .args(["--service-prefix", prefix, "--json"])
        .env_remove("RUST_BACKTRACE")
        .output()
        .expect("run hydrometra control")
}

/// The response of a request the daemon must answer `ok`.
fn ok(prefix: &str, args: &[&str]) -> Value {
    let out = control(prefix, args);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "hydrometra control {args:?} failed: {stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: Value = serde_json::from_str(&stdout)
        .unwrap_or_else(|e| panic!("no JSON from control {args:?} ({e}): {stdout}"));
    assert_eq!(v["result"], "ok", "{v}");
    v
}

fn recordings(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .map(|entries| {
            entries
                .filter_map(Result::ok)
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.ends_with(".mcap"))
                .collect()
        })
        .unwrap_or_default();
    names.sort();
    names
}

fn start_recording_daemon(tag: &str) -> (Daemon, StatusReader, std::path::PathBuf) {
    let dir = temp_dir(tag);
    let rec = dir.join("recordings");
    let prefix = unique_prefix(tag);
    let daemon = Daemon::start(
        &prefix,
        &[
            "--emulated",
            "default",
            "--status-rate-hz",
            "100",
            "--record-dir",
            rec.to_str().expect("utf-8 temp path"),
        ],
    );
    let reader = StatusReader::connect(&prefix, Duration::from_secs(10));
    // Status is published before the control service is created (the daemon starts the loop
    // first): wait for control to answer too (a loaded CI run once asked in between).
    let deadline = Instant::now() + Duration::from_secs(10);
    while !control(&prefix, &["record", "status"]).status.success() && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(50));
    }
    (daemon, reader, rec)
}

fn last(v: Vec<Status>) -> Status {
    *v.last().expect("at least one status")
}

#[test]
fn new_procedure_resets_the_deficit_in_status_and_rotates_the_recording() {
    let (daemon, reader, rec) = start_recording_daemon("ctl-new-procedure");
    // The default scenario opens the inflow at 1 s: wait for fluid in and a deficit to reset.
    let before = last(reader.until(
        "fluid delivered and a deficit",
        Duration::from_secs(30),
        |s| s.hydraulic_flags & ACTIVE != 0 && s.fluid_in_m3 > 5e-6 && s.deficit_m3 > 1e-8,
    ));
    let old_file = format!("procedure-{}.mcap", before.procedure_id);
    assert_eq!(recordings(&rec), vec![old_file.clone()]);

    let response = ok(&daemon.prefix, &["new-procedure"]);
    let new_id = response["procedure_id"].as_u64().expect("procedure_id");
    assert_ne!(new_id, before.procedure_id, "{response}");
    let message = response["message"].as_str().unwrap_or_default();
    assert!(
        message.contains(&format!("procedure {} ended", before.procedure_id)),
        "{message}"
    );
    // The recording rotated: the response names the new file, which exists beside the old one.
    let new_file = format!("procedure-{new_id}.mcap");
    assert_eq!(response["recording"], true, "{response}");
    assert!(
        response["recording_path"]
            .as_str()
            .is_some_and(|p| p.ends_with(&new_file)),
        "{response}"
    );
    assert_eq!(response["recordings_finished"], 1, "{response}");
    assert_eq!(recordings(&rec), vec![old_file, new_file]);

    // Status carries the new procedure with the deficit and the fluid totals restarted from 0.
    let fresh = last(
        reader.until("the new procedure in status", Duration::from_secs(5), |s| {
            s.procedure_id == new_id
        }),
    );
    assert!(
        fresh.deficit_m3 < before.deficit_m3.max(1e-9) && fresh.deficit_m3 < 1e-7,
        "deficit {} m3 before, {} m3 after the new procedure",
        before.deficit_m3,
        fresh.deficit_m3
    );
    assert!(
        fresh.fluid_in_m3 < before.fluid_in_m3,
        "fluid in {} m3 before, {} m3 after",
        before.fluid_in_m3,
        fresh.fluid_in_m3
    );
    assert!(fresh.procedure_time_s < 1.0, "{}", fresh.procedure_time_s);
    let log = daemon.log();
    assert!(log.contains("new procedure started"), "{log}");
}

#[test]
fn load_scene_of_an_unknown_name_and_malformed_requests_are_refused_and_the_daemon_goes_on() {
    let (daemon, reader, _rec) = start_recording_daemon("ctl-unknown-scene");
    let out = control(&daemon.prefix, &["load-scene", "no-such-scene"]);
    assert!(!out.status.success(), "an unknown scene was accepted");
    let v: Value = serde_json::from_slice(&out.stdout).expect("a JSON response");
    assert_eq!(v["result"], "not_found", "{v}");
    assert_eq!(v["command"], "load_scene", "{v}");
    let message = v["message"].as_str().unwrap_or_default();
    assert!(
        message.contains("no built-in scene `no-such-scene`") && message.contains("default"),
        "the message names the scene and the known ones: {message}"
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("not_found"), "{stderr}");
    // A missing scene file is `not_found` too; the daemon still publishes.
    let out = control(&daemon.prefix, &["load-scene", "/nonexistent/scene.toml"]);
    let v: Value = serde_json::from_slice(&out.stdout).expect("a JSON response");
    assert_eq!(v["result"], "not_found", "{v}");
    // Malformed requests straight over iceoryx2: each gets `bad_request`, the daemon goes on.
    {
        use hydrometra_ipc::control::{self, command, result, ControlRequest};
        let names = hydrometra_ipc::ServiceNames::new(&daemon.prefix).expect("prefix");
        let node = test_node();
        let client = control::open(&node, &names)
            .expect("the control service")
            .client_builder()
            .create()
            .expect("client");
        let unknown = ControlRequest::new(99, "").expect("request");
        let mut overlong = ControlRequest::new(command::LOAD_SCENE, "default").expect("request");
        overlong.argument_len = 10_000;
        let mut not_utf8 = ControlRequest::new(command::LOAD_SCENE, "ab").expect("request");
        not_utf8.argument[0] = 0xff;
        let extra = ControlRequest::new(command::NEW_PROCEDURE, "now").expect("request");
        for (request, says) in [
            (unknown, "unknown command 99"),
            (overlong, "argument_len 10000"),
            (not_utf8, "not UTF-8"),
            (extra, "takes no argument"),
        ] {
            let pending = client.send_copy(request).expect("send");
            let deadline = Instant::now() + control::RESPONSE_TIMEOUT;
            let response = loop {
                if let Some(r) = pending.receive().expect("receive") {
                    break *r;
                }
                assert!(Instant::now() < deadline, "no response to {request:?}");
                std::thread::sleep(Duration::from_millis(5));
            };
            assert_eq!(
                response.result,
                result::BAD_REQUEST,
                "{}",
                response.message()
            );
            assert!(response.message().contains(says), "{}", response.message());
        }
    }
    let seq = last(reader.until("a status", Duration::from_secs(2), |_| true)).sequence;
    reader.until("statuses go on", Duration::from_secs(2), |s| {
        s.sequence > seq + 50
    });
}

#[test]
fn record_stop_and_start_change_the_record_status() {
    let (daemon, _reader, rec) = start_recording_daemon("ctl-record");
    let p = daemon.prefix.as_str();
    let deadline = Instant::now() + Duration::from_secs(10);
    let first = loop {
        let v = ok(p, &["record", "status"]);
        if v["recording"] == true || Instant::now() > deadline {
            break v;
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    assert_eq!(
        first["recording"], true,
        "recording from the start: {first}"
    );
    let first_path = first["recording_path"]
        .as_str()
        .unwrap_or_default()
        .to_string();

    let stopped = ok(p, &["record", "stop"]);
    assert_eq!(stopped["recording"], false, "{stopped}");
    assert_eq!(stopped["recordings_finished"], 1, "{stopped}");
    assert_eq!(stopped["recording_path"], first_path.as_str());
    let status = ok(p, &["record", "status"]);
    assert_eq!(status["recording"], false, "{status}");
    assert_eq!(ok(p, &["record", "stop"])["message"], "not recording");
    let files = recordings(&rec);
    std::thread::sleep(Duration::from_millis(300));
    assert_eq!(recordings(&rec), files, "no file while stopped");

    let started = ok(p, &["record", "start"]);
    assert_eq!(started["recording"], true, "{started}");
    let second_path = started["recording_path"].as_str().unwrap_or_default();
    assert_ne!(second_path, first_path, "a new file: {started}");
    assert!(Path::new(second_path).is_file(), "{second_path}");
    let status = ok(p, &["record", "status"]);
    assert_eq!(status["recording"], true, "{status}");
    assert_eq!(status["recording_path"], second_path);
    assert_eq!(recordings(&rec).len(), 2);

    // The same service from Python, written from docs/ipc.md.
    let python = std::env::var("PYTHON").unwrap_or_else(|_| "python3".into());
    let script = workspace_root().join("ipc/examples/python/control.py");
    let out = Command::new(&python)
        .arg(&script)
        .args(["record_status", "--prefix", p, "--json"])
        .output()
        .unwrap_or_else(|e| panic!("{python} is needed (run .ci/setup): {e}"));
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: Value = serde_json::from_slice(&out.stdout).expect("JSON from control.py");
    assert_eq!(v["result"], "ok", "{v}");
    assert_eq!(v["recording_path"], second_path, "{v}");
    let out = Command::new(&python)
        .arg(&script)
        .args(["load_scene", "no-such-scene", "--prefix", p])
        .output()
        .expect("python");
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stdout).starts_with("not_found:"));
}

#[test]
fn a_client_without_a_daemon_fails_fast_and_says_so() {
    let prefix = unique_prefix("ctl-no-daemon");
    let started = Instant::now();
    let out = control(&prefix, &["record", "status", "--timeout", "2"]);
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("no hydrometrad answers") && stderr.contains(&prefix),
        "{stderr}"
    );
    assert!(
        started.elapsed() < Duration::from_secs(5),
        "took {:?}",
        started.elapsed()
    );
}

/// The newest topology revision on `<prefix>/cavity/topology` (history 1), waiting for the
/// service and a sample.
fn topology_revision(prefix: &str, timeout: Duration) -> u64 {
    use hydrometra_ipc::slice::{self, Topology};
    let names = hydrometra_ipc::ServiceNames::new(prefix).expect("prefix");
    let node = test_node();
    let deadline = Instant::now() + timeout;
    loop {
        if let Ok(service) = slice::open::<Topology, _>(&node, &names) {
            let subscriber = service.subscriber_builder().create().expect("subscriber");
            let mut newest = None;
            while Instant::now() < deadline {
                while let Some(sample) = subscriber.receive().expect("receive") {
                    newest = Some(sample.user_header().topology_revision);
                }
                if newest.is_some() {
                    break;
                }
                std::thread::sleep(Duration::from_millis(20));
            }
            if let Some(revision) = newest {
                return revision;
            }
        }
        assert!(Instant::now() < deadline, "no topology within {timeout:?}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn load_scene_switches_the_running_scene_through_preparing() {
    use hydrometra_ipc::status::scene_state;
    let prefix = unique_prefix("ctl-load-scene");
    let daemon = Daemon::start(
        &prefix,
        &[
            "--scene",
            "default",
            "--emulated",
            "default",
            "--status-rate-hz",
            "100",
        ],
    );
    let reader = StatusReader::connect(&prefix, Duration::from_secs(10));
    let runs =
        |s: &Status| s.scene_state == scene_state::RUNNING || s.scene_state == scene_state::IDLE;
    let before = last(
        reader.until("the scene running", Duration::from_secs(120), |s| {
            runs(s) && s.scene_frames > 30
        }),
    );
    assert_eq!(topology_revision(&prefix, Duration::from_secs(10)), 1);

    // The same built-in scene again: its atlas is cached, so it prepares in seconds.
    let response = ok(&daemon.prefix, &["load-scene", "default"]);
    let message = response["message"].as_str().unwrap_or_default();
    assert!(message.contains("loading scene default"), "{message}");
    let statuses = reader.until("the new scene running", Duration::from_secs(120), |s| {
        runs(s) && s.scene_frames > 0 && s.scene_frames < before.scene_frames
    });
    assert!(
        statuses
            .iter()
            .any(|s| s.scene_state == scene_state::PREPARING),
        "status never showed preparing"
    );
    // The re-created topology service carries the next revision.
    assert_eq!(topology_revision(&prefix, Duration::from_secs(10)), 2);
    let log = daemon.log();
    assert!(log.contains("switching the scene"), "{log}");
}
