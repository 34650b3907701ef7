//! The next coarser level: its labels (a coarse cell is open if any child is, else fluid if any
//! child is, else solid) and the Galerkin couplings of piecewise-constant prolongation.

use super::level::{pad_index, Level, L_FLUID, L_OPEN, L_SOLID};

impl Level {
    /// The Galerkin operator of piecewise-constant prolongation on the coarse level `coarse`
    /// (labels and dense form built): every fine face between a fluid child and a fluid or open
    /// cell of another coarse cell adds its coupling, over the number of fine faces a full coarse
    /// face holds, to the coupling of the two coarse cells (so a fully fluid region keeps unit
    /// couplings), and the diagonal is the sum of a cell's couplings. Unlike the rediscretised
    /// operator of the coarse labels (a coarse cell with one fluid child coupled like a full
    /// one), thin and partly filled regions keep the strength of their fine connections.
    /// Periodic levels keep unit couplings.
    pub(super) fn galerkin(&self, coarse: &mut Level) {
        if self.any_periodic() || coarse.any_periodic() {
            for w in &mut coarse.wt {
                w.clear();
            }
            return;
        }
        let len = coarse.mask.len();
        // Zero outside the coarse non-solid ranges: `coarsen` cleared the last ones.
        if coarse.wt[0].len() != len {
            for w in &mut coarse.wt {
                w.clear();
                w.resize(len, 0.0);
            }
        }
        let [nx, ny, nz] = self.dims;
        let ratio: [f32; 3] = std::array::from_fn(|a| if self.dims[a] > 1 { 2.0 } else { 1.0 });
        let faces_per_face: [f32; 3] =
            std::array::from_fn(|a| (0..3).filter(|&b| b != a).map(|b| ratio[b]).product());
        let share: [f32; 3] = std::array::from_fn(|a| 1.0 / faces_per_face[a]);
        let fine_w = self.couplings();
        let cell_stride = [1, nx, nx * ny];
        let (fine_stride, coarse_stride) = ([1, self.sy, self.sz], [1, coarse.sy, coarse.sz]);
        for &[j, k, i0, i1] in &self.row_spans {
            let (j, k) = (j as usize, k as usize);
            let base = nx * (j + ny * k);
            for i in i0 as usize..i1 as usize {
                let ci = base + i;
                if self.label[ci] != L_FLUID {
                    continue;
                }
                let c = [i, j, k];
                let (pf, pc) = (
                    self.pad(i, j, k),
                    pad_index(coarse.sy, coarse.sz, i / 2, j / 2, k / 2),
                );
                for a in 0..3 {
                    let n = [nx, ny, nz][a];
                    // The fine face to the +axis neighbour crosses into another coarse cell when
                    // the cell is odd along the axis, the -axis face when it is even.
                    let odd = c[a] % 2 == 1;
                    // +axis face (fluid or open neighbour), and -axis face to an open neighbour
                    // (a fluid one is counted from its own +axis face).
                    if odd
                        && c[a] + 1 < n
                        && matches!(self.label[ci + cell_stride[a]], L_FLUID | L_OPEN)
                    {
                        let w = fine_w.map_or(1.0, |w| w[a][pf]);
                        coarse.wt[a][pc] += w * share[a];
                    }
                    if !odd && c[a] > 0 && self.label[ci - cell_stride[a]] == L_OPEN {
                        let w = fine_w.map_or(1.0, |w| w[a][pf - fine_stride[a]]);
                        coarse.wt[a][pc - coarse_stride[a]] += w * share[a];
                    }
                }
            }
        }
        coarse.diagonal_from_couplings();
    }

    /// The diagonal of every fluid cell as the sum of its six face couplings (`wt`, periodic
    /// ghost layers filled), and its inverse on the cell's colour.
    pub(crate) fn diagonal_from_couplings(&mut self) {
        let (sy, sz) = (self.sy, self.sz);
        for &[j, k, i0, i1] in &self.row_spans {
            let (j, k) = (j as usize, k as usize);
            for i in i0 as usize..i1 as usize {
                let p = pad_index(sy, sz, i, j, k);
                if self.mask[p] == 0.0 {
                    continue;
                }
                let w = &self.wt;
                let d = w[0][p] + w[0][p - 1] + w[1][p] + w[1][p - sy] + w[2][p] + w[2][p - sz];
                self.ddiag[p] = d;
                self.inv[(i + j + k) % 2][p] = if d > 0.0 { 1.0 / d } else { 0.0 };
            }
        }
    }

    /// Labels of the next coarser level, or false when this level should be the coarsest.
    pub(super) fn coarsen(&self, coarse: &mut Level) -> bool {
        if self.fluid <= 8 || self.dims.iter().all(|&n| n <= 1) {
            return false;
        }
        for a in 0..3 {
            if self.periodic[a] && self.dims[a] > 1 && self.dims[a] % 2 == 1 {
                return false;
            }
        }
        let cd: [usize; 3] = std::array::from_fn(|a| self.dims[a].div_ceil(2));
        let periodic = std::array::from_fn(|a| self.periodic[a] && cd[a] > 1);
        let (ncell, nrow) = (cd[0] * cd[1] * cd[2], cd[1] * cd[2]);
        if coarse.dims == cd
            && coarse.periodic == periodic
            && coarse.label.len() == ncell
            && coarse.row_ext.len() == nrow
        {
            // Only the last ranges can hold non-solid cells, and non-zero couplings.
            let clear_wt = coarse.wt[0].len() == coarse.mask.len();
            for (r, &[a, b]) in coarse.row_ext.iter().enumerate() {
                coarse.label[r * cd[0] + a as usize..r * cd[0] + b as usize].fill(L_SOLID);
                if clear_wt && a < b {
                    let p = coarse.pad(a as usize, r % cd[1], r / cd[1]);
                    for w in &mut coarse.wt {
                        w[p..p + (b - a) as usize].fill(0.0);
                    }
                }
            }
            coarse.row_ext.fill([0, 0]);
        } else {
            coarse.dims = cd;
            coarse.periodic = periodic;
            for w in &mut coarse.wt {
                w.clear();
            }
            coarse.label.clear();
            coarse.label.resize(ncell, L_SOLID);
            coarse.row_ext.clear();
            coarse.row_ext.resize(nrow, [0, 0]);
        }
        let [nx, ny, nz] = self.dims;
        for k in 0..nz {
            for j in 0..ny {
                let [a, b] = self.row_ext[j + ny * k];
                if a >= b {
                    continue;
                }
                let crow = j / 2 + cd[1] * (k / 2);
                let base = cd[0] * crow;
                for i in a as usize..b as usize {
                    let l = self.label[i + nx * (j + ny * k)];
                    let cl = &mut coarse.label[base + i / 2];
                    if l == L_OPEN || (l == L_FLUID && *cl == L_SOLID) {
                        *cl = l;
                    }
                }
                let ext = &mut coarse.row_ext[crow];
                let (ca, cb) = (a / 2, (b - 1) / 2 + 1);
                *ext = if ext[0] < ext[1] {
                    [ext[0].min(ca), ext[1].max(cb)]
                } else {
                    [ca, cb]
                };
            }
        }
        true
    }
}
