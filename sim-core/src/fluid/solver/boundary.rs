//! The topology rebuild after a relabelling (face sets, pressure levels, advection plan) and the
//! boundary values of a step: the prescribed velocity of fixed faces, the wall ghosts of the
//! viscous stencil, and the extrapolation layers the traces sample.

use super::super::topology::{self, NONE};
use super::super::CellLabel;
use super::projection::build_pressure_levels;
use super::FluidSolver;

impl FluidSolver {
    pub(super) fn rebuild_topology(&mut self) {
        // The rows' open ranges bound every cell that is fluid or open on level 0: the pressure
        // levels visit only them. The face sets visit only the faces near the cells whose labels
        // changed (and the ranges only the rows that hold them are found again).
        let diffed = self
            .label_diff
            .update(self.grid.labels(), self.grid.dims()[0]);
        if diffed && self.label_diff.cells().is_empty() {
            // Only the cut fractions changed (the scene's surface moved within its cut cells, most
            // frames): the face sets, open rows, outflow faces and advection plan are functions
            // of the labels and stand as they are; the weighted operator and the closed faces
            // follow the fractions. The same state as the whole rebuild, without its face sets
            // (on the 1.2 mm scene with cut cells the rebuild's largest part).
            let (grid, rows) = (&self.grid, &self.open_rows);
            build_pressure_levels(
                grid,
                rows,
                &mut self.pressure,
                &mut self.pressure_pa,
                &mut self.p_lag,
            );
            self.refresh_cut_faces();
            self.finish_rebuild();
            return;
        }
        let rows_changed = diffed.then(|| self.label_diff.rows());
        topology::update_open_row_ranges(&self.grid, rows_changed, &mut self.open_rows);
        if let Some(rows) = self.centred_rows.as_mut() {
            rows.update(&self.open_rows, self.grid.dims(), &mut self.centred);
        }
        let changed = diffed.then(|| self.label_diff.cells());
        // The three face sets and the pressure levels are independent: the x and z faces here,
        // the y faces and the pressure levels on the fork-join helper (the result does not depend
        // on which thread builds which). On the 0.6 mm scene (BENCHMARKS.md, "Topology rebuild,
        // session 12") all three face sets here took 1,387 us a rebuild (x, y, z: 480, 399, 508)
        // while the helper's levels took 586; split so, the halves took 1,048 and 1,167 us.
        let (grid, layout, rows) = (&self.grid, &self.layout, &self.open_rows);
        let [f0, f1, f2] = &mut self.faces;
        let (pressure, pressure_pa, p_lag) =
            (&mut self.pressure, &mut self.pressure_pa, &mut self.p_lag);
        crate::fork_join::join(
            || {
                f0.update(grid, layout, 0, changed);
                f2.update(grid, layout, 2, changed);
            },
            || {
                f1.update(grid, layout, 1, changed);
                build_pressure_levels(grid, rows, pressure, pressure_pa, p_lag);
            },
        );
        // The compact vectors (viscosity and advection results, wall ghosts) are written whole
        // before they are read (`update_ghosts` clears the ghosts), so a relabelling only sizes
        // them: clearing them cost more than the rest of the serial part of the rebuild.
        for c in 0..3 {
            let n = self.faces[c].active.len();
            for v in [&mut self.compact[c], &mut self.ghost[c]] {
                v.resize(n, 0.0);
            }
            let (l0, layout) = (&self.pressure.mg.levels[0], &self.layout);
            let cells = self.faces[c].runs.iter().map(|r| {
                let f = layout.face_coords(c, r[0] as usize);
                l0.pad(f[0], f[1], f[2]) as u32
            });
            self.run_cells[c].clear();
            self.run_cells[c].extend(cells);
            // Faces no longer tracked are zeroed so stale values never leak into samples (the
            // untracked faces hold zero: see `set_velocity_field`).
            for &idx in &self.faces[c].dropped {
                self.u[c][idx as usize] = 0.0;
            }
        }
        self.refresh_cut_faces();
        self.find_outflow_faces();
        let [f0, f1, f2] = &self.faces;
        let counts = [f0.active.len(), f1.active.len(), f2.active.len()];
        self.plan
            .rebuild(&self.layout, [&f0.runs, &f1.runs, &f2.runs], counts);
        let total = self.plan.offset[3];
        let [f0, f1, f2] = &mut self.adv_foot;
        for v in [
            &mut self.adv,
            &mut self.adv_lo,
            &mut self.adv_hi,
            &mut self.adv_orig,
            &mut self.adv_refl,
            f0,
            f1,
            f2,
        ] {
            v.resize(total, 0.0);
        }
        self.finish_rebuild();
    }

    /// The active faces the cut fractions close (held at zero velocity) and the viscous
    /// operators of the walls at their distance, from the grid's fractions on the current face
    /// sets.
    fn refresh_cut_faces(&mut self) {
        for c in 0..3 {
            self.cut_closed[c].clear();
            if let Some(cut) = self.grid.cut_fractions() {
                let closed = self.faces[c]
                    .active
                    .iter()
                    .filter(|&&idx| cut.face[c][idx as usize] == 0.0);
                self.cut_closed[c].extend(closed);
                for &idx in &self.cut_closed[c] {
                    self.u[c][idx as usize] = 0.0;
                }
            }
        }
        let walls = self.grid.cut_fractions().and_then(|c| c.walls.as_ref());
        self.cut_walls = walls.is_some();
        for c in 0..3 {
            match walls {
                Some(w) => {
                    self.cut_visc[c].build(&self.faces[c], &self.layout, &self.grid, c, &w.faces[c])
                }
                None => self.cut_visc[c] = Default::default(),
            }
        }
    }

    /// The end of every rebuild: current with the grid, boundary values re-applied.
    fn finish_rebuild(&mut self) {
        self.revision = self.grid.revision();
        self.apply_fixed(true);
        self.extrapolate();
    }

    /// The active faces between a fluid and an outflow cell (`outflow_faces`, in face order),
    /// from the outflow cells within the rows' open ranges (a few, at the ports) rather than from
    /// every active face.
    pub(super) fn find_outflow_faces(&mut self) {
        self.outflow_faces.clear();
        let dims = self.grid.dims();
        let [nx, ny, _] = dims;
        let labels = self.grid.labels();
        for (r, &[a, b]) in self.open_rows.iter().enumerate() {
            let row = &labels[r * nx..(r + 1) * nx];
            for i in a as usize..b as usize {
                if row[i] != CellLabel::Outflow {
                    continue;
                }
                let cell = [i, r % ny, r / ny];
                for c in 0..3 {
                    // The cell is the upper cell of its lower face and the lower cell of its
                    // upper face (wrapped on a periodic axis).
                    let mut up = cell;
                    up[c] += 1;
                    if up[c] == dims[c] && self.layout.periodic[c] {
                        up[c] = 0;
                    }
                    // On a one-cell periodic axis they are one face, counted as the lower.
                    let faces = [(cell, 1.0), (up, -1.0)];
                    for &(f, sign) in &faces[..if up == cell { 1 } else { 2 }] {
                        let idx = self.layout.face_index(c, f);
                        if self.faces[c].class[idx] == topology::ACTIVE {
                            let at = cell.map(|v| v as u32);
                            self.outflow_faces.push((c as u8, idx as u32, sign, at));
                        }
                    }
                }
            }
        }
        self.outflow_faces
            .sort_unstable_by_key(|&(c, idx, ..)| (c, idx));
    }

    /// Writes the prescribed normal velocity of the fixed faces: all of them (`all`, after the faces
    /// were rebuilt or overwritten), or only those beside `Velocity` cells (the others stay zero).
    pub(super) fn apply_fixed(&mut self, all: bool) {
        for c in 0..3 {
            let set = &self.faces[c];
            let list = if all {
                &set.fixed[..]
            } else {
                &set.fixed[..set.fixed_moving]
            };
            for &[idx, a, b] in list {
                self.u[c][idx as usize] = topology::wall_velocity(&self.grid, c, a, b);
            }
        }
    }

    /// Wall-ghost terms of the viscous stencil of component `c`. The ghost value behind a wall is the
    /// quadratic extrapolation through the wall velocity w and the two faces inside,
    /// `8/3 w - 2 u1 + 1/3 u2`: the `2 w - u1` part is implicit (in the stencil diagonal), the rest is
    /// lagged from the current field, so the matrix stays symmetric and steady states see the exact
    /// quadratic wall profile (a linear ghost alone over-predicts duct flow by ~1.5 % at 16 cells).
    pub(super) fn update_ghosts(&mut self, c: usize) {
        let set = &self.faces[c];
        let g = &mut self.ghost[c];
        let u = &self.u[c];
        g.fill(0.0);
        for &[n, a, b, opp] in &set.ghosts {
            let w = topology::wall_velocity(&self.grid, c, a, b);
            let mut v = 2.0 * w;
            if opp != NONE {
                let u1 = u[set.active[n as usize] as usize];
                v += 2.0 / 3.0 * w - u1 + u[opp as usize] / 3.0;
            }
            g[n as usize] += v;
        }
    }

    /// Fills the extrapolation layers from their inner neighbours (mean of the layer inside).
    pub(super) fn extrapolate(&mut self) {
        /// The faces with `K` sources each (a fixed-length sum, unrolled).
        fn group<const K: usize>(u: &mut [f32], faces: &[u32], srcs: &[u32]) {
            for (&idx, src) in faces.iter().zip(srcs.chunks_exact(K)) {
                let mut s = 0.0;
                for &g in src {
                    s += u[g as usize];
                }
                u[idx as usize] = s / K as f32;
            }
        }
        for c in 0..3 {
            let set = &self.faces[c];
            let u = &mut self.u[c];
            // Layer 1 first: layer 2 reads it.
            for layer in &set.ext_groups {
                for (k, (faces, srcs)) in layer.iter().enumerate() {
                    match k {
                        1 => group::<1>(u, faces, srcs),
                        2 => group::<2>(u, faces, srcs),
                        3 => group::<3>(u, faces, srcs),
                        4 => group::<4>(u, faces, srcs),
                        5 => group::<5>(u, faces, srcs),
                        6 => group::<6>(u, faces, srcs),
                        _ => faces.iter().for_each(|&idx| u[idx as usize] = 0.0),
                    }
                }
            }
        }
    }
}
