//! The Python flow example (`ipc/examples/python/flow_sample.py --volume`) against `hydrometrad
//! --emulated default` running the built-in default scene with cut cells: the fluid volume of
//! the published fluid volume fractions, `sum(fraction) h^3`, against the volume the cavity mesh
//! of the same scene frame encloses (docs/ipc.md, "Flow field").
//!
//! Needs `python3` (or `$PYTHON`) with iceoryx2 and numpy (`.ci/setup`).

use std::process::Command;

use hydrometra_hil_tests::{daemon_on_edited_default_scene, python_with_numpy, workspace_root};
use hydrometra_sim::scene::SceneDesc;
use serde_json::Value;

/// Seconds the example reads: the default scenario's scope goes from the cervical canal into the
/// cavity at about 18 s after the daemon's start, so the run sees both.
const SECONDS: f64 = 24.0;

/// The scene's own figure for the same scenario with cut cells: `hydrometra scene run --seconds
/// 30 --every 0` (1.2 mm, cut cells on) put the grid's fluid volume 4.7 to 9.2 % below the
/// surface's in every frame, the cavity's part in the scope's whole cells and the os's open
/// cells (docs/scene.md, "Cut cells"). The published fractions add the os cells' part back, so
/// they fall within this band's outer edge.
const SCENE_SHORTFALL: f64 = 0.10;

/// What the fractions guarantee in any scene, per field: the exact fractions sum to the volume
/// the surface they follow encloses, less the cavity's part in the scope's cells (at most one
/// cell each), each byte within 1/510 of its fraction (only cut cells are inexact), plus the
/// rounding of the mesh's `f32` positions (1e-5 of the volume, as the scene test of the cut cells
/// finds). The surface they follow is within `move_fraction` cells of the mesh at every vertex
/// (the scene's `skip.cut_move_fraction`), so within `move_fraction h A` of its volume (A: the
/// mesh's area).
fn check_bounds(line: &Value, move_fraction: f64) -> f64 {
    let f = |k: &str| {
        line[k]
            .as_f64()
            .unwrap_or_else(|| panic!("{k} missing: {line}"))
    };
    let (fluid, cavity, h) = (f("fluid_volume_m3"), f("cavity_volume_m3"), f("spacing_m"));
    let cell = h * h * h;
    let quantisation = f("cut_cells") / 510.0 * cell;
    let following = move_fraction * h * f("cavity_area_m2");
    let slack = quantisation + following + 1e-5 * cavity;
    assert!(
        fluid <= cavity + slack,
        "fluid {fluid:e} m^3 above the cavity's {cavity:e} (slack {slack:e}): {line}"
    );
    let scope = f("scope_cells") * cell;
    assert!(
        fluid >= cavity - scope - slack,
        "fluid {fluid:e} m^3 below the cavity's {cavity:e} less the scope's {} cells: {line}",
        f("scope_cells")
    );
    fluid / cavity - 1.0
}

#[test]
fn python_flow_example_the_fractions_fill_the_cavity_mesh_with_cut_cells() {
    let python = python_with_numpy();
    let mut move_fraction = f64::NAN;
    let (prefix, _daemon, _reader) = daemon_on_edited_default_scene("flow-fractions", |base| {
        // Cut cells are the default scene's own setting: the scene runs as the daemon ships it.
        assert!(
            base.contains("cut_cells = true"),
            "the default scene file no longer has cut cells on"
        );
        let desc = SceneDesc::parse(base, "the default scene", None).expect("the default scene");
        move_fraction = desc.skip.cut_move_fraction;
        base.to_string()
    });
    let out = Command::new(&python)
        .arg(workspace_root().join("ipc/examples/python/flow_sample.py"))
        .args(["--prefix", &prefix, "--volume", "--json", "--timeout", "30"])
        .args(["--seconds", &SECONDS.to_string()])
        .output()
        .expect("run the Python flow example");
    assert!(
        out.status.success(),
        "the Python flow example failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let lines: Vec<Value> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).expect("one JSON object per line"))
        .collect();
    assert!(
        lines.len() >= 30,
        "only {} flow fields in {SECONDS} s",
        lines.len()
    );
    let mut shortfall = Vec::new();
    for line in &lines {
        let relative = check_bounds(line, move_fraction);
        assert!(
            relative >= -SCENE_SHORTFALL,
            "fluid {:+.2} % of the cavity mesh's volume, beyond the scene's {} %: {line}",
            100.0 * relative,
            100.0 * SCENE_SHORTFALL
        );
        shortfall.push(relative);
    }
    let (worst, best) = shortfall
        .iter()
        .fold((0.0f64, f64::NEG_INFINITY), |(w, b), &r| {
            (w.min(r), b.max(r))
        });
    let (first, last) = (&lines[0], &lines[lines.len() - 1]);
    println!(
        "{} fields over {:.1} s of scene time: fluid volume of the fractions {:+.2} to {:+.2} % of \
         the cavity mesh's; first {:.3} vs {:.3} ml ({} scope cells), last {:.3} vs {:.3} ml ({} \
         scope cells)",
        lines.len(),
        last["sim_time_s"].as_f64().unwrap_or(0.0) - first["sim_time_s"].as_f64().unwrap_or(0.0),
        100.0 * worst,
        100.0 * best,
        first["fluid_volume_m3"].as_f64().unwrap_or(0.0) * 1e6,
        first["cavity_volume_m3"].as_f64().unwrap_or(0.0) * 1e6,
        first["scope_cells"],
        last["fluid_volume_m3"].as_f64().unwrap_or(0.0) * 1e6,
        last["cavity_volume_m3"].as_f64().unwrap_or(0.0) * 1e6,
        last["scope_cells"]
    );
}
