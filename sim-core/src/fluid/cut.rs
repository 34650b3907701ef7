//! Cut-cell weights of a grid: per cell the fluid volume fraction, per MAC face the open area
//! fraction (Batty, Bertails and Bridson 2007; Ng, Min and Gibou 2009).
//!
//! The projection is the area-weighted one: a fluid cell's divergence is `sum A_f u_f` over its
//! faces (`h^2` times the flux), the pressure update acts on faces with `A_f > 0`, and the
//! operator `D A G` (couplings `A_f` between neighbours, the diagonal their sum) stays symmetric
//! positive (semi-)definite, so the multigrid-preconditioned CG solves it as the plain one. The
//! volume fractions are what the grid carries (`sum V_i h^3`); they do not enter a projection
//! with walls at rest.
//!
//! A grid without cut cells (every fraction 1) stores none ([`CutFractions::is_whole`]), and the
//! solver then runs today's unweighted kernels: bit for bit the discretisation without cut cells.

use super::FluidError;
use crate::cutcell::{FaceWalls, NO_WALL};

/// The fractions of one grid, in the solver's layouts: cells x fastest, faces of component `c` in
/// `dims` with `dims[c] + 1` along `c` unless `c` is periodic (face `f` lies between cells
/// `f - e_c` and `f`; on a periodic axis face 0 is the one between the last cell and the first).
#[derive(Clone, Debug, PartialEq)]
pub struct CutFractions {
    /// Fluid volume fraction per cell (`>= 0`; a merge target of the small-cell rule may hold
    /// more than 1).
    pub volume: Vec<f32>,
    /// Open area fraction per face, per component (`[0, 1]`).
    pub face: [Vec<f32>; 3],
    /// Where the walls cross the viscous stencil's arms (faces in the solver's layout; see
    /// [`FaceWalls`], [`CutFractions::walls_from_box`]): with them the viscous step puts the
    /// no-slip wall at its distance (`fluid/cut_viscosity.rs`), without them (`None`) at the
    /// staircase of the labels.
    pub walls: Option<FaceWalls>,
}

/// Largest volume fraction accepted: a merge target holds its own cell and at most a neighbour's
/// small part (below 1), so 2 bounds every legitimate value.
const MAX_VOLUME_FRACTION: f32 = 2.0;

impl CutFractions {
    /// Every fraction 1 on a grid of `dims` cells (faces as the solver lays them out).
    pub fn whole(dims: [usize; 3], periodic: [bool; 3]) -> Self {
        let n = dims.iter().product();
        Self {
            volume: vec![1.0; n],
            face: std::array::from_fn(|c| vec![1.0; face_count(dims, periodic, c)]),
            walls: None,
        }
    }

    /// Checks the sizes and the values against a grid of `dims` cells: the error names the
    /// array, the index and the value.
    pub fn validate(&self, dims: [usize; 3], periodic: [bool; 3]) -> Result<(), FluidError> {
        let cells: usize = dims.iter().product();
        let bad = |what: String| Err(FluidError::InvalidGrid(format!("cut fractions: {what}")));
        if self.volume.len() != cells {
            return bad(format!(
                "{} volume fractions for {cells} cells ({dims:?})",
                self.volume.len()
            ));
        }
        if let Some((i, v)) = self
            .volume
            .iter()
            .enumerate()
            .find(|(_, v)| !(v.is_finite() && (0.0..=MAX_VOLUME_FRACTION).contains(*v)))
        {
            return bad(format!(
                "volume fraction of cell {i} is {v}: expected 0..={MAX_VOLUME_FRACTION}"
            ));
        }
        for c in 0..3 {
            let n = face_count(dims, periodic, c);
            let f = &self.face[c];
            if f.len() != n {
                return bad(format!(
                    "{} area fractions of component {c} for {n} faces",
                    f.len()
                ));
            }
            if let Some((i, v)) = f
                .iter()
                .enumerate()
                .find(|(_, v)| !(v.is_finite() && (0.0..=1.0).contains(*v)))
            {
                return bad(format!(
                    "area fraction of face {i} of component {c} is {v}: expected 0..=1"
                ));
            }
            let Some(walls) = &self.walls else { continue };
            let mut last = None;
            for &(idx, arms) in &walls.faces[c] {
                if idx as usize >= n || last.is_some_and(|l| l >= idx) {
                    return bad(format!(
                        "wall distances of component {c}: face {idx} out of order or beyond \
                         the {n} faces"
                    ));
                }
                last = Some(idx);
                if let Some(x) = arms
                    .iter()
                    .find(|x| !(**x >= 0.0 && (**x <= 1.0 || **x == NO_WALL)))
                {
                    return bad(format!(
                        "wall distance {x} at face {idx} of component {c}: expected 0..=1 or none"
                    ));
                }
            }
        }
        Ok(())
    }

    /// Whether every fraction is 1 (nothing is cut).
    pub fn is_whole(&self) -> bool {
        self.volume.iter().all(|&v| v == 1.0) && self.face.iter().flatten().all(|&a| a == 1.0)
    }

    /// From a box's faces (`dims[c] + 1` along every axis, the cutcell module's layout) to the
    /// solver's: on a periodic axis the box's first face (between the last cell's image and the
    /// first cell) is kept and its last face, the same face of the periodic geometry, dropped.
    pub fn face_from_box(
        dims: [usize; 3],
        periodic: [bool; 3],
        c: usize,
        boxed: &[f64],
    ) -> Vec<f32> {
        let mut out = Vec::new();
        face_from_box_into(dims, periodic, c, boxed, &mut out);
        out
    }

    /// Fractions of a box of `dims` cells in the cutcell module's layout (`volume` per cell,
    /// `faces` per axis with `dims[a] + 1` along it; e.g. `CutCells::stabilised_*`) in the
    /// solver's layout for a grid with the periodic axes `periodic`.
    pub fn from_box(
        dims: [usize; 3],
        periodic: [bool; 3],
        volume: &[f64],
        faces: [&[f64]; 3],
    ) -> Self {
        let mut f = Self {
            volume: Vec::new(),
            face: Default::default(),
            walls: None,
        };
        f.assign_from_box(dims, periodic, volume, faces);
        f
    }

    /// [`CutFractions::from_box`] into these arrays (no allocation once they have the sizes).
    pub fn assign_from_box(
        &mut self,
        dims: [usize; 3],
        periodic: [bool; 3],
        volume: &[f64],
        faces: [&[f64]; 3],
    ) {
        self.volume.clear();
        self.volume.extend(volume.iter().map(|&v| v as f32));
        for (c, boxed) in faces.into_iter().enumerate() {
            face_from_box_into(dims, periodic, c, boxed, &mut self.face[c]);
        }
    }
}

impl CutFractions {
    /// Checks the sizes against a non-periodic grid of `dims` cells and the values of the parts
    /// of cell rows `rows` ([`row_parts`]): [`CutFractions::validate`] for fractions known to
    /// differ from checked ones only there. The error names the array, the index and the value.
    pub fn validate_rows(&self, dims: [usize; 3], rows: &[u32]) -> Result<(), FluidError> {
        let bad = |what: String| Err(FluidError::InvalidGrid(format!("cut fractions: {what}")));
        let cells: usize = dims.iter().product();
        if self.volume.len() != cells {
            return bad(format!(
                "{} volume fractions for {cells} cells ({dims:?})",
                self.volume.len()
            ));
        }
        for c in 0..3 {
            let n = face_count(dims, [false; 3], c);
            if self.face[c].len() != n {
                let len = self.face[c].len();
                return bad(format!(
                    "{len} area fractions of component {c} for {n} faces"
                ));
            }
        }
        let rows_total = dims[1] * dims[2];
        for &row in rows {
            if row as usize >= rows_total {
                return bad(format!("row {row} beyond the {rows_total} cell rows"));
            }
            for (array, range) in row_parts(dims, row as usize) {
                let (values, max) = match array {
                    0 => (&self.volume, MAX_VOLUME_FRACTION),
                    a => (&self.face[a - 1], 1.0),
                };
                let start = range.start;
                if let Some((i, v)) = values[range]
                    .iter()
                    .enumerate()
                    .find(|(_, v)| !(v.is_finite() && (0.0..=max).contains(*v)))
                {
                    let i = start + i;
                    return bad(match array {
                        0 => format!("volume fraction of cell {i} is {v}: expected 0..={max}"),
                        a => format!(
                            "area fraction of face {i} of component {} is {v}: expected 0..=1",
                            a - 1
                        ),
                    });
                }
            }
        }
        Ok(())
    }

    /// [`CutFractions::assign_from_box`] on a non-periodic grid for the parts of cell rows `rows`
    /// alone ([`row_parts`]; the rest stands): for box fractions that changed only there.
    pub fn assign_rows_from_box(
        &mut self,
        dims: [usize; 3],
        rows: &[u32],
        volume: &[f64],
        faces: [&[f64]; 3],
    ) {
        for &row in rows {
            for (array, range) in row_parts(dims, row as usize) {
                let (dst, src) = match array {
                    0 => (&mut self.volume, volume),
                    a => (&mut self.face[a - 1], faces[a - 1]),
                };
                for (d, &s) in dst[range.clone()].iter_mut().zip(&src[range]) {
                    *d = s as f32;
                }
            }
        }
    }

    /// Copies the parts of cell rows `rows` ([`row_parts`]) from `from`, of the same sizes.
    pub(crate) fn copy_rows(&mut self, dims: [usize; 3], rows: &[u32], from: &CutFractions) {
        for &row in rows {
            for (array, range) in row_parts(dims, row as usize) {
                let (dst, src) = match array {
                    0 => (&mut self.volume, &from.volume),
                    a => (&mut self.face[a - 1], &from.face[a - 1]),
                };
                dst[range.clone()].copy_from_slice(&src[range]);
            }
        }
    }
}

/// What belongs to cell row `row` (`j + ny k`) of a non-periodic grid of `dims` cells (where the
/// solver's layout is the cutcell module's box layout): its cells' volumes, its `nx + 1` x
/// faces, and the y faces of the planes `j` and `j + 1` and the z faces of the planes `k` and
/// `k + 1` along it, as (0 for the volumes or 1 + the face axis, index range). The rows a change
/// lists ([`crate::cutcell::CutCells::changed_rows`]: a changed y or z face lists the rows on
/// both sides) so cover every changed value.
pub(crate) fn row_parts(dims: [usize; 3], row: usize) -> [(usize, std::ops::Range<usize>); 6] {
    let [nx, ny, _] = dims;
    let (j, k) = (row % ny, row / ny);
    let y = |j: usize| nx * (j + (ny + 1) * k);
    let z = |k: usize| nx * (j + ny * k);
    [
        (0, nx * row..nx * (row + 1)),
        (1, (nx + 1) * row..(nx + 1) * (row + 1)),
        (2, y(j)..y(j) + nx),
        (2, y(j + 1)..y(j + 1) + nx),
        (3, z(k)..z(k) + nx),
        (3, z(k + 1)..z(k + 1) + nx),
    ]
}

impl CutFractions {
    /// Wall distances of the cutcell module's box layout ([`crate::cutcell::CutCells::face_walls`])
    /// in the solver's, for a grid of `dims` cells with the periodic axes `periodic` (on a
    /// periodic axis the box's last face, the same face as its first, is dropped).
    pub fn walls_from_box(dims: [usize; 3], periodic: [bool; 3], boxed: &FaceWalls) -> FaceWalls {
        let mut out = FaceWalls::default();
        for c in 0..3 {
            let mut bd = dims;
            bd[c] += 1;
            let mut sd = dims;
            if !periodic[c] {
                sd[c] += 1;
            }
            for &(idx, arms) in &boxed.faces[c] {
                let idx = idx as usize;
                let f = [idx % bd[0], (idx / bd[0]) % bd[1], idx / (bd[0] * bd[1])];
                if f[c] >= sd[c] {
                    continue;
                }
                out.faces[c].push(((f[0] + sd[0] * (f[1] + sd[1] * f[2])) as u32, arms));
            }
        }
        out
    }
}

/// Whether a cell with this fluid volume fraction is a fluid cell of the solver (cut or whole);
/// a cell without fluid is solid or a boundary. The one rule by which the labels follow the
/// fractions (case files, the scene).
#[inline]
pub fn holds_fluid(volume_fraction: f32) -> bool {
    volume_fraction > 0.0
}

/// [`CutFractions::face_from_box`] into `out` (cleared first).
fn face_from_box_into(
    dims: [usize; 3],
    periodic: [bool; 3],
    c: usize,
    boxed: &[f64],
    out: &mut Vec<f32>,
) {
    let mut bd = dims;
    bd[c] += 1;
    let mut sd = dims;
    if !periodic[c] {
        sd[c] += 1;
    }
    out.clear();
    for k in 0..sd[2] {
        for j in 0..sd[1] {
            let row = bd[0] * (j + bd[1] * k);
            out.extend(boxed[row..row + sd[0]].iter().map(|&a| a as f32));
        }
    }
}

/// Faces of component `c` in the solver's layout.
pub(crate) fn face_count(dims: [usize; 3], periodic: [bool; 3], c: usize) -> usize {
    let mut d = dims;
    if !periodic[c] {
        d[c] += 1;
    }
    d.iter().product()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn validation_names_the_array_index_and_value() {
        let dims = [3, 2, 2];
        let mut f = CutFractions::whole(dims, [false, true, false]);
        assert!(f.is_whole());
        assert_eq!(f.face[0].len(), 4 * 2 * 2);
        assert_eq!(f.face[1].len(), 3 * 2 * 2);
        f.validate(dims, [false, true, false]).unwrap();
        f.face[2][5] = 1.5;
        let e = f
            .validate(dims, [false, true, false])
            .unwrap_err()
            .to_string();
        assert!(e.contains("face 5 of component 2 is 1.5"), "{e}");
        f.face[2][5] = 0.5;
        f.volume[7] = f32::NAN;
        let e = f
            .validate(dims, [false, true, false])
            .unwrap_err()
            .to_string();
        assert!(e.contains("cell 7"), "{e}");
        f.volume.pop();
        assert!(f.validate(dims, [false, true, false]).is_err());
        // A periodic axis drops the box's last face along it.
        let boxed: Vec<f64> = (0..4 * 3 * 2).map(|v| v as f64).collect();
        let s = CutFractions::face_from_box([3, 3, 2], [false, true, false], 1, &boxed);
        assert_eq!(s.len(), 3 * 3 * 2);
        assert_eq!(s[3 * 3], boxed[3 * 4] as f32);
    }

    /// The parts of the changed rows, converted or copied, give the fractions of a whole
    /// conversion, the parts cover every value of the box once per row (faces between two rows
    /// in both), and a bad value in a listed row is named.
    #[test]
    fn row_parts_convert_copy_and_check_what_changed() {
        let dims = [5, 4, 3];
        let rows_total = dims[1] * dims[2];
        let mut rng = fastrand::Rng::with_seed(9);
        let box_faces: [Vec<f64>; 3] = std::array::from_fn(|a| {
            let mut d = dims;
            d[a] += 1;
            (0..d.iter().product::<usize>())
                .map(|_| rng.f64())
                .collect()
        });
        let volume: Vec<f64> = (0..60).map(|_| rng.f64()).collect();
        let faces = std::array::from_fn(|a| &box_faces[a][..]);
        let old = CutFractions::from_box(dims, [false; 3], &volume, faces);
        // Every value reached by some row.
        let mut seen: [Vec<u32>; 4] = std::array::from_fn(|a| match a {
            0 => vec![0; old.volume.len()],
            a => vec![0; old.face[a - 1].len()],
        });
        for row in 0..rows_total {
            for (array, range) in row_parts(dims, row) {
                seen[array][range].iter_mut().for_each(|n| *n += 1);
            }
        }
        assert!(seen.iter().all(|s| s.iter().all(|&n| n >= 1)), "{seen:?}");
        // Change the values of two rows' parts; convert and copy only those rows.
        let rows = [2u32, 7];
        let (mut volume2, mut box2) = (volume.clone(), box_faces.clone());
        for &row in &rows {
            for (array, range) in row_parts(dims, row as usize) {
                let values = match array {
                    0 => &mut volume2,
                    a => &mut box2[a - 1],
                };
                values[range].iter_mut().for_each(|v| *v *= 0.5);
            }
        }
        let faces2 = std::array::from_fn(|a| &box2[a][..]);
        let want = CutFractions::from_box(dims, [false; 3], &volume2, faces2);
        let mut converted = old.clone();
        converted.assign_rows_from_box(dims, &rows, &volume2, faces2);
        assert_eq!(converted, want);
        let mut copied = old.clone();
        copied.copy_rows(dims, &rows, &want);
        assert_eq!(copied, want);
        want.validate_rows(dims, &rows).unwrap();
        // A bad value in a listed row is named; one in an unlisted row is not looked at.
        let mut bad = want.clone();
        let z = row_parts(dims, 7)[5].1.start + 1;
        bad.face[2][z] = 1.5;
        let e = bad.validate_rows(dims, &rows).unwrap_err().to_string();
        assert!(
            e.contains(&format!("face {z} of component 2 is 1.5")),
            "{e}"
        );
        bad.validate_rows(dims, &[0]).unwrap();
        let e = bad.validate_rows(dims, &[12]).unwrap_err().to_string();
        assert!(e.contains("row 12 beyond the 12 cell rows"), "{e}");
    }
}
