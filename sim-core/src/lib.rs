//! `hydrometra-sim`: the physics of the hydrometra simulation.
//!
//! Pure computation, no I/O beyond reading and writing its own files. SI units everywhere
//! (m, s, Pa, m^3); clinical units only through [`units`] at the edges.
#![warn(missing_docs)]
// Every `unsafe` block says why it is sound (`// SAFETY: ...`); CI's `-D warnings` makes it an error.
#![warn(clippy::undocumented_unsafe_blocks)]

pub mod anatomy;
pub mod atlas;
pub mod cutcell;
pub mod fem;
pub mod fluid;
mod fork_join;
/// How the solver's kernels split over two threads: the halves the helper thread ran and the joins
/// its guard ran in the calling thread because the helper did not pay (process-wide counts, for
/// logs and benchmarks; `sim-core/src/fork_join.rs`).
pub use fork_join::{guard_serial_joins, helper_tasks};
#[cfg(any(test, feature = "harness"))]
pub mod harness;
pub mod hydraulics;
pub mod mesh;
mod rounding;
pub mod scene;
mod simd;
pub mod units;
pub mod vtk;
