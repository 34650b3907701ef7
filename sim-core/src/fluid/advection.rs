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

/// Faces per chunk of the trace's split loops.
const CHAIN: usize = 64;

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
    /// Largest lower sample index (n - 2, or 0 for a single point).
    top: u32,
    stride: u32,
    /// Offset from a sample to the next one (0 for a single point).
    step: u32,
    periodic: bool,
    shift: f32,
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

/// Sampling geometry of a field with points `npts` per axis shifted by `shift`.
#[derive(Clone, Copy, Debug, Default)]
struct Grid3 {
    ax: [Axis; 3],
}

impl Grid3 {
    fn new(npts: [usize; 3], periodic: [bool; 3], shift: [f32; 3]) -> Self {
        let strides = [1, npts[0], npts[0] * npts[1]];
        Self {
            ax: std::array::from_fn(|a| Axis::new(npts[a], strides[a], periodic[a], shift[a])),
        }
    }
}

/// Four-lane vectors for positions and the centred velocity (the fourth lane is unused): one SSE
/// register on x86-64, where building them element-wise would go through memory (a stalled
/// store-to-load forward per face) and LLVM would drop the fourth lane and emit scalar code.
#[cfg(target_arch = "x86_64")]
pub(crate) mod v4 {
    use std::arch::x86_64::{
        __m128, _mm_add_ps, _mm_mul_ps, _mm_set1_ps, _mm_set_ps, _mm_setzero_ps, _mm_sub_ps,
    };
    // SAFETY (every `unsafe` below): SSE is part of the x86-64 baseline, so every x86-64 CPU has
    // it, and these intrinsics take no pointers.

    /// A vector.
    pub type V4 = __m128;
    /// `[a, b, c, 0]`.
    #[inline(always)]
    pub fn new(a: f32, b: f32, c: f32) -> V4 {
        unsafe { _mm_set_ps(0.0, c, b, a) }
    }
    /// All zero.
    #[inline(always)]
    pub fn zero() -> V4 {
        unsafe { _mm_setzero_ps() }
    }
    /// The lanes.
    #[inline(always)]
    pub fn lanes(v: V4) -> [f32; 4] {
        bytemuck::cast(v)
    }
    /// `a + b`.
    #[inline(always)]
    pub fn add(a: V4, b: V4) -> V4 {
        unsafe { _mm_add_ps(a, b) }
    }
    /// `a + t (b - a)`.
    #[inline(always)]
    pub fn lerp(a: V4, b: V4, t: f32) -> V4 {
        unsafe { _mm_add_ps(a, _mm_mul_ps(_mm_set1_ps(t), _mm_sub_ps(b, a))) }
    }
    /// `x - s v`.
    #[inline(always)]
    pub fn sub_scaled(x: V4, s: f32, v: V4) -> V4 {
        unsafe { _mm_sub_ps(x, _mm_mul_ps(_mm_set1_ps(s), v)) }
    }
}

/// Four-lane vectors (portable fallback).
#[cfg(not(target_arch = "x86_64"))]
pub(crate) mod v4 {
    /// A vector.
    pub type V4 = [f32; 4];
    /// `[a, b, c, 0]`.
    #[inline(always)]
    pub fn new(a: f32, b: f32, c: f32) -> V4 {
        [a, b, c, 0.0]
    }
    /// All zero.
    #[inline(always)]
    pub fn zero() -> V4 {
        [0.0; 4]
    }
    /// The lanes.
    #[inline(always)]
    pub fn lanes(v: V4) -> [f32; 4] {
        v
    }
    /// `a + b`.
    #[inline(always)]
    pub fn add(a: V4, b: V4) -> V4 {
        std::array::from_fn(|l| a[l] + b[l])
    }
    /// `a + t (b - a)`.
    #[inline(always)]
    pub fn lerp(a: V4, b: V4, t: f32) -> V4 {
        std::array::from_fn(|l| a[l] + t * (b[l] - a[l]))
    }
    /// `x - s v`.
    #[inline(always)]
    pub fn sub_scaled(x: V4, s: f32, v: V4) -> V4 {
        std::array::from_fn(|l| x[l] - s * v[l])
    }
}

use v4::lerp as lerp4;
pub(crate) use v4::V4;

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
    fn centred(&self, v: &[V4], p: V4) -> V4 {
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
    fn sample<const BOUNDS: bool>(&self, c: usize, field: &[f32], p: V4) -> (f32, f32, f32) {
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

    /// Centred-grid indices of the two cells beside face `f` of component `c` (clamped at a
    /// non-periodic boundary, wrapped at a periodic one).
    #[inline(always)]
    fn face_cells(&self, c: usize, f: [usize; 3]) -> (usize, usize) {
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

/// Runtime dispatch to the widest instruction set the CPU has (the shipped binary targets generic
/// x86-64, whose floor, min/max and FMA-free code is slower).
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
            if std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("fma")
            {
                // SAFETY: the CPU supports the features `avx2` is compiled for (checked above).
                unsafe { avx2(f) };
                return;
            }
        }
        f()
    }
}

/// Read-only inputs of one advection pass.
pub(crate) struct Pass<'a> {
    pub geo: &'a Geometry,
    pub plan: &'a Plan,
    /// Padded cell-centred velocity for the trace.
    pub vc: &'a [V4],
    /// Fields sampled at the foot points, per component.
    pub src: [&'a [f32]; 3],
    /// dt / h; negative for the forward trace of MacCormack.
    pub dt_cells: f32,
}

impl Pass<'_> {
    /// For every face of block `b`: traces it back (RK2 midpoint rule through the centred
    /// velocity) and samples its component of `src` at the foot point, then calls
    /// `each(position within the block, (value, min, max))` (min/max only when `BOUNDS`).
    #[inline(always)]
    fn block<const BOUNDS: bool>(&self, b: usize, mut each: impl FnMut(usize, (f32, f32, f32))) {
        let plan = self.plan;
        let runs = &plan.runs[plan.block_runs[b] as usize..plan.block_runs[b + 1] as usize];
        let base = b * BLOCK;
        let (geo, v, dt) = (self.geo, self.vc, self.dt_cells);
        let body = || {
            for run in runs {
                let c = run.c as usize;
                let f0 = run.f.map(|v| v as usize);
                let src = self.src[c];
                let o = run.compact as usize - base;
                let sh: [f32; 3] = std::array::from_fn(|a| if a == c { 0.0 } else { 0.5 });
                let mut x0 = v4::new(
                    f0[0] as f32 + sh[0],
                    f0[1] as f32 + sh[1],
                    f0[2] as f32 + sh[2],
                );
                let step = v4::new(1.0, 0.0, 0.0);
                // Three short loops over a chunk instead of one long one: each face's work is a
                // chain of dependent loads (velocity -> midpoint -> velocity -> foot -> samples),
                // and independent iterations let the CPU overlap many chains.
                let len = run.len as usize;
                let mut start = 0;
                while start < len {
                    let n = (len - start).min(CHAIN);
                    let mut pts = [v4::zero(); CHAIN];
                    let mut x = x0;
                    for (i, p) in pts[..n].iter_mut().enumerate() {
                        // At the face the centred field is the mean of the two cells beside it.
                        let (lo, hi) = geo.face_cells(c, [f0[0] + start + i, f0[1], f0[2]]);
                        *p = v4::sub_scaled(x, 0.5 * dt, lerp4(v[lo], v[hi], 0.5));
                        x = v4::add(x, step);
                    }
                    let mut x = x0;
                    for p in &mut pts[..n] {
                        *p = v4::sub_scaled(x, dt, geo.centred(v, *p));
                        x = v4::add(x, step);
                    }
                    for (i, p) in pts[..n].iter().enumerate() {
                        each(o + start + i, geo.sample::<BOUNDS>(c, src, *p));
                    }
                    x0 = x;
                    start += n;
                }
            }
        };
        simd::dispatch(body)
    }

    /// Semi-Lagrangian values at every active face into `out` (concatenated compact order).
    pub fn semi_lagrangian(&self, out: &mut [f32], parallel: bool) {
        let task = |(b, os): (usize, &mut [f32])| self.block::<false>(b, |n, r| os[n] = r.0);
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
        type Slices<'s> = ((&'s mut [f32], &'s mut [f32]), &'s mut [f32]);
        let task = |(b, ((os, ls), hs)): (usize, Slices)| {
            self.block::<true>(b, |n, r| (os[n], ls[n], hs[n]) = r)
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
            self.block::<false>(b, |n, (back, _, _)| {
                let fwd = os[n];
                let v = fwd + 0.5 * (us[n] - back);
                os[n] = if v.is_finite() {
                    v.clamp(ls[n], hs[n])
                } else {
                    fwd
                };
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

/// Averages the face velocities to the (padded) cell centres, row by row (z-slabs in parallel if
/// `parallel`).
pub(crate) fn update_centred(
    layout: &Layout,
    dims: [usize; 3],
    u: [&[f32]; 3],
    out: &mut [V4],
    parallel: bool,
) {
    let [nx, ny, nz] = dims;
    let fd = layout.fdims;
    let p = layout.periodic;
    let slab = |(k, slab): (usize, &mut [V4])| {
        let k1 = if k + 1 == nz && p[2] { 0 } else { k + 1 };
        for j in 0..ny {
            let j1 = if j + 1 == ny && p[1] { 0 } else { j + 1 };
            let row = &mut slab[nx * j..nx * (j + 1)];
            let r0 = fd[0][0] * (j + fd[0][1] * k);
            let x = &u[0][r0..r0 + fd[0][0]];
            let y0 = &u[1][nx * (j + fd[1][1] * k)..][..nx];
            let y1 = &u[1][nx * (j1 + fd[1][1] * k)..][..nx];
            let z0 = &u[2][nx * (j + ny * k)..][..nx];
            let z1 = &u[2][nx * (j + ny * k1)..][..nx];
            for (i, cell) in row.iter_mut().enumerate() {
                // The last x face wraps to the first on a periodic axis.
                let xh = if i + 1 < x.len() { x[i + 1] } else { x[0] };
                *cell = v4::new(
                    0.5 * (x[i] + xh),
                    0.5 * (y0[i] + y1[i]),
                    0.5 * (z0[i] + z1[i]),
                );
            }
        }
    };
    if parallel {
        out.par_chunks_mut(nx * ny).enumerate().for_each(slab);
    } else {
        out.chunks_mut(nx * ny).enumerate().for_each(slab);
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A deterministic pseudo-random sequence in [0, 1).
    fn lcg(state: &mut u64) -> f32 {
        *state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (*state >> 40) as f32 / (1u64 << 24) as f32
    }

    #[test]
    fn fast_sampling_matches_the_reference_interpolation_everywhere() {
        for periodic in [[false; 3], [true, false, true], [false, true, false]] {
            let dims = [5, 4, 6];
            let layout = Layout::new(dims, periodic);
            let geo = Geometry::new(dims, &layout);
            let mut st = 7u64;
            let fields: Vec<Vec<f32>> = (0..3)
                .map(|c| {
                    (0..layout.face_count(c))
                        .map(|_| lcg(&mut st) - 0.5)
                        .collect()
                })
                .collect();
            let cells = dims.iter().product::<usize>();
            let centred3: Vec<[f32; 3]> = (0..cells)
                .map(|_| [lcg(&mut st), lcg(&mut st), lcg(&mut st)])
                .collect();
            let centred: Vec<V4> = centred3.iter().map(|v| v4::new(v[0], v[1], v[2])).collect();
            for _ in 0..2000 {
                // Points inside, on sample positions, and far outside the grid.
                let p: [f32; 3] = std::array::from_fn(|a| {
                    let r = lcg(&mut st);
                    if r < 0.1 {
                        (lcg(&mut st) * 4.0).floor() * 0.5
                    } else {
                        (r - 0.5) * 3.0 * dims[a] as f32
                    }
                });
                let pv = v4::new(p[0], p[1], p[2]);
                for (c, field) in fields.iter().enumerate() {
                    let want = layout.sample_bounds(c, field, p);
                    let got = geo.sample::<true>(c, field, pv);
                    assert!(
                        (want.0 - got.0).abs() < 1e-5,
                        "{periodic:?} c {c} {p:?}: {want:?} {got:?}"
                    );
                    assert_eq!((want.1, want.2), (got.1, got.2), "{periodic:?} c {c} {p:?}");
                }
                let want = layout.sample_centred(dims, &centred3, p);
                let got = v4::lanes(geo.centred(&centred, pv));
                for a in 0..3 {
                    assert!(
                        (want[a] - got[a]).abs() < 1e-5,
                        "{periodic:?} {p:?}: {want:?} {got:?}"
                    );
                }
            }
        }
    }
}
