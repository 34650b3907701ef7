//! The scene description: one TOML file (or a built-in name) that says which uterus, material,
//! atlas, hydraulics, hysteroscope, fluid grid and stages a simulation runs. Specified in
//! `docs/scene.md`; unknown keys are errors naming the key.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::particles::ParticleSpec;
use super::vortices::VortexSpec;
use super::SceneError;
use crate::anatomy::AnatomyParams;
use crate::fem::material::MaterialSet;
use crate::fem::Element;
use crate::fluid::AdvectionScheme;
use crate::hydraulics::HydraulicParams;

/// The built-in scenes: name and TOML text.
pub const BUILTIN_SCENES: [(&str, &str); 3] = [
    ("default", include_str!("scenes/default.toml")),
    ("myoma-figo1", include_str!("scenes/myoma-figo1.toml")),
    ("bleed", include_str!("scenes/bleed.toml")),
];

/// The commented default scene file (`hydrometra scene print-default`).
pub const DEFAULT_SCENE_TOML: &str = BUILTIN_SCENES[0].1;

/// How the deformation atlas is obtained.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AtlasSpec {
    /// A precomputed atlas file (`hydrometra precompute`); relative to the scene file.
    pub file: Option<PathBuf>,
    /// Highest pressure of the sweep, mmHg.
    pub max_mmhg: f64,
    /// Levels from 0 to `max_mmhg`, both included.
    pub levels: usize,
    /// Finite element of the sweep: `tet4` (fast) or `tet10` (accurate reference).
    pub element: String,
}

impl Default for AtlasSpec {
    fn default() -> Self {
        Self {
            file: None,
            max_mmhg: 150.0,
            levels: 25,
            element: "tet4".into(),
        }
    }
}

/// The hysteroscope: a continuous-flow sheath.
///
/// Defaults: a 5 mm office hysteroscope of the continuous-flow (Bettocchi) type: outer sheath
/// 5.0 mm, inflow through the inner sheath's channel at the tip, outflow through holes in the outer
/// sheath a few mm behind the tip. The channel and hole areas are the hydraulics' port areas
/// (2.8 mm^2 each, 2 m/s at ~340 ml/min; `docs/hydraulics.md`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ScopeSpec {
    /// Outer diameter of the sheath, mm.
    pub sheath_outer_diameter_mm: f64,
    /// Cross-section of the inflow channel at the tip, mm^2.
    pub inflow_channel_area_mm2: f64,
    /// Total open area of the outflow holes, mm^2.
    pub outflow_holes_area_mm2: f64,
    /// The band of the sheath, measured back from the tip, that carries the outflow holes, mm.
    pub outflow_holes_from_tip_mm: [f64; 2],
}

impl Default for ScopeSpec {
    fn default() -> Self {
        Self {
            sheath_outer_diameter_mm: 5.0,
            inflow_channel_area_mm2: 2.8,
            outflow_holes_area_mm2: 2.8,
            outflow_holes_from_tip_mm: [3.0, 12.0],
        }
    }
}

/// The fluid grid and solver options.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FluidSpec {
    /// Voxel (cell) edge, mm.
    pub voxel_mm: f64,
    /// Lower corner of the region of interest in the organ frame, mm (none: the whole cavity).
    pub roi_min_mm: Option<[f64; 3]>,
    /// Upper corner of the region of interest in the organ frame, mm.
    pub roi_max_mm: Option<[f64; 3]>,
    /// Advection scheme of the fluid solver.
    pub advection: AdvectionScheme,
    /// Projection tolerance, max |div u| h / U.
    pub divergence_tolerance: f64,
    /// Below this many fluid cells (the resting slit) the fluid stage idles.
    pub min_fluid_cells: usize,
    /// Largest CFL number of one fluid substep: a frame whose fastest face (the inflow jet) would
    /// travel farther is split into substeps (at most the solver's `max_substeps`); `inf`: one
    /// fluid step per frame whatever the CFL number.
    pub max_cfl: f64,
    /// Cut cells: the fluid fills the cavity surface exactly (each cell's fluid volume fraction
    /// and each face's open area fraction from the surface, `crate::cutcell`) instead of the
    /// whole cells entirely inside it. Off: the conservative voxelization of before.
    pub cut_cells: bool,
}

/// The scene's default CFL bound of a fluid substep: a semi-Lagrangian trace of at most five
/// cells (Foster and Fedkiw 2001, as recommended by Bridson, *Fluid Simulation for Computer
/// Graphics*, section 3.2). Longer traces leave the 1-2 cell wide inflow jet through the scope's
/// walls and lose its momentum within a few millimetres of the port (`docs/particles.md`, "View
/// clarity").
pub const DEFAULT_MAX_CFL: f64 = 5.0;

impl Default for FluidSpec {
    fn default() -> Self {
        Self {
            voxel_mm: 1.2,
            roi_min_mm: None,
            roi_max_mm: None,
            advection: AdvectionScheme::default(),
            divergence_tolerance: 1e-5,
            min_fluid_cells: 64,
            max_cfl: DEFAULT_MAX_CFL,
            cut_cells: true,
        }
    }
}

/// Which optional stages exist. Hydraulics, deformation and voxelization always exist.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StagesSpec {
    /// The fluid solver (and with it the ports).
    pub fluid: bool,
    /// Rankine vortices on top of the fluid.
    pub vortices: bool,
    /// Blood, bubble and fragment particles.
    pub particles: bool,
}

impl Default for StagesSpec {
    fn default() -> Self {
        Self {
            fluid: true,
            vortices: false,
            particles: false,
        }
    }
}

/// When a stage may be skipped.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SkipSpec {
    /// The deformation is replayed only when the cavity pressure moved more than this, Pa.
    pub pressure_tolerance_pa: f64,
    /// The cavity is re-voxelized only where a vertex moved more than this fraction of a voxel
    /// (whole cells).
    pub voxel_move_fraction: f64,
    /// With cut cells, the fractions (and the cell states) follow a surface vertex only once it
    /// moved more than this fraction of a voxel since they last did (0: every move). Every vertex
    /// of the surface they are computed from is then within this many voxels of the deformed
    /// surface's, so their volume is within `cut_move_fraction h A` of its (A: its area). A
    /// moved vertex is held a little beyond its position along its move
    /// ([`crate::scene::CUT_LEAD`]), so the held surface straddles the deformed one.
    pub cut_move_fraction: f64,
    /// The scope is re-rasterized only when its tip (or the far end of its part in the grid)
    /// moved more than this fraction of a voxel: its cells follow the centre rule, so a smaller
    /// move changes at most a boundary cell, and every change costs a topology rebuild.
    pub scope_move_fraction: f64,
    /// The fluid step is skipped when no port or wall moves fluid and every face is slower than
    /// this, m/s.
    pub rest_speed_m_s: f64,
}

impl Default for SkipSpec {
    fn default() -> Self {
        Self {
            pressure_tolerance_pa: 1.0,
            voxel_move_fraction: 0.1,
            cut_move_fraction: 0.01,
            scope_move_fraction: 0.5,
            rest_speed_m_s: 1e-4,
        }
    }
}

/// The raw file, before the anatomy, material and hydraulics tables are handed to their parsers.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawScene {
    name: Option<String>,
    anatomy_file: Option<PathBuf>,
    anatomy: Option<toml::Table>,
    material_file: Option<PathBuf>,
    material: Option<toml::Table>,
    #[serde(default)]
    atlas: AtlasSpec,
    #[serde(default)]
    scope: ScopeSpec,
    #[serde(default)]
    fluid: FluidSpec,
    #[serde(default)]
    stages: StagesSpec,
    #[serde(default)]
    skip: SkipSpec,
    #[serde(default)]
    vortices: VortexSpec,
    #[serde(default)]
    particles: ParticleSpec,
    hydraulics: Option<toml::Table>,
}

/// A parsed, validated scene description.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneDesc {
    /// The scene's name (the built-in name, or the file's `name`, or its file stem).
    pub name: String,
    /// Where it came from (a built-in name or the file path), for messages.
    pub origin: String,
    /// The uterus.
    pub anatomy: AnatomyParams,
    /// The tissue.
    pub material: MaterialSet,
    /// The deformation atlas.
    pub atlas: AtlasSpec,
    /// The atlas's finite element, parsed from `atlas.element`.
    pub element: Element,
    /// The lumped hydraulics, with the port areas of the scope.
    pub hydraulics: HydraulicParams,
    /// The hysteroscope.
    pub scope: ScopeSpec,
    /// The fluid grid.
    pub fluid: FluidSpec,
    /// Which stages exist.
    pub stages: StagesSpec,
    /// Skip tolerances.
    pub skip: SkipSpec,
    /// The vortex stage (`docs/particles.md`).
    pub vortices: VortexSpec,
    /// The particle stage (`docs/particles.md`).
    pub particles: ParticleSpec,
}

impl Default for SceneDesc {
    fn default() -> Self {
        // ok: the built-in default is parsed in a test.
        Self::builtin("default").unwrap_or_else(|e| unreachable!("built-in default scene: {e}"))
    }
}

fn invalid_message(origin: &str, message: String) -> SceneError {
    SceneError::Description {
        origin: origin.to_string(),
        message,
    }
}

fn invalid(origin: &str, key: &str, message: impl std::fmt::Display) -> SceneError {
    SceneError::Description {
        origin: origin.to_string(),
        message: format!("`{key}`: {message}"),
    }
}

impl SceneDesc {
    /// A built-in scene by name (see [`BUILTIN_SCENES`]).
    pub fn builtin(name: &str) -> Result<Self, SceneError> {
        let text = BUILTIN_SCENES
            .iter()
            .find(|(n, _)| *n == name)
            .map(|(_, t)| *t)
            .ok_or_else(|| SceneError::UnknownScene {
                name: name.to_string(),
                known: BUILTIN_SCENES.iter().map(|(n, _)| *n).collect(),
            })?;
        Self::parse(text, &format!("<built-in scene {name}>"), None)
    }

    /// A built-in name or a scene file. The rule (one for every tool): a value that names an
    /// existing file, or contains a `/` or ends in `.toml`, is a file; anything else is a built-in
    /// name.
    pub fn load(name_or_path: &str) -> Result<Self, SceneError> {
        let path = Path::new(name_or_path);
        let is_file =
            path.is_file() || name_or_path.contains('/') || name_or_path.ends_with(".toml");
        if is_file {
            Self::from_file(path)
        } else {
            Self::builtin(name_or_path)
        }
    }

    /// Reads a scene file; relative paths inside it are relative to its directory.
    pub fn from_file(path: &Path) -> Result<Self, SceneError> {
        let text = std::fs::read_to_string(path).map_err(|source| SceneError::Io {
            path: path.display().to_string(),
            source,
        })?;
        let mut desc = Self::parse(&text, &path.display().to_string(), path.parent())?;
        if desc.name.is_empty() {
            desc.name = path
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
        }
        Ok(desc)
    }

    /// Parses scene TOML; `origin` names it in errors, `base` resolves relative file paths.
    pub fn parse(text: &str, origin: &str, base: Option<&Path>) -> Result<Self, SceneError> {
        let raw: RawScene = toml::from_str(text).map_err(|e| SceneError::Description {
            origin: origin.to_string(),
            message: e.to_string(),
        })?;
        let resolve = |p: &Path| match base {
            Some(b) if p.is_relative() => b.join(p),
            _ => p.to_path_buf(),
        };
        let read = |p: &Path, key: &str| {
            let p = resolve(p);
            std::fs::read_to_string(&p)
                .map(|t| (t, p.display().to_string()))
                .map_err(|e| invalid(origin, key, format!("{}: {e}", p.display())))
        };

        let anatomy = match (&raw.anatomy_file, &raw.anatomy) {
            (Some(_), Some(_)) => {
                return Err(invalid(
                    origin,
                    "anatomy_file",
                    "give either `anatomy_file` or an [anatomy] table, not both",
                ))
            }
            (Some(p), None) => {
                let (t, o) = read(p, "anatomy_file")?;
                AnatomyParams::from_toml_str(&t).map_err(|e| invalid(origin, &o, e))?
            }
            (None, Some(table)) => AnatomyParams::from_toml_str(&table.to_string())
                .map_err(|e| invalid(origin, "anatomy", e))?,
            (None, None) => AnatomyParams::default(),
        };
        let material = match (&raw.material_file, &raw.material) {
            (Some(_), Some(_)) => {
                return Err(invalid(
                    origin,
                    "material_file",
                    "give either `material_file` or a [material] table, not both",
                ))
            }
            (Some(p), None) => {
                let (t, o) = read(p, "material_file")?;
                MaterialSet::from_toml_str(&t, &o)
                    .map_err(|e| invalid(origin, "material_file", e))?
            }
            (None, Some(table)) => MaterialSet::from_toml_str(&table.to_string(), "[material]")
                .map_err(|e| invalid(origin, "material", e))?,
            (None, None) => {
                MaterialSet::default_uterus().map_err(|e| invalid(origin, "material", e))?
            }
        };

        let mut hydraulics_table = raw.hydraulics.clone().unwrap_or_default();
        for line in ["inflow", "outflow"] {
            if let Some(toml::Value::Table(t)) = hydraulics_table.get(line) {
                if t.contains_key("port_area_mm2") {
                    return Err(invalid(
                        origin,
                        &format!("hydraulics.{line}.port_area_mm2"),
                        "the port areas are the scope's: set [scope] inflow_channel_area_mm2 / \
                         outflow_holes_area_mm2 instead",
                    ));
                }
            }
        }
        let scope = raw.scope;
        let mut set_area = |line: &str, area: f64| {
            let entry = hydraulics_table
                .entry(line.to_string())
                .or_insert_with(|| toml::Value::Table(toml::Table::new()));
            if let toml::Value::Table(t) = entry {
                t.insert("port_area_mm2".into(), toml::Value::Float(area));
            }
        };
        set_area("inflow", scope.inflow_channel_area_mm2);
        set_area("outflow", scope.outflow_holes_area_mm2);
        let hydraulics =
            HydraulicParams::from_toml_str(&hydraulics_table.to_string(), "[hydraulics]")
                .map_err(|e| invalid(origin, "hydraulics", e))?;

        let element: Element = raw
            .atlas
            .element
            .parse()
            .map_err(|e| invalid(origin, "atlas.element", e))?;
        let desc = SceneDesc {
            name: raw.name.unwrap_or_default(),
            origin: origin.to_string(),
            anatomy,
            material,
            atlas: AtlasSpec {
                file: raw.atlas.file.as_deref().map(resolve),
                ..raw.atlas
            },
            element,
            hydraulics,
            scope,
            fluid: raw.fluid,
            stages: raw.stages,
            skip: raw.skip,
            vortices: raw.vortices,
            particles: raw.particles,
        };
        desc.validate()?;
        Ok(desc)
    }

    /// Checks every range, naming the key.
    pub fn validate(&self) -> Result<(), SceneError> {
        let o = &self.origin;
        let positive = |key: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(invalid(o, key, format!("{v}: expected a finite value > 0")))
            }
        };
        positive("atlas.max_mmhg", self.atlas.max_mmhg)?;
        if self.atlas.max_mmhg > 300.0 {
            return Err(invalid(
                o,
                "atlas.max_mmhg",
                format!("{}: expected at most 300 mmHg", self.atlas.max_mmhg),
            ));
        }
        if !(2..=200).contains(&self.atlas.levels) {
            return Err(invalid(
                o,
                "atlas.levels",
                format!("{}: expected 2 to 200 levels", self.atlas.levels),
            ));
        }
        let s = &self.scope;
        positive("scope.sheath_outer_diameter_mm", s.sheath_outer_diameter_mm)?;
        if s.sheath_outer_diameter_mm > 15.0 {
            return Err(invalid(
                o,
                "scope.sheath_outer_diameter_mm",
                format!("{}: expected at most 15 mm", s.sheath_outer_diameter_mm),
            ));
        }
        positive("scope.inflow_channel_area_mm2", s.inflow_channel_area_mm2)?;
        positive("scope.outflow_holes_area_mm2", s.outflow_holes_area_mm2)?;
        let sheath_area = std::f64::consts::PI * 0.25 * s.sheath_outer_diameter_mm.powi(2);
        if s.inflow_channel_area_mm2 >= sheath_area {
            return Err(invalid(
                o,
                "scope.inflow_channel_area_mm2",
                format!(
                    "{} mm^2 does not fit in a {} mm sheath ({sheath_area:.2} mm^2)",
                    s.inflow_channel_area_mm2, s.sheath_outer_diameter_mm
                ),
            ));
        }
        let [near, far] = s.outflow_holes_from_tip_mm;
        if !(near.is_finite() && far.is_finite() && 0.0 <= near && near < far && far <= 100.0) {
            return Err(invalid(
                o,
                "scope.outflow_holes_from_tip_mm",
                format!("[{near}, {far}]: expected 0 <= near < far <= 100 mm"),
            ));
        }
        let f = &self.fluid;
        positive("fluid.voxel_mm", f.voxel_mm)?;
        if !(0.2..=5.0).contains(&f.voxel_mm) {
            return Err(invalid(
                o,
                "fluid.voxel_mm",
                format!("{}: expected 0.2 to 5 mm", f.voxel_mm),
            ));
        }
        match (f.roi_min_mm, f.roi_max_mm) {
            (None, None) => {}
            (Some(lo), Some(hi)) => {
                if (0..3).any(|a| !(lo[a].is_finite() && hi[a].is_finite() && lo[a] < hi[a])) {
                    return Err(invalid(
                        o,
                        "fluid.roi_min_mm",
                        format!("{lo:?} .. {hi:?}: expected finite corners with min < max"),
                    ));
                }
            }
            _ => {
                return Err(invalid(
                    o,
                    "fluid.roi_min_mm",
                    "give both `roi_min_mm` and `roi_max_mm`, or neither",
                ))
            }
        }
        positive("fluid.divergence_tolerance", f.divergence_tolerance)?;
        if f.max_cfl.is_nan() || f.max_cfl <= 0.0 {
            return Err(invalid(
                o,
                "fluid.max_cfl",
                format!(
                    "{}: expected a CFL number > 0 (inf: one fluid step per frame)",
                    f.max_cfl
                ),
            ));
        }
        if f.divergence_tolerance > 0.1 {
            return Err(invalid(
                o,
                "fluid.divergence_tolerance",
                format!("{}: expected at most 0.1", f.divergence_tolerance),
            ));
        }
        let k = &self.skip;
        let non_negative = |key: &str, v: f64| {
            if v.is_finite() && v >= 0.0 {
                Ok(())
            } else {
                Err(invalid(
                    o,
                    key,
                    format!("{v}: expected a finite value >= 0"),
                ))
            }
        };
        non_negative("skip.pressure_tolerance_pa", k.pressure_tolerance_pa)?;
        non_negative("skip.rest_speed_m_s", k.rest_speed_m_s)?;
        non_negative("skip.voxel_move_fraction", k.voxel_move_fraction)?;
        non_negative("skip.cut_move_fraction", k.cut_move_fraction)?;
        non_negative("skip.scope_move_fraction", k.scope_move_fraction)?;
        if k.scope_move_fraction > 2.0 {
            return Err(invalid(
                o,
                "skip.scope_move_fraction",
                format!("{}: expected at most 2 voxels", k.scope_move_fraction),
            ));
        }
        for (key, v) in [
            ("skip.voxel_move_fraction", k.voxel_move_fraction),
            ("skip.cut_move_fraction", k.cut_move_fraction),
        ] {
            if v > 0.5 {
                return Err(invalid(
                    o,
                    key,
                    format!("{v}: expected at most 0.5 (a larger move could skip a cell)"),
                ));
            }
        }
        self.vortices
            .validate()
            .map_err(|m| invalid_message(o, m))?;
        self.particles
            .validate()
            .map_err(|m| invalid_message(o, m))?;
        if (self.stages.vortices || self.stages.particles) && !self.stages.fluid {
            return Err(invalid(
                o,
                "stages",
                "vortices and particles need the fluid stage (`stages.fluid = true`)",
            ));
        }
        Ok(())
    }

    /// Voxel edge, m.
    pub fn voxel_m(&self) -> f64 {
        self.fluid.voxel_mm * 1e-3
    }

    /// The key of the atlas this scene needs: a hash of everything the FEM sweep depends on
    /// (anatomy, material, element, pressures). Two scenes with the same key share an atlas.
    pub fn atlas_key(&self) -> String {
        let value = serde_json::json!({
            "anatomy": self.anatomy,
            "material": self.material,
            "element": self.element.to_string(),
            "max_mmhg": self.atlas.max_mmhg,
            "levels": self.atlas.levels,
            "format": crate::atlas::format::VERSION,
            "generator": env!("CARGO_PKG_VERSION"),
        });
        let text = value.to_string();
        format!("{:016x}", fnv1a64(text.as_bytes()))
    }
}

/// FNV-1a, 64 bit.
pub(crate) fn fnv1a64(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_scenes_parse_and_the_default_is_the_default_anatomy() {
        for (name, _) in BUILTIN_SCENES {
            let d = SceneDesc::builtin(name).unwrap();
            assert_eq!(d.name, name);
        }
        let d = SceneDesc::default();
        assert_eq!(d.anatomy, AnatomyParams::default());
        // The printed default file states the code's fluid defaults (two copies, kept equal
        // here), except the advection scheme, which the built-in scene chooses itself.
        let fluid = FluidSpec {
            advection: d.fluid.advection,
            ..FluidSpec::default()
        };
        assert_eq!(d.fluid, fluid);
        assert_eq!(d.hydraulics.inflow.port_area_mm2, 2.8);
        let m = SceneDesc::builtin("myoma-figo1").unwrap();
        assert_eq!(m.anatomy.myomas.len(), 1);
        assert_eq!(m.anatomy.myomas[0].figo, Some(1));
        assert_ne!(m.atlas_key(), d.atlas_key());
        // The heaviest built-in: every stage on, the default's anatomy and atlas (shared cache).
        let b = SceneDesc::builtin("bleed").unwrap();
        assert!(b.stages.fluid && b.stages.vortices && b.stages.particles);
        assert_eq!(b.atlas_key(), d.atlas_key());
        assert_eq!(b.fluid.voxel_mm, d.fluid.voxel_mm);
    }

    #[test]
    fn bad_descriptions_name_the_key() {
        let cases = [
            ("colour = 1", "colour"),
            ("[fluid]\nvoxel_mm = 0", "fluid.voxel_mm"),
            ("[fluid]\nvoxels = 1", "voxels"),
            (
                "[scope]\nsheath_outer_diameter_mm = -1",
                "scope.sheath_outer_diameter_mm",
            ),
            (
                "[scope]\ninflow_channel_area_mm2 = 50",
                "scope.inflow_channel_area_mm2",
            ),
            (
                "[hydraulics.inflow]\nport_area_mm2 = 3",
                "hydraulics.inflow.port_area_mm2",
            ),
            ("[hydraulics]\nbogus = 3", "bogus"),
            ("[anatomy]\nheight_mm = 3", "height_mm"),
            ("[atlas]\nelement = \"hex8\"", "atlas.element"),
            ("[atlas]\nlevels = 1", "atlas.levels"),
            ("[fluid]\nroi_min_mm = [0, 0, 0]", "roi_min_mm"),
            ("[fluid]\nmax_cfl = 0", "fluid.max_cfl"),
            ("[fluid]\nmax_cfl = nan", "fluid.max_cfl"),
            ("[stages]\nfluid = false\nparticles = true", "stages"),
            (
                "[skip]\nvoxel_move_fraction = 0.9",
                "skip.voxel_move_fraction",
            ),
            ("[skip]\ncut_move_fraction = 0.6", "skip.cut_move_fraction"),
            ("[skip]\ncut_move_fraction = -0.1", "skip.cut_move_fraction"),
            ("anatomy_file = \"/does/not/exist.toml\"", "anatomy_file"),
        ];
        for (text, key) in cases {
            let e = SceneDesc::parse(text, "test.toml", None)
                .unwrap_err()
                .to_string();
            assert!(e.contains(key) && e.contains("test.toml"), "{text}: {e}");
        }
    }

    #[test]
    fn names_and_files_follow_one_rule() {
        assert!(SceneDesc::load("default").is_ok());
        let e = SceneDesc::load("no-such-scene").unwrap_err().to_string();
        assert!(e.contains("no-such-scene") && e.contains("default"), "{e}");
        let e = SceneDesc::load("missing.toml").unwrap_err().to_string();
        assert!(e.contains("missing.toml"), "{e}");
    }
}
