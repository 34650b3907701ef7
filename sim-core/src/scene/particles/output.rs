//! The particles as VTK XML (PolyData `.vtp` or an UnstructuredGrid of vertex cells `.vtu`),
//! for ParaView and meshio.

use std::path::Path;

use super::system::ParticleSystem;
use crate::vtk::{CellType, Document};

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
    let mut doc = match flavour {
        VtkFlavour::PolyData => Document::poly_vertices(n),
        VtkFlavour::UnstructuredGrid => Document::unstructured_grid(n, n),
    };
    // Per particle (none without a system): its class, age, velocity and position.
    let particles = || {
        sys.into_iter()
            .flat_map(|s| (0..s.len()).map(move |i| (s, i)))
    };
    let class = |(s, i): (&ParticleSystem, usize)| s.class_of(i);
    doc.point_data("kind", Some("velocity"));
    doc.array("kind", particles().map(|p| [class(p).kind as u8]));
    doc.array(
        "diameter_m",
        particles().map(|p| [class(p).diameter_m as f32]),
    );
    doc.array(
        "age_s",
        particles().map(|(s, i)| [s.time_s as f32 - s.birth_s[i]]),
    );
    doc.array(
        "velocity",
        particles().map(|(s, i)| s.velocity_m_per_s(i).map(|v| v as f32)),
    );
    doc.points(particles().map(|(s, i)| s.position_m(i).map(|p| p as f32)));
    doc.cells((0..n).map(|i| [i]), CellType::Vertex);
    doc.finish()
}
