//! Atlas replay speed: `Atlas::positions_at` for a uterus-sized atlas (7,500 vertices, 25 levels),
//! Hermite and linear; and the scene's surface replay (positions and `dx/dp` of every 6th vertex
//! of a 30,000-vertex atlas), gathered from the whole atlas (`replay_subset`) or read in order from
//! the atlas restricted to those vertices (`subset`, `replay`).
//! Run: `cargo bench -p hydrometra-sim --bench fem_replay`.

use criterion::{criterion_group, criterion_main, Criterion};
use hydrometra_sim::atlas::{Atlas, AtlasLevel};
use std::hint::black_box;

fn synthetic_atlas(vertices: usize, levels: usize) -> Atlas {
    let rest: Vec<[f64; 3]> = (0..vertices)
        .map(|i| {
            let t = i as f64 * 0.001;
            [
                0.02 * t.sin(),
                0.015 * t.cos(),
                0.07 * (i as f64 / vertices as f64),
            ]
        })
        .collect();
    let lv: Vec<AtlasLevel> = (0..levels)
        .map(|k| {
            let p = 20000.0 * k as f64 / (levels - 1) as f64;
            let s = 1.0 + 1e-5 * p - 1e-10 * p * p;
            let ds = 1e-5 - 2e-10 * p;
            AtlasLevel {
                pressure_pa: p,
                cavity_volume_m3: 1e-6 * s * s * s,
                positions_m: rest.iter().map(|x| x.map(|c| c * s)).collect(),
                dxdp_m_per_pa: rest.iter().map(|x| x.map(|c| c * ds)).collect(),
            }
        })
        .collect();
    Atlas::new(0, serde_json::json!({}), rest, &lv).expect("valid synthetic atlas")
}

fn bench(c: &mut Criterion) {
    let atlas = synthetic_atlas(7500, 25);
    let mut out = vec![[0.0f32; 3]; atlas.vertex_count()];
    let mut p = 0.0f64;
    c.bench_function("atlas_positions_at_hermite_7500v", |b| {
        b.iter(|| {
            p = (p + 377.0) % 20000.0;
            atlas
                .positions_at(black_box(p), &mut out)
                .expect("sizes match");
        })
    });
    c.bench_function("atlas_positions_at_linear_7500v", |b| {
        b.iter(|| {
            p = (p + 377.0) % 20000.0;
            atlas
                .positions_at_linear(black_box(p), &mut out)
                .expect("sizes match");
        })
    });
}

fn surface_replay(c: &mut Criterion) {
    let atlas = synthetic_atlas(30_000, 25);
    let ids: Vec<u32> = (0..30_000).step_by(6).collect();
    let compact = atlas.subset(&ids).expect("ids in the atlas");
    let (mut pos, mut dxdp) = (vec![[0.0f32; 3]; ids.len()], vec![[0.0f32; 3]; ids.len()]);
    let mut p = 0.0f64;
    c.bench_function("atlas_replay_subset_5000_of_30000v", |b| {
        b.iter(|| {
            p = (p + 377.0) % 20000.0;
            atlas
                .replay_subset(black_box(p), &ids, &mut pos, &mut dxdp)
                .expect("sizes match");
        })
    });
    c.bench_function("atlas_replay_compact_5000v", |b| {
        b.iter(|| {
            p = (p + 377.0) % 20000.0;
            compact
                .replay(black_box(p), &mut pos, &mut dxdp)
                .expect("sizes match");
        })
    });
}

criterion_group!(benches, bench, surface_replay);
criterion_main!(benches);
