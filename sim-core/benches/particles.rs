//! Criterion benchmarks of the vortex and particle stages on the benchmark cavity at 1.2 mm (the
//! paper's voxel), jet 1 m/s: the fluid step alone, with 100 vortices (overlay: the vortex step
//! and its face field; injected: plus the injection), and one particle step of 1e4 and 1e5
//! particles (the field build, RK2 with walls and outlets, the clarity figure).
//! `cargo bench -p hydrometra-sim --bench particles`.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use hydrometra_sim::fluid::FluidSolver;
use hydrometra_sim::harness::stage_bench::{self, DT_S as DT};
use hydrometra_sim::scene::vortices::{VortexField, VortexMode, VortexSpec};

fn cavity() -> FluidSolver {
    stage_bench::cavity().expect("the benchmark cavity")
}

fn vortices(c: &mut Criterion) {
    let mut g = c.benchmark_group("vortices_1.2mm");
    g.sample_size(30);
    let mut s = cavity();
    g.bench_function("fluid_step", |b| b.iter(|| s.step(DT).expect("step")));
    for mode in [VortexMode::Overlay, VortexMode::Injected] {
        let spec = VortexSpec {
            mode,
            ..VortexSpec::default()
        };
        let mut s = cavity();
        let mut f = VortexField::new(spec, &s).expect("vortices");
        f.step(&s, 100, DT);
        let name = match mode {
            VortexMode::Overlay => "fluid_step_100_vortices_overlay",
            VortexMode::Injected => "fluid_step_100_vortices_injected",
        };
        g.bench_function(name, |b| {
            b.iter(|| {
                s.step(DT).expect("step");
                f.step(&s, 100, DT);
                if mode == VortexMode::Injected {
                    f.inject(&mut s);
                }
            })
        });
        g.bench_function(format!("{name}_vortex_stage_only"), |b| {
            b.iter(|| {
                f.step(&s, 100, DT);
                if mode == VortexMode::Injected {
                    f.inject(&mut s);
                }
            })
        });
    }
    g.finish();
}

fn particles(c: &mut Criterion) {
    let mut g = c.benchmark_group("particles_1.2mm");
    g.sample_size(30);
    let s = cavity();
    for count in [10_000usize, 100_000] {
        let mut blood = stage_bench::Blood::new(&s, count).expect("blood class");
        // Each step refills the count (outlets remove some; a few per step).
        g.bench_with_input(BenchmarkId::new("step", count), &count, |b, _| {
            b.iter(|| blood.step(&s))
        });
    }
    g.finish();
}

criterion_group!(benches, vortices, particles);
criterion_main!(benches);
