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
}

#[derive(Clone, Copy)]
enum Operand<'a> {
    Node(u32),
    Centroid(&'a [u32]),
    Fixed([f64; 3]),
}

impl Operand<'_> {
    fn value(&self, x: &[[f64; 3]]) -> [f64; 3] {
        match *self {
            Operand::Node(i) => x[i as usize],
            Operand::Fixed(p) => p,
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
        Self { triangles, caps }
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
        Self { triangles, caps }
    }

    fn for_each_term(&self, mut f: impl FnMut(Operand<'_>, Operand<'_>, Operand<'_>)) {
        for t in &self.triangles {
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

    #[test]
    fn pressure_load_gradient_and_hessian_match_finite_differences() {
        let (x, s) = open_box();
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
