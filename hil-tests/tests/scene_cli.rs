//! `hydrometra scene run --scene default --scenario default --seconds 20 --out DIR` runs as
//! documented (docs/scene.md) and its ParaView series is read by an independent reader (Python
//! meshio): every file the PVD names opens, the cavity surfaces are closed triangle meshes whose
//! volume matches the CSV's, and the flow files carry labels and velocities; the CSV's measured
//! inflow equals the hydraulics' once the scope is in the cavity.

use hydrometra_hil_tests::{hydrometra, shared_atlas_cache, temp_dir};

/// Runs the Python `script` (meshio, numpy) on the output directory `out`; fails the test with
/// its output unless it succeeds; returns its standard output.
fn read_back(script: &str, out: &std::path::Path, what: &str) -> String {
    let o = std::process::Command::new("python3")
        .arg("-c")
        .arg(script)
        .arg(out)
        .output()
        .expect("python3 with meshio and numpy (.ci/requirements.txt)");
    let stdout = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(
        o.status.success(),
        "{what} did not read back: {stdout}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    stdout
}

#[test]
fn scene_run_writes_a_paraview_series_meshio_reads() {
    let cache = shared_atlas_cache("default");
    let out = std::env::temp_dir().join(format!("hydrometra-scene-run-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let printed = hydrometra(&[
        "scene",
        "run",
        "--scene",
        "default",
        "--scenario",
        "default",
        "--seconds",
        "20",
        "--out",
        out.to_str().unwrap(),
        "--cache-dir",
        cache.to_str().unwrap(),
    ]);
    assert!(printed.contains("scene.pvd"), "{printed}");
    let script = r#"
import sys, os, re, csv
import meshio
import numpy as np
out = sys.argv[1]
pvd = open(os.path.join(out, "scene.pvd")).read()
files = re.findall(r'file="([^"]+)"', pvd)
cav = [f for f in files if f.endswith("_cavity.vtu")]
flow = [f for f in files if f.endswith("_flow.vtu")]
assert len(cav) == len(flow) == 200, (len(cav), len(flow))
vols = []
for f in cav:
    m = meshio.read(os.path.join(out, f))
    tri = m.cells_dict["triangle"]
    p = m.points.astype(float)
    a, b, c = p[tri[:, 0]], p[tri[:, 1]], p[tri[:, 2]]
    # Normals into the fluid: the divergence-theorem sum is negative.
    vols.append(-np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)
    # Closed: every edge is shared by exactly two triangles, once in each direction.
    edges = {}
    for t in tri:
        for k in range(3):
            e = (int(t[k]), int(t[(k + 1) % 3]))
            edges[e] = edges.get(e, 0) + 1
    assert all(edges.get((b_, a_), 0) == 1 for (a_, b_) in edges), f
labels = set()
for f in flow[-5:]:
    m = meshio.read(os.path.join(out, f))
    lab = m.cell_data_dict["label"]["hexahedron"] if "hexahedron" in m.cell_data_dict["label"] else list(m.cell_data_dict["label"].values())[0]
    vel = list(m.cell_data_dict["velocity"].values())[0]
    assert vel.shape[1] == 3 and np.isfinite(vel).all()
    labels |= set(int(x) for x in lab)
rows = list(csv.DictReader(open(os.path.join(out, "scene.csv"))))
assert len(rows) == 1200, len(rows)
# The surface volume every 6th frame against the CSV's.
for k, v in enumerate(vols):
    want = float(rows[6 * k + 5]["surface_volume_ml"]) * 1e-6
    assert abs(v - want) <= 1e-3 * want, (k, v, want)
late = [r for r in rows if float(r["time_s"]) > 15.0 and r["fluid_ran"] == "1"]
assert late, "the fluid ran after 15 s"
for r in late:
    hin, fin = float(r["inflow_ml_min"]), float(r["fluid_inflow_ml_min"])
    assert abs(fin - hin) <= 1e-3 * abs(hin) + 2e-3, (r["time_s"], hin, fin)
# Fluid, inflow port and cavity wall cells are in the last frames.
assert {1, 2, 5} <= labels, labels
print(len(cav), sorted(labels), "%.4f" % (vols[-1] * 1e6))
"#;
    read_back(script, &out, "the series");
    let _ = std::fs::remove_dir_all(&out);
}

/// The default scene with the particle stage on: a bleed on the posterior fundal wall from 12 s
/// and bubbles with the inflow (the built-in `default` scene has no particle stage).
const BLEED_SCENE: &str = r#"
name = "default-bleed"
[anatomy]
parity = "parous"
[stages]
particles = true
[particles.bubbles]
per_ml = 5.0
[[particles.blood.sources]]
position_mm = [0.0, 12.0, 55.0]
rate_ml_min = 1.0
onset_s = 12.0
"#;

#[test]
fn scene_run_writes_the_particles_into_the_series_meshio_reads() {
    let dir = temp_dir("scene-run-particles");
    let scene = dir.join("default-bleed.toml");
    std::fs::write(&scene, BLEED_SCENE).unwrap();
    // Same anatomy and atlas settings as `default`: the shared cache holds its atlas.
    let cache = shared_atlas_cache(scene.to_str().unwrap());
    let out = dir.join("out");
    hydrometra(&[
        "scene",
        "run",
        "--scene",
        scene.to_str().unwrap(),
        "--scenario",
        "default",
        "--seconds",
        "24",
        "--every",
        "12",
        "--out",
        out.to_str().unwrap(),
        "--cache-dir",
        cache.to_str().unwrap(),
    ]);
    let script = r#"
import sys, os, re, csv, json
import meshio
import numpy as np
out = sys.argv[1]
pvd = open(os.path.join(out, "scene.pvd")).read()
sets = re.findall(r'timestep="([^"]+)"[^>]*part="(\d)"[^>]*file="([^"]+)"', pvd)
parts = {p: [(float(t), f) for (t, q, f) in sets if q == p] for p in "012"}
# One particle file per series frame, at the cavity's and the flow's times.
assert len(parts["2"]) == len(parts["0"]) == len(parts["1"]) == 120, {p: len(v) for p, v in parts.items()}
assert [t for t, _ in parts["2"]] == [t for t, _ in parts["0"]]
assert all(f.endswith("_particles.vtu") for _, f in parts["2"])
rows = list(csv.DictReader(open(os.path.join(out, "scene.csv"))))
summary = json.load(open(os.path.join(out, "summary.json")))["particles"]
seen_kinds = set()
counts = []
for k, (t, f) in enumerate(parts["2"]):
    row = rows[12 * k + 11]
    assert abs(float(row["time_s"]) - t) < 1e-3, (row["time_s"], t)
    text = open(os.path.join(out, f)).read()
    if 'NumberOfPoints="0"' in text:
        # meshio cannot read a grid without cells (ParaView can): checked by its header.
        assert int(row["particles_alive"]) == 0, (t, row["particles_alive"])
        counts.append(0)
        continue
    m = meshio.read(os.path.join(out, f))
    n = len(m.points)
    # The file holds the particles the CSV counts at that frame.
    assert n == int(row["particles_alive"]), (t, n, row["particles_alive"])
    counts.append(n)
    pd = m.point_data
    kind, d, age, vel = pd["kind"], pd["diameter_m"], pd["age_s"], pd["velocity"]
    assert kind.shape == (n,) and d.shape == (n,) and age.shape == (n,) and vel.shape == (n, 3)
    assert set(int(x) for x in kind) <= {0, 1, 2}
    seen_kinds |= set(int(x) for x in kind)
    assert np.isfinite(m.points).all() and np.isfinite(vel).all()
    # Ages within the run; blood no older than its onset allows (a particle is emitted at the
    # start of a step and ages by that step: one frame); speeds below twice the fastest inflow
    # jet of the hydraulics (2.6 m/s at the default's flows).
    assert (age >= 0).all() and (age <= t + 1e-3).all()
    assert (age[kind == 0] <= t - 12.0 + 1.0 / 60.0 + 1e-3).all()
    assert (np.linalg.norm(vel, axis=1) < 5.0).all()
    # Inside the cavity's box of the same frame, within a voxel (1.2 mm).
    cav = meshio.read(os.path.join(out, parts["0"][k][1])).points
    lo, hi = cav.min(axis=0) - 1.2e-3, cav.max(axis=0) + 1.2e-3
    assert ((m.points >= lo) & (m.points <= hi)).all(), (t, m.points.min(axis=0), m.points.max(axis=0), lo, hi)
# Blood (from 12 s) and bubbles (with the inflow, from 8 s) are in the series.
assert {0, 1} <= seen_kinds, seen_kinds
assert counts[-1] > 0
# Blood: 1 ml/min for 12 s at 0.01 ul per particle, plus at most one frame's worth (the source's
# rate is sampled at each step's end, so the step ending at the onset emits).
want = 1.0 / 60.0 * 12.0 / 1e-5
frame = 1.0 / 60.0 / 60.0 / 1e-5
emitted = summary["emitted"][0]
assert 0.9 * want <= emitted <= want + frame + 1, (emitted, want, summary)
alive = summary["alive"]
assert alive[0] + alive[1] + alive[2] == counts[-1], (alive, counts[-1])
clar = [float(r["clarity"]) for r in rows if r["clarity"] != ""]
assert clar and all(0.0 <= c <= 1.0 for c in clar), clar[:5]
print(counts[-1], summary)
"#;
    let stdout = read_back(script, &out, "the particles");
    eprintln!("{stdout}");
    let _ = std::fs::remove_dir_all(&dir);
}
