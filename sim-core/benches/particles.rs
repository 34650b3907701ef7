//! Criterion benchmarks of the vortex and particle stages on the benchmark cavity at 1.2 mm (the
//! paper's voxel), jet 1 m/s: the fluid step alone, with 100 vortices (overlay: the vortex step
//! and its face field; injected: plus the injection), and one particle step of 1e4 and 1e5
//! particles (the field build, RK2 with walls and outlets, the clarity figure).
//! `cargo bench -p hydrometra-sim --bench particles`.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use hydrometra_sim::fluid::cavity::uterine_cavity;
use hydrometra_sim::fluid::{CellLabel, FluidParams, FluidSolver};
use hydrometra_sim::scene::clarity::ViewSpec;
use hydrometra_sim::scene::particles::{
    kinds_from_labels, ParticleClass, ParticleKind, ParticleSystem,
};
use hydrometra_sim::scene::vortices::{VortexField, VortexMode, VortexSpec};

const DT: f64 = 1.0 / 60.0;

fn cavity() -> FluidSolver {
    let grid = uterine_cavity(1.2e-3, 1.0).expect("cavity");
    let params = FluidParams {
        tolerance: 1e-5,
        ..Default::default()
    };
    let mut s = FluidSolver::new(grid, params).expect("solver");
    for _ in 0..30 {
        s.step(DT).expect("step");
    }
    s
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
    let kinds = kinds_from_labels(s.grid());
    let fluid: Vec<usize> = (0..kinds.len())
        .filter(|&n| s.grid().label_at(n) == CellLabel::Fluid)
        .collect();
    let view = ViewSpec::default();
    // The scope looks along +z from the cavity's lower middle.
    let [nx, ny, nz] = s.grid().dims();
    let h = s.grid().spacing_m();
    let o = s.grid().origin_m();
    let cone = view.cone(
        [
            o[0] + 0.5 * nx as f64 * h,
            o[1] + 0.5 * ny as f64 * h,
            o[2] + 0.2 * nz as f64 * h,
        ],
        [0.0, 0.0, 1.0],
    );
    for count in [10_000usize, 100_000] {
        let mut sys = ParticleSystem::new(s.grid(), count, 8, [0.0, -1.0, 0.0]);
        let cls = sys
            .add_class(ParticleClass {
                kind: ParticleKind::Blood,
                settle_m_s: 3e-4,
                tau_s: 1e-4,
                shade_m2: 2e-7,
                diameter_m: 5e-5,
            })
            .expect("class");
        let mut rng = fastrand::Rng::with_seed(0);
        let mut refill = |sys: &mut ParticleSystem| {
            while sys.len() < count {
                let n = fluid[rng.usize(..fluid.len())];
                let c = s.grid().cell_centre_m(s.grid().coords(n));
                sys.emit(&kinds, cls, c);
            }
        };
        refill(&mut sys);
        g.bench_with_input(BenchmarkId::new("step", count), &count, |b, _| {
            b.iter(|| {
                // Keep the count (outlets remove some); refilling is a few per step.
                refill(&mut sys);
                sys.step(&s, &kinds, None, DT, Some(&cone))
            })
        });
    }
    g.finish();
}

criterion_group!(benches, vortices, particles);
criterion_main!(benches);
