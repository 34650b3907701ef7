use hydrometra_sim::fluid::*;
#[test]
fn scratch() {
    for &h in &[0.0006, 0.0009, 0.0012, 0.0015, 0.0018] {
        let g = cavity::ellipsoid_cavity(h, 1.0).unwrap();
        let mut s = FluidSolver::new(g, FluidParams::default()).unwrap();
        let mut its = vec![];
        let t = std::time::Instant::now();
        let mut last = None;
        for _ in 0..30 { let st = s.step(1.0/60.0).unwrap(); its.push(st.projection_iterations); last = Some(st); }
        let st = last.unwrap();
        println!("h={h} cells={} total={} levels={} its={:?} div={:.2e} adv={:.2} proj={:.2} ms/step={:.2} ke={:.3e}",
          s.fluid_cells(), s.grid().cell_count(), s.multigrid_levels(), its, st.max_div_rel, st.advect_ms, st.project_ms,
          t.elapsed().as_secs_f64()*1e3/30.0, s.kinetic_energy_j());
    }
}
