//! Geometric multigrid V-cycle on voxelized (irregular) domains, used as the CG preconditioner.
//!
//! Each level is a 7-point Poisson operator on the "fluid" cells of a label grid (0 = solid wall,
//! Neumann; 1 = fluid, unknown; 2 = open, Dirichlet p = 0). A coarse cell is open if any child is
//! open, else fluid if any child is fluid, else solid. Restriction sums the children's residuals
//! (times a scale), prolongation injects the coarse value into every child (its transpose). Level 0
//! couples neighbours with weight 1; a coarser level carries the Galerkin operator of that
//! prolongation (`Level::galerkin`): per-face couplings that count the fine faces joining two
//! coarse cells, so a thin or partly filled region is not coupled like a full one (on the scene's
//! thin cavity this halved the MG-PCG iterations: 17.0 to 8.1 at 0.6 mm).
//! Smoothing is red-black Gauss-Seidel, red then black before and black then red after the coarse
//! correction, so the V-cycle is a symmetric operator and CG preconditioned by it stays valid.
//!
//! The levels are stored matrix-free on the dense box padded by one ghost layer per side: vectors
//! hold zero on every non-fluid cell (solid walls contribute nothing, open cells are p = 0), the
//! labels (and the couplings) only decide the diagonal, so every kernel is a branch-free loop over contiguous spans of
//! cells with fixed strides that the compiler vectorises. Periodic axes fill their ghost layers from
//! the opposite side before each stencil application (`halo`). A colour's half-sweep reads only the
//! other colour, so it computes a chunk into a stack buffer and adds it back (exact Gauss-Seidel;
//! where an odd periodic axis or a one-cell periodic axis makes a cell its own colour's neighbour it
//! is a Jacobi update within the colour, still symmetric, and the half-sweeps stay convergent).
//!
//! Level 0 can also build the compressed rows (fluid cells numbered in order, with neighbour lists)
//! that the reference solvers and the baseline use, when one of them runs.
//!
//! - `level.rs`: a level's data and its build from the labels (dense operator, spans, the halves);
//! - `coarse.rs`: the next coarser level (labels, Galerkin couplings);
//! - `kernels.rs`: the vector kernels over a level's spans ([`SpanOp`]), one copy compiled for
//!   AVX2 + FMA and one for the baseline (`crate::simd`), in two halves on two threads;
//! - `smoother.rs`: Gauss-Seidel half-sweeps and the residual on a level;
//! - `transfer.rs`: restriction and prolongation between two levels.

mod coarse;
mod kernels;
mod level;
mod smoother;
#[cfg(test)]
mod tests;
mod transfer;

pub(crate) use kernels::{for_spans, max_abs_from, max_abs_spans, run, Real, SpanOp};
use level::DenseDiag;
pub(crate) use level::{Level, L_FLUID, L_OPEN, L_SOLID};
use transfer::{prolongate, restrict};

/// The level hierarchy.
#[derive(Default, Debug)]
pub(crate) struct Multigrid {
    pub levels: Vec<Level>,
    /// Number of levels in use (levels beyond stay allocated for reuse).
    pub used: usize,
    /// Scale of the restricted residual (1/4 is Galerkin for injection; larger over-corrects).
    pub coarse_scale: f32,
    /// Smoothing sweeps before and after the coarse correction.
    pub sweeps: usize,
    /// Symmetric sweeps on the coarsest level.
    pub coarsest_sweeps: usize,
}

impl Multigrid {
    /// Builds the hierarchy under a finished level 0 (`levels[0].build_in_extents()` done by the
    /// caller).
    pub fn build_hierarchy(&mut self) {
        self.used = 1;
        while self.used < 16 {
            let l = self.used;
            if self.levels.len() <= l {
                self.levels.push(Level::default());
            }
            let (fine, coarse) = self.levels.split_at_mut(l);
            if !fine[l - 1].coarsen(&mut coarse[0]) {
                break;
            }
            let unit = fine[l - 1].any_periodic() || coarse[0].any_periodic();
            coarse[0].build_dense(if unit {
                DenseDiag::Count
            } else {
                DenseDiag::Later
            });
            fine[l - 1].galerkin(&mut coarse[0]);
            self.used += 1;
        }
    }

    /// Applies the V-cycle: `levels[0].x = M^{-1} levels[0].b` (dense, zero off the fluid cells).
    /// With `initialised`, level 0's first half-sweep (`x = inv b` on red cells) is already done.
    /// Returns `sum b x` on level 0 (computed in the last half-sweep where there is one).
    pub fn vcycle(&mut self, initialised: bool) -> f64 {
        let n = self.used;
        let sweeps = self.sweeps.max(1);
        for l in 0..n - 1 {
            let (fine, coarse) = self.levels.split_at_mut(l + 1);
            let fine = &mut fine[l];
            for s in 0..sweeps {
                if !(s == 0 && l == 0 && initialised) {
                    fine.half_sweep(0, s == 0, false);
                }
                fine.half_sweep(1, false, false);
            }
            fine.residual();
            restrict(fine, &mut coarse[0], self.coarse_scale);
        }
        let last = &mut self.levels[n - 1];
        for s in 0..self.coarsest_sweeps.max(1) {
            last.half_sweep(0, s == 0, false);
            last.half_sweep(1, false, false);
            last.half_sweep(1, false, false);
            last.half_sweep(0, false, false);
        }
        let mut sum = None;
        for l in (0..n - 1).rev() {
            let (fine, coarse) = self.levels.split_at_mut(l + 1);
            let fine = &mut fine[l];
            prolongate(&coarse[0], fine);
            for s in 0..sweeps {
                fine.half_sweep(1, false, false);
                let last = l == 0 && s + 1 == sweeps;
                let v = fine.half_sweep(0, false, last);
                if last {
                    sum = Some(v);
                }
            }
        }
        sum.unwrap_or_else(|| {
            let l0 = &self.levels[0];
            run(l0, SpanOp::Dot { a: &l0.b, b: &l0.x })
        })
    }
}
