//! Subcommands of the `hydrometra` CLI, one module each.

pub mod fem;
pub mod precompute;
