//! The particles as VTK XML (PolyData `.vtp` or an UnstructuredGrid of vertex cells `.vtu`),
//! for ParaView and meshio.

use std::fmt::Write as _;
use std::path::Path;

use super::system::ParticleSystem;

impl ParticleSystem {
    /// The particles as a VTK PolyData document (`.vtp`, ASCII): points (m), one vertex cell
    /// each, point data `kind` (0 blood, 1 bubble, 2 fragment), `diameter_m`, `age_s` and
    /// `velocity` (m/s, [`ParticleSystem::velocity_m_per_s`]).
    pub fn vtp_string(&self) -> String {
        particles_xml(Some(self), VtkFlavour::PolyData)
    }

    /// The same particles and point data as a VTK UnstructuredGrid of vertex cells (`.vtu`,
    /// ASCII): ParaView shows it as the `.vtp`, and readers that know only unstructured grids
    /// (meshio) read it too.
    pub fn vtu_string(&self) -> String {
        particles_xml(Some(self), VtkFlavour::UnstructuredGrid)
    }

    /// Writes [`ParticleSystem::vtp_string`] to `path`.
    pub fn write_vtp(&self, path: &Path) -> std::io::Result<()> {
        std::fs::write(path, self.vtp_string())
    }
}

/// Which VTK XML dataset the particles are written as.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VtkFlavour {
    /// PolyData with one vertex cell per particle (`.vtp`).
    PolyData,
    /// UnstructuredGrid with one `VTK_VERTEX` cell per particle (`.vtu`).
    UnstructuredGrid,
}

/// The particles of `sys` (none: an empty document) as VTK XML, ASCII.
pub fn particles_xml(sys: Option<&ParticleSystem>, flavour: VtkFlavour) -> String {
    let n = sys.map_or(0, ParticleSystem::len);
    let poly = flavour == VtkFlavour::PolyData;
    let (root, cells_tag) = if poly {
        ("PolyData", "Verts")
    } else {
        ("UnstructuredGrid", "Cells")
    };
    let mut s = String::with_capacity(160 * n + 1024);
    let _ = writeln!(
        s,
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"{root}\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n<{root}>"
    );
    if poly {
        let _ = writeln!(
            s,
            "<Piece NumberOfPoints=\"{n}\" NumberOfVerts=\"{n}\" NumberOfLines=\"0\" NumberOfStrips=\"0\" NumberOfPolys=\"0\">"
        );
    } else {
        let _ = writeln!(s, "<Piece NumberOfPoints=\"{n}\" NumberOfCells=\"{n}\">");
    }
    s.push_str("<PointData Scalars=\"kind\" Vectors=\"velocity\">\n<DataArray type=\"UInt8\" Name=\"kind\" format=\"ascii\">\n");
    if let Some(sys) = sys {
        for &c in &sys.class {
            let _ = writeln!(s, "{}", sys.classes[c as usize].kind as u8);
        }
    }
    s.push_str("</DataArray>\n<DataArray type=\"Float32\" Name=\"diameter_m\" format=\"ascii\">\n");
    if let Some(sys) = sys {
        for &c in &sys.class {
            let _ = writeln!(s, "{:e}", sys.classes[c as usize].diameter_m as f32);
        }
    }
    s.push_str("</DataArray>\n<DataArray type=\"Float32\" Name=\"age_s\" format=\"ascii\">\n");
    if let Some(sys) = sys {
        for &b in &sys.birth_s {
            let _ = writeln!(s, "{:e}", sys.time_s as f32 - b);
        }
    }
    s.push_str("</DataArray>\n<DataArray type=\"Float32\" Name=\"velocity\" NumberOfComponents=\"3\" format=\"ascii\">\n");
    if let Some(sys) = sys {
        for i in 0..n {
            let v = sys.velocity_m_per_s(i);
            let _ = writeln!(s, "{:e} {:e} {:e}", v[0] as f32, v[1] as f32, v[2] as f32);
        }
    }
    s.push_str("</DataArray>\n</PointData>\n<Points>\n<DataArray type=\"Float32\" NumberOfComponents=\"3\" format=\"ascii\">\n");
    if let Some(sys) = sys {
        for i in 0..n {
            let p = sys.position_m(i);
            let _ = writeln!(s, "{:e} {:e} {:e}", p[0] as f32, p[1] as f32, p[2] as f32);
        }
    }
    let _ = writeln!(
        s,
        "</DataArray>\n</Points>\n<{cells_tag}>\n<DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">"
    );
    for i in 0..n {
        let _ = writeln!(s, "{i}");
    }
    s.push_str("</DataArray>\n<DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">\n");
    for i in 0..n {
        let _ = writeln!(s, "{}", i + 1);
    }
    s.push_str("</DataArray>\n");
    if !poly {
        // VTK_VERTEX.
        s.push_str("<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">\n");
        for _ in 0..n {
            s.push_str("1\n");
        }
        s.push_str("</DataArray>\n");
    }
    let _ = writeln!(s, "</{cells_tag}>\n</Piece>\n</{root}>\n</VTKFile>");
    s
}
