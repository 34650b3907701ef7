//! The pressure Poisson solve: multigrid-preconditioned CG (ours), Jacobi-preconditioned CG (the
//! simple reference kept for cross-checks), and a fixed number of Gauss-Seidel sweeps (the classic
//! real-time stable-fluids baseline of the paper's class).
//!
//! Unknowns are `q = p dt / (rho h)` on fluid cells; the system is `A q = b` with `A` the 7-point
//! negative Laplacian in cell units (diagonal = number of fluid or open neighbours) and `b = -h div u*`,
//! so the residual of a row *is* `-h div u` of the projected velocity there: stopping on
//! `max |r| <= tol * U` stops on `max |div u| h / U <= tol`.

use rayon::prelude::*;

use super::multigrid::{run, Level, Multigrid, SpanOp};
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
    /// A fixed number of Gauss-Seidel sweeps from zero each step (the paper-class baseline).
    GaussSeidel {
        /// Sweeps per step.
        sweeps: usize,
    },
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
    /// Unknowns (warm start between steps).
    pub q: Vec<f64>,
    pub b: Vec<f64>,
    r: Vec<f64>,
    z: Vec<f64>,
    p: Vec<f64>,
    ap: Vec<f64>,
    /// Dense (padded) vectors of the multigrid-PCG: the warm start in f64, and the increment, search
    /// direction and its product in f32 (the residual and the preconditioned residual live in level
    /// 0's `b` and `x`).
    dq: Vec<f64>,
    dd: Vec<f32>,
    dp: Vec<f32>,
    dap: Vec<f32>,
    /// Rows above which the matrix-vector product runs on rayon.
    pub parallel_rows: usize,
    /// Full face indices of each row's faces (lower x, upper x, lower y, ...), for the divergence;
    /// rebuilt by the solver when `faces_stale`.
    pub faces_of_row: Vec<[u32; 6]>,
    pub faces_stale: bool,
}

const CHUNK: usize = 2048;

/// Multigrid levels run their kernels on rayon from this many times `parallel_rows` fluid cells.
/// Measured on the shared 2-core machine at 34.6k rows (0.6 mm cavity): two halves per kernel (one
/// fork-join each, ~20 per CG iteration, plus the extra pass of the out-of-place smoother) were
/// 1.4-1.8x slower than one thread, so only much larger grids split.
const MG_PARALLEL_FACTOR: usize = 4;

fn matvec(l: &Level, x: &[f64], y: &mut [f64], parallel: bool) {
    let n_rows = x.len();
    let row_op = |row: usize, x: &[f64]| {
        let nb = l.nbr[row];
        let mut s = l.diag[row] as f64 * x[row];
        for &n in &nb {
            if (n as usize) < n_rows {
                s -= x[n as usize];
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
    /// Resizes the vectors after the level-0 rows changed, keeping nothing of the old warm start.
    pub fn resize(&mut self) {
        let n = self.mg.levels[0].rows();
        for v in [
            &mut self.q,
            &mut self.b,
            &mut self.r,
            &mut self.z,
            &mut self.p,
            &mut self.ap,
        ] {
            v.clear();
            v.resize(n, 0.0);
        }
        self.regions.build(&self.mg.levels[0]);
        self.faces_stale = true;
        let len = self.mg.levels[0].x.len();
        self.dq.clear();
        self.dq.resize(len, 0.0);
        for v in [&mut self.dd, &mut self.dp, &mut self.dap] {
            v.clear();
            v.resize(len, 0.0);
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

    /// Solves `A q = b` from the current `q` until `max |r| <= tol_abs` or `max_iterations` (the
    /// recurrence residual: the caller measures the true one).
    pub fn solve(
        &mut self,
        method: ProjectionMethod,
        tol_abs: f64,
        max_iterations: usize,
    ) -> SolveOutcome {
        let n = self.q.len();
        if n == 0 {
            return SolveOutcome {
                iterations: 0,
                converged: true,
            };
        }
        match method {
            ProjectionMethod::GaussSeidel { sweeps } => return self.gauss_seidel(sweeps, tol_abs),
            ProjectionMethod::MultigridPcg => return self.solve_multigrid(tol_abs, max_iterations),
            ProjectionMethod::JacobiPcg => {}
        }
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

    /// Multigrid-preconditioned CG on the dense operator, for the increment `d` of the warm start
    /// `q`: the residual of the warm start is formed in f64, the increment is solved in f32 (dot
    /// products accumulated in f64), and `q += d` in f64, so the f32 rounding only ever applies to
    /// the (small) correction.
    fn solve_multigrid(&mut self, tol_abs: f64, max_iterations: usize) -> SolveOutcome {
        // Closed regions: pressure is defined up to a constant; keeping it mean-free keeps it small.
        self.regions.remove_closed_means(&mut self.q);
        let PressureSolver {
            mg,
            regions,
            q,
            b,
            dq,
            dd,
            dp,
            dap,
            parallel_rows,
            ..
        } = self;
        let periodic = mg.levels[0].periodic.iter().any(|&p| p);
        for l in &mut mg.levels[..mg.used] {
            l.parallel = l.fluid >= parallel_rows.saturating_mul(MG_PARALLEL_FACTOR);
        }
        {
            let l0 = &mut mg.levels[0];
            for (&qv, &p) in q.iter().zip(&l0.pad_of_row) {
                dq[p as usize] = qv;
            }
            if periodic {
                l0.halo(dq);
            }
            let (sy, sz) = (l0.sy, l0.sz);
            for (&bv, &p) in b.iter().zip(&l0.pad_of_row) {
                let p = p as usize;
                let nsum =
                    (dq[p - 1] + dq[p + 1]) + (dq[p - sy] + dq[p + sy]) + (dq[p - sz] + dq[p + sz]);
                l0.b[p] = (bv - (l0.ddiag[p] as f64 * dq[p] - nsum)) as f32;
            }
            regions.remove_closed_means_dense(&mut l0.b, &l0.pad_of_row);
        }
        let tol = tol_abs as f32;
        let mut outcome = SolveOutcome {
            iterations: 0,
            converged: false,
        };
        let l0max = {
            let l0 = &mg.levels[0];
            l0.pad_of_row
                .iter()
                .fold(0.0f32, |m, &p| m.max(l0.b[p as usize].abs()))
        };
        if l0max <= tol {
            outcome.converged = true;
            return outcome;
        }
        for &[s, e] in &mg.levels[0].spans {
            dd[s as usize..e as usize].fill(0.0);
        }
        let precondition = |mg: &mut Multigrid, regions: &mut Regions| {
            mg.vcycle();
            let l0 = &mut mg.levels[0];
            regions.remove_closed_means_dense(&mut l0.x, &l0.pad_of_row);
        };
        precondition(mg, regions);
        let l0 = &mg.levels[0];
        dp.copy_from_slice(&l0.x);
        let mut rz = run(l0, SpanOp::Dot { a: &l0.b, b: &l0.x });
        for it in 1..=max_iterations {
            outcome.iterations = it;
            let l0 = &mut mg.levels[0];
            if periodic {
                l0.halo(dp);
            }
            l0.apply(dp, dap);
            let pap = run(l0, SpanOp::Dot { a: dp, b: dap });
            if pap.is_nan() || pap <= 0.0 || !rz.is_finite() {
                break;
            }
            let alpha = (rz / pap) as f32;
            let mut r = std::mem::take(&mut l0.b);
            let mut rmax = run(
                l0,
                SpanOp::Update {
                    alpha,
                    p: dp,
                    ap: dap,
                    d: dd,
                    r: &mut r,
                },
            ) as f32;
            l0.b = r;
            if regions.any_closed() {
                // In f32 the rounding of `r -= alpha A p` accumulates a region mean no pressure
                // can remove, on which CG would stagnate: keep r in the range of A.
                regions.remove_closed_means_dense(&mut l0.b, &l0.pad_of_row);
                rmax = l0
                    .pad_of_row
                    .iter()
                    .fold(0.0f32, |m, &p| m.max(l0.b[p as usize].abs()));
            }
            if rmax <= tol {
                outcome.converged = true;
                break;
            }
            precondition(mg, regions);
            let l0 = &mg.levels[0];
            let rz_new = run(l0, SpanOp::Dot { a: &l0.b, b: &l0.x });
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
        for (qv, &p) in q.iter_mut().zip(&mg.levels[0].pad_of_row) {
            *qv += dd[p as usize] as f64;
        }
        outcome
    }

    /// The baseline: `sweeps` lexicographic Gauss-Seidel sweeps from q = 0.
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
                for &nb in &l.nbr[row] {
                    if (nb as usize) < n_rows {
                        s += self.q[nb as usize];
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
