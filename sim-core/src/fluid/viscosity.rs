//! Viscous diffusion of the face velocities: explicit where stable, backward Euler (Jacobi-PCG)
//! otherwise. Walls enter through ghost values (no-slip at the wall, moving with `Velocity` cells),
//! outflow sides as zero gradient. This is the labels' (staircase) operator; on grids whose cut
//! fractions carry the walls' distances the solver builds the operator of `cut_viscosity.rs`
//! instead and runs the same implicit solve on it ([`Operator`]).

// Index loops over several parallel arrays read clearer than zipped iterators here.
#![allow(clippy::needless_range_loop)]

use super::topology::{FaceSet, Irregular, CONST_BIT, NONE};

/// Which viscosity step ran.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ViscosityMode {
    /// Viscosity is zero: the stage was skipped.
    #[default]
    Skipped,
    /// Explicit (forward Euler), used when `nu dt / h^2` is below the stability limit.
    Explicit,
    /// Implicit (backward Euler), solved by Jacobi-preconditioned CG.
    Implicit,
}

/// Largest `nu dt / h^2` for which the explicit step is used (stable with quadratic wall ghosts on up to two sides).
pub const EXPLICIT_LIMIT: f64 = 0.08;

/// Scratch vectors of the implicit solve.
#[derive(Default, Debug)]
pub(crate) struct ViscosityScratch {
    pub rhs: Vec<f32>,
    pub x: Vec<f32>,
    pub r: Vec<f32>,
    pub p: Vec<f32>,
    pub ap: Vec<f32>,
}

/// The implicit system of one component: per compact face its full index, the diagonal of the
/// negative Laplacian and the stencil (see [`FaceSet`]; `compact` maps full indices).
#[derive(Clone, Copy)]
pub(crate) struct Operator<'a> {
    pub active: &'a [u32],
    pub compact: &'a [u32],
    pub stencil: &'a [[u32; 6]],
    pub diag: &'a [f32],
}

impl<'a> Operator<'a> {
    /// The labels' operator (staircase walls).
    pub fn of(set: &'a FaceSet) -> Self {
        Self {
            active: &set.active,
            compact: &set.compact,
            stencil: &set.stencil,
            diag: &set.diag,
        }
    }
}

/// Sum of the fixed (constant) neighbours of compact face `n` plus its wall ghosts.
#[inline]
fn constant_part(op: Operator, full: &[f32], ghost: &[f32], n: usize) -> f32 {
    let mut s = ghost[n];
    for &e in &op.stencil[n] {
        if e != NONE && e & CONST_BIT != 0 {
            s += full[(e & !CONST_BIT) as usize];
        }
    }
    s
}

/// Sum of the active neighbours of compact face `n` in `x` (compact; the stencil holds full
/// indices, which `compact` maps).
#[inline]
fn variable_part(op: Operator, x: &[f32], n: usize) -> f32 {
    let mut s = 0.0;
    for &e in &op.stencil[n] {
        if e != NONE && e & CONST_BIT == 0 {
            s += x[op.compact[e as usize] as usize];
        }
    }
    s
}

/// Explicit step: `out[n] = u + a (sum of neighbours + ghosts - diag u)`.
pub(crate) fn explicit(
    set: &FaceSet,
    full: &[f32],
    ghost: &[f32],
    a: f32,
    out: &mut [f32],
    parallel: bool,
) {
    let d = set.fdims;
    let (sy, sz) = (d[0], d[0] * d[1]);
    /// The inputs of the regular runs: the field, its wall ghosts, `a`, and the y and z strides.
    #[derive(Clone, Copy)]
    struct Stencil<'s> {
        full: &'s [f32],
        ghost: &'s [f32],
        a: f32,
        strides: [usize; 2],
    }
    // Regular runs: the 7-point stencil on contiguous slices (same sum order as the general
    // form below, so the same rounding), which the compiler vectorises. `base` is the compact
    // index of `out[0]`.
    #[inline(always)]
    fn runs(st: Stencil, runs: &[[u32; 3]], base: usize, out: &mut [f32]) {
        let Stencil {
            full,
            ghost,
            a,
            strides: [sy, sz],
        } = st;
        for &[f, n, len] in runs {
            let (f, n, len) = (f as usize, n as usize, len as usize);
            let u = &full[f..f + len];
            let (xm, xp) = (&full[f - 1..f - 1 + len], &full[f + 1..f + 1 + len]);
            let (ym, yp) = (&full[f - sy..f - sy + len], &full[f + sy..f + sy + len]);
            let (zm, zp) = (&full[f - sz..f - sz + len], &full[f + sz..f + sz + len]);
            let g = &ghost[n..n + len];
            let o = &mut out[n - base..n - base + len];
            for i in 0..len {
                let mut s = g[i] - 6.0 * u[i];
                s += xm[i];
                s += xp[i];
                s += ym[i];
                s += yp[i];
                s += zm[i];
                s += zp[i];
                o[i] = u[i] + a * s;
            }
        }
    }
    /// [`runs`] as a kernel compiled twice: for AVX2 when the CPU has it (eight lanes; no FMA
    /// contraction, same values) and for the baseline (`crate::simd`).
    struct Runs<'s> {
        st: Stencil<'s>,
        runs: &'s [[u32; 3]],
        base: usize,
        out: &'s mut [f32],
    }
    impl crate::simd::Kernel for Runs<'_> {
        type Output = ();
        #[inline(always)]
        fn run(self) {
            runs(self.st, self.runs, self.base, self.out)
        }
    }
    let st = Stencil {
        full,
        ghost,
        a,
        strides: [sy, sz],
    };
    let run = |runs: &[[u32; 3]], base: usize, out: &mut [f32]| {
        crate::simd::dispatch(Runs {
            st,
            runs,
            base,
            out,
        })
    };
    // The others through the general stencil (see `FaceSet::nbr`); `base` is the compact index
    // of `out[0]`.
    let others = |list: &[Irregular], base: usize, out: &mut [f32]| {
        for f in list {
            let n = f.n as usize;
            let u = full[f.idx as usize];
            let mut s = ghost[n] - f.self_diag * u;
            for &e in &f.nbr {
                s += full[e as usize];
            }
            out[n - base] = u + a * s;
        }
    };
    if parallel {
        // Two halves by compact index (the machine this is tuned on has two cores): the regular
        // runs split in two, and the irregular faces (ascending) on the same side of the cut.
        let (r0, r1) = set.regular.split_at(set.regular.len() / 2);
        let split = r1.first().map_or(out.len(), |r| r[1] as usize);
        let (i0, i1) = set
            .irregular
            .split_at(set.irregular.partition_point(|f| (f.n as usize) < split));
        let (o0, o1) = out.split_at_mut(split);
        crate::fork_join::join(
            || {
                run(r0, 0, o0);
                others(i0, 0, o0);
            },
            || {
                run(r1, split, o1);
                others(i1, split, o1);
            },
        );
    } else {
        run(&set.regular, 0, out);
        others(&set.irregular, 0, out);
    }
}

/// Copies the compact values back into the active faces of the full array, run by run.
pub(crate) fn write_back(set: &FaceSet, compact: &[f32], full: &mut [f32]) {
    for &[f, n, len] in &set.runs {
        let (f, n, len) = (f as usize, n as usize, len as usize);
        full[f..f + len].copy_from_slice(&compact[n..n + len]);
    }
}

/// Implicit step: solves `(1 + a diag) x - a sum(active neighbours) = u + a (constants)`. Returns
/// the CG iterations; the result is in `scratch.x`.
pub(crate) fn implicit(
    op: Operator,
    full: &[f32],
    ghost: &[f32],
    a: f32,
    scratch: &mut ViscosityScratch,
    rel_tol: f64,
    max_iterations: usize,
) -> usize {
    let n = op.active.len();
    let ViscosityScratch { rhs, x, r, p, ap } = scratch;
    for v in [&mut *rhs, &mut *x, &mut *r, &mut *p, &mut *ap] {
        v.clear();
        v.resize(n, 0.0);
    }
    for i in 0..n {
        let u = full[op.active[i] as usize];
        rhs[i] = u + a * constant_part(op, full, ghost, i);
        x[i] = u;
    }
    let apply = |x: &[f32], i: usize| (1.0 + a * op.diag[i]) * x[i] - a * variable_part(op, x, i);
    let mut rr = 0.0f64;
    let mut bb = 0.0f64;
    for i in 0..n {
        r[i] = rhs[i] - apply(x, i);
        rr += (r[i] as f64).powi(2);
        bb += (rhs[i] as f64).powi(2);
    }
    let inv = |i: usize| 1.0 / (1.0 + a * op.diag[i]);
    // Relative to the initial residual (the warm start is usually close), floored near f32 precision.
    let tol2 = (rel_tol * rel_tol * rr).max(1e-14 * bb).max(1e-30);
    if rr <= 1e-14 * bb {
        return 0;
    }
    let mut rz = 0.0f64;
    for i in 0..n {
        p[i] = r[i] * inv(i);
        rz += (r[i] * p[i]) as f64;
    }
    for it in 1..=max_iterations {
        let mut pap = 0.0f64;
        for i in 0..n {
            ap[i] = apply(p, i);
            pap += (p[i] * ap[i]) as f64;
        }
        if pap.is_nan() || pap <= 0.0 {
            return it;
        }
        let alpha = (rz / pap) as f32;
        let mut rr = 0.0f64;
        for i in 0..n {
            x[i] += alpha * p[i];
            r[i] -= alpha * ap[i];
            rr += (r[i] as f64).powi(2);
        }
        if rr <= tol2 {
            return it;
        }
        let mut rz_new = 0.0f64;
        for i in 0..n {
            rz_new += (r[i] * r[i] * inv(i)) as f64;
        }
        let beta = (rz_new / rz) as f32;
        rz = rz_new;
        for i in 0..n {
            p[i] = r[i] * inv(i) + beta * p[i];
        }
    }
    max_iterations
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fluid::sample::Layout;
    use crate::fluid::{CellLabel, FluidGrid};

    /// The explicit step (the regular runs on the AVX2 path where the CPU has it, the other faces
    /// through the general stencil) against the general stencil on every active face, on one and
    /// two threads: equal to the bit, as the runs sum in the general form's order and without
    /// FMA. A grid of scattered walls, moving walls and outflow cells, so that both kinds of face
    /// occur in every component.
    #[test]
    fn the_explicit_step_equals_the_general_stencil_on_every_face() {
        let mut rng = fastrand::Rng::with_seed(41);
        let mut grid = FluidGrid::new([37, 13, 11], 1e-3, [0.0; 3], [false; 3]).unwrap();
        let [nx, ny, nz] = grid.dims();
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    let label = match rng.u32(0..40) {
                        0..=2 => CellLabel::Solid,
                        3 => CellLabel::Velocity,
                        4 => CellLabel::Outflow,
                        _ => CellLabel::Fluid,
                    };
                    grid.set_label([i, j, k], label).unwrap();
                }
            }
        }
        let layout = Layout::new(grid.dims(), grid.periodic());
        let a = 0.15f32;
        for c in 0..3 {
            let mut set = FaceSet::default();
            set.update(&grid, &layout, c, None);
            assert!(
                !set.regular.is_empty() && !set.irregular.is_empty(),
                "component {c}"
            );
            let full: Vec<f32> = (0..layout.face_count(c)).map(|_| rng.f32() - 0.5).collect();
            let ghost: Vec<f32> = (0..set.active.len()).map(|_| rng.f32() - 0.5).collect();
            for parallel in [false, true] {
                let mut out = vec![f32::NAN; set.active.len()];
                explicit(&set, &full, &ghost, a, &mut out, parallel);
                for (n, &idx) in set.active.iter().enumerate() {
                    let u = full[idx as usize];
                    let mut s = ghost[n] - set.self_diag[n] * u;
                    for &e in &set.nbr[n] {
                        s += full[e as usize];
                    }
                    let want = u + a * s;
                    assert_eq!(
                        out[n].to_bits(),
                        want.to_bits(),
                        "component {c}, face {idx}, parallel {parallel}: {} vs {want}",
                        out[n]
                    );
                }
            }
        }
    }
}
