//! What a scene needs before it can step: the anatomy mesh and its deformation atlas, loaded from a
//! file, from a cache, or built by the FEM sweep.

use std::path::{Path, PathBuf};

use super::desc::SceneDesc;
use super::SceneError;
use crate::anatomy;
use crate::atlas::{self, Atlas, AtlasLevel};
use crate::fem::{FemModel, Solver, SolverOptions};
use crate::hydraulics::{ComplianceError, TabulatedCompliance};
use crate::mesh::TetMesh;
use crate::units::mmhg_to_pa;

/// The mesh and the atlas of a scene.
#[derive(Debug, Clone)]
pub struct SceneAssets {
    /// The anatomy's tetrahedral mesh.
    pub mesh: TetMesh,
    /// Its deformation atlas.
    pub atlas: Atlas,
}

impl SceneAssets {
    /// Pairs a mesh with an atlas, refusing an atlas of another mesh.
    pub fn new(mesh: TetMesh, atlas: Atlas, origin: &str) -> Result<Self, SceneError> {
        let want = atlas::mesh_hash(&mesh);
        if atlas.mesh_hash != want {
            return Err(SceneError::AtlasMismatch {
                origin: origin.to_string(),
                message: format!(
                    "the atlas belongs to mesh {:016x}, the scene's anatomy is mesh {want:016x} \
                     (another anatomy or generator version): rebuild it",
                    atlas.mesh_hash
                ),
            });
        }
        if atlas.vertex_count() != mesh.positions_m.len() {
            return Err(SceneError::AtlasMismatch {
                origin: origin.to_string(),
                message: format!(
                    "the atlas has {} vertices, the mesh {}",
                    atlas.vertex_count(),
                    mesh.positions_m.len()
                ),
            });
        }
        Ok(Self { mesh, atlas })
    }

    /// The atlas's pressure-volume curve as the hydraulics' cavity compliance (one source of
    /// truth for the cavity volume at a pressure).
    pub fn compliance(&self) -> Result<TabulatedCompliance, ComplianceError> {
        compliance_of(&self.atlas)
    }
}

/// The P-V curve of an atlas as a compliance: its levels' (pressure, volume) points.
pub fn compliance_of(atlas: &Atlas) -> Result<TabulatedCompliance, ComplianceError> {
    let points: Vec<(f64, f64)> = atlas
        .pressure_pa
        .iter()
        .copied()
        .zip(atlas.cavity_volume_m3.iter().copied())
        .collect();
    TabulatedCompliance::new(&points)
}

/// Progress of an atlas build: `(levels done, levels in all, pressure Pa, cavity volume m^3)`.
pub type Progress<'a> = &'a mut dyn FnMut(usize, usize, f64, f64);

/// Generates the scene's anatomy mesh.
pub fn mesh(desc: &SceneDesc) -> Result<TetMesh, SceneError> {
    anatomy::generate(&desc.anatomy)
        .map(|a| a.mesh)
        .map_err(|e| SceneError::Prepare(format!("{}: generating the anatomy: {e}", desc.origin)))
}

/// Runs the FEM pressure sweep of `mesh` as the scene asks (levels equally spaced from 0 to
/// `atlas.max_mmhg`) and returns the atlas.
pub fn build_atlas(
    desc: &SceneDesc,
    mesh: &TetMesh,
    progress: Progress<'_>,
) -> Result<Atlas, SceneError> {
    let fail = |what: &str, e: &dyn std::fmt::Display| {
        SceneError::Prepare(format!("{}: {what}: {e}", desc.origin))
    };
    let mut model = FemModel::from_mesh(mesh, &desc.material).map_err(|e| fail("FEM model", &e))?;
    if desc.element == crate::fem::Element::Tet10 {
        model = model
            .to_tet10(|a, b| std::array::from_fn(|k| 0.5 * (a[k] + b[k])))
            .map_err(|e| fail("tet10 model", &e))?;
    }
    let options = SolverOptions::default();
    let mut solver = Solver::new(&model, options.clone()).map_err(|e| fail("FEM solver", &e))?;
    let levels = desc.atlas.levels;
    let pressures: Vec<f64> = (0..levels)
        .map(|k| mmhg_to_pa(desc.atlas.max_mmhg) * k as f64 / (levels - 1) as f64)
        .collect();
    let started = std::time::Instant::now();
    let states = solver
        .sweep(&pressures, |k, eq| {
            progress(k + 1, levels, eq.pressure_pa, eq.cavity_volume_m3)
        })
        .map_err(|e| fail("FEM sweep", &e))?;
    let n = mesh.positions_m.len();
    let levels: Vec<AtlasLevel> = states
        .into_iter()
        .map(|mut s| {
            s.positions_m.truncate(n);
            s.dxdp_m_per_pa.truncate(n);
            AtlasLevel {
                pressure_pa: s.pressure_pa,
                cavity_volume_m3: s.cavity_volume_m3,
                positions_m: s.positions_m,
                dxdp_m_per_pa: s.dxdp_m_per_pa,
            }
        })
        .collect();
    let metadata = serde_json::json!({
        "generator": format!("hydrometra {}", env!("CARGO_PKG_VERSION")),
        "scene": desc.name,
        "atlas_key": desc.atlas_key(),
        "mesh": {"vertices": n, "tets": mesh.tets.len()},
        "material": desc.material,
        "solver": {
            "element": desc.element.to_string(),
            "tolerance": options.tolerance,
            "newton_iterations": solver.counters.newton_iterations,
            "factorizations": solver.counters.factorizations,
            "sweep_seconds": started.elapsed().as_secs_f64(),
        },
        "levels": {"count": levels.len(), "max_mmhg": desc.atlas.max_mmhg},
    });
    Atlas::new(
        atlas::mesh_hash(mesh),
        metadata,
        mesh.positions_m.clone(),
        &levels,
    )
    .map_err(|e| fail("atlas", &e))
}

/// Where the atlas of `desc` is cached under `cache_dir`.
pub fn cache_path(desc: &SceneDesc, cache_dir: &Path) -> PathBuf {
    cache_dir.join(format!("atlas-{}.hma", desc.atlas_key()))
}

/// How the atlas was obtained.
#[derive(Debug, Clone, PartialEq)]
pub enum AtlasSource {
    /// The scene's `atlas.file`.
    File(PathBuf),
    /// A valid cached atlas.
    Cache(PathBuf),
    /// Built now (and written to the cache if one was given).
    Built {
        /// The cache file written, if any.
        cached: Option<PathBuf>,
        /// Why the cache was not used (missing, corrupt, mismatched), if there was a cache.
        cache_problem: Option<String>,
    },
}

/// The scene's mesh and atlas: the scene's own `atlas.file` (refused if corrupt or of another
/// mesh: a user's file is never silently replaced), else a valid cached atlas under `cache_dir`,
/// else built by the FEM sweep and cached (a corrupt or mismatched cache file is rebuilt).
pub fn load_or_build(
    desc: &SceneDesc,
    cache_dir: Option<&Path>,
    progress: Progress<'_>,
) -> Result<(SceneAssets, AtlasSource), SceneError> {
    let mesh = mesh(desc)?;
    if let Some(file) = &desc.atlas.file {
        let atlas = Atlas::read(file).map_err(SceneError::Atlas)?;
        let origin = file.display().to_string();
        return Ok((
            SceneAssets::new(mesh, atlas, &origin)?,
            AtlasSource::File(file.clone()),
        ));
    }
    let mut cache_problem = None;
    if let Some(dir) = cache_dir {
        let path = cache_path(desc, dir);
        if path.exists() {
            match Atlas::read(&path)
                .map_err(SceneError::Atlas)
                .and_then(|a| SceneAssets::new(mesh.clone(), a, &path.display().to_string()))
            {
                Ok(assets) => return Ok((assets, AtlasSource::Cache(path))),
                Err(e) => cache_problem = Some(e.to_string()),
            }
        } else {
            cache_problem = Some(format!("{}: not cached yet", path.display()));
        }
    }
    let atlas = build_atlas(desc, &mesh, progress)?;
    let mut cached = None;
    if let Some(dir) = cache_dir {
        std::fs::create_dir_all(dir).map_err(|source| SceneError::Io {
            path: dir.display().to_string(),
            source,
        })?;
        let path = cache_path(desc, dir);
        // Written beside and renamed, so a crash never leaves a half-written cache file.
        let tmp = path.with_extension("hma.partial");
        atlas.write(&tmp).map_err(SceneError::Atlas)?;
        std::fs::rename(&tmp, &path).map_err(|source| SceneError::Io {
            path: path.display().to_string(),
            source,
        })?;
        cached = Some(path);
    }
    Ok((
        SceneAssets::new(mesh, atlas, "built atlas")?,
        AtlasSource::Built {
            cached,
            cache_problem,
        },
    ))
}
