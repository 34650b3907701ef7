use hydrometra_sim::fluid::*;
#[test]
fn scratch() {
    for &h in &[0.0006, 0.0012] {
        let g = cavity::ellipsoid_cavity(h, 1.0).unwrap();
        let mut s = FluidSolver::new(g, FluidParams::default()).unwrap();
        for _ in 0..10 { s.step(1.0/60.0).unwrap(); }
        let (mut a, mut d, mut p, mut t, mut it) = (0.0, 0.0, 0.0, 0.0, 0);
        let n = 40;
        for _ in 0..n { let st = s.step(1.0/60.0).unwrap(); a += st.advect_ms; d += st.diffuse_ms; p += st.project_ms; t += st.total_ms; it += st.projection_iterations; }
        let n = n as f64;
        println!("h={h} cells={} adv={:.3} diff={:.3} proj={:.3} total={:.3} its={:.1}", s.fluid_cells(), a/n, d/n, p/n, t/n, it as f64/n);
    }
}
