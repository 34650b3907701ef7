//! Geometric multigrid V-cycle on voxelized (irregular) domains, used as the CG preconditioner.
//!
//! Each level is a 7-point Poisson operator on the "fluid" cells of a label grid (0 = solid wall,
//! Neumann; 1 = fluid, unknown; 2 = open, Dirichlet p = 0). A coarse cell is open if any child is
//! open, else fluid if any child is fluid, else solid. Restriction sums the children's residuals
//! (times a scale), prolongation injects the coarse value into every child (its transpose). Level 0
//! couples neighbours with weight 1; a coarser level carries the Galerkin operator of that
//! prolongation (`Level::galerkin`): per-face couplings that count the fine faces joining two
//! coarse cells, so a thin or partly filled region is not coupled like a full one (on the scene's
//! thin cavity this halved the MG-PCG iterations: 17.0 to 8.1 at 0.6 mm).
//! Smoothing is red-black Gauss-Seidel, red then black before and black then red after the coarse
//! correction, so the V-cycle is a symmetric operator and CG preconditioned by it stays valid.
//!
//! The levels are stored matrix-free on the dense box padded by one ghost layer per side: vectors
//! hold zero on every non-fluid cell (solid walls contribute nothing, open cells are p = 0), the
//! labels (and the couplings) only decide the diagonal, so every kernel is a branch-free loop over contiguous spans of
//! cells with fixed strides that the compiler vectorises. Periodic axes fill their ghost layers from
//! the opposite side before each stencil application (`halo`). A colour's half-sweep reads only the
//! other colour, so it computes a chunk into a stack buffer and adds it back (exact Gauss-Seidel;
//! where an odd periodic axis or a one-cell periodic axis makes a cell its own colour's neighbour it
//! is a Jacobi update within the colour, still symmetric, and the half-sweeps stay convergent).
//!
//! Level 0 can also build the compressed rows (fluid cells numbered in order, with neighbour lists)
//! that the reference solvers and the baseline use, when one of them runs.

use super::grid::step_along;
use super::topology::NONE;

/// Label codes of a level.
pub(crate) const L_SOLID: u8 = 0;
pub(crate) const L_FLUID: u8 = 1;
pub(crate) const L_OPEN: u8 = 2;

/// Cells per stack buffer of the smoother (a few cache lines; any length is correct).
const CHUNK: usize = 128;
/// Spans closer than this many cells merge (the cells between are masked out, so this only trades
/// work on non-fluid cells for longer vector loops; on the benchmark cavity 48 beat 12 by ~15 % of
/// the projection at 0.6 and 1.2 mm, 128 gained nothing more).
const SPAN_GAP: usize = 48;

/// The fixed cost of a span in a kernel, in cells: splitting a level's kernels in two halves of
/// equal cells left the half with the cavity's fragmented end (342 spans against 29 on the 0.6 mm
/// scene) taking 1.5-1.7 times as long as the other in every kernel; fitted to those times, a span
/// costs as much as about 33 cells (BENCHMARKS.md, "Residual maximum and the split, session 13").
const SPAN_COST: usize = 32;

/// Lanes of the f32 reductions (one AVX register; the compiler vectorises the fixed-width bodies).
const LANES: usize = 8;

/// Neighbour windows of cells `c..c+n` in a padded vector: (x-1, x+1, y-1, y+1, z-1, z+1).
macro_rules! windows {
    ($v:expr, $c:expr, $n:expr, $sy:expr, $sz:expr) => {{
        let (c, n, sy, sz) = ($c, $n, $sy, $sz);
        (
            &$v[c - 1..c - 1 + n],
            &$v[c + 1..c + 1 + n],
            &$v[c - sy..c - sy + n],
            &$v[c + sy..c + sy + n],
            &$v[c - sz..c - sz + n],
            &$v[c + sz..c + sz + n],
        )
    }};
}

/// `for $q in 0..$n { let $nsum = sum of the neighbours of cell c+q; $body }` over the windows of
/// `$v` at `$c`: the plain sum on a level with unit couplings (`$wt` `None`), the sum weighted by
/// the face couplings `[x, y, z]` (coupling of a cell to its +axis neighbour) otherwise. The body is
/// expanded once per case so both loops vectorise.
macro_rules! for_nsum {
    ($wt:expr, $v:expr, $c:expr, $n:expr, $sy:expr, $sz:expr, |$nsum:ident, $q:ident| $body:block) => {{
        let (c, n, sy, sz) = ($c, $n, $sy, $sz);
        let (xm, xp, ym, yp, zm, zp) = windows!($v, c, n, sy, sz);
        match $wt {
            None => {
                for $q in 0..n {
                    let $nsum = (xm[$q] + xp[$q]) + (ym[$q] + yp[$q]) + (zm[$q] + zp[$q]);
                    $body
                }
            }
            Some([w0, w1, w2]) => {
                let (wxm, wxp) = (&w0[c - 1..c - 1 + n], &w0[c..c + n]);
                let (wym, wyp) = (&w1[c - sy..c - sy + n], &w1[c..c + n]);
                let (wzm, wzp) = (&w2[c - sz..c - sz + n], &w2[c..c + n]);
                for $q in 0..n {
                    let $nsum = (wxm[$q] * xm[$q] + wxp[$q] * xp[$q])
                        + (wym[$q] * ym[$q] + wyp[$q] * yp[$q])
                        + (wzm[$q] * zm[$q] + wzp[$q] * zp[$q]);
                    $body
                }
            }
        }
    }};
}

/// A vector kernel over the spans of a level. Outputs (`&mut`) are indexed relative to the offset
/// the kernel runs with (so a thread can own a piece of them); inputs are whole vectors.
pub(crate) enum SpanOp<'a> {
    /// `x = inv b` (a colour's half-sweep from x = 0).
    Init {
        x: &'a mut [f32],
        b: &'a [f32],
        inv: &'a [f32],
    },
    /// `x += inv (b - A x)` on the cells where `inv` is non-zero (one colour), in place (serial);
    /// with `dot`, returns `sum b x` of the result (as `Dot`).
    Relax {
        x: &'a mut [f32],
        b: &'a [f32],
        diag: &'a [f32],
        inv: &'a [f32],
        dot: bool,
    },
    /// `t = x + inv (b - A x)`: the result of `Relax` into a separate vector (parallel); with
    /// `dot`, returns `sum b t`.
    RelaxInto {
        t: &'a mut [f32],
        x: &'a [f32],
        b: &'a [f32],
        diag: &'a [f32],
        inv: &'a [f32],
        dot: bool,
    },
    /// `y = mask (b - A v)` with `b`, `y = mask A v` without.
    Stencil {
        y: &'a mut [f32],
        v: &'a [f32],
        b: Option<&'a [f32]>,
        diag: &'a [f32],
        mask: &'a [f32],
    },
    /// `sum a b` accumulated in f64.
    Dot { a: &'a [f32], b: &'a [f32] },
    /// `y = mask A v` and `sum v y` (as `Stencil` then `Dot`, in one pass).
    ApplyDot {
        y: &'a mut [f32],
        v: &'a [f32],
        diag: &'a [f32],
        mask: &'a [f32],
    },
    /// `d += alpha p`, `r -= alpha ap`; returns `max |r|`. With `init = (x, inv)` also the first
    /// half-sweep of a V-cycle whose right-hand side is the new `r`: `x = inv r` (as `Init`).
    Update {
        alpha: f32,
        p: &'a [f32],
        ap: &'a [f32],
        d: &'a mut [f32],
        r: &'a mut [f32],
        init: Option<(&'a mut [f32], &'a [f32])>,
    },
    /// `p = z + beta p`.
    Xpby {
        p: &'a mut [f32],
        z: &'a [f32],
        beta: f32,
    },
}

impl<'a> SpanOp<'a> {
    /// Splits the outputs at padded index `mid`: the first op keeps `..mid`, the second gets
    /// `mid..` (to run with offset `mid`).
    fn split(self, mid: usize) -> (SpanOp<'a>, SpanOp<'a>) {
        use SpanOp::*;
        match self {
            Init { x, b, inv } => {
                let (xa, xb) = x.split_at_mut(mid);
                (Init { x: xa, b, inv }, Init { x: xb, b, inv })
            }
            RelaxInto {
                t,
                x,
                b,
                diag,
                inv,
                dot,
            } => {
                let (ta, tb) = t.split_at_mut(mid);
                (
                    RelaxInto {
                        t: ta,
                        x,
                        b,
                        diag,
                        inv,
                        dot,
                    },
                    RelaxInto {
                        t: tb,
                        x,
                        b,
                        diag,
                        inv,
                        dot,
                    },
                )
            }
            Stencil {
                y,
                v,
                b,
                diag,
                mask,
            } => {
                let (ya, yb) = y.split_at_mut(mid);
                (
                    Stencil {
                        y: ya,
                        v,
                        b,
                        diag,
                        mask,
                    },
                    Stencil {
                        y: yb,
                        v,
                        b,
                        diag,
                        mask,
                    },
                )
            }
            Dot { a, b } => (Dot { a, b }, Dot { a, b }),
            ApplyDot { y, v, diag, mask } => {
                let (ya, yb) = y.split_at_mut(mid);
                (
                    ApplyDot {
                        y: ya,
                        v,
                        diag,
                        mask,
                    },
                    ApplyDot {
                        y: yb,
                        v,
                        diag,
                        mask,
                    },
                )
            }
            Update {
                alpha,
                p,
                ap,
                d,
                r,
                init,
            } => {
                let (da, db) = d.split_at_mut(mid);
                let (ra, rb) = r.split_at_mut(mid);
                let (ia, ib) = match init {
                    Some((x, inv)) => {
                        let (xa, xb) = x.split_at_mut(mid);
                        (Some((xa, inv)), Some((xb, inv)))
                    }
                    None => (None, None),
                };
                (
                    Update {
                        alpha,
                        p,
                        ap,
                        d: da,
                        r: ra,
                        init: ia,
                    },
                    Update {
                        alpha,
                        p,
                        ap,
                        d: db,
                        r: rb,
                        init: ib,
                    },
                )
            }
            Xpby { p, z, beta } => {
                let (pa, pb) = p.split_at_mut(mid);
                (Xpby { p: pa, z, beta }, Xpby { p: pb, z, beta })
            }
            // In place: cannot be split (parallel levels use RelaxInto and a swap instead).
            op @ Relax { .. } => (op, Dot { a: &[], b: &[] }),
        }
    }
}

struct SpanRun<'a> {
    op: SpanOp<'a>,
    spans: &'a [[u32; 2]],
    /// The level's face couplings (`None`: unit couplings).
    wt: Option<[&'a [f32]; 3]>,
    /// Padded index of element 0 of the outputs.
    off: usize,
    sy: usize,
    sz: usize,
}

impl pulp::WithSimd for SpanRun<'_> {
    type Output = f64;

    // Everything below is inlined into pulp's per-instruction-set entry points, so it is compiled
    // (and auto-vectorised) once for AVX2 + FMA and once for the SSE2 baseline.
    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) -> f64 {
        let (sy, sz, off, wt) = (self.sy, self.sz, self.off, self.wt);
        let spans = self.spans.iter().map(|&[s, e]| (s as usize, e as usize));
        match self.op {
            SpanOp::Init { x, b, inv } => {
                for (s, e) in spans {
                    let x = &mut x[s - off..e - off];
                    for ((x, &b), &d) in x.iter_mut().zip(&b[s..e]).zip(&inv[s..e]) {
                        *x = b * d;
                    }
                }
                0.0
            }
            SpanOp::Relax {
                x,
                b,
                diag,
                inv,
                dot,
            } => {
                debug_assert_eq!(off, 0);
                let mut acc = [0.0f64; LANES];
                for (s, e) in spans {
                    relax_span(x, b, diag, inv, wt, s, e, sy, sz);
                    if dot {
                        dot_span(&mut acc, &b[s..e], &x[s..e]);
                    }
                }
                acc.iter().sum()
            }
            SpanOp::RelaxInto {
                t,
                x,
                b,
                diag,
                inv,
                dot,
            } => {
                let mut acc = [0.0f64; LANES];
                for (s, e) in spans {
                    let (x0, bb, dd, ii) = (&x[s..e], &b[s..e], &diag[s..e], &inv[s..e]);
                    let t = &mut t[s - off..e - off];
                    for_nsum!(wt, x, s, e - s, sy, sz, |nsum, q| {
                        t[q] = x0[q] + ii[q] * (bb[q] + nsum - dd[q] * x0[q]);
                    });
                    if dot {
                        dot_span(&mut acc, bb, t);
                    }
                }
                acc.iter().sum()
            }
            SpanOp::Stencil {
                y,
                v,
                b,
                diag,
                mask,
            } => {
                for (s, e) in spans {
                    stencil_span(&mut y[s - off..e - off], v, b, diag, mask, wt, s, e, sy, sz);
                }
                0.0
            }
            SpanOp::Dot { a, b } => {
                let mut acc = [0.0f64; LANES];
                for (s, e) in spans {
                    dot_span(&mut acc, &a[s..e], &b[s..e]);
                }
                acc.iter().sum()
            }
            SpanOp::ApplyDot { y, v, diag, mask } => {
                let mut acc = [0.0f64; LANES];
                for (s, e) in spans {
                    let y = &mut y[s - off..e - off];
                    stencil_span(y, v, None, diag, mask, wt, s, e, sy, sz);
                    dot_span(&mut acc, &v[s..e], y);
                }
                acc.iter().sum()
            }
            SpanOp::Update {
                alpha,
                p,
                ap,
                d,
                r,
                mut init,
            } => {
                let mut m = [0.0f32; LANES];
                for (s, e) in spans {
                    let rs = s - off..e - off;
                    let (p, ap) = (&p[s..e], &ap[s..e]);
                    let (d, r) = (&mut d[s - off..e - off], &mut r[s - off..e - off]);
                    let mut pc = p.chunks_exact(LANES);
                    let mut apc = ap.chunks_exact(LANES);
                    let mut dc = d.chunks_exact_mut(LANES);
                    let mut rc = r.chunks_exact_mut(LANES);
                    for (((p, ap), d), r) in (&mut pc).zip(&mut apc).zip(&mut dc).zip(&mut rc) {
                        for k in 0..LANES {
                            d[k] += alpha * p[k];
                            r[k] -= alpha * ap[k];
                            // A plain comparison: one vector max (f32::max adds a NaN blend).
                            let a = r[k].abs();
                            m[k] = if a > m[k] { a } else { m[k] };
                        }
                    }
                    let tail = pc
                        .remainder()
                        .iter()
                        .zip(apc.remainder())
                        .zip(dc.into_remainder().iter_mut().zip(rc.into_remainder()));
                    for ((&p, &ap), (d, r)) in tail {
                        *d += alpha * p;
                        *r -= alpha * ap;
                        let a = r.abs();
                        m[0] = if a > m[0] { a } else { m[0] };
                    }
                    if let Some((x, inv)) = init.as_mut() {
                        for ((x, &r), &i) in x[rs].iter_mut().zip(r.iter()).zip(&inv[s..e]) {
                            *x = r * i;
                        }
                    }
                }
                m.iter().fold(0.0f32, |a, &b| a.max(b)) as f64
            }
            SpanOp::Xpby { p, z, beta } => {
                for (s, e) in spans {
                    for (p, &z) in p[s - off..e - off].iter_mut().zip(&z[s..e]) {
                        *p = z + beta * *p;
                    }
                }
                0.0
            }
        }
    }
}

fn dispatch(level: &Level, spans: &[[u32; 2]], off: usize, op: SpanOp<'_>) -> f64 {
    pulp::Arch::new().dispatch(SpanRun {
        op,
        spans,
        wt: level.couplings(),
        off,
        sy: level.sy,
        sz: level.sz,
    })
}

/// Runs `op` over `level`'s spans, compiled for the best instruction set of this CPU (AVX2 + FMA
/// where present, else the SSE2 baseline of the generic x86-64 binary; element-wise kernels give
/// bit-identical results either way, and the reductions use fixed lanes). On a level marked
/// `parallel` the spans run in two halves on rayon (one fork-join per call).
pub(crate) fn run(level: &Level, op: SpanOp<'_>) -> f64 {
    let k = level.split_span;
    if !level.parallel || k == 0 || k >= level.spans.len() {
        return dispatch(level, &level.spans, 0, op);
    }
    let is_max = matches!(op, SpanOp::Update { .. });
    let mid = level.spans[k][0] as usize;
    let (sa, sb) = level.spans.split_at(k);
    let (oa, ob) = op.split(mid);
    let (ra, rb) = crate::fork_join::join(
        || dispatch(level, sa, 0, oa),
        || dispatch(level, sb, mid, ob),
    );
    if is_max {
        ra.max(rb)
    } else {
        ra + rb
    }
}

/// Runs `f(spans, out, off)` over the level's spans (`out` holds the padded vector from index
/// `off`), in two halves on a `parallel` level (the output split at the first cell of the second
/// half), and returns the larger of the two results.
pub(crate) fn for_spans<T: Send>(
    level: &Level,
    out: &mut [T],
    f: impl Fn(&[[u32; 2]], &mut [T], usize) -> f64 + Sync,
) -> f64 {
    let k = level.split_span;
    if !level.parallel || k == 0 || k >= level.spans.len() {
        return f(&level.spans, out, 0);
    }
    let mid = level.spans[k][0] as usize;
    let (a, b) = out.split_at_mut(mid);
    let (sa, sb) = level.spans.split_at(k);
    let (ra, rb) = crate::fork_join::join(|| f(sa, a, 0), || f(sb, b, mid));
    ra.max(rb)
}

/// The larger of `m` and the largest `|x|` of `v`, NaN skipped (not `max`: a plain comparison
/// vectorizes, `max` adds a NaN blend).
#[inline]
pub(crate) fn max_abs_from<T: Real + PartialOrd>(m: T, v: &[T]) -> T {
    v.iter().fold(m, |m, &x| {
        let a = x.abs();
        if a > m {
            a
        } else {
            m
        }
    })
}

/// Largest `|v|` over the level's spans (NaN skipped), in two halves on a `parallel` level like
/// every kernel: each thread reads the half its kernels wrote. One thread reading the whole
/// vector cost more than the scan: the other core's half crossed over, and that core's next
/// write to it waited for the lines back (BENCHMARKS.md, "Residual maximum, session 13").
pub(crate) fn max_abs_spans<T: Real + PartialOrd + Sync>(level: &Level, v: &[T]) -> f64 {
    let max = |spans: &[[u32; 2]]| {
        let zero = T::from_f64(0.0);
        let m = spans.iter().fold(zero, |m, &[s, e]| {
            max_abs_from(m, &v[s as usize..e as usize])
        });
        m.to_f64()
    };
    let k = level.split_span;
    if !level.parallel || k == 0 || k >= level.spans.len() {
        return max(&level.spans);
    }
    let (sa, sb) = level.spans.split_at(k);
    let (ra, rb) = crate::fork_join::join(|| max(sa), || max(sb));
    ra.max(rb)
}

/// The vector element types of the pressure solve.
pub(crate) trait Real: Copy {
    fn to_f64(self) -> f64;
    fn from_f64(v: f64) -> Self;
    fn abs(self) -> Self;
}

impl Real for f32 {
    fn to_f64(self) -> f64 {
        self as f64
    }
    fn from_f64(v: f64) -> Self {
        v as f32
    }
    fn abs(self) -> Self {
        f32::abs(self)
    }
}

impl Real for f64 {
    fn to_f64(self) -> f64 {
        self
    }
    fn from_f64(v: f64) -> Self {
        v
    }
    fn abs(self) -> Self {
        f64::abs(self)
    }
}

/// Padded index of interior cell (i, j, k) in a box of strides `sy`, `sz` with one ghost layer.
#[inline]
fn pad_index(sy: usize, sz: usize, i: usize, j: usize, k: usize) -> usize {
    (i + 1) + sy * (j + 1) + sz * (k + 1)
}

/// Where [`Level::build_dense`] takes the diagonal from.
#[derive(Clone, Copy)]
enum DenseDiag {
    /// Counted from the labels (level 0, and a coarse level with unit couplings).
    Count,
    /// Left to [`Level::galerkin`], which sets it on every fluid cell.
    Later,
}

/// One multigrid level.
#[derive(Default, Debug)]
pub(crate) struct Level {
    pub dims: [usize; 3],
    pub periodic: [bool; 3],
    pub label: Vec<u8>,
    /// Whether the compressed rows below match the labels (level 0 only; built by
    /// [`Level::build_compressed_rows`] when a reference solver needs them).
    pub rows_built: bool,
    /// Compressed rows (level 0 only): row of each cell (NONE if not fluid), cell of each row.
    pub row_of_cell: Vec<u32>,
    pub cell_of_row: Vec<u32>,
    /// Neighbour rows, order -x +x -y +y -z +z; a wall or open neighbour is `rows()` (level 0 only).
    pub nbr: Vec<[u32; 6]>,
    /// Number of fluid or open neighbours, per row (level 0 only).
    pub diag: Vec<f32>,
    pub inv_diag: Vec<f32>,
    /// Dense (padded) index of each compressed row (level 0 only).
    pub pad_of_row: Vec<u32>,
    /// Strides of the padded box along y and z (x is 1).
    pub sy: usize,
    pub sz: usize,
    /// Fluid cells.
    pub fluid: usize,
    /// Padded-index ranges `[start, end)` that cover every fluid cell.
    pub spans: Vec<[u32; 2]>,
    /// The spans before the last [`Level::build_dense`] (`None`: the dense vectors were cleared
    /// whole): every dense vector of the level and of the pressure solver is zero outside the
    /// spans, so a relabelling zeroes these ranges instead of the box.
    pub old_spans: Option<Vec<[u32; 2]>>,
    /// First span of the second half (by cells) when the level runs on two threads.
    pub split_span: usize,
    /// Whether the kernels of this level run on rayon (set by the solver from its threshold).
    pub parallel: bool,
    /// Interior rows holding fluid: `[j, k, i_first, i_end)`.
    pub row_spans: Vec<[u32; 4]>,
    /// Per row `j + ny k`, an x range `[first, end)` outside which every cell of the row is solid
    /// (`[0, 0]`: the whole row is). The builds visit only these ranges and clear only the last
    /// ones, so a relabelling costs the fluid region, not the box.
    pub row_ext: Vec<[u32; 2]>,
    /// Dense diagonal (fluid cells; 0 elsewhere), fluid mask, and the inverse diagonal on red
    /// (`inv[0]`, even i+j+k) and black (`inv[1]`) fluid cells only.
    pub ddiag: Vec<f32>,
    pub mask: Vec<f32>,
    pub inv: [Vec<f32>; 2],
    /// Face couplings of a Galerkin coarse level (dense, per axis: the coupling of a cell to its
    /// +axis neighbour); empty on level 0 and on periodic levels, whose couplings are 1 between
    /// unknowns (and to open cells, in the diagonal).
    pub wt: [Vec<f32>; 3],
    /// Scratch of [`Level::build_dense`]: one row's neighbour counts.
    pub row_counts: Vec<u8>,
    /// Dense unknowns, right-hand side and residual.
    pub x: Vec<f32>,
    pub b: Vec<f32>,
    pub r: Vec<f32>,
}

impl Level {
    /// The face couplings the kernels weight the neighbours by (`None`: unit couplings).
    fn couplings(&self) -> Option<[&[f32]; 3]> {
        let [a, b, c] = &self.wt;
        (!a.is_empty()).then_some([&a[..], &b[..], &c[..]])
    }

    /// The Galerkin operator of piecewise-constant prolongation on the coarse level `coarse`
    /// (labels and dense form built): every fine face between a fluid child and a fluid or open
    /// cell of another coarse cell adds its coupling, over the number of fine faces a full coarse
    /// face holds, to the coupling of the two coarse cells (so a fully fluid region keeps unit
    /// couplings), and the diagonal is the sum of a cell's couplings. Unlike the rediscretised
    /// operator of the coarse labels (a coarse cell with one fluid child coupled like a full
    /// one), thin and partly filled regions keep the strength of their fine connections.
    /// Periodic levels keep unit couplings.
    fn galerkin(&self, coarse: &mut Level) {
        if self.any_periodic() || coarse.any_periodic() {
            for w in &mut coarse.wt {
                w.clear();
            }
            return;
        }
        let len = coarse.mask.len();
        // Zero outside the coarse non-solid ranges: `coarsen` cleared the last ones.
        if coarse.wt[0].len() != len {
            for w in &mut coarse.wt {
                w.clear();
                w.resize(len, 0.0);
            }
        }
        let [nx, ny, nz] = self.dims;
        let ratio: [f32; 3] = std::array::from_fn(|a| if self.dims[a] > 1 { 2.0 } else { 1.0 });
        let faces_per_face: [f32; 3] =
            std::array::from_fn(|a| (0..3).filter(|&b| b != a).map(|b| ratio[b]).product());
        let share: [f32; 3] = std::array::from_fn(|a| 1.0 / faces_per_face[a]);
        let fine_w = self.couplings();
        let cell_stride = [1, nx, nx * ny];
        let (fine_stride, coarse_stride) = ([1, self.sy, self.sz], [1, coarse.sy, coarse.sz]);
        for &[j, k, i0, i1] in &self.row_spans {
            let (j, k) = (j as usize, k as usize);
            let base = nx * (j + ny * k);
            for i in i0 as usize..i1 as usize {
                let ci = base + i;
                if self.label[ci] != L_FLUID {
                    continue;
                }
                let c = [i, j, k];
                let (pf, pc) = (
                    self.pad(i, j, k),
                    pad_index(coarse.sy, coarse.sz, i / 2, j / 2, k / 2),
                );
                for a in 0..3 {
                    let n = [nx, ny, nz][a];
                    // The fine face to the +axis neighbour crosses into another coarse cell when
                    // the cell is odd along the axis, the -axis face when it is even.
                    let odd = c[a] % 2 == 1;
                    // +axis face (fluid or open neighbour), and -axis face to an open neighbour
                    // (a fluid one is counted from its own +axis face).
                    if odd
                        && c[a] + 1 < n
                        && matches!(self.label[ci + cell_stride[a]], L_FLUID | L_OPEN)
                    {
                        let w = fine_w.map_or(1.0, |w| w[a][pf]);
                        coarse.wt[a][pc] += w * share[a];
                    }
                    if !odd && c[a] > 0 && self.label[ci - cell_stride[a]] == L_OPEN {
                        let w = fine_w.map_or(1.0, |w| w[a][pf - fine_stride[a]]);
                        coarse.wt[a][pc - coarse_stride[a]] += w * share[a];
                    }
                }
            }
        }
        let (sy, sz) = (coarse.sy, coarse.sz);
        for &[j, k, i0, i1] in &coarse.row_spans {
            let (j, k) = (j as usize, k as usize);
            for i in i0 as usize..i1 as usize {
                let p = coarse.pad(i, j, k);
                if coarse.mask[p] == 0.0 {
                    continue;
                }
                let w = &coarse.wt;
                let d = w[0][p] + w[0][p - 1] + w[1][p] + w[1][p - sy] + w[2][p] + w[2][p - sz];
                coarse.ddiag[p] = d;
                coarse.inv[(i + j + k) % 2][p] = if d > 0.0 { 1.0 / d } else { 0.0 };
            }
        }
    }

    /// Fluid cells (the compressed rows, when built).
    pub fn rows(&self) -> usize {
        self.fluid
    }

    /// Cell indices of the six neighbours of cell `c` (index `ci`), order -x +x -y +y -z +z, with
    /// `usize::MAX` past a non-periodic wall (a periodic axis wraps, onto the cell itself when it
    /// is one cell long).
    #[inline(always)]
    pub(super) fn neighbour_cells(&self, c: [usize; 3], ci: usize) -> [usize; 6] {
        let [nx, ny, _] = self.dims;
        let stride = [1, nx, nx * ny];
        let mut out = [usize::MAX; 6];
        for a in 0..3 {
            let beside = step_along(ci, c[a], self.dims[a], stride[a], self.periodic[a]);
            for (o, b) in out[2 * a..2 * a + 2].iter_mut().zip(beside) {
                *o = b.unwrap_or(usize::MAX);
            }
        }
        out
    }

    /// The padded index at which the level's kernels split in two halves (the first cell of
    /// the second half's spans; the vector's end when they do not split).
    pub fn split_at(&self) -> usize {
        match self.spans.get(self.split_span) {
            Some(&[p, _]) if self.split_span > 0 => p as usize,
            _ => self.mask.len(),
        }
    }

    /// Padded index of interior cell (i, j, k).
    #[inline]
    pub fn pad(&self, i: usize, j: usize, k: usize) -> usize {
        pad_index(self.sy, self.sz, i, j, k)
    }

    /// Linear index of the first cell of the rows beside row `(j, k)`, order -y +y -z +z (`None`
    /// past a non-periodic wall; a periodic axis wraps, onto the row itself when it is one row
    /// long), as [`Level::neighbour_cells`] steps.
    pub(super) fn neighbour_rows(&self, j: usize, k: usize) -> [Option<usize>; 4] {
        let [nx, ny, nz] = self.dims;
        let row = nx * (j + ny * k);
        let [ym, yp] = step_along(row, j, ny, nx, self.periodic[1]);
        let [zm, zp] = step_along(row, k, nz, nx * ny, self.periodic[2]);
        [ym, yp, zm, zp]
    }

    /// The number of fluid or open neighbours of cells `a..b` of the row starting at cell `row`
    /// (`rows`: [`Level::neighbour_rows`] of it) into `out`, a row's slice at a time (the
    /// loops vectorise).
    fn count_row(
        &self,
        row: usize,
        [a, b]: [usize; 2],
        rows: &[Option<usize>; 4],
        out: &mut Vec<u8>,
    ) {
        let nx = self.dims[0];
        out.clear();
        out.resize(b - a, 0);
        let add = |out: &mut [u8], labels: &[u8]| {
            for (o, &l) in out.iter_mut().zip(labels) {
                *o += u8::from(l != L_SOLID);
            }
        };
        for r in rows.iter().flatten() {
            add(out, &self.label[r + a..r + b]);
        }
        let label = &self.label[row..row + nx];
        // -x: the cell before, or across a periodic axis the row's last cell.
        let lo = usize::from(a == 0);
        add(&mut out[lo..], &label[a + lo - 1..b - 1]);
        if a == 0 && self.periodic[0] {
            out[0] += u8::from(label[nx - 1] != L_SOLID);
        }
        // +x: the cell after, or across a periodic axis the row's first cell.
        let hi = b - usize::from(b == nx);
        add(&mut out[..hi - a], &label[a + 1..hi + 1]);
        if b == nx && self.periodic[0] {
            out[b - a - 1] += u8::from(label[0] != L_SOLID);
        }
    }

    /// Sets level 0's box and its labels: `label(cell)` inside the row ranges `rows` (per row
    /// `j + ny k`, `[first, end)`), solid everywhere else. When the box is unchanged only the
    /// ranges of the last call and of this one are written.
    pub fn set_labels(
        &mut self,
        dims: [usize; 3],
        periodic: [bool; 3],
        rows: &[[u32; 2]],
        label: impl Fn(usize) -> u8,
    ) {
        let [nx, ny, nz] = dims;
        debug_assert_eq!(rows.len(), ny * nz);
        let same = self.dims == dims
            && self.periodic == periodic
            && self.label.len() == nx * ny * nz
            && self.row_ext.len() == rows.len();
        self.dims = dims;
        self.periodic = periodic;
        if !same {
            self.label.clear();
            self.label.resize(nx * ny * nz, L_SOLID);
            self.row_ext.clear();
            self.row_ext.resize(rows.len(), [0, 0]);
        }
        for (r, (old, &new)) in self.row_ext.iter_mut().zip(rows).enumerate() {
            let base = r * nx;
            self.label[base + old[0] as usize..base + old[1] as usize].fill(L_SOLID);
            for c in base + new[0] as usize..base + new[1] as usize {
                self.label[c] = label(c);
            }
            *old = new;
        }
    }

    /// Row ranges of the non-solid cells of `label` (a scan of the box; [`Level::set_labels`]
    /// keeps them without one).
    #[cfg(test)]
    fn scan_row_ext(&mut self) {
        let nx = self.dims[0];
        self.row_ext.clear();
        for row in self.label.chunks_exact(nx) {
            let ext = match row.iter().position(|&l| l != L_SOLID) {
                Some(a) => {
                    let b = row.iter().rposition(|&l| l != L_SOLID).unwrap_or(a); // ok: `a` is
                    [a as u32, b as u32 + 1]
                }
                None => [0, 0],
            };
            self.row_ext.push(ext);
        }
    }

    /// Builds level 0 (dense form and compressed rows) from `label`, `dims`, `periodic`, scanning
    /// the box for the rows' ranges (the reference the solver's [`Level::set_labels`] and
    /// [`Level::build_in_extents`] must match).
    #[cfg(test)]
    pub fn build_rows(&mut self) {
        self.scan_row_ext();
        self.build_in_extents();
        self.build_compressed_rows();
    }

    /// Level 0's dense form from the labels within the row ranges `row_ext` (which
    /// [`Level::set_labels`] keeps): its cost is that of the ranges. The compressed rows, which only
    /// the reference solvers read, are built when one runs ([`Level::build_compressed_rows`]).
    pub fn build_in_extents(&mut self) {
        self.rows_built = false;
        self.build_dense(DenseDiag::Count);
    }

    /// The compressed rows of level 0 (row of each fluid cell in cell order, neighbour rows,
    /// diagonal, dense index), from the labels within `row_ext`, unless they are current.
    pub fn build_compressed_rows(&mut self) {
        if self.rows_built {
            return;
        }
        let [nx, ny, nz] = self.dims;
        debug_assert_eq!(self.row_ext.len(), ny * nz);
        let ncell = self.label.len();
        // `row_of_cell` is NONE but at the cells of the last rows.
        if self.row_of_cell.len() == ncell {
            for &c in &self.cell_of_row {
                self.row_of_cell[c as usize] = NONE;
            }
        } else {
            self.row_of_cell.clear();
            self.row_of_cell.resize(ncell, NONE);
        }
        self.cell_of_row.clear();
        for (r, &[a, b]) in self.row_ext.iter().enumerate() {
            for c in r * nx + a as usize..r * nx + b as usize {
                if self.label[c] == L_FLUID {
                    self.row_of_cell[c] = self.cell_of_row.len() as u32;
                    self.cell_of_row.push(c as u32);
                }
            }
        }
        self.nbr.clear();
        self.diag.clear();
        self.inv_diag.clear();
        self.pad_of_row.clear();
        let zero_slot = self.cell_of_row.len() as u32;
        let (sy, sz) = (nx + 2, (nx + 2) * (ny + 2));
        // The same order as the scan above: row by row within the ranges.
        for (r, &[a, b]) in self.row_ext.iter().enumerate() {
            let (j, k) = (r % ny, r / ny);
            for i in a as usize..b as usize {
                let ci = r * nx + i;
                if self.label[ci] != L_FLUID {
                    continue;
                }
                let mut nb = [zero_slot; 6];
                let mut diag = 0.0f32;
                for (slot, g) in nb.iter_mut().zip(self.neighbour_cells([i, j, k], ci)) {
                    if g == usize::MAX {
                        continue;
                    }
                    match self.label[g] {
                        L_FLUID => {
                            *slot = self.row_of_cell[g];
                            diag += 1.0;
                        }
                        L_OPEN => diag += 1.0,
                        _ => {}
                    }
                }
                self.nbr.push(nb);
                self.diag.push(diag);
                self.inv_diag
                    .push(if diag > 0.0 { 1.0 / diag } else { 0.0 });
                self.pad_of_row.push(pad_index(sy, sz, i, j, k) as u32);
            }
        }
        self.rows_built = true;
    }

    /// Builds the dense (padded) operator, spans and vectors from `label`, the diagonal as `diag`
    /// says.
    fn build_dense(&mut self, diag: DenseDiag) {
        let [nx, ny, nz] = self.dims;
        let (old_sy, old_sz) = (self.sy, self.sz);
        self.sy = nx + 2;
        self.sz = (nx + 2) * (ny + 2);
        let len = self.sz * (nz + 2);
        // Periodic halos are written outside the fluid cells: those levels clear the whole box.
        let sparse = self.mask.len() == len && !self.periodic.iter().any(|&p| p);
        let [inv0, inv1] = &mut self.inv;
        let vectors = [
            &mut self.ddiag,
            &mut self.mask,
            inv0,
            inv1,
            &mut self.x,
            &mut self.b,
            &mut self.r,
        ];
        if sparse {
            // Every vector of the level is zero off its fluid cells: clearing the last fluid
            // rows (not the spans, twice as long with their gaps) zeroes the box.
            for v in vectors {
                for &[j, k, i0, i1] in &self.row_spans {
                    let p = pad_index(old_sy, old_sz, i0 as usize, j as usize, k as usize);
                    v[p..p + (i1 - i0) as usize].fill(0.0);
                }
            }
            let mut old = self.old_spans.take().unwrap_or_default();
            old.clear();
            old.extend_from_slice(&self.spans);
            self.old_spans = Some(old);
        } else {
            for v in vectors {
                v.clear();
                v.resize(len, 0.0);
            }
            self.old_spans = None;
        }
        self.spans.clear();
        self.row_spans.clear();
        self.fluid = 0;
        let mut counts = std::mem::take(&mut self.row_counts);
        debug_assert_eq!(self.row_ext.len(), ny * nz);
        for k in 0..nz {
            for j in 0..ny {
                let mut first = None;
                let mut end = 0;
                let [a, b] = self.row_ext[j + ny * k];
                if a >= b {
                    continue;
                }
                let row = nx * (j + ny * k);
                if let DenseDiag::Count = diag {
                    let rows = self.neighbour_rows(j, k);
                    self.count_row(row, [a as usize, b as usize], &rows, &mut counts);
                }
                for i in a as usize..b as usize {
                    if self.label[row + i] != L_FLUID {
                        continue;
                    }
                    self.fluid += 1;
                    first.get_or_insert(i);
                    end = i + 1;
                    let p = self.pad(i, j, k);
                    self.mask[p] = 1.0;
                    let d = match diag {
                        DenseDiag::Count => counts[i - a as usize] as f32,
                        DenseDiag::Later => continue,
                    };
                    self.ddiag[p] = d;
                    self.inv[(i + j + k) % 2][p] = if d > 0.0 { 1.0 / d } else { 0.0 };
                }
                if let Some(i0) = first {
                    self.row_spans
                        .push([j as u32, k as u32, i0 as u32, end as u32]);
                    let (s, e) = (
                        self.pad(i0, j, k) as u32,
                        self.pad(end - 1, j, k) as u32 + 1,
                    );
                    match self.spans.last_mut() {
                        Some(last) if (s as usize) <= last[1] as usize + SPAN_GAP => last[1] = e,
                        _ => self.spans.push([s, e]),
                    }
                }
            }
        }
        self.row_counts = counts;
        if !self.periodic.iter().any(|&p| p) {
            round_spans(&mut self.spans, len - self.sz);
        }
        // The halves are balanced by their cost, a span's fixed part included (a fragmented end
        // of the cavity holds many short spans, a wide one a few long ones).
        let cost = |&[s, e]: &[u32; 2]| (e - s) as usize + SPAN_COST;
        let total: usize = self.spans.iter().map(cost).sum();
        let mut acc = 0;
        self.split_span = self.spans.len();
        for (n, span) in self.spans.iter().enumerate() {
            if 2 * acc >= total {
                self.split_span = n;
                break;
            }
            acc += cost(span);
        }
    }

    /// Labels of the next coarser level, or false when this level should be the coarsest.
    fn coarsen(&self, coarse: &mut Level) -> bool {
        if self.fluid <= 8 || self.dims.iter().all(|&n| n <= 1) {
            return false;
        }
        for a in 0..3 {
            if self.periodic[a] && self.dims[a] > 1 && self.dims[a] % 2 == 1 {
                return false;
            }
        }
        let cd: [usize; 3] = std::array::from_fn(|a| self.dims[a].div_ceil(2));
        let periodic = std::array::from_fn(|a| self.periodic[a] && cd[a] > 1);
        let (ncell, nrow) = (cd[0] * cd[1] * cd[2], cd[1] * cd[2]);
        if coarse.dims == cd
            && coarse.periodic == periodic
            && coarse.label.len() == ncell
            && coarse.row_ext.len() == nrow
        {
            // Only the last ranges can hold non-solid cells, and non-zero couplings.
            let clear_wt = coarse.wt[0].len() == coarse.mask.len();
            for (r, &[a, b]) in coarse.row_ext.iter().enumerate() {
                coarse.label[r * cd[0] + a as usize..r * cd[0] + b as usize].fill(L_SOLID);
                if clear_wt && a < b {
                    let p = coarse.pad(a as usize, r % cd[1], r / cd[1]);
                    for w in &mut coarse.wt {
                        w[p..p + (b - a) as usize].fill(0.0);
                    }
                }
            }
            coarse.row_ext.fill([0, 0]);
        } else {
            coarse.dims = cd;
            coarse.periodic = periodic;
            for w in &mut coarse.wt {
                w.clear();
            }
            coarse.label.clear();
            coarse.label.resize(ncell, L_SOLID);
            coarse.row_ext.clear();
            coarse.row_ext.resize(nrow, [0, 0]);
        }
        let [nx, ny, nz] = self.dims;
        for k in 0..nz {
            for j in 0..ny {
                let [a, b] = self.row_ext[j + ny * k];
                if a >= b {
                    continue;
                }
                let crow = j / 2 + cd[1] * (k / 2);
                let base = cd[0] * crow;
                for i in a as usize..b as usize {
                    let l = self.label[i + nx * (j + ny * k)];
                    let cl = &mut coarse.label[base + i / 2];
                    if l == L_OPEN || (l == L_FLUID && *cl == L_SOLID) {
                        *cl = l;
                    }
                }
                let ext = &mut coarse.row_ext[crow];
                let (ca, cb) = (a / 2, (b - 1) / 2 + 1);
                *ext = if ext[0] < ext[1] {
                    [ext[0].min(ca), ext[1].max(cb)]
                } else {
                    [ca, cb]
                };
            }
        }
        true
    }

    fn any_periodic(&self) -> bool {
        self.periodic.iter().any(|&p| p)
    }

    /// The ghost layers of the periodic axes: `f(ghost, source)` for each piece, `ghost` a range of
    /// the padded vector and `source` the start of the interior cells it copies.
    fn ghost_layers(&self, mut f: impl FnMut(std::ops::Range<usize>, usize)) {
        let [nx, ny, nz] = self.dims;
        let (sy, sz) = (self.sy, self.sz);
        let (py, pz) = (ny + 2, nz + 2);
        if self.periodic[0] {
            for k in 0..pz {
                for j in 0..py {
                    let row = j * sy + k * sz;
                    f(row..row + 1, row + nx);
                    f(row + nx + 1..row + nx + 2, row + 1);
                }
            }
        }
        if self.periodic[1] {
            for k in 0..pz {
                let plane = k * sz;
                f(plane..plane + sy, plane + ny * sy);
                f(plane + (ny + 1) * sy..plane + (ny + 2) * sy, plane + sy);
            }
        }
        if self.periodic[2] {
            f(0..sz, nz * sz);
            f((nz + 1) * sz..(nz + 2) * sz, sz);
        }
    }

    /// Fills the ghost layers of periodic axes of `v` from the opposite side.
    pub fn halo<T: Copy>(&self, v: &mut [T]) {
        self.ghost_layers(|ghost, src| v.copy_within(src..src + ghost.len(), ghost.start));
    }

    /// Zeroes the ghost layers that [`Level::halo`] fills.
    fn clear_halo(&self, v: &mut [f32]) {
        self.ghost_layers(|ghost, _| v[ghost].fill(0.0));
    }

    /// One colour's half-sweep of Gauss-Seidel on `x` (`colour` 0 = red, 1 = black). With `init`,
    /// `x` is taken as zero (it is written, not read: the first half-sweep of a V-cycle level).
    /// With `dot` (not with `init`), returns `sum b x` of the result, else 0.
    pub(super) fn half_sweep(&mut self, colour: usize, init: bool, dot: bool) -> f64 {
        let mut x = std::mem::take(&mut self.x);
        let mut sum = 0.0;
        if init {
            run(
                self,
                SpanOp::Init {
                    x: &mut x,
                    b: &self.b,
                    inv: &self.inv[colour],
                },
            );
        } else {
            if self.any_periodic() {
                self.halo(&mut x);
            }
            if self.parallel {
                // Two threads cannot update `x` in place: the new values go to the residual vector
                // (free during smoothing), which then becomes `x`. Off the spans and the ghost
                // layers both hold zero, so the swap is exact.
                let mut t = std::mem::take(&mut self.r);
                sum = run(
                    self,
                    SpanOp::RelaxInto {
                        t: &mut t,
                        x: &x,
                        b: &self.b,
                        diag: &self.ddiag,
                        inv: &self.inv[colour],
                        dot,
                    },
                );
                self.r = std::mem::replace(&mut x, t);
                if self.any_periodic() {
                    // The old `x` kept its ghost copies; the restriction reads `r` on the ghost
                    // layer of a one-cell periodic axis, where it must be zero.
                    let mut r = std::mem::take(&mut self.r);
                    self.clear_halo(&mut r);
                    self.r = r;
                }
            } else {
                sum = run(
                    self,
                    SpanOp::Relax {
                        x: &mut x,
                        b: &self.b,
                        diag: &self.ddiag,
                        inv: &self.inv[colour],
                        dot,
                    },
                );
            }
        }
        self.x = x;
        sum
    }

    /// `r = b - A x` on the spans.
    fn residual(&mut self) {
        let mut x = std::mem::take(&mut self.x);
        let mut r = std::mem::take(&mut self.r);
        if self.any_periodic() {
            self.halo(&mut x);
        }
        run(
            self,
            SpanOp::Stencil {
                y: &mut r,
                v: &x,
                b: Some(&self.b),
                diag: &self.ddiag,
                mask: &self.mask,
            },
        );
        self.x = x;
        self.r = r;
    }

    /// `y = A v` on the spans (zero on non-fluid cells of the spans); `v`'s periodic ghost layers
    /// must be filled.
    #[cfg(test)]
    pub fn apply(&self, v: &[f32], y: &mut [f32]) {
        run(
            self,
            SpanOp::Stencil {
                y,
                v,
                b: None,
                diag: &self.ddiag,
                mask: &self.mask,
            },
        );
    }
}

/// Lengthens every span to a whole number of [`LANES`] cells where that stays below `limit` (the
/// first index whose +z neighbour window would leave the vector), merging spans that then meet.
/// The added cells are not fluid, so every kernel leaves them as they are (zero) while its loops
/// run without a scalar remainder: on the scene's thin cavity the remainders were a quarter of
/// the projection's instructions. Not for periodic levels, whose ghost cells hold halo copies.
fn round_spans(spans: &mut Vec<[u32; 2]>, limit: usize) {
    let rounded = |[s, e]: [u32; 2]| {
        let want = s as usize + ((e - s) as usize).next_multiple_of(LANES);
        want.min(limit).max(e as usize) as u32
    };
    let mut out = 0usize;
    for n in 0..spans.len() {
        let [s, e] = spans[n];
        if out > 0 && s < rounded(spans[out - 1]) {
            spans[out - 1][1] = spans[out - 1][1].max(e);
        } else {
            spans[out] = [s, e];
            out += 1;
        }
    }
    spans.truncate(out);
    for span in spans.iter_mut() {
        span[1] = rounded(*span);
    }
}

/// Adds `a b` to the lane accumulators: lane k takes the elements at k mod 8 of the span's whole
/// 8-blocks, lane 0 the tail.
#[inline(always)]
fn dot_span(acc: &mut [f64; LANES], a: &[f32], b: &[f32]) {
    let (ac, bc) = (a.chunks_exact(LANES), b.chunks_exact(LANES));
    for (&x, &y) in ac.remainder().iter().zip(bc.remainder()) {
        acc[0] += x as f64 * y as f64;
    }
    for (x, y) in ac.zip(bc) {
        for k in 0..LANES {
            acc[k] += x[k] as f64 * y[k] as f64;
        }
    }
}

/// Relaxes the cells of `s..e` whose `inv` is non-zero: `x += inv (b + sum of neighbours - d x)`.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn relax_span(
    x: &mut [f32],
    b: &[f32],
    diag: &[f32],
    inv: &[f32],
    wt: Option<[&[f32]; 3]>,
    s: usize,
    e: usize,
    sy: usize,
    sz: usize,
) {
    let mut c = s;
    let mut t = [0.0f32; CHUNK];
    while c < e {
        let n = (e - c).min(CHUNK);
        {
            let x0 = &x[c..c + n];
            let (bb, dd, ii) = (&b[c..c + n], &diag[c..c + n], &inv[c..c + n]);
            let t = &mut t[..n];
            for_nsum!(wt, x, c, n, sy, sz, |nsum, q| {
                t[q] = ii[q] * (bb[q] + nsum - dd[q] * x0[q]);
            });
        }
        for (xv, &tv) in x[c..c + n].iter_mut().zip(&t[..n]) {
            *xv += tv;
        }
        c += n;
    }
}

/// `y = mask (b - A v)` with `b`, or `y = mask A v` without, on cells `s..e` (`y` holds just
/// those cells).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn stencil_span(
    y: &mut [f32],
    v: &[f32],
    b: Option<&[f32]>,
    diag: &[f32],
    mask: &[f32],
    wt: Option<[&[f32]; 3]>,
    s: usize,
    e: usize,
    sy: usize,
    sz: usize,
) {
    let n = e - s;
    let (v0, dd, mm) = (&v[s..e], &diag[s..e], &mask[s..e]);
    let y = &mut y[..n];
    match b {
        Some(b) => {
            let b = &b[s..e];
            for_nsum!(wt, v, s, n, sy, sz, |nsum, q| {
                y[q] = mm[q] * (b[q] + nsum - dd[q] * v0[q]);
            });
        }
        None => {
            for_nsum!(wt, v, s, n, sy, sz, |nsum, q| {
                y[q] = mm[q] * (dd[q] * v0[q] - nsum);
            });
        }
    }
}

/// The grid transfers between a level and the next coarser one, dispatched like [`SpanOp`]: each
/// coarse row of fluid cells meets four fine rows, whose cells pair up along x.
struct Transfer<'a> {
    fine: &'a Level,
    coarse: &'a Level,
    /// The coarse rows to transfer.
    rows: &'a [[u32; 4]],
    /// Padded index of element 0 of the output.
    off: usize,
    /// Restriction: the coarse right-hand side to write (`Some(scale, b)`); prolongation: the fine
    /// unknowns to correct.
    restrict: Option<(f32, &'a mut [f32])>,
    fine_x: Option<&'a mut [f32]>,
}

impl pulp::WithSimd for Transfer<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        let (fine, coarse, off) = (self.fine, self.coarse, self.off);
        let (fsy, fsz) = (fine.sy, fine.sz);
        let (mut restrict, mut fine_x) = (self.restrict, self.fine_x);
        for &[j, k, i0, i1] in self.rows {
            let (j, k, i0, i1) = (j as usize, k as usize, i0 as usize, i1 as usize);
            let c = coarse.pad(i0, j, k)..coarse.pad(i1, j, k);
            let f0 = fine.pad(2 * i0, 2 * j, 2 * k);
            let n2 = 2 * (i1 - i0);
            let rows = [f0, f0 + fsy, f0 + fsz, f0 + fsz + fsy];
            if let Some((scale, b)) = restrict.as_mut() {
                let b = &mut b[c.start - off..c.end - off];
                b.fill(0.0);
                for f in rows {
                    for (bv, r2) in b.iter_mut().zip(fine.r[f..f + n2].chunks_exact(2)) {
                        *bv += r2[0] + r2[1];
                    }
                }
                for (bv, &m) in b.iter_mut().zip(&coarse.mask[c.clone()]) {
                    *bv *= m * *scale;
                }
            }
            if let Some(x) = fine_x.as_mut() {
                let xc = &coarse.x[c.clone()];
                for f in rows {
                    let xs = x[f - off..f - off + n2].chunks_exact_mut(2);
                    let ms = fine.mask[f..f + n2].chunks_exact(2);
                    for ((x2, m2), &v) in xs.zip(ms).zip(xc) {
                        x2[0] += m2[0] * v;
                        x2[1] += m2[1] * v;
                    }
                }
            }
        }
    }
}

/// Runs a transfer over all coarse rows; on a `parallel` coarse level in two halves split at a
/// coarse plane (the fine rows of the two halves then lie in separate fine planes).
fn transfer(fine: &Level, coarse: &Level, restrict: Option<f32>, out: &mut [f32]) {
    let rows = &coarse.row_spans[..];
    let whole = |rows, off, out: &mut [f32]| {
        let (restrict, fine_x) = match restrict {
            Some(scale) => (Some((scale, out)), None),
            None => (None, Some(out)),
        };
        pulp::Arch::new().dispatch(Transfer {
            fine,
            coarse,
            rows,
            off,
            restrict,
            fine_x,
        })
    };
    // The coarse plane whose fine planes start nearest the fine level's own split, so each
    // thread transfers the fine cells its kernels work on (the middle coarse row instead put a
    // band of fine planes on the other core every V-cycle).
    let split = fine.split_at();
    let k_mid = if fine.parallel && split < fine.mask.len() {
        // Padded plane `split / sz` is interior plane `split / sz - 1`; its coarse plane rounds up.
        (split / fine.sz / 2) as u32
    } else {
        rows.get(rows.len() / 2).map_or(0, |r| r[1])
    };
    let m = rows.partition_point(|r| r[1] < k_mid);
    if !coarse.parallel || m == 0 || m == rows.len() {
        return whole(rows, 0, out);
    }
    let k = k_mid as usize;
    let mid = if restrict.is_some() {
        coarse.sz * (k + 1)
    } else {
        fine.sz * (2 * k + 1)
    };
    let (a, b) = out.split_at_mut(mid);
    let (ra, rb) = rows.split_at(m);
    crate::fork_join::join(|| whole(ra, 0, a), || whole(rb, mid, b));
}

/// `coarse.b = scale * (sum of the children's residuals)` on the coarse fluid cells.
fn restrict(fine: &Level, coarse: &mut Level, scale: f32) {
    let mut b = std::mem::take(&mut coarse.b);
    transfer(fine, coarse, Some(scale), &mut b);
    coarse.b = b;
}

/// `fine.x += coarse.x` of the parent on every fine fluid cell.
fn prolongate(coarse: &Level, fine: &mut Level) {
    let mut x = std::mem::take(&mut fine.x);
    transfer(fine, coarse, None, &mut x);
    fine.x = x;
}

/// The level hierarchy.
#[derive(Default, Debug)]
pub(crate) struct Multigrid {
    pub levels: Vec<Level>,
    /// Number of levels in use (levels beyond stay allocated for reuse).
    pub used: usize,
    /// Scale of the restricted residual (1/4 is Galerkin for injection; larger over-corrects).
    pub coarse_scale: f32,
    /// Smoothing sweeps before and after the coarse correction.
    pub sweeps: usize,
    /// Symmetric sweeps on the coarsest level.
    pub coarsest_sweeps: usize,
}

impl Multigrid {
    /// Builds the hierarchy under a finished level 0 (`levels[0].build_in_extents()` done by the
    /// caller).
    pub fn build_hierarchy(&mut self) {
        self.used = 1;
        while self.used < 16 {
            let l = self.used;
            if self.levels.len() <= l {
                self.levels.push(Level::default());
            }
            let (fine, coarse) = self.levels.split_at_mut(l);
            if !fine[l - 1].coarsen(&mut coarse[0]) {
                break;
            }
            let unit = fine[l - 1].any_periodic() || coarse[0].any_periodic();
            coarse[0].build_dense(if unit {
                DenseDiag::Count
            } else {
                DenseDiag::Later
            });
            fine[l - 1].galerkin(&mut coarse[0]);
            self.used += 1;
        }
    }

    /// Applies the V-cycle: `levels[0].x = M^{-1} levels[0].b` (dense, zero off the fluid cells).
    /// With `initialised`, level 0's first half-sweep (`x = inv b` on red cells) is already done.
    /// Returns `sum b x` on level 0 (computed in the last half-sweep where there is one).
    pub fn vcycle(&mut self, initialised: bool) -> f64 {
        let n = self.used;
        let sweeps = self.sweeps.max(1);
        for l in 0..n - 1 {
            let (fine, coarse) = self.levels.split_at_mut(l + 1);
            let fine = &mut fine[l];
            for s in 0..sweeps {
                if !(s == 0 && l == 0 && initialised) {
                    fine.half_sweep(0, s == 0, false);
                }
                fine.half_sweep(1, false, false);
            }
            fine.residual();
            restrict(fine, &mut coarse[0], self.coarse_scale);
        }
        let last = &mut self.levels[n - 1];
        for s in 0..self.coarsest_sweeps.max(1) {
            last.half_sweep(0, s == 0, false);
            last.half_sweep(1, false, false);
            last.half_sweep(1, false, false);
            last.half_sweep(0, false, false);
        }
        let mut sum = None;
        for l in (0..n - 1).rev() {
            let (fine, coarse) = self.levels.split_at_mut(l + 1);
            let fine = &mut fine[l];
            prolongate(&coarse[0], fine);
            for s in 0..sweeps {
                fine.half_sweep(1, false, false);
                let last = l == 0 && s + 1 == sweeps;
                let v = fine.half_sweep(0, false, last);
                if last {
                    sum = Some(v);
                }
            }
        }
        sum.unwrap_or_else(|| {
            let l0 = &self.levels[0];
            run(l0, SpanOp::Dot { a: &l0.b, b: &l0.x })
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An irregular label grid: a ball of fluid with an open cap and a solid inclusion.
    fn ball(n: usize, periodic: [bool; 3]) -> Level {
        let mut l = Level {
            dims: [n, n, n],
            periodic,
            ..Default::default()
        };
        let c = (n as f64 - 1.0) / 2.0;
        for k in 0..n {
            for j in 0..n {
                for i in 0..n {
                    let r2 = [i, j, k]
                        .iter()
                        .map(|&v| (v as f64 - c).powi(2))
                        .sum::<f64>();
                    let label = if r2 > c * c {
                        L_SOLID
                    } else if k + 2 >= n {
                        L_OPEN
                    } else if (i as f64 - c).abs() < 1.5 && (j as f64 - c).abs() < 1.5 && k < n / 2
                    {
                        L_SOLID
                    } else {
                        L_FLUID
                    };
                    l.label.push(label);
                }
            }
        }
        l.build_rows();
        l
    }

    fn mg(n: usize) -> Multigrid {
        let mut m = Multigrid {
            coarse_scale: 0.5,
            sweeps: 2,
            coarsest_sweeps: 16,
            ..Default::default()
        };
        m.levels.push(ball(n, [false; 3]));
        m.build_hierarchy();
        m
    }

    /// `M b` in compressed rows.
    fn apply(m: &mut Multigrid, b: &[f32]) -> Vec<f32> {
        let l0 = &mut m.levels[0];
        l0.b.fill(0.0);
        for (row, &v) in b.iter().enumerate() {
            let p = l0.pad_of_row[row] as usize;
            l0.b[p] = v;
        }
        m.vcycle(false);
        let l0 = &m.levels[0];
        l0.pad_of_row.iter().map(|&p| l0.x[p as usize]).collect()
    }

    /// `A x` from the compressed rows (the reference the dense operator must match).
    fn matvec(l: &Level, x: &[f32]) -> Vec<f32> {
        (0..l.rows())
            .map(|r| {
                let mut s = l.diag[r] * x[r];
                for &nb in &l.nbr[r] {
                    if (nb as usize) < l.rows() {
                        s -= x[nb as usize];
                    }
                }
                s
            })
            .collect()
    }

    #[test]
    fn dense_operator_equals_the_compressed_rows() {
        // Non-periodic and periodic (odd and one-cell axes included) grids.
        for (n, periodic) in [
            (9, [false; 3]),
            (8, [true, false, true]),
            (7, [true, true, false]),
        ] {
            let mut l = ball(n, periodic);
            if periodic[2] {
                // A fully fluid periodic slab so wrap-around neighbours exist.
                l.label.iter_mut().for_each(|v| *v = L_FLUID);
                l.build_rows();
            }
            let x: Vec<f32> = (0..l.rows())
                .map(|i| ((i * 37) % 11) as f32 - 5.0)
                .collect();
            let mut v = vec![0.0f32; l.x.len()];
            for (row, &p) in l.pad_of_row.iter().enumerate() {
                v[p as usize] = x[row];
            }
            l.halo(&mut v);
            let mut y = vec![0.0f32; v.len()];
            l.apply(&v, &mut y);
            let reference = matvec(&l, &x);
            for (row, &p) in l.pad_of_row.iter().enumerate() {
                assert_eq!(y[p as usize], reference[row], "n {n} periodic {periodic:?}");
            }
            // Nothing leaks onto non-fluid cells.
            let fluid_sum: f32 = l.pad_of_row.iter().map(|&p| y[p as usize].abs()).sum();
            assert_eq!(y.iter().map(|v| v.abs()).sum::<f32>(), fluid_sum);
        }
    }

    /// Every coarse level is the Galerkin operator `P^T A P / 4` of the level above it (`P` the
    /// piecewise-constant prolongation onto the fluid children of fluid coarse cells), checked
    /// column by column through the levels' own dense stencils: on the ball (odd sizes, so blocks
    /// are cut by the box) and on random labels with solid, fluid and open cells.
    #[test]
    fn coarse_levels_are_the_galerkin_operator_of_the_level_above() {
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut random_labels = |n: usize| {
            let mut l = Level {
                dims: [n, n - 2, n + 3],
                ..Default::default()
            };
            l.label = (0..n * (n - 2) * (n + 3))
                .map(|_| {
                    seed ^= seed << 13;
                    seed ^= seed >> 7;
                    seed ^= seed << 17;
                    match seed % 20 {
                        0 => L_OPEN,
                        1..=5 => L_SOLID,
                        _ => L_FLUID,
                    }
                })
                .collect();
            l.build_rows();
            l
        };
        for level0 in [ball(9, [false; 3]), ball(12, [false; 3]), random_labels(11)] {
            let mut m = Multigrid {
                levels: vec![level0],
                ..Default::default()
            };
            m.build_hierarchy();
            assert!(m.used >= 3, "levels: {}", m.used);
            for l in 1..m.used {
                let (fine, coarse) = (&m.levels[l - 1], &m.levels[l]);
                let cells = |lv: &Level| {
                    let mut v = Vec::new();
                    for &[j, k, i0, i1] in &lv.row_spans {
                        for i in i0..i1 {
                            let c = [i as usize, j as usize, k as usize];
                            if lv.mask[lv.pad(c[0], c[1], c[2])] == 1.0 {
                                v.push(c);
                            }
                        }
                    }
                    v
                };
                let (fine_cells, coarse_cells) = (cells(fine), cells(coarse));
                let parent = |c: [usize; 3]| coarse.pad(c[0] / 2, c[1] / 2, c[2] / 2);
                for &cj in &coarse_cells {
                    let pj = coarse.pad(cj[0], cj[1], cj[2]);
                    // A_f P e_J, then P^T of it / 4.
                    let mut v = vec![0.0f32; fine.x.len()];
                    for &c in &fine_cells {
                        if parent(c) == pj {
                            v[fine.pad(c[0], c[1], c[2])] = 1.0;
                        }
                    }
                    let mut y = vec![0.0f32; v.len()];
                    fine.apply(&v, &mut y);
                    let mut galerkin = vec![0.0f32; coarse.x.len()];
                    for &c in &fine_cells {
                        galerkin[parent(c)] += y[fine.pad(c[0], c[1], c[2])] / 4.0;
                    }
                    let mut e = vec![0.0f32; coarse.x.len()];
                    e[pj] = 1.0;
                    let mut column = vec![0.0f32; e.len()];
                    coarse.apply(&e, &mut column);
                    for &ci in &coarse_cells {
                        let pi = coarse.pad(ci[0], ci[1], ci[2]);
                        assert!(
                            (column[pi] - galerkin[pi]).abs() <= 1e-6 * galerkin[pi].abs().max(1.0),
                            "level {l}, row {ci:?}, column {cj:?}: {} vs Galerkin {}",
                            column[pi],
                            galerkin[pi]
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn vcycle_is_a_symmetric_positive_operator() {
        let mut m = mg(17);
        assert!(m.used >= 3, "levels {}", m.used);
        let n = m.levels[0].rows();
        let a: Vec<f32> = (0..n)
            .map(|i| ((i * 7919) % 101) as f32 / 50.0 - 1.0)
            .collect();
        let b: Vec<f32> = (0..n)
            .map(|i| ((i * 104729) % 97) as f32 / 48.0 - 1.0)
            .collect();
        let ma = apply(&mut m, &a);
        let mb = apply(&mut m, &b);
        let dot = |x: &[f32], y: &[f32]| {
            x.iter()
                .zip(y)
                .map(|(p, q)| *p as f64 * *q as f64)
                .sum::<f64>()
        };
        let (ab, ba) = (dot(&ma, &b), dot(&a, &mb));
        assert!(
            (ab - ba).abs() <= 1e-4 * ab.abs().max(ba.abs()),
            "<Ma,b> = {ab}, <a,Mb> = {ba}"
        );
        assert!(dot(&ma, &a) > 0.0 && dot(&mb, &b) > 0.0);
    }

    #[test]
    fn parallel_vcycle_equals_the_serial_one() {
        let mut serial = mg(17);
        let mut parallel = mg(17);
        for l in &mut parallel.levels {
            l.parallel = true;
        }
        let l0 = &parallel.levels[0];
        assert!(l0.split_span > 0 && l0.split_span < l0.spans.len());
        let n = serial.levels[0].rows();
        let b: Vec<f32> = (0..n).map(|i| ((i * 31) % 17) as f32 - 8.0).collect();
        assert_eq!(apply(&mut serial, &b), apply(&mut parallel, &b));
    }

    #[test]
    fn parallel_vcycle_equals_the_serial_one_on_a_periodic_slab() {
        // A one-cell periodic axis: the transfers read the ghost layer of the residual, which the
        // split smoother's swap must leave at zero.
        let make = |parallel: bool| {
            let mut l = Level {
                dims: [16, 12, 1],
                periodic: [true; 3],
                ..Default::default()
            };
            l.label = vec![L_FLUID; 16 * 12];
            l.label[5] = L_OPEN;
            l.build_rows();
            let mut m = Multigrid {
                coarse_scale: 0.5,
                sweeps: 2,
                coarsest_sweeps: 16,
                ..Default::default()
            };
            m.levels.push(l);
            m.build_hierarchy();
            for l in &mut m.levels {
                l.parallel = parallel;
            }
            m
        };
        let (mut serial, mut parallel) = (make(false), make(true));
        assert!(serial.used >= 3, "levels {}", serial.used);
        let n = serial.levels[0].rows();
        let b: Vec<f32> = (0..n).map(|i| ((i * 31) % 17) as f32 - 8.0).collect();
        assert_eq!(apply(&mut serial, &b), apply(&mut parallel, &b));
    }

    #[test]
    fn vcycle_reduces_the_error_of_the_poisson_problem() {
        // As a stationary iteration x <- x + M (b - A x), one V-cycle must contract the error well.
        let mut m = mg(17);
        let n = m.levels[0].rows();
        let exact: Vec<f32> = (0..n).map(|i| (i as f32 * 0.37).sin()).collect();
        let b = matvec(&m.levels[0], &exact);
        let mut x = vec![0.0f32; n];
        for _ in 0..2 {
            let ax = matvec(&m.levels[0], &x);
            let r: Vec<f32> = b.iter().zip(&ax).map(|(p, q)| p - q).collect();
            let z = apply(&mut m, &r);
            for (xi, zi) in x.iter_mut().zip(&z) {
                *xi += zi;
            }
        }
        let err = x
            .iter()
            .zip(&exact)
            .map(|(p, q)| (p - q).abs())
            .fold(0.0f32, f32::max);
        assert!(err < 0.1, "error after two V-cycles: {err}");
    }

    /// Level 0 relabelled through `set_labels` (which clears only the last row ranges) and the
    /// hierarchy rebuilt over the row ranges, after any sequence of relabellings, equal a
    /// hierarchy built from scratch by scanning the box, level by level and field by field.
    #[test]
    fn rounded_spans_cover_the_spans_in_whole_lanes_without_overlap() {
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut next = |m: u32| {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed % m as u64) as u32
        };
        for _ in 0..2000 {
            let limit = 200 + next(100) as usize;
            let mut spans = Vec::new();
            let mut at = next(5);
            while spans.len() < 12 {
                let e = at + 1 + next(20);
                if e as usize > limit {
                    break;
                }
                spans.push([at, e]);
                at = e + next(12);
            }
            let before = spans.clone();
            round_spans(&mut spans, limit);
            for w in spans.windows(2) {
                assert!(w[0][1] <= w[1][0], "{spans:?}");
            }
            for &[s, e] in &spans {
                let len = (e - s) as usize;
                assert!(
                    len.is_multiple_of(LANES) || e as usize == limit,
                    "{spans:?} limit {limit}"
                );
            }
            for &[s, e] in &before {
                assert!(
                    spans.iter().any(|&[a, b]| a <= s && e <= b),
                    "[{s}, {e}) of {before:?} not in {spans:?}"
                );
            }
            for &[a, b] in &spans {
                // Only whole-lane padding is added: each rounded span starts at an original span.
                assert!(before.iter().any(|&[s, _]| s == a), "{spans:?}");
                assert!(b as usize <= limit);
            }
        }
    }

    #[test]
    fn a_relabelled_hierarchy_equals_one_built_from_scratch() {
        fn hierarchy(m: &mut Multigrid) {
            m.coarse_scale = 0.5;
            m.sweeps = 1;
            m.coarsest_sweeps = 1;
            m.build_hierarchy();
        }
        for (dims, periodic) in [
            ([13, 9, 10], [false; 3]),
            ([12, 8, 10], [true, false, true]),
            ([10, 7, 6], [false, true, false]),
        ] {
            let mut rng = fastrand::Rng::with_seed(5);
            let [nx, ny, nz] = dims;
            let mut labels = vec![L_SOLID; nx * ny * nz];
            let mut rows = Vec::new();
            let mut kept = Multigrid::default();
            for round in 0..30 {
                // A moving blob of fluid with open and solid cells sprinkled in, now and then
                // emptied (no fluid at all) or filling whole rows.
                let centre = [rng.usize(..nx), rng.usize(..ny), rng.usize(..nz)];
                let radius = if round % 7 == 3 { 0 } else { rng.usize(1..nx) };
                for (c, l) in labels.iter_mut().enumerate() {
                    let p = [c % nx, (c / nx) % ny, c / (nx * ny)];
                    let d2: usize = (0..3).map(|a| p[a].abs_diff(centre[a]).pow(2)).sum();
                    *l = if d2 >= radius * radius {
                        L_SOLID
                    } else {
                        [L_FLUID, L_FLUID, L_FLUID, L_OPEN, L_SOLID][rng.usize(..5)]
                    };
                }
                rows.clear();
                for row in labels.chunks_exact(nx) {
                    let open = |l: &u8| *l != L_SOLID;
                    rows.push(
                        match (row.iter().position(open), row.iter().rposition(open)) {
                            (Some(a), Some(b)) => [a as u32, b as u32 + 1],
                            _ => [0, 0],
                        },
                    );
                }
                if kept.levels.is_empty() {
                    kept.levels.push(Level::default());
                }
                kept.levels[0].set_labels(dims, periodic, &rows, |c| labels[c]);
                kept.levels[0].build_in_extents();
                // The compressed rows are built lazily: now and then, after relabellings that
                // did not build them.
                let rows = round % 3 == 2;
                if rows {
                    kept.levels[0].build_compressed_rows();
                }
                hierarchy(&mut kept);
                let mut fresh = Multigrid::default();
                fresh.levels.push(Level {
                    dims,
                    periodic,
                    label: labels.clone(),
                    ..Default::default()
                });
                fresh.levels[0].build_rows();
                hierarchy(&mut fresh);
                assert_eq!(kept.used, fresh.used, "levels, round {round}");
                for (l, (a, b)) in kept.levels.iter().zip(&fresh.levels).enumerate() {
                    if l >= fresh.used {
                        break;
                    }
                    let at = format!("level {l}, round {round}, {periodic:?}");
                    // Every field of the level, named in the failure.
                    macro_rules! same {
                        ($($f:ident),*) => {$(
                            assert_eq!(a.$f, b.$f, "{} at {at}", stringify!($f));
                        )*};
                    }
                    same!(dims, periodic, label, sy, sz, fluid, spans);
                    if l == 0 && rows {
                        same!(rows_built, row_of_cell, cell_of_row, nbr, diag, inv_diag);
                        same!(pad_of_row);
                    }
                    same!(split_span, row_spans, ddiag, mask, inv, wt, x, b, r);
                }
            }
        }
    }
}
