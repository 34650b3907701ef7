//! Helpers shared by the scene tests: the coarse test scene (8k-tet default anatomy, 7 levels
//! to 150 mmHg, its atlas built once per test run and cached under `CARGO_TARGET_TMPDIR`), rig
//! inputs, a scope pose in the cavity and its periodic move, and the fluid's incompressibility.

// Each test binary that says `mod scene_common;` uses a part of it.
#![allow(dead_code)]

use hydrometra_sim::hydraulics::HydraulicInputs;
use hydrometra_sim::scene::{
    prepare, FluxBalance, HydraulicsInput, RigInputs, Scene, SceneAssets, SceneDesc, SceneInputs,
    ScopePose,
};
use hydrometra_sim::units::mmhg_to_pa;

/// The scene step of the tests, s (60 Hz).
pub const DT: f64 = 1.0 / 60.0;

/// The coarse test scene and its assets (built once, cached).
pub fn coarse(voxel_mm: f64) -> (SceneDesc, SceneAssets) {
    let text = format!(
        "name = \"coarse\"\n[anatomy]\nparity = \"parous\"\n[anatomy.mesh]\ntarget_tets = 8000\n\
         [atlas]\nlevels = 7\n[fluid]\nvoxel_mm = {voxel_mm}\n"
    );
    let desc = SceneDesc::parse(&text, "coarse test scene", None).unwrap();
    let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("scene-atlas-cache");
    let (assets, _) = prepare::load_or_build(&desc, Some(&dir), &mut |_, _, _, _| {}).unwrap();
    (desc, assets)
}

/// A scope pose inside the distended cavity of any anatomy: the tip at the centroid of the
/// surface at the atlas's top pressure, looking from the external os towards it.
pub fn scope_in_cavity(scene: &Scene) -> ScopePose {
    let atlas = scene.atlas();
    let mut s = scene.cavity_surface().clone();
    s.replay(atlas, atlas.pressure_pa[atlas.level_count() - 1])
        .unwrap();
    let p = s.positions_m();
    let n = p.len() - 1; // the last vertex is the opening's centroid
    let c: [f64; 3] =
        std::array::from_fn(|a| p[..n].iter().map(|q| q[a] as f64).sum::<f64>() / n as f64);
    let os = p[n].map(f64::from);
    ScopePose {
        tip_position_m: c,
        view_direction: [c[0] - os[0], c[1] - os[1], c[2] - os[2]],
        valid: true,
    }
}

pub fn inputs(valve_in: f64, valve_out: f64, pump_mmhg: f64, scope: ScopePose) -> RigInputs {
    RigInputs {
        hydraulic: HydraulicInputs {
            valve_in_opening: valve_in,
            valve_out_opening: valve_out,
            pump_set_pressure_pa: mmhg_to_pa(pump_mmhg),
            perforation: false,
        },
        scope,
    }
}

pub fn own(rig: RigInputs) -> SceneInputs<'static> {
    SceneInputs {
        rig,
        hydraulics: HydraulicsInput::Own,
    }
}

/// The fluid of the scene's last step is incompressible: what the ports and walls let in, less what
/// they let out, leaves through the open os, up to what the projection tolerance allows (each fluid
/// cell may keep tol * U * h^2 of flux imbalance) and the closed regions' reported mismatch.
/// Returns that slack.
pub fn assert_incompressible(scene: &Scene, f: usize) -> f64 {
    let (r, fl) = (scene.report(), scene.report().flux);
    let h = scene.cells().spacing_m;
    let u = scene.flow().unwrap().solver().max_speed_m_s().max(1e-3);
    let slack = r.fluid_cells as f64 * 1e-5 * u * h * h + fl.closed_region_mismatch_m3_per_s.abs();
    let in_minus_out =
        fl.fluid_inflow_m3_per_s - fl.fluid_outflow_m3_per_s - fl.fluid_wall_m3_per_s;
    assert!(
        (in_minus_out - fl.fluid_open_m3_per_s).abs() <= slack,
        "frame {f}: the fluid is not incompressible: in - out - walls {in_minus_out:e}, open {:e} \
         (slack {slack:e})",
        fl.fluid_open_m3_per_s
    );
    slack
}

/// `home` at frame `f` of a periodic move: a slide of +-2 mm along the view (period 120 frames,
/// 2 s) and a sway of +-1.5 mm across it (60 frames), so the same poses come back every 2 s.
pub fn slide_and_sway(home: ScopePose, f: usize) -> ScopePose {
    let d = home.view_direction;
    let m = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    // A unit vector across the view (the view is never along z here: it runs along the canal).
    let c = [d[1], -d[0], 0.0];
    let n = (c[0] * c[0] + c[1] * c[1]).sqrt();
    let tau = std::f64::consts::TAU;
    let slide = 2.0e-3 * (tau * (f % 120) as f64 / 120.0).sin();
    let sway = 1.5e-3 * (tau * (f % 60) as f64 / 60.0).sin();
    let mut s = home;
    for a in 0..3 {
        s.tip_position_m[a] += slide * d[a] / m + sway * c[a] / n;
    }
    s
}

/// The largest of a frame's hydraulic flows (inflow, outflow, losses, dV/dt), m^3/s: the scale the
/// fluxes' bounds are relative to.
pub fn largest_flow_m3_per_s(fl: &FluxBalance) -> f64 {
    [
        fl.hydraulic_inflow_m3_per_s,
        fl.hydraulic_outflow_m3_per_s,
        fl.hydraulic_losses_m3_per_s,
        fl.hydraulic_dvdt_m3_per_s,
    ]
    .iter()
    .fold(0.0f64, |m, q| m.max(q.abs()))
}

/// `in - out - walls - os` of the fluxes measured on the projected field, m^3/s: what the
/// projection removed from closed regions plus rounding.
pub fn flux_balance_m3_per_s(fl: &FluxBalance) -> f64 {
    fl.fluid_inflow_m3_per_s
        - fl.fluid_outflow_m3_per_s
        - fl.fluid_wall_m3_per_s
        - fl.fluid_open_m3_per_s
}
