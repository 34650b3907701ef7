//! Conversions between SI units (used inside) and clinical units (used at the edges): the
//! workspace's one copy lives in `hydrometra-units`, re-exported here.

pub use hydrometra_units::*;
