//! Lattice mesher: a Kuhn (Freudenthal) cube lattice whose plane y = 0 is a lattice plane, and the
//! insertion of an implicit surface into a tetrahedral mesh by warping and edge splitting.
//!
//! Insertion (after Labelle & Shewchuk's isosurface stuffing, with edge splits instead of their
//! stencil table): on every mesh edge the field changes sign across, the crossing point is found;
//! a vertex closer than `alpha` (fraction of the edge) to a crossing is warped onto it; every
//! remaining crossed edge is split at its crossing in all tetrahedra that contain it. Splitting
//! edges in one global order makes shared faces split identically on both sides, so the result is
//! conforming, and afterwards no edge has a strict sign change: every tetrahedron lies on one side.

use std::collections::HashMap;

/// A tetrahedral mesh under construction (positions in metres).
#[derive(Debug, Clone, Default)]
pub(crate) struct WorkMesh {
    pub pos: Vec<[f64; 3]>,
    pub tets: Vec<[u32; 4]>,
}

/// Builds the Kuhn lattice with spacing `h` over the box, keeping the cubes with a corner where
/// `inside(p) < 0`. Lattice points lie at integer multiples of `h`, so x = 0 and y = 0 are lattice
/// planes.
pub(crate) fn kuhn_lattice(
    inside: &dyn Fn([f64; 3]) -> f64,
    lo: [f64; 3],
    hi: [f64; 3],
    h: f64,
) -> WorkMesh {
    let i0 = [0, 1, 2].map(|k| (lo[k] / h).floor() as i64 - 1);
    let i1 = [0, 1, 2].map(|k| (hi[k] / h).ceil() as i64 + 1);
    let n = [0, 1, 2].map(|k| (i1[k] - i0[k] + 1) as usize);
    let idx = |i: usize, j: usize, k: usize| (k * n[1] + j) * n[0] + i;
    let point = |i: usize, j: usize, k: usize| {
        [
            (i0[0] + i as i64) as f64 * h,
            (i0[1] + j as i64) as f64 * h,
            (i0[2] + k as i64) as f64 * h,
        ]
    };
    let mut value = vec![0.0; n[0] * n[1] * n[2]];
    for k in 0..n[2] {
        for j in 0..n[1] {
            for i in 0..n[0] {
                value[idx(i, j, k)] = inside(point(i, j, k));
            }
        }
    }
    let mut id = vec![u32::MAX; value.len()];
    let mut mesh = WorkMesh::default();
    const PERMS: [[usize; 3]; 6] = [
        [0, 1, 2],
        [0, 2, 1],
        [1, 0, 2],
        [1, 2, 0],
        [2, 0, 1],
        [2, 1, 0],
    ];
    for k in 0..n[2] - 1 {
        for j in 0..n[1] - 1 {
            for i in 0..n[0] - 1 {
                let mut any_inside = false;
                for c in 0..8 {
                    let v = value[idx(i + (c & 1), j + ((c >> 1) & 1), k + ((c >> 2) & 1))];
                    any_inside |= v < 0.0;
                }
                if !any_inside {
                    continue;
                }
                for perm in PERMS {
                    let mut c = [i, j, k];
                    let mut verts = [0u32; 4];
                    for (s, vert) in verts.iter_mut().enumerate() {
                        if s > 0 {
                            c[perm[s - 1]] += 1;
                        }
                        let g = idx(c[0], c[1], c[2]);
                        if id[g] == u32::MAX {
                            id[g] = mesh.pos.len() as u32;
                            mesh.pos.push(point(c[0], c[1], c[2]));
                        }
                        *vert = id[g];
                    }
                    orient(&mesh.pos, &mut verts);
                    mesh.tets.push(verts);
                }
            }
        }
    }
    mesh
}

/// Reorders a tetrahedron to positive orientation.
pub(crate) fn orient(pos: &[[f64; 3]], t: &mut [u32; 4]) {
    if volume6(pos, t) < 0.0 {
        t.swap(2, 3);
    }
}

/// Six times the signed volume.
pub(crate) fn volume6(pos: &[[f64; 3]], t: &[u32; 4]) -> f64 {
    let [a, b, c, d] = t.map(|i| pos[i as usize]);
    let u = sub(b, a);
    let v = sub(c, a);
    let w = sub(d, a);
    dot(u, cross(v, w))
}

pub(crate) use crate::mesh::{cross, dot, sub};
pub(crate) fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}
pub(crate) fn lerp(a: [f64; 3], b: [f64; 3], t: f64) -> [f64; 3] {
    [
        a[0] + t * (b[0] - a[0]),
        a[1] + t * (b[1] - a[1]),
        a[2] + t * (b[2] - a[2]),
    ]
}

/// The six edges of a tetrahedron as local index pairs.
pub(crate) const TET_EDGES: [(usize, usize); 6] = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)];

/// Sorted, deduplicated edges of a tetrahedral mesh.
pub(crate) fn unique_edges(tets: &[[u32; 4]]) -> Vec<(u32, u32)> {
    let mut edges: Vec<(u32, u32)> = Vec::with_capacity(tets.len() * 6);
    for t in tets {
        for (i, j) in TET_EDGES {
            let (a, b) = (t[i].min(t[j]), t[i].max(t[j]));
            edges.push((a, b));
        }
    }
    edges.sort_unstable();
    edges.dedup();
    edges
}

/// How to insert one implicit surface.
pub(crate) struct Insertion<'a> {
    /// The field whose zero set is inserted.
    pub field: &'a dyn Fn([f64; 3]) -> f64,
    /// Warp threshold as a fraction of the edge length (< 0.5).
    pub alpha: f64,
    /// Whether a vertex may be warped to the given point.
    pub movable: &'a dyn Fn(u32, [f64; 3]) -> bool,
    /// Whether an edge may be cut (both endpoints given).
    pub edge_ok: &'a dyn Fn(u32, u32) -> bool,
    /// A vertex that is too close to a crossing but may not move is declared on the surface
    /// (value 0) where it is, instead of splitting a sliver off next to it.
    pub pin_unmovable: bool,
}

/// Result of an insertion: the field's value at every vertex (exactly 0 on the inserted surface).
pub(crate) struct Inserted {
    pub values: Vec<f64>,
}

/// Inserts the zero set of `ins.field` into `mesh` (see the module docs).
pub(crate) fn insert_surface(mesh: &mut WorkMesh, ins: &Insertion<'_>, tol: f64) -> Inserted {
    let f = ins.field;
    let mut values: Vec<f64> = mesh
        .pos
        .iter()
        .map(|&p| {
            let v = f(p);
            if v.abs() < tol {
                0.0
            } else {
                v
            }
        })
        .collect();
    let edges = unique_edges(&mesh.tets);
    // Crossings: (edge, fraction from the smaller id, point).
    let mut crossings: Vec<((u32, u32), f64, [f64; 3])> = Vec::new();
    for &(a, b) in &edges {
        let (va, vb) = (values[a as usize], values[b as usize]);
        if va * vb < 0.0 && (ins.edge_ok)(a, b) {
            let (pa, pb) = (mesh.pos[a as usize], mesh.pos[b as usize]);
            let t = root(|t| f(lerp(pa, pb, t)), va, vb);
            crossings.push(((a, b), t, lerp(pa, pb, t)));
        }
    }
    // Warping: each vertex goes to its nearest violating crossing.
    let mut best: HashMap<u32, (f64, [f64; 3])> = HashMap::new();
    let mut pinned: Vec<u32> = Vec::new();
    for &((a, b), t, p) in &crossings {
        for (v, frac) in [(a, t), (b, 1.0 - t)] {
            if frac < ins.alpha {
                if (ins.movable)(v, p) {
                    let e = best.entry(v).or_insert((f64::INFINITY, p));
                    if frac < e.0 {
                        *e = (frac, p);
                    }
                } else if ins.pin_unmovable {
                    pinned.push(v);
                }
            }
        }
    }
    for v in pinned {
        values[v as usize] = 0.0;
    }
    let mut warped: Vec<(u32, [f64; 3])> = best.into_iter().map(|(v, (_, p))| (v, p)).collect();
    warped.sort_unstable_by_key(|w| w.0);
    for &(v, p) in &warped {
        mesh.pos[v as usize] = p;
        values[v as usize] = 0.0;
    }
    // Splits at the crossings that remain.
    let mut splits: HashMap<(u32, u32), u32> = HashMap::new();
    for &((a, b), _, p) in &crossings {
        if values[a as usize] * values[b as usize] < 0.0 {
            splits.insert((a, b), mesh.pos.len() as u32);
            mesh.pos.push(p);
            values.push(0.0);
        }
    }
    if !splits.is_empty() {
        let mut out = Vec::with_capacity(mesh.tets.len() + 4 * splits.len());
        for &t in &mesh.tets {
            split_tet(t, &splits, &mut out);
        }
        mesh.tets = out;
    }
    Inserted { values }
}

/// Splits edge (a, b) at `point` in every tetrahedron containing it; returns the new vertex.
/// `point` should lie near the segment (the caller checks the resulting elements).
pub(crate) fn split_edge(mesh: &mut WorkMesh, a: u32, b: u32, point: [f64; 3]) -> u32 {
    let m = mesh.pos.len() as u32;
    mesh.pos.push(point);
    let mut out = Vec::with_capacity(mesh.tets.len() + 8);
    for &t in &mesh.tets {
        match (
            t.iter().position(|&v| v == a),
            t.iter().position(|&v| v == b),
        ) {
            (Some(i), Some(j)) => {
                let mut t1 = t;
                t1[j] = m;
                let mut t2 = t;
                t2[i] = m;
                out.push(t1);
                out.push(t2);
            }
            _ => out.push(t),
        }
    }
    mesh.tets = out;
    m
}

/// Splits `t` at the split edges it contains, smallest edge first, recursively.
fn split_tet(t: [u32; 4], splits: &HashMap<(u32, u32), u32>, out: &mut Vec<[u32; 4]>) {
    let mut best: Option<((u32, u32), usize, usize, u32)> = None;
    for (i, j) in TET_EDGES {
        let key = (t[i].min(t[j]), t[i].max(t[j]));
        if let Some(&m) = splits.get(&key) {
            if best.is_none_or(|b| key < b.0) {
                best = Some((key, i, j, m));
            }
        }
    }
    match best {
        None => out.push(t),
        Some((_, i, j, m)) => {
            let mut t1 = t;
            t1[j] = m;
            let mut t2 = t;
            t2[i] = m;
            split_tet(t1, splits, out);
            split_tet(t2, splits, out);
        }
    }
}

/// Root of `f` on (0, 1) given opposite-signed end values (Illinois false position).
fn root(f: impl Fn(f64) -> f64, fa: f64, fb: f64) -> f64 {
    let (mut a, mut b, mut fa, mut fb) = (0.0, 1.0, fa, fb);
    let mut side = 0;
    let mut c = 0.5;
    for _ in 0..60 {
        c = (a * fb - b * fa) / (fb - fa);
        if !(c > a && c < b) {
            c = 0.5 * (a + b);
        }
        let fc = f(c);
        if fc == 0.0 || (b - a) < 1e-12 {
            break;
        }
        if fc * fb > 0.0 {
            b = c;
            fb = fc;
            if side == -1 {
                fa *= 0.5;
            }
            side = -1;
        } else {
            a = c;
            fa = fc;
            if side == 1 {
                fb *= 0.5;
            }
            side = 1;
        }
    }
    c.clamp(1e-6, 1.0 - 1e-6)
}

/// Faces that belong to exactly one tetrahedron (the mesh boundary), each as the sorted triple.
pub(crate) fn boundary_faces(tets: &[[u32; 4]]) -> Vec<[u32; 3]> {
    let mut faces: Vec<[u32; 3]> = Vec::with_capacity(tets.len() * 4);
    for t in tets {
        for skip in 0..4 {
            let mut f = [0u32; 3];
            let mut n = 0;
            for (k, &v) in t.iter().enumerate() {
                if k != skip {
                    f[n] = v;
                    n += 1;
                }
            }
            f.sort_unstable();
            faces.push(f);
        }
    }
    faces.sort_unstable();
    let mut out = Vec::new();
    let mut i = 0;
    while i < faces.len() {
        let mut j = i + 1;
        while j < faces.len() && faces[j] == faces[i] {
            j += 1;
        }
        if j - i == 1 {
            out.push(faces[i]);
        }
        i = j;
    }
    out
}

/// Drops unused vertices and renumbers; returns the old id of every kept vertex.
pub(crate) fn compact(mesh: &mut WorkMesh) -> Vec<u32> {
    let mut new_id = vec![u32::MAX; mesh.pos.len()];
    let mut old_of_new = Vec::new();
    for t in &mut mesh.tets {
        for v in t.iter_mut() {
            if new_id[*v as usize] == u32::MAX {
                new_id[*v as usize] = old_of_new.len() as u32;
                old_of_new.push(*v);
            }
            *v = new_id[*v as usize];
        }
    }
    mesh.pos = old_of_new.iter().map(|&o| mesh.pos[o as usize]).collect();
    old_of_new
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sphere_insertion_is_conforming_and_positive() {
        let r = 1.0;
        let sphere = |p: [f64; 3]| norm(p) - r;
        let h = 0.17;
        let mut m = kuhn_lattice(&sphere, [-r; 3], [r; 3], h);
        let ins = insert_surface(
            &mut m,
            &Insertion {
                field: &sphere,
                alpha: 0.3,
                movable: &|_, _| true,
                edge_ok: &|_, _| true,
                pin_unmovable: false,
            },
            1e-12,
        );
        m.tets.retain(|t| {
            t.iter().any(|&v| ins.values[v as usize] < 0.0)
                || (t.iter().all(|&v| ins.values[v as usize] == 0.0) && {
                    let c = t.iter().fold([0.0; 3], |a, &v| {
                        let p = m.pos[v as usize];
                        [a[0] + p[0] / 4.0, a[1] + p[1] / 4.0, a[2] + p[2] / 4.0]
                    });
                    sphere(c) < 0.0
                })
        });
        compact(&mut m);
        let vol: f64 = m.tets.iter().map(|t| volume6(&m.pos, t) / 6.0).sum();
        for t in &m.tets {
            assert!(volume6(&m.pos, t) > 0.0);
        }
        // Boundary vertices lie on the sphere; the volume is that of the inscribed polyhedron.
        for f in boundary_faces(&m.tets) {
            for v in f {
                assert!((norm(m.pos[v as usize]) - r).abs() < 1e-9);
            }
        }
        let exact = 4.0 / 3.0 * std::f64::consts::PI;
        assert!(vol < exact && vol > 0.97 * exact, "volume {vol} vs {exact}");
    }
}
