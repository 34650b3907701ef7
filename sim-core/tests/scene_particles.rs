//! The vortex and particle stages inside a scene (coarse anatomy: 8000 tets, 6 atlas levels).

use hydrometra_sim::hydraulics::HydraulicInputs;
use hydrometra_sim::scene::{
    prepare, HydraulicsInput, RigInputs, Scene, SceneDesc, SceneInputs, ScopePose, Stage, VoxelKind,
};

#[test]
fn vortices_and_particles_run_in_the_scene_and_stay_in_the_fluid() {
    let toml = r#"
[anatomy]
parity = "parous"
[anatomy.mesh]
target_tets = 8000
smoothing_sweeps = 0
[atlas]
levels = 6
[stages]
vortices = true
particles = true
[vortices]
threshold_ml_min = 1.0
full_flow_ml_min = 50.0
[particles]
budget = 20000
[particles.bubbles]
per_ml = 20.0
[[particles.blood.sources]]
position_mm = [0.0, 0.0, 60.0]
rate_ml_min = 2.0
"#;
    let desc = SceneDesc::parse(toml, "scene_particles.toml", None).unwrap();
    let (assets, _) = prepare::load_or_build(&desc, None, &mut |_, _, _, _| {}).unwrap();
    let mut scene = Scene::new(desc, assets).unwrap();
    let mut rig = RigInputs {
        hydraulic: HydraulicInputs {
            valve_in_opening: 1.0,
            valve_out_opening: 1.0,
            pump_set_pressure_pa: 12_000.0,
            perforation: false,
        },
        ..RigInputs::default()
    };
    let dt = 1.0 / 60.0;
    for _ in 0..5 {
        scene
            .step(
                &SceneInputs {
                    rig,
                    hydraulics: HydraulicsInput::Own,
                },
                dt,
            )
            .unwrap();
    }
    // The scope in the middle of the fluid, looking towards the fundus.
    let flow = scene.flow().unwrap();
    let (dims, o, h) = (flow.dims(), flow.first_centre_m(), flow.spacing_m());
    let mut c = [0.0; 3];
    let mut count = 0.0;
    for (n, k) in flow.kinds().iter().enumerate() {
        if *k == VoxelKind::Fluid {
            let ijk = [
                n % dims[0],
                (n / dims[0]) % dims[1],
                n / (dims[0] * dims[1]),
            ];
            for a in 0..3 {
                c[a] += o[a] + ijk[a] as f64 * h;
            }
            count += 1.0;
        }
    }
    assert!(count > 100.0, "a cavity: {count} fluid cells");
    let c = c.map(|x| x / count);
    rig.scope = ScopePose {
        tip_position_m: c,
        view_direction: [0.0, 0.0, 1.0],
        valid: true,
    };
    for _ in 0..60 {
        scene
            .step(
                &SceneInputs {
                    rig,
                    hydraulics: HydraulicsInput::Own,
                },
                dt,
            )
            .unwrap();
        let flow = scene.flow().unwrap();
        let kinds = flow.kinds();
        let sys = scene.particles().unwrap().system().unwrap();
        for i in 0..sys.len() {
            let p = sys.position_m(i);
            let ijk: [usize; 3] =
                std::array::from_fn(|a| ((p[a] - o[a]) / h + 0.5).floor() as usize);
            assert_eq!(
                kinds[ijk[0] + dims[0] * (ijk[1] + dims[1] * ijk[2])],
                VoxelKind::Fluid
            );
        }
    }
    let report = scene.report();
    assert!(report.counters.get(Stage::Particles).runs > 0);
    assert!(report.counters.get(Stage::Vortices).runs > 0);
    let p = scene.particles().unwrap();
    let counts = p.system().unwrap().counts();
    assert!(
        counts.emitted[0] > 100 && counts.emitted[1] > 0,
        "{counts:?}"
    );
    let clarity = p.clarity().unwrap();
    assert!(clarity > 0.0 && clarity <= 1.0);
    let v = scene.vortices().unwrap().field().unwrap();
    assert!(!v.vortices().is_empty());
    assert!(p
        .vtp_string()
        .contains(&format!("NumberOfPoints=\"{}\"", counts.alive)));
    let t = scene.flow().unwrap().time_to_traverse(1e-3, 2.0);
    // A 4 x 4 sub-grid on each of the port's fluid faces.
    let per_face = hydrometra_sim::scene::particles::TRAVERSE_SUBGRID.pow(2);
    assert!(
        t.released > 0 && t.released.is_multiple_of(per_face),
        "{t:?}"
    );
}
