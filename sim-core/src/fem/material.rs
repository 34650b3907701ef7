//! The strain energy `Psi = sum_p mu_p (I1bar - 3)^p + kappa/2 (J - 1)^2`, per region, from TOML.
//!
//! The deviatoric part is evaluated per tetrahedron (stress and tangent with respect to `F`); the
//! volumetric part is nodally averaged by [`super::volumetric`], so only `kappa` is used there.

use crate::mesh::Region;
use serde::{Deserialize, Serialize};
use std::path::Path;

use super::FemError;

/// One hyperelastic material: `sum_p mu_p (I1bar - 3)^p + kappa/2 (J - 1)^2`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Material {
    /// `mu_p` in Pa for p = 1..N. The small-strain shear modulus is `2 mu_1`.
    pub mu_pa: Vec<f64>,
    /// Bulk modulus `kappa` in Pa.
    pub kappa_pa: f64,
}

impl Material {
    /// Neo-Hookean material with small-strain shear modulus `shear_modulus_pa` (so `mu_1` is half
    /// of it) and bulk modulus `kappa_pa`.
    pub fn neo_hookean(shear_modulus_pa: f64, kappa_pa: f64) -> Self {
        Self {
            mu_pa: vec![0.5 * shear_modulus_pa],
            kappa_pa,
        }
    }

    /// Small-strain shear modulus `2 mu_1` in Pa.
    pub fn shear_modulus_pa(&self) -> f64 {
        2.0 * self.mu_pa.first().copied().unwrap_or(0.0)
    }

    /// Checks that the parameters define a stable material; `what` names it in the error.
    pub fn validate(&self, what: &str) -> Result<(), FemError> {
        let bad = |msg: String| Err(FemError::Material(format!("{what}: {msg}")));
        if self.mu_pa.is_empty() {
            return bad("mu_pa is empty; expected at least mu_1 > 0".into());
        }
        for (p, &m) in self.mu_pa.iter().enumerate() {
            if !m.is_finite() || m < 0.0 {
                return bad(format!("mu_pa[{p}] = {m}; expected a finite value >= 0"));
            }
        }
        if self.mu_pa[0] <= 0.0 {
            return bad(format!("mu_pa[0] = {}; expected > 0", self.mu_pa[0]));
        }
        if !self.kappa_pa.is_finite() || self.kappa_pa <= 0.0 {
            return bad(format!(
                "kappa_pa = {}; expected a finite value > 0",
                self.kappa_pa
            ));
        }
        Ok(())
    }

    /// `g(I1bar) = sum_p mu_p (I1bar - 3)^p` and its first two derivatives.
    pub fn deviatoric(&self, i1bar: f64) -> (f64, f64, f64) {
        let s = i1bar - 3.0;
        let (mut g, mut g1, mut g2) = (0.0, 0.0, 0.0);
        for (k, &m) in self.mu_pa.iter().enumerate() {
            let p = (k + 1) as i32;
            g += m * s.powi(p);
            g1 += m * p as f64 * s.powi(p - 1);
            if p >= 2 {
                g2 += m * (p * (p - 1)) as f64 * s.powi(p - 2);
            }
        }
        (g, g1, g2)
    }

    /// Energy of the incompressible material under the equibiaxial stretch `l` (`W(l, l, l^-2)`)
    /// and its derivative in `l`: the integrand of the thick-sphere formula.
    pub fn equibiaxial_incompressible(&self, l: f64) -> (f64, f64) {
        let i1 = 2.0 * l * l + 1.0 / (l * l * l * l);
        let di1 = 4.0 * l - 4.0 / (l * l * l * l * l);
        let (w, g1, _) = self.deviatoric(i1);
        (w, g1 * di1)
    }
}

/// Deviatoric energy density, first Piola-Kirchhoff stress and its tangent `dP/dF` for a
/// deformation gradient `f` (row-major 3x3, `f[i][J]`). Returns `None` when `det F <= 0`.
///
/// The tangent is `a[i][J][k][L] = d P_iJ / d F_kL`, flattened as `a[3 i + J][3 k + L]`.
pub fn deviatoric_stress(
    material: &Material,
    f: &[[f64; 3]; 3],
) -> Option<(f64, [f64; 9], [[f64; 9]; 9])> {
    let j = det3(f);
    if j <= 0.0 || !j.is_finite() {
        return None;
    }
    // H = F^-T.
    let inv = inv3(f, j);
    let mut h = [0.0; 9];
    for i in 0..3 {
        for jj in 0..3 {
            h[3 * i + jj] = inv[jj][i];
        }
    }
    let mut fv = [0.0; 9];
    let mut i1 = 0.0;
    for i in 0..3 {
        for jj in 0..3 {
            fv[3 * i + jj] = f[i][jj];
            i1 += f[i][jj] * f[i][jj];
        }
    }
    let jm23 = j.powf(-2.0 / 3.0);
    let i1bar = jm23 * i1;
    let (w, g1, g2) = material.deviatoric(i1bar);
    // d I1bar / dF = J^-2/3 (2 F - 2/3 I1 H).
    let mut d = [0.0; 9];
    for k in 0..9 {
        d[k] = jm23 * (2.0 * fv[k] - 2.0 / 3.0 * i1 * h[k]);
    }
    let mut p = [0.0; 9];
    for k in 0..9 {
        p[k] = g1 * d[k];
    }
    // d2 I1bar / dF dF = J^-2/3 [2 II - 4/3 (F x H + H x F) + 4/9 I1 H x H + 2/3 I1 H_iL H_kJ].
    let mut a = [[0.0; 9]; 9];
    for i in 0..3 {
        for jj in 0..3 {
            let r = 3 * i + jj;
            for k in 0..3 {
                for l in 0..3 {
                    let c = 3 * k + l;
                    let mut dd = -4.0 / 3.0 * (fv[r] * h[c] + h[r] * fv[c])
                        + 4.0 / 9.0 * i1 * h[r] * h[c]
                        + 2.0 / 3.0 * i1 * h[3 * i + l] * h[3 * k + jj];
                    if i == k && jj == l {
                        dd += 2.0;
                    }
                    a[r][c] = g2 * d[r] * d[c] + g1 * jm23 * dd;
                }
            }
        }
    }
    Some((w, p, a))
}

/// Determinant of a 3x3 matrix.
pub fn det3(m: &[[f64; 3]; 3]) -> f64 {
    m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
}

/// Inverse of a 3x3 matrix with determinant `det`.
pub fn inv3(m: &[[f64; 3]; 3], det: f64) -> [[f64; 3]; 3] {
    let id = 1.0 / det;
    [
        [
            (m[1][1] * m[2][2] - m[1][2] * m[2][1]) * id,
            (m[0][2] * m[2][1] - m[0][1] * m[2][2]) * id,
            (m[0][1] * m[1][2] - m[0][2] * m[1][1]) * id,
        ],
        [
            (m[1][2] * m[2][0] - m[1][0] * m[2][2]) * id,
            (m[0][0] * m[2][2] - m[0][2] * m[2][0]) * id,
            (m[0][2] * m[1][0] - m[0][0] * m[1][2]) * id,
        ],
        [
            (m[1][0] * m[2][1] - m[1][1] * m[2][0]) * id,
            (m[0][1] * m[2][0] - m[0][0] * m[2][1]) * id,
            (m[0][0] * m[1][1] - m[0][1] * m[1][0]) * id,
        ],
    ]
}

/// Materials per region, read from a TOML file with tables `[myometrium]`, `[fibroid]`, `[polyp]`
/// (each `mu_pa = [...]`, `kappa_pa = ...`) and an optional top-level `source` string.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialSet {
    /// Where the parameters come from (free text, kept in the atlas metadata).
    #[serde(default)]
    pub source: Option<String>,
    /// Uterine muscle.
    pub myometrium: Material,
    /// Myoma; defaults to the myometrium when absent.
    #[serde(default)]
    pub fibroid: Option<Material>,
    /// Polyp; defaults to the myometrium when absent.
    #[serde(default)]
    pub polyp: Option<Material>,
}

/// The default material file (calibrated estimate; see docs/fem.md).
pub const DEFAULT_MATERIAL_TOML: &str = include_str!("default_material.toml");

impl MaterialSet {
    /// One material for every region.
    pub fn uniform(material: Material) -> Self {
        Self {
            source: None,
            myometrium: material,
            fibroid: None,
            polyp: None,
        }
    }

    /// The built-in default (the contents of `DEFAULT_MATERIAL_TOML`).
    pub fn default_uterus() -> Result<Self, FemError> {
        Self::from_toml_str(DEFAULT_MATERIAL_TOML, "<built-in default material>")
    }

    /// Parses and validates a material TOML; `origin` names the file in errors.
    pub fn from_toml_str(text: &str, origin: &str) -> Result<Self, FemError> {
        let set: MaterialSet =
            toml::from_str(text).map_err(|e| FemError::Material(format!("{origin}: {e}")))?;
        set.myometrium
            .validate(&format!("{origin}: [myometrium]"))?;
        if let Some(m) = &set.fibroid {
            m.validate(&format!("{origin}: [fibroid]"))?;
        }
        if let Some(m) = &set.polyp {
            m.validate(&format!("{origin}: [polyp]"))?;
        }
        Ok(set)
    }

    /// Reads and validates a material TOML file.
    pub fn from_file(path: &Path) -> Result<Self, FemError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| FemError::Material(format!("{}: cannot read: {e}", path.display())))?;
        Self::from_toml_str(&text, &path.display().to_string())
    }

    /// The material of `region`.
    pub fn get(&self, region: Region) -> &Material {
        match region {
            Region::Myometrium => &self.myometrium,
            Region::Fibroid => self.fibroid.as_ref().unwrap_or(&self.myometrium),
            Region::Polyp => self.polyp.as_ref().unwrap_or(&self.myometrium),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn test_f() -> [[f64; 3]; 3] {
        [[1.2, 0.1, -0.05], [0.03, 0.9, 0.2], [-0.1, 0.05, 1.1]]
    }

    #[test]
    fn stress_and_tangent_match_finite_differences() {
        let mat = Material {
            mu_pa: vec![1.0, 0.7, 0.3],
            kappa_pa: 100.0,
        };
        let f0 = test_f();
        let (_, p, a) = deviatoric_stress(&mat, &f0).unwrap();
        let eps = 1e-6;
        let mut max_rel_p: f64 = 0.0;
        let mut max_rel_a: f64 = 0.0;
        let pnorm = p.iter().map(|v| v * v).sum::<f64>().sqrt();
        let anorm = a.iter().flatten().map(|v| v * v).sum::<f64>().sqrt();
        for c in 0..9 {
            let mut fp = f0;
            let mut fm = f0;
            fp[c / 3][c % 3] += eps;
            fm[c / 3][c % 3] -= eps;
            let (wp, pp, _) = deviatoric_stress(&mat, &fp).unwrap();
            let (wm, pm, _) = deviatoric_stress(&mat, &fm).unwrap();
            let dw = (wp - wm) / (2.0 * eps);
            max_rel_p = max_rel_p.max((dw - p[c]).abs() / pnorm);
            for r in 0..9 {
                let da = (pp[r] - pm[r]) / (2.0 * eps);
                max_rel_a = max_rel_a.max((da - a[r][c]).abs() / anorm);
            }
        }
        assert!(max_rel_p < 1e-8, "stress FD error {max_rel_p}");
        assert!(max_rel_a < 1e-8, "tangent FD error {max_rel_a}");
    }

    #[test]
    fn deviatoric_energy_vanishes_under_pure_dilation() {
        let mat = Material::neo_hookean(2.0, 100.0);
        let s = 1.3;
        let f = [[s, 0.0, 0.0], [0.0, s, 0.0], [0.0, 0.0, s]];
        let (w, p, _) = deviatoric_stress(&mat, &f).unwrap();
        assert!(w.abs() < 1e-12 && p.iter().all(|v| v.abs() < 1e-12));
    }

    #[test]
    fn material_toml_errors_name_the_region_and_key() {
        let err =
            MaterialSet::from_toml_str("[myometrium]\nmu_pa = [1.0]\nkappa_pa = -3.0\n", "m.toml")
                .unwrap_err()
                .to_string();
        assert!(
            err.contains("m.toml") && err.contains("[myometrium]") && err.contains("kappa_pa"),
            "{err}"
        );
        let err = MaterialSet::from_toml_str("[myometrium]\nmu_pa = [1.0]\n", "m.toml")
            .unwrap_err()
            .to_string();
        assert!(err.contains("kappa_pa"), "{err}");
        assert!(MaterialSet::default_uterus().is_ok());
    }
}
