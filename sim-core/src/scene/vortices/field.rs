//! The vortices on one MAC grid ([`VortexField`]): moved with the resolved flow, respawned in the
//! fluid, oriented by its curl, and their field as discretely divergence-free face velocities
//! (the curl of the node potential of [`super::potential`]).

use super::potential::{self, curl_run, Slab, Support, Table, Vortex};
use super::spec::VortexSpec;
use crate::fluid::{CellLabel, FluidSolver};
use crate::mesh::dot;
use crate::scene::random::SeededRng;

/// What the last [`VortexField::step`] did.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct VortexStats {
    /// Vortices alive.
    pub count: usize,
    /// Vortices respawned because they left the fluid.
    pub respawned: usize,
    /// Vortices added to follow the flow rate.
    pub spawned: usize,
    /// Vortices removed to follow the flow rate.
    pub removed: usize,
    /// Grid nodes whose potential was evaluated.
    pub nodes_evaluated: usize,
}

/// The vortices on one MAC grid, and their field as face velocities.
#[derive(Debug, Clone)]
pub struct VortexField {
    spec: VortexSpec,
    rng: SeededRng,
    vortices: Vec<Vortex>,
    dims: [usize; 3],
    h: f64,
    origin: [f64; 3],
    core_radius_m: f64,
    revision: u64,
    /// Per node: 1 when all eight cells around it are fluid.
    node_mask: Vec<u8>,
    fluid_cells: Vec<u32>,
    /// `(i, j, k)` of each of `fluid_cells`.
    fluid_coords: Vec<[u32; 3]>,
    /// Per cell row `j + ny k`, the x range of its open cells, when the solver's topology is not
    /// current (labels changed since its last step) and they are scanned here.
    row_ranges: Vec<[u32; 2]>,
    /// Per component: every face of a fluid cell once, as `(face, its lowest node)`.
    fluid_faces: [Vec<[u32; 2]>; 3],
    /// The same faces as runs along x: `(first face, its lowest node, length)` (a run's faces and
    /// their nodes are consecutive, so the curl over a run is a loop over slices).
    face_runs: [Vec<[u32; 3]>; 3],
    /// Scratch of the face lists' build: the lower and the upper faces (each in index order).
    face_lower: Vec<[u32; 2]>,
    face_upper: Vec<[u32; 2]>,
    /// Node-centred vector potential, per component, m^2/s.
    pot: [Vec<f32>; 3],
    /// The field's face velocities, m/s (the solver's layout).
    faces: [Vec<f32>; 3],
    /// The field last added to the solver (injected mode).
    injected: [Vec<f32>; 3],
    /// The nodes of `node_mask` (the only ones whose potential can be non-zero).
    fluid_nodes: Vec<u32>,
    /// Per row of nodes (`j + (ny + 1) k`): the first and last `i` of its nodes in `node_mask`
    /// (first > last: none).
    row_nodes: Vec<(u32, u32)>,
    /// The node layer splitting the nodes of `node_mask` in halves (the two tasks of
    /// `rebuild`).
    split_k: usize,
    /// The radial factor of the potential, tabulated.
    table: Box<Table>,
    /// Each vortex's support on the grid (the step's scratch, kept for its capacity).
    supports: Vec<Support>,
    stats: VortexStats,
}

impl VortexField {
    /// Vortices for the grid of `solver` (not periodic).
    pub fn new(spec: VortexSpec, solver: &FluidSolver) -> Result<Self, String> {
        spec.validate()?;
        let g = solver.grid();
        if g.periodic().iter().any(|&p| p) {
            return Err("vortices: periodic fluid grids are not supported".into());
        }
        let dims = g.dims();
        let h = g.spacing_m();
        let nodes = (dims[0] + 1) * (dims[1] + 1) * (dims[2] + 1);
        let faces: [Vec<f32>; 3] =
            std::array::from_fn(|c| vec![0.0; solver.face_velocities(c).len()]);
        Ok(Self {
            rng: SeededRng::new(spec.seed),
            vortices: Vec::with_capacity(spec.max_count),
            supports: Vec::with_capacity(spec.max_count),
            fluid_nodes: Vec::new(),
            split_k: 0,
            row_nodes: vec![(1, 0); (dims[1] + 1) * (dims[2] + 1)],
            core_radius_m: spec.core_radius_m(h),
            spec,
            dims,
            h,
            origin: g.origin_m(),
            revision: 0,
            node_mask: vec![0; nodes],
            fluid_cells: Vec::new(),
            fluid_coords: Vec::new(),
            row_ranges: Vec::new(),
            fluid_faces: std::array::from_fn(|_| Vec::new()),
            face_runs: std::array::from_fn(|_| Vec::new()),
            face_lower: Vec::new(),
            face_upper: Vec::new(),
            pot: std::array::from_fn(|_| vec![0.0; nodes]),
            injected: faces.clone(),
            faces,
            table: potential::table(),
            stats: VortexStats::default(),
        })
    }

    /// The description.
    pub fn spec(&self) -> &VortexSpec {
        &self.spec
    }
    /// The vortices.
    pub fn vortices(&self) -> &[Vortex] {
        &self.vortices
    }
    /// Replaces the vortices (tests, replays); the count is capped at `max_count`.
    pub fn set_vortices(&mut self, vortices: &[Vortex]) {
        self.vortices.clear();
        let n = vortices.len().min(self.spec.max_count);
        self.vortices.extend_from_slice(&vortices[..n]);
    }
    /// The core radius on this grid, m.
    pub fn core_radius_m(&self) -> f64 {
        self.core_radius_m
    }
    /// The field's face velocities of component `c` (the solver's layout), from the last
    /// [`VortexField::rebuild`].
    pub fn face_velocities(&self, c: usize) -> &[f32] {
        &self.faces[c]
    }
    /// What the last step did.
    pub fn stats(&self) -> VortexStats {
        self.stats
    }

    /// The closed-form sum of the vortices' velocities at `p`, m/s.
    pub fn velocity_at(&self, p: [f64; 3]) -> [f64; 3] {
        let mut v = [0.0; 3];
        for w in &self.vortices {
            for (x, u) in v.iter_mut().zip(w.velocity_m_s(p)) {
                *x += u;
            }
        }
        v
    }

    fn sync_labels(&mut self, solver: &FluidSolver) {
        let g = solver.grid();
        if g.revision() == self.revision {
            return;
        }
        self.revision = g.revision();
        // The potential's support moved with the labels: start the field afresh (what was
        // injected stays in the solver's state and decays there). Everything non-zero sits on
        // the old lists, so only they are cleared: the work follows the fluid cells, not the
        // grid (the cavity relabels often).
        for &n in &self.fluid_nodes {
            self.node_mask[n as usize] = 0;
            for p in &mut self.pot {
                p[n as usize] = 0.0;
            }
        }
        for c in 0..3 {
            for &[f, _] in &self.fluid_faces[c] {
                self.faces[c][f as usize] = 0.0;
                self.injected[c][f as usize] = 0.0;
            }
        }
        let [nx, ny, nz] = self.dims;
        let labels = g.labels();
        let fluid = |n: usize| labels[n] == CellLabel::Fluid;
        // The fluid cells in index order, row by row within each row's open range (the solver's
        // when its topology is current, else a scan of the labels).
        let rows: &[[u32; 2]] = match solver.open_rows() {
            Some(open) => open,
            None => {
                crate::fluid::open_row_ranges(g, &mut self.row_ranges);
                &self.row_ranges
            }
        };
        self.fluid_cells.clear();
        self.fluid_coords.clear();
        for (row, &[a, b]) in rows.iter().enumerate() {
            if a >= b {
                continue;
            }
            let (j, k) = ((row % ny) as u32, (row / ny) as u32);
            let base = nx * row;
            for i in a..b {
                if labels[base + i as usize] == CellLabel::Fluid {
                    self.fluid_cells.push((base + i as usize) as u32);
                    self.fluid_coords.push([i, j, k]);
                }
            }
        }
        // A node is in `node_mask` when its eight cells are fluid. Each such node is the upper
        // corner of exactly one of them (its lowest), so walking the fluid cells in index order
        // lists the nodes in index order too (no sort).
        let (sx, sy) = (nx + 1, (nx + 1) * (ny + 1));
        let (cy, cz) = (nx, nx * ny);
        self.fluid_nodes.clear();
        self.row_nodes.fill((1, 0));
        for (&n, &[i, j, k]) in self.fluid_cells.iter().zip(&self.fluid_coords) {
            let (n, i, j, k) = (n as usize, i as usize, j as usize, k as usize);
            if i + 1 >= nx || j + 1 >= ny || k + 1 >= nz {
                continue;
            }
            let upper = [1, cy, cy + 1, cz, cz + 1, cz + cy, cz + cy + 1];
            if upper.iter().all(|&d| fluid(n + d)) {
                let node = (i + 1) + sx * (j + 1) + sy * (k + 1);
                self.node_mask[node] = 1;
                self.fluid_nodes.push(node as u32);
                let (i, row) = ((i + 1) as u32, node / sx);
                let r = &mut self.row_nodes[row];
                *r = if r.0 > r.1 {
                    (i, i)
                } else {
                    (r.0.min(i), r.1.max(i))
                };
            }
        }
        let layer = sy;
        self.split_k = self
            .fluid_nodes
            .get(self.fluid_nodes.len() / 2)
            .map_or(0, |&n| n as usize / layer);
        // The faces of the fluid cells, each once (the upper face only where the next cell is
        // not fluid), in index order; only those with a corner node in `node_mask` (the others'
        // circulation is zero). The lower faces and the upper faces each come in index order
        // from the cells in index order: one merge, no sort.
        let node_stride = [1, sx, sy];
        let cell_stride = [1, nx, nx * ny];
        for c in 0..3 {
            let mut fd = [nx, ny, nz];
            fd[c] += 1;
            let (sa, sb) = (node_stride[(c + 1) % 3], node_stride[(c + 2) % 3]);
            let (lower, upper) = (&mut self.face_lower, &mut self.face_upper);
            lower.clear();
            upper.clear();
            for (&n, cell) in self.fluid_cells.iter().zip(&self.fluid_coords) {
                let (n, cell) = (n as usize, cell.map(|x| x as usize));
                let next_fluid = cell[c] + 1 < [nx, ny, nz][c] && fluid(n + cell_stride[c]);
                for up in 0..2 {
                    if up == 1 && next_fluid {
                        continue;
                    }
                    let mut f = cell;
                    f[c] += up;
                    let idx = f[0] + fd[0] * (f[1] + fd[1] * f[2]);
                    let node = f[0] + sx * f[1] + sy * f[2];
                    let corners = [node, node + sa, node + sb, node + sa + sb];
                    if corners.iter().any(|&m| self.node_mask[m] != 0) {
                        [&mut *lower, &mut *upper][up].push([idx as u32, node as u32]);
                    }
                }
            }
            let list = &mut self.fluid_faces[c];
            list.clear();
            let (mut a, mut b) = (lower.iter().peekable(), upper.iter().peekable());
            while let (Some(&&x), Some(&&y)) = (a.peek(), b.peek()) {
                if x[0] < y[0] {
                    list.push(x);
                    a.next();
                } else {
                    list.push(y);
                    b.next();
                }
            }
            list.extend(a);
            list.extend(b);
            let runs = &mut self.face_runs[c];
            runs.clear();
            for &[f, base] in list.iter() {
                match runs.last_mut() {
                    Some([f0, b0, len]) if *f0 + *len == f && *b0 + *len == base => *len += 1,
                    _ => runs.push([f, base, 1]),
                }
            }
        }
        // Vortices now outside the fluid respawn on the next step.
    }

    fn cell_of(&self, p: [f64; 3]) -> Option<usize> {
        let mut c = [0usize; 3];
        for a in 0..3 {
            let x = (p[a] - self.origin[a]) / self.h;
            if !(x >= 0.0 && x < self.dims[a] as f64) {
                return None;
            }
            c[a] = x as usize;
        }
        Some(c[0] + self.dims[0] * (c[1] + self.dims[1] * c[2]))
    }

    fn in_fluid(&self, solver: &FluidSolver, p: [f64; 3]) -> bool {
        self.cell_of(p)
            .is_some_and(|n| solver.grid().label_at(n) == CellLabel::Fluid)
    }

    /// Axis and circulation from the resolved flow at the vortex's centre; a vortex where the
    /// flow has no curl keeps its axis.
    fn orient(&self, solver: &FluidSolver, v: &mut Vortex) {
        let (u, w) = solver.velocity_and_curl(v.centre_m);
        let m = dot(w, w).sqrt();
        if m.is_finite() && m > 1e-9 {
            v.axis = w.map(|x| x / m);
        }
        let speed = dot(u, u).sqrt();
        let peak = (self.spec.intensity * speed).min(self.spec.max_peak_speed_m_s);
        let peak = if peak.is_finite() { peak } else { 0.0 };
        v.circulation_m2_s = 2.0 * std::f64::consts::PI * v.core_radius_m * peak;
    }

    fn spawn(&mut self, solver: &FluidSolver) -> Option<Vortex> {
        if self.fluid_cells.is_empty() {
            return None;
        }
        let n = self.fluid_cells[self.rng.below(self.fluid_cells.len())] as usize;
        let [nx, ny, _] = self.dims;
        let c = [n % nx, (n / nx) % ny, n / (nx * ny)];
        let centre: [f64; 3] =
            std::array::from_fn(|a| self.origin[a] + (c[a] as f64 + self.rng.unit()) * self.h);
        let mut v = Vortex {
            centre_m: centre,
            axis: self.rng.direction(),
            circulation_m2_s: 0.0,
            core_radius_m: self.core_radius_m,
        };
        self.orient(solver, &mut v);
        Some(v)
    }

    /// Moves the vortices by an Euler step with the resolved velocity at their centres,
    /// respawns those that left the fluid, re-orients them from the curl, brings their number
    /// to `target_count` (capped at `max_count`) and rebuilds the field's face velocities.
    pub fn step(&mut self, solver: &FluidSolver, target_count: usize, dt_s: f64) -> VortexStats {
        self.sync_labels(solver);
        let mut stats = VortexStats::default();
        let mut i = 0;
        while i < self.vortices.len() {
            let mut v = self.vortices[i];
            let u = solver.sample_velocity_m_s(v.centre_m);
            for (c, u) in v.centre_m.iter_mut().zip(u) {
                *c += dt_s * u;
            }
            if self.in_fluid(solver, v.centre_m) {
                self.orient(solver, &mut v);
                self.vortices[i] = v;
                i += 1;
            } else if let Some(w) = self.spawn(solver) {
                stats.respawned += 1;
                self.vortices[i] = w;
                i += 1;
            } else {
                self.vortices.swap_remove(i);
                stats.removed += 1;
            }
        }
        let target = target_count.min(self.spec.max_count);
        while self.vortices.len() > target {
            self.vortices.pop();
            stats.removed += 1;
        }
        while self.vortices.len() < target {
            match self.spawn(solver) {
                Some(v) => {
                    self.vortices.push(v);
                    stats.spawned += 1;
                }
                None => break,
            }
        }
        stats.nodes_evaluated = self.rebuild(solver);
        stats.count = self.vortices.len();
        self.stats = stats;
        stats
    }

    /// Recomputes the node potential of the current vortices and the face velocities (the
    /// discrete curl) on every face of the fluid cells of `solver`'s grid; returns the nodes
    /// evaluated.
    pub fn rebuild(&mut self, solver: &FluidSolver) -> usize {
        self.sync_labels(solver);
        for &n in &self.fluid_nodes {
            for p in &mut self.pot {
                p[n as usize] = 0.0;
            }
        }
        // Two tasks: the node layers below `split_k` and the rest (disjoint nodes, so no
        // locks), then the curl's faces in two halves.
        let layer = (self.dims[0] + 1) * (self.dims[1] + 1);
        let at = self.split_k * layer;
        let [p0, p1, p2] = &mut self.pot;
        let (p0a, p0b) = p0.split_at_mut(at);
        let (p1a, p1b) = p1.split_at_mut(at);
        let (p2a, p2b) = p2.split_at_mut(at);
        let inv_h = 1.0 / self.h;
        self.supports.clear();
        self.supports.extend(
            (self.vortices.iter()).filter_map(|v| Support::of(v, self.origin, inv_h, self.dims)),
        );
        let slab = Slab {
            supports: &self.supports,
            node_mask: &self.node_mask,
            row_nodes: &self.row_nodes,
            table: &self.table,
            dims: self.dims,
        };
        let (lower, upper) = crate::fork_join::join(
            || slab.potential(0..self.split_k, 0, [p0a, p1a, p2a]),
            || slab.potential(self.split_k..self.dims[2] + 1, at, [p0b, p1b, p2b]),
        );
        self.curl_faces();
        lower + upper
    }

    /// Face velocities of the fluid cells' faces from the node potential (each component's
    /// runs in two halves, on two tasks).
    fn curl_faces(&mut self) {
        let [nx, ny, _] = self.dims;
        let stride = [1, nx + 1, (nx + 1) * (ny + 1)];
        let inv = (0.5 / self.h) as f32;
        let pot = &self.pot;
        type Part<'a> = (&'a [[u32; 3]], &'a mut [f32], usize);
        let [f0, f1, f2] = &mut self.faces;
        let parts: [[Part; 2]; 3] = [(0, f0), (1, f1), (2, f2)].map(|(c, out)| {
            let runs = &self.face_runs[c][..];
            let (ra, rb) = runs.split_at(runs.len() / 2);
            let at = rb.first().map_or(out.len(), |r| r[0] as usize);
            let (oa, ob) = out.split_at_mut(at);
            [(ra, oa, 0), (rb, ob, at)]
        });
        let [[a0, b0], [a1, b1], [a2, b2]] = parts;
        let run = |parts: [Part; 3]| {
            for (c, (runs, out, offset)) in parts.into_iter().enumerate() {
                let (a, b) = ((c + 1) % 3, (c + 2) % 3);
                let (sa, sb) = (stride[a], stride[b]);
                let (na, nb) = (&pot[a][..], &pot[b][..]);
                for &[f, base, len] in runs {
                    let (f, base, len) = (f as usize - offset, base as usize, len as usize);
                    curl_run(&mut out[f..f + len], [na, nb], base, [sa, sb], inv);
                }
            }
        };
        crate::fork_join::join(|| run([a0, a1, a2]), || run([b0, b1, b2]));
    }

    /// Adds the change of the field since the last injection to the solver's face velocities
    /// (fluid cells' faces only; the change is discretely divergence-free and zero on faces
    /// beside walls, ports and the open os).
    pub fn inject(&mut self, solver: &mut FluidSolver) {
        if solver.grid().revision() != self.revision {
            return;
        }
        for c in 0..3 {
            let u = solver.face_velocities_mut(c);
            let (faces, injected) = (&self.faces[c], &mut self.injected[c]);
            // Over the runs of consecutive faces (vectorised); an unchanged face adds zero.
            for &[f, _, len] in &self.face_runs[c] {
                let r = f as usize..(f + len) as usize;
                let (u, new, old) = (&mut u[r.clone()], &faces[r.clone()], &mut injected[r]);
                for ((u, &new), old) in u.iter_mut().zip(new).zip(old.iter_mut()) {
                    *u += new - *old;
                    *old = new;
                }
            }
        }
    }

    /// Adds the field's cell-centred velocity to `out` (one per cell, x fastest) in fluid cells.
    pub fn overlay_into(&self, out: &mut [[f32; 3]]) {
        let [nx, ny, nz] = self.dims;
        for &n in &self.fluid_cells {
            let n = n as usize;
            if n >= out.len() {
                continue;
            }
            let cell = [n % nx, (n / nx) % ny, n / (nx * ny)];
            for c in 0..3 {
                let mut fd = [nx, ny, nz];
                fd[c] += 1;
                let lo = cell[0] + fd[0] * (cell[1] + fd[1] * cell[2]);
                let stride = [1, fd[0], fd[0] * fd[1]][c];
                out[n][c] += 0.5 * (self.faces[c][lo] + self.faces[c][lo + stride]);
            }
        }
    }
}
