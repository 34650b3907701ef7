// Per-axis loops index several arrays at once.
#![allow(clippy::needless_range_loop)]
//! Shapes for fluid case files: the sphere and cylinder builders (volumes exact by construction,
//! any axis, closed and outward), and the STL (binary, ASCII) and OBJ readers, with errors that
//! name the file, the line or byte offset and what is wrong.

mod cutcell_common;

use cutcell_common::{ascii_stl, binary_stl};
use hydrometra_sim::cutcell::mesh::{ClosedMesh, MeshError};
use hydrometra_sim::cutcell::shapes::{self, Tessellation};
use std::f64::consts::PI;
use std::path::PathBuf;

fn tmp(name: &str) -> PathBuf {
    let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("cutcell-shapes-io");
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

fn err(r: Result<ClosedMesh, MeshError>) -> String {
    r.expect_err("an error").to_string()
}

#[test]
fn builders_give_closed_outward_meshes_with_the_exact_volume() {
    for (c, axis) in [
        ([0.0, 0.0, 0.0], [0.0, 0.0, 1.0]),
        ([0.01, -0.02, 0.03], [0.3, -0.7, 0.2]),
        ([0.0; 3], [1.0, 0.0, 0.0]),
    ] {
        for h in [0.001, 0.0004] {
            let s = shapes::sphere(c, 0.005, Tessellation::for_spacing(h)).unwrap();
            let v = 4.0 / 3.0 * PI * 0.005f64.powi(3);
            assert!(
                (s.volume_m3() - v).abs() < 1e-6 * v,
                "{}",
                s.volume_m3() / v - 1.0
            );
            let cyl =
                shapes::cylinder(c, axis, 0.002, 0.011, Tessellation::for_spacing(h)).unwrap();
            let v = PI * 0.002f64.powi(2) * 0.011;
            assert!(
                (cyl.volume_m3() - v).abs() < 1e-6 * v,
                "{}",
                cyl.volume_m3() / v - 1.0
            );
            // The sagitta rule: every vertex within h^2 / (32 R) (plus the volume matching's
            // scaling) of the sphere.
            let r_dev = s
                .positions_m()
                .iter()
                .map(|p| {
                    let d: f64 = (0..3)
                        .map(|a| (p[a] as f64 - c[a]).powi(2))
                        .sum::<f64>()
                        .sqrt();
                    (d - 0.005).abs()
                })
                .fold(0.0, f64::max);
            assert!(
                r_dev < h * h / (32.0 * 0.005) * 1.5,
                "{r_dev} {}",
                h * h / (32.0 * 0.005)
            );
        }
    }
    let e = err(shapes::sphere(
        [0.0; 3],
        -1.0,
        Tessellation::for_spacing(0.001),
    ));
    assert!(e.contains("sphere") && e.contains("radius_m = -1"), "{e}");
    let e = err(shapes::cylinder(
        [0.0; 3],
        [0.0; 3],
        0.001,
        0.01,
        Tessellation::for_spacing(0.001),
    ));
    assert!(e.contains("cylinder") && e.contains("axis"), "{e}");
    let e = err(shapes::sphere(
        [0.0; 3],
        1.0,
        Tessellation::for_spacing(1e-6),
    ));
    assert!(e.contains("triangles"), "{e}");
    let e = err(shapes::cylinder(
        [f64::NAN, 0.0, 0.0],
        [0.0, 0.0, 1.0],
        0.001,
        0.01,
        Tessellation::for_spacing(0.001),
    ));
    assert!(e.contains("centre_m"), "{e}");
}

#[test]
fn stl_and_obj_files_read_back_the_same_solid() {
    let m = shapes::cylinder(
        [0.001, 0.002, 0.003],
        [0.2, 0.3, 0.9],
        0.002,
        0.006,
        Tessellation::for_spacing(0.001),
    )
    .unwrap();
    let v = m.volume_m3();
    // Millimetres in the files, scaled back to metres.
    let bin = tmp("c.stl");
    std::fs::write(&bin, binary_stl(&m, 1e3)).unwrap();
    let asc = tmp("c_ascii.STL");
    std::fs::write(&asc, ascii_stl(&m, 1e3)).unwrap();
    let obj = tmp("c.obj");
    let mut s = String::from("# a cylinder\no cyl\n");
    for p in m.positions_m() {
        s += &format!("v {} {} {}\nvn 0 0 1\n", p[0] * 1e3, p[1] * 1e3, p[2] * 1e3);
    }
    let n = m.positions_m().len() as i64;
    for (i, t) in m.triangles().iter().enumerate() {
        // Mixed forms: v, v/vt/vn, v//vn, negative (relative) references.
        s += &match i % 3 {
            0 => format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1),
            1 => format!("f {}/1/1 {}//1 {}\n", t[0] + 1, t[1] + 1, t[2] as i64 - n),
            _ => format!("f {}//1 {} {}/2\n", t[0] as i64 - n, t[1] + 1, t[2] + 1),
        };
    }
    std::fs::write(&obj, s).unwrap();
    for path in [&bin, &asc, &obj] {
        let r = ClosedMesh::read(path, 1e-3).unwrap();
        assert!(
            (r.volume_m3() - v).abs() < 1e-6 * v,
            "{}: {} vs {v}",
            path.display(),
            r.volume_m3()
        );
    }
    // A quad mesh (a cube of quads) in OBJ, normals inwards: read, fanned, turned outwards.
    let cube = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n\
                f 1 2 3 4\nf 5 8 7 6\nf 1 5 6 2\nf 2 6 7 3\nf 3 7 8 4\nf 4 8 5 1\n";
    let r = ClosedMesh::parse_obj(cube.as_bytes(), "cube.obj", 0.01).unwrap();
    assert!((r.volume_m3() - 1e-6).abs() < 1e-12, "{}", r.volume_m3());
}

#[test]
fn bad_mesh_files_are_refused_with_where_and_what() {
    let m = shapes::sphere([0.0; 3], 0.003, Tessellation::for_spacing(0.002)).unwrap();
    // Binary: a hole (one facet dropped), an inconsistent facet, a NaN, a wrong size.
    let mut holed = binary_stl(&m, 1.0);
    holed.truncate(84 + 50 * (m.triangles().len() - 1));
    holed[80..84].copy_from_slice(&((m.triangles().len() - 1) as u32).to_le_bytes());
    let e = err(ClosedMesh::parse_stl(&holed, "holed.stl", 1.0));
    assert!(
        e.starts_with("holed.stl: byte offset ") && e.contains("not closed") && e.contains("hole"),
        "{e}"
    );
    let mut flipped = binary_stl(&m, 1.0);
    // Swap the second and third vertices of facet 5.
    let f = 84 + 50 * 5 + 12;
    let (a, b) = (
        flipped[f + 12..f + 24].to_vec(),
        flipped[f + 24..f + 36].to_vec(),
    );
    flipped[f + 12..f + 24].copy_from_slice(&b);
    flipped[f + 24..f + 36].copy_from_slice(&a);
    let e = err(ClosedMesh::parse_stl(&flipped, "flipped.stl", 1.0));
    assert!(e.contains("inconsistent orientation"), "{e}");
    let mut nan = binary_stl(&m, 1.0);
    let at = 84 + 50 * 7 + 12 + 12 + 4;
    nan[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    let e = err(ClosedMesh::parse_stl(&nan, "nan.stl", 1.0));
    assert!(
        e.contains(&format!("byte offset {}", 84 + 50 * 7 + 24)) && e.contains("not a finite"),
        "{e}"
    );
    let e = err(ClosedMesh::parse_stl(&holed[..200], "cut.stl", 1.0));
    assert!(
        e.contains("not an STL file") && e.contains("200 bytes"),
        "{e}"
    );
    let e = err(ClosedMesh::parse_stl(b"", "empty.stl", 1.0));
    assert!(e.contains("empty.stl: empty"), "{e}");
    let mut zero = vec![0u8; 84];
    zero[80] = 0;
    let e = err(ClosedMesh::parse_stl(&zero, "zero.stl", 1.0));
    assert!(e.contains("0 facets"), "{e}");
    // ASCII: a bad number, a quad facet, a truncated file, a hole (line of the facet).
    let text = ascii_stl(&m, 1.0);
    let bad = text.replacen("vertex ", "vertex x", 1);
    let e = err(ClosedMesh::parse_stl(bad.as_bytes(), "bad.stl", 1.0));
    assert!(
        e.contains("bad.stl: line 4:") && e.contains("not a number"),
        "{e}"
    );
    let inf = text.replacen("vertex ", "vertex inf ", 1);
    let e = err(ClosedMesh::parse_stl(inf.as_bytes(), "inf.stl", 1.0));
    assert!(
        e.contains("line 4") && (e.contains("not a finite") || e.contains("not a number")),
        "{e}"
    );
    let quad = text.replacen("    endloop\n", "      vertex 0 0 0\n    endloop\n", 1);
    let e = err(ClosedMesh::parse_stl(quad.as_bytes(), "quad.stl", 1.0));
    assert!(
        e.contains("line 7") && e.contains("more than 3 vertices"),
        "{e}"
    );
    let short = &text[..text.len() / 2];
    let e = err(ClosedMesh::parse_stl(short.as_bytes(), "short.stl", 1.0));
    assert!(
        e.contains("short.stl") && (e.contains("ends inside a facet") || e.contains("not closed")),
        "{e}"
    );
    let lines: Vec<&str> = text.lines().collect();
    let mut holed = lines[..1].to_vec();
    holed.extend(&lines[8..]);
    let e = err(ClosedMesh::parse_stl(
        holed.join("\n").as_bytes(),
        "holed.stl",
        1.0,
    ));
    assert!(
        e.starts_with("holed.stl: line ") && e.contains("not closed"),
        "{e}"
    );
    // OBJ: unknown statement, a dangling reference, a two-vertex face, no faces.
    for (obj, want) in [
        ("v 0 0 0\nvx 1 2 3\n", "line 2: unknown OBJ statement `vx`"),
        (
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n",
            "line 4: vertex reference 4",
        ),
        (
            "v 0 0 0\nv 1 0 0\nf 1 2\n",
            "line 3: a face needs at least 3 vertices",
        ),
        ("v 0 0 0\n", "empty: no faces"),
        ("v 0 0 nan\n", "line 1: vertex"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "line 4: not closed"),
    ] {
        let e = err(ClosedMesh::parse_obj(obj.as_bytes(), "m.obj", 1.0));
        assert!(
            e.starts_with("m.obj: ") && e.contains(want),
            "{e} (wanted {want})"
        );
    }
    let e = err(ClosedMesh::read(&tmp("nothing.xyz"), 1.0));
    assert!(
        e.contains("nothing.xyz") && e.contains(".stl or .obj"),
        "{e}"
    );
    let e = err(ClosedMesh::read(&tmp("missing.stl"), 1.0));
    assert!(e.contains("missing.stl: cannot read"), "{e}");
    let e = err(ClosedMesh::parse_stl(&binary_stl(&m, 1.0), "s.stl", -1.0));
    assert!(e.contains("scale_m_per_unit"), "{e}");
    // A flat closed surface (two triangles back to back) encloses nothing.
    let e = err(ClosedMesh::new(
        "flat",
        vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        vec![[0, 1, 2], [0, 2, 1]],
    ));
    assert!(e.contains("encloses no volume"), "{e}");
}
