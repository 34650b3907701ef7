//! The boundary-value problem: rest geometry, materials per tetrahedron, fixed degrees of freedom
//! and the pressurised cavity.

use super::material::{Material, MaterialSet};
use super::pressure::CavitySurface;
use super::FemError;
use crate::mesh::{TetMesh, VertexLabel};
use std::collections::HashMap;

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
    /// Mid-edge nodes of each tetrahedron (edges (0,1), (0,2), (0,3), (1,2), (1,3), (2,3)) when
    /// the model uses 10-node tetrahedra ([`Element::Tet10`]); empty for linear tetrahedra.
    pub edge_nodes: Vec<[u32; 6]>,
}

/// The finite element.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Element {
    /// Linear tetrahedra with the nodally averaged volumetric energy (fast; the sweep default).
    #[default]
    Tet4,
    /// Quadratic 10-node tetrahedra with a mean-dilatation (P2/P0) volumetric energy and mid-edge
    /// nodes on the curved boundary where the caller knows it (the accurate reference).
    Tet10,
}

impl std::str::FromStr for Element {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "tet4" => Ok(Self::Tet4),
            "tet10" => Ok(Self::Tet10),
            other => Err(format!("unknown element '{other}': expected tet4 or tet10")),
        }
    }
}

impl std::fmt::Display for Element {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Tet4 => "tet4",
            Self::Tet10 => "tet10",
        })
    }
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
            edge_nodes: Vec::new(),
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
        if !self.edge_nodes.is_empty() {
            if self.edge_nodes.len() != self.tets.len() {
                return Err(FemError::Mesh(format!(
                    "edge_nodes has {} entries for {} tetrahedra",
                    self.edge_nodes.len(),
                    self.tets.len()
                )));
            }
            if let Some((t, _)) = self
                .edge_nodes
                .iter()
                .enumerate()
                .find(|(_, e)| e.iter().any(|&i| i >= n))
            {
                return Err(FemError::Mesh(format!(
                    "tetrahedron {t} has a mid-edge node beyond the {n} nodes"
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
            edge_nodes: Vec::new(),
        };
        model.validate()?;
        Ok(model)
    }

    /// The element of this model.
    pub fn element(&self) -> Element {
        if self.edge_nodes.is_empty() {
            Element::Tet4
        } else {
            Element::Tet10
        }
    }

    /// Number of corner vertices (the linear mesh's vertices come first; mid-edge nodes follow).
    pub fn corner_count(&self) -> usize {
        match self.edge_nodes.iter().flatten().min() {
            Some(&m) => m as usize,
            None => self.rest_positions_m.len(),
        }
    }

    /// The same problem on 10-node tetrahedra: one new node per edge, appended after the
    /// vertices, placed by `place(a, b)` from the rest positions of the edge's ends (the chord
    /// midpoint, or a point on the exact curved boundary). A mid node's coordinate is fixed when it
    /// is fixed at both ends of its edge. Already quadratic models are returned unchanged.
    pub fn to_tet10(
        &self,
        place: impl Fn([f64; 3], [f64; 3]) -> [f64; 3],
    ) -> Result<Self, FemError> {
        if self.element() == Element::Tet10 {
            return Ok(self.clone());
        }
        let mut positions = self.rest_positions_m.clone();
        let mut fixed = self.fixed_dofs.clone();
        let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
        let mut edge_nodes = Vec::with_capacity(self.tets.len());
        for tet in &self.tets {
            let mut e = [0u32; 6];
            for (k, &(i, j)) in super::tet10::EDGES.iter().enumerate() {
                let (a, b) = (tet[i].min(tet[j]), tet[i].max(tet[j]));
                e[k] = *mid.entry((a, b)).or_insert_with(|| {
                    let (pa, pb) = (positions[a as usize], positions[b as usize]);
                    positions.push(place(pa, pb));
                    for d in 0..3 {
                        fixed.push(fixed[3 * a as usize + d] && fixed[3 * b as usize + d]);
                    }
                    positions.len() as u32 - 1
                });
            }
            edge_nodes.push(e);
        }
        let cavity = self.cavity.to_quadratic(&mid).ok_or_else(|| {
            FemError::Mesh("a cavity edge is not an edge of any tetrahedron".into())
        })?;
        let model = Self {
            rest_positions_m: positions,
            tets: self.tets.clone(),
            tet_material: self.tet_material.clone(),
            materials: self.materials.clone(),
            fixed_dofs: fixed,
            cavity,
            edge_nodes,
        };
        model.validate()?;
        Ok(model)
    }

    /// The 10 node indices of tetrahedron `t` of a quadratic model.
    pub fn tet10_nodes(&self, t: usize) -> [u32; 10] {
        let c = self.tets[t];
        let e = self.edge_nodes[t];
        [c[0], c[1], c[2], c[3], e[0], e[1], e[2], e[3], e[4], e[5]]
    }
}
