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

/// `dW/dlambda_1` of the compressible energy `W(l1, l2, l3)` (principal stretches).
fn principal_stress(material: &Material, l1: f64, l2: f64, l3: f64) -> f64 {
    let j = l1 * l2 * l3;
    let i1 = l1 * l1 + l2 * l2 + l3 * l3;
    let jm23 = j.powf(-2.0 / 3.0);
    let (_, g1, _) = material.deviatoric(jm23 * i1);
    g1 * jm23 * (2.0 * l1 - 2.0 / 3.0 * i1 / l1) + material.kappa_pa * (j - 1.0) * j / l1
}

/// Radial stretch `l1` with `dW/dl1 (l1, lt, lt) = target` (Newton on a convex function).
fn radial_stretch(material: &Material, lt: f64, target: f64, guess: f64) -> Option<f64> {
    let mut l = guess;
    for _ in 0..60 {
        let f = principal_stress(material, l, lt, lt) - target;
        let h = 1e-6 * l;
        let df = (principal_stress(material, l + h, lt, lt)
            - principal_stress(material, l - h, lt, lt))
            / (2.0 * h);
        if df.is_nan() || df <= 0.0 {
            return None;
        }
        let step = f / df;
        let next = if l - step <= 0.0 { 0.5 * l } else { l - step };
        if (next - l).abs() <= 1e-14 * l {
            return Some(next);
        }
        l = next;
    }
    Some(l)
}

/// Radial shooting for the compressible thick sphere: with `r(A) = la A` and the radial
/// nominal stress `-P la^2` at `A`, integrates `d(R^2 W_1)/dR = 2 R W_2`, `dr/dR = l1`
/// (RK4, `steps` steps) and returns `R^2 W_1` at `R = B` (zero for the equilibrium).
fn shoot(
    material: &Material,
    inner: f64,
    outer: f64,
    la: f64,
    pressure: f64,
    steps: usize,
) -> Option<f64> {
    let mut rr = inner;
    let mut r = la * inner;
    let mut s = -pressure * la * la * inner * inner;
    let mut guess = 1.0 / (la * la);
    let h = (outer - inner) / steps as f64;
    let rhs = |rr: f64, r: f64, s: f64, guess: &mut f64| -> Option<(f64, f64)> {
        let lt = r / rr;
        let l1 = radial_stretch(material, lt, s / (rr * rr), *guess)?;
        *guess = l1;
        Some((l1, 2.0 * rr * principal_stress(material, lt, l1, lt)))
    };
    for _ in 0..steps {
        let (k1r, k1s) = rhs(rr, r, s, &mut guess)?;
        let (k2r, k2s) = rhs(
            rr + 0.5 * h,
            r + 0.5 * h * k1r,
            s + 0.5 * h * k1s,
            &mut guess,
        )?;
        let (k3r, k3s) = rhs(
            rr + 0.5 * h,
            r + 0.5 * h * k2r,
            s + 0.5 * h * k2s,
            &mut guess,
        )?;
        let (k4r, k4s) = rhs(rr + h, r + h * k3r, s + h * k3s, &mut guess)?;
        r += h / 6.0 * (k1r + 2.0 * k2r + 2.0 * k3r + k4r);
        s += h / 6.0 * (k1s + 2.0 * k2s + 2.0 * k3s + k4s);
        rr += h;
    }
    Some(s)
}

/// Bisection for the sign change of `f` in `[lo, hi]`.
fn bisect(mut lo: f64, mut hi: f64, f: impl Fn(f64) -> Option<f64>) -> Option<f64> {
    let flo = f(lo)?;
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if (hi - lo) <= 1e-13 * hi.abs() {
            return Some(mid);
        }
        let fm = f(mid)?;
        if (fm > 0.0) == (flo > 0.0) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Some(0.5 * (lo + hi))
}

/// Internal pressure (Pa) of the *compressible* thick sphere (the material's finite `kappa`) at
/// inner stretch `la`, by radial shooting: the exact solution the FEM converges to.
pub fn sphere_pressure_compressible(
    material: &Material,
    inner: f64,
    outer: f64,
    la: f64,
) -> Option<f64> {
    let steps = 400;
    // The incompressible pressure brackets the answer within a factor of two for kappa/mu >= 10.
    let p_inc = sphere_pressure(material, inner, outer, la)
        .abs()
        .max(1e-12 * material.kappa_pa);
    let f = |p: f64| shoot(material, inner, outer, la, p, steps);
    let (lo, hi) = (0.0, 4.0 * p_inc);
    let (flo, fhi) = (f(lo)?, f(hi)?);
    if (flo > 0.0) == (fhi > 0.0) {
        return None;
    }
    bisect(lo, hi, f)
}

/// Inner stretch of the compressible thick sphere at `pressure_pa` (below the limit point), by
/// radial shooting; `None` if no equilibrium was bracketed up to stretch 20.
pub fn sphere_inner_stretch_compressible(
    material: &Material,
    inner: f64,
    outer: f64,
    pressure_pa: f64,
) -> Option<f64> {
    if pressure_pa <= 0.0 {
        return Some(1.0);
    }
    // Shoot on la directly: the first sign change of the outer radial stress from la = 1.
    let f = |la: f64| shoot(material, inner, outer, la, pressure_pa, 400);
    let f1 = f(1.0)?;
    let (mut lo, mut step) = (1.0, 1e-3);
    loop {
        let hi = lo + step;
        if (f(hi)? > 0.0) != (f1 > 0.0) {
            return bisect(lo, hi, f);
        }
        lo = hi;
        step *= 1.5;
        if lo > 20.0 {
            return None;
        }
    }
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
    fn compressible_shooting_matches_the_reference_and_the_incompressible_limit() {
        // kappa/mu = 1000, A = 1, B = 2: P(la = 1.1) = 0.287092 (references.md, radial shooting).
        let mat = Material::neo_hookean(1.0, 1000.0);
        let p = sphere_pressure_compressible(&mat, 1.0, 2.0, 1.1).unwrap();
        assert!((p - 0.287092).abs() < 2e-6, "{p}");
        let la = sphere_inner_stretch_compressible(&mat, 1.0, 2.0, 0.287092).unwrap();
        assert!((la - 1.1).abs() < 1e-5, "{la}");
        // Nearly incompressible N = 2 material: the integral formula.
        let stiff = Material {
            mu_pa: vec![0.5, 0.4],
            kappa_pa: 1e7,
        };
        for (a, b, la) in [(1.0, 2.0, 1.3), (0.8, 1.0, 1.15)] {
            let pc = sphere_pressure_compressible(&stiff, a, b, la).unwrap();
            let pi = sphere_pressure(&stiff, a, b, la);
            assert!((pc / pi - 1.0).abs() < 1e-5, "{a}/{b}: {pc} vs {pi}");
        }
    }

    #[test]
    fn cylinder_formula_matches_table() {
        for (la, p) in [(1.1, 0.131562), (1.5, 0.428228), (2.0, 0.574054)] {
            assert!((cylinder_pressure_neo_hookean(1.0, 1.0, 2.0, la) - p).abs() < 2e-6);
        }
    }
}
