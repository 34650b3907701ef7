//! `hydrometra scene`: print the default scene, prepare a scene's atlas, run a scene offline from a
//! rig scenario (ParaView series and CSV), and benchmark it (the paper's Table 1 on the real
//! deformed uterus).

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand};
use hydrometra_sim::scene::particles::Particles;
use hydrometra_sim::scene::{
    prepare, HydraulicsInput, RigInputs, Scene, SceneAssets, SceneDesc, SceneInputs, ScopePose,
    Stage, VoxelKind,
};
use hydrometra_sim::units::{m3_to_ml, mmhg_to_pa, pa_to_mmhg};

use crate::service::hydraulics::load_scenario;

/// `hydrometra scene ...`
#[derive(Subcommand, Debug)]
pub enum SceneCommand {
    /// Print the default scene file, every key commented.
    PrintDefault,
    /// Build (or find in the cache) the scene's deformation atlas.
    Prepare(PrepareArgs),
    /// Run the scene offline from a rig scenario; write a ParaView series and a CSV.
    Run(RunArgs),
    /// The paper's Table 1 on the real deformed uterus: grid, fluid, voxelization, replay, step.
    Bench(BenchArgs),
}

/// Where the scene comes from and where its atlas is cached.
#[derive(Args, Debug, Clone)]
pub struct SceneArg {
    /// A built-in scene (`default`, `myoma-figo1`) or a scene file.
    #[arg(long, default_value = "default")]
    pub scene: String,
    /// Atlas cache directory (default: $XDG_CACHE_HOME/hydrometra or ~/.cache/hydrometra).
    #[arg(long)]
    pub cache_dir: Option<PathBuf>,
}

/// `scene prepare`
#[derive(Args, Debug)]
pub struct PrepareArgs {
    #[command(flatten)]
    scene: SceneArg,
}

/// `scene run`
#[derive(Args, Debug)]
pub struct RunArgs {
    #[command(flatten)]
    scene: SceneArg,
    /// A built-in rig scenario (`default`, `flaky`) or a scenario file.
    #[arg(long, default_value = "default")]
    scenario: String,
    /// Simulated seconds.
    #[arg(long, default_value_t = 20.0)]
    seconds: f64,
    /// Scene steps per second.
    #[arg(long, default_value_t = 60.0)]
    rate_hz: f64,
    /// Write the ParaView series every this many frames (0: no series).
    #[arg(long, default_value_t = 6)]
    every: usize,
    /// Voxel size override, mm.
    #[arg(long)]
    voxel_mm: Option<f64>,
    /// Output directory.
    #[arg(long)]
    out: PathBuf,
}

/// `scene bench`
#[derive(Args, Debug)]
pub struct BenchArgs {
    #[command(flatten)]
    scene: SceneArg,
    /// Voxel sizes, mm.
    #[arg(long, value_delimiter = ',', default_values_t = [0.6, 0.9, 1.2, 1.5, 1.8])]
    voxels_mm: Vec<f64>,
    /// Pump pressure of the run, mmHg (the cavity distends to about it).
    #[arg(long, default_value_t = 100.0)]
    pump_mmhg: f64,
    /// Untimed steps first (the cavity distends, the jet develops).
    #[arg(long, default_value_t = 120)]
    warmup: usize,
    /// Timed steps.
    #[arg(long, default_value_t = 200)]
    steps: usize,
    /// Scene rate, Hz.
    #[arg(long, default_value_t = 60.0)]
    rate_hz: f64,
    /// Print JSON instead of a table.
    #[arg(long)]
    json: bool,
}

/// Runs a `scene` subcommand.
pub fn run(cmd: SceneCommand) -> Result<()> {
    match cmd {
        SceneCommand::PrintDefault => {
            print!("{}", hydrometra_sim::scene::desc::DEFAULT_SCENE_TOML);
            Ok(())
        }
        SceneCommand::Prepare(a) => {
            let desc = SceneDesc::load(&a.scene.scene)?;
            let (assets, source) = assets(&desc, &a.scene)?;
            println!(
                "{}: atlas {:?}, {} levels, {} vertices",
                desc.name,
                source,
                assets.atlas.level_count(),
                assets.atlas.vertex_count()
            );
            Ok(())
        }
        SceneCommand::Run(a) => run_offline(&a),
        SceneCommand::Bench(a) => bench(&a),
    }
}

/// The default atlas cache directory.
pub fn default_cache_dir() -> PathBuf {
    if let Some(d) = std::env::var_os("XDG_CACHE_HOME").filter(|d| !d.is_empty()) {
        return PathBuf::from(d).join("hydrometra");
    }
    match std::env::var_os("HOME").filter(|d| !d.is_empty()) {
        Some(h) => PathBuf::from(h).join(".cache").join("hydrometra"),
        None => std::env::temp_dir().join("hydrometra-cache"),
    }
}

fn assets(desc: &SceneDesc, arg: &SceneArg) -> Result<(SceneAssets, prepare::AtlasSource)> {
    let dir = arg.cache_dir.clone().unwrap_or_else(default_cache_dir);
    let t0 = Instant::now();
    let mut progress = |done: usize, total: usize, p: f64, v: f64| {
        eprint!(
            "\ratlas: {done}/{total} levels, {:.1} mmHg, cavity {:.3} ml, {:.0} s   ",
            pa_to_mmhg(p),
            m3_to_ml(v),
            t0.elapsed().as_secs_f64()
        );
        let _ = std::io::stderr().flush();
        if done == total {
            eprintln!();
        }
    };
    let (a, s) = prepare::load_or_build(desc, Some(&dir), &mut progress)
        .with_context(|| format!("preparing scene {}", desc.name))?;
    Ok((a, s))
}

/// Rig inputs from a scenario sample (clinical units and mm at the edge, SI inside).
fn rig_inputs(
    s: &hydrometra_drivers::emulator::scenario::ScenarioSample,
    perforation: bool,
) -> RigInputs {
    RigInputs {
        valve_in_opening: s.valve_in,
        valve_out_opening: s.valve_out,
        pump_set_pressure_pa: mmhg_to_pa(s.pump_mmhg),
        scope: ScopePose {
            tip_position_m: s.tip_mm.map(|v| v * 1e-3),
            view_direction: s.view_dir,
            valid: s.pose_valid,
        },
        perforation,
    }
}

fn run_offline(a: &RunArgs) -> Result<()> {
    if !(a.seconds.is_finite() && a.seconds > 0.0 && a.seconds <= 24.0 * 3600.0) {
        bail!("--seconds {}: expected a duration in (0, 86400]", a.seconds);
    }
    if !(a.rate_hz.is_finite() && (1.0..=1000.0).contains(&a.rate_hz)) {
        bail!("--rate-hz {}: expected 1 to 1000", a.rate_hz);
    }
    let mut desc = SceneDesc::load(&a.scene.scene)?;
    if let Some(v) = a.voxel_mm {
        desc.fluid.voxel_mm = v;
        desc.validate()?;
    }
    let (scenario, case) = load_scenario(&a.scenario)?;
    if let Some(p) = case.params.clone() {
        // The scenario's hydraulics, with the scope's port areas (one source).
        let mut p = p;
        p.inflow.port_area_mm2 = desc.hydraulics.inflow.port_area_mm2;
        p.outflow.port_area_mm2 = desc.hydraulics.outflow.port_area_mm2;
        desc.hydraulics = p;
    }
    let (assets, _) = assets(&desc, &a.scene)?;
    let mut scene = Scene::new(desc, assets)?;
    std::fs::create_dir_all(a.out.join("vtu"))
        .with_context(|| format!("creating {}", a.out.display()))?;
    let dt = 1.0 / a.rate_hz;
    let frames = (a.seconds * a.rate_hz).round() as usize;
    let mut csv = String::from(
        "frame,time_s,pressure_mmhg,cavity_volume_ml,surface_volume_ml,grid_fluid_volume_ml,fluid_cells,\
         inflow_ml_min,outflow_ml_min,losses_ml_min,dvdt_ml_min,fluid_inflow_ml_min,fluid_outflow_ml_min,\
         fluid_wall_ml_min,fluid_open_ml_min,wall_flux_scale,deficit_ml,step_ms,replay_ms,voxelize_ms,ports_ms,fluid_ms,\
         fluid_ran,projection_iterations,max_div_rel,particles_alive,clarity\n",
    );
    let mut pvd = String::from("<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\" byte_order=\"LittleEndian\">\n<Collection>\n");
    let ml_min = |q: f64| q * 6e7;
    let mut written = 0;
    for f in 0..frames {
        let t = (f + 1) as f64 * dt;
        let sample = scenario.sample_at(t);
        let inputs = SceneInputs {
            rig: rig_inputs(&sample, case.perforated_at(t)),
            hydraulics: HydraulicsInput::Own,
        };
        scene.step(&inputs, dt)?;
        let deficit_m3 = scene.hydraulic_state().deficit.deficit_m3;
        let r = scene.report();
        let c = &r.counters;
        let last = |s: Stage| {
            if c.get(s).ran_last {
                c.get(s).last_ms
            } else {
                0.0
            }
        };
        let fl = &r.flux;
        let (its, div) = r
            .fluid
            .map_or((0, f64::NAN), |s| (s.projection_iterations, s.max_div_rel));
        // Particles alive and the view's clarity (empty without the stage or a scope pose).
        let (alive, clarity) = scene.particles().map_or((0, None), |p| {
            (p.system().map_or(0, |s| s.len()), p.clarity())
        });
        let clarity = clarity.map_or(String::new(), |c| format!("{c:.4}"));
        let _ = writeln!(
            csv,
            "{f},{:.5},{:.4},{:.5},{:.5},{:.5},{},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{},{},{:.3e},{alive},{clarity}",
            r.time_s,
            pa_to_mmhg(r.cavity_pressure_pa),
            m3_to_ml(r.cavity_volume_m3),
            m3_to_ml(r.surface_volume_m3),
            m3_to_ml(r.grid_fluid_volume_m3),
            r.fluid_cells,
            ml_min(fl.hydraulic_inflow_m3_per_s),
            ml_min(fl.hydraulic_outflow_m3_per_s),
            ml_min(fl.hydraulic_losses_m3_per_s),
            ml_min(fl.hydraulic_dvdt_m3_per_s),
            ml_min(fl.fluid_inflow_m3_per_s),
            ml_min(fl.fluid_outflow_m3_per_s),
            ml_min(fl.fluid_wall_m3_per_s),
            ml_min(fl.fluid_open_m3_per_s),
            fl.wall_flux_scale,
            m3_to_ml(deficit_m3),
            c.step.last_ms,
            last(Stage::Deformation),
            last(Stage::Voxelize),
            last(Stage::Ports),
            last(Stage::Fluid),
            u8::from(c.get(Stage::Fluid).ran_last),
            its,
            div
        );
        if a.every > 0 && (f + 1) % a.every == 0 {
            let name = format!("frame_{written:05}");
            let cavity = format!("vtu/{name}_cavity.vtu");
            let flow = format!("vtu/{name}_flow.vtu");
            std::fs::write(a.out.join(&cavity), cavity_vtu(&scene))
                .with_context(|| format!("writing {cavity}"))?;
            std::fs::write(a.out.join(&flow), flow_vtu(&scene))
                .with_context(|| format!("writing {flow}"))?;
            let _ = writeln!(
                pvd,
                "<DataSet timestep=\"{t:.4}\" group=\"\" part=\"0\" file=\"{cavity}\"/>\n<DataSet timestep=\"{t:.4}\" group=\"\" part=\"1\" file=\"{flow}\"/>"
            );
            // The particles, when the scene has the stage: a file every series frame (no
            // points before any is released), so the series stays aligned in ParaView.
            if let Some(p) = scene.particles() {
                let particles = format!("vtu/{name}_particles.vtu");
                std::fs::write(a.out.join(&particles), p.vtu_string())
                    .with_context(|| format!("writing {particles}"))?;
                let _ = writeln!(
                    pvd,
                    "<DataSet timestep=\"{t:.4}\" group=\"\" part=\"2\" file=\"{particles}\"/>"
                );
            }
            written += 1;
        }
    }
    pvd.push_str("</Collection>\n</VTKFile>\n");
    std::fs::write(a.out.join("scene.csv"), csv).context("writing scene.csv")?;
    std::fs::write(a.out.join("scene.pvd"), pvd).context("writing scene.pvd")?;
    let r = scene.report();
    let summary = serde_json::json!({
        "scene": scene.desc().name,
        "scenario": a.scenario,
        "frames": frames,
        "rate_hz": a.rate_hz,
        "series_frames": written,
        "grid_dims": scene.cells().dims,
        "voxel_mm": scene.desc().fluid.voxel_mm,
        "stages": stage_json(&r.counters),
        "particles": scene.particles().map(particles_json),
    });
    std::fs::write(
        a.out.join("summary.json"),
        serde_json::to_string_pretty(&summary)?,
    )
    .context("writing summary.json")?;
    println!("{}", serde_json::to_string_pretty(&summary)?);
    println!(
        "wrote {} (open scene.pvd in ParaView), scene.csv, summary.json",
        a.out.display()
    );
    Ok(())
}

/// The particle counters per kind (blood, bubble, fragment) and the clarity figures.
fn particles_json(p: &Particles) -> serde_json::Value {
    let c = p.system().map(|s| s.counts()).unwrap_or_default();
    let t = p.tracker();
    let alive: Vec<u64> = (0..3)
        .map(|k| c.emitted[k].saturating_sub(c.outflow[k] + c.open[k] + c.lost[k]))
        .collect();
    serde_json::json!({
        "kinds": ["blood", "bubble", "fragment"],
        "alive": alive,
        "emitted": c.emitted,
        "left_by_outflow": c.outflow,
        "left_by_open_os": c.open,
        "lost": c.lost,
        "dropped_over_budget": c.dropped,
        "rejected_not_in_fluid": c.rejected,
        "clarity": p.clarity(),
        "min_clarity": t.min_clarity,
        "time_to_clear_s": t.time_to_clear_s,
        "last_obscured_s": t.last_obscured_s,
    })
}

fn stage_json(c: &hydrometra_sim::scene::Counters) -> serde_json::Value {
    let mut m = serde_json::Map::new();
    for s in Stage::ALL {
        let x = c.get(s);
        if !x.present {
            continue;
        }
        m.insert(
            s.name().into(),
            serde_json::json!({"runs": x.runs, "skips": x.skips, "mean_ms": x.mean_ms(),
                "p50_ms": x.p50_ms(), "p99_ms": x.p99_ms()}),
        );
    }
    m.insert(
        "step".into(),
        serde_json::json!({"runs": c.step.runs, "mean_ms": c.step.mean_ms(),
            "p50_ms": c.step.p50_ms(), "p99_ms": c.step.p99_ms()}),
    );
    serde_json::Value::Object(m)
}

/// The closed cavity surface as a VTU of triangles (point data: displacement-free positions).
fn cavity_vtu(scene: &Scene) -> String {
    let c = scene.cavity();
    let (np, nc) = (c.positions_m.len(), c.triangles.len());
    let mut s = String::with_capacity(40 * (np + nc));
    s.push_str("<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n<UnstructuredGrid>\n");
    let _ = writeln!(s, "<Piece NumberOfPoints=\"{np}\" NumberOfCells=\"{nc}\">");
    s.push_str(
        "<CellData Scalars=\"cap\">\n<DataArray type=\"UInt8\" Name=\"cap\" format=\"ascii\">\n",
    );
    for t in 0..nc {
        s.push_str(if t < c.cap_triangles { "1\n" } else { "0\n" });
    }
    s.push_str("</DataArray>\n</CellData>\n<Points>\n<DataArray type=\"Float32\" NumberOfComponents=\"3\" format=\"ascii\">\n");
    for p in c.positions_m {
        let _ = writeln!(s, "{:e} {:e} {:e}", p[0], p[1], p[2]);
    }
    s.push_str("</DataArray>\n</Points>\n<Cells>\n<DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n");
    for t in c.triangles {
        let _ = writeln!(s, "{} {} {}", t[0], t[1], t[2]);
    }
    s.push_str("</DataArray>\n<DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">\n");
    for i in 0..nc {
        let _ = writeln!(s, "{}", 3 * (i + 1));
    }
    s.push_str("</DataArray>\n<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">\n");
    for _ in 0..nc {
        s.push_str("5\n");
    }
    s.push_str("</DataArray>\n</Cells>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n");
    s
}

/// The non-solid cells of the flow field as a VTU of hexahedra (cell data `label`: the
/// [`VoxelKind`] value, `velocity`: m/s).
fn flow_vtu(scene: &Scene) -> String {
    let Some(flow) = scene.flow() else {
        return String::new();
    };
    let [nx, ny, nz] = flow.dims();
    let h = flow.spacing_m();
    let c0 = flow.first_centre_m();
    let o = [c0[0] - 0.5 * h, c0[1] - 0.5 * h, c0[2] - 0.5 * h];
    let kinds = flow.kinds();
    let mut vel = vec![[0.0f32; 3]; kinds.len()];
    flow.velocities_into(&mut vel);
    let cells: Vec<usize> = (0..kinds.len())
        .filter(|&n| !matches!(kinds[n], VoxelKind::Solid | VoxelKind::Scope))
        .collect();
    // Shared corner nodes.
    let node = |i: usize, j: usize, k: usize| i + (nx + 1) * (j + (ny + 1) * k);
    let mut id = vec![u32::MAX; (nx + 1) * (ny + 1) * (nz + 1)];
    let mut points: Vec<usize> = Vec::new();
    let mut conn: Vec<u32> = Vec::with_capacity(8 * cells.len());
    for &n in &cells {
        let (i, j, k) = (n % nx, (n / nx) % ny, n / (nx * ny));
        // VTK_VOXEL order: x fastest, then y, then z.
        for (dk, dj, di) in [
            (0, 0, 0),
            (0, 0, 1),
            (0, 1, 0),
            (0, 1, 1),
            (1, 0, 0),
            (1, 0, 1),
            (1, 1, 0),
            (1, 1, 1),
        ] {
            let q = node(i + di, j + dj, k + dk);
            if id[q] == u32::MAX {
                id[q] = points.len() as u32;
                points.push(q);
            }
            conn.push(id[q]);
        }
    }
    let mut s = String::with_capacity(64 * (points.len() + cells.len()));
    s.push_str("<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n<UnstructuredGrid>\n");
    let _ = writeln!(
        s,
        "<Piece NumberOfPoints=\"{}\" NumberOfCells=\"{}\">",
        points.len(),
        cells.len()
    );
    s.push_str("<CellData Scalars=\"label\" Vectors=\"velocity\">\n<DataArray type=\"UInt8\" Name=\"label\" format=\"ascii\">\n");
    for &n in &cells {
        let _ = writeln!(s, "{}", kinds[n] as u8);
    }
    s.push_str("</DataArray>\n<DataArray type=\"Float32\" Name=\"velocity\" NumberOfComponents=\"3\" format=\"ascii\">\n");
    for &n in &cells {
        let v = vel[n];
        let _ = writeln!(s, "{:.5e} {:.5e} {:.5e}", v[0], v[1], v[2]);
    }
    s.push_str("</DataArray>\n</CellData>\n<Points>\n<DataArray type=\"Float32\" NumberOfComponents=\"3\" format=\"ascii\">\n");
    for &q in &points {
        let (i, j, k) = (
            q % (nx + 1),
            (q / (nx + 1)) % (ny + 1),
            q / ((nx + 1) * (ny + 1)),
        );
        let _ = writeln!(
            s,
            "{:e} {:e} {:e}",
            (o[0] + i as f64 * h) as f32,
            (o[1] + j as f64 * h) as f32,
            (o[2] + k as f64 * h) as f32
        );
    }
    s.push_str("</DataArray>\n</Points>\n<Cells>\n<DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n");
    for c in conn.chunks(8) {
        let _ = writeln!(
            s,
            "{} {} {} {} {} {} {} {}",
            c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]
        );
    }
    s.push_str("</DataArray>\n<DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">\n");
    for i in 0..cells.len() {
        let _ = writeln!(s, "{}", 8 * (i + 1));
    }
    s.push_str("</DataArray>\n<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">\n");
    for _ in 0..cells.len() {
        s.push_str("12\n");
    }
    s.push_str("</DataArray>\n</Cells>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n");
    s
}

/// One row of the bench table.
#[derive(Debug, serde::Serialize)]
struct BenchRow {
    voxel_mm: f64,
    box_cells: usize,
    fluid_cells: usize,
    fluid_ms_mean: f64,
    fluid_ms_p99: f64,
    projection_iterations_mean: f64,
    max_div_rel: f64,
    voxelize_full_ms: f64,
    voxelize_incremental_ms_mean: f64,
    voxelize_incremental_ms_p99: f64,
    replay_us_mean: f64,
    replay_us_p99: f64,
    step_ms_mean: f64,
    step_ms_p99: f64,
    grid_fluid_volume_ml: f64,
    surface_volume_ml: f64,
    volume_error_percent: f64,
}

fn bench(a: &BenchArgs) -> Result<()> {
    let base = SceneDesc::load(&a.scene.scene)?;
    let (assets, _) = assets(&base, &a.scene)?;
    let dt = 1.0 / a.rate_hz;
    let mut rows = Vec::new();
    for &v in &a.voxels_mm {
        let mut desc = base.clone();
        desc.fluid.voxel_mm = v;
        desc.validate()?;
        let mut scene = Scene::new(desc, assets.clone())?;
        // The default scenario's operating point: scope in the cavity, inflow open, outflow half
        // open, the pump at --pump-mmhg; the scope sweeps slowly so voxelization and ports run.
        let at = |f: usize| {
            let t = f as f64 * dt;
            let sway = 1.5e-3 * (0.7 * t).sin();
            RigInputs {
                valve_in_opening: 1.0,
                valve_out_opening: 0.5,
                pump_set_pressure_pa: mmhg_to_pa(a.pump_mmhg) * (1.0 + 0.05 * (0.3 * t).sin()),
                scope: ScopePose {
                    // In the corpus of the default uterus (drivers/scenarios/default.toml, t = 45 s).
                    tip_position_m: [sway, 0.0129, 0.0426],
                    view_direction: [0.0, 0.5, 0.866],
                    valid: true,
                },
                perforation: false,
            }
        };
        for f in 0..a.warmup {
            scene.step(
                &SceneInputs {
                    rig: at(f),
                    hydraulics: HydraulicsInput::Own,
                },
                dt,
            )?;
        }
        let start = scene.report().counters.clone();
        let mut its = 0usize;
        let mut max_div = 0.0f64;
        let mut fluid_runs = 0usize;
        let (mut rebuilds, mut topology_ms, mut advect_ms, mut project_ms) =
            (0usize, 0.0, 0.0, 0.0);
        for f in a.warmup..a.warmup + a.steps {
            let r = scene.step(
                &SceneInputs {
                    rig: at(f),
                    hydraulics: HydraulicsInput::Own,
                },
                dt,
            )?;
            if let Some(s) = r.fluid {
                its += s.projection_iterations;
                max_div = max_div.max(s.max_div_rel);
                fluid_runs += 1;
                rebuilds += usize::from(s.topology_rebuilt);
                topology_ms += s.topology_ms;
                advect_ms += s.advect_ms;
                project_ms += s.project_ms;
            }
        }
        let per_run = |x: f64| x / fluid_runs.max(1) as f64;
        eprintln!(
            "{v} mm: {fluid_runs} fluid steps, {rebuilds} topology rebuilds; per fluid step: topology {:.3} ms, advection {:.3} ms, projection {:.3} ms",
            per_run(topology_ms), per_run(advect_ms), per_run(project_ms)
        );
        let r = scene.report();
        let c = &r.counters;
        let delta_mean = |s: Stage| {
            let (now, then) = (c.get(s), start.get(s));
            let runs = now.runs - then.runs;
            if runs == 0 {
                0.0
            } else {
                (now.total_ms - then.total_ms) / runs as f64
            }
        };
        let step_mean = (c.step.total_ms - start.step.total_ms) / a.steps as f64;
        // A full voxelization, timed alone.
        let mut vox = scene.voxelizer().clone();
        let t = Instant::now();
        let reps = 5;
        for _ in 0..reps {
            vox.full(scene.cavity().positions_m);
        }
        let full_ms = t.elapsed().as_secs_f64() * 1e3 / reps as f64;
        let grid_ml = m3_to_ml(r.grid_fluid_volume_m3);
        let surf_ml = m3_to_ml(r.surface_volume_m3);
        rows.push(BenchRow {
            voxel_mm: v,
            box_cells: scene.cells().cell_count(),
            fluid_cells: r.fluid_cells,
            fluid_ms_mean: delta_mean(Stage::Fluid),
            fluid_ms_p99: c.get(Stage::Fluid).p99_ms(),
            projection_iterations_mean: its as f64 / fluid_runs.max(1) as f64,
            max_div_rel: max_div,
            voxelize_full_ms: full_ms,
            voxelize_incremental_ms_mean: delta_mean(Stage::Voxelize),
            voxelize_incremental_ms_p99: c.get(Stage::Voxelize).p99_ms(),
            replay_us_mean: 1e3 * delta_mean(Stage::Deformation),
            replay_us_p99: 1e3 * c.get(Stage::Deformation).p99_ms(),
            step_ms_mean: step_mean,
            step_ms_p99: c.step.p99_ms(),
            grid_fluid_volume_ml: grid_ml,
            surface_volume_ml: surf_ml,
            volume_error_percent: 100.0 * (grid_ml / surf_ml - 1.0),
        });
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
        return Ok(());
    }
    println!(
        "scene {}, {} warm-up + {} timed steps at {} Hz, pump {} mmHg, rayon threads {}",
        base.name,
        a.warmup,
        a.steps,
        a.rate_hz,
        a.pump_mmhg,
        rayon::current_num_threads()
    );
    println!("| voxel mm | box cells | fluid cells | fluid ms mean / p99 | CG its | max div h/U | voxelize full ms | voxelize incr. ms mean / p99 | replay us mean / p99 | step ms mean / p99 | grid vol ml | surface vol ml | vol err % |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for r in &rows {
        println!(
            "| {} | {} | {} | {:.3} / {:.3} | {:.1} | {:.1e} | {:.3} | {:.3} / {:.3} | {:.1} / {:.1} | {:.3} / {:.3} | {:.3} | {:.3} | {:+.1} |",
            r.voxel_mm, r.box_cells, r.fluid_cells, r.fluid_ms_mean, r.fluid_ms_p99,
            r.projection_iterations_mean, r.max_div_rel, r.voxelize_full_ms,
            r.voxelize_incremental_ms_mean, r.voxelize_incremental_ms_p99, r.replay_us_mean,
            r.replay_us_p99, r.step_ms_mean, r.step_ms_p99, r.grid_fluid_volume_ml,
            r.surface_volume_ml, r.volume_error_percent
        );
    }
    Ok(())
}
