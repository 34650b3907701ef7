//! Criterion benchmarks of the cut-cell geometry on the default scene's cavity at 1.2 and 0.6 mm
//! (the scene's own box): a full build of every fraction, and the incremental update after a
//! 1 mmHg pressure step (40 <-> 41 mmHg) with every vertex taken at its new position
//! (threshold 0) and with the voxelizer's threshold of a tenth of a cell.
//! `cargo bench -p hydrometra-sim --bench cutcell` (the atlas comes from `target/hil-atlas`).

#[path = "../tests/cutcell_common/mod.rs"]
mod cutcell_common;

use criterion::{criterion_group, criterion_main, Criterion};
use hydrometra_sim::cutcell::{CutCells, Phase, SmallCellParams};

fn cut_cells(c: &mut Criterion) {
    for voxel_mm in [1.2, 0.6] {
        let scene = cutcell_common::default_scene(voxel_mm);
        let frames = cutcell_common::replayed(&scene, &[40.0, 41.0]);
        let (p0, p1) = (&frames[0], &frames[1]);
        let layers = vec![cutcell_common::cavity_layer(scene.cavity_surface())];
        let cells = *scene.cells();
        let new = || {
            CutCells::new(
                cells,
                Phase::Solid,
                layers.clone(),
                SmallCellParams::default(),
            )
            .expect("cut cells")
        };
        let mut g = c.benchmark_group(format!("cutcell_default_{voxel_mm}mm"));
        g.sample_size(30);
        let mut cut = new();
        g.bench_function("full", |b| b.iter(|| cut.full(&[p0]).expect("full")));
        for (name, threshold_m) in [
            ("update_1mmHg_all_vertices", 0.0),
            ("update_1mmHg_threshold_0.1_cell", 0.1 * cells.spacing_m),
        ] {
            let mut cut = new();
            cut.full(&[p0]).expect("full");
            let mut flip = false;
            g.bench_function(name, |b| {
                b.iter(|| {
                    flip = !flip;
                    let p = if flip { p1 } else { p0 };
                    cut.update(&[p], threshold_m).expect("update")
                })
            });
        }
        g.finish();
    }
}

criterion_group!(benches, cut_cells);
criterion_main!(benches);
