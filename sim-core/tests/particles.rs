//! Vortices, particles and view clarity (docs/particles.md) on small MAC grids, no atlas.

use hydrometra_sim::fluid::{CellLabel, FluidGrid, FluidParams, FluidSolver};
use hydrometra_sim::scene::clarity::{ClarityTracker, ViewSpec};
use hydrometra_sim::scene::particles::{
    kinds_from_labels, terminal_slip, time_to_traverse, ParticleClass, ParticleKind, ParticleSpec,
    ParticleSystem, GRAVITY_M_S2,
};
use hydrometra_sim::scene::vortices::{Vortex, VortexField, VortexSpec, CUTOFF_CORES};
use hydrometra_sim::scene::{SceneDesc, VoxelKind};

const PI: f64 = std::f64::consts::PI;

fn solver(dims: [usize; 3], h: f64) -> FluidSolver {
    let grid = FluidGrid::new(dims, h, [0.0; 3], [false; 3]).unwrap();
    FluidSolver::new(grid, FluidParams::default()).unwrap()
}

fn tracer(sys: &mut ParticleSystem) -> u8 {
    sys.add_class(ParticleClass {
        kind: ParticleKind::Blood,
        settle_m_s: 0.0,
        tau_s: 0.0,
        shade_m2: 1e-9,
        diameter_m: 0.0,
    })
    .unwrap()
}

#[test]
fn rankine_profile_inside_and_outside_the_core_matches_the_closed_form() {
    let r_core = 2e-3;
    let gamma = 2.0 * PI * r_core * 0.3; // 0.3 m/s at the core's edge
    let v = Vortex {
        centre_m: [0.01, 0.02, 0.03],
        axis: [0.0, 0.6, 0.8],
        circulation_m2_s: gamma,
        core_radius_m: r_core,
    };
    // e1 is perpendicular to the axis; e_theta = n x e1.
    let e1 = [1.0, 0.0, 0.0];
    let et = [0.0, 0.8, -0.6];
    for i in 1..=30 {
        let r = 1.5 * r_core * i as f64 / 30.0;
        let exact = if r <= r_core {
            gamma * r / (2.0 * PI * r_core * r_core)
        } else {
            gamma / (2.0 * PI * r)
        };
        assert!(
            (v.tangential_speed_m_s(r) - exact).abs() <= 1e-12 * exact,
            "r = {r}"
        );
        // In the centre plane and off it inside the flat part of the axial window.
        for s in [0.0, 0.9 * r_core, -r_core] {
            let p: [f64; 3] = std::array::from_fn(|a| v.centre_m[a] + r * e1[a] + s * v.axis[a]);
            let u = v.velocity_m_s(p);
            for a in 0..3 {
                assert!(
                    (u[a] - exact * et[a]).abs() <= 1e-12 * exact + 1e-15,
                    "r {r} s {s}"
                );
            }
        }
    }
    // Continuity at the core's edge, zero beyond the cutoff and beyond the axial window.
    let k = gamma / (2.0 * PI * r_core);
    assert!((v.tangential_speed_m_s(r_core * (1.0 - 1e-9)) - k).abs() < 1e-6 * k);
    assert_eq!(v.tangential_speed_m_s(CUTOFF_CORES * r_core * 1.0001), 0.0);
    let far: [f64; 3] =
        std::array::from_fn(|a| v.centre_m[a] + r_core * e1[a] + 2.01 * r_core * v.axis[a]);
    assert_eq!(v.velocity_m_s(far), [0.0; 3]);
    // The potential's radial derivative is minus the tangential speed (checked by differences).
    for r in [0.5, 1.2, 1.8, 2.2].map(|x| x * r_core) {
        let d = 1e-7;
        let pot = |r: f64| v.potential_m2_s(std::array::from_fn(|a| v.centre_m[a] + r * e1[a]));
        let dpsi = (pot(r + d) - pot(r - d)) / (2.0 * d);
        let vt = v.tangential_speed_m_s(r);
        assert!((dpsi + vt).abs() < 1e-5 * k, "r {r}: {dpsi} vs {vt}");
    }
}

/// Largest |div u| h over the cells, and the largest |u|.
fn divergence(field: &VortexField, dims: [usize; 3]) -> (f64, f64) {
    let [nx, ny, nz] = dims;
    let u = [0, 1, 2].map(|c| field.face_velocities(c));
    let (mut dmax, mut umax) = (0.0f64, 0.0f64);
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let mut d = 0.0f64;
                for (c, uc) in u.iter().enumerate() {
                    let mut fd = dims;
                    fd[c] += 1;
                    let lo = i + fd[0] * (j + fd[1] * k);
                    let st = [1, fd[0], fd[0] * fd[1]][c];
                    d += uc[lo + st] as f64 - uc[lo] as f64;
                    umax = umax.max((uc[lo] as f64).abs());
                }
                dmax = dmax.max(d.abs());
            }
        }
    }
    (dmax, umax)
}

#[test]
fn vortex_field_on_the_grid_is_discretely_divergence_free_and_converges() {
    // Several overlapping vortices in a box with a solid block in it.
    let mut errors = Vec::new();
    for n in [24usize, 48] {
        let h = 0.024 / n as f64;
        let dims = [n, n, n];
        let mut s = solver(dims, h);
        let blk = 0.024 * 0.75;
        s.grid_mut().fill_box(
            [blk, blk, blk],
            [0.024, 0.024, 0.024],
            CellLabel::Solid,
            [0.0; 3],
        );
        let spec = VortexSpec {
            core_radius_mm: 2.0,
            min_core_voxels: 0.1,
            ..VortexSpec::default()
        };
        let mut f = VortexField::new(spec, &s).unwrap();
        let mk = |c: [f64; 3], a: [f64; 3], g: f64| {
            let m = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
            Vortex {
                centre_m: c,
                axis: a.map(|x| x / m),
                circulation_m2_s: g,
                core_radius_m: 2e-3,
            }
        };
        let vs = [
            mk([0.008, 0.009, 0.010], [0.3, -0.2, 1.0], 2e-3),
            mk([0.011, 0.010, 0.012], [1.0, 0.5, 0.1], -1.5e-3),
            mk([0.016, 0.016, 0.015], [0.0, 1.0, 1.0], 1e-3), // touches the block
        ];
        f.set_vortices(&vs);
        f.rebuild(&s);
        let (d, umax) = divergence(&f, dims);
        assert!(umax > 0.05, "the field is there: {umax}");
        assert!(d / umax < 1e-5, "n {n}: max |div u| h / U = {:e}", d / umax);
        // No flux into the block: faces of block cells are zero.
        let i0 = (blk / h).round() as usize;
        for c in 0..3 {
            let mut fd = dims;
            fd[c] += 1;
            for k in i0..n {
                for j in i0..n {
                    for i in i0..n {
                        assert_eq!(f.face_velocities(c)[i + fd[0] * (j + fd[1] * k)], 0.0);
                    }
                }
            }
        }
        // Against the closed form on faces well inside the fluid (more than 3 mm from the block
        // and the box's walls, where the potential is masked).
        let mut err = 0.0f64;
        let mut peak = 0.0f64;
        for c in 0..3 {
            let mut fd = dims;
            fd[c] += 1;
            for k in 0..fd[2] {
                for j in 0..fd[1] {
                    for i in 0..fd[0] {
                        let mut p = [
                            (i as f64 + 0.5) * h,
                            (j as f64 + 0.5) * h,
                            (k as f64 + 0.5) * h,
                        ];
                        p[c] -= 0.5 * h;
                        if p.iter().any(|&x| !(0.003..=0.0145).contains(&x)) {
                            continue;
                        }
                        let exact: f64 = vs.iter().map(|v| v.velocity_m_s(p)[c]).sum();
                        let got = f.face_velocities(c)[i + fd[0] * (j + fd[1] * k)] as f64;
                        err = err.max((got - exact).abs());
                        peak = peak.max(exact.abs());
                    }
                }
            }
        }
        errors.push(err / peak);
    }
    // Rankine's profile has a kink at the core's edge (and the tapers' ends), so the largest
    // face error converges at first order (0.20 at 4 cells per core radius, 0.10 at 8).
    let order = (errors[0] / errors[1]).log2();
    assert!(errors[1] < 0.12, "relative error at 48 cells: {errors:?}");
    assert!(order > 0.85, "observed order {order} from {errors:?}");
}

#[test]
fn a_relabelled_grid_gives_the_field_of_a_fresh_one() {
    // The field keeps lists of the fluid nodes and faces between relabellings: after the walls
    // move, it must equal the field built from scratch on the new labels.
    let n = 20;
    let h = 1e-3;
    let mut s = solver([n, n, n], h);
    s.grid_mut().fill_box(
        [0.012, 0.0, 0.0],
        [0.02, 0.02, 0.02],
        CellLabel::Solid,
        [0.0; 3],
    );
    let spec = VortexSpec {
        core_radius_mm: 2.0,
        ..VortexSpec::default()
    };
    let vs = [
        Vortex {
            centre_m: [0.008, 0.010, 0.009],
            axis: [0.0, 0.6, 0.8],
            circulation_m2_s: 2e-3,
            core_radius_m: 2e-3,
        },
        Vortex {
            centre_m: [0.011, 0.007, 0.012],
            axis: [1.0, 0.0, 0.0],
            circulation_m2_s: -1e-3,
            core_radius_m: 2e-3,
        },
    ];
    let mut kept = VortexField::new(spec.clone(), &s).unwrap();
    kept.set_vortices(&vs);
    kept.rebuild(&s);
    // The wall moves: part of the block becomes fluid, a new block appears.
    s.grid_mut().fill_box(
        [0.012, 0.0, 0.0],
        [0.015, 0.02, 0.02],
        CellLabel::Fluid,
        [0.0; 3],
    );
    s.grid_mut().fill_box(
        [0.0, 0.0, 0.0],
        [0.02, 0.004, 0.02],
        CellLabel::Solid,
        [0.0; 3],
    );
    let evaluated = kept.rebuild(&s);
    let mut fresh = VortexField::new(spec, &s).unwrap();
    fresh.set_vortices(&vs);
    assert_eq!(fresh.rebuild(&s), evaluated);
    let mut nonzero = 0;
    for c in 0..3 {
        assert_eq!(
            kept.face_velocities(c),
            fresh.face_velocities(c),
            "component {c}"
        );
        nonzero += fresh
            .face_velocities(c)
            .iter()
            .filter(|&&u| u != 0.0)
            .count();
    }
    assert!(nonzero > 100, "the field is there: {nonzero} faces");
    let (d, umax) = divergence(&kept, [n, n, n]);
    assert!(d / umax < 1e-5, "{d:e} / {umax:e}");
}

#[test]
fn injected_vortices_keep_the_solver_field_divergence_free() {
    let n = 20;
    let h = 1e-3;
    let mut s = solver([n, n, n], h);
    let spec = VortexSpec {
        core_radius_mm: 2.0,
        ..VortexSpec::default()
    };
    let mut f = VortexField::new(spec, &s).unwrap();
    f.set_vortices(&[Vortex {
        centre_m: [0.01, 0.01, 0.01],
        axis: [0.0, 0.0, 1.0],
        circulation_m2_s: 2e-3,
        core_radius_m: 2e-3,
    }]);
    f.rebuild(&s);
    f.inject(&mut s);
    assert!(s.max_speed_m_s() > 0.05);
    let d = s.max_divergence_rel();
    assert!(d < 1e-5, "divergence after the injection: {d:e}");
    // Injecting the same field again adds nothing.
    let before = s.face_velocities(0).to_vec();
    f.rebuild(&s);
    f.inject(&mut s);
    assert_eq!(before, s.face_velocities(0));
}

#[test]
fn vortex_count_follows_the_flow_rate_and_vortices_stay_in_the_fluid() {
    let spec = VortexSpec::default();
    assert_eq!(spec.target_count(50.0 / 6e7), 0);
    assert_eq!(spec.target_count(spec.threshold_ml_min / 6e7), 0);
    assert_eq!(spec.target_count(250.0 / 6e7), 50);
    assert_eq!(spec.target_count(2000.0 / 6e7), 100);
    // A jet through a box: the vortices move with it and respawn when they leave.
    let n = 16;
    let h = 1e-3;
    let mut s = solver([n, n, n], h);
    s.grid_mut().fill_box(
        [0.0, 0.006, 0.006],
        [0.001, 0.010, 0.010],
        CellLabel::Velocity,
        [0.3, 0.0, 0.0],
    );
    s.grid_mut().fill_box(
        [0.015, 0.0, 0.0],
        [0.016, 0.016, 0.016],
        CellLabel::Outflow,
        [0.0; 3],
    );
    let mut f = VortexField::new(spec, &s).unwrap();
    let mut respawned = 0;
    for step in 0..60 {
        s.step(1.0 / 60.0).unwrap();
        let target = if step < 40 { 30 } else { 10 };
        let st = f.step(&s, target, 1.0 / 60.0);
        respawned += st.respawned;
        assert_eq!(st.count, target);
        for v in f.vortices() {
            let c = v.centre_m.map(|x| (x / h) as usize);
            assert_eq!(s.grid().label(c), Some(CellLabel::Fluid), "{v:?}");
            let m = v.axis.iter().map(|x| x * x).sum::<f64>();
            assert!((m - 1.0).abs() < 1e-9);
        }
    }
    assert!(respawned > 0, "some vortices left with the jet");
}

fn rotation_error(steps: usize, omega: f64, t_end: f64) -> f64 {
    let n = 24;
    let h = 1e-3;
    let mut s = solver([n, n, n], h);
    let c = 0.012;
    // Solid-body rotation about z through (c, c): u = -omega (y - c), v = omega (x - c).
    s.set_velocity_field(|comp, p| match comp {
        0 => -omega * (p[1] - c),
        1 => omega * (p[0] - c),
        _ => 0.0,
    });
    let kinds = vec![VoxelKind::Fluid; n * n * n];
    let mut sys = ParticleSystem::new(s.grid(), 16, 1, [0.0, -1.0, 0.0]);
    let cls = tracer(&mut sys);
    let starts = [
        [c + 0.005, c, 0.01],
        [c, c - 0.004, 0.012],
        [c - 0.003, c + 0.003, 0.008],
    ];
    for p in starts {
        assert!(sys.emit(&kinds, cls, p));
    }
    let dt = t_end / steps as f64;
    for _ in 0..steps {
        sys.step(&s, &kinds, None, dt, None);
    }
    let th = omega * t_end;
    let mut err = 0.0f64;
    for (i, p0) in starts.iter().enumerate() {
        let (x, y) = (p0[0] - c, p0[1] - c);
        let exact = [
            c + x * th.cos() - y * th.sin(),
            c + x * th.sin() + y * th.cos(),
            p0[2],
        ];
        let got = sys.position_m(i);
        err = err.max(
            (0..3)
                .map(|a| (got[a] - exact[a]).powi(2))
                .sum::<f64>()
                .sqrt(),
        );
    }
    err
}

#[test]
fn advection_matches_exact_trajectories_uniform_and_solid_body_rotation() {
    // Uniform flow: exact up to round-off.
    let n = 16;
    let h = 1e-3;
    let mut s = solver([n, n, n], h);
    let u = [0.02, -0.01, 0.005];
    s.set_velocity_field(|c, _| u[c]);
    let kinds = vec![VoxelKind::Fluid; n * n * n];
    let mut sys = ParticleSystem::new(s.grid(), 4, 8, [0.0, -1.0, 0.0]);
    let cls = tracer(&mut sys);
    let p0 = [0.004, 0.010, 0.006];
    assert!(sys.emit(&kinds, cls, p0));
    for _ in 0..30 {
        sys.step(&s, &kinds, None, 0.01, None);
    }
    let p = sys.position_m(0);
    for a in 0..3 {
        assert!((p[a] - (p0[a] + u[a] * 0.3)).abs() < 1e-8, "{p:?}");
    }
    // Solid-body rotation: a quarter turn at two step sizes; the midpoint rule is second order.
    let omega = 2.0;
    let t_end = PI / 4.0;
    let e1 = rotation_error(16, omega, t_end);
    let e2 = rotation_error(32, omega, t_end);
    let e3 = rotation_error(64, omega, t_end);
    let o1 = (e1 / e2).log2();
    let o2 = (e2 / e3).log2();
    assert!(e1 < 2e-4, "error {e1}");
    assert!(
        (1.8..2.3).contains(&o1) && (1.8..2.3).contains(&o2),
        "orders {o1}, {o2} ({e1:e} {e2:e} {e3:e})"
    );
}

#[test]
fn no_particle_ends_inside_a_wall_after_1e5_random_steps() {
    // 200 particles (one thread) and 20000 (two halves on two threads).
    for count in [200usize, 20_000] {
        let n = 16;
        let h = 1e-3;
        let mut s = solver([n, n, n], h);
        let mut rng = fastrand::Rng::with_seed(42 + count as u64);
        let mut kinds = vec![VoxelKind::Fluid; n * n * n];
        let mut sys = ParticleSystem::new(s.grid(), count, 4, [0.0, -1.0, 0.0]);
        let cls = tracer(&mut sys);
        let mut steps = 0usize;
        let mut walled = 0;
        let mut rounds = 0;
        while steps < 100_000 || rounds < 4 {
            rounds += 1;
            // New walls (random cells, some under particles) and a new random field of up to
            // 3 cells per step.
            for k in kinds.iter_mut() {
                *k = if rng.f64() < 0.25 {
                    VoxelKind::Wall
                } else {
                    VoxelKind::Fluid
                };
            }
            for i in 0..sys.len() {
                let p = sys.position_m(i).map(|x| (x / h).floor() as usize);
                walled += (kinds[p[0] + n * (p[1] + n * p[2])] != VoxelKind::Fluid) as usize;
            }
            let amp = 0.18;
            let mut r2 = rng.fork();
            s.set_velocity_field(|_, _| amp * (2.0 * r2.f64() - 1.0));
            while sys.len() < count {
                let p = [0, 1, 2].map(|_| rng.f64() * n as f64 * h);
                sys.emit(&kinds, cls, p);
            }
            for _ in 0..5 {
                sys.step(&s, &kinds, None, 1.0 / 60.0, None);
                steps += sys.len();
                for i in 0..sys.len() {
                    let p = sys.position_m(i).map(|x| (x / h).floor() as usize);
                    assert_eq!(
                        kinds[p[0] + n * (p[1] + n * p[2])],
                        VoxelKind::Fluid,
                        "particle {i}"
                    );
                }
            }
        }
        assert!(walled > 100, "walls moved onto particles: {walled}");
    }
}

/// A channel along x: an inflow port (velocity cells) at x = 0, an outflow (open) at the far
/// end, walls around.
fn channel(n: [usize; 3], h: f64, u_in: f32) -> (FluidSolver, Vec<VoxelKind>) {
    let mut s = solver(n, h);
    let l = [n[0] as f64 * h, n[1] as f64 * h, n[2] as f64 * h];
    let g = s.grid_mut();
    g.fill_box(
        [0.0; 3],
        [h, l[1], l[2]],
        CellLabel::Velocity,
        [u_in, 0.0, 0.0],
    );
    g.fill_box([l[0] - h, 0.0, 0.0], l, CellLabel::Outflow, [0.0; 3]);
    let kinds = kinds_from_labels(s.grid());
    (s, kinds)
}

#[test]
fn blood_particles_are_conserved_except_through_the_outlets() {
    for open in [true, false] {
        let n = [24, 10, 10];
        let h = 1e-3;
        let (mut s, mut kinds) = channel(n, h, if open { 0.05 } else { 0.0 });
        if !open {
            for k in kinds.iter_mut() {
                if *k == VoxelKind::Open {
                    *k = VoxelKind::Wall;
                }
            }
            let l = [n[0] as f64 * h, n[1] as f64 * h, n[2] as f64 * h];
            s.grid_mut()
                .fill_box([l[0] - h, 0.0, 0.0], l, CellLabel::Solid, [0.0; 3]);
            // A swirl with no way out.
            s.set_velocity_field(|c, p| match c {
                0 => -(p[1] - 0.005),
                1 => p[0] - 0.012,
                _ => 0.0,
            });
        }
        let mut sys = ParticleSystem::new(s.grid(), 20_000, 8, [0.0, -1.0, 0.0]);
        let cls = tracer(&mut sys);
        let mut rng = fastrand::Rng::with_seed(3);
        for _ in 0..120 {
            if open {
                s.step(1.0 / 60.0).unwrap();
            }
            for _ in 0..40 {
                let p = [
                    0.004 + 0.002 * rng.f64(),
                    0.002 + 0.006 * rng.f64(),
                    0.002 + 0.006 * rng.f64(),
                ];
                sys.emit(&kinds, cls, p);
            }
            sys.step(&s, &kinds, None, 1.0 / 60.0, None);
        }
        let c = sys.counts();
        assert_eq!(c.lost[0], 0, "{c:?}");
        assert_eq!(
            c.emitted[0],
            (c.alive as u64) + c.outflow[0] + c.open[0],
            "{c:?}"
        );
        if open {
            assert!(c.open[0] > 1000, "most left through the open end: {c:?}");
        } else {
            assert_eq!(c.alive as u64, c.emitted[0]);
        }
    }
}

#[test]
fn a_bubble_rises_at_its_terminal_velocity() {
    let (rho_f, mu): (f64, f64) = (1000.0, 1e-3);
    // Stokes regime (Re ~ 0.004): the closed form.
    let d = 20e-6;
    let (w, _) = terminal_slip(d, 1.2, rho_f, mu);
    let stokes = (rho_f - 1.2) * GRAVITY_M_S2 * d * d / (18.0 * mu);
    assert!(w < 0.0, "bubbles rise");
    assert!(
        (w.abs() - stokes).abs() < 0.01 * stokes,
        "{w} vs Stokes {stokes}"
    );
    // A 1 mm bubble (Re ~ 100): the force balance with the Schiller-Naumann drag, solved here
    // independently by a secant iteration.
    let d: f64 = 1e-3;
    let weight = (rho_f - 1.2) * GRAVITY_M_S2 * PI / 6.0 * d.powi(3);
    let f = |w: f64| {
        let re = rho_f * w * d / mu;
        0.5 * rho_f * 24.0 / re * (1.0 + 0.15 * re.powf(0.687)) * PI / 4.0 * d * d * w * w - weight
    };
    let (mut a, mut b) = (0.05, 0.2);
    for _ in 0..50 {
        let c = b - f(b) * (b - a) / (f(b) - f(a));
        a = b;
        b = c;
        if (b - a).abs() < 1e-14 {
            break;
        }
    }
    let w_ref = b;
    assert!((0.08..0.15).contains(&w_ref), "{w_ref}");
    // Released at rest in still fluid, with gravity along -z (a head-down... any direction).
    let n = [8, 8, 160];
    let h = 1e-3;
    let s = solver(n, h);
    let kinds = vec![VoxelKind::Fluid; n[0] * n[1] * n[2]];
    let mut sys = ParticleSystem::new(s.grid(), 4, 8, [0.0, 0.0, -1.0]);
    let (settle, tau) = terminal_slip(d, 1.2, rho_f, mu);
    let cls = sys
        .add_class(ParticleClass {
            kind: ParticleKind::Bubble,
            settle_m_s: settle,
            tau_s: tau,
            shade_m2: PI / 4.0 * d * d,
            diameter_m: d,
        })
        .unwrap();
    assert!(sys.emit(&kinds, cls, [0.004, 0.004, 0.005]));
    let dt = 1.0 / 240.0;
    let mut z = vec![];
    for _ in 0..240 {
        sys.step(&s, &kinds, None, dt, None);
        z.push(sys.position_m(0)[2]);
    }
    // The transient: z(t) = w t - w tau (1 - e^(-t/tau)).
    let t = 10.0 * dt;
    let exact = 0.005 + w_ref * (t - tau * (1.0 - (-t / tau).exp()));
    assert!((z[9] - exact).abs() < 2e-3 * exact, "{} vs {exact}", z[9]);
    let rise = (z[239] - z[119]) / (120.0 * dt);
    assert!(
        (rise - w_ref).abs() < 1e-3 * w_ref,
        "rise {rise} vs terminal {w_ref}"
    );
}

/// Time for the view to clear after a one-second bleed near the inflow of a channel with the
/// given through-flow speed.
fn time_to_clear(u_in: f32) -> Option<f64> {
    let n = [30, 12, 12];
    let h = 1e-3;
    let (mut s, kinds) = channel(n, h, u_in);
    let mut sys = ParticleSystem::new(s.grid(), 20_000, 8, [0.0, -1.0, 0.0]);
    let cls = sys
        .add_class(ParticleClass {
            kind: ParticleKind::Blood,
            settle_m_s: 0.0,
            tau_s: 0.0,
            shade_m2: 20e3 * 1e-11, // 0.01 ul of blood at 20 /mm
            diameter_m: 0.0,
        })
        .unwrap();
    let view = ViewSpec::default().cone([0.002, 0.006, 0.006], [1.0, 0.0, 0.0]);
    let mut tracker = ClarityTracker::new(0.9);
    let mut rng = fastrand::Rng::with_seed(9);
    let dt = 1.0 / 60.0;
    for step in 0..600 {
        let t = step as f64 * dt;
        s.step(dt).unwrap();
        if t < 1.0 {
            for _ in 0..60 {
                let p = [
                    0.008 + 0.002 * rng.f64(),
                    0.004 + 0.004 * rng.f64(),
                    0.004 + 0.004 * rng.f64(),
                ];
                sys.emit(&kinds, cls, p);
            }
        }
        let c = sys.step(&s, &kinds, None, dt, Some(&view)).unwrap();
        tracker.update(t + dt, c, Some(1.0));
        if tracker.time_to_clear_s.is_some() {
            break;
        }
    }
    assert!(
        tracker.min_clarity.unwrap() < 0.5,
        "the bleed obscured the view"
    );
    tracker.time_to_clear_s
}

#[test]
fn clarity_recovers_faster_with_the_outflow_open_wider() {
    let speeds = [0.01f32, 0.02, 0.04];
    let times: Vec<f64> = speeds
        .iter()
        .map(|&u| time_to_clear(u).unwrap_or(f64::INFINITY))
        .collect();
    assert!(times[2].is_finite(), "{times:?}");
    for w in times.windows(2) {
        assert!(w[1] < w[0], "monotone: {times:?}");
    }
}

#[test]
fn time_to_traverse_of_a_plug_flow_is_the_length_over_the_speed() {
    let n = [30, 8, 8];
    let h = 1e-3;
    let mut s = solver(n, h);
    let g = s.grid_mut();
    g.fill_box(
        [0.0; 3],
        [h, 0.008, 0.008],
        CellLabel::Velocity,
        [0.1, 0.0, 0.0],
    );
    g.fill_box(
        [0.029, 0.0, 0.0],
        [0.030, 0.008, 0.008],
        CellLabel::Velocity,
        [0.1, 0.0, 0.0],
    );
    s.set_velocity_field(|c, _| if c == 0 { 0.1 } else { 0.0 });
    let mut kinds = kinds_from_labels(s.grid());
    for (n, k) in kinds.iter_mut().enumerate() {
        if *k == VoxelKind::Wall && n % 30 == 29 {
            *k = VoxelKind::Outflow;
        }
    }
    // From the first fluid cell's centre (x = 1.5 mm) to the outflow cells (x = 29 mm).
    let t = time_to_traverse(&s, &kinds, &[[0.0015, 0.004, 0.004]], 1e-3, 2.0);
    let exact = (0.029 - 0.0015) / 0.1;
    assert_eq!(t.reached, 1);
    assert!(
        (t.first_s.unwrap() - exact).abs() <= 1.5e-3,
        "{t:?} vs {exact}"
    );
    // A cloud over the whole cross-section (a regular 12 x 12 sub-grid, as the scene releases
    // over the port's faces): every tracer arrives, first and half within 1.5 steps of L / U.
    let cloud: Vec<[f64; 3]> = (0..144)
        .map(|m| {
            let (a, b) = ((m % 12) as f64, (m / 12) as f64);
            [0.0015, (a + 0.5) / 12.0 * 0.008, (b + 0.5) / 12.0 * 0.008]
        })
        .collect();
    let t = time_to_traverse(&s, &kinds, &cloud, 1e-3, 2.0);
    assert_eq!((t.released, t.reached, t.open), (144, 144, 0), "{t:?}");
    for x in [t.first_s, t.median_s] {
        assert!(
            x.is_some_and(|x| (x - exact).abs() <= 1.5e-3),
            "{t:?} vs {exact}"
        );
    }
}

#[test]
fn a_tracer_pressed_into_an_edge_slides_along_it_to_the_outflow() {
    // A one-cell channel along x (j = k = 1) in walls, the outflow cell at x = 0, and a field
    // pointing into the channel's -y and -z walls as well as along -x: the tracer is pushed
    // into the edge y = z = 1 and must slide along it (x is the one free axis there).
    let (n, h) = ([6, 3, 3], 1e-3);
    let mut s = solver(n, h);
    s.set_velocity_field(|_, _| -0.01);
    let mut kinds = vec![VoxelKind::Wall; n[0] * n[1] * n[2]];
    let at = |i: usize| i + n[0] * (1 + n[1]);
    for i in 1..n[0] {
        kinds[at(i)] = VoxelKind::Fluid;
    }
    kinds[at(0)] = VoxelKind::Outflow;
    let t = time_to_traverse(&s, &kinds, &[[4.5 * h, 1.5 * h, 1.5 * h]], 1e-3, 5.0);
    assert_eq!((t.released, t.reached), (1, 1), "{t:?}");
}

#[test]
fn particle_and_vortex_tables_parse_and_bad_values_name_the_key() {
    let toml = r#"
[stages]
vortices = true
particles = true
[vortices]
max_count = 50
mode = "injected"
[particles]
budget = 20000
[particles.gravity]
table_tilt_deg = 15.0
[[particles.blood.sources]]
position_mm = [5.0, 0.0, 40.0]
rate_ml_min = 1.0
[particles.bubbles]
per_ml = 2.0
"#;
    let desc = SceneDesc::parse(toml, "test.toml", None).unwrap();
    assert_eq!(desc.vortices.max_count, 50);
    assert_eq!(desc.particles.blood.sources.len(), 1);
    let g = desc.particles.gravity.unit().unwrap();
    assert!((g[2] - 15f64.to_radians().sin()).abs() < 1e-12 && g[1] < 0.0);
    for (bad, key) in [
        ("[particles]\nbudget = 0", "particles.budget"),
        (
            "[particles.blood]\nparticle_volume_ul = -1.0",
            "particles.blood.particle_volume_ul",
        ),
        (
            "[vortices]\nfull_flow_ml_min = 10.0",
            "vortices.full_flow_ml_min",
        ),
        (
            "[particles.view]\nhalf_angle_deg = 95.0",
            "particles.view.half_angle_deg",
        ),
        (
            "[[particles.blood.sources]]\nrate_ml_min = -2.0",
            "particles.blood.sources[0].rate_ml_min",
        ),
        ("[particles]\nbogus = 1", "bogus"),
    ] {
        let e = SceneDesc::parse(bad, "bad.toml", None)
            .unwrap_err()
            .to_string();
        assert!(e.contains(key), "{bad}: {e}");
    }
    assert!(ParticleSpec::default().validate().is_ok());
}
