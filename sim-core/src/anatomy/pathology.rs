//! Myomas and polyps: placement from the FIGO type (or the type from the placement), their shape in
//! the implicit geometry and their material region.

use super::error::AnatomyError;
use super::geometry::{Geometry, LESION_GAP_FRACTION};
use super::lesion::{Lesion, LesionKind};
use super::params::{AnatomyParams, PolypKind, MM};

/// Fraction of an ellipsoid's volume beyond a plane at normalised distance `t` (= depth / semi-axis)
/// from its centre: the cap of height 1 - t of the unit sphere.
pub(crate) fn protruding_fraction(t: f64) -> f64 {
    let eta = (1.0 - t).clamp(0.0, 2.0);
    eta * eta * (3.0 - eta) / 4.0
}

/// FIGO type of a myoma whose centre lies `depth` below the endometrium (semi-axis `ry` across
/// the wall), in the geometry as requested (before meshing).
pub(crate) fn figo_from_depth(depth: f64, ry: f64) -> u8 {
    if depth <= -ry {
        0
    } else if depth < ry {
        if protruding_fraction(depth / ry) > 0.5 {
            1
        } else {
            2
        }
    } else if depth <= ry + 1.0 * MM {
        3
    } else {
        4
    }
}

/// Depth at which a myoma of semi-axis `ry` is placed for a requested FIGO type.
fn depth_for_figo(figo: u8, ry: f64, stalk_len: f64, spacing: f64) -> f64 {
    let depth_for_fraction = |f: f64| {
        // Solve protruding_fraction(t) = f by bisection (monotone decreasing in t).
        let (mut lo, mut hi) = (-1.0, 1.0);
        for _ in 0..80 {
            let mid = 0.5 * (lo + hi);
            if protruding_fraction(mid) > f {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        0.5 * (lo + hi) * ry
    };
    match figo {
        0 => -(ry + stalk_len),
        1 => depth_for_fraction(0.7),
        2 => depth_for_fraction(0.3),
        3 => ry,
        _ => ry + (3.0 * MM).max(2.0 * spacing),
    }
}

impl Geometry {
    /// The organ of [`Geometry::without_lesions`] with every myoma and polyp placed in it.
    pub(crate) fn with_lesions(p: &AnatomyParams, spacing_m: f64) -> Result<Self, AnatomyError> {
        let mut g = Geometry::without_lesions(p, spacing_m)?;
        g.lesions = place_lesions(p, &g, spacing_m)?;
        Ok(g)
    }
}

/// Places every myoma and polyp and checks that it fits the anatomy and the mesh resolution.
fn place_lesions(
    p: &AnatomyParams,
    g: &Geometry,
    spacing: f64,
) -> Result<Vec<Lesion>, AnatomyError> {
    let mut out = Vec::new();
    for (i, m) in p.myomas.iter().enumerate() {
        let key = format!("myomas[{i}]");
        let r = m.diameters_mm.map(|d| 0.5 * d * MM);
        if 2.0 * r.iter().cloned().fold(f64::INFINITY, f64::min) < 3.0 * spacing {
            return Err(AnatomyError::conflict(
                &[&format!("{key}.diameters_mm"), "mesh.target_tets"],
                format!(
                    "a myoma of {:?} mm is below the mesh resolution (smallest diameter at least 3 lattice spacings = {:.1} mm); \
                     raise mesh.target_tets",
                    m.diameters_mm,
                    3.0 * spacing / MM
                ),
            ));
        }
        let Some(sign) = m.wall.sign() else {
            let lesion = place_intramural(m, i, &key, r, g, spacing)?;
            out.push(lesion);
            continue;
        };
        if m.angle_deg.is_some() {
            return Err(AnatomyError::conflict(
                &[&format!("{key}.angle_deg"), &format!("{key}.wall")],
                "angle_deg is only used with wall = \"oblique\"".to_string(),
            ));
        }
        let stalk_len = (0.4 * r[1]).max(1.5 * spacing);
        let depth = match (m.figo, m.depth_mm) {
            (Some(f), None) => depth_for_figo(f, r[1], stalk_len, spacing),
            (None, Some(d)) => d * MM,
            (Some(f), Some(d)) => {
                let derived = figo_from_depth(d * MM, r[1]);
                if derived != f {
                    return Err(AnatomyError::conflict(
                        &[&format!("{key}.figo"), &format!("{key}.depth_mm")],
                        format!(
                            "depth {d} mm with an antero-posterior diameter of {} mm gives FIGO type {derived}, not {f}",
                            m.diameters_mm[1]
                        ),
                    ));
                }
                d * MM
            }
            (None, None) => {
                return Err(AnatomyError::Parse(format!(
                    "{key}: give `figo` or `depth_mm`"
                )))
            }
        };
        let figo = figo_from_depth(depth, r[1]);
        let x0 = m.x_mm * MM;
        let z0 = g.cavity_top_z_m - m.from_fundus_mm * MM;
        let centre = [x0, sign * depth, z0];
        let protrudes = figo <= 2;
        // The fillet must be well above the half-gap the slit opens by, or the wall draped over the
        // lesion's base is crushed when the slit opens.
        let min_fillet = (3.0 * MM).max(2.0 * g.gap_m);
        let fillet = (0.3 * r[0].min(r[1]).min(r[2])).clamp(min_fillet, min_fillet.max(5.0 * MM));
        let stalk = (figo == 0).then(|| {
            let rs = (0.35 * r[0].min(r[2])).max(1.2 * spacing);
            ([x0, sign * 2.0 * MM, z0], rs)
        });
        let lesion = Lesion {
            index: i,
            kind: LesionKind::Myoma { figo },
            wall_sign: sign,
            centre_m: centre,
            semi_axes_m: r,
            stalk,
            fillet_m: fillet,
            protrudes,
            inflate_m: if protrudes {
                0.5 * LESION_GAP_FRACTION * g.gap_m
            } else {
                0.0
            },
        };
        check_fit(g, &lesion, &key, spacing, depth)?;
        out.push(lesion);
    }
    for (i, pp) in p.polyps.iter().enumerate() {
        let key = format!("polyps[{i}]");
        let rr = 0.5 * pp.diameter_mm * MM;
        let r = [rr, 0.8 * rr, rr];
        if 2.0 * r[1] < 3.0 * spacing {
            return Err(AnatomyError::conflict(
                &[&format!("{key}.diameter_mm"), "mesh.target_tets"],
                format!(
                    "a polyp of {} mm is below the mesh resolution (at least {:.1} mm at this spacing); raise mesh.target_tets",
                    pp.diameter_mm,
                    3.0 * spacing / 0.8 / MM
                ),
            ));
        }
        let Some(sign) = pp.wall.sign() else {
            return Err(AnatomyError::conflict(
                &[&format!("{key}.wall")],
                format!(
                    "polyps grow from the anterior or posterior wall (the slit's faces), not {:?}",
                    pp.wall
                ),
            ));
        };
        let x0 = pp.x_mm * MM;
        let z0 = g.cavity_top_z_m - pp.from_fundus_mm * MM;
        let (depth, stalk) = match pp.kind {
            PolypKind::Sessile => (-0.55 * r[1], None),
            PolypKind::Pedunculated => {
                let len = (0.8 * r[1]).max(1.5 * spacing);
                let rs = (0.3 * rr).max(1.0 * spacing);
                (-(r[1] + len), Some(([x0, sign * 2.0 * MM, z0], rs)))
            }
        };
        let lesion = Lesion {
            index: i,
            kind: LesionKind::Polyp(pp.kind),
            wall_sign: sign,
            centre_m: [x0, sign * depth, z0],
            semi_axes_m: r,
            stalk,
            fillet_m: {
                let min_fillet = (3.0 * MM).max(2.0 * g.gap_m);
                (0.3 * rr).clamp(min_fillet, min_fillet.max(5.0 * MM))
            },
            protrudes: true,
            inflate_m: 0.5 * LESION_GAP_FRACTION * g.gap_m,
        };
        check_fit(g, &lesion, &key, spacing, depth)?;
        out.push(lesion);
    }
    Ok(out)
}

/// Points on an ellipsoid's surface (a latitude-longitude grid).
fn ellipsoid_samples(c: [f64; 3], r: [f64; 3]) -> Vec<[f64; 3]> {
    let (nu, nv) = (48, 24);
    let mut out = Vec::with_capacity(nu * (nv + 1));
    for j in 0..=nv {
        let v = std::f64::consts::PI * j as f64 / nv as f64;
        for i in 0..nu {
            let u = 2.0 * std::f64::consts::PI * i as f64 / nu as f64;
            out.push([
                c[0] + r[0] * v.sin() * u.cos(),
                c[1] + r[1] * v.sin() * u.sin(),
                c[2] + r[2] * v.cos(),
            ]);
        }
    }
    out
}

/// A myoma on a lateral, fundal or oblique wall, FIGO type 3 (touching the endometrium) or 4
/// (intramural, at least max(3 mm, 2 spacings) from it). Its centre moves from the cavity along
/// the wall's direction until the ellipsoid leaves the slit (bisection on the distance between
/// the ellipsoid and the slit's footprint in the mid-plane, the endometrium before opening);
/// type 3 then sinks back half a spacing so that elements of the myoma line the cavity.
fn place_intramural(
    m: &super::params::MyomaParams,
    index: usize,
    key: &str,
    r: [f64; 3],
    g: &Geometry,
    spacing: f64,
) -> Result<Lesion, AnatomyError> {
    use super::params::WallSide;
    let figo = match (m.figo, m.depth_mm) {
        (Some(f @ (3 | 4)), None) => f,
        _ => {
            return Err(AnatomyError::conflict(
                &[&format!("{key}.figo"), &format!("{key}.wall")],
                format!(
                    "a myoma on the {:?} wall must be given as figo = 3 or 4 without depth_mm \
                     (types 0-2 protrude into the slit cavity, modelled for the anterior and posterior walls only)",
                    m.wall
                ),
            ))
        }
    };
    let z0 = g.cavity_top_z_m - m.from_fundus_mm * MM;
    let (start, dir) = match (m.wall, m.angle_deg) {
        (WallSide::Left, None) => ([0.0, 0.0, z0], [1.0, 0.0, 0.0]),
        (WallSide::Right, None) => ([0.0, 0.0, z0], [-1.0, 0.0, 0.0]),
        (WallSide::Fundal, None) => ([m.x_mm * MM, 0.0, g.cavity_top_z_m], [0.0, 0.0, 1.0]),
        (WallSide::Oblique, Some(a)) => {
            let a = a.to_radians();
            ([0.0, 0.0, z0], [a.sin(), a.cos(), 0.0])
        }
        (WallSide::Oblique, None) => {
            return Err(AnatomyError::Parse(format!(
                "{key}: wall = \"oblique\" needs angle_deg"
            )))
        }
        _ => {
            return Err(AnatomyError::conflict(
                &[&format!("{key}.angle_deg"), &format!("{key}.wall")],
                "angle_deg is only used with wall = \"oblique\"".to_string(),
            ))
        }
    };
    if g.footprint(start[0], start[2]) > 0.0 {
        return Err(AnatomyError::conflict(
            &[&format!("{key}.from_fundus_mm"), &format!("{key}.x_mm")],
            format!(
                "the myoma's level ({:.1} mm below the fundal line, x {:.1} mm) is outside the cavity",
                m.from_fundus_mm, m.x_mm
            ),
        ));
    }
    let centre_at = |t: f64| [0, 1, 2].map(|k| start[k] + t * dir[k]);
    // Distance from the ellipsoid to the slit's footprint (0 where they overlap).
    let gap_to_slit = |t: f64| {
        ellipsoid_samples(centre_at(t), r)
            .iter()
            .map(|p| {
                let f = g.footprint(p[0], p[2]).max(0.0);
                (p[1] * p[1] + f * f).sqrt()
            })
            .fold(f64::INFINITY, f64::min)
    };
    // A point of the ellipsoid's mid-plane section inside the footprint means overlap.
    let overlaps = |t: f64| {
        let c = centre_at(t);
        if c[1].abs() >= r[1] {
            return false;
        }
        let k = (1.0 - (c[1] / r[1]).powi(2)).sqrt();
        (0..64).any(|i| {
            let u = 2.0 * std::f64::consts::PI * i as f64 / 64.0;
            g.footprint(c[0] + k * r[0] * u.cos(), c[2] + k * r[2] * u.sin()) < 0.0
        }) || g.footprint(c[0], c[2]) < 0.0
    };
    let bisect = |pred: &dyn Fn(f64) -> bool| {
        // pred(lo) true, pred(hi) false.
        let (mut lo, mut hi) = (0.0, 0.15);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if pred(mid) {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        hi
    };
    let t_touch = bisect(&|t| overlaps(t));
    let t = if figo == 3 {
        (t_touch - 0.5 * spacing).max(0.0)
    } else {
        let clear = (3.0 * MM).max(2.0 * spacing);
        bisect(&|t| t <= t_touch || gap_to_slit(t) < clear)
    };
    let centre = centre_at(t);
    clear_of_serosa(
        g,
        ellipsoid_samples(centre, r),
        spacing,
        &[
            &format!("{key}.from_fundus_mm"),
            &format!("{key}.diameters_mm"),
            &format!("{key}.figo"),
        ],
        "myoma",
    )?;
    Ok(Lesion {
        index,
        kind: LesionKind::Myoma { figo },
        wall_sign: 0.0,
        centre_m: centre,
        semi_axes_m: r,
        stalk: None,
        fillet_m: 0.0,
        protrudes: false,
        inflate_m: 0.0,
    })
}

/// Every probe point stays 1.5 lattice spacings inside the serosa, or the parameters `keys` conflict.
fn clear_of_serosa(
    g: &Geometry,
    probes: impl IntoIterator<Item = [f64; 3]>,
    spacing: f64,
    keys: &[&str],
    what: &str,
) -> Result<(), AnatomyError> {
    match probes.into_iter().find(|&q| g.organ(q) > -1.5 * spacing) {
        None => Ok(()),
        Some(q) => Err(AnatomyError::conflict(
            keys,
            format!(
                "the {what} reaches within 1.5 lattice spacings of the serosa at ({:.1}, {:.1}, {:.1}) mm \
                 (subserosal FIGO types 5-7 are not modelled)",
                q[0] / MM,
                q[1] / MM,
                q[2] / MM
            ),
        )),
    }
}

fn check_fit(
    g: &Geometry,
    l: &Lesion,
    key: &str,
    spacing: f64,
    depth: f64,
) -> Result<(), AnatomyError> {
    let [x0, _, z0] = l.centre_m;
    let r = l.semi_axes_m;
    let s = l.wall_sign;
    // Inside the wall: every extreme point of the part in the wall stays 1.5 spacings from the serosa.
    let wall_extent = depth + r[1];
    if wall_extent > 0.0 {
        let yc = s * depth.max(0.0);
        let probes = [
            [x0, s * wall_extent, z0],
            [x0 + r[0], yc, z0],
            [x0 - r[0], yc, z0],
            [x0, yc, z0 + r[2]],
            [x0, yc, z0 - r[2]],
        ];
        clear_of_serosa(
            g,
            probes,
            spacing,
            &[
                &format!("{key}.x_mm"),
                &format!("{key}.from_fundus_mm"),
                &format!("{key}.diameters_mm"),
            ],
            "lesion",
        )?;
    }
    if l.protrudes {
        // The wrapped slit must stay inside the cavity's footprint, away from its rim: the part in
        // the cavity projects to its full outline, the base (where the wall is cut) adds the fillet.
        let base = if depth.abs() < r[1] {
            (1.0 - (depth / r[1]).powi(2)).sqrt()
        } else {
            0.0
        };
        let stalk_r = l.stalk.map_or(0.0, |s| s.1);
        let reach = |ri: f64| {
            let body = if depth < r[1] { ri } else { 0.0 };
            body.max((ri * base).max(stalk_r) + l.fillet_m) + 0.5 * spacing
        };
        let (mx, mz) = (reach(r[0]), reach(r[2]));
        let m = mx.max(mz);
        let probes = [
            [x0, z0],
            [x0 + mx, z0],
            [x0 - mx, z0],
            [x0, z0 + mz],
            [x0, z0 - mz],
        ];
        for q in probes {
            if g.footprint(q[0], q[1]) > 0.0 {
                return Err(AnatomyError::conflict(
                    &[
                        &format!("{key}.x_mm"),
                        &format!("{key}.from_fundus_mm"),
                        "fundal_cavity_width_mm",
                    ],
                    format!(
                        "a lesion protruding into the cavity must lie inside the cavity outline, with its base fillet \
                         (reach {:.1} mm from its centre); ({:.1}, {:.1}) mm is outside",
                        m / MM,
                        q[0] / MM,
                        q[1] / MM
                    ),
                ));
            }
        }
        // The opposite wall drapes over the protrusion: it must keep 2 spacings of thickness.
        let top = r[1] - depth;
        let q = [x0, -s * (top + 2.0 * spacing), z0];
        if g.organ(q) > 0.0 {
            return Err(AnatomyError::conflict(
                &[&format!("{key}.diameters_mm"), "ap_depth_mm"],
                format!(
                    "the lesion protrudes {:.1} mm into the cavity: the opposite wall would be thinner than 2 lattice spacings",
                    top / MM
                ),
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn figo_placement_round_trips() {
        let ry = 0.008;
        for f in 0..=4u8 {
            let d = depth_for_figo(f, ry, 0.003, 0.0025);
            assert_eq!(figo_from_depth(d, ry), f, "type {f} at depth {d}");
        }
    }

    #[test]
    fn protruding_fraction_of_a_hemisphere_is_one_half() {
        assert!((protruding_fraction(0.0) - 0.5).abs() < 1e-15);
        assert!((protruding_fraction(1.0)).abs() < 1e-15);
        assert!((protruding_fraction(-1.0) - 1.0).abs() < 1e-15);
    }
}
