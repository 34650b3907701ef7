//! Our solver alone on the uterine benchmark cavity, for profiling the projection:
//! `cargo run -p hydrometra-sim --example fluid_projection -- [voxel_mm] [steps] [warmup]
//! [parallel_threshold_cells]`.
//! `parallel_threshold_cells` is `FluidParams::parallel_threshold_cells` (the multigrid splits levels
//! of at least 1/12 of that many fluid cells over two threads: 2,000 by default).
//! Prints the fluid cells, the step and projection means (ms), the CG iterations per step and the
//! worst `max |div u| h / U`.

use std::time::Instant;

use hydrometra_sim::fluid::{FluidParams, FluidSolver, ProjectionMethod};
use hydrometra_sim::harness::analytic_cavity::uterine_cavity;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let arg = |i: usize, default: f64| -> Result<f64, Box<dyn std::error::Error>> {
        Ok(match args.get(i) {
            Some(s) => s
                .parse()
                .map_err(|e| format!("argument {}: {s:?}: {e}", i + 1))?,
            None => default,
        })
    };
    let voxel_mm = arg(0, 1.2)?;
    let steps = arg(1, 200.0)? as usize;
    let warmup = arg(2, 40.0)? as usize;
    let threshold = arg(3, FluidParams::default().parallel_threshold_cells as f64)? as usize;
    let params = FluidParams {
        parallel_threshold_cells: threshold,
        projection: ProjectionMethod::MultigridPcg,
        tolerance: 1e-5,
        ..Default::default()
    };
    let mut s = FluidSolver::new(uterine_cavity(voxel_mm * 1e-3, 1.0)?, params)?;
    for _ in 0..warmup {
        s.step(1.0 / 60.0)?;
    }
    let (mut step, mut proj, mut its, mut div) = (0.0, 0.0, 0, 0.0f64);
    let mut proj_min = f64::INFINITY;
    for _ in 0..steps {
        let t = Instant::now();
        let st = s.step(1.0 / 60.0)?;
        step += t.elapsed().as_secs_f64() * 1e3;
        proj += st.project_ms;
        proj_min = proj_min.min(st.project_ms);
        its += st.projection_iterations;
        div = div.max(st.max_div_rel);
    }
    let n = steps as f64;
    println!(
        "voxel {voxel_mm} mm: {} fluid cells, step {:.3} ms, project {:.3} ms (min {:.3}), {:.2} its/step, max div h/U {:.2e}",
        s.fluid_cells(), step / n, proj / n, proj_min, its as f64 / n, div
    );
    Ok(())
}
