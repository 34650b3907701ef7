//! Where the fluid's boundary crosses the arms of the viscous stencil: for every MAC face centre,
//! the distance along each axis to the boundary when it lies within one cell (the second-order
//! no-slip rule of Gibou, Fedkiw, Cheng and Kang 2002 needs it; `fluid/viscosity.rs`).
//!
//! Method: the lines along each axis through the face centres are cut with the layers' triangles
//! (the same held positions as the fractions, so one copy of the geometry); per line, the
//! crossings of every layer, with their direction from the triangle's orientation, give each
//! layer's winding number, and the layers combine over the background in their order as the
//! fractions do ([`CutCells`]). A line through an edge or a vertex counts it once: a point on an
//! edge belongs to the triangle its symbolic perturbation `(d, d^2)` (along the line's two
//! transverse axes) falls into, and each edge's function is evaluated in one canonical vertex
//! order, so the two triangles beside an edge see the same value with opposite signs.

use super::cells::{CutCells, Phase};
use super::clip::P3;
use super::face_walls::{FaceWalls, NO_WALL};
use super::Orientation;

/// One crossing of a line with a layer: position along the line (cells), layer, and +1 entering
/// the layer's enclosed region, -1 leaving it.
type Event = (f64, u32, i32);

impl CutCells {
    /// The boundary distances of every MAC face's stencil arms ([`FaceWalls`]) at the positions
    /// the last [`CutCells::full`] or [`CutCells::update`] held. Lines reach beyond the box: on a
    /// periodic axis the surfaces must continue past the box for the arms there to be right.
    pub fn face_walls(&self) -> FaceWalls {
        let dims = self.cells().dims;
        let mut out = FaceWalls::default();
        let mut events: Vec<Event> = Vec::new();
        let mut phases: Vec<(f64, Phase)> = Vec::new();
        let mut winding = vec![0i32; self.layer_count()];
        for d in 0..3 {
            let (e1, e2) = ((d + 1) % 3, (d + 2) % 3);
            let bins = Bins::new(self, d);
            for c in 0..3 {
                let mut fd = dims;
                fd[c] += 1;
                // Transverse coordinates: a face plane (integer) along `c`, a cell centre
                // (half-integer) along the others; likewise the face centres along the line.
                let at = |e: usize, n: usize| n as f64 + if e == c { 0.0 } else { 0.5 };
                let entries = &mut out.faces[c];
                for n2 in 0..fd[e2] {
                    for n1 in 0..fd[e1] {
                        let q = [at(e1, n1), at(e2, n2)];
                        bins.crossings(self, d, q, &mut events);
                        self.transitions(&mut events, &mut winding, &mut phases);
                        if phases.is_empty() && self.background() == Phase::Fluid {
                            continue;
                        }
                        let mut p = 0;
                        for i in 0..fd[d] {
                            let s = at(d, i);
                            // `phases[..p]` lie at or below `s`.
                            while p < phases.len() && phases[p].0 <= s {
                                p += 1;
                            }
                            let here = if p == 0 {
                                self.background()
                            } else {
                                phases[p - 1].1
                            };
                            let mut f = [0usize; 3];
                            f[d] = i;
                            f[e1] = n1;
                            f[e2] = n2;
                            let idx = (f[0] + fd[0] * (f[1] + fd[1] * f[2])) as u32;
                            if here == Phase::Solid {
                                entries.push((idx, [0.0; 6]));
                                continue;
                            }
                            let below = (p > 0).then(|| s - phases[p - 1].0);
                            let above = phases.get(p).map(|t| t.0 - s);
                            let mut arms = [NO_WALL; 6];
                            let mut any = false;
                            for (slot, dist) in [(2 * d, below), (2 * d + 1, above)] {
                                if let Some(x) = dist.filter(|&x| x <= 1.0) {
                                    arms[slot] = x as f32;
                                    any = true;
                                }
                            }
                            if any {
                                entries.push((idx, arms));
                            }
                        }
                    }
                }
            }
        }
        for entries in &mut out.faces {
            merge(entries);
        }
        out
    }

    /// The phase changes along a line from its crossings `events` (sorted here): `(position,
    /// phase above it)`, in order, only where the combined phase changes.
    fn transitions(
        &self,
        events: &mut [Event],
        winding: &mut [i32],
        phases: &mut Vec<(f64, Phase)>,
    ) {
        phases.clear();
        winding.fill(0);
        events.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut phase = self.background();
        let mut k = 0;
        while k < events.len() {
            let t = events[k].0;
            while k < events.len() && events[k].0 == t {
                winding[events[k].1 as usize] += events[k].2;
                k += 1;
            }
            let mut now = self.background();
            for (l, &w) in winding.iter().enumerate() {
                if w > 0 {
                    now = self.layer_phase(l);
                }
            }
            if now != phase {
                phases.push((t, now));
                phase = now;
            }
        }
    }
}

/// Entries of one component, sorted, one per face: a face in the solid on any line stays all
/// zeros, otherwise the arms of its lines combine.
fn merge(entries: &mut Vec<(u32, [f32; 6])>) {
    entries.sort_by_key(|e| e.0);
    let mut out: Vec<(u32, [f32; 6])> = Vec::with_capacity(entries.len());
    for &(idx, arms) in entries.iter() {
        match out.last_mut() {
            Some(last) if last.0 == idx => {
                let solid = |a: &[f32; 6]| a.iter().all(|&x| x == 0.0);
                if solid(&last.1) || solid(&arms) {
                    last.1 = [0.0; 6];
                } else {
                    for (a, b) in last.1.iter_mut().zip(arms) {
                        *a = a.min(b);
                    }
                }
            }
            _ => out.push((idx, arms)),
        }
    }
    *entries = out;
}

/// The triangles of every layer binned by the cell their projection's box reaches across the
/// lines along one axis (`(layer, triangle)` per bin, CSR).
struct Bins {
    dims: [usize; 2],
    start: Vec<u32>,
    items: Vec<(u32, u32)>,
}

impl Bins {
    fn new(cut: &CutCells, d: usize) -> Self {
        let box_dims = cut.cells().dims;
        let (e1, e2) = ((d + 1) % 3, (d + 2) % 3);
        // Lines lie at transverse coordinates 0..=n: bin `floor(q)` holds every triangle whose
        // closed box reaches it.
        let dims = [box_dims[e1] + 1, box_dims[e2] + 1];
        let reach = |lo: f64, hi: f64, n: usize| -> Option<(usize, usize)> {
            if hi < 0.0 || lo > (n - 1) as f64 || !(lo.is_finite() && hi.is_finite()) {
                return None;
            }
            let a = lo.floor().max(0.0) as usize;
            let b = (hi.floor().max(0.0) as usize).min(n - 1);
            Some((a, b))
        };
        let mut boxes = Vec::new();
        for l in 0..cut.layer_count() {
            let f = cut.layer(l);
            let pos = f.cell_positions();
            for (t, tri) in f.triangles().iter().enumerate() {
                let v = tri.map(|i| pos[i as usize]);
                let ext = |e: usize| {
                    let lo = v[0][e].min(v[1][e]).min(v[2][e]);
                    let hi = v[0][e].max(v[1][e]).max(v[2][e]);
                    (lo, hi)
                };
                let ((lo1, hi1), (lo2, hi2)) = (ext(e1), ext(e2));
                if let (Some(r1), Some(r2)) = (reach(lo1, hi1, dims[0]), reach(lo2, hi2, dims[1])) {
                    boxes.push((l as u32, t as u32, r1, r2));
                }
            }
        }
        let mut count = vec![0u32; dims[0] * dims[1] + 1];
        for &(_, _, (a1, b1), (a2, b2)) in &boxes {
            for j in a2..=b2 {
                for i in a1..=b1 {
                    count[i + dims[0] * j + 1] += 1;
                }
            }
        }
        for k in 1..count.len() {
            count[k] += count[k - 1];
        }
        let mut fill = count.clone();
        let mut items = vec![(0, 0); count[count.len() - 1] as usize];
        for &(l, t, (a1, b1), (a2, b2)) in &boxes {
            for j in a2..=b2 {
                for i in a1..=b1 {
                    let b = i + dims[0] * j;
                    items[fill[b] as usize] = (l, t);
                    fill[b] += 1;
                }
            }
        }
        Self {
            dims,
            start: count,
            items,
        }
    }

    /// The crossings of the line along `d` at transverse coordinates `q` with every layer.
    fn crossings(&self, cut: &CutCells, d: usize, q: [f64; 2], out: &mut Vec<Event>) {
        out.clear();
        let (e1, e2) = ((d + 1) % 3, (d + 2) % 3);
        let b = (q[0].floor() as usize).min(self.dims[0] - 1)
            + self.dims[0] * (q[1].floor() as usize).min(self.dims[1] - 1);
        for &(l, t) in &self.items[self.start[b] as usize..self.start[b + 1] as usize] {
            let f = cut.layer(l as usize);
            let tri = f.triangles()[t as usize];
            let pos = f.cell_positions();
            let v: [P3; 3] = tri.map(|i| pos[i as usize]);
            let p2 = |p: P3| [p[e1], p[e2]];
            // Edge k runs from vertex k to vertex k + 1; its function is evaluated from the
            // vertex with the smaller index, so both triangles beside it see the same value.
            let mut e = [0.0f64; 3];
            let mut sign = [0i32; 3];
            for k in 0..3 {
                let (ia, ib) = (tri[k], tri[(k + 1) % 3]);
                let (a, b, flip) = if ia < ib {
                    (p2(v[k]), p2(v[(k + 1) % 3]), 1.0)
                } else {
                    (p2(v[(k + 1) % 3]), p2(v[k]), -1.0)
                };
                let dd = [b[0] - a[0], b[1] - a[1]];
                let val = dd[0] * (q[1] - a[1]) - dd[1] * (q[0] - a[0]);
                // The sign at the perturbed point `q + (d, d^2)` where the value is zero.
                let s = if dd == [0.0, 0.0] {
                    // An edge along the line: the projection has no area.
                    0.0
                } else if val != 0.0 {
                    val.signum()
                } else if dd[1] != 0.0 {
                    -dd[1].signum()
                } else {
                    dd[0].signum()
                };
                e[k] = flip * val;
                sign[k] = (flip * s) as i32;
            }
            if sign[0] == 0 || sign[0] != sign[1] || sign[1] != sign[2] {
                continue;
            }
            // Barycentric weights: edge k is opposite vertex k + 2.
            let (w0, w1, w2) = (e[1], e[2], e[0]);
            let sum = w0 + w1 + w2;
            let x = if sum != 0.0 {
                ((w0 * v[0][d] + w1 * v[1][d] + w2 * v[2][d]) / sum).clamp(
                    v[0][d].min(v[1][d]).min(v[2][d]),
                    v[0][d].max(v[1][d]).max(v[2][d]),
                )
            } else {
                (v[0][d] + v[1][d] + v[2][d]) / 3.0
            };
            // Counter-clockwise in (e1, e2) is a normal along +d: moving +d leaves the region
            // the normals point out of.
            let out_of = match f.orientation() {
                Orientation::Outward => 1,
                Orientation::Inward => -1,
            };
            out.push((x, l, -sign[0] * out_of));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cutcell::shapes::{self, Tessellation};
    use crate::cutcell::{Layer, SmallCellParams};
    use crate::scene::voxelize::VoxelBox;

    /// The arms of a sphere of radius 4.3 cells (off the grid's planes) in a solid box, against
    /// the sphere: every arm that ends at the boundary ends on it (within the tessellation's
    /// sagitta, `h / 64` here, and its volume-matched radius), every face centre clearly inside
    /// with a neighbour clearly outside has the arm, and every face centre clearly outside reads
    /// solid. Then a fluid box layer over it (stacking): a face inside the box has no arm.
    #[test]
    fn arms_end_on_the_sphere_and_none_is_missed() {
        let h = 1.0;
        let (centre, radius) = ([6.13, 5.87, 6.41], 4.3);
        let sphere = shapes::sphere(centre, radius, Tessellation::for_spacing(h)).unwrap();
        let cells = VoxelBox {
            dims: [13, 12, 13],
            origin_m: [0.0; 3],
            spacing_m: h,
        };
        let layer = Layer {
            name: "sphere".into(),
            triangles: sphere.triangles().to_vec(),
            vertex_count: sphere.positions_m().len(),
            orientation: Orientation::Outward,
            inside: Phase::Fluid,
        };
        let mut cut =
            CutCells::new(cells, Phase::Solid, vec![layer], SmallCellParams::default()).unwrap();
        cut.full(&[sphere.positions_m()]).unwrap();
        let walls = cut.face_walls();
        let dist = |p: [f64; 3]| {
            ((p[0] - centre[0]).powi(2) + (p[1] - centre[1]).powi(2) + (p[2] - centre[2]).powi(2))
                .sqrt()
        };
        let mut arms = 0;
        for c in 0..3 {
            let mut fd = cells.dims;
            fd[c] += 1;
            let entry = |idx: usize| {
                walls.faces[c]
                    .binary_search_by_key(&(idx as u32), |e| e.0)
                    .ok()
                    .map(|k| walls.faces[c][k].1)
            };
            for idx in 0..fd.iter().product::<usize>() {
                let f = [idx % fd[0], (idx / fd[0]) % fd[1], idx / (fd[0] * fd[1])];
                let x: [f64; 3] =
                    std::array::from_fn(|a| f[a] as f64 + if a == c { 0.0 } else { 0.5 });
                let e = entry(idx);
                let r = dist(x);
                if r > radius + 0.05 {
                    assert_eq!(e, Some([0.0; 6]), "component {c}, face {f:?} at r = {r}");
                    continue;
                }
                if r < radius - 0.05 {
                    for slot in 0..6 {
                        let mut y = x;
                        y[slot / 2] += if slot % 2 == 0 { -1.0 } else { 1.0 };
                        let arm = e.map_or(NO_WALL, |a| a[slot]);
                        if dist(y) > radius + 0.05 {
                            assert!(arm <= 1.0, "component {c}, face {f:?}, arm {slot}");
                        }
                        if arm <= 1.0 {
                            let mut w = x;
                            w[slot / 2] += if slot % 2 == 0 { -1.0 } else { 1.0 } * arm as f64;
                            let off = dist(w) - radius;
                            assert!(
                                off.abs() < 0.02,
                                "component {c}, face {f:?}, arm {slot}: {off}"
                            );
                            arms += 1;
                        }
                    }
                }
            }
        }
        assert!(arms > 500, "{arms}");
    }

    /// A box tilted to the grid (exact planes): every arm's end lies on a face of the box to
    /// rounding; a box layer made solid inside a fluid background reads the other way round.
    #[test]
    fn arms_end_on_a_tilted_box_exactly() {
        let (s, c) = (0.3f64.sin(), 0.3f64.cos());
        let half = [3.2, 2.1, 2.6];
        // Off the grid's planes and cell centres (a face centre exactly on a face of the box
        // may go either way).
        let centre = [6.4, 6.1, 5.93];
        // Rotation about z by 0.3 rad; corner v has bit a set for the upper side along a.
        let rot = |p: [f64; 3]| [c * p[0] - s * p[1], s * p[0] + c * p[1], p[2]];
        let corners: [[f64; 3]; 8] = std::array::from_fn(|v| {
            let p: [f64; 3] =
                std::array::from_fn(|a| if v >> a & 1 == 1 { half[a] } else { -half[a] });
            let q = rot(p);
            std::array::from_fn(|a| centre[a] + q[a])
        });
        let mesh = shapes::hexahedron("box", corners).unwrap();
        let cells = VoxelBox {
            dims: [13, 13, 12],
            origin_m: [0.0; 3],
            spacing_m: 1.0,
        };
        // In the box's own frame, the signed distance outside the box.
        let local = |p: [f64; 3]| {
            let d: [f64; 3] = std::array::from_fn(|a| p[a] - centre[a]);
            [c * d[0] + s * d[1], -s * d[0] + c * d[1], d[2]]
        };
        let outside = |p: [f64; 3]| {
            let q = local(p);
            (0..3)
                .map(|a| q[a].abs() - half[a])
                .fold(f64::NEG_INFINITY, f64::max)
        };
        for (background, inside) in [(Phase::Solid, Phase::Fluid), (Phase::Fluid, Phase::Solid)] {
            let layer = Layer {
                name: "box".into(),
                triangles: mesh.triangles().to_vec(),
                vertex_count: mesh.positions_m().len(),
                orientation: Orientation::Outward,
                inside,
            };
            let mut cut =
                CutCells::new(cells, background, vec![layer], SmallCellParams::default()).unwrap();
            cut.full(&[mesh.positions_m()]).unwrap();
            let walls = cut.face_walls();
            let mut arms = 0;
            for comp in 0..3 {
                let mut fd = cells.dims;
                fd[comp] += 1;
                for &(idx, a) in &walls.faces[comp] {
                    let idx = idx as usize;
                    let f = [idx % fd[0], (idx / fd[0]) % fd[1], idx / (fd[0] * fd[1])];
                    let x: [f64; 3] =
                        std::array::from_fn(|k| f[k] as f64 + if k == comp { 0.0 } else { 0.5 });
                    let fluid_here = (outside(x) < 0.0) == (inside == Phase::Fluid);
                    if a == [0.0; 6] {
                        assert!(!fluid_here || outside(x).abs() < 1e-6, "{f:?}");
                        continue;
                    }
                    assert!(fluid_here, "{f:?}");
                    for (slot, &t) in a.iter().enumerate() {
                        if t <= 1.0 {
                            let mut w = x;
                            w[slot / 2] += if slot % 2 == 0 { -1.0 } else { 1.0 } * t as f64;
                            // f32 corners and an f32 distance: 1e-5 of a cell.
                            assert!(outside(w).abs() < 1e-5, "{f:?} arm {slot}: {}", outside(w));
                            arms += 1;
                        }
                    }
                }
            }
            assert!(arms > 300, "{arms}");
        }
    }
}
