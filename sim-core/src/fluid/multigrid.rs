//! Geometric multigrid V-cycle on voxelized (irregular) domains, used as the CG preconditioner.
//!
//! Each level is a 7-point Poisson operator on the "fluid" cells of a label grid (0 = solid wall,
//! Neumann; 1 = fluid, unknown; 2 = open, Dirichlet p = 0), stored as compressed rows with neighbour
//! lists (periodic axes wrap). A coarse cell is open if any child is open, else fluid if any child
//! is fluid, else solid. Restriction sums the children's residuals (times a scale), prolongation
//! injects the coarse value into every child (its transpose). Smoothing is red-black Gauss-Seidel,
//! forward before and reversed after the coarse correction, so the V-cycle is a symmetric operator and
//! CG preconditioned by it stays valid.

use rayon::prelude::*;

use super::topology::NONE;

const CHUNK: usize = 2048;

/// Label codes of a level.
pub(crate) const L_SOLID: u8 = 0;
pub(crate) const L_FLUID: u8 = 1;
pub(crate) const L_OPEN: u8 = 2;

/// One multigrid level.
#[derive(Default, Debug)]
pub(crate) struct Level {
    pub dims: [usize; 3],
    pub periodic: [bool; 3],
    pub label: Vec<u8>,
    pub row_of_cell: Vec<u32>,
    pub cell_of_row: Vec<u32>,
    /// Neighbour rows, order -x +x -y +y -z +z; a wall or open neighbour points at the extra slot
    /// `rows()` of `x`, which is always zero, so the smoother needs no branches.
    pub nbr: Vec<[u32; 6]>,
    /// Number of fluid or open neighbours.
    pub diag: Vec<f32>,
    pub inv_diag: Vec<f32>,
    /// Rows `0..red_rows` are red (even i+j+k), the rest black.
    pub red_rows: usize,
    /// True when no row has a neighbour of its own colour (parallel sweeps are then exact).
    pub exact_colouring: bool,
    /// Scratch for parallel sweeps.
    pub scratch: Vec<f32>,
    /// Coarse row of each row's parent cell (NONE when the parent is open).
    pub parent: Vec<u32>,
    pub x: Vec<f32>,
    pub b: Vec<f32>,
    pub r: Vec<f32>,
}

impl Level {
    pub fn rows(&self) -> usize {
        self.cell_of_row.len()
    }

    fn neighbour_cell(&self, c: [usize; 3], axis: usize, dir: i32) -> Option<usize> {
        let n = self.dims[axis];
        let mut g = c;
        if dir < 0 {
            if c[axis] == 0 {
                if !self.periodic[axis] {
                    return None;
                }
                g[axis] = n - 1;
            } else {
                g[axis] -= 1;
            }
        } else if c[axis] + 1 == n {
            if !self.periodic[axis] {
                return None;
            }
            g[axis] = 0;
        } else {
            g[axis] += 1;
        }
        Some(g[0] + self.dims[0] * (g[1] + self.dims[1] * g[2]))
    }

    /// Builds rows, stencils and colours from `self.label`, `dims`, `periodic`.
    pub fn build_rows(&mut self) {
        let [nx, ny, _] = self.dims;
        let ncell = self.label.len();
        self.row_of_cell.clear();
        self.row_of_cell.resize(ncell, NONE);
        self.cell_of_row.clear();
        // Red cells (even i+j+k) first, then black: each colour is a contiguous range of rows, so a
        // colour can be relaxed in parallel into a scratch buffer and copied back in one piece.
        let parity = |i: usize| (i % nx + (i / nx) % ny + i / (nx * ny)) % 2;
        for colour in 0..2 {
            for (i, &l) in self.label.iter().enumerate() {
                if l == L_FLUID && parity(i) == colour {
                    self.row_of_cell[i] = self.cell_of_row.len() as u32;
                    self.cell_of_row.push(i as u32);
                }
            }
            if colour == 0 {
                self.red_rows = self.cell_of_row.len();
            }
        }
        self.nbr.clear();
        self.diag.clear();
        self.inv_diag.clear();
        self.exact_colouring = true;
        let zero_slot = self.cell_of_row.len() as u32;
        for row in 0..self.cell_of_row.len() {
            let ci = self.cell_of_row[row] as usize;
            let c = [ci % nx, (ci / nx) % ny, ci / (nx * ny)];
            let mut nb = [zero_slot; 6];
            let mut diag = 0.0f32;
            for axis in 0..3 {
                for (s, dir) in [-1i32, 1].into_iter().enumerate() {
                    if let Some(g) = self.neighbour_cell(c, axis, dir) {
                        match self.label[g] {
                            L_FLUID => {
                                nb[2 * axis + s] = self.row_of_cell[g];
                                diag += 1.0;
                            }
                            L_OPEN => diag += 1.0,
                            _ => {}
                        }
                    }
                }
            }
            self.nbr.push(nb);
            self.diag.push(diag);
            self.inv_diag
                .push(if diag > 0.0 { 1.0 / diag } else { 0.0 });
            // Odd periodic axes make some neighbours share a colour: then only serial sweeps are
            // Gauss-Seidel.
            let red = row < self.red_rows;
            if nb
                .iter()
                .any(|&m| m != zero_slot && ((m as usize) < self.red_rows) == red)
            {
                self.exact_colouring = false;
            }
        }
        let n = self.cell_of_row.len() + 1;
        for v in [&mut self.x, &mut self.b, &mut self.r, &mut self.scratch] {
            v.clear();
            v.resize(n, 0.0);
        }
    }

    /// Labels of the next coarser level, or None when this level should be the coarsest.
    fn coarsen(&self, coarse: &mut Level) -> bool {
        if self.rows() <= 8 || self.dims.iter().all(|&n| n <= 1) {
            return false;
        }
        for a in 0..3 {
            if self.periodic[a] && self.dims[a] > 1 && self.dims[a] % 2 == 1 {
                return false;
            }
        }
        let cd: [usize; 3] = std::array::from_fn(|a| self.dims[a].div_ceil(2));
        coarse.dims = cd;
        coarse.periodic = std::array::from_fn(|a| self.periodic[a] && cd[a] > 1);
        coarse.label.clear();
        coarse.label.resize(cd[0] * cd[1] * cd[2], L_SOLID);
        let [nx, ny, nz] = self.dims;
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    let l = self.label[i + nx * (j + ny * k)];
                    let p = i / 2 + cd[0] * (j / 2 + cd[1] * (k / 2));
                    let cl = &mut coarse.label[p];
                    if l == L_OPEN || (l == L_FLUID && *cl == L_SOLID) {
                        *cl = l;
                    }
                }
            }
        }
        true
    }

    fn link_parents(&mut self, coarse: &Level) {
        let [nx, ny, _] = self.dims;
        let cd = coarse.dims;
        self.parent.clear();
        for row in 0..self.rows() {
            let ci = self.cell_of_row[row] as usize;
            let (i, j, k) = (ci % nx, (ci / nx) % ny, ci / (nx * ny));
            let p = i / 2 + cd[0] * (j / 2 + cd[1] * (k / 2));
            self.parent.push(coarse.row_of_cell[p]);
        }
    }

    #[inline]
    fn relax(&mut self, row: usize) {
        let nb = self.nbr[row];
        let x = &self.x;
        let s = self.b[row]
            + (x[nb[0] as usize] + x[nb[1] as usize])
            + (x[nb[2] as usize] + x[nb[3] as usize])
            + (x[nb[4] as usize] + x[nb[5] as usize]);
        self.x[row] = s * self.inv_diag[row];
    }

    /// Relaxes rows `range` (one colour): in parallel through the scratch buffer when `parallel` and
    /// the colouring is exact, else in order (`reverse`: backwards).
    fn relax_range(&mut self, range: std::ops::Range<usize>, reverse: bool, parallel: bool) {
        if parallel && self.exact_colouring {
            let start = range.start;
            let Level {
                x,
                b,
                nbr,
                inv_diag,
                scratch,
                ..
            } = self;
            let x_read: &[f32] = x;
            scratch[range.clone()]
                .par_chunks_mut(CHUNK)
                .enumerate()
                .for_each(|(ci, out)| {
                    for (o, v) in out.iter_mut().enumerate() {
                        let row = start + ci * CHUNK + o;
                        let nb = nbr[row];
                        let s = b[row]
                            + (x_read[nb[0] as usize] + x_read[nb[1] as usize])
                            + (x_read[nb[2] as usize] + x_read[nb[3] as usize])
                            + (x_read[nb[4] as usize] + x_read[nb[5] as usize]);
                        *v = s * inv_diag[row];
                    }
                });
            x[range.clone()].copy_from_slice(&scratch[range]);
        } else if reverse {
            for row in range.rev() {
                self.relax(row);
            }
        } else {
            for row in range {
                self.relax(row);
            }
        }
    }

    /// Red then black Gauss-Seidel sweep.
    pub fn smooth_forward(&mut self, parallel: bool) {
        let (red, n) = (self.red_rows, self.rows());
        self.relax_range(0..red, false, parallel);
        self.relax_range(red..n, false, parallel);
    }

    /// The adjoint of `smooth_forward`: black then red, each in reverse order.
    pub fn smooth_backward(&mut self, parallel: bool) {
        let (red, n) = (self.red_rows, self.rows());
        self.relax_range(red..n, true, parallel);
        self.relax_range(0..red, true, parallel);
    }

    fn residual(&mut self) {
        for row in 0..self.rows() {
            let nb = self.nbr[row];
            let x = &self.x;
            self.r[row] = self.b[row] - self.diag[row] * x[row]
                + (x[nb[0] as usize] + x[nb[1] as usize])
                + (x[nb[2] as usize] + x[nb[3] as usize])
                + (x[nb[4] as usize] + x[nb[5] as usize]);
        }
    }
}

/// The level hierarchy.
#[derive(Default, Debug)]
pub(crate) struct Multigrid {
    pub levels: Vec<Level>,
    /// Number of levels in use (levels beyond stay allocated for reuse).
    pub used: usize,
    /// Scale of the restricted residual (1/4 is Galerkin for injection; larger over-corrects).
    pub coarse_scale: f32,
    /// Smoothing sweeps before and after the coarse correction.
    pub sweeps: usize,
    /// Symmetric sweeps on the coarsest level.
    pub coarsest_sweeps: usize,
    /// Levels with at least this many rows smooth in parallel (rayon).
    pub parallel_rows: usize,
}

impl Multigrid {
    /// Builds the hierarchy under a finished level 0 (`levels[0]` must be built by the caller).
    pub fn build_hierarchy(&mut self) {
        self.used = 1;
        loop {
            let l = self.used;
            if self.levels.len() <= l {
                self.levels.push(Level::default());
            }
            let (fine, coarse) = self.levels.split_at_mut(l);
            let fine = &mut fine[l - 1];
            if !fine.coarsen(&mut coarse[0]) {
                fine.parent.clear();
                break;
            }
            coarse[0].build_rows();
            fine.link_parents(&coarse[0]);
            self.used += 1;
            if self.used >= 16 {
                break;
            }
        }
        if self.used >= 16 {
            self.levels[self.used - 1].parent.clear();
        }
    }

    /// Applies the V-cycle: `levels[0].x = M^{-1} levels[0].b`.
    pub fn vcycle(&mut self) {
        let n = self.used;
        for l in 0..n - 1 {
            let (fine, coarse) = self.levels.split_at_mut(l + 1);
            let fine = &mut fine[l];
            let coarse = &mut coarse[0];
            fine.x.fill(0.0);
            let par = fine.rows() >= self.parallel_rows;
            for _ in 0..self.sweeps {
                fine.smooth_forward(par);
            }
            fine.residual();
            coarse.b.fill(0.0);
            for row in 0..fine.rows() {
                let p = fine.parent[row];
                if p != NONE {
                    coarse.b[p as usize] += self.coarse_scale * fine.r[row];
                }
            }
        }
        let last = &mut self.levels[n - 1];
        last.x.fill(0.0);
        for _ in 0..self.coarsest_sweeps {
            last.smooth_forward(false);
            last.smooth_backward(false);
        }
        for l in (0..n - 1).rev() {
            let (fine, coarse) = self.levels.split_at_mut(l + 1);
            let fine = &mut fine[l];
            let coarse = &coarse[0];
            for row in 0..fine.rows() {
                let p = fine.parent[row];
                if p != NONE {
                    fine.x[row] += coarse.x[p as usize];
                }
            }
            let par = fine.rows() >= self.parallel_rows;
            for _ in 0..self.sweeps {
                fine.smooth_backward(par);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An irregular label grid: a ball of fluid with an open cap and a solid inclusion.
    fn ball(n: usize) -> Level {
        let mut l = Level {
            dims: [n, n, n],
            periodic: [false; 3],
            ..Default::default()
        };
        let c = (n as f64 - 1.0) / 2.0;
        for k in 0..n {
            for j in 0..n {
                for i in 0..n {
                    let r2 = [i, j, k]
                        .iter()
                        .map(|&v| (v as f64 - c).powi(2))
                        .sum::<f64>();
                    let label = if r2 > c * c {
                        L_SOLID
                    } else if k + 2 >= n {
                        L_OPEN
                    } else if (i as f64 - c).abs() < 1.5 && (j as f64 - c).abs() < 1.5 && k < n / 2
                    {
                        L_SOLID
                    } else {
                        L_FLUID
                    };
                    l.label.push(label);
                }
            }
        }
        l.build_rows();
        l
    }

    fn mg(n: usize) -> Multigrid {
        let mut m = Multigrid {
            coarse_scale: 0.5,
            sweeps: 2,
            coarsest_sweeps: 16,
            ..Default::default()
        };
        m.levels.push(ball(n));
        m.build_hierarchy();
        m
    }

    fn apply(m: &mut Multigrid, b: &[f32]) -> Vec<f32> {
        let n = m.levels[0].rows();
        m.levels[0].b[..n].copy_from_slice(b);
        m.vcycle();
        m.levels[0].x[..n].to_vec()
    }

    #[test]
    fn vcycle_is_a_symmetric_positive_operator() {
        let mut m = mg(17);
        assert!(m.used >= 3, "levels {}", m.used);
        let n = m.levels[0].rows();
        let a: Vec<f32> = (0..n)
            .map(|i| ((i * 7919) % 101) as f32 / 50.0 - 1.0)
            .collect();
        let b: Vec<f32> = (0..n)
            .map(|i| ((i * 104729) % 97) as f32 / 48.0 - 1.0)
            .collect();
        let ma = apply(&mut m, &a);
        let mb = apply(&mut m, &b);
        let dot = |x: &[f32], y: &[f32]| {
            x.iter()
                .zip(y)
                .map(|(p, q)| *p as f64 * *q as f64)
                .sum::<f64>()
        };
        let (ab, ba) = (dot(&ma, &b), dot(&a, &mb));
        assert!(
            (ab - ba).abs() <= 1e-4 * ab.abs().max(ba.abs()),
            "<Ma,b> = {ab}, <a,Mb> = {ba}"
        );
        assert!(dot(&ma, &a) > 0.0 && dot(&mb, &b) > 0.0);
    }

    #[test]
    fn parallel_sweeps_equal_serial_sweeps() {
        let mut serial = mg(17);
        let mut parallel = mg(17);
        parallel.parallel_rows = 0;
        assert!(parallel.levels[0].exact_colouring);
        let n = serial.levels[0].rows();
        let b: Vec<f32> = (0..n).map(|i| ((i * 31) % 17) as f32 - 8.0).collect();
        assert_eq!(apply(&mut serial, &b), apply(&mut parallel, &b));
    }

    #[test]
    fn vcycle_reduces_the_error_of_the_poisson_problem() {
        // As a stationary iteration x <- x + M (b - A x), one V-cycle must contract the error well.
        let mut m = mg(17);
        let n = m.levels[0].rows();
        let l0 = &m.levels[0];
        let exact: Vec<f32> = (0..n).map(|i| (i as f32 * 0.37).sin()).collect();
        let matvec = |l: &Level, x: &[f32]| -> Vec<f32> {
            (0..l.rows())
                .map(|r| {
                    let mut s = l.diag[r] * x[r];
                    for &nb in &l.nbr[r] {
                        if (nb as usize) < l.rows() {
                            s -= x[nb as usize];
                        }
                    }
                    s
                })
                .collect()
        };
        let b = matvec(l0, &exact);
        let mut x = vec![0.0f32; n];
        for _ in 0..2 {
            let ax = matvec(&m.levels[0], &x);
            let r: Vec<f32> = b.iter().zip(&ax).map(|(p, q)| p - q).collect();
            let z = apply(&mut m, &r);
            for (xi, zi) in x.iter_mut().zip(&z) {
                *xi += zi;
            }
        }
        let err = x
            .iter()
            .zip(&exact)
            .map(|(p, q)| (p - q).abs())
            .fold(0.0f32, f32::max);
        assert!(err < 0.1, "error after two V-cycles: {err}");
    }
}
