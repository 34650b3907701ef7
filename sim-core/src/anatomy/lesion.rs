//! A placed lesion (myoma or polyp): its kind, body and the implicit functions the geometry wraps
//! the slit over. Placement is in `pathology`.

use super::params::{PolypKind, MM};

/// What a lesion is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum LesionKind {
    /// A myoma of the given FIGO type (0-4).
    Myoma { figo: u8 },
    /// A polyp.
    Polyp(PolypKind),
}

/// A placed lesion in the straight reference frame (metres).
#[derive(Debug, Clone)]
pub(crate) struct Lesion {
    /// Index in `params.myomas` or `params.polyps`.
    pub index: usize,
    pub kind: LesionKind,
    /// +1 anterior wall, -1 posterior wall, 0 other walls (not protruding; its region takes
    /// elements on both sides of the slit).
    pub wall_sign: f64,
    pub centre_m: [f64; 3],
    pub semi_axes_m: [f64; 3],
    /// Stalk: (base point on the mid-surface, radius) for pedunculated lesions.
    pub stalk: Option<([f64; 3], f64)>,
    /// Fillet radius where the lesion meets the endometrium.
    pub fillet_m: f64,
    /// Whether the lesion protrudes into the cavity (so the slit wraps it).
    pub protrudes: bool,
    /// The slit is wrapped this much outside the lesion: opening the slit moves each face by half
    /// the gap, so the lesion ends up at its requested size.
    pub inflate_m: f64,
}

/// Approximate signed distance to an axis-aligned ellipsoid (exact on the surface, distance-like
/// near it).
pub(crate) fn ellipsoid_sdf(p: [f64; 3], c: [f64; 3], r: [f64; 3]) -> f64 {
    let q = [
        (p[0] - c[0]) / r[0],
        (p[1] - c[1]) / r[1],
        (p[2] - c[2]) / r[2],
    ];
    let k0 = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt();
    let q1 = [q[0] / r[0], q[1] / r[1], q[2] / r[2]];
    let k1 = (q1[0] * q1[0] + q1[1] * q1[1] + q1[2] * q1[2]).sqrt();
    if k1 < 1e-300 {
        return -r[0].min(r[1]).min(r[2]);
    }
    k0 * (k0 - 1.0) / k1
}

fn capsule_sdf(p: [f64; 3], a: [f64; 3], b: [f64; 3], r: f64) -> f64 {
    let ab = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
    let ap = [p[0] - a[0], p[1] - a[1], p[2] - a[2]];
    let l2 = ab[0] * ab[0] + ab[1] * ab[1] + ab[2] * ab[2];
    let t = ((ap[0] * ab[0] + ap[1] * ab[1] + ap[2] * ab[2]) / l2).clamp(0.0, 1.0);
    let d = [ap[0] - ab[0] * t, ap[1] - ab[1] * t, ap[2] - ab[2] * t];
    (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() - r
}

impl Lesion {
    /// Distance-like function of the lesion body (with its stalk), if it protrudes.
    pub fn protruding_sdf(&self, p: [f64; 3]) -> Option<f64> {
        if !self.protrudes {
            return None;
        }
        let mut d = ellipsoid_sdf(p, self.centre_m, self.semi_axes_m);
        if let Some((base, r)) = self.stalk {
            d = d.min(capsule_sdf(p, base, self.centre_m, r));
        }
        Some(d - self.inflate_m)
    }

    /// Whether a tetrahedron with reference centroid `c` on slit side `side` (+1/-1) belongs to
    /// this lesion's material region.
    pub fn region_contains(&self, c: [f64; 3], side: f64) -> bool {
        if self.wall_sign != 0.0 && side != self.wall_sign {
            return false;
        }
        match self.kind {
            LesionKind::Myoma { .. } => {
                let grow = if self.wall_sign * c[1] < 0.0 {
                    self.inflate_m
                } else {
                    0.0
                };
                ellipsoid_sdf(c, self.centre_m, self.semi_axes_m) < grow
            }
            LesionKind::Polyp(_) => {
                // Everything of the polyp's wall that lies beyond the mid-plane near the polyp.
                self.wall_sign * c[1] < 0.0
                    && self
                        .protruding_sdf(c)
                        .is_some_and(|d| d < self.fillet_m + 2.0 * MM)
            }
        }
    }
}
