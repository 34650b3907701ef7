//! `hydrometra scene converge` end to end on a coarse scene: the table's structure, finite
//! figures, the reference from the cache on a second run, and bad arguments refused by name.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// A coarse scene file (a small mesh, few atlas levels) with a bleed, and the atlas cache dir.
fn coarse_scene(dir: &Path) -> (PathBuf, PathBuf) {
    let text = "name = \"coarse-converge\"\n[anatomy]\nparity = \"parous\"\n[anatomy.mesh]\n\
                target_tets = 8000\n[atlas]\nlevels = 7\n[stages]\nparticles = true\n\
                [[particles.blood.sources]]\nposition_mm = [0.0, 12.0, 55.0]\nrate_ml_min = 1.0\n";
    std::fs::create_dir_all(dir).unwrap();
    let scene = dir.join("coarse.toml");
    std::fs::write(&scene, text).unwrap();
    let cache = Path::new(env!("CARGO_TARGET_TMPDIR")).join("converge-atlas-cache");
    (scene, cache)
}

fn converge(scene: &Path, cache: &Path, out: &Path, extra: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_hydrometra"))
        .args(["scene", "converge", "--scene"])
        .arg(scene)
        .arg("--cache-dir")
        .arg(cache)
        .arg("--out")
        .arg(out)
        .args(extra)
        .output()
        .unwrap()
}

fn finite(v: &serde_json::Value, what: &str) -> f64 {
    let x = v
        .as_f64()
        .unwrap_or_else(|| panic!("{what}: {v} is not a number"));
    assert!(x.is_finite(), "{what}: {x}");
    x
}

#[test]
fn converge_prints_a_table_of_finite_errors_and_orders_and_caches_the_reference() {
    let dir = std::env::temp_dir().join(format!("hydrometra-converge-{}", std::process::id()));
    let (scene, cache) = coarse_scene(&dir);
    let out = dir.join("out");
    let args = [
        "--sizes-mm",
        "1.8,1.2",
        "--reference-mm",
        "0.9",
        "--seconds",
        "1",
        "--window-s",
        "0.5",
        "--bleed-onset-s",
        "0.2",
        "--bleed-stop-s",
        "0.6",
    ];
    let o = converge(&scene, &cache, &out, &args);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    let md = String::from_utf8_lossy(&o.stdout);
    for head in [
        "| voxel mm |",
        "| 1.8 |",
        "| 1.2 |",
        "| 0.9 (ref) |",
        "| error of |",
        "| fit |",
    ] {
        assert!(md.contains(head), "no `{head}` in\n{md}");
    }
    let t: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("table.json")).unwrap()).unwrap();
    let rows = t["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 2);
    for (r, mm) in rows.iter().zip([1.8, 1.2]) {
        assert_eq!(r["voxel_mm"].as_f64(), Some(mm));
        assert!(finite(&r["step_ms_mean"], "step ms") > 0.0);
        finite(&r["volume_vs_surface_mean_pct"], "volume vs surface");
        assert!(finite(&r["volume_vs_reference_mean_pct"], "volume vs reference") >= 0.0);
        for i in 0..3 {
            assert!(finite(&r["jet_m_s"][i], "jet speed") >= 0.0);
            assert!(finite(&r["jet_error"][i], "jet error") >= 0.0);
        }
        assert!(finite(&r["fundal_m_s"], "fundal speed") > 0.0);
        finite(&r["fundal_error"], "fundal error");
        // No clearing is promised in a second of scenario; a time, where there is one, is finite.
        if !r["time_to_clear_s"].is_null() {
            finite(&r["time_to_clear_s"], "time to clear");
        }
    }
    let orders = t["orders"].as_array().unwrap();
    assert_eq!(orders.len(), 6);
    for o in orders {
        assert_eq!(o["successive"].as_array().unwrap().len(), 1);
    }
    assert!(out.join("run-0.900mm.json").exists());
    // The jet's speed is the peak of a disk centred on the view line's point: never below it.
    let run: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("run-1.200mm.json")).unwrap())
            .unwrap();
    for (peaks, on_line) in run["jet_m_s"]
        .as_array()
        .unwrap()
        .iter()
        .zip(run["jet_on_line_m_s"].as_array().unwrap())
    {
        for (p, l) in peaks
            .as_array()
            .unwrap()
            .iter()
            .zip(on_line.as_array().unwrap())
        {
            if let (Some(p), Some(l)) = (p.as_f64(), l.as_f64()) {
                assert!(p >= l, "peak {p} below the line's {l}");
            }
        }
    }

    // Again: the reference (and here the sizes) come from the cache, and the table is the same.
    let again = converge(&scene, &cache, &out, &args);
    assert!(again.status.success());
    let stderr = String::from_utf8_lossy(&again.stderr);
    assert!(stderr.contains("0.9 mm: from"), "{stderr}");
    assert_eq!(again.stdout, o.stdout);

    // Bad arguments: refused, naming the option.
    for (bad, named) in [
        (
            vec!["--sizes-mm", "0.6,1.2", "--reference-mm", "0.3"],
            "--sizes-mm",
        ),
        (
            vec!["--sizes-mm", "0.2", "--reference-mm", "0.3"],
            "--sizes-mm",
        ),
        (vec!["--reference-mm=-1"], "--reference-mm"),
        (vec!["--seconds", "0"], "--seconds"),
        (vec!["--window-s", "30", "--seconds", "2"], "--window-s"),
        (
            vec!["--bleed-stop-s", "50", "--seconds", "2"],
            "--bleed-stop-s",
        ),
    ] {
        let o = converge(&scene, &cache, &dir.join("bad"), &bad);
        assert!(!o.status.success(), "{bad:?} was accepted");
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(e.contains(named) && !e.contains("panicked"), "{bad:?}: {e}");
    }
    let o = Command::new(env!("CARGO_BIN_EXE_hydrometra"))
        .args([
            "scene",
            "converge",
            "--scene",
            "default",
            "--bleed-stop-s",
            "1",
        ])
        .arg("--out")
        .arg(dir.join("bad"))
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && e.contains("no blood source"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}
