//! A long random run of the coupled scene with cut cells (the default) on the coarse test uterus:
//! the valves, the pump and the scope jump at random (the scope swaying in the cavity, out of it,
//! anywhere in the box and beyond it, in tissue, flagged invalid), a perforation now and then, and
//! steps from 1e-4 s to far above CFL 1 (up to the scene's 1 s clamp), with zero and non-finite
//! steps among them. Every frame: no error, everything finite, every projection converged, the
//! fluid's volume within 2 % of the cavity surface less the sheath wherever it has enough cells,
//! the fluxes balanced, the jet within the ports' rule, and no fluid cell faster than a small
//! multiple of the speeds the ports and the flows impose. Then everything closes and the flow decays.
//!
//! The slivers of a collapsing cavity (cells below the small-cell threshold with no neighbour to
//! merge into) are held to the same bound: before faces a thousandth open were closed
//! (`SmallCellParams::min_face_fraction`) they reached 71 m/s at the first seed.

use hydrometra_sim::cutcell::SmallCellParams;
use hydrometra_sim::scene::{Scene, ScopePose, VoxelKind, MIN_INFLOW_OPEN_FRACTION};

mod scene_common;
use scene_common::*;

/// Frames of the random run.
const FRAMES: usize = 2400;

/// The fastest fluid cell may reach, as a multiple of the scene's speed scale so far (the fastest
/// port, or the largest hydraulic flow through the channel's area): a jet speeds up where it
/// squeezes past tissue or the sheath, never without bound (the solver's own soak,
/// `fluid_stress.rs`, bounds it by 8 times the port's speed too).
const SPEED_RATIO: f64 = 8.0;

/// The runs' seeds (each its own sequence of inputs).
const SEEDS: [u64; 2] = [0x5eed_2818, 0x0dd_5eed];

#[test]
fn a_long_random_run_with_cut_cells_stays_finite_balanced_and_bounded() {
    for seed in SEEDS {
        soak(seed);
    }
}

fn soak(seed: u64) {
    println!("seed {seed:#x}");
    let (desc, assets) = coarse(1.2);
    assert!(desc.fluid.cut_cells, "cut cells are the default");
    let min_cells = desc.fluid.min_fluid_cells;
    let mut scene = Scene::new(desc, assets).unwrap();
    let home = scope_in_cavity(&scene);
    let (lo, hi) = box_bounds_m(&scene);
    let mut rng = fastrand::Rng::with_seed(seed);

    let (mut checked_volume, mut worst_volume) = (0, 0.0f64);
    let (mut fluid_steps, mut unconverged, mut worst_balance) = (0, 0, 0.0f64);
    // The fastest speed a port imposed so far (at least 1 cm/s: the walls move the fluid too).
    // The scene's speed scale so far: the fastest port, or the largest of the hydraulics' flows
    // (in, out, losses, dV/dt: the walls move the fluid too) through the inflow channel's area.
    let (mut peak_speed, mut worst_speed_ratio, mut worst_sliver) = (0.01f64, 0.0f64, 0.0f64);
    let small_cell = SmallCellParams::default().min_volume_fraction;
    let channel_m2 = scene.desc().scope.inflow_channel_area_mm2 * 1e-6;
    let mut segment_end = 0;
    let (mut rig, mut dt, mut mode) = (inputs(0.0, 0.0, 0.0, home), DT, 0);
    for f in 0..FRAMES {
        if f == segment_end {
            segment_end = f + 1 + rng.usize(..60);
            let mut opening = || match rng.u8(..4) {
                0 => 0.0,
                1 => 1.0,
                _ => rng.f64(),
            };
            let (valve_in, valve_out) = (opening(), opening());
            let pump_mmhg = match rng.u8(..5) {
                0 => 0.0,
                1 => 150.0,
                _ => 150.0 * rng.f64(),
            };
            mode = rng.u8(..10);
            rig = inputs(valve_in, valve_out, pump_mmhg, home);
            rig.hydraulic.perforation = rng.u8(..20) == 0;
            dt = match rng.u8(..20) {
                0..=11 => DT,
                12 | 13 => 1e-4,
                14 | 15 => 0.1,
                16 | 17 => 0.3 + 0.7 * rng.f64(),
                18 => 0.0,
                _ => f64::NAN,
            };
        }
        // The scope: swaying in the cavity, out of it, anywhere in (and 20 % beyond) the box
        // looking anywhere, or its last pose flagged invalid (a lost tracker).
        rig.scope = match mode {
            0..=4 => slide_and_sway(home, f),
            5 => ScopePose::default(),
            6 | 7 => {
                let mut s = home;
                for a in 0..3 {
                    let span = hi[a] - lo[a];
                    s.tip_position_m[a] = lo[a] - 0.2 * span + 1.4 * span * rng.f64();
                    s.view_direction[a] = rng.f64() - 0.5;
                }
                s
            }
            8 => ScopePose {
                valid: false,
                ..slide_and_sway(home, f)
            },
            _ => rig.scope,
        };
        let r = scene
            .step(&own(rig), dt)
            .unwrap_or_else(|e| panic!("frame {f}: {e} ({rig:?}, dt {dt})"));
        let fl = r.flux;
        for (what, x) in [
            ("cavity pressure", r.cavity_pressure_pa),
            ("surface volume", r.surface_volume_m3),
            ("grid fluid volume", r.grid_fluid_volume_m3),
            ("fluid inflow", fl.fluid_inflow_m3_per_s),
            ("fluid outflow", fl.fluid_outflow_m3_per_s),
            ("fluid walls", fl.fluid_wall_m3_per_s),
            ("fluid os", fl.fluid_open_m3_per_s),
            ("jet", fl.inflow_jet_speed_m_per_s),
        ] {
            assert!(x.is_finite(), "frame {f}: {what} {x}");
        }
        // The volume the renderer draws (the acceptance, in every frame).
        if let Some(reference) = r.cavity_less_sheath_volume_m3 {
            if r.fluid_cells >= min_cells {
                let err = (r.grid_fluid_volume_m3 - reference).abs() / reference;
                assert!(err < 0.02, "frame {f}: volume error {err:e}");
                worst_volume = worst_volume.max(err);
                checked_volume += 1;
            }
        }
        if let Some(stats) = r.fluid {
            fluid_steps += 1;
            assert!(stats.max_div_rel.is_finite(), "frame {f}: {stats:?}");
            unconverged += usize::from(!stats.projection_converged);
            // in - out - walls - os is what the projection removed from closed regions (reported)
            // plus single-precision rounding (scene_cut_walls.rs).
            let balance = flux_balance_m3_per_s(&fl);
            let scale = largest_flow_m3_per_s(&fl).max(1e-12);
            let rel = (balance.abs() - fl.closed_region_mismatch_m3_per_s).max(0.0) / scale;
            assert!(
                rel <= 1e-4,
                "frame {f}: balance {balance:e} of {scale:e}, {fl:?}"
            );
            worst_balance = worst_balance.max(rel);
        }
        // No NaN hides in the field (the solver's max speed counts NaN as 0); the jet obeys the
        // ports' rule; no speed grows beyond what the ports inject, in the cells holding at least
        // the small-cell threshold of fluid nor in the slivers below it (printed apart).
        let flow = scene.flow().unwrap();
        let mut v = vec![[0.0f32; 3]; flow.kinds().len()];
        flow.velocities_into(&mut v);
        assert!(
            v.iter().flatten().all(|x| x.is_finite()),
            "frame {f}: a non-finite velocity"
        );
        let speed = |v: &[f32; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt() as f64;
        let (mut port, mut resolved, mut sliver) = (0.0f64, 0.0f64, 0.0f64);
        for (n, (k, v)) in flow.kinds().iter().zip(&v).enumerate() {
            match k {
                VoxelKind::Inflow | VoxelKind::Outflow => port = port.max(speed(v)),
                VoxelKind::Fluid if flow.fluid_fraction(n) >= small_cell => {
                    resolved = resolved.max(speed(v))
                }
                VoxelKind::Fluid => sliver = sliver.max(speed(v)),
                _ => {}
            }
        }
        let jet_limit = fl.hydraulic_inflow_m3_per_s / (MIN_INFLOW_OPEN_FRACTION * channel_m2);
        assert!(
            fl.inflow_jet_speed_m_per_s <= jet_limit * (1.0 + 1e-9),
            "frame {f}: jet {} m/s, open fraction {}",
            fl.inflow_jet_speed_m_per_s,
            fl.inflow_open_fraction
        );
        let largest_flow = largest_flow_m3_per_s(&fl);
        peak_speed = peak_speed.max(port).max(largest_flow / channel_m2);
        let ratio = resolved.max(sliver) / peak_speed;
        assert!(
            ratio < SPEED_RATIO,
            "frame {f}: {resolved} m/s in a resolved cell, {sliver} m/s in a sliver, the speed \
             scale so far {peak_speed} m/s"
        );
        worst_speed_ratio = worst_speed_ratio.max(ratio);
        worst_sliver = worst_sliver.max(sliver);
    }
    println!(
        "{FRAMES} frames, {fluid_steps} fluid steps ({unconverged} unconverged): worst volume \
         error {:.3} % over {checked_volume} frames, worst |balance| beyond the removed mismatch \
         {worst_balance:.2e} of the flow, fastest fluid cell {worst_speed_ratio:.2} x the \
         speed scale so far (at most {peak_speed:.3} m/s); fastest sliver {worst_sliver:.1} m/s",
        100.0 * worst_volume
    );
    assert!(
        checked_volume > FRAMES / 4,
        "{checked_volume} frames checked"
    );
    assert_eq!(
        unconverged, 0,
        "{unconverged} of {fluid_steps} projections unconverged"
    );

    // Everything closes: the cavity holds, the flow decays.
    let speed = |scene: &Scene| scene.flow().unwrap().solver().max_speed_m_s();
    let rest = inputs(0.0, 0.0, 0.0, home);
    scene.step(&own(rest), DT).unwrap();
    let start = speed(&scene);
    let mut last = start;
    for f in 0..600 {
        scene.step(&own(rest), DT).unwrap();
        last = speed(&scene);
        assert!(
            last.is_finite() && last <= start.max(1e-3),
            "closed frame {f}: {last} m/s"
        );
    }
    println!("closed: fastest face {start:.4} -> {last:.6} m/s over 10 s");
    assert!(last <= 0.1 * start.max(1e-3), "{start} -> {last}");
}

/// The fluid box's bounds, m.
fn box_bounds_m(scene: &Scene) -> ([f64; 3], [f64; 3]) {
    let cells = scene.cells();
    let lo = cells.origin_m;
    let hi = std::array::from_fn(|a| lo[a] + cells.dims[a] as f64 * cells.spacing_m);
    (lo, hi)
}
