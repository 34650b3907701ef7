//! The advection stage of a substep: the scheme's passes through the centred velocity and, for
//! the reflection schemes, the reflection (advection-reflection's intermediate projection, or
//! the lagged pressure gradient).

use std::time::Instant;

use super::super::multigrid::for_spans;
use super::{advection, AdvectionScheme, FluidSolver, StepStats, LAGGED_REFLECTION_MAX_CFL};

impl FluidSolver {
    /// The cell-centred velocity the traces follow, from the current face velocities.
    pub(super) fn update_centred(&mut self) {
        let wide = self.split();
        let [u0, u1, u2] = &self.u;
        advection::update_centred(
            &self.layout,
            self.grid.dims(),
            [u0, u1, u2],
            &mut self.centred,
            self.centred_rows.as_ref(),
            wide,
        );
    }

    /// `tmp = u` with the advected values of the active faces scattered in (the field a
    /// second trace of the two-step schemes samples).
    pub(super) fn advected_into_tmp(
        plan: &advection::Plan,
        u: &[Vec<f32>; 3],
        adv: &[f32],
        tmp: &mut [Vec<f32>; 3],
    ) {
        for c in 0..3 {
            tmp[c].copy_from_slice(&u[c]);
        }
        advection::scatter(plan, adv, tmp);
    }

    /// Advects the face velocities by `dt_cells` (dt / h) through the centred velocity of the
    /// last [`FluidSolver::update_centred`] with `scheme` (a single-step scheme: a reflection
    /// scheme's half steps are its base scheme), leaving the compact result in `adv`.
    pub(super) fn advect_passes(&mut self, dt_cells: f64, parallel: bool, scheme: AdvectionScheme) {
        let dt_cells = dt_cells as f32;
        let [u0, u1, u2] = &self.u;
        let pass = advection::Pass {
            geo: &self.geo,
            plan: &self.plan,
            vc: &self.centred,
            src: [u0, u1, u2],
            dt_cells,
        };
        match scheme {
            AdvectionScheme::SemiLagrangian => pass.semi_lagrangian(&mut self.adv, parallel),
            AdvectionScheme::MonotoneCubic => pass.cubic(&mut self.adv, parallel),
            AdvectionScheme::MacCormack
            | AdvectionScheme::MacCormackReflection
            | AdvectionScheme::MacCormackLaggedReflection => {
                // The backward step with its bounds and the forward trace in one pass, then the
                // forward step of its result (`tmp`: `u` off the active faces) and the correction.
                let [f0, f1, f2] = &mut self.adv_foot;
                pass.maccormack_trace(
                    &mut self.adv,
                    [&mut self.adv_lo, &mut self.adv_hi],
                    [f0, f1, f2],
                    parallel,
                );
                Self::advected_into_tmp(&self.plan, &self.u, &self.adv, &mut self.tmp);
                let [t0, t1, t2] = &self.tmp;
                // The forward trace is done: this pass only samples `tmp` at its feet.
                let forward = advection::Pass {
                    src: [t0, t1, t2],
                    ..pass
                };
                let [f0, f1, f2] = &self.adv_foot;
                forward.maccormack_correct(
                    [u0, u1, u2],
                    [f0, f1, f2],
                    [&self.adv_lo, &self.adv_hi],
                    &mut self.adv,
                    parallel,
                );
            }
            AdvectionScheme::Bfecc => {
                pass.semi_lagrangian_bounds(
                    &mut self.adv,
                    &mut self.adv_lo,
                    &mut self.adv_hi,
                    parallel,
                );
                advection::gather(&self.plan, [u0, u1, u2], &mut self.adv_orig);
                Self::advected_into_tmp(&self.plan, &self.u, &self.adv, &mut self.tmp);
                let [t0, t1, t2] = &self.tmp;
                let forward = advection::Pass {
                    src: [t0, t1, t2],
                    dt_cells: -dt_cells,
                    ..pass
                };
                // The corrected field `u + (u - forward(backward(u))) / 2`, advected backward
                // once more (`tmp` keeps `u` off the active faces) and clamped.
                forward.bfecc_source(&mut self.adv_orig, parallel);
                advection::scatter(&self.plan, &self.adv_orig, &mut self.tmp);
                let [t0, t1, t2] = &self.tmp;
                let corrected = advection::Pass {
                    src: [t0, t1, t2],
                    ..pass
                };
                corrected.clamped(&mut self.adv, &self.adv_lo, &self.adv_hi, parallel);
            }
        }
        advection::scatter(&self.plan, &self.adv, &mut self.u);
    }

    /// `rho g_a h` per axis (Pa per cell) of the body force along the non-periodic axes: the
    /// hydrostatic potential `phi = rho g.x` of cell (i, j, k) is the sum of `coef_a (i_a + 1/2)`
    /// (any constant would do). A periodic axis has no hydrostatic balance (the force drives a
    /// flow there), so its component is left out; `None` without such a force.
    pub(super) fn hydrostatic_coefficients(&self) -> Option<[f64; 3]> {
        let (rho, h) = (self.params.density_kg_m3, self.grid.spacing_m());
        let periodic = self.grid.periodic();
        let f = self.params.body_force_m_s2;
        let coef: [f64; 3] =
            std::array::from_fn(|a| if periodic[a] { 0.0 } else { rho * f[a] * h });
        coef.iter().any(|&c| c != 0.0).then_some(coef)
    }

    /// The reflection of [`AdvectionScheme::MacCormackLaggedReflection`]: the reflected pressure
    /// `R = (p - phi) / 2` (`p` the last pressure, `phi` the hydrostatic potential of the body
    /// force, see [`FluidSolver::hydrostatic_coefficients`]) kept in `p_lag`, its gradient times
    /// dt / rho subtracted from the face velocities; `p - R` is left in `pressure_pa` as the
    /// projection's warm start, and after the projection `pressure_pa + p_lag` is the pressure.
    /// Only the part of the pressure that does not balance the body force is reflected: at
    /// hydrostatic rest nothing is, so nothing is advected.
    pub(super) fn lagged_reflection(&mut self, dt: f64) {
        let to_q = dt / (self.params.density_kg_m3 * self.grid.spacing_m());
        // The pressure is zero off the fluid cells: the spans cover them.
        for &[s, e] in &self.pressure.mg.levels[0].spans {
            let r = s as usize..e as usize;
            for (l, p) in self.p_lag[r.clone()]
                .iter_mut()
                .zip(&mut self.pressure_pa[r])
            {
                *l = 0.5 * *p;
                *p = *l;
            }
        }
        if let Some(coef) = self.hydrostatic_coefficients() {
            let l0 = &self.pressure.mg.levels[0];
            for &[j, k, i0, i1] in &l0.row_spans {
                let (j, k, i0, i1) = (j as usize, k as usize, i0 as usize, i1 as usize);
                let base = coef[1] * (j as f64 + 0.5) + coef[2] * (k as f64 + 0.5);
                let p0 = l0.pad(i0, j, k);
                for i in i0..i1 {
                    let idx = p0 + (i - i0);
                    let half_phi = 0.5 * (base + coef[0] * (i as f64 + 0.5)) * l0.mask[idx] as f64;
                    self.p_lag[idx] -= half_phi;
                    self.pressure_pa[idx] += half_phi;
                }
            }
        }
        let p_lag = &self.p_lag;
        let ps = &mut self.pressure;
        for_spans(&ps.mg.levels[0], &mut ps.dq, |spans, dq, off| {
            for &[s, e] in spans {
                let (s, e) = (s as usize, e as usize);
                for (q, &p) in dq[s - off..e - off].iter_mut().zip(&p_lag[s..e]) {
                    *q = p * to_q;
                }
            }
            0.0
        });
        if self.grid.periodic().iter().any(|&p| p) {
            self.pressure.mg.levels[0].halo(&mut self.pressure.dq);
        }
        self.subtract_gradient();
        // The outflow cells' reflected pressure is -phi / 2 (`dq` holds 0 there).
        self.outflow_potential_gradient(dt, -1.0);
    }

    /// `u -= dt / rho grad(sign phi / 2)` on the faces between fluid and outflow cells, `phi / 2`
    /// taken on the outflow cell only (zero on the fluid cell); nothing without a hydrostatic
    /// potential.
    pub(super) fn outflow_potential_gradient(&mut self, dt: f64, sign: f64) {
        let Some(coef) = self.hydrostatic_coefficients() else {
            return;
        };
        let to_q = dt / (self.params.density_kg_m3 * self.grid.spacing_m());
        for &(c, idx, side, cell) in &self.outflow_faces {
            let phi: f64 = (0..3).map(|a| coef[a] * (cell[a] as f64 + 0.5)).sum();
            self.u[c as usize][idx as usize] -= (side as f64 * sign * 0.5 * phi * to_q) as f32;
        }
    }

    /// The advection stage of a substep of `dt` s. Advection-reflection runs its first half step,
    /// the intermediate projection (counted as projection time) and the reflection here.
    pub(super) fn advect(&mut self, dt: f64, parallel: bool, stats: &mut StepStats) {
        let h = self.grid.spacing_m();
        let scheme = self.params.advection;
        let t = Instant::now();
        // The lagged reflection only up to CFL 1: above, the lagged gradient carried many cells
        // turned into rotational velocity and pumped energy into the stress soak (max speed 76x
        // the port's over 10^6 steps at CFL up to 50); there the step is plain MacCormack.
        // And only a step's pressure: before the first step there is none (zero would reflect
        // the whole hydrostatic potential, and the viscous step would leave a trace of it).
        self.lagged_applied = scheme == AdvectionScheme::MacCormackLaggedReflection
            && self.pressure_from_step
            && self.max_speed_m_s() * dt <= LAGGED_REFLECTION_MAX_CFL * h;
        self.extrapolate();
        self.update_centred();
        // The traces follow the (divergence-free) velocity before the reflection, as the second
        // half step of advection-reflection follows the projected one: through the reflected
        // field, whose divergence is dt/2 lap(p) / rho, the advection would change the energy by
        // -dt^2 |grad p|^2 / rho^2 per step (to leading order), all the reflection saves.
        if self.lagged_applied {
            self.lagged_reflection(dt);
            self.extrapolate();
        }
        if scheme != AdvectionScheme::MacCormackReflection {
            self.advect_passes(dt / h, parallel, scheme);
            stats.advect_ms += t.elapsed().as_secs_f64() * 1e3;
            return;
        }
        // u~ = A(u; u, dt/2), then u_half = P u~ (u~ kept in `adv_refl`).
        self.advect_passes(0.5 * dt / h, parallel, scheme);
        self.adv_refl.copy_from_slice(&self.adv);
        stats.advect_ms += t.elapsed().as_secs_f64() * 1e3;
        let t = Instant::now();
        self.project(0.5 * dt, stats);
        stats.project_ms += t.elapsed().as_secs_f64() * 1e3;
        // Trace through u_half; advect the reflection 2 u_half - u~ by dt/2.
        let t = Instant::now();
        self.extrapolate();
        self.update_centred();
        for run in &self.plan.runs {
            let (f, n, len) = (run.full as usize, run.compact as usize, run.len as usize);
            let u = &mut self.u[run.c as usize][f..f + len];
            for (v, &w) in u.iter_mut().zip(&self.adv_refl[n..n + len]) {
                *v = 2.0 * *v - w;
            }
        }
        self.extrapolate();
        self.advect_passes(0.5 * dt / h, parallel, scheme);
        stats.advect_ms += t.elapsed().as_secs_f64() * 1e3;
    }
}
