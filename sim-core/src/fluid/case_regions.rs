//! Curved regions of a case file: spheres, cylinders (any axis, capped ends) and closed triangle
//! meshes (STL or OBJ files, read here) with cut-cell boundaries. With at least one curved region, the grid's background and every fluid or solid
//! region (boxes too, as closed box surfaces) are layers of the cutcell module in file order,
//! each making what it encloses fluid or solid over what lies below; a cell is fluid where its
//! stabilised volume fraction (small cells merged, `SmallCellParams::default`) is above zero, and
//! the grid carries the fractions. Velocity and outflow regions stay boxes, labelled after.
//! Without curved regions nothing is cut (the labels of today).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::cut::holds_fluid;
use super::{CellLabel, CutFractions, FluidError, FluidGrid};
use crate::cutcell::mesh::{ClosedMesh, MeshError};
use crate::cutcell::shapes::{self, Tessellation};
use crate::cutcell::{CutCells, Layer, Orientation, Phase, SmallCellParams};
use crate::scene::voxelize::VoxelBox;

/// A bad value: the dotted key, the value and what was expected (a `CaseError::Invalid`).
#[derive(Debug)]
pub(crate) struct Invalid {
    pub key: String,
    pub value: String,
    pub problem: String,
}

fn invalid(key: impl Into<String>, value: impl std::fmt::Debug, problem: &str) -> Invalid {
    Invalid {
        key: key.into(),
        value: format!("{value:?}"),
        problem: problem.into(),
    }
}

fn solver(e: FluidError) -> Invalid {
    invalid("region", "", &e.to_string())
}

/// `[[region]]`: a box (cells whose centres lie in `[min_m, max_m]` get the label), or a curved
/// shape with cut-cell boundaries (`shape = "sphere"`, `"cylinder"` or `"mesh"`, fluid or solid
/// only; see `case_regions.rs`).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RegionSpec {
    /// `box` (default), `sphere`, `cylinder` or `mesh`.
    pub shape: Option<String>,
    /// `fluid`, `solid`, `velocity` or `outflow` (curved shapes: `fluid` or `solid`).
    pub label: String,
    /// Lower corner of a box (m).
    pub min_m: Option<[f64; 3]>,
    /// Upper corner of a box (m).
    pub max_m: Option<[f64; 3]>,
    /// Centre of a sphere or cylinder (m).
    pub centre_m: Option<[f64; 3]>,
    /// Radius of a sphere or cylinder (m).
    pub radius_m: Option<f64>,
    /// Axis direction of a cylinder (any non-zero vector).
    pub axis: Option<[f64; 3]>,
    /// Length of a cylinder along its axis, ends capped (m).
    pub length_m: Option<f64>,
    /// Velocity of `velocity` cells (m/s).
    pub velocity_m_s: Option<[f64; 3]>,
    /// The closed triangle mesh (STL or OBJ) of shape `mesh`, relative to the case file's
    /// directory.
    pub file: Option<PathBuf>,
    /// Metres per unit of the mesh file's coordinates (default 1).
    pub scale_m_per_unit: Option<f64>,
    /// The mesh read from `file` (by [`super::case::Case::parse_at`]), in metres.
    #[serde(skip)]
    pub(super) mesh: Option<ClosedMesh>,
}

/// The label of a region's `label` key.
pub(super) fn parse_label(s: &str) -> Option<CellLabel> {
    [
        CellLabel::Fluid,
        CellLabel::Solid,
        CellLabel::Velocity,
        CellLabel::Outflow,
    ]
    .into_iter()
    .find(|l| l.name() == s)
}

/// The shapes of `[[region]]`.
const SHAPES: [&str; 4] = ["box", "sphere", "cylinder", "mesh"];

/// Whether region `i` is a box (`true`; its box keys are checked by the caller) or a valid curved
/// shape (`false`). Every shape key belongs to the shapes named beside it and is refused on others.
pub(super) fn validate_shape(i: usize, r: &RegionSpec, label: CellLabel) -> Result<bool, Invalid> {
    let key = |k: &str| format!("region[{i}].{k}");
    let shape = r.shape.as_deref().unwrap_or("box");
    if !SHAPES.contains(&shape) {
        let expected = format!("expected one of {}", SHAPES.join(", "));
        return Err(invalid(key("shape"), shape, &expected));
    }
    let owned = [
        ("min_m", r.min_m.is_some(), "box"),
        ("max_m", r.max_m.is_some(), "box"),
        ("velocity_m_s", r.velocity_m_s.is_some(), "box"),
        ("centre_m", r.centre_m.is_some(), "sphere or cylinder"),
        ("radius_m", r.radius_m.is_some(), "sphere or cylinder"),
        ("axis", r.axis.is_some(), "cylinder"),
        ("length_m", r.length_m.is_some(), "cylinder"),
        ("file", r.file.is_some(), "mesh"),
        ("scale_m_per_unit", r.scale_m_per_unit.is_some(), "mesh"),
    ];
    if let Some((k, _, owners)) = owned
        .iter()
        .find(|(_, set, owners)| *set && !owners.split(" or ").any(|o| o == shape))
    {
        return Err(invalid(
            key(k),
            "given",
            &format!("only for shape {owners}"),
        ));
    }
    if shape == "box" {
        return Ok(true);
    }
    if !matches!(label, CellLabel::Fluid | CellLabel::Solid) {
        return Err(invalid(
            key("label"),
            &r.label,
            "a curved region is fluid or solid (ports stay boxes)",
        ));
    }
    let positive = |k: &str, v: Option<f64>, what: &str| match v {
        Some(x) if x.is_finite() && x > 0.0 => Ok(()),
        Some(x) => Err(invalid(key(k), x, &format!("expected a finite {what} > 0"))),
        None => Err(invalid(key(k), "missing", "required")),
    };
    if shape == "mesh" {
        if r.file.is_none() {
            return Err(invalid(
                key("file"),
                "missing",
                "required: a closed STL or OBJ mesh",
            ));
        }
        if r.scale_m_per_unit.is_some() {
            positive("scale_m_per_unit", r.scale_m_per_unit, "scale (m per unit)")?;
        }
        return Ok(false);
    }
    let c = r
        .centre_m
        .ok_or_else(|| invalid(key("centre_m"), "missing", "required"))?;
    if !c.iter().all(|x| x.is_finite()) {
        return Err(invalid(key("centre_m"), c, "expected three finite numbers"));
    }
    positive("radius_m", r.radius_m, "length")?;
    if shape == "cylinder" {
        positive("length_m", r.length_m, "length")?;
        let a = r
            .axis
            .ok_or_else(|| invalid(key("axis"), "missing", "required"))?;
        let n2: f64 = a.iter().map(|x| x * x).sum();
        if !(n2.is_finite() && n2 > 0.0) {
            return Err(invalid(
                key("axis"),
                a,
                "expected a finite non-zero direction",
            ));
        }
    }
    Ok(false)
}

/// Reads the closed mesh of every `mesh` region (validated), its relative `file` resolved against
/// the directory of `case_file`; without a case file only an absolute `file` can be read.
pub(super) fn read_meshes(
    regions: &mut [RegionSpec],
    case_file: Option<&Path>,
) -> Result<(), Invalid> {
    for (i, r) in regions.iter_mut().enumerate() {
        let Some(file) = r.file.as_ref() else {
            continue;
        };
        let key = format!("region[{i}].file");
        let path =
            match case_file {
                _ if file.is_absolute() => file.clone(),
                Some(case) => case.parent().unwrap_or(Path::new("")).join(file),
                None => return Err(invalid(
                    key,
                    file,
                    "a relative path needs the case file's directory, and this case was parsed \
                     from text without one: give an absolute path or load the case from its file",
                )),
            };
        let origin = path.display().to_string();
        // Only a regular file: a device (`/dev/zero`) or a fifo would block the reader.
        let regular = match std::fs::metadata(&path) {
            Err(source) => Err(MeshError::Io { origin, source }),
            Ok(m) if !m.is_file() => Err(MeshError::Whole {
                origin,
                what: "not a regular file".into(),
            }),
            Ok(_) => Ok(()),
        };
        let mesh = regular
            .and_then(|()| ClosedMesh::read(&path, r.scale_m_per_unit.unwrap_or(1.0)))
            .map_err(|e| {
                let case = case_file.map_or(String::new(), |c| {
                    format!(" (a region of case file {})", c.display())
                });
                invalid(key, file, &format!("{e}{case}"))
            })?;
        r.mesh = Some(mesh);
    }
    Ok(())
}

/// The grid's background phase.
pub(super) fn background(name: Option<&str>) -> Result<Phase, Invalid> {
    match name.unwrap_or("fluid") {
        "fluid" => Ok(Phase::Fluid),
        "solid" => Ok(Phase::Solid),
        other => Err(invalid("grid.background", other, "expected fluid or solid")),
    }
}

/// The closed surface of a fluid or solid region (a box's six faces, or the tessellated shape).
fn surface(i: usize, r: &RegionSpec, h: f64) -> Result<ClosedMesh, Invalid> {
    let fail = |e: MeshError| invalid(format!("region[{i}]"), "", &e.to_string());
    let t = Tessellation::for_spacing(h);
    match r.shape.as_deref().unwrap_or("box") {
        "sphere" => shapes::sphere(r.centre_m.unwrap_or_default(), r.radius_m.unwrap_or(0.0), t)
            .map_err(fail),
        "cylinder" => shapes::cylinder(
            r.centre_m.unwrap_or_default(),
            r.axis.unwrap_or_default(),
            r.radius_m.unwrap_or(0.0),
            r.length_m.unwrap_or(0.0),
            t,
        )
        .map_err(fail),
        "mesh" => r.mesh.clone().ok_or_else(|| {
            invalid(
                format!("region[{i}].file"),
                &r.file,
                "the mesh was not read: make cases with Case::parse or Case::parse_at",
            )
        }),
        _ => {
            let (lo, hi) = (r.min_m.unwrap_or_default(), r.max_m.unwrap_or_default());
            let corners = std::array::from_fn(|v| {
                std::array::from_fn(|a| if v >> a & 1 == 1 { hi[a] } else { lo[a] })
            });
            shapes::hexahedron(&format!("region[{i}]"), corners).map_err(fail)
        }
    }
}

/// Labels and cut fractions of the case's fluid and solid regions when one is curved (returns
/// `true`: the caller then labels only the velocity and outflow boxes); otherwise only a solid
/// background is applied (returns `false`).
pub(super) fn apply_cut_regions(
    background_name: Option<&str>,
    regions: &[RegionSpec],
    grid: &mut FluidGrid,
) -> Result<bool, Invalid> {
    let phase = background(background_name)?;
    let curved = regions
        .iter()
        .any(|r| !matches!(r.shape.as_deref(), None | Some("box")));
    let (dims, h, origin) = (grid.dims(), grid.spacing_m(), grid.origin_m());
    if !curved {
        if phase == Phase::Solid {
            let top = std::array::from_fn(|a| origin[a] + dims[a] as f64 * h);
            grid.fill_box(origin, top, CellLabel::Solid, [0.0; 3]);
        }
        return Ok(false);
    }
    let mut layers = Vec::new();
    let mut meshes = Vec::new();
    for (i, r) in regions.iter().enumerate() {
        let inside = match parse_label(&r.label) {
            Some(CellLabel::Fluid) => Phase::Fluid,
            Some(CellLabel::Solid) => Phase::Solid,
            _ => continue,
        };
        let mesh = surface(i, r, h)?;
        layers.push(Layer {
            name: format!("region[{i}]"),
            triangles: mesh.triangles().to_vec(),
            vertex_count: mesh.positions_m().len(),
            orientation: Orientation::Outward,
            inside,
        });
        meshes.push(mesh);
    }
    let cells = VoxelBox {
        dims,
        origin_m: origin,
        spacing_m: h,
    };
    let fail = |e: crate::cutcell::CutCellError| invalid("region", "", &e.to_string());
    let mut cut = CutCells::new(cells, phase, layers, SmallCellParams::default()).map_err(fail)?;
    let positions: Vec<&[[f32; 3]]> = meshes.iter().map(|m| m.positions_m()).collect();
    cut.full(&positions).map_err(fail)?;
    let faces = std::array::from_fn(|a| cut.stabilised_face_fractions(a));
    let volume = cut.stabilised_volume_fractions();
    let mut fractions = CutFractions::from_box(dims, grid.periodic(), volume, faces);
    // The walls' distances along the viscous stencil's arms, from the same surfaces.
    fractions.walls = Some(CutFractions::walls_from_box(
        dims,
        grid.periodic(),
        &cut.face_walls(),
    ));
    for (n, &v) in fractions.volume.iter().enumerate() {
        let label = if holds_fluid(v) {
            CellLabel::Fluid
        } else {
            CellLabel::Solid
        };
        grid.set_label(grid.coords(n), label).map_err(solver)?;
    }
    grid.set_cut_fractions(fractions).map_err(solver)?;
    Ok(true)
}
