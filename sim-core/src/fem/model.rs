//! The boundary-value problem: rest geometry, materials per tetrahedron, fixed degrees of freedom
//! and the pressurised cavity.

use super::material::{Material, MaterialSet};
use super::pressure::CavitySurface;
use super::FemError;
use crate::mesh::{TetMesh, VertexLabel};

/// A quasi-static inflation problem.
#[derive(Debug, Clone)]
pub struct FemModel {
    /// Rest (reference) positions in metres.
    pub rest_positions_m: Vec<[f64; 3]>,
    /// Positively oriented tetrahedra.
    pub tets: Vec<[u32; 4]>,
    /// Index into `materials` per tetrahedron.
    pub tet_material: Vec<u16>,
    /// Distinct materials.
    pub materials: Vec<Material>,
    /// Fixed degree of freedom flags, 3 per vertex (x, y, z).
    pub fixed_dofs: Vec<bool>,
    /// The cavity on which the pressure acts.
    pub cavity: CavitySurface,
}

impl FemModel {
    /// The problem of a labelled mesh: `Fixed` vertices clamped, pressure on the cavity triangles
    /// closed over the opening loop, region materials from `materials`.
    pub fn from_mesh(mesh: &TetMesh, materials: &MaterialSet) -> Result<Self, FemError> {
        let n = mesh.positions_m.len();
        if mesh.tet_regions.len() != mesh.tets.len() {
            return Err(FemError::Mesh(format!(
                "tet_regions has {} entries for {} tetrahedra",
                mesh.tet_regions.len(),
                mesh.tets.len()
            )));
        }
        if mesh.vertex_labels.len() != n {
            return Err(FemError::Mesh(format!(
                "vertex_labels has {} entries for {n} vertices",
                mesh.vertex_labels.len()
            )));
        }
        let mut mats: Vec<Material> = Vec::new();
        let mut tet_material = Vec::with_capacity(mesh.tets.len());
        for &r in &mesh.tet_regions {
            let m = materials.get(r);
            let idx = match mats.iter().position(|q| q == m) {
                Some(i) => i,
                None => {
                    mats.push(m.clone());
                    mats.len() - 1
                }
            };
            tet_material.push(idx as u16);
        }
        let mut fixed_dofs = vec![false; 3 * n];
        for (i, l) in mesh.vertex_labels.iter().enumerate() {
            if *l == VertexLabel::Fixed {
                fixed_dofs[3 * i..3 * i + 3].fill(true);
            }
        }
        let model = Self {
            rest_positions_m: mesh.positions_m.clone(),
            tets: mesh.tets.clone(),
            tet_material,
            materials: mats,
            fixed_dofs,
            cavity: CavitySurface::from_mesh(mesh),
        };
        model.validate()?;
        Ok(model)
    }

    /// Checks indices, sizes and orientation.
    pub fn validate(&self) -> Result<(), FemError> {
        let n = self.rest_positions_m.len() as u32;
        if self.fixed_dofs.len() != 3 * n as usize {
            return Err(FemError::Mesh(format!(
                "fixed_dofs has {} entries, expected {}",
                self.fixed_dofs.len(),
                3 * n
            )));
        }
        if self.tet_material.len() != self.tets.len() {
            return Err(FemError::Mesh(
                "tet_material length differs from the tetrahedron count".into(),
            ));
        }
        for (t, tet) in self.tets.iter().enumerate() {
            if let Some(&bad) = tet.iter().find(|&&i| i >= n) {
                return Err(FemError::Mesh(format!(
                    "tetrahedron {t} refers to vertex {bad}, but there are {n} vertices"
                )));
            }
            if self.tet_material[t] as usize >= self.materials.len() {
                return Err(FemError::Mesh(format!("tetrahedron {t} has no material")));
            }
        }
        for (k, tri) in self.cavity.triangles.iter().enumerate() {
            if let Some(&bad) = tri.iter().find(|&&i| i >= n) {
                return Err(FemError::Mesh(format!(
                    "cavity triangle {k} refers to vertex {bad}, but there are {n} vertices"
                )));
            }
        }
        if self.cavity.triangles.is_empty() {
            return Err(FemError::Mesh(
                "the mesh has no cavity triangles to load".into(),
            ));
        }
        if !self.fixed_dofs.iter().any(|&f| f) {
            return Err(FemError::Mesh(
                "no fixed vertices: rigid motions are unconstrained".into(),
            ));
        }
        Ok(())
    }
}

impl FemModel {
    /// A model from raw parts with one material set applied to every tetrahedron as myometrium.
    pub fn from_parts(
        rest_positions_m: Vec<[f64; 3]>,
        tets: Vec<[u32; 4]>,
        materials: &MaterialSet,
        fixed_dofs: Vec<bool>,
        cavity: CavitySurface,
    ) -> Result<Self, FemError> {
        let nt = tets.len();
        let model = Self {
            rest_positions_m,
            tets,
            tet_material: vec![0; nt],
            materials: vec![materials.myometrium.clone()],
            fixed_dofs,
            cavity,
        };
        model.validate()?;
        Ok(model)
    }
}
