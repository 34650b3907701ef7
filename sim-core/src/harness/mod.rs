//! Harnesses: the analytic test meshes, the Table 1 benchmark, the validation cases and the stability
//! soak. They drive the library the way the CLI, the tests and the benchmarks need; they are not its
//! API and are compiled only with the `harness` feature (enabled by the daemon's CLI and by this
//! crate's own tests and benchmarks).
//!
//! - [`testmesh`]: thick sphere and cylinder meshes for the FEM (exact solutions in
//!   [`crate::fem::analytic`]).
//! - [`analytic_cavity`]: analytic cavities (uterine-shaped, ellipsoid) voxelized with a scope, the
//!   geometry of the fluid benchmark and tests.
//! - [`benchmark`]: the paper's Table 1 operating points, ours against the Gauss-Seidel baseline.
//! - [`validation`]: the analytic fluid cases (Taylor-Green, square duct, Ethier-Steinman).
//! - [`pipe`]: Hagen-Poiseuille flow in a pipe tilted to the grid (cut-cell walls).
//! - [`soak`]: the random stability soak of the fluid solver.
//! - [`converge`]: the scene's accuracy metrics against a fine reference (`hydrometra scene converge`).
//! - [`load`]: busy threads, to measure the fork-joins under load.
//! - [`stage_bench`]: the cavity and particles the vortex and particle benchmarks share.

// The harness files moved here from `fluid` and `fem` and still name the library's items through
// `super::`; these imports are what `super::` finds.
use crate::fem::{element, pressure};
use crate::fluid::{
    AdvectionScheme, CellLabel, FluidError, FluidGrid, FluidParams, FluidSolver, ProjectionMethod,
};

pub mod analytic_cavity;
pub mod benchmark;
pub mod converge;
pub mod load;
pub mod pipe;
pub mod soak;
pub mod stage_bench;
// Index loops mirror the mesh formulas, as in `fem`.
#[allow(clippy::needless_range_loop)]
pub mod testmesh;
pub mod validation;

/// The SIMD paths (`sim-core/src/simd`): whether the AVX2 + FMA kernels run, and the switch that
/// runs every kernel on its portable path instead (process-wide; for tests and benchmarks).
pub mod simd {
    pub use crate::simd::{avx2_fma, set_portable};
}

/// The solver's two-way fork-join, switchable to `rayon::join` or chili to measure against.
pub mod fork_join {
    pub use crate::fork_join::{set_backend, set_guard, Backend};
}
