//! The follower pressure load as the conservative potential `-p V(x)` of the closed cavity.
//!
//! The cavity volume is `V = -(1/6) sum det[x0, x1, x2]` over the cavity triangles (normals into
//! the fluid) plus cap triangles `(c, b, a)` over each boundary half-edge `a -> b`, where the cap
//! centre `c` is a fixed point or the centroid of a loop of vertices that moves with them. Its
//! gradient is the nodal pressure force per unit pressure and its Hessian the load stiffness, which
//! is symmetric because the load is conservative.

use super::element::{cross, skew};
use crate::mesh::TetMesh;
use std::collections::{HashMap, HashSet};

/// Centre of a cap fan closing an opening of the cavity surface.
#[derive(Debug, Clone, PartialEq)]
pub enum CapCentre {
    /// A fixed point (e.g. the centre of a symmetry-plane octant: its fan has zero volume).
    Fixed([f64; 3]),
    /// The centroid of these vertices, moving with them.
    Centroid(Vec<u32>),
}

/// A fan of triangles closing one opening.
#[derive(Debug, Clone, PartialEq)]
pub struct Cap {
    /// Fan centre.
    pub centre: CapCentre,
    /// Boundary half-edges `a -> b` of the cavity surface; the cap triangle is `(c, b, a)`.
    pub edges: Vec<(u32, u32)>,
}

/// The closed cavity surface on which the pressure acts.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct CavitySurface {
    /// Cavity triangles with right-hand normals into the fluid.
    pub triangles: Vec<[u32; 3]>,
    /// Caps closing the openings.
    pub caps: Vec<Cap>,
    /// Quadratic (6-node) cavity triangles `[v0, v1, v2, m01, m12, m20]` of a 10-node mesh; when
    /// present they replace `triangles` (their corners) in the volume and its derivatives.
    pub quadratic: Vec<[u32; 6]>,
}

#[derive(Clone, Copy)]
enum Operand<'a> {
    Node(u32),
    Centroid(&'a [u32]),
    Fixed([f64; 3]),
    /// A fixed linear combination of six nodes (a quadratic triangle at a quadrature point).
    Combo([u32; 6], [f64; 6]),
}

/// 6-point degree-4 rule on the triangle (Dunavant): barycentric points and weights summing to 1.
const TRI6: [([f64; 3], f64); 6] = [
    (
        [
            0.445_948_490_915_965,
            0.445_948_490_915_965,
            0.108_103_018_168_07,
        ],
        0.223_381_589_678_011,
    ),
    (
        [
            0.445_948_490_915_965,
            0.108_103_018_168_07,
            0.445_948_490_915_965,
        ],
        0.223_381_589_678_011,
    ),
    (
        [
            0.108_103_018_168_07,
            0.445_948_490_915_965,
            0.445_948_490_915_965,
        ],
        0.223_381_589_678_011,
    ),
    (
        [
            0.091_576_213_509_771,
            0.091_576_213_509_771,
            0.816_847_572_980_459,
        ],
        0.109_951_743_655_322,
    ),
    (
        [
            0.091_576_213_509_771,
            0.816_847_572_980_459,
            0.091_576_213_509_771,
        ],
        0.109_951_743_655_322,
    ),
    (
        [
            0.816_847_572_980_459,
            0.091_576_213_509_771,
            0.091_576_213_509_771,
        ],
        0.109_951_743_655_322,
    ),
];

/// Weights of `x`, `dx/dxi`, `dx/deta` of a 6-node triangle at barycentric point `l`
/// (`xi = l1`, `eta = l2`), nodes `[v0, v1, v2, m01, m12, m20]`.
fn quadratic_triangle_weights(l: [f64; 3]) -> [[f64; 6]; 3] {
    let [l0, l1, l2] = l;
    let n = [
        l0 * (2.0 * l0 - 1.0),
        l1 * (2.0 * l1 - 1.0),
        l2 * (2.0 * l2 - 1.0),
        4.0 * l0 * l1,
        4.0 * l1 * l2,
        4.0 * l2 * l0,
    ];
    // d/dxi: dl0 = -1, dl1 = 1; d/deta: dl0 = -1, dl2 = 1.
    let dxi = [
        -(4.0 * l0 - 1.0),
        4.0 * l1 - 1.0,
        0.0,
        4.0 * (l0 - l1),
        4.0 * l2,
        -4.0 * l2,
    ];
    let deta = [
        -(4.0 * l0 - 1.0),
        0.0,
        4.0 * l2 - 1.0,
        -4.0 * l1,
        4.0 * l1,
        4.0 * (l0 - l2),
    ];
    [n, dxi, deta]
}

impl Operand<'_> {
    fn value(&self, x: &[[f64; 3]]) -> [f64; 3] {
        match *self {
            Operand::Node(i) => x[i as usize],
            Operand::Fixed(p) => p,
            Operand::Combo(ids, w) => {
                let mut c = [0.0; 3];
                for a in 0..6 {
                    for k in 0..3 {
                        c[k] += w[a] * x[ids[a] as usize][k];
                    }
                }
                c
            }
            Operand::Centroid(ids) => {
                let mut c = [0.0; 3];
                for &i in ids {
                    for k in 0..3 {
                        c[k] += x[i as usize][k];
                    }
                }
                let n = ids.len().max(1) as f64;
                c.map(|v| v / n)
            }
        }
    }
    fn for_each_node(&self, mut f: impl FnMut(u32, f64)) {
        match *self {
            Operand::Node(i) => f(i, 1.0),
            Operand::Fixed(_) => {}
            Operand::Combo(ids, w) => {
                for a in 0..6 {
                    f(ids[a], w[a]);
                }
            }
            Operand::Centroid(ids) => {
                let w = 1.0 / ids.len().max(1) as f64;
                for &i in ids {
                    f(i, w);
                }
            }
        }
    }
}

fn boundary_half_edges(triangles: &[[u32; 3]]) -> Vec<(u32, u32)> {
    let mut set = HashSet::with_capacity(triangles.len() * 3);
    for t in triangles {
        for k in 0..3 {
            set.insert((t[k], t[(k + 1) % 3]));
        }
    }
    let mut out: Vec<(u32, u32)> = set
        .iter()
        .copied()
        .filter(|&(a, b)| !set.contains(&(b, a)))
        .collect();
    out.sort_unstable();
    out
}

impl CavitySurface {
    /// The cavity of a [`TetMesh`]: its triangles closed by one fan from the centroid of the
    /// opening loop over all boundary edges (the same closure as `TetMesh::cavity_volume_m3`).
    pub fn from_mesh(mesh: &TetMesh) -> Self {
        let edges = boundary_half_edges(&mesh.cavity_triangles);
        let caps = if edges.is_empty() {
            Vec::new()
        } else if mesh.cavity_opening_loop.is_empty() {
            vec![Cap {
                centre: CapCentre::Fixed([0.0; 3]),
                edges,
            }]
        } else {
            vec![Cap {
                centre: CapCentre::Centroid(mesh.cavity_opening_loop.clone()),
                edges,
            }]
        };
        Self {
            triangles: mesh.cavity_triangles.clone(),
            caps,
            quadratic: Vec::new(),
        }
    }

    /// Triangles closed by one fan from the fixed point `centre` over all boundary edges.
    pub fn with_fixed_cap(triangles: Vec<[u32; 3]>, centre: [f64; 3]) -> Self {
        let edges = boundary_half_edges(&triangles);
        let caps = if edges.is_empty() {
            Vec::new()
        } else {
            vec![Cap {
                centre: CapCentre::Fixed(centre),
                edges,
            }]
        };
        Self {
            triangles,
            caps,
            quadratic: Vec::new(),
        }
    }

    /// Triangles whose openings (connected groups of boundary edges) are each closed by a fan from
    /// the centroid of the opening's vertices.
    pub fn with_loop_caps(triangles: Vec<[u32; 3]>) -> Self {
        let edges = boundary_half_edges(&triangles);
        // Union-find over the boundary vertices.
        let mut parent: HashMap<u32, u32> = HashMap::new();
        fn find(p: &mut HashMap<u32, u32>, i: u32) -> u32 {
            let mut r = i;
            while let Some(&q) = p.get(&r) {
                if q == r {
                    break;
                }
                r = q;
            }
            p.insert(i, r);
            r
        }
        for &(a, b) in &edges {
            parent.entry(a).or_insert(a);
            parent.entry(b).or_insert(b);
            let ra = find(&mut parent, a);
            let rb = find(&mut parent, b);
            if ra != rb {
                parent.insert(ra, rb);
            }
        }
        type Opening = (Vec<u32>, Vec<(u32, u32)>);
        let mut groups: HashMap<u32, Opening> = HashMap::new();
        for &(a, b) in &edges {
            let r = find(&mut parent, a);
            let g = groups.entry(r).or_default();
            g.1.push((a, b));
            g.0.push(a);
        }
        let mut caps: Vec<Cap> = groups
            .into_values()
            .map(|(mut nodes, edges)| {
                nodes.sort_unstable();
                nodes.dedup();
                Cap {
                    centre: CapCentre::Centroid(nodes),
                    edges,
                }
            })
            .collect();
        caps.sort_by_key(|c| c.edges.first().copied());
        Self {
            triangles,
            caps,
            quadratic: Vec::new(),
        }
    }

    /// The same cavity on a 10-node mesh: each triangle becomes a 6-node triangle with the
    /// mid-edge nodes `mid(a, b)` (keys with `a < b`), and each cap edge `a -> b` is split at its
    /// mid node so the fan follows the curved boundary through it. `None` if an edge has no mid
    /// node.
    pub fn to_quadratic(&self, mid: &HashMap<(u32, u32), u32>) -> Option<Self> {
        let m = |a: u32, b: u32| mid.get(&(a.min(b), a.max(b))).copied();
        let mut quadratic = Vec::with_capacity(self.triangles.len());
        for t in &self.triangles {
            quadratic.push([
                t[0],
                t[1],
                t[2],
                m(t[0], t[1])?,
                m(t[1], t[2])?,
                m(t[2], t[0])?,
            ]);
        }
        let mut caps = Vec::with_capacity(self.caps.len());
        for cap in &self.caps {
            let mut edges = Vec::with_capacity(2 * cap.edges.len());
            for &(a, b) in &cap.edges {
                let c = m(a, b)?;
                edges.push((a, c));
                edges.push((c, b));
            }
            caps.push(Cap {
                centre: cap.centre.clone(),
                edges,
            });
        }
        Some(Self {
            triangles: self.triangles.clone(),
            caps,
            quadratic,
        })
    }

    fn for_each_term(&self, mut f: impl FnMut(Operand<'_>, Operand<'_>, Operand<'_>)) {
        // A curved triangle contributes -(1/3) int x . (x_xi x x_eta) = -(1/6) sum_q
        // det[2 w_q x_q, x_xi, x_eta] (the flat terms below are -(1/6) det[x0, x1, x2]).
        for t in &self.quadratic {
            for (l, w) in TRI6 {
                let [mut n, dxi, deta] = quadratic_triangle_weights(l);
                for v in n.iter_mut() {
                    *v *= w;
                }
                f(
                    Operand::Combo(*t, n),
                    Operand::Combo(*t, dxi),
                    Operand::Combo(*t, deta),
                );
            }
        }
        let flat = if self.quadratic.is_empty() {
            &self.triangles[..]
        } else {
            &[]
        };
        for t in flat {
            f(
                Operand::Node(t[0]),
                Operand::Node(t[1]),
                Operand::Node(t[2]),
            );
        }
        for cap in &self.caps {
            let c = match &cap.centre {
                CapCentre::Fixed(p) => Operand::Fixed(*p),
                CapCentre::Centroid(ids) => Operand::Centroid(ids),
            };
            for &(a, b) in &cap.edges {
                f(c, Operand::Node(b), Operand::Node(a));
            }
        }
    }

    /// Enclosed volume at positions `x`.
    pub fn volume(&self, x: &[[f64; 3]]) -> f64 {
        let mut s = 0.0;
        self.for_each_term(|u, v, w| {
            let (u, v, w) = (u.value(x), v.value(x), w.value(x));
            s += super::element::dot(u, cross(v, w));
        });
        -s / 6.0
    }

    /// Adds `scale * dV/dx` to `g` (3 entries per vertex).
    pub fn add_gradient(&self, x: &[[f64; 3]], scale: f64, g: &mut [f64]) {
        let s = -scale / 6.0;
        self.for_each_term(|u, v, w| {
            let (uu, vv, ww) = (u.value(x), v.value(x), w.value(x));
            let parts = [(u, cross(vv, ww)), (v, cross(ww, uu)), (w, cross(uu, vv))];
            for (op, d) in parts {
                op.for_each_node(|i, wgt| {
                    for k in 0..3 {
                        g[3 * i as usize + k] += s * wgt * d[k];
                    }
                });
            }
        });
    }

    /// Calls `add(i, j, block)` with `scale * d2V/dx_i dx_j` for every coupled vertex pair.
    pub fn for_each_hessian_block(
        &self,
        x: &[[f64; 3]],
        scale: f64,
        mut add: impl FnMut(u32, u32, [[f64; 3]; 3]),
    ) {
        let s = -scale / 6.0;
        self.for_each_term(|u, v, w| {
            let vals = [u.value(x), v.value(x), w.value(x)];
            let ops = [u, v, w];
            // d2 det / d(op_a) d(op_b) = -skew(op_c) for (a, b, c) cyclic; its transpose for (b, a).
            for a in 0..3 {
                let b = (a + 1) % 3;
                let c = (a + 2) % 3;
                let m = skew(vals[c]);
                ops[a].for_each_node(|i, wi| {
                    ops[b].for_each_node(|j, wj| {
                        let f = s * wi * wj;
                        let mut blk = [[0.0; 3]; 3];
                        let mut blk_t = [[0.0; 3]; 3];
                        for r in 0..3 {
                            for q in 0..3 {
                                blk[r][q] = -f * m[r][q];
                                blk_t[q][r] = -f * m[r][q];
                            }
                        }
                        add(i, j, blk);
                        add(j, i, blk_t);
                    });
                });
            }
        });
    }

    /// Vertex pairs coupled by the load stiffness (for the sparsity pattern).
    pub fn coupled_pairs(&self) -> Vec<(u32, u32)> {
        let mut out = Vec::new();
        self.for_each_term(|u, v, w| {
            let mut ids = Vec::new();
            for op in [u, v, w] {
                op.for_each_node(|i, _| ids.push(i));
            }
            for &i in &ids {
                for &j in &ids {
                    out.push((i, j));
                }
            }
        });
        out.sort_unstable();
        out.dedup();
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An open box (unit cube without its top), normals inward, with the opening capped by the
    /// centroid of its four top vertices; positions perturbed so nothing is symmetric.
    fn open_box() -> (Vec<[f64; 3]>, CavitySurface) {
        let mut x: Vec<[f64; 3]> = (0..8)
            .map(|i| [(i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64])
            .collect();
        for (i, p) in x.iter_mut().enumerate() {
            p[0] += 0.03 * (i as f64).sin();
            p[1] += 0.02 * (1.7 * i as f64).cos();
            p[2] += 0.025 * (0.3 * i as f64).sin();
        }
        let outward: [[u32; 4]; 5] = [
            [0, 2, 3, 1],
            [0, 1, 5, 4],
            [2, 6, 7, 3],
            [0, 4, 6, 2],
            [1, 3, 7, 5],
        ];
        let mut tris = Vec::new();
        for q in outward {
            tris.push([q[0], q[2], q[1]]);
            tris.push([q[0], q[3], q[2]]);
        }
        (x, CavitySurface::with_loop_caps(tris))
    }

    #[test]
    fn volume_matches_mesh_closure_and_unit_box() {
        let (x, s) = open_box();
        let loop_ = vec![4, 5, 7, 6];
        let v_mesh = crate::mesh::cavity_volume_m3(&x, &s.triangles, &loop_);
        assert!((s.volume(&x) - v_mesh).abs() < 1e-14);
        let unit: Vec<[f64; 3]> = (0..8)
            .map(|i| [(i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64])
            .collect();
        assert!((s.volume(&unit) - 1.0).abs() < 1e-14);
    }

    /// The open box on 6-node triangles, mid nodes pushed off the chords (a curved surface).
    fn curved_open_box() -> (Vec<[f64; 3]>, CavitySurface, CavitySurface) {
        let (mut x, s) = open_box();
        let mut mid = HashMap::new();
        for t in &s.triangles {
            for k in 0..3 {
                let (a, b) = (t[k].min(t[(k + 1) % 3]), t[k].max(t[(k + 1) % 3]));
                mid.entry((a, b)).or_insert_with(|| {
                    x.push(std::array::from_fn(|c| {
                        0.5 * (x[a as usize][c] + x[b as usize][c])
                    }));
                    x.len() as u32 - 1
                });
            }
        }
        let q = s.to_quadratic(&mid).unwrap();
        (x, s, q)
    }

    #[test]
    fn quadratic_surface_encloses_the_flat_volume_and_an_exact_bulge() {
        let (x, flat, quad) = curved_open_box();
        assert!((quad.volume(&x) - flat.volume(&x)).abs() < 1e-14);
        // Unit box with every mid node of the bottom face (z = 0) lowered by d: the bottom becomes
        // z = -d sum_m N_m, whose integral is d per unit area (int 4 L_i L_j = A/3, 3 per
        // triangle), so the enclosed volume is exactly 1 + d (the sides stay closed through the
        // shared mid nodes).
        let mut u: Vec<[f64; 3]> = (0..8)
            .map(|i| [(i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64])
            .collect();
        for t in &quad.quadratic {
            for (k, &m) in t[3..].iter().enumerate() {
                let (a, b) = (t[k] as usize, t[(k + 1) % 3] as usize);
                if u.len() <= m as usize {
                    u.resize(m as usize + 1, [0.0; 3]);
                }
                u[m as usize] = std::array::from_fn(|c| 0.5 * (u[a][c] + u[b][c]));
            }
        }
        assert!((quad.volume(&u) - 1.0).abs() < 1e-14);
        let d = 0.05;
        for p in u.iter_mut().skip(8) {
            if p[2] == 0.0 {
                p[2] = -d;
            }
        }
        assert!(
            (quad.volume(&u) - (1.0 + d)).abs() < 1e-14,
            "{}",
            quad.volume(&u)
        );
    }

    #[test]
    fn quadratic_pressure_load_matches_finite_differences() {
        let (mut x, _, q) = curved_open_box();
        for (i, p) in x.iter_mut().enumerate().skip(8) {
            p[0] += 0.04 * (i as f64).cos();
            p[2] -= 0.03 * (0.7 * i as f64).sin();
        }
        check_derivatives(&x, &q);
    }

    #[test]
    fn pressure_load_gradient_and_hessian_match_finite_differences() {
        let (x, s) = open_box();
        check_derivatives(&x, &s);
    }

    fn check_derivatives(x: &[[f64; 3]], s: &CavitySurface) {
        let x = x.to_vec();
        let n = x.len();
        let mut g = vec![0.0; 3 * n];
        s.add_gradient(&x, 1.0, &mut g);
        let mut h = vec![vec![0.0; 3 * n]; 3 * n];
        s.for_each_hessian_block(&x, 1.0, |i, j, b| {
            for r in 0..3 {
                for c in 0..3 {
                    h[3 * i as usize + r][3 * j as usize + c] += b[r][c];
                }
            }
        });
        let pairs = s.coupled_pairs();
        let eps = 1e-6;
        for d in 0..3 * n {
            let mut xp = x.clone();
            let mut xm = x.clone();
            xp[d / 3][d % 3] += eps;
            xm[d / 3][d % 3] -= eps;
            let fd = (s.volume(&xp) - s.volume(&xm)) / (2.0 * eps);
            assert!(
                (fd - g[d]).abs() < 1e-9,
                "gradient dof {d}: {fd} vs {}",
                g[d]
            );
            let mut gp = vec![0.0; 3 * n];
            let mut gm = vec![0.0; 3 * n];
            s.add_gradient(&xp, 1.0, &mut gp);
            s.add_gradient(&xm, 1.0, &mut gm);
            for c in 0..3 * n {
                let fdh = (gp[c] - gm[c]) / (2.0 * eps);
                assert!(
                    (fdh - h[c][d]).abs() < 1e-8,
                    "hessian ({c},{d}): {fdh} vs {}",
                    h[c][d]
                );
                if fdh.abs() > 1e-8 {
                    assert!(pairs
                        .binary_search(&((c / 3) as u32, (d / 3) as u32))
                        .is_ok());
                }
            }
        }
    }
}
