//! Trilinear interpolation of staggered (MAC) fields, in grid units.
//!
//! A position `p` is measured in cells from the grid origin (`p = (x - origin) / h`). Component `c`
//! of the velocity is sampled on its faces: along axis `c` the samples sit at integer positions, along
//! the other axes at half-integer ones. Periodic axes wrap; other axes clamp to the outermost samples.

/// Samples per axis of each velocity component, and the periodicity.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Layout {
    pub periodic: [bool; 3],
    /// Face-array dimensions of component c: dims with dims[c] + 1 unless periodic along c.
    pub fdims: [[usize; 3]; 3],
}

impl Layout {
    pub fn new(dims: [usize; 3], periodic: [bool; 3]) -> Self {
        let fdims = std::array::from_fn(|c| {
            let mut d = dims;
            if !periodic[c] {
                d[c] += 1;
            }
            d
        });
        Self { periodic, fdims }
    }

    #[inline]
    pub fn face_index(&self, c: usize, f: [usize; 3]) -> usize {
        let d = self.fdims[c];
        f[0] + d[0] * (f[1] + d[1] * f[2])
    }

    #[inline]
    pub fn face_coords(&self, c: usize, idx: usize) -> [usize; 3] {
        // u32 arithmetic: grids are limited to < 2^30 cells, and 32-bit division is much cheaper.
        let d = self.fdims[c];
        let (idx, d0, d1) = (idx as u32, d[0] as u32, d[1] as u32);
        let i = idx % d0;
        let r = idx / d0;
        [i as usize, (r % d1) as usize, (r / d1) as usize]
    }

    pub fn face_count(&self, c: usize) -> usize {
        self.fdims[c].iter().product()
    }

    /// Two sample indices and the weight of the second along one axis. (i32 conversions: they
    /// compile to one instruction, where `as usize` on a float needs saturation code.)
    #[inline]
    fn axis(s: f32, npts: usize, periodic: bool) -> (usize, usize, f32) {
        if periodic {
            let fl = s.floor();
            let t = s - fl;
            let n = npts as i32;
            let mut i0 = (fl as i32) % n;
            if i0 < 0 {
                i0 += n;
            }
            let i0 = i0 as usize;
            let i1 = if i0 + 1 == npts { 0 } else { i0 + 1 };
            (i0, i1, t)
        } else if npts == 1 {
            (0, 0, 0.0)
        } else {
            // max/min (not clamp) so a NaN position lands on sample 0 instead of panicking.
            let s = s.max(0.0).min((npts - 1) as f32);
            let i0 = (s as i32 as usize).min(npts - 2);
            (i0, i0 + 1, s - i0 as f32)
        }
    }

    #[inline]
    fn stencil(&self, c: usize, p: [f32; 3]) -> ([usize; 8], [f32; 8]) {
        let d = self.fdims[c];
        let mut ax = [(0usize, 0usize, 0f32); 3];
        for (a, slot) in ax.iter_mut().enumerate() {
            let s = if a == c { p[a] } else { p[a] - 0.5 };
            *slot = Self::axis(s, d[a], self.periodic[a]);
        }
        let (x0, x1, tx) = ax[0];
        let (y0, y1, ty) = ax[1];
        let (z0, z1, tz) = ax[2];
        let r00 = d[0] * (y0 + d[1] * z0);
        let r10 = d[0] * (y1 + d[1] * z0);
        let r01 = d[0] * (y0 + d[1] * z1);
        let r11 = d[0] * (y1 + d[1] * z1);
        let idx = [
            r00 + x0,
            r00 + x1,
            r10 + x0,
            r10 + x1,
            r01 + x0,
            r01 + x1,
            r11 + x0,
            r11 + x1,
        ];
        (idx, trilinear_weights([tx, ty, tz]))
    }

    /// Component `c` of `field` at `p`.
    #[inline]
    pub fn sample(&self, c: usize, field: &[f32], p: [f32; 3]) -> f32 {
        let (idx, w) = self.stencil(c, p);
        let mut v = 0.0;
        for n in 0..8 {
            v += w[n] * field[idx[n]];
        }
        v
    }

    /// Component `c` at `p`, with the minimum and maximum of the samples used (for clamping).
    /// (The reference for the advection's fast sampler, in its tests.)
    #[cfg(test)]
    #[inline]
    pub fn sample_bounds(&self, c: usize, field: &[f32], p: [f32; 3]) -> (f32, f32, f32) {
        let (idx, w) = self.stencil(c, p);
        let mut v = 0.0;
        let mut lo = f32::INFINITY;
        let mut hi = f32::NEG_INFINITY;
        for n in 0..8 {
            let f = field[idx[n]];
            v += w[n] * f;
            lo = lo.min(f);
            hi = hi.max(f);
        }
        (v, lo, hi)
    }

    /// Trilinear interpolation of a cell-centred vector field at `p`.
    /// (The reference for the advection's fast sampler, in its tests.)
    #[cfg(test)]
    #[inline]
    pub fn sample_centred(&self, dims: [usize; 3], field: &[[f32; 3]], p: [f32; 3]) -> [f32; 3] {
        let (x0, x1, tx) = Self::axis(p[0] - 0.5, dims[0], self.periodic[0]);
        let (y0, y1, ty) = Self::axis(p[1] - 0.5, dims[1], self.periodic[1]);
        let (z0, z1, tz) = Self::axis(p[2] - 0.5, dims[2], self.periodic[2]);
        let r00 = dims[0] * (y0 + dims[1] * z0);
        let r10 = dims[0] * (y1 + dims[1] * z0);
        let r01 = dims[0] * (y0 + dims[1] * z1);
        let r11 = dims[0] * (y1 + dims[1] * z1);
        let lerp = |a: [f32; 3], b: [f32; 3], t: f32| -> [f32; 3] {
            [
                a[0] + t * (b[0] - a[0]),
                a[1] + t * (b[1] - a[1]),
                a[2] + t * (b[2] - a[2]),
            ]
        };
        let c00 = lerp(field[r00 + x0], field[r00 + x1], tx);
        let c10 = lerp(field[r10 + x0], field[r10 + x1], tx);
        let c01 = lerp(field[r01 + x0], field[r01 + x1], tx);
        let c11 = lerp(field[r11 + x0], field[r11 + x1], tx);
        lerp(lerp(c00, c10, ty), lerp(c01, c11, ty), tz)
    }

    /// The velocity at `p` and `d[c][a]`: component `c` at `p + e_a` minus at `p - e_a` (one
    /// cell each way), for `a != c` (`d[c][c]` is 0); `None` where a sample would be clamped or
    /// wrap (then sample the points one by one). Each component's weights serve all three
    /// points: a shift by a whole cell keeps them.
    pub fn velocity_and_cross_differences(
        &self,
        u: [&[f32]; 3],
        p: [f32; 3],
    ) -> Option<([f32; 3], [[f32; 3]; 3])> {
        if self.periodic.iter().any(|&x| x) {
            return None;
        }
        let mut v = [0.0f32; 3];
        let mut d = [[0.0f32; 3]; 3];
        for c in 0..3 {
            let fd = self.fdims[c];
            let stride = [1, fd[0], fd[0] * fd[1]];
            let mut base = 0;
            let mut t = [0.0f32; 3];
            for a in 0..3 {
                let s = if a == c { p[a] } else { p[a] - 0.5 };
                // Room for the shifted samples (a != c) or for the stencil (a == c).
                let room = if a == c { 0.0 } else { 1.0 };
                if !(s >= room && s < fd[a] as f32 - 1.0 - room) {
                    return None;
                }
                let i0 = s as i32 as usize;
                base += i0 * stride[a];
                t[a] = s - i0 as f32;
            }
            let (sx, sy, sz) = (stride[0], stride[1], stride[2]);
            let idx = [
                base,
                base + sx,
                base + sy,
                base + sy + sx,
                base + sz,
                base + sz + sx,
                base + sz + sy,
                base + sz + sy + sx,
            ];
            let w = trilinear_weights(t);
            let field = u[c];
            for n in 0..8 {
                v[c] += w[n] * field[idx[n]];
            }
            for a in (0..3).filter(|&a| a != c) {
                let mut x = 0.0;
                for n in 0..8 {
                    x += w[n] * (field[idx[n] + stride[a]] - field[idx[n] - stride[a]]);
                }
                d[c][a] = x;
            }
        }
        Some((v, d))
    }

    /// The velocity vector at `p`.
    #[inline]
    pub fn velocity(&self, u: [&[f32]; 3], p: [f32; 3]) -> [f32; 3] {
        [
            self.sample(0, u[0], p),
            self.sample(1, u[1], p),
            self.sample(2, u[2], p),
        ]
    }

    /// Position (grid units) of face `f` of component `c`.
    #[inline]
    pub fn face_position(c: usize, f: [usize; 3]) -> [f32; 3] {
        std::array::from_fn(|a| {
            if a == c {
                f[a] as f32
            } else {
                f[a] as f32 + 0.5
            }
        })
    }
}

/// Trilinear weights of the corners `(0,0,0), (1,0,0), (0,1,0), (1,1,0), (0,0,1), ...` (x fastest)
/// at the local coordinates `t` in the cell.
#[inline(always)]
fn trilinear_weights(t: [f32; 3]) -> [f32; 8] {
    let [tx, ty, tz] = t;
    let (sx, sy, sz) = (1.0 - tx, 1.0 - ty, 1.0 - tz);
    [
        sx * sy * sz,
        tx * sy * sz,
        sx * ty * sz,
        tx * ty * sz,
        sx * sy * tz,
        tx * sy * tz,
        sx * ty * tz,
        tx * ty * tz,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn linear_fields_are_reproduced_exactly_inside_and_wrap_on_periodic_axes() {
        let layout = Layout::new([5, 4, 3], [false, true, false]);
        // u (component 0) = 2 x + 0.5 z at its faces, in grid units.
        let field: Vec<f32> = (0..layout.face_count(0))
            .map(|i| {
                let p = Layout::face_position(0, layout.face_coords(0, i));
                2.0 * p[0] + 0.5 * p[2]
            })
            .collect();
        for p in [[0.3, 1.7, 1.1], [4.9, 0.9, 2.4], [2.0, 3.0, 0.5]] {
            let v = layout.sample(0, &field, p);
            assert!((v - (2.0 * p[0] + 0.5 * p[2])).abs() < 1e-5, "{p:?}: {v}");
        }
        // Periodic in y: sampling at y and y + 4 is the same.
        let a = layout.sample(0, &field, [1.3, 0.2, 1.0]);
        let b = layout.sample(0, &field, [1.3, 4.2, 1.0]);
        let c = layout.sample(0, &field, [1.3, -3.8, 1.0]);
        assert!((a - b).abs() < 1e-6 && (a - c).abs() < 1e-6);
        // Outside a non-periodic axis the sample clamps to the last face.
        let edge = layout.sample(0, &field, [5.0, 1.5, 1.5]);
        assert_eq!(layout.sample(0, &field, [9.0, 1.5, 1.5]), edge);
    }

    #[test]
    fn shared_weight_differences_match_six_samples_and_decline_at_the_edges() {
        let dims = [7, 6, 8];
        let layout = Layout::new(dims, [false; 3]);
        let fields: [Vec<f32>; 3] = std::array::from_fn(|c| {
            (0..layout.face_count(c))
                .map(|i| ((i * 7919 + 13 * c) % 101) as f32 / 50.0 - 1.0)
                .collect()
        });
        let u = [&fields[0][..], &fields[1][..], &fields[2][..]];
        let mut checked = 0;
        for p in [
            [3.2, 2.7, 4.9],
            [1.6, 1.51, 1.5],
            [5.4, 4.4, 6.45],
            [2.5, 3.0, 3.0],
        ] {
            let (v, d) = layout.velocity_and_cross_differences(u, p).expect("inside");
            for c in 0..3 {
                assert!((v[c] - layout.sample(c, u[c], p)).abs() < 1e-6);
                for a in (0..3).filter(|&a| a != c) {
                    let (mut lo, mut hi) = (p, p);
                    lo[a] -= 1.0;
                    hi[a] += 1.0;
                    let want = layout.sample(c, u[c], hi) - layout.sample(c, u[c], lo);
                    assert!((d[c][a] - want).abs() < 1e-5, "{p:?} {c} {a}");
                    checked += 1;
                }
            }
        }
        assert_eq!(checked, 24);
        // Within a cell of the boundary a shifted sample would clamp: the caller samples.
        for p in [
            [0.9, 3.0, 3.0],
            [3.0, 5.2, 3.0],
            [3.0, 3.0, 7.6],
            [f32::NAN, 3.0, 3.0],
        ] {
            assert!(
                layout.velocity_and_cross_differences(u, p).is_none(),
                "{p:?}"
            );
        }
    }
}
