//! Turbulent (eddy) dispersion of the particles: the mixing by the inflow jet's turbulence that
//! the resolved flow on a millimetre grid does not carry (`docs/particles.md`, "Eddy
//! dispersion").
//!
//! The jet leaving the scope's inflow channel (diameter `d_j`, mean speed `u_j = Q_in / A_j`) is
//! turbulent at clinical flows (`Re = u_j d_j / nu` of 1000-4000 at 100-400 ml/min) and the
//! cavity, a few centimetres long, lies within its reach: it hits the fundus and recirculates. In
//! the self-similar round jet the turbulent viscosity is uniform,
//! `nu_T = 0.028 U_0 r_half` with `U_0 r_half = B S u_j d_j` (`B = 5.8`, `S = 0.094`; Pope,
//! *Turbulent Flows*, 2000, section 5.6), and a passive scalar mixes with `D_T = nu_T / sigma_T`
//! (`sigma_T = 0.7`). So `D_T = 0.0218 u_j d_j`, which is `0.0218 * 4 Q_in / (pi d_j)`: linear in
//! the flow rate, as the paper's vortex count. At 200 ml/min through 2.8 mm^2 it is
//! `5e-5 m^2/s`, a root-mean-square spread of about 10 mm per second and axis: a cavity of a few
//! millilitres is stirred within seconds, which is what a trainee sees (blood clouds, then
//! thins out while the flow washes it out), and what keeps blood out of the one-voxel crevices
//! and dead ends a coarse grid leaves along the wall (their resolved speed is near zero).
//!
//! Each step the particles take a random walk of that diffusivity (operator splitting: the walk,
//! then the advection): per axis a uniform displacement of variance `2 D_T dt` (the sum over steps
//! tends to the Gaussian), in substeps of at most [`MAX_AMPLITUDE_CELLS`] so the walk never jumps a
//! wall. A substep that would end in a wall or the scope is rejected (the particle stays), which
//! keeps a uniform concentration uniform (reflecting walls); one that ends in an outflow hole or
//! the open os moves the particle there, and the advection then removes it through that outlet.

use super::VoxelKind;

/// Pope's round-jet constants: `nu_T = NU_T_FACTOR * U_0 * r_half`, `U_0 r_half = B S u_j d_j`.
const NU_T_FACTOR: f64 = 0.028;
/// Velocity-decay constant `B` of the round jet.
const JET_DECAY_B: f64 = 5.8;
/// Spreading rate `S` of the round jet.
const JET_SPREAD_S: f64 = 0.094;
/// Turbulent Schmidt number of a passive scalar in free shear flows.
const TURBULENT_SCHMIDT: f64 = 0.7;

/// Largest displacement of one substep along any axis, cells (as the advection's substeps).
pub const MAX_AMPLITUDE_CELLS: f32 = 0.9;
/// Most substeps of one step's walk; beyond, the walk is shortened (`D_T dt / h^2` above about
/// 4: far finer grids or flows than the clinical ones).
pub const MAX_WALK_SUBSTEPS: u32 = 16;

/// The eddy diffusivity of the inflow jet, m^2/s: `D_T = 0.0218 u_j d_j` for a flow of
/// `inflow_m3_per_s` through a round channel of `channel_area_m2` (0 without flow or channel).
pub fn jet_eddy_diffusivity_m2_s(inflow_m3_per_s: f64, channel_area_m2: f64) -> f64 {
    if !(inflow_m3_per_s.is_finite()
        && inflow_m3_per_s > 0.0
        && channel_area_m2.is_finite()
        && channel_area_m2 > 0.0)
    {
        return 0.0;
    }
    let d_j = (4.0 * channel_area_m2 / std::f64::consts::PI).sqrt();
    let u_j = inflow_m3_per_s / channel_area_m2;
    NU_T_FACTOR * JET_DECAY_B * JET_SPREAD_S / TURBULENT_SCHMIDT * u_j * d_j
}

/// One step's walk in grid units: the substeps and the half width of each substep's uniform
/// displacement (variance `2 D dt / h^2` over the step). `None` when there is nothing to do.
pub fn walk_plan(diffusivity_m2_s: f64, dt_s: f64, h_m: f64) -> Option<(u32, f32)> {
    let var_cells = 2.0 * diffusivity_m2_s * dt_s / (h_m * h_m);
    if !(var_cells.is_finite() && var_cells > 0.0) {
        return None;
    }
    // A uniform on [-a, a] has variance a^2 / 3; m substeps of a each: m a^2 / 3 = var.
    let a_max = f64::from(MAX_AMPLITUDE_CELLS);
    let m = (3.0 * var_cells / (a_max * a_max))
        .ceil()
        .clamp(1.0, f64::from(MAX_WALK_SUBSTEPS));
    let a = (3.0 * var_cells / m).sqrt().min(a_max);
    Some((m as u32, a as f32))
}

/// Moves the particles `pos` (grid units) by the walk of [`walk_plan`] (`substeps` of half width
/// `amplitude` cells) on a grid of `dims` cells of `kinds`, drawing from `rng`. Returns whether a
/// particle moved into an outlet (it no longer starts the advection in a fluid cell).
pub fn walk(
    pos: &mut [[f32; 3]],
    kinds: &[VoxelKind],
    dims: [usize; 3],
    (substeps, amplitude): (u32, f32),
    rng: &mut fastrand::Rng,
) -> bool {
    let mut entered_outlet = false;
    // 21 random bits per axis from one draw, mapped to [-a, a).
    let scale = 2.0 * amplitude / (1u32 << 21) as f32;
    let kind_at = |p: [f32; 3]| -> VoxelKind {
        if !(p[0] >= 0.0 && p[1] >= 0.0 && p[2] >= 0.0) {
            return VoxelKind::Solid;
        }
        // Non-negative here: the conversions truncate (and saturate far outside).
        let (i, j, k) = (p[0] as usize, p[1] as usize, p[2] as usize);
        if i < dims[0] && j < dims[1] && k < dims[2] {
            kinds[i + dims[0] * (j + dims[1] * k)]
        } else {
            VoxelKind::Solid
        }
    };
    for p in pos {
        for _ in 0..substeps {
            if kind_at(*p) != VoxelKind::Fluid {
                break; // in an outlet (the advection removes it) or not movable
            }
            // One axis at a time: in a channel one cell thick a move across it is rejected
            // without blocking the moves along it (each axis's move is symmetric, so the walk
            // stays reversible and a uniform concentration stays uniform).
            let bits = rng.u64(..);
            for a in 0..3 {
                let r = ((bits >> (21 * a)) & ((1 << 21) - 1)) as f32;
                let mut q = *p;
                q[a] += r * scale - amplitude;
                match kind_at(q) {
                    VoxelKind::Fluid => *p = q,
                    VoxelKind::Outflow | VoxelKind::Open => {
                        *p = q;
                        entered_outlet = true;
                        break;
                    }
                    _ => {}
                }
            }
        }
    }
    entered_outlet
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_jet_diffusivity_is_the_round_jets_turbulent_viscosity_over_the_schmidt_number() {
        // 200 ml/min through 2.8 mm^2: u_j = 1.190 m/s, d_j = 1.888 mm.
        let q = 200.0 / 6e7;
        let a = 2.8e-6;
        let d = jet_eddy_diffusivity_m2_s(q, a);
        let (u_j, d_j) = (q / a, (4.0 * a / std::f64::consts::PI).sqrt());
        let expected = 0.028 * 5.8 * 0.094 / 0.7 * u_j * d_j;
        assert!((d - expected).abs() < 1e-15, "{d} vs {expected}");
        assert!((d - 4.9e-5).abs() < 0.1e-5, "{d}");
        // Linear in the flow rate; none without flow.
        assert!((jet_eddy_diffusivity_m2_s(2.0 * q, a) - 2.0 * d).abs() < 1e-15);
        assert_eq!(jet_eddy_diffusivity_m2_s(0.0, a), 0.0);
        assert_eq!(jet_eddy_diffusivity_m2_s(f64::NAN, a), 0.0);
    }

    #[test]
    fn the_walk_spreads_with_the_diffusivity_and_never_ends_in_a_wall() {
        // A 40-cell cube of fluid inside a one-cell wall; particles at the centre. After t the
        // variance per axis is 2 D t (far from the walls), within the sampling error.
        let n = 42;
        let dims = [n, n, n];
        let mut kinds = vec![VoxelKind::Wall; n * n * n];
        for k in 1..n - 1 {
            for j in 1..n - 1 {
                for i in 1..n - 1 {
                    kinds[i + n * (j + n * k)] = VoxelKind::Fluid;
                }
            }
        }
        let (h, dt, d) = (1e-3, 1.0 / 60.0, 5e-5);
        let plan = walk_plan(d, dt, h).unwrap();
        assert!(plan.1 <= MAX_AMPLITUDE_CELLS && plan.0 > 1, "{plan:?}");
        let mut pos = vec![[21.0f32; 3]; 20_000];
        let mut rng = fastrand::Rng::with_seed(3);
        let steps = 30;
        for _ in 0..steps {
            walk(&mut pos, &kinds, dims, plan, &mut rng);
        }
        let expected = 2.0 * d * steps as f64 * dt / (h * h);
        for a in 0..3 {
            let var = pos
                .iter()
                .map(|p| (f64::from(p[a]) - 21.0).powi(2))
                .sum::<f64>()
                / pos.len() as f64;
            // Standard error of a variance estimate from 20000 samples: sqrt(2/N) = 1 %; 4 %.
            assert!(
                (var / expected - 1.0).abs() < 0.04,
                "axis {a}: variance {var} cells^2, expected {expected}"
            );
        }
        // Long enough to reach the walls (an rms spread of 26 cells): nobody ends in one.
        pos.truncate(2000);
        for _ in 0..400 {
            walk(&mut pos, &kinds, dims, plan, &mut rng);
        }
        for p in &pos {
            let c = p.map(|x| x as usize);
            assert_eq!(
                kinds[c[0] + n * (c[1] + n * c[2])],
                VoxelKind::Fluid,
                "{p:?}"
            );
        }
    }
}
