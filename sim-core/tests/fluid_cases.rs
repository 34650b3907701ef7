//! Case files: the documented examples run, the lid-driven cavity matches Ghia et al. (1982), and
//! malformed files get errors naming the key.

use hydrometra_sim::fluid::case::{Case, CaseError};

fn example(name: &str) -> String {
    let path = format!(
        "{}/../docs/fluid-cases/{name}.toml",
        env!("CARGO_MANIFEST_DIR")
    );
    std::fs::read_to_string(path).unwrap()
}

#[test]
fn lid_driven_cavity_matches_ghia_at_re_100() {
    let case = Case::parse(&example("lid_driven_cavity")).unwrap();
    let report = case.run().unwrap();
    let s = &report.statistics;
    assert!(s.steady_reached, "{s:?}");
    assert!(s.final_max_div_rel <= 1e-5);
    // Ghia, Ghia & Shin (1982), Re = 100, u on the vertical centreline.
    let ghia = [
        (0.0547, -0.03717),
        (0.1016, -0.06434),
        (0.1719, -0.10150),
        (0.2813, -0.15662),
        (0.4531, -0.21090),
        (0.6172, -0.13641),
        (0.7344, 0.00332),
        (0.8516, 0.23151),
        (0.9531, 0.68717),
    ];
    // Probe with 17 points: interpolate linearly at Ghia's ordinates.
    let probe = &report.probes[0].samples;
    let mut worst = 0.0f64;
    for (y, u_ref) in ghia {
        let t: f64 = y * 16.0;
        let i = (t.floor() as usize).min(15);
        let f = t - i as f64;
        let u = probe[i].velocity_m_s[0] * (1.0 - f) + probe[i + 1].velocity_m_s[0] * f;
        worst = worst.max((u - u_ref).abs());
    }
    println!("lid-driven cavity 32x32, Re 100: max |u - u_Ghia| on the vertical centreline = {worst:.4} (lid speed 1)");
    // 32 cells and a dissipative scheme: within 4 % of the lid speed.
    assert!(worst < 0.04, "{worst}");
}

#[test]
fn example_cases_parse_and_port_channel_runs() {
    for name in ["lid_driven_cavity", "square_duct", "port_channel"] {
        Case::parse(&example(name)).unwrap();
    }
    let short = example("port_channel").replace("end_s = 0.5", "end_s = 0.05");
    let r = Case::parse(&short).unwrap().run().unwrap();
    assert_eq!(r.statistics.steps, 10);
    assert_eq!(r.probes[0].samples.len(), 22);
    // Mass conservation: the jet carries 0.2 m/s through the port at the start of the axis.
    assert!((r.probes[0].samples[0].velocity_m_s[0] - 0.2).abs() < 0.01);
    assert!(r.statistics.final_max_div_rel <= 1e-5);
}

fn err(text: &str) -> String {
    match Case::parse(text) {
        Err(e) => e.to_string(),
        Ok(_) => panic!("accepted a bad case:\n{text}"),
    }
}

const BASE: &str = r#"
[grid]
cells = [4, 4, 4]
spacing_m = 0.001
[fluid]
density_kg_m3 = 1000.0
viscosity_m2_s = 1e-6
[time]
dt_s = 0.01
end_s = 0.1
"#;

#[test]
fn malformed_case_files_name_the_key_and_the_problem() {
    assert!(Case::parse(BASE).is_ok());
    let e = err(&BASE.replace("spacing_m = 0.001", "spacing_m = -1.0"));
    assert!(e.contains("grid.spacing_m") && e.contains("-1"), "{e}");
    let e = err(&BASE.replace("spacing_m", "spacing"));
    assert!(e.contains("spacing") && e.contains("line"), "{e}");
    let e = err(&BASE.replace("cells = [4, 4, 4]", "cells = [4, 4]"));
    assert!(e.contains("cells"), "{e}");
    let e = err(&BASE.replace("dt_s = 0.01", "dt_s = 0.01\ncfl = 1.0"));
    assert!(e.contains("time") && e.contains("exactly one"), "{e}");
    let e = err(&BASE.replace("end_s = 0.1", ""));
    assert!(e.contains("steady_tolerance"), "{e}");
    let e = err(&format!(
        "{BASE}[[region]]\nlabel = \"velocity\"\nmin_m = [0,0,0]\nmax_m = [1,1,1]\n"
    ));
    assert!(
        e.contains("region[0].velocity_m_s") && e.contains("required"),
        "{e}"
    );
    let e = err(&format!(
        "{BASE}[[region]]\nlabel = \"wall\"\nmin_m = [0,0,0]\nmax_m = [1,1,1]\n"
    ));
    assert!(e.contains("region[0].label") && e.contains("wall"), "{e}");
    let e = err(&format!("{BASE}[solver]\nprojection = \"sor\"\n"));
    assert!(e.contains("solver.projection") && e.contains("sor"), "{e}");
    let e = err(&format!("{BASE}[solver]\ntolerance = 0.0\n"));
    assert!(e.contains("tolerance"), "{e}");
    let e = err(&format!(
        "{BASE}[[probe]]\nname = \"a\"\nfrom_m = [0,0,0]\nto_m = [1,1,1]\npoints = 0\n"
    ));
    assert!(e.contains("probe[0].points"), "{e}");
    let e = err(&BASE.replace("density_kg_m3 = 1000.0", "density_kg_m3 = \"water\""));
    assert!(e.contains("density_kg_m3"), "{e}");
    assert!(matches!(
        Case::parse("not toml ["),
        Err(CaseError::Parse(_))
    ));
}

#[test]
fn cfl_time_step_without_motion_asks_for_max_dt() {
    let text = BASE.replace("dt_s = 0.01", "cfl = 1.0");
    let e = Case::parse(&text).unwrap().run().unwrap_err().to_string();
    assert!(e.contains("time.max_dt_s"), "{e}");
}
