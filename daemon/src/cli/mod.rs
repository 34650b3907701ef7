//! Subcommands of the `hydrometra` CLI, one module each.

pub mod anatomy;
pub mod fem;
pub mod precompute;
