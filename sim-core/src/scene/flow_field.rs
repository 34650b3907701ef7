//! The flow field as the scene publishes it: the cells' kinds and velocities on the voxel grid.

use super::particles::{self, Traverse, TRAVERSE_SUBGRID};
use super::ports::Ports;
use super::types::VoxelKind;
use super::vortices::Vortices;
use crate::fluid::FluidSolver;

/// The flow field on the voxel grid.
pub struct FlowField<'a> {
    pub(super) ports: &'a Ports,
    pub(super) solver: &'a FluidSolver,
    pub(super) vortices: Option<&'a Vortices>,
}

impl FlowField<'_> {
    /// Cells per axis.
    pub fn dims(&self) -> [usize; 3] {
        self.ports.cells().dims
    }
    /// Centre of cell (0, 0, 0), m.
    pub fn first_centre_m(&self) -> [f64; 3] {
        self.ports.cells().centre_m(0, 0, 0)
    }
    /// Cell edge, m.
    pub fn spacing_m(&self) -> f64 {
        self.ports.cells().spacing_m
    }
    /// Kind of every cell, x fastest.
    pub fn kinds(&self) -> &[VoxelKind] {
        self.ports.kinds()
    }
    /// Cell-centred velocities (m/s) into `out` (one per cell, x fastest): the mean of the faces
    /// in fluid and open cells, the prescribed velocity in ports and walls, zero elsewhere;
    /// plus the vortex overlay where it is display-only.
    pub fn velocities_into(&self, out: &mut [[f32; 3]]) {
        let [nx, ny, nz] = self.dims();
        let grid = self.solver.grid();
        let kinds = self.ports.kinds();
        let mut n = 0;
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    if n >= out.len() {
                        return;
                    }
                    out[n] = match kinds[n] {
                        VoxelKind::Fluid | VoxelKind::Open => {
                            self.solver.centred_velocity_m_s([i, j, k])
                        }
                        // The jet out of the channel (the rim cell imposes its share of it).
                        VoxelKind::Inflow => self.ports.inflow_jet_m_per_s(),
                        VoxelKind::Outflow | VoxelKind::Wall => grid.velocity_at(n),
                        _ => [0.0; 3],
                    };
                    n += 1;
                }
            }
        }
        if let Some(v) = self.vortices {
            v.overlay_into(out);
        }
    }
    /// The fluid solver (face velocities, pressure, sampling).
    pub fn solver(&self) -> &FluidSolver {
        self.solver
    }

    /// The paper's "time to traverse" in the current flow (frozen): a cloud of tracers spread
    /// evenly over the inflow port's fluid-facing area ([`particles::inflow_face_points`]),
    /// advanced with steps of `dt_s` until they leave or `max_time_s`
    /// ([`particles::time_to_traverse`]).
    pub fn time_to_traverse(&self, dt_s: f64, max_time_s: f64) -> Traverse {
        let port = self.ports.inflow_port();
        let per_face = TRAVERSE_SUBGRID * TRAVERSE_SUBGRID;
        let mut starts = Vec::with_capacity(port.cells.len() * 6 * per_face);
        particles::inflow_face_points(&port, TRAVERSE_SUBGRID, &mut starts);
        particles::time_to_traverse(self.solver, self.kinds(), &starts, dt_s, max_time_s)
    }
}
