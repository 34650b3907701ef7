//! Measurements on a generated mesh: dimensions (in the straightened frame) and the FIGO type of
//! each myoma, measured from the meshed geometry rather than taken from its placement.

use serde::{Deserialize, Serialize};

use crate::mesh::{Region, VertexLabel};

use super::geometry::Geometry;
use super::lesion::{ellipsoid_sdf, LesionKind};
use super::params::AnatomyParams;
use super::quality::QualityStats;
use crate::mesh::TetMesh;

/// What the JSON summary holds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AnatomySummary {
    /// Number of vertices.
    pub vertices: usize,
    /// Number of tetrahedra.
    pub tets: usize,
    /// Number of cavity (endometrium) triangles.
    pub cavity_triangles: usize,
    /// Vertices in the cavity's opening loop at the external os.
    pub opening_loop_vertices: usize,
    /// Vertices per label: interior, fixed, endometrium, serosa.
    pub label_counts: [usize; 4],
    /// Tetrahedra per region: myometrium, fibroid, polyp.
    pub region_counts: [usize; 3],
    /// Lattice spacing, mm.
    pub lattice_spacing_mm: f64,
    /// Volume of the tissue (the mesh), ml.
    pub tissue_volume_ml: f64,
    /// Volume of the cavity at rest (closed over the external os), ml.
    pub cavity_volume_ml: f64,
    /// Uterine volume: tissue plus cavity, ml.
    pub uterine_volume_ml: f64,
    /// Element quality.
    pub quality: QualityStats,
    /// Dimensions measured on the mesh (straightened: version/flexion undone).
    pub dimensions: Dimensions,
    /// FIGO type of each myoma: requested, placed and measured on the mesh.
    pub myomas: Vec<MyomaReport>,
    /// Iterations of the harmonic opening solve.
    pub opening_solve_iterations: usize,
    /// The parameters used.
    pub params: AnatomyParams,
}

impl AnatomySummary {
    /// Whether every tetrahedron has positive volume.
    pub fn min_volume_positive(&self) -> bool {
        self.quality.min_volume_m3 > 0.0
    }
}

/// Dimensions measured on the mesh, mm and degrees, from the mesh alone (positions, cavity
/// triangles, the opening loop): no generator input is used. Definitions: docs/anatomy.md,
/// "Landmarks and how they are measured". Lengths along the axis are arc lengths along the
/// cavity's mid-line measured on the mesh, so they do not depend on version/flexion.
/// Landmark-based values are `None` when the landmark is not found (e.g. a lesion hides it).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Dimensions {
    /// External os to the top of the fundus (serosa), along the axis.
    pub uterine_length_mm: f64,
    /// Largest left-right extent of the organ.
    pub corpus_width_mm: f64,
    /// Largest antero-posterior extent, perpendicular to the axis.
    pub ap_depth_mm: f64,
    /// Left-right extent of the cavity surface (between the cornua).
    pub fundal_cavity_width_mm: f64,
    /// Fundal endometrium to the top of the fundus, along the axis.
    pub fundal_wall_mm: f64,
    /// External os to the fundal endometrium along the axis (the clinical sounding length =
    /// cervix + isthmus + cavity).
    pub sounding_length_mm: f64,
    /// Anatomical internal os to the fundal endometrium, along the axis.
    pub cavity_length_mm: Option<f64>,
    /// External os to the histological internal os (top of the cervical canal), along the axis.
    pub cervix_length_mm: Option<f64>,
    /// Histological to anatomical internal os (the isthmus), along the axis.
    pub isthmus_length_mm: Option<f64>,
    /// Coronal width of the lumen at the internal os (the isthmus, the lumen's narrowest part).
    pub internal_os_width_mm: Option<f64>,
    /// Coronal width of the cervical canal at the level of the external os (its straight lateral
    /// walls, extended to that level).
    pub canal_diameter_mm: Option<f64>,
    /// Largest distance between the anterior and posterior endometrium, perpendicular to the
    /// cavity's mid-surface.
    pub slit_gap_mm: f64,
    /// Angle at the cornua between the fundal line and the upper lateral wall (mean of both).
    pub cornual_angle_deg: Option<f64>,
    /// Angle of the cervical axis from the organ frame's +z axis, towards +y (anterior) positive.
    pub version_deg: f64,
    /// Angle of the corpus axis against the cervical axis, towards +y (anteflexion) positive.
    pub flexion_deg: f64,
}

/// Below this distance (m) points count as lying on one line: landmark vertices are placed on
/// the geometry's straight walls to ~1e-15 m, while a chord over a curved or kinked piece
/// deviates by far more than this.
const COLLINEAR_M: f64 = 1e-8;

type P2 = [f64; 2];

fn sub2(a: P2, b: P2) -> P2 {
    [a[0] - b[0], a[1] - b[1]]
}
fn dot2(a: P2, b: P2) -> f64 {
    a[0] * b[0] + a[1] * b[1]
}
fn cross2(a: P2, b: P2) -> f64 {
    a[0] * b[1] - a[1] * b[0]
}
fn unit2(a: P2) -> P2 {
    let l = dot2(a, a).sqrt();
    [a[0] / l, a[1] / l]
}
/// Normal of a sagittal direction (y, z): +y for the direction +z.
fn perp(t: P2) -> P2 {
    [t[1], -t[0]]
}
/// Distance of `q` from the line through `a` and `b`.
fn line_dist(a: P2, b: P2, q: P2) -> f64 {
    let d = sub2(b, a);
    cross2(d, sub2(q, a)).abs() / dot2(d, d).sqrt()
}

/// The cavity's mid-line in the sagittal (y, z) plane, measured on the mesh: a straight cervical
/// piece, a circular arc, a straight corpus piece (the arc has zero length without flexion).
/// Positions map to (offset from the mid-line, arc length along it): the measured straightening.
#[derive(Debug, Clone, Copy)]
pub(crate) struct MeasuredAxis {
    origin: P2,
    t1: P2,
    t2: P2,
    /// Signed turning angle from t1 to t2 (towards +y positive).
    theta: f64,
    /// Arc length at the start of the arc, from `origin`.
    s_arc: f64,
    radius: f64,
    centre: P2,
    arc_start: P2,
    arc_end: P2,
}

impl MeasuredAxis {
    fn new(origin: P2, t1: P2, t2: P2, x: P2, tangent_len: f64) -> Self {
        let mut theta = sagittal_angle(t2) - sagittal_angle(t1);
        if theta > std::f64::consts::PI {
            theta -= 2.0 * std::f64::consts::PI;
        } else if theta < -std::f64::consts::PI {
            theta += 2.0 * std::f64::consts::PI;
        }
        let arc_start = [x[0] - t1[0] * tangent_len, x[1] - t1[1] * tangent_len];
        let arc_end = [x[0] + t2[0] * tangent_len, x[1] + t2[1] * tangent_len];
        let radius = if theta.abs() > 1e-12 {
            tangent_len / (0.5 * theta.abs()).tan()
        } else {
            0.0
        };
        let n1 = perp(t1);
        // The centre lies on the side the axis turns to (+y side of t1 for theta > 0).
        let side = theta.signum();
        let centre = [
            arc_start[0] + side * radius * n1[0],
            arc_start[1] + side * radius * n1[1],
        ];
        MeasuredAxis {
            origin,
            t1,
            t2,
            theta,
            s_arc: dot2(sub2(arc_start, origin), t1),
            radius,
            centre,
            arc_start,
            arc_end,
        }
    }

    fn straight(origin: P2, t1: P2) -> Self {
        MeasuredAxis {
            origin,
            t1,
            t2: t1,
            theta: 0.0,
            s_arc: f64::INFINITY,
            radius: 0.0,
            centre: origin,
            arc_start: origin,
            arc_end: origin,
        }
    }

    /// (offset along the local normal, arc length from the origin) of a sagittal point.
    pub(crate) fn locate(&self, q: P2) -> (f64, f64) {
        let s1 = dot2(sub2(q, self.origin), self.t1);
        let n1 = dot2(sub2(q, self.origin), perp(self.t1));
        if self.theta == 0.0 || s1 <= self.s_arc {
            let mut best = (n1, s1);
            if self.theta == 0.0 {
                return best;
            }
            // Beyond the bend's inner side a point can lie nearer the corpus piece.
            let s2 = dot2(sub2(q, self.arc_end), self.t2);
            if s2 >= 0.0 {
                let n2 = dot2(sub2(q, self.arc_end), perp(self.t2));
                if n2.abs() < best.0.abs() {
                    best = (n2, self.s_arc + self.radius * self.theta.abs() + s2);
                }
            }
            return best;
        }
        let s2 = dot2(sub2(q, self.arc_end), self.t2);
        let len = self.radius * self.theta.abs();
        let mut cands: Vec<(f64, f64)> = Vec::with_capacity(2);
        if s2 >= 0.0 {
            cands.push((
                dot2(sub2(q, self.arc_end), perp(self.t2)),
                self.s_arc + len + s2,
            ));
        }
        let a = sub2(self.arc_start, self.centre);
        let v = sub2(q, self.centre);
        let turn = cross2(a, sub2(self.arc_end, self.centre)).signum();
        let phi = turn * cross2(a, v).atan2(dot2(a, v));
        if (0.0..=self.theta.abs()).contains(&phi) {
            let rho = dot2(v, v).sqrt();
            // Local tangent: t1 turned by phi in the axis' turning direction.
            let ang = self.theta.signum() * phi;
            let (c, sn) = (ang.cos(), ang.sin());
            // Rotation towards +y: (y, z) -> (y c + z s, -y s + z c) turns +z towards +y.
            let t = [
                self.t1[0] * c + self.t1[1] * sn,
                -self.t1[0] * sn + self.t1[1] * c,
            ];
            let foot = [
                self.centre[0] + v[0] / rho * self.radius,
                self.centre[1] + v[1] / rho * self.radius,
            ];
            cands.push((dot2(sub2(q, foot), perp(t)), self.s_arc + self.radius * phi));
        }
        if cands.is_empty() {
            // In the wedge outside the bend: the arc's start or end, whichever is nearer.
            let da = dot2(sub2(q, self.arc_start), sub2(q, self.arc_start));
            let de = dot2(sub2(q, self.arc_end), sub2(q, self.arc_end));
            return if da <= de {
                (n1, self.s_arc)
            } else {
                (dot2(sub2(q, self.arc_end), perp(self.t2)), self.s_arc + len)
            };
        }
        cands
            .into_iter()
            .min_by(|a, b| a.0.abs().total_cmp(&b.0.abs()))
            .unwrap_or((n1, s1)) // ok: cands is not empty
    }

    /// Sum of squared distances of the points from the axis.
    fn residual(&self, pts: &[P2]) -> f64 {
        pts.iter().map(|&q| self.locate(q).0.powi(2)).sum()
    }
}

/// Angle of a sagittal direction from +z towards +y.
fn sagittal_angle(t: P2) -> f64 {
    t[0].atan2(t[1])
}

/// Longest run of `pts` (in order) from the first that lies on one line; returns its length.
fn collinear_prefix(pts: &[P2]) -> usize {
    let mut best = pts.len().min(2);
    for k in 2..pts.len() {
        if dot2(sub2(pts[k], pts[0]), sub2(pts[k], pts[0])) < COLLINEAR_M * COLLINEAR_M {
            continue;
        }
        if (1..k).all(|i| line_dist(pts[0], pts[k], pts[i]) < COLLINEAR_M) {
            best = k + 1;
        } else {
            break;
        }
    }
    best
}

/// Fits the mid-line to the sagittal positions of the slit's rim (which lies on the mid-surface),
/// sorted by distance from the external os `e`.
fn fit_axis(e: P2, rim: &[P2]) -> Option<MeasuredAxis> {
    let mut pts: Vec<P2> = rim.to_vec();
    pts.sort_by(|a, b| dot2(sub2(*a, e), sub2(*a, e)).total_cmp(&dot2(sub2(*b, e), sub2(*b, e))));
    pts.dedup_by(|a, b| dot2(sub2(*a, *b), sub2(*a, *b)) < COLLINEAR_M * COLLINEAR_M);
    if pts.len() < 3 {
        return None;
    }
    let n1 = collinear_prefix(&pts);
    let last1 = pts[n1 - 1];
    let t1 = unit2(sub2(last1, pts[0]));
    if n1 == pts.len() {
        return Some(MeasuredAxis::straight(pts[0], t1));
    }
    let rev: Vec<P2> = pts.iter().rev().copied().collect();
    let n2 = collinear_prefix(&rev);
    if n2 < 2 || n1 + n2 > pts.len() {
        return None;
    }
    let first2 = rev[n2 - 1];
    let t2 = unit2(sub2(rev[0], first2));
    // Intersection of the two lines.
    let den = cross2(t1, t2);
    if den.abs() < 1e-12 {
        return Some(MeasuredAxis::straight(pts[0], t1));
    }
    let u = cross2(sub2(first2, pts[0]), t2) / den;
    let x = [pts[0][0] + u * t1[0], pts[0][1] + u * t1[1]];
    let t_max = dot2(sub2(x, last1), t1).min(dot2(sub2(first2, x), t2));
    if t_max <= 0.0 {
        return None;
    }
    let between = &pts[n1..pts.len() - n2];
    // Golden-section search for the tangent length that puts the points between on the arc.
    let g = 0.5 * (5f64.sqrt() - 1.0);
    let (mut lo, mut hi) = (0.0, t_max);
    let f = |t: f64| MeasuredAxis::new(pts[0], t1, t2, x, t).residual(between);
    let mut c = hi - g * (hi - lo);
    let mut d = lo + g * (hi - lo);
    let (mut fc, mut fd) = (f(c), f(d));
    for _ in 0..200 {
        if fc < fd {
            hi = d;
            d = c;
            fd = fc;
            c = hi - g * (hi - lo);
            fc = f(c);
        } else {
            lo = c;
            c = d;
            fc = fd;
            d = lo + g * (hi - lo);
            fd = f(d);
        }
        if hi - lo < 1e-13 {
            break;
        }
    }
    Some(MeasuredAxis::new(pts[0], t1, t2, x, 0.5 * (lo + hi)))
}

/// A straight piece of the lumen's coronal outline: half-width = a + b * s.
#[derive(Debug, Clone, Copy)]
struct Wall {
    a: f64,
    b: f64,
    s_first: f64,
}

/// Maximal runs of at least three consecutive collinear points of the outline (s, |x|) sorted by
/// s: the straight walls.
fn straight_walls(pts: &[P2]) -> Vec<Wall> {
    let mut out = Vec::new();
    let mut i = 0;
    while i + 2 < pts.len() {
        let n = collinear_prefix(&pts[i..]);
        if n >= 3 {
            let (p, q) = (pts[i], pts[i + n - 1]);
            let b = (q[1] - p[1]) / (q[0] - p[0]);
            out.push(Wall {
                a: p[1] - b * p[0],
                b,
                s_first: p[0],
            });
            i += n - 1;
        } else {
            i += 1;
        }
    }
    out
}

/// Landmarks of one side's outline: (external-os half-width, histological os s, anatomical os s,
/// os half-width, cornual angle deg).
fn side_landmarks(outline: &[P2], s_ext: f64) -> Option<(f64, f64, f64, f64, f64)> {
    let walls = straight_walls(outline);
    let flat = 1e-6;
    let ia = walls.iter().position(|w| w.b > flat)?;
    let ib = ia + 1 + walls[ia + 1..].iter().position(|w| w.b < -flat)?;
    let ic = ib + 1 + walls[ib + 1..].iter().position(|w| w.b > flat)?;
    let id = walls.iter().rposition(|w| w.b > flat)?;
    let (a, b, c, d) = (walls[ia], walls[ib], walls[ic], walls[id]);
    // The isthmus: the narrowest part of the lumen between the canal's waist and the cavity.
    let half_os = outline
        .iter()
        .filter(|p| p[0] >= b.s_first && p[0] <= c.s_first)
        .map(|p| p[1])
        .fold(f64::INFINITY, f64::min);
    if !half_os.is_finite() {
        return None;
    }
    let s_hist = (half_os - b.a) / b.b;
    let s_ios = (half_os - c.a) / c.b;
    let cornual = 1.0f64.atan2(d.b).to_degrees();
    Some((a.a + a.b * s_ext, s_hist, s_ios, half_os, cornual))
}

/// Measures the dimensions on the mesh.
pub(crate) fn measure_dimensions(mesh: &crate::mesh::TetMesh) -> Option<Dimensions> {
    let pos = &mesh.positions_m;
    let sag = |v: usize| [pos[v][1], pos[v][2]];
    let loop_: Vec<usize> = mesh
        .cavity_opening_loop
        .iter()
        .map(|&v| v as usize)
        .collect();
    if loop_.is_empty() {
        return None;
    }
    let e = loop_.iter().fold([0.0, 0.0], |acc, &v| {
        let q = sag(v);
        [
            acc[0] + q[0] / loop_.len() as f64,
            acc[1] + q[1] / loop_.len() as f64,
        ]
    });
    // Rim of the slit: cavity vertices where the anterior and posterior endometrium meet, i.e.
    // whose cavity triangles face opposite ways.
    let mut normals: Vec<Vec<[f64; 3]>> = vec![Vec::new(); pos.len()];
    for t in &mesh.cavity_triangles {
        let [a, b, c] = t.map(|v| pos[v as usize]);
        let n = crate::mesh::cross(crate::mesh::sub(b, a), crate::mesh::sub(c, a));
        for &v in t {
            normals[v as usize].push(n);
        }
    }
    let mut cavity: Vec<usize> = (0..pos.len()).filter(|&v| !normals[v].is_empty()).collect();
    cavity.sort_unstable();
    let rim: Vec<usize> = cavity
        .iter()
        .copied()
        .filter(|&v| {
            let ns = &normals[v];
            ns.iter()
                .any(|a| ns.iter().any(|b| crate::mesh::dot(*a, *b) < 0.0))
        })
        .collect();
    let axis = fit_axis(e, &rim.iter().map(|&v| sag(v)).collect::<Vec<_>>())?;
    let straight: Vec<[f64; 3]> = (0..pos.len())
        .map(|v| {
            let (n, s) = axis.locate(sag(v));
            [pos[v][0], n, s]
        })
        .collect();
    let mm = 1e3;
    let ext = |it: &mut dyn Iterator<Item = f64>| {
        it.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        })
    };
    let s_ext = loop_
        .iter()
        .map(|&v| straight[v][2])
        .fold(f64::INFINITY, f64::min);
    let (x0, x1) = ext(&mut straight.iter().map(|p| p[0]));
    let (n0, n1) = ext(&mut straight.iter().map(|p| p[1]));
    let (_, s1) = ext(&mut straight.iter().map(|p| p[2]));
    let (cx0, cx1) = ext(&mut cavity.iter().map(|&v| straight[v][0]));
    let (cn0, cn1) = ext(&mut cavity.iter().map(|&v| straight[v][1]));
    let (_, s_fund) = ext(&mut cavity.iter().map(|&v| straight[v][2]));
    // Coronal outline of the lumen on each side, below the fundal line.
    let mut sides = Vec::new();
    for sign in [1.0, -1.0] {
        let mut outline: Vec<P2> = rim
            .iter()
            .map(|&v| [straight[v][2], sign * straight[v][0]])
            .filter(|p| p[1] > 0.0 && p[0] < s_fund - COLLINEAR_M)
            .collect();
        outline.sort_by(|a, b| a[0].total_cmp(&b[0]));
        sides.push(side_landmarks(&outline, s_ext));
    }
    let both = match (sides[0], sides[1]) {
        (Some(l), Some(r)) => Some((l, r)),
        _ => None,
    };
    let mean = |f: fn(&(f64, f64, f64, f64, f64)) -> f64| both.map(|(l, r)| 0.5 * (f(&l) + f(&r)));
    let s_hist = mean(|l| l.1);
    let s_ios = mean(|l| l.2);
    let dims = Dimensions {
        uterine_length_mm: (s1 - s_ext) * mm,
        corpus_width_mm: (x1 - x0) * mm,
        ap_depth_mm: (n1 - n0) * mm,
        fundal_cavity_width_mm: (cx1 - cx0) * mm,
        fundal_wall_mm: (s1 - s_fund) * mm,
        sounding_length_mm: (s_fund - s_ext) * mm,
        cavity_length_mm: s_ios.map(|s| (s_fund - s) * mm),
        cervix_length_mm: s_hist.map(|s| (s - s_ext) * mm),
        isthmus_length_mm: s_hist.zip(s_ios).map(|(h, i)| (i - h) * mm),
        internal_os_width_mm: mean(|l| 2.0 * l.3).map(|w| w * mm),
        canal_diameter_mm: mean(|l| 2.0 * l.0).map(|w| w * mm),
        slit_gap_mm: (cn1 - cn0) * mm,
        cornual_angle_deg: mean(|l| l.4),
        version_deg: sagittal_angle(axis.t1).to_degrees(),
        flexion_deg: axis.theta.to_degrees(),
    };
    Some(dims)
}

/// A myoma's FIGO type: requested, as placed in the geometry, and measured on the mesh.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MyomaReport {
    /// Index in `params.myomas`.
    pub index: usize,
    /// The type given in the parameters, if any.
    pub figo_requested: Option<u8>,
    /// The type of the geometry as placed.
    pub figo_placed: u8,
    /// The type measured on the mesh.
    pub figo_measured: u8,
    /// Fraction of the myoma's meshed volume on the wall side of its endometrial plane.
    pub intramural_fraction: f64,
    /// Whether a myoma element touches the endometrium.
    pub contacts_endometrium: bool,
    /// Meshed myoma volume, ml.
    pub volume_ml: f64,
}

/// Fills the summary's volumes, counts, dimensions and myoma reports.
pub(crate) fn fill_summary(mesh: &TetMesh, geometry: &Geometry, s: &mut AnatomySummary) {
    // Organ-frame positions back in the straight reference frame (version/flexion undone).
    let straight: Vec<[f64; 3]> = mesh
        .positions_m
        .iter()
        .map(|&p| geometry.bend.invert(p))
        .collect();
    let mut label_counts = [0usize; 4];
    for l in &mesh.vertex_labels {
        label_counts[*l as usize] += 1;
    }
    let mut region_counts = [0usize; 3];
    for r in &mesh.tet_regions {
        region_counts[*r as usize] += 1;
    }
    let tissue = mesh.volume_m3();
    let cavity = mesh.cavity_volume_m3();
    let mm = 1e3;
    let dims = measure_dimensions(mesh).unwrap_or_default();
    // FIGO per myoma.
    let mut on_endometrium = vec![false; straight.len()];
    for t in &mesh.cavity_triangles {
        for &v in t {
            on_endometrium[v as usize] = true;
        }
    }
    let spacing = s.lattice_spacing_mm / mm;
    let mut reports = Vec::new();
    for l in &geometry.lesions {
        let LesionKind::Myoma { figo } = l.kind else {
            continue;
        };
        let plane = 0.5 * geometry.gap_at(l.centre_m);
        let (mut inside, mut total, mut contact) = (0.0, 0.0, false);
        for (ti, t) in mesh.tets.iter().enumerate() {
            if mesh.tet_regions[ti] != Region::Fibroid {
                continue;
            }
            let mut c = [0.0; 3];
            for &v in t {
                for k in 0..3 {
                    c[k] += 0.25 * straight[v as usize][k];
                }
            }
            if ellipsoid_sdf(c, l.centre_m, l.semi_axes_m) > 2.0 * spacing + 2.0 * plane {
                continue;
            }
            let vol = mesh.tet_volume_m3(ti);
            total += vol;
            let intramural = if l.wall_sign == 0.0 {
                // Lateral, fundal, oblique: everything not inside the opened slit.
                !(geometry.footprint(c[0], c[2]) < 0.0 && c[1].abs() < 0.5 * geometry.gap_at(c))
            } else {
                l.wall_sign * c[1] > plane
            };
            if intramural {
                inside += vol;
            }
            contact |= t.iter().any(|&v| on_endometrium[v as usize]);
        }
        let frac = if total > 0.0 { inside / total } else { 0.0 };
        let measured = if frac <= 1e-9 {
            0
        } else if frac < 0.5 {
            1
        } else if frac < 1.0 - 1e-9 {
            2
        } else if contact {
            3
        } else {
            4
        };
        reports.push(MyomaReport {
            index: l.index,
            figo_requested: s.params.myomas.get(l.index).and_then(|m| m.figo),
            figo_placed: figo,
            figo_measured: measured,
            intramural_fraction: frac,
            contacts_endometrium: contact,
            volume_ml: total * 1e6,
        });
    }
    s.label_counts = label_counts;
    s.region_counts = region_counts;
    s.tissue_volume_ml = tissue * 1e6;
    s.cavity_volume_ml = cavity * 1e6;
    s.uterine_volume_ml = (tissue + cavity) * 1e6;
    s.dimensions = dims;
    s.myomas = reports;
    let _ = VertexLabel::Interior;
}
