//! Exact solutions used as oracles: the incompressible thick sphere for any isotropic energy
//! (references.md, "Thick-walled sphere"), the neo-Hookean plane-strain cylinder and the
//! small-strain Lame solutions.

use super::material::Material;

/// Composite 8-point Gauss-Legendre quadrature of `f` on `[a, b]` with `panels` panels.
fn gauss(f: impl Fn(f64) -> f64, a: f64, b: f64, panels: usize) -> f64 {
    const X: [f64; 4] = [
        0.183_434_642_495_649_8,
        0.525_532_409_916_329,
        0.796_666_477_413_626_7,
        0.960_289_856_497_536_3,
    ];
    const W: [f64; 4] = [
        0.362_683_783_378_362,
        0.313_706_645_877_887_3,
        0.222_381_034_453_374_5,
        0.101_228_536_290_376_3,
    ];
    let h = (b - a) / panels as f64;
    let mut s = 0.0;
    for k in 0..panels {
        let c = a + (k as f64 + 0.5) * h;
        for q in 0..4 {
            s += W[q] * (f(c - 0.5 * h * X[q]) + f(c + 0.5 * h * X[q]));
        }
    }
    0.5 * h * s
}

/// Outer stretch `lb` of the incompressible thick sphere for inner stretch `la`.
pub fn sphere_outer_stretch(inner: f64, outer: f64, la: f64) -> f64 {
    (1.0 + (la.powi(3) - 1.0) * (inner / outer).powi(3)).cbrt()
}

/// Internal pressure (Pa) of an incompressible thick sphere (radii `inner < outer`) of `material`
/// at inner stretch `la`: `P = int_lb^la W'(l) / (l^3 - 1) dl` with `W(l) = Psi_dev(l, l, l^-2)`.
pub fn sphere_pressure(material: &Material, inner: f64, outer: f64, la: f64) -> f64 {
    let lb = sphere_outer_stretch(inner, outer, la);
    let integrand = |l: f64| {
        let d = l * l * l - 1.0;
        if d.abs() < 1e-9 {
            // W'(l) ~ W''(1)(l - 1) and l^3 - 1 ~ 3(l - 1).
            let h = 1e-5;
            let (_, wp) = material.equibiaxial_incompressible(1.0 + h);
            let (_, wm) = material.equibiaxial_incompressible(1.0 - h);
            (wp - wm) / (2.0 * h) / 3.0
        } else {
            material.equibiaxial_incompressible(l).1 / d
        }
    };
    gauss(integrand, lb, la, 64)
}

/// The smallest inner stretch at which the incompressible thick sphere carries `pressure_pa`, or
/// `None` if the pressure exceeds the limit point below stretch 20.
pub fn sphere_inner_stretch(
    material: &Material,
    inner: f64,
    outer: f64,
    pressure_pa: f64,
) -> Option<f64> {
    if pressure_pa <= 0.0 {
        return Some(1.0);
    }
    let mut lo = 1.0;
    let mut hi = 1.0;
    let mut step = 1e-3;
    loop {
        hi += step;
        if sphere_pressure(material, inner, outer, hi) >= pressure_pa {
            break;
        }
        lo = hi;
        step *= 1.3;
        if hi > 20.0 {
            return None;
        }
    }
    for _ in 0..100 {
        let mid = 0.5 * (lo + hi);
        if sphere_pressure(material, inner, outer, mid) >= pressure_pa {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    Some(0.5 * (lo + hi))
}

/// Neo-Hookean (shear modulus `mu`) incompressible plane-strain cylinder pressure at inner
/// stretch `la`.
pub fn cylinder_pressure_neo_hookean(mu: f64, inner: f64, outer: f64, la: f64) -> f64 {
    let lb = (1.0 + (la * la - 1.0) * (inner / outer).powi(2)).sqrt();
    mu * ((la / lb).ln() + 0.5 / (lb * lb) - 0.5 / (la * la))
}

/// Small-strain radial displacement of a plane-strain thick cylinder at radius `r` (Young's
/// modulus `e`, Poisson ratio `nu`, internal pressure `p`).
pub fn cylinder_displacement_small_strain(
    p: f64,
    e: f64,
    nu: f64,
    inner: f64,
    outer: f64,
    r: f64,
) -> f64 {
    (1.0 + nu) * p * inner * inner / (e * (outer * outer - inner * inner))
        * ((1.0 - 2.0 * nu) * r + outer * outer / r)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integral_reproduces_the_neo_hookean_closed_form_and_table() {
        let mat = Material::neo_hookean(1.0, 1e9);
        let table = [
            (1.01, 0.034279),
            (1.05, 0.158081),
            (1.1, 0.287155),
            (1.2, 0.480160),
            (1.3, 0.610817),
            (1.5, 0.755433),
            (2.0, 0.806927),
        ];
        for (la, p) in table {
            let got = sphere_pressure(&mat, 1.0, 2.0, la);
            let lb = sphere_outer_stretch(1.0, 2.0, la);
            let closed = (2.0 / lb + 0.5 / lb.powi(4)) - (2.0 / la + 0.5 / la.powi(4));
            assert!(
                (got - closed).abs() < 1e-10,
                "la {la}: {got} vs closed form {closed}"
            );
            assert!((got - p).abs() < 2e-6, "la {la}: {got} vs table {p}");
        }
        let la = sphere_inner_stretch(&mat, 1.0, 2.0, 0.287155).unwrap();
        assert!((la - 1.1).abs() < 1e-5);
    }

    #[test]
    fn cylinder_formula_matches_table() {
        for (la, p) in [(1.1, 0.131562), (1.5, 0.428228), (2.0, 0.574054)] {
            assert!((cylinder_pressure_neo_hookean(1.0, 1.0, 2.0, la) - p).abs() < 2e-6);
        }
    }
}
