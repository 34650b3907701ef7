//! The advection schemes against each other on flows with known dissipation: Taylor-Green (2D and
//! 3D) and ABC (3D) effective viscosity, the Re-1000 cavity, and case files naming every scheme.

use hydrometra_sim::fluid::case::Case;
use hydrometra_sim::fluid::AdvectionScheme;
use hydrometra_sim::harness::validation::{abc_flow, taylor_green};

fn run(r: hydrometra_sim::harness::validation::ValidationResult) -> f64 {
    assert!(r.all_converged, "{r:?}");
    println!(
        "{} {} cells: nu_eff / nu = {:.4}",
        r.case, r.cells_across, r.error
    );
    r.error
}

#[test]
fn taylor_green_dissipation_of_every_scheme_and_the_default_within_5_percent_at_32_cells() {
    let sl = run(taylor_green(32, AdvectionScheme::SemiLagrangian).unwrap());
    let mc = run(taylor_green(32, AdvectionScheme::MacCormack).unwrap());
    for scheme in AdvectionScheme::ALL {
        let r = run(taylor_green(32, scheme).unwrap());
        // Numerical dissipation only adds (a scheme that gains energy would read below 1).
        assert!(r > 0.98, "{scheme:?}: {r}");
        if scheme != AdvectionScheme::SemiLagrangian {
            // Every higher-order scheme removes at least 70 % of semi-Lagrangian's excess.
            assert!(r - 1.0 < 0.3 * (sl - 1.0), "{scheme:?}: {r} vs {sl}");
        }
    }
    // The default (the lagged reflection): within 2 % of the physical viscosity at 32 cells (the
    // closed-form decay rate ignores the discrete Laplacian's -(kh)^2/12 = -0.3 %), less than a
    // quarter of MacCormack's excess.
    let default = AdvectionScheme::default();
    assert_eq!(default, AdvectionScheme::MacCormackLaggedReflection);
    let d = run(taylor_green(32, default).unwrap());
    assert!((d - 1.0).abs() <= 0.02, "{d}");
    assert!((d - 1.0).abs() < 0.25 * (mc - 1.0), "{d} vs {mc}");
    // And it converges: the excess at 16 cells is larger.
    let d16 = run(taylor_green(16, default).unwrap());
    assert!(d16 - 1.0 > (d - 1.0).abs(), "{d16} vs {d}");
}

#[test]
fn abc_flow_dissipation_drops_with_every_higher_order_scheme_and_reflection_removes_the_split_loss()
{
    let sl = run(abc_flow(16, AdvectionScheme::SemiLagrangian).unwrap());
    for scheme in AdvectionScheme::ALL {
        let r = run(abc_flow(16, scheme).unwrap());
        assert!(r > 0.98, "{scheme:?}: {r}");
        if scheme != AdvectionScheme::SemiLagrangian {
            assert!(r - 1.0 < 0.3 * (sl - 1.0), "{scheme:?}: {r} vs {sl}");
        }
        if scheme == AdvectionScheme::MacCormackReflection {
            assert!(r < 1.03, "{r}");
        }
    }
    // The lagged reflection removes the split loss too (it traces through the divergence-free
    // velocity: through the reflected field it would lose what it saves) and converges.
    let mc = run(abc_flow(16, AdvectionScheme::MacCormack).unwrap());
    let lagged = AdvectionScheme::MacCormackLaggedReflection;
    let d16 = run(abc_flow(16, lagged).unwrap());
    assert!(d16 - 1.0 < 0.15 * (mc - 1.0), "{d16} vs {mc}");
    let d32 = run(abc_flow(32, lagged).unwrap());
    assert!(
        (d32 - 1.0).abs() <= 0.01 && d32 - 1.0 < 0.5 * (d16 - 1.0),
        "{d32} vs {d16}"
    );
}

/// The energy-identity estimate of `nu_eff` (`-dE/dt / 2Z`, no exact solution needed) agrees with
/// the closed-form decay of the ABC flow: they differ by the discrete curl against the continuous
/// wavenumber, `(kh)^2/12` = 1.3 % at 16 cells, times the scheme's excess.
#[test]
fn energy_identity_estimate_of_the_effective_viscosity_matches_the_abc_closed_form() {
    use hydrometra_sim::fluid::{FluidGrid, FluidParams, FluidSolver};
    use hydrometra_sim::harness::validation::periodic_effective_viscosity;
    use std::f64::consts::PI;
    let (n, nu) = (16, 0.01);
    let (h, k) = (1.0 / n as f64, 2.0 * PI);
    for scheme in [AdvectionScheme::SemiLagrangian, AdvectionScheme::default()] {
        let closed = run(abc_flow(n, scheme).unwrap());
        let grid = FluidGrid::new([n; 3], h, [0.0; 3], [true; 3]).unwrap();
        let params = FluidParams {
            density_kg_m3: 1.0,
            viscosity_m2_s: nu,
            advection: scheme,
            ..Default::default()
        };
        let mut s = FluidSolver::new(grid, params).unwrap();
        s.set_velocity_field(|c, x| {
            let [x, y, z] = x.map(|v| k * v);
            [z.sin() + y.cos(), x.sin() + z.cos(), y.sin() + x.cos()][c]
        });
        assert!(s.project_now(1.0).projection_converged);
        let steps = (0.5 / (0.5 * h / s.max_speed_m_s())).ceil() as usize;
        let (nu_eff, ok) = periodic_effective_viscosity(&mut s, 0.5 / steps as f64, 0.5).unwrap();
        assert!(ok);
        println!(
            "{scheme:?}: identity {:.4}, closed form {closed:.4}",
            nu_eff / nu
        );
        assert!(
            (nu_eff / nu / closed - 1.0).abs() < 0.05,
            "{nu_eff} vs {closed}"
        );
        assert!(
            nu_eff / nu >= closed,
            "the discrete curl is the smaller wavenumber"
        );
    }
    // Not a periodic box: refused, not guessed.
    let grid = FluidGrid::new([4; 3], h, [0.0; 3], [true, true, false]).unwrap();
    let mut s = FluidSolver::new(grid, FluidParams::default()).unwrap();
    assert!(periodic_effective_viscosity(&mut s, 0.1, 0.1).is_err());
}

/// The issue's acceptance case: the 3D Taylor-Green vortex (Re 100, to t = 5) at 32 cells per
/// period. The default's effective viscosity is within 10 % of the physical one and closer than
/// MacCormack's; below 1 from t ~ 1 on, where the stretched vortex reaches the grid scale (the full
/// advection-reflection reads the same, 0.92 at 32 cells, 0.98 at 64).
#[test]
fn taylor_green_3d_effective_viscosity_of_the_default_within_10_percent_at_32_cells() {
    use hydrometra_sim::harness::validation::taylor_green_3d;
    let mc = run(taylor_green_3d(32, AdvectionScheme::MacCormack).unwrap());
    let d = run(taylor_green_3d(32, AdvectionScheme::default()).unwrap());
    assert!((d - 1.0).abs() <= 0.1, "{d}");
    assert!((d - 1.0).abs() < (mc - 1.0).abs(), "{d} vs {mc}");
}

#[test]
fn case_files_offer_every_scheme_and_name_them_on_a_bad_one() {
    let base = r#"
[grid]
cells = [6, 5, 4]
spacing_m = 0.001
[fluid]
density_kg_m3 = 1000.0
viscosity_m2_s = 1e-6
[time]
dt_s = 0.01
end_s = 0.03
[[region]]
label = "velocity"
min_m = [0.0, 0.001, 0.001]
max_m = [0.001, 0.003, 0.003]
velocity_m_s = [0.05, 0.0, 0.0]
[[region]]
label = "outflow"
min_m = [0.005, 0.0, 0.0]
max_m = [0.006, 0.005, 0.004]
"#;
    assert_eq!(
        Case::parse(base).unwrap().params().unwrap().advection,
        AdvectionScheme::default()
    );
    for scheme in AdvectionScheme::ALL {
        let text = format!("{base}[solver]\nadvection = \"{}\"\n", scheme.name());
        let case = Case::parse(&text).unwrap();
        assert_eq!(case.params().unwrap().advection, scheme);
        let r = case.run().unwrap();
        assert_eq!(r.statistics.steps, 3);
        assert!(r.statistics.final_max_div_rel <= 1e-5, "{scheme:?}");
        assert!(r.statistics.max_speed_m_s.is_finite());
    }
    let text = format!("{base}[solver]\nadvection = \"weno\"\n");
    let e = match Case::parse(&text) {
        Err(e) => e.to_string(),
        Ok(c) => c.params().unwrap_err().to_string(),
    };
    assert!(e.contains("solver.advection") && e.contains("weno"), "{e}");
    for scheme in AdvectionScheme::ALL {
        assert!(e.contains(scheme.name()), "{e}");
    }
}

#[test]
fn cavity_at_re_1000_with_64_cells_meets_ghia_extrema_within_0_02_with_the_default() {
    use hydrometra_sim::harness::validation::{lid_cavity_re1000, CavityExtrema};
    // The reference extrema from the data file (not from the library's constants).
    let csv = include_str!("data/cavity_re1000_reference.csv");
    let rows: Vec<(String, f64)> = csv
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (f[0].to_string(), f[2].trim().parse().unwrap())
        })
        .collect();
    let line =
        |name: &str| -> Vec<f64> { rows.iter().filter(|r| r.0 == name).map(|r| r.1).collect() };
    let ghia = CavityExtrema {
        u_min: line("u_vertical").into_iter().fold(f64::INFINITY, f64::min),
        v_max: line("v_horizontal")
            .into_iter()
            .fold(f64::NEG_INFINITY, f64::max),
        v_min: line("v_horizontal")
            .into_iter()
            .fold(f64::INFINITY, f64::min),
    };
    assert_eq!(ghia.max_diff(&CavityExtrema::GHIA), 0.0);
    let (r, e) = lid_cavity_re1000(64, AdvectionScheme::default()).unwrap();
    println!("{r:?}\n{e:?}");
    assert!(r.all_converged, "{r:?}");
    assert!(e.max_diff(&ghia) <= 0.02, "{e:?}");
    // Botella-Peyret's spectral extrema are 0.004-0.012 beyond Ghia's; ours lie on Ghia's side.
    assert!(e.max_diff(&CavityExtrema::BOTELLA_PEYRET) <= 0.03, "{e:?}");
}
