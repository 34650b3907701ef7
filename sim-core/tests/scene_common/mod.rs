//! The coarse test scene and its inputs, shared by the scene's integration tests (each file that
//! needs them says `mod scene_common;`).

use hydrometra_sim::hydraulics::HydraulicInputs;
use hydrometra_sim::scene::{
    prepare, HydraulicsInput, RigInputs, Scene, SceneAssets, SceneDesc, SceneInputs, ScopePose,
};
use hydrometra_sim::units::mmhg_to_pa;

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
