//! `hydrometra scene converge`: one scene and scenario at several voxel sizes and a fine
//! reference; the run time per frame, the fluid volume against the surface's, and the error
//! against the reference of what a trainee sees, with the observed order (docs/scene.md,
//! "Accuracy table"). Every run is cached in the output directory, keyed by its settings.

mod args;
mod table;

pub use args::{ConvergeArgs, OnOff, RunKey, RunRecord};

use std::path::Path;
use std::time::{Instant, SystemTime, UNIX_EPOCH};

use anyhow::{bail, Context, Result};
use hydrometra_sim::harness::converge::{
    band_start_z_m, in_fluid, jet_search_radius_m, mean_speed_above_m_s, peak_speed_on_disk_m_s,
    probe_points_m, speed_at_m_s, FUNDAL_FROM, JET_PROBE_MM, JET_SEARCH_SPACING_M,
};
use hydrometra_sim::scene::{Scene, SceneDesc};

use crate::scenario::load_scenario;
use crate::scene_setup::{apply_scenario_hydraulics, assets, scene_inputs_at};

/// Runs `scene converge`.
pub fn run(a: &ConvergeArgs) -> Result<()> {
    let base = check_and_prepare(a)?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let (assets, _) = assets(&base, &a.scene)?;
    let mut sizes: Vec<f64> = vec![a.reference_mm];
    sizes.extend(&a.sizes_mm);
    let mut records = Vec::with_capacity(sizes.len());
    for (n, &mm) in sizes.iter().enumerate() {
        let key = run_key(a, &base, mm);
        let path = a.out.join(format!("run-{mm:.3}mm.json"));
        let reuse = n == 0 || !a.rerun;
        if let Some(r) = reuse.then(|| cached(&path, &key)).flatten() {
            tracing::info!("{mm} mm: from {}", path.display());
            records.push(r);
            continue;
        }
        let mut desc = base.clone();
        desc.fluid.voxel_mm = mm;
        desc.validate()?;
        let scene = Scene::new(desc, assets.clone())?;
        let record = run_one(a, scene, key).with_context(|| format!("the {mm} mm run"))?;
        std::fs::write(&path, serde_json::to_string(&record)?)
            .with_context(|| format!("writing {}", path.display()))?;
        records.push(record);
    }
    let (reference, runs) = records
        .split_first()
        .context("no reference run (internal)")?;
    let t = table::Table::compare(a, reference, runs);
    let md = t.markdown();
    print!("{md}");
    std::fs::write(a.out.join("table.md"), &md).context("writing table.md")?;
    std::fs::write(a.out.join("table.json"), serde_json::to_string_pretty(&t)?)
        .context("writing table.json")?;
    Ok(())
}

/// Checks the arguments (each error names its option) and gives the scene with the options
/// applied (cut cells, the bleed's window); the voxel size is set per run.
fn check_and_prepare(a: &ConvergeArgs) -> Result<SceneDesc> {
    if !(a.seconds.is_finite() && a.seconds > 0.0 && a.seconds <= 24.0 * 3600.0) {
        bail!("--seconds {}: expected a duration in (0, 86400]", a.seconds);
    }
    if !(a.rate_hz.is_finite() && (1.0..=1000.0).contains(&a.rate_hz)) {
        bail!("--rate-hz {}: expected 1 to 1000", a.rate_hz);
    }
    if !(a.window_s.is_finite() && a.window_s > 0.0 && a.window_s <= a.seconds) {
        bail!(
            "--window-s {}: expected a duration in (0, --seconds]",
            a.window_s
        );
    }
    if a.sizes_mm.is_empty() {
        bail!("--sizes-mm: expected at least one voxel size");
    }
    for &mm in &a.sizes_mm {
        if !(mm.is_finite() && mm > a.reference_mm) {
            bail!(
                "--sizes-mm {mm}: expected a size coarser than the reference (--reference-mm {})",
                a.reference_mm
            );
        }
    }
    if a.sizes_mm.windows(2).any(|w| w[1] >= w[0]) {
        bail!(
            "--sizes-mm {:?}: expected coarse to fine, each once",
            a.sizes_mm
        );
    }
    if !(a.reference_mm.is_finite() && a.reference_mm > 0.0) {
        bail!("--reference-mm {}: expected a size > 0", a.reference_mm);
    }
    let mut desc = SceneDesc::load(&a.scene.scene)?;
    desc.fluid.cut_cells = a.cut_cells == OnOff::On;
    let (_, case) = load_scenario(&a.scenario)?;
    apply_scenario_hydraulics(&mut desc, &case);
    if !desc.stages.fluid {
        bail!(
            "--scene {}: the scene has no fluid stage (`[stages] fluid = false`): nothing to converge",
            a.scene.scene
        );
    }
    if a.bleed_onset_s.is_some() || a.bleed_stop_s.is_some() {
        let sources = &mut desc.particles.blood.sources;
        if !desc.stages.particles || sources.is_empty() {
            bail!(
                "--bleed-onset-s/--bleed-stop-s: scene {} has no blood source (or no particle stage)",
                a.scene.scene
            );
        }
        for s in sources.iter_mut() {
            if let Some(t) = a.bleed_onset_s {
                if !(t.is_finite() && t >= 0.0) {
                    bail!("--bleed-onset-s {t}: expected a time >= 0");
                }
                s.onset_s = t;
            }
            if let Some(stop) = a.bleed_stop_s {
                if !(stop.is_finite() && stop > s.onset_s && stop < a.seconds) {
                    bail!(
                        "--bleed-stop-s {stop}: expected a time after the bleed's onset ({} s) and \
                         before the run's end (--seconds {})",
                        s.onset_s,
                        a.seconds
                    );
                }
                s.duration_s = stop - s.onset_s;
            }
        }
    }
    desc.validate()?;
    Ok(desc)
}

fn run_key(a: &ConvergeArgs, desc: &SceneDesc, voxel_mm: f64) -> RunKey {
    RunKey {
        version: env!("CARGO_PKG_VERSION").to_string(),
        scene: desc.name.clone(),
        scene_origin: desc.origin.clone(),
        scenario: a.scenario.clone(),
        seconds: a.seconds,
        rate_hz: a.rate_hz,
        window_s: a.window_s,
        voxel_mm,
        cut_cells: desc.fluid.cut_cells,
        bleed_onset_s: a.bleed_onset_s,
        bleed_stop_s: a.bleed_stop_s,
    }
}

/// The cached record at `path` if it holds a run of `key` (an unreadable file is run again).
fn cached(path: &Path, key: &RunKey) -> Option<RunRecord> {
    let text = std::fs::read_to_string(path).ok()?;
    match serde_json::from_str::<RunRecord>(&text) {
        Ok(r) if r.key == *key => Some(r),
        Ok(_) => {
            tracing::info!("{}: other settings, run again", path.display());
            None
        }
        Err(e) => {
            tracing::warn!("{}: {e}; run again", path.display());
            None
        }
    }
}

/// Runs `scene` through the scenario and samples it.
fn run_one(a: &ConvergeArgs, mut scene: Scene, key: RunKey) -> Result<RunRecord> {
    let (scenario, case) = load_scenario(&a.scenario)?;
    let mm = key.voxel_mm;
    let dt = 1.0 / a.rate_hz;
    let frames = (a.seconds * a.rate_hz).round() as usize;
    let window_frames = ((a.window_s * a.rate_hz).round() as usize).clamp(1, frames);
    let probe_m = JET_PROBE_MM.map(|d| d * 1e-3);
    let channel_area_m2 = scene.desc().scope.inflow_channel_area_mm2 * 1e-6;
    let mut r = RunRecord {
        key,
        profile: if cfg!(debug_assertions) {
            "dev"
        } else {
            "release"
        }
        .to_string(),
        rayon_threads: rayon::current_num_threads(),
        finished_unix_s: 0,
        grid_dims: scene.cells().dims,
        frames,
        step_ms_mean: 0.0,
        wall_s: 0.0,
        time_s: Vec::with_capacity(frames),
        grid_fluid_ml: Vec::with_capacity(frames),
        surface_ml: Vec::with_capacity(frames),
        fluid_cells: Vec::with_capacity(frames),
        min_fluid_cells: scene.desc().fluid.min_fluid_cells,
        window_time_s: Vec::with_capacity(window_frames),
        jet_m_s: vec![Vec::with_capacity(window_frames); probe_m.len()],
        jet_on_line_m_s: vec![Vec::with_capacity(window_frames); probe_m.len()],
        jet_in_fluid: vec![Vec::with_capacity(window_frames); probe_m.len()],
        fundal_m_s: Vec::with_capacity(window_frames),
        clarity: Vec::with_capacity(frames),
        time_to_clear_s: None,
        min_clarity: None,
        clear_threshold: scene
            .desc()
            .stages
            .particles
            .then_some(scene.desc().particles.view.clear_threshold),
    };
    tracing::info!("{mm} mm: grid {:?}, {frames} frames", r.grid_dims);
    let started = Instant::now();
    let mut step_ms_sum = 0.0;
    for f in 0..frames {
        let t = (f + 1) as f64 * dt;
        let inputs = scene_inputs_at(&scenario, &case, t);
        let report = scene.step(&inputs, dt)?;
        step_ms_sum += report.counters.step.last_ms;
        r.time_s.push(report.time_s);
        r.grid_fluid_ml.push(report.grid_fluid_volume_m3 * 1e6);
        r.surface_ml.push(report.surface_volume_m3 * 1e6);
        r.fluid_cells.push(report.fluid_cells);
        r.clarity.push(scene.particles().and_then(|p| p.clarity()));
        if f + window_frames >= frames {
            let flow = scene.flow().context("the scene has no fluid stage")?;
            let solver = flow.solver();
            r.window_time_s.push(t);
            let pose = inputs.rig.scope;
            let probes = pose
                .valid
                .then(|| probe_points_m(pose.tip_position_m, pose.view_direction, &probe_m))
                .flatten();
            for (i, &d_m) in probe_m.iter().enumerate() {
                let p = probes.as_ref().map(|p| p[i]);
                let radius_m = jet_search_radius_m(channel_area_m2, d_m);
                r.jet_m_s[i].push(p.and_then(|p| {
                    peak_speed_on_disk_m_s(
                        solver,
                        p,
                        pose.view_direction,
                        radius_m,
                        JET_SEARCH_SPACING_M,
                    )
                }));
                r.jet_on_line_m_s[i].push(p.map(|p| speed_at_m_s(solver, p)));
                r.jet_in_fluid[i].push(p.is_some_and(|p| in_fluid(solver, p)));
            }
            let z0 = band_start_z_m(scene.cavity_surface().positions_m(), FUNDAL_FROM);
            r.fundal_m_s
                .push(z0.and_then(|z| mean_speed_above_m_s(solver, z)));
        }
        if (f + 1) % (a.rate_hz.round() as usize).max(1) == 0 {
            tracing::info!(
                "{mm} mm: {t:.1} / {} s, {:.0} s wall",
                a.seconds,
                started.elapsed().as_secs_f64()
            );
        }
    }
    r.wall_s = started.elapsed().as_secs_f64();
    r.step_ms_mean = step_ms_sum / frames.max(1) as f64;
    if let Some(p) = scene.particles() {
        r.time_to_clear_s = p.tracker().time_to_clear_s;
        r.min_clarity = p.tracker().min_clarity;
    }
    r.finished_unix_s = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    Ok(r)
}
