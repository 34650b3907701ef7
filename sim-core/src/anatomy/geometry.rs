//! Implicit geometry of the uterus in its straight reference frame (before version/flexion).
//!
//! Frame: metres, origin at the external os, +z along the uterine axis towards the fundus, +x to
//! the patient's left, +y anterior. The organ is symmetric in x and y.
//!
//! * `organ(p)`: negative inside the serosa (corpus super-ellipsoid smoothly united with the cervix
//!   capsule whose hemispherical end is the portio, apex at the external os).
//! * The cavity and cervical canal form one slit whose mid-surface lies in the plane y = 0 (or wraps
//!   protruding lesions, see `side`) inside the coronal footprint `footprint(x, z) < 0`: a rounded
//!   triangle (fundal width at the cornua, internal os width at its apex) continued by the canal
//!   down to (and through) the external os.
//! * `gap(x, z)`: the slit's antero-posterior opening at rest, zero on the footprint's rim.

use super::error::AnatomyError;
use super::lesion::Lesion;
use super::params::{AnatomyParams, MM};

/// Fraction of the resting gap kept over protruding lesions.
pub(crate) const LESION_GAP_FRACTION: f64 = 0.25;

/// Width of the zone along the footprint's rim over which the gap grows from 0 to its full value.
pub(crate) const GAP_RAMP_M: f64 = 4.0 * MM;

/// The straight-frame geometry derived from the parameters.
#[derive(Debug, Clone)]
pub(crate) struct Geometry {
    pub uterine_length_m: f64,
    pub corpus_half_width_m: f64,
    pub corpus_half_depth_m: f64,
    /// Level of the corpus' widest cross-section (just below the cornua).
    pub corpus_centre_z_m: f64,
    /// Corpus extent above and below its widest cross-section.
    pub corpus_up_m: f64,
    pub corpus_down_m: f64,
    pub corpus_taper: f64,
    pub cervix_radius_m: f64,
    pub cervix_top_z_m: f64,
    pub blend_m: f64,
    /// Fundal end of the cavity.
    pub cavity_top_z_m: f64,
    pub gap_m: f64,
    /// Rounding radius of the footprint's convex corners.
    pub rounding_m: f64,
    /// Inner polygon of the footprint (x, z); the footprint is this polygon grown by `rounding_m`.
    pub polygon: Vec<[f64; 2]>,
    /// Portio (fixed) region: outer surface below this level.
    pub portio_top_z_m: f64,
    /// Top of the cervix (histological internal os): the canal's waist, where the isthmus starts.
    pub histological_os_z_m: f64,
    /// Anatomical internal os: the isthmus ends and the cavity's lateral walls start to widen.
    pub internal_os_z_m: f64,
    /// Half-width of the isthmus (the internal os).
    pub os_half_width_m: f64,
    /// Points (x, z; right side) on the straight part of the upper lateral wall.
    pub upper_wall_points: Vec<[f64; 2]>,
    pub lesions: Vec<Lesion>,
    pub bend: Bend,
}

/// Superellipsoid exponents of the corpus (cross-section, axis): fuller than an ellipsoid, as a
/// uterus is (an 8 x 5 x 4 cm ellipsoid holds 84 ml; references.md gives 80-200 ml).
const P_XY: f64 = 3.0;
/// Widest width of the fusiform cervical canal (at mid-cervix) relative to the larger of the
/// canal width at the external os and the internal os width.
pub(crate) const CANAL_FUSIFORM: f64 = 1.3;
const P_Z: f64 = 2.4;

impl Geometry {
    /// Builds the organ without lesions (`lesions` empty; `pathology` places them:
    /// `Geometry::with_lesions`); `spacing_m` is the mesh lattice spacing, used for the resolution
    /// checks.
    pub fn without_lesions(p: &AnatomyParams, spacing_m: f64) -> Result<Self, AnatomyError> {
        let lu = p.uterine_length_mm * MM;
        let tf = p.fundal_wall_mm * MM;
        let lc = p.cavity_length_mm * MM;
        let cx = p.cervix_length_mm * MM;
        let isthmus = lu - tf - lc - cx;
        if isthmus < 0.0 {
            return Err(AnatomyError::conflict(
                &["cervix_length_mm", "cavity_length_mm", "fundal_wall_mm", "uterine_length_mm"],
                format!(
                    "cervix {} + cavity {} + fundal wall {} = {:.1} mm exceed the uterine length {} mm",
                    p.cervix_length_mm,
                    p.cavity_length_mm,
                    p.fundal_wall_mm,
                    p.cervix_length_mm + p.cavity_length_mm + p.fundal_wall_mm,
                    p.uterine_length_mm
                ),
            ));
        }
        let cervix_r = 0.5 * p.cervix_diameter_mm * MM;
        if p.cervix_diameter_mm > 0.8 * p.corpus_width_mm
            || p.cervix_diameter_mm > 0.9 * p.ap_depth_mm
        {
            return Err(AnatomyError::conflict(
                &["cervix_diameter_mm", "corpus_width_mm", "ap_depth_mm"],
                format!(
                    "a cervix of {} mm needs a corpus at least 1.25x as wide ({} mm) and 1.1x as deep ({} mm)",
                    p.cervix_diameter_mm, p.corpus_width_mm, p.ap_depth_mm
                ),
            ));
        }
        let corpus_bottom = 0.45 * cx;
        // The corpus is widest at the level of the cornua (tubal insertions).
        let corpus_centre = lu - tf - 0.1 * lc;
        let h = spacing_m;
        let min_wall = 2.0 * h;
        let wf = p.fundal_cavity_width_mm * MM;
        let wos = p.internal_os_width_mm * MM;
        let canal = p.canal_diameter_mm * MM;
        if tf < min_wall {
            return Err(AnatomyError::conflict(
                &["fundal_wall_mm", "mesh.target_tets"],
                format!(
                    "a fundal wall of {} mm is thinner than the mesh resolves (2 lattice spacings = {:.1} mm); \
                     raise mesh.target_tets",
                    p.fundal_wall_mm,
                    min_wall / MM
                ),
            ));
        }
        if wos > wf {
            return Err(AnatomyError::conflict(
                &["internal_os_width_mm", "fundal_cavity_width_mm"],
                format!(
                    "the internal os ({} mm) is wider than the fundal cavity ({} mm): the cavity must narrow towards the os",
                    p.internal_os_width_mm, p.fundal_cavity_width_mm
                ),
            ));
        }
        if canal > 2.0 * cervix_r - 2.0 * min_wall {
            return Err(AnatomyError::conflict(
                &["canal_diameter_mm", "cervix_diameter_mm"],
                format!(
                    "a canal of {} mm in a cervix of {} mm leaves a wall below 2 lattice spacings ({:.1} mm)",
                    p.canal_diameter_mm,
                    p.cervix_diameter_mm,
                    min_wall / MM
                ),
            ));
        }
        if wos > 2.0 * cervix_r - 2.0 * min_wall {
            return Err(AnatomyError::conflict(
                &["internal_os_width_mm", "cervix_diameter_mm"],
                format!(
                    "an internal os of {} mm in a cervix of {} mm leaves a wall below 2 lattice spacings ({:.1} mm)",
                    p.internal_os_width_mm,
                    p.cervix_diameter_mm,
                    min_wall / MM
                ),
            ));
        }
        let gap = p.slit_gap_mm * MM;
        let rounding = (3.0 * MM).min(0.4 * canal).min(0.4 * wos);
        let z_io = lu - tf - lc;
        let z_ft = lu - tf;
        // The lumen's coronal outline (right half, x >= 0) is piecewise straight so that every
        // landmark is a corner between straight walls (docs/anatomy.md, "Landmarks"):
        // fusiform cervical canal (external os -> widest at mid-cervix -> histological internal
        // os at the top of the cervix), isthmus of constant width up to the anatomical internal
        // os, lateral cavity wall in two straight pieces (os -> knee -> cornu, the upper piece
        // at the cornual angle to the fundal line), fundal line. Convex corners are rounded by
        // `rounding` (the footprint is an inner polygon grown by it); concave ones stay sharp.
        let canal_mid = 0.5 * CANAL_FUSIFORM * canal.max(wos);
        if 2.0 * canal_mid > 2.0 * cervix_r - 2.0 * min_wall {
            return Err(AnatomyError::conflict(
                &["canal_diameter_mm", "internal_os_width_mm", "cervix_diameter_mm"],
                format!(
                    "the fusiform canal ({:.1} mm at its widest = {CANAL_FUSIFORM} x max(canal {} mm, os {} mm)) \
                     in a cervix of {} mm leaves a wall below 2 lattice spacings ({:.1} mm)",
                    2.0 * canal_mid / MM,
                    p.canal_diameter_mm,
                    p.internal_os_width_mm,
                    p.cervix_diameter_mm,
                    min_wall / MM
                ),
            ));
        }
        let m1 = 1.0 / p.cornual_angle_deg.to_radians().tan();
        // Upper lateral wall: tangent to the cornu's rounding circle, whose extreme x is half the
        // fundal width.
        let q5 = [0.5 * wf - rounding, z_ft - rounding];
        let c_d = q5[0] - m1 * q5[1] + rounding * (1.0 + m1 * m1).sqrt();
        let cornu = [m1 * z_ft + c_d, z_ft];
        let lower_room = cornu[0] - 0.5 * wos;
        let upper_len = if m1 > 0.0 {
            (0.4 * lc).min(0.75 * lower_room / m1)
        } else {
            0.4 * lc
        };
        if lower_room <= 0.0 || upper_len < 0.25 * lc {
            let smallest = (lc / (3.0 * lower_room.max(1e-9))).atan().to_degrees();
            return Err(AnatomyError::conflict(
                &[
                    "cornual_angle_deg",
                    "cavity_length_mm",
                    "fundal_cavity_width_mm",
                    "internal_os_width_mm",
                ],
                format!(
                    "a cornual angle of {} deg cannot join a fundal width of {} mm to an os of {} mm over {} mm \
                     with a lateral wall that widens all the way (smallest possible: {:.1} deg)",
                    p.cornual_angle_deg,
                    p.fundal_cavity_width_mm,
                    p.internal_os_width_mm,
                    p.cavity_length_mm,
                    smallest
                ),
            ));
        }
        let knee = [m1 * (z_ft - upper_len) + c_d, z_ft - upper_len];
        let canal_slope = (canal_mid - 0.5 * canal) / (0.5 * cx);
        let below = 4.0 * MM;
        let mut right: Vec<[f64; 2]> = vec![
            [0.5 * canal - canal_slope * below, -below],
            [canal_mid, 0.5 * cx],
            [0.5 * wos, cx],
        ];
        if z_io - cx > 1e-6 {
            right.push([0.5 * wos, z_io]);
        }
        right.push(knee);
        right.push(cornu);
        let mut outline = right.clone();
        for q in right.iter().rev() {
            outline.push([-q[0], q[1]]);
        }
        let polygon = inset_polygon(&outline, rounding);
        // Three points on the straight part of the upper lateral wall (between the roundings of
        // the knee, if convex, and of the cornu): rim vertices are put there so the cornual
        // angle is measurable even where that part is short against the lattice spacing.
        let slope_c = (knee[0] - 0.5 * wos) / (knee[1] - z_io);
        let turn_knee = slope_c.atan() - m1.atan();
        let t_knee = if turn_knee > 0.0 {
            rounding * (0.5 * turn_knee).tan()
        } else {
            0.0
        };
        let t_cornu = rounding / (0.5 * p.cornual_angle_deg.to_radians()).tan();
        let u = [m1 / (1.0 + m1 * m1).sqrt(), 1.0 / (1.0 + m1 * m1).sqrt()];
        let wall_len = ((cornu[0] - knee[0]).powi(2) + (cornu[1] - knee[1]).powi(2)).sqrt();
        let straight = wall_len - t_knee - t_cornu;
        let upper_wall_points: Vec<[f64; 2]> = [0.2, 0.5, 0.8]
            .iter()
            .map(|f| {
                let d = t_knee + f * straight.max(0.0);
                [knee[0] + d * u[0], knee[1] + d * u[1]]
            })
            .collect();
        let bend = Bend::new(p, cx, z_io, cervix_r);
        let os_half_width_m = 0.5 * wos;
        let g = Geometry {
            uterine_length_m: lu,
            corpus_half_width_m: 0.5 * p.corpus_width_mm * MM,
            corpus_half_depth_m: 0.5 * p.ap_depth_mm * MM,
            corpus_centre_z_m: corpus_centre,
            corpus_up_m: lu - corpus_centre,
            corpus_down_m: corpus_centre - corpus_bottom,
            corpus_taper: 0.3,
            cervix_radius_m: cervix_r,
            cervix_top_z_m: cx + 0.5 * (z_io - cx) + 5.0 * MM,
            blend_m: 0.5 * cervix_r,
            cavity_top_z_m: z_ft,
            gap_m: gap,
            rounding_m: rounding,
            polygon,
            portio_top_z_m: 0.5 * cx,
            histological_os_z_m: cx,
            upper_wall_points,
            internal_os_z_m: z_io,
            os_half_width_m,
            lesions: Vec::new(),
            bend,
        };
        // Lateral wall at the cornua, measured on the implicit serosa.
        let cornu_x = 0.5 * wf;
        let serosa_x = g.serosa_x_at(z_ft - rounding);
        if serosa_x - cornu_x < min_wall {
            return Err(AnatomyError::conflict(
                &["fundal_cavity_width_mm", "corpus_width_mm", "fundal_wall_mm"],
                format!(
                    "the cavity ({} mm wide) leaves a lateral wall of {:.1} mm at the cornua in a corpus {} mm wide; \
                     at least 2 lattice spacings ({:.1} mm) are needed",
                    p.fundal_cavity_width_mm,
                    (serosa_x - cornu_x) / MM,
                    p.corpus_width_mm,
                    min_wall / MM
                ),
            ));
        }
        // The slit's opening spreads over the wall: it must be small against the wall depth.
        let ap_wall = g.corpus_half_depth_m.min(cervix_r);
        if gap > 0.25 * ap_wall {
            return Err(AnatomyError::conflict(
                &["slit_gap_mm", "ap_depth_mm", "cervix_diameter_mm"],
                format!(
                    "a resting gap of {} mm is too large for an antero-posterior half-depth of {:.1} mm (at most 1/4)",
                    p.slit_gap_mm,
                    ap_wall / MM
                ),
            ));
        }
        Ok(g)
    }

    /// Signed, distance-like function of the serosa: negative inside the organ.
    pub fn organ(&self, p: [f64; 3]) -> f64 {
        let [x, y, z] = p;
        // Corpus: super-ellipsoid, tapering below its centre towards the isthmus.
        let s = ((self.corpus_centre_z_m - z) / self.corpus_down_m).clamp(0.0, 1.0);
        let taper = 1.0 - self.corpus_taper * s * s;
        let a = self.corpus_half_width_m * taper;
        let b = self.corpus_half_depth_m * taper;
        let u = (x / a).abs().powf(P_XY) + (y / b).abs().powf(P_XY);
        let dz = z - self.corpus_centre_z_m;
        let w = if dz > 0.0 {
            dz / self.corpus_up_m
        } else {
            -dz / self.corpus_down_m
        };
        let f = (u.powf(P_Z / P_XY) + w.powf(P_Z)).powf(1.0 / P_Z);
        let corpus = (f - 1.0) * self.corpus_half_depth_m.min(self.corpus_half_width_m) * taper;
        // Cervix: a capsule whose lower hemisphere is the portio, apex at the external os.
        let r = self.cervix_radius_m;
        let zc = z.clamp(r, self.cervix_top_z_m);
        let cervix = (x * x + y * y + (z - zc) * (z - zc)).sqrt() - r;
        // The blend rounds the isthmus; it fades out towards the portio so the external os stays
        // exactly at z = 0.
        let fade = ((z - self.portio_top_z_m * 0.5) / (self.portio_top_z_m * 0.5)).clamp(0.0, 1.0);
        smin(corpus, cervix, self.blend_m * fade)
    }

    /// x of the serosa at height z in the plane y = 0 (bisection).
    pub fn serosa_x_at(&self, z: f64) -> f64 {
        let (mut lo, mut hi) = (0.0, 0.2);
        if self.organ([lo, 0.0, z]) > 0.0 {
            return 0.0;
        }
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if self.organ([mid, 0.0, z]) < 0.0 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        lo
    }

    /// Signed distance in the coronal plane to the slit's footprint (negative inside).
    pub fn footprint(&self, x: f64, z: f64) -> f64 {
        polygon_sdf(&self.polygon, [x, z]) - self.rounding_m
    }

    /// Antero-posterior gap of the slit at rest at (x, z).
    pub fn gap(&self, x: f64, z: f64) -> f64 {
        let t = (-self.footprint(x, z) / GAP_RAMP_M).clamp(0.0, 1.0);
        self.gap_m * t * (2.0 - t)
    }

    /// Gap at a point of the slit: `gap(x, z)`, reduced to a quarter over and around protruding
    /// lesions, where the slit is strongly curved and opening it by the full gap would crush the
    /// elements draped over the lesion.
    pub fn gap_at(&self, p: [f64; 3]) -> f64 {
        let mut w: f64 = 0.0;
        for l in &self.lesions {
            if let Some(sdf) = l.protruding_sdf(p) {
                w = w.max((1.0 - sdf.max(0.0) / (l.fillet_m + 2.0 * MM)).clamp(0.0, 1.0));
            }
        }
        self.gap(p[0], p[2]) * (1.0 - (1.0 - LESION_GAP_FRACTION) * w)
    }

    /// Side function: positive on the anterior side of the slit's mid-surface, negative on the
    /// posterior side; its zero set is the plane y = 0 wrapped over protruding lesions.
    pub fn side(&self, p: [f64; 3]) -> f64 {
        let mut chi = p[1];
        for l in &self.lesions {
            if let Some(sdf) = l.protruding_sdf(p) {
                let k = l.fillet_m;
                if l.wall_sign < 0.0 {
                    chi = smin(chi, sdf, k);
                } else {
                    chi = -smin(-chi, sdf, k);
                }
            }
        }
        chi
    }

    /// Unit normal of the side function (towards the anterior side).
    pub fn side_gradient(&self, p: [f64; 3]) -> [f64; 3] {
        gradient(|q| self.side(q), p)
    }
}

/// Polynomial smooth minimum with blend radius `k` (exact min where |a-b| >= k).
pub(crate) fn smin(a: f64, b: f64, k: f64) -> f64 {
    if k <= 0.0 {
        return a.min(b);
    }
    let h = (k - (a - b).abs()).max(0.0) / k;
    a.min(b) - h * h * k * 0.25
}

fn gradient(f: impl Fn([f64; 3]) -> f64, p: [f64; 3]) -> [f64; 3] {
    let e = 1e-6;
    let mut g = [0.0; 3];
    for (k, gk) in g.iter_mut().enumerate() {
        let mut a = p;
        let mut b = p;
        a[k] += e;
        b[k] -= e;
        *gk = (f(a) - f(b)) / (2.0 * e);
    }
    let n = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
    if n > 0.0 {
        g.map(|c| c / n)
    } else {
        g
    }
}

/// The polygon whose outward offset by `r` is `outline` with its convex corners rounded (radius
/// `r`) and its concave corners kept sharp: every edge moved inwards by `r`, consecutive moved
/// edges intersected. `outline` is a simple polygon whose edges are long against `r`.
pub(crate) fn inset_polygon(outline: &[[f64; 2]], r: f64) -> Vec<[f64; 2]> {
    let n = outline.len();
    let area2: f64 = (0..n)
        .map(|i| {
            let (a, b) = (outline[i], outline[(i + 1) % n]);
            a[0] * b[1] - b[0] * a[1]
        })
        .sum();
    let orient = area2.signum();
    // Inward normal of edge i (from vertex i to i + 1).
    let normal = |i: usize| {
        let (a, b) = (outline[i], outline[(i + 1) % n]);
        let e = [b[0] - a[0], b[1] - a[1]];
        let l = (e[0] * e[0] + e[1] * e[1]).sqrt();
        [-orient * e[1] / l, orient * e[0] / l]
    };
    (0..n)
        .map(|i| {
            let prev = (i + n - 1) % n;
            let (n0, n1) = (normal(prev), normal(i));
            let v = outline[i];
            // Point at distance r from both lines: v + r (n0 + n1) / (1 + n0.n1).
            let c = 1.0 + n0[0] * n1[0] + n0[1] * n1[1];
            if c < 1e-9 {
                return [v[0] + r * n1[0], v[1] + r * n1[1]];
            }
            [
                v[0] + r * (n0[0] + n1[0]) / c,
                v[1] + r * (n0[1] + n1[1]) / c,
            ]
        })
        .collect()
}

/// Exact signed distance to a simple polygon (negative inside).
pub(crate) fn polygon_sdf(poly: &[[f64; 2]], p: [f64; 2]) -> f64 {
    let n = poly.len();
    let d0 = [p[0] - poly[0][0], p[1] - poly[0][1]];
    let mut d = d0[0] * d0[0] + d0[1] * d0[1];
    let mut s = 1.0;
    let mut j = n - 1;
    for i in 0..n {
        let vi = poly[i];
        let vj = poly[j];
        let e = [vj[0] - vi[0], vj[1] - vi[1]];
        let w = [p[0] - vi[0], p[1] - vi[1]];
        let ee = e[0] * e[0] + e[1] * e[1];
        let t = if ee > 0.0 {
            ((w[0] * e[0] + w[1] * e[1]) / ee).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let b = [w[0] - e[0] * t, w[1] - e[1] * t];
        d = d.min(b[0] * b[0] + b[1] * b[1]);
        let c1 = p[1] >= vi[1];
        let c2 = p[1] < vj[1];
        let c3 = e[0] * w[1] > e[1] * w[0];
        if (c1 && c2 && c3) || (!c1 && !c2 && !c3) {
            s = -s;
        }
        j = i;
    }
    s * d.sqrt()
}

/// Version and flexion: a smooth bend of the axis at the isthmus (flexion), then a rotation of the
/// whole organ about the external os (version), both about the x axis towards +y when positive.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Bend {
    /// Start of the bend zone on the axis.
    pub z0_m: f64,
    /// Length of the bend zone (arc length of the axis; lengths along the axis are preserved).
    pub length_m: f64,
    /// Flexion angle, rad.
    pub flexion_rad: f64,
    /// Version angle, rad.
    pub version_rad: f64,
}

impl Bend {
    fn new(p: &AnatomyParams, cervix_len: f64, z_io: f64, _cervix_r: f64) -> Self {
        let theta = p.flexion_deg.to_radians();
        let half_depth = 0.5 * p.ap_depth_mm * MM;
        // Radius of curvature at least 1.3x the half-depth so the inner side never folds.
        let length = (12.0 * MM).max(1.3 * half_depth * theta.abs());
        let centre = 0.5 * (cervix_len + z_io);
        Bend {
            z0_m: centre - 0.5 * length,
            length_m: length,
            flexion_rad: theta,
            version_rad: p.version_deg.to_radians(),
        }
    }

    /// Straight frame -> organ frame.
    pub fn apply(&self, p: [f64; 3]) -> [f64; 3] {
        let [x, y, z] = p;
        let th = self.flexion_rad;
        let (mut yy, mut zz) = (y, z);
        if th.abs() > 1e-12 && z > self.z0_m {
            let r = self.length_m / th;
            let s = (z - self.z0_m).min(self.length_m);
            let a = s / r;
            // Axis point and rotated normal at arc length s.
            let py = r * (1.0 - a.cos());
            let pz = self.z0_m + r * a.sin();
            yy = py + y * a.cos();
            zz = pz - y * a.sin();
            let rest = z - self.z0_m - s;
            if rest > 0.0 {
                yy += rest * a.sin();
                zz += rest * a.cos();
            }
        }
        let (c, s) = (self.version_rad.cos(), self.version_rad.sin());
        [x, yy * c + zz * s, -yy * s + zz * c]
    }

    /// Organ frame -> straight frame (exact inverse of `apply`).
    pub fn invert(&self, q: [f64; 3]) -> [f64; 3] {
        let (c, s) = (self.version_rad.cos(), self.version_rad.sin());
        let [x, yv, zv] = q;
        let (y, z) = (yv * c - zv * s, yv * s + zv * c);
        let th = self.flexion_rad;
        if th.abs() <= 1e-12 || z <= self.z0_m {
            return [x, y, z];
        }
        // Mirror a retroflexion onto an anteflexion.
        let m = th.signum();
        let (y, th) = (m * y, th.abs());
        let r = self.length_m / th;
        let (py, pz) = (r * (1.0 - th.cos()), self.z0_m + r * th.sin());
        let (ty, tz) = (th.sin(), th.cos());
        let along = (y - py) * ty + (z - pz) * tz;
        let (ys, zs) = if along >= 0.0 {
            let off = (y - py) * tz - (z - pz) * ty;
            (off, self.z0_m + self.length_m + along)
        } else {
            let a = (z - self.z0_m).atan2(r - y);
            let rho = ((z - self.z0_m).powi(2) + (r - y).powi(2)).sqrt();
            (r - rho, self.z0_m + r * a)
        };
        [x, m * ys, zs]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bend_inverts_exactly() {
        for flex in [-60.0, -10.0, 0.0, 25.0, 90.0] {
            let p = AnatomyParams {
                flexion_deg: flex,
                version_deg: 15.0,
                ..Default::default()
            };
            let b = Bend::new(&p, 0.028, 0.031, 0.014);
            for q in [
                [0.01, 0.005, 0.002],
                [-0.02, -0.015, 0.03],
                [0.0, 0.018, 0.05],
                [0.003, -0.02, 0.079],
            ] {
                let back = b.invert(b.apply(q));
                for k in 0..3 {
                    assert!(
                        (back[k] - q[k]).abs() < 1e-12,
                        "flex {flex}: {q:?} -> {back:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn polygon_sdf_of_a_square() {
        let sq = vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]];
        assert!((polygon_sdf(&sq, [0.5, 0.5]) + 0.5).abs() < 1e-12);
        assert!((polygon_sdf(&sq, [2.0, 0.5]) - 1.0).abs() < 1e-12);
        assert!((polygon_sdf(&sq, [2.0, 2.0]) - 2f64.sqrt()).abs() < 1e-12);
    }
}
