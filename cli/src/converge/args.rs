//! The arguments of `scene converge` and the records of its runs (cached in the output dir).

use std::path::PathBuf;

use clap::{Args, ValueEnum};
use serde::{Deserialize, Serialize};

use crate::scene_setup::SceneArg;

/// `scene converge`
#[derive(Args, Debug)]
pub struct ConvergeArgs {
    #[command(flatten)]
    pub scene: SceneArg,
    /// A built-in rig scenario (`default`, `flaky`) or a scenario file.
    #[arg(long, default_value = "default")]
    pub scenario: String,
    /// Simulated seconds of every run (from the scenario's start).
    #[arg(long, default_value_t = 10.0)]
    pub seconds: f64,
    /// Scene steps per second.
    #[arg(long, default_value_t = 60.0)]
    pub rate_hz: f64,
    /// The jet and fundal speeds are averaged over every frame of the run's last this many
    /// seconds (the same instants at every size).
    #[arg(long, default_value_t = 2.0)]
    pub window_s: f64,
    /// Voxel sizes, mm (coarse to fine).
    #[arg(long, value_delimiter = ',', default_values_t = [1.8, 1.2, 0.9, 0.6])]
    pub sizes_mm: Vec<f64>,
    /// Voxel size of the reference, mm (finer than every size).
    #[arg(long, default_value_t = 0.3)]
    pub reference_mm: f64,
    /// Cut cells (`[fluid] cut_cells`) on or off in every run, whatever the scene file says.
    #[arg(long, value_enum, default_value_t = OnOff::On)]
    pub cut_cells: OnOff,
    /// Every blood source starts bleeding at this scene time, s (default: the scene's onsets).
    #[arg(long)]
    pub bleed_onset_s: Option<f64>,
    /// Every blood source stops bleeding at this scene time, s: the time to clear counts from
    /// here (default: the scene's durations; an endless bleed has no time to clear).
    #[arg(long)]
    pub bleed_stop_s: Option<f64>,
    /// Run the sizes again even where the output directory holds a run with the same settings
    /// (the reference is taken from the cache whenever it matches).
    #[arg(long)]
    pub rerun: bool,
    /// Output directory: a run's record per size (`run-<mm>mm.json`), `table.md`, `table.json`.
    #[arg(long)]
    pub out: PathBuf,
}

/// On or off.
#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OnOff {
    /// On.
    On,
    /// Off.
    Off,
}

/// What makes two runs the same run: a cached record is reused only when its key equals.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunKey {
    /// The crate version that ran it (the cache does not know the code; clear the directory
    /// after a change to the solver).
    pub version: String,
    pub scene: String,
    pub scene_origin: String,
    pub scenario: String,
    pub seconds: f64,
    pub rate_hz: f64,
    pub window_s: f64,
    pub voxel_mm: f64,
    pub cut_cells: bool,
    pub bleed_onset_s: Option<f64>,
    pub bleed_stop_s: Option<f64>,
}

/// One run's record: its cost and the samples the table compares.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RunRecord {
    pub key: RunKey,
    /// Build profile (`dev`: opt-level 2 with debug assertions; `release`).
    pub profile: String,
    pub rayon_threads: usize,
    /// When the run finished, s since the Unix epoch.
    pub finished_unix_s: u64,
    pub grid_dims: [usize; 3],
    pub frames: usize,
    /// Mean wall time of `Scene::step`, ms.
    pub step_ms_mean: f64,
    /// Wall time of the whole run, s.
    pub wall_s: f64,
    /// Per frame: the scene time (s), the grid's fluid volume and the surface's (ml), and the
    /// fluid cells (None without a fluid stage).
    pub time_s: Vec<f64>,
    pub grid_fluid_ml: Vec<f64>,
    pub surface_ml: Vec<f64>,
    pub fluid_cells: Vec<usize>,
    /// The scene's `min_fluid_cells`: frames with fewer are not compared.
    pub min_fluid_cells: usize,
    /// Per frame of the window: its time (s); at each jet probe's distance the jet's speed (the
    /// peak `|u|` on the search disk, m/s, None without a scope pose) and the speed at the point
    /// on the view line; whether that point lay in a fluid cell; the fundal third's mean speed.
    pub window_time_s: Vec<f64>,
    pub jet_m_s: Vec<Vec<Option<f64>>>,
    pub jet_on_line_m_s: Vec<Vec<Option<f64>>>,
    pub jet_in_fluid: Vec<Vec<bool>>,
    pub fundal_m_s: Vec<Option<f64>>,
    /// The view's clarity every frame (None without particles or a scope pose).
    pub clarity: Vec<Option<f64>>,
    /// The scene's clarity tracker at the end: the time from the bleed's stop to a clear view,
    /// and the lowest clarity.
    pub time_to_clear_s: Option<f64>,
    pub min_clarity: Option<f64>,
    pub clear_threshold: Option<f64>,
}
