//! Structured verification meshes: a thick-walled sphere octant with symmetry planes and a
//! plane-strain thick cylinder ring. Both are layers of prisms split into three tetrahedra each by
//! the vertex-index rule, which keeps neighbouring prisms conforming.

use super::element::{cross, dot, sub};
use super::pressure::CavitySurface;
use crate::mesh::signed_tet_volume;

/// A generated verification case.
#[derive(Debug, Clone)]
pub struct TestCase {
    /// Rest positions.
    pub positions_m: Vec<[f64; 3]>,
    /// Positively oriented tetrahedra.
    pub tets: Vec<[u32; 4]>,
    /// Fixed degrees of freedom (symmetry rollers / plane strain).
    pub fixed_dofs: Vec<bool>,
    /// The loaded cavity, closed.
    pub cavity: CavitySurface,
    /// Factor from the meshed cavity volume to the full cavity (8 for an octant).
    pub volume_factor: f64,
}

/// Splits the prism over the surface triangle `tri` between layers `l` and `l+1` (surface vertex
/// count `ns`) into three positively oriented tetrahedra.
fn prism_tets(tri: [u32; 3], l: u32, ns: u32, x: &[[f64; 3]], out: &mut Vec<[u32; 4]>) {
    let mut s = tri;
    s.sort_unstable();
    let lo = |i: u32| l * ns + i;
    let hi = |i: u32| (l + 1) * ns + i;
    let (a, b, c) = (s[0], s[1], s[2]);
    // The quad face over edge (i, j), i < j, is split along lo(i)-hi(j): decided by the face alone.
    for mut t in [
        [lo(a), lo(b), lo(c), hi(c)],
        [lo(a), lo(b), hi(b), hi(c)],
        [lo(a), hi(a), hi(b), hi(c)],
    ] {
        let p = t.map(|i| x[i as usize]);
        if signed_tet_volume(p[0], p[1], p[2], p[3]) < 0.0 {
            t.swap(2, 3);
        }
        out.push(t);
    }
}

/// Octant `x, y, z >= 0` of a sphere with inner radius `inner` and outer radius `outer`:
/// `surface_divisions` edges along each octant arc, `layers` elements through the wall. Rollers on
/// the three symmetry planes; the cavity is the inner surface closed by fans from the origin
/// (which add no volume), so `8 x` its volume is the full cavity.
pub fn thick_sphere_octant(
    inner: f64,
    outer: f64,
    surface_divisions: usize,
    layers: usize,
) -> TestCase {
    let n = surface_divisions.max(1);
    let m = layers.max(1);
    // Surface vertices on the barycentric grid of the octant triangle, projected on the sphere.
    let mut index = vec![vec![u32::MAX; n + 1]; n + 1];
    let mut dirs = Vec::new();
    for i in 0..=n {
        for j in 0..=(n - i) {
            let k = n - i - j;
            let w = [i, j, k].map(|q| q as f64);
            let len = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
            index[i][j] = dirs.len() as u32;
            dirs.push([w[0] / len, w[1] / len, w[2] / len]);
        }
    }
    let mut tris = Vec::new();
    for i in 0..n {
        for j in 0..(n - i) {
            tris.push([index[i][j], index[i + 1][j], index[i][j + 1]]);
            if i + j + 1 < n {
                tris.push([index[i + 1][j], index[i + 1][j + 1], index[i][j + 1]]);
            }
        }
    }
    let ns = dirs.len() as u32;
    let mut positions = Vec::with_capacity(dirs.len() * (m + 1));
    for l in 0..=m {
        // Geometric grading: equal h/r through the wall, where u ~ 1/r^2 varies fastest inside.
        let r = inner * (outer / inner).powf(l as f64 / m as f64);
        for d in &dirs {
            positions.push(d.map(|c| c * r));
        }
    }
    let mut tets = Vec::new();
    for l in 0..m as u32 {
        for &t in &tris {
            prism_tets(t, l, ns, &positions, &mut tets);
        }
    }
    let mut fixed = vec![false; 3 * positions.len()];
    for (i, p) in positions.iter().enumerate() {
        for k in 0..3 {
            if p[k].abs() < 1e-12 * outer {
                fixed[3 * i + k] = true;
            }
        }
    }
    // Inner surface with normals into the fluid (towards the origin).
    let cavity_tris: Vec<[u32; 3]> = tris
        .iter()
        .map(|&t| {
            let p = t.map(|i| positions[i as usize]);
            let nrm = cross(sub(p[1], p[0]), sub(p[2], p[0]));
            if dot(nrm, p[0]) > 0.0 {
                [t[0], t[2], t[1]]
            } else {
                t
            }
        })
        .collect();
    TestCase {
        positions_m: positions,
        tets,
        fixed_dofs: fixed,
        cavity: CavitySurface::with_fixed_cap(cavity_tris, [0.0; 3]),
        volume_factor: 8.0,
    }
}

/// Mid-edge node of a sphere mesh centred at the origin, on the exact geometry: direction the
/// normalised mean of the ends' directions, radius the mean of their radii (a surface edge's node
/// lies on its sphere; symmetry-plane edges stay in their plane). For
/// [`crate::fem::FemModel::to_tet10`].
pub fn spherical_midpoint(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    let (ra, rb) = (dot(a, a).sqrt(), dot(b, b).sqrt());
    let d: [f64; 3] = std::array::from_fn(|k| a[k] / ra + b[k] / rb);
    let len = dot(d, d).sqrt();
    d.map(|c| c / len * 0.5 * (ra + rb))
}

/// Mid-edge node of a cylinder mesh around the z axis, on the exact geometry (angle and radius
/// averaged, z linear).
pub fn cylindrical_midpoint(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    let (ra, rb) = (a[0].hypot(a[1]), b[0].hypot(b[1]));
    let (dx, dy) = (a[0] / ra + b[0] / rb, a[1] / ra + b[1] / rb);
    let len = dx.hypot(dy);
    let r = 0.5 * (ra + rb);
    [dx / len * r, dy / len * r, 0.5 * (a[2] + b[2])]
}

/// A full ring of a thick cylinder (radii `inner`, `outer`), one element layer of height
/// `height` in z with every z fixed (plane strain); `ux = 0` on the plane x = 0 and `uy = 0` on
/// y = 0 remove the rigid modes without constraining the axisymmetric solution. The cavity is the
/// inner lateral surface closed by a centroid fan at each end.
pub fn thick_cylinder_ring(
    inner: f64,
    outer: f64,
    height: f64,
    circumferential: usize,
    radial: usize,
) -> TestCase {
    let nc = circumferential.max(4).div_ceil(4) * 4;
    let m = radial.max(1);
    let mut pts2 = Vec::new();
    for k in 0..=m {
        let r = inner * (outer / inner).powf(k as f64 / m as f64);
        for c in 0..nc {
            let th = 2.0 * std::f64::consts::PI * c as f64 / nc as f64;
            pts2.push([r * th.cos(), r * th.sin()]);
        }
    }
    let id = |k: usize, c: usize| (k * nc + c % nc) as u32;
    let mut tris = Vec::new();
    for k in 0..m {
        for c in 0..nc {
            let (a, b, cc, d) = (id(k, c), id(k, c + 1), id(k + 1, c + 1), id(k + 1, c));
            if (k + c) % 2 == 0 {
                tris.push([a, b, cc]);
                tris.push([a, cc, d]);
            } else {
                tris.push([a, b, d]);
                tris.push([b, cc, d]);
            }
        }
    }
    let ns = pts2.len() as u32;
    let mut positions = Vec::new();
    for z in [0.0, height] {
        for p in &pts2 {
            positions.push([p[0], p[1], z]);
        }
    }
    let mut tets = Vec::new();
    for &t in &tris {
        prism_tets(t, 0, ns, &positions, &mut tets);
    }
    let mut fixed = vec![false; 3 * positions.len()];
    for (i, p) in positions.iter().enumerate() {
        fixed[3 * i + 2] = true;
        if p[0].abs() < 1e-12 * outer {
            fixed[3 * i] = true;
        }
        if p[1].abs() < 1e-12 * outer {
            fixed[3 * i + 1] = true;
        }
    }
    // Inner lateral quads split like the prisms' faces (diagonal lo(min)-hi(max)), normals inward.
    let mut cavity_tris = Vec::new();
    for c in 0..nc {
        let (i, j) = (id(0, c), id(0, c + 1));
        let (a, b) = (i.min(j), i.max(j));
        for t in [[a, b, b + ns], [a, b + ns, a + ns]] {
            let p = t.map(|q| positions[q as usize]);
            let nrm = cross(sub(p[1], p[0]), sub(p[2], p[0]));
            let radial = [p[0][0], p[0][1], 0.0];
            cavity_tris.push(if dot(nrm, radial) > 0.0 {
                [t[0], t[2], t[1]]
            } else {
                t
            });
        }
    }
    TestCase {
        positions_m: positions,
        tets,
        fixed_dofs: fixed,
        cavity: CavitySurface::with_loop_caps(cavity_tris),
        volume_factor: 1.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sphere_octant_is_valid_and_encloses_an_eighth_ball() {
        let c = thick_sphere_octant(1.0, 2.0, 12, 4);
        let vol: f64 = c
            .tets
            .iter()
            .map(|t| {
                let p = t.map(|i| c.positions_m[i as usize]);
                let v = signed_tet_volume(p[0], p[1], p[2], p[3]);
                assert!(v > 0.0);
                v
            })
            .sum();
        let exact_shell = 4.0 / 3.0 * std::f64::consts::PI * (8.0 - 1.0) / 8.0;
        assert!(
            (vol / exact_shell - 1.0).abs() < 0.02,
            "shell volume {vol} vs {exact_shell}"
        );
        let cav = c.cavity.volume(&c.positions_m) * c.volume_factor;
        let exact = 4.0 / 3.0 * std::f64::consts::PI;
        assert!((cav / exact - 1.0).abs() < 0.02, "cavity {cav} vs {exact}");
    }

    #[test]
    fn cylinder_ring_cavity_is_the_polygon_area_times_height() {
        let c = thick_cylinder_ring(1.0, 2.0, 0.1, 32, 4);
        let cav = c.cavity.volume(&c.positions_m);
        let polygon = 0.5 * 32.0 * (2.0 * std::f64::consts::PI / 32.0).sin();
        assert!((cav - polygon * 0.1).abs() < 1e-12, "{cav}");
        assert_eq!(c.cavity.caps.len(), 2);
    }
}
