//! Subcommands of the `hydrometra` CLI, one module each.
pub mod control;
pub mod fluid;
pub mod hydraulics;
pub mod monitor;
pub mod procedure;
pub mod record;
pub mod rig;
pub mod scene;

pub mod anatomy;
pub mod fem;
pub mod precompute;
