//! The flow field as the scene publishes it: the cells' kinds, velocities and fluid volume
//! fractions on the voxel grid.

use super::particles::{self, Traverse, TRAVERSE_SUBGRID};
use super::ports::Ports;
use super::types::VoxelKind;
use super::vortices::Vortices;
use crate::cutcell::CutCells;
use crate::fluid::FluidSolver;
use crate::vtk::{CellType, Digits, Document};

/// The flow field on the voxel grid.
pub struct FlowField<'a> {
    pub(super) ports: &'a Ports,
    pub(super) solver: &'a FluidSolver,
    pub(super) vortices: Option<&'a Vortices>,
    /// The cavity's cut cells, with `[fluid] cut_cells`.
    pub(super) cut: Option<&'a CutCells>,
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
    /// The fluid volume fraction of cell `n` (x fastest) as a renderer draws the fluid region,
    /// in [0, 1]. With cut cells: the exact, unmerged fraction of the cell inside the cavity
    /// surface (a small cell merged into a neighbour keeps its own; the stabilised fractions the
    /// solver uses put it in the neighbour, which may then exceed 1), 0 in the scope's cells
    /// (sheath and ports, whole cells). With whole cells: 1 in fluid and open cells, 0 elsewhere.
    #[inline]
    pub fn fluid_fraction(&self, n: usize) -> f64 {
        let kind = self.ports.kinds().get(n).copied().unwrap_or_default();
        match (self.cut, kind) {
            (_, VoxelKind::Scope | VoxelKind::Inflow | VoxelKind::Outflow) => 0.0,
            (Some(cut), _) => cut
                .volume_fractions()
                .get(n)
                .map_or(0.0, |v| v.clamp(0.0, 1.0)),
            (None, VoxelKind::Fluid | VoxelKind::Open) => 1.0,
            (None, _) => 0.0,
        }
    }

    /// The fluid volume of [`FlowField::fluid_fraction`], m^3: `sum f h^3`.
    pub fn fluid_volume_m3(&self) -> f64 {
        let h = self.spacing_m();
        let cells = self.kinds().len();
        (0..cells).map(|n| self.fluid_fraction(n)).sum::<f64>() * h * h * h
    }

    /// The fluid solver (face velocities, pressure, sampling).
    pub fn solver(&self) -> &FluidSolver {
        self.solver
    }

    /// The cells in the cavity (not tissue, not the sheath) as a VTU of hexahedra on their
    /// shared corners (m), cell data `label` (the [`VoxelKind`] value) and `velocity`
    /// ([`FlowField::velocities_into`], m/s, five digits).
    pub fn vtu_string(&self) -> String {
        let [nx, ny, nz] = self.dims();
        let h = self.spacing_m();
        let c0 = self.first_centre_m();
        let o = [c0[0] - 0.5 * h, c0[1] - 0.5 * h, c0[2] - 0.5 * h];
        let kinds = self.kinds();
        let mut vel = vec![[0.0f32; 3]; kinds.len()];
        self.velocities_into(&mut vel);
        let cells: Vec<usize> = (0..kinds.len())
            .filter(|&n| !matches!(kinds[n], VoxelKind::Solid | VoxelKind::Scope))
            .collect();
        // Shared corner nodes, numbered in the order the cells first touch them.
        let node = |i: usize, j: usize, k: usize| i + (nx + 1) * (j + (ny + 1) * k);
        let mut id = vec![u32::MAX; (nx + 1) * (ny + 1) * (nz + 1)];
        let mut points: Vec<usize> = Vec::new();
        let mut conn: Vec<[u32; 8]> = Vec::with_capacity(cells.len());
        for &n in &cells {
            let (i, j, k) = (n % nx, (n / nx) % ny, n / (nx * ny));
            // x fastest, then y, then z.
            let corners = [
                (0, 0, 0),
                (0, 0, 1),
                (0, 1, 0),
                (0, 1, 1),
                (1, 0, 0),
                (1, 0, 1),
                (1, 1, 0),
                (1, 1, 1),
            ];
            conn.push(corners.map(|(dk, dj, di)| {
                let q = node(i + di, j + dj, k + dk);
                if id[q] == u32::MAX {
                    id[q] = points.len() as u32;
                    points.push(q);
                }
                id[q]
            }));
        }
        let mut doc = Document::unstructured_grid(points.len(), cells.len());
        doc.cell_data("label", Some("velocity"));
        doc.array("label", cells.iter().map(|&n| [kinds[n] as u8]));
        doc.array("velocity", cells.iter().map(|&n| vel[n].map(Digits::<5>)));
        doc.points(points.iter().map(|&q| {
            let (i, j, k) = (
                q % (nx + 1),
                (q / (nx + 1)) % (ny + 1),
                q / ((nx + 1) * (ny + 1)),
            );
            [
                (o[0] + i as f64 * h) as f32,
                (o[1] + j as f64 * h) as f32,
                (o[2] + k as f64 * h) as f32,
            ]
        }));
        doc.cells(conn, CellType::Hexahedron);
        doc.finish()
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
