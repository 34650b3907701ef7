//! The solver's parameters (checked, naming the first bad one) and the counters of a step.

use serde::{Deserialize, Serialize};

use super::super::pressure::ProjectionMethod;
use super::super::viscosity::ViscosityMode;
use super::super::FluidError;
use super::AdvectionScheme;

/// Physical and numerical parameters of the solver.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FluidParams {
    /// Density.
    pub density_kg_m3: f64,
    /// Kinematic viscosity.
    pub viscosity_m2_s: f64,
    /// Body force per unit mass (e.g. gravity or a driving pressure gradient / rho).
    pub body_force_m_s2: [f64; 3],
    /// Advection scheme.
    pub advection: AdvectionScheme,
    /// Pressure solve.
    pub projection: ProjectionMethod,
    /// Divergence tolerance: the projection stops when `max |div u| h / U <= tolerance`, U being the
    /// largest face speed (or `velocity_scale_m_s` if larger).
    pub tolerance: f64,
    /// Iteration cap of the CG solves.
    pub max_iterations: usize,
    /// Lower bound of the velocity scale U of the tolerance.
    pub velocity_scale_m_s: f64,
    /// Split a step into substeps so that the CFL number stays below this (None: never split).
    pub max_cfl: Option<f64>,
    /// Upper bound on substeps per step.
    pub max_substeps: usize,
    /// Fluid cells from which the reference solver's CG products run on rayon; every stage of a
    /// step (advection, viscosity, the multigrid levels, divergence and gradient) runs in two halves
    /// on two threads from 1/12 of this.
    pub parallel_threshold_cells: usize,
}

impl Default for FluidParams {
    fn default() -> Self {
        Self {
            density_kg_m3: 1000.0,
            viscosity_m2_s: 1.0e-6,
            body_force_m_s2: [0.0; 3],
            advection: AdvectionScheme::default(),
            projection: ProjectionMethod::MultigridPcg,
            tolerance: 1.0e-6,
            max_iterations: 500,
            velocity_scale_m_s: 0.0,
            max_cfl: None,
            max_substeps: 8,
            parallel_threshold_cells: 24_000,
        }
    }
}

impl FluidParams {
    /// Checks the parameters, naming the first bad one.
    pub fn validate(&self) -> Result<(), FluidError> {
        let bad = |key: &str, value: String, expected: &str| {
            Err(FluidError::InvalidParameter {
                key: key.into(),
                value,
                expected: expected.into(),
            })
        };
        if !(self.density_kg_m3.is_finite() && self.density_kg_m3 > 0.0) {
            return bad(
                "density_kg_m3",
                self.density_kg_m3.to_string(),
                "a finite value > 0",
            );
        }
        if !(self.viscosity_m2_s.is_finite() && self.viscosity_m2_s >= 0.0) {
            return bad(
                "viscosity_m2_s",
                self.viscosity_m2_s.to_string(),
                "a finite value >= 0",
            );
        }
        if self.body_force_m_s2.iter().any(|f| !f.is_finite()) {
            return bad(
                "body_force_m_s2",
                format!("{:?}", self.body_force_m_s2),
                "finite values",
            );
        }
        if !(self.tolerance.is_finite() && self.tolerance > 0.0) {
            return bad(
                "tolerance",
                self.tolerance.to_string(),
                "a finite value > 0",
            );
        }
        if self.max_iterations == 0 {
            return bad("max_iterations", "0".into(), "at least 1");
        }
        if let Some(c) = self.max_cfl {
            if !(c.is_finite() && c > 0.0) {
                return bad("max_cfl", c.to_string(), "a finite value > 0");
            }
        }
        if self.max_substeps == 0 {
            return bad("max_substeps", "0".into(), "at least 1");
        }
        if let ProjectionMethod::GaussSeidel { sweeps: 0 }
        | ProjectionMethod::RedBlackGaussSeidel { sweeps: 0 } = self.projection
        {
            return bad("sweeps", "0".into(), "at least 1");
        }
        Ok(())
    }
}

/// Counters of one step (summed over its substeps; times in milliseconds).
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct StepStats {
    /// Substeps taken.
    pub substeps: usize,
    /// Whether the labels changed and the topology was rebuilt.
    pub topology_rebuilt: bool,
    /// Time rebuilding the topology.
    pub topology_ms: f64,
    /// Time in advection (including boundary values and extrapolation).
    pub advect_ms: f64,
    /// Time in body forces and viscosity.
    pub diffuse_ms: f64,
    /// Time in the projection.
    pub project_ms: f64,
    /// Whole step.
    pub total_ms: f64,
    /// Viscosity mode of the last substep.
    pub viscosity: ViscosityMode,
    /// Implicit-viscosity CG iterations (all components, all substeps).
    pub viscosity_iterations: usize,
    /// Projection iterations (CG iterations or Gauss-Seidel sweeps), summed over substeps.
    pub projection_iterations: usize,
    /// Whether every projection reached the tolerance.
    pub projection_converged: bool,
    /// After the last projection: max |div u| h / U over fluid cells, the incompatible part of closed
    /// regions removed.
    pub max_div_rel: f64,
    /// Largest incompatible mean `|h div u|` removed from a closed region (m/s): a flux mismatch of
    /// its ports that no pressure can remove.
    pub closed_region_mismatch_m_s: f64,
    /// The whole incompatible flux removed from closed regions, summed over them (m^3/s; largest
    /// over the substeps).
    pub closed_region_flux_m3_per_s: f64,
    /// What the last projection added to the weighted cells' boundary fluxes so that each closed
    /// region with some weight balances by itself (`FluidGrid::boundary_flux_weights_m2`), summed
    /// over the regions, m^3/s into the fluid (0 without weights).
    pub boundary_flux_shift_m3_per_s: f64,
    /// The shared flux (`FluidGrid::shared_flux_m3_per_s`) the last projection applied over the
    /// weighted cells of the regions that can carry it, m^3/s into the fluid (0 when it had no
    /// weighted fluid cell).
    pub shared_flux_m3_per_s: f64,
    /// Fluid cells.
    pub fluid_cells: usize,
}
