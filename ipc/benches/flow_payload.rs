//! The daemon's cost of writing one flow field payload (labels, velocities, fractions) at the
//! default scene's box sizes, 0.6 and 1.2 mm: `FlowLayout::fill` into the scene thread's buffer,
//! then the copy into a loaned sample (a plain slice copy here).
//! Run: `cargo bench -p hydrometra-ipc --bench flow_payload`.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use hydrometra_ipc::field::{fraction_to_u8, FlowLayout};

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("flow_payload");
    // The default scene's grid boxes (BENCHMARKS.md, the scene step rows).
    for (voxel, cells) in [("0.6mm", 312_620usize), ("1.2mm", 43_680)] {
        let layout = FlowLayout::new(cells);
        let labels: Vec<u8> = (0..cells).map(|c| (c % 7) as u8).collect();
        let velocities: Vec<[f32; 3]> = (0..cells)
            .map(|c| [c as f32 * 1e-6, -(c as f32) * 1e-6, 0.01])
            .collect();
        let fractions: Vec<f64> = (0..cells).map(|c| (c % 101) as f64 / 100.0).collect();
        let mut payload = Vec::with_capacity(layout.total_bytes);
        let mut sample = vec![0u8; layout.total_bytes];
        g.throughput(Throughput::Bytes(layout.total_bytes as u64));
        g.bench_with_input(BenchmarkId::new("fill_and_copy", voxel), &cells, |b, _| {
            b.iter(|| {
                layout.fill(
                    &mut payload,
                    |c| labels[c],
                    |c| velocities[c],
                    |c| fraction_to_u8(fractions[c]),
                );
                sample.copy_from_slice(black_box(&payload));
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
