//! Closed meshes from STL (binary and ASCII) and Wavefront OBJ files.
//!
//! Both readers weld vertices with bit-identical coordinates, scale the file's units to metres by
//! `scale_m_per_unit`, and then validate the mesh ([`ClosedMesh`]): closed, consistently
//! oriented, enclosing a volume; a mesh whose normals all point inwards is turned outwards.
//! STL facet normals are ignored (the vertex order decides). Every error names the file and the
//! line (text) or byte offset (binary) of the offending element.

use super::mesh::{ClosedMesh, Location, MeshError, Welder};
use std::path::Path;

fn at(origin: &str, at: Location, what: impl Into<String>) -> MeshError {
    MeshError::At {
        origin: origin.to_string(),
        at,
        what: what.into(),
    }
}

fn whole(origin: &str, what: impl Into<String>) -> MeshError {
    MeshError::Whole {
        origin: origin.to_string(),
        what: what.into(),
    }
}

fn check_scale(origin: &str, scale_m_per_unit: f64) -> Result<(), MeshError> {
    if scale_m_per_unit.is_finite() && scale_m_per_unit > 0.0 {
        Ok(())
    } else {
        Err(whole(
            origin,
            format!("scale_m_per_unit = {scale_m_per_unit}: expected a finite value > 0"),
        ))
    }
}

fn scaled(origin: &str, where_: Location, p: [f32; 3], scale: f64) -> Result<[f32; 3], MeshError> {
    let q = p.map(|x| (x as f64 * scale) as f32);
    if p.iter().chain(q.iter()).all(|x| x.is_finite()) {
        Ok(q)
    } else {
        Err(at(
            origin,
            where_,
            format!("vertex {p:?} is not a finite position (in metres)"),
        ))
    }
}

/// Three coordinates after `keyword` on text line `line`.
fn point<'a>(
    tok: &mut impl Iterator<Item = &'a str>,
    keyword: &str,
    origin: &str,
    line: usize,
) -> Result<[f32; 3], MeshError> {
    let mut p = [0.0f32; 3];
    for (a, slot) in p.iter_mut().enumerate() {
        let s = tok.next().ok_or_else(|| {
            at(
                origin,
                Location::Line(line),
                format!("`{keyword}` needs 3 coordinates, found {a}"),
            )
        })?;
        *slot = s.parse::<f32>().map_err(|_| {
            at(
                origin,
                Location::Line(line),
                format!("`{s}` is not a number"),
            )
        })?;
    }
    Ok(p)
}

impl ClosedMesh {
    /// Reads an STL (`.stl`) or OBJ (`.obj`) file by its extension, any case.
    pub fn read(path: &Path, scale_m_per_unit: f64) -> Result<Self, MeshError> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        match ext.as_deref() {
            Some("stl") => Self::read_stl(path, scale_m_per_unit),
            Some("obj") => Self::read_obj(path, scale_m_per_unit),
            _ => Err(whole(
                &path.display().to_string(),
                "unknown mesh format: expected a .stl or .obj file",
            )),
        }
    }

    /// Reads a binary or ASCII STL file.
    pub fn read_stl(path: &Path, scale_m_per_unit: f64) -> Result<Self, MeshError> {
        let origin = path.display().to_string();
        let bytes = std::fs::read(path).map_err(|source| MeshError::Io {
            origin: origin.clone(),
            source,
        })?;
        Self::parse_stl(&bytes, &origin, scale_m_per_unit)
    }

    /// Reads a Wavefront OBJ file (`v` and `f` statements; polygons are fanned into triangles).
    pub fn read_obj(path: &Path, scale_m_per_unit: f64) -> Result<Self, MeshError> {
        let origin = path.display().to_string();
        let bytes = std::fs::read(path).map_err(|source| MeshError::Io {
            origin: origin.clone(),
            source,
        })?;
        Self::parse_obj(&bytes, &origin, scale_m_per_unit)
    }

    /// Parses STL bytes: binary when the length is `84 + 50 n` for the facet count `n` at byte
    /// 80, else ASCII when the text starts with `solid`.
    pub fn parse_stl(bytes: &[u8], origin: &str, scale_m_per_unit: f64) -> Result<Self, MeshError> {
        check_scale(origin, scale_m_per_unit)?;
        if bytes.is_empty() {
            return Err(whole(origin, "empty file"));
        }
        if bytes.len() >= 84 {
            let n = u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]]) as u64;
            if bytes.len() as u64 == 84 + 50 * n {
                return parse_binary_stl(bytes, n as usize, origin, scale_m_per_unit);
            }
        }
        let text = std::str::from_utf8(bytes).ok();
        match text {
            Some(t)
                if t.trim_start_matches('\u{feff}')
                    .trim_start()
                    .starts_with("solid") =>
            {
                parse_ascii_stl(t, origin, scale_m_per_unit)
            }
            _ => {
                let n = (bytes.len() >= 84)
                    .then(|| u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]]));
                Err(whole(
                    origin,
                    format!(
                        "not an STL file: {} bytes is not the binary size 84 + 50 x {} facets, \
                         and the text does not start with `solid`",
                        bytes.len(),
                        n.map_or("?".to_string(), |n| n.to_string())
                    ),
                ))
            }
        }
    }

    /// Parses OBJ text.
    pub fn parse_obj(bytes: &[u8], origin: &str, scale_m_per_unit: f64) -> Result<Self, MeshError> {
        check_scale(origin, scale_m_per_unit)?;
        let text = std::str::from_utf8(bytes).map_err(|e| {
            let line = bytes[..e.valid_up_to()]
                .iter()
                .filter(|&&b| b == b'\n')
                .count()
                + 1;
            at(origin, Location::Line(line), "not UTF-8 text")
        })?;
        // Welded index of each OBJ vertex; (line, face corners as OBJ vertex numbers).
        let mut welder = Welder::default();
        let mut obj_vertex: Vec<u32> = Vec::new();
        let mut triangles: Vec<[u32; 3]> = Vec::new();
        let mut lines: Vec<usize> = Vec::new();
        for (n, raw) in text.lines().enumerate() {
            let line = n + 1;
            let content = raw.split('#').next().unwrap_or("");
            let mut tok = content.split_whitespace();
            let Some(keyword) = tok.next() else {
                continue;
            };
            match keyword {
                "v" => {
                    let p = point(&mut tok, "v", origin, line)?;
                    let p = scaled(origin, Location::Line(line), p, scale_m_per_unit)?;
                    obj_vertex.push(welder.index(p));
                }
                "f" => {
                    let mut corners = [0u32; 3];
                    let mut count = 0;
                    for s in tok {
                        let number = s.split('/').next().unwrap_or("");
                        let i: i64 = number.parse().map_err(|_| {
                            at(
                                origin,
                                Location::Line(line),
                                format!("`{s}` is not a vertex reference"),
                            )
                        })?;
                        let defined = obj_vertex.len() as i64;
                        let k = if i > 0 { i - 1 } else { defined + i };
                        if i == 0 || k < 0 || k >= defined {
                            return Err(at(
                                origin,
                                Location::Line(line),
                                format!(
                                    "vertex reference {i} does not name one of the {defined} \
                                     vertices defined so far"
                                ),
                            ));
                        }
                        let v = obj_vertex[k as usize];
                        // A polygon is fanned from its first corner.
                        if count < 3 {
                            corners[count] = v;
                        } else {
                            corners[1] = corners[2];
                            corners[2] = v;
                        }
                        count += 1;
                        if count >= 3 {
                            triangles.push(corners);
                            lines.push(line);
                        }
                    }
                    if count < 3 {
                        return Err(at(
                            origin,
                            Location::Line(line),
                            format!("a face needs at least 3 vertices, found {count}"),
                        ));
                    }
                }
                // Texture, normals, groups, smoothing, materials, lines and points: not part of
                // the surface.
                "vt" | "vn" | "vp" | "g" | "o" | "s" | "usemtl" | "mtllib" | "l" | "p" => {}
                other => {
                    return Err(at(
                        origin,
                        Location::Line(line),
                        format!("unknown OBJ statement `{other}`"),
                    ));
                }
            }
        }
        if triangles.is_empty() {
            return Err(whole(origin, "empty: no faces"));
        }
        ClosedMesh::from_parts(origin, welder.positions_m, triangles, &|t| {
            Location::Line(lines[t])
        })
    }
}

fn parse_binary_stl(
    bytes: &[u8],
    n: usize,
    origin: &str,
    scale: f64,
) -> Result<ClosedMesh, MeshError> {
    if n == 0 {
        return Err(whole(origin, "empty: a binary STL with 0 facets"));
    }
    let mut welder = Welder::default();
    let mut triangles = Vec::with_capacity(n);
    for f in 0..n {
        let record = 84 + 50 * f;
        let mut tri = [0u32; 3];
        for (c, slot) in tri.iter_mut().enumerate() {
            let o = record + 12 + 12 * c;
            let p: [f32; 3] = std::array::from_fn(|a| {
                let b = o + 4 * a;
                f32::from_le_bytes([bytes[b], bytes[b + 1], bytes[b + 2], bytes[b + 3]])
            });
            let p = scaled(origin, Location::Offset(o as u64), p, scale)?;
            *slot = welder.index(p);
        }
        triangles.push(tri);
    }
    ClosedMesh::from_parts(origin, welder.positions_m, triangles, &|t| {
        Location::Offset(84 + 50 * t as u64)
    })
}

fn parse_ascii_stl(text: &str, origin: &str, scale: f64) -> Result<ClosedMesh, MeshError> {
    #[derive(PartialEq, Clone, Copy)]
    enum Expect {
        Solid,
        FacetOrEnd,
        OuterLoop,
        Vertex(usize),
        EndLoop,
        EndFacet,
    }
    let mut welder = Welder::default();
    let mut triangles = Vec::new();
    let mut lines = Vec::new();
    let mut expect = Expect::Solid;
    let mut tri = [0u32; 3];
    let mut facet_line = 0;
    let mut last_line = 0;
    for (n, raw) in text.lines().enumerate() {
        let line = n + 1;
        let mut tok = raw.split_whitespace();
        let Some(word) = tok.next() else {
            continue;
        };
        last_line = line;
        let wrong = |wanted: &str| {
            at(
                origin,
                Location::Line(line),
                format!("expected {wanted}, found `{}`", raw.trim()),
            )
        };
        expect = match (expect, word) {
            (Expect::Solid, "solid") => Expect::FacetOrEnd,
            (Expect::Solid, _) => return Err(wrong("`solid`")),
            (Expect::FacetOrEnd, "facet") => {
                facet_line = line;
                Expect::OuterLoop
            }
            (Expect::FacetOrEnd, "endsolid") => Expect::Solid,
            (Expect::FacetOrEnd, _) => return Err(wrong("`facet` or `endsolid`")),
            (Expect::OuterLoop, "outer") => Expect::Vertex(0),
            (Expect::OuterLoop, _) => return Err(wrong("`outer loop`")),
            (Expect::Vertex(c), "vertex") => {
                let p = point(&mut tok, "vertex", origin, line)?;
                tri[c] = welder.index(scaled(origin, Location::Line(line), p, scale)?);
                if c == 2 {
                    Expect::EndLoop
                } else {
                    Expect::Vertex(c + 1)
                }
            }
            (Expect::Vertex(c), _) => {
                return Err(at(
                    origin,
                    Location::Line(line),
                    format!(
                        "a facet needs 3 vertices, found {c} before `{}`",
                        raw.trim()
                    ),
                ))
            }
            (Expect::EndLoop, "endloop") => Expect::EndFacet,
            (Expect::EndLoop, "vertex") => {
                return Err(at(
                    origin,
                    Location::Line(line),
                    "a facet with more than 3 vertices (only triangles are STL facets)",
                ))
            }
            (Expect::EndLoop, _) => return Err(wrong("`endloop`")),
            (Expect::EndFacet, "endfacet") => {
                triangles.push(tri);
                lines.push(facet_line);
                Expect::FacetOrEnd
            }
            (Expect::EndFacet, _) => return Err(wrong("`endfacet`")),
        };
    }
    if expect != Expect::Solid && expect != Expect::FacetOrEnd {
        return Err(at(
            origin,
            Location::Line(last_line),
            "the file ends inside a facet",
        ));
    }
    if triangles.is_empty() {
        return Err(whole(origin, "empty: no facets"));
    }
    ClosedMesh::from_parts(origin, welder.positions_m, triangles, &|t| {
        Location::Line(lines[t])
    })
}
