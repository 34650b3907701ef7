// Per-axis loops index several arrays at once.
#![allow(clippy::needless_range_loop)]
//! Cut-cell updates allocate nothing on the heap once built: the default cavity stepping between
//! pressures at 1.2 mm, and a breathing ellipsoid with a moving sheath through it (two layers and
//! the small-cell rule). The first cycle may grow buffers; the second must not.

use std::sync::atomic::Ordering;

mod common;
mod cutcell_common;
use common::alloc::ALLOCS;
use cutcell_common::*;
use hydrometra_sim::cutcell::shapes::{self, Tessellation};
use hydrometra_sim::cutcell::{CutCells, Orientation, Phase, SmallCellParams};
use hydrometra_sim::scene::voxelize::VoxelBox;

#[test]
fn updates_do_not_allocate() {
    // The default cavity: a cycle of pressures, positions replayed beforehand.
    let scene = default_scene(1.2);
    let frames = replayed(&scene, &[40.0, 41.0, 43.0, 45.0, 42.0, 38.0, 30.0, 35.0]);
    let mut cavity = CutCells::new(
        *scene.cells(),
        Phase::Solid,
        vec![cavity_layer(scene.cavity_surface())],
        SmallCellParams::default(),
    )
    .unwrap();

    // A breathing ellipsoid and a sheath sliding through it.
    let unit = shapes::sphere([0.0; 3], 0.004, Tessellation::for_spacing(0.001)).unwrap();
    let sheath = shapes::cylinder(
        [0.0; 3],
        [1.0, 0.3, 0.1],
        0.001,
        0.012,
        Tessellation::for_spacing(0.001),
    )
    .unwrap();
    let cells = VoxelBox {
        dims: [14, 12, 10],
        origin_m: [-0.007, -0.006, -0.005],
        spacing_m: 0.001,
    };
    let layers = vec![
        layer("ellipsoid", &unit, Orientation::Outward, Phase::Fluid),
        layer("sheath", &sheath, Orientation::Outward, Phase::Solid),
    ];
    let mut pair = CutCells::new(cells, Phase::Solid, layers, SmallCellParams::default()).unwrap();
    let pair_frames: Vec<[Vec<[f32; 3]>; 2]> = (0..8)
        .map(|n| {
            let s = 1.0 + 0.15 * (n as f64 * 0.8).sin();
            let e = transformed(
                &unit,
                [s, 0.7 * s, 0.5],
                &rotation(0.1 * n as f64, 0.2, 0.0),
                [0.0; 3],
            );
            let c = transformed(
                &sheath,
                [1.0; 3],
                &rotation(0.0, 0.0, 0.0),
                [0.0005 * n as f64, 0.0, 0.0],
            );
            [e.positions_m().to_vec(), c.positions_m().to_vec()]
        })
        .collect();

    cavity.full(&[&frames[0]]).unwrap();
    pair.full(&[&pair_frames[0][0], &pair_frames[0][1]])
        .unwrap();
    let mut stats = Vec::with_capacity(64);
    for cycle in 0..2 {
        let before = ALLOCS.load(Ordering::Relaxed);
        for (f, g) in frames.iter().zip(&pair_frames) {
            stats.push(cavity.update(&[f], 0.0).unwrap());
            stats.push(pair.update(&[&g[0], &g[1]], 0.0).unwrap());
        }
        let allocations = ALLOCS.load(Ordering::Relaxed) - before;
        eprintln!(
            "cycle {cycle}: {allocations} allocations in {} updates",
            2 * frames.len()
        );
        if cycle == 1 {
            assert_eq!(allocations, 0);
        }
    }
    // Every update but the first two (the positions of the full build) recomputed rows.
    assert!(stats[2..].iter().all(|s| s.layers.rows > 0));
}
