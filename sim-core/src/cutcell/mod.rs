//! Cut cells: the exact fluid volume fraction of every cell and open area fraction of every MAC
//! face of a box of cells, from closed triangle surfaces, kept up to date as the surfaces move.
//!
//! What it computes, for a [`VoxelBox`] (cell `(i, j, k)` spans `origin + h [i, i+1] x [j, j+1] x
//! [k, k+1]`, x fastest) and a stack of closed surfaces ([`CutCells`]; one surface alone:
//! [`SurfaceFractions`]):
//! - per cell, the fluid volume fraction in `[0, 1]` ([`CutCells::volume_fractions`]) and the area
//!   vector of the walls inside it, `integral of n dA / h^2` with `n` out of the fluid
//!   ([`CutCells::wall_areas`]);
//! - per MAC face, the open (fluid) area fraction in `[0, 1]` ([`CutCells::face_fractions`]): along
//!   axis `a` the face `(i, j, k)` lies between cells `(i, j, k) - e_a` and `(i, j, k)`, with
//!   `dims[a] + 1` faces along the axis (the box's boundary faces included), x fastest: the
//!   solver's face layout;
//! - the small-cell rule's merge targets and stabilised fractions ([`small`]);
//! - per MAC face centre, the distance along each axis to the fluid's boundary where it lies
//!   within one cell ([`CutCells::face_walls`], `crossings.rs`): the no-slip rule of the viscous
//!   step at cut walls.
//!
//! Method: exact for the polygonal surface, up to rounding (about 1e-15 relative on the default
//! cavity). Each triangle is clipped to the rows of cells it crosses and cut along x into cells;
//! the divergence theorem turns the pieces' moments into volumes and the faces' areas into running
//! sums along each row, one dimension lower for the faces normal to y and z (the surface's
//! cross-section with the face plane, clipped to a strip of faces); see `fractions.rs`. No level
//! set and no sampling: a slit thinner than a cell keeps its volume, a surface may cross the box's
//! boundary (the part of the surface left of the box still closes the faces in the box), and
//! zero-area triangles add nothing.
//!
//! The surfaces: closed and consistently oriented (every directed edge `a -> b` matched by a
//! `b -> a`; checked when built), normals out of ([`Orientation::Outward`], STL/OBJ,
//! [`mesh::ClosedMesh`]) or into ([`Orientation::Inward`], the cavity surface) the enclosed region.
//! Self-intersections are not detected; a region enclosed twice counts once (clamped to a cell).
//! Several surfaces stack as layers: each makes what it encloses fluid or solid ([`Phase`]) over
//! what lies below; a cell cut by two surfaces is approximate ([`CutCells`]).
//!
//! Tie rule: a point exactly on a grid plane belongs to the cell below the plane (cells are
//! `(i, i+1]` along each axis), as if every plane lay an infinitesimal above its nominal position;
//! the exception is a triangle lying in a grid plane with the fluid above it, which belongs to the
//! cell above, on its fluid side. So a face the surface lies in is open only where there is fluid
//! on both sides of it, walls on grid planes (a duct) close their faces and sit in the fluid
//! cells, and nothing is counted twice or lost. "Exactly" means in the cell coordinates
//! `(x - origin) / h` as computed in f64 from the f32 positions: give grid-aligned walls
//! coordinates that are exact in binary, or expect a sliver a rounding wide (which the small-cell
//! rule absorbs).
//!
//! Incremental: [`CutCells::update`] takes the new position of every vertex that moved (beyond a
//! threshold) and recomputes only the rows and strips of faces the moved triangles' old and new
//! boxes reach, then combines and re-applies the small-cell rule to the cells whose inputs changed
//! (and, for the rule, their face neighbours).
//! Every unit is a function of the held positions alone, visited in triangle order, so the result
//! equals [`CutCells::full`] at the held positions bit for bit after any sequence of moves; the
//! counts are in [`CutCellStats`], the rows changed in [`CutCells::changed_rows`]. After the build
//! an update allocates nothing (the triangle index keeps room to grow).
//!
//! Small fractions ([`small`]): a cell with a fluid fraction below
//! [`SmallCellParams::min_volume_fraction`] (default 0.1) is merged into the face neighbour with
//! at least that fraction with which it shares the largest open face; its volume moves there
//! ([`CutCells::stabilised_volume_fractions`], which sum to the exact fractions; a merged cell
//! reads 0, its target may exceed 1). A small cell without such a neighbour is left unmerged and
//! counted. The stabilised fractions drop rounding: faces within
//! [`SmallCellParams::round_off_fraction`] (default 1e-12) of 1 read 1, and a cell holding no
//! more than that (dust where a surface passes a cell's corner) reads 0. Faces open by less than
//! [`SmallCellParams::min_face_fraction`] (default 1e-3) read 0: closed, so no velocity is set on
//! a face that carries next to no flux (the slivers of a collapsing slit).
//!
//! Errors ([`CutCellError`], [`mesh::MeshError`]): a box without cells, a surface that is not
//! closed or consistently oriented (naming the edge and triangles), positions that are too few or
//! too many, not finite or more than [`MAX_CELLS_AWAY`] cells from the box (naming the vertex;
//! nothing changes), and for files the path with the line or byte offset. Nothing panics on bad
//! input.
//!
//! ```
//! use hydrometra_sim::cutcell::shapes::{self, Tessellation};
//! use hydrometra_sim::cutcell::{CutCells, Layer, Orientation, Phase, SmallCellParams};
//! use hydrometra_sim::scene::voxelize::VoxelBox;
//! // A sphere of radius 4 mm on 1 mm cells: its fluid volume is the sphere's.
//! let h = 1e-3;
//! let sphere = shapes::sphere([0.0; 3], 4e-3, Tessellation::for_spacing(h)).unwrap();
//! let cells = VoxelBox { dims: [10, 10, 10], origin_m: [-5e-3; 3], spacing_m: h };
//! let layer = Layer {
//!     name: "sphere".into(),
//!     triangles: sphere.triangles().to_vec(),
//!     vertex_count: sphere.positions_m().len(),
//!     orientation: Orientation::Outward,
//!     inside: Phase::Fluid,
//! };
//! let mut cut = CutCells::new(cells, Phase::Solid, vec![layer], SmallCellParams::default()).unwrap();
//! cut.full(&[sphere.positions_m()]).unwrap();
//! let volume_m3: f64 = cut.volume_fractions().iter().sum::<f64>() * h * h * h;
//! let exact = 4.0 / 3.0 * std::f64::consts::PI * 4e-3f64.powi(3);
//! assert!((volume_m3 - exact).abs() < 1e-6 * exact);
//! ```

mod cells;
mod clip;
mod crossings;
mod face_walls;
mod fractions;
pub mod mesh;
mod mesh_io;
pub mod shapes;
pub mod small;

pub use cells::{CutCellStats, CutCells, Layer, Phase, SmallCellParams};
pub use face_walls::{FaceWalls, NO_WALL};
pub use fractions::{FractionStats, SurfaceFractions, MAX_CELLS_AWAY};

use crate::scene::voxelize::VoxelBox;

/// Which way a closed surface's triangle normals point (by the right-hand rule of their vertex
/// order).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Orientation {
    /// Out of the enclosed region (the STL/OBJ convention; [`mesh::ClosedMesh`]).
    Outward,
    /// Into the enclosed region (the cavity surface: normals into the fluid).
    Inward,
}

/// Errors of the cut-cell geometry.
#[derive(Debug, thiserror::Error)]
pub enum CutCellError {
    /// The box cannot carry fractions.
    #[error("cut-cell box: {0}")]
    Box(String),
    /// A surface cannot be used as given.
    #[error("surface `{surface}`: {what}")]
    Surface {
        /// The surface's name.
        surface: String,
        /// What is wrong.
        what: String,
    },
    /// A vertex position is refused.
    #[error("surface `{surface}`: vertex {vertex} at {position_m:?} m: {what}")]
    Vertex {
        /// The surface's name.
        surface: String,
        /// The vertex.
        vertex: usize,
        /// Its position.
        position_m: [f32; 3],
        /// What is wrong.
        what: String,
    },
}

/// Refuses boxes the fractions cannot be computed on.
fn check_box(cells: &VoxelBox) -> Result<(), CutCellError> {
    if cells.dims.contains(&0) {
        return Err(CutCellError::Box(format!(
            "dims = {:?}: every axis needs at least one cell",
            cells.dims
        )));
    }
    let fits = cells.dims.iter().all(|&d| d < (1 << 20))
        && cells
            .dims
            .iter()
            .map(|&d| d + 1)
            .try_fold(1usize, |a, d| a.checked_mul(d))
            .is_some_and(|n| n < u32::MAX as usize);
    if !fits {
        return Err(CutCellError::Box(format!(
            "dims = {:?}: too many cells",
            cells.dims
        )));
    }
    if !(cells.spacing_m.is_finite() && cells.spacing_m > 0.0) {
        return Err(CutCellError::Box(format!(
            "spacing_m = {}: expected a finite length > 0",
            cells.spacing_m
        )));
    }
    if cells.origin_m.iter().any(|o| !o.is_finite()) {
        return Err(CutCellError::Box(format!(
            "origin_m = {:?}: expected finite coordinates",
            cells.origin_m
        )));
    }
    Ok(())
}
