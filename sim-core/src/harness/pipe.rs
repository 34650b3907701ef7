//! Hagen-Poiseuille flow in a circular pipe tilted to the grid (issue 28, acceptance 2): the
//! check of the cut-cell walls' second-order no-slip rule (`fluid/cut_viscosity.rs`).
//!
//! The case: a periodic cube of `L` cells on every axis and a pipe of radius `R` along an integer
//! direction `(p, q, r)`, driven by a body force `g` along its axis. Along a rational direction
//! the periodic box maps the pipe onto itself (the shift `L (p, q, r)` runs along the axis), so
//! the box holds an infinite straight pipe: no ends, no entrance length, and Hagen-Poiseuille's
//! `u(r) = g (R^2 - r^2) / (4 nu)` with a uniform pressure is the exact solution; the flow rate is
//! `Q = pi R^4 g / (8 nu)` (`G = rho g`, so this is `pi R^4 G / (8 mu)`). The pipe's periodic images
//! (its lines through the centre shifted by `L v`, `v` integer) are `cylinder` regions of a case
//! file in solid rock (the same path as a user's case); `L` is the smallest size that keeps
//! neighbouring images at least `2 R + 3` cells apart, so solid always separates them.
//!
//! Measured: the flux through every grid plane normal to the axis `x_m` of the direction's largest
//! component (each plane crosses the pipe `|p_m|` times per period; the projection makes every
//! plane carry the same flux), and the face velocities whose centres lie inside the circle
//! against `u(r)` projected on their component. The body force is scaled so the largest CFL
//! number is `nu dt / h^2 / 5000` (advection, exact for the analytic field only up to
//! interpolation, then adds an error of about 5e-5 of the viscous term), and `nu dt / h^2` as asked ([`PipeSpec::new`]: 50, implicit viscosity),
//! run from rest until the transient left (from the flow rate's change in a step and the slowest
//! mode's decay per step) is below `1e-5` of the flow rate in three successive steps.

use std::f64::consts::PI;
use std::time::Instant;

use serde::Serialize;

use crate::fluid::case::{Case, CaseError};
use crate::fluid::{CellLabel, FluidSolver};

/// The steady criterion: what is left of the transient, estimated from the flow rate's change in
/// a step and the decay per step of the slowest mode (`rho`: the pipe's first Bessel mode, `nu
/// dt / (R / 2.405)^2` per step, backward Euler or forward), below this (relative) in three
/// successive steps. The iterative solves' tolerances leave a noise of about 1e-6 of the flow
/// rate from step to step.
const STEADY_CHANGE: f64 = 1e-5;

/// One tilted-pipe case.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct PipeSpec {
    /// The pipe's direction (integers, not all zero).
    pub axis: [i32; 3],
    /// Radius in cells.
    pub radius_cells: f64,
    /// Kinematic viscosity.
    pub viscosity_m2_s: f64,
    /// Radius (the spacing is `radius_m / radius_cells`).
    pub radius_m: f64,
    /// `nu dt / h^2`: above [`crate::fluid::EXPLICIT_LIMIT`] the viscous step is implicit.
    pub nu_dt_per_h2: f64,
}

impl PipeSpec {
    /// A pipe of radius 1 mm along `axis`, run with implicit viscosity (`nu dt / h^2 = 50`).
    pub fn new(axis: [i32; 3], radius_cells: f64, viscosity_m2_s: f64) -> Self {
        Self {
            axis,
            radius_cells,
            viscosity_m2_s,
            radius_m: 1e-3,
            nu_dt_per_h2: 50.0,
        }
    }
}

/// What one run measured.
#[derive(Clone, Debug, Serialize)]
pub struct PipeResult {
    /// The case.
    pub spec: PipeSpec,
    /// Cells per axis of the periodic cube.
    pub cells: usize,
    /// Flow rate.
    pub flow_m3_per_s: f64,
    /// Hagen-Poiseuille's flow rate.
    pub hagen_poiseuille_m3_per_s: f64,
    /// `(Q - Q_HP) / Q_HP`.
    pub flow_error: f64,
    /// Over the faces inside the circle: `sqrt(sum (u - u_HP)^2 / sum u_HP^2)`.
    pub profile_l2: f64,
    /// Over the faces inside the circle: `max |u - u_HP| / U_centre`.
    pub profile_max: f64,
    /// Faces compared.
    pub profile_faces: usize,
    /// Steps run.
    pub steps: usize,
    /// Whether the steady criterion was met.
    pub steady: bool,
    /// Whether every projection converged.
    pub converged: bool,
    /// Wall time of the run (s).
    pub wall_s: f64,
}

fn norm(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

/// The perpendicular part of `v` against the unit axis `a`.
fn perpendicular(v: [f64; 3], a: [f64; 3]) -> [f64; 3] {
    let s = v[0] * a[0] + v[1] * a[1] + v[2] * a[2];
    std::array::from_fn(|k| v[k] - s * a[k])
}

/// The shortest distance between the pipe's images in a unit periodic cube (the shortest
/// perpendicular part of an integer shift not along the axis).
fn image_spacing(a: [f64; 3]) -> f64 {
    let mut best = f64::INFINITY;
    for x in -3i32..=3 {
        for y in -3i32..=3 {
            for z in -3i32..=3 {
                let d = norm(perpendicular([x as f64, y as f64, z as f64], a));
                if d > 1e-9 {
                    best = best.min(d);
                }
            }
        }
    }
    best
}

/// The case file of a spec: the cube's size in cells, the text, and the image axes' points
/// (m) through which the pipe's images run.
pub fn pipe_case(spec: &PipeSpec) -> Result<(usize, String, Vec<[f64; 3]>), CaseError> {
    let bad = |what: &str| CaseError::Invalid {
        key: "pipe".into(),
        value: format!("{spec:?}"),
        problem: what.into(),
    };
    if spec.axis == [0; 3] {
        return Err(bad("the axis needs a non-zero component"));
    }
    if !(spec.radius_cells >= 1.0
        && spec.radius_m > 0.0
        && spec.viscosity_m2_s > 0.0
        && spec.nu_dt_per_h2 > 0.0)
    {
        return Err(bad(
            "expected radius_cells >= 1, radius_m > 0, viscosity > 0, nu_dt_per_h2 > 0",
        ));
    }
    let a0 = spec.axis.map(f64::from);
    let a = a0.map(|x| x / norm(a0));
    let h = spec.radius_m / spec.radius_cells;
    let cells = ((2.0 * spec.radius_cells + 3.0) / image_spacing(a)).ceil() as usize;
    let l = cells as f64 * h;
    let centre = [0.5 * l; 3];
    // Images within reach of the box (perpendicular distance from its centre up to its half
    // diagonal plus the radius), one per distinct line.
    let reach = 0.5 * 3f64.sqrt() * l + spec.radius_m + 2.0 * h;
    let mut offsets: Vec<[f64; 3]> = Vec::new();
    let k = 3;
    for x in -k..=k {
        for y in -k..=k {
            for z in -k..=k {
                let o = perpendicular([x as f64 * l, y as f64 * l, z as f64 * l], a);
                if norm(o) <= reach
                    && offsets
                        .iter()
                        .all(|p| norm(std::array::from_fn::<f64, 3, _>(|i| p[i] - o[i])) > 1e-6 * l)
                {
                    offsets.push(o);
                }
            }
        }
    }
    let length = 3f64.sqrt() * l + 4.0 * h;
    let nu = spec.viscosity_m2_s;
    let dt = spec.nu_dt_per_h2 * h * h / nu;
    // CFL a / 5000 at the centre speed g R^2 / (4 nu): the advection's interpolation error per
    // step against the viscous change per step is about CFL / (4 a).
    let cfl = spec.nu_dt_per_h2 / 5000.0;
    let g = cfl * h / dt * 4.0 * nu / (spec.radius_m * spec.radius_m);
    let force = a.map(|x| g * x);
    let mut text = format!(
        r#"[grid]
cells = [{cells}, {cells}, {cells}]
spacing_m = {h:e}
periodic = [true, true, true]
background = "solid"
[fluid]
density_kg_m3 = 1000.0
viscosity_m2_s = {nu:e}
body_force_m_s2 = [{:e}, {:e}, {:e}]
[time]
dt_s = {dt:e}
end_s = {end:e}
[solver]
tolerance = 1e-6
"#,
        force[0],
        force[1],
        force[2],
        end = 1e9 * dt,
    );
    let mut points = Vec::new();
    for o in &offsets {
        let c: [f64; 3] = std::array::from_fn(|i| centre[i] + o[i]);
        points.push(c);
        text += &format!(
            "[[region]]\nshape = \"cylinder\"\nlabel = \"fluid\"\ncentre_m = [{:e}, {:e}, {:e}]\naxis = [{:e}, {:e}, {:e}]\nradius_m = {:e}\nlength_m = {length:e}\n",
            c[0], c[1], c[2], a[0], a[1], a[2], spec.radius_m
        );
    }
    Ok((cells, text, points))
}

/// Runs one tilted pipe to its steady state (at most `max_steps` steps).
pub fn tilted_pipe(spec: &PipeSpec, max_steps: usize) -> Result<PipeResult, CaseError> {
    let t0 = Instant::now();
    let (cells, text, points) = pipe_case(spec)?;
    let case = Case::parse(&text)?;
    let mut s = FluidSolver::new(case.build_grid()?, case.params()?)?;
    let dt = case.time.dt_s.unwrap_or(0.0);
    let a0 = spec.axis.map(f64::from);
    let a = a0.map(|x| x / norm(a0));
    let m = (0..3)
        .max_by(|&i, &j| a0[i].abs().total_cmp(&a0[j].abs()))
        .unwrap_or(0);
    let crossings = spec.axis[m].unsigned_abs() as f64;
    let h = case.grid.spacing_m;
    let nu = spec.viscosity_m2_s;
    let g = norm(case.fluid.body_force_m_s2);
    let r = spec.radius_m;
    let flow = |s: &FluidSolver| -> f64 {
        let grid = s.grid();
        let cut = grid.cut_fractions();
        let u = s.face_velocities(m);
        let mut sum = 0.0;
        // Every axis is periodic: face `f` of component `m` has the cell index of its upper cell
        // and lies between it and the cell below along `m` (wrapped). Only faces between two
        // fluid cells carry flux (the others are walls or, in the solid, extrapolated).
        let fluid = |i: usize| grid.label_at(i) == CellLabel::Fluid;
        for (idx, &v) in u.iter().enumerate() {
            let f = grid.coords(idx);
            let mut lower = f;
            lower[m] = (f[m] + cells - 1) % cells;
            if !(fluid(idx) && fluid(grid.index(lower))) {
                continue;
            }
            let area = cut.map_or(1.0, |c| c.face[m][idx]) as f64;
            sum += area * v as f64;
        }
        // Every plane normal to x_m (cells of them) carries the flux; their mean, per crossing,
        // signed along the axis.
        sum * h * h / cells as f64 / crossings * a[m].signum()
    };
    let mut q = 0.0;
    let (mut steps, mut steady, mut converged) = (0, false, true);
    let mut calm = 0;
    let mode = spec.nu_dt_per_h2 * (2.405 / spec.radius_cells).powi(2);
    let rho = if spec.nu_dt_per_h2 > crate::fluid::EXPLICIT_LIMIT {
        1.0 / (1.0 + mode)
    } else {
        (1.0 - mode).max(0.0)
    };
    let steady_change = STEADY_CHANGE * (1.0 - rho) / rho.max(f64::MIN_POSITIVE);
    while steps < max_steps {
        let st = s.step(dt)?;
        converged &= st.projection_converged;
        steps += 1;
        let q_new = flow(&s);
        let change = (q_new - q).abs() / q_new.abs().max(f64::MIN_POSITIVE);
        q = q_new;
        calm = if change < steady_change { calm + 1 } else { 0 };
        if calm >= 3 {
            steady = true;
            break;
        }
    }
    let q_exact = PI * r.powi(4) * g / (8.0 * nu);
    // The profile: faces inside the circle (distance to the nearest image axis below R).
    let u_centre = g * r * r / (4.0 * nu);
    let (mut e2, mut n2, mut emax, mut count) = (0.0, 0.0, 0.0f64, 0);
    for c in 0..3 {
        let u = s.face_velocities(c);
        for (idx, &v) in u.iter().enumerate() {
            let x = s.face_position_m(c, idx);
            let rr = points
                .iter()
                .map(|p| norm(perpendicular(std::array::from_fn(|i| x[i] - p[i]), a)))
                .fold(f64::INFINITY, f64::min);
            if rr >= r {
                continue;
            }
            let want = a[c] * g * (r * r - rr * rr) / (4.0 * nu);
            let d = v as f64 - want;
            e2 += d * d;
            n2 += want * want;
            emax = emax.max(d.abs() / u_centre);
            count += 1;
        }
    }
    Ok(PipeResult {
        spec: *spec,
        cells,
        flow_m3_per_s: q,
        hagen_poiseuille_m3_per_s: q_exact,
        flow_error: (q - q_exact) / q_exact,
        profile_l2: (e2 / n2.max(f64::MIN_POSITIVE)).sqrt(),
        profile_max: emax,
        profile_faces: count,
        steps,
        steady,
        converged,
        wall_s: t0.elapsed().as_secs_f64(),
    })
}

/// The observed order of an error between two radii: `log(e1 / e2) / log(r2 / r1)`.
pub fn observed_order(r1: f64, e1: f64, r2: f64, e2: f64) -> f64 {
    (e1.abs() / e2.abs()).ln() / (r2 / r1).ln()
}
