//! The vector kernels of the multigrid and of the CG around it: every one a branch-free loop over
//! the contiguous spans of a level's padded vectors, written so that LLVM vectorises it and
//! compiled twice by [`crate::simd::dispatch`] (AVX2 + FMA where the CPU has both, else the SSE2
//! baseline: the same operations, so the same results to the bit; the reductions use fixed
//! lanes). On a level marked `parallel` the spans run in two halves on two threads.

use super::level::{Level, LANES};

/// Cells per stack buffer of the smoother (a few cache lines; any length is correct).
const CHUNK: usize = 128;

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

impl crate::simd::Kernel for SpanRun<'_> {
    type Output = f64;

    // Everything below is inlined into `simd::dispatch`'s two instantiations, so it is compiled
    // (and auto-vectorised) once for AVX2 + FMA and once for the SSE2 baseline.
    #[inline(always)]
    fn run(self) -> f64 {
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

/// Runs `op` over `spans` of `level` (outputs from padded index `off`), compiled for AVX2 + FMA
/// where the CPU has both.
pub(super) fn dispatch(level: &Level, spans: &[[u32; 2]], off: usize, op: SpanOp<'_>) -> f64 {
    crate::simd::dispatch(SpanRun {
        op,
        spans,
        wt: level.couplings(),
        off,
        sy: level.sy,
        sz: level.sz,
    })
}

/// [`dispatch`] over all of `level`'s spans compiled for the baseline only: the reference of the
/// AVX2 compilation in the tests.
#[cfg(test)]
pub(super) fn portable(level: &Level, op: SpanOp<'_>) -> f64 {
    use crate::simd::Kernel;
    SpanRun {
        op,
        spans: &level.spans,
        wt: level.couplings(),
        off: 0,
        sy: level.sy,
        sz: level.sz,
    }
    .run()
}

/// Runs `op` over `level`'s spans, compiled for the best instruction set of this CPU (AVX2 + FMA
/// where present, else the SSE2 baseline of the generic x86-64 binary; element-wise kernels give
/// bit-identical results either way, and the reductions use fixed lanes). On a level marked
/// `parallel` the spans run in two halves on two threads (one fork-join per call).
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
