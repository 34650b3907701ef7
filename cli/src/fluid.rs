//! `hydrometra fluid`: run fluid case files, print the Table 1 benchmark, run the stability soak.

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use hydrometra_sim::fluid::case::Case;
use hydrometra_sim::fluid::{AdvectionScheme, FluidParams, ProjectionMethod};
use hydrometra_sim::harness::analytic_cavity::{
    CAVITY_SEMI_AXES_M, UTERINE_HALF_LENGTH_M, UTERINE_HALF_THICKNESS_M, UTERINE_HALF_WIDTH_M,
    UTERINE_TAPER,
};
use hydrometra_sim::harness::benchmark::{
    bench_shape, BenchRow, Cavity, StepTimes, PAPER_FLUID_VOXELS, PAPER_MS, PAPER_VOXELS_M,
};
use hydrometra_sim::harness::fork_join::{set_backend, Backend};
use hydrometra_sim::harness::load::BusyThreads;
use hydrometra_sim::harness::soak::run_soak;

/// `hydrometra fluid ...`
#[derive(Subcommand, Debug)]
pub enum FluidCommand {
    /// Run a case file (docs/fluid-cases.md) and report its probes and statistics.
    Run(RunArgs),
    /// The paper's Table 1 on the uterine benchmark cavity: our solver and the Gauss-Seidel baseline
    /// side by side, with per-stage times.
    Bench(BenchArgs),
    /// The stability soak: random inflow switching, CFL up to 50, labels flipping.
    Soak(SoakArgs),
    /// The analytic validation cases at several resolutions: error against run time.
    Validate(ValidateArgs),
}

/// Arguments of `fluid validate`.
#[derive(Args, Debug)]
pub struct ValidateArgs {
    /// Also run the finest (slowest) resolutions: duct 32, Taylor-Green 128, Ethier-Steinman 32.
    #[arg(long)]
    pub fine: bool,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Advection schemes of the Taylor-Green, ABC and cavity rows (comma separated); default: all.
    #[arg(long, value_enum, value_delimiter = ',')]
    pub advection: Vec<AdvectionArg>,
    /// Only the advection rows (Taylor-Green, ABC, cavity), not the duct and Ethier-Steinman.
    #[arg(long)]
    pub advection_only: bool,
}

/// Arguments of `fluid run`.
#[derive(Args, Debug)]
pub struct RunArgs {
    /// The case file (TOML).
    #[arg(long)]
    pub case: PathBuf,
    /// Print the report as JSON on stdout.
    #[arg(long)]
    pub json: bool,
    /// Write report.json and one CSV per probe into this directory (created if missing).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// Arguments of `fluid bench`.
#[derive(Args, Debug)]
pub struct BenchArgs {
    /// Timed steps per row.
    #[arg(long, default_value_t = 200)]
    pub steps: usize,
    /// Untimed steps before (the jet develops, the warm start settles).
    #[arg(long, default_value_t = 60)]
    pub warmup: usize,
    /// Time step (s); the default is the 60 Hz frame of the paper's simulator.
    #[arg(long, default_value_t = 1.0 / 60.0, conflicts_with = "hz")]
    pub dt_s: f64,
    /// Step rate (Hz) instead of --dt-s: dt = 1 / HZ.
    #[arg(long)]
    pub hz: Option<f64>,
    /// Advection scheme of our solver (and of the baseline); default: the solver's default.
    #[arg(long, value_enum)]
    pub advection: Option<AdvectionArg>,
    /// Skip the Gauss-Seidel baselines (only our solver's rows).
    #[arg(long)]
    pub no_baseline: bool,
    /// Fork-joins to run our solver on, comma separated (each one a row; the baselines use the
    /// helper): the home-made spinning helper, `rayon::join`, chili's heartbeat join.
    #[arg(long, value_enum, value_delimiter = ',', default_value = "helper")]
    pub fork_join: Vec<ForkJoinArg>,
    /// Runs per row, interleaved across the rows of a voxel size (pooled in the table).
    #[arg(long, default_value_t = 1)]
    pub repeats: usize,
    /// Benchmark geometry: the analytic uterine cavity (matches the paper's fluid-cell counts) or the
    /// earlier ellipsoid (for comparison with older figures).
    #[arg(long, value_enum, default_value_t = CavityArg::Uterine)]
    pub cavity: CavityArg,
    /// Jet speed at the scope tip (m/s).
    #[arg(long, default_value_t = 1.0)]
    pub jet_m_s: f32,
    /// Divergence tolerance of our projection (max |div u| h / U).
    #[arg(long, default_value_t = 1e-5)]
    pub tolerance: f64,
    /// Gauss-Seidel sweeps per step of the baselines.
    #[arg(long, default_value_t = 20)]
    pub sweeps: usize,
    /// Voxel sizes (mm), comma separated.
    #[arg(long, value_delimiter = ',', default_value = "0.6,0.9,1.2,1.5,1.8")]
    pub voxels_mm: Vec<f64>,
    /// Rayon threads (0: rayon's default, all cores).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Busy threads competing for the cores while the rows run (0: quiet), to measure the
    /// fork-joins under load.
    #[arg(long, default_value_t = 0)]
    pub load_threads: usize,
    /// Print the rows as JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// A fork-join on the command line.
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum ForkJoinArg {
    /// The solver's spinning helper thread.
    Helper,
    /// `rayon::join`.
    Rayon,
    /// `chili::Scope::join`.
    Chili,
}

impl From<ForkJoinArg> for Backend {
    fn from(f: ForkJoinArg) -> Self {
        match f {
            ForkJoinArg::Helper => Backend::Helper,
            ForkJoinArg::Rayon => Backend::Rayon,
            ForkJoinArg::Chili => Backend::Chili,
        }
    }
}

/// Benchmark geometry on the command line.
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum CavityArg {
    /// The analytic uterine cavity (flattened pear; `harness::analytic_cavity`).
    Uterine,
    /// The earlier ellipsoid.
    Ellipsoid,
}

/// Advection scheme on the command line (docs/fluid-cases.md, `[solver] advection`).
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum AdvectionArg {
    /// RK2 semi-Lagrangian.
    SemiLagrangian,
    /// MacCormack (clamped) on top of it.
    Maccormack,
    /// BFECC (clamped).
    Bfecc,
    /// Semi-Lagrangian with monotone (clamped) tricubic interpolation.
    MonotoneCubic,
    /// Advection-reflection with clamped MacCormack half steps.
    MaccormackReflection,
    /// Clamped MacCormack with the lagged-pressure reflection.
    MaccormackLaggedReflection,
}

impl From<AdvectionArg> for AdvectionScheme {
    fn from(a: AdvectionArg) -> Self {
        match a {
            AdvectionArg::SemiLagrangian => AdvectionScheme::SemiLagrangian,
            AdvectionArg::Maccormack => AdvectionScheme::MacCormack,
            AdvectionArg::Bfecc => AdvectionScheme::Bfecc,
            AdvectionArg::MonotoneCubic => AdvectionScheme::MonotoneCubic,
            AdvectionArg::MaccormackReflection => AdvectionScheme::MacCormackReflection,
            AdvectionArg::MaccormackLaggedReflection => AdvectionScheme::MacCormackLaggedReflection,
        }
    }
}

/// The scheme of `--advection`, or the solver's default.
fn scheme_or_default(a: Option<AdvectionArg>) -> AdvectionScheme {
    a.map_or_else(|| FluidParams::default().advection, AdvectionScheme::from)
}

/// Arguments of `fluid soak`.
#[derive(Args, Debug)]
pub struct SoakArgs {
    /// Steps.
    #[arg(long, default_value_t = 1_000_000)]
    pub steps: usize,
    /// Random seed.
    #[arg(long, default_value_t = 7)]
    pub seed: u64,
    /// Use MacCormack advection instead of semi-Lagrangian (same as `--advection maccormack`).
    #[arg(long, conflicts_with = "advection")]
    pub maccormack: bool,
    /// Advection scheme; default: the solver's default.
    #[arg(long, value_enum)]
    pub advection: Option<AdvectionArg>,
}

/// Runs a `fluid` subcommand.
pub fn run(cmd: FluidCommand) -> Result<()> {
    match cmd {
        FluidCommand::Run(a) => run_case(a),
        FluidCommand::Bench(a) => bench(a),
        FluidCommand::Soak(a) => soak(a),
        FluidCommand::Validate(a) => validate(a),
    }
}

fn run_case(a: RunArgs) -> Result<()> {
    let text = std::fs::read_to_string(&a.case)
        .with_context(|| format!("reading case file {}", a.case.display()))?;
    let case =
        Case::parse_at(&text, Some(&a.case)).with_context(|| format!("in {}", a.case.display()))?;
    let report = case
        .run()
        .with_context(|| format!("running {}", a.case.display()))?;
    let json = serde_json::to_string_pretty(&report)?;
    if let Some(dir) = &a.out {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let path = dir.join("report.json");
        std::fs::write(&path, &json).with_context(|| format!("writing {}", path.display()))?;
        for p in &report.probes {
            let safe: String = p
                .name
                .chars()
                .map(|c| {
                    if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                        c
                    } else {
                        '_'
                    }
                })
                .collect();
            let mut csv = String::from("x_m,y_m,z_m,u_m_s,v_m_s,w_m_s,pressure_pa\n");
            for s in &p.samples {
                let [x, y, z] = s.position_m;
                let [u, v, w] = s.velocity_m_s;
                let pr = s.pressure_pa.map_or(String::new(), |p| format!("{p:e}"));
                writeln!(csv, "{x:e},{y:e},{z:e},{u:e},{v:e},{w:e},{pr}")?;
            }
            let path = dir.join(format!("probe_{safe}.csv"));
            std::fs::write(&path, csv).with_context(|| format!("writing {}", path.display()))?;
        }
        tracing::info!("wrote {}", dir.display());
    }
    if a.json {
        println!("{json}");
    } else {
        let s = &report.statistics;
        println!(
            "{} steps, {:.4} s simulated, {} fluid cells ({} regions, {} closed)",
            s.steps, s.simulated_time_s, s.fluid_cells, s.regions, s.closed_regions
        );
        println!(
            "ms/step mean {:.3}, p99 {:.3}; projection iterations mean {:.1}, max {}; unconverged {}",
            s.ms_per_step_mean,
            s.ms_per_step_p99,
            s.projection_iterations_mean,
            s.projection_iterations_max,
            s.unconverged_projections
        );
        println!(
            "final max |div u| h/U {:.2e}; kinetic energy {:.4e} J; max speed {:.4e} m/s; steady {}",
            s.final_max_div_rel, s.kinetic_energy_j, s.max_speed_m_s, s.steady_reached
        );
        for p in &report.probes {
            println!("probe {}:", p.name);
            for s in &p.samples {
                let [x, y, z] = s.position_m;
                let [u, v, w] = s.velocity_m_s;
                let pr = s
                    .pressure_pa
                    .map_or("-".to_string(), |p| format!("{p:.4e}"));
                println!("  ({x:.5}, {y:.5}, {z:.5}) m  u = ({u:.5e}, {v:.5e}, {w:.5e}) m/s  p = {pr} Pa");
            }
        }
    }
    Ok(())
}

/// One solver configuration of the benchmark table.
#[derive(Clone, Copy, Debug)]
struct Config {
    label: &'static str,
    projection: ProjectionMethod,
    fork_join: Backend,
    /// Run with one thread (the fork-join then runs both halves in the caller).
    one_thread: bool,
}

fn bench(a: BenchArgs) -> Result<()> {
    if a.threads > 0 {
        rayon::ThreadPoolBuilder::new()
            .num_threads(a.threads)
            .build_global()
            .context("configuring the rayon thread pool")?;
    }
    anyhow::ensure!(a.steps > 0, "--steps must be at least 1");
    anyhow::ensure!(a.repeats > 0, "--repeats must be at least 1");
    let dt_s = match a.hz {
        Some(hz) => {
            anyhow::ensure!(
                hz.is_finite() && hz > 0.0,
                "--hz must be a finite rate > 0, got {hz}"
            );
            1.0 / hz
        }
        None => a.dt_s,
    };
    anyhow::ensure!(
        dt_s.is_finite() && dt_s > 0.0,
        "--dt-s must be > 0, got {dt_s}"
    );
    for &mm in &a.voxels_mm {
        anyhow::ensure!(
            mm.is_finite() && mm > 0.0,
            "--voxels-mm: {mm} is not a voxel size > 0 (mm)"
        );
    }
    let advection = scheme_or_default(a.advection);
    let cavity = match a.cavity {
        CavityArg::Uterine => Cavity::Uterine,
        CavityArg::Ellipsoid => Cavity::Ellipsoid,
    };
    // Ours with each fork-join asked for, then the baselines: the like-for-like one (warm start,
    // dense SIMD kernels, the same fork-join) and the paper-class one as the paper ran it.
    let mut configs: Vec<Config> = a
        .fork_join
        .iter()
        .map(|&f| Config {
            label: match f {
                ForkJoinArg::Helper => "ours (MG-PCG), helper fork-join",
                ForkJoinArg::Rayon => "ours (MG-PCG), rayon::join",
                ForkJoinArg::Chili => "ours (MG-PCG), chili join",
            },
            projection: ProjectionMethod::MultigridPcg,
            fork_join: f.into(),
            one_thread: false,
        })
        .collect();
    let sweeps = a.sweeps;
    if !a.no_baseline {
        configs.push(Config {
            label: "GS red-black, warm, dense SIMD, 2 halves (like for like)",
            projection: ProjectionMethod::RedBlackGaussSeidel { sweeps },
            fork_join: Backend::Helper,
            one_thread: false,
        });
        configs.push(Config {
            label: "GS lexicographic, cold, 1 thread, compressed rows (paper-class)",
            projection: ProjectionMethod::GaussSeidel { sweeps },
            fork_join: Backend::Helper,
            one_thread: true,
        });
    }
    // Rows of one voxel size and configuration over the repeats, interleaved so that load drifts
    // touch every configuration alike.
    let mut rows: Vec<(Config, Vec<BenchRow>)> = Vec::new();
    let load = BusyThreads::start(a.load_threads).context("starting the load threads")?;
    for &mm in &a.voxels_mm {
        let h = mm * 1e-3;
        let first = rows.len();
        for c in &configs {
            rows.push((*c, Vec::new()));
        }
        for _ in 0..a.repeats {
            for (i, c) in configs.iter().enumerate() {
                set_backend(c.fork_join);
                let params = FluidParams {
                    tolerance: a.tolerance,
                    projection: c.projection,
                    advection,
                    ..Default::default()
                };
                let run = || bench_shape(cavity, h, a.jet_m_s, dt_s, a.warmup, a.steps, params);
                let r = if c.one_thread {
                    rayon::ThreadPoolBuilder::new()
                        .num_threads(1)
                        .build()
                        .context("building a one-thread pool")?
                        .install(run)?
                } else {
                    run()?
                };
                rows[first + i].1.push(r);
            }
        }
        set_backend(Backend::Helper);
        tracing::info!("{mm} mm done");
    }
    drop(load);
    if a.json {
        let out: Vec<_> = rows
            .iter()
            .map(|(c, r)| serde_json::json!({"solver": c.label, "runs": r}))
            .collect();
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    let shape = match cavity {
        Cavity::Uterine => format!(
            "Uterine cavity (flattened pear: {} mm long, {} mm thick, mid half-width {} mm, taper {}; cells with all corners inside)",
            2e3 * UTERINE_HALF_LENGTH_M,
            2e3 * UTERINE_HALF_THICKNESS_M,
            1e3 * UTERINE_HALF_WIDTH_M,
            UTERINE_TAPER
        ),
        Cavity::Ellipsoid => {
            let [sa, sb, sc] = CAVITY_SEMI_AXES_M.map(|v| v * 1e3);
            format!("Ellipsoid cavity {sa} x {sb} x {sc} mm (semi-axes)")
        }
    };
    println!(
        "{shape}, jet {} m/s, dt {:.5} s, {:?} advection, {} warm-up + {} timed steps per run, {} run(s) per row interleaved, rayon threads {}, load threads {}, our tolerance max|div u|h/U <= {:.0e}, baselines {} Gauss-Seidel sweeps per step.",
        a.jet_m_s,
        dt_s,
        advection,
        a.warmup,
        a.steps,
        a.repeats,
        rayon::current_num_threads(),
        a.load_threads,
        a.tolerance,
        a.sweeps
    );
    println!("ms: wall time per step (mean ± sem and median over all timed steps of all runs; p99: the largest of the runs'). CPU: CLOCK_PROCESS_CPUTIME_ID (all threads) and CLOCK_THREAD_CPUTIME_ID (stepping thread) around the timed steps only. div h/U: max |div u| h / U after each step, its mean and worst over the steps.");
    println!();
    println!("| voxel [mm] | voxels total | fluid (paper) | paper ms | solver | ms mean ± sem | median | p99 | CPU ms all threads | CPU ms stepping thread | advect / diffuse / project / other ms | projection its | mean div h/U | max div h/U |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for (c, runs) in &rows {
        let Some(o) = runs.first() else { continue };
        let paper = PAPER_VOXELS_M
            .iter()
            .position(|&v| (v - o.voxel_m).abs() < 1e-9);
        let (pf, pm) = paper.map_or(("-".into(), "-".into()), |i| {
            (PAPER_FLUID_VOXELS[i].to_string(), PAPER_MS[i].to_string())
        });
        let m = merge(runs);
        println!(
            "| {:.1} | {} | {} ({}) | {} | {} | {:.2} ± {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.3} / {:.3} / {:.3} / {:.3} | {:.1} | {:.2e} | {:.2e} |",
            o.voxel_m * 1e3,
            o.voxels_total,
            o.fluid_voxels,
            pf,
            pm,
            c.label,
            m.ms_mean,
            m.ms_sem,
            m.ms_median,
            m.ms_p99,
            m.cpu_ms_per_step,
            m.caller_cpu_ms_per_step,
            m.advect_ms_mean,
            m.diffuse_ms_mean,
            m.project_ms_mean,
            m.other_ms_mean,
            m.iterations_mean,
            m.div_rel_mean,
            m.div_rel_max,
        );
    }
    Ok(())
}

/// The runs of one row as one: means weighted by steps, the sem of the pooled steps (from each
/// run's mean and sem), the largest p99 and worst divergence.
fn merge(runs: &[BenchRow]) -> BenchRow {
    let mut m = runs[0].clone();
    if runs.len() == 1 {
        return m;
    }
    let n: f64 = runs.iter().map(|r| r.steps as f64).sum();
    let mean =
        |f: fn(&BenchRow) -> f64| runs.iter().map(|r| f(r) * r.steps as f64).sum::<f64>() / n;
    m.ms_mean = mean(|r| r.ms_mean);
    // Pooled variance: within-run variance (sem^2 * steps) plus the spread of the run means.
    let var = runs
        .iter()
        .map(|r| {
            let k = r.steps as f64;
            r.ms_sem.powi(2) * k * k + k * (r.ms_mean - m.ms_mean).powi(2)
        })
        .sum::<f64>()
        / n;
    m.ms_sem = (var / n).sqrt();
    m.ms_p99 = runs.iter().map(|r| r.ms_p99).fold(0.0, f64::max);
    m.step_ms = runs
        .iter()
        .flat_map(|r| r.step_ms.iter().copied())
        .collect();
    m.ms_median = StepTimes::of(&m.step_ms).median;
    m.cpu_ms_per_step = mean(|r| r.cpu_ms_per_step);
    m.caller_cpu_ms_per_step = mean(|r| r.caller_cpu_ms_per_step);
    m.advect_ms_mean = mean(|r| r.advect_ms_mean);
    m.diffuse_ms_mean = mean(|r| r.diffuse_ms_mean);
    m.project_ms_mean = mean(|r| r.project_ms_mean);
    m.other_ms_mean = mean(|r| r.other_ms_mean);
    m.iterations_mean = mean(|r| r.iterations_mean);
    m.div_rel_mean = mean(|r| r.div_rel_mean);
    m.div_rel_max = runs.iter().map(|r| r.div_rel_max).fold(0.0, f64::max);
    m.steps = n as usize;
    m
}

fn validate(a: ValidateArgs) -> Result<()> {
    use hydrometra_sim::harness::validation::{
        abc_flow, ethier_steinman_with, lid_cavity_re1000, square_duct, taylor_green,
        taylor_green_3d, CavityExtrema,
    };
    let schemes: Vec<AdvectionScheme> = if a.advection.is_empty() {
        AdvectionScheme::ALL.to_vec()
    } else {
        a.advection.iter().map(|&s| s.into()).collect()
    };
    let mut rows = Vec::new();
    let duct_n: &[usize] = if a.fine { &[8, 16, 32] } else { &[8, 16] };
    if !a.advection_only {
        for &n in duct_n {
            rows.push(square_duct(n, 2.0)?.0);
        }
    }
    let tg_n: &[usize] = if a.fine {
        &[16, 32, 64, 128]
    } else {
        &[16, 32, 64]
    };
    let abc_n: &[usize] = if a.fine { &[16, 32, 64] } else { &[16, 32] };
    let tg3_n: &[usize] = if a.fine { &[16, 32, 64] } else { &[16, 32] };
    let cavity_n: &[usize] = if a.fine { &[32, 64, 128] } else { &[32, 64] };
    let es_n: &[usize] = if a.fine { &[8, 16, 32] } else { &[8, 16] };
    let mut extrema = Vec::new();
    for &scheme in &schemes {
        for &n in tg_n {
            rows.push(taylor_green(n, scheme)?);
        }
        for &n in abc_n {
            rows.push(abc_flow(n, scheme)?);
        }
        for &n in tg3_n {
            rows.push(taylor_green_3d(n, scheme)?);
        }
        for &n in cavity_n {
            let (r, e) = lid_cavity_re1000(n, scheme)?;
            extrema.push((r.case.clone(), n, e));
            rows.push(r);
        }
        if !a.advection_only {
            for &n in es_n {
                rows.push(ethier_steinman_with(n, scheme)?);
            }
        }
    }
    if !a.json && !extrema.is_empty() {
        println!("| cavity Re 1000 | cells | u_min | v_max | v_min | max diff Ghia | max diff Botella-Peyret |");
        println!("|---|---|---|---|---|---|---|");
        for (case, n, e) in &extrema {
            println!(
                "| {case} | {n} | {:.4} | {:.4} | {:.4} | {:.4} | {:.4} |",
                e.u_min,
                e.v_max,
                e.v_min,
                e.max_diff(&CavityExtrema::GHIA),
                e.max_diff(&CavityExtrema::BOTELLA_PEYRET)
            );
        }
        println!();
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
        return Ok(());
    }
    println!("| case | cells across | error | metric | steps | wall s | converged |");
    println!("|---|---|---|---|---|---|---|");
    for r in &rows {
        println!(
            "| {} | {} | {:.4e} | {} | {} | {:.2} | {} |",
            r.case,
            r.cells_across,
            r.error,
            r.metric.replace('|', "\\|"),
            r.steps,
            r.wall_s,
            r.all_converged
        );
    }
    Ok(())
}

fn soak(a: SoakArgs) -> Result<()> {
    let scheme = if a.maccormack {
        AdvectionScheme::MacCormack
    } else {
        scheme_or_default(a.advection)
    };
    let r = run_soak(a.steps, a.seed, scheme)?;
    println!("{}", serde_json::to_string_pretty(&r)?);
    anyhow::ensure!(
        r.non_finite_steps == 0,
        "{} steps produced non-finite values",
        r.non_finite_steps
    );
    Ok(())
}
