//! What both element systems share: the tangent's block sparsity pattern (with the follower
//! pressure and the fixed unknowns applied at the end of every evaluation) and the evaluation
//! result. [`super::system`] (linear tetrahedra) and [`super::system10`] (10-node tetrahedra) use
//! it; it uses neither.

use super::model::FemModel;

/// Energy and residual at one state.
#[derive(Debug, Clone)]
pub struct Evaluation {
    /// Total potential `W_dev + U_vol - p V` in J.
    pub energy_j: f64,
    /// Gradient of the potential (N), zero at fixed degrees of freedom.
    pub residual: Vec<f64>,
    /// Smallest `v / V0` over the tetrahedra.
    pub min_volume_ratio: f64,
    /// Smallest nodal `J`.
    pub min_nodal_j: f64,
}

/// Replaces the rows and columns of fixed displacement unknowns by identity rows scaled to the
/// mean absolute diagonal of the free ones (columns past `fixed.len()` are never fixed).
pub(crate) fn apply_fixed(
    k: &mut [f64],
    col_ptr: &[usize],
    row_idx: &[usize],
    diag_pos: &[usize],
    fixed: &[bool],
) {
    let nx = fixed.len();
    let free: Vec<f64> = (0..nx)
        .filter(|&d| !fixed[d])
        .map(|d| k[diag_pos[d]].abs())
        .collect();
    let scale = if free.is_empty() {
        1.0
    } else {
        free.iter().sum::<f64>() / free.len() as f64
    };
    let is_fixed = |d: usize| d < nx && fixed[d];
    for j in 0..col_ptr.len() - 1 {
        let fj = is_fixed(j);
        for p in col_ptr[j]..col_ptr[j + 1] {
            let r = row_idx[p];
            if fj || is_fixed(r) {
                k[p] = if r == j { scale } else { 0.0 };
            }
        }
    }
}

/// The tangent's sparsity, shared by both element systems: vertex adjacency, the column-compressed
/// pattern of the full symmetric matrix, the diagonal positions and the fixed unknowns.
#[derive(Debug, Clone)]
pub(crate) struct BlockPattern {
    /// Per vertex j, the range of `nbr_idx` holding its neighbours (sorted, itself included).
    pub nbr_ptr: Vec<usize>,
    /// Neighbour vertices.
    pub nbr_idx: Vec<u32>,
    /// Column pointers of the tangent.
    pub col_ptr: Vec<usize>,
    /// Row indices of the tangent, sorted within each column.
    pub row_idx: Vec<usize>,
    /// Position of each diagonal entry in the values.
    pub diag_pos: Vec<usize>,
    /// Fixed displacement unknowns.
    pub fixed: Vec<bool>,
}

impl BlockPattern {
    /// Adds the 3x3 block coupling vertex `i` (rows) with vertex `j` (columns).
    #[inline]
    pub fn add_block(&self, values: &mut [f64], i: u32, j: u32, blk: &[[f64; 3]; 3]) {
        let nb = &self.nbr_idx[self.nbr_ptr[j as usize]..self.nbr_ptr[j as usize + 1]];
        if let Ok(k) = nb.binary_search(&i) {
            for dj in 0..3 {
                let col = self.col_ptr[3 * j as usize + dj] + 3 * k;
                for di in 0..3 {
                    values[col + di] += blk[di][dj];
                }
            }
        }
    }

    /// The common end of an evaluation: the follower pressure as the potential `-p V(x)` of the
    /// closed cavity (energy, residual, load stiffness), then the fixed unknowns.
    pub fn finish(
        &self,
        model: &FemModel,
        x: &[[f64; 3]],
        pressure_pa: f64,
        energy: &mut f64,
        residual: &mut [f64],
        mut tangent: Option<&mut [f64]>,
    ) {
        if pressure_pa != 0.0 {
            *energy -= pressure_pa * model.cavity.volume(x);
            model.cavity.add_gradient(x, -pressure_pa, residual);
            if let Some(k) = tangent.as_deref_mut() {
                model
                    .cavity
                    .for_each_hessian_block(x, -pressure_pa, |i, j, blk| {
                        self.add_block(k, i, j, &blk)
                    });
            }
        }
        for (r, &f) in residual.iter_mut().zip(&self.fixed) {
            if f {
                *r = 0.0;
            }
        }
        if let Some(k) = tangent {
            apply_fixed(k, &self.col_ptr, &self.row_idx, &self.diag_pos, &self.fixed);
        }
    }

    /// `y = A x` for the matrix with this pattern and the stored `values`.
    pub fn multiply(&self, values: &[f64], x: &[f64]) -> Vec<f64> {
        let mut y = vec![0.0; x.len()];
        for (j, &xj) in x.iter().enumerate().take(self.col_ptr.len() - 1) {
            for p in self.col_ptr[j]..self.col_ptr[j + 1] {
                y[self.row_idx[p]] += values[p] * xj;
            }
        }
        y
    }
}
