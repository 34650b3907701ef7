//! The tetrahedral mesh shared by the anatomy generator, the FEM and the atlas.
//!
//! Positions in metres in the organ frame: origin at the external os, +z from the cervix towards the
//! fundus (the uterine axis before version/flexion), +x to the patient's left, +y anterior.

use serde::{Deserialize, Serialize};

/// What a vertex does under load.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[repr(u8)]
pub enum VertexLabel {
    /// Inside the wall: no boundary condition.
    Interior = 0,
    /// Portio protruding into the vagina: displacement fixed to zero.
    Fixed = 1,
    /// Cavity surface: loaded by the distension pressure.
    Endometrium = 2,
    /// Outer surface: free.
    Serosa = 3,
}

/// Material region of a tetrahedron.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[repr(u8)]
pub enum Region {
    /// Uterine muscle.
    Myometrium = 0,
    /// Myoma (fibroid).
    Fibroid = 1,
    /// Endometrial polyp.
    Polyp = 2,
}

/// A labelled tetrahedral mesh.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TetMesh {
    /// Vertex positions in metres.
    pub positions_m: Vec<[f64; 3]>,
    /// Tetrahedra as vertex indices, positively oriented: `(b-a) . ((c-a) x (d-a)) > 0`.
    pub tets: Vec<[u32; 4]>,
    /// Material region of each tetrahedron.
    pub tet_regions: Vec<Region>,
    /// Label of each vertex.
    pub vertex_labels: Vec<VertexLabel>,
    /// The cavity surface (endometrium) as triangles whose right-hand normals point into the fluid.
    pub cavity_triangles: Vec<[u32; 3]>,
    /// The cavity surface's boundary loop at the cervical canal opening, in order.
    pub cavity_opening_loop: Vec<u32>,
}

impl TetMesh {
    /// Signed volume of tetrahedron `t` in m^3 (positive for a valid element).
    pub fn tet_volume_m3(&self, t: usize) -> f64 {
        let [a, b, c, d] = self.tets[t].map(|i| self.positions_m[i as usize]);
        signed_tet_volume(a, b, c, d)
    }

    /// Total volume of the mesh in m^3.
    pub fn volume_m3(&self) -> f64 {
        (0..self.tets.len()).map(|t| self.tet_volume_m3(t)).sum()
    }

    /// Volume enclosed by the cavity surface, closed by a fan over the opening loop, in m^3.
    ///
    /// Uses `positions_m` as given, so it also measures a deformed cavity when the caller passes a
    /// mesh with moved positions. Fluid-pointing normals make the divergence-theorem sum negative,
    /// hence the sign flip.
    pub fn cavity_volume_m3(&self) -> f64 {
        cavity_volume_m3(
            &self.positions_m,
            &self.cavity_triangles,
            &self.cavity_opening_loop,
        )
    }
}

/// Signed volume of the tetrahedron `a b c d`.
pub fn signed_tet_volume(a: [f64; 3], b: [f64; 3], c: [f64; 3], d: [f64; 3]) -> f64 {
    let u = sub(b, a);
    let v = sub(c, a);
    let w = sub(d, a);
    dot(u, cross(v, w)) / 6.0
}

/// Volume enclosed by `triangles` (normals into the enclosed fluid) closed over `opening_loop`.
///
/// The opening is closed by a fan from the loop's centroid over the surface's boundary half-edges,
/// each traversed against the surface's own orientation, so the result does not depend on the
/// direction in which the loop is listed.
pub fn cavity_volume_m3(
    positions_m: &[[f64; 3]],
    triangles: &[[u32; 3]],
    opening_loop: &[u32],
) -> f64 {
    let p = |i: u32| positions_m[i as usize];
    let mut centroid = [0.0; 3];
    for &i in opening_loop {
        centroid = add(centroid, p(i));
    }
    let n = opening_loop.len().max(1) as f64;
    centroid = centroid.map(|c| c / n);
    let mut half_edges = std::collections::HashSet::with_capacity(triangles.len() * 3);
    let mut six_v = 0.0;
    for t in triangles {
        six_v += dot(p(t[0]), cross(p(t[1]), p(t[2])));
        for k in 0..3 {
            half_edges.insert((t[k], t[(k + 1) % 3]));
        }
    }
    for &(a, b) in &half_edges {
        if !half_edges.contains(&(b, a)) {
            // Boundary edge a->b: the cap triangle (centroid, b, a) continues the orientation.
            six_v += dot(centroid, cross(p(b), p(a)));
        }
    }
    // Normals point into the fluid, i.e. inward: the divergence-theorem sum is negative.
    -six_v / 6.0
}

pub(crate) fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
pub(crate) fn add(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
#[inline]
pub(crate) fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
#[inline]
pub(crate) fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unit_tet_volume_is_one_sixth() {
        let v = signed_tet_volume([0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]);
        assert!((v - 1.0 / 6.0).abs() < 1e-15);
    }

    #[test]
    fn open_box_cavity_volume_closes_over_the_opening() {
        // A unit cube without its top face; normals point inward (into the fluid).
        let positions: Vec<[f64; 3]> = (0..8)
            .map(|i| [(i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64])
            .collect();
        // Faces of the cube with outward normals, reversed to point inward; the z=1 face left open.
        let outward: [[u32; 4]; 5] = [
            [0, 2, 3, 1], // z = 0
            [0, 1, 5, 4], // y = 0
            [2, 6, 7, 3], // y = 1
            [0, 4, 6, 2], // x = 0
            [1, 3, 7, 5], // x = 1
        ];
        let mut tris = Vec::new();
        for q in outward {
            tris.push([q[0], q[2], q[1]]);
            tris.push([q[0], q[3], q[2]]);
        }
        let loop_ = vec![4, 5, 7, 6];
        let v = cavity_volume_m3(&positions, &tris, &loop_);
        assert!((v - 1.0).abs() < 1e-12, "volume {v}");
    }
}
