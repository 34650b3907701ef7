//! `hydrometra fluid run` end to end: a moving-wall case file in, JSON on stdout and files out.

use std::process::Command;

fn case_path(name: &str) -> String {
    format!(
        "{}/../docs/fluid-cases/{name}.toml",
        env!("CARGO_MANIFEST_DIR")
    )
}

/// The stderr of `hydrometra fluid run --case CASE`, which must fail.
fn refused(case: &std::path::Path) -> String {
    let o = Command::new(env!("CARGO_BIN_EXE_hydrometra"))
        .args(["fluid", "run", "--case"])
        .arg(case)
        .output()
        .unwrap();
    assert!(!o.status.success());
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[test]
fn fluid_run_writes_probes_as_json_and_csv() {
    let out = std::env::temp_dir().join(format!("hydrometra-fluid-cli-{}", std::process::id()));
    // A shortened lid-driven cavity (moving wall).
    let text = std::fs::read_to_string(case_path("lid_driven_cavity"))
        .unwrap()
        .replace("end_s = 40.0", "end_s = 0.5");
    std::fs::create_dir_all(&out).unwrap();
    let case = out.join("lid.toml");
    std::fs::write(&case, text).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_hydrometra"))
        .args(["fluid", "run", "--case"])
        .arg(&case)
        .arg("--json")
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let stats = &v["statistics"];
    assert!(stats["steps"].as_u64().unwrap() > 0);
    assert!(stats["final_max_div_rel"].as_f64().unwrap() <= 1e-5);
    for key in [
        "ms_per_step_mean",
        "ms_per_step_p99",
        "projection_iterations_mean",
        "kinetic_energy_j",
        "simulated_time_s",
    ] {
        assert!(stats[key].is_number(), "{key}");
    }
    let probe = &v["probes"][0];
    assert_eq!(probe["name"], "vertical_centreline");
    assert_eq!(probe["samples"].as_array().unwrap().len(), 17);
    // The sample just below the lid moves with it.
    let top = &probe["samples"][16]["velocity_m_s"][0];
    assert!(top.as_f64().unwrap() > 0.3, "{top}");
    let csv = std::fs::read_to_string(out.join("probe_vertical_centreline.csv")).unwrap();
    assert_eq!(csv.lines().count(), 18);
    assert!(csv.starts_with("x_m,y_m,z_m,u_m_s,v_m_s,w_m_s,pressure_pa"));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["statistics"]["steps"], stats["steps"]);
    std::fs::remove_dir_all(&out).ok();
}

#[test]
fn fluid_run_rejects_a_malformed_case_naming_file_and_key() {
    let dir = std::env::temp_dir().join(format!("hydrometra-fluid-bad-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let case = dir.join("bad.toml");
    let text = std::fs::read_to_string(case_path("port_channel"))
        .unwrap()
        .replace(
            "velocity_m_s = [0.2, 0.0, 0.0]",
            "velocity_m_s = [0.2, 0.0]",
        );
    std::fs::write(&case, text).unwrap();
    let err = refused(&case);
    assert!(
        err.contains("bad.toml") && err.contains("velocity_m_s"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// A mesh region's file is found beside the case file whatever the working directory, and a
/// missing one is refused naming the case file, the region and the key.
#[test]
fn fluid_run_reads_a_mesh_beside_the_case_file() {
    let elsewhere = std::env::temp_dir();
    let o = Command::new(env!("CARGO_BIN_EXE_hydrometra"))
        .current_dir(&elsewhere)
        .args(["fluid", "run", "--json", "--case"])
        .arg(case_path("mesh_pipe"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["statistics"]["steady_reached"], true);
    let dir = elsewhere.join(format!("hydrometra-fluid-mesh-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let case = dir.join("pipe.toml");
    std::fs::write(
        &case,
        std::fs::read_to_string(case_path("mesh_pipe")).unwrap(),
    )
    .unwrap();
    let err = refused(&case);
    assert!(
        err.contains("pipe.toml") && err.contains("region[0].file") && err.contains("pipe_mm.obj"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).ok();
}
