//! The scene's error: every variant names what failed and where.

use crate::atlas::AtlasError;
use crate::cutcell::CutCellError;
use crate::fluid::FluidError;
use crate::hydraulics::ParamsError;

/// Errors of the scene: every one names what failed and where.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// A scene file cannot be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// A scene description is invalid.
    #[error("{origin}: {message}")]
    Description {
        /// The file or built-in name.
        origin: String,
        /// What is wrong, naming the key.
        message: String,
    },
    /// No built-in scene of that name.
    #[error("no built-in scene `{name}` (built-in: {}); a scene file path must exist, contain a `/` or end in .toml", known.join(", "))]
    UnknownScene {
        /// The name asked for.
        name: String,
        /// The built-in names.
        known: Vec<&'static str>,
    },
    /// An atlas that does not belong to the scene's mesh.
    #[error("{origin}: atlas does not match the scene: {message}")]
    AtlasMismatch {
        /// The atlas file.
        origin: String,
        /// What differs.
        message: String,
    },
    /// An atlas error (corrupt file, bad argument).
    #[error(transparent)]
    Atlas(#[from] AtlasError),
    /// Preparing the mesh or the atlas failed.
    #[error("{0}")]
    Prepare(String),
    /// The hydraulic parameters are invalid.
    #[error(transparent)]
    Hydraulics(#[from] ParamsError),
    /// The fluid solver refused its grid or parameters.
    #[error(transparent)]
    Fluid(#[from] FluidError),
    /// The cut cells of the cavity surface cannot be computed (`[fluid] cut_cells`).
    #[error("cut cells: {0}")]
    CutCells(#[from] CutCellError),
}
