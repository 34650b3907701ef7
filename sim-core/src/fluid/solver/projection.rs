//! The pressure projection of a substep: `-h div u` as the right-hand side (closed regions'
//! incompatible mean removed), the pressure solve, `u -= grad q`, and the pressure levels built
//! from the labels after a relabelling.

use super::super::grid::FluidGrid;
use super::super::multigrid::{for_spans, max_abs_spans, Level, L_FLUID, L_OPEN, L_SOLID};
use super::super::pressure::PressureSolver;
use super::super::CellLabel;
use super::{FluidSolver, StepStats};

/// Level 0 of the pressure solver from the grid's labels within the rows' open ranges `rows`,
/// the levels under it and the solver's vectors; the pressure of cells that stay fluid is kept
/// for the warm start across the relabelling (the rest is zeroed).
pub(super) fn build_pressure_levels(
    grid: &FluidGrid,
    rows: &[[u32; 2]],
    pressure: &mut PressureSolver,
    pressure_pa: &mut Vec<f64>,
    p_lag: &mut Vec<f64>,
) {
    let mg = &mut pressure.mg;
    if mg.levels.is_empty() {
        mg.levels.push(Default::default());
    }
    let l0 = &mut mg.levels[0];
    let labels = grid.labels();
    l0.set_labels(grid.dims(), grid.periodic(), rows, |c| match labels[c] {
        CellLabel::Fluid => L_FLUID,
        CellLabel::Outflow => L_OPEN,
        _ => L_SOLID,
    });
    l0.build_in_extents();
    set_cut_couplings(grid, l0);
    // The pressure is zero outside the fluid cells, so only the previous spans can hold stale
    // values.
    let len = l0.mask.len();
    let whole = pressure_pa.len() != len || l0.old_spans.is_none();
    pressure_pa.resize(len, 0.0);
    p_lag.resize(len, 0.0);
    let ranges: &[[u32; 2]] = match &l0.old_spans {
        Some(old) if !whole => old,
        _ => &[[0, len as u32]],
    };
    for &[s, e] in ranges {
        let r = s as usize..e as usize;
        for (p, &m) in pressure_pa[r.clone()].iter_mut().zip(&l0.mask[r]) {
            if m == 0.0 {
                *p = 0.0;
            }
        }
    }
    mg.build_hierarchy();
    pressure.resize();
}

/// Level 0's face couplings from the grid's cut fractions (the open area fraction of every face
/// between a fluid cell and a fluid or open one) and the diagonal their sum; without cut cells
/// the couplings stay empty (unit, the unweighted kernels).
fn set_cut_couplings(grid: &FluidGrid, l0: &mut Level) {
    let Some(cut) = grid.cut_fractions() else {
        for w in &mut l0.wt {
            w.clear();
        }
        l0.wt_ext.1.clear();
        return;
    };
    let len = l0.mask.len();
    // Every coupling is written at a fluid or open cell, within the rows' ranges of the labels it
    // was built from (a periodic halo writes outside them: such boxes are cleared whole). With the
    // same box, clearing those ranges leaves `wt` as zero as clearing it whole.
    let periodic_box = l0.periodic.iter().any(|&p| p);
    // Taken out and put back below (moved, not allocated).
    let (wt_dims, mut wt_rows) = std::mem::take(&mut l0.wt_ext);
    let ranged = !periodic_box
        && wt_dims == l0.dims
        && wt_rows.len() == l0.row_ext.len()
        && l0.wt.iter().all(|w| w.len() == len);
    if ranged {
        let [_, ny, _] = l0.dims;
        for (r, &[a, b]) in wt_rows.iter().enumerate() {
            if a < b {
                let p = l0.pad(a as usize, r % ny, r / ny);
                for w in &mut l0.wt {
                    w[p..p + (b - a) as usize].fill(0.0);
                }
            }
        }
    } else {
        for w in &mut l0.wt {
            w.clear();
            w.resize(len, 0.0);
        }
    }
    // The ranges this build writes within, for the next one (sized once per box).
    wt_rows.clear();
    if !periodic_box {
        wt_rows.extend_from_slice(&l0.row_ext);
    }
    l0.wt_ext = (l0.dims, wt_rows);
    let dims = grid.dims();
    let periodic = grid.periodic();
    let fdims: [[usize; 3]; 3] = std::array::from_fn(|a| {
        let mut d = dims;
        d[a] += usize::from(!periodic[a]);
        d
    });
    let face = |a: usize, f: [usize; 3]| {
        let d = fdims[a];
        cut.face[a][f[0] + d[0] * (f[1] + d[1] * f[2])]
    };
    let label = &l0.label;
    for &[j, k, i0, i1] in &l0.row_spans {
        let (j, k) = (j as usize, k as usize);
        for i in i0 as usize..i1 as usize {
            let c = [i, j, k];
            if label[grid.index(c)] != L_FLUID {
                continue;
            }
            let p = l0.pad(i, j, k);
            for a in 0..3 {
                // The +a face, stored at the cell; the -a face to an open cell, at the open cell
                // (a fluid one stores it itself).
                if let Some(g) = grid.neighbour(c, a, 1) {
                    if label[grid.index(g)] != L_SOLID {
                        let mut f = c;
                        f[a] = if c[a] + 1 == dims[a] { 0 } else { c[a] + 1 };
                        l0.wt[a][p] = face(a, f);
                    }
                }
                if let Some(g) = grid.neighbour(c, a, -1) {
                    if label[grid.index(g)] == L_OPEN {
                        let pg = l0.pad(g[0], g[1], g[2]);
                        l0.wt[a][pg] = face(a, c);
                    }
                }
            }
        }
    }
    if l0.periodic.iter().any(|&p| p) {
        let mut wt = std::mem::take(&mut l0.wt);
        for w in &mut wt {
            l0.halo(w);
        }
        l0.wt = wt;
    }
    l0.diagonal_from_couplings();
}

impl FluidSolver {
    /// The solver's scaled pressure `dq = to_q pressure_pa` on the fluid spans of level 0.
    pub(super) fn pressure_to_dq(&mut self, to_q: f64) {
        let pressure_pa = &self.pressure_pa;
        let ps = &mut self.pressure;
        for_spans(&ps.mg.levels[0], &mut ps.dq, |spans, dq, off| {
            for &[s, e] in spans {
                let (s, e) = (s as usize, e as usize);
                for (q, &p) in dq[s - off..e - off].iter_mut().zip(&pressure_pa[s..e]) {
                    *q = p * to_q;
                }
            }
            0.0
        });
    }

    /// `-h div u` on the fluid cells of level 0's padded box (zero elsewhere), into the pressure
    /// solver's right-hand side, with the incompatible mean of closed regions removed; returns the
    /// largest mean removed (m/s). Row by row: each row's faces are contiguous in every component.
    pub(super) fn divergence_rhs(&mut self) -> f64 {
        if self.grid.cut_fractions().is_some() {
            return self.divergence_rhs_cut();
        }
        let ps = &mut self.pressure;
        let l0 = &ps.mg.levels[0];
        let [nx, ny, nz] = self.grid.dims();
        let periodic = self.grid.periodic();
        let fd = self.layout.fdims;
        let [u0, u1, u2] = &self.u;
        // `out` holds the padded box from index `off`.
        let rows_kernel = |rows: &[[u32; 4]], out: &mut [f64], off: usize| {
            for &[j, k, i0, i1] in rows {
                let (j, k, i0, i1) = (j as usize, k as usize, i0 as usize, i1 as usize);
                let n = i1 - i0;
                let up = |a: usize, v: usize, len: usize| {
                    if v + 1 == len && periodic[a] {
                        0
                    } else {
                        v + 1
                    }
                };
                let x0 = i0 + fd[0][0] * (j + fd[0][1] * k);
                let (y0, y1) = (nx * (j + fd[1][1] * k), nx * (up(1, j, ny) + fd[1][1] * k));
                let (z0, z1) = (nx * (j + ny * k), nx * (j + ny * up(2, k, nz)));
                let (xl, yl, yu) = (
                    &u0[x0..x0 + n],
                    &u1[y0 + i0..y0 + i1],
                    &u1[y1 + i0..y1 + i1],
                );
                let (zl, zu) = (&u2[z0 + i0..z0 + i1], &u2[z1 + i0..z1 + i1]);
                // The upper x face of the row's last cell wraps on a periodic axis.
                let wrap = periodic[0] && i1 == nx;
                let xu = &u0[x0 + 1..x0 + n + usize::from(!wrap)];
                let p0 = l0.pad(i0, j, k);
                let (out, mask) = (&mut out[p0 - off..p0 - off + n], &l0.mask[p0..p0 + n]);
                for i in 0..xu.len() {
                    let dx = xu[i] as f64 - xl[i] as f64;
                    let dy = yu[i] as f64 - yl[i] as f64;
                    let dz = zu[i] as f64 - zl[i] as f64;
                    out[i] = -(dx + dy + dz) * mask[i] as f64;
                }
                if wrap {
                    let i = n - 1;
                    let dx = u0[x0 - i0] as f64 - xl[i] as f64;
                    let dy = yu[i] as f64 - yl[i] as f64;
                    let dz = zu[i] as f64 - zl[i] as f64;
                    out[i] = -(dx + dy + dz) * mask[i] as f64;
                }
            }
        };
        let rows = &l0.row_spans[..];
        // Split where the level's kernels split, so each thread writes the half of `bd` it
        // reads in the solve.
        let pad = |r: &[u32; 4]| l0.pad(r[2] as usize, r[0] as usize, r[1] as usize);
        let mid = l0.split_at();
        let m = rows.partition_point(|r| pad(r) < mid);
        if l0.parallel && m > 0 && m < rows.len() {
            let mid = pad(&rows[m]);
            let (a, b) = ps.bd.split_at_mut(mid);
            let (ra, rb) = rows.split_at(m);
            crate::fork_join::join(|| rows_kernel(ra, a, 0), || rows_kernel(rb, b, mid));
        } else {
            rows_kernel(rows, &mut ps.bd, 0);
        }
        let q = self.grid.boundary_fluxes_m3_per_s();
        if !q.is_empty() {
            let to_rhs = 1.0 / (self.grid.spacing_m() * self.grid.spacing_m());
            for &[j, k, i0, i1] in rows {
                let (j, k) = (j as usize, k as usize);
                let (p0, c0) = (l0.pad(i0 as usize, j, k), self.grid.index([0, j, k]));
                for i in i0 as usize..i1 as usize {
                    let (p, qc) = (p0 + i - i0 as usize, q[c0 + i]);
                    // A zero flux leaves the value (and the sign of a zero) as it is.
                    if qc != 0.0 && l0.mask[p] != 0.0 {
                        ps.bd[p] += qc * to_rhs;
                    }
                }
            }
        }
        self.shift_weighted_boundaries();
        self.pressure
            .regions
            .remove_closed_means_dense(&mut self.pressure.bd)
    }

    /// [`FluidSolver::divergence_rhs`] with cut cells: `-(sum A_f u_f - q / h^2)` over each fluid
    /// cell's faces (`h^2` times the flux out of the cell's fluid part less the flux `q` its
    /// boundaries push in, [`FluidGrid::boundary_fluxes_m3_per_s`]; `A_f` the open area fraction).
    fn divergence_rhs_cut(&mut self) -> f64 {
        let ps = &mut self.pressure;
        let l0 = &ps.mg.levels[0];
        let Some(cut) = self.grid.cut_fractions() else {
            return 0.0;
        };
        let dims = self.grid.dims();
        let layout = &self.layout;
        let q = self.grid.boundary_fluxes_m3_per_s();
        let to_rhs = 1.0 / (self.grid.spacing_m() * self.grid.spacing_m());
        for &[j, k, i0, i1] in &l0.row_spans {
            let (j, k) = (j as usize, k as usize);
            for i in i0 as usize..i1 as usize {
                let p = l0.pad(i, j, k);
                if l0.mask[p] == 0.0 {
                    ps.bd[p] = 0.0;
                    continue;
                }
                let c = [i, j, k];
                let mut flux = 0.0f64;
                for a in 0..3 {
                    let mut up = c;
                    up[a] = if c[a] + 1 == dims[a] && layout.periodic[a] {
                        0
                    } else {
                        c[a] + 1
                    };
                    let (fl, fu) = (layout.face_index(a, c), layout.face_index(a, up));
                    flux += cut.face[a][fu] as f64 * self.u[a][fu] as f64
                        - cut.face[a][fl] as f64 * self.u[a][fl] as f64;
                }
                // `flux - 0.0` is `flux` bit for bit: no boundary flux is today's value.
                if let Some(&qc) = q.get(self.grid.index(c)) {
                    flux -= qc * to_rhs;
                }
                ps.bd[p] = -flux;
            }
        }
        self.shift_weighted_boundaries();
        self.pressure
            .regions
            .remove_closed_means_dense(&mut self.pressure.bd)
    }

    /// `dst` (a dense, padded vector like `bd`) sized and set to `src` (per cell) on the fluid
    /// cells, 0 elsewhere in the spans; returns its sum.
    fn fill_padded(
        dst: &mut Vec<f64>,
        len: usize,
        src: &[f64],
        l0: &Level,
        grid: &FluidGrid,
    ) -> f64 {
        if dst.len() != len {
            dst.clear();
            dst.resize(len, 0.0);
        }
        let mut sum = 0.0;
        for &[j, k, i0, i1] in &l0.row_spans {
            let (j, k) = (j as usize, k as usize);
            let (p0, c0) = (l0.pad(i0 as usize, j, k), grid.index([i0 as usize, j, k]));
            let n = (i1 - i0) as usize;
            for (x, (&wc, &mk)) in dst[p0..p0 + n]
                .iter_mut()
                .zip(src[c0..c0 + n].iter().zip(&l0.mask[p0..p0 + n]))
            {
                *x = if mk != 0.0 { wc } else { 0.0 };
                sum += *x;
            }
        }
        sum
    }

    /// The shared flux (`FluidGrid::shared_flux_m3_per_s`) into the right-hand side `bd`, over
    /// the weighted fluid cells of the regions that can carry it; then closed regions with
    /// weighted boundaries (`FluidGrid::boundary_flux_weights_m2`) balance by shifting those
    /// boundaries' fluxes in `bd`; the rest of a mismatch is removed as a uniform mean after
    /// this. Nothing changes without weights.
    fn shift_weighted_boundaries(&mut self) {
        self.boundary_flux_shift_m3_per_s = 0.0;
        self.shared_flux_m3_per_s = 0.0;
        let ps = &mut self.pressure;
        let l0 = &ps.mg.levels[0];
        let len = ps.bd.len();
        let w = self.grid.boundary_flux_weights_m2();
        let h = self.grid.spacing_m();
        if !w.is_empty() {
            Self::fill_padded(&mut ps.wd, len, w, l0, &self.grid);
        }
        let (shared, s) = (
            self.grid.shared_flux_m3_per_s(),
            self.grid.shared_flux_weights_m2(),
        );
        if shared != 0.0 && !s.is_empty() {
            let all = Self::fill_padded(&mut ps.sd, len, s, l0, &self.grid);
            let wd = (!w.is_empty()).then_some(&ps.wd[..]);
            let zeroed = ps.regions.zero_stranded_dense(&mut ps.sd, wd);
            let mut carrying = all - zeroed;
            // Only pockets hold weight (the difference is rounding): all of them share it.
            if carrying <= 1e-9 * all {
                carrying = Self::fill_padded(&mut ps.sd, len, s, l0, &self.grid);
            }
            if carrying > 0.0 {
                let per_weight = shared / (carrying * h * h);
                for &[j, k, i0, i1] in &l0.row_spans {
                    let p0 = l0.pad(i0 as usize, j as usize, k as usize);
                    let r = p0..p0 + (i1 - i0) as usize;
                    for (b, &sc) in ps.bd[r.clone()].iter_mut().zip(&ps.sd[r]) {
                        if sc != 0.0 {
                            *b += per_weight * sc;
                        }
                    }
                }
                self.shared_flux_m3_per_s = shared;
            }
        }
        if w.is_empty() || !ps.regions.any_closed() {
            return;
        }
        let taken = ps.regions.shift_closed_sums_dense(&mut ps.bd, &ps.wd);
        // `bd` is `q / h^2 - flux out`: taking `s` from it takes `s h^2` from the fluxes in.
        self.boundary_flux_shift_m3_per_s = -taken * h * h;
    }

    /// The boundary fluxes a projection applies now: [`FluidGrid::boundary_fluxes_m3_per_s`]
    /// summed over the fluid cells (the others' values do not count) plus the last projection's
    /// shift of the weighted ones (`StepStats::boundary_flux_shift_m3_per_s`) and its shared flux
    /// (`StepStats::shared_flux_m3_per_s`), m^3/s into the fluid.
    pub fn applied_boundary_flux_m3_per_s(&self) -> f64 {
        self.boundary_flux_shift_m3_per_s
            + self.shared_flux_m3_per_s
            + self.set_boundary_flux_m3_per_s()
    }

    /// [`FluidGrid::boundary_fluxes_m3_per_s`] summed over the fluid cells, as set (without the
    /// last projection's shift), m^3/s into the fluid.
    fn set_boundary_flux_m3_per_s(&self) -> f64 {
        let q = self.grid.boundary_fluxes_m3_per_s();
        if q.is_empty() || self.revision != self.grid.revision() {
            // Before the first step on these labels the cells are read from the labels.
            return q
                .iter()
                .zip(self.grid.labels())
                .filter(|(_, &l)| l == CellLabel::Fluid)
                .map(|(&v, _)| v)
                .sum();
        }
        let l0 = &self.pressure.mg.levels[0];
        let mut sum = 0.0;
        for &[j, k, i0, i1] in &l0.row_spans {
            let c0 = self.grid.index([0, j as usize, k as usize]);
            for i in i0 as usize..i1 as usize {
                if l0.mask[l0.pad(i, j as usize, k as usize)] != 0.0 {
                    sum += q[c0 + i];
                }
            }
        }
        sum
    }

    /// The speed the divergence tolerance is relative to: the largest face speed, the
    /// parameters' `velocity_scale_m_s`, and the largest speed a boundary flux pushes through
    /// a cell's side (`|q| / h^2`: walls moving inside cut cells move no face), m/s.
    fn speed_scale_m_s(&self) -> f64 {
        let mut u = self.max_speed_m_s().max(self.params.velocity_scale_m_s);
        let q = self.grid.boundary_fluxes_m3_per_s();
        if !q.is_empty() {
            let h = self.grid.spacing_m();
            let l0 = &self.pressure.mg.levels[0];
            let mut q_max = 0.0f64;
            for &[j, k, i0, i1] in &l0.row_spans {
                let c0 = self.grid.index([0, j as usize, k as usize]);
                for &v in &q[c0 + i0 as usize..c0 + i1 as usize] {
                    q_max = q_max.max(v.abs());
                }
            }
            u = u.max(q_max / (h * h));
        }
        u.max(1e-12)
    }

    /// Largest `|h div u|` over the fluid cells from the last [`FluidSolver::divergence_rhs`].
    pub(super) fn max_divergence_m_s(&self) -> f64 {
        max_abs_spans(&self.pressure.mg.levels[0], &self.pressure.bd)
    }

    /// `u -= grad q` on the active faces, `q` being the dense solution of the pressure solver.
    pub(super) fn subtract_gradient(&mut self) {
        let l0 = &self.pressure.mg.levels[0];
        let q = &self.pressure.dq;
        let strides = [1, l0.sy, l0.sz];
        let split = l0.split_at();
        for c in 0..3 {
            let st = strides[c];
            // `u` holds the full face array from index `off`.
            let kernel = |runs: &[[u32; 3]], cells: &[u32], u: &mut [f32], off: usize| {
                for (&[first, _, len], &pu) in runs.iter().zip(cells) {
                    let (f, pu, n) = (first as usize - off, pu as usize, len as usize);
                    let (up, lo) = (&q[pu..pu + n], &q[pu - st..pu - st + n]);
                    for ((u, &qu), &ql) in u[f..f + n].iter_mut().zip(up).zip(lo) {
                        *u -= (qu - ql) as f32;
                    }
                }
            };
            let (runs, cells) = (&self.faces[c].runs[..], &self.run_cells[c][..]);
            // Split at the level's split: each thread reads the half of `q` the solve wrote there
            // (a run's cells are consecutive, `run_cells` holds the first's padded index).
            let m = cells.partition_point(|&p| (p as usize) < split);
            if l0.parallel && m > 0 && m < runs.len() {
                let mid = runs[m][0] as usize;
                let (a, b) = self.u[c].split_at_mut(mid);
                let ((ra, rb), (ca, cb)) = (runs.split_at(m), cells.split_at(m));
                crate::fork_join::join(|| kernel(ra, ca, a, 0), || kernel(rb, cb, b, mid));
            } else {
                kernel(runs, cells, &mut self.u[c], 0);
            }
            // A face with no open area is a wall: the pressure does not act there.
            for &idx in &self.cut_closed[c] {
                self.u[c][idx as usize] = 0.0;
            }
        }
    }

    pub(super) fn project(&mut self, dt: f64, stats: &mut StepStats) {
        let n = self.fluid_cells();
        if n == 0 {
            stats.max_div_rel = 0.0;
            return;
        }
        let h = self.grid.spacing_m();
        let rho = self.params.density_kg_m3;
        let u_ref = self.speed_scale_m_s();
        self.pressure
            .set_parallel_rows(self.params.parallel_threshold_cells);
        let mismatch = self.divergence_rhs();
        stats.closed_region_mismatch_m_s = stats.closed_region_mismatch_m_s.max(mismatch);
        stats.closed_region_flux_m3_per_s = stats
            .closed_region_flux_m3_per_s
            .max(self.pressure.regions.removed_total * h * h);
        stats.boundary_flux_shift_m3_per_s = self.boundary_flux_shift_m3_per_s;
        stats.shared_flux_m3_per_s = self.shared_flux_m3_per_s;
        let to_q = dt / (rho * h);
        let periodic = self.grid.periodic().iter().any(|&p| p);
        self.pressure_to_dq(to_q);
        let method = self.params.projection;
        let tol_abs = self.params.tolerance * u_ref;
        let mut iterations_left = self.params.max_iterations;
        let mut max_div = f64::INFINITY;
        // The CG stops on its recurrence residual at half the tolerance (the velocity update is
        // rounded to f32, and the divergence measured afterwards from the f32 faces must still meet
        // the tolerance). That measured divergence is the true residual: if it misses the
        // tolerance (f32 inner solves, or a warm start far off), it is the right-hand side of a
        // correction solve from zero, at most twice.
        for round in 0..3 {
            if round > 0 {
                if max_div <= tol_abs || iterations_left == 0 || method.is_fixed_sweeps() {
                    break;
                }
                self.pressure.dq.fill(0.0);
            }
            let out = self
                .pressure
                .solve(method, 0.5 * tol_abs, iterations_left.max(1));
            iterations_left = iterations_left.saturating_sub(out.iterations);
            stats.projection_iterations += out.iterations;
            let l0 = &self.pressure.mg.levels[0];
            if periodic {
                l0.halo(&mut self.pressure.dq);
            }
            let dq = &self.pressure.dq;
            for_spans(l0, &mut self.pressure_pa, |spans, pa, off| {
                for &[s, e] in spans {
                    let (s, e) = (s as usize, e as usize);
                    for (p, &qv) in pa[s - off..e - off].iter_mut().zip(&dq[s..e]) {
                        *p = if round == 0 {
                            qv / to_q
                        } else {
                            *p + qv / to_q
                        };
                    }
                }
                0.0
            });
            self.subtract_gradient();
            self.divergence_rhs();
            max_div = self.max_divergence_m_s();
        }
        // Every method is judged on the measured divergence (the fixed sweeps too).
        if max_div > tol_abs {
            stats.projection_converged = false;
        }
        stats.max_div_rel = max_div / u_ref;
    }

    /// Max |div u| h / U over fluid cells now (closed regions' incompatible mean removed).
    pub fn max_divergence_rel(&mut self) -> f64 {
        if self.fluid_cells() == 0 {
            return 0.0;
        }
        let u_ref = self.speed_scale_m_s();
        self.divergence_rhs();
        self.max_divergence_m_s() / u_ref
    }

    /// Projects the current velocity field (e.g. after setting an initial condition) without
    /// advancing time.
    pub fn project_now(&mut self, dt_s: f64) -> StepStats {
        let mut stats = StepStats {
            projection_converged: true,
            ..Default::default()
        };
        if self.revision != self.grid.revision() {
            self.rebuild_topology();
        }
        self.apply_fixed(true);
        self.project(dt_s, &mut stats);
        self.pressure_from_step = false;
        self.extrapolate();
        stats
    }
}
