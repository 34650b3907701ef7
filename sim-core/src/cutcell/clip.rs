//! Clipping primitives in cell units (every grid plane is an integer coordinate).
//!
//! The tie rule lives here and only here: a point whose coordinate equals a grid plane's belongs
//! to the side **below** the plane (`x <= m` is "left of plane m"), as if every grid plane lay an
//! infinitesimal above its nominal position. So cell `i` along an axis holds `(i, i+1]`, and
//! [`cell_of`] is `ceil(x) - 1`.

/// A point in cell units.
pub(crate) type P3 = [f64; 3];

/// Room for a polygon's vertices: a triangle clipped by the six planes of a cell gains at most one
/// vertex per plane (9); a sliver whose vertices rounding puts on alternating sides of a plane can
/// gain more, and vertices beyond the room are dropped (a sliver's area is at rounding level).
const MAX_VERTICES: usize = 16;

/// A small convex-or-not planar polygon (a clipped triangle), vertices in the triangle's order.
#[derive(Clone, Copy)]
pub(crate) struct Polygon {
    pub n: usize,
    pub v: [P3; MAX_VERTICES],
}

impl Polygon {
    pub const EMPTY: Polygon = Polygon {
        n: 0,
        v: [[0.0; 3]; MAX_VERTICES],
    };

    #[inline]
    fn push(&mut self, p: P3) {
        if self.n < MAX_VERTICES {
            self.v[self.n] = p;
            self.n += 1;
        }
    }

    /// Smallest and largest coordinate along `axis`.
    #[inline]
    pub fn extent(&self, axis: usize) -> (f64, f64) {
        let mut lo = f64::INFINITY;
        let mut hi = f64::NEG_INFINITY;
        for p in &self.v[..self.n] {
            lo = lo.min(p[axis]);
            hi = hi.max(p[axis]);
        }
        (lo, hi)
    }

    /// The area vector `1/2 sum p_m x p_m+1` (a fan from the first vertex) and the moment
    /// `integral of (x - x0) n_x dA` over the polygon.
    #[inline]
    pub fn area_and_x_moment(&self, x0: f64) -> ([f64; 3], f64) {
        let mut s = [0.0; 3];
        let mut moment = 0.0;
        if self.n < 3 {
            return (s, moment);
        }
        let o = self.v[0];
        for m in 1..self.n - 1 {
            let a = sub(self.v[m], o);
            let b = sub(self.v[m + 1], o);
            let c = [
                0.5 * (a[1] * b[2] - a[2] * b[1]),
                0.5 * (a[2] * b[0] - a[0] * b[2]),
                0.5 * (a[0] * b[1] - a[1] * b[0]),
            ];
            s[0] += c[0];
            s[1] += c[1];
            s[2] += c[2];
            // n_x dA is constant on the fan triangle, x is linear: its mean is the centroid's.
            let cx = (o[0] + self.v[m][0] + self.v[m + 1][0]) * (1.0 / 3.0) - x0;
            moment += c[0] * cx;
        }
        (s, moment)
    }
}

#[inline]
fn sub(a: P3, b: P3) -> P3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// The cell holding coordinate `x` under the tie rule: `ceil(x) - 1`.
#[inline]
pub(crate) fn cell_of(x: f64) -> f64 {
    crate::rounding::ceil(x) - 1.0
}

/// The point at which the segment from `a` towards `b` meets plane `axis = m` (the endpoints on
/// opposite sides or on it), interpolated from `a`, with its `axis` coordinate set to `m`
/// exactly. Callers choose `a` canonically (the smaller coordinate, or the smaller vertex index)
/// so that every polygon or section sharing the segment gets the same point, bit for bit.
#[inline]
fn towards(a: &P3, b: &P3, axis: usize, m: f64) -> P3 {
    let d = b[axis] - a[axis];
    let t = if d != 0.0 {
        ((m - a[axis]) / d).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let mut x = [
        a[0] + t * (b[0] - a[0]),
        a[1] + t * (b[1] - a[1]),
        a[2] + t * (b[2] - a[2]),
    ];
    x[axis] = m;
    x
}

/// [`towards`] from the endpoint with the smaller coordinate along `axis`.
#[inline]
fn on_plane(p: &P3, q: &P3, axis: usize, m: f64) -> P3 {
    if p[axis] <= q[axis] {
        towards(p, q, axis, m)
    } else {
        towards(q, p, axis, m)
    }
}

/// Splits `src` at plane `axis = m` into the part below (`<= m`, into `below`) and the part
/// above (`> m`, into `above`); the points on the plane that the cut creates go to both. Either
/// output may come out with fewer than three vertices (nothing on that side).
#[inline]
pub(crate) fn split(src: &Polygon, axis: usize, m: f64, below: &mut Polygon, above: &mut Polygon) {
    below.n = 0;
    above.n = 0;
    let n = src.n;
    for s in 0..n {
        let p = &src.v[s];
        let q = &src.v[if s + 1 == n { 0 } else { s + 1 }];
        let (bp, bq) = (p[axis] <= m, q[axis] <= m);
        if bp {
            below.push(*p);
        } else {
            above.push(*p);
        }
        if bp != bq {
            let x = on_plane(p, q, axis, m);
            below.push(x);
            above.push(x);
        }
    }
}

/// A polygon being clipped, in three buffers used in turn: a clip or a cut along x writes its
/// parts into the free buffers and the part kept becomes the current one, so no polygon is zeroed
/// or copied whole per piece (the cut cells clip every triangle of the moving surface for every
/// row it crosses, each frame the scene's surface moves). The arithmetic is [`split`]'s.
#[derive(Clone, Copy)]
pub(crate) struct Clipper {
    bufs: [Polygon; 3],
    cur: usize,
}

impl std::fmt::Debug for Clipper {
    // Scratch between calls: nothing worth printing.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Clipper")
    }
}

impl Default for Clipper {
    fn default() -> Self {
        Self {
            bufs: [Polygon::EMPTY; 3],
            cur: 0,
        }
    }
}

/// The buffer `s` and the two others, in turn.
#[inline]
fn parts(bufs: &mut [Polygon; 3], s: usize) -> (&mut Polygon, &mut Polygon, &mut Polygon) {
    let [p0, p1, p2] = bufs;
    match s {
        0 => (p0, p1, p2),
        1 => (p1, p2, p0),
        _ => (p2, p0, p1),
    }
}

impl Clipper {
    /// Starts on the triangle `a b c`.
    #[inline]
    pub fn start(&mut self, a: P3, b: P3, c: P3) {
        let p = &mut self.bufs[self.cur];
        p.v[0] = a;
        p.v[1] = b;
        p.v[2] = c;
        p.n = 3;
    }

    /// Starts on the polygon `p`.
    #[inline]
    pub fn start_from(&mut self, p: &Polygon) {
        let q = &mut self.bufs[self.cur];
        q.v[..p.n].copy_from_slice(&p.v[..p.n]);
        q.n = p.n;
    }

    /// The polygon as clipped so far.
    #[inline]
    pub fn poly(&self) -> &Polygon {
        &self.bufs[self.cur]
    }

    /// Keeps the part with `lo < coordinate <= hi` along `axis`.
    #[inline]
    pub fn clip_slab(&mut self, axis: usize, lo: f64, hi: f64) {
        let (min, max) = self.poly().extent(axis);
        if min > lo && max <= hi {
            return;
        }
        if max <= lo || min > hi {
            self.bufs[self.cur].n = 0;
            return;
        }
        if min <= lo {
            let (poly, below, above) = parts(&mut self.bufs, self.cur);
            split(poly, axis, lo, below, above);
            self.cur = (self.cur + 2) % 3;
            if self.bufs[self.cur].n < 3 {
                self.bufs[self.cur].n = 0;
                return;
            }
        }
        if max > hi {
            let (poly, below, above) = parts(&mut self.bufs, self.cur);
            split(poly, axis, hi, below, above);
            self.cur = (self.cur + 1) % 3;
            if self.bufs[self.cur].n < 3 {
                self.bufs[self.cur].n = 0;
            }
        }
    }

    /// Cuts the polygon along x into cells `(c, c+1]` and calls `f(c, piece)` for every cell
    /// `c < nx` it reaches, with `c = -1` for its part left of the box (`x <= 0`); with `forced =
    /// Some(c)` the whole polygon goes to cell `c` (a triangle in an x-plane under the tie rule's
    /// exception). The polygon is used up.
    #[inline]
    pub fn split_along_x(
        &mut self,
        nx: usize,
        forced: Option<f64>,
        mut f: impl FnMut(i64, &Polygon),
    ) {
        let nxf = nx as f64;
        if let Some(c) = forced {
            if c < nxf {
                f((c as i64).max(-1), self.poly());
            }
            return;
        }
        let (xmin, xmax) = self.poly().extent(0);
        let mut c = cell_of(xmin);
        let last = cell_of(xmax);
        if c >= nxf {
            return;
        }
        if c < 0.0 {
            if last < 0.0 {
                f(-1, self.poly());
                return;
            }
            let (poly, below, above) = parts(&mut self.bufs, self.cur);
            split(poly, 0, 0.0, below, above);
            f(-1, below);
            self.cur = (self.cur + 2) % 3;
            c = 0.0;
        }
        while c < last && c < nxf {
            let (poly, below, above) = parts(&mut self.bufs, self.cur);
            split(poly, 0, c + 1.0, below, above);
            f(c as i64, below);
            self.cur = (self.cur + 2) % 3;
            c += 1.0;
        }
        if c < nxf {
            f(c as i64, self.poly());
        }
    }
}

/// A directed segment on a grid plane.
#[derive(Clone, Copy)]
pub(crate) struct Segment {
    pub p: P3,
    pub q: P3,
}

/// The cross-section of triangle `v` (vertex indices `ids`) with plane `axis = m`: the segment
/// from the point on the edge that goes from above the plane to below it (in the triangle's
/// order) to the point on the edge that goes from below to above. For a triangle whose normal
/// points out of the enclosed region, the region lies to the left of the segment in the plane's
/// right-handed coordinates `(axis + 1, axis + 2)`. `None` when the triangle does not straddle
/// the plane (every vertex on one side under the tie rule).
#[inline]
pub(crate) fn plane_section(ids: &[u32; 3], v: &[P3; 3], axis: usize, m: f64) -> Option<Segment> {
    let above = [v[0][axis] > m, v[1][axis] > m, v[2][axis] > m];
    if above[0] == above[1] && above[1] == above[2] {
        return None;
    }
    let mut down = None;
    let mut up = None;
    for e in 0..3 {
        let f = if e == 2 { 0 } else { e + 1 };
        if above[e] && !above[f] {
            down = Some(edge_point(ids[e], &v[e], ids[f], &v[f], axis, m));
        } else if !above[e] && above[f] {
            up = Some(edge_point(ids[e], &v[e], ids[f], &v[f], axis, m));
        }
    }
    match (down, up) {
        (Some(p), Some(q)) => Some(Segment { p, q }),
        _ => None,
    }
}

/// [`towards`] from the endpoint with the smaller vertex index: the two triangles sharing the
/// edge get the same point, bit for bit, so the cross-section polylines close exactly.
#[inline]
fn edge_point(ia: u32, a: &P3, ib: u32, b: &P3, axis: usize, m: f64) -> P3 {
    if ia <= ib {
        towards(a, b, axis, m)
    } else {
        towards(b, a, axis, m)
    }
}

/// The part of `s` with `lo < coordinate <= hi` along `axis`, direction kept.
#[inline]
pub(crate) fn clip_segment(s: &Segment, axis: usize, lo: f64, hi: f64) -> Option<Segment> {
    let (a, b, flipped) = if s.p[axis] <= s.q[axis] {
        (s.p, s.q, false)
    } else {
        (s.q, s.p, true)
    };
    if b[axis] <= lo || a[axis] > hi {
        return None;
    }
    let at = |m: f64| towards(&a, &b, axis, m);
    let start = if a[axis] > lo { a } else { at(lo) };
    let end = if b[axis] <= hi { b } else { at(hi) };
    Some(if flipped {
        Segment { p: end, q: start }
    } else {
        Segment { p: start, q: end }
    })
}

/// The tie rule's exception: when triangle `v` lies in a grid plane normal to `axis` (its three
/// coordinates there equal and integral) with the enclosed region on the plane's upper side (its
/// normal, times `sign` to make it outward, pointing down), that plane. Such a triangle belongs
/// to the cell above the plane, on its fluid side, instead of the one below; and the face in the
/// plane is open only where the region lies on both sides of it.
#[inline]
pub(crate) fn flat_below_region(v: &[P3; 3], axis: usize, sign: f64) -> Option<f64> {
    let m = v[0][axis];
    if v[1][axis] != m || v[2][axis] != m || m != m.round() {
        return None;
    }
    let (b, c) = ((axis + 1) % 3, (axis + 2) % 3);
    let n = (v[1][b] - v[0][b]) * (v[2][c] - v[0][c]) - (v[1][c] - v[0][c]) * (v[2][b] - v[0][b]);
    (sign * n < 0.0).then_some(m)
}
