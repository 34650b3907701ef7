//! The stability soak: random inflow switching (off, full, partial, reversed), an outflow that opens
//! and closes (a sealed region with a flux mismatch), random boxes flipping between solid and fluid,
//! water or very viscous fluid (explicit or implicit viscosity) and CFL numbers from 0.1 to 50, on an
//! 8^3 box with a 2x2-cell port. Deterministic for a given seed.

use serde::Serialize;

use super::{AdvectionScheme, CellLabel, FluidError, FluidGrid, FluidParams, FluidSolver};

/// Result of a soak.
#[derive(Clone, Debug, Serialize)]
pub struct SoakReport {
    /// Steps run.
    pub steps: usize,
    /// Largest `max |u| / U_port` seen.
    pub max_speed_ratio: f64,
    /// Largest kinetic energy seen over `rho/2 V_box U_port^2` (the energy of the whole box moving at
    /// the port speed).
    pub max_energy_ratio: f64,
    /// Steps whose projection missed the tolerance.
    pub unconverged_projections: usize,
    /// Steps with a non-finite value (must be 0).
    pub non_finite_steps: usize,
    /// Largest `max |div u| h / U` after a projection.
    pub max_div_rel: f64,
    /// Topology rebuilds (label changes).
    pub relabels: usize,
    /// Wall time (s).
    pub wall_s: f64,
}

/// Runs the soak for `steps` steps.
pub fn run_soak(
    steps: usize,
    seed: u64,
    scheme: AdvectionScheme,
) -> Result<SoakReport, FluidError> {
    let t0 = std::time::Instant::now();
    let (n, h) = (8usize, 1e-3);
    let u_port = 0.5f32;
    let mut rng = fastrand::Rng::with_seed(seed);
    let grid = FluidGrid::new([n; 3], h, [0.0; 3], [false; 3])?;
    let params = FluidParams {
        advection: scheme,
        ..Default::default()
    };
    let mut s = FluidSolver::new(grid, params.clone())?;
    let inlet = ([0.0, 0.003, 0.003], [0.001, 0.005, 0.005]);
    let outlet = ([0.007, 0.002, 0.002], [0.008, 0.006, 0.006]);
    let e_ref = 0.5 * params.density_kg_m3 * (n as f64 * h).powi(3) * (u_port as f64).powi(2);
    let mut rep = SoakReport {
        steps,
        max_speed_ratio: 0.0,
        max_energy_ratio: 0.0,
        unconverged_projections: 0,
        non_finite_steps: 0,
        max_div_rel: 0.0,
        relabels: 0,
        wall_s: 0.0,
    };
    let mut inflow = u_port;
    for step in 0..steps {
        if step % 37 == 0 {
            inflow = u_port * [0.0, 1.0, -1.0, 0.3][rng.usize(..4)];
            let g = s.grid_mut();
            g.fill_box(inlet.0, inlet.1, CellLabel::Velocity, [inflow, 0.0, 0.0]);
            let label = if rng.f64() < 0.7 {
                CellLabel::Outflow
            } else {
                CellLabel::Solid
            };
            g.fill_box(outlet.0, outlet.1, label, [0.0; 3]);
        }
        if step % 53 == 0 {
            let c: [f64; 3] = std::array::from_fn(|_| 0.0015 + rng.f64() * 0.005);
            let e: [f64; 3] = std::array::from_fn(|_| rng.f64() * 0.003);
            let lo = [c[0] - e[0], c[1] - e[1], c[2] - e[2]];
            let hi = [c[0] + e[0], c[1] + e[1], c[2] + e[2]];
            let label = if rng.f64() < 0.5 {
                CellLabel::Solid
            } else {
                CellLabel::Fluid
            };
            let g = s.grid_mut();
            g.fill_box(lo, hi, label, [0.0; 3]);
            g.fill_box(inlet.0, inlet.1, CellLabel::Velocity, [inflow, 0.0, 0.0]);
        }
        if step % 1000 == 0 {
            let nu = if rng.f64() < 0.3 { 1e-3 } else { 1e-6 };
            s.set_params(FluidParams {
                viscosity_m2_s: nu,
                ..params.clone()
            })?;
        }
        let cfl = 0.1 + rng.f64() * 49.9;
        let st = s.step(cfl * h / u_port as f64)?;
        let speed = s.max_speed_m_s();
        let energy = s.kinetic_energy_j();
        if !(speed.is_finite() && energy.is_finite() && st.max_div_rel.is_finite()) {
            rep.non_finite_steps += 1;
        }
        rep.relabels += usize::from(st.topology_rebuilt);
        rep.unconverged_projections += usize::from(!st.projection_converged);
        rep.max_div_rel = rep.max_div_rel.max(st.max_div_rel);
        rep.max_speed_ratio = rep.max_speed_ratio.max(speed / u_port as f64);
        rep.max_energy_ratio = rep.max_energy_ratio.max(energy / e_ref);
    }
    rep.wall_s = t0.elapsed().as_secs_f64();
    Ok(rep)
}
