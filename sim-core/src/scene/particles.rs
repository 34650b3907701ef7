//! Blood, bubble and fragment particles advected by the flow (`docs/particles.md`).
//!
//! Particles live in fixed-capacity arrays (the budget, allocated once); positions are kept in
//! grid units (cell `(i, j, k)` spans `[i, i+1) x [j, j+1) x [k, k+1)`). Each step builds the
//! cell-centred velocity `v = v_f (+ the vortex overlay)` once, then moves every particle with
//! the explicit midpoint rule (RK2) in as many substeps as keep it under one cell per substep
//! (`max_substeps` at most), plus its slip: the velocity relative to the fluid relaxes
//! exponentially (time `tau`) to the terminal settling or rise velocity along gravity, integrated
//! exactly over the step. A substep that ends in a non-fluid cell slides (one axis reverted) or
//! stays; a particle entering an outflow-hole cell or the open os leaves the cavity.

use std::fmt::Write as _;
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::clarity::{ClarityTracker, View, ViewSpec};
use super::dispersion;
use super::random::SeededRng;
use super::vortex_potential::cross;
use super::{Scene, VoxelKind};
use crate::fluid::{CellLabel, FluidGrid, FluidSolver};
use crate::simd::{v4, v4 as lane, V4};

#[cfg(target_arch = "x86_64")]
mod block8;

/// Gravity's magnitude, m/s^2.
pub const GRAVITY_M_S2: f64 = 9.81;
/// Bubble size classes (diameters spread evenly over the configured range).
const BUBBLE_CLASSES: usize = 8;
/// The eddy dispersion's default seed; a scene's walk uses `particles.seed ^ WALK_STREAM` (a
/// stream apart from the emission's).
const WALK_STREAM: u64 = 0x5eed_d15c;

/// What a particle is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[repr(u8)]
pub enum ParticleKind {
    /// A puff of blood (a tracer with Beer-Lambert attenuation).
    Blood = 0,
    /// An air bubble (buoyant, opaque).
    Bubble = 1,
    /// A tissue fragment (denser than the fluid, opaque).
    Fragment = 2,
}

/// Gravity in the organ frame (origin at the external os, +z towards the fundus, +x the
/// patient's left, +y anterior).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GravitySpec {
    /// Head-down tilt of the table (Trendelenburg), degrees; negative: head up.
    pub table_tilt_deg: f64,
    /// Roll of the table towards the patient's left, degrees.
    pub lateral_tilt_deg: f64,
    /// An explicit direction in the organ frame (need not be unit); overrides the tilts.
    pub direction: Option<[f64; 3]>,
}

impl Default for GravitySpec {
    fn default() -> Self {
        Self {
            table_tilt_deg: 0.0,
            lateral_tilt_deg: 0.0,
            direction: None,
        }
    }
}

impl GravitySpec {
    /// Unit gravity direction. Supine lithotomy: anterior is up, so gravity is -y; a head-down
    /// tilt turns it towards the fundus (+z, cranial), a left roll towards +x.
    pub fn unit(&self) -> Result<[f64; 3], String> {
        let g = match self.direction {
            Some(d) => d,
            None => {
                let (t, l) = (
                    self.table_tilt_deg.to_radians(),
                    self.lateral_tilt_deg.to_radians(),
                );
                [l.sin() * t.cos(), -l.cos() * t.cos(), t.sin()]
            }
        };
        let m = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
        if !(m.is_finite() && m > 0.0) {
            return Err(format!(
                "`particles.gravity.direction` = {g:?}: expected a finite non-zero vector"
            ));
        }
        Ok(g.map(|x| x / m))
    }
}

/// A bleeding source on the endometrium.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BleedingSourceSpec {
    /// Position in the organ frame, mm (snapped to the nearest cavity-surface vertex).
    pub position_mm: [f64; 3],
    /// Blood flow at onset, ml/min.
    pub rate_ml_min: f64,
    /// Onset, s of scene time.
    pub onset_s: f64,
    /// Duration, s (infinite: bleeds on).
    pub duration_s: f64,
    /// Focal-to-diffuse time constant, s: the jet shortens and the area widens with it.
    pub ageing_s: f64,
    /// Rate decay time constant, s (0: constant rate).
    pub decay_s: f64,
    /// Radius of the bleeding area at onset, mm.
    pub focal_radius_mm: f64,
    /// Radius of the bleeding area once diffuse, mm.
    pub diffuse_radius_mm: f64,
    /// Length of the focal jet into the cavity at onset, mm.
    pub jet_length_mm: f64,
}

impl Default for BleedingSourceSpec {
    fn default() -> Self {
        Self {
            position_mm: [0.0, 0.0, 30.0],
            rate_ml_min: 0.5,
            onset_s: 0.0,
            duration_s: f64::INFINITY,
            ageing_s: 20.0,
            decay_s: 0.0,
            focal_radius_mm: 0.3,
            diffuse_radius_mm: 4.0,
            jet_length_mm: 3.0,
        }
    }
}

impl BleedingSourceSpec {
    /// Blood flow (m^3/s), area radius (m) and jet length (m) at scene time `t_s`; zero flow
    /// before onset and after the duration.
    pub fn at(&self, t_s: f64) -> (f64, f64, f64) {
        let a = t_s - self.onset_s;
        if !(a >= 0.0 && a < self.duration_s) {
            return (0.0, 0.0, 0.0);
        }
        let rate = self.rate_ml_min / 6e7
            * if self.decay_s > 0.0 {
                (-a / self.decay_s).exp()
            } else {
                1.0
            };
        let age = if self.ageing_s > 0.0 {
            1.0 - (-a / self.ageing_s).exp()
        } else {
            1.0
        };
        let radius = self.focal_radius_mm + (self.diffuse_radius_mm - self.focal_radius_mm) * age;
        (rate, radius * 1e-3, self.jet_length_mm * 1e-3 * (1.0 - age))
    }
}

/// Blood.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BloodSpec {
    /// Blood volume one particle carries, microlitres.
    pub particle_volume_ul: f64,
    /// Attenuation coefficient of whole blood (absorption + scattering), 1/mm.
    pub attenuation_per_mm: f64,
    /// Density, kg/m^3.
    pub density_kg_m3: f64,
    /// Diameter of the droplet a particle settles as, mm.
    pub droplet_diameter_mm: f64,
    /// The sources.
    pub sources: Vec<BleedingSourceSpec>,
}

impl Default for BloodSpec {
    fn default() -> Self {
        Self {
            particle_volume_ul: 0.01,
            attenuation_per_mm: 20.0,
            density_kg_m3: 1060.0,
            droplet_diameter_mm: 0.05,
            sources: Vec::new(),
        }
    }
}

/// Air bubbles entering with the inflow.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BubbleSpec {
    /// Bubbles per ml of inflow.
    pub per_ml: f64,
    /// Smallest diameter, mm.
    pub min_diameter_mm: f64,
    /// Largest diameter, mm.
    pub max_diameter_mm: f64,
    /// Density of the gas, kg/m^3.
    pub density_kg_m3: f64,
}

impl Default for BubbleSpec {
    fn default() -> Self {
        Self {
            per_ml: 0.0,
            min_diameter_mm: 0.3,
            max_diameter_mm: 1.5,
            density_kg_m3: 1.2,
        }
    }
}

/// A release of tissue fragments.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FragmentSpec {
    /// Where, organ frame, mm.
    pub position_mm: [f64; 3],
    /// When, s of scene time.
    pub time_s: f64,
    /// How many.
    pub count: usize,
    /// Their diameter, mm.
    pub diameter_mm: f64,
    /// Their density, kg/m^3.
    pub density_kg_m3: f64,
    /// Radius of the cloud they start in, mm.
    pub spread_mm: f64,
}

impl Default for FragmentSpec {
    fn default() -> Self {
        Self {
            position_mm: [0.0, 0.0, 30.0],
            time_s: 0.0,
            count: 20,
            diameter_mm: 1.0,
            density_kg_m3: 1060.0,
            spread_mm: 2.0,
        }
    }
}

/// The `[particles]` table of a scene.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ParticleSpec {
    /// Most particles alive at once (storage allocated once).
    pub budget: usize,
    /// Seed of the emission and of the eddy dispersion's random walk.
    pub seed: u64,
    /// Most RK2 substeps per particle and step (each under one cell).
    pub max_substeps: usize,
    /// Density of the distension fluid, kg/m^3.
    pub fluid_density_kg_m3: f64,
    /// Viscosity of the distension fluid, Pa s.
    pub fluid_viscosity_pa_s: f64,
    /// Gravity.
    pub gravity: GravitySpec,
    /// Blood.
    pub blood: BloodSpec,
    /// Bubbles.
    pub bubbles: BubbleSpec,
    /// Fragments.
    pub fragments: Vec<FragmentSpec>,
    /// The clarity figure's view.
    pub view: ViewSpec,
    /// The inflow jet's turbulent mixing as a random walk (`scene::dispersion`).
    pub eddy_dispersion: bool,
}

impl Default for ParticleSpec {
    fn default() -> Self {
        Self {
            budget: 100_000,
            seed: 7,
            max_substeps: 8,
            fluid_density_kg_m3: 1000.0,
            fluid_viscosity_pa_s: 1e-3,
            gravity: GravitySpec::default(),
            blood: BloodSpec::default(),
            bubbles: BubbleSpec::default(),
            fragments: Vec::new(),
            view: ViewSpec::default(),
            eddy_dispersion: true,
        }
    }
}

impl ParticleSpec {
    /// Checks every range; the message names the key.
    pub fn validate(&self) -> Result<(), String> {
        let pos = |v: f64| v.is_finite() && v > 0.0;
        let nonneg = |v: f64| v.is_finite() && v >= 0.0;
        if self.budget == 0 || self.budget > 1_000_000 {
            return Err(format!(
                "`particles.budget` = {}: expected 1 to 1000000",
                self.budget
            ));
        }
        if !(1..=64).contains(&self.max_substeps) {
            return Err(format!(
                "`particles.max_substeps` = {}: expected 1 to 64",
                self.max_substeps
            ));
        }
        let checks = [
            (
                "fluid_density_kg_m3",
                self.fluid_density_kg_m3,
                pos(self.fluid_density_kg_m3),
            ),
            (
                "fluid_viscosity_pa_s",
                self.fluid_viscosity_pa_s,
                pos(self.fluid_viscosity_pa_s),
            ),
            (
                "blood.particle_volume_ul",
                self.blood.particle_volume_ul,
                pos(self.blood.particle_volume_ul),
            ),
            (
                "blood.attenuation_per_mm",
                self.blood.attenuation_per_mm,
                nonneg(self.blood.attenuation_per_mm),
            ),
            (
                "blood.density_kg_m3",
                self.blood.density_kg_m3,
                pos(self.blood.density_kg_m3),
            ),
            (
                "blood.droplet_diameter_mm",
                self.blood.droplet_diameter_mm,
                pos(self.blood.droplet_diameter_mm),
            ),
            (
                "bubbles.per_ml",
                self.bubbles.per_ml,
                nonneg(self.bubbles.per_ml),
            ),
            (
                "bubbles.min_diameter_mm",
                self.bubbles.min_diameter_mm,
                pos(self.bubbles.min_diameter_mm),
            ),
            (
                "bubbles.max_diameter_mm",
                self.bubbles.max_diameter_mm,
                pos(self.bubbles.max_diameter_mm)
                    && self.bubbles.max_diameter_mm >= self.bubbles.min_diameter_mm,
            ),
            (
                "bubbles.density_kg_m3",
                self.bubbles.density_kg_m3,
                pos(self.bubbles.density_kg_m3),
            ),
        ];
        for (key, v, ok) in checks {
            if !ok {
                return Err(format!(
                    "`particles.{key}` = {v}: out of range (see docs/particles.md)"
                ));
            }
        }
        for (n, s) in self.blood.sources.iter().enumerate() {
            let key = |k: &str| format!("`particles.blood.sources[{n}].{k}`");
            if s.position_mm.iter().any(|v| !v.is_finite()) {
                return Err(format!(
                    "{} = {:?}: expected finite coordinates",
                    key("position_mm"),
                    s.position_mm
                ));
            }
            for (k, v) in [
                ("rate_ml_min", s.rate_ml_min),
                ("onset_s", s.onset_s),
                ("ageing_s", s.ageing_s),
                ("decay_s", s.decay_s),
                ("focal_radius_mm", s.focal_radius_mm),
                ("diffuse_radius_mm", s.diffuse_radius_mm),
                ("jet_length_mm", s.jet_length_mm),
            ] {
                if !nonneg(v) {
                    return Err(format!("{} = {v}: expected a finite value >= 0", key(k)));
                }
            }
            if s.duration_s.is_nan() || s.duration_s < 0.0 {
                return Err(format!(
                    "{} = {}: expected a duration >= 0",
                    key("duration_s"),
                    s.duration_s
                ));
            }
        }
        for (n, f) in self.fragments.iter().enumerate() {
            let key = |k: &str| format!("`particles.fragments[{n}].{k}`");
            if f.position_mm.iter().any(|v| !v.is_finite()) {
                return Err(format!(
                    "{} = {:?}: expected finite coordinates",
                    key("position_mm"),
                    f.position_mm
                ));
            }
            for (k, v) in [
                ("diameter_mm", f.diameter_mm),
                ("density_kg_m3", f.density_kg_m3),
            ] {
                if !pos(v) {
                    return Err(format!("{} = {v}: expected a finite value > 0", key(k)));
                }
            }
            for (k, v) in [("time_s", f.time_s), ("spread_mm", f.spread_mm)] {
                if !nonneg(v) {
                    return Err(format!("{} = {v}: expected a finite value >= 0", key(k)));
                }
            }
        }
        if self.fragments.len() + BUBBLE_CLASSES + 1 > 255 {
            return Err("`particles.fragments`: at most 200 releases".into());
        }
        self.gravity.unit()?;
        self.view.validate()
    }
}

/// Drag coefficient of a sphere (Schiller-Naumann, 24/Re (1 + 0.15 Re^0.687) up to Re = 1000,
/// 0.44 above).
pub fn drag_coefficient(re: f64) -> f64 {
    if re >= 1000.0 {
        0.44
    } else {
        24.0 / re.max(1e-12) * (1.0 + 0.15 * re.powf(0.687))
    }
}

/// Terminal slip speed (m/s, positive along gravity: sinking) of a sphere of diameter `d_m` and
/// density `rho_p` in a fluid (`rho_f`, `mu`): the buoyancy-weight balance with
/// [`drag_coefficient`], solved by bisection on the speed. Also the relaxation time (s) of the
/// slip, `(rho_p + rho_f / 2) d^2 / (18 mu f(Re))` (added mass included, drag linearised at the
/// terminal Reynolds number).
pub fn terminal_slip(d_m: f64, rho_p: f64, rho_f: f64, mu: f64) -> (f64, f64) {
    let drho = rho_p - rho_f;
    let weight = drho.abs() * GRAVITY_M_S2 * std::f64::consts::PI / 6.0 * d_m.powi(3);
    let drag = |w: f64| {
        let re = rho_f * w * d_m / mu;
        0.5 * rho_f * drag_coefficient(re) * std::f64::consts::PI / 4.0 * d_m * d_m * w * w
    };
    let (mut lo, mut hi) = (0.0, 100.0);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if drag(mid) < weight {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let w = 0.5 * (lo + hi);
    let re = rho_f * w * d_m / mu;
    let f = if re > 0.0 {
        drag_coefficient(re) * re / 24.0
    } else {
        1.0
    };
    let tau = (rho_p + 0.5 * rho_f) * d_m * d_m / (18.0 * mu * f);
    (w * drho.signum(), tau)
}

/// Physical properties of one particle class.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ParticleClass {
    /// Kind.
    pub kind: ParticleKind,
    /// Terminal slip along gravity, m/s (negative: rises).
    pub settle_m_s: f64,
    /// Slip relaxation time, s.
    pub tau_s: f64,
    /// Obscuring weight, m^2: `kappa V` for blood, the projected area for opaque particles.
    pub shade_m2: f64,
    /// Diameter, m (for display).
    pub diameter_m: f64,
}

/// Counters of the particle stage (cumulative, except `alive`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ParticleCounts {
    /// Alive now.
    pub alive: usize,
    /// Emitted, per kind.
    pub emitted: [u64; 3],
    /// Left through the outflow holes, per kind.
    pub outflow: [u64; 3],
    /// Left through the open external os, per kind.
    pub open: [u64; 3],
    /// Removed because their cell closed with no fluid cell around, per kind.
    pub lost: [u64; 3],
    /// Not emitted because the budget was full.
    pub dropped: u64,
    /// Not emitted because the emission point was not in the fluid.
    pub rejected: u64,
}

/// The particles on one grid: fixed-capacity storage and the advection.
#[derive(Debug, Clone)]
pub struct ParticleSystem {
    dims: [usize; 3],
    h: f64,
    origin: [f64; 3],
    capacity: usize,
    max_substeps: usize,
    gravity: [f64; 3],
    classes: Vec<ParticleClass>,
    /// Position, grid units.
    pos: Vec<[f32; 3]>,
    /// Slip velocity, cells/s.
    slip: Vec<[f32; 3]>,
    class: Vec<u8>,
    birth_s: Vec<f32>,
    /// Cell-centred velocity, cells/s (4 lanes, the fourth unused).
    field: Vec<V4>,
    /// The cell kinds `field`'s cell lists were built for.
    field_kinds: Vec<VoxelKind>,
    /// Fluid and open cells: `(cell, lowest x face, lowest y face)` (the z face is the cell's).
    centred_cells: Vec<[u32; 3]>,
    /// Inflow, outflow and wall cells (prescribed velocity).
    prescribed_cells: Vec<u32>,
    /// Per class and step: slip decay, slip displacement factor, terminal slip (cells/s).
    class_step: Vec<([f32; 3], f32, f32)>,
    /// Per particle, this step: KEEP or how it left.
    fate: Vec<u8>,
    /// The upper half's sums of the clarity's cone weights per class (a step in two halves).
    upper_sums: Box<ClassSums>,
    /// Particles `[0, settled)` ended the last step in fluid cells of `field_kinds`.
    settled: usize,
    counts: ParticleCounts,
    time_s: f64,
    /// Eddy diffusivity of the sub-grid turbulent mixing, m^2/s (0: none; `scene::dispersion`).
    eddy_diffusivity_m2_s: f64,
    /// The random walk's generator (seeded per system: runs repeat).
    walk_rng: fastrand::Rng,
    /// The reordering by cell (`ParticleSystem::sort_by_cell`): its scratch, allocated once.
    sorter: CellSort,
}

/// A cell kind per cell from a solver grid's labels (fluid, solid -> wall, velocity -> wall,
/// outflow -> open), for runs without a scene.
pub fn kinds_from_labels(grid: &FluidGrid) -> Vec<VoxelKind> {
    grid.labels()
        .iter()
        .map(|l| match l {
            CellLabel::Fluid => VoxelKind::Fluid,
            CellLabel::Solid => VoxelKind::Solid,
            CellLabel::Velocity => VoxelKind::Wall,
            CellLabel::Outflow => VoxelKind::Open,
        })
        .collect()
}

impl ParticleSystem {
    /// Storage for `capacity` particles on the grid of `solver`.
    pub fn new(
        grid: &FluidGrid,
        capacity: usize,
        max_substeps: usize,
        gravity_unit: [f64; 3],
    ) -> Self {
        Self {
            dims: grid.dims(),
            h: grid.spacing_m(),
            origin: grid.origin_m(),
            capacity,
            max_substeps: max_substeps.max(1),
            gravity: gravity_unit,
            classes: Vec::with_capacity(256),
            pos: Vec::with_capacity(capacity),
            slip: Vec::with_capacity(capacity),
            class: Vec::with_capacity(capacity),
            birth_s: Vec::with_capacity(capacity),
            field: vec![v4::zero(); grid.cell_count()],
            field_kinds: Vec::new(),
            centred_cells: Vec::new(),
            prescribed_cells: Vec::new(),
            class_step: Vec::with_capacity(256),
            fate: Vec::with_capacity(capacity),
            upper_sums: Box::new([0.0; 256]),
            settled: 0,
            counts: ParticleCounts::default(),
            time_s: 0.0,
            eddy_diffusivity_m2_s: 0.0,
            walk_rng: fastrand::Rng::with_seed(WALK_STREAM),
            sorter: CellSort::new(grid.cell_count(), capacity),
        }
    }

    /// Reseeds the eddy dispersion's random walk (a scene seeds it from `particles.seed`).
    pub fn seed_walk(&mut self, seed: u64) {
        self.walk_rng = fastrand::Rng::with_seed(seed);
    }

    /// Sets the eddy diffusivity of the random walk every later step adds to the advection,
    /// m^2/s (0, the default: none; `scene::dispersion`).
    pub fn set_eddy_diffusivity(&mut self, d_m2_s: f64) {
        self.eddy_diffusivity_m2_s = if d_m2_s.is_finite() {
            d_m2_s.max(0.0)
        } else {
            0.0
        };
    }

    /// The eddy dispersion's random walk over `dt_s` (`scene::dispersion::walk`).
    fn disperse(&mut self, kinds: &[VoxelKind], dt_s: f64) {
        let Some(plan) = dispersion::walk_plan(self.eddy_diffusivity_m2_s, dt_s, self.h) else {
            return;
        };
        let n = self.pos.len();
        let entered_outlet = if n >= PARALLEL_MIN {
            // The advection's chunks, each with its own generator seeded from the system's (the
            // same draws whatever the thread count).
            use rayon::prelude::*;
            let chunk = n.div_ceil(PARALLEL_TASKS);
            let mut seeds = [0u64; PARALLEL_TASKS];
            seeds.iter_mut().for_each(|s| *s = self.walk_rng.u64(..));
            let (dims, pos) = (self.dims, &mut self.pos);
            pos.par_chunks_mut(chunk)
                .zip(seeds.par_iter())
                .map(|(p, &seed)| {
                    let mut rng = fastrand::Rng::with_seed(seed);
                    dispersion::walk(p, kinds, dims, plan, &mut rng)
                })
                .reduce(|| false, |a, b| a || b)
        } else {
            dispersion::walk(&mut self.pos, kinds, self.dims, plan, &mut self.walk_rng)
        };
        if entered_outlet {
            // Particles moved into an outlet no longer start in fluid cells.
            self.settled = 0;
        }
    }

    /// Adds a class; returns its index, or `None` when 255 exist.
    pub fn add_class(&mut self, class: ParticleClass) -> Option<u8> {
        if self.classes.len() >= 255 {
            return None;
        }
        self.classes.push(class);
        self.class_step.push(([0.0; 3], 0.0, 0.0));
        Some((self.classes.len() - 1) as u8)
    }
    /// The classes.
    pub fn classes(&self) -> &[ParticleClass] {
        &self.classes
    }
    /// Alive particles.
    pub fn len(&self) -> usize {
        self.pos.len()
    }
    /// No particle alive.
    pub fn is_empty(&self) -> bool {
        self.pos.is_empty()
    }
    /// The storage's capacity (the budget).
    pub fn capacity(&self) -> usize {
        self.capacity
    }
    /// The counters.
    pub fn counts(&self) -> ParticleCounts {
        ParticleCounts {
            alive: self.pos.len(),
            ..self.counts
        }
    }
    /// Time of the system, s.
    pub fn time_s(&self) -> f64 {
        self.time_s
    }
    /// Position of particle `n`, m.
    pub fn position_m(&self, n: usize) -> [f64; 3] {
        let p = self.pos[n];
        std::array::from_fn(|a| self.origin[a] + p[a] as f64 * self.h)
    }
    /// Velocity of particle `n`, m/s: the fluid's at its position (as of the last step) plus
    /// its slip.
    pub fn velocity_m_per_s(&self, n: usize) -> [f64; 3] {
        let u = self.fluid_velocity(n);
        let slip = self.slip[n];
        std::array::from_fn(|a| f64::from(u[a] + slip[a]) * self.h)
    }
    /// The cell-centred field of the last step at particle `n`, cells/s.
    fn fluid_velocity(&self, n: usize) -> [f32; 4] {
        let p = self.pos[n];
        v4::lanes(Sampler::new(&self.field, self.dims).sample::<false>(v4::new(p[0], p[1], p[2])))
    }
    /// Time since particle `n` was emitted, s.
    pub fn age_s(&self, n: usize) -> f64 {
        (self.time_s - f64::from(self.birth_s[n])).max(0.0)
    }
    /// Class of particle `n`.
    pub fn class_of(&self, n: usize) -> ParticleClass {
        self.classes[self.class[n] as usize]
    }
    /// Sets the unit gravity direction.
    pub fn set_gravity(&mut self, gravity_unit: [f64; 3]) {
        self.gravity = gravity_unit;
    }
    /// Removes every particle (counters kept).
    pub fn clear(&mut self) {
        self.pos.clear();
        self.slip.clear();
        self.class.clear();
        self.birth_s.clear();
        self.settled = 0;
    }

    /// The cell (linear index) of a position in grid units, if inside the grid.
    #[inline]
    fn cell(&self, p: [f32; 3]) -> Option<usize> {
        let [nx, ny, nz] = self.dims;
        if !(p[0] >= 0.0 && p[1] >= 0.0 && p[2] >= 0.0) {
            return None;
        }
        let (i, j, k) = (p[0] as usize, p[1] as usize, p[2] as usize);
        (i < nx && j < ny && k < nz).then(|| i + nx * (j + ny * k))
    }

    /// Emits a particle of class `class` at `p_m` with the fluid's velocity (slip zero); false
    /// when the budget is full or the point is not in a fluid cell.
    pub fn emit(&mut self, kinds: &[VoxelKind], class: u8, p_m: [f64; 3]) -> bool {
        let Some(c) = self.classes.get(class as usize).copied() else {
            return false;
        };
        let k = c.kind as usize;
        if self.pos.len() >= self.capacity {
            self.counts.dropped += 1;
            return false;
        }
        let g: [f32; 3] = std::array::from_fn(|a| ((p_m[a] - self.origin[a]) / self.h) as f32);
        if self.cell(g).and_then(|n| kinds.get(n)) != Some(&VoxelKind::Fluid) {
            self.counts.rejected += 1;
            return false;
        }
        self.pos.push(g);
        self.slip.push([0.0; 3]);
        self.class.push(class);
        self.birth_s.push(self.time_s as f32);
        self.counts.emitted[k] += 1;
        true
    }

    /// Rebuilds the lists of cells whose velocity `build_field` writes when the kinds changed
    /// (the cavity moved; returns whether they did); the other cells' velocity is zero.
    fn sync_kinds(&mut self, kinds: &[VoxelKind]) -> bool {
        let cells = self.field.len();
        let kinds = &kinds[..cells.min(kinds.len())];
        if kind_bytes(&self.field_kinds) == kind_bytes(kinds) {
            return false;
        }
        self.field_kinds.clear();
        self.field_kinds.extend_from_slice(kinds);
        self.field.fill(v4::zero());
        self.centred_cells.clear();
        self.prescribed_cells.clear();
        let [nx, ny, _] = self.dims;
        for (n, kind) in kinds.iter().enumerate() {
            match kind {
                VoxelKind::Fluid | VoxelKind::Open => {
                    // x faces: (nx + 1) per row, so the row count is added; y faces: nx more per
                    // layer.
                    let (row, layer) = (n / nx, n / (nx * ny));
                    self.centred_cells
                        .push([n as u32, (n + row) as u32, (n + nx * layer) as u32]);
                }
                VoxelKind::Inflow | VoxelKind::Outflow | VoxelKind::Wall => {
                    self.prescribed_cells.push(n as u32);
                }
                _ => {}
            }
        }
        true
    }

    /// Builds the cell-centred velocity (cells/s): the mean of the faces in fluid and open
    /// cells (plus the overlay's), the prescribed velocity in port and wall cells, zero elsewhere.
    /// Returns whether the kinds changed since the last build.
    fn build_field(
        &mut self,
        solver: &FluidSolver,
        kinds: &[VoxelKind],
        overlay: Option<[&[f32]; 3]>,
    ) -> bool {
        let changed = self.sync_kinds(kinds);
        let [nx, ny, _] = self.dims;
        let inv_h = (1.0 / self.h) as f32;
        let half = 0.5 * inv_h;
        let grid = solver.grid();
        let faces: [&[f32]; 3] = std::array::from_fn(|c| solver.face_velocities(c));
        // Two halves of the cell list (in index order) on the two cores: at 10^4 particles the
        // build is a tenth of the step.
        let cells = &self.centred_cells[..];
        let (lower, upper) = cells.split_at(cells.len() / 2);
        let at = upper.first().map_or(self.field.len(), |c| c[0] as usize);
        let (fa, fb) = self.field.split_at_mut(at);
        let fill = |cells: &[[u32; 3]], field: &mut [V4], offset: usize| match overlay {
            None => centre_faces(cells, field, offset, [faces], [nx, ny], half),
            Some(o) => centre_faces(cells, field, offset, [faces, o], [nx, ny], half),
        };
        crate::fork_join::join(|| fill(lower, fa, 0), || fill(upper, fb, at));
        let field = &mut self.field;
        for &n in &self.prescribed_cells {
            let p = grid.velocity_at(n as usize);
            field[n as usize] = v4::new(p[0] * inv_h, p[1] * inv_h, p[2] * inv_h);
        }
        changed
    }

    /// Advances every particle by `dt_s` in the solver's current velocity (plus the overlay's
    /// face velocities, same layout), against `kinds` (one per cell). Returns the clarity of the
    /// view if one is given.
    pub fn step(
        &mut self,
        solver: &FluidSolver,
        kinds: &[VoxelKind],
        overlay: Option<[&[f32]; 3]>,
        dt_s: f64,
        view: Option<&View>,
    ) -> Option<f64> {
        self.time_s += dt_s;
        if !self.pos.is_empty() && dt_s > 0.0 && kinds.len() >= self.field.len() {
            let kinds_changed = self.build_field(solver, kinds, overlay);
            self.disperse(kinds, dt_s);
            let cone = view.map(|v| Cone::new(v, self.origin, self.h));
            let sums = self.advance(kinds, kinds_changed, dt_s, cone);
            return view.map(|v| self.clarity_from(v, &sums));
        }
        view.map(|v| self.clarity(v))
    }

    /// Moves every particle; returns the clarity's sums per class over the particles that stay
    /// (zero without a cone).
    fn advance(
        &mut self,
        kinds: &[VoxelKind],
        kinds_changed: bool,
        dt_s: f64,
        cone: Option<Cone>,
    ) -> ClassSums {
        let inv_h = 1.0 / self.h;
        for (c, s) in self.classes.iter().zip(&mut self.class_step) {
            let e = if c.tau_s > 0.0 {
                (-dt_s / c.tau_s).exp()
            } else {
                0.0
            };
            let disp = c.tau_s * (1.0 - e);
            let t = self.gravity.map(|g| (g * c.settle_m_s * inv_h) as f32);
            *s = (t, e as f32, disp as f32);
        }
        let k = Kernel::new(
            Sampler::new(&self.field, self.dims),
            kinds,
            &self.class_step,
            if kinds_changed { 0 } else { self.settled },
            self.max_substeps,
            dt_s,
            cone,
        );
        let n = self.pos.len();
        let classes = self.classes.len();
        // The fate of every particle this step (KEEP, or the outlet), then a compaction.
        self.fate.clear();
        self.fate.resize(n, KEEP);
        let mut sums = [0.0f32; 256];
        let left = if n >= PARALLEL_MIN {
            // On the two cores by the solver's fork-join (at 10^4 particles a step is ~0.2 ms, where
            // a thread pool's wake-ups showed), in CHUNKS chunks dealt alternately: the particles
            // are ordered by cell, so the costly ones (the jet's, with more substeps) are
            // neighbours and each core gets its share of them.
            let chunk = n.div_ceil(CHUNKS).next_multiple_of(BLOCK);
            let mut tasks: [[Option<Task>; CHUNKS / 2]; 2] =
                std::array::from_fn(|_| std::array::from_fn(|_| None));
            let parts = self
                .pos
                .chunks_mut(chunk)
                .zip(self.slip.chunks_mut(chunk))
                .zip(self.class.chunks(chunk))
                .zip(self.fate.chunks_mut(chunk));
            for (t, (((pos, slip), class), fate)) in parts.enumerate().take(CHUNKS) {
                tasks[t % 2][t / 2] = Some(Task {
                    offset: t * chunk,
                    pos,
                    slip,
                    class,
                    fate,
                });
            }
            let [lower, upper] = tasks;
            let upper_sums = &mut *self.upper_sums;
            upper_sums[..classes].fill(0.0);
            let run = |tasks: [Option<Task>; CHUNKS / 2], sums: &mut ClassSums| {
                tasks
                    .into_iter()
                    .flatten()
                    .map(|t| k.run(t, sums))
                    .sum::<usize>()
            };
            let (a, b) =
                crate::fork_join::join(|| run(lower, &mut sums), || run(upper, upper_sums));
            for (x, y) in sums[..classes].iter_mut().zip(upper_sums.iter()) {
                *x += y;
            }
            a + b
        } else {
            let task = Task {
                offset: 0,
                pos: &mut self.pos,
                slip: &mut self.slip,
                class: &self.class,
                fate: &mut self.fate,
            };
            k.run(task, &mut sums)
        };
        if left > 0 {
            self.remove_left();
        }
        self.settled = self.pos.len();
        if self.pos.len() >= PARALLEL_MIN {
            self.sorter.steps += 1;
            if self.sorter.steps >= SORT_PERIOD {
                self.sort_by_cell();
            }
        }
        sums
    }

    /// Reorders the particles by cell (a counting sort on the cell index), so that the kernel's
    /// consecutive particles sample neighbouring cells and the field's samples stay in the L1
    /// cache (emission at random cells and removals shuffle them). Particle indices change, as
    /// they do with removals.
    fn sort_by_cell(&mut self) {
        let n = self.pos.len();
        let cs = &mut self.sorter;
        cs.steps = 0;
        if cs.start.len() != self.field.len() + 1 || cs.pos.capacity() < n {
            return;
        }
        cs.start.fill(0);
        cs.key.clear();
        let [nx, ny, nz] = self.dims.map(|n| n as f32);
        let (dims, stride) = (
            lane::new4(nx, ny, nz, 1.0),
            [1, self.dims[0], self.dims[0] * self.dims[1]],
        );
        for p in &self.pos {
            // Every particle here ended its step in a fluid cell (inside the grid).
            let k = lane::cell(v4::new(p[0], p[1], p[2]), dims, stride).unwrap_or(0);
            cs.key.push(k as u32);
            cs.start[k + 1] += 1;
        }
        for k in 1..cs.start.len() {
            cs.start[k] += cs.start[k - 1];
        }
        cs.pos.resize(n, [0.0; 3]);
        cs.slip.resize(n, [0.0; 3]);
        cs.class.resize(n, 0);
        cs.birth_s.resize(n, 0.0);
        for (i, &k) in cs.key.iter().enumerate() {
            let to = cs.start[k as usize] as usize;
            cs.start[k as usize] += 1;
            cs.pos[to] = self.pos[i];
            cs.slip[to] = self.slip[i];
            cs.class[to] = self.class[i];
            cs.birth_s[to] = self.birth_s[i];
        }
        std::mem::swap(&mut self.pos, &mut cs.pos);
        std::mem::swap(&mut self.slip, &mut cs.slip);
        std::mem::swap(&mut self.class, &mut cs.class);
        std::mem::swap(&mut self.birth_s, &mut cs.birth_s);
    }

    /// Removes the particles whose fate is not KEEP (the last particle fills each hole, so the
    /// cost is the scan of the fates plus O(left)) and counts them.
    fn remove_left(&mut self) {
        let mut i = 0;
        while let Some(next) = next_left(&self.fate, i) {
            i = next;
            let f = self.fate[i];
            let kind = self.classes[self.class[i] as usize].kind as usize;
            match f {
                OUTFLOW => self.counts.outflow[kind] += 1,
                OPEN => self.counts.open[kind] += 1,
                _ => self.counts.lost[kind] += 1,
            }
            // The last particle moves here and is looked at next.
            self.fate.swap_remove(i);
            self.pos.swap_remove(i);
            self.slip.swap_remove(i);
            self.class.swap_remove(i);
            self.birth_s.swap_remove(i);
        }
    }

    /// The clarity of `view` (see [`View`]): `exp(-mean optical depth over the view cone)`.
    pub fn clarity(&self, view: &View) -> f64 {
        let cone = Cone::new(view, self.origin, self.h);
        let mut sums = [0.0f32; 256];
        for (p, &c) in self.pos.iter().zip(&self.class) {
            sums[c as usize] += cone.weight(*p);
        }
        self.clarity_from(view, &sums)
    }

    /// The clarity from the per-class sums of [`Cone::weight`].
    fn clarity_from(&self, view: &View, sums: &ClassSums) -> f64 {
        let mut tau = 0.0f64;
        for (c, s) in self.classes.iter().zip(sums) {
            tau += c.shade_m2 * f64::from(*s) / (self.h * self.h);
        }
        (-tau / view.solid_angle_sr()).exp()
    }

    /// Velocity of particle `n`, m/s: the fluid's (the cell-centred field of the last step, plus
    /// the vortex overlay, sampled at the particle) plus its slip. Zero before the first step
    /// that moved particles.
    pub fn velocity_m_s(&self, n: usize) -> [f64; 3] {
        let v = self.fluid_velocity(n);
        let w = self.slip[n];
        std::array::from_fn(|a| (v[a] + w[a]) as f64 * self.h)
    }

    /// The particles as a VTK PolyData document (`.vtp`, ASCII): points (m), one vertex cell
    /// each, point data `kind` (0 blood, 1 bubble, 2 fragment), `diameter_m`, `age_s` and
    /// `velocity` (m/s, [`ParticleSystem::velocity_m_s`]).
    pub fn vtp_string(&self) -> String {
        particles_xml(Some(self), VtkFlavour::PolyData)
    }

    /// The same particles and point data as a VTK UnstructuredGrid of vertex cells (`.vtu`,
    /// ASCII): ParaView shows it as the `.vtp`, and readers that know only unstructured grids
    /// (meshio) read it too.
    pub fn vtu_string(&self) -> String {
        particles_xml(Some(self), VtkFlavour::UnstructuredGrid)
    }

    /// Writes [`ParticleSystem::vtp_string`] to `path`.
    pub fn write_vtp(&self, path: &Path) -> std::io::Result<()> {
        std::fs::write(path, self.vtp_string())
    }
}

/// Which VTK XML dataset the particles are written as.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VtkFlavour {
    /// PolyData with one vertex cell per particle (`.vtp`).
    PolyData,
    /// UnstructuredGrid with one `VTK_VERTEX` cell per particle (`.vtu`).
    UnstructuredGrid,
}

/// The particles of `sys` (none: an empty document) as VTK XML, ASCII.
pub fn particles_xml(sys: Option<&ParticleSystem>, flavour: VtkFlavour) -> String {
    let n = sys.map_or(0, ParticleSystem::len);
    let poly = flavour == VtkFlavour::PolyData;
    let (root, cells_tag) = if poly {
        ("PolyData", "Verts")
    } else {
        ("UnstructuredGrid", "Cells")
    };
    let mut s = String::with_capacity(160 * n + 1024);
    let _ = writeln!(
        s,
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"{root}\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n<{root}>"
    );
    if poly {
        let _ = writeln!(
            s,
            "<Piece NumberOfPoints=\"{n}\" NumberOfVerts=\"{n}\" NumberOfLines=\"0\" NumberOfStrips=\"0\" NumberOfPolys=\"0\">"
        );
    } else {
        let _ = writeln!(s, "<Piece NumberOfPoints=\"{n}\" NumberOfCells=\"{n}\">");
    }
    s.push_str("<PointData Scalars=\"kind\" Vectors=\"velocity\">\n<DataArray type=\"UInt8\" Name=\"kind\" format=\"ascii\">\n");
    if let Some(sys) = sys {
        for &c in &sys.class {
            let _ = writeln!(s, "{}", sys.classes[c as usize].kind as u8);
        }
    }
    s.push_str("</DataArray>\n<DataArray type=\"Float32\" Name=\"diameter_m\" format=\"ascii\">\n");
    if let Some(sys) = sys {
        for &c in &sys.class {
            let _ = writeln!(s, "{:e}", sys.classes[c as usize].diameter_m as f32);
        }
    }
    s.push_str("</DataArray>\n<DataArray type=\"Float32\" Name=\"age_s\" format=\"ascii\">\n");
    if let Some(sys) = sys {
        for &b in &sys.birth_s {
            let _ = writeln!(s, "{:e}", sys.time_s as f32 - b);
        }
    }
    s.push_str("</DataArray>\n<DataArray type=\"Float32\" Name=\"velocity\" NumberOfComponents=\"3\" format=\"ascii\">\n");
    if let Some(sys) = sys {
        for i in 0..n {
            let v = sys.velocity_m_s(i);
            let _ = writeln!(s, "{:e} {:e} {:e}", v[0] as f32, v[1] as f32, v[2] as f32);
        }
    }
    s.push_str("</DataArray>\n</PointData>\n<Points>\n<DataArray type=\"Float32\" NumberOfComponents=\"3\" format=\"ascii\">\n");
    if let Some(sys) = sys {
        for i in 0..n {
            let p = sys.position_m(i);
            let _ = writeln!(s, "{:e} {:e} {:e}", p[0] as f32, p[1] as f32, p[2] as f32);
        }
    }
    let _ = writeln!(
        s,
        "</DataArray>\n</Points>\n<{cells_tag}>\n<DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">"
    );
    for i in 0..n {
        let _ = writeln!(s, "{i}");
    }
    s.push_str("</DataArray>\n<DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">\n");
    for i in 0..n {
        let _ = writeln!(s, "{}", i + 1);
    }
    s.push_str("</DataArray>\n");
    if !poly {
        // VTK_VERTEX.
        s.push_str("<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">\n");
        for _ in 0..n {
            s.push_str("1\n");
        }
        s.push_str("</DataArray>\n");
    }
    let _ = writeln!(s, "</{cells_tag}>\n</Piece>\n</{root}>\n</VTKFile>");
    s
}

/// Scratch of [`ParticleSystem::sort_by_cell`], allocated with the system (the particle arrays
/// are swapped with these, so both have the budget's capacity).
#[derive(Debug, Clone)]
struct CellSort {
    /// Steps since the last reordering.
    steps: u32,
    /// Per cell (one more): the particle count, then the first slot of the cell's particles.
    start: Vec<u32>,
    /// Each particle's cell.
    key: Vec<u32>,
    pos: Vec<[f32; 3]>,
    slip: Vec<[f32; 3]>,
    class: Vec<u8>,
    birth_s: Vec<f32>,
}

impl CellSort {
    fn new(cells: usize, capacity: usize) -> Self {
        Self {
            steps: 0,
            start: vec![0; cells + 1],
            key: Vec::with_capacity(capacity),
            pos: Vec::with_capacity(capacity),
            slip: Vec::with_capacity(capacity),
            class: Vec::with_capacity(capacity),
            birth_s: Vec::with_capacity(capacity),
        }
    }
}

/// Steps between two reorderings of the particles by cell (from [`PARALLEL_MIN`] particles; a
/// particle moves about a third of a cell per step, so the order decays slowly).
const SORT_PERIOD: u32 = 16;
const KEEP: u8 = 0;
const OUTFLOW: u8 = 1;
const OPEN: u8 = 2;
const LOST: u8 = 3;
/// From this many particles a step runs in parallel tasks ...
const PARALLEL_MIN: usize = 4096;
/// ... the eddy dispersion in this many tasks (a few per core, so a slow chunk does not hold the
/// step) ...
const PARALLEL_TASKS: usize = 8;
/// ... and the advection in this many chunks, dealt alternately to the two halves of a fork-join.
const CHUNKS: usize = 32;
/// Particles the kernel moves together (their independent samples overlap in the CPU).
const GROUP: usize = 4;
/// Particles the AVX2 kernel moves in the lanes of one vector (`block8`); chunks are whole
/// blocks (and so whole groups).
const BLOCK: usize = 8;
/// Longest substep along any axis, cells.
const SUBSTEP_CELLS: f32 = 0.9;

/// Per class: the sum over a step's particles of their [`Cone::weight`].
type ClassSums = [f32; 256];

/// The view cone in grid units.
#[derive(Clone, Copy)]
struct Cone {
    tip: [f32; 3],
    dir: [f32; 3],
    cos2: f32,
    depth: f32,
    near2: f32,
}

impl Cone {
    fn new(view: &View, origin: [f64; 3], h: f64) -> Self {
        let c = view.cos_half_angle as f32;
        Self {
            tip: std::array::from_fn(|a| ((view.tip_m[a] - origin[a]) / h) as f32),
            dir: view.dir.map(|x| x as f32),
            cos2: c * c,
            depth: (view.depth_m / h) as f32,
            near2: ((view.near_m / h) as f32).powi(2),
        }
    }

    /// `1 / max(r, near)^2` (grid units) for a particle inside the cone, else 0.
    #[inline(always)]
    fn weight(&self, p: [f32; 3]) -> f32 {
        let d = [p[0] - self.tip[0], p[1] - self.tip[1], p[2] - self.tip[2]];
        let along = d[0] * self.dir[0] + d[1] * self.dir[1] + d[2] * self.dir[2];
        let r2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
        if along > 0.0 && along <= self.depth && along * along >= self.cos2 * r2 {
            1.0 / r2.max(self.near2)
        } else {
            0.0
        }
    }
}

/// Trilinear interpolation of the cell-centred field (4 lanes, one SIMD lerp per pair).
#[derive(Clone, Copy)]
struct Sampler<'a> {
    field: &'a [V4],
    /// Largest sample position along each axis (`n - 1`; lane 3 zero).
    smax: V4,
    /// Largest lower sample index along each axis (`n - 2`, 0 for one cell; lane 3 zero).
    imax: V4,
    /// Index strides `[1, nx, nx ny]`.
    stride: [usize; 3],
    /// Index step to the upper sample along each axis (0 for one cell).
    step: [usize; 3],
    /// Byte offsets of the eight samples from the lower one, `{0, x} + {0, y} + {0, z}` in the
    /// order `000, x00, 0y0, xy0, 00z, x0z, 0yz, xyz` (bytes: no shift per address).
    corner_bytes: [usize; 8],
    /// The upper sample along x is the next element (more than one cell along x).
    x_pairs: bool,
    /// `field` holds every cell of the grid, and a cell's byte offset in it fits a `u32` (the
    /// eight-particle kernel's precondition: its samples need no bounds check).
    whole: bool,
}

impl<'a> Sampler<'a> {
    fn new(field: &'a [V4], dims: [usize; 3]) -> Self {
        let stride = [1, dims[0], dims[0] * dims[1]];
        let f = |v: [usize; 3]| v4::new(v[0] as f32, v[1] as f32, v[2] as f32);
        let step: [usize; 3] = std::array::from_fn(|a| usize::from(dims[a] > 1) * stride[a]);
        let size = std::mem::size_of::<V4>();
        Self {
            field,
            smax: f(dims.map(|n| n.saturating_sub(1))),
            imax: f(dims.map(|n| n.saturating_sub(2))),
            stride,
            step,
            corner_bytes: std::array::from_fn(|c| {
                (0..3).map(|a| (c >> a & 1) * step[a]).sum::<usize>() * size
            }),
            x_pairs: step[0] == 1,
            whole: dims
                .iter()
                .try_fold(1usize, |n, &d| n.checked_mul(d))
                .is_some_and(|n| n <= field.len() && n <= (u32::MAX as usize) / size),
        }
    }

    /// The field at `p` (grid units; clamped to the outermost samples). With `FMA` (set only by
    /// [`Kernel::run_avx2`], on a CPU with AVX2 and FMA) each pair of x neighbours is one
    /// eight-lane load and the blends run along y, z, then x with fused multiply-adds: the same
    /// trilinear interpolant in half the loads and blends, rounded once per blend.
    #[inline(always)]
    fn sample<const FMA: bool>(&self, p: V4) -> V4 {
        let (b, t) = lane::locate(p, self.smax, self.imax, self.stride);
        let [sx, sy, sz] = self.step;
        // The eight samples are b + {0, sx} + {0, sy} + {0, sz}, the largest b + sx + sy + sz:
        // one check for all (always true: the lower index is at most n - 2 along each axis).
        let f = match self.field.get(b..=b + sx + sy + sz) {
            Some(f) => f,
            None => return v4::zero(),
        };
        let (first, o) = (f.as_ptr(), &self.corner_bytes);
        #[cfg(target_arch = "x86_64")]
        if FMA && self.x_pairs {
            // SAFETY: `FMA` only in `run_avx2` (the CPU has AVX2 and FMA); the pairs start at
            // `first` + {0, sy} + {0, sz} and end at most at `first` + 1 + sy + sz, the last
            // element of `f`.
            return unsafe { lane::trilinear_x_pairs(first, sy, sz, t) };
        }
        let [tx, ty, tz] = lane::broadcast3(t);
        // SAFETY: every corner is `first` plus at most sx + sy + sz whole elements, the last of
        // `f` (so in bounds and aligned).
        let at = |c: usize| unsafe { first.byte_add(o[c]).read() };
        let c00 = lane::lerp(at(0), at(1), tx);
        let c10 = lane::lerp(at(2), at(3), tx);
        let c01 = lane::lerp(at(4), at(5), tx);
        let c11 = lane::lerp(at(6), at(7), tx);
        lane::lerp(lane::lerp(c00, c10, ty), lane::lerp(c01, c11, ty), tz)
    }
}

/// One task's particles for [`Kernel::run`]: the first is particle `offset` of the system.
struct Task<'a> {
    offset: usize,
    pos: &'a mut [[f32; 3]],
    slip: &'a mut [[f32; 3]],
    class: &'a [u8],
    fate: &'a mut [u8],
}

/// The per-particle step, shared by the threads.
struct Kernel<'a> {
    field: Sampler<'a>,
    kinds: &'a [VoxelKind],
    /// The grid's dimensions as floats (lane 3: 1).
    fdims: V4,
    /// The particles from this index on start in a cell that may not be fluid (all when the
    /// kinds changed; else those emitted since the last step, which ends each particle in a
    /// fluid cell).
    check_from: usize,
    class_step: &'a [([f32; 3], f32, f32)],
    dt: f32,
    max_sub: u32,
    cone: Option<Cone>,
}

impl<'a> Kernel<'a> {
    fn new(
        field: Sampler<'a>,
        kinds: &'a [VoxelKind],
        class_step: &'a [([f32; 3], f32, f32)],
        check_from: usize,
        max_sub: usize,
        dt_s: f64,
        cone: Option<Cone>,
    ) -> Self {
        let [nx, ny, nz, _] = v4::lanes(field.smax).map(|x| x + 1.0);
        Self {
            field,
            kinds,
            // Lane 3 (zero in positions) passes the bounds test.
            fdims: lane::new4(nx, ny, nz, 1.0),
            check_from,
            class_step,
            dt: dt_s as f32,
            max_sub: max_sub as u32,
            cone,
        }
    }

    /// Whether [`block8`] can move this kernel's particles (the sampler has the whole grid and
    /// x pairs).
    #[cfg(target_arch = "x86_64")]
    fn blocks(&self) -> bool {
        self.field.whole && self.field.x_pairs
    }

    #[inline(always)]
    fn kind_at(&self, p: V4) -> VoxelKind {
        lane::cell(p, self.fdims, self.field.stride)
            .and_then(|n| self.kinds.get(n))
            .copied()
            .unwrap_or(VoxelKind::Solid)
    }

    /// Moves the particles of `task`; adds the clarity's cone weights of those that stay to `sums`
    /// and returns how many left (their fate is not KEEP).
    fn run(&self, task: Task<'_>, sums: &mut ClassSums) -> usize {
        #[cfg(target_arch = "x86_64")]
        if crate::simd::avx2_fma() {
            // SAFETY: the CPU has AVX2 and FMA (checked above).
            return unsafe { self.run_avx2(task, sums) };
        }
        self.run_portable::<false>(task, sums)
    }

    /// [`Kernel::run_portable`] compiled for AVX2 and FMA (the fluid stages' SIMD style: the
    /// same portable code, a second time with the wider instruction set).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn run_avx2(&self, task: Task<'_>, sums: &mut ClassSums) -> usize {
        // The FMA sampler (`Sampler::sample`): only instantiated here, where the CPU has both.
        self.run_portable::<true>(task, sums)
    }

    #[inline(always)]
    fn run_portable<const FMA: bool>(&self, task: Task<'_>, sums: &mut ClassSums) -> usize {
        let Task {
            offset,
            pos,
            slip,
            class,
            fate,
        } = task;
        let mut left = 0;
        let n = pos.len().min(slip.len()).min(class.len()).min(fate.len());
        // Groups of GROUP particles whose starts need no check: the common case (one substep
        // into a fluid cell) for all of them at once, so the independent samples overlap; the
        // others one at a time.
        let grouped = if offset + n <= self.check_from {
            n
        } else {
            self.check_from.saturating_sub(offset).min(n)
        } / GROUP
            * GROUP;
        let (pos, pos_rest) = pos[..n].split_at_mut(grouped);
        let (slip, slip_rest) = slip[..n].split_at_mut(grouped);
        let (class, class_rest) = class[..n].split_at(grouped);
        let (fate, fate_rest) = fate[..n].split_at_mut(grouped);
        // Particles of the groups that need more substeps (or met a wall): collected until there
        // are GROUP of them, whose substeps then run side by side (their samples overlap too).
        let mut waiting = [Resume::default(); GROUP];
        let mut count = 0;
        // Eight at a time, each particle in a lane of its own (`block8`), where it can; the rest
        // (fewer than eight) in groups of four.
        #[cfg(target_arch = "x86_64")]
        let from = if FMA && self.blocks() {
            // SAFETY: `FMA` only in `run_avx2` (the CPU has AVX2 and FMA).
            let (l, moved) = unsafe { block8::run(self, grouped, pos, slip, class, fate, sums) };
            left += l;
            moved
        } else {
            0
        };
        #[cfg(not(target_arch = "x86_64"))]
        let from = 0;
        for g in (from..grouped).step_by(GROUP) {
            let p: Result<&mut [[f32; 3]; GROUP], _> = (&mut pos[g..g + GROUP]).try_into();
            let w: Result<&mut [[f32; 3]; GROUP], _> = (&mut slip[g..g + GROUP]).try_into();
            let c: Result<&[u8; GROUP], _> = class[g..g + GROUP].try_into();
            let (Ok(p), Ok(w), Ok(c)) = (p, w, c) else {
                continue;
            };
            let more = self.advance_group::<FMA>(&mut *p, w, c);
            let ends = *p;
            for l in 0..GROUP {
                match more[l] {
                    None => {
                        fate[g + l] = KEEP;
                        left += self.tally(KEEP, c[l], ends[l], sums);
                    }
                    Some(r) => {
                        waiting[count] = Resume { at: g + l, ..r };
                        count += 1;
                        if count == GROUP {
                            left += self.resume::<FMA>(&waiting, pos, class, fate, sums);
                            count = 0;
                        }
                    }
                }
            }
        }
        left += self.resume::<FMA>(&waiting[..count], pos, class, fate, sums);
        for (m, (((p, w), &c), f)) in pos_rest
            .iter_mut()
            .zip(slip_rest)
            .zip(class_rest)
            .zip(fate_rest)
            .enumerate()
        {
            let check = offset + grouped + m >= self.check_from;
            *f = self.advance_one::<FMA>(p, w, c, check);
            left += self.tally(*f, c, *p, sums);
        }
        left
    }

    /// A particle's end of step: its cone weight added to `sums` if it stays (returns 0), else 1.
    #[inline(always)]
    fn tally(&self, fate: u8, class: u8, p: [f32; 3], sums: &mut ClassSums) -> usize {
        if fate != KEEP {
            return 1;
        }
        if let Some(cone) = &self.cone {
            sums[class as usize] += cone.weight(p);
        }
        0
    }

    /// The substeps of the `waiting` particles side by side ([`Kernel::substeps_lanes`]): their
    /// ends and fates written at their indices, tallied; returns how many left.
    #[inline(always)]
    fn resume<const FMA: bool>(
        &self,
        waiting: &[Resume],
        pos: &mut [[f32; 3]],
        class: &[u8],
        fate: &mut [u8],
        sums: &mut ClassSums,
    ) -> usize {
        let ends = self.substeps_lanes::<FMA>(waiting);
        let mut left = 0;
        for (r, (end, f)) in waiting.iter().zip(ends) {
            let e = v4::lanes(end);
            let (Some(p), Some(c), Some(fr)) =
                (pos.get_mut(r.at), class.get(r.at), fate.get_mut(r.at))
            else {
                continue;
            };
            *p = [e[0], e[1], e[2]];
            *fr = f;
            left += self.tally(f, *c, *p, sums);
        }
        left
    }

    /// The slip displacement over the step (grid units) and the slip at its end.
    #[inline(always)]
    fn slip_step(&self, class: u8, w0: [f32; 3]) -> (V4, [f32; 3]) {
        // Slip: w(t) = wt + (w0 - wt) e^(-t/tau), integrated exactly over the step.
        let (wt, e, disp) = self
            .class_step
            .get(class as usize)
            .copied()
            .unwrap_or(([0.0; 3], 0.0, 0.0));
        let (wt, w0) = (v4::new(wt[0], wt[1], wt[2]), v4::new(w0[0], w0[1], w0[2]));
        let dw = lane::sub(w0, wt);
        // wt dt + (w0 - wt) disp and wt + (w0 - wt) e.
        let slip_d = lane::mul_add(dw, lane::splat(disp), lane::mul(wt, lane::splat(self.dt)));
        let w1 = v4::lanes(lane::mul_add(dw, lane::splat(e), wt));
        (slip_d, [w1[0], w1[1], w1[2]])
    }

    /// Substeps of a particle whose fluid velocity at the start is `k1` and whose slip
    /// displacement is `sd`: at most SUBSTEP_CELLS along any axis each, at most `max_sub`.
    #[inline(always)]
    fn substeps(&self, k1: V4, sd: V4) -> u32 {
        let travel = lane::max_abs_sum(lane::mul_add(k1, lane::splat(self.dt), v4::zero()), sd);
        // max/min: a NaN travel takes one substep.
        let x = (travel * (1.0 / SUBSTEP_CELLS))
            .max(1.0)
            .min(self.max_sub as f32);
        // SAFETY: `x` is finite and in [1, max_sub] here.
        unsafe { x.ceil().to_int_unchecked::<u32>() }
    }

    /// GROUP particles that start in fluid cells: the samples, slips and one-substep moves of all
    /// of them first (independent, so they overlap in the CPU). The particles that stay in the
    /// fluid in one substep are done (fate KEEP); the others, which need more substeps or whose
    /// move ended outside a fluid cell, are returned to continue from their start.
    #[inline(always)]
    fn advance_group<const FMA: bool>(
        &self,
        pos: &mut [[f32; 3]; GROUP],
        slip: &mut [[f32; 3]; GROUP],
        class: &[u8; GROUP],
    ) -> [Option<Resume>; GROUP] {
        let field = &self.field;
        let mut p = [v4::zero(); GROUP];
        let mut k1 = [v4::zero(); GROUP];
        let mut sd = [v4::zero(); GROUP];
        let mut w1 = [[0.0f32; 3]; GROUP];
        let mut one = [true; GROUP];
        for l in 0..GROUP {
            p[l] = v4::new(pos[l][0], pos[l][1], pos[l][2]);
            (sd[l], w1[l]) = self.slip_step(class[l], slip[l]);
        }
        for l in 0..GROUP {
            k1[l] = field.sample::<FMA>(p[l]);
        }
        let dt = lane::splat(self.dt);
        let half_dt = lane::splat(0.5 * self.dt);
        let mut q = [v4::zero(); GROUP];
        for l in 0..GROUP {
            one[l] &= self.substeps(k1[l], sd[l]) == 1;
            // The midpoint rule's one substep as in `advance_one` (the same operations).
            let half_sd = lane::mul_add(sd[l], lane::splat(0.5), v4::zero());
            let mid = lane::mul_add(half_dt, k1[l], v4::add(p[l], half_sd));
            q[l] = lane::mul_add(
                dt,
                field.sample::<FMA>(mid),
                v4::add(p[l], lane::mul_add(sd[l], lane::splat(1.0), v4::zero())),
            );
        }
        let mut more = [None; GROUP];
        for l in 0..GROUP {
            slip[l] = w1[l];
            if one[l] && self.kind_at(q[l]) == VoxelKind::Fluid {
                let r = v4::lanes(q[l]);
                pos[l] = [r[0], r[1], r[2]];
            } else {
                // More substeps, or a wall or an outlet: from the start, with the sample taken.
                more[l] = Some(Resume {
                    at: l,
                    p: p[l],
                    k1: k1[l],
                    sd: sd[l],
                });
            }
        }
        more
    }

    /// One particle's step; returns its fate.
    #[inline(always)]
    fn advance_one<const FMA: bool>(
        &self,
        pos: &mut [f32; 3],
        slip: &mut [f32; 3],
        class: u8,
        check: bool,
    ) -> u8 {
        let mut p = v4::new(pos[0], pos[1], pos[2]);
        // A cell that stopped being fluid: leave through an outlet, or move to a fluid
        // neighbour, or be lost.
        if check {
            match self.kind_at(p) {
                VoxelKind::Fluid => {}
                VoxelKind::Outflow => return OUTFLOW,
                VoxelKind::Open => return OPEN,
                _ => match relocate(*pos, &|q| self.kind_at(v4::new(q[0], q[1], q[2]))) {
                    Some(q) => p = v4::new(q[0], q[1], q[2]),
                    None => return LOST,
                },
            }
        }
        let (sdv, w1) = self.slip_step(class, *slip);
        *slip = w1;
        let start = Resume {
            at: 0,
            p,
            k1: self.field.sample::<FMA>(p),
            sd: sdv,
        };
        let [(p, fate), ..] = self.substeps_lanes::<FMA>(&[start]);
        let p = v4::lanes(p);
        *pos = [p[0], p[1], p[2]];
        fate
    }

    /// The substeps of up to GROUP particles side by side (each as if alone: the same operations
    /// in the same order), each starting at `p` (in a fluid cell) with the fluid velocity `k1`
    /// there and the slip displacement `sd` over the step: where each ends and its fate (lanes
    /// past `starts.len()` unused).
    #[inline(always)]
    fn substeps_lanes<const FMA: bool>(&self, starts: &[Resume]) -> [(V4, u8); GROUP] {
        let field = &self.field;
        let n = starts.len().min(GROUP);
        let mut p = [v4::zero(); GROUP];
        let mut k1 = [v4::zero(); GROUP];
        let mut subs = [0u32; GROUP];
        let mut hs = [v4::zero(); GROUP];
        let mut half_hs = [v4::zero(); GROUP];
        let mut sd = [v4::zero(); GROUP];
        let mut half_sd = [v4::zero(); GROUP];
        let mut fate = [KEEP; GROUP];
        for (l, r) in starts[..n].iter().enumerate() {
            (p[l], k1[l]) = (r.p, r.k1);
            subs[l] = self.substeps(r.k1, r.sd);
            let inv = 1.0 / subs[l] as f32;
            hs[l] = lane::splat(self.dt * inv);
            half_hs[l] = lane::splat(0.5 * self.dt * inv);
            sd[l] = lane::mul_add(r.sd, lane::splat(inv), v4::zero());
            half_sd[l] = lane::mul_add(r.sd, lane::splat(0.5 * inv), v4::zero());
        }
        let most = subs[..n].iter().copied().max().unwrap_or(0);
        let mut mid = [v4::zero(); GROUP];
        let mut q = [v4::zero(); GROUP];
        for sub in 0..most {
            let on: [bool; GROUP] = std::array::from_fn(|l| sub < subs[l] && fate[l] == KEEP);
            for l in 0..n {
                if on[l] {
                    if sub > 0 {
                        k1[l] = field.sample::<FMA>(p[l]);
                    }
                    mid[l] = lane::mul_add(half_hs[l], k1[l], v4::add(p[l], half_sd[l]));
                }
            }
            for l in 0..n {
                if on[l] {
                    q[l] = lane::mul_add(hs[l], field.sample::<FMA>(mid[l]), v4::add(p[l], sd[l]));
                }
            }
            for l in 0..n {
                if on[l] {
                    (p[l], fate[l]) = self.land(p[l], q[l]);
                }
            }
        }
        std::array::from_fn(|l| (p[l], fate[l]))
    }

    /// Where the substep `p -> q` of a particle in a fluid cell ends and its fate: at `q` in a
    /// fluid cell, out through an outlet, or slid along a wall ([`Kernel::slide`]).
    #[inline(always)]
    fn land(&self, p: V4, q: V4) -> (V4, u8) {
        match self.kind_at(q) {
            VoxelKind::Fluid => (q, KEEP),
            VoxelKind::Outflow => (p, OUTFLOW),
            VoxelKind::Open => (p, OPEN),
            _ => {
                let (pa, qa) = (v4::lanes(p), v4::lanes(q));
                match self.slide([pa[0], pa[1], pa[2]], [qa[0], qa[1], qa[2]]) {
                    Slide::To(r) => (v4::new(r[0], r[1], r[2]), KEEP),
                    Slide::Leave(f) => (p, f),
                    Slide::Stay => (p, KEEP),
                }
            }
        }
    }
}

/// A particle whose step continues from its start `p` with the fluid velocity `k1` there and the
/// slip displacement `sd` over the step (index `at` in its task).
#[derive(Clone, Copy)]
struct Resume {
    at: usize,
    p: V4,
    k1: V4,
    sd: V4,
}

impl Default for Resume {
    fn default() -> Self {
        Self {
            at: 0,
            p: v4::zero(),
            k1: v4::zero(),
            sd: v4::zero(),
        }
    }
}

/// Where a substep that ended in a wall goes instead.
enum Slide {
    /// Along the axes of the move that stay in the fluid.
    To([f32; 3]),
    /// Through an outlet (the fate).
    Leave(u8),
    /// Nowhere.
    Stay,
}

impl Kernel<'_> {
    /// The move `p -> q` ended in a wall (or the scope, a port, outside the grid): keep as much
    /// of it as lands in the fluid or an outlet. First one axis reverted (the first that works),
    /// then two: a particle pressed into an edge or a corner by a field pointing into both walls
    /// still moves along the one free axis (with one axis only it stayed, and in a frozen field
    /// stayed forever).
    #[inline(always)]
    fn slide(&self, p: [f32; 3], q: [f32; 3]) -> Slide {
        let tries = [
            [false, true, true],
            [true, false, true],
            [true, true, false],
            [true, false, false],
            [false, true, false],
            [false, false, true],
        ];
        for keep in tries {
            let r: [f32; 3] = std::array::from_fn(|a| if keep[a] { q[a] } else { p[a] });
            match self.kind_at(v4::new(r[0], r[1], r[2])) {
                VoxelKind::Fluid => return Slide::To(r),
                VoxelKind::Outflow => return Slide::Leave(OUTFLOW),
                VoxelKind::Open => return Slide::Leave(OPEN),
                _ => {}
            }
        }
        Slide::Stay
    }
}

/// The cell-centred velocity of `cells` (`(cell, lowest x face, lowest y face)`, cells from
/// `offset` on, in `field[cell - offset]`): `half` times the sum over the face fields `sets`
/// (the solver's, plus the overlay's) of the cell's two faces per axis.
#[inline(always)]
fn centre_faces<const S: usize>(
    cells: &[[u32; 3]],
    field: &mut [V4],
    offset: usize,
    sets: [[&[f32]; 3]; S],
    [nx, ny]: [usize; 2],
    half: f32,
) {
    for &[n, a, b] in cells {
        let (n, a, b) = (n as usize, a as usize, b as usize);
        let mut s = [0.0f32; 3];
        for [u, v, w] in sets {
            s[0] += u[a] + u[a + 1];
            s[1] += v[b] + v[b + nx];
            s[2] += w[n] + w[n + nx * ny];
        }
        field[n - offset] = v4::new(s[0] * half, s[1] * half, s[2] * half);
    }
}

/// Moves `p` (grid units) to the centre of a fluid cell among the 26 around its cell.
fn relocate(p: [f32; 3], kind_at: &impl Fn([f32; 3]) -> VoxelKind) -> Option<[f32; 3]> {
    let base = p.map(|x| x.floor() + 0.5);
    let mut best: Option<([f32; 3], f32)> = None;
    for dz in -1..=1 {
        for dy in -1..=1 {
            for dx in -1..=1 {
                let q = [
                    base[0] + dx as f32,
                    base[1] + dy as f32,
                    base[2] + dz as f32,
                ];
                if kind_at(q) == VoxelKind::Fluid {
                    let d = (0..3).map(|a| (q[a] - p[a]).powi(2)).sum::<f32>();
                    if best.is_none_or(|b| d < b.1) {
                        best = Some((q, d));
                    }
                }
            }
        }
    }
    best.map(|b| b.0)
}

/// Result of [`time_to_traverse`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Traverse {
    /// Tracers released.
    pub released: usize,
    /// Tracers that left through the outflow holes within the time limit.
    pub reached: usize,
    /// Tracers that left through the open external os instead.
    pub open: usize,
    /// Time of the first arrival, s.
    pub first_s: Option<f64>,
    /// Time by which half of the released tracers arrived, s.
    pub median_s: Option<f64>,
}

/// Releases one tracer (no slip) at each of `starts_m` (those in a fluid cell) into the solver's current (frozen)
/// velocity and advances them with steps of `dt_s` until all left or `max_time_s`; reports when
/// they leave through [`VoxelKind::Outflow`] cells (the paper's "time to traverse").
pub fn time_to_traverse(
    solver: &FluidSolver,
    kinds: &[VoxelKind],
    starts_m: &[[f64; 3]],
    dt_s: f64,
    max_time_s: f64,
) -> Traverse {
    let mut sys = ParticleSystem::new(solver.grid(), starts_m.len().max(1), 16, [0.0, -1.0, 0.0]);
    let tracer = sys.add_class(ParticleClass {
        kind: ParticleKind::Blood,
        settle_m_s: 0.0,
        tau_s: 0.0,
        shade_m2: 0.0,
        diameter_m: 0.0,
    });
    let mut out = Traverse {
        released: 0,
        reached: 0,
        open: 0,
        first_s: None,
        median_s: None,
    };
    let Some(tracer) = tracer else {
        return out;
    };
    for &p in starts_m {
        if sys.emit(kinds, tracer, p) {
            out.released += 1;
        }
    }
    if out.released == 0 || dt_s.is_nan() || dt_s <= 0.0 {
        return out;
    }
    let mut t = 0.0;
    while t < max_time_s && !sys.is_empty() {
        sys.step(solver, kinds, None, dt_s, None);
        t += dt_s;
        let reached = sys.counts().outflow.iter().sum::<u64>() as usize;
        if reached > 0 && out.first_s.is_none() {
            out.first_s = Some(t);
        }
        if 2 * reached >= out.released && out.median_s.is_none() {
            out.median_s = Some(t);
        }
        out.reached = reached;
        out.open = sys.counts().open.iter().sum::<u64>() as usize;
    }
    out
}

/// A bleeding source placed on the cavity surface.
#[derive(Debug, Clone)]
struct Source {
    spec: BleedingSourceSpec,
    vertex: usize,
    /// Triangles around the vertex (for its normal).
    ring: Vec<u32>,
    /// Particles owed (fractional emission).
    owed: f64,
}

/// The particle stage of a scene.
#[derive(Debug, Clone, Default)]
pub struct Particles {
    spec: ParticleSpec,
    system: Option<ParticleSystem>,
    rng: Option<SeededRng>,
    sources: Vec<Source>,
    fragments_done: Vec<bool>,
    bubble_owed: f64,
    /// Class indices: blood, the bubble classes, then one per fragment release.
    blood_class: u8,
    bubble_class0: u8,
    fragment_class0: u8,
    emit_points: Vec<[f64; 3]>,
    clarity: Option<f64>,
    tracker: ClarityTracker,
}

impl Particles {
    /// The stage for a scene's `[particles]` table.
    pub fn new(spec: ParticleSpec) -> Self {
        let tracker = ClarityTracker::new(spec.view.clear_threshold);
        Self {
            spec,
            tracker,
            ..Self::default()
        }
    }
    /// The particles, once the stage has run.
    pub fn system(&self) -> Option<&ParticleSystem> {
        self.system.as_ref()
    }
    /// The clarity of the scope's view after the last step (1 clear, 0 opaque); `None` without a
    /// scope.
    pub fn clarity(&self) -> Option<f64> {
        self.clarity
    }
    /// The clarity's history: time obscured, time to clear after the last bleed.
    pub fn tracker(&self) -> &ClarityTracker {
        &self.tracker
    }
    /// The particles as VTK PolyData (a document with no points before the first step).
    pub fn vtp_string(&self) -> String {
        particles_xml(self.system.as_ref(), VtkFlavour::PolyData)
    }
    /// The particles as a VTK UnstructuredGrid of vertex cells (no points before the first
    /// step); what `hydrometra scene run` writes into its ParaView series.
    pub fn vtu_string(&self) -> String {
        particles_xml(self.system.as_ref(), VtkFlavour::UnstructuredGrid)
    }

    fn init(&mut self, scene: &Scene) -> Option<()> {
        let solver = scene.fluid.as_ref()?;
        let spec = &self.spec;
        let g = spec.gravity.unit().ok()?;
        let mut sys = ParticleSystem::new(solver.grid(), spec.budget, spec.max_substeps, g);
        let (rf, mu) = (spec.fluid_density_kg_m3, spec.fluid_viscosity_pa_s);
        let b = &spec.blood;
        let d = b.droplet_diameter_mm * 1e-3;
        let (settle, tau) = terminal_slip(d, b.density_kg_m3, rf, mu);
        self.blood_class = sys.add_class(ParticleClass {
            kind: ParticleKind::Blood,
            settle_m_s: settle,
            tau_s: tau,
            shade_m2: b.attenuation_per_mm * 1e3 * b.particle_volume_ul * 1e-9,
            diameter_m: d,
        })?;
        let bs = &spec.bubbles;
        for c in 0..BUBBLE_CLASSES {
            let f = (c as f64 + 0.5) / BUBBLE_CLASSES as f64;
            let d = (bs.min_diameter_mm + f * (bs.max_diameter_mm - bs.min_diameter_mm)) * 1e-3;
            let (settle, tau) = terminal_slip(d, bs.density_kg_m3, rf, mu);
            let idx = sys.add_class(ParticleClass {
                kind: ParticleKind::Bubble,
                settle_m_s: settle,
                tau_s: tau,
                shade_m2: std::f64::consts::PI / 4.0 * d * d,
                diameter_m: d,
            })?;
            if c == 0 {
                self.bubble_class0 = idx;
            }
        }
        self.fragment_class0 = sys.classes().len() as u8;
        for f in &spec.fragments {
            let d = f.diameter_mm * 1e-3;
            let (settle, tau) = terminal_slip(d, f.density_kg_m3, rf, mu);
            sys.add_class(ParticleClass {
                kind: ParticleKind::Fragment,
                settle_m_s: settle,
                tau_s: tau,
                shade_m2: std::f64::consts::PI / 4.0 * d * d,
                diameter_m: d,
            })?;
        }
        self.fragments_done = vec![false; spec.fragments.len()];
        // Sources: the nearest surface vertex (not on the os's cap) and its triangle ring.
        let cav = scene.cavity();
        let first_cap = cav.triangles.len().saturating_sub(cav.cap_triangles);
        let mut on_wall = vec![false; cav.positions_m.len()];
        for t in &cav.triangles[..first_cap] {
            for &v in t {
                if let Some(w) = on_wall.get_mut(v as usize) {
                    *w = true;
                }
            }
        }
        self.sources.clear();
        for s in &spec.blood.sources {
            let p = s.position_mm.map(|v| v * 1e-3);
            let mut best = (f64::INFINITY, usize::MAX);
            for (i, q) in cav.positions_m.iter().enumerate() {
                if !on_wall[i] {
                    continue;
                }
                let d2 = (0..3).map(|a| (q[a] as f64 - p[a]).powi(2)).sum::<f64>();
                if d2 < best.0 {
                    best = (d2, i);
                }
            }
            if best.1 == usize::MAX {
                continue;
            }
            let ring = cav.triangles[..first_cap]
                .iter()
                .enumerate()
                .filter(|(_, t)| t.contains(&(best.1 as u32)))
                .map(|(i, _)| i as u32)
                .collect();
            self.sources.push(Source {
                spec: s.clone(),
                vertex: best.1,
                ring,
                owed: 0.0,
            });
        }
        self.rng = Some(SeededRng::new(spec.seed));
        sys.seed_walk(spec.seed ^ WALK_STREAM);
        self.emit_points = Vec::with_capacity(64);
        self.system = Some(sys);
        Some(())
    }

    /// Whether the scene can ever emit (sources, bubbles or fragments configured).
    fn has_sources(&self) -> bool {
        !self.spec.blood.sources.is_empty()
            || self.spec.bubbles.per_ml > 0.0
            || !self.spec.fragments.is_empty()
    }

    /// Advances the particles after the fluid (and vortex) step; returns whether the stage ran
    /// (skipped when the scene has no source and no particle is alive).
    pub(crate) fn step(&mut self, scene: &Scene, dt_s: f64) -> bool {
        let alive = self.system.as_ref().is_some_and(|s| !s.is_empty());
        if !self.has_sources() && !alive {
            return false;
        }
        let Some(solver) = scene.fluid.as_ref() else {
            return false;
        };
        if self.system.is_none() && self.init(scene).is_none() {
            return false;
        }
        let t = scene.report.time_s;
        self.emit_blood(scene, t, dt_s);
        self.emit_bubbles(scene, dt_s);
        self.emit_fragments(scene, t);
        let overlay = scene.vortices.as_ref().and_then(|v| v.overlay_faces());
        let view = scene
            .scope()
            .map(|sc| self.spec.view.cone(sc.tip_m, sc.dir));
        let Some(sys) = self.system.as_mut() else {
            return false;
        };
        sys.set_eddy_diffusivity(if self.spec.eddy_dispersion {
            dispersion::jet_eddy_diffusivity_m2_s(
                scene.hydraulic_state.flows.inflow_m3_per_s,
                scene.desc.scope.inflow_channel_area_mm2 * 1e-6,
            )
        } else {
            0.0
        });
        self.clarity = sys.step(solver, &scene.kinds, overlay, dt_s, view.as_ref());
        let bleed_end = self
            .spec
            .blood
            .sources
            .iter()
            .map(|s| s.onset_s + s.duration_s)
            .fold(f64::NEG_INFINITY, f64::max);
        if let Some(c) = self.clarity {
            self.tracker
                .update(t, c, bleed_end.is_finite().then_some(bleed_end));
        }
        true
    }

    fn emit_blood(&mut self, scene: &Scene, t: f64, dt_s: f64) {
        let (Some(sys), Some(rng)) = (self.system.as_mut(), self.rng.as_mut()) else {
            return;
        };
        let cav = scene.cavity();
        let h = scene.cells.spacing_m;
        let vol = self.spec.blood.particle_volume_ul * 1e-9;
        for s in &mut self.sources {
            let (rate, radius, jet) = s.spec.at(t);
            s.owed += rate * dt_s / vol;
            let count = s.owed.floor();
            s.owed -= count;
            if count <= 0.0 {
                continue;
            }
            let Some(v) = cav.positions_m.get(s.vertex) else {
                continue;
            };
            let v = v.map(|x| x as f64);
            let mut n = [0.0; 3];
            for &ti in &s.ring {
                let [a, b, c] = cav.triangles[ti as usize].map(|i| cav.positions_m[i as usize]);
                let e1: [f64; 3] = std::array::from_fn(|k| (b[k] - a[k]) as f64);
                let e2: [f64; 3] = std::array::from_fn(|k| (c[k] - a[k]) as f64);
                let x = [
                    e1[1] * e2[2] - e1[2] * e2[1],
                    e1[2] * e2[0] - e1[0] * e2[2],
                    e1[0] * e2[1] - e1[1] * e2[0],
                ];
                for k in 0..3 {
                    n[k] += x[k];
                }
            }
            let m = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            if m.is_nan() || m <= 0.0 {
                continue;
            }
            let mut n = n.map(|x| x / m);
            // Into the fluid: the side where a point two cells off the wall is fluid.
            let probe = |n: [f64; 3]| {
                let q: [f64; 3] = std::array::from_fn(|k| v[k] + 2.0 * h * n[k]);
                kind_at_m(scene, q) == VoxelKind::Fluid
            };
            if !probe(n) && probe(n.map(|x| -x)) {
                n = n.map(|x| -x);
            }
            // A tangent basis.
            let a = if n[0].abs() < 0.9 {
                [1.0, 0.0, 0.0]
            } else {
                [0.0, 1.0, 0.0]
            };
            let t1 = unit(cross(n, a));
            let t2 = cross(n, t1);
            for _ in 0..count as usize {
                let r = radius * rng.unit().sqrt();
                let phi = rng.range(0.0, std::f64::consts::TAU);
                let d = 0.75 * h + jet * rng.unit();
                let mut placed = false;
                for lift in 0..4 {
                    let along = d + lift as f64 * 0.5 * h;
                    let p: [f64; 3] = std::array::from_fn(|k| {
                        v[k] + r * (phi.cos() * t1[k] + phi.sin() * t2[k]) + along * n[k]
                    });
                    if kind_at_m(scene, p) == VoxelKind::Fluid {
                        placed = sys.emit(&scene.kinds, self.blood_class, p);
                        break;
                    }
                }
                if !placed {
                    sys.counts.rejected += 1;
                }
            }
        }
    }

    fn emit_bubbles(&mut self, scene: &Scene, dt_s: f64) {
        let per_ml = self.spec.bubbles.per_ml;
        if per_ml <= 0.0 {
            return;
        }
        let q_ml = scene.hydraulic_state.flows.inflow_m3_per_s * 1e6 * dt_s;
        self.bubble_owed += per_ml * q_ml.max(0.0);
        let count = self.bubble_owed.floor();
        if count <= 0.0 {
            return;
        }
        self.bubble_owed -= count;
        // The fluid cells next to the inflow port.
        self.emit_points.clear();
        inflow_neighbours(scene, &mut self.emit_points);
        let c = &scene.cells;
        let (Some(sys), Some(rng)) = (self.system.as_mut(), self.rng.as_mut()) else {
            return;
        };
        if self.emit_points.is_empty() {
            sys.counts.rejected += count as u64;
            return;
        }
        let h = c.spacing_m;
        for _ in 0..count as usize {
            let p = self.emit_points[rng.below(self.emit_points.len())];
            let p: [f64; 3] = std::array::from_fn(|a| p[a] + rng.range(-0.45, 0.45) * h);
            let class = self.bubble_class0 + rng.below(BUBBLE_CLASSES) as u8;
            sys.emit(&scene.kinds, class, p);
        }
    }

    fn emit_fragments(&mut self, scene: &Scene, t: f64) {
        let (Some(sys), Some(rng)) = (self.system.as_mut(), self.rng.as_mut()) else {
            return;
        };
        for (i, f) in self.spec.fragments.iter().enumerate() {
            if self.fragments_done[i] || t < f.time_s {
                continue;
            }
            self.fragments_done[i] = true;
            let class = self.fragment_class0 + i as u8;
            for _ in 0..f.count {
                let d = rng.direction();
                let r = f.spread_mm * 1e-3 * rng.unit().cbrt();
                let p: [f64; 3] = std::array::from_fn(|a| f.position_mm[a] * 1e-3 + r * d[a]);
                sys.emit(&scene.kinds, class, p);
            }
        }
    }

    /// The paper's "time to traverse" in the scene's current flow: a cloud of tracers spread
    /// evenly over the inflow port's fluid-facing area (see [`inflow_face_points`] and
    /// [`time_to_traverse`]).
    pub fn time_to_traverse(scene: &Scene, dt_s: f64, max_time_s: f64) -> Option<Traverse> {
        let solver = scene.fluid.as_ref()?;
        let per_face = TRAVERSE_SUBGRID * TRAVERSE_SUBGRID;
        let mut starts = Vec::with_capacity(scene.inflow.len() * 6 * per_face);
        inflow_face_points(scene, TRAVERSE_SUBGRID, &mut starts);
        Some(time_to_traverse(
            solver,
            &scene.kinds,
            &starts,
            dt_s,
            max_time_s,
        ))
    }
}

/// Tracers of the time to traverse per inflow face and side: a regular 4 x 4 sub-grid.
pub const TRAVERSE_SUBGRID: usize = 4;
/// How far into the fluid the tracers start from the port's face, voxels.
pub const TRAVERSE_OFFSET_VOXELS: f64 = 0.25;

/// Calls `f` with the cell `(i, j, k)` of every inflow port cell and each of its faces
/// (0..6, [`super::ports::FACE_NORMALS`]) that borders fluid.
fn for_each_inflow_face(scene: &Scene, mut f: impl FnMut([usize; 3], usize)) {
    let [nx, ny, _] = scene.cells.dims;
    for b in &scene.inflow {
        let n = b.cell as usize;
        let ijk = [n % nx, (n / nx) % ny, n / (nx * ny)];
        for face in 0..6 {
            if b.faces >> face & 1 == 1 {
                f(ijk, face);
            }
        }
    }
}

/// Centres of the cells next to the inflow port's fluid faces, appended to `out` up to its
/// capacity (no allocation).
fn inflow_neighbours(scene: &Scene, out: &mut Vec<[f64; 3]>) {
    let c = &scene.cells;
    for_each_inflow_face(scene, |ijk, f| {
        let mut q = ijk.map(|x| x as i64);
        q[f / 2] += if f % 2 == 1 { 1 } else { -1 };
        if q.iter()
            .zip(c.dims)
            .all(|(&x, d)| x >= 0 && (x as usize) < d)
            && out.len() < out.capacity()
        {
            out.push(c.centre_m(q[0] as usize, q[1] as usize, q[2] as usize));
        }
    });
}

/// Points spread over the inflow port's fluid-facing area: on every fluid face of a port cell
/// that the inflow crosses (`d . n > 0`, `d` the scope's direction; the others carry no flux), a
/// regular `side` x `side` sub-grid (the centres of the face's sub-squares), moved
/// [`TRAVERSE_OFFSET_VOXELS`] into the fluid cell; appended to `out` up to its capacity.
/// Deterministic, and as many points per face at every voxel size, so each face (the same
/// area in voxels) carries the same weight.
pub fn inflow_face_points(scene: &Scene, side: usize, out: &mut Vec<[f64; 3]>) {
    let c = &scene.cells;
    let h = c.spacing_m;
    let Some(dir) = scene.scope().map(|sc| sc.dir) else {
        return;
    };
    for_each_inflow_face(scene, |[i, j, k], f| {
        let n = super::ports::FACE_NORMALS[f];
        if dir[0] * n[0] + dir[1] * n[1] + dir[2] * n[2] <= 0.0 {
            return;
        }
        let centre = c.centre_m(i, j, k);
        let axis = f / 2;
        let sign = if f % 2 == 1 { 1.0 } else { -1.0 };
        let (t1, t2) = ((axis + 1) % 3, (axis + 2) % 3);
        for a in 0..side {
            for b in 0..side {
                if out.len() >= out.capacity() {
                    return;
                }
                let mut p = centre;
                p[axis] += sign * (0.5 + TRAVERSE_OFFSET_VOXELS) * h;
                p[t1] += ((a as f64 + 0.5) / side as f64 - 0.5) * h;
                p[t2] += ((b as f64 + 0.5) / side as f64 - 0.5) * h;
                out.push(p);
            }
        }
    });
}

fn kind_at_m(scene: &Scene, p: [f64; 3]) -> VoxelKind {
    let c = &scene.cells;
    let mut idx = [0usize; 3];
    for a in 0..3 {
        let x = (p[a] - c.origin_m[a]) / c.spacing_m;
        if !(x >= 0.0 && x < c.dims[a] as f64) {
            return VoxelKind::Solid;
        }
        idx[a] = x as usize;
    }
    scene.kinds[c.index(idx[0], idx[1], idx[2])]
}

/// The first particle from `from` on whose fate is not KEEP (eight fates a comparison).
fn next_left(fate: &[u8], from: usize) -> Option<usize> {
    let rest = fate.get(from..)?;
    let mut words = rest.chunks_exact(8);
    let mut skipped = 0;
    for w in words.by_ref() {
        if w.iter().any(|&f| f != KEEP) {
            break;
        }
        skipped += 8;
    }
    rest[skipped..]
        .iter()
        .position(|&f| f != KEEP)
        .map(|k| from + skipped + k)
}

/// The kinds as bytes (one comparison of memory when the field checks whether they changed).
fn kind_bytes(kinds: &[VoxelKind]) -> &[u8] {
    // SAFETY: `VoxelKind` is `repr(u8)`, so a slice of them is a slice of initialised bytes of
    // the same length.
    unsafe { std::slice::from_raw_parts(kinds.as_ptr().cast::<u8>(), kinds.len()) }
}

fn unit(a: [f64; 3]) -> [f64; 3] {
    let m = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
    if m > 0.0 {
        a.map(|x| x / m)
    } else {
        a
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fluid::FluidParams;

    /// The grouped kernels (particles that start in fluid, eight at a time on AVX2, else four at
    /// a time, the one-substep case together) move every particle bit for bit as the
    /// one-at-a-time path.
    #[test]
    fn grouped_particles_move_exactly_as_one_at_a_time() {
        let (n, h) = (16, 1e-3);
        let grid = FluidGrid::new([n, n, n], h, [0.0; 3], [false; 3]).unwrap();
        let mut s = FluidSolver::new(grid, FluidParams::default()).unwrap();
        // A swirl fast enough near its rim for several substeps, and a wall block to slide on.
        s.set_velocity_field(|c, p| match c {
            0 => -12.0 * (p[1] - 0.008),
            1 => 12.0 * (p[0] - 0.008),
            _ => 0.05,
        });
        let mut kinds = vec![VoxelKind::Fluid; n * n * n];
        for k in 0..n {
            for j in 10..14 {
                for i in 10..14 {
                    kinds[i + n * (j + n * k)] = VoxelKind::Wall;
                }
            }
        }
        let mut sys = ParticleSystem::new(s.grid(), 4000, 8, [0.0, -1.0, 0.0]);
        let cls = sys
            .add_class(ParticleClass {
                kind: ParticleKind::Blood,
                settle_m_s: 3e-3,
                tau_s: 2e-3,
                shade_m2: 0.0,
                diameter_m: 0.0,
            })
            .unwrap();
        let mut rng = fastrand::Rng::with_seed(5);
        // Blocks of eight, then a group of four and one particle alone (3005 = 375 x 8 + 4 + 1).
        while sys.len() < 3005 {
            let p = [0, 1, 2].map(|_| rng.f64() * n as f64 * h);
            sys.emit(&kinds, cls, p);
        }
        for v in &mut sys.slip {
            *v = [0, 1, 2].map(|_| rng.f32() - 0.5);
        }
        // One step to build the field and the per-class factors.
        sys.step(&s, &kinds, None, 1.0 / 60.0, None);
        let dt = 1.0 / 60.0;
        let run = |check_from: usize| {
            let k = Kernel::new(
                Sampler::new(&sys.field, sys.dims),
                &kinds,
                &sys.class_step,
                check_from,
                sys.max_substeps,
                dt,
                None,
            );
            let (mut pos, mut slip) = (sys.pos.clone(), sys.slip.clone());
            let mut fate = vec![KEEP; pos.len()];
            let mut sums = [0.0; 256];
            let task = Task {
                offset: 0,
                pos: &mut pos,
                slip: &mut slip,
                class: &sys.class,
                fate: &mut fate,
            };
            let left = k.run(task, &mut sums);
            (pos, slip, fate, left)
        };
        // From 0: every start checked, one at a time; from the end: all grouped.
        let (one, grouped) = (run(0), run(usize::MAX));
        let bits = |v: &[[f32; 3]]| v.iter().flatten().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&one.0), bits(&grouped.0));
        assert_eq!(bits(&one.1), bits(&grouped.1));
        assert_eq!((&one.2, one.3), (&grouped.2, grouped.3));
        // The case mix the comparison covers: particles that moved more than a cell (several
        // substeps) and particles that moved less.
        let far = one
            .0
            .iter()
            .zip(&sys.pos)
            .filter(|(a, b)| (0..3).any(|c| (a[c] - b[c]).abs() > 1.0))
            .count();
        assert!(far > 100 && far < 2900, "{far} of 3005 moved over a cell");
    }
}
