//! The cut cells of the cavity (`[fluid] cut_cells`): per cell the fluid volume fraction and per
//! face the open area fraction of the region inside the cavity surface ([`crate::cutcell`], small
//! cells merged), from the voxelizer's held positions, so the fractions and the cell states belong
//! to one surface. Incremental: only the rows the moved triangles reach are recomputed, equal to a
//! full recomputation bit for bit (the cutcell module's guarantee, tested on the scene).
//!
//! The scope is not a layer here: its sheath stays the whole cells whose centres lie in it (the
//! ports stage's rasterization), whose fluid part is not the fluid's (docs/scene.md, "Cut cells").

use std::time::Instant;

use super::counters::StageCounters;
use super::error::SceneError;
use super::voxelize::{VoxelBox, Voxelizer};
use crate::cutcell::{CutCells, Layer, Orientation, Phase, SmallCellParams};
use crate::fluid::{CutFractions, FluidGrid};

/// The scene's grid is not periodic.
const PERIODIC: [bool; 3] = [false; 3];

/// The fractions of the fluid inside the cavity surface, kept with the voxelizer.
pub struct CavityFractions {
    cut: CutCells,
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
}

impl CavityFractions {
    /// The fractions of the surface of `triangles` (normals into the fluid) on `cells`; nothing
    /// is computed until the first step.
    pub fn new(
        cells: VoxelBox,
        triangles: Vec<[u32; 3]>,
        vertex_count: usize,
    ) -> Result<Self, SceneError> {
        let cavity = Layer {
            name: "cavity".into(),
            triangles,
            vertex_count,
            orientation: Orientation::Inward,
            inside: Phase::Fluid,
        };
        let cut = CutCells::new(
            cells,
            Phase::Solid,
            vec![cavity],
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
        let rows = cells.dims[1] * cells.dims[2];
        Ok(Self {
            cut,
            fractions,
            converted: false,
            unsent: true,
            unsent_all: true,
            unsent_rows: Vec::with_capacity(rows),
            row_unsent: vec![false; rows],
        })
    }

    /// The cut-cell part of the voxelize stage: when the voxelizer moved vertices in this frame,
    /// the fractions at its held positions (the first time in full). Returns the rows whose
    /// fractions changed (empty when none did); the time joins the voxelize stage's run.
    pub fn step(
        &mut self,
        voxels: &Voxelizer,
        counters: &mut StageCounters,
    ) -> Result<&[u32], SceneError> {
        if voxels.last_stats().moved_vertices == 0 {
            return Ok(&[]);
        }
        let t = Instant::now();
        // Threshold 0: exactly the vertices whose held position the voxelizer moved.
        let stats = self.cut.update(&[voxels.voxel_positions_m()], 0.0)?;
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
    /// alone, so the other rows are already there).
    pub fn send(&mut self, grid: &mut FluidGrid) -> Result<(), SceneError> {
        if self.unsent {
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

    /// The fractions (stabilised, the solver's layout).
    pub fn fractions(&self) -> &CutFractions {
        &self.fractions
    }

    /// The cut cells (exact and stabilised fractions, counts).
    pub fn cut_cells(&self) -> &CutCells {
        &self.cut
    }
}
