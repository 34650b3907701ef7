//! What `scene run`, `scene bench` and `scene converge` share: the scene argument, its atlas
//! (cached), the scenario's hydraulics and the scene's inputs at an instant of the scenario.

use std::io::Write as _;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Args;
use hydrometra_sim::hydraulics::{CaseScript, HydraulicInputs};
use hydrometra_sim::scene::{
    prepare, HydraulicsInput, RigInputs, SceneAssets, SceneDesc, SceneInputs, ScopePose,
};
use hydrometra_sim::units::{m3_to_ml, mmhg_to_pa, pa_to_mmhg};

/// Where the scene comes from and where its atlas is cached.
#[derive(Args, Debug, Clone)]
pub struct SceneArg {
    /// A built-in scene (`default`, `myoma-figo1`, `bleed`) or a scene file.
    #[arg(long, default_value = "default")]
    pub scene: String,
    /// Atlas cache directory (default: $XDG_CACHE_HOME/hydrometra or ~/.cache/hydrometra).
    #[arg(long)]
    pub cache_dir: Option<PathBuf>,
}

/// The default atlas cache directory.
pub fn default_cache_dir() -> PathBuf {
    if let Some(d) = std::env::var_os("XDG_CACHE_HOME").filter(|d| !d.is_empty()) {
        return PathBuf::from(d).join("hydrometra");
    }
    match std::env::var_os("HOME").filter(|d| !d.is_empty()) {
        Some(h) => PathBuf::from(h).join(".cache").join("hydrometra"),
        None => std::env::temp_dir().join("hydrometra-cache"),
    }
}

pub(crate) fn assets(
    desc: &SceneDesc,
    arg: &SceneArg,
) -> Result<(SceneAssets, prepare::AtlasSource)> {
    let dir = arg.cache_dir.clone().unwrap_or_else(default_cache_dir);
    let t0 = Instant::now();
    let mut progress = |done: usize, total: usize, p: f64, v: f64| {
        eprint!(
            "\ratlas: {done}/{total} levels, {:.1} mmHg, cavity {:.3} ml, {:.0} s   ",
            pa_to_mmhg(p),
            m3_to_ml(v),
            t0.elapsed().as_secs_f64()
        );
        let _ = std::io::stderr().flush();
        if done == total {
            eprintln!();
        }
    };
    let (a, s) = prepare::load_or_build(desc, Some(&dir), &mut progress)
        .with_context(|| format!("preparing scene {}", desc.name))?;
    Ok((a, s))
}

/// The scenario's hydraulics, when its case has a `[hydraulics]` table, with the scope's port
/// areas (one source: the scene's scope).
pub(crate) fn apply_scenario_hydraulics(desc: &mut SceneDesc, case: &CaseScript) {
    if let Some(mut p) = case.params.clone() {
        p.inflow.port_area_mm2 = desc.hydraulics.inflow.port_area_mm2;
        p.outflow.port_area_mm2 = desc.hydraulics.outflow.port_area_mm2;
        desc.hydraulics = p;
    }
}

/// The scene's inputs at time `t_s` of a scenario, the scene owning the hydraulics: the rig's
/// sample (clinical units and mm at the edge, SI inside) and the case's perforation.
pub(crate) fn scene_inputs_at(
    scenario: &hydrometra_drivers::emulator::scenario::Scenario,
    case: &CaseScript,
    t_s: f64,
) -> SceneInputs<'static> {
    let s = scenario.sample_at(t_s);
    let perforation = case.perforated_at(t_s);
    let rig = RigInputs {
        hydraulic: HydraulicInputs {
            valve_in_opening: s.valve_in,
            valve_out_opening: s.valve_out,
            pump_set_pressure_pa: mmhg_to_pa(s.pump_mmhg),
            perforation,
        },
        scope: ScopePose {
            tip_position_m: s.tip_mm.map(|v| v * 1e-3),
            view_direction: s.view_dir,
            valid: s.pose_valid,
        },
    };
    SceneInputs {
        rig,
        hydraulics: HydraulicsInput::Own,
    }
}
