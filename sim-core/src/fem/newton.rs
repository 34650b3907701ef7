//! Newton's method for the quasi-static equilibrium, with line search, a tangent predictor,
//! adaptive load steps, a cavity-volume-controlled mode (bordered system) and an inversion guard.

use super::linear::LdltSolver;
use super::model::FemModel;
use super::system::{Evaluation, System};
use super::FemError;
use std::time::{Duration, Instant};

/// Solver settings.
#[derive(Debug, Clone)]
pub struct SolverOptions {
    /// Converged when `|R| <= tolerance * |p dV/dx|` (2-norms).
    pub tolerance: f64,
    /// Newton iterations per load step before the step is cut.
    pub max_iterations: usize,
    /// Line-search halvings before the step is cut.
    pub max_line_search: usize,
    /// Smallest load step as a fraction of the requested increment.
    pub min_step_fraction: f64,
    /// First load step as a fraction of the requested increment (grows after easy steps).
    pub initial_step_fraction: f64,
    /// Reuse an older factorization while the residual falls fast enough; refactorize when it
    /// does not.
    pub reuse_factorization: bool,
    /// Under pressure control, solve with the current tangent by conjugate gradients
    /// preconditioned with the older factorization (refactorize when that takes more than
    /// `max_krylov_iterations`).
    pub krylov: bool,
    /// Conjugate-gradient iterations before giving up and refactorizing.
    pub max_krylov_iterations: usize,
}

impl Default for SolverOptions {
    fn default() -> Self {
        Self {
            tolerance: 1e-8,
            max_iterations: 25,
            max_line_search: 8,
            min_step_fraction: 1.0 / 1024.0,
            initial_step_fraction: 1.0,
            reuse_factorization: true,
            krylov: true,
            max_krylov_iterations: 10,
        }
    }
}

/// Work and time spent, for benchmarks and logs.
#[derive(Debug, Clone, Default)]
pub struct SolverCounters {
    /// Newton iterations (each one assembly and one factorization).
    pub newton_iterations: usize,
    /// Numeric factorizations.
    pub factorizations: usize,
    /// Load steps that were cut and retried.
    pub step_cuts: usize,
    /// Preconditioned conjugate-gradient iterations.
    pub krylov_iterations: usize,
    /// Time in assembly.
    pub assembly: Duration,
    /// Time in factorization and solves.
    pub linear: Duration,
}

/// A converged equilibrium state.
#[derive(Debug, Clone)]
pub struct Equilibrium {
    /// Positions in metres.
    pub positions_m: Vec<[f64; 3]>,
    /// Cavity pressure in Pa.
    pub pressure_pa: f64,
    /// Cavity volume in m^3.
    pub cavity_volume_m3: f64,
    /// `dx/dp` in m/Pa (pressure-controlled tangent at this state).
    pub dxdp_m_per_pa: Vec<[f64; 3]>,
    /// Newton iterations spent reaching this state from the previous one.
    pub newton_iterations: usize,
    /// Smallest `v/V0` over the tetrahedra.
    pub min_volume_ratio: f64,
    /// Which factorization of the solver belongs to this state (0: none).
    factor_tag: u64,
}

/// The nonlinear solver for one model; keeps the symbolic factorization for all solves.
pub struct Solver<'m> {
    model: &'m FemModel,
    system: System,
    linear: LdltSolver,
    values: Vec<f64>,
    options: SolverOptions,
    /// Work counters.
    pub counters: SolverCounters,
    force_floor: f64,
    factor_tag: u64,
    length_scale: f64,
}

fn norm(v: &[f64]) -> f64 {
    v.iter().map(|a| a * a).sum::<f64>().sqrt()
}
fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}
fn axpy(x: &[[f64; 3]], alpha: f64, d: &[f64]) -> Vec<[f64; 3]> {
    x.iter()
        .enumerate()
        .map(|(i, p)| {
            [
                p[0] + alpha * d[3 * i],
                p[1] + alpha * d[3 * i + 1],
                p[2] + alpha * d[3 * i + 2],
            ]
        })
        .collect()
}
fn flatten(v: &[[f64; 3]]) -> Vec<f64> {
    v.iter().flatten().copied().collect()
}
fn unflatten(v: &[f64]) -> Vec<[f64; 3]> {
    v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
}

/// Converged positions, pressure and iterations, or the failure with its residual history.
type NewtonResult = Result<(Vec<[f64; 3]>, f64, usize), (FemError, Vec<f64>)>;

enum Control {
    Pressure(f64),
    Volume(f64),
}

impl<'m> Solver<'m> {
    /// Builds the sparsity pattern and the symbolic factorization.
    pub fn new(model: &'m FemModel, options: SolverOptions) -> Result<Self, FemError> {
        let system = System::new(model)?;
        let n = system.n_linear();
        let order = system.elimination_order(model);
        let linear = LdltSolver::new(
            n,
            system.col_ptr().to_vec(),
            system.row_idx().to_vec(),
            Some(order),
        )?;
        let values = vec![0.0; system.nnz()];
        let mu_max = model
            .materials
            .iter()
            .map(|m| m.shear_modulus_pa())
            .fold(0.0, f64::max);
        let vol = system.rest_volume();
        let force_floor = 1e-9 * mu_max * vol.abs().powf(2.0 / 3.0);
        let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for p in &model.rest_positions_m {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        let length_scale = (0..3).map(|k| hi[k] - lo[k]).fold(0.0, f64::max);
        Ok(Self {
            model,
            system,
            linear,
            values,
            options,
            counters: SolverCounters::default(),
            force_floor,
            factor_tag: 0,
            length_scale,
        })
    }

    /// The assembled system (pattern and nodal data).
    pub fn system(&self) -> &System {
        &self.system
    }

    /// Stored entries in the tangent and in its factor.
    pub fn sizes(&self) -> (usize, usize) {
        (self.system.nnz(), self.linear.factor_nnz())
    }

    /// The unloaded state.
    pub fn rest_state(&self) -> Equilibrium {
        let x = self.model.rest_positions_m.clone();
        Equilibrium {
            cavity_volume_m3: self.model.cavity.volume(&x),
            dxdp_m_per_pa: vec![[0.0; 3]; x.len()],
            positions_m: x,
            pressure_pa: 0.0,
            newton_iterations: 0,
            min_volume_ratio: 1.0,
            factor_tag: 0,
        }
    }

    fn evaluate(&mut self, x: &[[f64; 3]], p: f64, tangent: bool) -> Result<Evaluation, FemError> {
        let t0 = Instant::now();
        let r = if tangent {
            self.system
                .evaluate(self.model, x, p, Some(&mut self.values))
        } else {
            self.system.evaluate(self.model, x, p, None)
        };
        self.counters.assembly += t0.elapsed();
        r
    }

    fn factorize(&mut self) -> Result<(), FemError> {
        let t0 = Instant::now();
        let r = self.linear.factorize(&self.values);
        self.counters.factorizations += 1;
        self.factor_tag += 1;
        self.counters.linear += t0.elapsed();
        r
    }

    /// Solves the condensed system for a displacement right-hand side through the expanded one.
    fn solve(&mut self, rhs: &mut [f64]) -> Result<(), FemError> {
        let t0 = Instant::now();
        let mut full = rhs.to_vec();
        full.resize(self.system.n_linear(), 0.0);
        let r = self.linear.solve_in_place(&mut full);
        rhs.copy_from_slice(&full[..rhs.len()]);
        self.counters.linear += t0.elapsed();
        r
    }

    /// Conjugate gradients on the assembled (condensed) tangent, preconditioned by the last
    /// factorization. `None` if not converged to `rel_tol` in the allowed iterations or if the
    /// tangent is not positive definite.
    fn pcg(&mut self, rhs: &[f64], rel_tol: f64) -> Result<Option<Vec<f64>>, FemError> {
        let bnorm = norm(rhs);
        let mut x = vec![0.0; rhs.len()];
        if bnorm == 0.0 {
            return Ok(Some(x));
        }
        let mut r = rhs.to_vec();
        let mut z = r.clone();
        self.solve(&mut z)?;
        let mut d = z.clone();
        let mut rz = dot(&r, &z);
        for _ in 0..self.options.max_krylov_iterations {
            self.counters.krylov_iterations += 1;
            let t0 = Instant::now();
            let ad = self.system.multiply(&self.values, &d);
            self.counters.linear += t0.elapsed();
            let dad = dot(&d, &ad);
            if dad.is_nan() || dad <= 0.0 {
                return Ok(None);
            }
            let alpha = rz / dad;
            for i in 0..x.len() {
                x[i] += alpha * d[i];
                r[i] -= alpha * ad[i];
            }
            if norm(&r) <= rel_tol * bnorm {
                return Ok(Some(x));
            }
            z.copy_from_slice(&r);
            self.solve(&mut z)?;
            let rz_new = dot(&r, &z);
            let beta = rz_new / rz;
            rz = rz_new;
            for i in 0..d.len() {
                d[i] = z[i] + beta * d[i];
            }
        }
        Ok(None)
    }

    /// Solves with the tangent assembled last: by preconditioned CG if allowed and a factor
    /// exists, else (or if CG fails) by a fresh factorization.
    fn solve_tangent(
        &mut self,
        rhs: &mut [f64],
        rel_tol: f64,
        allow_krylov: bool,
    ) -> Result<bool, FemError> {
        if allow_krylov && self.options.krylov && self.factor_tag > 0 {
            if let Some(x) = self.pcg(rhs, rel_tol)? {
                rhs.copy_from_slice(&x);
                return Ok(false);
            }
        }
        self.factorize()?;
        self.solve(rhs)?;
        Ok(true)
    }

    /// Fills `dx/dp` (and the volume) of a converged state.
    fn finish_state(&mut self, eq: &mut Equilibrium) -> Result<(), FemError> {
        let ev = self.evaluate(&eq.positions_m, eq.pressure_pa, true)?;
        let mut g = self.system.volume_gradient(self.model, &eq.positions_m);
        self.solve_tangent(&mut g, 1e-7, true)?;
        eq.dxdp_m_per_pa = unflatten(&g);
        eq.cavity_volume_m3 = self.model.cavity.volume(&eq.positions_m);
        eq.min_volume_ratio = ev.min_volume_ratio;
        eq.factor_tag = self.factor_tag;
        Ok(())
    }

    /// Newton iterations from `x` (and `p`) towards equilibrium under `control`.
    /// Returns the converged positions, pressure, iteration count and residual history.
    fn newton(
        &mut self,
        mut x: Vec<[f64; 3]>,
        mut p: f64,
        control: &Control,
        factor_tag: u64,
    ) -> NewtonResult {
        let mut history: Vec<f64> = Vec::new();
        let _ = factor_tag;
        let krylov = self.options.krylov && matches!(control, Control::Pressure(_));
        let mut fresh = !self.options.reuse_factorization || self.factor_tag == 0;
        for it in 0..self.options.max_iterations {
            if let Control::Pressure(pt) = control {
                p = *pt;
            }
            // Modified Newton: refactorize only when the old factor stops converging fast. The
            // bordered volume-controlled step has no merit function to guard a stale tangent, so
            // it always uses the current one.
            if let [.., a, b] = history[..] {
                if b > 0.2 * a {
                    fresh = true;
                }
            }
            if matches!(control, Control::Volume(_)) {
                fresh = true;
            }
            let ev = self
                .evaluate(&x, p, fresh || krylov)
                .map_err(|e| (e, history.clone()))?;
            let g = self.system.volume_gradient(self.model, &x);
            let scale = (p.abs() * norm(&g)).max(self.force_floor);
            let rnorm = norm(&ev.residual);
            let cres = match control {
                Control::Volume(vt) => self.model.cavity.volume(&x) - vt,
                Control::Pressure(_) => 0.0,
            };
            // Volume residual measured as the force it would take to close it.
            let v_scale = self.model.cavity.volume(&x).abs().max(1e-30);
            let rel = (rnorm / scale).max(cres.abs() / v_scale);
            history.push(rel);
            if !rel.is_finite() {
                return Err((
                    FemError::Diverged {
                        reason: "residual is not finite".into(),
                    },
                    history,
                ));
            }
            tracing::trace!(it, rel, fresh, "newton");
            if rel <= self.options.tolerance {
                return Ok((x, p, it));
            }
            // Diverging: after three corrections the residual is still above twice the start.
            // Cutting the load step now is cheaper than exhausting the iterations (each one a
            // factorization).
            if it >= 3 && rel > 2.0 * history[0] {
                return Err((
                    FemError::Diverged {
                        reason: format!(
                            "residual grew from {:.3e} to {rel:.3e} in {it} iterations",
                            history[0]
                        ),
                    },
                    history,
                ));
            }
            let mut stale = !fresh;
            let mut a: Vec<f64> = ev.residual.iter().map(|r| -r).collect();
            if fresh {
                self.factorize().map_err(|e| (e, history.clone()))?;
                fresh = !self.options.reuse_factorization;
                self.solve(&mut a).map_err(|e| (e, history.clone()))?;
            } else if krylov {
                // Inexact Newton: the current tangent solved by CG to 1e-3 (a triangular solve
                // costs ~1/50 of a factorization, so a few CG steps beat refactorizing).
                self.solve_tangent(&mut a, 1e-3, true)
                    .map_err(|e| (e, history.clone()))?;
                stale = false;
            } else {
                self.solve(&mut a).map_err(|e| (e, history.clone()))?;
            }
            let (dx, dp) = match control {
                Control::Pressure(_) => (a, 0.0),
                Control::Volume(_) => {
                    let mut b = g.clone();
                    self.solve(&mut b).map_err(|e| (e, history.clone()))?;
                    let gb = dot(&g, &b);
                    if gb.abs() < 1e-300 {
                        return Err((
                            FemError::Diverged {
                                reason: "bordered system is singular (g . K^-1 g = 0)".into(),
                            },
                            history,
                        ));
                    }
                    let dp = (-cres - dot(&g, &a)) / gb;
                    let dx: Vec<f64> = a.iter().zip(&b).map(|(ai, bi)| ai + dp * bi).collect();
                    (dx, dp)
                }
            };
            // Line search with the inversion guard. Under pressure control the potential is the
            // merit (sufficient decrease along the descent direction), or else the residual norm;
            // under volume control (a saddle point) only inversions shorten the step.
            let slope = dot(&dx, &ev.residual);
            let fresh_step = !stale;
            let mut alpha = 1.0;
            let mut accepted = false;
            for _ in 0..=self.options.max_line_search {
                let xt = axpy(&x, alpha, &dx);
                let pt = p + alpha * dp;
                match self.evaluate(&xt, pt, false) {
                    Ok(evt) => {
                        let ok = match control {
                            Control::Volume(_) => true,
                            Control::Pressure(_) => {
                                evt.energy_j
                                    <= ev.energy_j
                                        + 1e-4 * alpha * slope.min(0.0)
                                        + 1e-13 * ev.energy_j.abs()
                                    || norm(&evt.residual) <= (1.0 - 1e-4 * alpha) * rnorm
                                    || (fresh_step && alpha < 0.2)
                            }
                        };
                        if ok {
                            x = xt;
                            p = pt;
                            accepted = true;
                            break;
                        }
                    }
                    Err(FemError::Inverted { .. }) => {}
                    Err(e) => return Err((e, history)),
                }
                alpha *= 0.5;
            }
            // Round-off floor: a fresh Newton correction this small means the residual is noise.
            let dx_max = dx.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            if accepted
                && !stale
                && alpha == 1.0
                && dx_max <= 1e-12 * self.length_scale
                && rel < 1e-4
            {
                return Ok((x, p, it + 1));
            }
            if !accepted {
                if stale {
                    // A stale factor gave a poor direction: retry with the current tangent.
                    fresh = true;
                    history.pop();
                    continue;
                }
                return Err((FemError::Diverged { reason: "line search found no acceptable step (inverted elements or no decrease)".into() }, history));
            }
        }
        Err((
            FemError::Diverged {
                reason: format!(
                    "no convergence in {} iterations",
                    self.options.max_iterations
                ),
            },
            history,
        ))
    }

    /// Advances a converged state to `target_pressure_pa` with adaptive steps; the returned state
    /// carries `dx/dp`.
    pub fn solve_to_pressure(
        &mut self,
        from: &Equilibrium,
        target_pressure_pa: f64,
    ) -> Result<Equilibrium, FemError> {
        self.continuation(from, target_pressure_pa, false)
    }

    /// Advances a converged state to the cavity volume `target_volume_m3` (pressure is an
    /// unknown, so limit points are passed); the returned state carries `dx/dp`.
    pub fn solve_to_volume(
        &mut self,
        from: &Equilibrium,
        target_volume_m3: f64,
    ) -> Result<Equilibrium, FemError> {
        self.continuation(from, target_volume_m3, true)
    }

    fn continuation(
        &mut self,
        from: &Equilibrium,
        target: f64,
        volume_control: bool,
    ) -> Result<Equilibrium, FemError> {
        let mut cur = from.clone();
        if cur.factor_tag != self.factor_tag || cur.factor_tag == 0 {
            self.finish_state(&mut cur)?;
        }
        let start = if volume_control {
            cur.cavity_volume_m3
        } else {
            cur.pressure_pa
        };
        let total = target - start;
        let min_step = (total.abs() * self.options.min_step_fraction).max(1e-300);
        let mut step = total * self.options.initial_step_fraction.clamp(1e-6, 1.0);
        let mut iterations = 0;
        let mut last_history = Vec::new();
        loop {
            let now = if volume_control {
                cur.cavity_volume_m3
            } else {
                cur.pressure_pa
            };
            let remaining = target - now;
            if remaining.abs() <= 1e-12 * total.abs().max(1e-300) {
                break;
            }
            if step.abs() > remaining.abs() {
                step = remaining;
            }
            // Tangent predictor from the converged state's dx/dp.
            let (dp, control) = if volume_control {
                let gd = dot(
                    &self.system.volume_gradient(self.model, &cur.positions_m),
                    &flatten(&cur.dxdp_m_per_pa),
                );
                let dp = if gd.abs() > 1e-300 { step / gd } else { 0.0 };
                (dp, Control::Volume(now + step))
            } else {
                (step, Control::Pressure(now + step))
            };
            let x0 = axpy(&cur.positions_m, dp, &flatten(&cur.dxdp_m_per_pa));
            let x0 = if x0.iter().all(|p| p.iter().all(|v| v.is_finite())) {
                x0
            } else {
                cur.positions_m.clone()
            };
            match self.newton(x0, cur.pressure_pa + dp, &control, cur.factor_tag) {
                Ok((x, p, its)) => {
                    iterations += its;
                    self.counters.newton_iterations += its;
                    let mut next = Equilibrium {
                        positions_m: x,
                        pressure_pa: p,
                        cavity_volume_m3: 0.0,
                        dxdp_m_per_pa: Vec::new(),
                        newton_iterations: 0,
                        min_volume_ratio: 0.0,
                        factor_tag: 0,
                    };
                    self.finish_state(&mut next)?;
                    if volume_control {
                        // Land exactly on the target volume's bookkeeping despite round-off.
                        if let Control::Volume(vt) = control {
                            if (next.cavity_volume_m3 - vt).abs() <= 1e-7 * vt.abs() {
                                next.cavity_volume_m3 = vt;
                            }
                        }
                    }
                    cur = next;
                    if its <= 6 {
                        step *= 1.5;
                    }
                }
                Err((e, history)) => {
                    self.counters.newton_iterations += history.len();
                    iterations += history.len();
                    self.counters.step_cuts += 1;
                    tracing::debug!(step, error = %e, ?history, "load step cut");
                    last_history = history;
                    step *= 0.5;
                    if step.abs() < min_step {
                        return Err(FemError::NoConvergence {
                            control: if volume_control {
                                "cavity volume m^3"
                            } else {
                                "pressure Pa"
                            },
                            reached: now,
                            target,
                            residual_history: last_history,
                            cause: e.to_string(),
                        });
                    }
                }
            }
        }
        let _ = last_history;
        cur.newton_iterations = iterations;
        if volume_control {
            cur.cavity_volume_m3 = target;
        } else {
            cur.pressure_pa = target;
        }
        Ok(cur)
    }

    /// A pressure sweep through the increasing `pressures_pa` (first may be 0); `on_level` is
    /// called after each level (for progress reporting).
    pub fn sweep(
        &mut self,
        pressures_pa: &[f64],
        mut on_level: impl FnMut(usize, &Equilibrium),
    ) -> Result<Vec<Equilibrium>, FemError> {
        let mut out = Vec::with_capacity(pressures_pa.len());
        let mut cur = self.rest_state();
        self.finish_state(&mut cur)?;
        for (k, &p) in pressures_pa.iter().enumerate() {
            let next = if p == cur.pressure_pa {
                cur.clone()
            } else {
                self.solve_to_pressure(&cur, p).map_err(|e| match e {
                    FemError::NoConvergence {
                        control,
                        reached,
                        target,
                        residual_history,
                        cause,
                    } => FemError::LevelFailed {
                        level: k,
                        pressure_pa: p,
                        inner: Box::new(FemError::NoConvergence {
                            control,
                            reached,
                            target,
                            residual_history,
                            cause,
                        }),
                    },
                    other => FemError::LevelFailed {
                        level: k,
                        pressure_pa: p,
                        inner: Box::new(other),
                    },
                })?
            };
            on_level(k, &next);
            out.push(next.clone());
            cur = next;
        }
        Ok(out)
    }
}
