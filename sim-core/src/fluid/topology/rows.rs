//! What changed since the last topology build ([`LabelDiff`]: the labels, compared x row by x
//! row) and the x range of the open cells of every cell row.

use super::super::grid::FluidGrid;
use super::super::CellLabel;

/// Labels as of the last topology build, and the cells and cell rows whose labels changed since:
/// what an incremental update starts from.
#[derive(Default, Debug)]
pub(crate) struct LabelDiff {
    seen: Vec<u8>,
    changed: Vec<u32>,
    cells: Vec<u32>,
}

impl LabelDiff {
    /// Compares the labels with those of the last call, x row (`nx` cells) by x row, and keeps
    /// them: true when there was a previous call of the same size, and then [`LabelDiff::rows`]
    /// and [`LabelDiff::cells`] tell what changed (false: everything did).
    pub fn update(&mut self, labels: &[CellLabel], nx: usize) -> bool {
        self.changed.clear();
        self.cells.clear();
        if self.seen.len() != labels.len() || nx == 0 {
            self.seen.clear();
            self.seen.extend(labels.iter().map(|&l| l as u8));
            return false;
        }
        for (r, (now, seen)) in labels
            .chunks_exact(nx)
            .zip(self.seen.chunks_exact_mut(nx))
            .enumerate()
        {
            // An OR of differences (no early exit) vectorises.
            let differ = now
                .iter()
                .zip(seen.iter())
                .fold(0u8, |acc, (&l, &s)| acc | (l as u8 ^ s));
            if differ != 0 {
                for (i, (s, &l)) in seen.iter_mut().zip(now).enumerate() {
                    if *s != l as u8 {
                        *s = l as u8;
                        self.cells.push((r * nx + i) as u32);
                    }
                }
                self.changed.push(r as u32);
            }
        }
        true
    }

    /// The rows (`j + ny k`) whose labels the last [`LabelDiff::update`] found changed.
    pub fn rows(&self) -> &[u32] {
        &self.changed
    }

    /// The cells (linear indices) whose labels the last [`LabelDiff::update`] found changed.
    pub fn cells(&self) -> &[u32] {
        &self.cells
    }
}

/// The x range `[first, end)` of the open (fluid or outflow) cells of every cell row `(j, k)`
/// (index `j + ny k`; `[0, 0]` when the row has none): the only rows whose faces can be active or
/// fixed, so a rebuild costs the fluid region, not the box.
pub(crate) fn open_row_ranges(grid: &FluidGrid, out: &mut Vec<[u32; 2]>) {
    let nx = grid.dims()[0];
    out.clear();
    out.extend(grid.labels().chunks_exact(nx).map(open_row_range));
}

/// [`open_row_ranges`] after the rows `changed` (from [`LabelDiff`]; None: all of them) changed.
pub(crate) fn update_open_row_ranges(
    grid: &FluidGrid,
    changed: Option<&[u32]>,
    out: &mut Vec<[u32; 2]>,
) {
    let [nx, ny, nz] = grid.dims();
    match changed {
        Some(changed) if out.len() == ny * nz => {
            for &row in changed {
                let row = row as usize;
                out[row] = open_row_range(&grid.labels()[row * nx..(row + 1) * nx]);
            }
        }
        _ => open_row_ranges(grid, out),
    }
}

/// The smallest x range `[first, end)` holding both (an empty range, `first >= end`, holds none).
pub(crate) fn range_hull(a: [u32; 2], b: [u32; 2]) -> [u32; 2] {
    match (a[0] < a[1], b[0] < b[1]) {
        (false, _) => b,
        (_, false) => a,
        _ => [a[0].min(b[0]), a[1].max(b[1])],
    }
}

/// The x range of the open cells of one cell row (`[0, 0]`: none).
fn open_row_range(row: &[CellLabel]) -> [u32; 2] {
    let open = |l: &CellLabel| matches!(l, CellLabel::Fluid | CellLabel::Outflow);
    match row.iter().position(open) {
        Some(first) => {
            let last = row.iter().rposition(open).unwrap_or(first); // ok: `first` is open
            [first as u32, last as u32 + 1]
        }
        None => [0, 0],
    }
}
