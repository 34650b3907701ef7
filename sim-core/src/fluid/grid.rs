//! The MAC (staggered) grid: geometry, cell labels and the velocities of `Velocity` cells.
//!
//! Cell `(i, j, k)` spans `origin + h * [i, i+1) x [j, j+1) x [k, k+1)`. The x-velocity lives on the
//! faces normal to x at `origin + h * (i, j + 1/2, k + 1/2)`, and likewise for y and z. Cells outside
//! the grid are solid walls unless the axis is periodic.

use super::cut::CutFractions;
use super::{CellLabel, FluidError};

/// Geometry and labels of a box-shaped MAC grid.
#[derive(Clone, Debug)]
pub struct FluidGrid {
    dims: [usize; 3],
    spacing_m: f64,
    origin_m: [f64; 3],
    periodic: [bool; 3],
    labels: Vec<CellLabel>,
    velocity_m_s: Vec<[f32; 3]>,
    /// Cut-cell fractions (`None`: every cell and face whole).
    cut: Option<CutFractions>,
    /// Per cell, the flux the boundaries inside it push into its fluid, m^3/s (empty: all zero,
    /// nothing allocated until the first one is set).
    boundary_flux_m3_per_s: Vec<f64>,
    /// Per cell, the share of its closed region's mismatch its boundaries take up, m^2 (empty:
    /// none, nothing allocated until the first one is set).
    boundary_flux_weight_m2: Vec<f64>,
    /// A flux shared over the cells with a share weight, m^3/s into the fluid, and the weights,
    /// m^2 (empty: none, nothing allocated until the first one is set).
    shared_flux_m3_per_s: f64,
    shared_flux_weight_m2: Vec<f64>,
    revision: u64,
}

impl FluidGrid {
    /// A grid of `dims` cells of edge `spacing_m`, all fluid.
    pub fn new(
        dims: [usize; 3],
        spacing_m: f64,
        origin_m: [f64; 3],
        periodic: [bool; 3],
    ) -> Result<Self, FluidError> {
        if dims.contains(&0) {
            return Err(FluidError::InvalidGrid(format!(
                "cells = {dims:?}: every axis needs at least one cell"
            )));
        }
        let n = dims[0]
            .checked_mul(dims[1])
            .and_then(|v| v.checked_mul(dims[2]))
            .filter(|&n| n < u32::MAX as usize / 4)
            .ok_or_else(|| FluidError::InvalidGrid(format!("cells = {dims:?}: too many cells")))?;
        if !(spacing_m.is_finite() && spacing_m > 0.0) {
            return Err(FluidError::InvalidGrid(format!(
                "spacing_m = {spacing_m}: expected a finite length > 0"
            )));
        }
        if origin_m.iter().any(|o| !o.is_finite()) {
            return Err(FluidError::InvalidGrid(format!(
                "origin_m = {origin_m:?}: expected finite coordinates"
            )));
        }
        Ok(Self {
            dims,
            spacing_m,
            origin_m,
            periodic,
            labels: vec![CellLabel::Fluid; n],
            velocity_m_s: vec![[0.0; 3]; n],
            cut: None,
            boundary_flux_m3_per_s: Vec::new(),
            boundary_flux_weight_m2: Vec::new(),
            shared_flux_m3_per_s: 0.0,
            shared_flux_weight_m2: Vec::new(),
            revision: 1,
        })
    }

    /// Cells per axis.
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }
    /// Cell edge length.
    pub fn spacing_m(&self) -> f64 {
        self.spacing_m
    }
    /// Position of the grid's lower corner.
    pub fn origin_m(&self) -> [f64; 3] {
        self.origin_m
    }
    /// Periodic axes.
    pub fn periodic(&self) -> [bool; 3] {
        self.periodic
    }
    /// Number of cells.
    pub fn cell_count(&self) -> usize {
        self.labels.len()
    }
    /// Changes whenever a label changes (the solver rebuilds its topology then).
    pub fn revision(&self) -> u64 {
        self.revision
    }
    /// Linear index of a cell (x fastest).
    #[inline]
    pub fn index(&self, cell: [usize; 3]) -> usize {
        cell[0] + self.dims[0] * (cell[1] + self.dims[1] * cell[2])
    }
    /// Cell coordinates of a linear index.
    #[inline]
    pub fn coords(&self, index: usize) -> [usize; 3] {
        let i = index % self.dims[0];
        let r = index / self.dims[0];
        [i, r % self.dims[1], r / self.dims[1]]
    }
    /// Centre of a cell.
    pub fn cell_centre_m(&self, cell: [usize; 3]) -> [f64; 3] {
        std::array::from_fn(|a| self.origin_m[a] + (cell[a] as f64 + 0.5) * self.spacing_m)
    }
    /// Label of a cell (by linear index).
    #[inline]
    pub fn label_at(&self, index: usize) -> CellLabel {
        self.labels[index]
    }
    /// All labels, x fastest.
    pub fn labels(&self) -> &[CellLabel] {
        &self.labels
    }
    /// Prescribed velocity of a cell (meaningful for `Velocity` cells).
    #[inline]
    pub fn velocity_at(&self, index: usize) -> [f32; 3] {
        self.velocity_m_s[index]
    }

    /// Sets the cut-cell fractions (see [`CutFractions`] for the layout), checked against the
    /// grid; all ones clears them, so the solver runs the unweighted discretisation. They apply to
    /// the faces between fluid and fluid or outflow cells (elsewhere the labels decide); a fluid
    /// cell with no open face is a closed region of its own. The solver rebuilds its operator on
    /// the next step.
    pub fn set_cut_fractions(&mut self, fractions: CutFractions) -> Result<(), FluidError> {
        fractions.validate(self.dims, self.periodic)?;
        self.cut = (!fractions.is_whole()).then_some(fractions);
        self.revision += 1;
        Ok(())
    }

    /// [`FluidGrid::set_cut_fractions`] from a borrowed copy, into the arrays the grid holds (no
    /// allocation once it holds fractions of its size): for fractions that change while a scene
    /// runs.
    pub fn copy_cut_fractions(&mut self, fractions: &CutFractions) -> Result<(), FluidError> {
        fractions.validate(self.dims, self.periodic)?;
        if fractions.is_whole() {
            self.cut = None;
        } else if let Some(cut) = &mut self.cut {
            cut.volume.clone_from(&fractions.volume);
            for (a, b) in cut.face.iter_mut().zip(&fractions.face) {
                a.clone_from(b);
            }
            cut.walls.clone_from(&fractions.walls);
        } else {
            self.cut = Some(fractions.clone());
        }
        self.revision += 1;
        Ok(())
    }

    /// [`FluidGrid::copy_cut_fractions`] for fractions that differ from those the grid holds only
    /// in the cell rows `rows` (`j + ny k`): only those rows' parts are checked and copied
    /// ([`CutFractions::validate_rows`]), the scene's moving surface each frame. A periodic grid,
    /// wall distances, or a grid without fractions of these sizes yet take the whole copy.
    pub fn copy_cut_fraction_rows(
        &mut self,
        fractions: &CutFractions,
        rows: &[u32],
    ) -> Result<(), FluidError> {
        let sizes = |c: &CutFractions| {
            (
                c.volume.len(),
                c.face.each_ref().map(Vec::len),
                c.walls.is_some(),
            )
        };
        let rows_apply = self.periodic == [false; 3]
            && fractions.walls.is_none()
            && self
                .cut
                .as_ref()
                .is_some_and(|c| sizes(c) == sizes(fractions));
        if !rows_apply {
            return self.copy_cut_fractions(fractions);
        }
        fractions.validate_rows(self.dims, rows)?;
        if fractions.is_whole() {
            self.cut = None;
        } else if let Some(cut) = &mut self.cut {
            cut.copy_rows(self.dims, rows, fractions);
        }
        self.revision += 1;
        Ok(())
    }

    /// Sets cut-cell fractions without the all-ones shortcut (tests of the weighted path).
    #[cfg(test)]
    pub(crate) fn set_cut_fractions_weighted(&mut self, fractions: CutFractions) {
        fractions.validate(self.dims, self.periodic).unwrap();
        self.cut = Some(fractions);
        self.revision += 1;
    }

    /// Removes the cut-cell fractions (every cell and face whole).
    pub fn clear_cut_fractions(&mut self) {
        if self.cut.take().is_some() {
            self.revision += 1;
        }
    }

    /// The cut-cell fractions, if any cell or face is cut.
    pub fn cut_fractions(&self) -> Option<&CutFractions> {
        self.cut.as_ref()
    }

    /// Fluid volume fraction of a cell (by linear index; 1 without cut cells).
    #[inline]
    pub fn volume_fraction(&self, index: usize) -> f32 {
        self.cut.as_ref().map_or(1.0, |c| c.volume[index])
    }

    /// Per cell (x fastest), the flux that the moving boundaries inside the cell (the wall
    /// pieces of a cut cell, a port) push into its fluid, m^3/s, positive into the fluid: the
    /// projection makes the flux out of a fluid cell through its faces, `h^2 sum A_f u_f`, equal
    /// to it (Batty, Bertails and Bridson 2007; Ng, Min and Gibou 2009). Empty when none was ever
    /// set (all zero). Only fluid cells' values count; a closed fluid region whose values and
    /// face fluxes do not balance has the mismatch taken up by the boundary fluxes of its cells
    /// with a weight ([`FluidGrid::boundary_flux_weights_m2`]), else removed as a uniform mean
    /// (`StepStats::closed_region_*`).
    pub fn boundary_fluxes_m3_per_s(&self) -> &[f64] {
        &self.boundary_flux_m3_per_s
    }

    /// Per cell (x fastest), how much of its closed fluid region's mismatch (the region's
    /// boundary fluxes and prescribed face fluxes not summing to zero) the cell's boundary flux
    /// takes up, m^2 (e.g. the area of the wall pieces in it): the projection shifts the
    /// boundary flux of each such cell by `-mismatch w_c / sum w` over the region, so every
    /// closed region with some weight balances by itself (`StepStats::boundary_flux_shift_m3_per_s`).
    /// Empty when none was ever set (all zero: the mismatch is removed as a uniform mean).
    pub fn boundary_flux_weights_m2(&self) -> &[f64] {
        &self.boundary_flux_weight_m2
    }

    /// Sets the weight of one cell (see [`FluidGrid::boundary_flux_weights_m2`]): finite and
    /// `>= 0`. The first call allocates the per-cell array, later ones nothing. Does not change
    /// the topology.
    pub fn set_boundary_flux_weight_m2(
        &mut self,
        cell: [usize; 3],
        weight_m2: f64,
    ) -> Result<(), FluidError> {
        let idx = self.checked_weight(cell, weight_m2, "boundary flux weight")?;
        let cells = self.labels.len();
        set_lazily(&mut self.boundary_flux_weight_m2, cells, idx, weight_m2);
        Ok(())
    }

    /// The index of `cell` for a weight (m^2) that is finite and `>= 0`; `what` names it.
    fn checked_weight(
        &self,
        cell: [usize; 3],
        weight_m2: f64,
        what: &str,
    ) -> Result<usize, FluidError> {
        if !self.in_range(cell) {
            return Err(FluidError::OutOfRange {
                cell,
                dims: self.dims,
            });
        }
        if !(weight_m2.is_finite() && weight_m2 >= 0.0) {
            return Err(FluidError::InvalidParameter {
                key: format!("{what} of cell {cell:?}"),
                value: weight_m2.to_string(),
                expected: "a finite area >= 0 in m^2".into(),
            });
        }
        Ok(self.index(cell))
    }

    /// A boundary flux (m^3/s into the fluid, e.g. an opening's losses) the projection shares
    /// over the fluid cells with a share weight ([`FluidGrid::shared_flux_weights_m2`]) in
    /// proportion to it, but only over the cells whose region can carry it: an open region, or a
    /// closed one with some boundary-flux weight ([`FluidGrid::boundary_flux_weights_m2`]) to take
    /// up its mismatch. A closed region without (an isolated pocket) gets no share, as its
    /// share could only be removed again. When no carrying cell has a share weight, all weighted
    /// fluid cells share it; with no weighted fluid cell it is not applied
    /// (`StepStats::shared_flux_m3_per_s` is what the last projection applied).
    pub fn shared_flux_m3_per_s(&self) -> f64 {
        self.shared_flux_m3_per_s
    }

    /// Sets the shared flux (see [`FluidGrid::shared_flux_m3_per_s`]): finite.
    pub fn set_shared_flux_m3_per_s(&mut self, flux_m3_per_s: f64) -> Result<(), FluidError> {
        if !flux_m3_per_s.is_finite() {
            return Err(FluidError::InvalidParameter {
                key: "shared boundary flux".into(),
                value: flux_m3_per_s.to_string(),
                expected: "a finite flux in m^3/s".into(),
            });
        }
        self.shared_flux_m3_per_s = flux_m3_per_s;
        Ok(())
    }

    /// Per cell (x fastest), its share weight of [`FluidGrid::shared_flux_m3_per_s`], m^2 (e.g.
    /// the area of the opening's pieces in it). Empty when none was ever set.
    pub fn shared_flux_weights_m2(&self) -> &[f64] {
        &self.shared_flux_weight_m2
    }

    /// Sets the share weight of one cell: finite and `>= 0`. The first call allocates the
    /// per-cell array, later ones nothing. Does not change the topology.
    pub fn set_shared_flux_weight_m2(
        &mut self,
        cell: [usize; 3],
        weight_m2: f64,
    ) -> Result<(), FluidError> {
        let idx = self.checked_weight(cell, weight_m2, "shared flux weight")?;
        let cells = self.labels.len();
        set_lazily(&mut self.shared_flux_weight_m2, cells, idx, weight_m2);
        Ok(())
    }

    /// Sets the boundary flux of one cell (see [`FluidGrid::boundary_fluxes_m3_per_s`]); the
    /// first call allocates the per-cell array, later ones nothing. Does not change the topology.
    pub fn set_boundary_flux_m3_per_s(
        &mut self,
        cell: [usize; 3],
        flux_m3_per_s: f64,
    ) -> Result<(), FluidError> {
        let slot = self.boundary_flux_slot(cell, flux_m3_per_s)?;
        *slot = flux_m3_per_s;
        Ok(())
    }

    /// Adds to the boundary flux of one cell (several boundaries in one cell).
    pub fn add_boundary_flux_m3_per_s(
        &mut self,
        cell: [usize; 3],
        flux_m3_per_s: f64,
    ) -> Result<(), FluidError> {
        let slot = self.boundary_flux_slot(cell, flux_m3_per_s)?;
        *slot += flux_m3_per_s;
        Ok(())
    }

    /// Every cell's boundary flux to zero, keeping the array (no allocation).
    pub fn clear_boundary_fluxes(&mut self) {
        self.boundary_flux_m3_per_s.fill(0.0);
    }

    fn boundary_flux_slot(
        &mut self,
        cell: [usize; 3],
        flux_m3_per_s: f64,
    ) -> Result<&mut f64, FluidError> {
        if !self.in_range(cell) {
            return Err(FluidError::OutOfRange {
                cell,
                dims: self.dims,
            });
        }
        if !flux_m3_per_s.is_finite() {
            return Err(FluidError::InvalidParameter {
                key: format!("boundary flux of cell {cell:?}"),
                value: flux_m3_per_s.to_string(),
                expected: "a finite flux in m^3/s".into(),
            });
        }
        if self.boundary_flux_m3_per_s.is_empty() {
            self.boundary_flux_m3_per_s = vec![0.0; self.labels.len()];
        }
        let idx = self.index(cell);
        Ok(&mut self.boundary_flux_m3_per_s[idx])
    }

    /// The fluid volume the grid carries (m^3): `sum V_i h^3` over the fluid cells.
    pub fn fluid_volume_m3(&self) -> f64 {
        let cells: f64 = self
            .labels
            .iter()
            .enumerate()
            .filter(|(_, &l)| l == CellLabel::Fluid)
            .map(|(i, _)| self.volume_fraction(i) as f64)
            .sum();
        cells * self.spacing_m.powi(3)
    }

    /// Label of a cell; `None` when the coordinates are outside the grid.
    pub fn label(&self, cell: [usize; 3]) -> Option<CellLabel> {
        self.in_range(cell).then(|| self.labels[self.index(cell)])
    }

    fn in_range(&self, cell: [usize; 3]) -> bool {
        (0..3).all(|a| cell[a] < self.dims[a])
    }

    /// Sets one cell's label. Out-of-range cells are an error.
    pub fn set_label(&mut self, cell: [usize; 3], label: CellLabel) -> Result<(), FluidError> {
        if !self.in_range(cell) {
            return Err(FluidError::OutOfRange {
                cell,
                dims: self.dims,
            });
        }
        let idx = self.index(cell);
        if self.labels[idx] != label {
            self.labels[idx] = label;
            self.revision += 1;
        }
        Ok(())
    }

    /// Sets a cell's prescribed velocity (used where the label is `Velocity`). Changing a velocity
    /// does not change the topology.
    pub fn set_velocity(
        &mut self,
        cell: [usize; 3],
        velocity_m_s: [f32; 3],
    ) -> Result<(), FluidError> {
        if !self.in_range(cell) {
            return Err(FluidError::OutOfRange {
                cell,
                dims: self.dims,
            });
        }
        let idx = self.index(cell);
        self.velocity_m_s[idx] = velocity_m_s;
        Ok(())
    }

    /// Labels every cell whose centre lies inside the closed box `[min_m, max_m]`, and gives it
    /// `velocity_m_s`. Returns the number of cells changed.
    pub fn fill_box(
        &mut self,
        min_m: [f64; 3],
        max_m: [f64; 3],
        label: CellLabel,
        velocity_m_s: [f32; 3],
    ) -> usize {
        let mut count = 0;
        let (lo, hi) = (
            self.cell_range(min_m, max_m, 0),
            self.cell_range(min_m, max_m, 1),
        );
        let (lo2, hi2) = (
            self.cell_range(min_m, max_m, 2),
            self.cell_range(min_m, max_m, 3),
        );
        let (lo3, hi3) = (
            self.cell_range(min_m, max_m, 4),
            self.cell_range(min_m, max_m, 5),
        );
        for k in lo3..hi3 {
            for j in lo2..hi2 {
                for i in lo..hi {
                    let idx = self.index([i, j, k]);
                    if self.labels[idx] != label {
                        self.labels[idx] = label;
                        self.revision += 1;
                    }
                    self.velocity_m_s[idx] = velocity_m_s;
                    count += 1;
                }
            }
        }
        count
    }

    /// `which` = 2*axis + (0 for the first cell index, 1 for one past the last) of the cells whose
    /// centres lie in `[min_m, max_m]` along `axis`.
    fn cell_range(&self, min_m: [f64; 3], max_m: [f64; 3], which: usize) -> usize {
        let a = which / 2;
        let h = self.spacing_m;
        // Centre i lies inside when min <= o + (i+0.5)h <= max.
        let first = ((min_m[a] - self.origin_m[a]) / h - 0.5).ceil().max(0.0);
        let last = ((max_m[a] - self.origin_m[a]) / h - 0.5).floor();
        let n = self.dims[a] as f64;
        if which.is_multiple_of(2) || last < first {
            first.min(n) as usize
        } else {
            (last + 1.0).clamp(0.0, n) as usize
        }
    }

    /// Neighbour of a cell along `axis` in direction `dir` (-1 or +1), wrapping on periodic axes;
    /// `None` outside the grid.
    #[inline]
    pub fn neighbour(&self, cell: [usize; 3], axis: usize, dir: i32) -> Option<[usize; 3]> {
        let n = self.dims[axis];
        let mut c = cell;
        if dir < 0 {
            if cell[axis] == 0 {
                if !self.periodic[axis] {
                    return None;
                }
                c[axis] = n - 1;
            } else {
                c[axis] -= 1;
            }
        } else if cell[axis] + 1 == n {
            if !self.periodic[axis] {
                return None;
            }
            c[axis] = 0;
        } else {
            c[axis] += 1;
        }
        Some(c)
    }
}

/// The linear indices one step down and up an axis from `index` (coordinate `at` of `n` along
/// it, `stride` apart): `None` past a non-periodic wall, wrapped on a periodic axis (onto `index`
/// itself when the axis is one long). The one rule of the multigrid levels' and the scene's
/// neighbour steps.
#[inline(always)]
pub(crate) fn step_along(
    index: usize,
    at: usize,
    n: usize,
    stride: usize,
    periodic: bool,
) -> [Option<usize>; 2] {
    let down = if at > 0 {
        Some(index - stride)
    } else {
        periodic.then(|| index + (n - 1) * stride)
    };
    let up = if at + 1 < n {
        Some(index + stride)
    } else {
        periodic.then(|| index - (n - 1) * stride)
    };
    [down, up]
}

/// Sets `values[idx]`, allocating the per-cell array of `cells` zeros on the first call.
fn set_lazily(values: &mut Vec<f64>, cells: usize, idx: usize, value: f64) {
    if values.is_empty() {
        *values = vec![0.0; cells];
    }
    values[idx] = value;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fill_box_takes_cells_whose_centres_are_inside() {
        let mut g = FluidGrid::new([10, 4, 4], 0.1, [1.0, 0.0, 0.0], [false; 3]).unwrap();
        // Centres at x = 1.05, 1.15, ...: the box [1.1, 1.35] holds 1.15, 1.25, 1.35 (closed box).
        let n = g.fill_box(
            [1.1, 0.0, 0.0],
            [1.35, 0.4, 0.4],
            CellLabel::Outflow,
            [0.0; 3],
        );
        assert_eq!(n, 3 * 16);
        assert_eq!(g.label([0, 0, 0]), Some(CellLabel::Fluid));
        assert_eq!(g.label([1, 0, 0]), Some(CellLabel::Outflow));
        assert_eq!(g.label([3, 3, 3]), Some(CellLabel::Outflow));
        assert_eq!(g.label([4, 0, 0]), Some(CellLabel::Fluid));
        // Boxes outside the grid or inverted touch nothing.
        assert_eq!(
            g.fill_box([5.0; 3], [6.0; 3], CellLabel::Solid, [0.0; 3]),
            0
        );
        assert_eq!(
            g.fill_box([1.5, 0.0, 0.0], [1.2, 0.4, 0.4], CellLabel::Solid, [0.0; 3]),
            0
        );
        assert!(g.set_label([10, 0, 0], CellLabel::Solid).is_err());
        assert!(FluidGrid::new([0, 1, 1], 0.1, [0.0; 3], [false; 3]).is_err());
        assert!(FluidGrid::new([1, 1, 1], f64::NAN, [0.0; 3], [false; 3]).is_err());
    }
}
