//! `hydrometra fluid`: run fluid case files, print the Table 1 benchmark, run the stability soak.

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use hydrometra_sim::fluid::benchmark::{
    bench_shape, BenchRow, Cavity, PAPER_FLUID_VOXELS, PAPER_MS, PAPER_VOXELS_M,
};
use hydrometra_sim::fluid::case::Case;
use hydrometra_sim::fluid::cavity::{
    CAVITY_SEMI_AXES_M, UTERINE_HALF_LENGTH_M, UTERINE_HALF_THICKNESS_M, UTERINE_HALF_WIDTH_M,
    UTERINE_TAPER,
};
use hydrometra_sim::fluid::soak::run_soak;
use hydrometra_sim::fluid::{AdvectionScheme, FluidParams, ProjectionMethod};

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
    /// Skip the Gauss-Seidel baseline (only our solver's rows).
    #[arg(long)]
    pub no_baseline: bool,
    /// Benchmark geometry: the uterine stand-in (matches the paper's fluid-cell counts) or the
    /// earlier ellipsoid (for comparison with older figures).
    #[arg(long, value_enum, default_value_t = CavityArg::Uterine)]
    pub cavity: CavityArg,
    /// Jet speed at the scope tip (m/s).
    #[arg(long, default_value_t = 1.0)]
    pub jet_m_s: f32,
    /// Divergence tolerance of our projection (max |div u| h / U).
    #[arg(long, default_value_t = 1e-5)]
    pub tolerance: f64,
    /// Gauss-Seidel sweeps per step of the baseline.
    #[arg(long, default_value_t = 20)]
    pub sweeps: usize,
    /// Voxel sizes (mm), comma separated.
    #[arg(long, value_delimiter = ',', default_value = "0.6,0.9,1.2,1.5,1.8")]
    pub voxels_mm: Vec<f64>,
    /// Rayon threads (0: rayon's default, all cores).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Print the rows as JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// Benchmark geometry on the command line.
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum CavityArg {
    /// The uterine stand-in (flattened pear).
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
    let case = Case::parse(&text).with_context(|| format!("in {}", a.case.display()))?;
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

fn bench(a: BenchArgs) -> Result<()> {
    if a.threads > 0 {
        rayon::ThreadPoolBuilder::new()
            .num_threads(a.threads)
            .build_global()
            .context("configuring the rayon thread pool")?;
    }
    anyhow::ensure!(a.steps > 0, "--steps must be at least 1");
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
    let mut rows: Vec<(BenchRow, Option<BenchRow>)> = Vec::new();
    let mut cpu: Vec<(f64, f64)> = Vec::new();
    for &mm in &a.voxels_mm {
        let h = mm * 1e-3;
        let ours = FluidParams {
            tolerance: a.tolerance,
            projection: ProjectionMethod::MultigridPcg,
            advection,
            ..Default::default()
        };
        let base = FluidParams {
            tolerance: a.tolerance,
            projection: ProjectionMethod::GaussSeidel { sweeps: a.sweeps },
            advection,
            ..Default::default()
        };
        let c0 = process_cpu_s();
        let r1 = bench_shape(cavity, h, a.jet_m_s, dt_s, a.warmup, a.steps, ours)?;
        let c1 = process_cpu_s();
        let r2 = if a.no_baseline {
            None
        } else {
            Some(bench_shape(
                cavity, h, a.jet_m_s, dt_s, a.warmup, a.steps, base,
            )?)
        };
        let c2 = process_cpu_s();
        let per_step = |c: Option<f64>, d: Option<f64>| match (c, d) {
            (Some(c), Some(d)) => (d - c) * 1e3 / (a.warmup + a.steps) as f64,
            _ => f64::NAN,
        };
        cpu.push((per_step(c0, c1), per_step(c1, c2)));
        tracing::info!("{mm} mm done");
        rows.push((r1, r2));
    }
    if a.json {
        let out: Vec<_> = rows
            .iter()
            .zip(&cpu)
            .map(|((o, b), (co, cb))| serde_json::json!({"ours": o, "baseline": b, "ours_cpu_ms_per_step": co, "baseline_cpu_ms_per_step": cb}))
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
        "{shape}, jet {} m/s, dt {:.5} s, {:?} advection, {} warm-up + {} timed steps, rayon threads {}, our tolerance max|div u|h/U <= {:.0e}, baseline {} Gauss-Seidel sweeps.",
        a.jet_m_s,
        dt_s,
        advection,
        a.warmup,
        a.steps,
        rayon::current_num_threads(),
        a.tolerance,
        a.sweeps
    );
    println!();
    println!("| voxel [mm] | voxels total | fluid (paper) | paper ms | ours ms mean ± sem | ours p99 | ours CPU ms | ours advect / diffuse / project / other ms | ours CG its | ours max div h/U | GS ms mean ± sem | GS p99 | GS CPU ms | GS mean div h/U |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for ((o, b), (co, cb)) in rows.iter().zip(&cpu) {
        let paper = PAPER_VOXELS_M
            .iter()
            .position(|&v| (v - o.voxel_m).abs() < 1e-9);
        let (pf, pm) = paper.map_or(("-".into(), "-".into()), |i| {
            (PAPER_FLUID_VOXELS[i].to_string(), PAPER_MS[i].to_string())
        });
        let gs = b.as_ref().map_or_else(
            || "- | - | - | -".to_string(),
            |b| {
                format!(
                    "{:.2} ± {:.2} | {:.2} | {:.2} | {:.1e}",
                    b.ms_mean, b.ms_sem, b.ms_p99, cb, b.div_rel_mean
                )
            },
        );
        println!(
            "| {:.1} | {} | {} ({}) | {} | {:.2} ± {:.2} | {:.2} | {:.2} | {:.3} / {:.3} / {:.3} / {:.3} | {:.1} | {:.2e} | {gs} |",
            o.voxel_m * 1e3,
            o.voxels_total,
            o.fluid_voxels,
            pf,
            pm,
            o.ms_mean,
            o.ms_sem,
            o.ms_p99,
            co,
            o.advect_ms_mean,
            o.diffuse_ms_mean,
            o.project_ms_mean,
            o.other_ms_mean,
            o.iterations_mean,
            o.div_rel_max,
        );
    }
    Ok(())
}

fn validate(a: ValidateArgs) -> Result<()> {
    use hydrometra_sim::fluid::validation::{
        abc_flow, ethier_steinman_with, lid_cavity_re1000, square_duct, taylor_green, CavityExtrema,
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

/// CPU time (user + system, all threads) of this process so far, from /proc/self/stat (Linux);
/// None elsewhere. Under a loaded machine this is closer to the unloaded wall time than wall time is.
fn process_cpu_s() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the command name (which is in parentheses and may contain spaces).
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let utime: f64 = f.get(11)?.parse().ok()?;
    let stime: f64 = f.get(12)?.parse().ok()?;
    // Linux reports in clock ticks of 1/100 s (USER_HZ) on every mainstream configuration.
    Some((utime + stime) / 100.0)
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
