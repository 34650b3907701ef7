//! The per-particle step: the field's trilinear sampler, the midpoint rule's substeps with the
//! slip, the landing (a slide along a wall, an outlet) and the clarity's cone weight.
//! [`super::sweep`] runs it over a task's particles; [`super::block8`] is its eight-lane twin.

use crate::scene::clarity::View;
use crate::scene::VoxelKind;
use crate::simd::{v4, v4 as lane, V4};

/// A particle stays in the cavity ...
pub(super) const KEEP: u8 = 0;
/// ... left through the outflow holes ...
pub(super) const OUTFLOW: u8 = 1;
/// ... left through the open external os ...
pub(super) const OPEN: u8 = 2;
/// ... or was lost (its cell closed with no fluid cell around).
pub(super) const LOST: u8 = 3;
/// Particles the kernel moves together (their independent samples overlap in the CPU).
pub(super) const GROUP: usize = 4;
/// Particles the AVX2 kernel moves in the lanes of one vector (`block8`); chunks are whole
/// blocks (and so whole groups).
pub(super) const BLOCK: usize = 8;
/// Longest substep along any axis, cells.
pub(super) const SUBSTEP_CELLS: f32 = 0.9;

/// Per class: the sum over a step's particles of their [`Cone::weight`].
pub(super) type ClassSums = [f32; 256];

/// The view cone in grid units.
#[derive(Clone, Copy)]
pub(super) struct Cone {
    pub tip: [f32; 3],
    pub dir: [f32; 3],
    pub cos2: f32,
    pub depth: f32,
    pub near2: f32,
}

impl Cone {
    /// The cone of `view` on the grid of origin `origin` (m) and spacing `h` (m).
    pub fn new(view: &View, origin: [f64; 3], h: f64) -> Self {
        let c = view.cos_half_angle as f32;
        Self {
            tip: std::array::from_fn(|a| ((view.tip_m[a] - origin[a]) / h) as f32),
            dir: view.dir.map(|x| x as f32),
            cos2: c * c,
            depth: (view.depth_m / h) as f32,
            near2: ((view.near_m / h) as f32).powi(2),
        }
    }

    /// `1 / max(r, near)^2` (grid units) for a particle inside the cone, else 0.
    #[inline(always)]
    pub fn weight(&self, p: [f32; 3]) -> f32 {
        let d = [p[0] - self.tip[0], p[1] - self.tip[1], p[2] - self.tip[2]];
        let along = d[0] * self.dir[0] + d[1] * self.dir[1] + d[2] * self.dir[2];
        let r2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
        if along > 0.0 && along <= self.depth && along * along >= self.cos2 * r2 {
            1.0 / r2.max(self.near2)
        } else {
            0.0
        }
    }
}

/// Trilinear interpolation of the cell-centred field (4 lanes, one SIMD lerp per pair).
#[derive(Clone, Copy)]
pub(super) struct Sampler<'a> {
    pub field: &'a [V4],
    /// Largest sample position along each axis (`n - 1`; lane 3 zero).
    pub smax: V4,
    /// Largest lower sample index along each axis (`n - 2`, 0 for one cell; lane 3 zero).
    pub imax: V4,
    /// Index strides `[1, nx, nx ny]`.
    pub stride: [usize; 3],
    /// Index step to the upper sample along each axis (0 for one cell).
    pub step: [usize; 3],
    /// Byte offsets of the eight samples from the lower one, `{0, x} + {0, y} + {0, z}` in the
    /// order `000, x00, 0y0, xy0, 00z, x0z, 0yz, xyz` (bytes: no shift per address).
    pub corner_bytes: [usize; 8],
    /// The upper sample along x is the next element (more than one cell along x).
    pub x_pairs: bool,
    /// `field` holds every cell of the grid, and a cell's byte offset in it fits a `u32` (the
    /// eight-particle kernel's precondition: its samples need no bounds check).
    pub whole: bool,
}

impl<'a> Sampler<'a> {
    /// The sampler of `field`, the cell-centred velocities of a grid of `dims` cells.
    pub fn new(field: &'a [V4], dims: [usize; 3]) -> Self {
        let stride = [1, dims[0], dims[0] * dims[1]];
        let f = |v: [usize; 3]| v4::new(v[0] as f32, v[1] as f32, v[2] as f32);
        let step: [usize; 3] = std::array::from_fn(|a| usize::from(dims[a] > 1) * stride[a]);
        let size = std::mem::size_of::<V4>();
        Self {
            field,
            smax: f(dims.map(|n| n.saturating_sub(1))),
            imax: f(dims.map(|n| n.saturating_sub(2))),
            stride,
            step,
            corner_bytes: std::array::from_fn(|c| {
                (0..3).map(|a| (c >> a & 1) * step[a]).sum::<usize>() * size
            }),
            x_pairs: step[0] == 1,
            whole: dims
                .iter()
                .try_fold(1usize, |n, &d| n.checked_mul(d))
                .is_some_and(|n| n <= field.len() && n <= (u32::MAX as usize) / size),
        }
    }

    /// The field at `p` (grid units; clamped to the outermost samples). With `FMA` (set only by
    /// [`super::sweep`]'s AVX2 path, on a CPU with AVX2 and FMA) each pair of x neighbours is one
    /// eight-lane load and the blends run along y, z, then x with fused multiply-adds: the same
    /// trilinear interpolant in half the loads and blends, rounded once per blend.
    #[inline(always)]
    pub fn sample<const FMA: bool>(&self, p: V4) -> V4 {
        let (b, t) = lane::locate(p, self.smax, self.imax, self.stride);
        let [sx, sy, sz] = self.step;
        // The eight samples are b + {0, sx} + {0, sy} + {0, sz}, the largest b + sx + sy + sz:
        // one check for all (always true: the lower index is at most n - 2 along each axis).
        let f = match self.field.get(b..=b + sx + sy + sz) {
            Some(f) => f,
            None => return v4::zero(),
        };
        let (first, o) = (f.as_ptr(), &self.corner_bytes);
        #[cfg(target_arch = "x86_64")]
        if FMA && self.x_pairs {
            // SAFETY: `FMA` only in `run_avx2` (the CPU has AVX2 and FMA); the pairs start at
            // `first` + {0, sy} + {0, sz} and end at most at `first` + 1 + sy + sz, the last
            // element of `f`.
            return unsafe { lane::trilinear_x_pairs(first, sy, sz, t) };
        }
        let [tx, ty, tz] = lane::broadcast3(t);
        // SAFETY: every corner is `first` plus at most sx + sy + sz whole elements, the last of
        // `f` (so in bounds and aligned).
        let at = |c: usize| unsafe { first.byte_add(o[c]).read() };
        let c00 = lane::lerp(at(0), at(1), tx);
        let c10 = lane::lerp(at(2), at(3), tx);
        let c01 = lane::lerp(at(4), at(5), tx);
        let c11 = lane::lerp(at(6), at(7), tx);
        lane::lerp(lane::lerp(c00, c10, ty), lane::lerp(c01, c11, ty), tz)
    }
}

/// One task's particles for [`super::sweep::sweep`]: the first is particle `offset` of the
/// system.
pub(super) struct Task<'a> {
    pub offset: usize,
    pub pos: &'a mut [[f32; 3]],
    pub slip: &'a mut [[f32; 3]],
    pub class: &'a [u8],
    pub fate: &'a mut [u8],
}

/// The per-particle step, shared by the threads.
pub(super) struct Kernel<'a> {
    pub field: Sampler<'a>,
    pub kinds: &'a [VoxelKind],
    /// The grid's dimensions as floats (lane 3: 1).
    pub fdims: V4,
    /// The particles from this index on start in a cell that may not be fluid (all when the
    /// kinds changed; else those emitted since the last step, which ends each particle in a
    /// fluid cell).
    pub check_from: usize,
    pub class_step: &'a [([f32; 3], f32, f32)],
    pub dt: f32,
    pub max_sub: u32,
    pub cone: Option<Cone>,
}

impl<'a> Kernel<'a> {
    /// The step of `dt_s` in the field `field` against `kinds`, with the classes' slip factors
    /// `class_step`; the particles from `check_from` on may start outside a fluid cell.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        field: Sampler<'a>,
        kinds: &'a [VoxelKind],
        class_step: &'a [([f32; 3], f32, f32)],
        check_from: usize,
        max_sub: usize,
        dt_s: f64,
        cone: Option<Cone>,
    ) -> Self {
        let [nx, ny, nz, _] = v4::lanes(field.smax).map(|x| x + 1.0);
        Self {
            field,
            kinds,
            // Lane 3 (zero in positions) passes the bounds test.
            fdims: lane::new4(nx, ny, nz, 1.0),
            check_from,
            class_step,
            dt: dt_s as f32,
            max_sub: max_sub as u32,
            cone,
        }
    }

    /// Whether [`super::block8`] can move this kernel's particles (the sampler has the whole grid and
    /// x pairs).
    #[cfg(target_arch = "x86_64")]
    pub fn blocks(&self) -> bool {
        self.field.whole && self.field.x_pairs
    }

    #[inline(always)]
    pub fn kind_at(&self, p: V4) -> VoxelKind {
        lane::cell(p, self.fdims, self.field.stride)
            .and_then(|n| self.kinds.get(n))
            .copied()
            .unwrap_or(VoxelKind::Solid)
    }

    /// A particle's end of step: its cone weight added to `sums` if it stays (returns 0), else 1.
    #[inline(always)]
    pub fn tally(&self, fate: u8, class: u8, p: [f32; 3], sums: &mut ClassSums) -> usize {
        if fate != KEEP {
            return 1;
        }
        if let Some(cone) = &self.cone {
            sums[class as usize] += cone.weight(p);
        }
        0
    }

    /// The substeps of the `waiting` particles side by side ([`Kernel::substeps_lanes`]): their
    /// ends and fates written at their indices, tallied; returns how many left.
    #[inline(always)]
    pub fn resume<const FMA: bool>(
        &self,
        waiting: &[Resume],
        pos: &mut [[f32; 3]],
        class: &[u8],
        fate: &mut [u8],
        sums: &mut ClassSums,
    ) -> usize {
        let ends = self.substeps_lanes::<FMA>(waiting);
        let mut left = 0;
        for (r, (end, f)) in waiting.iter().zip(ends) {
            let e = v4::lanes(end);
            let (Some(p), Some(c), Some(fr)) =
                (pos.get_mut(r.at), class.get(r.at), fate.get_mut(r.at))
            else {
                continue;
            };
            *p = [e[0], e[1], e[2]];
            *fr = f;
            left += self.tally(f, *c, *p, sums);
        }
        left
    }

    /// The slip displacement over the step (grid units) and the slip at its end.
    #[inline(always)]
    fn slip_step(&self, class: u8, w0: [f32; 3]) -> (V4, [f32; 3]) {
        // Slip: w(t) = wt + (w0 - wt) e^(-t/tau), integrated exactly over the step.
        let (wt, e, disp) = self
            .class_step
            .get(class as usize)
            .copied()
            .unwrap_or(([0.0; 3], 0.0, 0.0));
        let (wt, w0) = (v4::new(wt[0], wt[1], wt[2]), v4::new(w0[0], w0[1], w0[2]));
        let dw = lane::sub(w0, wt);
        // wt dt + (w0 - wt) disp and wt + (w0 - wt) e.
        let slip_d = lane::mul_add(dw, lane::splat(disp), lane::mul(wt, lane::splat(self.dt)));
        let w1 = v4::lanes(lane::mul_add(dw, lane::splat(e), wt));
        (slip_d, [w1[0], w1[1], w1[2]])
    }

    /// Substeps of a particle whose fluid velocity at the start is `k1` and whose slip
    /// displacement is `sd`: at most SUBSTEP_CELLS along any axis each, at most `max_sub`.
    #[inline(always)]
    fn substeps(&self, k1: V4, sd: V4) -> u32 {
        let travel = lane::max_abs_sum(lane::mul_add(k1, lane::splat(self.dt), v4::zero()), sd);
        // max/min: a NaN travel takes one substep.
        let x = (travel * (1.0 / SUBSTEP_CELLS))
            .max(1.0)
            .min(self.max_sub as f32);
        // SAFETY: `x` is finite and in [1, max_sub] here.
        unsafe { x.ceil().to_int_unchecked::<u32>() }
    }

    /// GROUP particles that start in fluid cells: the samples, slips and one-substep moves of all
    /// of them first (independent, so they overlap in the CPU). The particles that stay in the
    /// fluid in one substep are done (fate KEEP); the others, which need more substeps or whose
    /// move ended outside a fluid cell, are returned to continue from their start.
    #[inline(always)]
    pub fn advance_group<const FMA: bool>(
        &self,
        pos: &mut [[f32; 3]; GROUP],
        slip: &mut [[f32; 3]; GROUP],
        class: &[u8; GROUP],
    ) -> [Option<Resume>; GROUP] {
        let field = &self.field;
        let mut p = [v4::zero(); GROUP];
        let mut k1 = [v4::zero(); GROUP];
        let mut sd = [v4::zero(); GROUP];
        let mut w1 = [[0.0f32; 3]; GROUP];
        let mut one = [true; GROUP];
        for l in 0..GROUP {
            p[l] = v4::new(pos[l][0], pos[l][1], pos[l][2]);
            (sd[l], w1[l]) = self.slip_step(class[l], slip[l]);
        }
        for l in 0..GROUP {
            k1[l] = field.sample::<FMA>(p[l]);
        }
        let dt = lane::splat(self.dt);
        let half_dt = lane::splat(0.5 * self.dt);
        let mut q = [v4::zero(); GROUP];
        for l in 0..GROUP {
            one[l] &= self.substeps(k1[l], sd[l]) == 1;
            // The midpoint rule's one substep as in `advance_one` (the same operations).
            let half_sd = lane::mul_add(sd[l], lane::splat(0.5), v4::zero());
            let mid = lane::mul_add(half_dt, k1[l], v4::add(p[l], half_sd));
            q[l] = lane::mul_add(
                dt,
                field.sample::<FMA>(mid),
                v4::add(p[l], lane::mul_add(sd[l], lane::splat(1.0), v4::zero())),
            );
        }
        let mut more = [None; GROUP];
        for l in 0..GROUP {
            slip[l] = w1[l];
            if one[l] && self.kind_at(q[l]) == VoxelKind::Fluid {
                let r = v4::lanes(q[l]);
                pos[l] = [r[0], r[1], r[2]];
            } else {
                // More substeps, or a wall or an outlet: from the start, with the sample taken.
                more[l] = Some(Resume {
                    at: l,
                    p: p[l],
                    k1: k1[l],
                    sd: sd[l],
                });
            }
        }
        more
    }

    /// One particle's step; returns its fate.
    #[inline(always)]
    pub fn advance_one<const FMA: bool>(
        &self,
        pos: &mut [f32; 3],
        slip: &mut [f32; 3],
        class: u8,
        check: bool,
    ) -> u8 {
        let mut p = v4::new(pos[0], pos[1], pos[2]);
        // A cell that stopped being fluid: leave through an outlet, or move to a fluid
        // neighbour, or be lost.
        if check {
            match self.kind_at(p) {
                VoxelKind::Fluid => {}
                VoxelKind::Outflow => return OUTFLOW,
                VoxelKind::Open => return OPEN,
                _ => match relocate(*pos, &|q| self.kind_at(v4::new(q[0], q[1], q[2]))) {
                    Some(q) => p = v4::new(q[0], q[1], q[2]),
                    None => return LOST,
                },
            }
        }
        let (sdv, w1) = self.slip_step(class, *slip);
        *slip = w1;
        let start = Resume {
            at: 0,
            p,
            k1: self.field.sample::<FMA>(p),
            sd: sdv,
        };
        let [(p, fate), ..] = self.substeps_lanes::<FMA>(&[start]);
        let p = v4::lanes(p);
        *pos = [p[0], p[1], p[2]];
        fate
    }

    /// The substeps of up to GROUP particles side by side (each as if alone: the same operations
    /// in the same order), each starting at `p` (in a fluid cell) with the fluid velocity `k1`
    /// there and the slip displacement `sd` over the step: where each ends and its fate (lanes
    /// past `starts.len()` unused).
    #[inline(always)]
    fn substeps_lanes<const FMA: bool>(&self, starts: &[Resume]) -> [(V4, u8); GROUP] {
        let field = &self.field;
        let n = starts.len().min(GROUP);
        let mut p = [v4::zero(); GROUP];
        let mut k1 = [v4::zero(); GROUP];
        let mut subs = [0u32; GROUP];
        let mut hs = [v4::zero(); GROUP];
        let mut half_hs = [v4::zero(); GROUP];
        let mut sd = [v4::zero(); GROUP];
        let mut half_sd = [v4::zero(); GROUP];
        let mut fate = [KEEP; GROUP];
        for (l, r) in starts[..n].iter().enumerate() {
            (p[l], k1[l]) = (r.p, r.k1);
            subs[l] = self.substeps(r.k1, r.sd);
            let inv = 1.0 / subs[l] as f32;
            hs[l] = lane::splat(self.dt * inv);
            half_hs[l] = lane::splat(0.5 * self.dt * inv);
            sd[l] = lane::mul_add(r.sd, lane::splat(inv), v4::zero());
            half_sd[l] = lane::mul_add(r.sd, lane::splat(0.5 * inv), v4::zero());
        }
        let most = subs[..n].iter().copied().max().unwrap_or(0);
        let mut mid = [v4::zero(); GROUP];
        let mut q = [v4::zero(); GROUP];
        for sub in 0..most {
            let on: [bool; GROUP] = std::array::from_fn(|l| sub < subs[l] && fate[l] == KEEP);
            for l in 0..n {
                if on[l] {
                    if sub > 0 {
                        k1[l] = field.sample::<FMA>(p[l]);
                    }
                    mid[l] = lane::mul_add(half_hs[l], k1[l], v4::add(p[l], half_sd[l]));
                }
            }
            for l in 0..n {
                if on[l] {
                    q[l] = lane::mul_add(hs[l], field.sample::<FMA>(mid[l]), v4::add(p[l], sd[l]));
                }
            }
            for l in 0..n {
                if on[l] {
                    (p[l], fate[l]) = self.land(p[l], q[l]);
                }
            }
        }
        std::array::from_fn(|l| (p[l], fate[l]))
    }

    /// Where the substep `p -> q` of a particle in a fluid cell ends and its fate: at `q` in a
    /// fluid cell, out through an outlet, or slid along a wall ([`Kernel::slide`]).
    #[inline(always)]
    pub fn land(&self, p: V4, q: V4) -> (V4, u8) {
        match self.kind_at(q) {
            VoxelKind::Fluid => (q, KEEP),
            VoxelKind::Outflow => (p, OUTFLOW),
            VoxelKind::Open => (p, OPEN),
            _ => {
                let (pa, qa) = (v4::lanes(p), v4::lanes(q));
                match self.slide([pa[0], pa[1], pa[2]], [qa[0], qa[1], qa[2]]) {
                    Slide::To(r) => (v4::new(r[0], r[1], r[2]), KEEP),
                    Slide::Leave(f) => (p, f),
                    Slide::Stay => (p, KEEP),
                }
            }
        }
    }
}

/// A particle whose step continues from its start `p` with the fluid velocity `k1` there and the
/// slip displacement `sd` over the step (index `at` in its task).
#[derive(Clone, Copy)]
pub(super) struct Resume {
    pub at: usize,
    pub p: V4,
    pub k1: V4,
    pub sd: V4,
}

impl Default for Resume {
    fn default() -> Self {
        Self {
            at: 0,
            p: v4::zero(),
            k1: v4::zero(),
            sd: v4::zero(),
        }
    }
}

/// Where a substep that ended in a wall goes instead.
enum Slide {
    /// Along the axes of the move that stay in the fluid.
    To([f32; 3]),
    /// Through an outlet (the fate).
    Leave(u8),
    /// Nowhere.
    Stay,
}

impl Kernel<'_> {
    /// The move `p -> q` ended in a wall (or the scope, a port, outside the grid): keep as much
    /// of it as lands in the fluid or an outlet. First one axis reverted (the first that works),
    /// then two: a particle pressed into an edge or a corner by a field pointing into both walls
    /// still moves along the one free axis (with one axis only it stayed, and in a frozen field
    /// stayed forever).
    #[inline(always)]
    fn slide(&self, p: [f32; 3], q: [f32; 3]) -> Slide {
        let tries = [
            [false, true, true],
            [true, false, true],
            [true, true, false],
            [true, false, false],
            [false, true, false],
            [false, false, true],
        ];
        for keep in tries {
            let r: [f32; 3] = std::array::from_fn(|a| if keep[a] { q[a] } else { p[a] });
            match self.kind_at(v4::new(r[0], r[1], r[2])) {
                VoxelKind::Fluid => return Slide::To(r),
                VoxelKind::Outflow => return Slide::Leave(OUTFLOW),
                VoxelKind::Open => return Slide::Leave(OPEN),
                _ => {}
            }
        }
        Slide::Stay
    }
}

/// Moves `p` (grid units) to the centre of a fluid cell among the 26 around its cell.
fn relocate(p: [f32; 3], kind_at: &impl Fn([f32; 3]) -> VoxelKind) -> Option<[f32; 3]> {
    let base = p.map(|x| x.floor() + 0.5);
    let mut best: Option<([f32; 3], f32)> = None;
    for dz in -1..=1 {
        for dy in -1..=1 {
            for dx in -1..=1 {
                let q = [
                    base[0] + dx as f32,
                    base[1] + dy as f32,
                    base[2] + dz as f32,
                ];
                if kind_at(q) == VoxelKind::Fluid {
                    let d = (0..3).map(|a| (q[a] - p[a]).powi(2)).sum::<f32>();
                    if best.is_none_or(|b| d < b.1) {
                        best = Some((q, d));
                    }
                }
            }
        }
    }
    best.map(|b| b.0)
}
