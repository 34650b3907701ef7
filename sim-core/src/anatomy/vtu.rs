//! VTK XML unstructured grid (`.vtu`, ASCII) for ParaView: tetrahedra (cell type 10), point data
//! `label` (UInt8, [`crate::mesh::VertexLabel`]), cell data `region` (UInt8, [`crate::mesh::Region`]).

use std::path::Path;

use crate::mesh::TetMesh;
use crate::vtk::{CellType, Document};

use super::error::AnatomyError;

/// The mesh as a VTU document (positions in metres).
pub fn vtu_string(mesh: &TetMesh) -> String {
    let mut doc = Document::unstructured_grid(mesh.positions_m.len(), mesh.tets.len());
    doc.point_data("label", None);
    doc.array("label", mesh.vertex_labels.iter().map(|&l| [l as u8]));
    doc.cell_data("region", None);
    doc.array("region", mesh.tet_regions.iter().map(|&r| [r as u8]));
    doc.points(mesh.positions_m.iter().copied());
    doc.cells(mesh.tets.iter().copied(), CellType::Tetra);
    doc.finish()
}

/// Writes the mesh as a VTU file.
pub fn write_vtu(mesh: &TetMesh, path: &Path) -> Result<(), AnatomyError> {
    std::fs::write(path, vtu_string(mesh)).map_err(|source| AnatomyError::Io {
        path: path.display().to_string(),
        source,
    })
}
