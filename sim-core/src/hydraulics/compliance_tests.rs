//! The cavity compliance curves with the documented default parameters (a file of its own: the
//! defaults live in `params`, which builds on `compliance`).

use super::compliance::*;
use crate::units::{ml_to_m3, mmhg_to_pa};

fn default_curve() -> AnalyticCompliance {
    crate::hydraulics::HydraulicParams::default()
        .cavity
        .compliance()
}

#[test]
fn analytic_default_holds_a_few_ml_and_separates_near_40_mmhg() {
    let c = default_curve();
    let v = |mmhg: f64| c.volume_m3(mmhg_to_pa(mmhg)) / ml_to_m3(1.0);
    assert!(v(0.0) < 0.5, "collapsed {}", v(0.0));
    assert!((1.5..4.0).contains(&v(40.0)), "at 40 mmHg {}", v(40.0));
    assert!((3.0..8.0).contains(&v(150.0)), "at 150 mmHg {}", v(150.0));
    // The compliance peaks at wall separation.
    let peak = (0..=200)
        .map(|i| i as f64)
        .max_by(|a, b| {
            c.compliance_m3_per_pa(mmhg_to_pa(*a))
                .total_cmp(&c.compliance_m3_per_pa(mmhg_to_pa(*b)))
        })
        .unwrap();
    assert!(
        (35.0..=45.0).contains(&peak),
        "peak compliance at {peak} mmHg"
    );
}

#[test]
fn derivative_matches_finite_differences() {
    let c = default_curve();
    for i in -30..=40 {
        let p = i as f64 * 500.0;
        let h = 0.1;
        let fd = (c.volume_m3(p + h) - c.volume_m3(p - h)) / (2.0 * h);
        let d = c.compliance_m3_per_pa(p);
        assert!((fd - d).abs() <= 1e-5 * d.abs(), "p {p}: fd {fd} vs {d}");
    }
}

#[test]
fn curve_is_finite_and_monotone_for_extreme_pressures() {
    let c = default_curve();
    let mut last = 0.0;
    for e in -300..=300 {
        let p = (e as f64 / 10.0).sinh() * 1e3;
        let v = c.volume_m3(p);
        assert!(v.is_finite() && v >= last && v > 0.0, "p {p} V {v}");
        assert!(c.compliance_m3_per_pa(p).is_finite());
        last = v;
    }
}

#[test]
fn default_inverse_round_trips() {
    let c = default_curve();
    for i in -20..=60 {
        let p = i as f64 * 400.0;
        let back = c.pressure_pa(c.volume_m3(p)).unwrap();
        assert!((back - p).abs() < 1e-4, "p {p} back {back}");
    }
    assert_eq!(c.pressure_pa(0.0), None);
}

#[test]
fn tabulated_curve_interpolates_and_extends_linearly() {
    let t = TabulatedCompliance::new(&[(0.0, 1.0), (10.0, 3.0), (20.0, 4.0)]).unwrap();
    assert_eq!(t.volume_m3(5.0), 2.0);
    assert_eq!(t.volume_m3(15.0), 3.5);
    assert_eq!(t.volume_m3(-10.0), -1.0);
    assert_eq!(t.volume_m3(30.0), 5.0);
    assert_eq!(t.compliance_m3_per_pa(25.0), 0.1);
    assert!((t.pressure_pa(3.5).unwrap() - 15.0).abs() < 1e-6);
    assert_eq!(
        TabulatedCompliance::new(&[(0.0, 1.0)]),
        Err(ComplianceError::TooFewPoints(1))
    );
    assert!(matches!(
        TabulatedCompliance::new(&[(0.0, 1.0), (1.0, 1.0)]),
        Err(ComplianceError::NotIncreasing { index: 1, .. })
    ));
}
