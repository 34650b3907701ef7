//! Semi-Lagrangian advection of the face velocities: RK2 (midpoint) backtrace, MacCormack
//! (a backward and a forward semi-Lagrangian step, error-corrected, clamped to the values the first
//! step interpolated from so it cannot create new extrema), BFECC (a third, backward step from the
//! error-compensated field, clamped alike) and monotone tricubic sampling. The reflection schemes
//! ([`AdvectionScheme::MacCormackReflection`], [`AdvectionScheme::MacCormackLaggedReflection`])
//! combine these passes with the projection in `solver/`.
//!
//! - `plan.rs`: the work list (runs of active faces, blocks) and the compact gather/scatter;
//! - `geometry.rs`: where a point falls among the samples, and the interpolations there;
//! - `trace.rs`: a pass's inputs and its scalar kernels (the trace, MacCormack's correction);
//! - `passes.rs`: the schemes' passes over all blocks, each block on the AVX2 or scalar kernel;
//! - `centred.rs`: the cell-centred velocity the traces follow;
//! - `avx2.rs`: the AVX2 paths of the trace, MacCormack's correction and the centred velocity.
//!
//! Layout for speed: the active faces of the three components are walked as runs of consecutive
//! faces along x (so a face's coordinates come from the loop, not from divisions), the results go to
//! one array concatenating the three components (so one rayon region covers the whole stage), and
//! the trace reads a padded cell-centred velocity (`[f32; 4]`: one 4-lane trilinear per sample).

use serde::{Deserialize, Serialize};

#[cfg(target_arch = "x86_64")]
mod avx2;
mod centred;
mod geometry;
mod passes;
mod plan;
#[cfg(test)]
mod tests;
mod trace;

pub(crate) use centred::{update_centred, CentredRows};
pub(crate) use geometry::Geometry;
pub(crate) use plan::{gather, scatter, Plan};
pub(crate) use trace::Pass;

/// Advection scheme.
///
/// Every scheme traces the RK2 (midpoint) characteristic through the cell-centred velocity, and
/// every scheme above first order clamps its result to the extrema of the eight samples the
/// trilinear step read (so it creates no new extrema and stays unconditionally stable).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum AdvectionScheme {
    /// Semi-Lagrangian with an RK2 (midpoint) backtrace: unconditionally stable, dissipative.
    SemiLagrangian,
    /// MacCormack on top of the RK2 semi-Lagrangian step, clamped: less dissipative, two traces.
    #[serde(rename = "maccormack")]
    MacCormack,
    /// Back and forth error compensation and correction (Kim, Liu, Llamas, Rossignac 2005), clamped:
    /// three traces (backward, forward, backward from the corrected field).
    Bfecc,
    /// Semi-Lagrangian with tricubic (Catmull-Rom) interpolation at the foot point, clamped to the
    /// trilinear stencil's extrema (monotone): one trace, 64 samples per face.
    MonotoneCubic,
    /// Advection-reflection (Zehnder, Narain, Thomaszewski 2018) with clamped MacCormack half steps:
    /// advect dt/2, project, reflect (`2 P u - u`), advect dt/2 through the projected velocity,
    /// project. Four traces and a second projection per step.
    #[serde(rename = "maccormack_reflection")]
    MacCormackReflection,
    /// Clamped MacCormack of `u - dt/2 grad (p - phi) / rho`, `p` being the last projection's
    /// pressure and `phi = rho g.x` the hydrostatic potential of the body force (along the
    /// non-periodic axes): advection-reflection's reflection with the intermediate projection's
    /// gradient replaced by the lagged one (the lagged pressure gradient of the predictor of Bell,
    /// Colella and Glaz 1989), traced through the divergence-free velocity before the reflection.
    /// Two traces and one projection, as MacCormack. Only in substeps up to CFL
    /// [`LAGGED_REFLECTION_MAX_CFL`](super::LAGGED_REFLECTION_MAX_CFL); above, plain MacCormack.
    /// The default: the least dissipative scheme at MacCormack's cost (BENCHMARKS.md, issue 17).
    #[default]
    #[serde(rename = "maccormack_lagged_reflection")]
    MacCormackLaggedReflection,
}

impl AdvectionScheme {
    /// Every scheme, in order of cost.
    pub const ALL: [AdvectionScheme; 6] = [
        Self::SemiLagrangian,
        Self::MacCormack,
        Self::MacCormackLaggedReflection,
        Self::Bfecc,
        Self::MonotoneCubic,
        Self::MacCormackReflection,
    ];

    /// The name used in case files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Self::SemiLagrangian => "semi_lagrangian",
            Self::MacCormack => "maccormack",
            Self::Bfecc => "bfecc",
            Self::MonotoneCubic => "monotone_cubic",
            Self::MacCormackReflection => "maccormack_reflection",
            Self::MacCormackLaggedReflection => "maccormack_lagged_reflection",
        }
    }

    /// The scheme called `name` ([`AdvectionScheme::name`]).
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|s| s.name() == name)
    }
}
