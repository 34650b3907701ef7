use super::super::topology::NONE;
use super::super::CellLabel;
use super::*;

/// With stray closed cells beside the open cavity, the multigrid CG's update runs the
/// V-cycle's first half-sweep and the residual's maximum in its own pass and redoes them on
/// the closed cells after their means are removed: the projection equals the one whose
/// V-cycle does that half-sweep itself, bit for bit, iterations included.
#[test]
fn the_fused_update_with_closed_regions_equals_the_plain_one() {
    let solver = |plain: bool| {
        let mut grid = crate::harness::analytic_cavity::ellipsoid_cavity(0.0015, 1.0).unwrap();
        assert!(crate::harness::analytic_cavity::add_stray_blocks(&mut grid, 4).len() >= 16);
        let params = FluidParams {
            tolerance: 1e-6,
            ..FluidParams::default()
        };
        let mut s = FluidSolver::new(grid, params).unwrap();
        s.pressure.plain_update = plain;
        let mut rng = fastrand::Rng::with_seed(99);
        s.set_velocity_field(move |_, _| rng.f64() - 0.5);
        s
    };
    let (mut fused, mut plain) = (solver(false), solver(true));
    assert!(fused.pressure.regions.any_closed() && !fused.pressure.regions.all_closed());
    let (a, b) = (fused.project_now(1e-2), plain.project_now(1e-2));
    assert!(a.projection_converged, "{a:?}");
    assert_eq!(a.projection_iterations, b.projection_iterations);
    for c in 0..3 {
        let same = fused
            .face_velocities(c)
            .iter()
            .zip(plain.face_velocities(c))
            .all(|(x, y)| x.to_bits() == y.to_bits());
        assert!(same, "component {c} differs");
    }
}

/// The centred velocity computed on the open rows dilated by `advection::CENTRED_REACH` equals
/// the whole box's after any sequence of relabellings (regions that grow, shrink, split and
/// vanish; moving walls and outflow cells among them) and steps: every other cell holds zero.
#[test]
fn centred_velocity_on_the_open_rows_equals_the_whole_box() {
    let labels = [
        CellLabel::Fluid,
        CellLabel::Solid,
        CellLabel::Velocity,
        CellLabel::Outflow,
    ];
    for (seed, dims) in [[14, 11, 9], [9, 16, 12], [20, 7, 7]]
        .into_iter()
        .enumerate()
    {
        let mut rng = fastrand::Rng::with_seed(40 + seed as u64);
        let mut grid = FluidGrid::new(dims, 1e-3, [0.0; 3], [false; 3]).unwrap();
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    grid.set_label([i, j, k], CellLabel::Solid).unwrap();
                }
            }
        }
        let mut s = FluidSolver::new(grid, FluidParams::default()).unwrap();
        let mut checked = 0;
        for step in 0..80 {
            // A random box of cells to one label: fluid most often, so regions form.
            let label = match rng.u8(..6) {
                0..=2 => CellLabel::Fluid,
                3 => CellLabel::Solid,
                n => labels[n as usize - 2],
            };
            let lo = dims.map(|n| rng.usize(..n));
            let size = dims.map(|n| rng.usize(1..=n / 2));
            for k in lo[2]..(lo[2] + size[2]).min(dims[2]) {
                for j in lo[1]..(lo[1] + size[1]).min(dims[1]) {
                    for i in lo[0]..(lo[0] + size[0]).min(dims[0]) {
                        let g = s.grid_mut();
                        g.set_label([i, j, k], label).unwrap();
                        if label == CellLabel::Velocity {
                            let v = [rng.f32() - 0.5, rng.f32() - 0.5, rng.f32() - 0.5];
                            g.set_velocity([i, j, k], v).unwrap();
                        }
                    }
                }
            }
            s.step(1e-3).unwrap();
            if step % 2 == 0 {
                s.set_velocity_field(|_, _| rng.f64() - 0.5);
            }
            s.update_centred();
            let [u0, u1, u2] = &s.u;
            let mut whole = vec![crate::simd::v4::zero(); s.centred.len()];
            advection::update_centred(&s.layout, dims, [u0, u1, u2], &mut whole, None, false);
            for (n, (got, want)) in s.centred.iter().zip(&whole).enumerate() {
                assert_eq!(
                    crate::simd::v4::lanes(*got),
                    crate::simd::v4::lanes(*want),
                    "cell {n} of {dims:?}, step {step}"
                );
            }
            checked += whole
                .iter()
                .filter(|v| crate::simd::v4::lanes(**v) != [0.0; 4])
                .count();
        }
        assert!(checked > 1000, "{checked} non-zero cells compared");
    }
}

/// The outflow faces by their definition: every active face with an outflow cell on one
/// side, in face order, with +1 when the outflow cell is its upper cell.
fn outflow_faces_by_scan(s: &FluidSolver) -> Vec<(u8, u32, f32, [u32; 3])> {
    let mut out = Vec::new();
    for c in 0..3 {
        let set = &s.faces[c];
        for (&idx, &[lo, up]) in set.active.iter().zip(set.active_cells()) {
            let outflow = |cell: u32| {
                (cell != NONE && s.grid.label_at(cell as usize) == CellLabel::Outflow)
                    .then(|| s.grid.coords(cell as usize).map(|v| v as u32))
            };
            match (outflow(lo), outflow(up)) {
                (_, Some(x)) => out.push((c as u8, idx, 1.0, x)),
                (Some(x), None) => out.push((c as u8, idx, -1.0, x)),
                (None, None) => {}
            }
        }
    }
    out
}

#[test]
fn outflow_faces_found_from_the_outflow_cells_equal_a_scan_of_the_active_faces() {
    let labels = [
        CellLabel::Fluid,
        CellLabel::Fluid,
        CellLabel::Solid,
        CellLabel::Velocity,
        CellLabel::Outflow,
    ];
    let mut found = 0;
    for (seed, (dims, periodic)) in [
        ([9, 7, 6], [false; 3]),
        ([8, 6, 5], [true, false, true]),
        ([7, 1, 6], [false; 3]),
        ([7, 3, 6], [false, true, false]),
        ([7, 1, 6], [false, true, false]),
        ([7, 2, 6], [false, true, false]),
    ]
    .into_iter()
    .enumerate()
    {
        let mut rng = fastrand::Rng::with_seed(3 + seed as u64);
        let grid = FluidGrid::new(dims, 1e-3, [0.0; 3], periodic).unwrap();
        let mut s = FluidSolver::new(grid, FluidParams::default()).unwrap();
        for round in 0..12 {
            for _ in 0..rng.usize(1..40) {
                let cell = dims.map(|n| rng.usize(..n));
                let l = labels[rng.usize(..labels.len())];
                s.grid_mut().set_label(cell, l).unwrap();
            }
            s.rebuild_topology();
            let want = outflow_faces_by_scan(&s);
            assert_eq!(s.outflow_faces, want, "round {round}, {periodic:?}");
            found += want.len();
        }
    }
    assert!(found > 100, "{found} outflow faces");
}
