// Per-axis loops index several arrays at once.
#![allow(clippy::needless_range_loop)]
//! Incremental cut cells equal a full recomputation bit for bit after any sequence of vertex
//! moves (random moves, jumps, vertices snapped onto grid planes, thresholds), for one surface and
//! for layers combined with the small-cell rule; the rows reported changed are the only ones that
//! changed.

mod cutcell_common;
use cutcell_common::*;
use hydrometra_sim::cutcell::shapes::{self, Tessellation};
use hydrometra_sim::cutcell::{CutCells, Layer, Orientation, Phase, SmallCellParams};
use hydrometra_sim::scene::voxelize::VoxelBox;
use proptest::prelude::*;

/// A fluid ellipsoid (inward normals, like the cavity) with a solid cylinder (the sheath)
/// through it, on a box of 1 mm cells.
fn scene() -> (VoxelBox, Vec<Vec<[f32; 3]>>, Vec<Layer>) {
    let unit = shapes::sphere(
        [0.0; 3],
        0.004,
        Tessellation {
            max_edge_m: 0.0015,
            match_volume: true,
        },
    )
    .unwrap();
    let cavity = transformed(
        &unit,
        [1.0, 0.7, 0.4],
        &rotation(0.3, 0.2, 0.1),
        [0.0002, 0.0001, 0.0003],
    );
    let sheath = shapes::cylinder(
        [0.003, 0.0, 0.0],
        [1.0, 0.2, 0.1],
        0.0012,
        0.008,
        Tessellation::for_spacing(0.002),
    )
    .unwrap();
    let cells = VoxelBox {
        dims: [11, 9, 7],
        origin_m: [-0.0055, -0.0045, -0.0035],
        spacing_m: 0.001,
    };
    // The cavity with its normals turned inwards.
    let layers = vec![
        layer("cavity", &cavity, Orientation::Inward, Phase::Fluid),
        layer("sheath", &sheath, Orientation::Outward, Phase::Solid),
    ];
    (
        cells,
        vec![cavity.positions_m().to_vec(), sheath.positions_m().to_vec()],
        layers,
    )
}

fn bits(x: &[f64]) -> Vec<u64> {
    x.iter().map(|v| v.to_bits()).collect()
}

/// Every output of `a` and `b`, bit for bit.
fn assert_same(a: &CutCells, b: &CutCells) {
    assert_eq!(
        bits(a.volume_fractions()),
        bits(b.volume_fractions()),
        "volumes"
    );
    assert_eq!(
        bits(a.stabilised_volume_fractions()),
        bits(b.stabilised_volume_fractions()),
        "stabilised volumes"
    );
    assert_eq!(a.merge_targets(), b.merge_targets(), "merge targets");
    assert_eq!(a.approximate(), b.approximate(), "approximate cells");
    for axis in 0..3 {
        assert_eq!(
            bits(a.face_fractions(axis)),
            bits(b.face_fractions(axis)),
            "faces {axis}"
        );
        assert_eq!(
            bits(a.stabilised_face_fractions(axis)),
            bits(b.stabilised_face_fractions(axis)),
            "stabilised faces {axis}"
        );
    }
    let walls = |c: &CutCells| {
        c.wall_areas()
            .iter()
            .flat_map(|s| s.map(f64::to_bits))
            .collect::<Vec<_>>()
    };
    assert_eq!(walls(a), walls(b), "walls");
    for l in 0..a.layer_count() {
        let (x, y) = (a.layer(l), b.layer(l));
        assert_eq!(
            bits(x.volume_fractions()),
            bits(y.volume_fractions()),
            "layer {l} volumes"
        );
        for axis in 0..3 {
            assert_eq!(
                bits(x.face_fractions(axis)),
                bits(y.face_fractions(axis)),
                "layer {l} faces {axis}"
            );
        }
    }
}

/// A move: which layer, which vertices (every `stride`-th from `first`), by how much (cells),
/// snapped onto the nearest grid plane along an axis or not.
#[derive(Debug, Clone)]
struct Move {
    layer: usize,
    first: usize,
    stride: usize,
    by: [f64; 3],
    snap: Option<usize>,
    threshold_cells: f64,
}

fn moves() -> impl Strategy<Value = Vec<Move>> {
    let one = (
        0..2usize,
        0..400usize,
        1..40usize,
        prop::array::uniform3(-1.5..1.5f64),
        prop::option::of(0..3usize),
        prop_oneof![Just(0.0), Just(0.05), 0.0..0.5f64],
    )
        .prop_map(|(layer, first, stride, by, snap, threshold_cells)| Move {
            layer,
            first,
            stride,
            by,
            snap,
            threshold_cells,
        });
    prop::collection::vec(one, 1..12)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, failure_persistence: None, ..ProptestConfig::default() })]
    #[test]
    fn incremental_equals_full_after_any_moves(seq in moves()) {
        let (cells, mut pos, layers) = scene();
        let params = SmallCellParams::default();
        let mut inc = CutCells::new(cells, Phase::Solid, layers.clone(), params).unwrap();
        inc.update(&[&pos[0], &pos[1]], 0.0).unwrap();
        for m in &seq {
            let before = inc.clone();
            let p = &mut pos[m.layer];
            let n = p.len();
            let mut v = m.first % n;
            while v < n {
                for a in 0..3 {
                    p[v][a] += (m.by[a] * cells.spacing_m) as f32;
                }
                if let Some(a) = m.snap {
                    // Onto the nearest grid plane, exactly in the cell coordinates.
                    let c = ((p[v][a] as f64 - cells.origin_m[a]) / cells.spacing_m).round();
                    p[v][a] = (cells.origin_m[a] + c * cells.spacing_m) as f32;
                }
                v += m.stride;
            }
            let stats = inc.update(&[&pos[0], &pos[1]], m.threshold_cells * cells.spacing_m).unwrap();
            let held = [inc.layer(0).positions_m().to_vec(), inc.layer(1).positions_m().to_vec()];
            let mut full = CutCells::new(cells, Phase::Solid, layers.clone(), params).unwrap();
            full.full(&[&held[0], &held[1]]).unwrap();
            assert_same(&inc, &full);
            prop_assert!(inc.volume_fractions().iter().all(|v| (0.0..=1.0).contains(v)));
            // Rows not reported changed are unchanged.
            let nx = cells.dims[0];
            let mut reported = vec![false; cells.dims[1] * cells.dims[2]];
            for &r in inc.changed_rows() {
                reported[r as usize] = true;
            }
            prop_assert_eq!(stats.changed_rows, inc.changed_rows().len());
            for (r, &rep) in reported.iter().enumerate() {
                if !rep {
                    let s = nx * r..nx * (r + 1);
                    prop_assert_eq!(bits(&inc.volume_fractions()[s.clone()]), bits(&before.volume_fractions()[s.clone()]));
                    prop_assert_eq!(bits(&inc.stabilised_volume_fractions()[s.clone()]), bits(&before.stabilised_volume_fractions()[s]));
                }
            }
        }
    }
}

/// The small-cell rule: every small cell with a large neighbour is merged into the one it shares
/// the largest open face with, its volume moved there; the stabilised volumes sum to the exact
/// ones; unmerged small cells have no large neighbour.
#[test]
fn small_cells_merge_into_their_largest_open_neighbour_and_conserve_volume() {
    let (cells, pos, layers) = scene();
    for theta in [0.05, 0.1, 0.3, 0.5] {
        let params = SmallCellParams {
            min_volume_fraction: theta,
            ..SmallCellParams::default()
        };
        let mut c = CutCells::new(cells, Phase::Solid, layers.clone(), params).unwrap();
        let stats = c.full(&[&pos[0], &pos[1]]).unwrap();
        let v = c.volume_fractions();
        let (exact, stabilised): (f64, f64) =
            (v.iter().sum(), c.stabilised_volume_fractions().iter().sum());
        // Conserved but for the rounding dust the rule drops (at most round_off per cell).
        let dust: f64 = v
            .iter()
            .filter(|&&x| x > 0.0 && x <= params.round_off_fraction)
            .sum();
        assert!(
            (exact - dust - stabilised).abs() <= 1e-12 * exact,
            "theta {theta}: {exact} - {dust} vs {stabilised}"
        );
        // The stabilised faces: closed below `min_face_fraction`, rounding removed, else exact.
        let mut closed = 0;
        for axis in 0..3 {
            let exact = c.face_fractions(axis);
            for (f, (&e, &s)) in exact
                .iter()
                .zip(c.stabilised_face_fractions(axis))
                .enumerate()
            {
                let want = if e < params.min_face_fraction {
                    closed += usize::from(e > 0.0);
                    0.0
                } else if e > 1.0 - params.round_off_fraction {
                    1.0
                } else {
                    e
                };
                assert_eq!(s, want, "axis {axis} face {f}: exact {e}");
            }
        }
        assert!(
            closed > 0,
            "no face below min_face_fraction: the rule is not exercised"
        );
        let [nx, ny, nz] = cells.dims;
        let (mut merged, mut unmerged) = (0, 0);
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    let n = cells.index(i, j, k);
                    let small = v[n] > params.round_off_fraction && v[n] < theta;
                    // The neighbours, their shared faces.
                    let mut best: Option<(f64, usize)> = None;
                    let nb = [
                        (i > 0).then(|| (n - 1, c.face_fractions(0)[i + (nx + 1) * (j + ny * k)])),
                        (i + 1 < nx)
                            .then(|| (n + 1, c.face_fractions(0)[i + 1 + (nx + 1) * (j + ny * k)])),
                        (j > 0).then(|| (n - nx, c.face_fractions(1)[i + nx * (j + (ny + 1) * k)])),
                        (j + 1 < ny).then(|| {
                            (n + nx, c.face_fractions(1)[i + nx * (j + 1 + (ny + 1) * k)])
                        }),
                        (k > 0).then(|| (n - nx * ny, c.face_fractions(2)[i + nx * (j + ny * k)])),
                        (k + 1 < nz).then(|| {
                            (
                                n + nx * ny,
                                c.face_fractions(2)[i + nx * (j + ny * (k + 1))],
                            )
                        }),
                    ];
                    for (m, a) in nb.into_iter().flatten() {
                        if v[m] >= theta
                            && a > params.round_off_fraction
                            && best.is_none_or(|b| a > b.0)
                        {
                            best = Some((a, m));
                        }
                    }
                    let t = c.merge_targets()[n];
                    match (small, best) {
                        (true, Some((_, m))) => {
                            assert_eq!(t, m as u32, "cell {i},{j},{k}");
                            merged += 1;
                        }
                        (true, None) => {
                            assert_eq!(t, u32::MAX);
                            unmerged += 1;
                        }
                        (false, _) => assert_eq!(t, u32::MAX),
                    }
                    // Stabilised: own (unless merged) plus the merged neighbours.
                    let into: f64 = nb
                        .iter()
                        .flatten()
                        .filter(|(m, _)| c.merge_targets()[*m] == n as u32)
                        .map(|(m, _)| v[*m])
                        .sum();
                    let own = if t == u32::MAX && v[n] > params.round_off_fraction {
                        v[n]
                    } else {
                        0.0
                    };
                    assert!((c.stabilised_volume_fractions()[n] - own - into).abs() < 1e-15);
                    if t == u32::MAX && v[n] >= theta {
                        assert!(c.stabilised_volume_fractions()[n] >= theta);
                    }
                }
            }
        }
        eprintln!("theta {theta}: {merged} merged, {unmerged} unmerged small cells, {} approximate (cut twice); volume {exact} = {stabilised}", stats.approximate_cells);
        assert_eq!(
            (stats.merged_cells, stats.unmerged_small_cells),
            (merged, unmerged)
        );
        assert!(merged > 0);
        // After the rule no fluid cell is below theta unless it had no neighbour to merge into.
        let below = c
            .stabilised_volume_fractions()
            .iter()
            .filter(|&&x| x > 0.0 && x < theta)
            .count();
        assert!(below <= unmerged);
    }
}

/// Bad input: errors that say what and where, never a panic; nothing changes on an error.
#[test]
fn bad_positions_are_refused_and_change_nothing() {
    let (cells, pos, layers) = scene();
    let mut c = CutCells::new(cells, Phase::Solid, layers, SmallCellParams::default()).unwrap();
    c.full(&[&pos[0], &pos[1]]).unwrap();
    let before = c.clone();
    let mut bad = pos[1].clone();
    bad[3][1] = f32::NAN;
    let e = c.update(&[&pos[0], &bad], 0.0).unwrap_err().to_string();
    assert!(
        e.contains("sheath") && e.contains("vertex 3") && e.contains("finite"),
        "{e}"
    );
    let e = c.update(&[&pos[0]], 0.0).unwrap_err().to_string();
    assert!(e.contains("1 position sets for 2 layers"), "{e}");
    let e = c
        .update(&[&pos[0], &pos[1][1..]], 0.0)
        .unwrap_err()
        .to_string();
    assert!(e.contains("sheath") && e.contains("positions for"), "{e}");
    bad[3] = [1e9, 0.0, 0.0];
    let e = c.update(&[&pos[0], &bad], 0.0).unwrap_err().to_string();
    assert!(e.contains("cells from the box"), "{e}");
    assert_same(&c, &before);
    // Open surfaces and bad boxes.
    let open = Layer {
        name: "open".into(),
        triangles: vec![[0, 1, 2], [0, 2, 3]],
        vertex_count: 4,
        orientation: Orientation::Outward,
        inside: Phase::Fluid,
    };
    let e = CutCells::new(cells, Phase::Solid, vec![open], SmallCellParams::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("open") && e.contains("not closed"), "{e}");
    let flat = VoxelBox {
        dims: [4, 0, 4],
        ..cells
    };
    assert!(CutCells::new(flat, Phase::Solid, vec![], SmallCellParams::default()).is_err());
}
