//! The slit cavity: find the inserted mid-surface inside the cavity's footprint, cut the mesh open
//! along it (duplicating its vertices), orient the cavity triangles into the fluid, order the
//! opening loop at the external os, and open the slit to its resting gap.
//!
//! The opening moves the two faces of the slit by +-gap/2 along the mid-surface's normal and
//! spreads that displacement harmonically (graph Laplacian) into the wall, with the serosa held
//! fixed, so the outer surface keeps its exact shape and no element is squeezed into one layer.

use super::error::AnatomyError;
use super::geometry::Geometry;
use super::mesher::{boundary_faces, cross, dot, sub, unique_edges, WorkMesh};

/// The cut-open cavity.
pub(crate) struct Cavity {
    /// Cavity triangles, right-hand normals into the fluid.
    pub triangles: Vec<[u32; 3]>,
    /// Boundary loop of the cavity surface at the external os, in order.
    pub opening_loop: Vec<u32>,
    /// Iterations and final relative residual of the harmonic opening solve.
    pub solve: (usize, f64),
}

/// Cuts the mesh open along the slit and opens it to the resting gap.
///
/// `side[t]` is +1/-1 for the side of the mid-surface each tetrahedron lies on; `chi_zero[v]`
/// marks vertices on the mid-surface; `psi[v]` is the footprint function at each vertex (exactly
/// 0 on the rim).
pub(crate) fn open_slit(
    mesh: &mut WorkMesh,
    side: &[f64],
    chi_zero: &[bool],
    psi: &[f64],
    geo: &Geometry,
) -> Result<Cavity, AnatomyError> {
    // Faces on the mid-surface, grouped by vertex triple.
    let mut faces: Vec<([u32; 3], u32, usize)> = Vec::new();
    for (ti, t) in mesh.tets.iter().enumerate() {
        for skip in 0..4 {
            let f: Vec<u32> = (0..4).filter(|&k| k != skip).map(|k| t[k]).collect();
            if f.iter().all(|&v| chi_zero[v as usize]) {
                let mut key = [f[0], f[1], f[2]];
                key.sort_unstable();
                faces.push((key, ti as u32, skip));
            }
        }
    }
    faces.sort_unstable();
    // (anterior face, posterior face) of each slit face, as (vertices, tet, local opposite vertex).
    type Face = ([u32; 3], u32, usize);
    let mut crack: Vec<(Face, Face)> = Vec::new();
    let mut i = 0;
    while i < faces.len() {
        let mut j = i + 1;
        while j < faces.len() && faces[j].0 == faces[i].0 {
            j += 1;
        }
        if j - i == 2 {
            let (a, b) = (faces[i], faces[i + 1]);
            let (sa, sb) = (side[a.1 as usize], side[b.1 as usize]);
            let key = a.0;
            // A face with all three vertices on the rim would have zero gap: it stays closed.
            let in_footprint = key.iter().all(|&v| psi[v as usize] <= 0.0)
                && key.iter().any(|&v| psi[v as usize] < 0.0);
            if sa * sb < 0.0 && in_footprint {
                let (plus, minus) = if sa > 0.0 { (a, b) } else { (b, a) };
                crack.push((plus, minus));
            }
        }
        i = j;
    }
    if crack.is_empty() {
        return Err(AnatomyError::Mesher(
            "no cavity faces found: the slit was not resolved by the lattice".into(),
        ));
    }
    // Duplicate the mid-surface vertices strictly inside the footprint.
    let mut dup: Vec<u32> = crack
        .iter()
        .flat_map(|(p, _)| p.0)
        .filter(|&v| psi[v as usize] < 0.0)
        .collect();
    dup.sort_unstable();
    dup.dedup();
    let mut copy_of = vec![u32::MAX; mesh.pos.len()];
    let mut copies = Vec::with_capacity(dup.len());
    for &v in &dup {
        let c = mesh.pos.len() as u32;
        mesh.pos.push(mesh.pos[v as usize]);
        copy_of[v as usize] = c;
        copies.push((v, c));
    }
    copy_of.resize(mesh.pos.len(), u32::MAX);
    for (ti, t) in mesh.tets.iter_mut().enumerate() {
        if side[ti] < 0.0 {
            for v in t.iter_mut() {
                if copy_of[*v as usize] != u32::MAX {
                    *v = copy_of[*v as usize];
                }
            }
        }
    }
    // Cavity triangles, oriented away from their own tetrahedron (into the fluid).
    let mut triangles = Vec::with_capacity(2 * crack.len());
    for (plus, minus) in &crack {
        for (_, ti, skip) in [plus, minus] {
            let t = mesh.tets[*ti as usize];
            let mut f = [0u32; 3];
            let mut n = 0;
            for (k, &v) in t.iter().enumerate() {
                if k != *skip {
                    f[n] = v;
                    n += 1;
                }
            }
            let opp = mesh.pos[t[*skip] as usize];
            let [a, b, c] = f.map(|v| mesh.pos[v as usize]);
            if dot(cross(sub(b, a), sub(c, a)), sub(opp, a)) > 0.0 {
                f.swap(1, 2);
            }
            triangles.push(f);
        }
    }
    let opening_loop = opening_loop(&triangles)?;
    // Opening displacement: Dirichlet on the slit faces (+-gap/2 along the normal), on the serosa
    // and on the rim (0); harmonic elsewhere.
    let nv = mesh.pos.len();
    let mut fixed = vec![false; nv];
    let mut disp = vec![[0.0f64; 3]; nv];
    let mut cavity_keys: Vec<[u32; 3]> = triangles
        .iter()
        .map(|t| {
            let mut k = *t;
            k.sort_unstable();
            k
        })
        .collect();
    cavity_keys.sort_unstable();
    for f in boundary_faces(&mesh.tets) {
        if cavity_keys.binary_search(&f).is_err() {
            for v in f {
                fixed[v as usize] = true;
            }
        }
    }
    for t in &triangles {
        for &v in t {
            fixed[v as usize] = true;
        }
    }
    for &(v, c) in &copies {
        let p = mesh.pos[v as usize];
        let n = geo.side_gradient(p);
        let half = 0.5 * geo.gap_at(p);
        disp[v as usize] = n.map(|x| half * x);
        disp[c as usize] = n.map(|x| -half * x);
    }
    let solve = harmonic_extend(&mesh.tets, &mesh.pos, &fixed, &mut disp);
    for (p, u) in mesh.pos.iter_mut().zip(&disp) {
        for k in 0..3 {
            p[k] += u[k];
        }
    }
    Ok(Cavity {
        triangles,
        opening_loop,
        solve,
    })
}

/// Orders the boundary half-edges of the cavity surface into its single loop.
pub(crate) fn opening_loop(triangles: &[[u32; 3]]) -> Result<Vec<u32>, AnatomyError> {
    let mut half: Vec<(u32, u32)> = Vec::with_capacity(3 * triangles.len());
    for t in triangles {
        for k in 0..3 {
            half.push((t[k], t[(k + 1) % 3]));
        }
    }
    half.sort_unstable();
    let mut boundary: Vec<(u32, u32)> = half
        .iter()
        .filter(|&&(a, b)| half.binary_search(&(b, a)).is_err())
        .copied()
        .collect();
    boundary.sort_unstable();
    if boundary.is_empty() {
        return Err(AnatomyError::Mesher(
            "the cavity surface has no opening at the external os".into(),
        ));
    }
    // Each boundary vertex must start exactly one boundary half-edge.
    for w in boundary.windows(2) {
        if w[0].0 == w[1].0 {
            return Err(AnatomyError::Mesher(format!(
                "the cavity opening is not a simple loop at vertex {} (edges to {} and {})",
                w[0].0, w[0].1, w[1].1
            )));
        }
    }
    let next = |v: u32| {
        boundary
            .binary_search_by_key(&v, |e| e.0)
            .ok()
            .map(|i| boundary[i].1)
    };
    let start = boundary[0].0;
    let mut loop_ = vec![start];
    let mut v = start;
    loop {
        let Some(n) = next(v) else {
            return Err(AnatomyError::Mesher(format!(
                "the cavity opening is broken after vertex {v}"
            )));
        };
        if n == start {
            break;
        }
        loop_.push(n);
        v = n;
        if loop_.len() > boundary.len() {
            return Err(AnatomyError::Mesher(
                "the cavity opening does not close".into(),
            ));
        }
    }
    if loop_.len() != boundary.len() {
        return Err(AnatomyError::Mesher(format!(
            "the cavity surface has more than one boundary loop ({} of {} boundary edges in the first)",
            loop_.len(),
            boundary.len()
        )));
    }
    Ok(loop_)
}

/// Solves the graph Laplace equation for the free vertices' displacement (conjugate gradients,
/// one system per component); returns (iterations, relative residual).
fn harmonic_extend(
    tets: &[[u32; 4]],
    pos: &[[f64; 3]],
    fixed: &[bool],
    disp: &mut [[f64; 3]],
) -> (usize, f64) {
    let nv = fixed.len();
    let edges = unique_edges(tets);
    let mut count = vec![0usize; nv];
    for &(a, b) in &edges {
        count[a as usize] += 1;
        count[b as usize] += 1;
    }
    let mut start = vec![0usize; nv + 1];
    for v in 0..nv {
        start[v + 1] = start[v] + count[v];
    }
    let mut fill = start.clone();
    let mut adj = vec![0u32; start[nv]];
    // Edge weights 1/length^2: short edges (split next to a surface) couple strongly, so the
    // displacement does not drop across a thin element.
    let mut wgt = vec![0.0f64; start[nv]];
    let mut deg = vec![0.0f64; nv];
    for &(a, b) in &edges {
        let d = sub(pos[a as usize], pos[b as usize]);
        let w = 1.0 / dot(d, d);
        adj[fill[a as usize]] = b;
        wgt[fill[a as usize]] = w;
        fill[a as usize] += 1;
        adj[fill[b as usize]] = a;
        wgt[fill[b as usize]] = w;
        fill[b as usize] += 1;
        deg[a as usize] += w;
        deg[b as usize] += w;
    }
    let free: Vec<usize> = (0..nv).filter(|&v| !fixed[v]).collect();
    let mut worst = (0usize, 0.0f64);
    #[allow(clippy::needless_range_loop)] // one system per component of disp
    for comp in 0..3 {
        let apply = |x: &[f64], out: &mut [f64]| {
            for &v in &free {
                let mut s = deg[v] * x[v];
                for k in start[v]..start[v + 1] {
                    let w = adj[k] as usize;
                    if !fixed[w] {
                        s -= wgt[k] * x[w];
                    }
                }
                out[v] = s;
            }
        };
        let mut b = vec![0.0; nv];
        for &v in &free {
            b[v] = (start[v]..start[v + 1])
                .filter(|&k| fixed[adj[k] as usize])
                .map(|k| wgt[k] * disp[adj[k] as usize][comp])
                .sum();
        }
        let bnorm = free.iter().map(|&v| b[v] * b[v]).sum::<f64>().sqrt();
        if bnorm == 0.0 {
            continue;
        }
        let mut x = vec![0.0; nv];
        let mut r = b.clone();
        let mut p = r.clone();
        let mut ap = vec![0.0; nv];
        let mut rr: f64 = free.iter().map(|&v| r[v] * r[v]).sum();
        let mut it = 0;
        while it < 5000 && rr.sqrt() > 1e-12 * bnorm {
            apply(&p, &mut ap);
            let pap: f64 = free.iter().map(|&v| p[v] * ap[v]).sum();
            let alpha = rr / pap;
            for &v in &free {
                x[v] += alpha * p[v];
                r[v] -= alpha * ap[v];
            }
            let rr_new: f64 = free.iter().map(|&v| r[v] * r[v]).sum();
            let beta = rr_new / rr;
            for &v in &free {
                p[v] = r[v] + beta * p[v];
            }
            rr = rr_new;
            it += 1;
        }
        for &v in &free {
            disp[v][comp] = x[v];
        }
        worst = (worst.0.max(it), worst.1.max(rr.sqrt() / bnorm));
    }
    worst
}
