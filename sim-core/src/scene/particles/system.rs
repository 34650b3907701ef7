//! The particles on one grid ([`ParticleSystem`]): fixed-capacity storage, emission, the step
//! (the cell-centred field, the eddy dispersion's walk, the advection in parallel chunks, the
//! removal of those that left) and the clarity of a view.

use super::kernel::{ClassSums, Cone, Kernel, Sampler, Task, BLOCK, KEEP, OPEN, OUTFLOW};
use super::spec::ParticleKind;
use super::sweep::sweep;
use crate::fluid::{CellLabel, FluidGrid, FluidSolver};
use crate::scene::clarity::View;
use crate::scene::dispersion;
use crate::scene::VoxelKind;
use crate::simd::{v4, v4 as lane, V4};

/// The eddy dispersion's default seed; a scene's walk uses `particles.seed ^ WALK_STREAM` (a
/// stream apart from the emission's).
pub(super) const WALK_STREAM: u64 = 0x5eed_d15c;
/// Steps between two reorderings of the particles by cell (from [`PARALLEL_MIN`] particles; a
/// particle moves about a third of a cell per step, so the order decays slowly).
const SORT_PERIOD: u32 = 16;
/// From this many particles a step runs in parallel tasks ...
const PARALLEL_MIN: usize = 4096;
/// ... the eddy dispersion in this many tasks (a few per core, so a slow chunk does not hold the
/// step) ...
const PARALLEL_TASKS: usize = 8;
/// ... and the advection in this many chunks, dealt alternately to the two halves of a fork-join.
const CHUNKS: usize = 32;

/// Physical properties of one particle class.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ParticleClass {
    /// Kind.
    pub kind: ParticleKind,
    /// Terminal slip along gravity, m/s (negative: rises).
    pub settle_m_s: f64,
    /// Slip relaxation time, s.
    pub tau_s: f64,
    /// Obscuring weight, m^2: `kappa V` for blood, the projected area for opaque particles.
    pub shade_m2: f64,
    /// Diameter, m (for display).
    pub diameter_m: f64,
}

/// Counters of the particle stage (cumulative, except `alive`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ParticleCounts {
    /// Alive now.
    pub alive: usize,
    /// Emitted, per kind.
    pub emitted: [u64; 3],
    /// Left through the outflow holes, per kind.
    pub outflow: [u64; 3],
    /// Left through the open external os, per kind.
    pub open: [u64; 3],
    /// Removed because their cell closed with no fluid cell around, per kind.
    pub lost: [u64; 3],
    /// Not emitted because the budget was full.
    pub dropped: u64,
    /// Not emitted because the emission point was not in the fluid.
    pub rejected: u64,
}

/// The particles on one grid: fixed-capacity storage and the advection.
#[derive(Debug, Clone)]
pub struct ParticleSystem {
    dims: [usize; 3],
    h: f64,
    origin: [f64; 3],
    capacity: usize,
    /// The budget in use (at most `capacity`): the daemon lowers it under overload.
    limit: usize,
    max_substeps: usize,
    gravity: [f64; 3],
    classes: Vec<ParticleClass>,
    /// Position, grid units.
    pos: Vec<[f32; 3]>,
    /// Slip velocity, cells/s.
    slip: Vec<[f32; 3]>,
    class: Vec<u8>,
    pub(super) birth_s: Vec<f32>,
    /// Cell-centred velocity, cells/s (4 lanes, the fourth unused).
    field: Vec<V4>,
    /// The cell kinds `field`'s cell lists were built for.
    field_kinds: Vec<VoxelKind>,
    /// Fluid and open cells: `(cell, lowest x face, lowest y face)` (the z face is the cell's).
    centred_cells: Vec<[u32; 3]>,
    /// Inflow, outflow and wall cells (prescribed velocity).
    prescribed_cells: Vec<u32>,
    /// Per class and step: slip decay, slip displacement factor, terminal slip (cells/s).
    class_step: Vec<([f32; 3], f32, f32)>,
    /// Per particle, this step: KEEP or how it left.
    fate: Vec<u8>,
    /// The upper half's sums of the clarity's cone weights per class (a step in two halves).
    upper_sums: Box<ClassSums>,
    /// Particles `[0, settled)` ended the last step in fluid cells of `field_kinds`.
    settled: usize,
    counts: ParticleCounts,
    pub(super) time_s: f64,
    /// Eddy diffusivity of the sub-grid turbulent mixing, m^2/s (0: none; `scene::dispersion`).
    eddy_diffusivity_m2_s: f64,
    /// The random walk's generator (seeded per system: runs repeat).
    walk_rng: fastrand::Rng,
    /// The reordering by cell (`ParticleSystem::sort_by_cell`): its scratch, allocated once.
    sorter: CellSort,
}

/// A cell kind per cell from a solver grid's labels (fluid, solid -> wall, velocity -> wall,
/// outflow -> open), for runs without a scene.
pub fn kinds_from_labels(grid: &FluidGrid) -> Vec<VoxelKind> {
    grid.labels()
        .iter()
        .map(|l| match l {
            CellLabel::Fluid => VoxelKind::Fluid,
            CellLabel::Solid => VoxelKind::Solid,
            CellLabel::Velocity => VoxelKind::Wall,
            CellLabel::Outflow => VoxelKind::Open,
        })
        .collect()
}

impl ParticleSystem {
    /// Storage for `capacity` particles on the grid of `solver`.
    pub fn new(
        grid: &FluidGrid,
        capacity: usize,
        max_substeps: usize,
        gravity_unit: [f64; 3],
    ) -> Self {
        Self {
            dims: grid.dims(),
            h: grid.spacing_m(),
            origin: grid.origin_m(),
            capacity,
            limit: capacity,
            max_substeps: max_substeps.max(1),
            gravity: gravity_unit,
            classes: Vec::with_capacity(256),
            pos: Vec::with_capacity(capacity),
            slip: Vec::with_capacity(capacity),
            class: Vec::with_capacity(capacity),
            birth_s: Vec::with_capacity(capacity),
            field: vec![v4::zero(); grid.cell_count()],
            field_kinds: Vec::new(),
            centred_cells: Vec::new(),
            prescribed_cells: Vec::new(),
            class_step: Vec::with_capacity(256),
            fate: Vec::with_capacity(capacity),
            upper_sums: Box::new([0.0; 256]),
            settled: 0,
            counts: ParticleCounts::default(),
            time_s: 0.0,
            eddy_diffusivity_m2_s: 0.0,
            walk_rng: fastrand::Rng::with_seed(WALK_STREAM),
            sorter: CellSort::new(grid.cell_count(), capacity),
        }
    }

    /// Reseeds the eddy dispersion's random walk (a scene seeds it from `particles.seed`).
    pub fn seed_walk(&mut self, seed: u64) {
        self.walk_rng = fastrand::Rng::with_seed(seed);
    }

    /// Sets the eddy diffusivity of the random walk every later step adds to the advection,
    /// m^2/s (0, the default: none; `scene::dispersion`).
    pub fn set_eddy_diffusivity(&mut self, d_m2_s: f64) {
        self.eddy_diffusivity_m2_s = if d_m2_s.is_finite() {
            d_m2_s.max(0.0)
        } else {
            0.0
        };
    }

    /// The eddy dispersion's random walk over `dt_s` (`scene::dispersion::walk`).
    fn disperse(&mut self, kinds: &[VoxelKind], dt_s: f64) {
        let Some(plan) = dispersion::walk_plan(self.eddy_diffusivity_m2_s, dt_s, self.h) else {
            return;
        };
        let n = self.pos.len();
        let entered_outlet = if n >= PARALLEL_MIN {
            // The advection's chunks, each with its own generator seeded from the system's (the
            // same draws whatever the thread count).
            use rayon::prelude::*;
            let chunk = n.div_ceil(PARALLEL_TASKS);
            let mut seeds = [0u64; PARALLEL_TASKS];
            seeds.iter_mut().for_each(|s| *s = self.walk_rng.u64(..));
            let (dims, pos) = (self.dims, &mut self.pos);
            pos.par_chunks_mut(chunk)
                .zip(seeds.par_iter())
                .map(|(p, &seed)| {
                    let mut rng = fastrand::Rng::with_seed(seed);
                    dispersion::walk(p, kinds, dims, plan, &mut rng)
                })
                .reduce(|| false, |a, b| a || b)
        } else {
            dispersion::walk(&mut self.pos, kinds, self.dims, plan, &mut self.walk_rng)
        };
        if entered_outlet {
            // Particles moved into an outlet no longer start in fluid cells.
            self.settled = 0;
        }
    }

    /// Adds a class; returns its index, or `None` when 255 exist.
    pub fn add_class(&mut self, class: ParticleClass) -> Option<u8> {
        if self.classes.len() >= 255 {
            return None;
        }
        self.classes.push(class);
        self.class_step.push(([0.0; 3], 0.0, 0.0));
        Some((self.classes.len() - 1) as u8)
    }
    /// The classes.
    pub fn classes(&self) -> &[ParticleClass] {
        &self.classes
    }
    /// Alive particles.
    pub fn len(&self) -> usize {
        self.pos.len()
    }
    /// No particle alive.
    pub fn is_empty(&self) -> bool {
        self.pos.is_empty()
    }
    /// The storage's capacity (the budget).
    pub fn capacity(&self) -> usize {
        self.capacity
    }
    /// The budget in use: emission stops at this many particles (at most the capacity).
    pub fn limit(&self) -> usize {
        self.limit
    }
    /// Uses `share` of the budget (clamped to `[0, 1]`, at least one particle): emission stops
    /// at that count; particles already above it stay until they leave. No allocation.
    pub fn set_budget_share(&mut self, share: f64) {
        let share = if share.is_nan() {
            1.0
        } else {
            share.clamp(0.0, 1.0)
        };
        self.limit = ((self.capacity as f64 * share).round() as usize)
            .max(1)
            .min(self.capacity);
    }
    /// The counters.
    pub fn counts(&self) -> ParticleCounts {
        ParticleCounts {
            alive: self.pos.len(),
            ..self.counts
        }
    }
    /// Time of the system, s.
    pub fn time_s(&self) -> f64 {
        self.time_s
    }
    /// Position of particle `n`, m.
    pub fn position_m(&self, n: usize) -> [f64; 3] {
        let p = self.pos[n];
        std::array::from_fn(|a| self.origin[a] + p[a] as f64 * self.h)
    }
    /// Velocity of particle `n`, m/s: the fluid's (the cell-centred field of the last step, plus
    /// the vortex overlay, sampled at the particle) plus its slip. Zero before the first step
    /// that moved particles.
    pub fn velocity_m_per_s(&self, n: usize) -> [f64; 3] {
        let u = self.fluid_velocity(n);
        let slip = self.slip[n];
        std::array::from_fn(|a| f64::from(u[a] + slip[a]) * self.h)
    }
    /// The cell-centred field of the last step at particle `n`, cells/s.
    fn fluid_velocity(&self, n: usize) -> [f32; 4] {
        let p = self.pos[n];
        v4::lanes(Sampler::new(&self.field, self.dims).sample::<false>(v4::new(p[0], p[1], p[2])))
    }
    /// Time since particle `n` was emitted, s.
    pub fn age_s(&self, n: usize) -> f64 {
        (self.time_s - f64::from(self.birth_s[n])).max(0.0)
    }
    /// Class of particle `n`.
    pub fn class_of(&self, n: usize) -> ParticleClass {
        self.classes[self.class[n] as usize]
    }
    /// Sets the unit gravity direction.
    pub fn set_gravity(&mut self, gravity_unit: [f64; 3]) {
        self.gravity = gravity_unit;
    }
    /// Counts `n` particles not emitted because their emission point was not in the fluid.
    pub(super) fn count_rejected(&mut self, n: u64) {
        self.counts.rejected += n;
    }
    /// Removes every particle (counters kept).
    pub fn clear(&mut self) {
        self.pos.clear();
        self.slip.clear();
        self.class.clear();
        self.birth_s.clear();
        self.settled = 0;
    }

    /// The cell (linear index) of a position in grid units, if inside the grid.
    #[inline]
    fn cell(&self, p: [f32; 3]) -> Option<usize> {
        let [nx, ny, nz] = self.dims;
        if !(p[0] >= 0.0 && p[1] >= 0.0 && p[2] >= 0.0) {
            return None;
        }
        let (i, j, k) = (p[0] as usize, p[1] as usize, p[2] as usize);
        (i < nx && j < ny && k < nz).then(|| i + nx * (j + ny * k))
    }

    /// Emits a particle of class `class` at `p_m` with the fluid's velocity (slip zero); false
    /// when the budget is full or the point is not in a fluid cell.
    pub fn emit(&mut self, kinds: &[VoxelKind], class: u8, p_m: [f64; 3]) -> bool {
        let Some(c) = self.classes.get(class as usize).copied() else {
            return false;
        };
        let k = c.kind as usize;
        if self.pos.len() >= self.limit {
            self.counts.dropped += 1;
            return false;
        }
        let g: [f32; 3] = std::array::from_fn(|a| ((p_m[a] - self.origin[a]) / self.h) as f32);
        if self.cell(g).and_then(|n| kinds.get(n)) != Some(&VoxelKind::Fluid) {
            self.counts.rejected += 1;
            return false;
        }
        self.pos.push(g);
        self.slip.push([0.0; 3]);
        self.class.push(class);
        self.birth_s.push(self.time_s as f32);
        self.counts.emitted[k] += 1;
        true
    }

    /// Rebuilds the lists of cells whose velocity `build_field` writes when the kinds changed
    /// (the cavity moved; returns whether they did); the other cells' velocity is zero.
    fn sync_kinds(&mut self, kinds: &[VoxelKind]) -> bool {
        let cells = self.field.len();
        let kinds = &kinds[..cells.min(kinds.len())];
        if kind_bytes(&self.field_kinds) == kind_bytes(kinds) {
            return false;
        }
        self.field_kinds.clear();
        self.field_kinds.extend_from_slice(kinds);
        self.field.fill(v4::zero());
        self.centred_cells.clear();
        self.prescribed_cells.clear();
        let [nx, ny, _] = self.dims;
        for (n, kind) in kinds.iter().enumerate() {
            match kind {
                VoxelKind::Fluid | VoxelKind::Open => {
                    // x faces: (nx + 1) per row, so the row count is added; y faces: nx more per
                    // layer.
                    let (row, layer) = (n / nx, n / (nx * ny));
                    self.centred_cells
                        .push([n as u32, (n + row) as u32, (n + nx * layer) as u32]);
                }
                VoxelKind::Inflow | VoxelKind::Outflow | VoxelKind::Wall => {
                    self.prescribed_cells.push(n as u32);
                }
                _ => {}
            }
        }
        true
    }

    /// Builds the cell-centred velocity (cells/s): the mean of the faces in fluid and open
    /// cells (plus the overlay's), the prescribed velocity in port and wall cells, zero elsewhere.
    /// Returns whether the kinds changed since the last build.
    fn build_field(
        &mut self,
        solver: &FluidSolver,
        kinds: &[VoxelKind],
        overlay: Option<[&[f32]; 3]>,
    ) -> bool {
        let changed = self.sync_kinds(kinds);
        let [nx, ny, _] = self.dims;
        let inv_h = (1.0 / self.h) as f32;
        let half = 0.5 * inv_h;
        let grid = solver.grid();
        let faces: [&[f32]; 3] = std::array::from_fn(|c| solver.face_velocities(c));
        // Two halves of the cell list (in index order) on the two cores: at 10^4 particles the
        // build is a tenth of the step.
        let cells = &self.centred_cells[..];
        let (lower, upper) = cells.split_at(cells.len() / 2);
        let at = upper.first().map_or(self.field.len(), |c| c[0] as usize);
        let (fa, fb) = self.field.split_at_mut(at);
        let fill = |cells: &[[u32; 3]], field: &mut [V4], offset: usize| match overlay {
            None => centre_faces(cells, field, offset, [faces], [nx, ny], half),
            Some(o) => centre_faces(cells, field, offset, [faces, o], [nx, ny], half),
        };
        crate::fork_join::join(|| fill(lower, fa, 0), || fill(upper, fb, at));
        let field = &mut self.field;
        for &n in &self.prescribed_cells {
            let p = grid.velocity_at(n as usize);
            field[n as usize] = v4::new(p[0] * inv_h, p[1] * inv_h, p[2] * inv_h);
        }
        changed
    }

    /// Advances every particle by `dt_s` in the solver's current velocity (plus the overlay's
    /// face velocities, same layout), against `kinds` (one per cell). Returns the clarity of the
    /// view if one is given.
    pub fn step(
        &mut self,
        solver: &FluidSolver,
        kinds: &[VoxelKind],
        overlay: Option<[&[f32]; 3]>,
        dt_s: f64,
        view: Option<&View>,
    ) -> Option<f64> {
        self.time_s += dt_s;
        if !self.pos.is_empty() && dt_s > 0.0 && kinds.len() >= self.field.len() {
            let kinds_changed = self.build_field(solver, kinds, overlay);
            self.disperse(kinds, dt_s);
            let cone = view.map(|v| Cone::new(v, self.origin, self.h));
            let sums = self.advance(kinds, kinds_changed, dt_s, cone);
            return view.map(|v| self.clarity_from(v, &sums));
        }
        view.map(|v| self.clarity(v))
    }

    /// Moves every particle; returns the clarity's sums per class over the particles that stay
    /// (zero without a cone).
    fn advance(
        &mut self,
        kinds: &[VoxelKind],
        kinds_changed: bool,
        dt_s: f64,
        cone: Option<Cone>,
    ) -> ClassSums {
        let inv_h = 1.0 / self.h;
        for (c, s) in self.classes.iter().zip(&mut self.class_step) {
            let e = if c.tau_s > 0.0 {
                (-dt_s / c.tau_s).exp()
            } else {
                0.0
            };
            let disp = c.tau_s * (1.0 - e);
            let t = self.gravity.map(|g| (g * c.settle_m_s * inv_h) as f32);
            *s = (t, e as f32, disp as f32);
        }
        let k = Kernel::new(
            Sampler::new(&self.field, self.dims),
            kinds,
            &self.class_step,
            if kinds_changed { 0 } else { self.settled },
            self.max_substeps,
            dt_s,
            cone,
        );
        let n = self.pos.len();
        let classes = self.classes.len();
        // The fate of every particle this step (KEEP, or the outlet), then a compaction.
        self.fate.clear();
        self.fate.resize(n, KEEP);
        let mut sums = [0.0f32; 256];
        let left = if n >= PARALLEL_MIN {
            // On the two cores by the solver's fork-join (at 10^4 particles a step is ~0.2 ms, where
            // a thread pool's wake-ups showed), in CHUNKS chunks dealt alternately: the particles
            // are ordered by cell, so the costly ones (the jet's, with more substeps) are
            // neighbours and each core gets its share of them.
            let chunk = n.div_ceil(CHUNKS).next_multiple_of(BLOCK);
            let mut tasks: [[Option<Task>; CHUNKS / 2]; 2] =
                std::array::from_fn(|_| std::array::from_fn(|_| None));
            let parts = self
                .pos
                .chunks_mut(chunk)
                .zip(self.slip.chunks_mut(chunk))
                .zip(self.class.chunks(chunk))
                .zip(self.fate.chunks_mut(chunk));
            for (t, (((pos, slip), class), fate)) in parts.enumerate().take(CHUNKS) {
                tasks[t % 2][t / 2] = Some(Task {
                    offset: t * chunk,
                    pos,
                    slip,
                    class,
                    fate,
                });
            }
            let [lower, upper] = tasks;
            let upper_sums = &mut *self.upper_sums;
            upper_sums[..classes].fill(0.0);
            let run = |tasks: [Option<Task>; CHUNKS / 2], sums: &mut ClassSums| {
                tasks
                    .into_iter()
                    .flatten()
                    .map(|t| sweep(&k, t, sums))
                    .sum::<usize>()
            };
            let (a, b) =
                crate::fork_join::join(|| run(lower, &mut sums), || run(upper, upper_sums));
            for (x, y) in sums[..classes].iter_mut().zip(upper_sums.iter()) {
                *x += y;
            }
            a + b
        } else {
            let task = Task {
                offset: 0,
                pos: &mut self.pos,
                slip: &mut self.slip,
                class: &self.class,
                fate: &mut self.fate,
            };
            sweep(&k, task, &mut sums)
        };
        if left > 0 {
            self.remove_left();
        }
        self.settled = self.pos.len();
        if self.pos.len() >= PARALLEL_MIN {
            self.sorter.steps += 1;
            if self.sorter.steps >= SORT_PERIOD {
                self.sort_by_cell();
            }
        }
        sums
    }

    /// Reorders the particles by cell (a counting sort on the cell index), so that the kernel's
    /// consecutive particles sample neighbouring cells and the field's samples stay in the L1
    /// cache (emission at random cells and removals shuffle them). Particle indices change, as
    /// they do with removals.
    fn sort_by_cell(&mut self) {
        let n = self.pos.len();
        let cs = &mut self.sorter;
        cs.steps = 0;
        if cs.start.len() != self.field.len() + 1 || cs.pos.capacity() < n {
            return;
        }
        cs.start.fill(0);
        cs.key.clear();
        let [nx, ny, nz] = self.dims.map(|n| n as f32);
        let (dims, stride) = (
            lane::new4(nx, ny, nz, 1.0),
            [1, self.dims[0], self.dims[0] * self.dims[1]],
        );
        for p in &self.pos {
            // Every particle here ended its step in a fluid cell (inside the grid).
            let k = lane::cell(v4::new(p[0], p[1], p[2]), dims, stride).unwrap_or(0);
            cs.key.push(k as u32);
            cs.start[k + 1] += 1;
        }
        for k in 1..cs.start.len() {
            cs.start[k] += cs.start[k - 1];
        }
        cs.pos.resize(n, [0.0; 3]);
        cs.slip.resize(n, [0.0; 3]);
        cs.class.resize(n, 0);
        cs.birth_s.resize(n, 0.0);
        for (i, &k) in cs.key.iter().enumerate() {
            let to = cs.start[k as usize] as usize;
            cs.start[k as usize] += 1;
            cs.pos[to] = self.pos[i];
            cs.slip[to] = self.slip[i];
            cs.class[to] = self.class[i];
            cs.birth_s[to] = self.birth_s[i];
        }
        std::mem::swap(&mut self.pos, &mut cs.pos);
        std::mem::swap(&mut self.slip, &mut cs.slip);
        std::mem::swap(&mut self.class, &mut cs.class);
        std::mem::swap(&mut self.birth_s, &mut cs.birth_s);
    }

    /// Removes the particles whose fate is not KEEP (the last particle fills each hole, so the
    /// cost is the scan of the fates plus O(left)) and counts them.
    fn remove_left(&mut self) {
        let mut i = 0;
        while let Some(next) = next_left(&self.fate, i) {
            i = next;
            let f = self.fate[i];
            let kind = self.classes[self.class[i] as usize].kind as usize;
            match f {
                OUTFLOW => self.counts.outflow[kind] += 1,
                OPEN => self.counts.open[kind] += 1,
                _ => self.counts.lost[kind] += 1,
            }
            // The last particle moves here and is looked at next.
            self.fate.swap_remove(i);
            self.pos.swap_remove(i);
            self.slip.swap_remove(i);
            self.class.swap_remove(i);
            self.birth_s.swap_remove(i);
        }
    }

    /// The clarity of `view` (see [`View`]): `exp(-mean optical depth over the view cone)`.
    pub fn clarity(&self, view: &View) -> f64 {
        let cone = Cone::new(view, self.origin, self.h);
        let mut sums = [0.0f32; 256];
        for (p, &c) in self.pos.iter().zip(&self.class) {
            sums[c as usize] += cone.weight(*p);
        }
        self.clarity_from(view, &sums)
    }

    /// The clarity from the per-class sums of [`Cone::weight`].
    fn clarity_from(&self, view: &View, sums: &ClassSums) -> f64 {
        let mut tau = 0.0f64;
        for (c, s) in self.classes.iter().zip(sums) {
            tau += c.shade_m2 * f64::from(*s) / (self.h * self.h);
        }
        (-tau / view.solid_angle_sr()).exp()
    }
}

/// Scratch of [`ParticleSystem::sort_by_cell`], allocated with the system (the particle arrays
/// are swapped with these, so both have the budget's capacity).
#[derive(Debug, Clone)]
struct CellSort {
    /// Steps since the last reordering.
    steps: u32,
    /// Per cell (one more): the particle count, then the first slot of the cell's particles.
    start: Vec<u32>,
    /// Each particle's cell.
    key: Vec<u32>,
    pos: Vec<[f32; 3]>,
    slip: Vec<[f32; 3]>,
    class: Vec<u8>,
    birth_s: Vec<f32>,
}

impl CellSort {
    fn new(cells: usize, capacity: usize) -> Self {
        Self {
            steps: 0,
            start: vec![0; cells + 1],
            key: Vec::with_capacity(capacity),
            pos: Vec::with_capacity(capacity),
            slip: Vec::with_capacity(capacity),
            class: Vec::with_capacity(capacity),
            birth_s: Vec::with_capacity(capacity),
        }
    }
}

/// The cell-centred velocity of `cells` (`(cell, lowest x face, lowest y face)`, cells from
/// `offset` on, in `field[cell - offset]`): `half` times the sum over the face fields `sets`
/// (the solver's, plus the overlay's) of the cell's two faces per axis.
#[inline(always)]
fn centre_faces<const S: usize>(
    cells: &[[u32; 3]],
    field: &mut [V4],
    offset: usize,
    sets: [[&[f32]; 3]; S],
    [nx, ny]: [usize; 2],
    half: f32,
) {
    for &[n, a, b] in cells {
        let (n, a, b) = (n as usize, a as usize, b as usize);
        let mut s = [0.0f32; 3];
        for [u, v, w] in sets {
            s[0] += u[a] + u[a + 1];
            s[1] += v[b] + v[b + nx];
            s[2] += w[n] + w[n + nx * ny];
        }
        field[n - offset] = v4::new(s[0] * half, s[1] * half, s[2] * half);
    }
}

/// The first particle from `from` on whose fate is not KEEP (eight fates a comparison).
fn next_left(fate: &[u8], from: usize) -> Option<usize> {
    let rest = fate.get(from..)?;
    let mut words = rest.chunks_exact(8);
    let mut skipped = 0;
    for w in words.by_ref() {
        if w.iter().any(|&f| f != KEEP) {
            break;
        }
        skipped += 8;
    }
    rest[skipped..]
        .iter()
        .position(|&f| f != KEEP)
        .map(|k| from + skipped + k)
}

/// The kinds as bytes (one comparison of memory when the field checks whether they changed).
fn kind_bytes(kinds: &[VoxelKind]) -> &[u8] {
    // SAFETY: `VoxelKind` is `repr(u8)`, so a slice of them is a slice of initialised bytes of
    // the same length.
    unsafe { std::slice::from_raw_parts(kinds.as_ptr().cast::<u8>(), kinds.len()) }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fluid::FluidParams;

    /// A lowered budget stops emission at its share (and counts the refusals as dropped), never
    /// allocates past the capacity, and restoring it lets emission go on.
    #[test]
    fn a_lowered_budget_stops_emission_at_its_share_and_restoring_it_resumes() {
        let (n, h) = (8, 1e-3);
        let grid = FluidGrid::new([n, n, n], h, [0.0; 3], [false; 3]).unwrap();
        let kinds = vec![VoxelKind::Fluid; n * n * n];
        for capacity in [1, 7, 100] {
            // A fresh system per share (a clone's storage holds only its particles).
            let new_system = || {
                let mut sys = ParticleSystem::new(&grid, capacity, 8, [0.0, -1.0, 0.0]);
                let class = sys
                    .add_class(ParticleClass {
                        kind: ParticleKind::Blood,
                        settle_m_s: 0.0,
                        tau_s: 1e-3,
                        shade_m2: 0.0,
                        diameter_m: 0.0,
                    })
                    .unwrap();
                (sys, class)
            };
            let fill = |sys: &mut ParticleSystem, cls: u8| {
                let mut placed = 0;
                for i in 0..2 * capacity {
                    let x = (0.5 + (i % n) as f64) * h;
                    placed += usize::from(sys.emit(&kinds, cls, [x, 4.5 * h, 4.5 * h]));
                }
                placed
            };
            for share in [0.5, 0.0, f64::NAN, 2.0] {
                let (mut s, cls) = new_system();
                s.set_budget_share(share);
                let want = match share {
                    x if x.is_nan() || x >= 1.0 => capacity,
                    x => ((capacity as f64 * x).round() as usize).clamp(1, capacity),
                };
                assert_eq!(
                    (s.limit(), fill(&mut s, cls)),
                    (want, want),
                    "{capacity} x {share}"
                );
                assert_eq!(s.len(), want);
                assert_eq!(s.counts().dropped, (2 * capacity - want) as u64);
                let storage = s.pos.capacity();
                s.set_budget_share(1.0);
                assert_eq!(
                    fill(&mut s, cls),
                    capacity - want,
                    "restored: {capacity} x {share}"
                );
                assert_eq!((s.len(), s.pos.capacity()), (capacity, storage));
            }
        }
    }

    /// The grouped kernels (particles that start in fluid, eight at a time on AVX2, else four at
    /// a time, the one-substep case together) move every particle bit for bit as the
    /// one-at-a-time path.
    #[test]
    fn grouped_particles_move_exactly_as_one_at_a_time() {
        let (n, h) = (16, 1e-3);
        let grid = FluidGrid::new([n, n, n], h, [0.0; 3], [false; 3]).unwrap();
        let mut s = FluidSolver::new(grid, FluidParams::default()).unwrap();
        // A swirl fast enough near its rim for several substeps, and a wall block to slide on.
        s.set_velocity_field(|c, p| match c {
            0 => -12.0 * (p[1] - 0.008),
            1 => 12.0 * (p[0] - 0.008),
            _ => 0.05,
        });
        let mut kinds = vec![VoxelKind::Fluid; n * n * n];
        for k in 0..n {
            for j in 10..14 {
                for i in 10..14 {
                    kinds[i + n * (j + n * k)] = VoxelKind::Wall;
                }
            }
        }
        let mut sys = ParticleSystem::new(s.grid(), 4000, 8, [0.0, -1.0, 0.0]);
        let cls = sys
            .add_class(ParticleClass {
                kind: ParticleKind::Blood,
                settle_m_s: 3e-3,
                tau_s: 2e-3,
                shade_m2: 0.0,
                diameter_m: 0.0,
            })
            .unwrap();
        let mut rng = fastrand::Rng::with_seed(5);
        // Blocks of eight, then a group of four and one particle alone (3005 = 375 x 8 + 4 + 1).
        while sys.len() < 3005 {
            let p = [0, 1, 2].map(|_| rng.f64() * n as f64 * h);
            sys.emit(&kinds, cls, p);
        }
        for v in &mut sys.slip {
            *v = [0, 1, 2].map(|_| rng.f32() - 0.5);
        }
        // One step to build the field and the per-class factors.
        sys.step(&s, &kinds, None, 1.0 / 60.0, None);
        let dt = 1.0 / 60.0;
        let run = |check_from: usize| {
            let k = Kernel::new(
                Sampler::new(&sys.field, sys.dims),
                &kinds,
                &sys.class_step,
                check_from,
                sys.max_substeps,
                dt,
                None,
            );
            let (mut pos, mut slip) = (sys.pos.clone(), sys.slip.clone());
            let mut fate = vec![KEEP; pos.len()];
            let mut sums = [0.0; 256];
            let task = Task {
                offset: 0,
                pos: &mut pos,
                slip: &mut slip,
                class: &sys.class,
                fate: &mut fate,
            };
            let left = sweep(&k, task, &mut sums);
            (pos, slip, fate, left)
        };
        // From 0: every start checked, one at a time; from the end: all grouped.
        let (one, grouped) = (run(0), run(usize::MAX));
        let bits = |v: &[[f32; 3]]| v.iter().flatten().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&one.0), bits(&grouped.0));
        assert_eq!(bits(&one.1), bits(&grouped.1));
        assert_eq!((&one.2, one.3), (&grouped.2, grouped.3));
        // The case mix the comparison covers: particles that moved more than a cell (several
        // substeps) and particles that moved less.
        let far = one
            .0
            .iter()
            .zip(&sys.pos)
            .filter(|(a, b)| (0..3).any(|c| (a[c] - b[c]).abs() > 1.0))
            .count();
        assert!(far > 100 && far < 2900, "{far} of 3005 moved over a cell");
    }
}
