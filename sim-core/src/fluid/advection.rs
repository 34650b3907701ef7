//! Semi-Lagrangian advection of the face velocities: RK2 (midpoint) backtrace, and MacCormack
//! (a backward and a forward semi-Lagrangian step, error-corrected, clamped to the values the first
//! step interpolated from so it cannot create new extrema).
//!
//! Layout for speed: the active faces of the three components are walked as runs of consecutive
//! faces along x (so a face's coordinates come from the loop, not from divisions), the results go to
//! one array concatenating the three components (so one rayon region covers the whole stage), and
//! the trace reads a padded cell-centred velocity (`[f32; 4]`: one 4-lane trilinear per sample).

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::sample::Layout;

/// Advection scheme.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum AdvectionScheme {
    /// Semi-Lagrangian with an RK2 (midpoint) backtrace: unconditionally stable, dissipative.
    #[default]
    SemiLagrangian,
    /// MacCormack on top of the RK2 semi-Lagrangian step, clamped: less dissipative, about 2x cost.
    MacCormack,
}

/// Faces per parallel task (a block of the concatenated active faces).
pub(crate) const BLOCK: usize = 2048;

/// Consecutive active faces of one component along x.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Run {
    /// Component.
    pub c: u32,
    /// Face coordinates of the first face.
    pub f: [u32; 3],
    /// Full index of the first face.
    pub full: u32,
    /// Position of the first face in the concatenated compact array.
    pub compact: u32,
    /// Number of faces.
    pub len: u32,
}

/// The runs of all three components, cut so none crosses a block boundary.
#[derive(Default, Debug)]
pub(crate) struct Plan {
    pub runs: Vec<Run>,
    /// First run of each block, and the number of runs at the end.
    pub block_runs: Vec<u32>,
    /// Start of each component in the concatenated compact array, and the total.
    pub offset: [usize; 4],
}

impl Plan {
    /// Rebuilds the runs from the (ascending) active face lists.
    pub fn rebuild(&mut self, layout: &Layout, active: [&[u32]; 3]) {
        self.runs.clear();
        self.block_runs.clear();
        let mut pos = 0usize;
        for (c, list) in active.iter().enumerate() {
            self.offset[c] = pos;
            let nx = layout.fdims[c][0] as u32;
            let mut n = 0;
            while n < list.len() {
                let first = list[n];
                // Extend while the next active face is the next face of the same x row.
                let mut len = 1usize;
                while n + len < list.len()
                    && list[n + len] == first + len as u32
                    && (first % nx) + (len as u32) < nx
                {
                    len += 1;
                }
                // Cut at block boundaries.
                let mut done = 0usize;
                while done < len {
                    let at = pos + done;
                    let room = BLOCK - at % BLOCK;
                    let take = room.min(len - done);
                    let f = layout.face_coords(c, (first as usize) + done);
                    self.runs.push(Run {
                        c: c as u32,
                        f: f.map(|v| v as u32),
                        full: first + done as u32,
                        compact: at as u32,
                        len: take as u32,
                    });
                    done += take;
                }
                pos += len;
                n += len;
            }
        }
        self.offset[3] = pos;
        let blocks = pos.div_ceil(BLOCK);
        let mut r = 0usize;
        for b in 0..blocks {
            while r < self.runs.len() && (self.runs[r].compact as usize) < b * BLOCK {
                r += 1;
            }
            self.block_runs.push(r as u32);
        }
        self.block_runs.push(self.runs.len() as u32);
    }
}

/// One axis of a sampled field: points per axis, stride, periodicity, and the offset of the sample
/// positions from integer grid positions (0 or 1/2).
#[derive(Clone, Copy, Debug, Default)]
struct Axis {
    n: i32,
    last: f32,
    stride: usize,
    periodic: bool,
    shift: f32,
}

impl Axis {
    /// Offsets (index times stride) of the two samples around `p` and the weight of the second.
    /// Periodic axes wrap, others clamp to the outermost samples (a NaN lands on sample 0).
    #[inline(always)]
    fn locate(&self, p: f32) -> (usize, usize, f32) {
        let s = p - self.shift;
        let (i0, i1, t) = if self.periodic {
            let fl = s.floor();
            let t = s - fl;
            let mut i0 = (fl as i32) % self.n;
            if i0 < 0 {
                i0 += self.n;
            }
            let i1 = if i0 + 1 == self.n { 0 } else { i0 + 1 };
            (i0, i1, t)
        } else {
            // max/min (not clamp): NaN-safe. i32 conversions compile to one instruction.
            let s = s.max(0.0).min(self.last);
            let i0 = (s as i32).min(self.n - 2).max(0);
            (i0, (i0 + 1).min(self.n - 1), s - i0 as f32)
        };
        (i0 as usize * self.stride, i1 as usize * self.stride, t)
    }
}

/// Sampling geometry of a field with points `npts` per axis shifted by `shift`.
#[derive(Clone, Copy, Debug, Default)]
struct Grid3 {
    ax: [Axis; 3],
}

impl Grid3 {
    fn new(npts: [usize; 3], periodic: [bool; 3], shift: [f32; 3]) -> Self {
        let strides = [1, npts[0], npts[0] * npts[1]];
        Self {
            ax: std::array::from_fn(|a| Axis {
                n: npts[a] as i32,
                last: (npts[a] - 1) as f32,
                stride: strides[a],
                periodic: periodic[a],
                shift: shift[a],
            }),
        }
    }

    /// The 8 sample indices and trilinear weights around `p`.
    #[inline(always)]
    fn stencil(&self, p: [f32; 3]) -> ([usize; 8], [f32; 8]) {
        let (x0, x1, tx) = self.ax[0].locate(p[0]);
        let (y0, y1, ty) = self.ax[1].locate(p[1]);
        let (z0, z1, tz) = self.ax[2].locate(p[2]);
        let (r00, r10, r01, r11) = (y0 + z0, y1 + z0, y0 + z1, y1 + z1);
        let (sx, sy, sz) = (1.0 - tx, 1.0 - ty, 1.0 - tz);
        (
            [
                r00 + x0,
                r00 + x1,
                r10 + x0,
                r10 + x1,
                r01 + x0,
                r01 + x1,
                r11 + x0,
                r11 + x1,
            ],
            [
                sx * sy * sz,
                tx * sy * sz,
                sx * ty * sz,
                tx * ty * sz,
                sx * sy * tz,
                tx * sy * tz,
                sx * ty * tz,
                tx * ty * tz,
            ],
        )
    }
}

/// Geometry of the advection: the centred grid and the face grids of the three components.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Geometry {
    dims: [usize; 3],
    periodic: [bool; 3],
    centred: Grid3,
    faces: [Grid3; 3],
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
    fn centred(&self, v: &[[f32; 4]], p: [f32; 3]) -> [f32; 4] {
        let (x0, x1, tx) = self.centred.ax[0].locate(p[0]);
        let (y0, y1, ty) = self.centred.ax[1].locate(p[1]);
        let (z0, z1, tz) = self.centred.ax[2].locate(p[2]);
        #[inline(always)]
        fn lerp(a: [f32; 4], b: [f32; 4], t: f32) -> [f32; 4] {
            std::array::from_fn(|l| a[l] + t * (b[l] - a[l]))
        }
        let row = |o: usize| lerp(v[o + x0], v[o + x1], tx);
        let c0 = lerp(row(y0 + z0), row(y1 + z0), ty);
        let c1 = lerp(row(y0 + z1), row(y1 + z1), ty);
        lerp(c0, c1, tz)
    }

    /// Component `c` of `field` at `p`.
    #[inline(always)]
    fn sample(&self, c: usize, field: &[f32], p: [f32; 3]) -> f32 {
        let (idx, w) = self.faces[c].stencil(p);
        let mut v = 0.0;
        for n in 0..8 {
            v += w[n] * field[idx[n]];
        }
        v
    }

    /// Component `c` of `field` at `p`, with the min and max of the samples used.
    #[inline(always)]
    fn sample_bounds(&self, c: usize, field: &[f32], p: [f32; 3]) -> (f32, f32, f32) {
        let (idx, w) = self.faces[c].stencil(p);
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

    /// Centred-grid indices of the two cells beside face `f` of component `c` (clamped at a
    /// non-periodic boundary, wrapped at a periodic one).
    #[inline(always)]
    fn face_cells(&self, c: usize, f: [usize; 3]) -> (usize, usize) {
        let n = self.dims[c];
        let stride = self.centred.ax[c].stride;
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

    /// RK2 (midpoint) trace from face `f` of component `c` at `x0` over `dt_cells` (= dt / h).
    #[inline(always)]
    fn trace(&self, v: &[[f32; 4]], c: usize, f: [usize; 3], x0: [f32; 3], dt: f32) -> [f32; 3] {
        // At the face the centred field is the mean of the two cells beside it: two loads.
        let (lo, hi) = self.face_cells(c, f);
        let (a, b) = (v[lo], v[hi]);
        let h = 0.5 * dt;
        let xm: [f32; 3] = std::array::from_fn(|l| x0[l] - h * 0.5 * (a[l] + b[l]));
        let vm = self.centred(v, xm);
        std::array::from_fn(|l| x0[l] - dt * vm[l])
    }
}

/// Averages the face velocities to the cell centres (one array per component), row by row.
pub(crate) fn update_centred(layout: &Layout, dims: [usize; 3], u: [&[f32]; 3], out: &mut [Vec<f32>; 3]) {
    let [nx, ny, nz] = dims;
    let fd = layout.fdims;
    let p = layout.periodic;
    let [ox, oy, oz] = out;
    for k in 0..nz {
        let k1 = if k + 1 == nz && p[2] { 0 } else { k + 1 };
        for j in 0..ny {
            let j1 = if j + 1 == ny && p[1] { 0 } else { j + 1 };
            let o = nx * (j + ny * k);
            let r0 = fd[0][0] * (j + fd[0][1] * k);
            let x = &u[0][r0..r0 + fd[0][0]];
            let rx = &mut ox[o..o + nx];
            for (cell, xs) in rx.iter_mut().zip(x.windows(2)) {
                *cell = 0.5 * (xs[0] + xs[1]);
            }
            let hi = if p[0] { x[0] } else { x[nx] };
            rx[nx - 1] = 0.5 * (x[nx - 1] + hi);
            let y0 = &u[1][nx * (j + fd[1][1] * k)..][..nx];
            let y1 = &u[1][nx * (j1 + fd[1][1] * k)..][..nx];
            for ((cell, a), b) in oy[o..o + nx].iter_mut().zip(y0).zip(y1) {
                *cell = 0.5 * (a + b);
            }
            let z0 = &u[2][nx * (j + ny * k)..][..nx];
            let z1 = &u[2][nx * (j + ny * k1)..][..nx];
            for ((cell, a), b) in oz[o..o + nx].iter_mut().zip(z0).zip(z1) {
                *cell = 0.5 * (a + b);
            }
        }
    }
}

/// Runtime dispatch to the widest instruction set the CPU has (the shipped binary targets generic
/// x86-64; AVX2 + FMA doubles the lanes of the vectorised group arithmetic).
mod simd {
    /// Runs `f`, compiled for AVX2 + FMA when the CPU has them.
    #[inline(always)]
    pub fn dispatch(f: impl FnOnce()) {
        #[cfg(target_arch = "x86_64")]
        {
            #[target_feature(enable = "avx2,fma")]
            fn avx2(f: impl FnOnce()) {
                f()
            }
            if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
                // SAFETY: the CPU supports the features `avx2` was compiled for (checked above).
                unsafe { avx2(f) };
                return;
            }
        }
        f()
    }
}

/// Faces traced together (SIMD lanes: the arithmetic of a group vectorises, the loads are gathers).
const L: usize = 8;
/// One value per lane.
type Lanes = [f32; L];

/// [`Axis::locate`] for a group of lanes; the clamped (non-periodic) case is branch-free so it
/// vectorises.
#[inline(always)]
fn locate_lanes(ax: &Axis, p: &Lanes) -> ([u32; L], [u32; L], Lanes) {
    let mut o0 = [0u32; L];
    let mut o1 = [0u32; L];
    let mut t = [0f32; L];
    if ax.periodic {
        for l in 0..L {
            let (a, b, w) = ax.locate(p[l]);
            (o0[l], o1[l], t[l]) = (a as u32, b as u32, w);
        }
    } else {
        let stride = ax.stride as u32;
        let step = if ax.n > 1 { stride } else { 0 };
        let top = (ax.n - 2).max(0) as f32;
        for l in 0..L {
            let s = (p[l] - ax.shift).max(0.0).min(ax.last);
            let fl = s.floor().min(top);
            t[l] = s - fl;
            // fl is a small non-negative integer: adding 2^23 puts it in the mantissa bits, an
            // exact conversion that vectorises (unlike the saturating `as`).
            // Wrapping arithmetic: the dev profile's overflow checks would stop vectorisation (the
            // values are far below 2^32 by construction).
            let i0 = (fl + 8_388_608.0).to_bits().wrapping_sub(0x4B00_0000);
            o0[l] = i0.wrapping_mul(stride);
            o1[l] = o0[l].wrapping_add(step);
        }
    }
    (o0, o1, t)
}

#[inline(always)]
fn lerp4(a: [f32; 4], b: [f32; 4], t: f32) -> [f32; 4] {
    [
        a[0] + t * (b[0] - a[0]),
        a[1] + t * (b[1] - a[1]),
        a[2] + t * (b[2] - a[2]),
        a[3] + t * (b[3] - a[3]),
    ]
}

/// The 8 trilinear sample indices and weights around each lane's point `p` on grid `g`.
#[inline(always)]
fn stencil_lanes(g: &Grid3, p: &[Lanes; 3]) -> ([[u32; L]; 8], [Lanes; 8]) {
    let (x0, x1, tx) = locate_lanes(&g.ax[0], &p[0]);
    let (y0, y1, ty) = locate_lanes(&g.ax[1], &p[1]);
    let (z0, z1, tz) = locate_lanes(&g.ax[2], &p[2]);
    let mut w = [[0f32; L]; 8];
    let mut idx = [[0u32; L]; 8];
    for l in 0..L {
        let (sx, sy, sz) = (1.0 - tx[l], 1.0 - ty[l], 1.0 - tz[l]);
        let (a, b, c, d) = (sy * sz, ty[l] * sz, sy * tz[l], ty[l] * tz[l]);
        w[0][l] = sx * a;
        w[1][l] = tx[l] * a;
        w[2][l] = sx * b;
        w[3][l] = tx[l] * b;
        w[4][l] = sx * c;
        w[5][l] = tx[l] * c;
        w[6][l] = sx * d;
        w[7][l] = tx[l] * d;
    }
    // Wrapping arithmetic: no overflow checks in the vectorised loop (indices < 2^30).
    for l in 0..L {
        let r = [
            y0[l].wrapping_add(z0[l]),
            y1[l].wrapping_add(z0[l]),
            y0[l].wrapping_add(z1[l]),
            y1[l].wrapping_add(z1[l]),
        ];
        for q in 0..4 {
            idx[2 * q][l] = r[q].wrapping_add(x0[l]);
            idx[2 * q + 1][l] = r[q].wrapping_add(x1[l]);
        }
    }
    (idx, w)
}

/// `sum_q w[q] field[idx[q]]` per lane.
#[inline(always)]
fn interpolate_lanes(field: &[f32], idx: &[[u32; L]; 8], w: &[Lanes; 8]) -> Lanes {
    let mut vals = [[0f32; L]; 8];
    for q in 0..8 {
        for l in 0..L {
            vals[q][l] = field[idx[q][l] as usize];
        }
    }
    let mut r = [0f32; L];
    for q in 0..8 {
        for l in 0..L {
            r[l] += w[q][l] * vals[q][l];
        }
    }
    r
}

impl Geometry {
    /// RK2 (midpoint) foot points of the `count` (<= L) consecutive x-faces of component `c` from
    /// face `f`, traced over `dt` (= dt / h) through the cell-centred velocity `v` (one array per
    /// component). Lanes past `count` repeat the last face.
    #[inline(always)]
    fn trace_lanes(
        &self,
        v: [&[f32]; 3],
        c: usize,
        f: [usize; 3],
        count: usize,
        dt: f32,
    ) -> [Lanes; 3] {
        let sh: [f32; 3] = std::array::from_fn(|a| if a == c { 0.0 } else { 0.5 });
        let mut x = [[0f32; L]; 3];
        let mut m = [[0f32; L]; 3];
        let h = 0.25 * dt;
        for l in 0..L {
            let fl = [f[0] + l.min(count - 1), f[1], f[2]];
            // At the face the centred field is the mean of the two cells beside it: two loads.
            let (lo, hi) = self.face_cells(c, fl);
            for d in 0..3 {
                x[d][l] = fl[d] as f32 + sh[d];
                m[d][l] = v[d][lo] + v[d][hi];
            }
        }
        for d in 0..3 {
            for l in 0..L {
                m[d][l] = x[d][l] - h * m[d][l];
            }
        }
        let (idx, w) = stencil_lanes(&self.centred, &m);
        let mut foot = [[0f32; L]; 3];
        for d in 0..3 {
            let vm = interpolate_lanes(v[d], &idx, &w);
            for l in 0..L {
                foot[d][l] = x[d][l] - dt * vm[l];
            }
        }
        foot
    }

    /// The 8 trilinear samples of component `c` of `field` around each lane's point, and their
    /// weights.
    #[inline(always)]
    fn gather_lanes(&self, c: usize, field: &[f32], p: &[Lanes; 3]) -> ([Lanes; 8], [Lanes; 8]) {
        let (idx, w) = stencil_lanes(&self.faces[c], p);
        let mut vals = [[0f32; L]; 8];
        for q in 0..8 {
            for l in 0..L {
                vals[q][l] = field[idx[q][l] as usize];
            }
        }
        (vals, w)
    }
}

/// Read-only inputs of one advection pass.
pub(crate) struct Pass<'a> {
    pub geo: &'a Geometry,
    pub plan: &'a Plan,
    /// Cell-centred velocity for the trace, one array per component.
    pub vc: [&'a [f32]; 3],
    /// Fields sampled at the foot points, per component.
    pub src: [&'a [f32]; 3],
    /// dt / h; negative for the forward trace of MacCormack.
    pub dt_cells: f32,
}

impl Pass<'_> {
    /// For every group of up to L faces of block `b`: traces them and gathers the samples of their
    /// component at the foot points, then calls `each(position within the block, count, samples,
    /// weights)`. Runs on the widest SIMD the CPU has (runtime dispatch).
    #[inline(always)]
    fn block(&self, b: usize, mut each: impl FnMut(usize, usize, &[Lanes; 8], &[Lanes; 8])) {
        let plan = self.plan;
        let runs = &plan.runs[plan.block_runs[b] as usize..plan.block_runs[b + 1] as usize];
        let base = b * BLOCK;
        let body = || {
                for run in runs {
                    let c = run.c as usize;
                    let f0 = run.f.map(|v| v as usize);
                    let o = run.compact as usize - base;
                    let len = run.len as usize;
                    let mut i = 0;
                    while i < len {
                        let count = (len - i).min(L);
                        let f = [f0[0] + i, f0[1], f0[2]];
                        let foot = self.geo.trace_lanes(self.vc, c, f, count, self.dt_cells);
                        let (vals, w) = self.geo.gather_lanes(c, self.src[c], &foot);
                        each(o + i, count, &vals, &w);
                        i += count;
                    }
                }
            };
        simd::dispatch(body)
    }

    /// Semi-Lagrangian values at every active face into `out` (concatenated compact order).
    pub fn semi_lagrangian(&self, out: &mut [f32], parallel: bool) {
        let task = |(b, os): (usize, &mut [f32])| {
            self.block(b, |n, count, vals, w| {
                let mut r = [0f32; L];
                for q in 0..8 {
                    for l in 0..L {
                        r[l] += w[q][l] * vals[q][l];
                    }
                }
                os[n..n + count].copy_from_slice(&r[..count]);
            })
        };
        if parallel {
            out.par_chunks_mut(BLOCK).enumerate().for_each(task);
        } else {
            out.chunks_mut(BLOCK).enumerate().for_each(task);
        }
    }

    /// As [`Pass::semi_lagrangian`], also writing the min and max of the samples used.
    pub fn semi_lagrangian_bounds(
        &self,
        out: &mut [f32],
        lo: &mut [f32],
        hi: &mut [f32],
        parallel: bool,
    ) {
        let task = |(b, ((os, ls), hs)): (usize, ((&mut [f32], &mut [f32]), &mut [f32]))| {
            self.block(b, |n, count, vals, w| {
                let mut r = [0f32; L];
                let mut mn = [f32::INFINITY; L];
                let mut mx = [f32::NEG_INFINITY; L];
                for q in 0..8 {
                    for l in 0..L {
                        r[l] += w[q][l] * vals[q][l];
                        mn[l] = mn[l].min(vals[q][l]);
                        mx[l] = mx[l].max(vals[q][l]);
                    }
                }
                os[n..n + count].copy_from_slice(&r[..count]);
                ls[n..n + count].copy_from_slice(&mn[..count]);
                hs[n..n + count].copy_from_slice(&mx[..count]);
            })
        };
        if parallel {
            out.par_chunks_mut(BLOCK)
                .zip(lo.par_chunks_mut(BLOCK))
                .zip(hi.par_chunks_mut(BLOCK))
                .enumerate()
                .for_each(task);
        } else {
            out.chunks_mut(BLOCK)
                .zip(lo.chunks_mut(BLOCK))
                .zip(hi.chunks_mut(BLOCK))
                .enumerate()
                .for_each(task);
        }
    }

    /// MacCormack correction (this pass traces forward and samples the backward-step field `hat`
    /// in `src`): `out` holds the backward-step values on entry and the corrected values clamped to
    /// `[lo, hi]` on return. `orig` is the compact field before the step.
    pub fn maccormack(
        &self,
        orig: &[f32],
        out: &mut [f32],
        lo: &[f32],
        hi: &[f32],
        parallel: bool,
    ) {
        type Slices<'s> = (((&'s mut [f32], &'s [f32]), &'s [f32]), &'s [f32]);
        let task = |(b, (((os, ls), hs), us)): (usize, Slices)| {
            self.block(b, |n, count, vals, w| {
                for l in 0..count {
                    let mut back = 0.0;
                    for q in 0..8 {
                        back += w[q][l] * vals[q][l];
                    }
                    let fwd = os[n + l];
                    let v = fwd + 0.5 * (us[n + l] - back);
                    os[n + l] = if v.is_finite() {
                        v.clamp(ls[n + l], hs[n + l])
                    } else {
                        fwd
                    };
                }
            })
        };
        if parallel {
            out.par_chunks_mut(BLOCK)
                .zip(lo.par_chunks(BLOCK))
                .zip(hi.par_chunks(BLOCK))
                .zip(orig.par_chunks(BLOCK))
                .enumerate()
                .for_each(task);
        } else {
            out.chunks_mut(BLOCK)
                .zip(lo.chunks(BLOCK))
                .zip(hi.chunks(BLOCK))
                .zip(orig.chunks(BLOCK))
                .enumerate()
                .for_each(task);
        }
    }
}

/// Copies the compact values of every run back into the full face arrays.
pub(crate) fn scatter(plan: &Plan, compact: &[f32], u: &mut [Vec<f32>; 3]) {
    for run in &plan.runs {
        let (f, n, len) = (run.full as usize, run.compact as usize, run.len as usize);
        u[run.c as usize][f..f + len].copy_from_slice(&compact[n..n + len]);
    }
}

/// Gathers the active faces of the full arrays into the concatenated compact order.
pub(crate) fn gather(plan: &Plan, u: [&[f32]; 3], compact: &mut [f32]) {
    for run in &plan.runs {
        let (f, n, len) = (run.full as usize, run.compact as usize, run.len as usize);
        compact[n..n + len].copy_from_slice(&u[run.c as usize][f..f + len]);
    }
}
