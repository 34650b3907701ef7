//! The sampling geometry of the advection: where a point falls among the samples of the
//! cell-centred velocity and of each face component (wrapped on periodic axes, clamped on the
//! others), and the trilinear and tricubic interpolations there.

use super::super::sample::Layout;
use crate::simd::{v4, V4};

/// `a + t (b - a)`, `t` the same in every lane.
#[inline(always)]
fn lerp4(a: V4, b: V4, t: f32) -> V4 {
    v4::lerp(a, b, v4::splat(t))
}

/// One axis of a sampled field: points per axis, stride, periodicity, and the offset of the sample
/// positions from integer grid positions (0 or 1/2).
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Axis {
    pub(super) n: i32,
    pub(super) last: f32,
    /// Largest lower sample index (n - 2, or 0 for a single point).
    pub(super) top: u32,
    pub(super) stride: u32,
    /// Offset from a sample to the next one (0 for a single point).
    pub(super) step: u32,
    pub(super) periodic: bool,
    pub(super) shift: f32,
}

impl Axis {
    fn new(n: usize, stride: usize, periodic: bool, shift: f32) -> Self {
        Self {
            n: n as i32,
            last: (n - 1) as f32,
            top: n.saturating_sub(2) as u32,
            stride: stride as u32,
            step: if n > 1 { stride as u32 } else { 0 },
            periodic,
            shift,
        }
    }

    /// Offsets (index times stride) of the two samples around `p` and the weight of the second.
    /// Periodic axes wrap, others clamp to the outermost samples (a NaN lands on sample 0).
    /// Wrapping arithmetic throughout: indices stay far below 2^32 by construction, and the dev
    /// profile's overflow checks would double the cost of this inner loop.
    #[inline(always)]
    fn locate(&self, p: f32) -> (u32, u32, f32) {
        let s = p - self.shift;
        if self.periodic {
            let fl = s.floor();
            let t = s - fl;
            let mut i0 = (fl as i32) % self.n;
            if i0 < 0 {
                i0 += self.n;
            }
            let i1 = if i0 + 1 == self.n { 0 } else { i0 + 1 };
            (
                (i0 as u32).wrapping_mul(self.stride),
                (i1 as u32).wrapping_mul(self.stride),
                t,
            )
        } else {
            // max/min (not clamp): NaN-safe.
            let s = s.max(0.0).min(self.last);
            // s >= 0, so truncation is the floor.
            let i0 = (s as u32).min(self.top);
            let o0 = i0.wrapping_mul(self.stride);
            (o0, o0.wrapping_add(self.step), s - i0 as f32)
        }
    }
}

impl Axis {
    /// Offsets of the four samples around `p` (the two of [`Axis::locate`] and one more on each
    /// side, wrapped on a periodic axis, repeated at the ends of a clamped one) and their
    /// Catmull-Rom weights.
    #[inline(always)]
    fn locate_cubic(&self, p: f32) -> ([u32; 4], [f32; 4]) {
        let s = p - self.shift;
        let n = self.n;
        let (i0, t) = if self.periodic {
            let fl = s.floor();
            // `as` saturates (NaN -> 0), and rem_euclid keeps the index in [0, n).
            ((fl as i32).rem_euclid(n), s - fl)
        } else {
            let s = s.max(0.0).min(self.last);
            let i0 = (s as u32).min(self.top) as i32;
            (i0, s - i0 as f32)
        };
        let idx = |d: i32| -> u32 {
            let i = i0 + d;
            let i = if self.periodic {
                i.rem_euclid(n)
            } else {
                i.clamp(0, n - 1)
            };
            (i as u32).wrapping_mul(self.stride)
        };
        let (t2, t3) = (t * t, t * t * t);
        (
            [idx(-1), idx(0), idx(1), idx(2)],
            [
                0.5 * (-t3 + 2.0 * t2 - t),
                0.5 * (3.0 * t3 - 5.0 * t2 + 2.0),
                0.5 * (-3.0 * t3 + 4.0 * t2 + t),
                0.5 * (t3 - t2),
            ],
        )
    }
}

/// Sampling geometry of a field with points `npts` per axis shifted by `shift`.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Grid3 {
    pub(super) ax: [Axis; 3],
}

impl Grid3 {
    fn new(npts: [usize; 3], periodic: [bool; 3], shift: [f32; 3]) -> Self {
        let strides = [1, npts[0], npts[0] * npts[1]];
        Self {
            ax: std::array::from_fn(|a| Axis::new(npts[a], strides[a], periodic[a], shift[a])),
        }
    }
}

/// Geometry of the advection: the centred grid and the face grids of the three components.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Geometry {
    pub(super) dims: [usize; 3],
    pub(super) periodic: [bool; 3],
    pub(super) centred: Grid3,
    pub(super) faces: [Grid3; 3],
}

impl Geometry {
    pub fn new(dims: [usize; 3], layout: &Layout) -> Self {
        let periodic = layout.periodic;
        Self {
            dims,
            periodic,
            centred: Grid3::new(dims, periodic, [0.5; 3]),
            faces: std::array::from_fn(|c| {
                Grid3::new(
                    layout.fdims[c],
                    periodic,
                    std::array::from_fn(|a| if a == c { 0.0 } else { 0.5 }),
                )
            }),
        }
    }

    /// Trilinear interpolation of the padded cell-centred velocity at `p` (grid units).
    #[inline(always)]
    pub(super) fn centred(&self, v: &[V4], p: V4) -> V4 {
        let p = v4::lanes(p);
        let (x0, x1, tx) = self.centred.ax[0].locate(p[0]);
        let (y0, y1, ty) = self.centred.ax[1].locate(p[1]);
        let (z0, z1, tz) = self.centred.ax[2].locate(p[2]);
        #[inline(always)]
        fn row(v: &[V4], o: u32, x0: u32, x1: u32, tx: f32) -> V4 {
            lerp4(
                v[o.wrapping_add(x0) as usize],
                v[o.wrapping_add(x1) as usize],
                tx,
            )
        }
        let c0 = lerp4(
            row(v, y0.wrapping_add(z0), x0, x1, tx),
            row(v, y1.wrapping_add(z0), x0, x1, tx),
            ty,
        );
        let c1 = lerp4(
            row(v, y0.wrapping_add(z1), x0, x1, tx),
            row(v, y1.wrapping_add(z1), x0, x1, tx),
            ty,
        );
        lerp4(c0, c1, tz)
    }

    /// Component `c` of `field` at `p`, with the min and max of the samples used when `BOUNDS`.
    #[inline(always)]
    pub(super) fn sample<const BOUNDS: bool>(
        &self,
        c: usize,
        field: &[f32],
        p: V4,
    ) -> (f32, f32, f32) {
        let p = v4::lanes(p);
        let g = &self.faces[c];
        let (x0, x1, tx) = g.ax[0].locate(p[0]);
        let (y0, y1, ty) = g.ax[1].locate(p[1]);
        let (z0, z1, tz) = g.ax[2].locate(p[2]);
        let r = [
            y0.wrapping_add(z0),
            y1.wrapping_add(z0),
            y0.wrapping_add(z1),
            y1.wrapping_add(z1),
        ];
        let mut s = [0f32; 8];
        for q in 0..4 {
            s[2 * q] = field[r[q].wrapping_add(x0) as usize];
            s[2 * q + 1] = field[r[q].wrapping_add(x1) as usize];
        }
        let (mut lo, mut hi) = (0.0, 0.0);
        if BOUNDS {
            lo = s.iter().fold(f32::INFINITY, |m, &v| m.min(v));
            hi = s.iter().fold(f32::NEG_INFINITY, |m, &v| m.max(v));
        }
        let r00 = s[0] + tx * (s[1] - s[0]);
        let r10 = s[2] + tx * (s[3] - s[2]);
        let r01 = s[4] + tx * (s[5] - s[4]);
        let r11 = s[6] + tx * (s[7] - s[6]);
        let c0 = r00 + ty * (r10 - r00);
        let c1 = r01 + ty * (r11 - r01);
        (c0 + tz * (c1 - c0), lo, hi)
    }

    /// Component `c` of `field` at `p` by tricubic (Catmull-Rom) interpolation, clamped to the min
    /// and max of the eight samples around `p` (the trilinear stencil), which are also returned.
    /// Near a clamped boundary the outer samples repeat the outermost one; NaN positions land on
    /// sample 0 as in [`Axis::locate`].
    #[inline(always)]
    pub(super) fn sample_cubic(&self, c: usize, field: &[f32], p: V4) -> (f32, f32, f32) {
        let p = v4::lanes(p);
        let g = &self.faces[c];
        let mut off = [[0u32; 4]; 3];
        let mut w = [[0f32; 4]; 3];
        for a in 0..3 {
            (off[a], w[a]) = g.ax[a].locate_cubic(p[a]);
        }
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        let mut acc_z = 0.0;
        for (kz, &oz) in off[2].iter().enumerate() {
            let mut acc_y = 0.0;
            for (ky, &oy) in off[1].iter().enumerate() {
                let r = oz.wrapping_add(oy);
                let s: [f32; 4] =
                    std::array::from_fn(|kx| field[r.wrapping_add(off[0][kx]) as usize]);
                if (1..3).contains(&kz) && (1..3).contains(&ky) {
                    lo = lo.min(s[1]).min(s[2]);
                    hi = hi.max(s[1]).max(s[2]);
                }
                let wx = &w[0];
                acc_y += w[1][ky] * (wx[0] * s[0] + wx[1] * s[1] + wx[2] * s[2] + wx[3] * s[3]);
            }
            acc_z += w[2][kz] * acc_y;
        }
        // max/min (not clamp): a NaN lands on `lo`.
        (acc_z.max(lo).min(hi), lo, hi)
    }

    /// Centred-grid indices of the two cells beside face `f` of component `c` (clamped at a
    /// non-periodic boundary, wrapped at a periodic one).
    #[inline(always)]
    pub(super) fn face_cells(&self, c: usize, f: [usize; 3]) -> (usize, usize) {
        let n = self.dims[c];
        let stride = self.centred.ax[c].stride as usize;
        let mut base = f[0] + self.dims[0] * (f[1] + self.dims[1] * f[2]);
        if f[c] >= n {
            // The far boundary face of a non-periodic axis: both sides clamp to the last cell.
            base -= stride;
            return (base, base);
        }
        let lo = if f[c] > 0 {
            base - stride
        } else if self.periodic[c] {
            base + (n - 1) * stride
        } else {
            base
        };
        (lo, base)
    }
}
