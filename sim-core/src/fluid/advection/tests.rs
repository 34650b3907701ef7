use super::super::sample::Layout;
#[cfg(target_arch = "x86_64")]
use super::avx2;
use super::plan::BLOCK;
use super::{gather, scatter, update_centred, Geometry, Pass, Plan};
use crate::fluid::topology::extend_runs;
use crate::simd::{v4, V4};

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
    if !crate::simd::avx2_fma() {
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
