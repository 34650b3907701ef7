// Per-axis loops index several arrays at once.
#![allow(clippy::needless_range_loop)]
//! The exact cut-cell fractions of one closed surface against analytic and independent
//! references: volumes of polyhedra at rounding, analytic solids converging at second order (and
//! exact for the volume-matched tessellation), every cell and face of convex polyhedra against
//! half-space clipping, a cylinder's faces against the circle's chords and segments, every cell's
//! faces and walls closing, grid-aligned walls, sub-cell slabs, surfaces beyond the box and
//! degenerate triangles.

mod cutcell_common;
use cutcell_common::*;
use hydrometra_sim::cutcell::shapes::{self, Tessellation};

/// Random-ish rotation and cell offset.
fn pose(rng: &mut Rng) -> ([V3; 3], V3) {
    (
        rotation(
            rng.range(0.0, 6.3),
            rng.range(0.0, 3.1),
            rng.range(0.0, 6.3),
        ),
        [rng.next(), rng.next(), rng.next()],
    )
}

fn relative(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs()
}

/// The sum of the fractions times h^3 equals the polyhedron's own volume at rounding, for
/// spheres, ellipsoids, slabs thinner than a cell and tetrahedra, in random orientations and
/// offsets, at several resolutions; and every cell closes.
#[test]
fn polyhedron_volumes_are_exact_up_to_rounding() {
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let mut worst: f64 = 0.0;
    let mut worst_div: f64 = 0.0;
    for case in 0..12 {
        let (r, shift) = pose(&mut rng);
        let c = [
            rng.range(-0.01, 0.01),
            rng.range(-0.01, 0.01),
            rng.range(0.0, 0.02),
        ];
        for cells_per_size in [3.0, 6.0, 12.0] {
            let (mesh, size) = match case % 4 {
                0 => {
                    let radius = rng.range(0.003, 0.006);
                    let h = radius / cells_per_size;
                    (
                        shapes::sphere(c, radius, Tessellation::for_spacing(h)).unwrap(),
                        radius,
                    )
                }
                1 => {
                    let s = [
                        rng.range(0.5, 1.0),
                        rng.range(0.3, 0.6),
                        rng.range(0.1, 0.3),
                    ];
                    let unit =
                        shapes::sphere([0.0; 3], 0.005, Tessellation::for_spacing(0.0005)).unwrap();
                    (transformed(&unit, s, &r, c), 0.005 * s[2])
                }
                2 => {
                    // Thickness 0.05 to 0.5 cells at the finest resolution.
                    let t = rng.range(0.05, 0.5) * 0.004 / 12.0;
                    (box_mesh([0.004, 0.003, 0.5 * t], &r, c, 2), 0.004)
                }
                _ => {
                    let p: [V3; 4] = std::array::from_fn(|_| {
                        add(
                            c,
                            [
                                rng.range(-0.004, 0.004),
                                rng.range(-0.004, 0.004),
                                rng.range(-0.004, 0.004),
                            ],
                        )
                    });
                    (tetrahedron(p), 0.004)
                }
            };
            let h = size / cells_per_size;
            let cells = box_around(&mesh, h, 1, shift);
            let f = fractions(&mesh, cells);
            let e = relative(fluid_volume(&f), mesh.volume_m3());
            worst = worst.max(e);
            worst_div = worst_div.max(max_divergence_defect(&f));
            assert!(
                e < 1e-12,
                "case {case} at {cells_per_size} cells: relative error {e:e}"
            );
        }
    }
    eprintln!("largest relative volume error {worst:e}, largest face/wall defect {worst_div:e}");
    assert!(worst_div < 1e-12);
}

/// A sphere and a rotated ellipsoid against their analytic volumes: with vertices on the solid
/// (inscribed) and edges following h, the error falls at second order; with the builder's
/// volume-matched tessellation it is at the f32 rounding of the vertices whatever h.
#[test]
fn analytic_volumes_converge_at_second_order() {
    let mut rng = Rng(0x2545_f491_4f6c_dd1d);
    for (what, axes) in [
        ("sphere", [1.0, 1.0, 1.0]),
        ("ellipsoid", [1.0, 0.62, 0.31]),
    ] {
        let radius: f64 = 0.006;
        let (r, shift) = pose(&mut rng);
        let c = [
            rng.range(-0.01, 0.01),
            rng.range(-0.01, 0.01),
            rng.range(0.0, 0.02),
        ];
        let exact = 4.0 / 3.0 * std::f64::consts::PI * radius.powi(3) * axes[0] * axes[1] * axes[2];
        let mut errors = Vec::new();
        for cells_across in [4.0, 8.0, 16.0, 32.0] {
            // The smallest semi-axis spans `cells_across` cells.
            let h = radius * axes[2] / cells_across;
            let mut e = [0.0; 2];
            for (m, match_volume) in [false, true].into_iter().enumerate() {
                let t = Tessellation {
                    max_edge_m: 0.5 * h / axes[2],
                    match_volume,
                };
                let unit = shapes::sphere([0.0; 3], radius, t).unwrap();
                let mesh = transformed(&unit, axes, &r, c);
                let f = fractions(&mesh, box_around(&mesh, h, 1, shift));
                e[m] = relative(fluid_volume(&f), exact);
            }
            eprintln!("{what}: {cells_across} cells across: inscribed error {:.3e}, volume-matched {:.3e}", e[0], e[1]);
            assert!(e[1] < 2e-6, "{what}: volume-matched error {:e}", e[1]);
            errors.push(e[0]);
        }
        let orders: Vec<f64> = errors.windows(2).map(|w| (w[0] / w[1]).log2()).collect();
        eprintln!("{what}: inscribed errors {errors:?}, observed orders {orders:.2?}");
        assert!(orders.iter().all(|&o| o > 1.8), "{what}: orders {orders:?}");
    }
}

/// Every cell's volume and every face's area of convex polyhedra (tetrahedra, bipyramids, some
/// thinner than a cell) equal the half-space clipping of the cell and face, an independent exact
/// method, within 1e-12 of a cell.
#[test]
fn convex_polyhedra_match_halfspace_clipping_in_every_cell_and_face() {
    let mut rng = Rng(0xdead_beef_cafe_f00d);
    let mut worst: f64 = 0.0;
    for case in 0..10 {
        let (r, shift) = pose(&mut rng);
        let c = [
            rng.range(-0.01, 0.01),
            rng.range(-0.01, 0.01),
            rng.range(0.0, 0.02),
        ];
        let h = 0.001;
        let mesh = if case % 2 == 0 {
            let p: [V3; 4] = std::array::from_fn(|_| {
                add(
                    c,
                    [
                        rng.range(-0.004, 0.004),
                        rng.range(-0.004, 0.004),
                        rng.range(-0.004, 0.004),
                    ],
                )
            });
            tetrahedron(p)
        } else {
            // Half the bipyramids are thinner than a cell.
            let thick = if case % 4 == 1 { 0.3 * h } else { 3.0 * h };
            bipyramid(
                5 + case,
                rng.range(0.002, 0.005),
                thick * rng.range(0.3, 1.0),
                thick * rng.range(0.3, 1.0),
                &r,
                c,
            )
        };
        let f = fractions(&mesh, box_around(&mesh, h, 1, shift));
        let conv = Convex::of_mesh(&mesh);
        worst = worst.max(max_difference_from_convex(&f, &conv));
    }
    eprintln!("largest difference from half-space clipping: {worst:e}");
    assert!(worst < 1e-12, "{worst:e}");
}

/// A cylinder along z, off-centre in its cells: each z-face's open fraction lies between those
/// of the circles inscribed in and circumscribing the polygon, i.e. within the polygon's sagitta
/// of the exact circle/square area; each x-face in the cylinder's middle equals the polygon's
/// chord through it; a plane's open area equals the polygon's area (and pi R^2, volume-matched).
#[test]
fn cylinder_faces_match_circle_chords_and_segments() {
    let mut rng = Rng(0x0123_4567_89ab_cdef);
    for radius_cells in [4.3, 7.7] {
        let h = 0.001;
        let radius = radius_cells * h;
        let c = [rng.range(0.0, h), rng.range(0.0, h), 0.0];
        let mesh = shapes::cylinder(
            c,
            [0.0, 0.0, 1.0],
            radius,
            10.0 * h,
            Tessellation::for_spacing(h),
        )
        .unwrap();
        let cells = box_around(&mesh, h, 1, [0.37, 0.61, 0.5]);
        let f = fractions(&mesh, cells);
        // The polygon: the vertices on the side (all but the two cap centres), per ring.
        let ring: Vec<[f64; 2]> = mesh
            .positions_m()
            .iter()
            .filter(|p| (p[2] as f64 - mesh.positions_m()[0][2] as f64).abs() < 1e-12)
            .map(|p| [p[0] as f64 - c[0], p[1] as f64 - c[1]])
            .filter(|q| q[0].hypot(q[1]) > 0.5 * radius)
            .collect();
        let n = ring.len() as f64;
        let edges = || (0..ring.len()).map(|e| (ring[e], ring[(e + 1) % ring.len()]));
        let r_out = ring.iter().map(|q| q[0].hypot(q[1])).fold(0.0, f64::max);
        // The distance from the centre to each edge's line.
        let r_in = edges()
            .map(|(p, q)| (p[0] * q[1] - p[1] * q[0]).abs() / (q[0] - p[0]).hypot(q[1] - p[1]))
            .fold(f64::INFINITY, f64::min);
        let polygon_area = 0.5 * edges().map(|(p, q)| p[0] * q[1] - p[1] * q[0]).sum::<f64>();
        let [nx, ny, nz] = cells.dims;
        let k = nz / 2;
        let z_plane = cells.origin_m[2] + k as f64 * h;
        assert!(z_plane > -4.0 * h && z_plane < 4.0 * h);
        let mut worst_circle: f64 = 0.0;
        let mut open = 0.0;
        for j in 0..ny {
            for i in 0..nx {
                let x0 = cells.origin_m[0] + i as f64 * h - c[0];
                let y0 = cells.origin_m[1] + j as f64 * h - c[1];
                let a = f.face_fractions(2)[i + nx * (j + ny * k)];
                open += a;
                let exact = circle_rect_area(radius, x0, x0 + h, y0, y0 + h) / (h * h);
                let lo = circle_rect_area(r_in, x0, x0 + h, y0, y0 + h) / (h * h);
                let hi = circle_rect_area(r_out, x0, x0 + h, y0, y0 + h) / (h * h);
                assert!(
                    a >= lo - 1e-12 && a <= hi + 1e-12,
                    "z-face {i},{j}: {a} outside [{lo}, {hi}]"
                );
                worst_circle = worst_circle.max((a - exact).abs());
            }
        }
        let open = open * h * h;
        eprintln!("R = {radius_cells} cells, {n} sides: largest z-face difference from the circle {worst_circle:.2e} \
                   (sagitta {:.2e} cells); plane open area against the polygon {:.1e}, against pi R^2 {:.1e}",
                  (r_out - r_in) / h, relative(open, polygon_area), relative(open, std::f64::consts::PI * radius * radius));
        assert!(relative(open, polygon_area) < 1e-12);
        assert!(relative(open, std::f64::consts::PI * radius * radius) < 1e-6);
        assert!(worst_circle <= 2.0 * std::f64::consts::PI * (r_out - r_in) / h);
        // x-faces in the middle rows: the chord of the polygon at that x within the face's y range.
        let mut worst_chord: f64 = 0.0;
        for i in 0..=nx {
            let x = cells.origin_m[0] + i as f64 * h - c[0];
            // The polygon's chord at x: where its edges cross the line.
            let mut ys = Vec::new();
            for e in 0..ring.len() {
                let (p, q) = (ring[e], ring[(e + 1) % ring.len()]);
                if (p[0] <= x) != (q[0] <= x) {
                    ys.push(p[1] + (x - p[0]) / (q[0] - p[0]) * (q[1] - p[1]));
                }
            }
            ys.sort_by(f64::total_cmp);
            for j in 0..ny {
                let y0 = cells.origin_m[1] + j as f64 * h - c[1];
                let exact = if ys.len() == 2 {
                    ((ys[1].min(y0 + h) - ys[0].max(y0)) / h).max(0.0)
                } else {
                    0.0
                };
                let a = f.face_fractions(0)[i + (nx + 1) * (j + ny * k)];
                worst_chord = worst_chord.max((a - exact).abs());
            }
        }
        eprintln!("  largest x-face difference from the polygon's chord {worst_chord:.2e}");
        assert!(worst_chord < 1e-9);
        assert!(max_divergence_defect(&f) < 1e-12);
    }
}

/// A box whose walls lie exactly on grid planes (coordinates exact in binary): its cells are
/// 0 or 1, and the faces on its walls are closed on both sides (the tie rule's exception for
/// triangles in a grid plane), with the walls in the fluid cells.
#[test]
fn grid_aligned_walls_close_their_faces() {
    let h = 1.0 / 1024.0;
    let lo = [2.0 * h, 3.0 * h, 1.0 * h];
    let hi = [5.0 * h, 7.0 * h, 4.0 * h];
    let id = rotation(0.0, 0.0, 0.0);
    let half: V3 = std::array::from_fn(|a| 0.5 * (hi[a] - lo[a]));
    let centre: V3 = std::array::from_fn(|a| 0.5 * (hi[a] + lo[a]));
    let mesh = box_mesh(half, &id, centre, 3);
    let cells = hydrometra_sim::scene::voxelize::VoxelBox {
        dims: [8, 9, 6],
        origin_m: [0.0; 3],
        spacing_m: h,
    };
    let f = fractions(&mesh, cells);
    let inside = |c: [usize; 3]| {
        (0..3).all(|a| (c[a] as f64) * h >= lo[a] && (c[a] as f64 + 1.0) * h <= hi[a])
    };
    for k in 0..6 {
        for j in 0..9 {
            for i in 0..8 {
                let v = f.volume_fractions()[cells.index(i, j, k)];
                assert_eq!(
                    v,
                    if inside([i, j, k]) { 1.0 } else { 0.0 },
                    "cell {i},{j},{k}"
                );
                let s = f.interface_areas()[cells.index(i, j, k)];
                if !inside([i, j, k]) {
                    assert_eq!(s, [0.0; 3], "wall in an empty cell {i},{j},{k}");
                }
            }
        }
    }
    for axis in 0..3 {
        let mut d = cells.dims;
        d[axis] += 1;
        for k in 0..d[2] {
            for j in 0..d[1] {
                for i in 0..d[0] {
                    let c = [i, j, k];
                    // Open only between two inside cells.
                    let mut below = c;
                    let open = c[axis] > 0 && c[axis] < cells.dims[axis] && {
                        below[axis] -= 1;
                        inside(c) && inside(below)
                    };
                    let a = f.face_fractions(axis)[i + d[0] * (j + d[1] * k)];
                    assert_eq!(a, if open { 1.0 } else { 0.0 }, "face {axis} {c:?}");
                }
            }
        }
    }
    assert_eq!(max_divergence_defect(&f), 0.0);
}

/// A surface reaching beyond the box on every side (a slab through it) and a mesh sprinkled with
/// zero-area triangles: finite fractions in [0, 1], cells that close, and the part of the volume
/// in the box exact.
#[test]
fn surfaces_beyond_the_box_and_degenerate_triangles() {
    let h = 0.001;
    let r = rotation(0.3, 0.4, 0.5);
    // A thin lens (a convex bipyramid 100 mm across) through the box.
    let slab = bipyramid(9, 0.05, 0.0013, 0.0011, &r, [0.0021, 0.0013, 0.0017]);
    let cells = hydrometra_sim::scene::voxelize::VoxelBox {
        dims: [7, 6, 5],
        origin_m: [0.0; 3],
        spacing_m: h,
    };
    let f = fractions(&slab, cells);
    let conv = Convex::of_mesh(&slab);
    assert!(max_difference_from_convex(&f, &conv) < 1e-9);
    assert!(max_divergence_defect(&f) < 1e-12);
    // Zero-area triangles: every triangle split at a point of its edge, plus needles.
    let tet = tetrahedron([
        [0.0, 0.0, 0.0],
        [0.004, 0.0005, 0.0],
        [0.001, 0.0035, 0.0003],
        [0.0012, 0.001, 0.0041],
    ]);
    let (mut pos, tris) = tet.clone().into_parts();
    let mut dirty = Vec::new();
    for t in &tris {
        let [a, b, _] = t.map(|i| pos[i as usize]);
        let m: [f32; 3] = std::array::from_fn(|k| 0.5 * (a[k] + b[k]));
        pos.push(m);
        let mi = (pos.len() - 1) as u32;
        dirty.push([t[0], mi, t[2]]);
        dirty.push([mi, t[1], t[2]]);
        // The zero-area triangle closing the split edge's T-junction.
        dirty.push([t[1], mi, t[0]]);
    }
    let dirty = hydrometra_sim::cutcell::mesh::ClosedMesh::new("dirty", pos, dirty).unwrap();
    let cells = box_around(&tet, h, 1, [0.5, 0.5, 0.5]);
    let (a, b) = (fractions(&tet, cells), fractions(&dirty, cells));
    let worst = a
        .volume_fractions()
        .iter()
        .zip(b.volume_fractions())
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max);
    assert!(worst < 1e-6, "{worst}");
    assert!(b.volume_fractions().iter().all(|v| (0.0..=1.0).contains(v)));
    assert!(max_divergence_defect(&b) < 1e-12);
}
