use super::level::{round_spans, LANES};
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
                } else if (i as f64 - c).abs() < 1.5 && (j as f64 - c).abs() < 1.5 && k < n / 2 {
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

/// Every span kernel and both grid transfers compiled for AVX2 + FMA (`simd::dispatch`) against
/// the baseline compilation of the same source, on a level with unit couplings and on a Galerkin
/// level: equal to the bit (Rust contracts nothing into FMA, and the reductions use fixed lanes).
#[test]
fn the_avx2_kernels_equal_the_portable_ones_to_the_bit() {
    if !crate::simd::avx2_fma() {
        eprintln!("SKIP the_avx2_kernels_equal_the_portable_ones_to_the_bit: no AVX2 + FMA");
        return;
    }
    use super::kernels::{dispatch, portable};
    let mut m = mg(14);
    assert!(m.used >= 2 && m.levels[1].couplings().is_some());
    let mut rng = fastrand::Rng::with_seed(31);
    let same = |a: &[f32], b: &[f32]| a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits());
    for l in 0..2 {
        let level = &m.levels[l];
        let n = level.mask.len();
        let mut random = || -> Vec<f32> { (0..n).map(|_| rng.f32() * 2.0 - 1.0).collect() };
        let (x, b, p, ap) = (random(), random(), random(), random());
        let (y0, z0, w0) = (random(), random(), random());
        let (diag, inv, mask) = (&level.ddiag[..], &level.inv[0][..], &level.mask[..]);
        // Runs `$op` (outputs `$y`, `$z`, `$w`) both ways and compares results and outputs.
        macro_rules! both {
            ($name:expr, |$y:ident, $z:ident, $w:ident| $op:expr) => {{
                let (mut y1, mut z1, mut w1) = (y0.clone(), z0.clone(), w0.clone());
                let (mut y2, mut z2, mut w2) = (y0.clone(), z0.clone(), w0.clone());
                let r1 = {
                    let ($y, $z, $w) = (&mut y1[..], &mut z1[..], &mut w1[..]);
                    let _ = (&$y, &$z, &$w);
                    portable(level, $op)
                };
                let r2 = {
                    let ($y, $z, $w) = (&mut y2[..], &mut z2[..], &mut w2[..]);
                    let _ = (&$y, &$z, &$w);
                    dispatch(level, &level.spans, 0, $op)
                };
                assert_eq!(
                    r1.to_bits(),
                    r2.to_bits(),
                    "level {l} {}: {r1} vs {r2}",
                    $name
                );
                assert!(
                    same(&y1, &y2) && same(&z1, &z2) && same(&w1, &w2),
                    "level {l} {}",
                    $name
                );
            }};
        }
        both!("init", |y, z, w| SpanOp::Init { x: y, b: &b, inv });
        both!("relax", |y, z, w| SpanOp::Relax {
            x: y,
            b: &b,
            diag,
            inv,
            dot: true
        });
        both!("relax into", |y, z, w| SpanOp::RelaxInto {
            t: y,
            x: &x,
            b: &b,
            diag,
            inv,
            dot: true
        });
        both!("residual", |y, z, w| SpanOp::Stencil {
            y,
            v: &x,
            b: Some(&b),
            diag,
            mask
        });
        both!("apply", |y, z, w| SpanOp::Stencil {
            y,
            v: &x,
            b: None,
            diag,
            mask
        });
        both!("dot", |y, z, w| SpanOp::Dot { a: &x, b: &b });
        both!("apply dot", |y, z, w| SpanOp::ApplyDot {
            y,
            v: &x,
            diag,
            mask
        });
        both!("update", |y, z, w| SpanOp::Update {
            alpha: 0.37,
            p: &p,
            ap: &ap,
            d: y,
            r: z,
            init: None
        });
        both!("update init", |y, z, w| SpanOp::Update {
            alpha: -1.3,
            p: &p,
            ap: &ap,
            d: y,
            r: z,
            init: Some((w, inv)),
        });
        both!("xpby", |y, z, w| SpanOp::Xpby {
            p: y,
            z: &x,
            beta: 0.61
        });
    }
    // The transfers between levels 0 and 1, on one thread each way.
    for level in &mut m.levels[..2] {
        level.parallel = false;
        for v in [&mut level.r, &mut level.x] {
            v.iter_mut().for_each(|v| *v = rng.f32() - 0.5);
        }
    }
    let (fine, coarse) = (&m.levels[0], &m.levels[1]);
    for restrict in [Some(0.5f32), None] {
        let out0: Vec<f32> = match restrict {
            Some(_) => coarse.b.clone(),
            None => fine.x.clone(),
        };
        let (mut a, mut b) = (out0.clone(), out0);
        super::transfer::transfer(fine, coarse, restrict, &mut a);
        super::transfer::transfer_portable(fine, coarse, restrict, &mut b);
        assert!(same(&a, &b), "transfer {restrict:?}");
    }
}
