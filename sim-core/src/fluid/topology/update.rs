//! [`FaceSet::update`]: the face set brought up to date with the labels, computed again only
//! within [`DIRTY_REACH`] of the changed cells and carried over elsewhere.

use super::super::grid::FluidGrid;
use super::super::sample::Layout;
use super::super::CellLabel;
use super::faces::{extend_runs, face_cell_indices, face_class, label_or_solid, neighbours};
use super::{
    FaceSet, Irregular, ACTIVE, CONST_BIT, DIRTY_REACH, EXT1, EXT2, FAR, FIXED, NEAR, NONE, OTHER,
    ROW_LISTS,
};

/// The face coordinates along one axis (`n` faces, wrapping when `periodic`) within
/// [`DIRTY_REACH`] of faces `at` and `at + extra`, each once, with whether it is within one face
/// of them (on a periodic axis shorter than the span, a face is near if any of its images is).
fn dirty_span(
    at: usize,
    extra: usize,
    n: usize,
    periodic: bool,
) -> impl Iterator<Item = (usize, bool)> {
    let (r, n_i) = (DIRTY_REACH as i64, n as i64);
    let (first, last) = (at as i64, at as i64 + extra as i64);
    let (lo, hi) = (first - r, last + r);
    let (lo, hi) = if periodic {
        (lo, hi.min(lo + n_i - 1))
    } else {
        (lo.max(0), hi.min(n_i - 1))
    };
    // Faces first - 1 ..= last + 1 are near: `window` positions from first - 1.
    let window = last - first + 3;
    (lo..=hi).map(move |x| {
        let from = x - (first - 1);
        let near = if periodic {
            window >= n_i || from.rem_euclid(n_i) < window
        } else {
            (0..window).contains(&from)
        };
        (x.rem_euclid(n_i) as usize, near)
    })
}

impl FaceSet {
    /// The cells beside each active face (lower, upper; NONE = outside), as [`face_cells`] finds
    /// them, in the order of `active`.
    #[cfg(test)]
    pub fn active_cells(&self) -> &[[u32; 2]] {
        &self.active_cells
    }

    /// Rebuilds this component's face set from the labels from scratch, visiting only the faces of
    /// every face: the reference of [`FaceSet::update`].
    #[cfg(test)]
    pub fn rebuild(&mut self, grid: &FluidGrid, layout: &Layout, c: usize) {
        self.update(grid, layout, c, None);
    }

    /// Brings the face set up to date with the labels after the cells `changed` changed (linear
    /// indices, from [`LabelDiff`]; None: all of them). Only the faces near a changed cell are
    /// classified again and their stencils and extrapolation sources computed; the other faces'
    /// are carried over, their compact indices renumbered. The result equals a
    /// [`FaceSet::rebuild`] from scratch field by field. The class, compact and layer-position
    /// arrays stay box-sized and are reset only at the faces computed again.
    pub fn update(&mut self, grid: &FluidGrid, layout: &Layout, c: usize, changed: Option<&[u32]>) {
        let nf = layout.face_count(c);
        let d = layout.fdims[c];
        self.previous.clear();
        self.dropped.clear();
        let resized = self.class.len() != nf || self.fdims != d;
        if resized {
            self.fdims = d;
            self.class.clear();
            self.class.resize(nf, OTHER);
            self.compact.clear();
            self.compact.resize(nf, NONE);
            self.ext_pos.clear();
            self.ext_pos.resize(nf, NONE);
            self.marked.clear();
            self.marked.resize(nf, 0);
        }
        let cdims = grid.dims();
        self.mark_dirty(layout, c, cdims, if resized { None } else { changed });
        let face_index =
            |f: [u32; 3]| f[0] as usize + d[0] * (f[1] as usize + d[1] * f[2] as usize);

        // Forget the dirty faces (remembering the tracked ones for `dropped`): their classes are
        // found again below, the clean faces' stay.
        let full = self.full;
        let level = move |marked: &[u8], idx: usize| if full { NEAR } else { marked[idx] };
        for &f in &self.dirty {
            let idx = face_index(f);
            let near = level(&self.marked, idx) == NEAR;
            if self.class[idx] != OTHER && (near || self.class[idx] == EXT2) {
                self.class[idx] = OTHER;
                self.previous.push(idx as u32);
                self.ext_pos[idx] = NONE;
            }
            if near {
                self.compact[idx] = NONE;
                self.ext_pos[idx] = NONE;
            }
        }

        // The last build's per-face results move aside (buffers swapped, not allocated).
        let mut old = std::mem::take(&mut self.carried);
        std::mem::swap(&mut old.active, &mut self.active);
        std::mem::swap(&mut old.active_cells, &mut self.active_cells);
        std::mem::swap(&mut old.stencil, &mut self.stencil);
        std::mem::swap(&mut old.diag, &mut self.diag);
        std::mem::swap(&mut old.nbr, &mut self.nbr);
        std::mem::swap(&mut old.self_diag, &mut self.self_diag);
        std::mem::swap(&mut old.ghosts, &mut self.ghosts);
        std::mem::swap(&mut old.ext_start, &mut self.ext_start);
        std::mem::swap(&mut old.ext_src, &mut self.ext_src);
        std::mem::swap(&mut old.row_at, &mut self.row_at);
        std::mem::swap(&mut old.fixed_in_order, &mut self.fixed_in_order);
        std::mem::swap(&mut old.ext1, &mut self.ext1);
        std::mem::swap(&mut old.ext2, &mut self.ext2);
        std::mem::swap(&mut old.runs, &mut self.runs);
        std::mem::swap(&mut old.regular, &mut self.regular);
        std::mem::swap(&mut old.irregular, &mut self.irregular);
        old.ext1_len = old.ext1.len();
        self.row_at.clear();
        self.fixed_in_order.clear();
        self.active.clear();
        self.active_cells.clear();
        self.reuse.clear();
        self.fixed.clear();
        self.stencil.clear();
        self.diag.clear();
        self.nbr.clear();
        self.self_diag.clear();
        self.runs.clear();
        self.regular.clear();
        self.irregular.clear();
        self.ghosts.clear();
        self.ext1.clear();
        self.ext2.clear();
        for v in &mut self.ext_reuse {
            v.clear();
        }
        self.ext_start.clear();
        self.ext_src.clear();

        let labels = grid.labels();
        let cell_periodic = grid.periodic();
        // Classes of the dirty faces: active and fixed ones first, then the layers.
        for &f in &self.dirty {
            if level(&self.marked, face_index(f)) != NEAR {
                continue;
            }
            let f = f.map(|x| x as usize);
            let (li, ui) = face_cell_indices(cdims, cell_periodic, c, f);
            let class = face_class(label_or_solid(labels, li), label_or_solid(labels, ui));
            self.class[f[0] + d[0] * (f[1] + d[1] * f[2])] = class;
        }
        let fstride = [1, d[0], d[0] * d[1]];
        // Layers: the OTHER faces next to a face of the layer inside (the neighbour relation is
        // symmetric). Within a layer no face reads another's new class.
        for (layer, from) in [(EXT1, ACTIVE), (EXT2, EXT1)] {
            for &f in &self.dirty {
                let f = f.map(|x| x as usize);
                let idx = f[0] + d[0] * (f[1] + d[1] * f[2]);
                if self.class[idx] != OTHER || (layer == EXT1 && level(&self.marked, idx) != NEAR) {
                    continue;
                }
                let next_to_inside = neighbours(layout, c, f, idx, fstride)
                    .into_iter()
                    .flatten()
                    .any(|g| self.class[g] == from);
                if next_to_inside {
                    self.class[idx] = layer;
                }
            }
        }

        // The lists in index order. A clean row's entries are the last build's, as whole slices
        // (its faces get their new compact indices and layer positions); a dirty row's come from
        // its classes (eight at a time: most rows hold no tracked face), where a face carried over
        // still holds its previous compact index (or layer position): the dirty faces were reset
        // to NONE.
        let rows = d[1] * d[2];
        let mut row = 0;
        while row < rows {
            if !self.row_dirty[row] {
                // A stretch of clean rows: their entries are contiguous in every old list, so
                // they move as one slice per list.
                let end = self.clean_stretch_end(row);
                let (from, to) = (old.row_at[row], old.row_at[end]);
                let now = self.list_lengths();
                for at in &old.row_at[row..end] {
                    self.row_at
                        .push(std::array::from_fn(|l| now[l] + (at[l] - from[l])));
                }
                row = end;
                let span = |l: usize| from[l] as usize..to[l] as usize;
                let (a, n0) = (span(0), self.active.len() as u32);
                for (k, &idx) in old.active[a.clone()].iter().enumerate() {
                    self.compact[idx as usize] = n0 + k as u32;
                }
                self.active.extend_from_slice(&old.active[a.clone()]);
                self.active_cells
                    .extend_from_slice(&old.active_cells[a.clone()]);
                self.reuse.extend(a.start as u32..a.end as u32);
                for l in 0..2 {
                    let (q, list, was) = if l == 0 {
                        (span(1), &mut self.ext1, &old.ext1)
                    } else {
                        (span(2), &mut self.ext2, &old.ext2)
                    };
                    let p0 = list.len() as u32;
                    for (k, &idx) in was[q.clone()].iter().enumerate() {
                        self.ext_pos[idx as usize] = p0 + k as u32;
                    }
                    list.extend_from_slice(&was[q.clone()]);
                    let at = if l == 0 { 0 } else { old.ext1_len as u32 };
                    self.ext_reuse[l].extend((q.start as u32..q.end as u32).map(|q| at + q));
                }
                self.fixed_in_order
                    .extend_from_slice(&old.fixed_in_order[span(3)]);
                continue;
            }
            self.row_at.push(self.list_lengths());
            let (fj, fk) = (row % d[1], row / d[1]);
            let base = d[0] * row;
            row += 1;
            for (w, chunk) in self.class[base..base + d[0]].chunks(8).enumerate() {
                let empty = match <[u8; 8]>::try_from(chunk) {
                    Ok(word) => u64::from_ne_bytes(word) == 0,
                    Err(_) => chunk.iter().all(|&cl| cl == OTHER),
                };
                if empty {
                    continue;
                }
                for (b, &cl) in chunk.iter().enumerate() {
                    let i = 8 * w + b;
                    let idx = base + i;
                    match cl {
                        ACTIVE => {
                            let m = self.compact[idx];
                            self.compact[idx] = self.active.len() as u32;
                            self.active.push(idx as u32);
                            self.reuse.push(m);
                            self.active_cells.push(if m == NONE {
                                let (li, ui) =
                                    face_cell_indices(cdims, cell_periodic, c, [i, fj, fk]);
                                [li, ui]
                            } else {
                                old.active_cells[m as usize]
                            });
                        }
                        FIXED => {
                            let (li, ui) = face_cell_indices(cdims, cell_periodic, c, [i, fj, fk]);
                            self.fixed_in_order.push([idx as u32, li, ui]);
                        }
                        EXT1 | EXT2 => {
                            let l = usize::from(cl == EXT2);
                            let list = if l == 0 {
                                &mut self.ext1
                            } else {
                                &mut self.ext2
                            };
                            let q = self.ext_pos[idx];
                            self.ext_pos[idx] = list.len() as u32;
                            list.push(idx as u32);
                            let at = if l == 0 { 0 } else { old.ext1_len as u32 };
                            self.ext_reuse[l].push(if q == NONE { NONE } else { at + q });
                        }
                        _ => {}
                    }
                }
            }
        }
        self.row_at.push(self.list_lengths());

        // Viscous stencils. A tangential neighbour's cells are the face's own shifted by one cell
        // along that axis (wrapped on a periodic one).
        let [cnx, cny, cnz] = cdims;
        let cstride = [1, cnx, cnx * cny];
        let shift = |cell: u32, a: usize, dir: i32| -> u32 {
            if cell == NONE {
                return NONE;
            }
            let (cell, n) = (cell as usize, [cnx, cny, cnz][a]);
            let at = (cell / cstride[a]) % n;
            let to = if dir < 0 {
                if at == 0 {
                    cell + (n - 1) * cstride[a]
                } else {
                    cell - cstride[a]
                }
            } else if at + 1 == n {
                cell - (n - 1) * cstride[a]
            } else {
                cell + cstride[a]
            };
            to as u32
        };
        let mut old_ghost = 0;
        let total = self.active.len();
        let mut next = 0;
        while next < total {
            let n = next;
            let m = self.reuse[n];
            if m != NONE {
                // Carried over, a stretch of consecutive faces at a time: the same stencils (full
                // indices), the same ghosts.
                let m = m as usize;
                let mut len = 1;
                while n + len < total && self.reuse[n + len] as usize == m + len {
                    len += 1;
                }
                self.stencil.extend_from_slice(&old.stencil[m..m + len]);
                self.diag.extend_from_slice(&old.diag[m..m + len]);
                self.self_diag.extend_from_slice(&old.self_diag[m..m + len]);
                self.nbr.extend_from_slice(&old.nbr[m..m + len]);
                while old
                    .ghosts
                    .get(old_ghost)
                    .is_some_and(|g| (g[0] as usize) < m)
                {
                    old_ghost += 1;
                }
                let shift = (n as u32).wrapping_sub(m as u32);
                while let Some(g) = old
                    .ghosts
                    .get(old_ghost)
                    .filter(|g| (g[0] as usize) < m + len)
                {
                    self.ghosts
                        .push([g[0].wrapping_add(shift), g[1], g[2], g[3]]);
                    old_ghost += 1;
                }
                next += len;
                continue;
            }
            next += 1;
            let idx = self.active[n] as usize;
            let f = layout.face_coords(c, idx);
            let [li0, ui0] = self.active_cells[n];
            let interior = (0..3).all(|a| f[a] > 0 && f[a] + 1 < d[a]);
            let nbs = neighbours(layout, c, f, idx, fstride);
            let mut st = [NONE; 6];
            let mut diag = 6.0f32;
            for (d, &cs) in cstride.iter().enumerate() {
                for (s, dir) in [-1i32, 1].into_iter().enumerate() {
                    let slot = 2 * d + s;
                    let opposite = || {
                        nbs[slot ^ 1]
                            .filter(|&o| matches!(self.class[o], ACTIVE | FIXED))
                            .map_or(NONE, |o| o as u32)
                    };
                    let Some(gi) = nbs[slot] else {
                        // Beyond a non-periodic tangential boundary: wall at rest.
                        diag += 1.0;
                        self.ghosts.push([n as u32, NONE, NONE, opposite()]);
                        continue;
                    };
                    if d == c {
                        match self.class[gi] {
                            ACTIVE => st[slot] = gi as u32,
                            FIXED => st[slot] = CONST_BIT | gi as u32,
                            _ => diag -= 1.0, // outflow-outflow: zero gradient
                        }
                        continue;
                    }
                    let (li, ui) = if interior {
                        let o = cs;
                        let step = |x: u32| match x {
                            NONE => NONE,
                            x if dir < 0 => x - o as u32,
                            x => x + o as u32,
                        };
                        (step(li0), step(ui0))
                    } else {
                        (shift(li0, d, dir), shift(ui0, d, dir))
                    };
                    let (ll, ul) = (label_or_solid(labels, li), label_or_solid(labels, ui));
                    if ll.is_wall() && ul.is_wall() {
                        diag += 1.0;
                        // Only `Velocity` cells are kept (see `ghosts`).
                        let moving = |i: u32| {
                            if i != NONE && labels[i as usize] == CellLabel::Velocity {
                                i
                            } else {
                                NONE
                            }
                        };
                        self.ghosts
                            .push([n as u32, moving(li), moving(ui), opposite()]);
                    } else if ll == CellLabel::Fluid || ul == CellLabel::Fluid {
                        st[slot] = match self.class[gi] {
                            ACTIVE => gi as u32,
                            _ => CONST_BIT | gi as u32,
                        };
                    } else {
                        diag -= 1.0;
                    }
                }
            }
            let mut nbr = [idx as u32; 6];
            let mut selfs = 0.0f32;
            for (slot, &e) in nbr.iter_mut().zip(&st) {
                if e == NONE {
                    selfs += 1.0;
                } else {
                    *slot = e & !CONST_BIT;
                }
            }
            self.stencil.push(st);
            self.diag.push(diag);
            self.self_diag.push(diag + selfs);
            self.nbr.push(nbr);
        }

        // Runs of active faces, and of regular ones (see `regular`), row by row (a run never
        // crosses a row): a clean row's are the last build's, shifted to its new compact indices.
        let offs = fstride;
        let mut row = 0;
        loop {
            let now = [
                self.runs.len() as u32,
                self.regular.len() as u32,
                self.irregular.len() as u32,
            ];
            if row == rows {
                self.row_at[row][4..].copy_from_slice(&now);
                break;
            }
            if !self.row_dirty[row] {
                // A stretch of clean rows, as above.
                let end = self.clean_stretch_end(row);
                let (from, to) = (old.row_at[row], old.row_at[end]);
                for (at, was) in self.row_at[row..end].iter_mut().zip(&old.row_at[row..end]) {
                    for l in 0..3 {
                        at[4 + l] = now[l] + (was[4 + l] - from[4 + l]);
                    }
                }
                let shift = self.row_at[row][0].wrapping_sub(from[0]);
                row = end;
                let moved = |r: &[u32; 3]| [r[0], r[1].wrapping_add(shift), r[2]];
                let span = |l: usize| from[l] as usize..to[l] as usize;
                self.runs.extend(old.runs[span(4)].iter().map(moved));
                self.regular.extend(old.regular[span(5)].iter().map(moved));
                self.irregular
                    .extend(old.irregular[span(6)].iter().map(|f| Irregular {
                        n: f.n.wrapping_add(shift),
                        ..*f
                    }));
                continue;
            }
            self.row_at[row][4..].copy_from_slice(&now);
            let (a0, a1) = (
                self.row_at[row][0] as usize,
                self.row_at[row + 1][0] as usize,
            );
            row += 1;
            for n in a0..a1 {
                let idx = self.active[n];
                let push = |runs: &mut Vec<[u32; 3]>| extend_runs(runs, idx, n as u32, d[0]);
                push(&mut self.runs);
                let i = idx as usize;
                let plain = self.self_diag[n] == 6.0
                    && (0..6).all(|slot| {
                        let o = offs[slot / 2];
                        let want = if slot % 2 == 0 {
                            i.checked_sub(o)
                        } else {
                            Some(i + o)
                        };
                        want == Some(self.nbr[n][slot] as usize)
                    });
                if plain {
                    push(&mut self.regular);
                } else {
                    self.irregular.push(Irregular {
                        n: n as u32,
                        idx,
                        nbr: self.nbr[n],
                        self_diag: self.self_diag[n],
                    });
                }
            }
        }

        // Keep only `Velocity` cells in the wall-velocity pairs (again for carried faces: their
        // cells did not change), moving fixed faces first, so the per-step wall updates skip
        // label lookups and still walls.
        let moving = |i: u32| i != NONE && grid.label_at(i as usize) == CellLabel::Velocity;
        for f in &mut self.fixed_in_order {
            for cell in &mut f[1..] {
                if !moving(*cell) {
                    *cell = NONE;
                }
            }
        }
        // A stable partition (one pass each way), not a sort: only the two groups matter.
        let still = |f: &[u32; 3]| f[1] == NONE && f[2] == NONE;
        self.fixed.clear();
        self.fixed
            .extend(self.fixed_in_order.iter().filter(|f| !still(f)));
        self.fixed
            .extend(self.fixed_in_order.iter().filter(|f| still(f)));
        self.fixed_moving = self
            .fixed
            .iter()
            .take_while(|f| f[1] != NONE || f[2] != NONE)
            .count();

        // Sources of the layers' faces: the tracked neighbours (active or fixed) of a first-layer
        // face, the first-layer neighbours of a second-layer face, in slot order; carried over
        // where the face was in the same layer before and its row is clean.
        if !self.ext1.is_empty() || !self.ext2.is_empty() {
            self.ext_start.push(0);
        }
        for (l, from) in [ACTIVE, EXT1].into_iter().enumerate() {
            let faces = if l == 0 { &self.ext1 } else { &self.ext2 };
            let reuse = &self.ext_reuse[l];
            let mut next = 0;
            while next < faces.len() {
                let (idx, q) = (faces[next], reuse[next]);
                if q != NONE {
                    // A stretch of consecutive carried faces: their sources in one slice.
                    let q = q as usize;
                    let mut len = 1;
                    while next + len < faces.len() && reuse[next + len] as usize == q + len {
                        len += 1;
                    }
                    let (s0, s1) = (old.ext_start[q], old.ext_start[q + len]);
                    let shift = (self.ext_src.len() as u32).wrapping_sub(s0);
                    self.ext_src
                        .extend_from_slice(&old.ext_src[s0 as usize..s1 as usize]);
                    self.ext_start.extend(
                        old.ext_start[q + 1..=q + len]
                            .iter()
                            .map(|&e| e.wrapping_add(shift)),
                    );
                    next += len;
                    continue;
                }
                next += 1;
                {
                    let f = layout.face_coords(c, idx as usize);
                    for gi in neighbours(layout, c, f, idx as usize, fstride)
                        .into_iter()
                        .flatten()
                    {
                        let cl = self.class[gi];
                        if cl == from || (from == ACTIVE && cl == FIXED) {
                            self.ext_src.push(gi as u32);
                        }
                    }
                }
                self.ext_start.push(self.ext_src.len() as u32);
            }
        }
        self.carried = old;
        for g in self.ext_groups.iter_mut().flatten() {
            g.0.clear();
            g.1.clear();
        }
        for (n, &idx) in self.ext1.iter().chain(&self.ext2).enumerate() {
            let layer = usize::from(n >= self.ext1.len());
            let (s0, s1) = (self.ext_start[n] as usize, self.ext_start[n + 1] as usize);
            // At most six sources (one per neighbour slot).
            let g = &mut self.ext_groups[layer][s1 - s0];
            g.0.push(idx);
            g.1.extend_from_slice(&self.ext_src[s0..s1]);
        }
        for &idx in &self.previous {
            if self.class[idx as usize] == OTHER {
                self.dropped.push(idx);
            }
        }
        for &f in &self.dirty {
            self.marked[face_index(f)] = 0;
        }
    }

    /// The end of the stretch of clean face rows that starts at `row` (clean): the next dirty row,
    /// or the number of rows. Both passes of an update carry such a stretch over as one slice per
    /// list, so they must find the same stretches.
    fn clean_stretch_end(&self, row: usize) -> usize {
        let rows = self.row_dirty.len();
        (row + 1..rows).find(|&r| self.row_dirty[r]).unwrap_or(rows)
    }

    /// The lengths of the lists [`FaceSet::row_at`] indexes that are built with the classes
    /// (active, ext1, ext2, fixed); the runs' three are filled in later.
    fn list_lengths(&self) -> [u32; ROW_LISTS] {
        let n = |len: usize| len as u32;
        [
            n(self.active.len()),
            n(self.ext1.len()),
            n(self.ext2.len()),
            n(self.fixed_in_order.len()),
            0,
            0,
            0,
        ]
    }

    /// Lists the faces an update computes again: those within [`DIRTY_REACH`] of a face beside a
    /// changed cell (the faces with the cell's coordinates and the next along `c`, whose lower
    /// cell it is); every face for a build from scratch.
    fn mark_dirty(
        &mut self,
        layout: &Layout,
        c: usize,
        cdims: [usize; 3],
        changed: Option<&[u32]>,
    ) {
        let d = self.fdims;
        self.dirty.clear();
        self.full = changed.is_none();
        self.row_dirty.clear();
        self.row_dirty.resize(d[1] * d[2], self.full);
        let Some(changed) = changed else {
            for fk in 0..d[2] {
                for fj in 0..d[1] {
                    self.dirty
                        .extend((0..d[0]).map(|i| [i as u32, fj as u32, fk as u32]));
                }
            }
            return;
        };
        let [nx, ny, _] = cdims;
        let p = layout.periodic;
        for &cell in changed {
            let cell = cell as usize;
            let at = [cell % nx, (cell / nx) % ny, cell / (nx * ny)];
            for (fk, near_k) in dirty_span(at[2], usize::from(c == 2), d[2], p[2]) {
                for (fj, near_j) in dirty_span(at[1], usize::from(c == 1), d[1], p[1]) {
                    self.row_dirty[fj + d[1] * fk] = true;
                    let base = d[0] * (fj + d[1] * fk);
                    for (i, near_i) in dirty_span(at[0], usize::from(c == 0), d[0], p[0]) {
                        let level = if near_i && near_j && near_k {
                            NEAR
                        } else {
                            FAR
                        };
                        let m = &mut self.marked[base + i];
                        if *m == 0 {
                            self.dirty.push([i as u32, fj as u32, fk as u32]);
                        }
                        if *m == 0 || level < *m {
                            *m = level;
                        }
                    }
                }
            }
        }
    }
}
