// Per-axis loops index several arrays at once.
#![allow(clippy::needless_range_loop)]
//! The default scene's cavity surface (its atlas from the shared test cache `target/hil-atlas`)
//! on the scene's own box at 1.2 and 0.6 mm: over a pressure sweep the fluid volume of the cut
//! cells (sum of fractions x h^3) equals the volume the surface encloses within 1e-9 relative
//! (the conservative voxelizer's fluid cells hold about half of it), every cell's faces and walls
//! close, and the incremental updates along the sweep equal full recomputations bit for bit.

mod cutcell_common;
use cutcell_common::*;
use hydrometra_sim::cutcell::{CutCells, Phase, SmallCellParams};
use hydrometra_sim::units::mmhg_to_pa;

#[test]
fn default_cavity_fluid_volume_is_the_surface_volume() {
    for voxel_mm in [1.2, 0.6] {
        let scene = default_scene(voxel_mm);
        let cells = *scene.cells();
        let h = cells.spacing_m;
        let mut surface = scene.cavity_surface().clone();
        let compact = surface.compact_atlas(scene.atlas()).unwrap();
        let layers = vec![cavity_layer(&surface)];
        let new = || {
            CutCells::new(
                cells,
                Phase::Solid,
                layers.clone(),
                SmallCellParams::default(),
            )
            .unwrap()
        };
        let mut inc = new();
        let mut worst: f64 = 0.0;
        for mmhg in [150.0, 80.0, 40.0, 41.0, 20.0, 10.0, 5.0, 2.0, 0.0, 30.0] {
            surface.replay_compact(&compact, mmhg_to_pa(mmhg)).unwrap();
            let pos = surface.positions_m();
            let stats = inc.update(&[pos], 0.0).unwrap();
            let mut full = new();
            full.full(&[pos]).unwrap();
            for (a, b) in [
                (inc.volume_fractions(), full.volume_fractions()),
                (
                    inc.stabilised_volume_fractions(),
                    full.stabilised_volume_fractions(),
                ),
            ] {
                assert!(
                    a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits()),
                    "{voxel_mm} mm, {mmhg} mmHg: incremental != full"
                );
            }
            for axis in 0..3 {
                assert!(inc
                    .face_fractions(axis)
                    .iter()
                    .zip(full.face_fractions(axis))
                    .all(|(x, y)| x.to_bits() == y.to_bits()));
            }
            let fluid = inc.volume_fractions().iter().sum::<f64>() * h * h * h;
            let enclosed = surface.enclosed_volume_m3();
            let e = (fluid - enclosed).abs() / enclosed;
            worst = worst.max(e);
            let defect = max_divergence_defect(inc.layer(0));
            let cells_cut = inc
                .volume_fractions()
                .iter()
                .filter(|&&v| v > 0.0 && v < 1.0)
                .count();
            eprintln!(
                "{voxel_mm} mm, {mmhg:5.1} mmHg: surface {:.4} ml, cut cells {:.4} ml (relative {e:.1e}), \
                 {cells_cut} cut cells, {} merged, {} small unmerged; update: {} rows, {} strips, \
                 {} rows changed; largest face/wall defect {defect:.1e}",
                enclosed * 1e6, fluid * 1e6, stats.merged_cells, stats.unmerged_small_cells,
                stats.layers.rows, stats.layers.strips, stats.changed_rows,
            );
            assert!(
                e < 1e-9,
                "{voxel_mm} mm at {mmhg} mmHg: relative volume error {e:e}"
            );
            assert!(defect < 1e-12);
            let stabilised: f64 = inc.stabilised_volume_fractions().iter().sum::<f64>() * h * h * h;
            assert!((stabilised - fluid).abs() <= 1e-12 * fluid);
        }
        eprintln!("{voxel_mm} mm: largest relative volume error {worst:.1e}");
    }
}
