//! Cut cells: the exact fluid volume fraction of every cell and open area fraction of every MAC
//! face of a box of cells, from closed triangle surfaces, kept up to date as the surfaces move.
//!
//! (Module docs: see the end of the work; placeholder.)

mod cells;
mod clip;
mod fractions;
pub mod mesh;
mod mesh_io;
pub mod shapes;
pub mod small;

pub use cells::{CutCellStats, CutCells, Layer, Phase, SmallCellParams};
pub use fractions::{FractionStats, SurfaceFractions, MAX_CELLS_AWAY};

use crate::scene::voxelize::VoxelBox;

/// Which way a closed surface's triangle normals point (by the right-hand rule of their vertex
/// order).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Orientation {
    /// Out of the enclosed region (the STL/OBJ convention; [`mesh::ClosedMesh`]).
    Outward,
    /// Into the enclosed region (the cavity surface: normals into the fluid).
    Inward,
}

/// Errors of the cut-cell geometry.
#[derive(Debug, thiserror::Error)]
pub enum CutCellError {
    /// The box cannot carry fractions.
    #[error("cut-cell box: {0}")]
    Box(String),
    /// A surface cannot be used as given.
    #[error("surface `{surface}`: {what}")]
    Surface {
        /// The surface's name.
        surface: String,
        /// What is wrong.
        what: String,
    },
    /// A vertex position is refused.
    #[error("surface `{surface}`: vertex {vertex} at {position_m:?} m: {what}")]
    Vertex {
        /// The surface's name.
        surface: String,
        /// The vertex.
        vertex: usize,
        /// Its position.
        position_m: [f32; 3],
        /// What is wrong.
        what: String,
    },
}

/// Refuses boxes the fractions cannot be computed on.
fn check_box(cells: &VoxelBox) -> Result<(), CutCellError> {
    if cells.dims.contains(&0) {
        return Err(CutCellError::Box(format!(
            "dims = {:?}: every axis needs at least one cell",
            cells.dims
        )));
    }
    let fits = cells.dims.iter().all(|&d| d < (1 << 20))
        && cells
            .dims
            .iter()
            .map(|&d| d + 1)
            .try_fold(1usize, |a, d| a.checked_mul(d))
            .is_some_and(|n| n < u32::MAX as usize);
    if !fits {
        return Err(CutCellError::Box(format!(
            "dims = {:?}: too many cells",
            cells.dims
        )));
    }
    if !(cells.spacing_m.is_finite() && cells.spacing_m > 0.0) {
        return Err(CutCellError::Box(format!(
            "spacing_m = {}: expected a finite length > 0",
            cells.spacing_m
        )));
    }
    if cells.origin_m.iter().any(|o| !o.is_finite()) {
        return Err(CutCellError::Box(format!(
            "origin_m = {:?}: expected finite coordinates",
            cells.origin_m
        )));
    }
    Ok(())
}
