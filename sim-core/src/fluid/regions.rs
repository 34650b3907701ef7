//! Connected fluid regions and the per-region compatibility of the pressure problem.
//!
//! A region that touches no open (outflow) cell has a Neumann-only Poisson problem: it is singular
//! (pressure defined up to a constant) and solvable only if its right-hand side sums to zero. We
//! subtract the region mean from the right-hand side (the part of the divergence no pressure can
//! remove, e.g. a flux mismatch of its ports) and keep iterates mean-free in that region.

use super::multigrid::Level;
use super::topology::NONE;

/// Fluid regions of the finest level.
#[derive(Default, Debug)]
pub(crate) struct Regions {
    /// Region id of each pressure row.
    pub of_row: Vec<u32>,
    /// Whether each region is closed (no open neighbour).
    pub closed: Vec<bool>,
    /// Rows per region.
    pub size: Vec<u32>,
    /// The rows of the closed regions, in row order (often a few stray cells beside an open
    /// cavity: the mean removal then touches only them).
    closed_rows: Vec<u32>,
    /// The closed regions' rows as runs of consecutive padded indices (`[region, start, end)`),
    /// for the dense vectors: a run is an x-run of fluid cells, contiguous in memory and all in
    /// one region, so its sum and its update are plain slice loops.
    closed_runs: Vec<[u32; 3]>,
    /// Scratch accumulators, one per region.
    sum: Vec<f64>,
    queue: Vec<u32>,
    /// Sum over the closed regions of `|sum of v|` removed by the last `remove_closed_means*`
    /// (for the divergence right-hand side `h div u`, times `h^2` it is the flux removed, m^3/s).
    pub removed_total: f64,
    /// Largest `|v|` over the rows of closed regions after the last `remove_closed_means*`.
    pub closed_max_abs: f64,
}

impl Regions {
    pub fn build(&mut self, level: &Level) {
        let n = level.rows();
        self.of_row.clear();
        self.of_row.resize(n, NONE);
        self.closed.clear();
        self.size.clear();
        for seed in 0..n {
            if self.of_row[seed] != NONE {
                continue;
            }
            let id = self.closed.len() as u32;
            let mut closed = true;
            let mut size = 0u32;
            self.queue.clear();
            self.queue.push(seed as u32);
            self.of_row[seed] = id;
            while let Some(r) = self.queue.pop() {
                size += 1;
                let nb = level.nbr[r as usize];
                let fluid_nb = nb.iter().filter(|&&x| (x as usize) < n).count() as f32;
                // Fluid neighbours through a periodic self-wrap count too; diag counts open ones.
                if level.diag[r as usize] > fluid_nb {
                    closed = false;
                }
                for &x in &nb {
                    if (x as usize) < n && self.of_row[x as usize] == NONE {
                        self.of_row[x as usize] = id;
                        self.queue.push(x);
                    }
                }
            }
            self.closed.push(closed);
            self.size.push(size);
        }
        self.sum.clear();
        self.sum.resize(self.closed.len(), 0.0);
        self.closed_rows.clear();
        let closed = &self.closed;
        let rows = self.of_row.iter().enumerate();
        let in_closed = rows.filter(|&(_, &id)| closed[id as usize]);
        self.closed_rows.extend(in_closed.map(|(r, _)| r as u32));
        self.closed_runs.clear();
        for &r in &self.closed_rows {
            let (id, p) = (self.of_row[r as usize], level.pad_of_row[r as usize]);
            match self.closed_runs.last_mut() {
                Some(run) if run[0] == id && run[2] == p => run[2] = p + 1,
                _ => self.closed_runs.push([id, p, p + 1]),
            }
        }
    }

    /// Number of regions.
    pub fn count(&self) -> usize {
        self.closed.len()
    }

    /// True if any region is closed.
    pub fn any_closed(&self) -> bool {
        // A closed region has at least one row.
        !self.closed_rows.is_empty()
    }

    /// True if every row lies in a closed region (a cavity whose ports are all prescribed
    /// velocities): then [`Regions::closed_max_abs`] is the largest value of the whole vector.
    pub fn all_closed(&self) -> bool {
        !self.of_row.is_empty() && self.closed_rows.len() == self.of_row.len()
    }

    /// Subtracts its region's mean from every row of a closed region. Returns the largest absolute
    /// mean removed.
    pub fn remove_closed_means(&mut self, v: &mut [f64]) -> f64 {
        self.removed_total = 0.0;
        if !self.any_closed() {
            return 0.0;
        }
        self.sum.fill(0.0);
        for &r in &self.closed_rows {
            self.sum[self.of_row[r as usize] as usize] += v[r as usize];
        }
        let worst = self.sums_to_means();
        for &r in &self.closed_rows {
            v[r as usize] -= self.sum[self.of_row[r as usize] as usize];
        }
        worst
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

/// The vector element types of the pressure solve.
pub(crate) trait Real: Copy {
    fn to_f64(self) -> f64;
    fn from_f64(v: f64) -> Self;
}

impl Real for f32 {
    fn to_f64(self) -> f64 {
        self as f64
    }
    fn from_f64(v: f64) -> Self {
        v as f32
    }
}

impl Real for f64 {
    fn to_f64(self) -> f64 {
        self
    }
    fn from_f64(v: f64) -> Self {
        v
    }
}
