//! The `[particles]` table of a scene: budget, gravity, blood and its bleeding sources, bubbles,
//! fragment releases, the clarity's view (`docs/particles.md` lists every key).

use serde::{Deserialize, Serialize};

use crate::scene::clarity::ViewSpec;

/// Bubble size classes (diameters spread evenly over the configured range).
pub(super) const BUBBLE_CLASSES: usize = 8;

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
    /// Whether the scene can ever emit (sources, bubbles or fragments configured).
    pub fn emits(&self) -> bool {
        !self.blood.sources.is_empty() || self.bubbles.per_ml > 0.0 || !self.fragments.is_empty()
    }

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
