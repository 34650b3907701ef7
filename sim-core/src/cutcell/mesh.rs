//! Closed triangle meshes: the validated input of the cut-cell geometry, from memory, from the
//! shape builders ([`super::shapes`]) or from STL and OBJ files ([`super::mesh_io`]).

use std::collections::HashMap;
use std::fmt;

/// Where in its source a problem lies.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Location {
    /// A line of a text file (from 1).
    Line(usize),
    /// A byte offset into a binary file.
    Offset(u64),
    /// A triangle of an in-memory mesh (from 0).
    Triangle(usize),
    /// A vertex of an in-memory mesh (from 0).
    Vertex(usize),
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Location::Line(n) => write!(f, "line {n}"),
            Location::Offset(n) => write!(f, "byte offset {n}"),
            Location::Triangle(n) => write!(f, "triangle {n}"),
            Location::Vertex(n) => write!(f, "vertex {n}"),
        }
    }
}

/// A mesh that cannot be used, and where it came from.
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    /// The file cannot be read.
    #[error("{origin}: cannot read: {source}")]
    Io {
        /// The file.
        origin: String,
        /// Why.
        source: std::io::Error,
    },
    /// Something at one place of the source is wrong.
    #[error("{origin}: {at}: {what}")]
    At {
        /// The file or shape.
        origin: String,
        /// Where.
        at: Location,
        /// What is wrong.
        what: String,
    },
    /// The mesh as a whole is wrong (empty, encloses nothing, a bad shape parameter).
    #[error("{origin}: {what}")]
    Whole {
        /// The file or shape.
        origin: String,
        /// What is wrong.
        what: String,
    },
}

/// A closed, consistently oriented triangle surface with outward normals (by the right-hand
/// rule of each triangle's vertex order), finite positions in metres and a positive enclosed
/// volume. Zero-area triangles are allowed; self-intersections are not detected (the fractions
/// of a self-intersecting surface count overlapped volume once per layer, clamped to a cell).
#[derive(Debug, Clone, PartialEq)]
pub struct ClosedMesh {
    positions_m: Vec<[f32; 3]>,
    triangles: Vec<[u32; 3]>,
}

/// A topology problem: what, and the triangle it is seen at.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct TopologyProblem {
    pub triangle: usize,
    pub what: String,
}

impl ClosedMesh {
    /// Validates an in-memory mesh (`origin` names it in errors); a mesh whose normals all point
    /// inwards is turned outwards.
    pub fn new(
        origin: &str,
        positions_m: Vec<[f32; 3]>,
        triangles: Vec<[u32; 3]>,
    ) -> Result<Self, MeshError> {
        if let Some(v) = positions_m
            .iter()
            .position(|p| p.iter().any(|x| !x.is_finite()))
        {
            return Err(MeshError::At {
                origin: origin.to_string(),
                at: Location::Vertex(v),
                what: format!("position {:?} is not finite", positions_m[v]),
            });
        }
        Self::from_parts(origin, positions_m, triangles, &Location::Triangle)
    }

    /// Validates finite positions and triangles; `locate` maps a triangle to where its source
    /// defined it.
    pub(crate) fn from_parts(
        origin: &str,
        positions_m: Vec<[f32; 3]>,
        mut triangles: Vec<[u32; 3]>,
        locate: &dyn Fn(usize) -> Location,
    ) -> Result<Self, MeshError> {
        if triangles.is_empty() {
            return Err(MeshError::Whole {
                origin: origin.to_string(),
                what: "empty: no triangles".to_string(),
            });
        }
        check_closed_detailed(&triangles, positions_m.len()).map_err(|p| MeshError::At {
            origin: origin.to_string(),
            at: locate(p.triangle),
            what: p.what,
        })?;
        let volume = signed_volume_m3(&positions_m, &triangles);
        if volume.is_nan() || volume == 0.0 {
            return Err(MeshError::Whole {
                origin: origin.to_string(),
                what: format!("encloses no volume ({volume} m^3)"),
            });
        }
        if volume < 0.0 {
            for t in &mut triangles {
                t.swap(1, 2);
            }
        }
        Ok(Self {
            positions_m,
            triangles,
        })
    }

    /// Vertex positions, m.
    pub fn positions_m(&self) -> &[[f32; 3]] {
        &self.positions_m
    }
    /// Triangles (outward normals).
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }
    /// The enclosed volume, m^3 (> 0).
    pub fn volume_m3(&self) -> f64 {
        signed_volume_m3(&self.positions_m, &self.triangles)
    }
    /// The parts.
    pub fn into_parts(self) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
        (self.positions_m, self.triangles)
    }
}

/// The enclosed volume for outward normals (the cavity's formula, whose normals point inwards,
/// with the sign turned).
pub(crate) fn signed_volume_m3(positions_m: &[[f32; 3]], triangles: &[[u32; 3]]) -> f64 {
    -crate::scene::surface::enclosed_volume_m3(positions_m, triangles)
}

/// [`check_closed_detailed`] as a message.
pub(crate) fn check_closed(triangles: &[[u32; 3]], vertex_count: usize) -> Result<(), String> {
    check_closed_detailed(triangles, vertex_count)
        .map_err(|p| format!("triangle {}: {}", p.triangle, p.what))
}

/// Checks that every vertex index is in range and that the surface is closed and consistently
/// oriented: every directed edge `a -> b` (`a != b`) is matched by as many `b -> a`. That is
/// exactly what the fractions need (the surface bounds a region); zero-area triangles pass.
pub(crate) fn check_closed_detailed(
    triangles: &[[u32; 3]],
    vertex_count: usize,
) -> Result<(), TopologyProblem> {
    if triangles.is_empty() {
        return Err(TopologyProblem {
            triangle: 0,
            what: "no triangles".to_string(),
        });
    }
    // (low vertex, high vertex, +1 if traversed low -> high, triangle).
    let mut edges: Vec<(u32, u32, i32, u32)> = Vec::with_capacity(3 * triangles.len());
    for (t, tri) in triangles.iter().enumerate() {
        for e in 0..3 {
            let (a, b) = (tri[e], tri[(e + 1) % 3]);
            if a as usize >= vertex_count || b as usize >= vertex_count {
                return Err(TopologyProblem {
                    triangle: t,
                    what: format!(
                        "vertex index {} is out of range ({vertex_count} vertices)",
                        a.max(b)
                    ),
                });
            }
            if a != b {
                let (lo, hi, d) = if a < b { (a, b, 1) } else { (b, a, -1) };
                edges.push((lo, hi, d, t as u32));
            }
        }
    }
    edges.sort_unstable();
    let mut s = 0;
    while s < edges.len() {
        let (lo, hi) = (edges[s].0, edges[s].1);
        let mut e = s;
        let mut net = 0;
        while e < edges.len() && edges[e].0 == lo && edges[e].1 == hi {
            net += edges[e].2;
            e += 1;
        }
        if net != 0 {
            let count = e - s;
            let forward = edges[s..e].iter().filter(|x| x.2 > 0).count();
            let mut tris: Vec<u32> = edges[s..e].iter().map(|x| x.3).collect();
            tris.dedup();
            let what = if count == 1 {
                format!(
                    "not closed: its edge between vertices {lo} and {hi} has no neighbouring \
                     triangle (a hole)"
                )
            } else if count % 2 == 1 {
                format!(
                    "not closed: its edge between vertices {lo} and {hi} is shared by {count} \
                     triangles {tris:?} (an odd number)"
                )
            } else {
                format!(
                    "inconsistent orientation: its edge between vertices {lo} and {hi} is \
                     traversed {forward} times as {lo} -> {hi} and {} times as {hi} -> {lo} by \
                     triangles {tris:?}",
                    count - forward
                )
            };
            return Err(TopologyProblem {
                triangle: edges[e - 1].3 as usize,
                what,
            });
        }
        s = e;
    }
    Ok(())
}

/// Welds vertices with bit-identical coordinates (`-0` and `0` alike): files that store a
/// position per triangle corner (STL) or repeat seam vertices (OBJ) become indexed surfaces.
#[derive(Default)]
pub(crate) struct Welder {
    map: HashMap<[u32; 3], u32>,
    pub positions_m: Vec<[f32; 3]>,
}

impl Welder {
    pub fn index(&mut self, p: [f32; 3]) -> u32 {
        let key = p.map(|x| (x + 0.0).to_bits());
        let positions = &mut self.positions_m;
        *self.map.entry(key).or_insert_with(|| {
            positions.push(p);
            (positions.len() - 1) as u32
        })
    }
}
