//! The cut cells of the cavity (`[fluid] cut_cells`): per cell the fluid volume fraction and per
//! face the open area fraction of the region inside the cavity surface and outside the scope's
//! sheath ([`crate::cutcell`], small cells merged), from the voxelizer's held positions and the
//! pose the ports compose, so the fractions and the cell states belong to one surface and one
//! pose. Incremental: only the rows the moved triangles reach are recomputed, equal to a full
//! recomputation bit for bit (the cutcell module's guarantee, tested on the scene).
//!
//! The sheath ([`SheathMesh`]) is a solid layer over the cavity's fluid, moved rigidly with the
//! pose. The ports still need whole cells: the tip layer's and hole band's cells (the ports
//! stage's rasterization) keep the cavity's own open fractions on their faces, so their
//! prescribed velocities carry the hydraulics' flows as without the sheath layer, and their
//! fluid is not the fluid's (docs/scene.md, "Cut cells").

use std::time::Instant;

use super::counters::StageCounters;
use super::error::SceneError;
use super::scope::{ScopeGeometry, ScopePart, SheathMesh};
use super::voxelize::{VoxelBox, Voxelizer};
use crate::cutcell::{CutCells, Layer, Orientation, Phase, SmallCellParams};
use crate::fluid::{CutFractions, FluidGrid};

/// The scene's grid is not periodic.
const PERIODIC: [bool; 3] = [false; 3];

/// The cavity's layer and the sheath's, in the stack.
const CAVITY: usize = 0;

/// The fractions of the fluid inside the cavity surface and outside the sheath, kept with the
/// voxelizer.
pub struct CavityFractions {
    cut: CutCells,
    sheath: SheathMesh,
    /// Where the sheath waits while there is no scope pose: above the box.
    parked_m: [f64; 3],
    /// The stabilised fractions in the solver's layout.
    fractions: CutFractions,
    /// Whether `fractions` were ever converted whole (afterwards only changed rows are).
    converted: bool,
    /// The fractions changed since the solver's grid last had them: all of them, or in the rows
    /// `unsent_rows` (flagged in `row_unsent`) alone.
    unsent: bool,
    unsent_all: bool,
    unsent_rows: Vec<u32>,
    row_unsent: Vec<bool>,
    /// The rows whose port faces [`Self::send`] set last time (restored before the next).
    patched_rows: Vec<u32>,
    /// Per row, the sum of the exact fluid fractions of its cells; their total, m^3.
    row_volume: Vec<f64>,
    volume_m3: f64,
}

impl CavityFractions {
    /// The fractions of the surface of `triangles` (normals into the fluid) less the `sheath` on
    /// `cells`; nothing is computed until the first step.
    pub fn new(
        cells: VoxelBox,
        triangles: Vec<[u32; 3]>,
        vertex_count: usize,
        sheath: SheathMesh,
    ) -> Result<Self, SceneError> {
        let cavity = Layer {
            name: "cavity".into(),
            triangles,
            vertex_count,
            orientation: Orientation::Inward,
            inside: Phase::Fluid,
        };
        let scope = Layer {
            name: "sheath".into(),
            triangles: sheath.triangles().to_vec(),
            vertex_count: sheath.positions_m().len(),
            orientation: Orientation::Outward,
            inside: Phase::Solid,
        };
        let cut = CutCells::new(
            cells,
            Phase::Solid,
            vec![cavity, scope],
            SmallCellParams::default(),
        )?;
        let fractions = CutFractions {
            volume: vec![0.0; cells.cell_count()],
            face: std::array::from_fn(|a| {
                let mut d = cells.dims;
                d[a] += 1;
                vec![0.0; d.iter().product()]
            }),
            // The scene's viscous step keeps the staircase wall (no wall distances per frame).
            walls: None,
        };
        let h = cells.spacing_m;
        let parked_m = [
            cells.origin_m[0] + 0.5 * h * cells.dims[0] as f64,
            cells.origin_m[1] + 0.5 * h * cells.dims[1] as f64,
            cells.origin_m[2] + h * (cells.dims[2] as f64 + 2.0),
        ];
        let rows = cells.dims[1] * cells.dims[2];
        Ok(Self {
            cut,
            sheath,
            parked_m,
            fractions,
            converted: false,
            unsent: true,
            unsent_all: true,
            unsent_rows: Vec::with_capacity(rows),
            row_unsent: vec![false; rows],
            patched_rows: Vec::with_capacity(rows),
            row_volume: vec![0.0; rows],
            volume_m3: 0.0,
        })
    }

    /// The cut-cell part of the voxelize stage: when the voxelizer moved vertices in this frame
    /// or the sheath's pose `scope` (the one the ports compose) changed, the fractions at the held
    /// positions (the first time in full). Returns the rows whose fractions changed (empty when
    /// none did); the time joins the voxelize stage's run.
    pub fn step(
        &mut self,
        voxels: &Voxelizer,
        scope: Option<&ScopeGeometry>,
        counters: &mut StageCounters,
    ) -> Result<&[u32], SceneError> {
        let t = Instant::now();
        let moved = self.sheath.place(scope, self.parked_m);
        if voxels.last_stats().moved_vertices == 0 && !moved {
            return Ok(&[]);
        }
        // Threshold 0: exactly the vertices whose held position the voxelizer moved, and the
        // sheath's when it moved.
        let positions = [voxels.voxel_positions_m(), self.sheath.positions_m()];
        let stats = self.cut.update(&positions, 0.0)?;
        if stats.changed_rows > 0 {
            let cut = &self.cut;
            let faces = std::array::from_fn(|a| cut.stabilised_face_fractions(a));
            let (dims, volume) = (cut.cells().dims, cut.stabilised_volume_fractions());
            let rows = cut.changed_rows();
            // Only the changed rows convert (the rest equals what it was): the surface moves in
            // most frames and the box is many times the band of cut cells.
            if self.converted {
                self.fractions
                    .assign_rows_from_box(dims, rows, volume, faces);
            } else {
                self.fractions
                    .assign_from_box(dims, PERIODIC, volume, faces);
                self.converted = true;
                self.unsent_all = true;
            }
            for &r in rows {
                if !std::mem::replace(&mut self.row_unsent[r as usize], true) {
                    self.unsent_rows.push(r);
                }
            }
            self.unsent = true;
            let nx = dims[0];
            let exact = cut.volume_fractions();
            for &r in cut.changed_rows() {
                let r = r as usize;
                self.row_volume[r] = exact[nx * r..nx * (r + 1)].iter().sum();
            }
            let h = cut.cells().spacing_m;
            self.volume_m3 = self.row_volume.iter().sum::<f64>() * h * h * h;
        }
        counters.extend_last_run_since(t);
        Ok(if stats.changed_rows > 0 {
            self.cut.changed_rows()
        } else {
            &[]
        })
    }

    /// Hands the fractions to the solver's `grid` when they changed since it last had them: the
    /// first time whole, then only the rows changed since (the grid's fractions are this stage's
    /// alone, so the other rows are already there). The faces of the ports' whole cells
    /// (`scope_cells` in the tip layer and the hole band) open as the cavity alone makes them
    /// ([`CavityFractions::port_face_fraction`]); the rows set so last time are restored first,
    /// since the ports may have moved off them.
    pub fn send(
        &mut self,
        grid: &mut FluidGrid,
        scope_cells: &[(u32, ScopePart)],
    ) -> Result<(), SceneError> {
        if self.unsent {
            let cells = *self.cut.cells();
            let [nx, ny, _] = cells.dims;
            if !self.patched_rows.is_empty() {
                let cut = &self.cut;
                let faces = std::array::from_fn(|a| cut.stabilised_face_fractions(a));
                let volume = cut.stabilised_volume_fractions();
                self.fractions
                    .assign_rows_from_box(cells.dims, &self.patched_rows, volume, faces);
                for &r in &self.patched_rows {
                    if !std::mem::replace(&mut self.row_unsent[r as usize], true) {
                        self.unsent_rows.push(r);
                    }
                }
                self.patched_rows.clear();
            }
            for &(n, part) in scope_cells {
                if !matches!(part, ScopePart::Tip | ScopePart::Holes) {
                    continue;
                }
                let n = n as usize;
                let at = [n % nx, (n / nx) % ny, n / (nx * ny)];
                for a in 0..3 {
                    let mut d = cells.dims;
                    d[a] += 1;
                    for up in 0..2 {
                        let mut f = at;
                        f[a] += up;
                        let idx = f[0] + d[0] * (f[1] + d[1] * f[2]);
                        self.fractions.face[a][idx] = self.port_face_fraction(a, idx);
                    }
                }
                // Every face of cell `n` is in its row's parts (`row_parts`).
                let row = (n / nx) as u32;
                self.patched_rows.push(row);
                if !std::mem::replace(&mut self.row_unsent[row as usize], true) {
                    self.unsent_rows.push(row);
                }
            }
            if self.unsent_all {
                grid.copy_cut_fractions(&self.fractions)?;
            } else {
                grid.copy_cut_fraction_rows(&self.fractions, &self.unsent_rows)?;
            }
            self.unsent = false;
            self.unsent_all = false;
            for &r in &self.unsent_rows {
                self.row_unsent[r as usize] = false;
            }
            self.unsent_rows.clear();
        }
        Ok(())
    }

    /// The open fraction of face `idx` normal to `axis` (the solver's face layout) where it
    /// borders a port's whole cell: the cavity's own, rounded as the stabilised faces are, not
    /// the sheath's (which closes the faces the ports' fluxes cross). The one rule for what the
    /// ports' velocities are set for (`Ports`) and what the solver's faces carry ([`Self::send`]).
    pub fn port_face_fraction(&self, axis: usize, idx: usize) -> f32 {
        self.cut
            .params()
            .stabilised_face(self.cut.layer(CAVITY).face_fractions(axis)[idx]) as f32
    }

    /// The fractions (stabilised, the solver's layout; the ports' faces as last sent).
    pub fn fractions(&self) -> &CutFractions {
        &self.fractions
    }

    /// The cut cells (exact and stabilised fractions, counts; layer 0 the cavity, 1 the sheath).
    pub fn cut_cells(&self) -> &CutCells {
        &self.cut
    }

    /// The sheath's surface where last placed.
    pub fn sheath(&self) -> &SheathMesh {
        &self.sheath
    }

    /// The fluid the cavity surface encloses less the sheath's part of it, m^3: the sum of the
    /// exact fractions, exact for the polygonal surfaces except in the cells both cut (see
    /// [`CutCells`]).
    pub fn cavity_less_sheath_m3(&self) -> f64 {
        self.volume_m3
    }
}
