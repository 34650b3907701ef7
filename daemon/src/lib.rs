//! Internals shared by the `hydrometrad` service and the `hydrometra` CLI.

pub mod cli;
pub mod service;
