//! The hysteroscope's geometry in the grid: which part of the scope a cell centre lies in, and
//! the rows and row spans of a grid the sheath can touch.
//!
//! Geometry (organ frame): the sheath is a cylinder of the outer radius around the axis through
//! the tip along the view direction `d`, from the tip back 200 mm (out of every grid). A cell
//! belongs to it when its centre lies inside (centre rule). With `s` the centre's axial coordinate
//! from the tip (negative behind it) and `r` its distance from the axis:
//! - the **tip layer** (`-h < s <= 0`) holds the inflow port (chosen by [`super::ports`]);
//! - the **hole band** (`-far <= s <= -near`) holds the outflow holes;
//! - the rest is sheath (a wall at rest).

use super::desc::ScopeSpec;
use crate::mesh::cross;

/// Sheath length behind the tip, m (longer than any grid).
pub const SHEATH_LENGTH_M: f64 = 0.2;

/// The scope's dimensions in SI units, from the scene file's `[scope]` (the one conversion).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScopeDims {
    /// Outer radius of the sheath, m.
    pub radius_m: f64,
    /// Hole band, m behind the tip: `[near, far]`.
    pub holes_m: [f64; 2],
    /// The inflow channel's area, m^2.
    pub channel_area_m2: f64,
}

impl ScopeDims {
    /// The dimensions of `spec`.
    pub fn of(spec: &ScopeSpec) -> Self {
        Self {
            radius_m: 0.5e-3 * spec.sheath_outer_diameter_mm,
            holes_m: spec.outflow_holes_from_tip_mm.map(|v| v * 1e-3),
            channel_area_m2: spec.inflow_channel_area_mm2 * 1e-6,
        }
    }
}

/// The scope pose the ports were built for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScopeGeometry {
    /// Tip, m.
    pub tip_m: [f64; 3],
    /// Unit view direction.
    pub dir: [f64; 3],
    /// Outer radius of the sheath, m.
    pub radius_m: f64,
    /// Hole band, m behind the tip: `[near, far]`.
    pub holes_m: [f64; 2],
}

/// Where a cell centre lies relative to the scope.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ScopePart {
    /// Not in the sheath.
    None,
    /// In the tip layer.
    Tip,
    /// In the hole band.
    Holes,
    /// Elsewhere in the sheath.
    Sheath,
}

impl ScopeGeometry {
    /// Axial coordinate `s` and axis distance `r` of a point.
    #[inline]
    pub fn axial_radial(&self, p: [f64; 3]) -> (f64, f64) {
        let q = [
            p[0] - self.tip_m[0],
            p[1] - self.tip_m[1],
            p[2] - self.tip_m[2],
        ];
        let s = q[0] * self.dir[0] + q[1] * self.dir[1] + q[2] * self.dir[2];
        let r2 = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] - s * s).max(0.0);
        (s, r2.sqrt())
    }

    /// The part of the scope a cell centre `p` lies in, for cells of edge `h`.
    #[inline]
    pub fn part(&self, p: [f64; 3], h: f64) -> ScopePart {
        let (s, r) = self.axial_radial(p);
        if r > self.radius_m || !(-SHEATH_LENGTH_M..=0.0).contains(&s) {
            ScopePart::None
        } else if s > -h {
            ScopePart::Tip
        } else if s <= -self.holes_m[0] && s >= -self.holes_m[1] {
            ScopePart::Holes
        } else {
            ScopePart::Sheath
        }
    }

    /// The rows `j` (inclusive) of the slab of cell centres at height `z` whose centres may lie
    /// in the sheath, for a grid whose row `j` has its centres at `y0 + (j + 0.5) h`; `None` if
    /// none can. Conservative: a centre in the sheath lies within the radius of an axis point,
    /// so that point is within the radius in z and in y (the caller tests each row).
    pub fn slab_rows(&self, z: f64, y0: f64, h: f64, ny: usize) -> Option<(usize, usize)> {
        let (d, r) = (self.dir, self.radius_m);
        // The axis points `tip + s d`, `-L <= s <= 0`, within the radius of the slab.
        let (mut lo, mut hi) = (-SHEATH_LENGTH_M, 0.0f64);
        if d[2].abs() > 1e-12 {
            let (a, b) = (
                (z - r - self.tip_m[2]) / d[2],
                (z + r - self.tip_m[2]) / d[2],
            );
            lo = lo.max(a.min(b));
            hi = hi.min(a.max(b));
        } else if (self.tip_m[2] - z).abs() > r {
            return None;
        }
        if lo > hi {
            return None;
        }
        let (ya, yb) = (self.tip_m[1] + lo * d[1], self.tip_m[1] + hi * d[1]);
        let to_row = |y: f64| (y - y0) / h - 0.5;
        let (a, b) = (
            to_row(ya.min(yb) - r).floor() - 1.0,
            to_row(ya.max(yb) + r).ceil() + 1.0,
        );
        if b < 0.0 || a > ny as f64 - 1.0 {
            return None;
        }
        Some((a.max(0.0) as usize, b.min(ny as f64 - 1.0) as usize))
    }

    /// The x-interval (cell indices, inclusive) of row `(y, z)` (centres in m) whose centres may
    /// lie in the sheath, for a grid whose cell `i` has its centre at `x0 + (i + 0.5) h`;
    /// `None` if the row misses it. Conservative (the caller tests each centre).
    pub fn row_span(&self, y: f64, z: f64, x0: f64, h: f64, nx: usize) -> Option<(usize, usize)> {
        let d = self.dir;
        let (b, c) = (y - self.tip_m[1], z - self.tip_m[2]);
        let e = b * d[1] + c * d[2];
        let (qa, qb, qc) = (
            1.0 - d[0] * d[0],
            -2.0 * d[0] * e,
            b * b + c * c - e * e - self.radius_m * self.radius_m,
        );
        // x' = x - tip_x: a x'^2 + b x' + c <= 0 (distance to the line) and -L <= x' d0 + e <= 0.
        let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
        if qa > 1e-12 {
            let disc = qb * qb - 4.0 * qa * qc;
            if disc < 0.0 {
                return None;
            }
            let sq = disc.sqrt();
            lo = (-qb - sq) / (2.0 * qa);
            hi = (-qb + sq) / (2.0 * qa);
        } else if qc > 0.0 {
            return None;
        }
        if d[0].abs() > 1e-12 {
            let (s0, s1) = ((-SHEATH_LENGTH_M - e) / d[0], -e / d[0]);
            lo = lo.max(s0.min(s1));
            hi = hi.min(s0.max(s1));
        } else if !(-SHEATH_LENGTH_M..=0.0).contains(&e) {
            return None;
        }
        if lo > hi {
            return None;
        }
        let to_cell = |x: f64| (x + self.tip_m[0] - x0) / h - 0.5;
        let (a, z) = (to_cell(lo).floor() - 1.0, to_cell(hi).ceil() + 1.0);
        if z < 0.0 || a > nx as f64 - 1.0 {
            return None;
        }
        Some((a.max(0.0) as usize, z.min(nx as f64 - 1.0) as usize))
    }
}

/// The sheath as a closed triangle surface (normals outward) for the cut-cell layers: the
/// cylinder of [`ScopeGeometry`] with a flat tip, from the tip back [`SHEATH_LENGTH_M`], placed
/// rigidly at a pose. Tessellated once for the grid spacing `h` (in the scope's own frame) with
/// the rule of [`crate::cutcell::shapes::Tessellation::for_spacing`]: `n` sides of at most
/// `h / 2`, their circumradius scaled so the polygon's cross-section is the circle's (so its
/// volume is `pi r^2 L`), rings at most `4 h` apart along the axis and one at each end of the hole
/// band, and on the tip a ring at the inflow channel's radius (area matched too). Placing it
/// writes the vertices into the same buffer (no allocation after [`SheathMesh::new`]).
#[derive(Debug, Clone)]
pub struct SheathMesh {
    /// Vertices in the scope's frame: `[radial u, radial w, axial s]` (`s <= 0` behind the tip).
    local: Vec<[f64; 3]>,
    triangles: Vec<[u32; 3]>,
    positions_m: Vec<[f32; 3]>,
    /// The pose the positions are at (`None`: parked out of the grid).
    placed: Option<Option<ScopeGeometry>>,
}

impl SheathMesh {
    /// The sheath of `dims` for cells of edge `spacing_m`.
    pub fn new(dims: ScopeDims, spacing_m: f64) -> Self {
        use std::f64::consts::PI;
        let ScopeDims {
            radius_m,
            holes_m,
            channel_area_m2,
        } = dims;
        let max_edge = 0.5 * spacing_m;
        let n = (2.0 * PI * radius_m / max_edge).ceil().max(12.0) as usize;
        // The n-gon of circumradius r has area n r^2 sin(2 pi / n) / 2.
        let area_scale = (2.0 * PI / (n as f64 * (2.0 * PI / n as f64).sin())).sqrt();
        let channel_r = (channel_area_m2 / PI).sqrt().min(0.9 * radius_m);
        // Ring positions from the far end to the tip, with the hole band's ends among them.
        let mut marks = vec![-SHEATH_LENGTH_M];
        for s in [-holes_m[1], -holes_m[0]] {
            if s > -SHEATH_LENGTH_M && s < 0.0 {
                marks.push(s);
            }
        }
        marks.push(0.0);
        marks.sort_by(f64::total_cmp);
        marks.dedup();
        let step = 8.0 * max_edge;
        let mut rings = vec![marks[0]];
        for w in marks.windows(2) {
            let parts = ((w[1] - w[0]) / step).ceil().max(1.0) as usize;
            for p in 1..=parts {
                rings.push(w[0] + (w[1] - w[0]) * p as f64 / parts as f64);
            }
        }
        let ring = |r: f64, s: f64, local: &mut Vec<[f64; 3]>| {
            for i in 0..n {
                let th = 2.0 * PI * i as f64 / n as f64;
                local.push([r * th.cos(), r * th.sin(), s]);
            }
        };
        let mut local = Vec::with_capacity((rings.len() + 1) * n + 2);
        for &s in &rings {
            ring(area_scale * radius_m, s, &mut local);
        }
        let inner = local.len() as u32;
        ring(area_scale * channel_r, 0.0, &mut local);
        let (tip, far) = (local.len() as u32, local.len() as u32 + 1);
        local.push([0.0, 0.0, 0.0]);
        local.push([0.0, 0.0, -SHEATH_LENGTH_M]);
        let at = |ring: usize, i: usize| (ring * n + i % n) as u32;
        let top = rings.len() - 1;
        let mut triangles = Vec::with_capacity(2 * n * rings.len() + 2 * n);
        for r in 0..top {
            for i in 0..n {
                triangles.push([at(r, i), at(r, i + 1), at(r + 1, i + 1)]);
                triangles.push([at(r, i), at(r + 1, i + 1), at(r + 1, i)]);
            }
        }
        let ch = |i: usize| inner + (i % n) as u32;
        for i in 0..n {
            // The tip: the channel's disk fanned from the centre, the annulus to the side.
            triangles.push([tip, ch(i), ch(i + 1)]);
            triangles.push([ch(i), at(top, i), at(top, i + 1)]);
            triangles.push([ch(i), at(top, i + 1), ch(i + 1)]);
            triangles.push([far, at(0, i + 1), at(0, i)]);
        }
        let positions_m = vec![[0.0; 3]; local.len()];
        Self {
            local,
            triangles,
            positions_m,
            placed: None,
        }
    }

    /// Its triangles (normals out of the sheath).
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }
    /// Its vertices where last placed.
    pub fn positions_m(&self) -> &[[f32; 3]] {
        &self.positions_m
    }

    /// Places the sheath at `scope`'s pose, or with none parks it `parked_m` (a point out of the
    /// grid, the sheath running away from it along +z); whether its vertices moved.
    pub fn place(&mut self, scope: Option<&ScopeGeometry>, parked_m: [f64; 3]) -> bool {
        if self.placed == Some(scope.copied()) {
            return false;
        }
        self.placed = Some(scope.copied());
        let (tip, a) = match scope {
            Some(sc) => (sc.tip_m, sc.dir),
            None => (parked_m, [0.0, 0.0, -1.0]),
        };
        // (u, w, a) right-handed, u across the axis's least component.
        let least = (0..3)
            .min_by(|&i, &j| a[i].abs().total_cmp(&a[j].abs()))
            .unwrap_or(0);
        let mut e = [0.0; 3];
        e[least] = 1.0;
        let u = unit(cross(a, e)).unwrap_or([1.0, 0.0, 0.0]);
        let w = cross(a, u);
        for (p, l) in self.positions_m.iter_mut().zip(&self.local) {
            *p = std::array::from_fn(|k| (tip[k] + l[0] * u[k] + l[1] * w[k] + l[2] * a[k]) as f32);
        }
        true
    }
}

/// Unit normal of face `f` (0..6: -x, +x, -y, +y, -z, +z) of a cell.
pub const FACE_NORMALS: [[f64; 3]; 6] = [
    [-1.0, 0.0, 0.0],
    [1.0, 0.0, 0.0],
    [0.0, -1.0, 0.0],
    [0.0, 1.0, 0.0],
    [0.0, 0.0, -1.0],
    [0.0, 0.0, 1.0],
];

/// Normalises a direction; `None` for a zero or non-finite one.
pub fn unit(v: [f64; 3]) -> Option<[f64; 3]> {
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    (n.is_finite() && n > 1e-9).then(|| v.map(|c| c / n))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every cell whose centre lies in the sheath is in a row that `slab_rows` and `row_span`
    /// keep, for random poses (tilted, axis-parallel, tip in and out of the grid).
    #[test]
    fn slab_rows_and_row_spans_hold_every_sheath_cell() {
        let mut rng = fastrand::Rng::with_seed(7);
        let (h, n) = (1e-3, [24usize, 20, 28]);
        let origin = [-0.012, -0.010, -0.014];
        let mut inside = 0;
        for pose in 0..200 {
            let mut dir: [f64; 3] = std::array::from_fn(|_| 2.0 * rng.f64() - 1.0);
            if pose % 5 == 0 {
                dir = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]][pose % 3];
            }
            let Some(dir) = unit(dir) else { continue };
            let sc = ScopeGeometry {
                tip_m: std::array::from_fn(|_| 0.03 * (rng.f64() - 0.5)),
                dir,
                radius_m: 1e-3 + 3e-3 * rng.f64(),
                holes_m: [3e-3, 12e-3],
            };
            for k in 0..n[2] {
                let z = origin[2] + (k as f64 + 0.5) * h;
                let rows = sc.slab_rows(z, origin[1], h, n[1]);
                for j in 0..n[1] {
                    let y = origin[1] + (j as f64 + 0.5) * h;
                    let span = sc.row_span(y, z, origin[0], h, n[0]);
                    for i in 0..n[0] {
                        let x = origin[0] + (i as f64 + 0.5) * h;
                        if sc.part([x, y, z], h) == ScopePart::None {
                            continue;
                        }
                        inside += 1;
                        let held = rows.is_some_and(|(a, b)| (a..=b).contains(&j))
                            && span.is_some_and(|(a, b)| (a..=b).contains(&i));
                        assert!(held, "pose {pose}: cell ({i}, {j}, {k}) of {sc:?} missed");
                    }
                }
            }
        }
        assert!(inside > 10_000, "only {inside} sheath cells tested");
    }
}
