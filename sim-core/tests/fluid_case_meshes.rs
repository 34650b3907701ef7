//! Mesh regions of fluid case files (`shape = "mesh"`): a closed STL (binary, ASCII) or OBJ file
//! gives the cut fractions of the same solid as a built-in shape, its units scale to metres,
//! periodic axes treat it as the built-in shapes, and bad regions are refused naming the region
//! and key.

mod cutcell_common;

use cutcell_common::{ascii_stl, binary_stl, box_mesh, obj_text, rotation};
use hydrometra_sim::cutcell::mesh::ClosedMesh;
use hydrometra_sim::cutcell::shapes::{self, Tessellation};
use hydrometra_sim::fluid::case::Case;
use hydrometra_sim::fluid::FluidGrid;
use std::f64::consts::PI;
use std::path::PathBuf;

const H_M: f64 = 0.0005;
const CENTRE_M: [f64; 3] = [0.006, 0.004, 0.0041];
const RADIUS_M: f64 = 0.0025;

fn head(background: &str, periodic: [bool; 3]) -> String {
    format!(
        "[grid]\ncells = [24, 16, 16]\nspacing_m = {H_M}\nbackground = \"{background}\"\n\
         periodic = {periodic:?}\n[fluid]\ndensity_kg_m3 = 1000.0\nviscosity_m2_s = 1e-6\n\
         [time]\ndt_s = 0.001\nend_s = 0.002\n"
    )
}

/// A directory of this test's own files (each test names its files apart).
fn dir() -> PathBuf {
    let d = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("fluid-case-meshes");
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn mesh_region(file: &str, label: &str, extra: &str) -> String {
    format!("[[region]]\nshape = \"mesh\"\nlabel = \"{label}\"\nfile = \"{file}\"\n{extra}")
}

/// Builds the case's grid with the case file in [`dir`] (relative mesh files resolve there).
fn grid(text: &str) -> FluidGrid {
    Case::parse_at(text, Some(&dir().join("case.toml")))
        .unwrap()
        .build_grid()
        .unwrap()
}

/// Largest difference of the cell volume and face fractions, and whether the labels agree.
fn max_fraction_difference(a: &FluidGrid, b: &FluidGrid) -> f64 {
    assert_eq!(a.labels(), b.labels());
    let (fa, fb) = (a.cut_fractions().unwrap(), b.cut_fractions().unwrap());
    let diff = |x: &[f32], y: &[f32]| {
        assert_eq!(x.len(), y.len());
        x.iter()
            .zip(y)
            .map(|(p, q)| (p - q).abs() as f64)
            .fold(0.0, f64::max)
    };
    (0..3)
        .map(|c| diff(&fa.face[c], &fb.face[c]))
        .fold(diff(&fa.volume, &fb.volume), f64::max)
}

/// Writes the mesh as `<stem>.stl` (binary), `<stem>_ascii.stl` and `<stem>.obj`, coordinates
/// times `scale`; returns the three file names.
fn write_all(m: &ClosedMesh, stem: &str, scale: f32) -> [String; 3] {
    let names = [
        format!("{stem}.stl"),
        format!("{stem}_ascii.stl"),
        format!("{stem}.obj"),
    ];
    std::fs::write(dir().join(&names[0]), binary_stl(m, scale)).unwrap();
    std::fs::write(dir().join(&names[1]), ascii_stl(m, scale)).unwrap();
    std::fs::write(dir().join(&names[2]), obj_text(m, scale)).unwrap();
    names
}

/// Writes the tessellation of the built-in sphere region about `centre` in every format and
/// checks that each mesh region gives the sphere region's fractions (within `1e-6`) and a fluid
/// volume within `tolerance` of `exact`.
fn sphere_files_match_the_built_in_sphere(
    centre: [f64; 3],
    periodic: [bool; 3],
    stem: &str,
    exact: f64,
    tolerance: f64,
) {
    let head = head("solid", periodic);
    let sphere = format!(
        "{head}[[region]]\nshape = \"sphere\"\nlabel = \"fluid\"\ncentre_m = {centre:?}\n\
         radius_m = {RADIUS_M}\n"
    );
    let reference = grid(&sphere);
    let m = shapes::sphere(centre, RADIUS_M, Tessellation::for_spacing(H_M)).unwrap();
    for file in write_all(&m, stem, 1.0) {
        let g = grid(&(head.clone() + &mesh_region(&file, "fluid", "")));
        let d = max_fraction_difference(&g, &reference);
        let v = g.fluid_volume_m3();
        println!(
            "{file}: max fraction difference {d:e}, volume / exact - 1 = {:e}",
            v / exact - 1.0
        );
        assert!(d <= 1e-6, "{file}: {d}");
        assert!(
            (v - exact).abs() <= tolerance * exact,
            "{file}: {v} {exact}"
        );
    }
}

/// The sphere's own tessellation written to each format gives the built-in sphere region's
/// fractions: the files hold the same f32 vertices (binary bit for bit; the text forms print
/// f32s that parse back exactly), so the fractions agree to f32 rounding of their sums (1e-6).
/// Both carry the analytic volume within 1e-5 (the tessellation's volume is matched to the
/// sphere's; the fractions are exact for the polyhedron).
#[test]
fn mesh_files_of_a_sphere_give_the_built_in_sphere() {
    let exact = 4.0 / 3.0 * PI * RADIUS_M.powi(3);
    sphere_files_match_the_built_in_sphere(CENTRE_M, [false; 3], "sphere", exact, 1e-5);
}

/// A solid box tilted to the grid, as a mesh in fluid, removes exactly its volume `8 a b c` (a
/// polyhedron: no tessellation error; f32 vertices and fractions, so 1e-5 of the box), in every
/// format.
#[test]
fn a_tilted_solid_box_mesh_removes_its_volume() {
    let half = [0.0031, 0.0017, 0.0012];
    let m = box_mesh(half, &rotation(0.4, 0.7, -0.3), CENTRE_M, 1);
    let whole = 24.0 * 16.0 * 16.0 * H_M.powi(3);
    let exact = 8.0 * half[0] * half[1] * half[2];
    for file in write_all(&m, "tilted_box", 1.0) {
        let g = grid(&(head("fluid", [false; 3]) + &mesh_region(&file, "solid", "")));
        let removed = whole - g.fluid_volume_m3();
        println!("{file}: removed / exact - 1 = {:e}", removed / exact - 1.0);
        assert!(
            (removed - exact).abs() <= 1e-5 * exact,
            "{file}: {removed} {exact}"
        );
    }
}

/// The sphere in millimetres with `scale_m_per_unit = 1e-3` gives the metre file's fractions:
/// the scaled vertices differ from the metre ones by f32 rounding (about 1e-7 relative, 5e-10 m
/// here), which moves a cell's fraction by at most about 3 x 5e-10 / h = 3e-6; allowed 1e-5.
#[test]
fn scale_m_per_unit_turns_millimetres_into_metres() {
    let m = shapes::sphere(CENTRE_M, RADIUS_M, Tessellation::for_spacing(H_M)).unwrap();
    let metres = write_all(&m, "scale_m", 1.0);
    let millimetres = write_all(&m, "scale_mm", 1e3);
    for (m_file, mm_file) in metres.iter().zip(&millimetres) {
        let a = grid(&(head("solid", [false; 3]) + &mesh_region(m_file, "fluid", "")));
        let b = grid(
            &(head("solid", [false; 3])
                + &mesh_region(mm_file, "fluid", "scale_m_per_unit = 1e-3\n")),
        );
        let d = max_fraction_difference(&a, &b);
        let rel = b.fluid_volume_m3() / a.fluid_volume_m3() - 1.0;
        println!("{mm_file}: max fraction difference {d:e}, volume ratio - 1 = {rel:e}");
        assert!(d <= 1e-5, "{mm_file}: {d}");
        assert!(rel.abs() <= 1e-6, "{mm_file}: {rel}");
        // Without the scale the millimetre sphere lies metres away: no fluid in the grid.
        let c = grid(&(head("solid", [false; 3]) + &mesh_region(mm_file, "fluid", "")));
        assert_eq!(c.fluid_volume_m3(), 0.0, "{mm_file}");
    }
}

/// Curved regions do not wrap across a periodic axis (docs/fluid-cases.md): a mesh sphere
/// crossing the periodic x boundary is cut there exactly like the built-in sphere, keeping the
/// sphere minus the cap beyond x = 0 (the tessellation's local error on the cap, about its
/// area times the sagitta, bounds the match to 2e-3; a wrap would add the cap, 27 %).
#[test]
fn a_mesh_on_a_periodic_axis_is_cut_like_the_built_in_shapes() {
    let centre = [0.001, 0.004, 0.0041];
    let cap_m = RADIUS_M - centre[0];
    let exact =
        4.0 / 3.0 * PI * RADIUS_M.powi(3) - PI * cap_m * cap_m * (3.0 * RADIUS_M - cap_m) / 3.0;
    let periodic = [true, false, false];
    sphere_files_match_the_built_in_sphere(centre, periodic, "periodic_sphere", exact, 2e-3);
}

/// Every bad mesh region is an error naming `region[1]` (a box comes first), the key, and what
/// is wrong; none panics.
#[test]
fn bad_mesh_regions_name_the_region_and_key() {
    let m = shapes::sphere(CENTRE_M, RADIUS_M, Tessellation::for_spacing(H_M)).unwrap();
    let mut holed = binary_stl(&m, 1.0);
    holed.truncate(holed.len() - 50); // the last facet gone: a hole
    holed[80..84].copy_from_slice(&(m.triangles().len() as u32 - 1).to_le_bytes());
    std::fs::write(dir().join("holed.stl"), holed).unwrap();
    let text = ascii_stl(&m, 1.0);
    let cut = text.find("  facet").unwrap();
    let end = text[cut..].find("endfacet\n").unwrap() + cut + "endfacet\n".len();
    std::fs::write(
        dir().join("holed_ascii.stl"),
        format!("{}{}", &text[..cut], &text[end..]),
    )
    .unwrap();
    std::fs::write(dir().join("sphere.ply"), "ply\n").unwrap();
    std::fs::write(dir().join("bad_number.obj"), "v 0 0 0\nv 1 x 0\n").unwrap();
    std::fs::create_dir_all(dir().join("a_directory.stl")).unwrap();
    let good = "file = \"x.stl\"\n";
    let cases: &[(&str, &str, &[&str])] = &[
        (
            "shape = \"mesh\"\nlabel = \"fluid\"\n",
            "region[1].file",
            &["missing"],
        ),
        (
            "shape = \"mesh\"\nlabel = \"fluid\"\nfile = \"absent.stl\"\n",
            "region[1].file",
            &["absent.stl", "os error", "case.toml"],
        ),
        (
            "shape = \"mesh\"\nlabel = \"fluid\"\nfile = \"holed.stl\"\n",
            "region[1].file",
            &["not closed", "byte offset"],
        ),
        (
            "shape = \"mesh\"\nlabel = \"fluid\"\nfile = \"holed_ascii.stl\"\n",
            "region[1].file",
            &["not closed", "line"],
        ),
        (
            "shape = \"mesh\"\nlabel = \"fluid\"\nfile = \"bad_number.obj\"\n",
            "region[1].file",
            &["line 2", "not a number"],
        ),
        (
            "shape = \"mesh\"\nlabel = \"fluid\"\nfile = \"sphere.ply\"\n",
            "region[1].file",
            &[".stl or .obj"],
        ),
        (
            "shape = \"mesh\"\nlabel = \"fluid\"\nfile = \"a_directory.stl\"\n",
            "region[1].file",
            &["not a regular file"],
        ),
        (
            "shape = \"mesh\"\nlabel = \"outflow\"\nfile = \"x.stl\"\n",
            "region[1].label",
            &["fluid or solid"],
        ),
    ];
    let mut all: Vec<(String, String, &[&str])> = cases
        .iter()
        .map(|(r, k, w)| (r.to_string(), k.to_string(), *w))
        .collect();
    for scale in ["0.0", "-1e-3", "inf", "nan"] {
        all.push((
            format!("shape = \"mesh\"\nlabel = \"fluid\"\n{good}scale_m_per_unit = {scale}\n"),
            "region[1].scale_m_per_unit".into(),
            &["finite"],
        ));
    }
    for other in [
        "centre_m = [0.0, 0.0, 0.0]",
        "radius_m = 0.001",
        "axis = [0.0, 0.0, 1.0]",
        "length_m = 0.001",
        "min_m = [0.0, 0.0, 0.0]",
        "max_m = [0.0, 0.0, 0.0]",
        "velocity_m_s = [0.0, 0.0, 0.0]",
    ] {
        let key = other.split(' ').next().unwrap_or_default();
        all.push((
            format!("shape = \"mesh\"\nlabel = \"fluid\"\n{good}{other}\n"),
            format!("region[1].{key}"),
            &["only for shape"],
        ));
    }
    for shape in [
        "shape = \"sphere\"\ncentre_m = [0.0, 0.0, 0.0]\nradius_m = 0.001\n",
        "min_m = [0.0, 0.0, 0.0]\nmax_m = [0.001, 0.001, 0.001]\n",
    ] {
        for (extra, key) in [
            (good, "file"),
            ("scale_m_per_unit = 1.0\n", "scale_m_per_unit"),
        ] {
            all.push((
                format!("label = \"fluid\"\n{shape}{extra}"),
                format!("region[1].{key}"),
                &["only for shape mesh"],
            ));
        }
    }
    let first =
        "[[region]]\nlabel = \"solid\"\nmin_m = [0.0, 0.0, 0.0]\nmax_m = [0.001, 0.001, 0.001]\n";
    for (region, key, words) in &all {
        let text = format!("{}{first}[[region]]\n{region}", head("solid", [false; 3]));
        let e = Case::parse_at(&text, Some(&dir().join("case.toml")))
            .unwrap_err()
            .to_string();
        println!("{e}");
        assert!(e.contains(&format!("`{key}`")), "{key}: {e}");
        for w in *words {
            assert!(e.contains(w), "{key}: `{w}` not in {e}");
        }
    }
    // Parsed from text with no file of its own: a relative path cannot be resolved, an absolute
    // one is read.
    let text = head("solid", [false; 3]) + first + &mesh_region("sphere.stl", "fluid", "");
    let e = Case::parse(&text).unwrap_err().to_string();
    assert!(
        e.contains("`region[1].file`") && e.contains("relative"),
        "{e}"
    );
    write_all(&m, "absolute", 1.0);
    let absolute = dir().join("absolute.stl");
    let text = head("solid", [false; 3])
        + first
        + &mesh_region(&absolute.display().to_string(), "fluid", "");
    let g = Case::parse(&text).unwrap().build_grid().unwrap();
    let exact = 4.0 / 3.0 * PI * RADIUS_M.powi(3);
    assert!((g.fluid_volume_m3() - exact).abs() <= 1e-5 * exact);
}
