//! hydrometrad's command line: bad configuration and arguments are reported with the key, the
//! value and what was expected, before anything starts.

use std::process::Command;

use hydrometra_hil_tests::*;

fn run(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(binary("hydrometrad"))
        .args(args)
        .output()
        .expect("run hydrometrad");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn print_default_config_round_trips_through_config() {
    let (ok, stdout, _) = run(&["--print-default-config"]);
    assert!(ok);
    assert!(
        stdout.contains("tick_rate_hz = 1000.0")
            && stdout.contains("service_prefix = \"hydrometra/v1\"")
    );
    let dir = temp_dir("cfg");
    let path = dir.join("hydrometrad.toml");
    std::fs::write(&path, &stdout).unwrap();
    // The printed file is a valid config: run it briefly on the emulated rig.
    let prefix = unique_prefix("cfg");
    let (ok, _, stderr) = run(&[
        "--config",
        path.to_str().unwrap(),
        "--emulated",
        "default",
        "--service-prefix",
        &prefix,
        "--duration",
        "0.5",
    ]);
    assert!(ok, "{stderr}");
    assert!(stderr.contains("stopped:"), "{stderr}");
}

#[test]
fn config_errors_name_file_key_value_and_expectation() {
    let dir = temp_dir("badcfg");
    let path = dir.join("bad.toml");
    std::fs::write(
        &path,
        "[loop]\ntick_rate_hz = 1000.0\nstatus_rate_hz = 300.0\n",
    )
    .unwrap();
    let (ok, _, stderr) = run(&["--config", path.to_str().unwrap()]);
    assert!(!ok);
    assert!(
        stderr.contains(path.to_str().unwrap())
            && stderr.contains("loop.status_rate_hz")
            && stderr.contains("300")
            && stderr.contains("expected"),
        "{stderr}"
    );
    std::fs::write(&path, "[rig]\nmode = \"serial\"\n").unwrap();
    let (ok, _, stderr) = run(&["--config", path.to_str().unwrap()]);
    assert!(!ok);
    assert!(
        stderr.contains("line 2") && stderr.contains("serial") && stderr.contains("mode"),
        "{stderr}"
    );
}

#[test]
fn bad_flags_and_missing_scenarios_are_named() {
    let (ok, _, stderr) = run(&["--emulated", "default", "--tick-rate-hz", "0"]);
    assert!(
        !ok && stderr.contains("loop.tick_rate_hz") && stderr.contains("command line"),
        "{stderr}"
    );
    let (ok, _, stderr) = run(&[
        "--emulated",
        "/nonexistent/scenario.toml",
        "--duration",
        "1",
    ]);
    assert!(
        !ok && stderr.contains("/nonexistent/scenario.toml") && stderr.contains("built-in"),
        "{stderr}"
    );
    let (ok, _, stderr) = run(&["--service-prefix", "a//b", "--emulated", "default"]);
    assert!(!ok && stderr.contains("ipc.service_prefix"), "{stderr}");
    let (ok, _, stderr) = run(&["--duration=-1", "--emulated", "default"]);
    assert!(!ok && stderr.contains("--duration"), "{stderr}");
}
