//! Offline hyperelastic finite elements: quasi-static, total-Lagrangian inflation of a tetrahedral
//! mesh by a follower pressure on its cavity.
//!
//! - [`material`]: `Psi = sum_p mu_p (I1bar - 3)^p + kappa/2 (J - 1)^2`, per region, from TOML.
//! - [`element`]: linear tetrahedron kinematics; [`system`]: assembly with a nodally averaged
//!   volumetric energy (locking-free for near-incompressible material).
//! - [`tet10`] and [`system10`]: the quadratic 10-node tetrahedron with a mean-dilatation
//!   (P2/P0) volumetric energy, the accurate element ([`Element::Tet10`],
//!   [`FemModel::to_tet10`]).
//! - [`pressure`]: the follower pressure as the potential `-p V_cavity(x)` of the closed cavity.
//! - [`newton`]: Newton with line search, tangent predictor, adaptive steps, volume control.
//! - [`linear`]: faer sparse LDL^T with the symbolic analysis reused.
//! - [`analytic`]: exact solutions of the thick sphere and cylinder (their meshes are in
//!   `hydrometra_sim::harness::testmesh`, feature `harness`)
//!   (incompressible integrals and the finite-kappa sphere by radial shooting).
//!
//! ```
//! use hydrometra_sim::fem::{analytic, material::{Material, MaterialSet}, FemModel, Solver};
//! use hydrometra_sim::harness::testmesh;
//! let material = Material::neo_hookean(1.0, 100.0);
//! let case = testmesh::thick_sphere_octant(1.0, 2.0, 4, 2);
//! let model = FemModel::from_parts(case.positions_m, case.tets, &MaterialSet::uniform(material), case.fixed_dofs, case.cavity).unwrap();
//! let mut solver = Solver::new(&model, Default::default()).unwrap();
//! let rest = solver.rest_state();
//! let loaded = solver.solve_to_pressure(&rest, 0.05).unwrap();
//! assert!(loaded.cavity_volume_m3 > rest.cavity_volume_m3);
//! // The same problem on quadratic tetrahedra with mid-edge nodes on the spheres.
//! let quadratic = model.to_tet10(testmesh::spherical_midpoint).unwrap();
//! let mut solver10 = Solver::new(&quadratic, Default::default()).unwrap();
//! let loaded10 = solver10.solve_to_pressure(&solver10.rest_state(), 0.05).unwrap();
//! assert!(loaded10.cavity_volume_m3 > solver10.rest_state().cavity_volume_m3);
//! ```

// Index loops mirror the tensor notation (F_iJ, A_iJkL) of the formulas they implement.
#![allow(clippy::needless_range_loop)]

pub mod analytic;
mod assembly;
pub mod element;
pub mod linear;
pub mod material;
pub mod model;
pub mod newton;
pub mod ordering;
pub mod pressure;
pub mod system;
pub mod system10;
pub mod tet10;

pub use model::{Element, FemModel};
pub use newton::{Equilibrium, Solver, SolverCounters, SolverOptions};

/// Errors of the FEM.
#[derive(Debug, thiserror::Error)]
pub enum FemError {
    /// Bad material parameters or file.
    #[error("material: {0}")]
    Material(String),
    /// Bad mesh or model.
    #[error("mesh: {0}")]
    Mesh(String),
    /// An element inverted (the inversion guard).
    #[error("tetrahedron {tet} inverted (v/V0 = {volume_ratio:.3e})")]
    Inverted {
        /// Tetrahedron index.
        tet: usize,
        /// Its current over rest volume.
        volume_ratio: f64,
    },
    /// The sparse solver failed.
    #[error("linear solver: {0}")]
    LinearSolver(String),
    /// One Newton solve diverged.
    #[error("Newton diverged: {reason}")]
    Diverged {
        /// Why.
        reason: String,
    },
    /// Continuation could not reach its target even with the smallest step.
    #[error("no convergence towards {control} = {target:.6e}: reached {reached:.6e}; last cause: {cause}; relative residual history of the last attempt: {residual_history:?}")]
    NoConvergence {
        /// What was controlled.
        control: &'static str,
        /// The last converged value.
        reached: f64,
        /// The target.
        target: f64,
        /// Relative residuals of the last failed attempt.
        residual_history: Vec<f64>,
        /// The last failure.
        cause: String,
    },
    /// A sweep level failed.
    #[error("level {level} ({pressure_pa:.1} Pa): {inner}")]
    LevelFailed {
        /// Level index.
        level: usize,
        /// Its pressure.
        pressure_pa: f64,
        /// The failure.
        inner: Box<FemError>,
    },
}
