//! Helpers shared by the cut-cell tests: test meshes, rigid transforms, boxes of cells around a
//! mesh, and independent exact references (convex clipping by half-spaces, circle/rectangle areas).
#![allow(dead_code)]

use hydrometra_sim::cutcell::mesh::ClosedMesh;
use hydrometra_sim::cutcell::{Orientation, SurfaceFractions};
use hydrometra_sim::scene::voxelize::VoxelBox;

pub type V3 = [f64; 3];

pub fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
pub fn add(a: V3, b: V3) -> V3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
pub fn scale(a: V3, s: f64) -> V3 {
    a.map(|x| x * s)
}
pub fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
pub fn cross(a: V3, b: V3) -> V3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
pub fn norm(a: V3) -> f64 {
    dot(a, a).sqrt()
}

/// A rotation matrix (rows) from Euler-like angles: about z by `a`, then x by `b`, then z by `c`.
pub fn rotation(a: f64, b: f64, c: f64) -> [V3; 3] {
    let rz = |t: f64| {
        [
            [t.cos(), -t.sin(), 0.0],
            [t.sin(), t.cos(), 0.0],
            [0.0, 0.0, 1.0],
        ]
    };
    let rx = |t: f64| {
        [
            [1.0, 0.0, 0.0],
            [0.0, t.cos(), -t.sin()],
            [0.0, t.sin(), t.cos()],
        ]
    };
    mul(rz(c), mul(rx(b), rz(a)))
}
pub fn mul(a: [V3; 3], b: [V3; 3]) -> [V3; 3] {
    std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| a[i][k] * b[k][j]).sum()))
}
pub fn apply(r: &[V3; 3], x: V3) -> V3 {
    std::array::from_fn(|i| dot(r[i], x))
}

/// A binary STL of the mesh, coordinates times `scale` (e.g. 1e3: millimetres).
pub fn binary_stl(m: &ClosedMesh, scale: f32) -> Vec<u8> {
    let mut b = vec![0u8; 80];
    b.extend((m.triangles().len() as u32).to_le_bytes());
    for t in m.triangles() {
        b.extend([0u8; 12]);
        for &v in t {
            for x in m.positions_m()[v as usize] {
                b.extend((x * scale).to_le_bytes());
            }
        }
        b.extend([0u8; 2]);
    }
    b
}

/// An ASCII STL of the mesh, coordinates times `scale`.
pub fn ascii_stl(m: &ClosedMesh, scale: f32) -> String {
    let mut s = String::from("solid test\n");
    for t in m.triangles() {
        s += "  facet normal 0 0 0\n    outer loop\n";
        for &v in t {
            let p = m.positions_m()[v as usize];
            s += &format!(
                "      vertex {:e} {:e} {:e}\n",
                p[0] * scale,
                p[1] * scale,
                p[2] * scale
            );
        }
        s += "    endloop\n  endfacet\n";
    }
    s + "endsolid test\n"
}

/// A Wavefront OBJ of the mesh (`v` and `f` statements), coordinates times `scale`.
pub fn obj_text(m: &ClosedMesh, scale: f32) -> String {
    let mut s = String::from("o test\n");
    for p in m.positions_m() {
        s += &format!("v {} {} {}\n", p[0] * scale, p[1] * scale, p[2] * scale);
    }
    for t in m.triangles() {
        s += &format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    s
}

/// A xorshift generator for reproducible "random-ish" parameters.
pub struct Rng(pub u64);
impl Rng {
    pub fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next()
    }
}

/// The box `centre + R diag(half) [-1, 1]^3`, each face split into `m x m` squares of two
/// triangles, outward normals.
pub fn box_mesh(half: V3, r: &[V3; 3], centre: V3, m: usize) -> ClosedMesh {
    let mut key = std::collections::HashMap::new();
    let mut pos: Vec<[f32; 3]> = Vec::new();
    let mut tris = Vec::new();
    let mut vid = |l: [usize; 3], pos: &mut Vec<[f32; 3]>| -> u32 {
        *key.entry(l).or_insert_with(|| {
            let local: V3 = std::array::from_fn(|a| half[a] * (2.0 * l[a] as f64 / m as f64 - 1.0));
            let x = add(apply(r, local), centre);
            pos.push(x.map(|c| c as f32));
            (pos.len() - 1) as u32
        })
    };
    for axis in 0..3 {
        for side in [0, m] {
            let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
            for u in 0..m {
                for v in 0..m {
                    let at = |du: usize, dv: usize| {
                        let mut l = [0; 3];
                        l[axis] = side;
                        l[a] = u + du;
                        l[b] = v + dv;
                        l
                    };
                    let q = [at(0, 0), at(1, 0), at(1, 1), at(0, 1)];
                    let q = q.map(|l| vid(l, &mut pos));
                    // (a, b, axis) is right-handed: a x b = +axis, outward on the high side.
                    if side == m {
                        tris.push([q[0], q[1], q[2]]);
                        tris.push([q[0], q[2], q[3]]);
                    } else {
                        tris.push([q[0], q[2], q[1]]);
                        tris.push([q[0], q[3], q[2]]);
                    }
                }
            }
        }
    }
    ClosedMesh::new("box", pos, tris).unwrap()
}

/// Applies `x -> R (S x) + c` to a mesh's positions.
pub fn transformed(mesh: &ClosedMesh, s: V3, r: &[V3; 3], c: V3) -> ClosedMesh {
    let pos = mesh
        .positions_m()
        .iter()
        .map(|p| {
            let x: V3 = std::array::from_fn(|a| p[a] as f64 * s[a]);
            add(apply(r, x), c).map(|v| v as f32)
        })
        .collect();
    ClosedMesh::new("transformed", pos, mesh.triangles().to_vec()).unwrap()
}

/// The polyhedron's own volume from its f32 vertices, in f64.
pub fn polyhedron_volume(mesh: &ClosedMesh) -> f64 {
    mesh.volume_m3()
}

/// A box of cells of edge `h` around the mesh with `margin` cells each side, its corner shifted by
/// `shift` cells (so vertices do not sit on planes by construction unless asked).
pub fn box_around(mesh: &ClosedMesh, h: f64, margin: usize, shift: V3) -> VoxelBox {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in mesh.positions_m() {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a] as f64);
            hi[a] = hi[a].max(p[a] as f64);
        }
    }
    VoxelBox {
        dims: std::array::from_fn(|a| ((hi[a] - lo[a]) / h).ceil() as usize + 2 * margin + 1),
        origin_m: std::array::from_fn(|a| lo[a] - (margin as f64 + shift[a]) * h),
        spacing_m: h,
    }
}

/// The exact fractions of `mesh` on `cells`.
pub fn fractions(mesh: &ClosedMesh, cells: VoxelBox) -> SurfaceFractions {
    let mut f = SurfaceFractions::new(
        "test",
        cells,
        mesh.triangles().to_vec(),
        mesh.positions_m().len(),
        Orientation::Outward,
    )
    .unwrap();
    f.full(mesh.positions_m()).unwrap();
    f
}

/// Sum of the volume fractions times h^3.
pub fn fluid_volume(f: &SurfaceFractions) -> f64 {
    let h = f.cells().spacing_m;
    f.volume_fractions().iter().sum::<f64>() * h * h * h
}

/// Largest `|sum over faces of +-A_f e_f + S|` over the cells (cell units).
pub fn max_divergence_defect(f: &SurfaceFractions) -> f64 {
    let [nx, ny, nz] = f.cells().dims;
    let (fx, fy, fz) = (
        f.face_fractions(0),
        f.face_fractions(1),
        f.face_fractions(2),
    );
    let mut worst: f64 = 0.0;
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let s = f.interface_areas()[f.cells().index(i, j, k)];
                let dx = fx[i + 1 + (nx + 1) * (j + ny * k)] - fx[i + (nx + 1) * (j + ny * k)];
                let dy = fy[i + nx * (j + 1 + (ny + 1) * k)] - fy[i + nx * (j + (ny + 1) * k)];
                let dz = fz[i + nx * (j + ny * (k + 1))] - fz[i + nx * (j + ny * k)];
                let d = [dx + s[0], dy + s[1], dz + s[2]];
                worst = worst.max(d.iter().map(|x| x.abs()).fold(0.0, f64::max));
            }
        }
    }
    worst
}

/// A convex region as half-spaces `n . x <= d`.
pub struct Convex(pub Vec<(V3, f64)>);

impl Convex {
    /// The half-spaces of a closed convex mesh's triangles (outward normals), one per distinct
    /// plane.
    pub fn of_mesh(mesh: &ClosedMesh) -> Convex {
        let mut planes: Vec<(V3, f64)> = Vec::new();
        for t in mesh.triangles() {
            let [a, b, c] = t.map(|i| mesh.positions_m()[i as usize].map(f64::from));
            let n = cross(sub(b, a), sub(c, a));
            let l = norm(n);
            if l < 1e-300 {
                continue;
            }
            let n = scale(n, 1.0 / l);
            // The plane through the triangle's centroid (the vertices are coplanar up to f32).
            let g = scale(add(add(a, b), c), 1.0 / 3.0);
            let d = dot(n, g);
            if !planes
                .iter()
                .any(|(m, e)| dot(*m, n) > 1.0 - 1e-12 && (e - d).abs() < 1e-12)
            {
                planes.push((n, d));
            }
        }
        Convex(planes)
    }

    /// Volume of the axis-aligned box `[lo, hi]` inside the region (clipping its faces).
    pub fn box_volume(&self, lo: V3, hi: V3) -> f64 {
        let mut faces = box_faces(lo, hi);
        let mut caps: Vec<Vec<V3>> = Vec::new();
        for &(n, d) in &self.0 {
            let mut cut_points = Vec::new();
            for f in &mut faces {
                *f = clip_polygon(f, n, d, &mut cut_points);
            }
            faces.retain(|f| f.len() >= 3);
            for c in &mut caps {
                *c = clip_polygon(c, n, d, &mut cut_points);
            }
            caps.retain(|c| c.len() >= 3);
            if cut_points.len() >= 3 {
                caps.push(convex_hull_on_plane(&cut_points, n));
            }
        }
        // Divergence theorem with the field x / 3 over the closed polyhedron.
        faces
            .iter()
            .chain(caps.iter())
            .map(|f| {
                let mut v = 0.0;
                for m in 1..f.len() - 1 {
                    v += dot(f[0], cross(f[m], f[m + 1]));
                }
                v / 6.0
            })
            .sum()
    }

    /// Area of a planar convex polygon inside the region.
    pub fn polygon_area(&self, poly: &[V3]) -> f64 {
        let mut p = poly.to_vec();
        for &(n, d) in &self.0 {
            p = clip_polygon(&p, n, d, &mut Vec::new());
            if p.len() < 3 {
                return 0.0;
            }
        }
        let mut s = [0.0; 3];
        for m in 1..p.len() - 1 {
            s = add(s, cross(sub(p[m], p[0]), sub(p[m + 1], p[0])));
        }
        0.5 * norm(s)
    }
}

/// The six faces of a box, outward (counter-clockwise seen from outside).
fn box_faces(lo: V3, hi: V3) -> Vec<Vec<V3>> {
    let c = |i: usize, j: usize, k: usize| -> V3 {
        [
            if i == 0 { lo[0] } else { hi[0] },
            if j == 0 { lo[1] } else { hi[1] },
            if k == 0 { lo[2] } else { hi[2] },
        ]
    };
    vec![
        vec![c(0, 0, 0), c(0, 0, 1), c(0, 1, 1), c(0, 1, 0)],
        vec![c(1, 0, 0), c(1, 1, 0), c(1, 1, 1), c(1, 0, 1)],
        vec![c(0, 0, 0), c(1, 0, 0), c(1, 0, 1), c(0, 0, 1)],
        vec![c(0, 1, 0), c(0, 1, 1), c(1, 1, 1), c(1, 1, 0)],
        vec![c(0, 0, 0), c(0, 1, 0), c(1, 1, 0), c(1, 0, 0)],
        vec![c(0, 0, 1), c(1, 0, 1), c(1, 1, 1), c(0, 1, 1)],
    ]
}

/// Sutherland-Hodgman against `n . x <= d`; the points created on the plane are added to `cut`.
fn clip_polygon(p: &[V3], n: V3, d: f64, cut: &mut Vec<V3>) -> Vec<V3> {
    let mut out = Vec::new();
    for s in 0..p.len() {
        let a = p[s];
        let b = p[(s + 1) % p.len()];
        let (da, db) = (dot(n, a) - d, dot(n, b) - d);
        if da <= 0.0 {
            out.push(a);
            if da == 0.0 {
                cut.push(a);
            }
        }
        if (da <= 0.0) != (db <= 0.0) {
            let t = da / (da - db);
            let x = add(a, scale(sub(b, a), t));
            out.push(x);
            cut.push(x);
        }
    }
    out
}

/// The convex polygon through coplanar points, ordered counter-clockwise about `n` (the cap
/// closing a clipped convex polyhedron, facing `n`).
fn convex_hull_on_plane(points: &[V3], n: V3) -> Vec<V3> {
    let c = scale(
        points.iter().fold([0.0; 3], |s, p| add(s, *p)),
        1.0 / points.len() as f64,
    );
    let u = {
        let e = if n[0].abs() < 0.9 {
            [1.0, 0.0, 0.0]
        } else {
            [0.0, 1.0, 0.0]
        };
        let u = cross(n, e);
        scale(u, 1.0 / norm(u))
    };
    let w = cross(n, u);
    let mut pts: Vec<(f64, V3)> = points
        .iter()
        .map(|p| {
            let q = sub(*p, c);
            (dot(q, w).atan2(dot(q, u)), *p)
        })
        .collect();
    pts.sort_by(|a, b| a.0.total_cmp(&b.0));
    pts.into_iter().map(|x| x.1).collect()
}

/// Area of `{x in [x0, x1], y in [y0, y1], x^2 + y^2 <= r^2}` (exact).
pub fn circle_rect_area(r: f64, x0: f64, x1: f64, y0: f64, y1: f64) -> f64 {
    let (a, b) = (x0.max(-r), x1.min(r));
    if a >= b {
        return 0.0;
    }
    // Breakpoints where the chord's ends cross y0 or y1.
    let mut xs = vec![a, b];
    for y in [y0, y1] {
        if y.abs() < r {
            let s = (r * r - y * y).sqrt();
            for x in [-s, s] {
                if x > a && x < b {
                    xs.push(x);
                }
            }
        }
    }
    xs.sort_by(f64::total_cmp);
    // G(x) = integral of sqrt(r^2 - t^2) from 0 to x.
    let g = |x: f64| {
        0.5 * (x * (r * r - x * x).max(0.0).sqrt() + r * r * (x / r).clamp(-1.0, 1.0).asin())
    };
    let mut area = 0.0;
    for w in xs.windows(2) {
        let (p, q) = (w[0], w[1]);
        if q <= p {
            continue;
        }
        let m = 0.5 * (p + q);
        let s = (r * r - m * m).sqrt();
        // Upper: min(y1, s), lower: max(y0, -s); constant choice on the piece.
        let upper = if y1 < s { y1 * (q - p) } else { g(q) - g(p) };
        let lower = if y0 > -s {
            y0 * (q - p)
        } else {
            -(g(q) - g(p))
        };
        if y1.min(s) > y0.max(-s) {
            area += upper - lower;
        }
    }
    area
}

/// A bipyramid over a regular `n`-gon of radius `r` in the plane normal to `R e_z` through `c`,
/// apexes `top` and `bottom` along that normal: convex whatever the rounding of its vertices, so
/// the half-spaces of its triangles describe it exactly.
pub fn bipyramid(n: usize, r: f64, top: f64, bottom: f64, rot: &[V3; 3], c: V3) -> ClosedMesh {
    let mut pos: Vec<[f32; 3]> = Vec::new();
    let put = |x: V3, pos: &mut Vec<[f32; 3]>| {
        pos.push(add(apply(rot, x), c).map(|v| v as f32));
        (pos.len() - 1) as u32
    };
    let ring: Vec<u32> = (0..n)
        .map(|i| {
            let t = 2.0 * std::f64::consts::PI * i as f64 / n as f64;
            put([r * t.cos(), r * t.sin(), 0.0], &mut pos)
        })
        .collect();
    let a = put([0.0, 0.0, top], &mut pos);
    let b = put([0.0, 0.0, -bottom], &mut pos);
    let mut tris = Vec::new();
    for i in 0..n {
        let (p, q) = (ring[i], ring[(i + 1) % n]);
        tris.push([a, p, q]);
        tris.push([b, q, p]);
    }
    ClosedMesh::new("bipyramid", pos, tris).unwrap()
}

/// The tetrahedron of four points.
pub fn tetrahedron(p: [V3; 4]) -> ClosedMesh {
    let pos = p.iter().map(|x| x.map(|v| v as f32)).collect();
    ClosedMesh::new(
        "tetrahedron",
        pos,
        vec![[0, 1, 2], [0, 3, 1], [1, 3, 2], [0, 2, 3]],
    )
    .unwrap()
}

/// Every cell's volume and every face's area of `f` against the half-space clipping of `conv`;
/// returns the largest difference (fractions).
pub fn max_difference_from_convex(f: &SurfaceFractions, conv: &Convex) -> f64 {
    let cells = *f.cells();
    let [nx, ny, nz] = cells.dims;
    let h = cells.spacing_m;
    let corner = |i: usize, j: usize, k: usize| -> V3 {
        std::array::from_fn(|a| cells.origin_m[a] + [i, j, k][a] as f64 * h)
    };
    let mut worst: f64 = 0.0;
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let lo = corner(i, j, k);
                let e = conv.box_volume(lo, lo.map(|x| x + h)) / (h * h * h);
                let d = (e - f.volume_fractions()[cells.index(i, j, k)]).abs();
                assert!(
                    d < 1e-9,
                    "cell {i},{j},{k}: {e} exact, {} computed",
                    f.volume_fractions()[cells.index(i, j, k)]
                );
                worst = worst.max(d);
            }
        }
    }
    for axis in 0..3 {
        let mut d = cells.dims;
        d[axis] += 1;
        let (b, c) = ((axis + 1) % 3, (axis + 2) % 3);
        for k in 0..d[2] {
            for j in 0..d[1] {
                for i in 0..d[0] {
                    let o = corner(i, j, k);
                    let mut eb = [0.0; 3];
                    eb[b] = h;
                    let mut ec = [0.0; 3];
                    ec[c] = h;
                    let square = [o, add(o, eb), add(add(o, eb), ec), add(o, ec)];
                    let e = conv.polygon_area(&square) / (h * h);
                    let got = f.face_fractions(axis)[i + d[0] * (j + d[1] * k)];
                    let diff = (e - got).abs();
                    assert!(
                        diff < 1e-9,
                        "face {axis} {i},{j},{k}: {e} exact, {got} computed"
                    );
                    worst = worst.max(diff);
                }
            }
        }
    }
    worst
}

/// The built-in default scene on cells of `voxel_mm` with its atlas from the shared test cache
/// `target/hil-atlas` (built there, under its lock file, if missing: minutes).
pub fn default_scene(voxel_mm: f64) -> hydrometra_sim::scene::Scene {
    use hydrometra_sim::scene::{prepare, Scene, SceneDesc};
    let exe = std::env::current_exe().expect("current_exe");
    // target/<profile>/deps/<test> -> target/hil-atlas
    let dir = exe
        .ancestors()
        .nth(3)
        .expect("target/<profile>/deps")
        .join("hil-atlas");
    std::fs::create_dir_all(&dir).expect("atlas cache dir");
    let mut desc = SceneDesc::builtin("default").expect("the default scene");
    desc.fluid.voxel_mm = voxel_mm;
    let lock = std::fs::File::create(dir.join(".lock")).expect("atlas cache lock file");
    lock.lock().expect("lock the atlas cache");
    let (assets, _) =
        prepare::load_or_build(&desc, Some(&dir), &mut |_, _, _, _| {}).expect("the default atlas");
    drop(lock);
    Scene::new(desc, assets).expect("the default scene")
}

/// The cavity surface's layer (normals into the fluid) for a [`hydrometra_sim::cutcell::CutCells`].
pub fn cavity_layer(
    s: &hydrometra_sim::scene::surface::CavitySurface,
) -> hydrometra_sim::cutcell::Layer {
    hydrometra_sim::cutcell::Layer {
        name: "cavity".into(),
        triangles: s.triangles().to_vec(),
        vertex_count: s.vertex_count(),
        orientation: Orientation::Inward,
        inside: hydrometra_sim::cutcell::Phase::Fluid,
    }
}

/// A layer of a mesh's triangles (flipped for `Inward`).
pub fn layer(
    name: &str,
    mesh: &ClosedMesh,
    orientation: Orientation,
    inside: hydrometra_sim::cutcell::Phase,
) -> hydrometra_sim::cutcell::Layer {
    let triangles = match orientation {
        Orientation::Outward => mesh.triangles().to_vec(),
        Orientation::Inward => mesh
            .triangles()
            .iter()
            .map(|t| [t[0], t[2], t[1]])
            .collect(),
    };
    hydrometra_sim::cutcell::Layer {
        name: name.into(),
        triangles,
        vertex_count: mesh.positions_m().len(),
        orientation,
        inside,
    }
}

/// The cavity surface of `scene` replayed at each of `mmhg`, its positions.
pub fn replayed(scene: &hydrometra_sim::scene::Scene, mmhg: &[f64]) -> Vec<Vec<[f32; 3]>> {
    let mut surface = scene.cavity_surface().clone();
    let compact = surface.compact_atlas(scene.atlas()).expect("compact atlas");
    mmhg.iter()
        .map(|&p| {
            surface
                .replay_compact(&compact, hydrometra_sim::units::mmhg_to_pa(p))
                .expect("replay");
            surface.positions_m().to_vec()
        })
        .collect()
}
