//! Quality smoothing: interior vertices move towards the centroid of their neighbours when that
//! raises the smallest dihedral angle of the elements around them (never lowers it, never inverts);
//! then the interior vertices of the remaining poor elements (slivers against a curved surface,
//! typically where the slit wraps a lesion) are optimised by a compass search that maximises the
//! smallest dihedral angle of their star.

use crate::mesh::VertexLabel;

use super::mesher::{unique_edges, volume6, WorkMesh};
use super::quality::tet_quality;

fn star_quality(m: &WorkMesh, star: &[u32]) -> f64 {
    let mut q = f64::INFINITY;
    for &t in star {
        let tet = m.tets[t as usize];
        if volume6(&m.pos, &tet) <= 0.0 {
            return f64::NEG_INFINITY;
        }
        q = q.min(tet_quality(tet.map(|v| m.pos[v as usize])).min_dihedral_deg);
    }
    q
}

/// Runs `sweeps` Gauss-Seidel sweeps of quality-guarded smoothing over the interior vertices.
pub(crate) fn smooth_interior(m: &mut WorkMesh, labels: &[VertexLabel], sweeps: u32) {
    if sweeps == 0 {
        return;
    }
    let nv = m.pos.len();
    let mut star_start = vec![0usize; nv + 1];
    for t in &m.tets {
        for &v in t {
            star_start[v as usize + 1] += 1;
        }
    }
    for v in 0..nv {
        star_start[v + 1] += star_start[v];
    }
    let mut fill = star_start.clone();
    let mut stars = vec![0u32; star_start[nv]];
    for (ti, t) in m.tets.iter().enumerate() {
        for &v in t {
            stars[fill[v as usize]] = ti as u32;
            fill[v as usize] += 1;
        }
    }
    let mut nbr: Vec<Vec<u32>> = vec![Vec::new(); nv];
    for (a, b) in unique_edges(&m.tets) {
        nbr[a as usize].push(b);
        nbr[b as usize].push(a);
    }
    for _ in 0..sweeps {
        smooth_sweep(m, labels, &stars, &star_start, &nbr);
    }
    optimise_poor(m, labels, &stars, &star_start, &nbr);
}

/// Elements whose smallest dihedral angle is below this get their interior vertices optimised.
const POOR_DIHEDRAL_DEG: f64 = 20.0;

/// Compass search on the interior vertices of poor elements: steps of a shrinking fraction of the
/// vertex's shortest edge along +-x, +-y, +-z, keeping a step only if the star's smallest
/// dihedral angle rises. Deterministic (vertices in index order).
fn optimise_poor(
    m: &mut WorkMesh,
    labels: &[VertexLabel],
    stars: &[u32],
    star_start: &[usize],
    nbr: &[Vec<u32>],
) {
    let movable = |v: u32| labels[v as usize] == VertexLabel::Interior;
    for _ in 0..3 {
        let mut verts: Vec<u32> = Vec::new();
        for t in &m.tets {
            if tet_quality(t.map(|v| m.pos[v as usize])).min_dihedral_deg < POOR_DIHEDRAL_DEG {
                verts.extend(t.iter().filter(|&&v| movable(v)));
            }
        }
        verts.sort_unstable();
        verts.dedup();
        if verts.is_empty() {
            return;
        }
        for v in verts {
            let v = v as usize;
            let star = &stars[star_start[v]..star_start[v + 1]];
            let shortest = nbr[v]
                .iter()
                .map(|&w| {
                    let d = super::mesher::sub(m.pos[w as usize], m.pos[v]);
                    super::mesher::dot(d, d).sqrt()
                })
                .fold(f64::INFINITY, f64::min);
            let mut q = star_quality(m, star);
            let mut step = 0.25 * shortest;
            for _ in 0..12 {
                let mut improved = false;
                for k in 0..3 {
                    for dir in [1.0, -1.0] {
                        let old = m.pos[v];
                        m.pos[v][k] += dir * step;
                        let qn = star_quality(m, star);
                        if qn > q {
                            q = qn;
                            improved = true;
                        } else {
                            m.pos[v] = old;
                        }
                    }
                }
                if !improved {
                    step *= 0.5;
                }
            }
        }
    }
}

fn smooth_sweep(
    m: &mut WorkMesh,
    labels: &[VertexLabel],
    stars: &[u32],
    star_start: &[usize],
    nbr: &[Vec<u32>],
) {
    let nv = m.pos.len();
    {
        for v in 0..nv {
            if labels[v] != VertexLabel::Interior {
                continue;
            }
            let star = &stars[star_start[v]..star_start[v + 1]];
            let q0 = star_quality(m, star);
            let old = m.pos[v];
            let mut c = [0.0; 3];
            for &w in &nbr[v] {
                for (ck, pk) in c.iter_mut().zip(m.pos[w as usize]) {
                    *ck += pk / nbr[v].len() as f64;
                }
            }
            let mut best = (q0, old);
            for t in [1.0, 0.5, 0.25] {
                m.pos[v] = [0, 1, 2].map(|k| old[k] + t * (c[k] - old[k]));
                let q = star_quality(m, star);
                if q > best.0 {
                    best = (q, m.pos[v]);
                }
            }
            m.pos[v] = best.1;
        }
    }
}
