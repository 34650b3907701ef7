//! The pressure Poisson solve: multigrid-preconditioned CG (ours), Jacobi-preconditioned CG (the
//! simple reference kept for cross-checks), and a fixed number of Gauss-Seidel sweeps (the classic
//! real-time stable-fluids baseline of the paper's class).
//!
//! Unknowns are `q = p dt / (rho h)` on fluid cells; the system is `A q = b` with `A` the 7-point
//! negative Laplacian in cell units (diagonal = number of fluid or open neighbours) and `b = -h div u*`,
//! so the residual of a row *is* `-h div u` of the projected velocity there: stopping on
//! `max |r| <= tol * U` stops on `max |div u| h / U <= tol`.
//!
//! The solver's interface is dense: `b` and `q` live on level 0's padded box (zero off the fluid
//! cells), where the velocity update and the divergence are contiguous row loops. The reference
//! solvers work on compressed rows and are wrapped by a gather and a scatter.

use std::mem::take;

use rayon::prelude::*;

use super::multigrid::{for_spans, max_abs_spans, run, Level, Multigrid, SpanOp};
use super::regions::Regions;
use super::topology::NONE;
use serde::{Deserialize, Serialize};

/// How the pressure is solved.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", tag = "method")]
pub enum ProjectionMethod {
    /// CG preconditioned by a geometric multigrid V-cycle, to the divergence tolerance.
    MultigridPcg,
    /// CG preconditioned by the diagonal (Jacobi), to the divergence tolerance: the reference.
    JacobiPcg,
    /// A fixed number of Gauss-Seidel sweeps from zero each step (the paper-class baseline as
    /// the paper ran it: cold start, lexicographic order, one thread, compressed rows).
    GaussSeidel {
        /// Sweeps per step.
        sweeps: usize,
    },
    /// A fixed number of red-black Gauss-Seidel sweeps on our machinery: warm-started from the last
    /// pressure like ours, on the dense f32 level-0 kernels of the multigrid smoother (SIMD, halves
    /// split on the fork-join from the same size as ours). The like-for-like baseline.
    RedBlackGaussSeidel {
        /// Sweeps (red then black) per step.
        sweeps: usize,
    },
}

impl ProjectionMethod {
    /// Whether the method runs a fixed number of sweeps instead of solving to the tolerance.
    pub fn is_fixed_sweeps(&self) -> bool {
        matches!(
            self,
            Self::GaussSeidel { .. } | Self::RedBlackGaussSeidel { .. }
        )
    }
}

/// Outcome of one pressure solve.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct SolveOutcome {
    pub iterations: usize,
    pub converged: bool,
}

/// The pressure solver's state and scratch vectors (allocated when the topology changes).
#[derive(Default, Debug)]
pub(crate) struct PressureSolver {
    pub mg: Multigrid,
    pub regions: Regions,
    /// Dense (padded) right-hand side `-h div u` and unknowns `q` (the warm start on entry to
    /// [`PressureSolver::solve`], the solution on return; zero off the fluid cells).
    pub bd: Vec<f64>,
    pub dq: Vec<f64>,
    /// Dense (padded) boundary-flux weights of the fluid cells (`FluidGrid::boundary_flux_weights_m2`;
    /// sized with `bd` when the first weight is read).
    pub wd: Vec<f64>,
    /// Dense (padded) share weights of the fluid cells (`FluidGrid::shared_flux_weights_m2`;
    /// sized with `bd` when the first weight is read).
    pub sd: Vec<f64>,
    /// Compressed rows of the reference solvers.
    q: Vec<f64>,
    b: Vec<f64>,
    r: Vec<f64>,
    z: Vec<f64>,
    p: Vec<f64>,
    ap: Vec<f64>,
    /// Dense vectors of the multigrid-PCG in f32: the increment of `dq`, the search direction and
    /// its product (the residual and the preconditioned residual live in level 0's `b` and `x`).
    dd: Vec<f32>,
    dp: Vec<f32>,
    dap: Vec<f32>,
    /// Rows above which the reference solver's matrix-vector product runs on rayon.
    parallel_rows: usize,
    /// Tests only: the multigrid CG's update leaves the V-cycle's first half-sweep to the V-cycle
    /// whenever a region is closed (as before the fusion), the reference a test compares the
    /// fused update with, bit for bit.
    #[cfg(test)]
    pub plain_update: bool,
}

const CHUNK: usize = 2048;

/// Multigrid levels split their kernels in two halves (on [`crate::fork_join`]) from `parallel_rows /
/// SPLIT_DIVISOR` fluid cells: 2,000 by default. A hand-over is a cache-line round trip there, so
/// it pays from a few thousand cells (measured on the 2-core machine: the 1.2 mm cavity's level 0,
/// 3.8k cells, gains ~25 % of the projection, the 0.6 mm cavity's levels 0 and 1 ~25 %; rayon's
/// fork-join lost at every size).
pub(crate) const SPLIT_DIVISOR: usize = 12;

fn matvec(l: &Level, x: &[f64], y: &mut [f64], parallel: bool) {
    let n_rows = x.len();
    let row_op = |row: usize, x: &[f64]| {
        let (nb, nw) = (l.nbr[row], l.nbr_w[row]);
        let mut s = l.diag[row] as f64 * x[row];
        for (&n, &w) in nb.iter().zip(&nw) {
            if (n as usize) < n_rows {
                s -= w as f64 * x[n as usize];
            }
        }
        s
    };
    if parallel {
        y.par_chunks_mut(CHUNK).enumerate().for_each(|(c, ys)| {
            for (o, yv) in ys.iter_mut().enumerate() {
                *yv = row_op(c * CHUNK + o, x);
            }
        });
    } else {
        for (row, yv) in y.iter_mut().enumerate() {
            *yv = row_op(row, x);
        }
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

fn max_abs(a: &[f64]) -> f64 {
    a.iter().fold(0.0f64, |m, &x| m.max(x.abs()))
}

impl PressureSolver {
    /// Resizes the vectors after the level-0 rows changed, keeping nothing of the old warm start
    /// (the compressed rows and their vectors, for the reference solvers, are built when one runs).
    pub fn resize(&mut self) {
        self.regions.build(&self.mg.levels[0]);
        let l0 = &self.mg.levels[0];
        let len = l0.x.len();
        // Zero outside level 0's spans: only the previous spans need clearing. `dd` and `dap` are
        // written over the spans before they are read, and read only there: they keep whatever
        // the old spans left.
        match &l0.old_spans {
            Some(old) if self.dq.len() == len => {
                for &[s, e] in old {
                    let r = s as usize..e as usize;
                    self.dq[r.clone()].fill(0.0);
                    self.bd[r.clone()].fill(0.0);
                    for v in [&mut self.wd, &mut self.sd] {
                        if !v.is_empty() {
                            v[r.clone()].fill(0.0);
                        }
                    }
                    self.dp[r].fill(0.0);
                }
            }
            _ => {
                for v in [&mut self.dq, &mut self.bd] {
                    v.clear();
                    v.resize(len, 0.0);
                }
                for v in [&mut self.wd, &mut self.sd] {
                    if !v.is_empty() {
                        v.clear();
                        v.resize(len, 0.0);
                    }
                }
                for v in [&mut self.dd, &mut self.dp, &mut self.dap] {
                    v.clear();
                    v.resize(len, 0.0);
                }
            }
        }
    }

    /// Sets the threshold of the reference solver's rayon products and marks the levels that split
    /// their kernels in two halves (from `rows / SPLIT_DIVISOR` fluid cells).
    pub fn set_parallel_rows(&mut self, rows: usize) {
        self.parallel_rows = rows;
        let split = (rows / SPLIT_DIVISOR).max(1);
        for l in &mut self.mg.levels[..self.mg.used] {
            l.parallel = l.fluid >= split;
        }
    }

    /// Jacobi preconditioner of the reference solver.
    fn precondition(&mut self) {
        let l0 = &self.mg.levels[0];
        for ((zv, &rv), &d) in self.z.iter_mut().zip(&self.r).zip(&l0.inv_diag) {
            *zv = rv * d as f64;
        }
        self.regions.remove_closed_means(&mut self.z);
    }

    /// Solves `A q = b` (dense `dq`, `bd`) from the current `dq` until `max |r| <= tol_abs` or
    /// `max_iterations` (the recurrence residual: the caller measures the true one).
    pub fn solve(
        &mut self,
        method: ProjectionMethod,
        tol_abs: f64,
        max_iterations: usize,
    ) -> SolveOutcome {
        let n = self.mg.levels[0].rows();
        if n == 0 {
            return SolveOutcome {
                iterations: 0,
                converged: true,
            };
        }
        match method {
            ProjectionMethod::MultigridPcg => return self.solve_multigrid(tol_abs, max_iterations),
            ProjectionMethod::RedBlackGaussSeidel { sweeps } => {
                return self.red_black_gauss_seidel(sweeps, tol_abs)
            }
            _ => {}
        }
        // The reference solvers work on the compressed rows, built when one first runs after a
        // relabelling.
        self.mg.levels[0].build_compressed_rows();
        for v in [
            &mut self.q,
            &mut self.b,
            &mut self.r,
            &mut self.z,
            &mut self.p,
            &mut self.ap,
        ] {
            v.resize(n, 0.0);
        }
        let pad_of_row = &self.mg.levels[0].pad_of_row;
        for ((q, b), &p) in self.q.iter_mut().zip(&mut self.b).zip(pad_of_row) {
            (*q, *b) = (self.dq[p as usize], self.bd[p as usize]);
        }
        let out = match method {
            ProjectionMethod::GaussSeidel { sweeps } => self.gauss_seidel(sweeps, tol_abs),
            _ => self.jacobi_pcg(tol_abs, max_iterations),
        };
        for (&q, &p) in self.q.iter().zip(&self.mg.levels[0].pad_of_row) {
            self.dq[p as usize] = q;
        }
        out
    }

    /// The reference: Jacobi-preconditioned CG on the compressed rows.
    fn jacobi_pcg(&mut self, tol_abs: f64, max_iterations: usize) -> SolveOutcome {
        let n = self.q.len();
        let parallel = n >= self.parallel_rows;
        self.regions.remove_closed_means(&mut self.q);
        matvec(&self.mg.levels[0], &self.q, &mut self.r, parallel);
        for (r, &b) in self.r.iter_mut().zip(&self.b) {
            *r = b - *r;
        }
        self.regions.remove_closed_means(&mut self.r);
        if max_abs(&self.r) <= tol_abs {
            return SolveOutcome {
                iterations: 0,
                converged: true,
            };
        }
        self.precondition();
        self.p.copy_from_slice(&self.z);
        let mut rz = dot(&self.r, &self.z);
        for it in 1..=max_iterations {
            matvec(&self.mg.levels[0], &self.p, &mut self.ap, parallel);
            let pap = dot(&self.p, &self.ap);
            if pap.is_nan() || pap <= 0.0 || !rz.is_finite() {
                return SolveOutcome {
                    iterations: it,
                    converged: false,
                };
            }
            let alpha = rz / pap;
            for ((q, r), (&p, &ap)) in self
                .q
                .iter_mut()
                .zip(self.r.iter_mut())
                .zip(self.p.iter().zip(&self.ap))
            {
                *q += alpha * p;
                *r -= alpha * ap;
            }
            if max_abs(&self.r) <= tol_abs {
                return SolveOutcome {
                    iterations: it,
                    converged: true,
                };
            }
            self.precondition();
            let rz_new = dot(&self.r, &self.z);
            let beta = rz_new / rz;
            rz = rz_new;
            for (p, &z) in self.p.iter_mut().zip(&self.z) {
                *p = z + beta * *p;
            }
        }
        SolveOutcome {
            iterations: max_iterations,
            converged: false,
        }
    }

    /// The residual `b - A q` of the warm start `q = dq` into level 0's `b` (in f64, rounded once
    /// to f32; closed regions mean-free), and its largest magnitude.
    fn warm_start_residual(&mut self) -> f32 {
        // Closed regions: pressure is defined up to a constant; keeping it mean-free keeps it small.
        self.regions.remove_closed_means_dense(&mut self.dq);
        let PressureSolver {
            mg,
            regions,
            bd,
            dq,
            ..
        } = self;
        let periodic = mg.levels[0].periodic.iter().any(|&p| p);
        {
            let l0 = &mut mg.levels[0];
            if periodic {
                l0.halo(dq);
            }
            // The warm start's residual in f64, rounded once to f32, and its largest value.
            let (sy, sz) = (l0.sy, l0.sz);
            let mut r0 = take(&mut l0.b);
            let wt = l0.couplings();
            let l0max = for_spans(l0, &mut r0, |spans, out, off| {
                let mut m = 0.0f32;
                for &[s, e] in spans {
                    let (s, e) = (s as usize, e as usize);
                    let n = e - s;
                    let (xm, xp) = (&dq[s - 1..e - 1], &dq[s + 1..e + 1]);
                    let (ym, yp) = (&dq[s - sy..e - sy], &dq[s + sy..e + sy]);
                    let (zm, zp) = (&dq[s - sz..e - sz], &dq[s + sz..e + sz]);
                    let (q0, b, d, mk) = (&dq[s..e], &bd[s..e], &l0.ddiag[s..e], &l0.mask[s..e]);
                    let out = &mut out[s - off..e - off];
                    let Some([w0, w1, w2]) = wt else {
                        for i in 0..n {
                            let nsum = (xm[i] + xp[i]) + (ym[i] + yp[i]) + (zm[i] + zp[i]);
                            out[i] = mk[i] * (b[i] - (d[i] as f64 * q0[i] - nsum)) as f32;
                            // Not f32::max: a plain comparison vectorizes (NaN is skipped by both).
                            let a = out[i].abs();
                            m = if a > m { a } else { m };
                        }
                        continue;
                    };
                    // Cut cells: the neighbours weighted by the couplings of their faces.
                    let (wxm, wxp) = (&w0[s - 1..e - 1], &w0[s..e]);
                    let (wym, wyp) = (&w1[s - sy..e - sy], &w1[s..e]);
                    let (wzm, wzp) = (&w2[s - sz..e - sz], &w2[s..e]);
                    let w = |w: &[f32], i: usize| w[i] as f64;
                    for i in 0..n {
                        let nsum = (w(wxm, i) * xm[i] + w(wxp, i) * xp[i])
                            + (w(wym, i) * ym[i] + w(wyp, i) * yp[i])
                            + (w(wzm, i) * zm[i] + w(wzp, i) * zp[i]);
                        out[i] = mk[i] * (b[i] - (d[i] as f64 * q0[i] - nsum)) as f32;
                        let a = out[i].abs();
                        m = if a > m { a } else { m };
                    }
                }
                m as f64
            }) as f32;
            l0.b = r0;
            if regions.any_closed() {
                regions.remove_closed_means_dense(&mut l0.b);
                max_abs_spans(l0, &l0.b) as f32
            } else {
                l0max
            }
        }
    }

    /// Multigrid-preconditioned CG on the dense operator, for the increment `d` of the warm start
    /// `q`: the residual of the warm start is formed in f64, the increment is solved in f32 (dot
    /// products accumulated in f64), and `q += d` in f64, so the f32 rounding only ever applies to
    /// the (small) correction.
    fn solve_multigrid(&mut self, tol_abs: f64, max_iterations: usize) -> SolveOutcome {
        #[cfg(test)]
        let plain_update = self.plain_update;
        #[cfg(not(test))]
        let plain_update = false;
        let l0max = self.warm_start_residual();
        let PressureSolver {
            mg,
            regions,
            dq,
            dd,
            dp,
            dap,
            ..
        } = self;
        let periodic = mg.levels[0].periodic.iter().any(|&p| p);
        let tol = tol_abs as f32;
        let mut outcome = SolveOutcome {
            iterations: 0,
            converged: false,
        };
        if l0max <= tol {
            outcome.converged = true;
            return outcome;
        }
        for_spans(&mg.levels[0], dd, |spans, out, off| {
            for &[s, e] in spans {
                out[s as usize - off..e as usize - off].fill(0.0);
            }
            0.0
        });
        // `z = M r`, and `r.z` from the V-cycle's last pass. Removing a closed region's mean m
        // from z leaves `r.z` as it is: r is mean-free in every closed region (its mean is
        // removed before each preconditioning), so the change `-m sum r` vanishes.
        let precondition = |mg: &mut Multigrid, regions: &mut Regions, initialised: bool| {
            let rz = mg.vcycle(initialised);
            let l0 = &mut mg.levels[0];
            if regions.any_closed() {
                regions.remove_closed_means_dense(&mut l0.x);
            }
            rz
        };
        let mut rz = precondition(mg, regions, false);
        // `dp` is zero off the spans (cleared at each relabelling, written only on them).
        let l0 = &mg.levels[0];
        for_spans(l0, dp, |spans, out, off| {
            for &[s, e] in spans {
                out[s as usize - off..e as usize - off]
                    .copy_from_slice(&l0.x[s as usize..e as usize]);
            }
            0.0
        });
        for it in 1..=max_iterations {
            outcome.iterations = it;
            let l0 = &mut mg.levels[0];
            if periodic {
                l0.halo(dp);
            }
            let pap = run(
                l0,
                SpanOp::ApplyDot {
                    y: dap,
                    v: dp,
                    diag: &l0.ddiag,
                    mask: &l0.mask,
                },
            );
            if pap.is_nan() || pap <= 0.0 || !rz.is_finite() {
                break;
            }
            let alpha = (rz / pap) as f32;
            // The V-cycle's first half-sweep on the new residual runs in the same pass (and its
            // maximum), except when every cell is in a closed region: closed regions are often a
            // few stray cells beside the open cavity, whose values are fixed up below.
            let plain = plain_update && regions.any_closed();
            let fused = !(regions.all_closed() || plain);
            let mut r = std::mem::take(&mut l0.b);
            let mut x = std::mem::take(&mut l0.x);
            let mut rmax = run(
                l0,
                SpanOp::Update {
                    alpha,
                    p: dp,
                    ap: dap,
                    d: dd,
                    r: &mut r,
                    init: fused.then_some((&mut x[..], &l0.inv[0][..])),
                },
            ) as f32;
            if regions.any_closed() {
                // In f32 the rounding of `r -= alpha A p` accumulates a region mean no pressure
                // can remove, on which CG would stagnate: keep r in the range of A.
                let closed_before = regions.closed_max_abs_dense(&r);
                regions.remove_closed_means_dense(&mut r);
                let closed_after = regions.closed_max_abs as f32;
                if fused {
                    regions.closed_scale_dense(&mut x, &r, &l0.inv[0]);
                }
                // The Update's maximum covers every cell before the removal: when a closed cell's
                // old value did not reach it, it is the open cells' maximum (which the removal
                // left as it was); else the open cells are scanned again.
                rmax = if regions.all_closed() {
                    closed_after
                } else if rmax > closed_before {
                    rmax.max(closed_after)
                } else {
                    max_abs_spans(l0, &r) as f32
                };
            }
            (l0.b, l0.x) = (r, x);
            if rmax <= tol {
                outcome.converged = true;
                break;
            }
            let rz_new = precondition(mg, regions, fused);
            let l0 = &mg.levels[0];
            let beta = (rz_new / rz) as f32;
            rz = rz_new;
            run(
                l0,
                SpanOp::Xpby {
                    p: dp,
                    z: &l0.x,
                    beta,
                },
            );
        }
        let dd = &*dd;
        for_spans(&mg.levels[0], dq, |spans, out, off| {
            for &[s, e] in spans {
                let (s, e) = (s as usize, e as usize);
                for (q, &d) in out[s - off..e - off].iter_mut().zip(&dd[s..e]) {
                    *q += d as f64;
                }
            }
            0.0
        });
        outcome
    }

    /// The like-for-like baseline: `sweeps` red-black sweeps for the increment of the warm start, on
    /// level 0's dense f32 smoother (the same kernels and thread split as the multigrid's).
    fn red_black_gauss_seidel(&mut self, sweeps: usize, tol_abs: f64) -> SolveOutcome {
        let l0max = self.warm_start_residual();
        if l0max <= tol_abs as f32 {
            return SolveOutcome {
                iterations: 0,
                converged: true,
            };
        }
        let l0 = &mut self.mg.levels[0];
        for sweep in 0..sweeps {
            l0.half_sweep(0, sweep == 0, false);
            l0.half_sweep(1, false, false);
        }
        let l0 = &self.mg.levels[0];
        let x = &l0.x;
        for_spans(l0, &mut self.dq, |spans, out, off| {
            for &[s, e] in spans {
                let (s, e) = (s as usize, e as usize);
                for (q, &d) in out[s - off..e - off].iter_mut().zip(&x[s..e]) {
                    *q += d as f64;
                }
            }
            0.0
        });
        // Converged or not is measured by the caller on the projected velocity.
        SolveOutcome {
            iterations: sweeps,
            converged: false,
        }
    }

    /// The baseline: `sweeps` lexicographic Gauss-Seidel sweeps from q = 0 (on the compressed rows).
    fn gauss_seidel(&mut self, sweeps: usize, tol_abs: f64) -> SolveOutcome {
        self.regions.remove_closed_means(&mut self.b);
        self.q.fill(0.0);
        let l = &self.mg.levels[0];
        let n_rows = self.q.len();
        for _ in 0..sweeps {
            // Lexicographic (cell) order, as in the classic solver; rows are numbered by colour.
            for &row in &l.row_of_cell {
                if row == NONE {
                    continue;
                }
                let row = row as usize;
                let mut s = self.b[row];
                for (&nb, &w) in l.nbr[row].iter().zip(&l.nbr_w[row]) {
                    if (nb as usize) < n_rows {
                        s += w as f64 * self.q[nb as usize];
                    }
                }
                self.q[row] = s * l.inv_diag[row] as f64;
            }
        }
        self.regions.remove_closed_means(&mut self.q);
        matvec(l, &self.q, &mut self.r, false);
        for (r, &b) in self.r.iter_mut().zip(&self.b) {
            *r = b - *r;
        }
        SolveOutcome {
            iterations: sweeps,
            converged: max_abs(&self.r) <= tol_abs,
        }
    }
}
