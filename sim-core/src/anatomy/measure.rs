//! Measurements on a generated mesh: dimensions (in the straightened frame) and the FIGO type of
//! each myoma, measured from the meshed geometry rather than taken from its placement.

use serde::{Deserialize, Serialize};

use crate::mesh::{Region, VertexLabel};

use super::pathology::{ellipsoid_sdf, LesionKind};
use super::Anatomy;

/// Dimensions measured on the mesh, mm. Definitions (straightened frame: version/flexion undone
/// with the exact inverse of the bend, which preserves lengths along the axis):
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Dimensions {
    /// Extent of all vertices along the axis (external os to the top of the fundus).
    pub uterine_length_mm: f64,
    /// Extent of all vertices left-right.
    pub corpus_width_mm: f64,
    /// Extent of all vertices antero-posterior.
    pub ap_depth_mm: f64,
    /// Left-right extent of the cavity surface (between the cornua).
    pub fundal_cavity_width_mm: f64,
    /// Top of the organ minus top of the cavity surface, along the axis.
    pub fundal_wall_mm: f64,
    /// Extent of the cavity surface along the axis: external os to the fundal endometrium
    /// (the clinical sounding length = cervix + isthmus + cavity).
    pub sounding_length_mm: f64,
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

fn extent(values: impl Iterator<Item = f64>) -> (f64, f64) {
    values.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
        (lo.min(v), hi.max(v))
    })
}

/// Fills the summary's volumes, counts, dimensions and myoma reports.
pub(crate) fn fill_summary(a: &mut Anatomy) {
    let mesh = &a.mesh;
    let straight: Vec<[f64; 3]> = mesh.positions_m.iter().map(|&p| a.straighten(p)).collect();
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
    let (x0, x1) = extent(straight.iter().map(|p| p[0]));
    let (y0, y1) = extent(straight.iter().map(|p| p[1]));
    let (z0, z1) = extent(straight.iter().map(|p| p[2]));
    let cav_vertices: Vec<usize> = {
        let mut v: Vec<usize> = mesh
            .cavity_triangles
            .iter()
            .flat_map(|t| t.iter().map(|&i| i as usize))
            .collect();
        v.sort_unstable();
        v.dedup();
        v
    };
    let (cx0, cx1) = extent(cav_vertices.iter().map(|&i| straight[i][0]));
    let (cz0, cz1) = extent(cav_vertices.iter().map(|&i| straight[i][2]));
    let dims = Dimensions {
        uterine_length_mm: (z1 - z0) * mm,
        corpus_width_mm: (x1 - x0) * mm,
        ap_depth_mm: (y1 - y0) * mm,
        fundal_cavity_width_mm: (cx1 - cx0) * mm,
        fundal_wall_mm: (z1 - cz1) * mm,
        sounding_length_mm: (cz1 - cz0) * mm,
    };
    // FIGO per myoma.
    let mut on_endometrium = vec![false; straight.len()];
    for t in &mesh.cavity_triangles {
        for &v in t {
            on_endometrium[v as usize] = true;
        }
    }
    let spacing = a.summary.lattice_spacing_mm / mm;
    let mut reports = Vec::new();
    for l in &a.geometry.lesions {
        let LesionKind::Myoma { figo } = l.kind else {
            continue;
        };
        let plane = 0.5 * a.geometry.gap_at(l.centre_m);
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
            if l.wall_sign * c[1] > plane {
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
            figo_requested: a.params.myomas.get(l.index).and_then(|m| m.figo),
            figo_placed: figo,
            figo_measured: measured,
            intramural_fraction: frac,
            contacts_endometrium: contact,
            volume_ml: total * 1e6,
        });
    }
    let s = &mut a.summary;
    s.label_counts = label_counts;
    s.region_counts = region_counts;
    s.tissue_volume_ml = tissue * 1e6;
    s.cavity_volume_ml = cavity * 1e6;
    s.uterine_volume_ml = (tissue + cavity) * 1e6;
    s.dimensions = dims;
    s.myomas = reports;
    let _ = VertexLabel::Interior;
}
