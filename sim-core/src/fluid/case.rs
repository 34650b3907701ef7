//! Case files: a box-shaped flow problem in TOML (grid, fluid, time, solver, regions, probes) and the
//! runner that steps it and samples its probes. The format is specified in `docs/fluid-cases.md`.

use std::path::Path;
use std::time::Instant;

use serde::{Deserialize, Serialize};

pub use super::case_regions::RegionSpec;
use super::case_regions::{parse_label, Invalid};

use super::{
    AdvectionScheme, CellLabel, FluidError, FluidGrid, FluidParams, FluidSolver, ProjectionMethod,
};

impl From<Invalid> for CaseError {
    fn from(e: Invalid) -> Self {
        CaseError::Invalid {
            key: e.key,
            value: e.value,
            problem: e.problem,
        }
    }
}

/// Errors of case files.
#[derive(Debug, thiserror::Error)]
pub enum CaseError {
    /// The TOML does not parse or does not match the schema (the message names key and line).
    #[error("case file: {0}")]
    Parse(String),
    /// A key has a value the solver cannot use.
    #[error("case file: `{key}` = {value}: {problem}")]
    Invalid {
        /// Dotted key, e.g. `region[2].velocity_m_s`.
        key: String,
        /// The offending value.
        value: String,
        /// What is wrong and what was expected.
        problem: String,
    },
    /// The solver rejected the case.
    #[error("case file: {0}")]
    Solver(#[from] FluidError),
}

/// `[grid]`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct GridSpec {
    /// Cells per axis.
    pub cells: [usize; 3],
    /// Cell edge (m).
    pub spacing_m: f64,
    /// Lower corner (m).
    #[serde(default)]
    pub origin_m: [f64; 3],
    /// Periodic axes.
    #[serde(default)]
    pub periodic: [bool; 3],
    /// What lies under the regions: `fluid` (default) or `solid`.
    pub background: Option<String>,
}

/// `[fluid]`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct FluidSpec {
    /// Density (kg/m^3).
    pub density_kg_m3: f64,
    /// Kinematic viscosity (m^2/s).
    pub viscosity_m2_s: f64,
    /// Body force per unit mass (m/s^2).
    #[serde(default)]
    pub body_force_m_s2: [f64; 3],
}

/// `[time]`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct TimeSpec {
    /// Fixed time step (s). Exactly one of `dt_s` and `cfl`.
    pub dt_s: Option<f64>,
    /// Time step from a CFL number: `dt = cfl h / U`, U the largest face or port speed.
    pub cfl: Option<f64>,
    /// Upper bound of the CFL-derived step (s); required with `cfl` when nothing moves at the start.
    pub max_dt_s: Option<f64>,
    /// Simulated time to run (s). At least one of `end_s` and `steady_tolerance`.
    pub end_s: Option<f64>,
    /// Stop when `max_f |u_f^{n+1} - u_f^n| / (max_f |u_f^{n+1}| dt) < steady_tolerance` (1/s).
    pub steady_tolerance: Option<f64>,
    /// Cap on steps (default 1,000,000).
    pub max_steps: Option<usize>,
}

/// `[solver]`.
#[derive(Clone, Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SolverSpec {
    /// An [`AdvectionScheme::name`] (default: the solver's default scheme).
    pub advection: Option<String>,
    /// `multigrid_pcg` (default), `jacobi_pcg`, `gauss_seidel` (cold, lexicographic, one thread) or
    /// `red_black_gauss_seidel` (warm-started, on the multigrid's dense kernels).
    pub projection: Option<String>,
    /// Gauss-Seidel sweeps per step (default 20).
    pub sweeps: Option<usize>,
    /// Divergence tolerance `max |div u| h / U` (default 1e-6).
    pub tolerance: Option<f64>,
    /// CG iteration cap (default 500).
    pub max_iterations: Option<usize>,
    /// Substep so that the CFL number stays below this.
    pub max_cfl: Option<f64>,
    /// Fluid cells from which the stages split over two threads (from 1/12 of this; see `FluidParams`).
    pub parallel_threshold_cells: Option<usize>,
}

/// `[[probe]]`: `points` samples evenly spaced from `from_m` to `to_m`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ProbeSpec {
    /// Name (unique).
    pub name: String,
    /// First point (m).
    pub from_m: [f64; 3],
    /// Last point (m).
    pub to_m: [f64; 3],
    /// Number of points (>= 1).
    pub points: usize,
}

/// A whole case file.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Case {
    /// `[grid]`.
    pub grid: GridSpec,
    /// `[fluid]`.
    pub fluid: FluidSpec,
    /// `[time]`.
    pub time: TimeSpec,
    /// `[solver]`.
    #[serde(default)]
    pub solver: SolverSpec,
    /// `[[region]]`.
    #[serde(default, rename = "region")]
    pub regions: Vec<RegionSpec>,
    /// `[[probe]]`.
    #[serde(default, rename = "probe")]
    pub probes: Vec<ProbeSpec>,
}

pub(super) fn invalid(
    key: impl Into<String>,
    value: impl std::fmt::Debug,
    problem: &str,
) -> CaseError {
    CaseError::Invalid {
        key: key.into(),
        value: format!("{value:?}"),
        problem: problem.into(),
    }
}

fn finite3(key: &str, v: [f64; 3]) -> Result<(), CaseError> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err(invalid(key, v, "expected three finite numbers"))
    }
}

impl Case {
    /// Parses and checks a case file's text that has no file of its own: a `mesh` region's
    /// `file` must then be an absolute path ([`Case::parse_at`]).
    pub fn parse(text: &str) -> Result<Case, CaseError> {
        Self::parse_at(text, None)
    }

    /// Parses and checks the text of `case_file` (the caller reads it) and reads the meshes of its
    /// `mesh` regions, a relative `file` resolved against the case file's directory.
    pub fn parse_at(text: &str, case_file: Option<&Path>) -> Result<Case, CaseError> {
        let mut case: Case = toml::from_str(text).map_err(|e| CaseError::Parse(e.to_string()))?;
        case.validate()?;
        super::case_regions::read_meshes(&mut case.regions, case_file)?;
        Ok(case)
    }

    fn validate(&self) -> Result<(), CaseError> {
        let g = &self.grid;
        if g.cells.contains(&0) {
            return Err(invalid(
                "grid.cells",
                g.cells,
                "every axis needs at least one cell",
            ));
        }
        if !(g.spacing_m.is_finite() && g.spacing_m > 0.0) {
            return Err(invalid(
                "grid.spacing_m",
                g.spacing_m,
                "expected a length > 0",
            ));
        }
        finite3("grid.origin_m", g.origin_m)?;
        let f = &self.fluid;
        if !(f.density_kg_m3.is_finite() && f.density_kg_m3 > 0.0) {
            return Err(invalid(
                "fluid.density_kg_m3",
                f.density_kg_m3,
                "expected a value > 0",
            ));
        }
        if !(f.viscosity_m2_s.is_finite() && f.viscosity_m2_s >= 0.0) {
            return Err(invalid(
                "fluid.viscosity_m2_s",
                f.viscosity_m2_s,
                "expected a value >= 0",
            ));
        }
        finite3("fluid.body_force_m_s2", f.body_force_m_s2)?;
        let t = &self.time;
        match (t.dt_s, t.cfl) {
            (Some(dt), None) if !(dt.is_finite() && dt > 0.0) => {
                return Err(invalid("time.dt_s", dt, "expected a time step > 0"))
            }
            (None, Some(c)) if !(c.is_finite() && c > 0.0) => {
                return Err(invalid("time.cfl", c, "expected a CFL number > 0"))
            }
            (Some(_), Some(_)) | (None, None) => {
                return Err(invalid(
                    "time",
                    (t.dt_s, t.cfl),
                    "give exactly one of dt_s and cfl",
                ))
            }
            _ => {}
        }
        if let Some(m) = t.max_dt_s {
            if !(m.is_finite() && m > 0.0) {
                return Err(invalid("time.max_dt_s", m, "expected a time step > 0"));
            }
        }
        if t.end_s.is_none() && t.steady_tolerance.is_none() {
            return Err(invalid(
                "time",
                (t.end_s, t.steady_tolerance),
                "give end_s, steady_tolerance or both",
            ));
        }
        if let Some(e) = t.end_s {
            if !(e.is_finite() && e > 0.0) {
                return Err(invalid("time.end_s", e, "expected a duration > 0"));
            }
        }
        if let Some(s) = t.steady_tolerance {
            if !(s.is_finite() && s > 0.0) {
                return Err(invalid(
                    "time.steady_tolerance",
                    s,
                    "expected a rate > 0 (1/s)",
                ));
            }
        }
        if t.max_steps == Some(0) {
            return Err(invalid("time.max_steps", 0, "expected at least 1"));
        }
        self.params()?.validate()?;
        super::case_regions::background(g.background.as_deref())?;
        for (i, r) in self.regions.iter().enumerate() {
            let label = parse_label(&r.label).ok_or_else(|| {
                invalid(
                    format!("region[{i}].label"),
                    &r.label,
                    "expected fluid, solid, velocity or outflow",
                )
            })?;
            if super::case_regions::validate_shape(i, r, label)? {
                let need = |key: &str, v: Option<[f64; 3]>| {
                    v.ok_or_else(|| {
                        invalid(
                            format!("region[{i}].{key}"),
                            "missing",
                            "required for a box",
                        )
                    })
                };
                let (min_m, max_m) = (need("min_m", r.min_m)?, need("max_m", r.max_m)?);
                finite3(&format!("region[{i}].min_m"), min_m)?;
                finite3(&format!("region[{i}].max_m"), max_m)?;
                if (0..3).any(|a| min_m[a] > max_m[a]) {
                    return Err(invalid(
                        format!("region[{i}].max_m"),
                        max_m,
                        "must not be below min_m on any axis",
                    ));
                }
            }
            match (label, r.velocity_m_s) {
                (CellLabel::Velocity, None) => {
                    return Err(invalid(
                        format!("region[{i}].velocity_m_s"),
                        "missing",
                        "required for label velocity",
                    ))
                }
                (CellLabel::Velocity, Some(v)) => finite3(&format!("region[{i}].velocity_m_s"), v)?,
                (_, Some(v)) => {
                    return Err(invalid(
                        format!("region[{i}].velocity_m_s"),
                        v,
                        "only velocity regions take a velocity",
                    ))
                }
                _ => {}
            }
        }
        for (i, p) in self.probes.iter().enumerate() {
            finite3(&format!("probe[{i}].from_m"), p.from_m)?;
            finite3(&format!("probe[{i}].to_m"), p.to_m)?;
            if p.points == 0 {
                return Err(invalid(
                    format!("probe[{i}].points"),
                    0,
                    "expected at least 1",
                ));
            }
            if self.probes[..i].iter().any(|q| q.name == p.name) {
                return Err(invalid(
                    format!("probe[{i}].name"),
                    &p.name,
                    "probe names must be unique",
                ));
            }
        }
        Ok(())
    }

    /// Solver parameters of the case.
    pub fn params(&self) -> Result<FluidParams, CaseError> {
        let s = &self.solver;
        let mut p = FluidParams {
            density_kg_m3: self.fluid.density_kg_m3,
            viscosity_m2_s: self.fluid.viscosity_m2_s,
            body_force_m_s2: self.fluid.body_force_m_s2,
            max_cfl: s.max_cfl,
            ..Default::default()
        };
        if let Some(name) = s.advection.as_deref() {
            p.advection = AdvectionScheme::from_name(name).ok_or_else(|| {
                let names: Vec<&str> = AdvectionScheme::ALL.iter().map(|a| a.name()).collect();
                invalid(
                    "solver.advection",
                    name,
                    &format!("expected one of {}", names.join(", ")),
                )
            })?;
        }
        p.projection =
            match s.projection.as_deref() {
                None | Some("multigrid_pcg") => ProjectionMethod::MultigridPcg,
                Some("jacobi_pcg") => ProjectionMethod::JacobiPcg,
                Some("gauss_seidel") => ProjectionMethod::GaussSeidel {
                    sweeps: s.sweeps.unwrap_or(20),
                },
                Some("red_black_gauss_seidel") => ProjectionMethod::RedBlackGaussSeidel {
                    sweeps: s.sweeps.unwrap_or(20),
                },
                Some(o) => return Err(invalid(
                    "solver.projection",
                    o,
                    "expected multigrid_pcg, jacobi_pcg, gauss_seidel or red_black_gauss_seidel",
                )),
            };
        if s.sweeps.is_some() && !p.projection.is_fixed_sweeps() {
            return Err(invalid(
                "solver.sweeps",
                s.sweeps,
                "only used with projection = \"gauss_seidel\" or \"red_black_gauss_seidel\"",
            ));
        }
        if let Some(t) = s.tolerance {
            p.tolerance = t;
        }
        if let Some(m) = s.max_iterations {
            p.max_iterations = m;
        }
        if let Some(t) = s.parallel_threshold_cells {
            p.parallel_threshold_cells = t;
        }
        p.validate().map_err(|e| match e {
            FluidError::InvalidParameter {
                key,
                value,
                expected,
            } => CaseError::Invalid {
                key: format!("solver.{key}"),
                value,
                problem: format!("expected {expected}"),
            },
            other => CaseError::Solver(other),
        })?;
        Ok(p)
    }

    /// The labelled grid of the case.
    pub fn build_grid(&self) -> Result<FluidGrid, CaseError> {
        let g = &self.grid;
        let mut grid = FluidGrid::new(g.cells, g.spacing_m, g.origin_m, g.periodic)?;
        // Curved regions (and the fluid and solid boxes with them) as cut cells, then the ports.
        let cut = super::case_regions::apply_cut_regions(
            self.grid.background.as_deref(),
            &self.regions,
            &mut grid,
        )?;
        for r in &self.regions {
            let label = parse_label(&r.label).unwrap_or(CellLabel::Fluid); // ok: validated
            let (Some(min_m), Some(max_m)) = (r.min_m, r.max_m) else {
                continue;
            };
            if cut && matches!(label, CellLabel::Fluid | CellLabel::Solid) {
                continue;
            }
            let v = r.velocity_m_s.unwrap_or([0.0; 3]).map(|x| x as f32);
            grid.fill_box(min_m, max_m, label, v);
        }
        Ok(grid)
    }

    /// Runs the case to its end and samples the probes.
    pub fn run(&self) -> Result<RunReport, CaseError> {
        let mut solver = FluidSolver::new(self.build_grid()?, self.params()?)?;
        let h = self.grid.spacing_m;
        let t = &self.time;
        let max_steps = t.max_steps.unwrap_or(1_000_000);
        let port_speed = solver
            .grid()
            .labels()
            .iter()
            .enumerate()
            .fold(0.0f64, |m, (i, l)| {
                if *l == CellLabel::Velocity {
                    let v = solver.grid().velocity_at(i);
                    m.max((v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt() as f64)
                } else {
                    m
                }
            });
        let mut prev: [Vec<f32>; 3] = std::array::from_fn(|c| solver.face_velocities(c).to_vec());
        let mut step_ms = Vec::new();
        let mut iterations = 0usize;
        let mut max_iterations = 0usize;
        let mut unconverged = 0usize;
        let mut last = None;
        let mut steady_rate = None;
        let mut steady = false;
        let end = t.end_s.unwrap_or(f64::INFINITY);
        while step_ms.len() < max_steps && solver.time_s() < end * (1.0 - 1e-12) {
            let mut dt = match (t.dt_s, t.cfl) {
                (Some(dt), _) => dt,
                (None, Some(cfl)) => {
                    let u = solver.max_speed_m_s().max(port_speed);
                    match (u > 0.0, t.max_dt_s) {
                        (true, Some(m)) => (cfl * h / u).min(m),
                        (true, None) => cfl * h / u,
                        (false, Some(m)) => m,
                        (false, None) => return Err(invalid(
                            "time.max_dt_s",
                            "missing",
                            "nothing moves at the start, so cfl gives no time step: add max_dt_s",
                        )),
                    }
                }
                (None, None) => return Err(invalid("time", "none", "give dt_s or cfl")),
            };
            dt = dt.min(end - solver.time_s()).max(1e-15);
            let t0 = Instant::now();
            let stats = solver.step(dt)?;
            step_ms.push(t0.elapsed().as_secs_f64() * 1e3);
            iterations += stats.projection_iterations;
            max_iterations = max_iterations.max(stats.projection_iterations);
            unconverged += usize::from(!stats.projection_converged);
            last = Some(stats);
            if let Some(tol) = t.steady_tolerance {
                let mut change = 0.0f32;
                let mut umax = 0.0f32;
                for (c, p) in prev.iter_mut().enumerate() {
                    for (a, b) in p.iter_mut().zip(solver.face_velocities(c)) {
                        change = change.max((*a - *b).abs());
                        umax = umax.max(b.abs());
                        *a = *b;
                    }
                }
                let rate = if umax > 0.0 {
                    change as f64 / (umax as f64 * dt)
                } else {
                    0.0
                };
                steady_rate = Some(rate);
                if rate < tol {
                    steady = true;
                    break;
                }
            }
        }
        let steps = step_ms.len();
        let mean = step_ms.iter().sum::<f64>() / steps.max(1) as f64;
        let mut sorted = step_ms.clone();
        sorted.sort_by(|a, b| a.total_cmp(b));
        let p99 = sorted
            .get(((steps as f64 * 0.99).ceil() as usize).saturating_sub(1))
            .copied()
            .unwrap_or(0.0);
        let last = last.unwrap_or_default();
        let probes = self
            .probes
            .iter()
            .map(|p| ProbeReport {
                name: p.name.clone(),
                samples: (0..p.points)
                    .map(|i| {
                        let s = if p.points == 1 {
                            0.0
                        } else {
                            i as f64 / (p.points - 1) as f64
                        };
                        let x: [f64; 3] =
                            std::array::from_fn(|a| p.from_m[a] + s * (p.to_m[a] - p.from_m[a]));
                        ProbeSample {
                            position_m: x,
                            velocity_m_s: solver.sample_velocity_m_s(x),
                            pressure_pa: solver.sample_pressure_pa(x),
                        }
                    })
                    .collect(),
            })
            .collect();
        let (regions, closed_regions) = solver.regions();
        Ok(RunReport {
            statistics: RunStatistics {
                steps,
                simulated_time_s: solver.time_s(),
                fluid_cells: solver.fluid_cells(),
                regions,
                closed_regions,
                ms_per_step_mean: mean,
                ms_per_step_p99: p99,
                projection_iterations_mean: iterations as f64 / steps.max(1) as f64,
                projection_iterations_max: max_iterations,
                unconverged_projections: unconverged,
                final_max_div_rel: last.max_div_rel,
                kinetic_energy_j: solver.kinetic_energy_j(),
                max_speed_m_s: solver.max_speed_m_s(),
                steady_reached: steady,
                final_change_rate_per_s: steady_rate,
            },
            probes,
        })
    }
}

/// Run statistics.
#[derive(Clone, Debug, Serialize)]
pub struct RunStatistics {
    /// Steps taken.
    pub steps: usize,
    /// Simulated time (s).
    pub simulated_time_s: f64,
    /// Fluid cells at the end.
    pub fluid_cells: usize,
    /// Connected fluid regions.
    pub regions: usize,
    /// Regions without an outflow cell.
    pub closed_regions: usize,
    /// Wall time per step (ms), mean.
    pub ms_per_step_mean: f64,
    /// Wall time per step (ms), 99th percentile.
    pub ms_per_step_p99: f64,
    /// Projection iterations per step, mean.
    pub projection_iterations_mean: f64,
    /// Projection iterations per step, max.
    pub projection_iterations_max: usize,
    /// Steps whose projection did not reach the tolerance.
    pub unconverged_projections: usize,
    /// `max |div u| h / U` after the last projection.
    pub final_max_div_rel: f64,
    /// Kinetic energy at the end (J).
    pub kinetic_energy_j: f64,
    /// Largest face speed at the end (m/s).
    pub max_speed_m_s: f64,
    /// Whether `steady_tolerance` was reached.
    pub steady_reached: bool,
    /// Last `max |du| / (max |u| dt)` (1/s), when `steady_tolerance` is set.
    pub final_change_rate_per_s: Option<f64>,
}

/// One probe point.
#[derive(Clone, Debug, Serialize)]
pub struct ProbeSample {
    /// Position (m).
    pub position_m: [f64; 3],
    /// Interpolated velocity (m/s).
    pub velocity_m_s: [f64; 3],
    /// Interpolated pressure (Pa); null where no fluid cell is near.
    pub pressure_pa: Option<f64>,
}

/// One probe line.
#[derive(Clone, Debug, Serialize)]
pub struct ProbeReport {
    /// The probe's name.
    pub name: String,
    /// Its samples, from `from_m` to `to_m`.
    pub samples: Vec<ProbeSample>,
}

/// The result of a run.
#[derive(Clone, Debug, Serialize)]
pub struct RunReport {
    /// Run statistics.
    pub statistics: RunStatistics,
    /// Probe samples.
    pub probes: Vec<ProbeReport>,
}

#[cfg(test)]
mod curved_region_tests {
    use super::*;

    const HEAD: &str = r#"
[grid]
cells = [24, 16, 16]
spacing_m = 0.0005
background = "solid"
[fluid]
density_kg_m3 = 1000.0
viscosity_m2_s = 1e-6
[time]
dt_s = 0.001
end_s = 0.002
"#;

    /// A sphere and a tilted cylinder of fluid in rock carry their analytic volumes (the
    /// tessellation matches the volume; the fractions are exact for it) and step; a solid
    /// sphere inside the fluid cylinder removes its own volume.
    #[test]
    fn curved_regions_carry_their_volumes_and_step() {
        let pi = std::f64::consts::PI;
        let sphere = format!(
            "{HEAD}[[region]]\nshape = \"sphere\"\nlabel = \"fluid\"\ncentre_m = [0.006, 0.004, 0.0041]\nradius_m = 0.0025\n"
        );
        let case = Case::parse(&sphere).unwrap();
        let grid = case.build_grid().unwrap();
        let exact = 4.0 / 3.0 * pi * 0.0025f64.powi(3);
        let v = grid.fluid_volume_m3();
        assert!((v - exact).abs() <= 1e-5 * exact, "{v} {exact}");
        case.run().unwrap();
        let cyl = format!(
            "{HEAD}[[region]]\nshape = \"cylinder\"\nlabel = \"fluid\"\ncentre_m = [0.006, 0.004, 0.004]\naxis = [0.6, 0.8, 0.0]\nradius_m = 0.0015\nlength_m = 0.006\n[[region]]\nshape = \"sphere\"\nlabel = \"solid\"\ncentre_m = [0.006, 0.004, 0.004]\nradius_m = 0.001\n"
        );
        let case = Case::parse(&cyl).unwrap();
        let grid = case.build_grid().unwrap();
        let exact = pi * 0.0015f64.powi(2) * 0.006 - 4.0 / 3.0 * pi * 0.001f64.powi(3);
        let v = grid.fluid_volume_m3();
        assert!((v - exact).abs() <= 1e-5 * exact, "{v} {exact}");
        let report = case.run().unwrap();
        assert!(report.statistics.regions >= 1);
    }

    /// Bad curved regions are refused naming the region and key.
    #[test]
    fn bad_curved_regions_name_the_region_and_key() {
        let cases = [
            ("shape = \"cone\"\nlabel = \"fluid\"\n", "region[0].shape"),
            ("shape = \"sphere\"\nlabel = \"fluid\"\nradius_m = 0.001\n", "region[0].centre_m"),
            (
                "shape = \"sphere\"\nlabel = \"fluid\"\ncentre_m = [0.0, 0.0, 0.0]\nradius_m = -1.0\n",
                "region[0].radius_m",
            ),
            (
                "shape = \"cylinder\"\nlabel = \"fluid\"\ncentre_m = [0.0, 0.0, 0.0]\nradius_m = 0.001\nlength_m = 0.002\naxis = [0.0, 0.0, 0.0]\n",
                "region[0].axis",
            ),
            (
                "shape = \"sphere\"\nlabel = \"outflow\"\ncentre_m = [0.0, 0.0, 0.0]\nradius_m = 0.001\n",
                "region[0].label",
            ),
            ("label = \"fluid\"\nmax_m = [0.0, 0.0, 0.0]\n", "region[0].min_m"),
            (
                "label = \"fluid\"\nmin_m = [0.0, 0.0, 0.0]\nmax_m = [0.0, 0.0, 0.0]\nradius_m = 0.001\n",
                "region[0].radius_m",
            ),
        ];
        for (region, key) in cases {
            let text = format!("{HEAD}[[region]]\n{region}");
            let e = Case::parse(&text).unwrap_err().to_string();
            assert!(e.contains(key), "{key}: {e}");
        }
        let e = Case::parse(&HEAD.replace("\"solid\"", "\"rock\""))
            .unwrap_err()
            .to_string();
        assert!(e.contains("grid.background"), "{e}");
    }
}
