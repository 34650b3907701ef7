//! One multigrid level: the labels, the dense (padded) operator and vectors, the spans the
//! kernels run over and where they split in two halves, and (level 0) the compressed rows of the
//! reference solvers, built from the labels within the rows' ranges.

use super::super::grid::step_along;
use super::super::topology::NONE;

/// Label codes of a level.
pub(crate) const L_SOLID: u8 = 0;
pub(crate) const L_FLUID: u8 = 1;
pub(crate) const L_OPEN: u8 = 2;

/// Lanes of the f32 reductions (one AVX register; the compiler vectorises the fixed-width bodies),
/// and the multiple of cells the spans are rounded to ([`round_spans`]).
pub(super) const LANES: usize = 8;

/// Spans closer than this many cells merge (the cells between are masked out, so this only trades
/// work on non-fluid cells for longer vector loops; on the benchmark cavity 48 beat 12 by ~15 % of
/// the projection at 0.6 and 1.2 mm, 128 gained nothing more).
const SPAN_GAP: usize = 48;

/// The fixed cost of a span in a kernel, in cells: splitting a level's kernels in two halves of
/// equal cells left the half with the cavity's fragmented end (342 spans against 29 on the 0.6 mm
/// scene) taking 1.5-1.7 times as long as the other in every kernel; fitted to those times, a span
/// costs as much as about 33 cells (BENCHMARKS.md, "Residual maximum and the split, session 13").
const SPAN_COST: usize = 32;

/// Padded index of interior cell (i, j, k) in a box of strides `sy`, `sz` with one ghost layer.
#[inline]
pub(super) fn pad_index(sy: usize, sz: usize, i: usize, j: usize, k: usize) -> usize {
    (i + 1) + sy * (j + 1) + sz * (k + 1)
}

/// Where [`Level::build_dense`] takes the diagonal from.
#[derive(Clone, Copy)]
pub(super) enum DenseDiag {
    /// Counted from the labels (level 0, and a coarse level with unit couplings).
    Count,
    /// Left to [`Level::galerkin`], which sets it on every fluid cell.
    Later,
}

/// One multigrid level.
#[derive(Default, Debug)]
pub(crate) struct Level {
    pub dims: [usize; 3],
    pub periodic: [bool; 3],
    pub label: Vec<u8>,
    /// Whether the compressed rows below match the labels (level 0 only; built by
    /// [`Level::build_compressed_rows`] when a reference solver needs them).
    pub rows_built: bool,
    /// Compressed rows (level 0 only): row of each cell (NONE if not fluid), cell of each row.
    pub row_of_cell: Vec<u32>,
    pub cell_of_row: Vec<u32>,
    /// Neighbour rows, order -x +x -y +y -z +z; a wall or open neighbour is `rows()` (level 0 only).
    pub nbr: Vec<[u32; 6]>,
    /// The coupling to each neighbour in `nbr` (the face's weight: 1 without cut cells; level 0
    /// only).
    pub nbr_w: Vec<[f32; 6]>,
    /// Number of fluid or open neighbours, per row (level 0 only).
    pub diag: Vec<f32>,
    pub inv_diag: Vec<f32>,
    /// Dense (padded) index of each compressed row (level 0 only).
    pub pad_of_row: Vec<u32>,
    /// Strides of the padded box along y and z (x is 1).
    pub sy: usize,
    pub sz: usize,
    /// Fluid cells.
    pub fluid: usize,
    /// Padded-index ranges `[start, end)` that cover every fluid cell.
    pub spans: Vec<[u32; 2]>,
    /// The spans before the last [`Level::build_dense`] (`None`: the dense vectors were cleared
    /// whole): every dense vector of the level and of the pressure solver is zero outside the
    /// spans, so a relabelling zeroes these ranges instead of the box.
    pub old_spans: Option<Vec<[u32; 2]>>,
    /// First span of the second half (by cells) when the level runs on two threads.
    pub split_span: usize,
    /// Whether the kernels of this level run on rayon (set by the solver from its threshold).
    pub parallel: bool,
    /// Interior rows holding fluid: `[j, k, i_first, i_end)`.
    pub row_spans: Vec<[u32; 4]>,
    /// Per row `j + ny k`, an x range `[first, end)` outside which every cell of the row is solid
    /// (`[0, 0]`: the whole row is). The builds visit only these ranges and clear only the last
    /// ones, so a relabelling costs the fluid region, not the box.
    pub row_ext: Vec<[u32; 2]>,
    /// Dense diagonal (fluid cells; 0 elsewhere), fluid mask, and the inverse diagonal on red
    /// (`inv[0]`, even i+j+k) and black (`inv[1]`) fluid cells only.
    pub ddiag: Vec<f32>,
    pub mask: Vec<f32>,
    pub inv: [Vec<f32>; 2],
    /// Face couplings of a Galerkin coarse level (dense, per axis: the coupling of a cell to its
    /// +axis neighbour); empty on level 0 and on periodic levels, whose couplings are 1 between
    /// unknowns (and to open cells, in the diagonal).
    pub wt: [Vec<f32>; 3],
    /// Level 0 with cut cells: the box (`dims`) and the row ranges (`row_ext`) the couplings in
    /// `wt` were last written within (empty: unknown, `wt` is cleared whole). Outside them `wt`
    /// is zero, so the next build clears only these ranges rather than the box (at 0.6 mm the
    /// three padded boxes are about 5 MB a rebuild).
    pub wt_ext: ([usize; 3], Vec<[u32; 2]>),
    /// Scratch of [`Level::build_dense`]: one row's neighbour counts.
    pub row_counts: Vec<u8>,
    /// Dense unknowns, right-hand side and residual.
    pub x: Vec<f32>,
    pub b: Vec<f32>,
    pub r: Vec<f32>,
}

impl Level {
    /// The face couplings the kernels weight the neighbours by (`None`: unit couplings).
    pub(crate) fn couplings(&self) -> Option<[&[f32]; 3]> {
        let [a, b, c] = &self.wt;
        (!a.is_empty()).then_some([&a[..], &b[..], &c[..]])
    }

    /// Fluid cells (the compressed rows, when built).
    pub fn rows(&self) -> usize {
        self.fluid
    }

    /// Cell indices of the six neighbours of cell `c` (index `ci`), order -x +x -y +y -z +z, with
    /// `usize::MAX` past a non-periodic wall (a periodic axis wraps, onto the cell itself when it
    /// is one cell long).
    #[inline(always)]
    pub(crate) fn neighbour_cells(&self, c: [usize; 3], ci: usize) -> [usize; 6] {
        let [nx, ny, _] = self.dims;
        let stride = [1, nx, nx * ny];
        let mut out = [usize::MAX; 6];
        for a in 0..3 {
            let beside = step_along(ci, c[a], self.dims[a], stride[a], self.periodic[a]);
            for (o, b) in out[2 * a..2 * a + 2].iter_mut().zip(beside) {
                *o = b.unwrap_or(usize::MAX);
            }
        }
        out
    }

    /// The padded index at which the level's kernels split in two halves (the first cell of
    /// the second half's spans; the vector's end when they do not split).
    pub fn split_at(&self) -> usize {
        match self.spans.get(self.split_span) {
            Some(&[p, _]) if self.split_span > 0 => p as usize,
            _ => self.mask.len(),
        }
    }

    /// Padded index of interior cell (i, j, k).
    #[inline]
    pub fn pad(&self, i: usize, j: usize, k: usize) -> usize {
        pad_index(self.sy, self.sz, i, j, k)
    }

    /// Linear index of the first cell of the rows beside row `(j, k)`, order -y +y -z +z (`None`
    /// past a non-periodic wall; a periodic axis wraps, onto the row itself when it is one row
    /// long), as [`Level::neighbour_cells`] steps.
    pub(crate) fn neighbour_rows(&self, j: usize, k: usize) -> [Option<usize>; 4] {
        let [nx, ny, nz] = self.dims;
        let row = nx * (j + ny * k);
        let [ym, yp] = step_along(row, j, ny, nx, self.periodic[1]);
        let [zm, zp] = step_along(row, k, nz, nx * ny, self.periodic[2]);
        [ym, yp, zm, zp]
    }

    /// The number of fluid or open neighbours of cells `a..b` of the row starting at cell `row`
    /// (`rows`: [`Level::neighbour_rows`] of it) into `out`, a row's slice at a time (the
    /// loops vectorise).
    fn count_row(
        &self,
        row: usize,
        [a, b]: [usize; 2],
        rows: &[Option<usize>; 4],
        out: &mut Vec<u8>,
    ) {
        let nx = self.dims[0];
        out.clear();
        out.resize(b - a, 0);
        let add = |out: &mut [u8], labels: &[u8]| {
            for (o, &l) in out.iter_mut().zip(labels) {
                *o += u8::from(l != L_SOLID);
            }
        };
        for r in rows.iter().flatten() {
            add(out, &self.label[r + a..r + b]);
        }
        let label = &self.label[row..row + nx];
        // -x: the cell before, or across a periodic axis the row's last cell.
        let lo = usize::from(a == 0);
        add(&mut out[lo..], &label[a + lo - 1..b - 1]);
        if a == 0 && self.periodic[0] {
            out[0] += u8::from(label[nx - 1] != L_SOLID);
        }
        // +x: the cell after, or across a periodic axis the row's first cell.
        let hi = b - usize::from(b == nx);
        add(&mut out[..hi - a], &label[a + 1..hi + 1]);
        if b == nx && self.periodic[0] {
            out[b - a - 1] += u8::from(label[0] != L_SOLID);
        }
    }

    /// Sets level 0's box and its labels: `label(cell)` inside the row ranges `rows` (per row
    /// `j + ny k`, `[first, end)`), solid everywhere else. When the box is unchanged only the
    /// ranges of the last call and of this one are written.
    pub fn set_labels(
        &mut self,
        dims: [usize; 3],
        periodic: [bool; 3],
        rows: &[[u32; 2]],
        label: impl Fn(usize) -> u8,
    ) {
        let [nx, ny, nz] = dims;
        debug_assert_eq!(rows.len(), ny * nz);
        let same = self.dims == dims
            && self.periodic == periodic
            && self.label.len() == nx * ny * nz
            && self.row_ext.len() == rows.len();
        self.dims = dims;
        self.periodic = periodic;
        if !same {
            self.label.clear();
            self.label.resize(nx * ny * nz, L_SOLID);
            self.row_ext.clear();
            self.row_ext.resize(rows.len(), [0, 0]);
        }
        for (r, (old, &new)) in self.row_ext.iter_mut().zip(rows).enumerate() {
            let base = r * nx;
            self.label[base + old[0] as usize..base + old[1] as usize].fill(L_SOLID);
            for c in base + new[0] as usize..base + new[1] as usize {
                self.label[c] = label(c);
            }
            *old = new;
        }
    }

    /// Row ranges of the non-solid cells of `label` (a scan of the box; [`Level::set_labels`]
    /// keeps them without one).
    #[cfg(test)]
    fn scan_row_ext(&mut self) {
        let nx = self.dims[0];
        self.row_ext.clear();
        for row in self.label.chunks_exact(nx) {
            let ext = match row.iter().position(|&l| l != L_SOLID) {
                Some(a) => {
                    let b = row.iter().rposition(|&l| l != L_SOLID).unwrap_or(a); // ok: `a` is
                    [a as u32, b as u32 + 1]
                }
                None => [0, 0],
            };
            self.row_ext.push(ext);
        }
    }

    /// Builds level 0 (dense form and compressed rows) from `label`, `dims`, `periodic`, scanning
    /// the box for the rows' ranges (the reference the solver's [`Level::set_labels`] and
    /// [`Level::build_in_extents`] must match).
    #[cfg(test)]
    pub fn build_rows(&mut self) {
        self.scan_row_ext();
        self.build_in_extents();
        self.build_compressed_rows();
    }

    /// Level 0's dense form from the labels within the row ranges `row_ext` (which
    /// [`Level::set_labels`] keeps): its cost is that of the ranges. The compressed rows, which only
    /// the reference solvers read, are built when one runs ([`Level::build_compressed_rows`]).
    pub fn build_in_extents(&mut self) {
        self.rows_built = false;
        self.build_dense(DenseDiag::Count);
    }

    /// The compressed rows of level 0 (row of each fluid cell in cell order, neighbour rows,
    /// diagonal, dense index), from the labels within `row_ext`, unless they are current.
    pub fn build_compressed_rows(&mut self) {
        if self.rows_built {
            return;
        }
        let [nx, ny, nz] = self.dims;
        debug_assert_eq!(self.row_ext.len(), ny * nz);
        let ncell = self.label.len();
        // `row_of_cell` is NONE but at the cells of the last rows.
        if self.row_of_cell.len() == ncell {
            for &c in &self.cell_of_row {
                self.row_of_cell[c as usize] = NONE;
            }
        } else {
            self.row_of_cell.clear();
            self.row_of_cell.resize(ncell, NONE);
        }
        self.cell_of_row.clear();
        for (r, &[a, b]) in self.row_ext.iter().enumerate() {
            for c in r * nx + a as usize..r * nx + b as usize {
                if self.label[c] == L_FLUID {
                    self.row_of_cell[c] = self.cell_of_row.len() as u32;
                    self.cell_of_row.push(c as u32);
                }
            }
        }
        self.nbr.clear();
        self.nbr_w.clear();
        self.diag.clear();
        self.inv_diag.clear();
        self.pad_of_row.clear();
        let zero_slot = self.cell_of_row.len() as u32;
        let (sy, sz) = (nx + 2, (nx + 2) * (ny + 2));
        // The same order as the scan above: row by row within the ranges.
        for (r, &[a, b]) in self.row_ext.iter().enumerate() {
            let (j, k) = (r % ny, r / ny);
            for i in a as usize..b as usize {
                let ci = r * nx + i;
                if self.label[ci] != L_FLUID {
                    continue;
                }
                let mut nb = [zero_slot; 6];
                let mut nw = [0.0f32; 6];
                let mut diag = 0.0f32;
                let weighted = !self.wt[0].is_empty();
                let p = pad_index(sy, sz, i, j, k);
                for (s, g) in self.neighbour_cells([i, j, k], ci).into_iter().enumerate() {
                    if g == usize::MAX || self.label[g] == L_SOLID {
                        continue;
                    }
                    // The face's coupling: stored at the cell for its +a face, at the neighbour
                    // for its -a face.
                    let w = if !weighted {
                        1.0
                    } else if s % 2 == 1 {
                        self.wt[s / 2][p]
                    } else {
                        let (gi, gr) = (g % nx, g / nx);
                        self.wt[s / 2][pad_index(sy, sz, gi, gr % ny, gr / ny)]
                    };
                    if self.label[g] == L_FLUID {
                        nb[s] = self.row_of_cell[g];
                        nw[s] = w;
                    }
                    diag += w;
                }
                self.nbr.push(nb);
                self.nbr_w.push(nw);
                self.diag.push(diag);
                self.inv_diag
                    .push(if diag > 0.0 { 1.0 / diag } else { 0.0 });
                self.pad_of_row.push(pad_index(sy, sz, i, j, k) as u32);
            }
        }
        self.rows_built = true;
    }

    /// Builds the dense (padded) operator, spans and vectors from `label`, the diagonal as `diag`
    /// says.
    pub(super) fn build_dense(&mut self, diag: DenseDiag) {
        let [nx, ny, nz] = self.dims;
        let (old_sy, old_sz) = (self.sy, self.sz);
        self.sy = nx + 2;
        self.sz = (nx + 2) * (ny + 2);
        let len = self.sz * (nz + 2);
        // Periodic halos are written outside the fluid cells: those levels clear the whole box.
        let sparse = self.mask.len() == len && !self.periodic.iter().any(|&p| p);
        let [inv0, inv1] = &mut self.inv;
        let vectors = [
            &mut self.ddiag,
            &mut self.mask,
            inv0,
            inv1,
            &mut self.x,
            &mut self.b,
            &mut self.r,
        ];
        if sparse {
            // Every vector of the level is zero off its fluid cells: clearing the last fluid
            // rows (not the spans, twice as long with their gaps) zeroes the box.
            for v in vectors {
                for &[j, k, i0, i1] in &self.row_spans {
                    let p = pad_index(old_sy, old_sz, i0 as usize, j as usize, k as usize);
                    v[p..p + (i1 - i0) as usize].fill(0.0);
                }
            }
            let mut old = self.old_spans.take().unwrap_or_default();
            old.clear();
            old.extend_from_slice(&self.spans);
            self.old_spans = Some(old);
        } else {
            for v in vectors {
                v.clear();
                v.resize(len, 0.0);
            }
            self.old_spans = None;
        }
        self.spans.clear();
        self.row_spans.clear();
        self.fluid = 0;
        let mut counts = std::mem::take(&mut self.row_counts);
        debug_assert_eq!(self.row_ext.len(), ny * nz);
        for k in 0..nz {
            for j in 0..ny {
                let mut first = None;
                let mut end = 0;
                let [a, b] = self.row_ext[j + ny * k];
                if a >= b {
                    continue;
                }
                let row = nx * (j + ny * k);
                if let DenseDiag::Count = diag {
                    let rows = self.neighbour_rows(j, k);
                    self.count_row(row, [a as usize, b as usize], &rows, &mut counts);
                }
                for i in a as usize..b as usize {
                    if self.label[row + i] != L_FLUID {
                        continue;
                    }
                    self.fluid += 1;
                    first.get_or_insert(i);
                    end = i + 1;
                    let p = self.pad(i, j, k);
                    self.mask[p] = 1.0;
                    let d = match diag {
                        DenseDiag::Count => counts[i - a as usize] as f32,
                        DenseDiag::Later => continue,
                    };
                    self.ddiag[p] = d;
                    self.inv[(i + j + k) % 2][p] = if d > 0.0 { 1.0 / d } else { 0.0 };
                }
                if let Some(i0) = first {
                    self.row_spans
                        .push([j as u32, k as u32, i0 as u32, end as u32]);
                    let (s, e) = (
                        self.pad(i0, j, k) as u32,
                        self.pad(end - 1, j, k) as u32 + 1,
                    );
                    match self.spans.last_mut() {
                        Some(last) if (s as usize) <= last[1] as usize + SPAN_GAP => last[1] = e,
                        _ => self.spans.push([s, e]),
                    }
                }
            }
        }
        self.row_counts = counts;
        if !self.periodic.iter().any(|&p| p) {
            round_spans(&mut self.spans, len - self.sz);
        }
        // The halves are balanced by their cost, a span's fixed part included (a fragmented end
        // of the cavity holds many short spans, a wide one a few long ones).
        let cost = |&[s, e]: &[u32; 2]| (e - s) as usize + SPAN_COST;
        let total: usize = self.spans.iter().map(cost).sum();
        let mut acc = 0;
        self.split_span = self.spans.len();
        for (n, span) in self.spans.iter().enumerate() {
            if 2 * acc >= total {
                self.split_span = n;
                break;
            }
            acc += cost(span);
        }
    }

    pub(super) fn any_periodic(&self) -> bool {
        self.periodic.iter().any(|&p| p)
    }

    /// The ghost layers of the periodic axes: `f(ghost, source)` for each piece, `ghost` a range of
    /// the padded vector and `source` the start of the interior cells it copies.
    fn ghost_layers(&self, mut f: impl FnMut(std::ops::Range<usize>, usize)) {
        let [nx, ny, nz] = self.dims;
        let (sy, sz) = (self.sy, self.sz);
        let (py, pz) = (ny + 2, nz + 2);
        if self.periodic[0] {
            for k in 0..pz {
                for j in 0..py {
                    let row = j * sy + k * sz;
                    f(row..row + 1, row + nx);
                    f(row + nx + 1..row + nx + 2, row + 1);
                }
            }
        }
        if self.periodic[1] {
            for k in 0..pz {
                let plane = k * sz;
                f(plane..plane + sy, plane + ny * sy);
                f(plane + (ny + 1) * sy..plane + (ny + 2) * sy, plane + sy);
            }
        }
        if self.periodic[2] {
            f(0..sz, nz * sz);
            f((nz + 1) * sz..(nz + 2) * sz, sz);
        }
    }

    /// Fills the ghost layers of periodic axes of `v` from the opposite side.
    pub fn halo<T: Copy>(&self, v: &mut [T]) {
        self.ghost_layers(|ghost, src| v.copy_within(src..src + ghost.len(), ghost.start));
    }

    /// Zeroes the ghost layers that [`Level::halo`] fills.
    pub(super) fn clear_halo(&self, v: &mut [f32]) {
        self.ghost_layers(|ghost, _| v[ghost].fill(0.0));
    }
}

/// Lengthens every span to a whole number of [`LANES`] cells where that stays below `limit` (the
/// first index whose +z neighbour window would leave the vector), merging spans that then meet.
/// The added cells are not fluid, so every kernel leaves them as they are (zero) while its loops
/// run without a scalar remainder: on the scene's thin cavity the remainders were a quarter of
/// the projection's instructions. Not for periodic levels, whose ghost cells hold halo copies.
pub(super) fn round_spans(spans: &mut Vec<[u32; 2]>, limit: usize) {
    let rounded = |[s, e]: [u32; 2]| {
        let want = s as usize + ((e - s) as usize).next_multiple_of(LANES);
        want.min(limit).max(e as usize) as u32
    };
    let mut out = 0usize;
    for n in 0..spans.len() {
        let [s, e] = spans[n];
        if out > 0 && s < rounded(spans[out - 1]) {
            spans[out - 1][1] = spans[out - 1][1].max(e);
        } else {
            spans[out] = [s, e];
            out += 1;
        }
    }
    spans.truncate(out);
    for span in spans.iter_mut() {
        span[1] = rounded(*span);
    }
}
