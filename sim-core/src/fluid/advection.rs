//! Semi-Lagrangian advection of the face velocities: RK2 (midpoint) backtrace, and MacCormack
//! (a backward and a forward semi-Lagrangian step, error-corrected, clamped to the values the first
//! step interpolated from so it cannot create new extrema).

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

const CHUNK: usize = 1024;

/// Cell-centred velocity used for tracing.
pub(crate) struct Centred<'a> {
    pub dims: [usize; 3],
    pub v: &'a [[f32; 3]],
}

/// Traces from face position `x0` (grid units) over `dt_cells` (= dt / h, so velocity * dt_cells is
/// a displacement in cells) with the midpoint rule and returns the foot point.
/// The velocity is interpolated from its cell-centred average `vc` (one stencil for all three
/// components: the trace needs a smooth velocity, not the staggered detail).
#[inline]
fn trace(layout: &Layout, vc: &Centred, c: usize, f: [usize; 3], dt_cells: f32) -> [f32; 3] {
    let x0 = Layout::face_position(c, f);
    // At the face itself the centred field is the mean of the two cells beside it (clamped at a
    // non-periodic boundary): two loads instead of a full trilinear stencil.
    let n = vc.dims[c];
    let mut lo = f;
    let mut hi = f;
    if f[c] == 0 {
        lo[c] = if layout.periodic[c] { n - 1 } else { 0 };
    } else {
        lo[c] -= 1;
    }
    if hi[c] >= n {
        hi[c] = n - 1;
    }
    let at = |g: [usize; 3]| vc.v[g[0] + vc.dims[0] * (g[1] + vc.dims[1] * g[2])];
    let (a, b) = (at(lo), at(hi));
    let v0 = [
        0.5 * (a[0] + b[0]),
        0.5 * (a[1] + b[1]),
        0.5 * (a[2] + b[2]),
    ];
    let xm: [f32; 3] = std::array::from_fn(|a| x0[a] - 0.5 * dt_cells * v0[a]);
    let vm = layout.sample_centred(vc.dims, vc.v, xm);
    std::array::from_fn(|a| x0[a] - dt_cells * vm[a])
}

/// Semi-Lagrangian step of component `c` of `src` (traced through `u`) at the faces `active`,
/// written to `out` (compact). With `bounds`, also the min/max of the samples used.
#[allow(clippy::too_many_arguments)]
pub(crate) fn semi_lagrangian(
    layout: &Layout,
    vc: &Centred,
    src: &[f32],
    c: usize,
    active: &[u32],
    dt_cells: f32,
    out: &mut [f32],
    bounds: Option<(&mut [f32], &mut [f32])>,
    parallel: bool,
) {
    let foot = |idx: u32| trace(layout, vc, c, layout.face_coords(c, idx as usize), dt_cells);
    let one = |idx: u32| layout.sample_bounds(c, src, foot(idx));
    let plain = |idx: u32| layout.sample(c, src, foot(idx));
    match (bounds, parallel) {
        (None, false) => {
            for (o, &idx) in out.iter_mut().zip(active) {
                *o = plain(idx);
            }
        }
        (None, true) => out
            .par_chunks_mut(CHUNK)
            .zip(active.par_chunks(CHUNK))
            .for_each(|(os, is)| {
                for (o, &idx) in os.iter_mut().zip(is) {
                    *o = plain(idx);
                }
            }),
        (Some((lo, hi)), false) => {
            for (((o, l), h), &idx) in out
                .iter_mut()
                .zip(lo.iter_mut())
                .zip(hi.iter_mut())
                .zip(active)
            {
                (*o, *l, *h) = one(idx);
            }
        }
        (Some((lo, hi)), true) => out
            .par_chunks_mut(CHUNK)
            .zip(lo.par_chunks_mut(CHUNK))
            .zip(hi.par_chunks_mut(CHUNK))
            .zip(active.par_chunks(CHUNK))
            .for_each(|(((os, ls), hs), is)| {
                for (((o, l), h), &idx) in
                    os.iter_mut().zip(ls.iter_mut()).zip(hs.iter_mut()).zip(is)
                {
                    (*o, *l, *h) = one(idx);
                }
            }),
    }
}

/// MacCormack correction of component `c`: `hat` is the full field after the backward step, `orig`
/// the field before it; `out` holds the compact backward-step values on entry and the corrected,
/// clamped values on return.
#[allow(clippy::too_many_arguments)]
pub(crate) fn maccormack_correct(
    layout: &Layout,
    vc: &Centred,
    orig: &[f32],
    hat: &[f32],
    c: usize,
    active: &[u32],
    dt_cells: f32,
    out: &mut [f32],
    lo: &[f32],
    hi: &[f32],
    parallel: bool,
) {
    let one = |idx: u32, fwd_val: f32, l: f32, h: f32| {
        let xf = trace(
            layout,
            vc,
            c,
            layout.face_coords(c, idx as usize),
            -dt_cells,
        );
        let back = layout.sample(c, hat, xf);
        let v = fwd_val + 0.5 * (orig[idx as usize] - back);
        if v.is_finite() {
            v.clamp(l, h)
        } else {
            fwd_val
        }
    };
    if parallel {
        out.par_chunks_mut(CHUNK)
            .zip(active.par_chunks(CHUNK))
            .zip(lo.par_chunks(CHUNK).zip(hi.par_chunks(CHUNK)))
            .for_each(|((os, is), (ls, hs))| {
                for (((o, &idx), &l), &h) in os.iter_mut().zip(is).zip(ls).zip(hs) {
                    *o = one(idx, *o, l, h);
                }
            });
    } else {
        for (((o, &idx), &l), &h) in out.iter_mut().zip(active).zip(lo).zip(hi) {
            *o = one(idx, *o, l, h);
        }
    }
}
