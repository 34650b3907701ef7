//! `hydrometra scene run --scene default --scenario default --seconds 20 --out DIR` runs as
//! documented (docs/scene.md) and its ParaView series is read by an independent reader (Python
//! meshio): every file the PVD names opens, the cavity surfaces are closed triangle meshes whose
//! volume matches the CSV's, and the flow files carry labels and velocities; the CSV's measured
//! inflow equals the hydraulics' once the scope is in the cavity.

use hydrometra_hil_tests::{hydrometra, shared_atlas_cache};

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
    let o = std::process::Command::new("python3")
        .arg("-c")
        .arg(script)
        .arg(&out)
        .output()
        .expect("python3 with meshio and numpy (.ci/requirements.txt)");
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "the series did not read back: {stdout}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let _ = std::fs::remove_dir_all(&out);
}
