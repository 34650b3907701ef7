//! With cut cells (`[fluid] cut_cells`), the cavity's walls and its os move the fluid through the
//! wall pieces inside the cut cells: each cell's pieces push `q = -h^2 W . v` into the fluid cell
//! that carries them (`CutCells::wall_flux_m3_per_s`, `CutCells::wall_carrier`), as the solver's
//! per-cell boundary flux (`FluidGrid::set_boundary_flux_m3_per_s`).
//!
//! - The wall pieces (cells whose owning triangle is a wall triangle) move at the atlas's
//!   `dx/dp dp/dt` of the owning triangle, scaled by one factor so that they push out exactly
//!   the hydraulics' `dV/dt` (`FluxBalance::wall_flux_scale`); if that motion does not carry
//!   `dV/dt`'s sign, they move along their normals instead, scaled the same way.
//! - The os's pieces (cells a cap triangle touches) carry exactly the hydraulics' losses, with
//!   their sign, as the solver's shared flux (`FluidGrid::set_shared_flux_m3_per_s`) shared in
//!   proportion to the pieces' areas over the regions that can carry it: a pocket cut off from
//!   the cavity with os pieces but no wall pieces gets no share (nothing in it could supply it).
//!
//! With the ports prescribing `Q_in` and `Q_out`, every fluid region is then closed and, while the
//! fluid is one region, its right-hand side compatible by the hydraulics' own balance
//! `in - out - losses = dV/dt`. When it splits, each region balances by itself: the wall pieces'
//! areas are the solver's boundary-flux weights (`FluidGrid::set_boundary_flux_weight_m2`), so
//! the projection shifts each region's wall fluxes by area until its ports, os and walls sum to
//! zero; summed over the regions the shifts cancel (the same balance), so the walls still carry
//! `dV/dt` and the os the losses.

use super::ports::CavityCells;
use super::types::{FluxBalance, FrameFlows, VoxelKind};
use super::voxelize::NO_TRIANGLE;
use crate::cutcell::CutCells;
use crate::fluid::{FluidError, FluidSolver, StepStats};

/// A piece of wall: the fluid cell that carries it, its raw flux (m^3/s into the fluid) and its
/// area (`|W| h^2`, m^2), whether it is the os's.
#[derive(Clone, Copy)]
struct Piece {
    carrier: u32,
    raw_m3_per_s: f64,
    area_m2: f64,
    os: bool,
}

/// The cut walls' fluxes of the last frame.
pub struct CutWalls {
    /// The pieces on fluid cells this frame (scratch; room for every cell, reserved once).
    pieces: Vec<Piece>,
    /// The cells whose boundary flux is set in the solver's grid, to zero next time.
    carriers: Vec<u32>,
    /// The cells whose boundary-flux weight (their wall pieces' area) is set, to zero next time.
    weighted: Vec<u32>,
    /// The cells whose share weight of the losses (their os pieces' area) is set, likewise.
    os_cells: Vec<u32>,
    /// Out of the fluid through the wall pieces, m^3/s.
    walls_out_m3_per_s: f64,
}

impl CutWalls {
    /// For a grid of `cells` cells; nothing set.
    pub fn new(cells: usize) -> Self {
        Self {
            pieces: Vec::with_capacity(cells),
            carriers: Vec::with_capacity(cells),
            weighted: Vec::with_capacity(cells),
            os_cells: Vec::with_capacity(cells),
            walls_out_m3_per_s: 0.0,
        }
    }

    /// Whether the last [`CutWalls::set_fluxes`] set any flux or weight.
    pub fn moving(&self) -> bool {
        !self.carriers.is_empty() || !self.weighted.is_empty() || !self.os_cells.is_empty()
    }

    /// Sets the frame's fluxes of the pieces of `cut` (the cavity's cut cells, whose cells'
    /// kinds `kinds` the ports stage composed) into the solver's grid, and the wall flux scale
    /// of `flux`.
    pub fn set_fluxes(
        &mut self,
        cut: &CutCells,
        cavity: &CavityCells<'_>,
        kinds: &[VoxelKind],
        flows: &FrameFlows,
        solver: &mut FluidSolver,
        flux: &mut FluxBalance,
    ) -> Result<(), FluidError> {
        let cells = *cut.cells();
        let h2 = cells.spacing_m * cells.spacing_m;
        let [nx, ny, nz] = cells.dims;
        let (owners, extents) = (cavity.voxels.owners(), cavity.voxels.row_extents());
        let caps = cavity.surface.cap_triangles() as u32;
        let tris = cavity.surface.triangles();
        let dxdp = cavity.surface.dxdp_m_per_pa();
        let dpdt = flows.dpdt_pa_per_s;
        let areas = cut.wall_areas();
        self.pieces.clear();
        // Raw: the pieces' flux at the atlas's motion, out of the fluid (walls) and the areas.
        let (mut walls_raw_out, mut walls_area, mut os_area) = (0.0, 0.0, 0.0);
        for (row, &[a, b]) in extents.iter().enumerate().take(ny * nz) {
            // Every cut cell is a band cell of the same surface: within the row's extent.
            for n in nx * row + a as usize..nx * row + b as usize {
                let w = areas[n];
                if w == [0.0; 3] {
                    continue;
                }
                let carrier = cut.wall_carrier(n);
                if kinds[carrier] != VoxelKind::Fluid {
                    continue; // under the scope: the cavity's fluid there is not the fluid's
                }
                let t = owners[n];
                let os = t < caps;
                let v = if os || t == NO_TRIANGLE {
                    [0.0; 3]
                } else {
                    let [p, q, r] = tris[t as usize].map(|i| dxdp[i as usize]);
                    std::array::from_fn(|x| (p[x] + q[x] + r[x]) as f64 / 3.0 * dpdt)
                };
                let raw = cut.wall_flux_m3_per_s(n, v);
                let area_m2 = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt() * h2;
                if os {
                    os_area += area_m2;
                } else {
                    walls_raw_out -= raw;
                    walls_area += area_m2;
                }
                self.pieces.push(Piece {
                    carrier: carrier as u32,
                    raw_m3_per_s: raw,
                    area_m2,
                    os,
                });
            }
        }
        // The one factor that makes the walls push out dV/dt; the rule of the whole-cell walls
        // (`Ports`): the atlas's motion when it carries dV/dt's sign, else a normal motion.
        let dvdt = flows.dvdt_m3_per_s;
        let (along_normals, scale) = if dvdt == 0.0 {
            (false, 0.0)
        } else if walls_raw_out * dvdt > 0.0 && (walls_raw_out / dvdt).abs() > 1e-3 {
            (false, dvdt / walls_raw_out)
        } else if walls_area > 0.0 {
            (true, dvdt / walls_area)
        } else {
            (false, 0.0)
        };
        flux.wall_flux_scale = scale;
        let losses = flows.losses_m3_per_s;
        // Into the solver: last frame's carriers to zero, this frame's pieces added.
        let grid = solver.grid_mut();
        for &c in &self.carriers {
            grid.set_boundary_flux_m3_per_s(cells_at(c, nx, ny), 0.0)?;
        }
        self.carriers.clear();
        for &c in &self.weighted {
            grid.set_boundary_flux_weight_m2(cells_at(c, nx, ny), 0.0)?;
        }
        self.weighted.clear();
        for &c in &self.os_cells {
            grid.set_shared_flux_weight_m2(cells_at(c, nx, ny), 0.0)?;
        }
        self.os_cells.clear();
        // The os's pieces share the losses by area, in the regions that can carry them (the
        // solver's rule: not in a pocket without wall pieces, which nothing could supply).
        grid.set_shared_flux_m3_per_s(if os_area > 0.0 { -losses } else { 0.0 })?;
        let mut walls_out = 0.0;
        for p in &self.pieces {
            let at = cells_at(p.carrier, nx, ny);
            if p.os {
                let w = grid.shared_flux_weights_m2().get(p.carrier as usize);
                let w = w.copied().unwrap_or(0.0);
                grid.set_shared_flux_weight_m2(at, w + p.area_m2)?;
                self.os_cells.push(p.carrier);
                continue;
            }
            // The walls take up their region's mismatch by area (the os keeps the losses).
            let w = grid.boundary_flux_weights_m2().get(p.carrier as usize);
            let w = w.copied().unwrap_or(0.0);
            grid.set_boundary_flux_weight_m2(at, w + p.area_m2)?;
            self.weighted.push(p.carrier);
            let q = if along_normals {
                // Outward along the normals: the walls move away from the fluid.
                -scale * p.area_m2
            } else {
                scale * p.raw_m3_per_s
            };
            if q == 0.0 {
                continue;
            }
            walls_out -= q;
            grid.add_boundary_flux_m3_per_s(at, q)?;
            self.carriers.push(p.carrier);
        }
        self.walls_out_m3_per_s = walls_out;
        Ok(())
    }

    /// Adds what the pieces carried out of the fluid in the last step to the measured wall and
    /// os fluxes of `flux` (their flux through whole wall cells' faces is measured there):
    /// the solver's shift of the wall pieces' fluxes into the fluid that balanced each region
    /// (`StepStats::boundary_flux_shift_m3_per_s`) is the walls', the shared flux it applied over
    /// the os's pieces (`StepStats::shared_flux_m3_per_s`) the os's.
    pub fn add_to(&self, flux: &mut FluxBalance, stats: &StepStats) {
        flux.fluid_wall_m3_per_s += self.walls_out_m3_per_s - stats.boundary_flux_shift_m3_per_s;
        flux.fluid_open_m3_per_s -= stats.shared_flux_m3_per_s;
    }
}

fn cells_at(n: u32, nx: usize, ny: usize) -> [usize; 3] {
    let n = n as usize;
    [n % nx, (n / nx) % ny, n / (nx * ny)]
}
