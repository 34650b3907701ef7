//! Criterion benchmark of one fluid step on the benchmark cavity (the paper's 1.2 and 0.6 mm voxels):
//! our multigrid-PCG projection and the paper-class 20-sweep Gauss-Seidel baseline.
//! `cargo bench -p hydrometra-sim --bench fluid`. The Table 1 shaped figures with divergence and
//! iterations come from `hydrometra fluid bench`.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use hydrometra_sim::fluid::{FluidParams, FluidSolver, ProjectionMethod};
use hydrometra_sim::harness::analytic_cavity::uterine_cavity;

fn step(c: &mut Criterion) {
    let mut g = c.benchmark_group("fluid_step_cavity");
    g.sample_size(20);
    for voxel_mm in [1.2, 0.6] {
        for (name, method) in [
            ("mgpcg_1e-5", ProjectionMethod::MultigridPcg),
            (
                "gauss_seidel_20",
                ProjectionMethod::GaussSeidel { sweeps: 20 },
            ),
        ] {
            let grid = uterine_cavity(voxel_mm * 1e-3, 1.0).expect("cavity");
            let params = FluidParams {
                projection: method,
                tolerance: 1e-5,
                ..Default::default()
            };
            let mut s = FluidSolver::new(grid, params).expect("solver");
            for _ in 0..30 {
                s.step(1.0 / 60.0).expect("step");
            }
            g.bench_with_input(BenchmarkId::new(name, voxel_mm), &voxel_mm, |b, _| {
                b.iter(|| s.step(1.0 / 60.0).expect("step"))
            });
        }
    }
    g.finish();
}

criterion_group!(benches, step);
criterion_main!(benches);
