//! `hydrometra precompute`: the FEM pressure sweep of an anatomy, written as a deformation atlas,
//! a ParaView series (one VTU per level and a PVD collection) and the P-V curve as CSV.

use anyhow::{bail, Context, Result};
use clap::Args;
use hydrometra_sim::anatomy::{self, AnatomyParams};
use hydrometra_sim::atlas::{self, Atlas, AtlasLevel};
use hydrometra_sim::fem::material::MaterialSet;
use hydrometra_sim::fem::{Element, Equilibrium, FemModel, Solver, SolverOptions};
use hydrometra_sim::mesh::TetMesh;
use hydrometra_sim::units::{m3_to_ml, mmhg_to_pa, pa_to_mmhg};
use hydrometra_sim::vtk;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Arguments of `hydrometra precompute`.
#[derive(Args, Debug)]
pub struct PrecomputeArgs {
    /// Anatomy: an AnatomyParams TOML (the mesh is generated in-process) or a mesh JSON file
    /// (`*.json`, a serialized TetMesh). Omitted: the default anatomy.
    #[arg(long)]
    pub anatomy: Option<PathBuf>,
    /// Material TOML (`[myometrium]`, `[fibroid]`, `[polyp]` with `mu_pa = [...]`, `kappa_pa`).
    /// Omitted: the built-in calibrated default.
    #[arg(long)]
    pub material: Option<PathBuf>,
    /// Highest pressure in mmHg.
    #[arg(long, default_value_t = 150.0)]
    pub max_mmhg: f64,
    /// Number of levels, equally spaced from 0 to --max-mmhg (both included).
    #[arg(long, default_value_t = 25)]
    pub levels: usize,
    /// Output directory (created if missing).
    #[arg(long)]
    pub out: PathBuf,
    /// Skip the VTU/PVD series.
    #[arg(long)]
    pub no_vtu: bool,
    /// Also solve the midpoint of every level interval (twice the work) and report the replay
    /// error (Hermite and linear) against these held-out states in summary.json.
    #[arg(long)]
    pub holdout: bool,
    /// Finite element: tet4 (linear tets, nodally averaged J: the fast default) or tet10
    /// (quadratic, mean dilatation; mid-edge nodes on the chords, since the anatomy mesh carries
    /// no curved geometry): the accurate reference, several times slower. The atlas, VTU and
    /// CSV describe the mesh vertices (tet10 mid-edge nodes are solved but not written); the
    /// cavity volume is the solved (curved, for tet10) one.
    #[arg(long, default_value_t = Element::Tet4)]
    pub element: Element,
}

/// Replay error of the atlas against held-out FEM states.
fn holdout_errors(
    atlas: &Atlas,
    mesh: &TetMesh,
    held: &[&Equilibrium],
) -> Result<serde_json::Value> {
    let n = atlas.vertex_count();
    let mut out = vec![[0.0f32; 3]; n];
    let max_disp_m = held
        .iter()
        .flat_map(|s| {
            s.positions_m
                .iter()
                .zip(&mesh.positions_m)
                .map(|(x, x0)| dist(*x, *x0))
        })
        .fold(0.0, f64::max);
    let mut report = serde_json::Map::new();
    for (name, hermite) in [("hermite", true), ("linear", false)] {
        let (mut max_err, mut sum_sq, mut count, mut max_vol_err) =
            (0.0f64, 0.0f64, 0usize, 0.0f64);
        for s in held {
            if hermite {
                atlas.positions_at(s.pressure_pa, &mut out)?;
            } else {
                atlas.positions_at_linear(s.pressure_pa, &mut out)?;
            }
            let replayed: Vec<[f64; 3]> = out.iter().map(|p| p.map(f64::from)).collect();
            for (a, b) in replayed.iter().zip(&s.positions_m) {
                let e = dist(*a, *b);
                max_err = max_err.max(e);
                sum_sq += e * e;
                count += 1;
            }
            let closure = |x: &[[f64; 3]]| {
                hydrometra_sim::mesh::cavity_volume_m3(
                    x,
                    &mesh.cavity_triangles,
                    &mesh.cavity_opening_loop,
                )
            };
            // Both on the vertex mesh (tet10 states carry a curved volume of their own).
            let v = closure(&replayed);
            max_vol_err = max_vol_err.max((v / closure(&s.positions_m) - 1.0).abs());
        }
        report.insert(
            name.to_string(),
            serde_json::json!({
                "max_vertex_error_mm": max_err * 1e3,
                "rms_vertex_error_mm": (sum_sq / count.max(1) as f64).sqrt() * 1e3,
                "max_vertex_error_percent_of_max_displacement": 100.0 * max_err / max_disp_m.max(1e-30),
                "max_cavity_volume_error_percent": 100.0 * max_vol_err,
            }),
        );
    }
    report.insert("held_out_states".into(), serde_json::json!(held.len()));
    report.insert(
        "max_displacement_mm".into(),
        serde_json::json!(max_disp_m * 1e3),
    );
    Ok(serde_json::Value::Object(report))
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

fn load_mesh(path: Option<&Path>) -> Result<(TetMesh, serde_json::Value)> {
    match path {
        None => {
            let params = AnatomyParams::default();
            let a = anatomy::generate(&params).context("generating the default anatomy")?;
            let uterine = a.summary.uterine_volume_ml;
            Ok((
                a.mesh,
                serde_json::json!({"source": "default anatomy", "uterine_volume_ml": uterine}),
            ))
        }
        Some(p) if p.extension().is_some_and(|e| e == "json") => {
            let text = std::fs::read_to_string(p)
                .with_context(|| format!("reading mesh {}", p.display()))?;
            let mesh: TetMesh = serde_json::from_str(&text)
                .with_context(|| format!("{}: not a TetMesh JSON", p.display()))?;
            Ok((mesh, serde_json::json!({"source": p.display().to_string()})))
        }
        Some(p) => {
            let text = std::fs::read_to_string(p)
                .with_context(|| format!("reading anatomy parameters {}", p.display()))?;
            let params =
                AnatomyParams::from_toml_str(&text).with_context(|| format!("{}", p.display()))?;
            let a = anatomy::generate(&params)
                .with_context(|| format!("generating the anatomy of {}", p.display()))?;
            let uterine = a.summary.uterine_volume_ml;
            Ok((
                a.mesh,
                serde_json::json!({"source": p.display().to_string(), "uterine_volume_ml": uterine}),
            ))
        }
    }
}

fn progress(done: usize, total: usize, pressure_pa: f64, volume_m3: f64, t0: Instant) {
    let width = 30;
    let filled = width * done / total.max(1);
    eprint!(
        "\r[{}{}] {done}/{total} levels  {:6.1} mmHg  cavity {:7.3} ml  {:5.1} s",
        "#".repeat(filled),
        ".".repeat(width - filled),
        pa_to_mmhg(pressure_pa),
        m3_to_ml(volume_m3),
        t0.elapsed().as_secs_f64()
    );
    let _ = std::io::stderr().flush();
    if done == total {
        eprintln!();
    }
}

/// Runs the sweep and writes the outputs.
pub fn run(args: &PrecomputeArgs) -> Result<()> {
    if !(args.max_mmhg > 0.0 && args.max_mmhg.is_finite()) {
        bail!("--max-mmhg {}: expected a positive pressure", args.max_mmhg);
    }
    if args.levels < 2 {
        bail!(
            "--levels {}: expected at least 2 (0 and --max-mmhg)",
            args.levels
        );
    }
    let materials = match &args.material {
        Some(p) => MaterialSet::from_file(p)?,
        None => MaterialSet::default_uterus()?,
    };
    let t_mesh = Instant::now();
    let (mesh, mesh_meta) = load_mesh(args.anatomy.as_deref())?;
    tracing::info!(
        vertices = mesh.positions_m.len(),
        tets = mesh.tets.len(),
        seconds = t_mesh.elapsed().as_secs_f64(),
        "mesh ready"
    );
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;

    let mut model = FemModel::from_mesh(&mesh, &materials)?;
    if args.element == Element::Tet10 {
        model = model.to_tet10(|a, b| std::array::from_fn(|k| 0.5 * (a[k] + b[k])))?;
    }
    let t0 = Instant::now();
    let options = SolverOptions::default();
    let mut solver = Solver::new(&model, options.clone())?;
    let (nnz, factor_nnz) = solver.sizes();
    tracing::info!(
        dofs = 3 * model.rest_positions_m.len(),
        nnz,
        factor_nnz,
        "symbolic factorization done"
    );
    let solved_levels = if args.holdout {
        2 * args.levels - 1
    } else {
        args.levels
    };
    let pressures: Vec<f64> = (0..solved_levels)
        .map(|k| mmhg_to_pa(args.max_mmhg) * k as f64 / (solved_levels - 1) as f64)
        .collect();
    let all_states = solver.sweep(&pressures, |k, eq| {
        progress(
            k + 1,
            solved_levels,
            eq.pressure_pa,
            eq.cavity_volume_m3,
            t0,
        )
    })?;
    let sweep_s = t0.elapsed().as_secs_f64();
    // The mesh vertices of every state (tet10 mid-edge nodes follow them and are dropped).
    let n_vertices = mesh.positions_m.len();
    let all_states: Vec<Equilibrium> = all_states
        .into_iter()
        .map(|mut s| {
            s.positions_m.truncate(n_vertices);
            s.dxdp_m_per_pa.truncate(n_vertices);
            s
        })
        .collect();
    let step = if args.holdout { 2 } else { 1 };
    let states: Vec<Equilibrium> = all_states.iter().step_by(step).cloned().collect();
    let held: Vec<&Equilibrium> = if args.holdout {
        all_states.iter().skip(1).step_by(2).collect()
    } else {
        Vec::new()
    };
    let n_levels = states.len();

    // Monotone P-V curve and no inversion are acceptance conditions of the atlas.
    for w in states.windows(2) {
        if w[1].cavity_volume_m3 <= w[0].cavity_volume_m3 {
            tracing::warn!(
                p0 = w[0].pressure_pa,
                p1 = w[1].pressure_pa,
                "P-V curve not monotone"
            );
        }
    }
    let levels: Vec<AtlasLevel> = states
        .iter()
        .map(|s| AtlasLevel {
            pressure_pa: s.pressure_pa,
            cavity_volume_m3: s.cavity_volume_m3,
            positions_m: s.positions_m.clone(),
            dxdp_m_per_pa: s.dxdp_m_per_pa.clone(),
        })
        .collect();
    let metadata = serde_json::json!({
        "generator": format!("hydrometra {}", env!("CARGO_PKG_VERSION")),
        "mesh": {"vertices": mesh.positions_m.len(), "tets": mesh.tets.len(), "origin": mesh_meta},
        "material": materials,
        "solver": {
            "element": args.element.to_string(),
            "formulation": match args.element {
                Element::Tet4 => "total Lagrangian, linear tets, nodally averaged volumetric energy, follower pressure as -p V(x), fixed vertices clamped",
                Element::Tet10 => "total Lagrangian, 10-node tets (straight-sided at rest), mean-dilatation volumetric energy, follower pressure as -p V(x) on 6-node cavity triangles, fixed vertices clamped",
            },
            "nodes": model.rest_positions_m.len(),
            "tolerance": options.tolerance,
            "newton_iterations": solver.counters.newton_iterations,
            "factorizations": solver.counters.factorizations,
            "step_cuts": solver.counters.step_cuts,
            "sweep_seconds": sweep_s,
        },
        "levels": {"count": n_levels, "max_mmhg": args.max_mmhg},
    });
    let atlas = Atlas::new(
        atlas::mesh_hash(&mesh),
        metadata,
        mesh.positions_m.clone(),
        &levels,
    )?;
    let atlas_path = args.out.join("atlas.hma");
    atlas.write(&atlas_path)?;

    // P-V curve.
    let rest_volume = mesh.cavity_volume_m3();
    let tissue_volume = mesh.volume_m3();
    let mut csv = String::from("level,pressure_mmhg,pressure_pa,cavity_volume_ml,cavity_volume_m3,newton_iterations,min_volume_ratio\n");
    for (k, s) in states.iter().enumerate() {
        csv.push_str(&format!(
            "{k},{:.4},{:.3},{:.6},{:.9e},{},{:.4}\n",
            pa_to_mmhg(s.pressure_pa),
            s.pressure_pa,
            m3_to_ml(s.cavity_volume_m3),
            s.cavity_volume_m3,
            s.newton_iterations,
            s.min_volume_ratio
        ));
    }
    let csv_path = args.out.join("pv_curve.csv");
    std::fs::write(&csv_path, csv).with_context(|| format!("writing {}", csv_path.display()))?;

    if !args.no_vtu {
        let dir = args.out.join("vtu");
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        let mut pvd = vtk::Collection::new();
        let mut deformed = mesh.clone();
        for (k, s) in states.iter().enumerate() {
            deformed.positions_m.clone_from(&s.positions_m);
            let name = format!("level_{k:03}.vtu");
            anatomy::write_vtu(&deformed, &dir.join(&name))?;
            pvd.dataset(pa_to_mmhg(s.pressure_pa), 0, &format!("vtu/{name}"));
        }
        let pvd_path = args.out.join("atlas.pvd");
        std::fs::write(&pvd_path, pvd.finish())
            .with_context(|| format!("writing {}", pvd_path.display()))?;
    }

    let last = states.last().context("no levels")?;
    let min_ratio = all_states
        .iter()
        .map(|s| s.min_volume_ratio)
        .fold(f64::INFINITY, f64::min);
    let monotone = states
        .windows(2)
        .all(|w| w[1].cavity_volume_m3 > w[0].cavity_volume_m3);
    let holdout = if args.holdout {
        holdout_errors(&atlas, &mesh, &held)?
    } else {
        serde_json::Value::Null
    };
    let uterine = tissue_volume + rest_volume;
    let summary = serde_json::json!({
        "sweep_seconds": sweep_s,
        "solved_levels": solved_levels,
        "levels": n_levels,
        "vertices": mesh.positions_m.len(),
        "tets": mesh.tets.len(),
        "threads": rayon::current_num_threads(),
        "element": args.element.to_string(),
        "nodes": model.rest_positions_m.len(),
        "pv_curve_monotone": monotone,
        "krylov_iterations": solver.counters.krylov_iterations,
        "replay_holdout": holdout,
        "newton_iterations": solver.counters.newton_iterations,
        "factorizations": solver.counters.factorizations,
        "step_cuts": solver.counters.step_cuts,
        "assembly_seconds": solver.counters.assembly.as_secs_f64(),
        "linear_solver_seconds": solver.counters.linear.as_secs_f64(),
        "tangent_nnz": nnz,
        "factor_nnz": factor_nnz,
        "rest_cavity_volume_ml": m3_to_ml(rest_volume),
        "uterine_volume_ml": m3_to_ml(uterine),
        "max_pressure_mmhg": pa_to_mmhg(last.pressure_pa),
        "cavity_volume_at_max_ml": m3_to_ml(last.cavity_volume_m3),
        "cavity_to_uterine_volume_ratio_at_max": last.cavity_volume_m3 / uterine,
        "reference_ratio_at_150_mmhg": 0.069,
        "min_volume_ratio": min_ratio,
    });
    std::fs::write(
        args.out.join("summary.json"),
        serde_json::to_string_pretty(&summary)?,
    )
    .context("writing summary.json")?;
    println!("{}", serde_json::to_string_pretty(&summary)?);
    println!(
        "wrote {}, {}{}",
        atlas_path.display(),
        csv_path.display(),
        if args.no_vtu {
            ""
        } else {
            ", atlas.pvd + vtu/"
        }
    );
    Ok(())
}
