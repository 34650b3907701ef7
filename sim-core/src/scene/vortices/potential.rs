//! One Rankine vortex in closed form ([`Vortex`]) and the vortices' vector potential on the grid
//! nodes (`docs/particles.md`; the field of many in [`super::VortexField`]): each vortex adds `g(s) Psi(r) n` at the nodes of its support, four
//! consecutive nodes of a row at a time (SSE2, the x86-64 baseline; element-wise elsewhere).
//!
//! A vortex touches a few dozen nodes in short rows (a core of one or two cells), so the work is
//! per row, not per node: a row is skipped or narrowed to the support by one quadratic, and its
//! nodes go through one branch-free four-lane kernel whose lanes outside the row, the support or
//! `node_mask` add zero.

use crate::mesh::{cross, dot};
use crate::simd::v4 as lane;

/// Rankine's profile holds exactly out to this many core radii.
pub const RANKINE_EXACT_CORES: f64 = 1.5;
/// The tangential velocity is zero from this many core radii.
pub const CUTOFF_CORES: f64 = 2.5;
/// The axial window is 1 up to this many core radii from the centre plane.
pub const AXIAL_FLAT_CORES: f64 = 1.0;
/// The axial window is zero from this many core radii.
pub const AXIAL_END_CORES: f64 = 2.0;

/// One Rankine vortex.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Vortex {
    /// Centre, m.
    pub centre_m: [f64; 3],
    /// Unit axis (the vorticity's direction).
    pub axis: [f64; 3],
    /// Circulation, m^2/s (positive: counter-clockwise about the axis).
    pub circulation_m2_s: f64,
    /// Core radius, m.
    pub core_radius_m: f64,
}

impl Vortex {
    /// Tangential speed at `r_m` from the axis in the centre plane (m/s): Rankine's out to
    /// `RANKINE_EXACT_CORES`, tapered to zero at `CUTOFF_CORES`.
    pub fn tangential_speed_m_s(&self, r_m: f64) -> f64 {
        let big_r = self.core_radius_m;
        let r = r_m.abs() / big_r;
        let k = self.circulation_m2_s / (2.0 * std::f64::consts::PI * big_r);
        let rankine = if r <= 1.0 { r } else { 1.0 / r };
        let (w, dw) = taper(r, RANKINE_EXACT_CORES, CUTOFF_CORES);
        // v = -(Psi w)' with Psi' = -rankine (in units of Gamma / (2 pi R)).
        k * (rankine * w - rankine_psi(r) * dw)
    }

    /// The axial window at `s_m` from the centre plane.
    pub fn axial_window(&self, s_m: f64) -> f64 {
        let r = self.core_radius_m;
        taper(s_m.abs(), AXIAL_FLAT_CORES * r, AXIAL_END_CORES * r).0
    }

    /// `(s, r_vec, r)`: the axial coordinate and the radial vector of `p`.
    fn frame(&self, p: [f64; 3]) -> (f64, [f64; 3], f64) {
        let d: [f64; 3] = std::array::from_fn(|a| p[a] - self.centre_m[a]);
        let s = dot(d, self.axis);
        let rv: [f64; 3] = std::array::from_fn(|a| d[a] - s * self.axis[a]);
        (s, rv, dot(rv, rv).sqrt())
    }

    /// The vortex's velocity at `p` (m/s), closed form.
    pub fn velocity_m_s(&self, p: [f64; 3]) -> [f64; 3] {
        let (s, rv, r) = self.frame(p);
        if r == 0.0 {
            return [0.0; 3];
        }
        let m = self.axial_window(s) * self.tangential_speed_m_s(r) / r;
        cross(self.axis, rv).map(|v| v * m)
    }

    /// The vector potential's magnitude at `p`, m^2/s (`A = phi n`, `curl A` = the velocity).
    pub fn potential_m2_s(&self, p: [f64; 3]) -> f64 {
        let (s, _, r) = self.frame(p);
        let rr = r / self.core_radius_m;
        let k = self.circulation_m2_s / (2.0 * std::f64::consts::PI);
        self.axial_window(s) * k * radial_potential(rr)
    }

    /// Half extent (m) of the vortex's support along each axis.
    pub fn half_extent_m(&self) -> [f64; 3] {
        let (l, r) = (
            AXIAL_END_CORES * self.core_radius_m,
            CUTOFF_CORES * self.core_radius_m,
        );
        self.axis
            .map(|n| l * n.abs() + r * (1.0 - n * n).max(0.0).sqrt())
    }
}

/// Intervals of the potential's table over `q = r^2 / R^2` in `[0, CUTOFF_CORES^2]` (a power of
/// two: the index needs no bounds check).
const TABLE_SIZE: usize = 512;

/// `(Psi w, its increment to the next entry)` over `Gamma / (2 pi)` at `q = r^2/R^2` (`w` the
/// radial taper): linear interpolation in `q`. The last interval ends at the cut-off (zero).
pub(super) type Table = [[f32; 2]; TABLE_SIZE];

/// Rankine's stream function over `Gamma / (2 pi)`, zero at the cutoff: `r` in core radii.
#[inline]
pub(super) fn rankine_psi(r: f64) -> f64 {
    if r <= 1.0 {
        0.5 * (1.0 - r * r) + CUTOFF_CORES.ln()
    } else {
        (CUTOFF_CORES / r).ln()
    }
}

/// Smoothstep taper: 1 for `x <= a`, 0 for `x >= b`, C1 in between; and its derivative.
#[inline]
pub(super) fn taper(x: f64, a: f64, b: f64) -> (f64, f64) {
    if x <= a {
        (1.0, 0.0)
    } else if x >= b {
        (0.0, 0.0)
    } else {
        let t = (x - a) / (b - a);
        (
            1.0 - t * t * (3.0 - 2.0 * t),
            -6.0 * t * (1.0 - t) / (b - a),
        )
    }
}

/// The radial factor `Psi(r) w(r)` over `Gamma / (2 pi)`, `r` in core radii.
#[inline]
pub(super) fn radial_potential(r: f64) -> f64 {
    rankine_psi(r) * taper(r, RANKINE_EXACT_CORES, CUTOFF_CORES).0
}

/// The table of [`radial_potential`] over `q`.
pub(super) fn table() -> Box<Table> {
    let qmax = CUTOFF_CORES * CUTOFF_CORES;
    let at = |i: usize| radial_potential((qmax * i as f64 / TABLE_SIZE as f64).sqrt());
    Box::new(std::array::from_fn(|i| {
        let (a, b) = (at(i) as f32, at(i + 1) as f32);
        [a, b - a]
    }))
}

/// A vortex's support in grid units (node `(i, j, k)` at `(i, j, k)`, lengths in cells, f32 from
/// here on): the box of nodes that can lie in it and what the node kernel needs.
#[derive(Debug, Clone, Copy)]
pub(super) struct Support {
    /// The box's lowest and highest node, inclusive.
    lo: [usize; 3],
    hi: [usize; 3],
    /// Node `lo` minus the centre.
    offset: [f32; 3],
    axis: [f32; 3],
    /// The axis times `Gamma / (2 pi)`.
    amp_axis: [f32; 3],
    /// `1 / R^2`, the cut-off cylinder's radius squared, the axial window's flat part and end,
    /// and one over the taper's length.
    inv_core2: f32,
    cut2: f32,
    flat: f32,
    end: f32,
    inv_taper: f32,
    /// `1 - n_x^2` (a row's squared distance from the axis is `a x^2 - 2 s0 n_x x + ...`), its
    /// inverse, and `1 / n_x`.
    a: f32,
    inv_a: f32,
    inv_nx: f32,
}

impl Support {
    /// `None` when no node of the grid (`dims` cells, origin `origin`, spacing `1 / inv_h`) can
    /// lie in it, or the vortex has no circulation.
    pub(super) fn of(v: &Vortex, origin: [f64; 3], inv_h: f64, dims: [usize; 3]) -> Option<Self> {
        if v.circulation_m2_s == 0.0 {
            return None;
        }
        let ext = v.half_extent_m();
        let (mut lo, mut hi, mut offset) = ([0usize; 3], [0usize; 3], [0f32; 3]);
        for a in 0..3 {
            let c = (v.centre_m[a] - origin[a]) * inv_h;
            let (l, u) = (c - ext[a] * inv_h, (c + ext[a] * inv_h).min(dims[a] as f64));
            // Also false on NaN (a NaN centre or axis leaves `l` NaN).
            if !(u >= 0.0 && l <= u) {
                return None;
            }
            // Both >= 0 here: the conversions truncate (floor), the first rounds up (no libm
            // call for ceil on the baseline target).
            let l = l.max(0.0);
            let li = l as usize;
            lo[a] = li + usize::from((li as f64) < l);
            hi[a] = u as usize;
            if lo[a] > hi[a] {
                return None;
            }
            offset[a] = (lo[a] as f64 - c) as f32;
        }
        let core = v.core_radius_m * inv_h;
        let axis = v.axis.map(|x| x as f32);
        let amp = (v.circulation_m2_s / (2.0 * std::f64::consts::PI)) as f32;
        let a = 1.0 - axis[0] * axis[0];
        let (flat, end) = (AXIAL_FLAT_CORES * core, AXIAL_END_CORES * core);
        Some(Self {
            lo,
            hi,
            offset,
            axis,
            amp_axis: axis.map(|x| x * amp),
            inv_core2: (1.0 / (core * core)) as f32,
            cut2: (CUTOFF_CORES * CUTOFF_CORES * core * core) as f32,
            flat: flat as f32,
            end: end as f32,
            inv_taper: (1.0 / (end - flat)) as f32,
            a,
            inv_a: 1.0 / a,
            inv_nx: 1.0 / axis[0],
        })
    }

    /// The nodes `first..=last` (counted from `lo`'s `i`) of the row of nodes `ia..=ib` (the same
    /// count) that can lie in the support, the row's axial offset and squared distance from the
    /// centre in y and z being `s0` and `e0`: within the cut-off cylinder and `|s| < end` of the
    /// centre plane. The margin is a thousandth of a cell (the f32 roots' error is far smaller, and
    /// the potential vanishes with zero slope at both edges); the kernel's test decides. `None`
    /// when no node can.
    #[inline]
    fn row_span(&self, s0: f32, e0: f32, ia: usize, ib: usize) -> Option<(usize, usize)> {
        // Along the row, x from the centre: r^2(x) = a x^2 - 2 s0 n_x x + e0 - s0^2 and
        // s(x) = s0 + n_x x. Rows nearly along the axis are narrowed by the axial window alone.
        let nx = self.axis[0];
        let (mut lo, mut hi) = (f32::NEG_INFINITY, f32::INFINITY);
        if self.a > 1e-3 {
            let beta = s0 * nx;
            let disc = beta * beta - self.a * (e0 - s0 * s0 - self.cut2);
            if disc.is_nan() || disc < 0.0 {
                return None;
            }
            let sq = disc.sqrt();
            (lo, hi) = ((beta - sq) * self.inv_a, (beta + sq) * self.inv_a);
        }
        if nx.abs() > 1e-6 {
            let (x1, x2) = (
                (-self.end - s0) * self.inv_nx,
                (self.end - s0) * self.inv_nx,
            );
            let (a, b) = if x1 < x2 { (x1, x2) } else { (x2, x1) };
            lo = if a > lo { a } else { lo };
            hi = if b < hi { b } else { hi };
        } else if s0.abs() >= self.end {
            return None;
        }
        const MARGIN_CELLS: f32 = 1e-3;
        // Clamped to the row (a NaN bound gives the row's end): both in `[ia, ib]`, finite.
        let (a, b) = (lo - self.offset[0] - MARGIN_CELLS, ia as i32 as f32);
        let first = if a > b { a } else { b };
        let (a, b) = (hi - self.offset[0] + MARGIN_CELLS, ib as i32 as f32);
        let last = if a < b { a } else { b };
        if first > last {
            return None;
        }
        // Both >= 0: truncation floors, the first rounds up.
        let (f, l) = (first as i32, last as i32);
        let f = f + i32::from((f as f32) < first);
        (f <= l).then_some((f as usize, l as usize))
    }
}

/// What the potential's evaluation over a range of node layers reads.
pub(super) struct Slab<'a> {
    pub supports: &'a [Support],
    pub node_mask: &'a [u8],
    /// Per row of nodes (`j + (ny + 1) k`): the first and last `i` of its nodes in `node_mask`.
    pub row_nodes: &'a [(u32, u32)],
    pub table: &'a Table,
    pub dims: [usize; 3],
}

impl Slab<'_> {
    /// Adds every vortex's potential at the nodes of `node_mask` in the node layers `layers`
    /// to `pot` (those layers' nodes, the first at node `offset`); returns the nodes evaluated.
    /// Eight lanes where the CPU has AVX2 and FMA.
    pub(super) fn potential(
        &self,
        layers: std::ops::Range<usize>,
        offset: usize,
        pot: [&mut [f32]; 3],
    ) -> usize {
        #[cfg(target_arch = "x86_64")]
        if crate::simd::avx2_fma() && pot[0].len() >= 8 {
            // SAFETY: the CPU has AVX2 and FMA (checked above).
            return unsafe { self.potential_avx2(layers, offset, pot) };
        }
        self.potential_sse(layers, offset, pot)
    }

    /// [`Slab::potential`] four lanes at a time, each row narrowed to the support first.
    pub(super) fn potential_sse(
        &self,
        layers: std::ops::Range<usize>,
        offset: usize,
        pot: [&mut [f32]; 3],
    ) -> usize {
        self.rows(
            layers,
            offset,
            pot,
            |b, out, kernel, [s0, e0], row, ia, ib| {
                if let Some((fa, fb)) = b.row_span(s0, e0, ia, ib) {
                    kernel.row(out, [s0, e0], row, fa, fb);
                }
            },
        )
    }

    /// [`Slab::potential`] eight lanes at a time: a row of the box (up to eight nodes with a
    /// core of one cell) is one group, so it is not narrowed first.
    ///
    /// # Safety
    /// The CPU has AVX2 and FMA; `pot[0].len() >= 8`.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn potential_avx2(
        &self,
        layers: std::ops::Range<usize>,
        offset: usize,
        pot: [&mut [f32]; 3],
    ) -> usize {
        self.rows(
            layers,
            offset,
            pot,
            |_, out, kernel, [s0, e0], row, ia, ib| {
                // SAFETY: the caller's.
                unsafe { avx2::row(kernel, out, [s0, e0], row, ia, ib) }
            },
        )
    }

    /// Calls `visit(support, out, kernel, [s0, e0], row, ia, ib)` for each row of each vortex's
    /// box with nodes in `node_mask`: `ia..=ib` the nodes (counted from the box's `lo[0]`, whose
    /// node is `row` in the slab), `s0` and `e0` the row's axial offset and squared distance from
    /// the centre in y and z.
    #[inline(always)]
    fn rows(
        &self,
        layers: std::ops::Range<usize>,
        offset: usize,
        pot: [&mut [f32]; 3],
        mut visit: impl FnMut(&Support, &mut Out<'_>, &Kernel<'_>, [f32; 2], usize, usize, usize),
    ) -> usize {
        if layers.is_empty() {
            return 0;
        }
        let [nx, ny, _] = self.dims;
        let (sx, sy) = (nx + 1, (nx + 1) * (ny + 1));
        let len = pot[0].len();
        let mut out = Out {
            pot,
            node_mask: &self.node_mask[offset..offset + len],
            evaluated: 0,
        };
        for b in self.supports {
            let (lo, hi, o, n) = (b.lo, b.hi, b.offset, b.axis);
            let kernel = Kernel::new(b, self.table);
            for k in lo[2].max(layers.start)..=hi[2].min(layers.end - 1) {
                let dz = (k - lo[2]) as i32 as f32 + o[2];
                for j in lo[1]..=hi[1] {
                    // Only the row's nodes in `node_mask` (their extent, precomputed).
                    let (ra, rb) = self.row_nodes[j + (ny + 1) * k];
                    let (ia, ib) = (lo[0].max(ra as usize), hi[0].min(rb as usize));
                    if ia > ib {
                        continue;
                    }
                    let dy = (j - lo[1]) as i32 as f32 + o[1];
                    let (s0, e0) = (dy * n[1] + dz * n[2], dy * dy + dz * dz);
                    let row = sx * j + sy * k + lo[0] - offset;
                    visit(b, &mut out, &kernel, [s0, e0], row, ia - lo[0], ib - lo[0]);
                }
            }
        }
        out.evaluated
    }
}

/// The slab's potential and mask (both from the slab's first node) and the count of nodes
/// evaluated.
struct Out<'a> {
    pot: [&'a mut [f32]; 3],
    node_mask: &'a [u8],
    evaluated: usize,
}

/// One vortex's constants broadcast to four lanes (and as scalars, for other widths).
struct Kernel<'a> {
    support: &'a Support,
    table: &'a Table,
    nx: lane::V4,
    offset_x: f32,
    amp_axis: [lane::V4; 3],
    inv_core2: lane::V4,
    qmax: lane::V4,
    flat: lane::V4,
    end: lane::V4,
    inv_taper: lane::V4,
    tscale: lane::V4,
}

impl<'a> Kernel<'a> {
    #[inline(always)]
    fn new(b: &'a Support, table: &'a Table) -> Self {
        let qmax = (CUTOFF_CORES * CUTOFF_CORES) as f32;
        Self {
            support: b,
            table,
            nx: lane::splat(b.axis[0]),
            offset_x: b.offset[0],
            amp_axis: b.amp_axis.map(lane::splat),
            inv_core2: lane::splat(b.inv_core2),
            qmax: lane::splat(qmax),
            flat: lane::splat(b.flat),
            end: lane::splat(b.end),
            inv_taper: lane::splat(b.inv_taper),
            tscale: lane::splat(TABLE_SIZE as f32 / qmax),
        }
    }

    /// Adds the potential at the nodes `fa..=fb` of the row whose node `lo[0]` is `row` in the
    /// slab (`s0`, `e0` as for [`Support::row_span`]), four at a time. The last group of four may
    /// reach past `fb` (into the next row, or back from the slab's end): its lanes outside the
    /// row add zero.
    #[inline(always)]
    fn row(&self, out: &mut Out<'_>, [s0, e0]: [f32; 2], row: usize, fa: usize, fb: usize) {
        let (s0, e0) = (lane::splat(s0), lane::splat(e0));
        // A slab holds whole layers of at least 2 x 2 nodes, so it has a group from `last`.
        let last = out.node_mask.len().saturating_sub(4);
        let mut first = fa;
        loop {
            // The group starts at the row's node `first`, or back from the slab's end; its lanes
            // `back..=back + fb - first` are the row's.
            let at = (row + first).min(last);
            let back = (row + first - at) as i32;
            let x0 = (first as i32 - back) as f32 + self.offset_x;
            let keep = lane::between(back as f32, (back + (fb - first) as i32) as f32);
            self.group(out, at, x0, [s0, e0], keep);
            first += 4;
            if first > fb {
                break;
            }
        }
    }

    /// The four nodes from `at` (the first at `x0` from the centre along the row), the lanes
    /// `keep` only.
    #[inline(always)]
    fn group(
        &self,
        out: &mut Out<'_>,
        at: usize,
        x0: f32,
        [s0, e0]: [lane::V4; 2],
        keep: lane::V4,
    ) {
        let [p0, p1, p2] = &mut out.pot;
        if at + 4 > out.node_mask.len() || at + 4 > p0.len().min(p1.len()).min(p2.len()) {
            return;
        }
        // SAFETY: (the loads and stores below) `at + 4` is within the mask and the three
        // potentials (checked above).
        let mask = unsafe { lane::nonzero_at(out.node_mask, at) };
        let x = lane::add(lane::ramp(), lane::splat(x0));
        let s = lane::add(s0, lane::mul(x, self.nx));
        let sa = lane::abs(s);
        let r2 = lane::sub(lane::add(lane::mul(x, x), e0), lane::mul(s, s));
        // max returns its second operand for a NaN.
        let q = lane::mul(lane::max(r2, lane::zero()), self.inv_core2);
        let inside = lane::and(
            lane::and(keep, mask),
            lane::and(lane::lt(sa, self.end), lane::lt(q, self.qmax)),
        );
        let bits = lane::bits(inside);
        if bits == 0 {
            return;
        }
        out.evaluated += bits.count_ones() as usize;
        // The axial window: 1 up to `flat`, smoothstep to zero at `end`.
        let t = lane::min(
            lane::max(
                lane::mul(lane::sub(sa, self.flat), self.inv_taper),
                lane::zero(),
            ),
            lane::splat(1.0),
        );
        let g = lane::sub(
            lane::splat(1.0),
            lane::mul(
                lane::mul(t, t),
                lane::sub(lane::splat(3.0), lane::add(t, t)),
            ),
        );
        // The table over q (clamped to the cut-off: outside lanes are dropped below).
        let tq = lane::min(lane::mul(q, self.tscale), lane::splat(TABLE_SIZE as f32));
        let psi = lane::lookup(self.table, tq);
        let phi = lane::and(inside, lane::mul(g, psi));
        for (p, an) in [p0, p1, p2].into_iter().zip(self.amp_axis) {
            // SAFETY: `at + 4` is within the three potentials (checked at the top).
            unsafe {
                let v = lane::add(lane::load_at(p, at), lane::mul(phi, an));
                lane::store_at(p, at, v);
            }
        }
    }
}

/// The node kernel eight lanes at a time (AVX2 and FMA).
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use std::arch::x86_64::*;

    use super::{Kernel, Out, CUTOFF_CORES, TABLE_SIZE};

    /// [`Kernel::row`] over the nodes `fa..=fb`, eight at a time.
    ///
    /// # Safety
    /// The CPU has AVX2 and FMA; the slab has at least eight nodes.
    #[target_feature(enable = "avx2,fma")]
    #[inline]
    pub unsafe fn row(
        kernel: &Kernel<'_>,
        out: &mut Out<'_>,
        [s0, e0]: [f32; 2],
        row: usize,
        fa: usize,
        fb: usize,
    ) {
        let b = kernel.support;
        let last = out.node_mask.len().saturating_sub(8);
        let ramp = _mm256_set_ps(7.0, 6.0, 5.0, 4.0, 3.0, 2.0, 1.0, 0.0);
        let splat = |x: f32| _mm256_set1_ps(x);
        let (s0, e0) = (splat(s0), splat(e0));
        let qmax = (CUTOFF_CORES * CUTOFF_CORES) as f32;
        let mut first = fa;
        loop {
            // As in `Kernel::row`: the group starts at `first`, or back from the slab's end.
            let at = (row + first).min(last);
            let back = (row + first - at) as i32;
            let x0 = (first as i32 - back) as f32 + b.offset[0];
            let keep = _mm256_and_ps(
                _mm256_cmp_ps::<_CMP_LE_OQ>(splat(back as f32), ramp),
                _mm256_cmp_ps::<_CMP_LE_OQ>(ramp, splat((back + (fb - first) as i32) as f32)),
            );
            let [p0, p1, p2] = &mut out.pot;
            if at + 8 > out.node_mask.len() || at + 8 > p0.len().min(p1.len()).min(p2.len()) {
                return;
            }
            // SAFETY: (the loads and stores below) `at + 8` is within the mask and the three
            // potentials (checked above); the table's index is masked to its size.
            let bytes = unsafe {
                out.node_mask
                    .as_ptr()
                    .add(at)
                    .cast::<i64>()
                    .read_unaligned()
            };
            let m = _mm256_cvtepu8_epi32(_mm_cvtsi64_si128(bytes));
            let z = _mm256_setzero_si256();
            let mask = _mm256_castsi256_ps(_mm256_xor_si256(
                _mm256_cmpeq_epi32(m, z),
                _mm256_set1_epi32(-1),
            ));
            let x = _mm256_add_ps(ramp, splat(x0));
            let s = _mm256_fmadd_ps(x, splat(b.axis[0]), s0);
            let sa = _mm256_and_ps(s, _mm256_castsi256_ps(_mm256_set1_epi32(0x7fff_ffff)));
            let r2 = _mm256_sub_ps(_mm256_fmadd_ps(x, x, e0), _mm256_mul_ps(s, s));
            // max returns its second operand for a NaN.
            let q = _mm256_mul_ps(_mm256_max_ps(r2, _mm256_setzero_ps()), splat(b.inv_core2));
            let inside = _mm256_and_ps(
                _mm256_and_ps(keep, mask),
                _mm256_and_ps(
                    _mm256_cmp_ps::<_CMP_LT_OQ>(sa, splat(b.end)),
                    _mm256_cmp_ps::<_CMP_LT_OQ>(q, splat(qmax)),
                ),
            );
            let bits = _mm256_movemask_ps(inside) as u32;
            if bits != 0 {
                out.evaluated += bits.count_ones() as usize;
                let one = splat(1.0);
                let t = _mm256_min_ps(
                    _mm256_max_ps(
                        _mm256_mul_ps(_mm256_sub_ps(sa, splat(b.flat)), splat(b.inv_taper)),
                        _mm256_setzero_ps(),
                    ),
                    one,
                );
                let g = _mm256_fnmadd_ps(
                    _mm256_mul_ps(t, t),
                    _mm256_fnmadd_ps(splat(2.0), t, splat(3.0)),
                    one,
                );
                let tq = _mm256_min_ps(
                    _mm256_mul_ps(q, splat(TABLE_SIZE as f32 / qmax)),
                    splat(TABLE_SIZE as f32),
                );
                let i = _mm256_min_ps(_mm256_floor_ps(tq), splat((TABLE_SIZE - 1) as f32));
                let f = _mm256_sub_ps(tq, i);
                let i = _mm256_and_si256(
                    _mm256_cvttps_epi32(i),
                    _mm256_set1_epi32(TABLE_SIZE as i32 - 1),
                );
                let i2 = _mm256_slli_epi32::<1>(i);
                let tp = kernel.table.as_ptr().cast::<f32>();
                // SAFETY: the CPU has AVX2 (this function's contract); `i2` indexes value and
                // slope of entries below TABLE_SIZE (masked above), inside the table.
                let (v, d) = unsafe {
                    (
                        _mm256_i32gather_ps::<4>(tp, i2),
                        _mm256_i32gather_ps::<4>(tp.add(1), i2),
                    )
                };
                let phi = _mm256_and_ps(inside, _mm256_mul_ps(g, _mm256_fmadd_ps(f, d, v)));
                for (p, an) in [p0, p1, p2].into_iter().zip(b.amp_axis) {
                    // SAFETY: `at + 8` is within the three potentials (checked above).
                    unsafe {
                        let ptr = p.as_mut_ptr().add(at);
                        let v = _mm256_fmadd_ps(phi, splat(an), _mm256_loadu_ps(ptr));
                        _mm256_storeu_ps(ptr, v);
                    }
                }
            }
            first += 8;
            if first > fb {
                break;
            }
        }
    }
}

/// The potential's discrete curl on a run of consecutive faces of one component `c`: face `i`
/// of `out` from the nodes `base + i` and their neighbours `+ sa`, `+ sb`, `+ sa + sb` along the
/// other two axes `a = c + 1` and `b = c + 2` of the potential's components `a` and `b` (`na`,
/// `nb`); `inv = 1 / (2 h)`. Four faces at a time, the last one to three through a padded group.
pub(super) fn curl_run(
    out: &mut [f32],
    [na, nb]: [&[f32]; 2],
    base: usize,
    [sa, sb]: [usize; 2],
    inv: f32,
) {
    let n = out.len();
    fn window(p: &[f32], at: usize, n: usize) -> &[f32] {
        &p[at..at + n]
    }
    let w = |p, o| window(p, base + o, n);
    let (a00, a10, a01, a11) = (w(na, 0), w(na, sa), w(na, sb), w(na, sa + sb));
    let (b00, b10, b01, b11) = (w(nb, 0), w(nb, sa), w(nb, sb), w(nb, sa + sb));
    let inv = lane::splat(inv);
    let face = |l: &dyn Fn(&[f32]) -> lane::V4| {
        use lane::{add, sub};
        let db = sub(sub(add(l(b10), l(b11)), l(b00)), l(b01));
        let da = sub(sub(add(l(a01), l(a11)), l(a00)), l(a10));
        lane::mul(sub(db, da), inv)
    };
    if n >= 4 {
        let mut i = 0;
        loop {
            // SAFETY: `out` and every window hold `n` floats, and `i + 4 <= n`.
            unsafe {
                let u = face(&|s| lane::load_at(s, i));
                lane::store_at(out, i, u);
            }
            if i + 4 == n {
                break;
            }
            // The last group ends at `n` (recomputing up to three faces).
            i = (i + 4).min(n - 4);
        }
    } else {
        let u = lane::lanes(face(&lane::load_padded));
        out.copy_from_slice(&u[..n]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The potential of a few vortices on an 18^3 grid whose interior nodes are all in the mask:
    /// each lane width against the closed form (the table's linear interpolation in q errs by
    /// about 4e-6 of the peak here, f32 rounding far less; 2e-5 leaves room), and against each
    /// other.
    #[test]
    fn the_node_kernel_matches_the_closed_form_potential_in_every_lane_width() {
        let n = 18;
        let h = 1e-3;
        let dims = [n, n, n];
        let origin = [0.0; 3];
        let nodes = (n + 1) * (n + 1) * (n + 1);
        let node = |i: usize, j: usize, k: usize| i + (n + 1) * (j + (n + 1) * k);
        let mut node_mask = vec![0u8; nodes];
        for k in 1..n {
            for j in 1..n {
                for i in 1..n {
                    node_mask[node(i, j, k)] = 1;
                }
            }
        }
        let mut row_nodes = vec![(1u32, 0u32); (n + 1) * (n + 1)];
        for k in 1..n {
            for j in 1..n {
                row_nodes[j + (n + 1) * k] = (1, (n - 1) as u32);
            }
        }
        let unit = |a: [f64; 3]| {
            let m = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
            a.map(|x| x / m)
        };
        let vortices = [
            ([0.0071, 0.0083, 0.0092], [0.3, -0.2, 1.0], 2e-3, 1.0e-3),
            ([0.0102, 0.0098, 0.0087], [1.0, 0.0, 0.0], -1e-3, 1.5e-3),
            ([0.0110, 0.0064, 0.0118], [0.0, 0.6, 0.8], 1.5e-3, 2.0e-3),
            ([0.0090, 0.0090, 0.0090], [0.01, 0.02, 1.0], 1e-3, 1.2e-3),
        ]
        .map(|(c, a, g, r)| Vortex {
            centre_m: c,
            axis: unit(a),
            circulation_m2_s: g,
            core_radius_m: r,
        });
        let supports: Vec<Support> = vortices
            .iter()
            .filter_map(|v| Support::of(v, origin, 1.0 / h, dims))
            .collect();
        let table = table();
        let slab = Slab {
            supports: &supports,
            node_mask: &node_mask,
            row_nodes: &row_nodes,
            table: &table,
            dims,
        };
        let run = |f: &dyn Fn([&mut [f32]; 3]) -> usize| {
            let mut pot: [Vec<f32>; 3] = std::array::from_fn(|_| vec![0.0; nodes]);
            let [a, b, c] = &mut pot;
            let evaluated = f([a, b, c]);
            (pot, evaluated)
        };
        let (sse, n_sse) = run(&|p| slab.potential_sse(0..n + 1, 0, p));
        let (any, n_any) = run(&|p| slab.potential(0..n + 1, 0, p));
        assert!(n_sse > 500, "the vortices are on the grid: {n_sse} nodes");
        // The lane widths' f32 roundings differ (FMA) only at nodes on the support's edge, where
        // the potential is zero to first order.
        assert!(n_sse.abs_diff(n_any) <= 2, "{n_sse} vs {n_any}");
        let peak = vortices
            .iter()
            .map(|v| v.circulation_m2_s.abs() / (2.0 * std::f64::consts::PI) * 1.5)
            .fold(0.0, f64::max);
        let (mut err_sse, mut err_any, mut largest) = (0.0f64, 0.0f64, 0.0f64);
        for k in 0..=n {
            for j in 0..=n {
                for i in 0..=n {
                    let m = node(i, j, k);
                    let p = [i, j, k].map(|x| x as f64 * h);
                    for c in 0..3 {
                        let exact: f64 = if node_mask[m] == 0 {
                            0.0
                        } else {
                            vortices
                                .iter()
                                .map(|v| v.potential_m2_s(p) * v.axis[c])
                                .sum()
                        };
                        err_sse = err_sse.max((sse[c][m] as f64 - exact).abs());
                        err_any = err_any.max((any[c][m] as f64 - exact).abs());
                        largest = largest.max(exact.abs());
                    }
                }
            }
        }
        assert!(largest > 0.3 * peak, "{largest} vs {peak}");
        assert!(err_sse < 2e-5 * peak, "four lanes: {err_sse:e} of {peak:e}");
        assert!(err_any < 2e-5 * peak, "dispatched: {err_any:e} of {peak:e}");
    }
}
