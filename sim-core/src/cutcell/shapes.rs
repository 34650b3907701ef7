//! Closed meshes of analytic shapes, tessellated for a grid spacing.
//!
//! The rule ([`Tessellation::for_spacing`]): facets whose edges subtend at most `max_edge_m / R`
//! radians, with `max_edge_m = h / 2`, so the polygon stays within the sagitta
//! `max_edge_m^2 / (8 R) = h^2 / (32 R)` of the analytic surface (a relative deviation of
//! `(h / R)^2 / 32`: second order in `h`, a thirty-second of the grid's own second-order term);
//! and the vertices sit on a radius scaled so that the polygon's **volume** (sphere) or
//! **cross-section area** (cylinder, hence its volume too) equals the analytic one exactly, up
//! to the rounding of the vertices to f32 (about 1e-7 relative). A cylinder's side is exact
//! along its axis; it is cut into lengths of at most `8 max_edge_m` only so that each
//! triangle's box stays small.

use super::mesh::{ClosedMesh, Location, MeshError};
use crate::mesh::{cross, dot, sub};
use std::collections::HashMap;
use std::f64::consts::PI;

/// Most triangles a shape may have.
pub const MAX_TRIANGLES: usize = 4_000_000;

/// How finely an analytic shape is tessellated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tessellation {
    /// Longest arc between neighbouring vertices around the shape, m.
    pub max_edge_m: f64,
    /// Scale the vertices' radius so the polygon's volume (sphere) or cross-section (cylinder)
    /// equals the analytic one; otherwise the vertices lie on the analytic surface (inscribed).
    pub match_volume: bool,
}

impl Tessellation {
    /// The rule for a grid of spacing `h`: edges of at most `h / 2`, volume matched.
    pub fn for_spacing(spacing_m: f64) -> Self {
        Self {
            max_edge_m: 0.5 * spacing_m,
            match_volume: true,
        }
    }
}

fn bad(origin: &str, what: String) -> MeshError {
    MeshError::Whole {
        origin: origin.to_string(),
        what,
    }
}

fn check_positive(origin: &str, key: &str, x: f64) -> Result<(), MeshError> {
    if x.is_finite() && x > 0.0 {
        Ok(())
    } else {
        Err(bad(
            origin,
            format!("{key} = {x}: expected a finite value > 0"),
        ))
    }
}

fn check_point(origin: &str, key: &str, p: [f64; 3]) -> Result<(), MeshError> {
    if p.iter().all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err(bad(
            origin,
            format!("{key} = {p:?}: expected finite coordinates"),
        ))
    }
}

/// The sphere of `radius_m` about `centre_m`, tessellated for `t`: a cube's faces divided into
/// `m x m` squares (equal angles), projected onto the sphere, two triangles per square.
pub fn sphere(centre_m: [f64; 3], radius_m: f64, t: Tessellation) -> Result<ClosedMesh, MeshError> {
    const ORIGIN: &str = "sphere";
    check_point(ORIGIN, "centre_m", centre_m)?;
    check_positive(ORIGIN, "radius_m", radius_m)?;
    check_positive(ORIGIN, "max_edge_m", t.max_edge_m)?;
    // A cube face spans a quarter of a great circle.
    let m = (0.5 * PI * radius_m / t.max_edge_m).ceil().max(2.0);
    if 12.0 * m * m > MAX_TRIANGLES as f64 {
        return Err(bad(
            ORIGIN,
            format!(
                "radius_m = {radius_m} with edges of {} m needs more than {MAX_TRIANGLES} \
                 triangles",
                t.max_edge_m
            ),
        ));
    }
    let m = m as usize;
    let mut unit: Vec<[f64; 3]> = Vec::with_capacity(6 * m * m + 2);
    let mut key: HashMap<[usize; 3], u32> = HashMap::with_capacity(6 * m * m + 2);
    let mut vertex = |lattice: [usize; 3]| -> u32 {
        *key.entry(lattice).or_insert_with(|| {
            let c = lattice.map(|l| (0.25 * PI * (2.0 * l as f64 / m as f64 - 1.0)).tan());
            let r = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
            unit.push(c.map(|x| x / r));
            (unit.len() - 1) as u32
        })
    };
    let mut triangles = Vec::with_capacity(12 * m * m);
    for axis in 0..3 {
        for side in [0, m] {
            let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
            for u in 0..m {
                for v in 0..m {
                    let at = |du: usize, dv: usize| {
                        let mut l = [0; 3];
                        l[axis] = side;
                        l[a] = u + du;
                        l[b] = v + dv;
                        l
                    };
                    let q = [at(0, 0), at(1, 0), at(1, 1), at(0, 1)].map(&mut vertex);
                    triangles.push([q[0], q[1], q[2]]);
                    triangles.push([q[0], q[2], q[3]]);
                }
            }
        }
    }
    // Outward: the normal along the centroid's direction.
    for tri in &mut triangles {
        let [p, q, r] = tri.map(|i| unit[i as usize]);
        let n = cross(sub(q, p), sub(r, p));
        let c = [p[0] + q[0] + r[0], p[1] + q[1] + r[1], p[2] + q[2] + r[2]];
        if dot(n, c) < 0.0 {
            tri.swap(1, 2);
        }
    }
    let scale = if t.match_volume {
        let v1 = volume(&unit, &triangles);
        radius_m * (4.0 / 3.0 * PI / v1).cbrt()
    } else {
        radius_m
    };
    let positions = unit
        .iter()
        .map(|p| std::array::from_fn(|a| (centre_m[a] + scale * p[a]) as f32))
        .collect();
    ClosedMesh::from_parts(ORIGIN, positions, triangles, &Location::Triangle)
}

/// The capped cylinder of `radius_m` and `length_m` about `centre_m` along `axis` (any
/// non-zero direction), tessellated for `t`: `n` sides around, flat caps fanned from their
/// centres.
pub fn cylinder(
    centre_m: [f64; 3],
    axis: [f64; 3],
    radius_m: f64,
    length_m: f64,
    t: Tessellation,
) -> Result<ClosedMesh, MeshError> {
    const ORIGIN: &str = "cylinder";
    check_point(ORIGIN, "centre_m", centre_m)?;
    check_point(ORIGIN, "axis", axis)?;
    check_positive(ORIGIN, "radius_m", radius_m)?;
    check_positive(ORIGIN, "length_m", length_m)?;
    check_positive(ORIGIN, "max_edge_m", t.max_edge_m)?;
    let norm = dot(axis, axis).sqrt();
    if !(norm > 0.0 && norm.is_finite()) {
        return Err(bad(
            ORIGIN,
            format!("axis = {axis:?}: expected a non-zero direction"),
        ));
    }
    let a = axis.map(|x| x / norm);
    let n = (2.0 * PI * radius_m / t.max_edge_m).ceil().max(12.0);
    let rings = (length_m / (8.0 * t.max_edge_m)).ceil().max(1.0);
    if n * (2.0 * rings + 2.0) > MAX_TRIANGLES as f64 {
        return Err(bad(
            ORIGIN,
            format!(
                "radius_m = {radius_m}, length_m = {length_m} with edges of {} m needs more \
                 than {MAX_TRIANGLES} triangles",
                t.max_edge_m
            ),
        ));
    }
    let (n, rings) = (n as usize, rings as usize);
    // (u, w, a) right-handed.
    let least = (0..3)
        .min_by(|&i, &j| a[i].abs().total_cmp(&a[j].abs()))
        .unwrap_or(0);
    let mut e = [0.0; 3];
    e[least] = 1.0;
    let u = {
        let c = cross(a, e);
        let l = dot(c, c).sqrt();
        c.map(|x| x / l)
    };
    let w = cross(a, u);
    let r = if t.match_volume {
        // The n-gon of circumradius r has area n r^2 sin(2 pi / n) / 2.
        radius_m * (2.0 * PI / (n as f64 * (2.0 * PI / n as f64).sin())).sqrt()
    } else {
        radius_m
    };
    let mut positions: Vec<[f32; 3]> = Vec::with_capacity((rings + 1) * n + 2);
    let point = |s: f64, c: f64, sn: f64| -> [f32; 3] {
        std::array::from_fn(|k| (centre_m[k] + s * a[k] + r * (c * u[k] + sn * w[k])) as f32)
    };
    for ring in 0..=rings {
        let s = length_m * (ring as f64 / rings as f64 - 0.5);
        for i in 0..n {
            let th = 2.0 * PI * i as f64 / n as f64;
            positions.push(point(s, th.cos(), th.sin()));
        }
    }
    let bottom = positions.len() as u32;
    positions.push(point(-0.5 * length_m, 0.0, 0.0));
    positions.push(point(0.5 * length_m, 0.0, 0.0));
    let top = bottom + 1;
    let at = |ring: usize, i: usize| (ring * n + i % n) as u32;
    let mut triangles = Vec::with_capacity(2 * n * rings + 2 * n);
    for ring in 0..rings {
        for i in 0..n {
            triangles.push([at(ring, i), at(ring, i + 1), at(ring + 1, i + 1)]);
            triangles.push([at(ring, i), at(ring + 1, i + 1), at(ring + 1, i)]);
        }
    }
    for i in 0..n {
        triangles.push([top, at(rings, i), at(rings, i + 1)]);
        triangles.push([bottom, at(0, i + 1), at(0, i)]);
    }
    ClosedMesh::from_parts(ORIGIN, positions, triangles, &Location::Triangle)
}

fn volume(p: &[[f64; 3]], triangles: &[[u32; 3]]) -> f64 {
    triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| p[i as usize]);
            dot(a, cross(b, c))
        })
        .sum::<f64>()
        / 6.0
}

/// The hexahedron of eight corners (corner `v` is on the upper side along axis `a` where bit `a`
/// of `v` is set: a box, or a box turned or sheared), two triangles per face, outward.
pub fn hexahedron(origin: &str, corners_m: [[f64; 3]; 8]) -> Result<ClosedMesh, MeshError> {
    let positions = corners_m.iter().map(|c| c.map(|x| x as f32)).collect();
    let quads = [
        [0, 2, 6, 4],
        [1, 5, 7, 3],
        [0, 4, 5, 1],
        [2, 3, 7, 6],
        [0, 1, 3, 2],
        [4, 6, 7, 5],
    ];
    let triangles = quads
        .iter()
        .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
        .collect();
    ClosedMesh::new(origin, positions, triangles)
}
