//! Linear tetrahedron kinematics: reference shape-function gradients, the deviatoric element force
//! and stiffness, and the current volume with its first and second derivatives.

use super::material::{deviatoric_stress, Material};

/// Reference data of one linear tetrahedron.
#[derive(Debug, Clone, Copy)]
pub struct TetReference {
    /// Gradients of the four shape functions in the reference configuration.
    pub grad: [[f64; 3]; 4],
    /// Reference volume.
    pub volume0: f64,
}

impl TetReference {
    /// Reference data from the rest positions of the four vertices; `None` if degenerate or
    /// inverted.
    pub fn new(x: &[[f64; 3]; 4]) -> Option<Self> {
        let e = [sub(x[1], x[0]), sub(x[2], x[0]), sub(x[3], x[0])];
        // Columns of D are the edge vectors; gradients of N1..N3 are the rows of D^-1.
        let d = [
            [e[0][0], e[1][0], e[2][0]],
            [e[0][1], e[1][1], e[2][1]],
            [e[0][2], e[1][2], e[2][2]],
        ];
        let det = super::material::det3(&d);
        if det <= 0.0 || !det.is_finite() {
            return None;
        }
        let inv = super::material::inv3(&d, det);
        let mut grad = [[0.0; 3]; 4];
        for a in 1..4 {
            grad[a] = inv[a - 1];
            for k in 0..3 {
                grad[0][k] -= inv[a - 1][k];
            }
        }
        Some(Self {
            grad,
            volume0: det / 6.0,
        })
    }

    /// Deformation gradient `F = sum_a x_a (x) grad N_a`.
    pub fn deformation_gradient(&self, x: &[[f64; 3]; 4]) -> [[f64; 3]; 3] {
        deformation_gradient(&self.grad, x)
    }

    /// Deviatoric energy, element force (12) and, if `stiffness` is given, element stiffness
    /// (12x12, row-major). `None` if the element is inverted.
    pub fn deviatoric(
        &self,
        material: &Material,
        x: &[[f64; 3]; 4],
        force: &mut [f64; 12],
        stiffness: Option<&mut [[f64; 12]; 12]>,
    ) -> Option<f64> {
        let f = self.deformation_gradient(x);
        let (w, p, a) = deviatoric_stress(material, &f)?;
        let v0 = self.volume0;
        for n in 0..4 {
            for i in 0..3 {
                let mut s = 0.0;
                for j in 0..3 {
                    s += p[3 * i + j] * self.grad[n][j];
                }
                force[3 * n + i] = v0 * s;
            }
        }
        if let Some(k) = stiffness {
            // AB[r][3b+k] = sum_L A[r][3k+L] G_bL, then K = B^T AB.
            let mut ab = [[0.0; 12]; 9];
            for r in 0..9 {
                for b in 0..4 {
                    for kk in 0..3 {
                        let mut s = 0.0;
                        for l in 0..3 {
                            s += a[r][3 * kk + l] * self.grad[b][l];
                        }
                        ab[r][3 * b + kk] = s;
                    }
                }
            }
            for an in 0..4 {
                for i in 0..3 {
                    let row = 3 * an + i;
                    for c in 0..12 {
                        let mut s = 0.0;
                        for j in 0..3 {
                            s += self.grad[an][j] * ab[3 * i + j][c];
                        }
                        k[row][c] = v0 * s;
                    }
                }
            }
        }
        Some(v0 * w)
    }
}

/// Current signed volume of a tetrahedron.
pub fn tet_volume(x: &[[f64; 3]; 4]) -> f64 {
    let e1 = sub(x[1], x[0]);
    let e2 = sub(x[2], x[0]);
    let e3 = sub(x[3], x[0]);
    dot(e1, cross(e2, e3)) / 6.0
}

/// Gradient of the tetrahedron volume with respect to its 12 vertex coordinates.
pub fn tet_volume_gradient(x: &[[f64; 3]; 4]) -> [f64; 12] {
    let e1 = sub(x[1], x[0]);
    let e2 = sub(x[2], x[0]);
    let e3 = sub(x[3], x[0]);
    let g1 = cross(e2, e3);
    let g2 = cross(e3, e1);
    let g3 = cross(e1, e2);
    let mut g = [0.0; 12];
    for k in 0..3 {
        g[3 + k] = g1[k] / 6.0;
        g[6 + k] = g2[k] / 6.0;
        g[9 + k] = g3[k] / 6.0;
        g[k] = -(g1[k] + g2[k] + g3[k]) / 6.0;
    }
    g
}

/// Hessian of the tetrahedron volume (12x12), scaled by `scale` and added to `h`.
pub fn add_tet_volume_hessian(x: &[[f64; 3]; 4], scale: f64, h: &mut [[f64; 12]; 12]) {
    let e = [sub(x[1], x[0]), sub(x[2], x[0]), sub(x[3], x[0])];
    // v = det[e1, e2, e3]/6; d2 det / de_a de_b = -skew(e_c) for (a, b, c) cyclic.
    let mut he = [[[[0.0; 3]; 3]; 3]; 3];
    for a in 0..3 {
        let b = (a + 1) % 3;
        let c = (a + 2) % 3;
        let s = skew(e[c]);
        for i in 0..3 {
            for j in 0..3 {
                he[a][b][i][j] = -s[i][j] * scale / 6.0;
                he[b][a][i][j] = s[i][j] * scale / 6.0;
            }
        }
    }
    // Chain rule: e_a = x_{a+1} - x_0.
    for a in 0..4 {
        for b in 0..4 {
            for i in 0..3 {
                for j in 0..3 {
                    let v = match (a, b) {
                        (0, 0) => {
                            let mut s = 0.0;
                            for p in 0..3 {
                                for q in 0..3 {
                                    s += he[p][q][i][j];
                                }
                            }
                            s
                        }
                        (0, b) => -(0..3).map(|p| he[p][b - 1][i][j]).sum::<f64>(),
                        (a, 0) => -(0..3).map(|q| he[a - 1][q][i][j]).sum::<f64>(),
                        (a, b) => he[a - 1][b - 1][i][j],
                    };
                    h[3 * a + i][3 * b + j] += v;
                }
            }
        }
    }
}

/// `skew(a) y = a x y`.
pub fn skew(a: [f64; 3]) -> [[f64; 3]; 3] {
    [[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]]
}

pub(crate) use crate::mesh::{cross, dot, sub};

/// Deformation gradient `F = sum_a x_a (x) grad N_a` of an element with `N` nodes.
pub(crate) fn deformation_gradient<const N: usize>(
    grad: &[[f64; 3]; N],
    x: &[[f64; 3]; N],
) -> [[f64; 3]; 3] {
    let mut f = [[0.0; 3]; 3];
    for (xa, ga) in x.iter().zip(grad) {
        for i in 0..3 {
            for j in 0..3 {
                f[i][j] += xa[i] * ga[j];
            }
        }
    }
    f
}

/// Central-difference check of an element's force (the gradient of its energy) and stiffness
/// (the Jacobian of its force), both relative to their largest entry.
#[cfg(test)]
pub(crate) fn check_force_and_stiffness<const N: usize, const D: usize>(
    x: &[[f64; 3]; N],
    force: &[f64; D],
    stiffness: &[[f64; D]; D],
    energy_and_force: impl Fn(&[[f64; 3]; N], &mut [f64; D]) -> f64,
) {
    let eps = 1e-6;
    let fscale = force.iter().map(|v| v.abs()).fold(0.0, f64::max);
    let kscale = stiffness
        .iter()
        .flatten()
        .map(|v| v.abs())
        .fold(0.0, f64::max);
    for d in 0..D {
        let perturbed = |s: f64| {
            let mut y = *x;
            y[d / 3][d % 3] += s;
            y
        };
        let (mut fp, mut fm) = ([0.0; D], [0.0; D]);
        let wp = energy_and_force(&perturbed(eps), &mut fp);
        let wm = energy_and_force(&perturbed(-eps), &mut fm);
        assert!(
            ((wp - wm) / (2.0 * eps) - force[d]).abs() < 1e-7 * fscale,
            "force dof {d}"
        );
        for c in 0..D {
            let fd = (fp[c] - fm[c]) / (2.0 * eps);
            assert!(
                (fd - stiffness[c][d]).abs() < 1e-7 * kscale,
                "stiffness ({c},{d}): {fd} vs {}",
                stiffness[c][d]
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rest() -> [[f64; 3]; 4] {
        [
            [0.0, 0.0, 0.0],
            [1.0, 0.1, 0.0],
            [0.2, 0.9, 0.1],
            [0.1, 0.2, 1.1],
        ]
    }
    fn moved() -> [[f64; 3]; 4] {
        [
            [0.05, -0.02, 0.01],
            [1.2, 0.1, 0.05],
            [0.1, 1.0, 0.2],
            [0.15, 0.1, 1.3],
        ]
    }
    fn perturbed(x: &[[f64; 3]; 4], dof: usize, eps: f64) -> [[f64; 3]; 4] {
        let mut y = *x;
        y[dof / 3][dof % 3] += eps;
        y
    }

    #[test]
    fn element_force_and_stiffness_match_finite_differences() {
        let mat = Material {
            mu_pa: vec![1.0, 0.5],
            kappa_pa: 10.0,
        };
        let r = TetReference::new(&rest()).unwrap();
        let x = moved();
        let mut f = [0.0; 12];
        let mut k = [[0.0; 12]; 12];
        r.deviatoric(&mat, &x, &mut f, Some(&mut k)).unwrap();
        check_force_and_stiffness(&x, &f, &k, |y, fy| r.deviatoric(&mat, y, fy, None).unwrap());
    }

    #[test]
    fn volume_gradient_and_hessian_match_finite_differences() {
        let x = moved();
        let g = tet_volume_gradient(&x);
        let mut h = [[0.0; 12]; 12];
        add_tet_volume_hessian(&x, 1.0, &mut h);
        let eps = 1e-6;
        for d in 0..12 {
            let fd = (tet_volume(&perturbed(&x, d, eps)) - tet_volume(&perturbed(&x, d, -eps)))
                / (2.0 * eps);
            assert!((fd - g[d]).abs() < 1e-9, "gradient {d}");
            let gp = tet_volume_gradient(&perturbed(&x, d, eps));
            let gm = tet_volume_gradient(&perturbed(&x, d, -eps));
            for c in 0..12 {
                assert!(
                    ((gp[c] - gm[c]) / (2.0 * eps) - h[c][d]).abs() < 1e-9,
                    "hessian ({c},{d})"
                );
            }
        }
    }

    #[test]
    fn reference_gradients_reproduce_an_affine_map() {
        let r = TetReference::new(&rest()).unwrap();
        let m = [[1.1, 0.2, 0.0], [-0.1, 0.95, 0.3], [0.05, 0.0, 1.2]];
        let x = rest().map(|p| {
            let mut q = [0.5, -0.2, 0.1];
            for i in 0..3 {
                for j in 0..3 {
                    q[i] += m[i][j] * p[j];
                }
            }
            q
        });
        let f = r.deformation_gradient(&x);
        for i in 0..3 {
            for j in 0..3 {
                assert!((f[i][j] - m[i][j]).abs() < 1e-12);
            }
        }
        assert!((r.volume0 - tet_volume(&rest())).abs() < 1e-14);
    }
}
