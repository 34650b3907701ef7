//! End-to-end checks of `hydrometra fem sphere` and `hydrometra precompute` through the binary.

use hydrometra_sim::atlas::Atlas;
use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn out_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("hydrometra-fem-cli-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Runs `hydrometra ARGS... [--material FILE]`.
fn hydrometra(args: &[&str], material: Option<&Path>) -> Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_hydrometra"));
    cmd.args(args);
    if let Some(m) = material {
        cmd.args([OsStr::new("--material"), m.as_os_str()]);
    }
    cmd.output().unwrap()
}

/// Its JSON on stdout, after checking that it succeeded.
/// `hydrometra fem sphere --inner 1 --outer 2 FLAG VALUE` fails and its error names FLAG.
fn assert_sphere_refused_naming(flag: &str, value: &str, material: &Path) {
    let bad = hydrometra(
        &["fem", "sphere", "--inner", "1", "--outer", "2", flag, value],
        Some(material),
    );
    assert!(!bad.status.success(), "{flag} {value} was accepted");
    assert!(
        String::from_utf8_lossy(&bad.stderr).contains(flag),
        "the error does not name {flag}: {}",
        String::from_utf8_lossy(&bad.stderr)
    );
}

fn success_json(out: &Output) -> serde_json::Value {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

#[test]
fn fem_sphere_json_reports_stretch_near_the_integral_oracle() {
    let dir = out_dir("sphere");
    let mat = dir.join("n2.toml");
    std::fs::write(
        &mat,
        "[myometrium]\nmu_pa = [0.5, 0.4]\nkappa_pa = 1000.0\n",
    )
    .unwrap();
    let out = hydrometra(
        &[
            "fem",
            "sphere",
            "--inner",
            "0.8",
            "--outer",
            "1.0",
            "--resolution",
            "4",
            "--json",
            "--pressures",
            "0.04,0.08",
        ],
        Some(&mat),
    );
    let v = success_json(&out);
    let rows = v["results"].as_array().unwrap();
    assert_eq!(rows.len(), 2);
    for r in rows {
        let err = r["relative_error_of_stretch_minus_1"].as_f64().unwrap();
        // Coarse (4 layers): a few per cent at most, converging with --resolution.
        assert!(err.abs() < 0.03, "error {err}");
        assert!(r["inner_stretch"].as_f64().unwrap() > 1.0);
    }
    // Bad input names the argument.
    assert_sphere_refused_naming("--pressures", "0.3,0.1", &mat);
}

#[test]
fn fem_sphere_volume_control_passes_the_neo_hookean_pressure_maximum() {
    // P(la) of the neo-Hookean thick sphere (A/B = 0.5) peaks near la = 1.85: pressure control
    // cannot pass it, cavity-volume control can, and the pressure then falls.
    let dir = out_dir("volume");
    let mat = dir.join("nh.toml");
    std::fs::write(&mat, "[myometrium]\nmu_pa = [0.5]\nkappa_pa = 1000.0\n").unwrap();
    let out = hydrometra(
        &[
            "fem",
            "sphere",
            "--inner",
            "1",
            "--outer",
            "2",
            "--element",
            "tet10",
            "--resolution",
            "3",
            "--divisions",
            "6",
            "--control",
            "volume",
            "--stretches",
            "1.3,1.6,1.85,2.0",
            "--json",
        ],
        Some(&mat),
    );
    let v = success_json(&out);
    assert_eq!(v["element"], "tet10");
    let rows = v["results"].as_array().unwrap();
    let p: Vec<f64> = rows
        .iter()
        .map(|r| r["pressure"].as_f64().unwrap())
        .collect();
    eprintln!("P at la 1.3, 1.6, 1.85, 2.0: {p:?}");
    assert!(
        p[1] > p[0] && p[2] > p[1],
        "rising before the maximum: {p:?}"
    );
    assert!(p[3] < p[2], "falling after the maximum: {p:?}");
    for r in rows {
        let err = r["relative_error_of_pressure"].as_f64().unwrap();
        assert!(
            err.abs() < 0.01,
            "pressure error {err} at la {}",
            r["inner_stretch"]
        );
        assert!(
            (r["inner_stretch"].as_f64().unwrap() - r["exact_inner_stretch"].as_f64().unwrap())
                .abs()
                < 1e-6
        );
    }
    // Stretches with pressure control is a mistake that names the flag.
    assert_sphere_refused_naming("--stretches", "1.2", &mat);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn precompute_writes_a_loadable_atlas_csv_and_paraview_series() {
    let dir = out_dir("precompute");
    let anatomy = dir.join("anatomy.toml");
    std::fs::write(&anatomy, "[mesh]\ntarget_tets = 20000\n").unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_hydrometra"))
        .args(["precompute", "--max-mmhg", "30", "--levels", "3", "--out"])
        .arg(&dir)
        .arg("--anatomy")
        .arg(&anatomy)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let atlas = Atlas::read(&dir.join("atlas.hma")).unwrap();
    assert_eq!(atlas.level_count(), 3);
    assert!((atlas.pressure_pa[2] - 30.0 * hydrometra_units::PA_PER_MMHG).abs() < 1e-6);
    assert!(atlas.cavity_volume_m3.windows(2).all(|w| w[1] > w[0]));
    let csv = std::fs::read_to_string(dir.join("pv_curve.csv")).unwrap();
    assert_eq!(csv.lines().count(), 4);
    let pvd = std::fs::read_to_string(dir.join("atlas.pvd")).unwrap();
    assert_eq!(pvd.matches("<DataSet").count(), 3);
    assert!(dir.join("vtu/level_002.vtu").exists());
    // A truncated copy is rejected with a size error naming the file.
    let bytes = std::fs::read(dir.join("atlas.hma")).unwrap();
    let cut = dir.join("cut.hma");
    std::fs::write(&cut, &bytes[..bytes.len() - 100]).unwrap();
    let err = Atlas::read(&cut).unwrap_err().to_string();
    assert!(err.contains("cut.hma") && err.contains("expected"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}
