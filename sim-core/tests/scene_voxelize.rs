// Per-axis loops index several arrays at once.
#![allow(clippy::needless_range_loop)]
//! The voxelizer against analytic solids and independent tests: every cell's state is checked
//! against the solid's analytic inside test (or a generalized winding number: solid angles, no
//! ray casting) and a separating-axis triangle/box test (no clipping); the volume of the inside cells converges to the solid's at
//! first order (the conservative rule loses a band of about half a cell); incremental updates equal
//! a full voxelization after random move sequences.

use hydrometra_sim::scene::voxelize::{state, VoxelBox, Voxelizer, NO_TRIANGLE};

type Mesh = (Vec<[f32; 3]>, Vec<[u32; 3]>);

/// A closed UV sphere (unit radius) with outward normals, `n` latitude bands.
fn unit_sphere(n: usize) -> Mesh {
    let mut p = vec![[0.0f32, 0.0, 1.0]];
    for a in 1..n {
        let th = std::f64::consts::PI * a as f64 / n as f64;
        for b in 0..2 * n {
            let ph = std::f64::consts::PI * b as f64 / n as f64;
            p.push([
                (th.sin() * ph.cos()) as f32,
                (th.sin() * ph.sin()) as f32,
                th.cos() as f32,
            ]);
        }
    }
    p.push([0.0, 0.0, -1.0]);
    let ring = |a: usize, b: usize| (1 + (a - 1) * 2 * n + b % (2 * n)) as u32;
    let mut t = Vec::new();
    for b in 0..2 * n {
        t.push([0, ring(1, b), ring(1, b + 1)]);
    }
    for a in 1..n - 1 {
        for b in 0..2 * n {
            t.push([ring(a, b), ring(a + 1, b), ring(a + 1, b + 1)]);
            t.push([ring(a, b), ring(a + 1, b + 1), ring(a, b + 1)]);
        }
    }
    let last = (p.len() - 1) as u32;
    for b in 0..2 * n {
        t.push([last, ring(n - 1, b + 1), ring(n - 1, b)]);
    }
    (p, t)
}

/// A unit cube [-1, 1]^3 split into 2 x 2 triangles per face... with `m` x `m` quads per face.
fn cube(m: usize) -> Mesh {
    let mut p: Vec<[f32; 3]> = Vec::new();
    let mut t = Vec::new();
    // Each face: origin corner o, axes u, v (u x v outward).
    let faces: [([f32; 3], [f32; 3], [f32; 3]); 6] = [
        ([1.0, -1.0, -1.0], [0.0, 2.0, 0.0], [0.0, 0.0, 2.0]),
        ([-1.0, -1.0, -1.0], [0.0, 0.0, 2.0], [0.0, 2.0, 0.0]),
        ([-1.0, 1.0, -1.0], [0.0, 0.0, 2.0], [2.0, 0.0, 0.0]),
        ([-1.0, -1.0, -1.0], [2.0, 0.0, 0.0], [0.0, 0.0, 2.0]),
        ([-1.0, -1.0, 1.0], [2.0, 0.0, 0.0], [0.0, 2.0, 0.0]),
        ([-1.0, -1.0, -1.0], [0.0, 2.0, 0.0], [2.0, 0.0, 0.0]),
    ];
    // Vertices are welded by position so the surface is watertight.
    let mut key = std::collections::HashMap::new();
    let mut vid = |q: [f32; 3], p: &mut Vec<[f32; 3]>| -> u32 {
        let k = q.map(|c| (c * 1e4).round() as i64);
        *key.entry(k).or_insert_with(|| {
            p.push(q);
            (p.len() - 1) as u32
        })
    };
    for (o, u, v) in faces {
        for a in 0..m {
            for b in 0..m {
                let at = |a: usize, b: usize| -> [f32; 3] {
                    let (s, r) = (a as f32 / m as f32, b as f32 / m as f32);
                    std::array::from_fn(|c| o[c] + s * u[c] + r * v[c])
                };
                let q00 = vid(at(a, b), &mut p);
                let q10 = vid(at(a + 1, b), &mut p);
                let q11 = vid(at(a + 1, b + 1), &mut p);
                let q01 = vid(at(a, b + 1), &mut p);
                t.push([q00, q10, q11]);
                t.push([q00, q11, q01]);
            }
        }
    }
    (p, t)
}

/// The inverse of [`transform`]'s map, for the analytic inside tests.
fn untransform(x: [f64; 3], scale: [f64; 3], rot_z: f64, rot_x: f64, c: [f64; 3]) -> [f64; 3] {
    let (sz, cz, sx, cx) = (rot_z.sin(), rot_z.cos(), rot_x.sin(), rot_x.cos());
    let q = [x[0] - c[0], x[1] - c[1], x[2] - c[2]];
    let z = [q[0], cx * q[1] + sx * q[2], -sx * q[1] + cx * q[2]];
    let s = [cz * z[0] + sz * z[1], -sz * z[0] + cz * z[1], z[2]];
    std::array::from_fn(|a| s[a] / scale[a])
}

/// Applies `x -> R S x + c` (S: per-axis scale, R: rotation about z then x).
fn transform(mesh: &Mesh, scale: [f64; 3], rot_z: f64, rot_x: f64, c: [f64; 3]) -> Mesh {
    let (sz, cz, sx, cx) = (rot_z.sin(), rot_z.cos(), rot_x.sin(), rot_x.cos());
    let p = mesh
        .0
        .iter()
        .map(|q| {
            let s: [f64; 3] = std::array::from_fn(|a| q[a] as f64 * scale[a]);
            let z = [cz * s[0] - sz * s[1], sz * s[0] + cz * s[1], s[2]];
            let x = [z[0], cx * z[1] - sx * z[2], sx * z[1] + cx * z[2]];
            [
                (x[0] + c[0]) as f32,
                (x[1] + c[1]) as f32,
                (x[2] + c[2]) as f32,
            ]
        })
        .collect();
    (p, mesh.1.clone())
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

/// Generalized winding number (Van Oosterom-Strackee solid angles / 4 pi).
fn winding(mesh: &Mesh, x: [f64; 3]) -> f64 {
    let mut w = 0.0;
    for t in &mesh.1 {
        let [a, b, c] = t.map(|i| sub(mesh.0[i as usize].map(f64::from), x));
        let (la, lb, lc) = (norm(a), norm(b), norm(c));
        let num = dot(a, cross(b, c));
        let den = la * lb * lc + dot(a, b) * lc + dot(b, c) * la + dot(c, a) * lb;
        w += 2.0 * num.atan2(den);
    }
    w / (4.0 * std::f64::consts::PI)
}

/// Akenine-Moller separating-axis test of triangle `v` against the box `c +- e`.
fn tri_box(v: [[f64; 3]; 3], c: [f64; 3], e: f64) -> bool {
    let v = v.map(|p| sub(p, c));
    let f = [sub(v[1], v[0]), sub(v[2], v[1]), sub(v[0], v[2])];
    let axes_box = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let sep = |ax: [f64; 3]| {
        if norm(ax) < 1e-300 {
            return false;
        }
        let p = v.map(|q| dot(q, ax));
        let r = e * (ax[0].abs() + ax[1].abs() + ax[2].abs());
        p.iter().cloned().fold(f64::INFINITY, f64::min) > r
            || p.iter().cloned().fold(f64::NEG_INFINITY, f64::max) < -r
    };
    for a in axes_box {
        if sep(a) {
            return false;
        }
    }
    if sep(cross(f[0], f[1])) {
        return false;
    }
    for a in axes_box {
        for fe in f {
            if sep(cross(a, fe)) {
                return false;
            }
        }
    }
    true
}

/// Checks every cell against the independent tests; returns the inside cells' volume.
fn check_all_cells(
    mesh: &Mesh,
    cells: VoxelBox,
    v: &Voxelizer,
    inside: &dyn Fn([f64; 3]) -> bool,
) -> f64 {
    let h = cells.spacing_m;
    let [nx, ny, nz] = cells.dims;
    // Cells touched by a triangle by SAT: `strict` on a box shrunk by a hair (must be band),
    // `loose` on one widened by more than the voxelizer's own widening (may be band).
    let n_cells = cells.cell_count();
    let mut strict = vec![false; n_cells];
    let mut loose = vec![false; n_cells];
    let mut min_strict = vec![NO_TRIANGLE; n_cells];
    let mut loose_owners: Vec<Vec<u32>> = vec![Vec::new(); n_cells];
    for (ti, t) in mesh.1.iter().enumerate() {
        let tv = t.map(|i| mesh.0[i as usize].map(f64::from));
        let lo: [usize; 3] = std::array::from_fn(|a| {
            let m = tv.iter().map(|p| p[a]).fold(f64::INFINITY, f64::min);
            (((m - cells.origin_m[a]) / h).floor() - 1.0).max(0.0) as usize
        });
        let hi: [usize; 3] = std::array::from_fn(|a| {
            let m = tv.iter().map(|p| p[a]).fold(f64::NEG_INFINITY, f64::max);
            (((m - cells.origin_m[a]) / h).floor() + 1.0).min(cells.dims[a] as f64 - 1.0) as usize
        });
        for k in lo[2]..=hi[2] {
            for j in lo[1]..=hi[1] {
                for i in lo[0]..=hi[0] {
                    let n = cells.index(i, j, k);
                    let c = cells.centre_m(i, j, k);
                    if tri_box(tv, c, 0.5 * h * (1.0 + 1e-4)) {
                        loose[n] = true;
                        loose_owners[n].push(ti as u32);
                        if tri_box(tv, c, 0.5 * h * (1.0 - 1e-7)) {
                            strict[n] = true;
                            min_strict[n] = min_strict[n].min(ti as u32);
                        }
                    }
                }
            }
        }
    }
    let mut volume = 0.0;
    let mut checked_inside = 0;
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let n = cells.index(i, j, k);
                let s = v.states()[n];
                let c = cells.centre_m(i, j, k);
                if strict[n] {
                    assert_eq!(s, state::BAND, "cell {i},{j},{k} is touched by a triangle");
                }
                if s == state::BAND {
                    assert!(
                        loose[n],
                        "cell {i},{j},{k} is band but no triangle is near it"
                    );
                    let o = v.owners()[n];
                    assert!(
                        loose_owners[n].contains(&o) && o <= min_strict[n],
                        "owner of {i},{j},{k}"
                    );
                    continue;
                }
                if inside(c) {
                    assert_eq!(
                        s,
                        state::INSIDE,
                        "cell {i},{j},{k}: centre inside, untouched"
                    );
                    checked_inside += 1;
                    volume += h * h * h;
                } else {
                    assert_eq!(
                        s,
                        state::OUTSIDE,
                        "cell {i},{j},{k}: centre outside, untouched"
                    );
                }
            }
        }
    }
    assert!(checked_inside > 0);
    volume
}

fn box_around(mesh: &Mesh, h: f64, margin_cells: usize) -> VoxelBox {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in &mesh.0 {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a] as f64);
            hi[a] = hi[a].max(p[a] as f64);
        }
    }
    // An irrational offset: no vertex sits on a cell boundary by construction.
    let dims = std::array::from_fn(|a| ((hi[a] - lo[a]) / h).ceil() as usize + 2 * margin_cells);
    VoxelBox {
        dims,
        origin_m: std::array::from_fn(|a| lo[a] - (margin_cells as f64 - 0.3177) * h),
        spacing_m: h,
    }
}

/// The inside volume against the polyhedron's own volume at h, h/2, h/4: every cell checked,
/// error decreasing at first order.
fn convergence(mesh: &Mesh, h0: f64, what: &str, inside: &dyn Fn([f64; 3]) -> bool) {
    let exact = {
        let mut six_v = 0.0;
        for t in &mesh.1 {
            let [a, b, c] = t.map(|i| mesh.0[i as usize].map(f64::from));
            six_v += dot(a, cross(b, c));
        }
        six_v / 6.0
    };
    let mut errors = Vec::new();
    for level in 0..3 {
        let h = h0 / f64::from(1 << level);
        let cells = box_around(mesh, h, 2);
        let mut v = Voxelizer::new(cells, mesh.1.clone(), mesh.0.len());
        v.full(&mesh.0);
        let vol = check_all_cells(mesh, cells, &v, inside);
        assert!(
            vol < exact,
            "{what}: conservative volume {vol} >= exact {exact}"
        );
        errors.push((exact - vol) / exact);
    }
    let o1 = (errors[0] / errors[1]).log2();
    let o2 = (errors[1] / errors[2]).log2();
    eprintln!("{what}: relative volume errors {errors:?}, orders {o1:.2} {o2:.2}");
    assert!(
        errors[2] < errors[1] && errors[1] < errors[0],
        "{what}: {errors:?}"
    );
    assert!((0.7..1.4).contains(&o2), "{what}: order {o2}");
}

#[test]
fn sphere_every_cell_checked_and_first_order_volume() {
    let (k, rz, rx, c) = ([0.02; 3], 0.3, 0.2, [0.01, -0.02, 0.035]);
    let s = transform(&unit_sphere(32), k, rz, rx, c);
    // The polygon lies within 0.1 mm (its sagitta) of the sphere, less than half a cell from any
    // untouched centre: the analytic test decides those centres as the polyhedron does.
    let inside = |x: [f64; 3]| norm(untransform(x, k, rz, rx, c)) < 1.0;
    convergence(&s, 4e-3, "sphere r=20 mm", &inside);
}

#[test]
fn ellipsoid_every_cell_checked_and_first_order_volume() {
    let (k, rz, rx, c) = ([0.022, 0.014, 0.007], 0.4, -0.6, [0.0, 0.0, 0.05]);
    let s = transform(&unit_sphere(32), k, rz, rx, c);
    let inside = |x: [f64; 3]| norm(untransform(x, k, rz, rx, c)) < 1.0;
    convergence(&s, 2e-3, "ellipsoid 22x14x7 mm rotated", &inside);
}

#[test]
fn rotated_box_every_cell_checked_and_first_order_volume() {
    let (k, rz, rx, c) = ([0.012, 0.008, 0.005], 0.5, 0.35, [0.003, 0.001, 0.02]);
    let s = transform(&cube(3), k, rz, rx, c);
    let inside = |x: [f64; 3]| untransform(x, k, rz, rx, c).iter().all(|v| v.abs() < 1.0);
    convergence(&s, 1.6e-3, "box 24x16x10 mm rotated", &inside);
}

/// Slivers and zero-area triangles: a box whose faces are cut into needles and degenerate
/// triangles is voxelized the same as its clean version, and every cell passes the checks.
#[test]
fn slivers_and_degenerate_triangles_change_nothing() {
    let clean = transform(&cube(1), [0.01, 0.01, 0.01], 0.2, 0.1, [0.0; 3]);
    let mut dirty = clean.clone();
    // Split every triangle at a point a hair from its first edge's midpoint (needles), and add
    // zero-area triangles along every edge (a repeated vertex).
    let mut tris = Vec::new();
    for t in &clean.1 {
        let [a, b, c] = t.map(|i| clean.0[i as usize]);
        let m: [f32; 3] = std::array::from_fn(|k| 0.5 * (a[k] + b[k]) + 1e-7 * (c[k] - a[k]));
        dirty.0.push(m);
        let mi = (dirty.0.len() - 1) as u32;
        tris.push([t[0], mi, t[2]]);
        tris.push([mi, t[1], t[2]]);
        tris.push([t[0], t[1], t[1]]);
    }
    dirty.1 = tris;
    let cells = box_around(&clean, 1.3e-3, 2);
    let mut a = Voxelizer::new(cells, clean.1.clone(), clean.0.len());
    a.full(&clean.0);
    let mut b = Voxelizer::new(cells, dirty.1.clone(), dirty.0.len());
    b.full(&dirty.0);
    // Here the independent test is the generalized winding number of the dirty mesh itself.
    let inside = |x: [f64; 3]| {
        let w = winding(&dirty, x).abs();
        assert!(
            (w - w.round()).abs() < 1e-6,
            "winding {w} at an untouched centre"
        );
        w > 0.5
    };
    check_all_cells(&dirty, cells, &b, &inside);
    let inside = |v: &Voxelizer| v.states().iter().filter(|&&s| s == state::INSIDE).count();
    // The needles' vertex sits 1e-7 off the clean surface: the same cells are inside.
    assert_eq!(inside(&a), inside(&b));
}

/// Random move sequences: after each, the incremental result equals a full voxelization of the
/// positions the voxelizer holds, with and without a lead.
#[test]
fn incremental_equals_full_after_random_moves() {
    incremental_equals_full(0.0);
}

#[test]
fn incremental_with_a_lead_equals_full_after_random_moves() {
    incremental_equals_full(0.9e-4);
}

fn incremental_equals_full(lead_m: f64) {
    let base = transform(&unit_sphere(20), [0.015, 0.011, 0.008], 0.3, 0.5, [0.0; 3]);
    let cells = box_around(&base, 1.0e-3, 6);
    let mut rng = 0x2545_f491_4f6c_dd1du64;
    let mut rand = move || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        (rng >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut pos = base.0.clone();
    let mut inc = Voxelizer::new(cells, base.1.clone(), pos.len());
    inc.update(&pos, 1e-4);
    for step in 0..60 {
        match step % 3 {
            // A few vertices jump (some less than the threshold).
            0 => {
                for _ in 0..20 {
                    let v = (rand() * pos.len() as f64) as usize % pos.len();
                    let s = if rand() < 0.3 { 5e-5 } else { 2e-3 };
                    for a in 0..3 {
                        pos[v][a] += (s * (rand() - 0.5)) as f32;
                    }
                }
            }
            // Everything inflates or deflates a little (as under pressure).
            1 => {
                let f = 1.0 + 0.04 * (rand() - 0.5);
                for p in pos.iter_mut() {
                    *p = p.map(|c| (c as f64 * f) as f32);
                }
            }
            // A rigid shift.
            _ => {
                let d: [f64; 3] = std::array::from_fn(|_| 1.5e-3 * (rand() - 0.5));
                for p in pos.iter_mut() {
                    for a in 0..3 {
                        p[a] += d[a] as f32;
                    }
                }
            }
        }
        inc.update_leading(&pos, 1e-4, lead_m);
        // Every held position lies within the threshold of its vertex (plus f32 rounding).
        for (p, q) in pos.iter().zip(inc.voxel_positions_m()) {
            let d = (0..3).map(|a| (p[a] - q[a]).powi(2)).sum::<f32>().sqrt();
            assert!(
                d <= 1e-4 + 1e-8,
                "held {d} m from its vertex after step {step}"
            );
        }
        let mut full = Voxelizer::new(cells, base.1.clone(), pos.len());
        full.full(inc.voxel_positions_m());
        assert!(
            inc.states() == full.states(),
            "states differ after step {step}"
        );
        assert!(
            inc.owners() == full.owners(),
            "owners differ after step {step}"
        );
    }
}

/// Vertices that move less than the threshold are not re-voxelized (the skip rule), and a NaN
/// vertex does not poison anything but its own triangles.
#[test]
fn small_moves_are_skipped_and_nan_is_contained() {
    let s = transform(&unit_sphere(12), [0.01; 3], 0.0, 0.0, [0.0; 3]);
    let cells = box_around(&s, 1e-3, 2);
    let mut v = Voxelizer::new(cells, s.1.clone(), s.0.len());
    v.update(&s.0, 1e-4);
    let mut p = s.0.clone();
    for q in p.iter_mut() {
        q[0] += 5e-5;
    }
    let st = v.update(&p, 1e-4);
    assert_eq!(st.moved_vertices, 0);
    assert_eq!(st.rows, 0);
    p[3] = [f32::NAN; 3];
    let st = v.update(&p, 1e-4);
    assert_eq!(st.moved_vertices, 1);
    assert!(v.states().contains(&state::INSIDE));
}

/// A vertex moving steadily is held `lead` beyond itself along the move: it is followed once per
/// `threshold + lead` of travel (not once per threshold), the held position straddles it, and it
/// always stays within the threshold.
#[test]
fn a_lead_straddles_a_steady_move_and_halves_the_updates() {
    let s = transform(&unit_sphere(12), [0.01; 3], 0.0, 0.0, [0.0; 3]);
    let cells = box_around(&s, 1e-3, 4);
    let (threshold, step) = (1e-4, 1e-6f32);
    let run = |lead: f64| {
        let mut v = Voxelizer::new(cells, s.1.clone(), s.0.len());
        v.update(&s.0, threshold);
        let mut p = s.0.clone();
        let (mut updates, mut ahead, mut behind) = (0, 0, 0);
        for _ in 0..2000 {
            p[0][0] += step;
            if v.update_leading(&p, threshold, lead).moved_vertices > 0 {
                updates += 1;
            }
            let d = v.voxel_positions_m()[0][0] - p[0][0];
            assert!(d.abs() <= threshold as f32 + 1e-7, "held {d} m off");
            if d > 0.0 {
                ahead += 1;
            } else if d < 0.0 {
                behind += 1;
            }
        }
        (updates, ahead, behind)
    };
    let (plain, ahead0, _) = run(0.0);
    let (leading, ahead, behind) = run(0.9 * threshold);
    // 2 mm of travel in 1 um steps: every 100 um without a lead, every 190 um with one.
    assert!((19..=20).contains(&plain), "{plain} updates without a lead");
    assert!(
        (10..=11).contains(&leading),
        "{leading} updates with a lead"
    );
    assert_eq!(ahead0, 0, "without a lead the held position never leads");
    // With it, ahead about 90 of every 190 steps.
    let share = ahead as f64 / (ahead + behind) as f64;
    assert!(
        (0.40..0.55).contains(&share),
        "ahead in {share} of the steps"
    );
}
