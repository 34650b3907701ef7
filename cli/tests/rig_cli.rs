//! `hydrometra rig emulate` in one process and `hydrometra rig probe` in another: the probe prints
//! the scenario's state in SI units.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use hydrometra_units::PA_PER_MMHG;

const HYDROMETRA: &str = env!("CARGO_BIN_EXE_hydrometra");

fn scratch(name: &str) -> PathBuf {
    let dir =
        std::env::temp_dir().join(format!("hydrometra-rig-cli-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn wait_for_path(p: &Path) {
    let deadline = Instant::now() + Duration::from_secs(20);
    while std::fs::symlink_metadata(p).is_err() {
        assert!(Instant::now() < deadline, "{} never appeared", p.display());
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn probe_prints_the_emulated_scenario_state() {
    let dir = scratch("state");
    let scenario = dir.join("hold.toml");
    std::fs::write(
        &scenario,
        "name = \"hold\"\n[[keyframe]]\nt_s = 0.0\nvalve_in = 0.25\nvalve_out = 0.5\n\
         pump_mmhg = 95.0\ntip_mm = [1.0, -2.0, 40.0]\nview_dir = [0.0, 0.6, 0.8]\nbuttons = 5\n",
    )
    .unwrap();
    let link = dir.join("rig");
    let mut emu = Command::new(HYDROMETRA)
        .args(["rig", "emulate", "--seconds", "8", "--scenario"])
        .arg(&scenario)
        .arg("--link")
        .arg(&link)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    wait_for_path(&link);
    let out = Command::new(HYDROMETRA)
        .args(["rig", "probe", "--seconds", "1", "--json", "--device"])
        .arg(&link)
        .output()
        .unwrap();
    let _ = emu.kill();
    let _ = emu.wait();
    let _ = std::fs::remove_dir_all(&dir);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["link_state"], "Connected");
    assert_eq!(v["device"]["serial_number"], "EMU-0001");
    assert_eq!(v["counters"]["crc_errors"], 0);
    // One second at 250 Hz plus heartbeats: well over 200 frames.
    assert!(v["counters"]["frames"].as_u64().unwrap() > 200, "{v}");
    let l = &v["latest"];
    let f = |x: &serde_json::Value| x.as_f64().unwrap();
    // Quantisation of the default calibration: 1/3700 opening, 200/4095 mmHg.
    assert!(
        (f(&l["valve_in_opening"]) - 0.25).abs() <= 1.0 / 3700.0,
        "{l}"
    );
    assert!(
        (f(&l["valve_out_opening"]) - 0.5).abs() <= 1.0 / 3700.0,
        "{l}"
    );
    assert!(
        (f(&l["pump_set_pressure_pa"]) - 95.0 * PA_PER_MMHG).abs() <= 200.0 / 4095.0 * PA_PER_MMHG
    );
    let tip = &l["scope"]["tip_position_m"];
    for (i, want) in [0.001, -0.002, 0.040].iter().enumerate() {
        assert!((f(&tip[i]) - want).abs() < 1e-6, "{l}");
    }
    let dir_v = &l["scope"]["view_direction"];
    for (i, want) in [0.0, 0.6, 0.8].iter().enumerate() {
        assert!((f(&dir_v[i]) - want).abs() < 1e-5, "{l}");
    }
    assert_eq!(l["scope"]["valid"], true);
    assert_eq!(l["buttons"], 5);
    assert!(f(&v["last_sample_age_s"]) < 0.1);
}

#[test]
fn probe_of_a_missing_device_fails_naming_it() {
    let out = Command::new(HYDROMETRA)
        .args([
            "rig",
            "probe",
            "--seconds",
            "0.3",
            "--device",
            "/nonexistent/hydrometra-rig",
        ])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("/nonexistent/hydrometra-rig") && err.contains("no sample"),
        "{err}"
    );
}

#[test]
fn emulate_rejects_a_bad_scenario_naming_line_and_key() {
    let dir = scratch("bad");
    let scenario = dir.join("bad.toml");
    std::fs::write(
        &scenario,
        "[[keyframe]]\nt_s = 0.0\nvalve_in = 2.0\nvalve_out = 0.0\npump_mmhg = 80.0\n\
         tip_mm = [0.0, 0.0, 20.0]\nview_dir = [0.0, 0.0, 1.0]\n",
    )
    .unwrap();
    let out = Command::new(HYDROMETRA)
        .args(["rig", "emulate", "--seconds", "1", "--scenario"])
        .arg(&scenario)
        .output()
        .unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("bad.toml") && err.contains("line 3") && err.contains("keyframe[0].valve_in"),
        "{err}"
    );
}
