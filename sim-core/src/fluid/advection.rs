//! Semi-Lagrangian advection of the face velocities: RK2 (midpoint) backtrace, MacCormack
//! (a backward and a forward semi-Lagrangian step, error-corrected, clamped to the values the first
//! step interpolated from so it cannot create new extrema), BFECC (a third, backward step from the
//! error-compensated field, clamped alike) and monotone tricubic sampling. The reflection schemes
//! ([`AdvectionScheme::MacCormackReflection`], [`AdvectionScheme::MacCormackLaggedReflection`])
//! combine these passes with the projection in `solver.rs`.
//!
//! Layout for speed: the active faces of the three components are walked as runs of consecutive
//! faces along x (so a face's coordinates come from the loop, not from divisions), the results go to
//! one array concatenating the three components (so one rayon region covers the whole stage), and
//! the trace reads a padded cell-centred velocity (`[f32; 4]`: one 4-lane trilinear per sample).

use serde::{Deserialize, Serialize};

use super::sample::Layout;

/// Advection scheme.
///
/// Every scheme traces the RK2 (midpoint) characteristic through the cell-centred velocity, and
/// every scheme above first order clamps its result to the extrema of the eight samples the
/// trilinear step read (so it creates no new extrema and stays unconditionally stable).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum AdvectionScheme {
    /// Semi-Lagrangian with an RK2 (midpoint) backtrace: unconditionally stable, dissipative.
    SemiLagrangian,
    /// MacCormack on top of the RK2 semi-Lagrangian step, clamped: less dissipative, two traces.
    #[serde(rename = "maccormack")]
    MacCormack,
    /// Back and forth error compensation and correction (Kim, Liu, Llamas, Rossignac 2005), clamped:
    /// three traces (backward, forward, backward from the corrected field).
    Bfecc,
    /// Semi-Lagrangian with tricubic (Catmull-Rom) interpolation at the foot point, clamped to the
    /// trilinear stencil's extrema (monotone): one trace, 64 samples per face.
    MonotoneCubic,
    /// Advection-reflection (Zehnder, Narain, Thomaszewski 2018) with clamped MacCormack half steps:
    /// advect dt/2, project, reflect (`2 P u - u`), advect dt/2 through the projected velocity,
    /// project. Four traces and a second projection per step.
    #[serde(rename = "maccormack_reflection")]
    MacCormackReflection,
    /// Clamped MacCormack of `u - dt/2 grad (p - phi) / rho`, `p` being the last projection's
    /// pressure and `phi = rho g.x` the hydrostatic potential of the body force (along the
    /// non-periodic axes): advection-reflection's reflection with the intermediate projection's
    /// gradient replaced by the lagged one (the lagged pressure gradient of the predictor of Bell,
    /// Colella and Glaz 1989), traced through the divergence-free velocity before the reflection.
    /// Two traces and one projection, as MacCormack. Only in substeps up to CFL
    /// [`LAGGED_REFLECTION_MAX_CFL`](super::LAGGED_REFLECTION_MAX_CFL); above, plain MacCormack.
    /// The default: the least dissipative scheme at MacCormack's cost (BENCHMARKS.md, issue 17).
    #[default]
    #[serde(rename = "maccormack_lagged_reflection")]
    MacCormackLaggedReflection,
}

impl AdvectionScheme {
    /// Every scheme, in order of cost.
    pub const ALL: [AdvectionScheme; 6] = [
        Self::SemiLagrangian,
        Self::MacCormack,
        Self::MacCormackLaggedReflection,
        Self::Bfecc,
        Self::MonotoneCubic,
        Self::MacCormackReflection,
    ];

    /// The name used in case files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Self::SemiLagrangian => "semi_lagrangian",
            Self::MacCormack => "maccormack",
            Self::Bfecc => "bfecc",
            Self::MonotoneCubic => "monotone_cubic",
            Self::MacCormackReflection => "maccormack_reflection",
            Self::MacCormackLaggedReflection => "maccormack_lagged_reflection",
        }
    }

    /// The scheme called `name` ([`AdvectionScheme::name`]).
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|s| s.name() == name)
    }
}

/// Faces per chunk of the trace's split loops.
const CHAIN: usize = 64;

/// The block at which `len` compact faces split into two halves on two threads, if `parallel` and
/// there are at least two blocks.
fn split_block(len: usize, parallel: bool) -> Option<usize> {
    let blocks = len.div_ceil(BLOCK);
    (parallel && blocks >= 2).then_some(blocks / 2)
}

/// Faces per task (a block of the concatenated active faces).
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
    /// Rebuilds the runs from each component's runs of active faces (`[full, compact, len]`,
    /// ascending, each a whole run of consecutive faces of one x row: [`FaceSet::runs`]) and
    /// its number of active faces.
    ///
    /// [`FaceSet::runs`]: super::topology::FaceSet::runs
    pub fn rebuild(&mut self, layout: &Layout, runs: [&[[u32; 3]]; 3], counts: [usize; 3]) {
        self.runs.clear();
        self.block_runs.clear();
        let mut pos = 0usize;
        for (c, list) in runs.iter().enumerate() {
            self.offset[c] = pos;
            for &[first, n, len] in list.iter() {
                let (start, len) = (pos + n as usize, len as usize);
                // Cut at block boundaries.
                let mut done = 0usize;
                while done < len {
                    let at = start + done;
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
            }
            pos += counts[c];
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

/// Four-lane vectors for positions and the centred velocity (the fourth lane is unused), and the
/// elementary four-lane operations the particle and vortex kernels share: one SSE register on
/// x86-64, where building them element-wise would go through memory (a stalled
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
    /// `a - b`.
    #[inline(always)]
    pub fn sub(a: V4, b: V4) -> V4 {
        unsafe { _mm_sub_ps(a, b) }
    }
    /// `a b`.
    #[inline(always)]
    pub fn mul(a: V4, b: V4) -> V4 {
        unsafe { _mm_mul_ps(a, b) }
    }
    /// `[x, x, x, x]`.
    #[inline(always)]
    pub fn splat(x: f32) -> V4 {
        unsafe { _mm_set1_ps(x) }
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
    /// `a - b`.
    #[inline(always)]
    pub fn sub(a: V4, b: V4) -> V4 {
        std::array::from_fn(|l| a[l] - b[l])
    }
    /// `a b`.
    #[inline(always)]
    pub fn mul(a: V4, b: V4) -> V4 {
        std::array::from_fn(|l| a[l] * b[l])
    }
    /// `[x, x, x, x]`.
    #[inline(always)]
    pub fn splat(x: f32) -> V4 {
        [x; 4]
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

    /// Component `c` of `field` at `p` by tricubic (Catmull-Rom) interpolation, clamped to the min
    /// and max of the eight samples around `p` (the trilinear stencil), which are also returned.
    /// Near a clamped boundary the outer samples repeat the outermost one; NaN positions land on
    /// sample 0 as in [`Axis::locate`].
    #[inline(always)]
    fn sample_cubic(&self, c: usize, field: &[f32], p: V4) -> (f32, f32, f32) {
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
        #[cfg(target_arch = "x86_64")]
        if avx2::available() {
            // SAFETY: the CPU has AVX2 and FMA (checked by `available`).
            unsafe {
                avx2::block::<BOUNDS>(self, b, |o, m, v, lo, hi| {
                    for i in 0..m {
                        each(o + i, (v[i], lo[i], hi[i]));
                    }
                })
            };
            return;
        }
        self.block_scalar::<BOUNDS>(b, each)
    }

    /// [`Pass::block`] one face at a time (the fallback, and the reference of the AVX2 kernel).
    #[inline(always)]
    fn block_scalar<const BOUNDS: bool>(
        &self,
        b: usize,
        mut each: impl FnMut(usize, (f32, f32, f32)),
    ) {
        let geo = self.geo;
        self.trace_scalar::<false>(
            b,
            |c, src, p| geo.sample::<BOUNDS>(c, src, p),
            |n, r, _| each(n, r),
        )
    }

    /// [`Pass::block_scalar`] with the foot-point sampler `sample(component, field, point)`.
    #[inline(always)]
    fn block_scalar_with(
        &self,
        b: usize,
        sample: impl Fn(usize, &[f32], V4) -> (f32, f32, f32),
        mut each: impl FnMut(usize, (f32, f32, f32)),
    ) {
        self.trace_scalar::<false>(b, sample, |n, r, _| each(n, r))
    }

    /// [`Pass::block_scalar_with`], and with `FORWARD` also the foot point of the forward trace
    /// (the trace of this pass with `-dt_cells`, to the bit; zero without `FORWARD`):
    /// `each(position within the block, sample, forward foot)`.
    #[inline(always)]
    fn trace_scalar<const FORWARD: bool>(
        &self,
        b: usize,
        sample: impl Fn(usize, &[f32], V4) -> (f32, f32, f32),
        mut each: impl FnMut(usize, (f32, f32, f32), V4),
    ) {
        let plan = self.plan;
        let runs = &plan.runs[plan.block_runs[b] as usize..plan.block_runs[b + 1] as usize];
        let base = b * BLOCK;
        let (geo, v, dt) = (self.geo, self.vc, self.dt_cells);
        let dt_f = -dt;
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
                let mut pts_f = [v4::zero(); CHAIN];
                let mut x = x0;
                for i in 0..n {
                    // At the face the centred field is the mean of the two cells beside it.
                    let (lo, hi) = geo.face_cells(c, [f0[0] + start + i, f0[1], f0[2]]);
                    let vf = lerp4(v[lo], v[hi], 0.5);
                    pts[i] = v4::sub_scaled(x, 0.5 * dt, vf);
                    if FORWARD {
                        pts_f[i] = v4::sub_scaled(x, 0.5 * dt_f, vf);
                    }
                    x = v4::add(x, step);
                }
                let mut x = x0;
                for i in 0..n {
                    pts[i] = v4::sub_scaled(x, dt, geo.centred(v, pts[i]));
                    if FORWARD {
                        pts_f[i] = v4::sub_scaled(x, dt_f, geo.centred(v, pts_f[i]));
                    }
                    x = v4::add(x, step);
                }
                for i in 0..n {
                    each(o + start + i, sample(c, src, pts[i]), pts_f[i]);
                }
                x0 = x;
                start += n;
            }
        }
    }

    /// Semi-Lagrangian values at every active face into `out` (concatenated compact order).
    pub fn semi_lagrangian(&self, out: &mut [f32], parallel: bool) {
        let task = |(b, os): (usize, &mut [f32])| {
            #[cfg(target_arch = "x86_64")]
            if avx2::available() {
                // SAFETY: the CPU has AVX2 and FMA (checked by `available`).
                unsafe { avx2::block::<false>(self, b, |o, m, v, _, _| put(os, o, v, m)) };
                return;
            }
            self.block_scalar::<false>(b, |n, r| os[n] = r.0)
        };
        let blocks = |first: usize, out: &mut [f32]| {
            for (b, os) in out.chunks_mut(BLOCK).enumerate() {
                task((first + b, os));
            }
        };
        match split_block(out.len(), parallel) {
            Some(mid) => {
                let (a, b) = out.split_at_mut(mid * BLOCK);
                crate::fork_join::join(|| blocks(0, a), || blocks(mid, b));
            }
            None => blocks(0, out),
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
        let blocks = |first: usize, out: &mut [f32], lo: &mut [f32], hi: &mut [f32]| {
            let chunks = out.chunks_mut(BLOCK).zip(lo.chunks_mut(BLOCK));
            for (b, s) in chunks.zip(hi.chunks_mut(BLOCK)).enumerate() {
                task((first + b, s));
            }
        };
        match split_block(out.len(), parallel) {
            Some(mid) => {
                let at = mid * BLOCK;
                let ((o0, o1), (l0, l1), (h0, h1)) = (
                    out.split_at_mut(at),
                    lo.split_at_mut(at),
                    hi.split_at_mut(at),
                );
                crate::fork_join::join(|| blocks(0, o0, l0, h0), || blocks(mid, o1, l1, h1));
            }
            None => blocks(0, out, lo, hi),
        }
    }

    /// MacCormack's backward step and forward trace, in one pass: `hat` gets the semi-Lagrangian
    /// values at every active face, `lo` and `hi` the min and max of the samples they used, and
    /// `foot` (x, y, z) the foot points of the forward trace (this pass with `-dt_cells`), all in
    /// concatenated compact order. [`Pass::maccormack_correct`] finishes the step.
    pub fn maccormack_trace(
        &self,
        hat: &mut [f32],
        [lo, hi]: [&mut [f32]; 2],
        foot: [&mut [f32]; 3],
        parallel: bool,
    ) {
        let [fx, fy, fz] = foot;
        for_blocks(
            [hat, lo, hi, fx, fy, fz],
            [],
            parallel,
            |b, [os, ls, hs, xs, ys, zs], []| {
                #[cfg(target_arch = "x86_64")]
                if avx2::available() {
                    // SAFETY: the CPU has AVX2 and FMA (checked by `available`).
                    unsafe {
                        avx2::trace::<true, true>(self, b, |o, m, v, lo, hi, f| {
                            put(os, o, v, m);
                            put(ls, o, lo, m);
                            put(hs, o, hi, m);
                            put(xs, o, &f[0], m);
                            put(ys, o, &f[1], m);
                            put(zs, o, &f[2], m);
                        })
                    };
                    return;
                }
                let geo = self.geo;
                self.trace_scalar::<true>(
                    b,
                    |c, src, p| geo.sample::<true>(c, src, p),
                    |n, r, f| {
                        (os[n], ls[n], hs[n]) = r;
                        [xs[n], ys[n], zs[n], _] = v4::lanes(f);
                    },
                )
            },
        );
    }

    /// MacCormack's correction, this pass sampling the backward step's field in `src` (`u` off
    /// the active faces) at the forward feet `foot` of [`Pass::maccormack_trace`]: `out` holds the
    /// backward step's values on entry and the corrected values clamped to `[lo, hi]` on return
    /// ([`maccormack_value`]). `orig` is the full face arrays before the step.
    pub fn maccormack_correct(
        &self,
        orig: [&[f32]; 3],
        foot: [&[f32]; 3],
        [lo, hi]: [&[f32]; 2],
        out: &mut [f32],
        parallel: bool,
    ) {
        let [fx, fy, fz] = foot;
        for_blocks(
            [out],
            [fx, fy, fz, lo, hi],
            parallel,
            |b, [os], [xs, ys, zs, ls, hs]| {
                #[cfg(target_arch = "x86_64")]
                if avx2::available() {
                    // SAFETY: the CPU has AVX2 and FMA (checked by `available`).
                    unsafe { avx2::correct(self, b, orig, [xs, ys, zs], [ls, hs], os) };
                    return;
                }
                self.correct_scalar(b, orig, [xs, ys, zs], [ls, hs], os)
            },
        );
    }

    /// [`Pass::maccormack_correct`] on block `b` one face at a time (the fallback, and the
    /// reference of the AVX2 kernel): `foot`, `lo`, `hi` and `out` are the block's slices.
    fn correct_scalar(
        &self,
        b: usize,
        orig: [&[f32]; 3],
        [xs, ys, zs]: [&[f32]; 3],
        [ls, hs]: [&[f32]; 2],
        os: &mut [f32],
    ) {
        let (plan, base) = (self.plan, b * BLOCK);
        let runs = &plan.runs[plan.block_runs[b] as usize..plan.block_runs[b + 1] as usize];
        for run in runs {
            let c = run.c as usize;
            let (o, full) = (run.compact as usize - base, run.full as usize);
            for i in 0..run.len as usize {
                let n = o + i;
                let p = v4::new(xs[n], ys[n], zs[n]);
                let (back, _, _) = self.geo.sample::<false>(c, self.src[c], p);
                os[n] = maccormack_value(os[n], orig[c][full + i], back, ls[n], hs[n]);
            }
        }
    }
}

/// The first `m` of `v` to `out` from `o`: a fixed-size copy for whole vectors (one store, no
/// memcpy call).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn put(out: &mut [f32], o: usize, v: &[f32; 8], m: usize) {
    if m == 8 {
        out[o..o + 8].copy_from_slice(v);
    } else {
        out[o..o + m].copy_from_slice(&v[..m]);
    }
}

/// MacCormack's corrected value of a face: `hat + (u - back) / 2` (`hat` the backward step's
/// value, `u` the value before the step, `back` the forward step of `hat`), clamped to the
/// backward step's samples `[lo, hi]`; `hat` where that is not finite.
#[inline(always)]
fn maccormack_value(hat: f32, u: f32, back: f32, lo: f32, hi: f32) -> f32 {
    let v = hat + 0.5 * (u - back);
    if !v.is_finite() {
        return hat;
    }
    // `f32::clamp`'s order without its panic on NaN bounds.
    let v = if v < lo { lo } else { v };
    if v > hi {
        hi
    } else {
        v
    }
}

/// Runs `task(block, output blocks, input blocks)` over the blocks of the concatenated compact
/// arrays `outs` and `ins` (all of one length), in two halves on two threads if `parallel`.
fn for_blocks<const M: usize, const N: usize>(
    outs: [&mut [f32]; M],
    ins: [&[f32]; N],
    parallel: bool,
    task: impl Fn(usize, [&mut [f32]; M], [&[f32]; N]) + Sync,
) {
    let len = outs.first().map_or(0, |o| o.len());
    debug_assert!(outs.iter().all(|o| o.len() == len) && ins.iter().all(|i| i.len() == len));
    let run = |first: usize, mut outs: [&mut [f32]; M], ins: [&[f32]; N]| {
        let len = outs.first().map_or(0, |o| o.len());
        for (b, s) in (0..len).step_by(BLOCK).enumerate() {
            let e = (s + BLOCK).min(len);
            task(
                first + b,
                outs.each_mut().map(|o| &mut o[s..e]),
                ins.map(|i| &i[s..e]),
            );
        }
    };
    match split_block(len, parallel) {
        Some(mid) => {
            let at = mid * BLOCK;
            let mut halves = outs.map(|o| o.split_at_mut(at));
            let a = std::array::from_fn(|i| std::mem::take(&mut halves[i].0));
            let b = std::array::from_fn(|i| std::mem::take(&mut halves[i].1));
            let (ia, ib) = (ins.map(|i| &i[..at]), ins.map(|i| &i[at..]));
            crate::fork_join::join(|| run(0, a, ia), || run(mid, b, ib));
        }
        None => run(0, outs, ins),
    }
}

impl Pass<'_> {
    /// BFECC's error estimate (this pass traces forward and samples the backward-step field in
    /// `src`): `w` holds the field before the step on entry and `w + (w - forward) / 2` on return
    /// (unchanged where that is not finite).
    pub fn bfecc_source(&self, w: &mut [f32], parallel: bool) {
        for_blocks([w], [], parallel, |b, [ws], []| {
            self.block::<false>(b, |n, (fwd, _, _)| {
                let v = ws[n] + 0.5 * (ws[n] - fwd);
                if v.is_finite() {
                    ws[n] = v;
                }
            })
        });
    }

    /// Semi-Lagrangian values clamped to `[lo, hi]` into `out` (unchanged where not finite).
    pub fn clamped(&self, out: &mut [f32], lo: &[f32], hi: &[f32], parallel: bool) {
        for_blocks([out], [lo, hi], parallel, |b, [os], [ls, hs]| {
            self.block::<false>(b, |n, (v, _, _)| {
                if v.is_finite() {
                    // max/min (not clamp): no panic on inverted or NaN bounds.
                    os[n] = v.max(ls[n]).min(hs[n]);
                }
            })
        });
    }

    /// Monotone tricubic semi-Lagrangian values ([`Geometry::sample_cubic`]) into `out`.
    pub fn cubic(&self, out: &mut [f32], parallel: bool) {
        let geo = self.geo;
        for_blocks([out], [], parallel, |b, [os], []| {
            self.block_scalar_with(
                b,
                |c, src, p| geo.sample_cubic(c, src, p),
                |n, (v, _, _)| os[n] = v,
            )
        });
    }
}

/// How far (cells, along every axis) from an open (fluid or outflow) cell the centred velocity
/// can be non-zero. Only tracked faces hold velocity (see `FluidSolver::set_velocity_field`): a
/// fixed face touches an open cell; an active face lies between two open cells, and the
/// extrapolation layers reach two face steps from it. A cell averages the two faces on its sides
/// along each axis, so a cell that reads a face two steps beyond the active face between open
/// cells `i - 1` and `i` lies at `i - 3` or `i + 2`: two cells from an open cell. The test
/// `centred_velocity_on_the_open_rows_equals_the_whole_box` fails with 1.
pub(crate) const CENTRED_REACH: usize = 2;

/// The cells whose centred velocity [`update_centred`] computes: per cell row `j + ny k` the x
/// range `[first, end)` (empty: `first >= end`), and the z-slab that splits the work in halves.
#[derive(Clone, Debug, Default)]
pub(crate) struct CentredRows {
    pub ranges: Vec<[u32; 2]>,
    pub split_k: usize,
    /// Scratch: the ranges before the update, and the ranges dilated along y only.
    prev: Vec<[u32; 2]>,
    along_y: Vec<[u32; 2]>,
}

impl CentredRows {
    /// The rows' open ranges `open` (per cell row, `[0, 0]`: none) dilated by [`CENTRED_REACH`]
    /// cells along x, y and z (a box, so it holds the reach in any direction); the cells that
    /// leave the ranges are zeroed in `centred` (those that join hold zero: nothing wrote them
    /// since they last left).
    pub fn update(&mut self, open: &[[u32; 2]], dims: [usize; 3], centred: &mut [V4]) {
        let [nx, ny, nz] = dims;
        let r = CENTRED_REACH;
        let hull = super::topology::range_hull;
        // Along y, then along z, then widened along x.
        let tmp = &mut self.along_y;
        tmp.clear();
        tmp.resize(ny * nz, [0, 0]);
        for k in 0..nz {
            for j in 0..ny {
                let rows = j.saturating_sub(r)..(j + r + 1).min(ny);
                tmp[j + ny * k] = rows.fold([0, 0], |h, jj| hull(h, open[jj + ny * k]));
            }
        }
        std::mem::swap(&mut self.ranges, &mut self.prev);
        self.ranges.clear();
        for k in 0..nz {
            for j in 0..ny {
                let slabs = k.saturating_sub(r)..(k + r + 1).min(nz);
                let [a, b] = slabs.fold([0, 0], |h, kk| hull(h, tmp[j + ny * kk]));
                self.ranges.push(if a < b {
                    [a.saturating_sub(r as u32), (b + r as u32).min(nx as u32)]
                } else {
                    [0, 0]
                });
            }
        }
        // The z-slab before which half the work lies: a row's cells and its fixed cost.
        let slab_cells = |k: usize| -> usize {
            let ranges = &self.ranges[ny * k..ny * (k + 1)];
            ranges
                .iter()
                .filter(|&&[a, b]| a < b)
                .map(|&[a, b]| (b - a) as usize + ROW_COST)
                .sum()
        };
        let cells: usize = (0..nz).map(slab_cells).sum();
        let mut done = 0;
        self.split_k = (0..nz)
            .find(|&k| {
                done += slab_cells(k);
                2 * done >= cells
            })
            .map_or(nz, |k| k + 1);
        // Cells that left the ranges.
        if self.prev.len() == self.ranges.len() {
            for (row, (&[oa, ob], &[na, nb])) in self.prev.iter().zip(&self.ranges).enumerate() {
                let base = nx * row;
                let mut zero = |a: u32, b: u32| {
                    if a < b {
                        centred[base + a as usize..base + b as usize].fill(v4::zero());
                    }
                };
                if na >= nb {
                    zero(oa, ob);
                } else {
                    zero(oa, ob.min(na));
                    zero(oa.max(nb), ob);
                }
            }
        } else {
            centred.fill(v4::zero());
        }
    }
}

/// The fixed cost of a row of [`update_centred`], in cells: its halves, balanced by cells alone,
/// took 88 and 44 us on the 0.6 mm scene, the fragmented end of the cavity (many short rows) in
/// the first; 32 gave 70 / 54 us, 64 gives 46-49 / 47-49 us (BENCHMARKS.md, "Residual maximum and
/// the split, session 13").
const ROW_COST: usize = 64;

/// Averages the face velocities to the (padded) cell centres, row by row (z-slabs in parallel if
/// `parallel`): every cell, or only the cells of `rows` (not on a periodic layout).
pub(crate) fn update_centred(
    layout: &Layout,
    dims: [usize; 3],
    u: [&[f32]; 3],
    out: &mut [V4],
    rows: Option<&CentredRows>,
    parallel: bool,
) {
    let [nx, ny, nz] = dims;
    let fd = layout.fdims;
    let p = layout.periodic;
    debug_assert!(rows.is_none() || p == [false; 3]);
    let slab = |(k, slab): (usize, &mut [V4])| {
        let k1 = if k + 1 == nz && p[2] { 0 } else { k + 1 };
        for j in 0..ny {
            let [a, b] = match rows {
                Some(r) => r.ranges[j + ny * k].map(|v| v as usize),
                None => [0, nx],
            };
            if a >= b {
                continue;
            }
            let j1 = if j + 1 == ny && p[1] { 0 } else { j + 1 };
            let row = &mut slab[nx * j..nx * (j + 1)];
            let r0 = fd[0][0] * (j + fd[0][1] * k);
            let x = &u[0][r0..r0 + fd[0][0]];
            let y0 = &u[1][nx * (j + fd[1][1] * k)..][..nx];
            let y1 = &u[1][nx * (j1 + fd[1][1] * k)..][..nx];
            let z0 = &u[2][nx * (j + ny * k)..][..nx];
            let z1 = &u[2][nx * (j + ny * k1)..][..nx];
            // The AVX2 rows do the full groups of eight cells whose upper x face is in the row.
            let mut done = a;
            #[cfg(target_arch = "x86_64")]
            if avx2::available() {
                let (xs, ys, zs) = (&x[a..], [&y0[a..b], &y1[a..b]], [&z0[a..b], &z1[a..b]]);
                // SAFETY: the CPU has AVX2 and FMA (checked by `available`).
                done += unsafe { avx2::centred_row(&mut row[a..b], xs, ys, zs) };
            }
            for (i, cell) in row.iter_mut().enumerate().take(b).skip(done) {
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
    let slabs = |first: usize, out: &mut [V4]| {
        for (k, sl) in out.chunks_mut(nx * ny).enumerate() {
            slab((first + k, sl));
        }
    };
    let mid = rows.map_or(nz / 2, |r| r.split_k);
    if parallel && nz >= 2 && mid > 0 && mid < nz {
        let (a, b) = out.split_at_mut(mid * nx * ny);
        crate::fork_join::join(|| slabs(0, a), || slabs(mid, b));
    } else {
        slabs(0, out);
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

/// The trace eight faces at a time with AVX2 + FMA (runtime dispatch: the shipped binary targets
/// generic x86-64).
///
/// The one SIMD style of the fluid stages in this module, `viscosity.rs` and `solver.rs`: portable
/// loops written so LLVM vectorises them, compiled a second time inside a
/// `#[target_feature(enable = "avx2,fma")]` wrapper that runs when [`avx2::available`] says so;
/// raw intrinsics only where the compiler cannot vectorise (this trace: gathers, lane transposes).
/// Not pulp (the multigrid's): explicit pulp kernels were 2-10x slower than the auto-vectorised
/// loops (BENCHMARKS.md, "Tried and dropped"), and the wrappers compile to the same code as before. The faces of a run are consecutive along x, so a vector is eight faces of one
/// run; the centred velocity is gathered lane-wise from the `V4` array (`4 cell + component`).
#[cfg(target_arch = "x86_64")]
pub(crate) mod avx2 {
    use std::arch::x86_64::*;

    use super::{Axis, Pass, BLOCK, V4};

    /// Vectors (of eight faces) per chunk of the trace's split loops.
    const CHUNK_VECTORS: usize = 4;

    /// Whether the CPU has AVX2 and FMA (`is_x86_feature_detected` caches its answer).
    #[inline]
    pub fn available() -> bool {
        is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma")
    }

    /// An [`Axis`] broadcast to eight lanes, its strides times `scale`.
    #[derive(Clone, Copy)]
    struct AxisV {
        periodic: bool,
        /// The upper sample is always the next one in memory (clamped axis, n > 1, stride 1).
        pairs: bool,
        /// Offset from the lower to the upper sample, the same in every lane (`step` on a clamped
        /// axis, where `locate` keeps the lower index at most n - 2), or `None` (periodic).
        fixed_step: Option<i32>,
        shift: __m256,
        last: __m256,
        top: __m256i,
        stride: __m256i,
        step: __m256i,
        n: __m256,
        inv_n: __m256,
        n_last: __m256i,
    }

    impl AxisV {
        #[target_feature(enable = "avx2,fma")]
        fn new(a: &Axis, scale: u32) -> Self {
            Self {
                periodic: a.periodic,
                pairs: !a.periodic && a.n > 1 && a.stride * scale == 1,
                fixed_step: (!a.periodic).then_some((a.step * scale) as i32),
                shift: _mm256_set1_ps(a.shift),
                last: _mm256_set1_ps(a.last),
                top: _mm256_set1_epi32(a.top as i32),
                stride: _mm256_set1_epi32((a.stride * scale) as i32),
                step: _mm256_set1_epi32((a.step * scale) as i32),
                n: _mm256_set1_ps(a.n as f32),
                inv_n: _mm256_set1_ps(1.0 / a.n as f32),
                n_last: _mm256_set1_epi32(a.n - 1),
            }
        }

        /// [`Axis::locate`] for eight positions. Every index lands in `[0, n)` whatever the input
        /// (NaN and infinities included): that is what keeps the gathers in bounds.
        #[target_feature(enable = "avx2,fma")]
        fn locate(&self, p: __m256) -> (__m256i, __m256i, __m256) {
            let zero = _mm256_setzero_ps();
            let s = _mm256_sub_ps(p, self.shift);
            if self.periodic {
                let fl = _mm256_floor_ps(s);
                let t = _mm256_sub_ps(s, fl);
                // fl mod n in floats (exact below 2^24; the quotient may be off by one, fixed
                // below), then clamped so NaN, infinities and huge values still give an index.
                let q = _mm256_floor_ps(_mm256_mul_ps(fl, self.inv_n));
                let mut r = _mm256_fnmadd_ps(q, self.n, fl);
                let neg = _mm256_cmp_ps::<_CMP_LT_OQ>(r, zero);
                r = _mm256_add_ps(r, _mm256_and_ps(neg, self.n));
                let over = _mm256_cmp_ps::<_CMP_GE_OQ>(r, self.n);
                r = _mm256_sub_ps(r, _mm256_and_ps(over, self.n));
                // max returns its second operand for a NaN: NaN -> 0.
                let r = _mm256_min_ps(
                    _mm256_max_ps(r, zero),
                    _mm256_sub_ps(self.n, _mm256_set1_ps(1.0)),
                );
                let i0 = _mm256_cvttps_epi32(r);
                let wrap = _mm256_cmpeq_epi32(i0, self.n_last);
                let i1 = _mm256_andnot_si256(wrap, _mm256_add_epi32(i0, _mm256_set1_epi32(1)));
                (
                    _mm256_mullo_epi32(i0, self.stride),
                    _mm256_mullo_epi32(i1, self.stride),
                    t,
                )
            } else {
                // max returns its second operand for a NaN: NaN -> 0.
                let s = _mm256_min_ps(_mm256_max_ps(s, zero), self.last);
                let i0 = _mm256_min_epi32(_mm256_cvttps_epi32(s), self.top);
                let o0 = _mm256_mullo_epi32(i0, self.stride);
                (
                    o0,
                    _mm256_add_epi32(o0, self.step),
                    _mm256_sub_ps(s, _mm256_cvtepi32_ps(i0)),
                )
            }
        }
    }

    /// `a + t (b - a)`. Here and in the trace: no FMA, the scalar code's operations in its
    /// order, so both paths round alike (FMA gains nothing in this gather-bound kernel, and
    /// bit-equal results keep the fallback an exact reference).
    #[target_feature(enable = "avx2,fma")]
    fn lerp(a: __m256, b: __m256, t: __m256) -> __m256 {
        _mm256_add_ps(a, _mm256_mul_ps(t, _mm256_sub_ps(b, a)))
    }

    /// `x - s v`.
    #[target_feature(enable = "avx2,fma")]
    fn sub_scaled(x: __m256, s: __m256, v: __m256) -> __m256 {
        _mm256_sub_ps(x, _mm256_mul_ps(s, v))
    }

    /// Largest lane of `v` (for the debug checks of gather indices).
    #[target_feature(enable = "avx2,fma")]
    fn max_lane(v: __m256i) -> i32 {
        let mut a = [0i32; 8];
        // SAFETY: `a` has room for eight lanes.
        unsafe { _mm256_storeu_si256(a.as_mut_ptr().cast(), v) };
        a.into_iter().max().unwrap_or(0)
    }

    /// Smallest lane of `v`.
    #[target_feature(enable = "avx2,fma")]
    fn min_lane(v: __m256i) -> i32 {
        let mut a = [0i32; 8];
        // SAFETY: `a` has room for eight lanes.
        unsafe { _mm256_storeu_si256(a.as_mut_ptr().cast(), v) };
        a.into_iter().min().unwrap_or(0)
    }

    /// Gathers `base[idx]`.
    ///
    /// # Safety
    /// Every lane of `idx` must be in `[0, len)`, `len` being the number of f32 readable at `base`.
    #[target_feature(enable = "avx2,fma")]
    #[inline]
    unsafe fn gather(base: *const f32, len: usize, idx: __m256i) -> __m256 {
        debug_assert!(min_lane(idx) >= 0 && (max_lane(idx) as usize) < len);
        // SAFETY: in bounds by the caller's contract.
        unsafe { _mm256_i32gather_ps::<4>(base, idx) }
    }

    /// [`super::update_centred`] on one row, eight cells at a time while the upper x face of all
    /// eight is in the row (`x[i + 1]`, no wrap): the same operations as the scalar loop, so the
    /// same values. Returns the number of cells done (a multiple of eight).
    ///
    /// # Safety
    /// The CPU must have AVX2 and FMA.
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn centred_row(
        row: &mut [V4],
        x: &[f32],
        y: [&[f32]; 2],
        z: [&[f32]; 2],
    ) -> usize {
        let n = row.len().min(x.len().saturating_sub(1));
        let n = n
            .min(y[0].len())
            .min(y[1].len())
            .min(z[0].len())
            .min(z[1].len());
        let half = _mm256_set1_ps(0.5);
        let zero = _mm256_setzero_ps();
        let mut i = 0;
        while i + 8 <= n {
            // SAFETY: i + 8 <= n, so every load (x up to i + 8 inclusive) and store is inside its
            // slice (n is below all their lengths, and below x.len() - 1).
            unsafe {
                let ld = |s: &[f32], o: usize| _mm256_loadu_ps(s.as_ptr().add(o));
                let vx = _mm256_mul_ps(half, _mm256_add_ps(ld(x, i), ld(x, i + 1)));
                let vy = _mm256_mul_ps(half, _mm256_add_ps(ld(y[0], i), ld(y[1], i)));
                let vz = _mm256_mul_ps(half, _mm256_add_ps(ld(z[0], i), ld(z[1], i)));
                // Eight (x, y, z, 0) cells from the three lane vectors.
                let t0 = _mm256_unpacklo_ps(vx, vy);
                let t1 = _mm256_unpackhi_ps(vx, vy);
                let t2 = _mm256_unpacklo_ps(vz, zero);
                let t3 = _mm256_unpackhi_ps(vz, zero);
                let r0 = _mm256_shuffle_ps::<0x44>(t0, t2); // cells 0 | 4
                let r1 = _mm256_shuffle_ps::<0xEE>(t0, t2); // cells 1 | 5
                let r2 = _mm256_shuffle_ps::<0x44>(t1, t3); // cells 2 | 6
                let r3 = _mm256_shuffle_ps::<0xEE>(t1, t3); // cells 3 | 7
                let out = row.as_mut_ptr().add(i).cast::<f32>();
                _mm256_storeu_ps(out, _mm256_permute2f128_ps::<0x20>(r0, r1));
                _mm256_storeu_ps(out.add(8), _mm256_permute2f128_ps::<0x20>(r2, r3));
                _mm256_storeu_ps(out.add(16), _mm256_permute2f128_ps::<0x31>(r0, r1));
                _mm256_storeu_ps(out.add(24), _mm256_permute2f128_ps::<0x31>(r2, r3));
            }
            i += 8;
        }
        i
    }

    /// Stores the eight lanes of `v`.
    #[target_feature(enable = "avx2,fma")]
    #[inline]
    fn lanes_i32(v: __m256i) -> [i32; 8] {
        let mut a = [0i32; 8];
        // SAFETY: `a` has room for eight lanes.
        unsafe { _mm256_storeu_si256(a.as_mut_ptr().cast(), v) };
        a
    }

    /// Four registers each holding two `V4`, `r[p] = [lane p | lane p + 4]`, to three registers of
    /// eight lanes (x, y, z) in lane order.
    #[target_feature(enable = "avx2,fma")]
    #[inline]
    fn transpose(r: [__m256; 4]) -> [__m256; 3] {
        let t0 = _mm256_unpacklo_ps(r[0], r[1]);
        let t1 = _mm256_unpackhi_ps(r[0], r[1]);
        let t2 = _mm256_unpacklo_ps(r[2], r[3]);
        let t3 = _mm256_unpackhi_ps(r[2], r[3]);
        [
            _mm256_shuffle_ps::<0x44>(t0, t2),
            _mm256_shuffle_ps::<0xEE>(t0, t2),
            _mm256_shuffle_ps::<0x44>(t1, t3),
        ]
    }

    /// The centred velocity field for the vector trace. Zen 3 runs a gather as ~40 micro-ops,
    /// so the `V4` of a cell is one 16-byte load instead, two faces per register (lanes p and
    /// p + 4, which `transpose` turns back into lane order): 4-lane lerps on two faces at once.
    #[derive(Clone, Copy)]
    pub(super) struct Centred {
        ax: [AxisV; 3],
        ptr: *const V4,
        len: usize,
        /// Per pair p, the lane indices `[p; 4] ++ [p + 4; 4]` (weights to the pair layout).
        pair: [__m256i; 4],
        /// Without a periodic axis, the offsets in bytes of the eight corners from the first (x
        /// fastest, then y, then z).
        corner_bytes: Option<[usize; 8]>,
    }

    impl Centred {
        #[target_feature(enable = "avx2,fma")]
        pub(super) fn new(geo: &super::Geometry, v: &[V4]) -> Self {
            // The centred grid has one sample per cell (`Axis::new` with the cell dims), so the
            // offsets `locate` returns are cells of `v`.
            assert_eq!(v.len(), geo.dims.iter().product::<usize>());
            Self {
                ax: std::array::from_fn(|a| AxisV::new(&geo.centred.ax[a], 1)),
                ptr: v.as_ptr(),
                len: v.len(),
                pair: std::array::from_fn(|p| {
                    let (a, b) = (p as i32, p as i32 + 4);
                    _mm256_setr_epi32(a, a, a, a, b, b, b, b)
                }),
                corner_bytes: corner_offsets(geo.centred.ax.map(|a| AxisV::new(&a, 1).fixed_step))
                    .map(|o| o.map(|o| o as usize * std::mem::size_of::<V4>())),
            }
        }

        /// The `V4` of cells `lo` (low half) and `hi` (high half).
        ///
        /// # Safety
        /// Both must be below `len`.
        #[target_feature(enable = "avx2,fma")]
        #[inline]
        unsafe fn pair_at(&self, lo: i32, hi: i32) -> __m256 {
            debug_assert!(lo >= 0 && hi >= 0 && (lo.max(hi) as usize) < self.len);
            // SAFETY: both cells are in `v` (the caller's contract); `V4` is 16 bytes.
            unsafe {
                _mm256_loadu2_m128(
                    self.ptr.add(hi as usize).cast(),
                    self.ptr.add(lo as usize).cast(),
                )
            }
        }

        /// The mean of the `V4` at cells `a` and `b` per lane (the velocity at a face).
        ///
        /// # Safety
        /// All lanes must be cells (below `len`).
        #[target_feature(enable = "avx2,fma")]
        pub(super) unsafe fn mean(&self, a: __m256i, b: __m256i) -> [__m256; 3] {
            let (a, b) = (lanes_i32(a), lanes_i32(b));
            let half = _mm256_set1_ps(0.5);
            let r: [__m256; 4] = std::array::from_fn(|p| {
                // SAFETY: cells by the caller's contract.
                let (va, vb) =
                    unsafe { (self.pair_at(a[p], a[p + 4]), self.pair_at(b[p], b[p + 4])) };
                lerp(va, vb, half)
            });
            transpose(r)
        }

        /// [`super::Geometry::centred`] at eight points.
        ///
        /// # Safety
        /// The CPU must have AVX2 and FMA. Not a `target_feature` function, so that it can be
        /// `inline(always)` (the callers are, and the intrinsics inline there): called twice per
        /// face, it must not be a call with its vectors passed through memory.
        #[inline(always)]
        pub(super) unsafe fn sample(&self, p: [__m256; 3]) -> [__m256; 3] {
            // SAFETY: the CPU has AVX2 and FMA (the caller's contract); the loads are in bounds
            // as said at each.
            unsafe {
                let (x0, x1, tx) = self.ax[0].locate(p[0]);
                let (y0, y1, ty) = self.ax[1].locate(p[1]);
                let (z0, z1, tz) = self.ax[2].locate(p[2]);
                let mut out = [_mm256_setzero_ps(); 4];
                // Pair p (lanes p and p + 4) lerped from its eight corners `$v(p, k)` (rows (y, z)
                // 00, 10, 01, 11, each at x0 and x1).
                macro_rules! pairs {
                    ($v:expr) => {
                        for (p, o) in out.iter_mut().enumerate() {
                            let g = |k: usize| ($v)(p, k);
                            let wx = _mm256_permutevar8x32_ps(tx, self.pair[p]);
                            let wy = _mm256_permutevar8x32_ps(ty, self.pair[p]);
                            let wz = _mm256_permutevar8x32_ps(tz, self.pair[p]);
                            let c0 = lerp(lerp(g(0), g(1), wx), lerp(g(2), g(3), wx), wy);
                            let c1 = lerp(lerp(g(4), g(5), wx), lerp(g(6), g(7), wx), wy);
                            *o = lerp(c0, c1, wz);
                        }
                    };
                }
                if let Some(off) = self.corner_bytes {
                    // No periodic axis: the corners are fixed offsets from the first, one index per
                    // lane instead of eight (and the loads address `first + offset` directly).
                    let first = lanes_i32(_mm256_add_epi32(_mm256_add_epi32(y0, z0), x0));
                    pairs!(|p: usize, k: usize| {
                        debug_assert!((first[p].max(first[p + 4]) as usize) < self.len);
                        // In bounds: `locate` keeps each lower index at most n - 2 on a clamped
                        // axis (0 for a single cell, whose step is 0), so every corner is a cell.
                        let lo = self.ptr.add(first[p] as usize).byte_add(off[k]);
                        let hi = self.ptr.add(first[p + 4] as usize).byte_add(off[k]);
                        _mm256_loadu2_m128(hi.cast(), lo.cast())
                    });
                } else {
                    let rows = [
                        _mm256_add_epi32(y0, z0),
                        _mm256_add_epi32(y1, z0),
                        _mm256_add_epi32(y0, z1),
                        _mm256_add_epi32(y1, z1),
                    ];
                    let corner: [[i32; 8]; 8] = std::array::from_fn(|k| {
                        lanes_i32(_mm256_add_epi32(
                            rows[k / 2],
                            if k % 2 == 0 { x0 } else { x1 },
                        ))
                    });
                    // In bounds: `locate` keeps every axis index in range, so the corners are cells.
                    pairs!(|p: usize, k: usize| self.pair_at(corner[k][p], corner[k][p + 4]));
                }
                transpose(out)
            }
        }
    }

    /// The offsets of the eight corners of a trilinear stencil from the first (x fastest, then y,
    /// then z), if every axis has a fixed step ([`AxisV::fixed_step`]).
    fn corner_offsets(steps: [Option<i32>; 3]) -> Option<[i32; 8]> {
        let [sx, sy, sz] = [steps[0]?, steps[1]?, steps[2]?];
        Some(std::array::from_fn(|k| {
            let bit = |b: usize, s: i32| if k >> b & 1 == 1 { s } else { 0 };
            bit(0, sx) + bit(1, sy) + bit(2, sz)
        }))
    }

    /// [`super::Geometry::sample`] of component `c` at eight points: (value, min, max).
    ///
    /// # Safety
    /// The CPU must have AVX2 and FMA, and `field` must be a full face array of component `c`
    /// (`layout.face_count(c)` values). Not a `target_feature` function, so that it can be
    /// `inline(always)`, as [`Centred::sample`].
    #[inline(always)]
    unsafe fn sample_face<const BOUNDS: bool>(
        ax: &[AxisV; 3],
        field: &[f32],
        p: [__m256; 3],
    ) -> (__m256, __m256, __m256) {
        // SAFETY: the CPU has AVX2 and FMA (the caller's contract); the loads are in bounds as
        // said at each.
        unsafe {
            let (x0, x1, tx) = ax[0].locate(p[0]);
            let (y0, y1, ty) = ax[1].locate(p[1]);
            let (z0, z1, tz) = ax[2].locate(p[2]);
            let r = [
                _mm256_add_epi32(y0, z0),
                _mm256_add_epi32(y1, z0),
                _mm256_add_epi32(y0, z1),
                _mm256_add_epi32(y1, z1),
            ];
            let (ptr, len) = (field.as_ptr(), field.len());
            let s: [__m256; 8] = if ax[0].pairs {
                // x1 = x0 + 1 in every lane: one 8-byte load per row and face instead of gathers
                // (~40 micro-ops each on Zen 3), then even/odd floats split into x0 and x1 lanes.
                // Faces are loaded in the order (0, 1, 4, 5) and (2, 3, 6, 7) so that the in-lane
                // shuffles come out in lane order.
                let mut s = [_mm256_setzero_ps(); 8];
                // Row q's eight pairs from `$at(q, lane)`, the address of the lower float.
                macro_rules! rows {
                    ($at:expr) => {
                        for q in 0..4 {
                            let ld = |l: usize| {
                                let at: *const f32 = ($at)(q, l);
                                // In bounds: `locate` keeps x0 <= n - 2 on a clamped axis with
                                // n > 1 (`pairs`), so both floats of each pair are faces of the
                                // array (its length is the caller's contract).
                                at.cast::<i64>().read_unaligned()
                            };
                            let a =
                                _mm256_castsi256_ps(_mm256_setr_epi64x(ld(0), ld(1), ld(4), ld(5)));
                            let b =
                                _mm256_castsi256_ps(_mm256_setr_epi64x(ld(2), ld(3), ld(6), ld(7)));
                            s[2 * q] = _mm256_shuffle_ps::<0x88>(a, b);
                            s[2 * q + 1] = _mm256_shuffle_ps::<0xDD>(a, b);
                        }
                    };
                }
                if let (Some(sy), Some(sz)) = (ax[1].fixed_step, ax[2].fixed_step) {
                    // Clamped y and z: the rows are fixed offsets from the first, one index per lane
                    // instead of four (and the loads address `first + offset` directly).
                    let first = lanes_i32(_mm256_add_epi32(r[0], x0));
                    let f32_bytes = std::mem::size_of::<f32>();
                    let off = [0, sy, sz, sy + sz].map(|o| o as usize * f32_bytes);
                    rows!(|q: usize, l: usize| {
                        debug_assert!(first[l] >= 0 && first[l] as usize + off[q] / 4 + 1 < len);
                        ptr.add(first[l] as usize).byte_add(off[q])
                    });
                } else {
                    let i = r.map(|r| lanes_i32(_mm256_add_epi32(r, x0)));
                    rows!(|q: usize, l: usize| {
                        debug_assert!(i[q][l] >= 0 && (i[q][l] as usize) + 1 < len);
                        ptr.add(i[q][l] as usize)
                    });
                }
                s
            } else {
                // In bounds: `locate` keeps each axis index below that axis' face count, so the
                // offsets index faces of the array (the caller's contract gives its length).
                std::array::from_fn(|k| {
                    gather(
                        ptr,
                        len,
                        _mm256_add_epi32(r[k / 2], if k % 2 == 0 { x0 } else { x1 }),
                    )
                })
            };
            let (mut lo, mut hi) = (_mm256_setzero_ps(), _mm256_setzero_ps());
            if BOUNDS {
                lo = s[0];
                hi = s[0];
                for &v in &s[1..] {
                    lo = _mm256_min_ps(lo, v);
                    hi = _mm256_max_ps(hi, v);
                }
            }
            let c0 = lerp(lerp(s[0], s[1], tx), lerp(s[2], s[3], tx), ty);
            let c1 = lerp(lerp(s[4], s[5], tx), lerp(s[6], s[7], tx), ty);
            (lerp(c0, c1, tz), lo, hi)
        }
    }

    /// [`Pass::block`] eight faces at a time: `each(position within the block, valid lanes,
    /// values, min, max)`.
    ///
    /// # Safety
    /// The CPU must have AVX2 and FMA.
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn block<const BOUNDS: bool>(
        pass: &Pass,
        b: usize,
        mut each: impl FnMut(usize, usize, &[f32; 8], &[f32; 8], &[f32; 8]),
    ) {
        // SAFETY: the caller's contract.
        unsafe { trace::<BOUNDS, false>(pass, b, |o, m, v, lo, hi, _| each(o, m, v, lo, hi)) }
    }

    /// [`Pass::block`] eight faces at a time, and with `FORWARD` also the forward trace's foot
    /// points (the trace of the same pass with `-dt_cells`, to the bit): `each(position within
    /// the block, valid lanes, values, min, max, forward foot x, y, z)`. The two traces share the
    /// velocity at the face and run side by side (their gathers overlap).
    ///
    /// # Safety
    /// The CPU must have AVX2 and FMA.
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn trace<const BOUNDS: bool, const FORWARD: bool>(
        pass: &Pass,
        b: usize,
        mut each: impl FnMut(usize, usize, &[f32; 8], &[f32; 8], &[f32; 8], &[[f32; 8]; 3]),
    ) {
        let plan = pass.plan;
        let runs = &plan.runs[plan.block_runs[b] as usize..plan.block_runs[b + 1] as usize];
        let base = b * BLOCK;
        let geo = pass.geo;
        let centred = Centred::new(geo, pass.vc);
        let dims = geo.dims.map(|d| d as i32);
        let dt = _mm256_set1_ps(pass.dt_cells);
        let half_dt = _mm256_set1_ps(0.5 * pass.dt_cells);
        // The forward trace's steps, as a pass with `-dt_cells` would compute them.
        let dt_f = _mm256_set1_ps(-pass.dt_cells);
        let half_dt_f = _mm256_set1_ps(0.5 * -pass.dt_cells);
        let lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
        let (mut vo, mut lo, mut hi) = ([0f32; 8], [0f32; 8], [0f32; 8]);
        let mut fo = [[0f32; 8]; 3];
        // The gathers' bounds rest on this (a cheap check per block, not a debug assertion).
        check_sources(pass);
        for run in runs {
            let c = run.c as usize;
            let src = pass.src[c];
            let fax: [AxisV; 3] = std::array::from_fn(|a| AxisV::new(&geo.faces[c].ax[a], 1));
            let f = run.f.map(|v| v as i32);
            let len = run.len as i32;
            let o = run.compact as usize - base;
            // The cells beside each face (`Geometry::face_cells`): `base` is the cell with the
            // face's coordinates, the lower one is a stride below (wrapped or clamped at 0),
            // and the far boundary face of a non-periodic axis takes the last cell on both sides.
            let n_c = _mm256_set1_epi32(dims[c]);
            let stride_c = _mm256_set1_epi32(geo.centred.ax[c].stride as i32);
            let wrap_c = if geo.periodic[c] {
                _mm256_mullo_epi32(_mm256_set1_epi32(dims[c] - 1), stride_c)
            } else {
                _mm256_setzero_si256()
            };
            let row = dims[0] * (f[1] + dims[1] * f[2]);
            let pos_y = _mm256_set1_ps(f[1] as f32 + if c == 1 { 0.0 } else { 0.5 });
            let pos_z = _mm256_set1_ps(f[2] as f32 + if c == 2 { 0.0 } else { 0.5 });
            let sh_x = if c == 0 { 0.0 } else { 0.5 };
            // Three short loops over a chunk of vectors, as in the scalar trace: each vector's
            // work is a long chain (gathers -> midpoint -> gathers -> foot -> gathers) of more
            // micro-ops than the reorder window holds, so independent chains must be adjacent.
            let mut k = 0;
            while k < len {
                let nv = ((len - k) as usize).div_ceil(8).min(CHUNK_VECTORS);
                let mut pos = [[_mm256_setzero_ps(); 3]; CHUNK_VECTORS];
                let mut pts = [[_mm256_setzero_ps(); 3]; CHUNK_VECTORS];
                let mut pts_f = [[_mm256_setzero_ps(); 3]; CHUNK_VECTORS];
                for j in 0..nv {
                    let k = k + 8 * j as i32;
                    // Lanes past the run repeat its last face (valid indices; results dropped).
                    let fx = _mm256_min_epi32(
                        _mm256_add_epi32(_mm256_set1_epi32(f[0] + k), lane),
                        _mm256_set1_epi32(f[0] + len - 1),
                    );
                    let fc = if c == 0 { fx } else { _mm256_set1_epi32(f[c]) };
                    let cell = _mm256_add_epi32(fx, _mm256_set1_epi32(row));
                    let below = _mm256_sub_epi32(cell, stride_c);
                    let at_zero = _mm256_cmpeq_epi32(fc, _mm256_setzero_si256());
                    let at_top =
                        _mm256_cmpgt_epi32(fc, _mm256_sub_epi32(n_c, _mm256_set1_epi32(1)));
                    let c_lo = _mm256_blendv_epi8(below, _mm256_add_epi32(cell, wrap_c), at_zero);
                    let c_hi = _mm256_blendv_epi8(cell, below, at_top);
                    pos[j] = [
                        _mm256_add_ps(_mm256_cvtepi32_ps(fx), _mm256_set1_ps(sh_x)),
                        pos_y,
                        pos_z,
                    ];
                    // SAFETY: `c_lo`, `c_hi` are cells of the grid (the face coordinates are in
                    // range and the boundary cases are clamped or wrapped as above).
                    let v = unsafe { centred.mean(c_lo, c_hi) };
                    for a in 0..3 {
                        pts[j][a] = sub_scaled(pos[j][a], half_dt, v[a]);
                        if FORWARD {
                            pts_f[j][a] = sub_scaled(pos[j][a], half_dt_f, v[a]);
                        }
                    }
                }
                for j in 0..nv {
                    // SAFETY: the CPU has AVX2 and FMA (this function's contract).
                    let vm = unsafe { centred.sample(pts[j]) };
                    let vm_f = if FORWARD {
                        // SAFETY: as above.
                        unsafe { centred.sample(pts_f[j]) }
                    } else {
                        vm
                    };
                    for a in 0..3 {
                        pts[j][a] = sub_scaled(pos[j][a], dt, vm[a]);
                        if FORWARD {
                            pts_f[j][a] = sub_scaled(pos[j][a], dt_f, vm_f[a]);
                        }
                    }
                }
                for (j, p) in pts[..nv].iter().enumerate() {
                    let k = k + 8 * j as i32;
                    // SAFETY: `src` is the full face array of component c (checked above).
                    let (v, l, h) = unsafe { sample_face::<BOUNDS>(&fax, src, *p) };
                    // SAFETY: the arrays have room for eight lanes.
                    unsafe {
                        _mm256_storeu_ps(vo.as_mut_ptr(), v);
                        if BOUNDS {
                            _mm256_storeu_ps(lo.as_mut_ptr(), l);
                            _mm256_storeu_ps(hi.as_mut_ptr(), h);
                        }
                        if FORWARD {
                            for (a, fa) in fo.iter_mut().enumerate() {
                                _mm256_storeu_ps(fa.as_mut_ptr(), pts_f[j][a]);
                            }
                        }
                    }
                    each(
                        o + k as usize,
                        (len - k).min(8) as usize,
                        &vo,
                        &lo,
                        &hi,
                        &fo,
                    );
                }
                k += 8 * nv as i32;
            }
        }
    }

    /// Asserts that every source of `pass` is a full face array of its component (what keeps the
    /// gathers of [`sample_face`] in bounds).
    fn check_sources(pass: &Pass) {
        for c in 0..3 {
            let faces = pass.geo.faces[c]
                .ax
                .iter()
                .map(|a| a.n as usize)
                .product::<usize>();
            assert_eq!(
                pass.src[c].len(),
                faces,
                "advection source {c} is not a full face array"
            );
        }
    }

    /// Eight lanes of `s` from `k` (`m` valid, the rest zero).
    ///
    /// # Safety
    /// The CPU must have AVX. Not a `target_feature` function, so that it can be
    /// `inline(always)`, as [`Centred::sample`].
    #[inline(always)]
    unsafe fn load8(s: &[f32], k: usize, m: usize) -> __m256 {
        let mut a = [0f32; 8];
        let s = if m == 8 {
            &s[k..k + 8]
        } else {
            a[..m].copy_from_slice(&s[k..k + m]);
            &a
        };
        // SAFETY: `s` has eight floats; the CPU has AVX (the caller's contract).
        unsafe { _mm256_loadu_ps(s.as_ptr()) }
    }

    /// [`Pass::maccormack_correct`] on block `b`, eight faces at a time (the same operations as
    /// the scalar loop, so the same values): `foot`, `lo`, `hi` and `out` are the block's slices.
    ///
    /// # Safety
    /// The CPU must have AVX2 and FMA.
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn correct(
        pass: &Pass,
        b: usize,
        orig: [&[f32]; 3],
        foot: [&[f32]; 3],
        [lo, hi]: [&[f32]; 2],
        out: &mut [f32],
    ) {
        let plan = pass.plan;
        let runs = &plan.runs[plan.block_runs[b] as usize..plan.block_runs[b + 1] as usize];
        let base = b * BLOCK;
        let half = _mm256_set1_ps(0.5);
        let abs_mask = _mm256_castsi256_ps(_mm256_set1_epi32(0x7fff_ffff));
        let inf = _mm256_set1_ps(f32::INFINITY);
        let mut r = [0f32; 8];
        check_sources(pass);
        for run in runs {
            let c = run.c as usize;
            let src = pass.src[c];
            let fax: [AxisV; 3] = std::array::from_fn(|a| AxisV::new(&pass.geo.faces[c].ax[a], 1));
            let (len, o, full) = (
                run.len as usize,
                run.compact as usize - base,
                run.full as usize,
            );
            let orig = &orig[c][full..full + len];
            let mut k = 0;
            while k < len {
                let (m, n) = ((len - k).min(8), o + k);
                // SAFETY: the CPU has AVX2 and FMA (this function's contract), and `src` is the
                // full face array of component c (checked above).
                let (hat, u0, l, h, back) = unsafe {
                    let p = [
                        load8(foot[0], n, m),
                        load8(foot[1], n, m),
                        load8(foot[2], n, m),
                    ];
                    let (hat, u0) = (load8(out, n, m), load8(orig, k, m));
                    let (l, h) = (load8(lo, n, m), load8(hi, n, m));
                    (hat, u0, l, h, sample_face::<false>(&fax, src, p).0)
                };
                let v = _mm256_add_ps(hat, _mm256_mul_ps(half, _mm256_sub_ps(u0, back)));
                let finite = _mm256_cmp_ps::<_CMP_LT_OQ>(_mm256_and_ps(v, abs_mask), inf);
                let w = _mm256_blendv_ps(v, l, _mm256_cmp_ps::<_CMP_LT_OQ>(v, l));
                let w = _mm256_blendv_ps(w, h, _mm256_cmp_ps::<_CMP_GT_OQ>(w, h));
                let res = _mm256_blendv_ps(hat, w, finite);
                if m == 8 {
                    let s = &mut out[n..n + 8];
                    // SAFETY: `s` has eight floats.
                    unsafe { _mm256_storeu_ps(s.as_mut_ptr(), res) };
                } else {
                    // SAFETY: `r` has eight floats.
                    unsafe { _mm256_storeu_ps(r.as_mut_ptr(), res) };
                    out[n..n + m].copy_from_slice(&r[..m]);
                }
                k += m;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fluid::topology::extend_runs;

    /// Face values of the three components, uniform in [-0.5, 0.5).
    fn random_faces(layout: &Layout, rng: &mut fastrand::Rng) -> Vec<Vec<f32>> {
        (0..3)
            .map(|c| (0..layout.face_count(c)).map(|_| rng.f32() - 0.5).collect())
            .collect()
    }

    #[test]
    fn fast_sampling_matches_the_reference_interpolation_everywhere() {
        for periodic in [[false; 3], [true, false, true], [false, true, false]] {
            let dims = [5, 4, 6];
            let layout = Layout::new(dims, periodic);
            let geo = Geometry::new(dims, &layout);
            let mut rng = fastrand::Rng::with_seed(7);
            let fields = random_faces(&layout, &mut rng);
            let cells = dims.iter().product::<usize>();
            let centred3: Vec<[f32; 3]> = (0..cells)
                .map(|_| [rng.f32(), rng.f32(), rng.f32()])
                .collect();
            let centred: Vec<V4> = centred3.iter().map(|v| v4::new(v[0], v[1], v[2])).collect();
            for _ in 0..2000 {
                // Points inside, on sample positions, and far outside the grid.
                let p: [f32; 3] = std::array::from_fn(|a| {
                    let r = rng.f32();
                    if r < 0.1 {
                        (rng.f32() * 4.0).floor() * 0.5
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
    /// Random advection cases: grids with an axis of one cell, every periodicity pattern, random
    /// fields and centred velocity, about 3/4 of the faces active (runs of every length, some of
    /// one face), and time steps that put the feet inside, on and far outside the grid:
    /// `each(layout, pass)`.
    fn random_passes(seed: u64, mut each: impl FnMut(&Layout, &Pass)) {
        let mut rng = fastrand::Rng::with_seed(seed);
        for dims in [[7, 4, 6], [11, 1, 3]] {
            for periodic in [
                [false; 3],
                [true, false, true],
                [false, true, false],
                [true; 3],
            ] {
                let layout = Layout::new(dims, periodic);
                let geo = Geometry::new(dims, &layout);
                let fields = random_faces(&layout, &mut rng);
                let cells = dims.iter().product::<usize>();
                let centred: Vec<V4> = (0..cells)
                    .map(|_| v4::new(rng.f32() - 0.5, rng.f32() - 0.5, rng.f32() - 0.5))
                    .collect();
                let active: Vec<Vec<u32>> = (0..3)
                    .map(|c| {
                        (0..layout.face_count(c) as u32)
                            .filter(|_| rng.f32() < 0.75)
                            .collect()
                    })
                    .collect();
                // Runs of consecutive active faces within an x row, as the face sets keep them.
                let runs: Vec<Vec<[u32; 3]>> = (0..3)
                    .map(|c| {
                        let mut runs: Vec<[u32; 3]> = Vec::new();
                        for (n, &idx) in active[c].iter().enumerate() {
                            extend_runs(&mut runs, idx, n as u32, layout.fdims[c][0]);
                        }
                        runs
                    })
                    .collect();
                let counts = [active[0].len(), active[1].len(), active[2].len()];
                let mut plan = Plan::default();
                plan.rebuild(&layout, [&runs[0], &runs[1], &runs[2]], counts);
                for dt_cells in [0.3, -2.5, 7.0, 300.0, -5000.0] {
                    let pass = Pass {
                        geo: &geo,
                        plan: &plan,
                        vc: &centred,
                        src: [&fields[0], &fields[1], &fields[2]],
                        dt_cells,
                    };
                    each(&layout, &pass);
                }
            }
        }
    }

    /// The AVX2 kernels against the scalar ones on every face of [`random_passes`]: the trace
    /// (values, bounds, and the forward feet of the fused MacCormack trace) and MacCormack's
    /// correction.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn avx2_trace_matches_the_scalar_trace_where_available() {
        if !avx2::available() {
            eprintln!("SKIP avx2_trace_matches_the_scalar_trace_where_available: no AVX2+FMA");
            return;
        }
        let mut checked = 0usize;
        random_passes(11, |layout, pass| {
            let (plan, dt_cells) = (pass.plan, pass.dt_cells);
            let total = plan.offset[3];
            let mut want = vec![(0.0, 0.0, 0.0); total];
            let mut got = vec![(f32::NAN, 0.0, 0.0); total];
            let mut want_foot = vec![[0f32; 3]; total];
            let mut got_foot = vec![[f32::NAN; 3]; total];
            for b in 0..plan.block_runs.len() - 1 {
                pass.block_scalar::<true>(b, |n, r| want[b * BLOCK + n] = r);
                let geo = pass.geo;
                pass.trace_scalar::<true>(
                    b,
                    |c, src, p| geo.sample::<false>(c, src, p),
                    |n, _, f| {
                        let [x, y, z, _] = v4::lanes(f);
                        want_foot[b * BLOCK + n] = [x, y, z];
                    },
                );
                // SAFETY: the CPU has AVX2 and FMA (checked above).
                unsafe {
                    avx2::block::<true>(pass, b, |o, m, v, lo, hi| {
                        for i in 0..m {
                            got[b * BLOCK + o + i] = (v[i], lo[i], hi[i]);
                        }
                    });
                    avx2::trace::<false, true>(pass, b, |o, m, _, _, _, f| {
                        for i in 0..m {
                            got_foot[b * BLOCK + o + i] = [f[0][i], f[1][i], f[2][i]];
                        }
                    });
                }
            }
            for (n, (w, g)) in want.iter().zip(&got).enumerate() {
                let ctx = || format!("{:?} dt {dt_cells} face {n}", layout.periodic);
                // Same operations in the same order: equal to the bit.
                assert_eq!(w.0.to_bits(), g.0.to_bits(), "{}: {w:?} {g:?}", ctx());
                assert_eq!((w.1, w.2), (g.1, g.2), "{}", ctx());
                let (wf, gf) = (want_foot[n], got_foot[n]);
                assert_eq!(wf.map(f32::to_bits), gf.map(f32::to_bits), "{}", ctx());
            }
            // The correction on random inputs around the same values (some outside the bounds,
            // some not finite), block by block.
            let mut rng = fastrand::Rng::with_seed(total as u64);
            let mut r = |_| rng.f32() * 4.0 - 2.0;
            let foot: [Vec<f32>; 3] = [0, 1, 2].map(|a| {
                want_foot
                    .iter()
                    .map(|f| f[a] + r(0) * 0.01 * a as f32)
                    .collect()
            });
            let lo: Vec<f32> = (0..total).map(|_| r(0) - 1.0).collect();
            let hi: Vec<f32> = lo.iter().map(|l| l + r(0).abs()).collect();
            let mut hat: Vec<f32> = (0..total).map(r).collect();
            hat.iter_mut().step_by(17).for_each(|h| *h = f32::INFINITY);
            let orig = pass.src;
            let (mut want, mut got) = (hat.clone(), hat.clone());
            for b in 0..plan.block_runs.len() - 1 {
                let s = b * BLOCK..((b + 1) * BLOCK).min(total);
                let foot = [0, 1, 2].map(|a| &foot[a][s.clone()]);
                let bounds = [&lo[s.clone()], &hi[s.clone()]];
                pass.correct_scalar(b, orig, foot, bounds, &mut want[s.clone()]);
                // SAFETY: the CPU has AVX2 and FMA (checked above).
                unsafe { avx2::correct(pass, b, orig, foot, bounds, &mut got[s]) };
            }
            for (n, (w, g)) in want.iter().zip(&got).enumerate() {
                assert_eq!(w.to_bits(), g.to_bits(), "correction, face {n}: {w} {g}");
            }
            checked += total;
        });
        assert!(checked > 10_000, "{checked}");
    }

    /// The fused MacCormack (one pass for the backward step and the forward trace, one for the
    /// forward step and the correction) against the textbook two passes, each a full scalar
    /// semi-Lagrangian step, with `f32::clamp`: equal to the bit, serial and split.
    #[test]
    fn fused_maccormack_matches_the_backward_and_forward_steps() {
        let mut checked = 0usize;
        random_passes(13, |layout, pass| {
            let plan = pass.plan;
            let total = plan.offset[3];
            let blocks = plan.block_runs.len() - 1;
            // Backward step with its bounds, then the forward step of its result.
            let mut hat = vec![(0.0, 0.0, 0.0); total];
            for b in 0..blocks {
                pass.block_scalar::<true>(b, |n, r| hat[b * BLOCK + n] = r);
            }
            let hat_values: Vec<f32> = hat.iter().map(|h| h.0).collect();
            let mut tmp: [Vec<f32>; 3] = pass.src.map(|s| s.to_vec());
            scatter(plan, &hat_values, &mut tmp);
            let forward = Pass {
                src: [&tmp[0], &tmp[1], &tmp[2]],
                dt_cells: -pass.dt_cells,
                ..*pass
            };
            let mut orig = vec![0.0; total];
            gather(plan, pass.src, &mut orig);
            let mut want = vec![0f32; total];
            for b in 0..blocks {
                forward.block_scalar::<false>(b, |n, (back, _, _)| {
                    let (h, lo, hi) = hat[b * BLOCK + n];
                    let v = h + 0.5 * (orig[b * BLOCK + n] - back);
                    want[b * BLOCK + n] = if v.is_finite() { v.clamp(lo, hi) } else { h };
                });
            }
            for parallel in [false, true] {
                let mut out = vec![f32::NAN; total];
                let (mut lo, mut hi) = (vec![0.0; total], vec![0.0; total]);
                let mut foot = [vec![0.0; total], vec![0.0; total], vec![0.0; total]];
                let [fx, fy, fz] = &mut foot;
                pass.maccormack_trace(&mut out, [&mut lo, &mut hi], [fx, fy, fz], parallel);
                let mut tmp: [Vec<f32>; 3] = pass.src.map(|s| s.to_vec());
                scatter(plan, &out, &mut tmp);
                let forward = Pass {
                    src: [&tmp[0], &tmp[1], &tmp[2]],
                    ..*pass
                };
                let [fx, fy, fz] = &foot;
                forward.maccormack_correct(pass.src, [fx, fy, fz], [&lo, &hi], &mut out, parallel);
                for (n, (w, g)) in want.iter().zip(&out).enumerate() {
                    assert_eq!(
                        w.to_bits(),
                        g.to_bits(),
                        "{:?} dt {} parallel {parallel} face {n}: {w} {g}",
                        layout.periodic,
                        pass.dt_cells
                    );
                }
            }
            checked += total;
        });
        assert!(checked > 10_000, "{checked}");
    }
    /// The centred velocity (AVX2 rows and scalar tails) against the face means, cell by cell.
    #[test]
    fn centred_velocity_is_the_mean_of_the_faces_around_each_cell() {
        let mut rng = fastrand::Rng::with_seed(5);
        for dims in [[13, 3, 2], [8, 2, 3], [21, 1, 1]] {
            for periodic in [[false; 3], [true, true, true], [true, false, false]] {
                let layout = Layout::new(dims, periodic);
                let fields = random_faces(&layout, &mut rng);
                let mut out = vec![v4::zero(); dims.iter().product()];
                for parallel in [false, true] {
                    let u = [&fields[0][..], &fields[1][..], &fields[2][..]];
                    update_centred(&layout, dims, u, &mut out, None, parallel);
                    for k in 0..dims[2] {
                        for j in 0..dims[1] {
                            for i in 0..dims[0] {
                                let cell = [i, j, k];
                                let got = v4::lanes(out[i + dims[0] * (j + dims[1] * k)]);
                                for c in 0..3 {
                                    let mut up = cell;
                                    up[c] += 1;
                                    if periodic[c] && up[c] == dims[c] {
                                        up[c] = 0;
                                    }
                                    let a = fields[c][layout.face_index(c, cell)];
                                    let b = fields[c][layout.face_index(c, up)];
                                    assert_eq!(
                                        got[c],
                                        0.5 * (a + b),
                                        "{dims:?} {periodic:?} {cell:?} {c}"
                                    );
                                }
                                assert_eq!(got[3], 0.0);
                            }
                        }
                    }
                }
            }
        }
    }
}
