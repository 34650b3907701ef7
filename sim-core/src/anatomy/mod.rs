//! Parametric uterus: from parameters a gynecologist knows to a labelled tetrahedral mesh.
//!
//! Pipeline ([`generate`]):
//! 1. [`AnatomyParams`] (mm, degrees; parity presets) are checked and turned into an implicit
//!    geometry in a straight reference frame: serosa, the slit cavity's coronal footprint and
//!    resting gap, lesions (myomas by FIGO type, polyps), version/flexion as a bend.
//! 2. A Kuhn cube lattice (spacing chosen for `mesh.target_tets`) is cut to the serosa by warping
//!    and edge splitting (isosurface stuffing); the slit's mid-surface (the plane y = 0, wrapped
//!    over protruding lesions) and the footprint's rim are inserted the same way.
//! 3. The mesh is cut open along the mid-surface inside the footprint (the cavity and cervical
//!    canal, open at the external os), the slit is opened to its resting gap, and the organ is bent
//!    into version/flexion.
//! 4. Vertices are labelled (portio fixed, endometrium, serosa), tetrahedra get their region.
//!
//! ```
//! use hydrometra_sim::anatomy::{generate, AnatomyParams};
//! let mut params = AnatomyParams::default();
//! params.mesh.target_tets = 8000; // coarse, for a quick look
//! let anatomy = generate(&params).unwrap();
//! assert!(anatomy.summary.min_volume_positive());
//! assert!(anatomy.mesh.cavity_volume_m3() > 0.0);
//! ```

mod cavity;
mod error;
mod geometry;
mod lesion;
mod measure;
mod mesher;
mod params;
mod pathology;
mod quality;
mod smooth;
mod vtu;

pub use error::AnatomyError;
pub use measure::{AnatomySummary, Dimensions, MyomaReport};
pub use params::{
    AnatomyParams, MeshParams, MyomaParams, Parity, PolypKind, PolypParams, WallSide,
};
pub use quality::{mesh_quality, tet_quality, QualityStats, TetQuality};
pub use vtu::write_vtu;

use crate::mesh::{Region, TetMesh, VertexLabel};
use geometry::{Bend, Geometry};
use mesher::{Insertion, WorkMesh};

/// Warp threshold (fraction of an edge) for inserting surfaces: vertices closer than this to a
/// crossing are moved onto the surface instead of splitting the edge next to them.
const ALPHA: f64 = 0.3;
/// Warp threshold for the slit's mid-surface: smaller, so fewer tetrahedra end with all four
/// vertices on it (their side of the slit would be ambiguous).
const ALPHA_MID: f64 = 0.2;
/// Tetrahedra per lattice cube (Kuhn) times the growth from boundary splits, measured on the presets.
const TETS_PER_CELL: f64 = 6.0 * 1.12;

/// A generated anatomy.
#[derive(Debug, Clone)]
pub struct Anatomy {
    /// The parameters used.
    pub params: AnatomyParams,
    /// The labelled mesh (organ frame, metres).
    pub mesh: TetMesh,
    /// Counts, volumes, quality, measured dimensions.
    pub summary: AnatomySummary,
    geometry: Geometry,
}

impl Anatomy {
    /// Maps organ-frame positions back to the straight reference frame (version/flexion undone).
    pub fn straighten(&self, p: [f64; 3]) -> [f64; 3] {
        self.geometry.bend.invert(p)
    }

    /// The summary as pretty JSON.
    pub fn summary_json(&self) -> Result<String, AnatomyError> {
        serde_json::to_string_pretty(&self.summary)
            .map_err(|e| AnatomyError::Mesher(format!("summary to JSON: {e}")))
    }
}

/// Lattice spacing for the target tetrahedron count: the organ volume (sampled on a 1.5 mm grid)
/// divided into `target / TETS_PER_CELL` cubes.
fn spacing_for(params: &AnatomyParams) -> Result<f64, AnatomyError> {
    let g0 = Geometry::with_lesions(params, 0.0)?;
    let step = 1.5e-3;
    let (hx, hy) = (g0.corpus_half_width_m, g0.corpus_half_depth_m);
    let mut inside = 0usize;
    let nx = (hx / step).ceil() as i64 + 1;
    let ny = (hy / step).ceil() as i64 + 1;
    let nz = (g0.uterine_length_m / step).ceil() as i64 + 1;
    for k in 0..nz {
        for j in -ny..=ny {
            for i in -nx..=nx {
                let p = [
                    (i as f64 + 0.5) * step,
                    (j as f64 + 0.5) * step,
                    (k as f64 + 0.5) * step,
                ];
                if g0.organ(p) < 0.0 {
                    inside += 1;
                }
            }
        }
    }
    let volume = inside as f64 * step * step * step;
    let cells = params.mesh.target_tets as f64 / TETS_PER_CELL;
    Ok((volume / cells).cbrt())
}

/// Generates the anatomy: a deterministic function of the parameters (bit-identical output).
pub fn generate(params: &AnatomyParams) -> Result<Anatomy, AnatomyError> {
    params.check_ranges()?;
    let h = spacing_for(params)?;
    let geo = Geometry::with_lesions(params, h)?;
    let tol = 1e-12;

    // 1. Lattice cut to the serosa.
    let organ = |p: [f64; 3]| geo.organ(p);
    let lo = [
        -geo.corpus_half_width_m - h,
        -geo.corpus_half_depth_m - h,
        -h,
    ];
    let hi = [
        geo.corpus_half_width_m + h,
        geo.corpus_half_depth_m + h,
        geo.uterine_length_m + h,
    ];
    let mut m = mesher::kuhn_lattice(&organ, lo, hi, h);
    let pos0 = m.pos.clone();
    let outer = mesher::insert_surface(
        &mut m,
        &Insertion {
            field: &organ,
            alpha: ALPHA,
            // Vertices on the mid-plane stay on it.
            movable: &|v, target| pos0[v as usize][1] != 0.0 || target[1] == 0.0,
            edge_ok: &|_, _| true,
            pin_unmovable: false,
        },
        tol,
    );
    let vals = outer.values;
    // Keep what lies inside. A tetrahedron whose four vertices were all warped onto the surface
    // is flat (a sliver in the surface) and is dropped: its faces become surface faces.
    m.tets.retain(|t| t.iter().any(|&v| vals[v as usize] < 0.0));
    mesher::compact(&mut m);

    // 2. The slit's mid-surface.
    let boundary = boundary_mask(&m);
    let side_fn = |p: [f64; 3]| geo.side(p);
    let chi = mesher::insert_surface(
        &mut m,
        &Insertion {
            field: &side_fn,
            alpha: ALPHA_MID,
            movable: &|v, _| !boundary.get(v as usize).copied().unwrap_or(true),
            edge_ok: &|_, _| true,
            pin_unmovable: false,
        },
        tol,
    );
    let chi_zero: Vec<bool> = chi.values.iter().map(|&c| c == 0.0).collect();

    // 3. The footprint's rim on the mid-surface.
    let boundary = boundary_mask(&m);
    let foot = |p: [f64; 3]| geo.footprint(p[0], p[2]);
    let rim = mesher::insert_surface(
        &mut m,
        &Insertion {
            field: &foot,
            alpha: ALPHA,
            movable: &|v, _| chi_zero[v as usize] && !boundary[v as usize],
            edge_ok: &|a, b| chi_zero[a as usize] && chi_zero[b as usize],
            // Where the rim meets the portio the surface vertices stay put and become rim vertices.
            pin_unmovable: true,
        },
        tol,
    );
    let mut chi_zero = chi_zero;
    chi_zero.resize(m.pos.len(), true);
    let mut psi = rim.values;
    snap_landmarks(&mut m, &mut chi_zero, &mut psi, &geo);
    let chi_vals: Vec<f64> = (0..m.pos.len())
        .map(|v| if chi_zero[v] { 0.0 } else { chi.values[v] })
        .collect();
    let side: Vec<f64> = m
        .tets
        .iter()
        .map(|t| {
            t.iter()
                .map(|&v| chi_vals[v as usize])
                .find(|&c| c != 0.0)
                .unwrap_or_else(|| geo.side(tet_centroid(&m.pos, t)))
                .signum()
        })
        .map(|s| if s == 0.0 { 1.0 } else { s })
        .collect();
    let reference_centroids: Vec<[f64; 3]> =
        m.tets.iter().map(|t| tet_centroid(&m.pos, t)).collect();

    // 4. Cut open, open to the resting gap.
    let cav = cavity::open_slit(&mut m, &side, &chi_zero, &psi, &geo)?;

    // 5. Regions from the reference centroids.
    let regions: Vec<Region> = reference_centroids
        .iter()
        .zip(&side)
        .map(|(&c, &s)| {
            for l in &geo.lesions {
                if l.region_contains(c, s) {
                    return match l.kind {
                        lesion::LesionKind::Myoma { .. } => Region::Fibroid,
                        lesion::LesionKind::Polyp(_) => Region::Polyp,
                    };
                }
            }
            Region::Myometrium
        })
        .collect();

    // 6. Labels on the straight mesh.
    let labels = label_vertices(&m, &cav.triangles, &geo);

    // 7. Quality smoothing of interior vertices, then version/flexion.
    smooth::smooth_interior(&mut m, &labels, params.mesh.smoothing_sweeps);
    let bend: Bend = geo.bend;
    let positions_m: Vec<[f64; 3]> = m.pos.iter().map(|&p| bend.apply(p)).collect();
    let mesh = TetMesh {
        positions_m,
        tets: m.tets,
        tet_regions: regions,
        vertex_labels: labels,
        cavity_triangles: cav.triangles,
        cavity_opening_loop: cav.opening_loop,
    };
    let quality = mesh_quality(&mesh.positions_m, &mesh.tets);
    if quality.min_volume_m3 <= 0.0 {
        return Err(AnatomyError::Mesher(format!(
            "a tetrahedron has non-positive volume ({:e} m^3)",
            quality.min_volume_m3
        )));
    }
    let mut anatomy = Anatomy {
        params: params.clone(),
        summary: AnatomySummary {
            vertices: mesh.positions_m.len(),
            tets: mesh.tets.len(),
            cavity_triangles: mesh.cavity_triangles.len(),
            opening_loop_vertices: mesh.cavity_opening_loop.len(),
            label_counts: [0; 4],
            region_counts: [0; 3],
            lattice_spacing_mm: h * 1e3,
            tissue_volume_ml: 0.0,
            cavity_volume_ml: 0.0,
            uterine_volume_ml: 0.0,
            quality,
            dimensions: Dimensions::default(),
            myomas: Vec::new(),
            opening_solve_iterations: cav.solve.0,
            params: params.clone(),
        },
        mesh,
        geometry: geo,
    };
    measure::fill_summary(&anatomy.mesh, &anatomy.geometry, &mut anatomy.summary);
    tracing::debug!(
        tets = anatomy.summary.tets,
        spacing_mm = anatomy.summary.lattice_spacing_mm,
        min_dihedral_deg = anatomy.summary.quality.min_dihedral_deg,
        "anatomy generated"
    );
    Ok(anatomy)
}

fn tet_centroid(pos: &[[f64; 3]], t: &[u32; 4]) -> [f64; 3] {
    let mut c = [0.0; 3];
    for &v in t {
        for k in 0..3 {
            c[k] += 0.25 * pos[v as usize][k];
        }
    }
    c
}

fn boundary_mask(m: &WorkMesh) -> Vec<bool> {
    let mut b = vec![false; m.pos.len()];
    for f in mesher::boundary_faces(&m.tets) {
        for v in f {
            b[v as usize] = true;
        }
    }
    b
}

/// Portio (outer surface below the portio level) fixed, cavity surface endometrium, the rest of
/// the outer surface serosa; fixed wins where the cavity opening meets the portio.
fn label_vertices(m: &WorkMesh, cavity: &[[u32; 3]], geo: &Geometry) -> Vec<VertexLabel> {
    let mut labels = vec![VertexLabel::Interior; m.pos.len()];
    for t in cavity {
        for &v in t {
            labels[v as usize] = VertexLabel::Endometrium;
        }
    }
    let mut keys: Vec<[u32; 3]> = cavity
        .iter()
        .map(|t| {
            let mut k = *t;
            k.sort_unstable();
            k
        })
        .collect();
    keys.sort_unstable();
    for f in mesher::boundary_faces(&m.tets) {
        if keys.binary_search(&f).is_ok() {
            continue;
        }
        for v in f {
            let l = &mut labels[v as usize];
            if m.pos[v as usize][2] < geo.portio_top_z_m {
                *l = VertexLabel::Fixed;
            } else if *l == VertexLabel::Interior {
                *l = VertexLabel::Serosa;
            }
        }
    }
    labels
}

/// Snapping a landmark may not push an element below this (or below what it replaces).
const SNAP_MIN_DIHEDRAL_DEG: f64 = 8.0;

/// Puts rim vertices exactly on the landmarks the measurement relies on, so they are represented
/// exactly rather than by a chord: each cornu's lateral extreme (the fundal width) and the middle
/// of the isthmus on both sides (the internal os width, even where the isthmus is shorter than a
/// lattice spacing), and three points on the straight part of each upper lateral wall (the
/// cornual angle). The nearest rim vertex is moved there if it is close (a third of its rim
/// edge), otherwise the rim edge passing the target is split there (the other options are tried
/// next). A change is kept only if no element around the vertex inverts or drops below 8 degrees
/// (or below the worst element it replaces).
fn snap_landmarks(m: &mut WorkMesh, on_mid: &mut Vec<bool>, psi: &mut Vec<f64>, geo: &Geometry) {
    let Some(top) = geo
        .polygon
        .iter()
        .copied()
        .max_by(|a, b| a[0].total_cmp(&b[0]))
    else {
        return;
    };
    // Smallest dihedral angle of the elements containing all of `verts`.
    let star_min = |m: &WorkMesh, verts: &[u32]| {
        m.tets
            .iter()
            .filter(|t| verts.iter().all(|v| t.contains(v)))
            .map(|tet| {
                if mesher::volume6(&m.pos, tet) <= 0.0 {
                    f64::NEG_INFINITY
                } else {
                    tet_quality(tet.map(|w| m.pos[w as usize])).min_dihedral_deg
                }
            })
            .fold(f64::INFINITY, f64::min)
    };
    // A change is kept if no element inverts and none drops below 8 degrees or below the worst
    // element it replaces (the elements at the rim may be poor before the later optimisation).
    let good =
        |m: &WorkMesh, v: u32, before: f64| star_min(m, &[v]) >= SNAP_MIN_DIHEDRAL_DEG.min(before);
    let isthmus_z = 0.5 * (geo.histological_os_z_m + geo.internal_os_z_m);
    let mut targets = Vec::new();
    for sign in [1.0, -1.0] {
        targets.push([sign * (top[0] + geo.rounding_m), 0.0, top[1]]);
        targets.push([sign * geo.os_half_width_m, 0.0, isthmus_z]);
        for q in &geo.upper_wall_points {
            targets.push([sign * q[0], 0.0, q[1]]);
        }
    }
    for target in targets {
        let is_rim = |v: u32| {
            let v = v as usize;
            on_mid[v] && psi[v] == 0.0 && m.pos[v][1] == 0.0
        };
        // The rim edge passing closest to the target.
        let mut best: Option<(f64, u32, u32, f64)> = None;
        for (a, b) in mesher::unique_edges(&m.tets) {
            if !(is_rim(a) && is_rim(b)) {
                continue;
            }
            let (pa, pb) = (m.pos[a as usize], m.pos[b as usize]);
            let ab = mesher::sub(pb, pa);
            let t =
                (mesher::dot(mesher::sub(target, pa), ab) / mesher::dot(ab, ab)).clamp(0.0, 1.0);
            let d = mesher::norm(mesher::sub(mesher::lerp(pa, pb, t), target));
            if best.is_none_or(|x| d < x.0) {
                best = Some((d, a, b, t));
            }
        }
        let Some((_, a, b, t)) = best else { continue };
        // Try the exact target first (moving the nearer end of the rim edge, the other end, or
        // splitting the edge there; the nearer alternative first), then points part of the way
        // from the chord towards it.
        let (pa, pb) = (m.pos[a as usize], m.pos[b as usize]);
        let split_first = (1.0 / 3.0..=2.0 / 3.0).contains(&t);
        let (near, far) = if t < 0.5 { (a, b) } else { (b, a) };
        // None: split the edge; Some(v): move v.
        let methods: [Option<u32>; 3] = if split_first {
            [None, Some(near), Some(far)]
        } else {
            [Some(near), None, Some(far)]
        };
        'search: for f in [1.0, 0.75, 0.5, 0.25] {
            for method in methods {
                match method {
                    Some(v) => {
                        let from = m.pos[v as usize];
                        let before = star_min(m, &[v]);
                        m.pos[v as usize] = mesher::lerp(from, target, f);
                        if good(m, v, before) {
                            break 'search;
                        }
                        m.pos[v as usize] = from;
                    }
                    None => {
                        let point = mesher::lerp(mesher::lerp(pa, pb, t), target, f);
                        let before = star_min(m, &[a, b]);
                        let saved = m.clone();
                        let v = mesher::split_edge(m, a, b, point);
                        if good(m, v, before) {
                            on_mid.push(true);
                            psi.push(0.0);
                            break 'search;
                        }
                        *m = saved;
                    }
                }
            }
        }
    }
}
