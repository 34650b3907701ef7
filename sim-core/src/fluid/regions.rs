//! Connected fluid regions and the per-region compatibility of the pressure problem.
//!
//! A region that touches no open (outflow) cell has a Neumann-only Poisson problem: it is singular
//! (pressure defined up to a constant) and solvable only if its right-hand side sums to zero. We
//! subtract the region mean from the right-hand side (the part of the divergence no pressure can
//! remove, e.g. a flux mismatch of its ports) and keep iterates mean-free in that region.

use super::multigrid::{max_abs_from, Level, Real, L_FLUID, L_OPEN};
use super::topology::NONE;

/// Fluid regions of the finest level.
#[derive(Default, Debug)]
pub(crate) struct Regions {
    /// Whether each region is closed (no open neighbour), regions numbered in the order of their
    /// first cell.
    pub closed: Vec<bool>,
    /// Fluid cells per region.
    pub size: Vec<u32>,
    /// The closed regions' x-runs of fluid cells as `[region, start, end)` in padded indices (for
    /// the dense vectors: a run is contiguous in memory and all in one region, so its sum and its
    /// update are plain slice loops); often a few stray cells beside an open cavity, and then
    /// the mean removal touches only them.
    closed_runs: Vec<[u32; 3]>,
    /// The same runs as ranges `[start, end)` of compressed rows (fluid cells numbered in cell
    /// order, as [`Level::build_compressed_rows`] numbers them), for the reference solvers.
    closed_row_runs: Vec<[u32; 2]>,
    /// Fluid cells, and those in closed regions.
    cells: usize,
    closed_cells: usize,
    /// Scratch of [`Regions::build`]: the fluid x-runs (`[cell row, first, end)`, cell order),
    /// their union-find parents and open flags, each cell row's range of runs, the region of
    /// each root run.
    runs: Vec<[u32; 3]>,
    parent: Vec<u32>,
    open: Vec<bool>,
    row_runs: Vec<[u32; 2]>,
    region: Vec<u32>,
    /// Scratch accumulators, one per region.
    sum: Vec<f64>,
    weight: Vec<f64>,
    /// Sum over the closed regions of `|sum of v|` removed by the last `remove_closed_means*`
    /// (for the divergence right-hand side `h div u`, times `h^2` it is the flux removed, m^3/s).
    pub removed_total: f64,
    /// Largest `|v|` over the rows of closed regions after the last `remove_closed_means*`.
    pub closed_max_abs: f64,
}

/// The root of run `x` (path halving).
fn find(parent: &mut [u32], mut x: u32) -> u32 {
    while parent[x as usize] != x {
        let up = parent[parent[x as usize] as usize];
        parent[x as usize] = up;
        x = up;
    }
    x
}

/// Joins the regions of runs `a` and `b` (the smaller root becomes the parent).
fn union(parent: &mut [u32], a: u32, b: u32) {
    let (ra, rb) = (find(parent, a), find(parent, b));
    if ra != rb {
        let (lo, hi) = (ra.min(rb), ra.max(rb));
        parent[hi as usize] = lo;
    }
}

impl Regions {
    /// The connected regions of `level`'s fluid cells (face neighbours, across periodic axes)
    /// and which of them touch no open cell, from its labels within its row ranges: x-runs of
    /// fluid cells joined where they overlap in neighbouring rows, so the cost is that of the
    /// runs, not of the cells' neighbour lists.
    pub fn build(&mut self, level: &Level) {
        let [nx, ny, nz] = level.dims;
        let (label, rows) = (&level.label, &level.row_ext);
        // Cut cells: a face whose coupling is zero joins nothing (its weight is stored at the
        // lower cell's padded index).
        let wt = level.couplings();
        let open_face = |a: usize, i: usize, j: usize, k: usize| {
            wt.is_none_or(|w| w[a][level.pad(i, j, k)] > 0.0)
        };
        self.runs.clear();
        self.row_runs.clear();
        self.row_runs.resize(ny * nz, [0, 0]);
        for (r, &[a, b]) in rows.iter().enumerate() {
            let first = self.runs.len() as u32;
            let row = &label[r * nx..(r + 1) * nx];
            let mut i = a as usize;
            while i < b as usize {
                if row[i] != L_FLUID {
                    i += 1;
                    continue;
                }
                let start = i;
                let (j, k) = (r % ny, r / ny);
                i += 1;
                while i < b as usize && row[i] == L_FLUID && open_face(0, i - 1, j, k) {
                    i += 1;
                }
                self.runs.push([r as u32, start as u32, i as u32]);
            }
            self.row_runs[r] = [first, self.runs.len() as u32];
        }
        self.parent.clear();
        self.parent.extend(0..self.runs.len() as u32);
        let (runs, parent) = (&self.runs, &mut self.parent);
        for r in 0..ny * nz {
            let [s, e] = self.row_runs[r];
            if s == e {
                continue;
            }
            // A periodic x axis joins a row's last cell to its first.
            if level.periodic[0]
                && runs[s as usize][1] == 0
                && runs[e as usize - 1][2] as usize == nx
                && open_face(0, nx - 1, r % ny, r / ny)
            {
                union(parent, s, e - 1);
            }
            // The +y and +z neighbour rows (the relation is symmetric; wrapped on a periodic
            // axis): runs that overlap along x touch.
            let [_, yp, _, zp] = level.neighbour_rows(r % ny, r / ny);
            for (axis, other) in [(1, yp), (2, zp)] {
                let Some(other) = other else { continue };
                let [mut y, t] = self.row_runs[other / nx];
                let mut x = s;
                while x < e && y < t {
                    let (a, b) = (runs[x as usize], runs[y as usize]);
                    let (lo, hi) = (a[1].max(b[1]), a[2].min(b[2]));
                    if lo < hi
                        && (wt.is_none()
                            || (lo..hi).any(|i| open_face(axis, i as usize, r % ny, r / ny)))
                    {
                        union(parent, x, y);
                    }
                    if a[2] < b[2] {
                        x += 1;
                    } else {
                        y += 1;
                    }
                }
            }
        }
        // A region is open when one of its cells has an open neighbour.
        self.open.clear();
        self.open.resize(self.runs.len(), false);
        for (r, &[a, b]) in rows.iter().enumerate() {
            let (j, k) = (r % ny, r / ny);
            for i in a as usize..b as usize {
                let ci = r * nx + i;
                if label[ci] != L_OPEN {
                    continue;
                }
                for (slot, g) in level.neighbour_cells([i, j, k], ci).into_iter().enumerate() {
                    if g == usize::MAX || label[g] != L_FLUID {
                        continue;
                    }
                    // The face's weight sits at its lower cell: this open cell for a +a
                    // neighbour, the fluid one for a -a neighbour.
                    let lower = if slot % 2 == 1 { ci } else { g };
                    let (li, lr) = (lower % nx, lower / nx);
                    if !open_face(slot / 2, li, lr % ny, lr / ny) {
                        continue;
                    }
                    let (gr, gi) = ((g / nx) as u32, (g % nx) as u32);
                    let [s, e] = self.row_runs[gr as usize];
                    let run = (s..e).find(|&n| {
                        let [_, i0, i1] = self.runs[n as usize];
                        i0 <= gi && gi < i1
                    });
                    if let Some(n) = run {
                        let root = find(&mut self.parent, n);
                        self.open[root as usize] = true;
                    }
                }
            }
        }
        // Regions numbered in the order of their first run (their first cell).
        self.region.clear();
        self.region.resize(self.runs.len(), NONE);
        self.closed.clear();
        self.size.clear();
        self.closed_runs.clear();
        self.closed_row_runs.clear();
        self.closed_cells = 0;
        let mut row = 0u32;
        for n in 0..self.runs.len() {
            let root = find(&mut self.parent, n as u32) as usize;
            if self.region[root] == NONE {
                self.region[root] = self.closed.len() as u32;
                self.closed.push(!self.open[root]);
                self.size.push(0);
            }
            let id = self.region[root];
            let [r, i0, i1] = self.runs[n];
            let len = i1 - i0;
            self.size[id as usize] += len;
            if self.closed[id as usize] {
                let (j, k) = (r as usize % ny, r as usize / ny);
                let p = level.pad(i0 as usize, j, k) as u32;
                self.closed_runs.push([id, p, p + len]);
                self.closed_row_runs.push([row, row + len]);
                self.closed_cells += len as usize;
            }
            row += len;
        }
        self.cells = row as usize;
        self.sum.clear();
        self.sum.resize(self.closed.len(), 0.0);
        self.weight.clear();
        self.weight.resize(self.closed.len(), 0.0);
    }

    /// Number of regions.
    pub fn count(&self) -> usize {
        self.closed.len()
    }

    /// True if any region is closed.
    pub fn any_closed(&self) -> bool {
        // A closed region has at least one run.
        !self.closed_runs.is_empty()
    }

    /// True if every row lies in a closed region (a cavity whose ports are all prescribed
    /// velocities): then [`Regions::closed_max_abs`] is the largest value of the whole vector.
    pub fn all_closed(&self) -> bool {
        self.cells > 0 && self.closed_cells == self.cells
    }

    /// Subtracts its region's mean from every row of a closed region. Returns the largest absolute
    /// mean removed.
    pub fn remove_closed_means(&mut self, v: &mut [f64]) -> f64 {
        self.removed_total = 0.0;
        if !self.any_closed() {
            return 0.0;
        }
        self.sum.fill(0.0);
        for (&[id, ..], &[s, e]) in self.closed_runs.iter().zip(&self.closed_row_runs) {
            for &x in &v[s as usize..e as usize] {
                self.sum[id as usize] += x;
            }
        }
        let worst = self.sums_to_means();
        for (&[id, ..], &[s, e]) in self.closed_runs.iter().zip(&self.closed_row_runs) {
            for x in &mut v[s as usize..e as usize] {
                *x -= self.sum[id as usize];
            }
        }
        worst
    }

    /// Makes each closed region with some weight sum to zero by itself: its sum of `v` (a dense,
    /// padded vector of the level the regions were built on) is taken from its cells in
    /// proportion to their weights `w` (same layout, `>= 0`), `v -= sum w / sum w`. Regions without
    /// weight are left as they are (for [`Regions::remove_closed_means_dense`]). Returns the
    /// signed total taken, summed in f64.
    pub fn shift_closed_sums_dense(&mut self, v: &mut [f64], w: &[f64]) -> f64 {
        if !self.any_closed() {
            return 0.0;
        }
        self.sum.fill(0.0);
        self.weight.fill(0.0);
        for &[id, s, e] in &self.closed_runs {
            let r = s as usize..e as usize;
            self.sum[id as usize] += v[r.clone()].iter().sum::<f64>();
            self.weight[id as usize] += w[r].iter().sum::<f64>();
        }
        let mut total = 0.0;
        for (s, &wt) in self.sum.iter_mut().zip(&self.weight) {
            if wt > 0.0 {
                total += *s;
                *s /= wt;
            } else {
                *s = 0.0;
            }
        }
        for &[id, s, e] in &self.closed_runs {
            let per_weight = self.sum[id as usize];
            if per_weight == 0.0 {
                continue;
            }
            let r = s as usize..e as usize;
            for (x, &wx) in v[r.clone()].iter_mut().zip(&w[r]) {
                *x -= per_weight * wx;
            }
        }
        total
    }

    /// Zeroes the share weights `s` (a dense, padded vector of the level the regions were built
    /// on) of the closed regions whose boundary-flux weights `w` (same layout; `None`: none) sum
    /// to zero: such a region cannot take up a share of a flux (nothing in it balances it).
    /// Returns the sum of the weights zeroed.
    pub fn zero_stranded_dense(&mut self, s: &mut [f64], w: Option<&[f64]>) -> f64 {
        if !self.any_closed() {
            return 0.0;
        }
        self.weight.fill(0.0);
        if let Some(w) = w {
            for &[id, a, e] in &self.closed_runs {
                self.weight[id as usize] += w[a as usize..e as usize].iter().sum::<f64>();
            }
        }
        let mut zeroed = 0.0;
        for &[id, a, e] in &self.closed_runs {
            if self.weight[id as usize] == 0.0 {
                let run = &mut s[a as usize..e as usize];
                zeroed += run.iter().sum::<f64>();
                run.fill(0.0);
            }
        }
        zeroed
    }

    /// Largest `|v|` over the closed regions' cells of a dense (padded) vector, NaN skipped.
    pub fn closed_max_abs_dense(&self, v: &[f32]) -> f32 {
        self.closed_runs.iter().fold(0.0f32, |m, &[_, s, e]| {
            max_abs_from(m, &v[s as usize..e as usize])
        })
    }

    /// `x = inv b` on the closed regions' cells of dense vectors: where a kernel wrote `x` from a
    /// `b` whose closed means were removed after it, these cells are written again.
    pub fn closed_scale_dense(&self, x: &mut [f32], b: &[f32], inv: &[f32]) {
        for &[_, s, e] in &self.closed_runs {
            let r = s as usize..e as usize;
            for ((x, &b), &i) in x[r.clone()].iter_mut().zip(&b[r.clone()]).zip(&inv[r]) {
                *x = b * i;
            }
        }
    }

    /// As [`Regions::remove_closed_means`] for a dense (padded) vector of the level the regions
    /// were built on; the means are accumulated in f64.
    pub fn remove_closed_means_dense<T: Real>(&mut self, v: &mut [T]) -> f64 {
        self.removed_total = 0.0;
        if !self.any_closed() {
            return 0.0;
        }
        self.sum.fill(0.0);
        for &[id, s, e] in &self.closed_runs {
            let run = &v[s as usize..e as usize];
            let sum = run.iter().map(|x| x.to_f64()).sum::<f64>();
            self.sum[id as usize] += sum;
        }
        let worst = self.sums_to_means();
        let mut max_abs = 0.0f64;
        for &[id, s, e] in &self.closed_runs {
            let mean = self.sum[id as usize];
            for x in &mut v[s as usize..e as usize] {
                *x = T::from_f64(x.to_f64() - mean);
                let a = x.to_f64().abs();
                // Not f64::max: a plain comparison vectorizes (NaN is skipped by both).
                max_abs = if a > max_abs { a } else { max_abs };
            }
        }
        self.closed_max_abs = max_abs;
        worst
    }

    /// Turns the per-region sums into the means to remove (0 for open regions), sets
    /// `removed_total` and returns the largest absolute mean.
    fn sums_to_means(&mut self) -> f64 {
        let mut worst = 0.0f64;
        let mut total = 0.0f64;
        for (id, s) in self.sum.iter_mut().enumerate() {
            *s = if self.closed[id] {
                total += s.abs();
                *s / self.size[id] as f64
            } else {
                0.0
            };
            worst = worst.max(s.abs());
        }
        self.removed_total = total;
        worst
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fluid::multigrid::L_SOLID;

    /// The regions by a search over the compressed rows' neighbour lists (the definition): per
    /// region whether it is closed (a row has more fluid or open neighbours than fluid ones) and
    /// its size, and the rows of the closed regions.
    fn by_search(level: &Level) -> (Vec<bool>, Vec<u32>, Vec<u32>) {
        let n = level.rows();
        let mut of_row = vec![NONE; n];
        let (mut closed, mut size) = (Vec::new(), Vec::new());
        for seed in 0..n {
            if of_row[seed] != NONE {
                continue;
            }
            let id = closed.len() as u32;
            let (mut is_closed, mut count) = (true, 0);
            let mut queue = vec![seed];
            of_row[seed] = id;
            while let Some(r) = queue.pop() {
                count += 1;
                let nb = level.nbr[r];
                let fluid_nb = nb.iter().filter(|&&x| (x as usize) < n).count() as f32;
                if level.diag[r] > fluid_nb {
                    is_closed = false;
                }
                for &x in &nb {
                    if (x as usize) < n && of_row[x as usize] == NONE {
                        of_row[x as usize] = id;
                        queue.push(x as usize);
                    }
                }
            }
            closed.push(is_closed);
            size.push(count);
        }
        let rows = (0..n as u32).filter(|&r| closed[of_row[r as usize] as usize]);
        let rows = rows.collect();
        (closed, size, rows)
    }

    #[test]
    fn regions_from_runs_equal_a_search_over_the_rows() {
        let mut rng = fastrand::Rng::with_seed(11);
        let mut regions = Regions::default();
        let mut any_closed = 0;
        for round in 0..120 {
            let dims = [rng.usize(1..9), rng.usize(1..9), rng.usize(1..9)];
            let periodic = [rng.bool(), rng.bool(), rng.bool()];
            let ncell = dims.iter().product();
            // Mostly fluid with solid walls sprinkled in (splitting regions) and a few open cells.
            let solid = rng.usize(10..60);
            let open = [0, 2, 5][round % 3];
            let label = (0..ncell)
                .map(|_| match rng.usize(..100) {
                    x if x < open => L_OPEN,
                    x if x < solid => L_SOLID,
                    _ => L_FLUID,
                })
                .collect();
            let mut level = Level {
                dims,
                periodic,
                label,
                ..Default::default()
            };
            level.build_rows();
            regions.build(&level);
            let (closed, size, closed_rows) = by_search(&level);
            let at = format!("round {round}, dims {dims:?}, periodic {periodic:?}");
            assert_eq!(regions.closed, closed, "closed, {at}");
            assert_eq!(regions.size, size, "size, {at}");
            let rows: Vec<u32> = regions
                .closed_row_runs
                .iter()
                .flat_map(|&[s, e]| s..e)
                .collect();
            assert_eq!(rows, closed_rows, "closed rows, {at}");
            let pads: Vec<u32> = regions
                .closed_runs
                .iter()
                .flat_map(|&[_, s, e]| s..e)
                .collect();
            let want: Vec<u32> = closed_rows
                .iter()
                .map(|&r| level.pad_of_row[r as usize])
                .collect();
            assert_eq!(pads, want, "closed runs, {at}");
            assert_eq!(regions.any_closed(), !closed_rows.is_empty(), "{at}");
            let all = level.rows() > 0 && closed_rows.len() == level.rows();
            assert_eq!(regions.all_closed(), all, "{at}");
            any_closed += usize::from(regions.any_closed() && !regions.all_closed());
        }
        // The random grids cover mixed open and closed regions.
        assert!(any_closed > 10, "{any_closed} grids with both kinds");
    }
}
