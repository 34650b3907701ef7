//! The fluid solver on the portable (baseline) compilation of every SIMD kernel against the AVX2
//! one, end to end: every fluid kernel does the scalar code's operations in their order, without
//! FMA (`sim-core/src/simd`), so the steps must agree to the bit, whatever the scheme, on one
//! thread and in two halves, across a relabelling. The SIMD level is process-wide: this binary
//! holds this one test.

use hydrometra_sim::fluid::{AdvectionScheme, CellLabel, FluidParams, FluidSolver};
use hydrometra_sim::harness::analytic_cavity::{add_stray_blocks, ellipsoid_cavity};
use hydrometra_sim::harness::simd::{avx2_fma, set_portable};

/// The face velocities' bits and the largest face speed's after 12 steps of the ellipsoid cavity (1.5 mm, jet 1 m/s, gravity,
/// stray closed blocks, one cell walled off after 6 steps) with `scheme`, stages split in two
/// halves from `threshold` cells (`parallel_threshold_cells`).
fn run(scheme: AdvectionScheme, threshold: usize) -> ([Vec<u32>; 3], u64) {
    let mut grid = ellipsoid_cavity(0.0015, 1.0).expect("cavity");
    assert!(add_stray_blocks(&mut grid, 2).len() >= 8);
    let params = FluidParams {
        advection: scheme,
        body_force_m_s2: [0.0, 0.0, -9.81],
        parallel_threshold_cells: threshold,
        ..Default::default()
    };
    let mut s = FluidSolver::new(grid, params).expect("solver");
    let dims = s.grid().dims();
    let middle = dims.map(|n| n / 2);
    for n in 0..12 {
        if n == 6 {
            assert_eq!(s.grid().label(middle), Some(CellLabel::Fluid));
            s.grid_mut()
                .set_label(middle, CellLabel::Solid)
                .expect("relabel");
        }
        s.step(1.0 / 60.0).expect("step");
    }
    let max_speed = s.max_speed_m_s();
    assert!(max_speed > 0.1, "the jet flows: {max_speed} m/s");
    let faces = std::array::from_fn(|c| s.face_velocities(c).iter().map(|v| v.to_bits()).collect());
    (faces, max_speed.to_bits())
}

#[test]
fn the_fluid_steps_are_the_same_bits_on_the_portable_kernels() {
    if !avx2_fma() {
        eprintln!("SKIP: no AVX2 + FMA, every kernel is on its portable path already");
        return;
    }
    for scheme in AdvectionScheme::ALL {
        // 12 000: one thread at this size; 120: every stage in two halves.
        for threshold in [12_000, 120] {
            set_portable(false);
            let wide = run(scheme, threshold);
            set_portable(true);
            let portable = run(scheme, threshold);
            set_portable(false);
            assert_eq!(
                wide.1, portable.1,
                "{scheme:?}, threshold {threshold}: max speed"
            );
            let (wide, portable) = (wide.0, portable.0);
            for c in 0..3 {
                let first = wide[c].iter().zip(&portable[c]).position(|(a, b)| a != b);
                assert_eq!(
                    first, None,
                    "{scheme:?}, threshold {threshold}, component {c}: face {first:?} differs"
                );
            }
        }
    }
}
