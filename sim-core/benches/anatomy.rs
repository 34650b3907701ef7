//! Meshing time of the parametric uterus: `cargo bench -p hydrometra-sim --bench anatomy`.

use criterion::{criterion_group, criterion_main, Criterion};
use hydrometra_sim::anatomy::{generate, AnatomyParams, MyomaParams, WallSide};

fn bench_anatomy(c: &mut Criterion) {
    let mut g = c.benchmark_group("anatomy");
    g.sample_size(10);
    let default = AnatomyParams::default();
    g.bench_function("default_35k", |b| {
        b.iter(|| generate(&default).map(|a| a.summary.tets))
    });
    let mut coarse = AnatomyParams::default();
    coarse.mesh.target_tets = 8_000;
    g.bench_function("default_8k", |b| {
        b.iter(|| generate(&coarse).map(|a| a.summary.tets))
    });
    let mut myoma = AnatomyParams::default();
    myoma.myomas.push(MyomaParams {
        wall: WallSide::Posterior,
        x_mm: 0.0,
        from_fundus_mm: 12.0,
        diameters_mm: [12.0, 10.0, 12.0],
        figo: Some(1),
        depth_mm: None,
        angle_deg: None,
    });
    g.bench_function("figo1_myoma_35k", |b| {
        b.iter(|| generate(&myoma).map(|a| a.summary.tets))
    });
    g.finish();
}

criterion_group!(benches, bench_anatomy);
criterion_main!(benches);
