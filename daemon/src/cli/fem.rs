//! `hydrometra fem sphere`: the thick-walled sphere verification case for any radii, material and
//! pressures, printing the inner stretch and cavity volume per pressure.

use anyhow::{bail, Result};
use clap::{Args, Subcommand};
use hydrometra_sim::fem::material::MaterialSet;
use hydrometra_sim::fem::{analytic, testmesh, FemModel, Solver};
use std::path::PathBuf;
use std::time::Instant;

/// `hydrometra fem ...` cases.
#[derive(Subcommand, Debug)]
pub enum FemCommand {
    /// Inflate a thick-walled sphere (octant mesh with symmetry planes) by internal pressure.
    Sphere(SphereArgs),
}

/// Arguments of `hydrometra fem sphere`.
#[derive(Args, Debug)]
pub struct SphereArgs {
    /// Inner radius A (m, or any length unit: the result is a stretch).
    #[arg(long)]
    pub inner: f64,
    /// Outer radius B > A (same unit as --inner).
    #[arg(long)]
    pub outer: f64,
    /// Material TOML; its `[myometrium]` material is used (Pa).
    #[arg(long)]
    pub material: PathBuf,
    /// Increasing internal pressures in Pa (the material's unit), comma separated.
    #[arg(long, value_delimiter = ',', required = true)]
    pub pressures: Vec<f64>,
    /// Element layers through the wall (graded geometrically); the surface divisions follow
    /// (at most 24 per octant arc unless --divisions is given).
    #[arg(long, default_value_t = 12)]
    pub resolution: usize,
    /// Edges along each octant arc (overrides the automatic choice).
    #[arg(long)]
    pub divisions: Option<usize>,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// Runs a `fem` case.
pub fn run(cmd: &FemCommand) -> Result<()> {
    match cmd {
        FemCommand::Sphere(a) => sphere(a),
    }
}

fn sphere(a: &SphereArgs) -> Result<()> {
    if !(a.inner > 0.0 && a.outer > a.inner && a.outer.is_finite()) {
        bail!(
            "--inner {} --outer {}: expected 0 < inner < outer",
            a.inner,
            a.outer
        );
    }
    if a.resolution < 1 || a.resolution > 64 {
        bail!("--resolution {}: expected 1..=64 layers", a.resolution);
    }
    for (i, w) in a.pressures.windows(2).enumerate() {
        if w[1].partial_cmp(&w[0]) != Some(std::cmp::Ordering::Greater) {
            bail!("--pressures: entry {} ({}) is not above entry {} ({}); expected increasing pressures", i + 1, w[1], i, w[0]);
        }
    }
    if let Some(p) = a.pressures.iter().find(|p| !p.is_finite() || **p <= 0.0) {
        bail!("--pressures: {p} is not a positive pressure");
    }
    let materials = MaterialSet::from_file(&a.material)?;
    let mat = materials.myometrium.clone();
    let layers = a.resolution;
    // Arcs divided to match the mean layer thickness at mid-wall, capped at 24: beyond that the
    // surface is no longer the dominant error (measured, docs/fem.md).
    let mean_layer = (a.outer - a.inner) / layers as f64;
    let auto =
        (std::f64::consts::FRAC_PI_2 * 0.5 * (a.inner + a.outer) / mean_layer).ceil() as usize;
    let divisions = a.divisions.unwrap_or(auto.clamp(8, 24));
    let case = testmesh::thick_sphere_octant(a.inner, a.outer, divisions, layers);
    let model = FemModel::from_parts(
        case.positions_m.clone(),
        case.tets.clone(),
        &MaterialSet::uniform(mat.clone()),
        case.fixed_dofs.clone(),
        case.cavity.clone(),
    )?;
    let t0 = Instant::now();
    let mut solver = Solver::new(&model, Default::default())?;
    let mut state = solver.rest_state();
    let v0 = state.cavity_volume_m3 * case.volume_factor;
    let mut rows = Vec::new();
    for &p in &a.pressures {
        state = solver.solve_to_pressure(&state, p)?;
        let v = state.cavity_volume_m3 * case.volume_factor;
        let la = (v / v0).cbrt();
        let exact = analytic::sphere_inner_stretch(&mat, a.inner, a.outer, p);
        rows.push(serde_json::json!({
            "pressure": p,
            "inner_stretch": la,
            "cavity_volume": v,
            "cavity_volume_exact_geometry": 4.0 / 3.0 * std::f64::consts::PI * (a.inner * la).powi(3),
            "newton_iterations": state.newton_iterations,
            "incompressible_integral_inner_stretch": exact,
            "relative_error_of_stretch_minus_1": exact.map(|e| (la - 1.0) / (e - 1.0) - 1.0),
        }));
    }
    let out = serde_json::json!({
        "case": "thick sphere, octant with symmetry planes, linear tets with nodally averaged J",
        "inner": a.inner, "outer": a.outer,
        "material": mat,
        "layers": layers, "divisions": divisions, "tets": case.tets.len(),
        "seconds": t0.elapsed().as_secs_f64(),
        "results": rows,
    });
    if a.json {
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        println!("thick sphere A = {} B = {}  layers {layers}  divisions {divisions}  tets {}  ({:.1} s)", a.inner, a.outer, case.tets.len(), t0.elapsed().as_secs_f64());
        println!(
            "{:>14} {:>12} {:>16} {:>14} {:>12}",
            "pressure", "stretch la", "cavity volume", "oracle la", "err(la-1) %"
        );
        for r in &rows {
            let oracle = r["incompressible_integral_inner_stretch"].as_f64();
            let err = r["relative_error_of_stretch_minus_1"].as_f64();
            println!(
                "{:>14.6e} {:>12.6} {:>16.6e} {:>14} {:>12}",
                r["pressure"].as_f64().unwrap_or(f64::NAN),
                r["inner_stretch"].as_f64().unwrap_or(f64::NAN),
                r["cavity_volume"].as_f64().unwrap_or(f64::NAN),
                oracle.map_or("beyond limit".to_string(), |v| format!("{v:.6}")),
                err.map_or("-".to_string(), |v| format!("{:.3}", 100.0 * v)),
            );
        }
        println!("oracle: incompressible thick-sphere integral P = int W'(l)/(l^3-1) dl (references.md); the FEM uses the file's finite kappa");
    }
    Ok(())
}
