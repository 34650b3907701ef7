//! The stable-fluids step on the MAC grid: advect, add body forces, diffuse, project.

// Loops over the three velocity components index several per-component arrays at once.
#![allow(clippy::needless_range_loop)]

use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::advection::{self, AdvectionScheme};
use super::grid::FluidGrid;
use super::multigrid::{for_spans, max_abs_spans, L_FLUID, L_OPEN, L_SOLID};
use super::pressure::{PressureSolver, ProjectionMethod, SPLIT_DIVISOR};
use super::sample::Layout;
use super::topology::{self, FaceSet, NONE};
use super::viscosity::{self, ViscosityMode, ViscosityScratch};
use super::{CellLabel, FluidError};

/// Largest CFL number (largest face speed dt / h) of a substep at which
/// [`AdvectionScheme::MacCormackLaggedReflection`] applies its reflection; above it the substep is
/// plain MacCormack.
pub const LAGGED_REFLECTION_MAX_CFL: f64 = 1.0;

/// Physical and numerical parameters of the solver.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FluidParams {
    /// Density.
    pub density_kg_m3: f64,
    /// Kinematic viscosity.
    pub viscosity_m2_s: f64,
    /// Body force per unit mass (e.g. gravity or a driving pressure gradient / rho).
    pub body_force_m_s2: [f64; 3],
    /// Advection scheme.
    pub advection: AdvectionScheme,
    /// Pressure solve.
    pub projection: ProjectionMethod,
    /// Divergence tolerance: the projection stops when `max |div u| h / U <= tolerance`, U being the
    /// largest face speed (or `velocity_scale_m_s` if larger).
    pub tolerance: f64,
    /// Iteration cap of the CG solves.
    pub max_iterations: usize,
    /// Lower bound of the velocity scale U of the tolerance.
    pub velocity_scale_m_s: f64,
    /// Split a step into substeps so that the CFL number stays below this (None: never split).
    pub max_cfl: Option<f64>,
    /// Upper bound on substeps per step.
    pub max_substeps: usize,
    /// Fluid cells from which the reference solver's CG products run on rayon; every stage of a
    /// step (advection, viscosity, the multigrid levels, divergence and gradient) runs in two halves
    /// on two threads from 1/12 of this.
    pub parallel_threshold_cells: usize,
}

impl Default for FluidParams {
    fn default() -> Self {
        Self {
            density_kg_m3: 1000.0,
            viscosity_m2_s: 1.0e-6,
            body_force_m_s2: [0.0; 3],
            advection: AdvectionScheme::default(),
            projection: ProjectionMethod::MultigridPcg,
            tolerance: 1.0e-6,
            max_iterations: 500,
            velocity_scale_m_s: 0.0,
            max_cfl: None,
            max_substeps: 8,
            parallel_threshold_cells: 24_000,
        }
    }
}

impl FluidParams {
    /// Checks the parameters, naming the first bad one.
    pub fn validate(&self) -> Result<(), FluidError> {
        let bad = |key: &str, value: String, expected: &str| {
            Err(FluidError::InvalidParameter {
                key: key.into(),
                value,
                expected: expected.into(),
            })
        };
        if !(self.density_kg_m3.is_finite() && self.density_kg_m3 > 0.0) {
            return bad(
                "density_kg_m3",
                self.density_kg_m3.to_string(),
                "a finite value > 0",
            );
        }
        if !(self.viscosity_m2_s.is_finite() && self.viscosity_m2_s >= 0.0) {
            return bad(
                "viscosity_m2_s",
                self.viscosity_m2_s.to_string(),
                "a finite value >= 0",
            );
        }
        if self.body_force_m_s2.iter().any(|f| !f.is_finite()) {
            return bad(
                "body_force_m_s2",
                format!("{:?}", self.body_force_m_s2),
                "finite values",
            );
        }
        if !(self.tolerance.is_finite() && self.tolerance > 0.0) {
            return bad(
                "tolerance",
                self.tolerance.to_string(),
                "a finite value > 0",
            );
        }
        if self.max_iterations == 0 {
            return bad("max_iterations", "0".into(), "at least 1");
        }
        if let Some(c) = self.max_cfl {
            if !(c.is_finite() && c > 0.0) {
                return bad("max_cfl", c.to_string(), "a finite value > 0");
            }
        }
        if self.max_substeps == 0 {
            return bad("max_substeps", "0".into(), "at least 1");
        }
        if let ProjectionMethod::GaussSeidel { sweeps: 0 }
        | ProjectionMethod::RedBlackGaussSeidel { sweeps: 0 } = self.projection
        {
            return bad("sweeps", "0".into(), "at least 1");
        }
        Ok(())
    }
}

/// Counters of one step (summed over its substeps; times in milliseconds).
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct StepStats {
    /// Substeps taken.
    pub substeps: usize,
    /// Whether the labels changed and the topology was rebuilt.
    pub topology_rebuilt: bool,
    /// Time rebuilding the topology.
    pub topology_ms: f64,
    /// Time in advection (including boundary values and extrapolation).
    pub advect_ms: f64,
    /// Time in body forces and viscosity.
    pub diffuse_ms: f64,
    /// Time in the projection.
    pub project_ms: f64,
    /// Whole step.
    pub total_ms: f64,
    /// Viscosity mode of the last substep.
    pub viscosity: ViscosityMode,
    /// Implicit-viscosity CG iterations (all components, all substeps).
    pub viscosity_iterations: usize,
    /// Projection iterations (CG iterations or Gauss-Seidel sweeps), summed over substeps.
    pub projection_iterations: usize,
    /// Whether every projection reached the tolerance.
    pub projection_converged: bool,
    /// After the last projection: max |div u| h / U over fluid cells, the incompatible part of closed
    /// regions removed.
    pub max_div_rel: f64,
    /// Largest incompatible mean `|h div u|` removed from a closed region (m/s): a flux mismatch of
    /// its ports that no pressure can remove.
    pub closed_region_mismatch_m_s: f64,
    /// The whole incompatible flux removed from closed regions, summed over them (m^3/s; largest
    /// over the substeps).
    pub closed_region_flux_m3_per_s: f64,
    /// Fluid cells.
    pub fluid_cells: usize,
}

/// A MAC-grid incompressible Navier-Stokes solver.
pub struct FluidSolver {
    grid: FluidGrid,
    params: FluidParams,
    layout: Layout,
    revision: u64,
    /// Face velocities per component (m/s).
    u: [Vec<f32>; 3],
    tmp: [Vec<f32>; 3],
    /// Cell-centred velocity (for tracing), padded to 4 lanes.
    centred: Vec<crate::simd::V4>,
    faces: [FaceSet; 3],
    compact: [Vec<f32>; 3],
    /// Advection: geometry, runs of active faces, and results in concatenated compact order (with
    /// the MacCormack clamping bounds and the field before the step).
    geo: advection::Geometry,
    plan: advection::Plan,
    adv: Vec<f32>,
    adv_lo: Vec<f32>,
    adv_hi: Vec<f32>,
    adv_orig: Vec<f32>,
    /// MacCormack's forward foot points (x, y, z), compact.
    adv_foot: [Vec<f32>; 3],
    /// The first half step's unprojected field of advection-reflection.
    adv_refl: Vec<f32>,
    ghost: [Vec<f32>; 3],
    visc: ViscosityScratch,
    pressure: PressureSolver,
    /// Pressure (Pa) on level 0's padded box (zero off the fluid cells), kept for warm starts and
    /// probes; the box does not change with the labels, so the pressure of a cell that stays fluid
    /// survives a relabelling.
    pressure_pa: Vec<f64>,
    /// The reflected pressure of the lagged reflection (Pa, level 0's padded box, zero off the
    /// fluid cells): half the pressure before the step less half the hydrostatic potential
    /// ([`FluidSolver::hydrostatic_coefficients`]), `R = (p - phi) / 2`.
    p_lag: Vec<f64>,
    /// Active faces between a fluid and an outflow cell: (component, full face index, +1 if the
    /// outflow cell is the face's upper cell else -1, the outflow cell). There the reflected
    /// pressure of the outflow cell is `-phi / 2` (its pressure is 0), and the projection's
    /// pressure `+phi / 2`, so their sum keeps the outflow at 0 Pa.
    outflow_faces: Vec<(u8, u32, f32, [u32; 3])>,
    /// Whether this substep subtracted the lagged gradient (`pressure_pa + p_lag` after it).
    lagged_applied: bool,
    /// Whether `pressure_pa` is a step's pressure (false before the first step and after
    /// [`FluidSolver::project_now`], whose pressure is no step's): only then is it reflected.
    pressure_from_step: bool,
    /// Padded (level 0) index of the upper cell of the first face of each active run
    /// (`FaceSet::runs`), for the pressure-gradient update.
    run_cells: [Vec<u32>; 3],
    /// Open-cell x range of every cell row (scratch of the topology rebuild).
    open_rows: Vec<[u32; 2]>,
    /// The cells whose centred velocity can be non-zero (None on a periodic grid: all of them).
    centred_rows: Option<advection::CentredRows>,
    /// The labels the topology was built from: the rows that changed since, which the face sets
    /// update.
    label_diff: topology::LabelDiff,
    time_s: f64,
}

/// Level 0 of the pressure solver from the grid's labels within the rows' open ranges `rows`,
/// the levels under it and the solver's vectors; the pressure of cells that stay fluid is kept
/// for the warm start across the relabelling (the rest is zeroed).
fn build_pressure_levels(
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

impl FluidSolver {
    /// A solver on `grid` with all velocities zero.
    pub fn new(grid: FluidGrid, params: FluidParams) -> Result<Self, FluidError> {
        params.validate()?;
        let layout = Layout::new(grid.dims(), grid.periodic());
        let u: [Vec<f32>; 3] = std::array::from_fn(|c| vec![0.0; layout.face_count(c)]);
        let centred_rows = (layout.periodic == [false; 3]).then(Default::default);
        let mut s = Self {
            tmp: u.clone(),
            centred: vec![crate::simd::v4::zero(); grid.cell_count()],
            geo: advection::Geometry::new(grid.dims(), &layout),
            plan: advection::Plan::default(),
            adv: Vec::new(),
            adv_lo: Vec::new(),
            adv_hi: Vec::new(),
            adv_orig: Vec::new(),
            adv_foot: Default::default(),
            adv_refl: Vec::new(),
            u,
            grid,
            params,
            layout,
            revision: 0,
            faces: Default::default(),
            compact: Default::default(),
            ghost: Default::default(),
            visc: ViscosityScratch::default(),
            pressure: PressureSolver::default(),
            pressure_pa: Vec::new(),
            p_lag: Vec::new(),
            outflow_faces: Vec::new(),
            lagged_applied: false,
            pressure_from_step: false,
            run_cells: Default::default(),
            open_rows: Vec::new(),
            centred_rows,
            label_diff: topology::LabelDiff::default(),
            time_s: 0.0,
        };
        // Measured with the Galerkin coarse levels: 2 sweeps and a coarse scale of 0.5 (twice
        // Galerkin's 1/4, compensating piecewise-constant prolongation) give 6.0 iterations to
        // 5e-6 on the benchmark cavity at 0.6 and 1.2 mm (0.55: 6.0 / 6.6, 0.6: 7.0 / 7.0) and
        // 8.1 / 6.6 on the scene's thin cavity (0.4: 10.8 / 7.9, 0.6: 8.9 / 7.0, 0.8: 14.6 / 9.0;
        // the rediscretised coarse levels took 17.0 / 12.1 there).
        s.pressure.mg.coarse_scale = 0.5;
        s.pressure.mg.sweeps = 2;
        s.pressure.mg.coarsest_sweeps = 4; // 16 gives the same iteration counts
        s.rebuild_topology();
        Ok(s)
    }

    /// Per cell row `j + ny k`, the x range `[first, end)` of its fluid and outflow cells, when
    /// the topology is current with the grid's labels (`None` after a relabelling until the
    /// next step rebuilds it).
    pub(crate) fn open_rows(&self) -> Option<&[[u32; 2]]> {
        (self.revision == self.grid.revision()).then_some(&self.open_rows[..])
    }

    /// The grid.
    pub fn grid(&self) -> &FluidGrid {
        &self.grid
    }
    /// The grid, to change labels or port velocities; the solver notices on the next step.
    pub fn grid_mut(&mut self) -> &mut FluidGrid {
        &mut self.grid
    }
    /// The parameters.
    pub fn params(&self) -> &FluidParams {
        &self.params
    }
    /// Replaces the parameters.
    pub fn set_params(&mut self, params: FluidParams) -> Result<(), FluidError> {
        params.validate()?;
        self.params = params;
        Ok(())
    }
    /// Simulated time.
    pub fn time_s(&self) -> f64 {
        self.time_s
    }
    /// Face velocities of component `c` (0, 1 or 2; layout: see [`FluidSolver::face_position_m`]).
    pub fn face_velocities(&self, c: usize) -> &[f32] {
        &self.u[c]
    }
    /// Face velocities of component `c`, to add a divergence-free field between steps (the scene's
    /// injected vortices). The caller leaves the faces beside solid, velocity and outflow cells
    /// as they are; the next step re-applies them and refreshes the extrapolation layers.
    pub fn face_velocities_mut(&mut self, c: usize) -> &mut [f32] {
        &mut self.u[c]
    }
    /// Number of fluid cells.
    pub fn fluid_cells(&self) -> usize {
        self.pressure.mg.levels.first().map_or(0, |l| l.rows())
    }
    /// Whether the stages run in two halves on two threads (from `parallel_threshold_cells /
    /// SPLIT_DIVISOR` fluid cells).
    fn split(&self) -> bool {
        self.fluid_cells() >= (self.params.parallel_threshold_cells / SPLIT_DIVISOR).max(1)
    }

    /// Number of connected fluid regions, and how many are closed (no outflow cell).
    pub fn regions(&self) -> (usize, usize) {
        let r = &self.pressure.regions;
        (r.count(), r.closed.iter().filter(|&&c| c).count())
    }
    /// Number of multigrid levels.
    pub fn multigrid_levels(&self) -> usize {
        self.pressure.mg.used
    }

    /// Position (m) of face `idx` of component `c`.
    pub fn face_position_m(&self, c: usize, idx: usize) -> [f64; 3] {
        let f = self.layout.face_coords(c, idx);
        let p = Layout::face_position(c, f);
        let h = self.grid.spacing_m();
        let o = self.grid.origin_m();
        std::array::from_fn(|a| o[a] + p[a] as f64 * h)
    }

    /// Sets every tracked face velocity from `field(component, position_m)` (initial conditions;
    /// untracked faces stay zero), then re-applies boundary values. Does not project.
    pub fn set_velocity_field(&mut self, mut field: impl FnMut(usize, [f64; 3]) -> f64) {
        for c in 0..3 {
            for idx in 0..self.u[c].len() {
                let x = self.face_position_m(c, idx);
                self.u[c][idx] = if self.faces[c].class[idx] == topology::OTHER {
                    0.0
                } else {
                    field(c, x) as f32
                };
            }
        }
        self.apply_fixed(true);
        self.extrapolate();
    }

    fn rebuild_topology(&mut self) {
        // The rows' open ranges bound every cell that is fluid or open on level 0: the pressure
        // levels visit only them. The face sets visit only the faces near the cells whose labels
        // changed (and the ranges only the rows that hold them are found again).
        let diffed = self
            .label_diff
            .update(self.grid.labels(), self.grid.dims()[0]);
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
        self.revision = self.grid.revision();
        self.apply_fixed(true);
        self.extrapolate();
    }

    /// The active faces between a fluid and an outflow cell (`outflow_faces`, in face order),
    /// from the outflow cells within the rows' open ranges (a few, at the ports) rather than from
    /// every active face.
    fn find_outflow_faces(&mut self) {
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
    fn apply_fixed(&mut self, all: bool) {
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
    fn update_ghosts(&mut self, c: usize) {
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
    fn extrapolate(&mut self) {
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

    /// Largest face speed (m/s) over active and fixed faces.
    pub fn max_speed_m_s(&self) -> f64 {
        // On the bits: |v| of a float orders as a (non-negative) i32, and an i32 max reduction
        // vectorises even on baseline SSE2 (f32::max's NaN rule does not, nor does u32 max).
        // NaN, which f32::max would skip, counts as 0.
        let bits = |v: f32| {
            let b = (v.to_bits() & 0x7fff_ffff) as i32;
            if b > 0x7f80_0000 {
                0
            } else {
                b
            }
        };
        /// The largest `bits` of the faces of `runs` (and `m`), in eight running maxima (lanes),
        /// so the reduction is plain lane-wise code: a kernel compiled twice (`crate::simd`), as
        /// SSE2 has no i32 max and LLVM keeps the baseline compilation scalar.
        struct RunsMax<'a, B> {
            u: &'a [f32],
            runs: &'a [[u32; 3]],
            m: i32,
            bits: B,
        }
        impl<B: Fn(f32) -> i32> crate::simd::Kernel for RunsMax<'_, B> {
            type Output = i32;
            #[inline(always)]
            fn run(self) -> i32 {
                let RunsMax {
                    u,
                    runs,
                    mut m,
                    bits,
                } = self;
                let mut acc = [m; 8];
                for &[f, _, len] in runs {
                    let (f, len) = (f as usize, len as usize);
                    let run = &u[f..f + len];
                    let mut chunks = run.chunks_exact(8);
                    for ch in &mut chunks {
                        for (a, &v) in acc.iter_mut().zip(ch) {
                            *a = (*a).max(bits(v));
                        }
                    }
                    for &v in chunks.remainder() {
                        m = m.max(bits(v));
                    }
                }
                acc.into_iter().fold(m, i32::max)
            }
        }
        let mut m = 0i32;
        for c in 0..3 {
            let set = &self.faces[c];
            let u = &self.u[c];
            m = crate::simd::dispatch(RunsMax {
                u,
                runs: &set.runs,
                m,
                bits,
            });
            for f in &set.fixed {
                m = m.max(bits(u[f[0] as usize]));
            }
        }
        f32::from_bits(m as u32) as f64
    }

    /// Kinetic energy (J) of the fluid: `rho/2 sum u_f^2 h^3` over active faces.
    pub fn kinetic_energy_j(&self) -> f64 {
        let h = self.grid.spacing_m();
        let mut e = 0.0f64;
        for c in 0..3 {
            for &idx in &self.faces[c].active {
                e += (self.u[c][idx as usize] as f64).powi(2);
            }
        }
        0.5 * self.params.density_kg_m3 * e * h * h * h
    }

    /// Advances by `dt_s` (split into substeps if `max_cfl` asks for it).
    pub fn step(&mut self, dt_s: f64) -> Result<StepStats, FluidError> {
        if !(dt_s.is_finite() && dt_s > 0.0) {
            return Err(FluidError::InvalidParameter {
                key: "dt_s".into(),
                value: dt_s.to_string(),
                expected: "a finite time step > 0".into(),
            });
        }
        let t0 = Instant::now();
        // The fork-join guard judges the share of a core this thread gets over its steps.
        let _busy = crate::fork_join::BusySpan::start();
        let mut stats = StepStats {
            projection_converged: true,
            ..Default::default()
        };
        if self.revision != self.grid.revision() {
            self.rebuild_topology();
            stats.topology_rebuilt = true;
            stats.topology_ms = t0.elapsed().as_secs_f64() * 1e3;
        } else {
            self.apply_fixed(false);
        }
        let mut n = 1usize;
        if let Some(max_cfl) = self.params.max_cfl {
            let cfl = self.max_speed_m_s() * dt_s / self.grid.spacing_m();
            if cfl > max_cfl {
                n = ((cfl / max_cfl).ceil() as usize).clamp(1, self.params.max_substeps);
            }
        }
        let sub = dt_s / n as f64;
        for _ in 0..n {
            self.substep(sub, &mut stats);
        }
        stats.substeps = n;
        stats.fluid_cells = self.fluid_cells();
        stats.total_ms = t0.elapsed().as_secs_f64() * 1e3;
        Ok(stats)
    }

    fn substep(&mut self, dt: f64, stats: &mut StepStats) {
        let h = self.grid.spacing_m();
        // Every stage splits in two halves from the multigrid's threshold (on the fork-join helper, whose
        // hand-over is a cache-line round trip, not a thread wake-up).
        let parallel = self.split();

        // Advection.
        self.advect(dt, parallel, stats);

        // Body forces and viscosity. The force goes in before an implicit and after an explicit
        // viscous step, and the lagged wall terms are taken before the force: then a steady state
        // of the split step is the steady state of the equations, whatever dt.
        let t = Instant::now();
        let nu = self.params.viscosity_m2_s;
        let a = nu * dt / (h * h);
        let wide = parallel;
        let implicit = nu > 0.0 && a > viscosity::EXPLICIT_LIMIT;
        stats.viscosity = match (nu > 0.0, implicit) {
            (false, _) => ViscosityMode::Skipped,
            (true, false) => ViscosityMode::Explicit,
            (true, true) => ViscosityMode::Implicit,
        };
        if nu > 0.0 {
            for c in 0..3 {
                self.update_ghosts(c);
            }
        }
        if nu == 0.0 || implicit {
            self.add_body_force(dt);
        }
        if nu > 0.0 {
            for c in 0..3 {
                let set = &self.faces[c];
                if implicit {
                    stats.viscosity_iterations += viscosity::implicit(
                        set,
                        &self.u[c],
                        &self.ghost[c],
                        a as f32,
                        &mut self.visc,
                        1e-6,
                        200,
                    );
                    for (n, &idx) in set.active.iter().enumerate() {
                        self.u[c][idx as usize] = self.visc.x[n];
                    }
                } else {
                    viscosity::explicit(
                        set,
                        &self.u[c],
                        &self.ghost[c],
                        a as f32,
                        &mut self.compact[c],
                        wide,
                    );
                    viscosity::write_back(set, &self.compact[c], &mut self.u[c]);
                }
            }
            if !implicit {
                self.add_body_force(dt);
            }
        }
        stats.diffuse_ms += t.elapsed().as_secs_f64() * 1e3;

        let t = Instant::now();
        if self.lagged_applied {
            // The projection's pressure of the outflow cells is +phi / 2 (a Dirichlet value).
            self.outflow_potential_gradient(dt, 1.0);
        }
        self.project(dt, stats);
        if self.lagged_applied {
            // Both are zero off the fluid cells: the spans cover them.
            for &[s, e] in &self.pressure.mg.levels[0].spans {
                let r = s as usize..e as usize;
                for (p, &l) in self.pressure_pa[r.clone()].iter_mut().zip(&self.p_lag[r]) {
                    *p += l;
                }
            }
        }
        self.pressure_from_step = true;
        stats.project_ms += t.elapsed().as_secs_f64() * 1e3;
        self.time_s += dt;
    }

    fn add_body_force(&mut self, dt: f64) {
        let f = self.params.body_force_m_s2;
        for c in 0..3 {
            if f[c] != 0.0 {
                let df = (f[c] * dt) as f32;
                for &idx in &self.faces[c].active {
                    self.u[c][idx as usize] += df;
                }
            }
        }
    }

    /// The cell-centred velocity the traces follow, from the current face velocities.
    fn update_centred(&mut self) {
        let wide = self.split();
        let [u0, u1, u2] = &self.u;
        advection::update_centred(
            &self.layout,
            self.grid.dims(),
            [u0, u1, u2],
            &mut self.centred,
            self.centred_rows.as_ref(),
            wide,
        );
    }

    /// `tmp = u` with the advected values of the active faces scattered in (the field a
    /// second trace of the two-step schemes samples).
    fn advected_into_tmp(
        plan: &advection::Plan,
        u: &[Vec<f32>; 3],
        adv: &[f32],
        tmp: &mut [Vec<f32>; 3],
    ) {
        for c in 0..3 {
            tmp[c].copy_from_slice(&u[c]);
        }
        advection::scatter(plan, adv, tmp);
    }

    /// Advects the face velocities by `dt_cells` (dt / h) through the centred velocity of the
    /// last [`FluidSolver::update_centred`] with `scheme` (a single-step scheme: a reflection
    /// scheme's half steps are its base scheme), leaving the compact result in `adv`.
    fn advect_passes(&mut self, dt_cells: f64, parallel: bool, scheme: AdvectionScheme) {
        let dt_cells = dt_cells as f32;
        let [u0, u1, u2] = &self.u;
        let pass = advection::Pass {
            geo: &self.geo,
            plan: &self.plan,
            vc: &self.centred,
            src: [u0, u1, u2],
            dt_cells,
        };
        match scheme {
            AdvectionScheme::SemiLagrangian => pass.semi_lagrangian(&mut self.adv, parallel),
            AdvectionScheme::MonotoneCubic => pass.cubic(&mut self.adv, parallel),
            AdvectionScheme::MacCormack
            | AdvectionScheme::MacCormackReflection
            | AdvectionScheme::MacCormackLaggedReflection => {
                // The backward step with its bounds and the forward trace in one pass, then the
                // forward step of its result (`tmp`: `u` off the active faces) and the correction.
                let [f0, f1, f2] = &mut self.adv_foot;
                pass.maccormack_trace(
                    &mut self.adv,
                    [&mut self.adv_lo, &mut self.adv_hi],
                    [f0, f1, f2],
                    parallel,
                );
                Self::advected_into_tmp(&self.plan, &self.u, &self.adv, &mut self.tmp);
                let [t0, t1, t2] = &self.tmp;
                // The forward trace is done: this pass only samples `tmp` at its feet.
                let forward = advection::Pass {
                    src: [t0, t1, t2],
                    ..pass
                };
                let [f0, f1, f2] = &self.adv_foot;
                forward.maccormack_correct(
                    [u0, u1, u2],
                    [f0, f1, f2],
                    [&self.adv_lo, &self.adv_hi],
                    &mut self.adv,
                    parallel,
                );
            }
            AdvectionScheme::Bfecc => {
                pass.semi_lagrangian_bounds(
                    &mut self.adv,
                    &mut self.adv_lo,
                    &mut self.adv_hi,
                    parallel,
                );
                advection::gather(&self.plan, [u0, u1, u2], &mut self.adv_orig);
                Self::advected_into_tmp(&self.plan, &self.u, &self.adv, &mut self.tmp);
                let [t0, t1, t2] = &self.tmp;
                let forward = advection::Pass {
                    src: [t0, t1, t2],
                    dt_cells: -dt_cells,
                    ..pass
                };
                // The corrected field `u + (u - forward(backward(u))) / 2`, advected backward
                // once more (`tmp` keeps `u` off the active faces) and clamped.
                forward.bfecc_source(&mut self.adv_orig, parallel);
                advection::scatter(&self.plan, &self.adv_orig, &mut self.tmp);
                let [t0, t1, t2] = &self.tmp;
                let corrected = advection::Pass {
                    src: [t0, t1, t2],
                    ..pass
                };
                corrected.clamped(&mut self.adv, &self.adv_lo, &self.adv_hi, parallel);
            }
        }
        advection::scatter(&self.plan, &self.adv, &mut self.u);
    }

    /// `rho g_a h` per axis (Pa per cell) of the body force along the non-periodic axes: the
    /// hydrostatic potential `phi = rho g.x` of cell (i, j, k) is the sum of `coef_a (i_a + 1/2)`
    /// (any constant would do). A periodic axis has no hydrostatic balance (the force drives a
    /// flow there), so its component is left out; `None` without such a force.
    fn hydrostatic_coefficients(&self) -> Option<[f64; 3]> {
        let (rho, h) = (self.params.density_kg_m3, self.grid.spacing_m());
        let periodic = self.grid.periodic();
        let f = self.params.body_force_m_s2;
        let coef: [f64; 3] =
            std::array::from_fn(|a| if periodic[a] { 0.0 } else { rho * f[a] * h });
        coef.iter().any(|&c| c != 0.0).then_some(coef)
    }

    /// The reflection of [`AdvectionScheme::MacCormackLaggedReflection`]: the reflected pressure
    /// `R = (p - phi) / 2` (`p` the last pressure, `phi` the hydrostatic potential of the body
    /// force, see [`FluidSolver::hydrostatic_coefficients`]) kept in `p_lag`, its gradient times
    /// dt / rho subtracted from the face velocities; `p - R` is left in `pressure_pa` as the
    /// projection's warm start, and after the projection `pressure_pa + p_lag` is the pressure.
    /// Only the part of the pressure that does not balance the body force is reflected: at
    /// hydrostatic rest nothing is, so nothing is advected.
    fn lagged_reflection(&mut self, dt: f64) {
        let to_q = dt / (self.params.density_kg_m3 * self.grid.spacing_m());
        // The pressure is zero off the fluid cells: the spans cover them.
        for &[s, e] in &self.pressure.mg.levels[0].spans {
            let r = s as usize..e as usize;
            for (l, p) in self.p_lag[r.clone()]
                .iter_mut()
                .zip(&mut self.pressure_pa[r])
            {
                *l = 0.5 * *p;
                *p = *l;
            }
        }
        if let Some(coef) = self.hydrostatic_coefficients() {
            let l0 = &self.pressure.mg.levels[0];
            for &[j, k, i0, i1] in &l0.row_spans {
                let (j, k, i0, i1) = (j as usize, k as usize, i0 as usize, i1 as usize);
                let base = coef[1] * (j as f64 + 0.5) + coef[2] * (k as f64 + 0.5);
                let p0 = l0.pad(i0, j, k);
                for i in i0..i1 {
                    let idx = p0 + (i - i0);
                    let half_phi = 0.5 * (base + coef[0] * (i as f64 + 0.5)) * l0.mask[idx] as f64;
                    self.p_lag[idx] -= half_phi;
                    self.pressure_pa[idx] += half_phi;
                }
            }
        }
        let p_lag = &self.p_lag;
        let ps = &mut self.pressure;
        for_spans(&ps.mg.levels[0], &mut ps.dq, |spans, dq, off| {
            for &[s, e] in spans {
                let (s, e) = (s as usize, e as usize);
                for (q, &p) in dq[s - off..e - off].iter_mut().zip(&p_lag[s..e]) {
                    *q = p * to_q;
                }
            }
            0.0
        });
        if self.grid.periodic().iter().any(|&p| p) {
            self.pressure.mg.levels[0].halo(&mut self.pressure.dq);
        }
        self.subtract_gradient();
        // The outflow cells' reflected pressure is -phi / 2 (`dq` holds 0 there).
        self.outflow_potential_gradient(dt, -1.0);
    }

    /// `u -= dt / rho grad(sign phi / 2)` on the faces between fluid and outflow cells, `phi / 2`
    /// taken on the outflow cell only (zero on the fluid cell); nothing without a hydrostatic
    /// potential.
    fn outflow_potential_gradient(&mut self, dt: f64, sign: f64) {
        let Some(coef) = self.hydrostatic_coefficients() else {
            return;
        };
        let to_q = dt / (self.params.density_kg_m3 * self.grid.spacing_m());
        for &(c, idx, side, cell) in &self.outflow_faces {
            let phi: f64 = (0..3).map(|a| coef[a] * (cell[a] as f64 + 0.5)).sum();
            self.u[c as usize][idx as usize] -= (side as f64 * sign * 0.5 * phi * to_q) as f32;
        }
    }

    /// The solver's scaled pressure `dq = to_q pressure_pa` on the fluid spans of level 0.
    fn pressure_to_dq(&mut self, to_q: f64) {
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

    /// The advection stage of a substep of `dt` s. Advection-reflection runs its first half step,
    /// the intermediate projection (counted as projection time) and the reflection here.
    fn advect(&mut self, dt: f64, parallel: bool, stats: &mut StepStats) {
        let h = self.grid.spacing_m();
        let scheme = self.params.advection;
        let t = Instant::now();
        // The lagged reflection only up to CFL 1: above, the lagged gradient carried many cells
        // turned into rotational velocity and pumped energy into the stress soak (max speed 76x
        // the port's over 10^6 steps at CFL up to 50); there the step is plain MacCormack.
        // And only a step's pressure: before the first step there is none (zero would reflect
        // the whole hydrostatic potential, and the viscous step would leave a trace of it).
        self.lagged_applied = scheme == AdvectionScheme::MacCormackLaggedReflection
            && self.pressure_from_step
            && self.max_speed_m_s() * dt <= LAGGED_REFLECTION_MAX_CFL * h;
        self.extrapolate();
        self.update_centred();
        // The traces follow the (divergence-free) velocity before the reflection, as the second
        // half step of advection-reflection follows the projected one: through the reflected
        // field, whose divergence is dt/2 lap(p) / rho, the advection would change the energy by
        // -dt^2 |grad p|^2 / rho^2 per step (to leading order), all the reflection saves.
        if self.lagged_applied {
            self.lagged_reflection(dt);
            self.extrapolate();
        }
        if scheme != AdvectionScheme::MacCormackReflection {
            self.advect_passes(dt / h, parallel, scheme);
            stats.advect_ms += t.elapsed().as_secs_f64() * 1e3;
            return;
        }
        // u~ = A(u; u, dt/2), then u_half = P u~ (u~ kept in `adv_refl`).
        self.advect_passes(0.5 * dt / h, parallel, scheme);
        self.adv_refl.copy_from_slice(&self.adv);
        stats.advect_ms += t.elapsed().as_secs_f64() * 1e3;
        let t = Instant::now();
        self.project(0.5 * dt, stats);
        stats.project_ms += t.elapsed().as_secs_f64() * 1e3;
        // Trace through u_half; advect the reflection 2 u_half - u~ by dt/2.
        let t = Instant::now();
        self.extrapolate();
        self.update_centred();
        for run in &self.plan.runs {
            let (f, n, len) = (run.full as usize, run.compact as usize, run.len as usize);
            let u = &mut self.u[run.c as usize][f..f + len];
            for (v, &w) in u.iter_mut().zip(&self.adv_refl[n..n + len]) {
                *v = 2.0 * *v - w;
            }
        }
        self.extrapolate();
        self.advect_passes(0.5 * dt / h, parallel, scheme);
        stats.advect_ms += t.elapsed().as_secs_f64() * 1e3;
    }

    /// `-h div u` on the fluid cells of level 0's padded box (zero elsewhere), into the pressure
    /// solver's right-hand side, with the incompatible mean of closed regions removed; returns the
    /// largest mean removed (m/s). Row by row: each row's faces are contiguous in every component.
    fn divergence_rhs(&mut self) -> f64 {
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
        ps.regions.remove_closed_means_dense(&mut ps.bd)
    }

    /// Largest `|h div u|` over the fluid cells from the last [`FluidSolver::divergence_rhs`].
    fn max_divergence_m_s(&self) -> f64 {
        max_abs_spans(&self.pressure.mg.levels[0], &self.pressure.bd)
    }

    /// `u -= grad q` on the active faces, `q` being the dense solution of the pressure solver.
    fn subtract_gradient(&mut self) {
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
        }
    }

    fn project(&mut self, dt: f64, stats: &mut StepStats) {
        let n = self.fluid_cells();
        if n == 0 {
            stats.max_div_rel = 0.0;
            return;
        }
        let h = self.grid.spacing_m();
        let rho = self.params.density_kg_m3;
        let u_ref = self
            .max_speed_m_s()
            .max(self.params.velocity_scale_m_s)
            .max(1e-12);
        self.pressure
            .set_parallel_rows(self.params.parallel_threshold_cells);
        let mismatch = self.divergence_rhs();
        stats.closed_region_mismatch_m_s = stats.closed_region_mismatch_m_s.max(mismatch);
        stats.closed_region_flux_m3_per_s = stats
            .closed_region_flux_m3_per_s
            .max(self.pressure.regions.removed_total * h * h);
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

    /// Velocity (m/s, along the face's +axis) on face `face` of `cell` (0..6: -x, +x, -y, +y,
    /// -z, +z).
    #[inline]
    pub fn cell_face_velocity_m_s(&self, cell: [usize; 3], face: usize) -> f32 {
        let c = face / 2;
        let mut f = cell;
        if face % 2 == 1 {
            f[c] += 1;
            if self.layout.periodic[c] && f[c] == self.grid.dims()[c] {
                f[c] = 0;
            }
        }
        self.u[c][self.layout.face_index(c, f)]
    }

    /// Cell-centred velocity (m/s): the mean of the two faces along each axis.
    #[inline]
    pub fn centred_velocity_m_s(&self, cell: [usize; 3]) -> [f32; 3] {
        std::array::from_fn(|c| {
            0.5 * (self.cell_face_velocity_m_s(cell, 2 * c)
                + self.cell_face_velocity_m_s(cell, 2 * c + 1))
        })
    }

    /// Velocity (m/s) interpolated at a point (clamped into the grid).
    pub fn sample_velocity_m_s(&self, point_m: [f64; 3]) -> [f64; 3] {
        let p = self.grid_units(point_m);
        let [u0, u1, u2] = &self.u;
        let v = self.layout.velocity([u0, u1, u2], p);
        [v[0] as f64, v[1] as f64, v[2] as f64]
    }

    /// Component `c` of the velocity (m/s) interpolated at a point (clamped into the grid): a
    /// third of [`FluidSolver::sample_velocity_m_s`]'s work.
    pub fn sample_velocity_component_m_s(&self, c: usize, point_m: [f64; 3]) -> f64 {
        let p = self.grid_units(point_m);
        f64::from(self.layout.sample(c, &self.u[c], p))
    }

    /// The interpolated velocity at a point (m/s, as [`FluidSolver::sample_velocity_m_s`]) and
    /// its curl (1/s) by central differences over one cell each way.
    pub fn velocity_and_curl(&self, point_m: [f64; 3]) -> ([f64; 3], [f64; 3]) {
        let h = self.grid.spacing_m();
        let [u0, u1, u2] = &self.u;
        let p = self.grid_units(point_m);
        // d[c][a] = u_c(p + h e_a) - u_c(p - h e_a).
        let (v, d) = match self.layout.velocity_and_cross_differences([u0, u1, u2], p) {
            Some((v, d)) => (v.map(f64::from), d.map(|r| r.map(f64::from))),
            None => (
                self.sample_velocity_m_s(point_m),
                std::array::from_fn(|c| {
                    std::array::from_fn(|a| {
                        if a == c {
                            return 0.0;
                        }
                        let (mut lo, mut hi) = (point_m, point_m);
                        lo[a] -= h;
                        hi[a] += h;
                        self.sample_velocity_component_m_s(c, hi)
                            - self.sample_velocity_component_m_s(c, lo)
                    })
                }),
            ),
        };
        let k = 0.5 / h;
        let curl = [
            (d[2][1] - d[1][2]) * k,
            (d[0][2] - d[2][0]) * k,
            (d[1][0] - d[0][1]) * k,
        ];
        (v, curl)
    }

    fn grid_units(&self, point_m: [f64; 3]) -> [f32; 3] {
        let h = self.grid.spacing_m();
        let o = self.grid.origin_m();
        std::array::from_fn(|a| ((point_m[a] - o[a]) / h) as f32)
    }

    /// Pressure (Pa) interpolated at a point from the fluid and outflow cells around it (outflow
    /// cells count as 0 Pa); `None` if none of the eight surrounding cells is fluid or outflow.
    pub fn sample_pressure_pa(&self, point_m: [f64; 3]) -> Option<f64> {
        let p = self.grid_units(point_m);
        let dims = self.grid.dims();
        let periodic = self.grid.periodic();
        let l0 = &self.pressure.mg.levels[0];
        let mut sum = 0.0;
        let mut wsum = 0.0;
        let mut ax = [[(0usize, 0.0f64); 2]; 3];
        for a in 0..3 {
            let s = (p[a] as f64 - 0.5).clamp(
                if periodic[a] { f64::MIN } else { 0.0 },
                if periodic[a] {
                    f64::MAX
                } else {
                    (dims[a] - 1) as f64
                },
            );
            let fl = s.floor();
            let t = s - fl;
            let n = dims[a] as i64;
            let i0 = fl as i64;
            let wrap = |i: i64| {
                if periodic[a] {
                    i.rem_euclid(n) as usize
                } else {
                    i.clamp(0, n - 1) as usize
                }
            };
            ax[a] = [(wrap(i0), 1.0 - t), (wrap(i0 + 1), t)];
        }
        for &(k, wz) in &ax[2] {
            for &(j, wy) in &ax[1] {
                for &(i, wx) in &ax[0] {
                    let w = wx * wy * wz;
                    if w <= 0.0 {
                        continue;
                    }
                    let idx = self.grid.index([i, j, k]);
                    match self.grid.label_at(idx) {
                        CellLabel::Fluid => {
                            sum += w * self.pressure_pa[l0.pad(i, j, k)];
                            wsum += w;
                        }
                        CellLabel::Outflow => wsum += w,
                        _ => {}
                    }
                }
            }
        }
        (wsum > 0.0).then(|| sum / wsum)
    }

    /// Pressure (Pa) of a fluid cell; `None` for other cells.
    pub fn cell_pressure_pa(&self, cell: [usize; 3]) -> Option<f64> {
        (self.grid.label(cell)? == CellLabel::Fluid).then(|| {
            let l0 = &self.pressure.mg.levels[0];
            self.pressure_pa[l0.pad(cell[0], cell[1], cell[2])]
        })
    }

    /// Max |div u| h / U over fluid cells now (closed regions' incompatible mean removed).
    pub fn max_divergence_rel(&mut self) -> f64 {
        if self.fluid_cells() == 0 {
            return 0.0;
        }
        let u_ref = self
            .max_speed_m_s()
            .max(self.params.velocity_scale_m_s)
            .max(1e-12);
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

#[cfg(test)]
mod tests {
    use super::*;

    /// With stray closed cells beside the open cavity, the multigrid CG's update runs the
    /// V-cycle's first half-sweep and the residual's maximum in its own pass and redoes them on
    /// the closed cells after their means are removed: the projection equals the one whose
    /// V-cycle does that half-sweep itself, bit for bit, iterations included.
    #[test]
    fn the_fused_update_with_closed_regions_equals_the_plain_one() {
        let solver = |plain: bool| {
            let mut grid = super::super::cavity::ellipsoid_cavity(0.0015, 1.0).unwrap();
            assert!(super::super::cavity::add_stray_blocks(&mut grid, 4).len() >= 16);
            let params = FluidParams {
                tolerance: 1e-6,
                ..FluidParams::default()
            };
            let mut s = FluidSolver::new(grid, params).unwrap();
            s.pressure.plain_update = plain;
            let mut rng = fastrand::Rng::with_seed(99);
            s.set_velocity_field(move |_, _| rng.f64() - 0.5);
            s
        };
        let (mut fused, mut plain) = (solver(false), solver(true));
        assert!(fused.pressure.regions.any_closed() && !fused.pressure.regions.all_closed());
        let (a, b) = (fused.project_now(1e-2), plain.project_now(1e-2));
        assert!(a.projection_converged, "{a:?}");
        assert_eq!(a.projection_iterations, b.projection_iterations);
        for c in 0..3 {
            let same = fused
                .face_velocities(c)
                .iter()
                .zip(plain.face_velocities(c))
                .all(|(x, y)| x.to_bits() == y.to_bits());
            assert!(same, "component {c} differs");
        }
    }

    /// The centred velocity computed on the open rows dilated by `advection::CENTRED_REACH` equals
    /// the whole box's after any sequence of relabellings (regions that grow, shrink, split and
    /// vanish; moving walls and outflow cells among them) and steps: every other cell holds zero.
    #[test]
    fn centred_velocity_on_the_open_rows_equals_the_whole_box() {
        let labels = [
            CellLabel::Fluid,
            CellLabel::Solid,
            CellLabel::Velocity,
            CellLabel::Outflow,
        ];
        for (seed, dims) in [[14, 11, 9], [9, 16, 12], [20, 7, 7]]
            .into_iter()
            .enumerate()
        {
            let mut rng = fastrand::Rng::with_seed(40 + seed as u64);
            let mut grid = FluidGrid::new(dims, 1e-3, [0.0; 3], [false; 3]).unwrap();
            for k in 0..dims[2] {
                for j in 0..dims[1] {
                    for i in 0..dims[0] {
                        grid.set_label([i, j, k], CellLabel::Solid).unwrap();
                    }
                }
            }
            let mut s = FluidSolver::new(grid, FluidParams::default()).unwrap();
            let mut checked = 0;
            for step in 0..80 {
                // A random box of cells to one label: fluid most often, so regions form.
                let label = match rng.u8(..6) {
                    0..=2 => CellLabel::Fluid,
                    3 => CellLabel::Solid,
                    n => labels[n as usize - 2],
                };
                let lo = dims.map(|n| rng.usize(..n));
                let size = dims.map(|n| rng.usize(1..=n / 2));
                for k in lo[2]..(lo[2] + size[2]).min(dims[2]) {
                    for j in lo[1]..(lo[1] + size[1]).min(dims[1]) {
                        for i in lo[0]..(lo[0] + size[0]).min(dims[0]) {
                            let g = s.grid_mut();
                            g.set_label([i, j, k], label).unwrap();
                            if label == CellLabel::Velocity {
                                let v = [rng.f32() - 0.5, rng.f32() - 0.5, rng.f32() - 0.5];
                                g.set_velocity([i, j, k], v).unwrap();
                            }
                        }
                    }
                }
                s.step(1e-3).unwrap();
                if step % 2 == 0 {
                    s.set_velocity_field(|_, _| rng.f64() - 0.5);
                }
                s.update_centred();
                let [u0, u1, u2] = &s.u;
                let mut whole = vec![crate::simd::v4::zero(); s.centred.len()];
                advection::update_centred(&s.layout, dims, [u0, u1, u2], &mut whole, None, false);
                for (n, (got, want)) in s.centred.iter().zip(&whole).enumerate() {
                    assert_eq!(
                        crate::simd::v4::lanes(*got),
                        crate::simd::v4::lanes(*want),
                        "cell {n} of {dims:?}, step {step}"
                    );
                }
                checked += whole
                    .iter()
                    .filter(|v| crate::simd::v4::lanes(**v) != [0.0; 4])
                    .count();
            }
            assert!(checked > 1000, "{checked} non-zero cells compared");
        }
    }

    /// The outflow faces by their definition: every active face with an outflow cell on one
    /// side, in face order, with +1 when the outflow cell is its upper cell.
    fn outflow_faces_by_scan(s: &FluidSolver) -> Vec<(u8, u32, f32, [u32; 3])> {
        let mut out = Vec::new();
        for c in 0..3 {
            let set = &s.faces[c];
            for (&idx, &[lo, up]) in set.active.iter().zip(set.active_cells()) {
                let outflow = |cell: u32| {
                    (cell != NONE && s.grid.label_at(cell as usize) == CellLabel::Outflow)
                        .then(|| s.grid.coords(cell as usize).map(|v| v as u32))
                };
                match (outflow(lo), outflow(up)) {
                    (_, Some(x)) => out.push((c as u8, idx, 1.0, x)),
                    (Some(x), None) => out.push((c as u8, idx, -1.0, x)),
                    (None, None) => {}
                }
            }
        }
        out
    }

    #[test]
    fn outflow_faces_found_from_the_outflow_cells_equal_a_scan_of_the_active_faces() {
        let labels = [
            CellLabel::Fluid,
            CellLabel::Fluid,
            CellLabel::Solid,
            CellLabel::Velocity,
            CellLabel::Outflow,
        ];
        let mut found = 0;
        for (seed, (dims, periodic)) in [
            ([9, 7, 6], [false; 3]),
            ([8, 6, 5], [true, false, true]),
            ([7, 1, 6], [false; 3]),
            ([7, 3, 6], [false, true, false]),
            ([7, 1, 6], [false, true, false]),
            ([7, 2, 6], [false, true, false]),
        ]
        .into_iter()
        .enumerate()
        {
            let mut rng = fastrand::Rng::with_seed(3 + seed as u64);
            let grid = FluidGrid::new(dims, 1e-3, [0.0; 3], periodic).unwrap();
            let mut s = FluidSolver::new(grid, FluidParams::default()).unwrap();
            for round in 0..12 {
                for _ in 0..rng.usize(1..40) {
                    let cell = dims.map(|n| rng.usize(..n));
                    let l = labels[rng.usize(..labels.len())];
                    s.grid_mut().set_label(cell, l).unwrap();
                }
                s.rebuild_topology();
                let want = outflow_faces_by_scan(&s);
                assert_eq!(s.outflow_faces, want, "round {round}, {periodic:?}");
                found += want.len();
            }
        }
        assert!(found > 100, "{found} outflow faces");
    }
}
