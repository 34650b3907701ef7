//! Quadratic (10-node, isoparametric) tetrahedron: the deviatoric energy by 4-point Gauss
//! quadrature and the element volume (exactly, by a degree-3 rule) with its first and second
//! derivatives, for the mean-dilatation (P2 displacement / P0 pressure) volumetric energy
//! `V0_e kappa/2 (v_e/V0_e - 1)^2`.
//!
//! Node order: the four corners, then the mid-edge nodes of edges (0,1), (0,2), (0,3), (1,2),
//! (1,3), (2,3). Shape functions in barycentric coordinates `L`: `L_i (2 L_i - 1)` at corners,
//! `4 L_i L_j` at mid-edge nodes. The reference configuration may be curved (mid-edge nodes off
//! the chords), which is how the element represents a curved boundary.

use super::element::deformation_gradient;
use super::material::{det3, deviatoric_stress, inv3, Material};

/// Corner pairs of the six edges, in mid-node order.
pub const EDGES: [(usize, usize); 6] = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)];

/// 4-point Gauss rule (degree 2) on the unit tetrahedron: barycentric points, weight 1/24 each.
const GAUSS4_A: f64 = 0.585_410_196_624_968_5;
const GAUSS4_B: f64 = 0.138_196_601_125_010_5;

/// Barycentric coordinates and weights (summing to 1/6) of the quadrature rule of `degree` 2 or 3.
fn rule(degree: usize) -> Vec<([f64; 4], f64)> {
    if degree <= 2 {
        (0..4)
            .map(|k| {
                let mut l = [GAUSS4_B; 4];
                l[k] = GAUSS4_A;
                (l, 1.0 / 24.0)
            })
            .collect()
    } else {
        // Keast's 5-point degree-3 rule (one negative weight).
        let mut r = vec![([0.25; 4], -2.0 / 15.0)];
        for k in 0..4 {
            let mut l = [1.0 / 6.0; 4];
            l[k] = 0.5;
            r.push((l, 3.0 / 40.0));
        }
        r
    }
}

/// Gradients of the 10 shape functions with respect to the reference coordinates
/// `(xi, eta, zeta) = (L1, L2, L3)` at the barycentric point `l`.
pub fn shape_gradients(l: &[f64; 4]) -> [[f64; 3]; 10] {
    let dl: [[f64; 3]; 4] = [
        [-1.0, -1.0, -1.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 0.0, 1.0],
    ];
    let mut g = [[0.0; 3]; 10];
    for i in 0..4 {
        for k in 0..3 {
            g[i][k] = (4.0 * l[i] - 1.0) * dl[i][k];
        }
    }
    for (e, &(i, j)) in EDGES.iter().enumerate() {
        for k in 0..3 {
            g[4 + e][k] = 4.0 * (l[i] * dl[j][k] + l[j] * dl[i][k]);
        }
    }
    g
}

/// `M_ij = sum_a x_ai dN_a/dxi_j`.
fn jacobian(x: &[[f64; 3]; 10], dn: &[[f64; 3]; 10]) -> [[f64; 3]; 3] {
    let mut m = [[0.0; 3]; 3];
    for a in 0..10 {
        for i in 0..3 {
            for j in 0..3 {
                m[i][j] += x[a][i] * dn[a][j];
            }
        }
    }
    m
}

/// Cofactor matrix `d det M / d M`.
fn cofactor(m: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut c = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            let (i1, i2) = ((i + 1) % 3, (i + 2) % 3);
            let (j1, j2) = ((j + 1) % 3, (j + 2) % 3);
            c[i][j] = m[i1][j1] * m[i2][j2] - m[i1][j2] * m[i2][j1];
        }
    }
    c
}

/// One deviatoric quadrature point: physical shape-function gradients and weight.
#[derive(Debug, Clone, Copy)]
struct QuadPoint {
    grad: [[f64; 3]; 10],
    weight: f64,
}

/// Reference data of one 10-node tetrahedron.
#[derive(Debug, Clone)]
pub struct Tet10Reference {
    points: [QuadPoint; 4],
    /// Reference-coordinate shape gradients at the degree-3 volume rule's points, with weights.
    volume_rule: Vec<([[f64; 3]; 10], f64)>,
    /// Reference (rest) volume.
    pub volume0: f64,
}

impl Tet10Reference {
    /// Reference data from the 10 rest positions; `None` if the isoparametric map is degenerate
    /// or inverted at a quadrature point.
    pub fn new(x: &[[f64; 3]; 10]) -> Option<Self> {
        let mut points = [QuadPoint {
            grad: [[0.0; 3]; 10],
            weight: 0.0,
        }; 4];
        for (q, (l, w)) in rule(2).into_iter().enumerate() {
            let dn = shape_gradients(&l);
            let m = jacobian(x, &dn);
            let det = det3(&m);
            if det <= 0.0 || !det.is_finite() {
                return None;
            }
            let inv = inv3(&m, det);
            // grad N_a = dN_a/dxi M^-1.
            let mut grad = [[0.0; 3]; 10];
            for a in 0..10 {
                for k in 0..3 {
                    grad[a][k] = (0..3).map(|j| dn[a][j] * inv[j][k]).sum();
                }
            }
            points[q] = QuadPoint {
                grad,
                weight: w * det,
            };
        }
        let volume_rule: Vec<([[f64; 3]; 10], f64)> = rule(3)
            .into_iter()
            .map(|(l, w)| (shape_gradients(&l), w))
            .collect();
        let mut r = Self {
            points,
            volume_rule,
            volume0: 0.0,
        };
        r.volume0 = r.volume(x);
        (r.volume0 > 0.0).then_some(r)
    }

    /// Exact volume of the element at positions `x` (`det` of the isoparametric Jacobian is a
    /// cubic, integrated exactly).
    pub fn volume(&self, x: &[[f64; 3]; 10]) -> f64 {
        self.volume_rule
            .iter()
            .map(|(dn, w)| w * det3(&jacobian(x, dn)))
            .sum()
    }

    /// Gradient of [`Self::volume`] (30 entries).
    pub fn volume_gradient(&self, x: &[[f64; 3]; 10]) -> [f64; 30] {
        let mut g = [0.0; 30];
        for (dn, w) in &self.volume_rule {
            let c = cofactor(&jacobian(x, dn));
            for a in 0..10 {
                for i in 0..3 {
                    g[3 * a + i] += w * (0..3).map(|j| c[i][j] * dn[a][j]).sum::<f64>();
                }
            }
        }
        g
    }

    /// Adds `scale` times the Hessian of [`Self::volume`] to `h` (30x30).
    pub fn add_volume_hessian(&self, x: &[[f64; 3]; 10], scale: f64, h: &mut [[f64; 30]; 30]) {
        for (dn, w) in &self.volume_rule {
            let m = jacobian(x, dn);
            // d2 det / dM_ij dM_kl = eps_ikm eps_jln M_mn; for i != k (m the third index):
            // E^{ik}_{jl} = s (eps_jln M_mn), s = eps_ikm.
            for i in 0..3 {
                for k in 0..3 {
                    if i == k {
                        continue;
                    }
                    let mi = 3 - i - k;
                    let s = if (k + 3 - i) % 3 == 1 { 1.0 } else { -1.0 };
                    let mut e = [[0.0; 3]; 3];
                    for j in 0..3 {
                        for l in 0..3 {
                            if j == l {
                                continue;
                            }
                            let n = 3 - j - l;
                            let sj = if (l + 3 - j) % 3 == 1 { 1.0 } else { -1.0 };
                            e[j][l] = s * sj * m[mi][n] * w * scale;
                        }
                    }
                    for b in 0..10 {
                        let eb: [f64; 3] = std::array::from_fn(|j| {
                            (0..3).map(|l| e[j][l] * dn[b][l]).sum::<f64>()
                        });
                        for a in 0..10 {
                            h[3 * a + i][3 * b + k] +=
                                (0..3).map(|j| dn[a][j] * eb[j]).sum::<f64>();
                        }
                    }
                }
            }
        }
    }

    /// Smallest `det F` over the deviatoric quadrature points (inversion check).
    pub fn min_jacobian(&self, x: &[[f64; 3]; 10]) -> f64 {
        self.points
            .iter()
            .map(|q| det3(&deformation_gradient(&q.grad, x)))
            .fold(f64::INFINITY, f64::min)
    }

    /// Deviatoric energy, element force (30) and, if `stiffness` is given, the element stiffness
    /// (30x30). `None` if `det F <= 0` at a quadrature point.
    pub fn deviatoric(
        &self,
        material: &Material,
        x: &[[f64; 3]; 10],
        force: &mut [f64; 30],
        mut stiffness: Option<&mut [[f64; 30]; 30]>,
    ) -> Option<f64> {
        force.fill(0.0);
        if let Some(k) = stiffness.as_deref_mut() {
            for row in k.iter_mut() {
                row.fill(0.0);
            }
        }
        let mut energy = 0.0;
        for q in &self.points {
            let f = deformation_gradient(&q.grad, x);
            let (w, p, a) = deviatoric_stress(material, &f)?;
            energy += q.weight * w;
            for n in 0..10 {
                for i in 0..3 {
                    let s: f64 = (0..3).map(|j| p[3 * i + j] * q.grad[n][j]).sum();
                    force[3 * n + i] += q.weight * s;
                }
            }
            if let Some(k) = stiffness.as_deref_mut() {
                // AB[r][3b+k] = sum_L A[r][3k+L] G_bL, then K += w B^T AB.
                let mut ab = [[0.0; 30]; 9];
                for r in 0..9 {
                    for b in 0..10 {
                        for kk in 0..3 {
                            ab[r][3 * b + kk] =
                                (0..3).map(|l| a[r][3 * kk + l] * q.grad[b][l]).sum();
                        }
                    }
                }
                for an in 0..10 {
                    for i in 0..3 {
                        let row = &mut k[3 * an + i];
                        for c in 0..30 {
                            let s: f64 = (0..3).map(|j| q.grad[an][j] * ab[3 * i + j][c]).sum();
                            row[c] += q.weight * s;
                        }
                    }
                }
            }
        }
        Some(energy)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A curved rest element (mid nodes off the chords) and a large non-affine deformation of it.
    fn rest() -> [[f64; 3]; 10] {
        let c = [
            [0.0, 0.0, 0.0],
            [1.0, 0.1, 0.0],
            [0.2, 0.9, 0.1],
            [0.1, 0.2, 1.1],
        ];
        let mut x = [[0.0; 3]; 10];
        x[..4].copy_from_slice(&c);
        for (e, &(i, j)) in EDGES.iter().enumerate() {
            for k in 0..3 {
                x[4 + e][k] = 0.5 * (c[i][k] + c[j][k]) + 0.03 * ((e + k) as f64).sin();
            }
        }
        x
    }
    fn moved() -> [[f64; 3]; 10] {
        rest().map(|p| {
            [
                1.1 * p[0] + 0.1 * p[1] * p[1] + 0.02,
                0.95 * p[1] + 0.15 * p[2] - 0.05 * p[0] * p[2],
                1.2 * p[2] + 0.1 * p[0] * p[1],
            ]
        })
    }
    fn perturbed(x: &[[f64; 3]; 10], dof: usize, eps: f64) -> [[f64; 3]; 10] {
        let mut y = *x;
        y[dof / 3][dof % 3] += eps;
        y
    }

    #[test]
    fn force_and_stiffness_match_finite_differences() {
        let mat = Material {
            mu_pa: vec![1.0, 0.5],
            kappa_pa: 10.0,
        };
        let r = Tet10Reference::new(&rest()).unwrap();
        let x = moved();
        let mut f = [0.0; 30];
        let mut k = Box::new([[0.0; 30]; 30]);
        r.deviatoric(&mat, &x, &mut f, Some(&mut k)).unwrap();
        crate::fem::element::check_force_and_stiffness(&x, &f, &k, |y, fy| {
            r.deviatoric(&mat, y, fy, None).unwrap()
        });
    }

    #[test]
    fn volume_gradient_and_hessian_match_finite_differences() {
        let r = Tet10Reference::new(&rest()).unwrap();
        let x = moved();
        let g = r.volume_gradient(&x);
        let mut h = Box::new([[0.0; 30]; 30]);
        r.add_volume_hessian(&x, 1.0, &mut h);
        let eps = 1e-6;
        for d in 0..30 {
            let fd = (r.volume(&perturbed(&x, d, eps)) - r.volume(&perturbed(&x, d, -eps)))
                / (2.0 * eps);
            assert!((fd - g[d]).abs() < 1e-9, "gradient {d}: {fd} vs {}", g[d]);
            let gp = r.volume_gradient(&perturbed(&x, d, eps));
            let gm = r.volume_gradient(&perturbed(&x, d, -eps));
            for c in 0..30 {
                assert!(
                    ((gp[c] - gm[c]) / (2.0 * eps) - h[c][d]).abs() < 1e-8,
                    "hessian ({c},{d})"
                );
            }
        }
    }

    #[test]
    fn volume_is_exact_for_a_curved_element_and_affine_maps_are_reproduced() {
        // Straight-sided element: the volume is the corner tet's; an affine map scales it by det.
        let c = [
            [0.0, 0.0, 0.0],
            [1.0, 0.1, 0.0],
            [0.2, 0.9, 0.1],
            [0.1, 0.2, 1.1],
        ];
        let mut x = [[0.0; 3]; 10];
        x[..4].copy_from_slice(&c);
        for (e, &(i, j)) in EDGES.iter().enumerate() {
            x[4 + e] = std::array::from_fn(|k| 0.5 * (c[i][k] + c[j][k]));
        }
        let r = Tet10Reference::new(&x).unwrap();
        let v = crate::mesh::signed_tet_volume(c[0], c[1], c[2], c[3]);
        assert!((r.volume0 - v).abs() < 1e-14);
        let m = [[1.1, 0.2, 0.0], [-0.1, 0.95, 0.3], [0.05, 0.0, 1.2]];
        let y = x.map(|p| std::array::from_fn(|i| (0..3).map(|j| m[i][j] * p[j]).sum::<f64>()));
        assert!((r.volume(&y) - det3(&m) * v).abs() < 1e-13);
        for q in &r.points {
            let f = deformation_gradient(&q.grad, &y);
            for i in 0..3 {
                for j in 0..3 {
                    assert!((f[i][j] - m[i][j]).abs() < 1e-12);
                }
            }
        }
        // Curved: the volume is the integral of det of the isoparametric map; compare with a
        // collapsed-coordinate (Duffy) tensor Gauss rule, exact for this degree-3 integrand.
        let xc = rest();
        let rc = Tet10Reference::new(&xc).unwrap();
        let gx = [0.069_431_844_202_973_7, 0.330_009_478_207_571_9];
        let gw = [0.173_927_422_568_726_9, 0.326_072_577_431_273_1];
        let pts: Vec<(f64, f64)> = (0..4)
            .map(|k| {
                if k < 2 {
                    (gx[k], gw[k])
                } else {
                    (1.0 - gx[3 - k], gw[3 - k])
                }
            })
            .collect();
        let mut sum = 0.0;
        for &(u, wu) in &pts {
            for &(v, wv) in &pts {
                for &(w, ww) in &pts {
                    let xi = u;
                    let eta = v * (1.0 - u);
                    let zeta = w * (1.0 - u) * (1.0 - v);
                    let jac = (1.0 - u) * (1.0 - u) * (1.0 - v);
                    let dn = shape_gradients(&[1.0 - xi - eta - zeta, xi, eta, zeta]);
                    sum += wu * wv * ww * jac * det3(&jacobian(&xc, &dn));
                }
            }
        }
        assert!((sum - rc.volume0).abs() < 1e-13, "{sum} vs {}", rc.volume0);
    }
}
