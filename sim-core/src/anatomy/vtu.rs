//! VTK XML unstructured grid (`.vtu`, ASCII) for ParaView: tetrahedra (cell type 10), point data
//! `label` (UInt8, [`crate::mesh::VertexLabel`]), cell data `region` (UInt8, [`crate::mesh::Region`]).

use std::fmt::Write as _;
use std::path::Path;

use crate::mesh::TetMesh;

use super::error::AnatomyError;

/// The mesh as a VTU document (positions in metres).
pub fn vtu_string(mesh: &TetMesh) -> String {
    let np = mesh.positions_m.len();
    let nc = mesh.tets.len();
    let mut s = String::with_capacity(64 * (np + nc));
    s.push_str("<?xml version=\"1.0\"?>\n");
    s.push_str(
        "<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n",
    );
    s.push_str("<UnstructuredGrid>\n");
    let _ = writeln!(s, "<Piece NumberOfPoints=\"{np}\" NumberOfCells=\"{nc}\">");
    s.push_str("<PointData Scalars=\"label\">\n");
    s.push_str("<DataArray type=\"UInt8\" Name=\"label\" format=\"ascii\">\n");
    for l in &mesh.vertex_labels {
        let _ = writeln!(s, "{}", *l as u8);
    }
    s.push_str("</DataArray>\n</PointData>\n");
    s.push_str("<CellData Scalars=\"region\">\n");
    s.push_str("<DataArray type=\"UInt8\" Name=\"region\" format=\"ascii\">\n");
    for r in &mesh.tet_regions {
        let _ = writeln!(s, "{}", *r as u8);
    }
    s.push_str("</DataArray>\n</CellData>\n");
    s.push_str(
        "<Points>\n<DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">\n",
    );
    for p in &mesh.positions_m {
        // `{:e}` prints the shortest representation that round-trips.
        let _ = writeln!(s, "{:e} {:e} {:e}", p[0], p[1], p[2]);
    }
    s.push_str("</DataArray>\n</Points>\n<Cells>\n");
    s.push_str("<DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n");
    for t in &mesh.tets {
        let _ = writeln!(s, "{} {} {} {}", t[0], t[1], t[2], t[3]);
    }
    s.push_str("</DataArray>\n<DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">\n");
    for i in 0..nc {
        let _ = writeln!(s, "{}", 4 * (i + 1));
    }
    s.push_str("</DataArray>\n<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">\n");
    for _ in 0..nc {
        s.push_str("10\n");
    }
    s.push_str("</DataArray>\n</Cells>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n");
    s
}

/// Writes the mesh as a VTU file.
pub fn write_vtu(mesh: &TetMesh, path: &Path) -> Result<(), AnatomyError> {
    std::fs::write(path, vtu_string(mesh)).map_err(|source| AnatomyError::Io {
        path: path.display().to_string(),
        source,
    })
}
