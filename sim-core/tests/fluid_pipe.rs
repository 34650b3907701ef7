//! Hagen-Poiseuille flow in a pipe tilted to the grid (issue 28, acceptance 2): the cut-cell
//! walls' no-slip rule (`fluid/cut_viscosity.rs`) against the exact flow of an infinite pipe
//! (`harness::pipe`: a rational tilt in a periodic cube), at `nu dt / h^2 = 50`. On cut grids the
//! split step's steady state depends on the time step (see the ignored sweep below and
//! docs/fluid-cases.md, "Caveat"): these bounds hold for this time step, not for the explicit
//! step's steady state.

use hydrometra_sim::harness::pipe::{observed_order, tilted_pipe, PipeResult, PipeSpec};

fn run(spec: PipeSpec) -> PipeResult {
    let r = tilted_pipe(&spec, 400).unwrap();
    println!(
        "axis {:?}, R = {} cells, nu = {:e}, nu dt / h^2 = {}: {}^3 cells, Q error {:+.4} %, \
         profile L2 {:.4} %, max {:.4} % of the centre speed ({} faces), {} steps, {:.1} s",
        spec.axis,
        spec.radius_cells,
        spec.viscosity_m2_s,
        spec.nu_dt_per_h2,
        r.cells,
        r.flow_error * 100.0,
        r.profile_l2 * 100.0,
        r.profile_max * 100.0,
        r.profile_faces,
        r.steps,
        r.wall_s
    );
    assert!(r.steady && r.converged, "{r:?}");
    r
}

/// The least-squares slope of `log |error|` against `log radius`: the observed order over a
/// series of radii.
fn fitted_order(runs: &[PipeResult], error: impl Fn(&PipeResult) -> f64) -> f64 {
    let pts: Vec<(f64, f64)> = runs
        .iter()
        .map(|r| (r.spec.radius_cells.ln(), error(r).abs().ln()))
        .collect();
    let n = pts.len() as f64;
    let (mx, my) = (
        pts.iter().map(|p| p.0).sum::<f64>() / n,
        pts.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    -sxy / sxx
}

/// The series of one tilt and viscosity: the flow rate within 2 % at the smallest radius and
/// the profile within 3 % (L2, relative) there, both errors falling with the radius at an
/// observed order of at least 1.5 (least squares over the series; a staircase wall gives 1),
/// and no step between radii worse than first order (the cut pattern changes with the radius,
/// so single steps scatter about the fit).
fn check_series(axis: [i32; 3], nu: f64, radii: &[f64]) {
    let runs: Vec<PipeResult> = radii
        .iter()
        .map(|&r| run(PipeSpec::new(axis, r, nu)))
        .collect();
    let first = &runs[0];
    assert!(first.flow_error.abs() < 0.02, "{first:?}");
    assert!(first.profile_l2 < 0.03, "{first:?}");
    let q_order = fitted_order(&runs, |r| r.flow_error);
    let p_order = fitted_order(&runs, |r| r.profile_l2);
    println!(
        "axis {axis:?}, nu {nu:e}: observed order (least squares over {radii:?}): flow rate \
         {q_order:.2}, profile L2 {p_order:.2}"
    );
    for w in runs.windows(2) {
        let (a, b) = (&w[0], &w[1]);
        let q = observed_order(
            a.spec.radius_cells,
            a.flow_error,
            b.spec.radius_cells,
            b.flow_error,
        );
        let p = observed_order(
            a.spec.radius_cells,
            a.profile_l2,
            b.spec.radius_cells,
            b.profile_l2,
        );
        println!(
            "  {} -> {} cells: flow rate {q:.2}, profile L2 {p:.2}",
            a.spec.radius_cells, b.spec.radius_cells
        );
        assert!(q >= 1.0 && p >= 1.0, "{a:?}\n{b:?}");
    }
    assert!(q_order >= 1.5 && p_order >= 1.3, "{q_order} {p_order}");
}

/// The stated case: along (1, 1, 1), water, radii 4, 8 and 16 cells.
#[test]
fn tilted_pipe_matches_hagen_poiseuille_at_second_order() {
    check_series([1, 1, 1], 1e-6, &[4.0, 8.0, 16.0]);
}

/// A case the rule was not tuned on: another tilt, radius and viscosity.
#[test]
fn tilted_pipe_unseen_tilt_radius_and_viscosity() {
    check_series([1, 2, 2], 3e-6, &[5.0, 10.0]);
}

/// The steady state's dependence on the time step on cut grids (not in CI: about ten minutes).
/// The split step's steady state is the discrete equations' only where the projection's
/// pressure gradient vanishes; at cut cells it does not (the area-weighted divergence of the
/// nearly exact viscous field is not zero there), and the implicit step then carries a term
/// `nu dt L grad p`: the flow rate moves with `nu dt / h^2`. The explicit step (the smallest
/// value, below its limit with the walls' diagonal) has no such term.
#[test]
#[ignore = "a measurement of about 15 minutes, run by hand for docs/fluid-cases.md: cargo test -p hydrometra-sim --test fluid_pipe -- --ignored --nocapture"]
fn tilted_pipe_flow_rate_against_the_time_step() {
    for radius in [4.0, 8.0] {
        for a in [0.0075, 0.1, 2.0, 50.0] {
            let mut spec = PipeSpec::new([1, 1, 1], radius, 1e-6);
            spec.nu_dt_per_h2 = a;
            let r = tilted_pipe(&spec, 100_000).unwrap();
            println!(
                "R = {radius} cells, nu dt / h^2 = {a}: Q error {:+.4} %, profile L2 {:.4} %, {} \
                 steps, {:.1} s",
                r.flow_error * 100.0,
                r.profile_l2 * 100.0,
                r.steps,
                r.wall_s
            );
            assert!(r.steady && r.converged, "{r:?}");
        }
    }
}
