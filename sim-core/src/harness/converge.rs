//! The scene's accuracy against a fine reference (`hydrometra scene converge`, docs/scene.md
//! "Accuracy table"): what a trainee sees, sampled at the same physical points and instants at
//! every voxel size, and the observed order of its error.
//!
//! Each metric is a function of the solver's state and the scene's geometry at one instant; the
//! command takes them every frame of a stated window, and these functions know nothing of sizes.

use crate::fluid::{CellLabel, FluidSolver};
use crate::mesh::{cross, dot};

/// Distances ahead of the scope tip, along its view direction, of the jet's probes, mm.
pub const JET_PROBE_MM: [f64; 3] = [5.0, 10.0, 20.0];

/// The fundal third starts at this share of the cavity's extent along the organ's z axis (the
/// cervix at low z, the fundus at high z).
pub const FUNDAL_FROM: f64 = 2.0 / 3.0;

/// The points `tip + d dir` for each `d` (m), `dir` normalized; `None` when `dir` has no
/// direction (zero or not finite).
pub fn probe_points_m(
    tip_m: [f64; 3],
    dir: [f64; 3],
    distances_m: &[f64],
) -> Option<Vec<[f64; 3]>> {
    let n = (dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]).sqrt();
    if !(n.is_finite() && n > 0.0) {
        return None;
    }
    let u = dir.map(|x| x / n);
    Some(
        distances_m
            .iter()
            .map(|&d| std::array::from_fn(|a| tip_m[a] + d * u[a]))
            .collect(),
    )
}

/// The speed (m/s) at `point_m` by the solver's own trilinear interpolation of its face
/// velocities (the particles' and probes' sampler).
pub fn speed_at_m_s(solver: &FluidSolver, point_m: [f64; 3]) -> f64 {
    let v = solver.sample_velocity_m_s(point_m);
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

/// Half-angle of the cone around the view direction in which the jet's peak is sought: a jet's
/// axis bends with the cavity's cross-flow (the outflow's pull, the walls), and a fixed point on
/// the view line then reads the jet's flank, more so the finer the grid keeps the jet narrow. The
/// search disk at distance `d` has the radius `r_channel + d tan(JET_CONE_HALF_ANGLE_DEG)`.
pub const JET_CONE_HALF_ANGLE_DEG: f64 = 15.0;

/// Sample spacing of the search disk, m: a sixth of the finest size the accuracy table is run at
/// (0.3 mm), so the trilinear field's peak (at most a face's spacing from a sample) is caught.
pub const JET_SEARCH_SPACING_M: f64 = 5e-5;

/// The radius (m) of the jet's search disk `distance_m` ahead of the tip for a channel of
/// `channel_area_m2`: `sqrt(A / pi) + d tan(`[`JET_CONE_HALF_ANGLE_DEG`]`)`.
pub fn jet_search_radius_m(channel_area_m2: f64, distance_m: f64) -> f64 {
    (channel_area_m2 / std::f64::consts::PI).sqrt()
        + distance_m * JET_CONE_HALF_ANGLE_DEG.to_radians().tan()
}

/// The jet's speed at a cross-section: the largest `|u|` (m/s) on the disk of `radius_m` centred on
/// `centre_m` and normal to `dir`, sampled on a square lattice of `spacing_m` in the disk's plane
/// by the solver's trilinear interpolation (the centreline of a jet is where its speed peaks, not
/// the line the scope points along). `None` when `dir` has no direction or the spacing or radius
/// is not positive.
pub fn peak_speed_on_disk_m_s(
    solver: &FluidSolver,
    centre_m: [f64; 3],
    dir: [f64; 3],
    radius_m: f64,
    spacing_m: f64,
) -> Option<f64> {
    let n = dot(dir, dir).sqrt();
    if !(n.is_finite() && n > 0.0 && radius_m > 0.0 && spacing_m > 0.0) {
        return None;
    }
    let d = dir.map(|x| x / n);
    // Two unit vectors spanning the plane normal to `d`: `a` from the axis least along `d`.
    let least = (0..3)
        .min_by(|&i, &j| d[i].abs().total_cmp(&d[j].abs()))
        .unwrap_or(0);
    let mut e = [0.0; 3];
    e[least] = 1.0;
    let a = cross(d, e);
    let a = a.map(|x| x / dot(a, a).sqrt());
    let b = cross(d, a);
    let steps = (radius_m / spacing_m).floor() as i64;
    let mut peak = speed_at_m_s(solver, centre_m);
    for i in -steps..=steps {
        for j in -steps..=steps {
            let (s, t) = (i as f64 * spacing_m, j as f64 * spacing_m);
            if s * s + t * t > radius_m * radius_m {
                continue;
            }
            let p = std::array::from_fn(|k| centre_m[k] + s * a[k] + t * b[k]);
            peak = peak.max(speed_at_m_s(solver, p));
        }
    }
    Some(peak)
}

/// Whether `point_m` lies in a fluid cell of the solver's grid.
pub fn in_fluid(solver: &FluidSolver, point_m: [f64; 3]) -> bool {
    let g = solver.grid();
    let (o, h) = (g.origin_m(), g.spacing_m());
    let mut cell = [0usize; 3];
    for a in 0..3 {
        let s = (point_m[a] - o[a]) / h;
        if !(s >= 0.0 && s < g.dims()[a] as f64) {
            return false;
        }
        cell[a] = s as usize;
    }
    g.label(cell) == Some(CellLabel::Fluid)
}

/// The height (m) from which the cavity's top `1 - from` share along z begins:
/// `z_min + from (z_max - z_min)` over the surface's vertices; `None` without vertices.
pub fn band_start_z_m(positions_m: &[[f32; 3]], from: f64) -> Option<f64> {
    let (lo, hi) = positions_m
        .iter()
        .map(|p| f64::from(p[2]))
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), z| {
            (lo.min(z), hi.max(z))
        });
    (lo <= hi).then_some(lo + from * (hi - lo))
}

/// The volume-weighted mean speed (m/s) of the fluid cells whose centre lies at or above
/// `z_from_m`: `sum V_i |u_i| / sum V_i`, `u_i` the cell-centred velocity (the mean of its two
/// faces per axis), `V_i` the cell's fluid volume fraction (1 without cut cells). `None` when no
/// fluid cell is there.
pub fn mean_speed_above_m_s(solver: &FluidSolver, z_from_m: f64) -> Option<f64> {
    let g = solver.grid();
    let [nx, ny, nz] = g.dims();
    let (o, h) = (g.origin_m(), g.spacing_m());
    let k0 = ((z_from_m - o[2]) / h - 0.5).ceil().max(0.0);
    if !k0.is_finite() {
        return None;
    }
    let (mut sum_v, mut sum_vu) = (0.0f64, 0.0f64);
    for k in (k0 as usize)..nz {
        for j in 0..ny {
            for i in 0..nx {
                let n = g.index([i, j, k]);
                if g.label_at(n) != CellLabel::Fluid {
                    continue;
                }
                let w = f64::from(g.volume_fraction(n));
                let u = solver.centred_velocity_m_s([i, j, k]);
                let s = u.iter().map(|&x| f64::from(x).powi(2)).sum::<f64>().sqrt();
                sum_v += w;
                sum_vu += w * s;
            }
        }
    }
    (sum_v > 0.0).then(|| sum_vu / sum_v)
}

/// The mean of the samples `(t, value)` with `t` in `[from_s, to_s]`; `None` without one.
pub fn window_mean(samples: &[(f64, f64)], from_s: f64, to_s: f64) -> Option<f64> {
    let (n, sum) = samples
        .iter()
        .filter(|(t, v)| *t >= from_s && *t <= to_s && v.is_finite())
        .fold((0usize, 0.0), |(n, s), (_, v)| (n + 1, s + v));
    (n > 0).then(|| sum / n as f64)
}

/// The observed order between successive sizes: `ln(e_i / e_{i+1}) / ln(h_i / h_{i+1})`, `None`
/// where an error is zero, missing or not finite (or two sizes are equal).
pub fn successive_orders(h: &[f64], errors: &[Option<f64>]) -> Vec<Option<f64>> {
    h.windows(2)
        .zip(errors.windows(2))
        .map(|(h, e)| match (e[0], e[1]) {
            (Some(a), Some(b)) if a > 0.0 && b > 0.0 && h[0] != h[1] => {
                let p = (a / b).ln() / (h[0] / h[1]).ln();
                p.is_finite().then_some(p)
            }
            _ => None,
        })
        .collect()
}

/// The order `p` of the least-squares fit `ln e = ln c + p ln h` over the sizes with a positive
/// finite error; `None` with fewer than two such sizes (or all at one size).
pub fn fitted_order(h: &[f64], errors: &[Option<f64>]) -> Option<f64> {
    let pts: Vec<(f64, f64)> = h
        .iter()
        .zip(errors)
        .filter_map(|(&h, e)| match e {
            Some(e) if *e > 0.0 && e.is_finite() && h > 0.0 => Some((h.ln(), e.ln())),
            _ => None,
        })
        .collect();
    if pts.len() < 2 {
        return None;
    }
    let n = pts.len() as f64;
    let (mx, my) = pts
        .iter()
        .fold((0.0, 0.0), |(x, y), p| (x + p.0 / n, y + p.1 / n));
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    (sxx > 0.0).then(|| sxy / sxx)
}

/// `|a / reference - 1|`; `None` when either is missing or the reference is zero.
pub fn relative_error(a: Option<f64>, reference: Option<f64>) -> Option<f64> {
    match (a, reference) {
        (Some(a), Some(r)) if r != 0.0 && a.is_finite() && r.is_finite() => {
            Some((a / r - 1.0).abs())
        }
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fluid::{FluidGrid, FluidParams};

    /// A solver on a box of `n^3` fluid cells of `h` at `origin`, its faces set by `field`
    /// (component, face position) -> m/s.
    fn solver_with(
        n: usize,
        h: f64,
        origin: [f64; 3],
        periodic: [bool; 3],
        field: impl Fn(usize, [f64; 3]) -> f64,
    ) -> FluidSolver {
        let grid = FluidGrid::new([n; 3], h, origin, periodic).unwrap();
        let mut s = FluidSolver::new(grid, FluidParams::default()).unwrap();
        s.set_velocity_field(field);
        s
    }

    /// Trilinear sampling reproduces a linear field exactly: the probes along a tilted view
    /// direction read `|u(tip + d dir)|` of `u = (0.1 + 2 x, -0.3 + 5 z, 0.2 - 3 y)`, to f32's
    /// precision, at every probe distance and whatever the grid's origin and spacing.
    #[test]
    fn probes_read_a_linear_field_exactly_along_the_view_direction() {
        let u = |p: [f64; 3]| [0.1 + 2.0 * p[0], -0.3 + 5.0 * p[2], 0.2 - 3.0 * p[1]];
        for (n, h, origin) in [
            (40, 1e-3, [-0.02, -0.02, 0.0]),
            (23, 1.7e-3, [-0.01, 0.0, 0.003]),
        ] {
            let s = solver_with(n, h, origin, [false; 3], |c, p| u(p)[c]);
            let tip = [
                origin[0] + 0.3 * n as f64 * h,
                origin[1] + 0.4 * n as f64 * h,
                origin[2] + 2.5e-3,
            ];
            let dir = [0.2, 0.3, 2.0];
            let d_m = JET_PROBE_MM.map(|d| d * 1e-3);
            let pts = probe_points_m(tip, dir, &d_m).unwrap();
            let norm = (0.04f64 + 0.09 + 4.0).sqrt();
            for (p, d) in pts.iter().zip(d_m) {
                for a in 0..3 {
                    assert!((p[a] - (tip[a] + d * dir[a] / norm)).abs() < 1e-15);
                }
                let v = u(*p);
                let exact = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                let got = speed_at_m_s(&s, *p);
                assert!(
                    (got - exact).abs() < 1e-5 * exact.max(1.0),
                    "{got} vs {exact} at {p:?}"
                );
                assert!(in_fluid(&s, *p));
            }
        }
        assert!(probe_points_m([0.0; 3], [0.0; 3], &[1.0]).is_none());
        assert!(probe_points_m([0.0; 3], [f64::NAN, 0.0, 1.0], &[1.0]).is_none());
    }

    /// A Gaussian jet `U exp(-r^2 / w^2)` along a tilted direction, its axis offset from the
    /// probe's line by less than the search radius: the disk's peak is `U` within the lattice's
    /// and the trilinear interpolation's error, while the point on the line reads the flank; with
    /// the axis outside the disk the peak is the flank's speed at the disk's rim.
    #[test]
    fn the_disk_finds_a_jet_whose_axis_is_off_the_view_line() {
        let (n, h) = (48usize, 2.5e-4);
        let big_u = 0.4;
        let w = 1.2e-3;
        let dir = [0.2f64, -0.3, 1.0];
        let nd = (dir.iter().map(|x| x * x).sum::<f64>()).sqrt();
        let d = dir.map(|x| x / nd);
        let tip = [6e-3, 6e-3, 1e-3];
        let dist = 5e-3;
        let centre: [f64; 3] = std::array::from_fn(|k| tip[k] + dist * d[k]);
        for offset_m in [0.0, 0.8e-3, 1.5e-3] {
            // The jet's axis: through `centre + offset e_x'`, along `d` (e_x' normal to d).
            let ex = [1.0, 0.0, -d[0] / d[2]];
            let ne = (ex.iter().map(|x| x * x).sum::<f64>()).sqrt();
            let ex = ex.map(|x| x / ne);
            let axis_pt: [f64; 3] = std::array::from_fn(|k| centre[k] + offset_m * ex[k]);
            let speed = move |p: [f64; 3]| {
                let r: [f64; 3] = std::array::from_fn(|k| p[k] - axis_pt[k]);
                let along = r[0] * d[0] + r[1] * d[1] + r[2] * d[2];
                let r2 = r.iter().map(|x| x * x).sum::<f64>() - along * along;
                big_u * (-r2 / (w * w)).exp()
            };
            let s = solver_with(n, h, [0.0; 3], [false; 3], |c, p| speed(p) * d[c]);
            let radius = 1.2e-3;
            let peak =
                peak_speed_on_disk_m_s(&s, centre, dir, radius, JET_SEARCH_SPACING_M).unwrap();
            let on_line = speed_at_m_s(&s, centre);
            if offset_m < radius {
                // Trilinear interpolation of a Gaussian of width 4.8 cells: about 1 % at its peak.
                assert!(
                    (peak / big_u - 1.0).abs() < 0.02,
                    "offset {offset_m}: {peak}"
                );
                if offset_m > 0.0 {
                    assert!(
                        on_line < 0.9 * peak,
                        "offset {offset_m}: {on_line} vs {peak}"
                    );
                }
            } else {
                // The nearest lattice point to the axis lies between the rim and a lattice
                // diagonal inside it.
                let flank = |r: f64| big_u * (-(r / w).powi(2)).exp();
                let (near, far) = (
                    offset_m - radius,
                    offset_m - radius + 1.5 * JET_SEARCH_SPACING_M,
                );
                assert!(
                    peak < 1.02 * flank(near) && peak > 0.98 * flank(far),
                    "offset {offset_m}: {peak} vs {} .. {}",
                    flank(far),
                    flank(near)
                );
            }
        }
        let s = solver_with(8, h, [0.0; 3], [false; 3], |_, _| 0.0);
        assert!(peak_speed_on_disk_m_s(&s, [1e-3; 3], [0.0; 3], 1e-3, 1e-4).is_none());
        assert!(peak_speed_on_disk_m_s(&s, [1e-3; 3], [0.0, 0.0, 1.0], 0.0, 1e-4).is_none());
        let r = jet_search_radius_m(2.8e-6, 1e-2);
        assert!((r - ((2.8e-6 / std::f64::consts::PI).sqrt() + 1e-2 * 0.267_949)).abs() < 1e-8);
    }

    /// The fundal band's mean speed in a shear flow `u_x = a z`: the cells whose centres lie at
    /// or above the band's start, each weighing its volume, give the mean of `a z_k` over those
    /// layers; and with a rigid flow the mean is that speed whatever the band.
    #[test]
    fn the_band_mean_is_the_volume_mean_of_the_cells_above_it() {
        let (n, h, a) = (12usize, 2e-3, 50.0);
        // x and y periodic: no wall face along the flow zeroes it.
        let periodic = [true, true, false];
        let s = solver_with(n, h, [0.0; 3], periodic, |c, p| {
            if c == 0 {
                a * p[2]
            } else {
                0.0
            }
        });
        let positions: Vec<[f32; 3]> = vec![[0.0, 0.0, 0.0], [0.0, 0.0, (n as f64 * h) as f32]];
        let z0 = band_start_z_m(&positions, FUNDAL_FROM).unwrap();
        assert!((z0 - FUNDAL_FROM * n as f64 * h).abs() < 1e-9);
        let layers: Vec<f64> = (0..n)
            .map(|k| (k as f64 + 0.5) * h)
            .filter(|&z| z >= z0)
            .collect();
        let exact = layers.iter().map(|z| a * z).sum::<f64>() / layers.len() as f64;
        let got = mean_speed_above_m_s(&s, z0).unwrap();
        assert!((got / exact - 1.0).abs() < 1e-6, "{got} vs {exact}");
        // Above the box: no fluid.
        assert!(mean_speed_above_m_s(&s, 1.0).is_none());
        let rigid = solver_with(n, h, [0.0; 3], periodic, |c, _| [0.3, -0.4, 0.0][c]);
        for from in [0.0, 0.5, 0.9] {
            let z = band_start_z_m(&positions, from).unwrap();
            assert!((mean_speed_above_m_s(&rigid, z).unwrap() - 0.5).abs() < 1e-6);
        }
        assert!(band_start_z_m(&[], 0.5).is_none());
    }

    /// Errors `c h^p` give back `p`, from successive pairs and from the fit, for any `c` and
    /// sizes not in a constant ratio; a noisy set gives a fit between its pairs; zero or missing
    /// errors give no order.
    #[test]
    fn orders_of_synthetic_errors_c_h_to_the_p() {
        let h = [1.8, 1.2, 0.9, 0.6];
        for (c, p) in [(0.3, 1.0), (7.0, 2.0), (0.01, 1.37)] {
            let e: Vec<Option<f64>> = h.iter().map(|&h: &f64| Some(c * h.powf(p))).collect();
            for o in successive_orders(&h, &e) {
                assert!((o.unwrap() - p).abs() < 1e-12);
            }
            assert!((fitted_order(&h, &e).unwrap() - p).abs() < 1e-12);
        }
        let noisy = [Some(1.0), Some(0.5), Some(0.4), Some(0.2)];
        let o: Vec<f64> = successive_orders(&h, &noisy)
            .into_iter()
            .flatten()
            .collect();
        let fit = fitted_order(&h, &noisy).unwrap();
        let (lo, hi) = o
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, u), &x| {
                (l.min(x), u.max(x))
            });
        assert!(fit > lo && fit < hi, "{fit} in {o:?}");
        let gaps = [Some(1.0), None, Some(0.0), Some(0.1)];
        assert_eq!(successive_orders(&h, &gaps), vec![None, None, None]);
        assert!(fitted_order(&h, &gaps).is_some()); // 1.8 and 0.6 remain
        assert!(fitted_order(&h, &[Some(1.0), None, None, None]).is_none());
    }

    #[test]
    fn window_means_and_relative_errors() {
        let s: Vec<(f64, f64)> = (0..10).map(|i| (i as f64, i as f64)).collect();
        assert_eq!(window_mean(&s, 2.0, 4.0), Some(3.0));
        assert_eq!(window_mean(&s, 20.0, 30.0), None);
        assert_eq!(
            relative_error(Some(1.1), Some(1.0)).map(|e| (e * 1e6).round()),
            Some(1e5)
        );
        assert_eq!(relative_error(Some(1.0), Some(0.0)), None);
        assert_eq!(relative_error(None, Some(1.0)), None);
    }
}
