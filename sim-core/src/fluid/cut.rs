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
}
