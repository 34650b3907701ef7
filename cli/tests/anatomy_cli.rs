//! `hydrometra anatomy` end to end: defaults round-trip, outputs written, bad input named.

use std::process::Command;

fn hydrometra() -> Command {
    Command::new(env!("CARGO_BIN_EXE_hydrometra"))
}

fn temp_dir(tag: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!(
        "hydrometra-anatomy-cli-{tag}-{}",
        std::process::id()
    ));
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn print_defaults_then_generate_writes_vtu_summary_and_mesh() {
    let dir = temp_dir("ok");
    let out = hydrometra()
        .args(["anatomy", "--print-defaults", "--preset", "nulliparous"])
        .output()
        .unwrap();
    assert!(out.status.success());
    let mut text = String::from_utf8(out.stdout).unwrap();
    assert!(text.contains("fundal_cavity_width_mm = 27.0"), "{text}");
    text = text.replace("target_tets = 35000", "target_tets = 6000");
    let params = dir.join("uterus.toml");
    std::fs::write(&params, text).unwrap();
    let out_dir = dir.join("out");
    let out = hydrometra()
        .args(["anatomy", "--params"])
        .arg(&params)
        .arg("--out")
        .arg(&out_dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("summary.json")).unwrap())
            .unwrap();
    assert_eq!(summary["params"]["parity"], "nulliparous");
    let tets = summary["tets"].as_u64().unwrap();
    assert!((5000..=7000).contains(&tets), "{tets} tets");
    let mesh: hydrometra_sim::mesh::TetMesh =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("mesh.json")).unwrap()).unwrap();
    assert_eq!(mesh.tets.len() as u64, tets);
    let vtu = std::fs::read_to_string(out_dir.join("uterus.vtu")).unwrap();
    assert!(vtu.contains(&format!("NumberOfCells=\"{tets}\"")));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_parameter_file_names_the_file_and_the_key() {
    let dir = temp_dir("bad");
    let params = dir.join("bad.toml");
    std::fs::write(
        &params,
        "corpus_width_mm = 52\nfundal_cavity_width_mm = 50\n",
    )
    .unwrap();
    let out = hydrometra()
        .args(["anatomy", "--params"])
        .arg(&params)
        .arg("--out")
        .arg(dir.join("out"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("bad.toml") && err.contains("fundal_cavity_width_mm"),
        "{err}"
    );
    std::fs::write(&params, "uterine_length_mm = \"long\"\n").unwrap();
    let out = hydrometra()
        .args(["anatomy", "--params"])
        .arg(&params)
        .arg("--out")
        .arg(dir.join("out"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("uterine_length_mm"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
