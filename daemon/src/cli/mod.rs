//! Subcommands of the `hydrometra` CLI, one module each.

pub mod anatomy;
