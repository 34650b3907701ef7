//! A step allocates nothing on the heap once the topology is built, serial or split over two threads,
//! with either advection scheme, explicit or implicit viscosity, and body forces. Steps right after a label change
//! rebuild the topology and may allocate (only when buffers must grow).

use std::sync::atomic::Ordering;

use hydrometra_sim::fluid::{AdvectionScheme, FluidParams, FluidSolver};
use hydrometra_sim::harness::analytic_cavity::ellipsoid_cavity;

mod common;
use common::alloc::ALLOCS;

#[test]
fn steady_steps_do_not_allocate() {
    // usize::MAX: serial; 12: every stage and level split (from 12 / 12 = 1 cell).
    for (scheme, nu, threshold) in [
        (AdvectionScheme::SemiLagrangian, 1e-6, usize::MAX),
        (AdvectionScheme::MacCormack, 1e-3, usize::MAX),
        (AdvectionScheme::SemiLagrangian, 1e-6, 12),
        (AdvectionScheme::MacCormack, 1e-3, 12),
        (
            AdvectionScheme::MacCormackLaggedReflection,
            1e-3,
            usize::MAX,
        ),
        (AdvectionScheme::MacCormackLaggedReflection, 1e-6, 12),
        (AdvectionScheme::Bfecc, 1e-6, 12),
        (AdvectionScheme::MonotoneCubic, 1e-6, 12),
        (AdvectionScheme::MacCormackReflection, 1e-3, 12),
    ] {
        let grid = ellipsoid_cavity(0.0018, 1.0).unwrap();
        let params = FluidParams {
            advection: scheme,
            viscosity_m2_s: nu,
            body_force_m_s2: [0.0, 0.0, -9.81],
            parallel_threshold_cells: threshold,
            ..Default::default()
        };
        let mut s = FluidSolver::new(grid, params).unwrap();
        for _ in 0..3 {
            s.step(1.0 / 60.0).unwrap();
        }
        // The split path's helper thread sets up its parker the first time it parks (after 0.3 ms
        // without work): once per process, so let it happen before counting.
        std::thread::sleep(std::time::Duration::from_millis(5));
        s.step(1.0 / 60.0).unwrap();
        let before = ALLOCS.load(Ordering::Relaxed);
        let mut stats = Vec::with_capacity(20);
        let after_reserve = ALLOCS.load(Ordering::Relaxed);
        for n in 0..20 {
            stats.push(s.step(1.0 / 60.0).unwrap());
            if n % 5 == 4 {
                // Idle as between frames: the helper parks and is woken by the next step.
                std::thread::sleep(std::time::Duration::from_millis(2));
            }
        }
        let after = ALLOCS.load(Ordering::Relaxed);
        assert_eq!(
            after,
            after_reserve,
            "{scheme:?}, threshold {threshold}: {} allocations in 20 steps",
            after - after_reserve
        );
        assert!(after_reserve > before);
        assert!(stats
            .iter()
            .all(|s| s.projection_converged && s.projection_iterations > 0));
    }
}
