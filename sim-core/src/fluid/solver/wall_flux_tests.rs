//! Walls moving inside cut cells (`FluidGrid::set_boundary_flux_m3_per_s`): a cut sphere whose
//! wall moves radially is a source of `4 pi R^2 U` whose field converges to `U R^2 / r^2`; a
//! rigid sphere translating in a closed box is compatible (no mean removed beyond rounding) and
//! pushes the fluid it sweeps back across its mid-plane; every flux zero is the projection
//! without them, bit for bit.

use super::super::{CellLabel, FluidGrid};
use super::cut_tests::cut_grid_with;
use super::*;
use crate::cutcell::shapes::{self, Tessellation};
use crate::cutcell::{CutCells, Phase};

/// The sphere's radius, its centre off the grid's planes, and its wall speed: arbitrary.
const RADIUS_M: f64 = 3.1e-3;
const CENTRE_M: [f64; 3] = [0.13e-3, -0.21e-3, 0.07e-3];
const WALL_SPEED_M_S: f64 = 0.021;

/// A box of fluid with a solid cut sphere in it, `per_radius` cells per radius, reaching
/// `half_widths` radii from the centre on every side plus one layer of boundary cells.
fn sphere_in_box(per_radius: usize, half_widths: f64) -> (FluidGrid, CutCells) {
    let h = RADIUS_M / per_radius as f64;
    let n = 2 * (half_widths * per_radius as f64).ceil() as usize + 2;
    let origin = [-(n as f64) * h / 2.0; 3];
    let sphere = shapes::sphere(CENTRE_M, RADIUS_M, Tessellation::for_spacing(h)).unwrap();
    cut_grid_with(&sphere, [n; 3], origin, h, Phase::Fluid, Phase::Solid)
}

/// Each cut cell's walls moving at `velocity(cell centre)`: their flux onto the fluid cell that
/// carries them. Returns the flux set on fluid cells.
fn set_wall_fluxes(
    grid: &mut FluidGrid,
    cut: &CutCells,
    velocity: impl Fn([f64; 3]) -> [f64; 3],
) -> f64 {
    let mut total = 0.0;
    for n in 0..grid.cell_count() {
        if cut.wall_areas()[n] == [0.0; 3] {
            continue;
        }
        let q = cut.wall_flux_m3_per_s(n, velocity(grid.cell_centre_m(grid.coords(n))));
        let carrier = cut.wall_carrier(n);
        if grid.label_at(carrier) == CellLabel::Fluid {
            grid.add_boundary_flux_m3_per_s(grid.coords(carrier), q)
                .unwrap();
            total += q;
        }
    }
    total
}

/// The net flux out of cell `c` through its six faces (spacing `h`), m^3/s.
fn net_outflow_m3_per_s(s: &FluidSolver, c: [usize; 3], h: f64) -> f64 {
    (0..6)
        .map(|f| {
            let q = s.cell_face_velocity_m_s(c, f) as f64 * h * h;
            if f % 2 == 1 {
                q
            } else {
                -q
            }
        })
        .sum()
}

fn is_boundary(c: [usize; 3], dims: [usize; 3]) -> bool {
    (0..3).any(|a| c[a] == 0 || c[a] + 1 == dims[a])
}

/// The source flow `U R^2 / r^2` along `r_hat` about the sphere's centre.
fn source(x: [f64; 3]) -> [f64; 3] {
    let d: [f64; 3] = std::array::from_fn(|a| x[a] - CENTRE_M[a]);
    let r2 = d.iter().map(|v| v * v).sum::<f64>();
    let s = WALL_SPEED_M_S * RADIUS_M * RADIUS_M / (r2 * r2.sqrt());
    d.map(|v| v * s)
}

fn radial_wall(x: [f64; 3]) -> [f64; 3] {
    let d: [f64; 3] = std::array::from_fn(|a| x[a] - CENTRE_M[a]);
    let r = d.iter().map(|v| v * v).sum::<f64>().sqrt();
    d.map(|v| WALL_SPEED_M_S * v / r)
}

/// The field starts at rest: the divergence tolerance is relative to the wall's speed.
fn params() -> FluidParams {
    FluidParams {
        tolerance: 1e-6,
        velocity_scale_m_s: WALL_SPEED_M_S,
        max_iterations: 2000,
        ..FluidParams::default()
    }
}

/// The flux out of the fluid through the faces of the cells labelled `label`, m^3/s.
fn flux_into(s: &FluidSolver, label: CellLabel) -> f64 {
    let g = s.grid();
    let h2 = g.spacing_m() * g.spacing_m();
    let mut sum = 0.0;
    for n in 0..g.cell_count() {
        if g.label_at(n) != label {
            continue;
        }
        let c = g.coords(n);
        for f in 0..6 {
            let (a, up) = (f / 2, f % 2 == 1);
            if let Some(m) = g.neighbour(c, a, if up { 1 } else { -1 }) {
                if g.label(m) == Some(CellLabel::Fluid) {
                    let q = s.cell_face_velocity_m_s(c, f) as f64
                        * s.cell_face_open_fraction(c, f) as f64
                        * h2;
                    // Along +a: into the cell through its lower face, out through its upper.
                    sum += if up { -q } else { q };
                }
            }
        }
    }
    sum
}

/// An open box (outflow cells around it): what the radially moving wall pushes in leaves
/// through the box, to the projection's tolerance (measured within 1e-12 relative), and equals
/// `4 pi R^2 U` up to the polygon's area (measured 9.7e-3, 2.3e-3, 5.8e-4 at 3, 6, 12 cells per
/// radius: second order).
#[test]
fn a_radially_moving_cut_wall_is_a_source_through_an_open_box() {
    let exact = 4.0 * std::f64::consts::PI * RADIUS_M * RADIUS_M * WALL_SPEED_M_S;
    let mut errors = Vec::new();
    for per_radius in [3usize, 6, 12] {
        let (mut grid, cut) = sphere_in_box(per_radius, 2.0);
        let dims = grid.dims();
        for n in 0..grid.cell_count() {
            let c = grid.coords(n);
            if is_boundary(c, dims) {
                grid.set_label(c, CellLabel::Outflow).unwrap();
            }
        }
        let pushed = set_wall_fluxes(&mut grid, &cut, radial_wall);
        let mut s = FluidSolver::new(grid, params()).unwrap();
        assert_eq!(s.regions().1, 0, "the region is open");
        // The same cells' fluxes, summed in another order.
        let applied = s.applied_boundary_flux_m3_per_s();
        assert!(
            (applied - pushed).abs() <= 1e-12 * pushed,
            "{applied} vs {pushed}"
        );
        let stats = s.project_now(1e-2);
        assert!(stats.projection_converged, "{stats:?}");
        let through_box = flux_into(&s, CellLabel::Outflow);
        // Each cell's divergence is within `tol U h^2` of its flux: the sum within N of those.
        let h = s.grid().spacing_m();
        let u_ref = s.max_speed_m_s().max(s.params().velocity_scale_m_s);
        let bound = s.fluid_cells() as f64 * s.params().tolerance * u_ref * h * h;
        let area = (pushed - exact).abs() / exact;
        println!(
            "{per_radius:2} cells per radius: pushed {pushed:.6e}, through the box {through_box:.6e} \
             (bound {bound:.1e}), against 4 pi R^2 U {area:.2e}"
        );
        assert!(
            (through_box - pushed).abs() <= bound,
            "{through_box} vs {pushed}"
        );
        assert!(
            (through_box - pushed).abs() <= 1e-5 * pushed,
            "{through_box} vs {pushed}"
        );
        errors.push(area);
    }
    // The polygon's area converges at second order (its vertices lie on the sphere's volume).
    assert!(errors[2] < 0.01 && errors[2] < errors[0], "{errors:?}");
}

/// Walls of the box moving at the source's velocity (closed region): the field converges to
/// `U R^2 / r^2` in the mean over the faces between whole fluid cells (measured 1.72e-3, 9.28e-4,
/// 5.03e-4 of U at 3, 6, 12 cells per radius: order 0.89, 0.88); the largest error, at faces
/// beside the cut cells, stays below 0.1 U without converging (3.8e-2, 7.2e-2, 9.3e-2): the
/// area-weighted projection is first order at the wall.
#[test]
fn the_field_of_a_radially_moving_cut_wall_converges_to_the_source_flow() {
    let mut means = Vec::new();
    for per_radius in [3usize, 6, 12] {
        let (mut grid, cut) = sphere_in_box(per_radius, 2.0);
        let (dims, h) = (grid.dims(), grid.spacing_m());
        for n in 0..grid.cell_count() {
            let c = grid.coords(n);
            if !is_boundary(c, dims) {
                continue;
            }
            grid.set_label(c, CellLabel::Velocity).unwrap();
            // Each component at the centre of the cell's face toward the inside along it.
            let v: [f32; 3] = std::array::from_fn(|a| {
                let mut x = grid.cell_centre_m(c);
                if c[a] == 0 {
                    x[a] += 0.5 * h;
                } else if c[a] + 1 == dims[a] {
                    x[a] -= 0.5 * h;
                }
                source(x)[a] as f32
            });
            grid.set_velocity(c, v).unwrap();
        }
        set_wall_fluxes(&mut grid, &cut, radial_wall);
        let mut s = FluidSolver::new(grid, params()).unwrap();
        let stats = s.project_now(1e-2);
        assert!(stats.projection_converged, "{stats:?}");
        let g = s.grid();
        let (mut sum, mut count, mut max) = (0.0, 0usize, 0.0f64);
        for n in 0..g.cell_count() {
            let c = g.coords(n);
            if g.label_at(n) != CellLabel::Fluid || g.volume_fraction(n) < 1.0 {
                continue;
            }
            for a in 0..3 {
                let Some(m) = g.neighbour(c, a, 1) else {
                    continue;
                };
                let m_idx = g.index(m);
                if g.label_at(m_idx) != CellLabel::Fluid || g.volume_fraction(m_idx) < 1.0 {
                    continue;
                }
                let mut x = g.cell_centre_m(c);
                x[a] += 0.5 * h;
                let e = (s.cell_face_velocity_m_s(c, 2 * a + 1) as f64 - source(x)[a]).abs()
                    / WALL_SPEED_M_S;
                sum += e;
                count += 1;
                max = max.max(e);
            }
        }
        let mean = sum / count as f64;
        println!(
            "{per_radius:2} cells per radius: mean error {mean:.3e}, largest {max:.3e} (of U), \
             mean removed {:.2e} m^3/s",
            stats.closed_region_flux_m3_per_s
        );
        assert!(max < 0.15, "{per_radius}: largest error {max} of U");
        means.push(mean);
    }
    for w in means.windows(2) {
        let order = (w[0] / w[1]).log2();
        assert!(order >= 0.8, "order {order}: {means:?}");
    }
}

/// A rigid sphere translating in a closed box: its walls' fluxes sum to zero, so nothing is
/// removed beyond rounding, and the fluid it sweeps crosses its mid-plane backwards at `V` times
/// its cross-section (the fluid on one side gains what the sphere's part there loses).
#[test]
fn a_translating_cut_sphere_in_a_closed_box_stays_compatible() {
    let v = [0.017, -0.004, 0.009];
    let (mut grid, cut) = sphere_in_box(6, 2.0);
    let pushed = set_wall_fluxes(&mut grid, &cut, |_| v);
    let gross: f64 = grid
        .boundary_fluxes_m3_per_s()
        .iter()
        .map(|q| q.abs())
        .sum();
    let mut s = FluidSolver::new(grid, params()).unwrap();
    assert_eq!(s.regions(), (1, 1), "one closed region");
    let stats = s.project_now(1e-2);
    assert!(stats.projection_converged, "{stats:?}");
    println!(
        "net {pushed:.2e} of {gross:.2e} m^3/s; removed {:.2e}",
        stats.closed_region_flux_m3_per_s
    );
    assert!(pushed.abs() <= 1e-12 * gross, "{pushed} of {gross}");
    assert!(
        stats.closed_region_flux_m3_per_s <= 1e-12 * gross,
        "{stats:?}"
    );
    // Flux along +x through the grid plane nearest the centre, over its fluid faces.
    let g = s.grid();
    let (dims, h) = (g.dims(), g.spacing_m());
    let i = ((CENTRE_M[0] - g.origin_m()[0]) / h).round() as usize;
    let plane_x = g.origin_m()[0] + i as f64 * h;
    let mut flux = 0.0;
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            let c = [i, j, k];
            flux += s.cell_face_velocity_m_s(c, 0) as f64
                * s.cell_face_open_fraction(c, 0) as f64
                * h
                * h;
        }
    }
    let chord2 = RADIUS_M * RADIUS_M - (plane_x - CENTRE_M[0]).powi(2);
    let swept = -v[0] * std::f64::consts::PI * chord2;
    println!("through the plane {flux:.5e}, swept back {swept:.5e}");
    assert!(
        (flux - swept).abs() <= 0.02 * swept.abs(),
        "{flux} vs {swept}"
    );
}

/// All-zero boundary fluxes (set, then cleared) give the projection without them bit for bit,
/// with and without cut cells.
#[test]
fn zero_boundary_fluxes_are_the_projection_without_them() {
    for cut in [false, true] {
        let build = |with_zeros: bool| {
            let (mut grid, _) = sphere_in_box(4, 2.0);
            if !cut {
                grid.clear_cut_fractions();
            }
            grid.fill_box([-1.0; 3], [1.0, 1.0, -3.5e-3], CellLabel::Outflow, [0.0; 3]);
            if with_zeros {
                grid.set_boundary_flux_m3_per_s([3, 4, 5], 1.0).unwrap();
                grid.clear_boundary_fluxes();
                assert_eq!(grid.boundary_fluxes_m3_per_s().len(), grid.cell_count());
            }
            let mut s = FluidSolver::new(grid, params()).unwrap();
            let mut rng = fastrand::Rng::with_seed(5);
            s.set_velocity_field(move |_, _| rng.f64() - 0.5);
            let stats = s.project_now(1e-2);
            (s, stats)
        };
        let ((a, sa), (b, sb)) = (build(false), build(true));
        assert_eq!(sa.projection_iterations, sb.projection_iterations);
        for c in 0..3 {
            let same = a.u[c]
                .iter()
                .zip(&b.u[c])
                .all(|(x, y)| x.to_bits() == y.to_bits());
            assert!(same, "cut {cut}: component {c} differs");
        }
    }
    // Bad input is refused, naming the cell.
    let (mut grid, _) = sphere_in_box(3, 2.0);
    let e = grid
        .set_boundary_flux_m3_per_s([1, 2, 3], f64::NAN)
        .unwrap_err()
        .to_string();
    assert!(e.contains("[1, 2, 3]"), "{e}");
    assert!(grid.set_boundary_flux_m3_per_s([99, 0, 0], 1.0).is_err());
}

/// Two closed regions whose boundary fluxes do not balance (a wall plane splits a box): the one
/// with weighted cells (`FluidGrid::set_boundary_flux_weight_m2`) balances by itself, its
/// mismatch taken from its weighted cells in proportion to their weights (each cell's net flux
/// out of its faces is its flux less that share); the one without weights has its mismatch
/// removed as a uniform mean, as before.
#[test]
fn a_closed_region_with_weights_takes_its_mismatch_from_its_weighted_cells() {
    use crate::fluid::CutFractions;
    let (dims, h) = ([12, 6, 5], 1e-3);
    let mut grid = FluidGrid::new(dims, h, [0.0; 3], [false; 3]).unwrap();
    for n in 0..grid.cell_count() {
        let c = grid.coords(n);
        if is_boundary(c, dims) || c[0] == 6 {
            grid.set_label(c, CellLabel::Solid).unwrap();
        }
    }
    grid.set_cut_fractions(CutFractions::whole(dims, [false; 3]))
        .unwrap();
    // Region A (x 1..=5): unbalanced fluxes in, weights on two columns (1 and 3 per cell);
    // region B (x 7..=10): unbalanced, no weights.
    let q_cell = 2e-9;
    let (mut net_a, mut net_b, mut weights_a) = (0.0, 0.0, 0.0);
    for n in 0..grid.cell_count() {
        let c = grid.coords(n);
        if grid.label_at(n) != CellLabel::Fluid {
            continue;
        }
        // Arbitrary, unbalanced: more in at low y, out at high z.
        let q = q_cell * (1.0 + c[1] as f64 - 0.7 * c[2] as f64);
        grid.set_boundary_flux_m3_per_s(c, q).unwrap();
        if c[0] < 6 {
            net_a += q;
            let w = match c[0] {
                1 => 1e-6,
                4 => 3e-6,
                _ => 0.0,
            };
            grid.set_boundary_flux_weight_m2(c, w).unwrap();
            weights_a += w;
        } else {
            net_b += q;
        }
    }
    assert!(net_a.abs() > 10.0 * q_cell && net_b.abs() > 10.0 * q_cell);
    let mut s = FluidSolver::new(
        grid,
        FluidParams {
            velocity_scale_m_s: q_cell / (h * h),
            ..params()
        },
    )
    .unwrap();
    let stats = s.project_now(1e-2);
    assert!(stats.projection_converged, "{stats:?}");
    assert_eq!(s.regions(), (2, 2));
    println!(
        "A {net_a:.3e}, B {net_b:.3e} m^3/s: shifted {:.3e}, removed {:.3e}",
        stats.boundary_flux_shift_m3_per_s, stats.closed_region_flux_m3_per_s
    );
    let tol = 1e-9 * (net_a.abs() + net_b.abs());
    assert!(
        (stats.boundary_flux_shift_m3_per_s + net_a).abs() <= tol,
        "{stats:?}"
    );
    assert!(
        (stats.closed_region_flux_m3_per_s - net_b.abs()).abs() <= tol,
        "{stats:?}"
    );
    let set: f64 = s.grid().boundary_fluxes_m3_per_s().iter().sum();
    assert!((s.applied_boundary_flux_m3_per_s() - (set - net_a)).abs() <= tol);
    // Each cell of A: out through its faces = its flux less its weight's share of A's net.
    let g = s.grid();
    let mut worst = 0.0f64;
    for n in 0..g.cell_count() {
        let c = g.coords(n);
        if g.label_at(n) != CellLabel::Fluid || c[0] > 5 {
            continue;
        }
        let out = net_outflow_m3_per_s(&s, c, h);
        let w = g.boundary_flux_weights_m2()[n];
        let want = g.boundary_fluxes_m3_per_s()[n] - net_a * w / weights_a;
        worst = worst.max((out - want).abs() / q_cell);
    }
    println!("largest cell error in A: {worst:.2e} of a cell's flux");
    assert!(worst < 1e-4, "{worst}");
}

/// A shared flux (`FluidGrid::set_shared_flux_m3_per_s`, an os's losses) over two regions split by
/// a wall plane: region A has weighted walls, region B none. B closed (a pocket) gets no share:
/// all of it goes to A's share cells by weight, A's walls balance A, nothing is removed. B open
/// (its mismatch leaves through the open cell) carries its share by weight. With share weights
/// only in the pocket, the pocket takes it all (and its mismatch is removed).
#[test]
fn a_shared_flux_goes_only_to_the_regions_that_can_carry_it() {
    use crate::fluid::CutFractions;
    let (dims, h) = ([13, 6, 5], 1e-3);
    let q_cell = 2e-9;
    // Arbitrary: the shared flux out of the fluid, A's and B's share weights per cell.
    let shared = -7.3 * q_cell;
    let (share_a, share_b) = (2e-6, 5e-7);
    for (b_open, a_shares) in [(false, true), (true, true), (false, false)] {
        let at = format!("B open {b_open}, A shares {a_shares}");
        let mut grid = FluidGrid::new(dims, h, [0.0; 3], [false; 3]).unwrap();
        for n in 0..grid.cell_count() {
            let c = grid.coords(n);
            if is_boundary(c, dims) || c[0] == 6 {
                grid.set_label(c, CellLabel::Solid).unwrap();
            }
        }
        if b_open {
            grid.set_label([9, 3, 0], CellLabel::Outflow).unwrap();
        }
        grid.set_cut_fractions(CutFractions::whole(dims, [false; 3]))
            .unwrap();
        grid.set_shared_flux_m3_per_s(shared).unwrap();
        let (mut net_a, mut walls_a, mut s_a, mut s_b) = (0.0, 0.0, 0.0, 0.0);
        for n in 0..grid.cell_count() {
            let c = grid.coords(n);
            if grid.label_at(n) != CellLabel::Fluid {
                continue;
            }
            if c[0] < 6 {
                // A: unbalanced boundary fluxes, walls on column 1, share cells on column 4.
                let q = q_cell * (1.0 + c[1] as f64 - 0.7 * c[2] as f64);
                grid.set_boundary_flux_m3_per_s(c, q).unwrap();
                net_a += q;
                if c[0] == 1 {
                    grid.set_boundary_flux_weight_m2(c, 1e-6).unwrap();
                    walls_a += 1e-6;
                }
                if c[0] == 4 && a_shares {
                    grid.set_shared_flux_weight_m2(c, share_a).unwrap();
                    s_a += share_a;
                }
            } else if c[0] == 10 {
                grid.set_shared_flux_weight_m2(c, share_b).unwrap();
                s_b += share_b;
            }
        }
        // What A's share cells get per m^2 of weight.
        let per_a = match (b_open, a_shares) {
            (false, true) => shared / s_a,
            (true, true) => shared / (s_a + s_b),
            _ => 0.0,
        };
        let mut s = FluidSolver::new(
            grid,
            FluidParams {
                velocity_scale_m_s: q_cell / (h * h),
                ..params()
            },
        )
        .unwrap();
        let stats = s.project_now(1e-2);
        assert!(stats.projection_converged, "{at}: {stats:?}");
        assert_eq!(s.regions(), (2, if b_open { 1 } else { 2 }), "{at}");
        let tol = 1e-9 * (net_a.abs() + shared.abs());
        assert!(
            (stats.shared_flux_m3_per_s - shared).abs() <= tol,
            "{at}: {stats:?}"
        );
        let into_a = net_a + per_a * s_a;
        assert!(
            (stats.boundary_flux_shift_m3_per_s + into_a).abs() <= tol,
            "{at}: {stats:?}"
        );
        // Removed: only the pocket's share when it takes it all.
        let removed = if a_shares { 0.0 } else { shared.abs() };
        assert!(
            (stats.closed_region_flux_m3_per_s - removed).abs() <= tol,
            "{at}: {stats:?}"
        );
        let set: f64 = s.grid().boundary_fluxes_m3_per_s().iter().sum();
        let applied = s.applied_boundary_flux_m3_per_s();
        assert!((applied - (set + shared - into_a)).abs() <= tol, "{at}");
        // Each cell of A, and of the closed pocket when it gets nothing: out through its faces =
        // its flux and share less its wall weight's part of A's net.
        let g = s.grid();
        let mut worst = 0.0f64;
        for n in 0..g.cell_count() {
            let c = g.coords(n);
            let pocket = c[0] > 6 && !b_open && a_shares;
            if g.label_at(n) != CellLabel::Fluid || !(c[0] < 6 || pocket) {
                continue;
            }
            let out = net_outflow_m3_per_s(&s, c, h);
            let want = if c[0] < 6 {
                let (q, w) = (
                    g.boundary_fluxes_m3_per_s()[n],
                    g.boundary_flux_weights_m2()[n],
                );
                q + per_a * g.shared_flux_weights_m2()[n] - into_a * w / walls_a
            } else {
                0.0
            };
            worst = worst.max((out - want).abs() / q_cell);
        }
        println!("{at}: largest cell error {worst:.2e} of a cell's flux");
        assert!(worst < 1e-4, "{at}: {worst}");
    }
    // Bad input is refused, naming the cell.
    let mut grid = FluidGrid::new(dims, h, [0.0; 3], [false; 3]).unwrap();
    assert!(grid.set_shared_flux_m3_per_s(f64::INFINITY).is_err());
    let e = grid.set_shared_flux_weight_m2([1, 2, 3], -1.0).unwrap_err();
    assert!(e.to_string().contains("[1, 2, 3]"), "{e}");
    assert!(grid.set_shared_flux_weight_m2([99, 0, 0], 1.0).is_err());
}
