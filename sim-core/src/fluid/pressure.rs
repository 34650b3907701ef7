//! The pressure Poisson solve: multigrid-preconditioned CG (ours), Jacobi-preconditioned CG (the
//! simple reference kept for cross-checks), and a fixed number of Gauss-Seidel sweeps (the classic
//! real-time stable-fluids baseline of the paper's class).
//!
//! Unknowns are `q = p dt / (rho h)` on fluid cells; the system is `A q = b` with `A` the 7-point
//! negative Laplacian in cell units (diagonal = number of fluid or open neighbours) and `b = -h div u*`,
//! so the residual of a row *is* `-h div u` of the projected velocity there: stopping on
//! `max |r| <= tol * U` stops on `max |div u| h / U <= tol`.

use rayon::prelude::*;

use super::multigrid::{Level, Multigrid};
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
    /// Rows above which the matrix-vector product runs on rayon.
    pub parallel_rows: usize,
}

const CHUNK: usize = 2048;

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
    }

    fn precondition(&mut self, method: ProjectionMethod) {
        match method {
            ProjectionMethod::MultigridPcg => {
                let l0 = &mut self.mg.levels[0];
                for (bv, &rv) in l0.b.iter_mut().zip(&self.r) {
                    *bv = rv as f32;
                }
                self.mg.vcycle();
                let l0 = &self.mg.levels[0];
                for (zv, &xv) in self.z.iter_mut().zip(&l0.x) {
                    *zv = xv as f64;
                }
            }
            _ => {
                let l0 = &self.mg.levels[0];
                for ((zv, &rv), &d) in self.z.iter_mut().zip(&self.r).zip(&l0.inv_diag) {
                    *zv = rv * d as f64;
                }
            }
        }
        self.regions.remove_closed_means(&mut self.z);
    }

    /// Solves `A q = b` from the current `q` until `max |r| <= tol_abs` or `max_iterations`.
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
        if let ProjectionMethod::GaussSeidel { sweeps } = method {
            return self.gauss_seidel(sweeps, tol_abs);
        }
        let parallel = n >= self.parallel_rows;
        self.mg.parallel_rows = self.parallel_rows;
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
        self.precondition(method);
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
            self.precondition(method);
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
