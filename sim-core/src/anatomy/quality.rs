//! Element quality: dihedral angles and the normalised radius-ratio aspect, per tetrahedron and
//! over a mesh.

use serde::{Deserialize, Serialize};

use super::mesher::{cross, dot, norm, sub};

/// Quality of one tetrahedron.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TetQuality {
    /// Smallest dihedral angle, degrees.
    pub min_dihedral_deg: f64,
    /// Largest dihedral angle, degrees.
    pub max_dihedral_deg: f64,
    /// Mean of the six dihedral angles, degrees.
    pub mean_dihedral_deg: f64,
    /// Aspect ratio: circumradius / (3 x inradius); 1 for the regular tetrahedron, grows without
    /// bound as the element degenerates.
    pub aspect: f64,
}

/// Quality of a tetrahedron given by its corners (any orientation).
pub fn tet_quality(p: [[f64; 3]; 4]) -> TetQuality {
    // Outward face normals (face k is opposite vertex k).
    let faces = [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]];
    let mut n = [[0.0; 3]; 4];
    let mut area_sum = 0.0;
    let vol6 = dot(sub(p[1], p[0]), cross(sub(p[2], p[0]), sub(p[3], p[0])));
    let s = if vol6 >= 0.0 { 1.0 } else { -1.0 };
    for (k, f) in faces.iter().enumerate() {
        let c = cross(sub(p[f[1]], p[f[0]]), sub(p[f[2]], p[f[0]]));
        let l = norm(c);
        area_sum += 0.5 * l;
        n[k] = if l > 0.0 { c.map(|x| s * x / l) } else { c };
    }
    let mut min_d = f64::INFINITY;
    let mut max_d: f64 = 0.0;
    let mut sum = 0.0;
    for k in 0..4 {
        for l in k + 1..4 {
            let c = dot(n[k], n[l]).clamp(-1.0, 1.0);
            let d = 180.0 - c.acos().to_degrees();
            min_d = min_d.min(d);
            max_d = max_d.max(d);
            sum += d;
        }
    }
    let a = sub(p[1], p[0]);
    let b = sub(p[2], p[0]);
    let c = sub(p[3], p[0]);
    let num = [0, 1, 2].map(|k| {
        dot(a, a) * cross(b, c)[k] + dot(b, b) * cross(c, a)[k] + dot(c, c) * cross(a, b)[k]
    });
    let circum = norm(num) / (2.0 * vol6.abs());
    let inr = 3.0 * (vol6.abs() / 6.0) / area_sum;
    TetQuality {
        min_dihedral_deg: min_d,
        max_dihedral_deg: max_d,
        mean_dihedral_deg: sum / 6.0,
        aspect: if inr > 0.0 {
            circum / (3.0 * inr)
        } else {
            f64::INFINITY
        },
    }
}

/// Quality over a mesh.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct QualityStats {
    /// Smallest dihedral angle of any tetrahedron, degrees.
    pub min_dihedral_deg: f64,
    /// Largest dihedral angle of any tetrahedron, degrees.
    pub max_dihedral_deg: f64,
    /// Mean dihedral angle over all angles of all tetrahedra, degrees.
    pub mean_dihedral_deg: f64,
    /// Mean of each tetrahedron's smallest dihedral angle, degrees.
    pub mean_min_dihedral_deg: f64,
    /// Largest aspect ratio (circumradius / 3 inradius).
    pub max_aspect: f64,
    /// Mean aspect ratio.
    pub mean_aspect: f64,
    /// Smallest tetrahedron volume, m^3 (positive for a valid mesh).
    pub min_volume_m3: f64,
}

/// Quality statistics of a mesh.
pub fn mesh_quality(pos: &[[f64; 3]], tets: &[[u32; 4]]) -> QualityStats {
    let mut st = QualityStats {
        min_dihedral_deg: f64::INFINITY,
        max_dihedral_deg: 0.0,
        mean_dihedral_deg: 0.0,
        mean_min_dihedral_deg: 0.0,
        max_aspect: 0.0,
        mean_aspect: 0.0,
        min_volume_m3: f64::INFINITY,
    };
    for t in tets {
        let p = t.map(|v| pos[v as usize]);
        let q = tet_quality(p);
        st.min_dihedral_deg = st.min_dihedral_deg.min(q.min_dihedral_deg);
        st.max_dihedral_deg = st.max_dihedral_deg.max(q.max_dihedral_deg);
        st.mean_dihedral_deg += q.mean_dihedral_deg;
        st.mean_min_dihedral_deg += q.min_dihedral_deg;
        st.max_aspect = st.max_aspect.max(q.aspect);
        st.mean_aspect += q.aspect;
        let v = dot(sub(p[1], p[0]), cross(sub(p[2], p[0]), sub(p[3], p[0]))) / 6.0;
        st.min_volume_m3 = st.min_volume_m3.min(v);
    }
    let n = tets.len().max(1) as f64;
    st.mean_dihedral_deg /= n;
    st.mean_min_dihedral_deg /= n;
    st.mean_aspect /= n;
    st
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn regular_tetrahedron_has_unit_aspect_and_70_53_degree_dihedrals() {
        let p = [
            [1.0, 1.0, 1.0],
            [1.0, -1.0, -1.0],
            [-1.0, 1.0, -1.0],
            [-1.0, -1.0, 1.0],
        ];
        let q = tet_quality(p);
        let exact = (1.0f64 / 3.0).acos().to_degrees();
        assert!((q.min_dihedral_deg - exact).abs() < 1e-9);
        assert!((q.max_dihedral_deg - exact).abs() < 1e-9);
        assert!((q.aspect - 1.0).abs() < 1e-12);
    }

    #[test]
    fn kuhn_simplex_dihedrals_are_45_60_90() {
        let q = tet_quality([
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [1.0, 1.0, 1.0],
        ]);
        assert!((q.min_dihedral_deg - 45.0).abs() < 1e-9, "{q:?}");
        assert!((q.max_dihedral_deg - 90.0).abs() < 1e-9, "{q:?}");
    }
}
