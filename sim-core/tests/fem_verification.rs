//! Verification of the FEM against analytic solutions (references.md section 1).

use hydrometra_sim::fem::analytic;
use hydrometra_sim::fem::material::{Material, MaterialSet};
use hydrometra_sim::fem::testmesh::{self, TestCase};
use hydrometra_sim::fem::{FemModel, Solver};

fn model(case: &TestCase, mat: &Material) -> FemModel {
    FemModel::from_parts(case.positions_m.clone(), case.tets.clone(), &MaterialSet::uniform(mat.clone()), case.fixed_dofs.clone(), case.cavity.clone()).unwrap()
}

/// Inner stretch of the FEM thick sphere (A = 1) at `pressure`, measured from the cavity volume.
fn sphere_stretch(mat: &Material, inner: f64, outer: f64, divisions: usize, layers: usize, pressure: f64) -> f64 {
    let case = testmesh::thick_sphere_octant(inner, outer, divisions, layers);
    let m = model(&case, mat);
    let mut s = Solver::new(&m, Default::default()).unwrap();
    let rest = s.rest_state();
    let loaded = s.solve_to_pressure(&rest, pressure).unwrap();
    eprintln!("tets {} sizes {:?} counters {:?}", case.tets.len(), s.sizes(), s.counters);
    (loaded.cavity_volume_m3 / rest.cavity_volume_m3).cbrt()
}

#[test]
fn scratch_sphere() {
    let mat = Material::neo_hookean(1.0, 1000.0);
    for (n, l) in [(16, 8), (24, 8)] {
        let t = std::time::Instant::now();
        let la = sphere_stretch(&mat, 1.0, 2.0, n, l, 0.287092);
        eprintln!("n {n} l {l}: la {la} err {:.4} % {:?}", ((la - 1.0) / 0.1 - 1.0) * 100.0, t.elapsed());
    }
    let _ = analytic::sphere_outer_stretch(1.0, 2.0, 1.1);
}
