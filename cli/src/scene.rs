//! `hydrometra scene`: print the default scene, prepare a scene's atlas, run a scene offline from a
//! rig scenario (ParaView series and CSV), and benchmark it (the paper's Table 1 on the real
//! deformed uterus).

use std::fmt::Write as _;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand};
use hydrometra_sim::harness::benchmark::StepTimes;
use hydrometra_sim::harness::fork_join::{set_backend, set_guard, Backend};
use hydrometra_sim::harness::load::BusyThreads;
use hydrometra_sim::hydraulics::HydraulicInputs;
use hydrometra_sim::scene::particles::{Particles, TRAVERSE_SUBGRID};
use hydrometra_sim::scene::{
    HydraulicsInput, RigInputs, Scene, SceneAssets, SceneDesc, SceneError, SceneInputs, ScopePose,
    Stage, StepReport,
};
use hydrometra_sim::units::{m3_to_ml, mmhg_to_pa, pa_to_mmhg};
use hydrometra_sim::vtk;
use hydrometra_sim::{guard_serial_joins, helper_tasks};

use crate::converge::OnOff;
use crate::fluid::ForkJoinArg;
use crate::scenario::load_scenario;
use crate::scene_setup::SceneArg;
use crate::scene_setup::{apply_scenario_hydraulics, assets, scene_inputs_at};

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
    /// The scene's accuracy table: run time and the error against a fine reference of what a
    /// trainee sees, at several voxel sizes, with the observed order.
    Converge(crate::converge::ConvergeArgs),
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
    /// Cut cells (`[fluid] cut_cells`) on or off whatever the scene file says (on by default;
    /// `--cut-cells` alone means on).
    #[arg(long, value_enum, value_name = "on|off", num_args = 0..=1, default_missing_value = "on")]
    cut_cells: Option<OnOff>,
    /// Run every SIMD kernel on its portable (SSE2 baseline) path instead of AVX2 + FMA, to check
    /// the fallbacks against a run on the AVX2 paths (the fluid's agree to the bit).
    #[arg(long)]
    portable_simd: bool,
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
    /// Vortices of the "with vortices" column (the paper: up to 100); 0 leaves them out. They
    /// follow no flow-rate rule here: all of them from the first step.
    #[arg(long, default_value_t = 100)]
    vortices: usize,
    /// Vortex mode: `overlay` (display only: measured in the same run, the fluid state is
    /// untouched) or `injected` (into the solver's state: a second run per voxel size).
    #[arg(long, value_enum, default_value_t = BenchVortexMode::Overlay)]
    vortex_mode: BenchVortexMode,
    /// Steps at fully open valves before the time to traverse is taken (the flow settles).
    #[arg(long, default_value_t = 120)]
    traverse_settle_steps: usize,
    /// Longest time a tracer is followed for the time to traverse, s.
    #[arg(long, default_value_t = 10.0)]
    traverse_max_s: f64,
    /// Overrides the scene's `fluid.max_cfl` (`inf`: one fluid step per frame, the paper's
    /// Table 1 and the session-7 figures).
    #[arg(long)]
    max_cfl: Option<f64>,
    /// Cut cells (`[fluid] cut_cells`) on or off whatever the scene file says (on by default;
    /// `--cut-cells` alone means on).
    #[arg(long, value_enum, value_name = "on|off", num_args = 0..=1, default_missing_value = "on")]
    cut_cells: Option<OnOff>,
    /// Turn off the fork-join guard (on in the daemon: it runs the solver's joins in one thread
    /// while the helper thread does not pay, e.g. another process on its core): every join is
    /// offered to the helper, to measure the guard against.
    #[arg(long)]
    no_fork_join_guard: bool,
    /// Compare fork-joins instead of the Table 1 columns (comma separated: helper, rayon,
    /// chili): per voxel size, `--repeats` runs of each, interleaved, each a new scene with the
    /// same warm-up and timed steps at the operating point (and the same vortices); prints the
    /// step and fluid-stage ms (mean, median, p99), the projection's iterations and divergence,
    /// and whether every run ended in the same state.
    #[arg(long, value_enum, value_delimiter = ',')]
    fork_join: Vec<ForkJoinArg>,
    /// Runs per fork-join and voxel size of `--fork-join` (interleaved: one of each in turn).
    #[arg(long, default_value_t = 1)]
    repeats: usize,
    /// Busy threads competing for the cores while `--fork-join` runs (0: quiet), as a renderer or
    /// another process on the machine would.
    #[arg(long, default_value_t = 0)]
    load_threads: usize,
    /// Print JSON instead of a table.
    #[arg(long)]
    json: bool,
}

/// `scene bench --vortex-mode`.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum BenchVortexMode {
    /// Display-only overlay.
    Overlay,
    /// Injected into the solver's state.
    Injected,
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
        SceneCommand::Converge(a) => crate::converge::run(&a),
    }
}

fn run_offline(a: &RunArgs) -> Result<()> {
    if !(a.seconds.is_finite() && a.seconds > 0.0 && a.seconds <= 24.0 * 3600.0) {
        bail!("--seconds {}: expected a duration in (0, 86400]", a.seconds);
    }
    if !(a.rate_hz.is_finite() && (1.0..=1000.0).contains(&a.rate_hz)) {
        bail!("--rate-hz {}: expected 1 to 1000", a.rate_hz);
    }
    hydrometra_sim::harness::simd::set_portable(a.portable_simd);
    let mut desc = SceneDesc::load(&a.scene.scene)?;
    if let Some(v) = a.voxel_mm {
        desc.fluid.voxel_mm = v;
        desc.validate()?;
    }
    if let Some(c) = a.cut_cells {
        desc.fluid.cut_cells = c == OnOff::On;
    }
    let (scenario, case) = load_scenario(&a.scenario)?;
    apply_scenario_hydraulics(&mut desc, &case);
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
         fluid_ran,projection_iterations,max_div_rel,particles_alive,clarity,balance_ml_min,\
         closed_mismatch_ml_min,cavity_less_sheath_volume_ml\n",
    );
    let mut pvd = vtk::Collection::new();
    let ml_min = |q: f64| q * 6e7;
    let mut written = 0;
    for f in 0..frames {
        let t = (f + 1) as f64 * dt;
        let inputs = scene_inputs_at(&scenario, &case, t);
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
        // With cut cells: the reference for the grid's fluid volume (empty without).
        let reference = r
            .cavity_less_sheath_volume_m3
            .map_or(String::new(), |v| format!("{:.5}", m3_to_ml(v)));
        let _ = writeln!(
            csv,
            "{f},{:.5},{:.4},{:.5},{:.5},{:.5},{},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{},{},{:.3e},{alive},{clarity},{:.3e},{:.3e},{reference}",
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
            div,
            // The projected field's net divergence over the fluid (docs/scene.md).
            ml_min(
                fl.fluid_inflow_m3_per_s
                    - fl.fluid_outflow_m3_per_s
                    - fl.fluid_wall_m3_per_s
                    - fl.fluid_open_m3_per_s
            ),
            ml_min(fl.closed_region_mismatch_m3_per_s)
        );
        if a.every > 0 && (f + 1) % a.every == 0 {
            let name = format!("frame_{written:05}");
            let cavity = format!("vtu/{name}_cavity.vtu");
            let flow = format!("vtu/{name}_flow.vtu");
            std::fs::write(a.out.join(&cavity), scene.cavity().vtu_string())
                .with_context(|| format!("writing {cavity}"))?;
            let flow_vtu = scene.flow().map(|f| f.vtu_string()).unwrap_or_default();
            std::fs::write(a.out.join(&flow), flow_vtu)
                .with_context(|| format!("writing {flow}"))?;
            pvd.dataset(t, 0, &cavity);
            pvd.dataset(t, 1, &flow);
            // The particles, when the scene has the stage: a file every series frame (no
            // points before any is released), so the series stays aligned in ParaView.
            if let Some(p) = scene.particles() {
                let particles = format!("vtu/{name}_particles.vtu");
                std::fs::write(a.out.join(&particles), p.vtu_string())
                    .with_context(|| format!("writing {particles}"))?;
                pvd.dataset(t, 2, &particles);
            }
            written += 1;
        }
    }
    std::fs::write(a.out.join("scene.csv"), csv).context("writing scene.csv")?;
    std::fs::write(a.out.join("scene.pvd"), pvd.finish()).context("writing scene.pvd")?;
    let r = scene.report();
    let summary = serde_json::json!({
        "scene": scene.desc().name,
        "scenario": a.scenario,
        "frames": frames,
        "rate_hz": a.rate_hz,
        "series_frames": written,
        "grid_dims": scene.cells().dims,
        "voxel_mm": scene.desc().fluid.voxel_mm,
        "simd": if hydrometra_sim::harness::simd::avx2_fma() { "avx2_fma" } else { "portable" },
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
    /// Vortices alive at the end of the "with vortices" run (0: not run).
    vortices: usize,
    vortex_mode: BenchVortexMode,
    /// The vortex stage alone, ms per step of the "with vortices" run.
    vortex_stage_ms_mean: f64,
    /// Fluid stage plus vortex stage, ms per step of the "with vortices" run (the paper's
    /// "CPU time with vortices").
    fluid_with_vortices_ms_mean: f64,
    /// `fluid_with_vortices_ms_mean` over `fluid_ms_mean`, minus 1, in %.
    vortex_overhead_percent: f64,
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
    /// Time to traverse at fully open valves: tracers released next to the inflow port.
    traverse_released: usize,
    /// Tracers that reached the outflow holes within `--traverse-max-s`.
    traverse_reached: usize,
    /// Tracers that left through the open external os instead.
    traverse_open: usize,
    /// First arrival at the outflow holes, s (the paper's "time to traverse").
    traverse_first_s: Option<f64>,
    /// Half of the tracers arrived, s.
    traverse_median_s: Option<f64>,
}

/// What one timed run of the operating point measured.
struct Timed {
    scene: Scene,
    start: hydrometra_sim::scene::Counters,
    projection_iterations: usize,
    max_div_rel: f64,
    fluid_runs: usize,
}

impl Timed {
    /// Mean run time of stage `s` over the timed steps, ms (0 if it never ran).
    fn stage_mean_ms(&self, s: Stage) -> f64 {
        let (now, then) = (self.scene.report().counters.get(s), self.start.get(s));
        let runs = now.runs - then.runs;
        if runs == 0 {
            0.0
        } else {
            (now.total_ms - then.total_ms) / runs as f64
        }
    }
}

/// The bench's operating point at frame `f`: the default scenario's scope in the cavity, inflow
/// open, outflow `valve_out`, the pump at `pump_mmhg` (+-5 %); the scope sways slowly so
/// voxelization and ports run.
fn operating_point(f: usize, dt: f64, pump_mmhg: f64, valve_out: f64) -> RigInputs {
    let t = f as f64 * dt;
    let sway = 1.5e-3 * (0.7 * t).sin();
    RigInputs {
        hydraulic: HydraulicInputs {
            valve_in_opening: 1.0,
            valve_out_opening: valve_out,
            pump_set_pressure_pa: mmhg_to_pa(pump_mmhg) * (1.0 + 0.05 * (0.3 * t).sin()),
            perforation: false,
        },
        scope: ScopePose {
            // In the corpus of the default uterus (drivers/scenarios/default.toml, t = 45 s).
            tip_position_m: [sway, 0.0129, 0.0426],
            view_direction: [0.0, 0.5, 0.866],
            valid: true,
        },
    }
}

/// One timed step of the bench: a symbol of its own so that a profile can take the timed steps
/// alone (`valgrind --tool=callgrind --toggle-collect='*timed_step*'`), without the warm-up.
#[inline(never)]
fn timed_step<'a>(
    scene: &'a mut Scene,
    inputs: &SceneInputs,
    dt_s: f64,
) -> Result<&'a StepReport, SceneError> {
    scene.step(inputs, dt_s)
}

/// Warms up and times the operating point (outflow half open) on a new scene per description.
/// With several, their timed steps alternate (one step of each in turn), so that the machine's
/// drifts during the runs fall on all of them alike: a like-for-like comparison.
fn timed_runs(descs: Vec<SceneDesc>, assets: &SceneAssets, a: &BenchArgs) -> Result<Vec<Timed>> {
    let dt = 1.0 / a.rate_hz;
    let inputs = |f: usize| SceneInputs {
        rig: operating_point(f, dt, a.pump_mmhg, 0.5),
        hydraulics: HydraulicsInput::Own,
    };
    let mut runs = Vec::with_capacity(descs.len());
    let joins_before = (helper_tasks(), guard_serial_joins());
    for desc in descs {
        let mut scene = Scene::new(desc, assets.clone())?;
        for f in 0..a.warmup {
            scene.step(&inputs(f), dt)?;
        }
        let start = scene.report().counters.clone();
        runs.push((
            Timed {
                scene,
                start,
                projection_iterations: 0,
                max_div_rel: 0.0,
                fluid_runs: 0,
            },
            FluidTimes::default(),
        ));
    }
    for f in a.warmup..a.warmup + a.steps {
        for (run, times) in &mut runs {
            let r = timed_step(&mut run.scene, &inputs(f), dt)?;
            if let Some(s) = r.fluid {
                run.projection_iterations += s.projection_iterations;
                run.max_div_rel = run.max_div_rel.max(s.max_div_rel);
                run.fluid_runs += 1;
                times.rebuilds += usize::from(s.topology_rebuilt);
                times.substeps += s.substeps;
                times.topology_ms += s.topology_ms;
                times.advect_ms += s.advect_ms;
                times.project_ms += s.project_ms;
            }
        }
    }
    // Process-wide counts, over the warm-up and the timed steps of every run of this call.
    let (helper, serial) = (
        helper_tasks() - joins_before.0,
        guard_serial_joins() - joins_before.1,
    );
    Ok(runs
        .into_iter()
        .map(|(run, times)| {
            let per_run = |x: f64| x / run.fluid_runs.max(1) as f64;
            eprintln!(
                "{} mm{}: {} fluid steps, {} substeps, {} topology rebuilds; per fluid step: topology {:.3} ms, advection {:.3} ms, projection {:.3} ms; halves on the fork-join helper {}, joins the guard ran in one thread {}",
                run.scene.desc().fluid.voxel_mm,
                if run.scene.vortices().is_some() { " with vortices" } else { "" },
                run.fluid_runs,
                times.substeps,
                times.rebuilds,
                per_run(times.topology_ms),
                per_run(times.advect_ms),
                per_run(times.project_ms),
                helper,
                serial
            );
            run
        })
        .collect())
}

/// The fluid step's parts summed over a timed run.
#[derive(Default)]
struct FluidTimes {
    rebuilds: usize,
    substeps: usize,
    topology_ms: f64,
    advect_ms: f64,
    project_ms: f64,
}

/// `desc` with `n` vortices in `mode`, all of them from the first step.
fn with_vortices(mut desc: SceneDesc, n: usize, mode: BenchVortexMode) -> Result<SceneDesc> {
    desc.stages.vortices = true;
    let v = &mut desc.vortices;
    v.max_count = n;
    v.threshold_ml_min = 0.0;
    v.full_flow_ml_min = 1e-6;
    v.mode = match mode {
        BenchVortexMode::Overlay => hydrometra_sim::scene::vortices::VortexMode::Overlay,
        BenchVortexMode::Injected => hydrometra_sim::scene::vortices::VortexMode::Injected,
    };
    desc.validate()?;
    Ok(desc)
}

fn bench(a: &BenchArgs) -> Result<()> {
    if !(a.traverse_max_s.is_finite() && a.traverse_max_s > 0.0) {
        bail!(
            "--traverse-max-s {}: expected a duration > 0",
            a.traverse_max_s
        );
    }
    set_guard(!a.no_fork_join_guard);
    let base = SceneDesc::load(&a.scene.scene)?;
    let (assets, _) = assets(&base, &a.scene)?;
    if !a.fork_join.is_empty() {
        return fork_join_bench(a, &base, &assets);
    }
    let dt = 1.0 / a.rate_hz;
    let mut rows = Vec::new();
    for &v in &a.voxels_mm {
        let desc = bench_desc(&base, a, v)?;
        // Overlay vortices leave the solver's state alone: the run with them times the fluid
        // step without them too (like for like, the same steps). Injected ones change the
        // state: a baseline scene without and a second scene with them, their steps alternating.
        let overlay = a.vortices > 0 && a.vortex_mode == BenchVortexMode::Overlay;
        let mut descs = vec![if overlay {
            with_vortices(desc.clone(), a.vortices, a.vortex_mode)?
        } else {
            desc.clone()
        }];
        if a.vortices > 0 && !overlay {
            descs.push(with_vortices(desc.clone(), a.vortices, a.vortex_mode)?);
        }
        let mut timed = timed_runs(descs, &assets, a)?.into_iter();
        let (Some(mut run), injected) = (timed.next(), timed.next()) else {
            bail!("{v} mm: no timed run");
        };
        let with = injected.as_ref().unwrap_or(&run);
        let vortices = with
            .scene
            .vortices()
            .and_then(|x| x.field())
            .map_or(0, |f| f.vortices().len());
        if vortices != a.vortices {
            tracing::warn!(
                "{v} mm: {vortices} vortices alive at the end of the run, {} asked for",
                a.vortices
            );
        }
        // The fluid stage followed by the vortex stage, per run, in the run with vortices (at
        // the operating point both run every step).
        let vortex_stage = with.stage_mean_ms(Stage::Vortices);
        let fluid_with = with.stage_mean_ms(Stage::Fluid) + vortex_stage;
        let fluid_without = run.stage_mean_ms(Stage::Fluid);
        let overhead = if a.vortices > 0 && fluid_without > 0.0 {
            100.0 * (fluid_with / fluid_without - 1.0)
        } else {
            f64::NAN
        };
        drop(injected);

        let scene = &run.scene;
        let r = scene.report();
        let c = &r.counters;
        let step_mean = (c.step.total_ms - run.start.step.total_ms) / a.steps as f64;
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
        let mut row = BenchRow {
            voxel_mm: v,
            box_cells: scene.cells().cell_count(),
            fluid_cells: r.fluid_cells,
            fluid_ms_mean: run.stage_mean_ms(Stage::Fluid),
            fluid_ms_p99: c.get(Stage::Fluid).p99_ms(),
            projection_iterations_mean: run.projection_iterations as f64
                / run.fluid_runs.max(1) as f64,
            max_div_rel: run.max_div_rel,
            vortices,
            vortex_mode: a.vortex_mode,
            vortex_stage_ms_mean: vortex_stage,
            fluid_with_vortices_ms_mean: fluid_with,
            vortex_overhead_percent: overhead,
            voxelize_full_ms: full_ms,
            voxelize_incremental_ms_mean: run.stage_mean_ms(Stage::Voxelize),
            voxelize_incremental_ms_p99: c.get(Stage::Voxelize).p99_ms(),
            replay_us_mean: 1e3 * run.stage_mean_ms(Stage::Deformation),
            replay_us_p99: 1e3 * c.get(Stage::Deformation).p99_ms(),
            step_ms_mean: step_mean,
            step_ms_p99: c.step.p99_ms(),
            grid_fluid_volume_ml: grid_ml,
            surface_volume_ml: surf_ml,
            volume_error_percent: 100.0 * (grid_ml / surf_ml - 1.0),
            traverse_released: 0,
            traverse_reached: 0,
            traverse_open: 0,
            traverse_first_s: None,
            traverse_median_s: None,
        };
        // Time to traverse: both valves fully open until the flow settles, then tracers from
        // the inflow port in the frozen flow, 1 ms steps (under a voxel per substep up to
        // about 10 m/s at 0.6 mm).
        let settle_from = a.warmup + a.steps;
        for f in settle_from..settle_from + a.traverse_settle_steps {
            let mut rig = operating_point(f, dt, a.pump_mmhg, 1.0);
            rig.scope.tip_position_m[0] = 0.0;
            run.scene.step(
                &SceneInputs {
                    rig,
                    hydraulics: HydraulicsInput::Own,
                },
                dt,
            )?;
        }
        if let Some(t) = (run.scene.flow()).map(|f| f.time_to_traverse(1e-3, a.traverse_max_s)) {
            row.traverse_released = t.released;
            row.traverse_reached = t.reached;
            row.traverse_open = t.open;
            row.traverse_first_s = t.first_s;
            row.traverse_median_s = t.median_s;
        }
        rows.push(row);
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
        return Ok(());
    }
    println!(
        "scene {}, {} warm-up + {} timed steps at {} Hz, pump {} mmHg, rayon threads {}; \
         with vortices: {} ({:?}{}); time to traverse: valves fully open after {} steps, tracers \
         spread over the inflow port's fluid faces (a {}x{} sub-grid per face), first arrival / \
         half arrived (of released), at most {} s",
        base.name,
        a.warmup,
        a.steps,
        a.rate_hz,
        a.pump_mmhg,
        rayon::current_num_threads(),
        a.vortices,
        a.vortex_mode,
        if a.vortex_mode == BenchVortexMode::Overlay {
            ", the same run; step ms includes them"
        } else {
            ", a second run"
        },
        a.traverse_settle_steps,
        TRAVERSE_SUBGRID,
        TRAVERSE_SUBGRID,
        a.traverse_max_s
    );
    let opt = |x: Option<f64>| x.map_or("-".to_string(), |v| format!("{v:.2}"));
    println!("| voxel mm | box cells | fluid cells | fluid ms mean / p99 | fluid + {} vortices ms (+%) | CG its | max div h/U | voxelize full ms | voxelize incr. ms mean / p99 | replay us mean / p99 | step ms mean / p99 | grid vol ml | surface vol ml | vol err % | time to traverse s |", a.vortices);
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for r in &rows {
        // No vortices asked: no vortex figures (the overhead would be 0/0).
        let with_vortices = if a.vortices > 0 {
            format!(
                "{:.3} ({:+.0} %)",
                r.fluid_with_vortices_ms_mean, r.vortex_overhead_percent
            )
        } else {
            "-".to_string()
        };
        println!(
            "| {} | {} | {} | {:.3} / {:.3} | {} | {:.1} | {:.1e} | {:.3} | {:.3} / {:.3} | {:.1} / {:.1} | {:.3} / {:.3} | {:.3} | {:.3} | {:+.1} | {} / {} ({}/{}) |",
            r.voxel_mm, r.box_cells, r.fluid_cells, r.fluid_ms_mean, r.fluid_ms_p99,
            with_vortices,
            r.projection_iterations_mean, r.max_div_rel, r.voxelize_full_ms,
            r.voxelize_incremental_ms_mean, r.voxelize_incremental_ms_p99, r.replay_us_mean,
            r.replay_us_p99, r.step_ms_mean, r.step_ms_p99, r.grid_fluid_volume_ml,
            r.surface_volume_ml, r.volume_error_percent, opt(r.traverse_first_s),
            opt(r.traverse_median_s), r.traverse_reached, r.traverse_released
        );
    }
    Ok(())
}

/// One timed run of `scene bench --fork-join`.
#[derive(Debug, Default, serde::Serialize)]
struct ForkJoinRun {
    /// Wall time of every timed scene step, ms.
    #[serde(skip)]
    step_ms: Vec<f64>,
    /// The fluid stage's time in the timed steps it ran, ms.
    #[serde(skip)]
    fluid_ms: Vec<f64>,
    fluid_steps: usize,
    projection_iterations: usize,
    div_rel_sum: f64,
    div_rel_max: f64,
    /// Halves run on the fork-join helper, and joins its guard ran in one thread, in the timed
    /// steps (process-wide counts: zero for the other fork-joins).
    helper_halves: u64,
    guard_serial_joins: u64,
    /// FNV-1a of the flow field's velocities and the cavity pressure after the run.
    state_digest: u64,
}

/// A row of `scene bench --fork-join`: one fork-join at one voxel size, its runs pooled.
#[derive(Debug, serde::Serialize)]
struct ForkJoinRow {
    voxel_mm: f64,
    fork_join: String,
    runs: usize,
    load_threads: usize,
    step_ms: StepTimes,
    fluid_ms: StepTimes,
    projection_iterations_mean: f64,
    div_rel_mean: f64,
    div_rel_max: f64,
    helper_halves: u64,
    guard_serial_joins: u64,
    /// The state digest of every run (equal when the fork-joins ran the same arithmetic).
    state_digests: Vec<u64>,
}

/// The flow field's velocities and the cavity pressure, hashed bit for bit (FNV-1a).
fn state_digest(scene: &Scene) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    let mut eat = |bits: u64| {
        for b in bits.to_le_bytes() {
            h = (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
        }
    };
    if let Some(flow) = scene.flow() {
        let mut vel = vec![[0.0f32; 3]; flow.kinds().len()];
        flow.velocities_into(&mut vel);
        for v in &vel {
            v.iter().for_each(|x| eat(u64::from(x.to_bits())));
        }
    }
    eat(scene.report().cavity_pressure_pa.to_bits());
    h
}

/// Warms up and times one scene of `desc` at the operating point on the current fork-join.
fn fork_join_run(desc: SceneDesc, assets: &SceneAssets, a: &BenchArgs) -> Result<ForkJoinRun> {
    let dt = 1.0 / a.rate_hz;
    let inputs = |f: usize| SceneInputs {
        rig: operating_point(f, dt, a.pump_mmhg, 0.5),
        hydraulics: HydraulicsInput::Own,
    };
    let mut scene = Scene::new(desc, assets.clone())?;
    for f in 0..a.warmup {
        scene.step(&inputs(f), dt)?;
    }
    let mut run = ForkJoinRun {
        step_ms: Vec::with_capacity(a.steps),
        fluid_ms: Vec::with_capacity(a.steps),
        ..Default::default()
    };
    let before = (helper_tasks(), guard_serial_joins());
    for f in a.warmup..a.warmup + a.steps {
        let r = timed_step(&mut scene, &inputs(f), dt)?;
        let c = &r.counters;
        run.step_ms.push(c.step.last_ms);
        if c.get(Stage::Fluid).ran_last {
            run.fluid_ms.push(c.get(Stage::Fluid).last_ms);
        }
        if let Some(s) = r.fluid {
            run.fluid_steps += 1;
            run.projection_iterations += s.projection_iterations;
            run.div_rel_sum += s.max_div_rel;
            run.div_rel_max = run.div_rel_max.max(s.max_div_rel);
        }
    }
    run.helper_halves = helper_tasks() - before.0;
    run.guard_serial_joins = guard_serial_joins() - before.1;
    run.state_digest = state_digest(&scene);
    Ok(run)
}

/// `scene bench --fork-join`: the fork-joins like for like on the real scene (module doc of
/// `sim-core/src/fork_join.rs`), quiet or beside `--load-threads` busy threads.
/// The benchmark's scene at voxel size `voxel_mm`: the base with `--max-cfl` applied and its own
/// vortices off (the benchmark adds its own).
fn bench_desc(base: &SceneDesc, a: &BenchArgs, voxel_mm: f64) -> Result<SceneDesc> {
    let mut desc = base.clone();
    desc.fluid.voxel_mm = voxel_mm;
    if let Some(c) = a.max_cfl {
        desc.fluid.max_cfl = c;
    }
    if let Some(c) = a.cut_cells {
        desc.fluid.cut_cells = c == OnOff::On;
    }
    desc.stages.vortices = false;
    desc.validate()?;
    Ok(desc)
}

fn fork_join_bench(a: &BenchArgs, base: &SceneDesc, assets: &SceneAssets) -> Result<()> {
    if a.repeats == 0 || a.steps == 0 {
        bail!("--repeats and --steps must be at least 1");
    }
    let load = BusyThreads::start(a.load_threads).context("starting the load threads")?;
    let mut rows = Vec::new();
    for &v in &a.voxels_mm {
        let mut desc = bench_desc(base, a, v)?;
        if a.vortices > 0 {
            desc = with_vortices(desc, a.vortices, a.vortex_mode)?;
        }
        let mut runs: Vec<Vec<ForkJoinRun>> = a.fork_join.iter().map(|_| Vec::new()).collect();
        for _ in 0..a.repeats {
            for (i, &fj) in a.fork_join.iter().enumerate() {
                set_backend(fj.into());
                let run = fork_join_run(desc.clone(), assets, a);
                set_backend(Backend::Helper);
                runs[i].push(run?);
            }
        }
        for (fj, runs) in a.fork_join.iter().zip(runs) {
            let pool = |f: fn(&ForkJoinRun) -> &Vec<f64>| -> Vec<f64> {
                runs.iter().flat_map(|r| f(r).iter().copied()).collect()
            };
            let fluid_steps = runs.iter().map(|r| r.fluid_steps).sum::<usize>().max(1) as f64;
            rows.push(ForkJoinRow {
                voxel_mm: v,
                fork_join: format!("{fj:?}").to_lowercase(),
                runs: runs.len(),
                load_threads: load.count(),
                step_ms: StepTimes::of(&pool(|r| &r.step_ms)),
                fluid_ms: StepTimes::of(&pool(|r| &r.fluid_ms)),
                projection_iterations_mean: runs
                    .iter()
                    .map(|r| r.projection_iterations)
                    .sum::<usize>() as f64
                    / fluid_steps,
                div_rel_mean: runs.iter().map(|r| r.div_rel_sum).sum::<f64>() / fluid_steps,
                div_rel_max: runs.iter().map(|r| r.div_rel_max).fold(0.0, f64::max),
                helper_halves: runs.iter().map(|r| r.helper_halves).sum(),
                guard_serial_joins: runs.iter().map(|r| r.guard_serial_joins).sum(),
                state_digests: runs.iter().map(|r| r.state_digest).collect(),
            });
        }
        tracing::info!("{v} mm done");
    }
    drop(load);
    if a.json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
        return Ok(());
    }
    println!(
        "scene {}, fork-joins compared: {} warm-up + {} timed steps at {} Hz per run, pump {} mmHg, \
         {} run(s) per fork-join interleaved, rayon threads {}, load threads {}, fork-join guard {}, \
         vortices {} ({:?}). ms: wall time of the timed steps of all runs pooled (scene step; fluid \
         stage where it ran), mean ± sem, median, p99 (nearest rank). div h/U: max |div u| h / U \
         after each fluid step, mean and worst.",
        base.name,
        a.warmup,
        a.steps,
        a.rate_hz,
        a.pump_mmhg,
        a.repeats,
        rayon::current_num_threads(),
        a.load_threads,
        if a.no_fork_join_guard { "off" } else { "on" },
        a.vortices,
        a.vortex_mode
    );
    println!("| voxel mm | fork-join | step ms mean ± sem | median | p99 | fluid ms mean ± sem | median | p99 | CG its | div h/U mean / max | helper halves | guard serial joins |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
    for r in &rows {
        let (s, f) = (&r.step_ms, &r.fluid_ms);
        println!(
            "| {} | {} | {:.3} ± {:.3} | {:.3} | {:.3} | {:.3} ± {:.3} | {:.3} | {:.3} | {:.2} | {:.2e} / {:.2e} | {} | {} |",
            r.voxel_mm, r.fork_join, s.mean, s.sem, s.median, s.p99, f.mean, f.sem, f.median,
            f.p99, r.projection_iterations_mean, r.div_rel_mean, r.div_rel_max, r.helper_halves,
            r.guard_serial_joins
        );
    }
    // The fork-join changes which thread runs a half, never the arithmetic: every run of a voxel
    // size must end in the same state.
    for v in &a.voxels_mm {
        let digests: Vec<u64> = rows
            .iter()
            .filter(|r| r.voxel_mm == *v)
            .flat_map(|r| r.state_digests.iter().copied())
            .collect();
        let same = digests.windows(2).all(|w| w[0] == w[1]);
        println!(
            "{v} mm: final state {} in all {} runs",
            if same { "identical" } else { "DIFFERENT" },
            digests.len()
        );
    }
    Ok(())
}
