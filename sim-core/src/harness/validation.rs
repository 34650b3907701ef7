//! Analytic validation cases (references.md section 2), shared by the tests and by
//! `hydrometra fluid validate`, which prints their error against run time.

use std::f64::consts::PI;
use std::time::Instant;

use serde::Serialize;

use super::{AdvectionScheme, CellLabel, FluidError, FluidGrid, FluidParams, FluidSolver};

/// Error of one validation run and what it cost.
#[derive(Clone, Debug, Serialize)]
pub struct ValidationResult {
    /// Case name.
    pub case: String,
    /// Cells across the domain.
    pub cells_across: usize,
    /// The error figure (meaning per case, see `metric`).
    pub error: f64,
    /// What `error` measures.
    pub metric: String,
    /// Steps run.
    pub steps: usize,
    /// Wall time of the run (s).
    pub wall_s: f64,
    /// Whether every projection reached its tolerance.
    pub all_converged: bool,
}

/// Square-duct velocity `u / (a^2 G / mu)` at `(y/a, z/a)`, from the series in references.md.
pub fn duct_series(y: f64, z: f64) -> f64 {
    let mut sum = 0.0;
    for m in 0..200 {
        let n = (2 * m + 1) as f64;
        let sign = if m % 2 == 0 { 1.0 } else { -1.0 };
        // cosh(n pi z / 2) / cosh(n pi / 2), written to avoid overflow.
        let ratio = ((n * PI * z / 2.0).abs() - n * PI / 2.0).exp()
            * (1.0 + (-n * PI * z.abs()).exp())
            / (1.0 + (-n * PI).exp());
        sum += sign * (1.0 - ratio) * (n * PI * y / 2.0).cos() / n.powi(3);
    }
    16.0 / PI.powi(3) * sum
}

/// Steady Poiseuille flow in a periodic square duct of `n` cells across (walls = the grid's outside),
/// driven by a body force, from rest to t = 2 L^2 / nu (the slowest mode has decayed by e^-39) with
/// `dt = dt_factor h^2 / nu`. Returns the relative flow-rate error and the largest face error over
/// the cross-section relative to the centre speed.
pub fn square_duct(n: usize, dt_factor: f64) -> Result<(ValidationResult, f64), FluidError> {
    let steps = (2.0 * (n * n) as f64 / dt_factor).ceil() as usize;
    let t0 = Instant::now();
    let h = 1e-3;
    let l = n as f64 * h;
    let a = l / 2.0;
    let (nu, rho) = (1e-6, 1000.0);
    let mu = rho * nu;
    // G such that the centre speed is 1 mm/s.
    let g = 1e-3 / (0.2946854 * a * a) * mu;
    let grid = FluidGrid::new([4, n, n], h, [0.0, -a, -a], [true, false, false])?;
    let params = FluidParams {
        density_kg_m3: rho,
        viscosity_m2_s: nu,
        body_force_m_s2: [g / rho, 0.0, 0.0],
        tolerance: 1e-7,
        ..Default::default()
    };
    let mut s = FluidSolver::new(grid, params)?;
    let dt = dt_factor * h * h / nu;
    let mut ok = true;
    for _ in 0..steps {
        ok &= s.step(dt)?.projection_converged;
    }
    let u = s.face_velocities(0);
    let u_max = 0.2946854 * a * a * g / mu;
    let (mut q, mut worst) = (0.0, 0.0f64);
    for k in 0..n {
        for j in 0..n {
            let v = u[4 * (j + n * k)] as f64;
            q += v * h * h;
            let y = (j as f64 + 0.5) * h - a;
            let z = (k as f64 + 0.5) * h - a;
            worst = worst.max((v - duct_series(y / a, z / a) * a * a * g / mu).abs() / u_max);
        }
    }
    let q_exact = 0.0351443 * l.powi(4) * g / mu;
    Ok((
        ValidationResult {
            case: "square duct (Poiseuille)".into(),
            cells_across: n,
            error: (q - q_exact).abs() / q_exact,
            metric: "|Q - Q_exact| / Q_exact".into(),
            steps,
            wall_s: t0.elapsed().as_secs_f64(),
            all_converged: ok,
        },
        worst,
    ))
}

/// 2D Taylor-Green vortex (Re = 100, CFL 0.5) on an `n x n x 1` periodic grid to t = 0.5; the error
/// figure is `nu_eff / nu` (1 is exact; numerical dissipation adds).
pub fn taylor_green(n: usize, scheme: AdvectionScheme) -> Result<ValidationResult, FluidError> {
    let t0 = Instant::now();
    let (l, u0, nu) = (1.0, 1.0, 0.01);
    let h = l / n as f64;
    let k = 2.0 * PI / l;
    let grid = FluidGrid::new([n, n, 1], h, [0.0; 3], [true; 3])?;
    let params = FluidParams {
        density_kg_m3: 1.0,
        viscosity_m2_s: nu,
        advection: scheme,
        ..Default::default()
    };
    let mut s = FluidSolver::new(grid, params)?;
    s.set_velocity_field(|c, x| match c {
        0 => u0 * (k * x[0]).sin() * (k * x[1]).cos(),
        1 => -u0 * (k * x[0]).cos() * (k * x[1]).sin(),
        _ => 0.0,
    });
    let e0 = s.kinetic_energy_j();
    let dt = 0.5 * h / u0;
    let steps = (0.5 / dt).round() as usize;
    let mut ok = true;
    for _ in 0..steps {
        let st = s.step(dt)?;
        ok &= st.projection_converged && st.max_div_rel <= 1e-5;
    }
    let nu_eff = -(s.kinetic_energy_j() / e0).ln() / (4.0 * k * k * s.time_s());
    Ok(ValidationResult {
        case: format!("Taylor-Green 2D ({})", scheme.name()),
        cells_across: n,
        error: nu_eff / nu,
        metric: "nu_eff / nu".into(),
        steps,
        wall_s: t0.elapsed().as_secs_f64(),
        all_converged: ok,
    })
}

/// Kinetic energy and enstrophy per unit mass of a periodic field, as means over the cells:
/// `E = 1/2 mean |u|^2` (each face once) and `Z = 1/2 mean |curl u|^2`, the curl from the MAC
/// differences on the cell edges. On a periodic MAC grid `sum |grad_h u|^2 = sum |curl_h u|^2` for a
/// discretely divergence-free field, so the viscous term alone takes `dE/dt = -2 nu Z` exactly.
pub fn energy_and_enstrophy(s: &FluidSolver) -> (f64, f64) {
    let dims = s.grid().dims();
    let [nx, ny, nz] = dims;
    let h = s.grid().spacing_m();
    // On a periodic axis face i is the lower face of cell i: every component's faces are indexed
    // as the cells.
    let at = |c: [usize; 3]| c[0] + nx * (c[1] + ny * c[2]);
    let back = |c: [usize; 3], a: usize| {
        let mut c = c;
        c[a] = (c[a] + dims[a] - 1) % dims[a];
        at(c)
    };
    let u: [&[f32]; 3] = std::array::from_fn(|a| s.face_velocities(a));
    let (mut e, mut z) = (0.0, 0.0);
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let c = [i, j, k];
                let n = at(c);
                for a in 0..3 {
                    e += (u[a][n] as f64).powi(2);
                    // Curl component a on the edge along a at the cell's lower corner.
                    let (b, d) = ((a + 1) % 3, (a + 2) % 3);
                    let w = (u[d][n] as f64 - u[d][back(c, b)] as f64)
                        - (u[b][n] as f64 - u[b][back(c, d)] as f64);
                    z += (w / h).powi(2);
                }
            }
        }
    }
    let cells = (nx * ny * nz) as f64;
    (0.5 * e / cells, 0.5 * z / cells)
}

/// The effective viscosity of a run on a fully periodic grid without body force, from the energy
/// identity of periodic incompressible flow `dE/dt = -2 nu Z` ([`energy_and_enstrophy`]):
/// steps `s` by `dt` until `t_end_s` and returns `-(E(T) - E(0)) / (2 int Z dt)` (trapezoidal in
/// time) and whether every projection converged to `max div h / U <= 1e-5`. Needs no exact
/// solution: numerical dissipation reads as `nu_eff > nu` on any periodic flow.
pub fn periodic_effective_viscosity(
    s: &mut FluidSolver,
    dt: f64,
    t_end_s: f64,
) -> Result<(f64, bool), FluidError> {
    if s.grid().periodic() != [true; 3] || s.params().body_force_m_s2 != [0.0; 3] {
        return Err(FluidError::InvalidParameter {
            key: "grid.periodic / body_force_m_s2".into(),
            value: format!(
                "{:?} / {:?}",
                s.grid().periodic(),
                s.params().body_force_m_s2
            ),
            expected: "a fully periodic grid without body force".into(),
        });
    }
    let steps = (t_end_s / dt).round().max(1.0) as usize;
    let (e0, mut z_prev) = energy_and_enstrophy(s);
    let (mut e, mut z_int, mut ok) = (e0, 0.0, true);
    for _ in 0..steps {
        let st = s.step(dt)?;
        ok &= st.projection_converged && st.max_div_rel <= 1e-5;
        let (e1, z1) = energy_and_enstrophy(s);
        z_int += 0.5 * (z_prev + z1) * dt;
        (e, z_prev) = (e1, z1);
    }
    Ok((-(e - e0) / (2.0 * z_int), ok))
}

/// A fully periodic cube of `n^3` cells of edge `h` (density 1, viscosity `nu`), its faces set from
/// `field(component, position)` and projected once; with whether that projection converged.
fn periodic_cube(
    n: usize,
    h: f64,
    nu: f64,
    scheme: AdvectionScheme,
    field: impl FnMut(usize, [f64; 3]) -> f64,
) -> Result<(FluidSolver, bool), FluidError> {
    let grid = FluidGrid::new([n; 3], h, [0.0; 3], [true; 3])?;
    let params = FluidParams {
        density_kg_m3: 1.0,
        viscosity_m2_s: nu,
        advection: scheme,
        ..Default::default()
    };
    let mut s = FluidSolver::new(grid, params)?;
    s.set_velocity_field(field);
    let ok = s.project_now(1.0).projection_converged;
    Ok((s, ok))
}

/// 3D Taylor-Green vortex `(sin x cos y cos z, -cos x sin y cos z, 0)` in a periodic `2 pi` box of
/// `n^3` cells (`n` cells per period), `u0 = 1`, `nu = 0.01` (Re = 100 on the unit length), CFL 0.5
/// to t = 5 (the vortex stretches into smaller scales); the error figure is `nu_eff / nu` from
/// [`periodic_effective_viscosity`] (1 is exact).
pub fn taylor_green_3d(n: usize, scheme: AdvectionScheme) -> Result<ValidationResult, FluidError> {
    let t0 = Instant::now();
    let nu = 0.01;
    let h = 2.0 * PI / n as f64;
    let (mut s, mut ok) = periodic_cube(n, h, nu, scheme, |c, [x, y, z]| match c {
        0 => x.sin() * y.cos() * z.cos(),
        1 => -x.cos() * y.sin() * z.cos(),
        _ => 0.0,
    })?;
    let t_end = 5.0;
    let steps = (t_end / (0.5 * h / s.max_speed_m_s())).ceil() as usize;
    let (nu_eff, ok_run) = periodic_effective_viscosity(&mut s, t_end / steps as f64, t_end)?;
    ok &= ok_run;
    Ok(ValidationResult {
        case: format!("Taylor-Green 3D ({})", scheme.name()),
        cells_across: n,
        error: nu_eff / nu,
        metric: "nu_eff / nu".into(),
        steps,
        wall_s: t0.elapsed().as_secs_f64(),
        all_converged: ok,
    })
}

/// Ethier-Steinman exact velocity.
pub fn ethier_steinman_velocity(x: [f64; 3], t: f64, nu: f64) -> [f64; 3] {
    let (a, d) = (PI / 4.0, PI / 2.0);
    let f = (-nu * d * d * t).exp();
    let [x, y, z] = x;
    [
        -a * ((a * x).exp() * (a * y + d * z).sin() + (a * z).exp() * (a * x + d * y).cos()) * f,
        -a * ((a * y).exp() * (a * z + d * x).sin() + (a * x).exp() * (a * y + d * z).cos()) * f,
        -a * ((a * z).exp() * (a * x + d * y).sin() + (a * y).exp() * (a * z + d * x).cos()) * f,
    ]
}

/// Ethier-Steinman on [-1,1]^3 (nu = 1, t = 0.05, dt = h^2/4) with `n` cells across and the exact
/// velocity prescribed on every face (a layer of `Velocity` cells). Error: the largest face-velocity
/// error over the interior relative to the largest exact speed.
pub fn ethier_steinman(n: usize) -> Result<ValidationResult, FluidError> {
    ethier_steinman_with(n, FluidParams::default().advection)
}

/// [`ethier_steinman`] with the advection `scheme`.
pub fn ethier_steinman_with(
    n: usize,
    scheme: AdvectionScheme,
) -> Result<ValidationResult, FluidError> {
    let t0 = Instant::now();
    let nu = 1.0;
    let h = 2.0 / n as f64;
    let m = n + 2;
    let mut grid = FluidGrid::new([m; 3], h, [-1.0 - h; 3], [false; 3])?;
    let boundary = |c: [usize; 3]| c.iter().any(|&v| v == 0 || v == m - 1);
    for k in 0..m {
        for j in 0..m {
            for i in 0..m {
                if boundary([i, j, k]) {
                    grid.set_label([i, j, k], CellLabel::Velocity)?;
                }
            }
        }
    }
    let params = FluidParams {
        density_kg_m3: 1.0,
        viscosity_m2_s: nu,
        tolerance: 1e-7,
        advection: scheme,
        ..Default::default()
    };
    let mut s = FluidSolver::new(grid, params)?;
    let set_boundary = |s: &mut FluidSolver, t: f64| -> Result<(), FluidError> {
        for k in 0..m {
            for j in 0..m {
                for i in 0..m {
                    if boundary([i, j, k]) {
                        // The point of the boundary this cell borders.
                        let x = s
                            .grid()
                            .cell_centre_m([i, j, k])
                            .map(|v| v.clamp(-1.0, 1.0));
                        let u = ethier_steinman_velocity(x, t, nu).map(|v| v as f32);
                        s.grid_mut().set_velocity([i, j, k], u)?;
                    }
                }
            }
        }
        Ok(())
    };
    set_boundary(&mut s, 0.0)?;
    s.set_velocity_field(|c, x| ethier_steinman_velocity(x, 0.0, nu)[c]);
    let mut ok = s.project_now(1.0).projection_converged;
    let dt = 0.25 * h * h;
    let steps = (0.05 / dt).round() as usize;
    for _ in 0..steps {
        let t_next = s.time_s() + dt;
        set_boundary(&mut s, t_next)?;
        ok &= s.step(dt)?.projection_converged;
    }
    let t = s.time_s();
    let (mut err, mut umax) = (0.0f64, 0.0f64);
    for c in 0..3 {
        for (idx, &v) in s.face_velocities(c).iter().enumerate() {
            let x = s.face_position_m(c, idx);
            if x.iter().all(|&v| v > -1.0 + 0.5 * h && v < 1.0 - 0.5 * h) {
                let e = ethier_steinman_velocity(x, t, nu)[c];
                err = err.max((v as f64 - e).abs());
                umax = umax.max(e.abs());
            }
        }
    }
    Ok(ValidationResult {
        case: format!("Ethier-Steinman 3D ({})", scheme.name()),
        cells_across: n,
        error: err / umax,
        metric: "max |u - u_exact| / max |u_exact|".into(),
        steps,
        wall_s: t0.elapsed().as_secs_f64(),
        all_converged: ok,
    })
}

/// ABC (Arnold-Beltrami-Childress) flow, A = B = C = 1, on an `n^3` periodic unit box (k = 2 pi,
/// nu = 0.01: Re = 100 on the box and the coefficient) to t = 0.5 at CFL 0.5. A Beltrami field
/// (`curl u = k u`): the advection term is a pure gradient, so the exact solution decays as
/// `exp(-nu k^2 t)` and the kinetic energy as `exp(-2 nu k^2 t)`; the error figure is `nu_eff / nu`
/// from the energy decay (1 is exact). Unlike Taylor-Green, every component varies along every
/// axis: a 3D test of the trace and the interpolation.
pub fn abc_flow(n: usize, scheme: AdvectionScheme) -> Result<ValidationResult, FluidError> {
    let t0 = Instant::now();
    let (l, nu) = (1.0, 0.01);
    let h = l / n as f64;
    let k = 2.0 * PI / l;
    // The staggered samples of the Beltrami field are not exactly discretely divergence-free:
    // `periodic_cube` projects them.
    let (mut s, mut ok) = periodic_cube(n, h, nu, scheme, |c, x| {
        let [x, y, z] = x.map(|v| k * v);
        match c {
            0 => z.sin() + y.cos(),
            1 => x.sin() + z.cos(),
            _ => y.sin() + x.cos(),
        }
    })?;
    let e0 = s.kinetic_energy_j();
    let u_max = s.max_speed_m_s();
    let steps = (0.5 / (0.5 * h / u_max)).ceil() as usize;
    let dt = 0.5 / steps as f64;
    for _ in 0..steps {
        let st = s.step(dt)?;
        ok &= st.projection_converged && st.max_div_rel <= 1e-5;
    }
    let nu_eff = -(s.kinetic_energy_j() / e0).ln() / (2.0 * k * k * s.time_s());
    Ok(ValidationResult {
        case: format!("ABC flow 3D ({})", scheme.name()),
        cells_across: n,
        error: nu_eff / nu,
        metric: "nu_eff / nu".into(),
        steps,
        wall_s: t0.elapsed().as_secs_f64(),
        all_converged: ok,
    })
}

/// Centreline extrema of the lid-driven cavity at Re = 1000 (lid speed 1): the smallest u on the
/// vertical centreline, the largest and smallest v on the horizontal one.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct CavityExtrema {
    /// min u on x = 1/2.
    pub u_min: f64,
    /// max v on y = 1/2.
    pub v_max: f64,
    /// min v on y = 1/2.
    pub v_min: f64,
}

impl CavityExtrema {
    /// Ghia, Ghia & Shin (1982), Re = 1000, the extrema of their tables I and II (129 x 129
    /// multigrid; sim-core/tests/data/cavity_re1000_reference.csv).
    pub const GHIA: CavityExtrema = CavityExtrema {
        u_min: -0.38289,
        v_max: 0.37095,
        v_min: -0.51550,
    };
    /// Botella & Peyret (1998), Re = 1000, Chebyshev collocation N = 160 (the finer reference).
    pub const BOTELLA_PEYRET: CavityExtrema = CavityExtrema {
        u_min: -0.3885698,
        v_max: 0.3769447,
        v_min: -0.5270771,
    };

    /// The largest difference of the three extrema.
    pub fn max_diff(&self, other: &CavityExtrema) -> f64 {
        (self.u_min - other.u_min)
            .abs()
            .max((self.v_max - other.v_max).abs())
            .max((self.v_min - other.v_min).abs())
    }
}

/// The case file of the 2D lid-driven cavity at Re = 1000 with `n` cells across (unit square, lid
/// at 1 m/s as a row of velocity cells above y = 1, one cell thick and periodic in z; CFL 1 to a
/// steady state or t = 100 s; centreline probes of 8 n + 1 points).
pub fn lid_cavity_re1000_case(n: usize, scheme: AdvectionScheme) -> String {
    let h = 1.0 / n as f64;
    let pts = 8 * n + 1;
    let zc = 0.5 * h;
    format!(
        r#"[grid]
cells = [{n}, {ny}, 1]
spacing_m = {h}
periodic = [false, false, true]
[fluid]
density_kg_m3 = 1.0
viscosity_m2_s = 0.001
[time]
cfl = 1.0
end_s = 100.0
steady_tolerance = 1e-4
[solver]
advection = "{name}"
[[region]]
label = "velocity"
min_m = [0.0, 1.0, 0.0]
max_m = [1.0, {top}, {h}]
velocity_m_s = [1.0, 0.0, 0.0]
[[probe]]
name = "vertical_centreline"
from_m = [0.5, 0.0, {zc}]
to_m = [0.5, 1.0, {zc}]
points = {pts}
[[probe]]
name = "horizontal_centreline"
from_m = [0.0, 0.5, {zc}]
to_m = [1.0, 0.5, {zc}]
points = {pts}
"#,
        ny = n + 1,
        name = scheme.name(),
        top = 1.0 + h,
    )
}

/// Runs [`lid_cavity_re1000_case`]: the centreline extrema, and a result whose error is their
/// largest difference from Ghia et al. (`all_converged`: every projection converged and the
/// steady state was reached).
pub fn lid_cavity_re1000(
    n: usize,
    scheme: AdvectionScheme,
) -> Result<(ValidationResult, CavityExtrema), crate::fluid::case::CaseError> {
    let t0 = Instant::now();
    let case = crate::fluid::case::Case::parse(&lid_cavity_re1000_case(n, scheme))?;
    let report = case.run()?;
    let line = |p: usize, c: usize| {
        report.probes[p]
            .samples
            .iter()
            .map(move |s| s.velocity_m_s[c])
    };
    let ext = CavityExtrema {
        u_min: line(0, 0).fold(f64::INFINITY, f64::min),
        v_max: line(1, 1).fold(f64::NEG_INFINITY, f64::max),
        v_min: line(1, 1).fold(f64::INFINITY, f64::min),
    };
    let st = &report.statistics;
    Ok((
        ValidationResult {
            case: format!("cavity Re 1000 ({})", scheme.name()),
            cells_across: n,
            error: ext.max_diff(&CavityExtrema::GHIA),
            metric: "max centreline-extremum difference from Ghia (lid speed 1)".into(),
            steps: st.steps,
            wall_s: t0.elapsed().as_secs_f64(),
            all_converged: st.unconverged_projections == 0 && st.steady_reached,
        },
        ext,
    ))
}
