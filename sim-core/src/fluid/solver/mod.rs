//! The stable-fluids step on the MAC grid: advect, add body forces, diffuse, project.
//!
//! - `params.rs`: the parameters and a step's counters;
//! - `boundary.rs`: the topology rebuild after a relabelling, and the boundary values (fixed
//!   faces, wall ghosts, extrapolation layers);
//! - `advect.rs`: the advection stage (the schemes' passes, the lagged reflection);
//! - `projection.rs`: the pressure projection (divergence, solve, gradient) and the pressure
//!   levels built from the labels;
//! - `sampling.rs`: velocity and pressure at cells and points, for the scene and the probes.

// Loops over the three velocity components index several per-component arrays at once.
#![allow(clippy::needless_range_loop)]

use std::time::Instant;

use super::advection::{self, AdvectionScheme};
use super::cut_viscosity::CutViscosity;
use super::grid::FluidGrid;
use super::pressure::{PressureSolver, SPLIT_DIVISOR};
use super::sample::Layout;
use super::topology::{self, FaceSet};
use super::viscosity::{self, Operator, ViscosityMode, ViscosityScratch};
use super::FluidError;

mod advect;
mod boundary;
#[cfg(test)]
mod cut_tests;
mod params;
mod projection;
mod sampling;
#[cfg(test)]
mod tests;
#[cfg(test)]
mod wall_flux_tests;

pub use params::{FluidParams, StepStats};

/// Largest CFL number (largest face speed dt / h) of a substep at which
/// [`AdvectionScheme::MacCormackLaggedReflection`] applies its reflection; above it the substep is
/// plain MacCormack.
pub const LAGGED_REFLECTION_MAX_CFL: f64 = 1.0;

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
    /// The viscous operators with the walls at their distance, when the grid's cut fractions
    /// carry the walls' distances (`cut_walls`); otherwise unused (the labels' staircase).
    cut_visc: [CutViscosity; 3],
    cut_walls: bool,
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
    /// The boundary fluxes the last projection shifted to balance closed regions, m^3/s into the
    /// fluid (`FluidGrid::boundary_flux_weights_m2`).
    boundary_flux_shift_m3_per_s: f64,
    /// The shared flux the last projection applied, m^3/s into the fluid
    /// (`FluidGrid::shared_flux_m3_per_s`).
    shared_flux_m3_per_s: f64,
    /// Padded (level 0) index of the upper cell of the first face of each active run
    /// (`FaceSet::runs`), for the pressure-gradient update.
    run_cells: [Vec<u32>; 3],
    /// Active faces (full indices) whose open area fraction is 0: walls between two cut fluid
    /// cells, held at zero velocity.
    cut_closed: [Vec<u32>; 3],
    /// Open-cell x range of every cell row (scratch of the topology rebuild).
    open_rows: Vec<[u32; 2]>,
    /// The cells whose centred velocity can be non-zero (None on a periodic grid: all of them).
    centred_rows: Option<advection::CentredRows>,
    /// The labels the topology was built from: the rows that changed since, which the face sets
    /// update.
    label_diff: topology::LabelDiff,
    time_s: f64,
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
            cut_visc: Default::default(),
            cut_walls: false,
            pressure: PressureSolver::default(),
            pressure_pa: Vec::new(),
            p_lag: Vec::new(),
            outflow_faces: Vec::new(),
            lagged_applied: false,
            pressure_from_step: false,
            boundary_flux_shift_m3_per_s: 0.0,
            shared_flux_m3_per_s: 0.0,
            run_cells: Default::default(),
            cut_closed: Default::default(),
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
        // With the walls at their distance the explicit limit also depends on them.
        let implicit = nu > 0.0
            && (a > viscosity::EXPLICIT_LIMIT
                || (self.cut_walls && !self.cut_visc.iter().all(|v| v.explicit_stable(a))));
        stats.viscosity = match (nu > 0.0, implicit) {
            (false, _) => ViscosityMode::Skipped,
            (true, false) => ViscosityMode::Explicit,
            (true, true) => ViscosityMode::Implicit,
        };
        if nu > 0.0 {
            for c in 0..3 {
                if self.cut_walls {
                    self.cut_visc[c].ghosts(&self.grid, c, &self.u[c], &mut self.ghost[c]);
                } else {
                    self.update_ghosts(c);
                }
            }
        }
        if nu == 0.0 || implicit {
            self.add_body_force(dt);
        }
        if nu > 0.0 {
            for c in 0..3 {
                let set = &self.faces[c];
                let cut = self.cut_walls.then_some(&self.cut_visc[c]);
                if implicit {
                    let op = cut.map_or_else(|| Operator::of(set), |v| v.operator(set));
                    stats.viscosity_iterations += viscosity::implicit(
                        op,
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
                    match cut {
                        Some(v) => v.explicit(
                            set,
                            &self.u[c],
                            &self.ghost[c],
                            a as f32,
                            &mut self.compact[c],
                        ),
                        None => viscosity::explicit(
                            set,
                            &self.u[c],
                            &self.ghost[c],
                            a as f32,
                            &mut self.compact[c],
                            wide,
                        ),
                    }
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
}
