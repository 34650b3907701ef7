//! The paper's Table 1 operating points on the benchmark cavity ([`super::analytic_cavity::uterine_cavity`]): our solver and the
//! paper-class baseline side by side.

use std::time::Instant;

use serde::Serialize;

use super::analytic_cavity::{ellipsoid_cavity, uterine_cavity};
use super::{FluidError, FluidParams, FluidSolver, ProjectionMethod};
use crate::fork_join::{cpu_time_ns, CpuClock};

/// The paper's voxel sizes (m).
pub const PAPER_VOXELS_M: [f64; 5] = [0.0006, 0.0009, 0.0012, 0.0015, 0.0018];
/// The paper's fluid-voxel counts at those sizes.
pub const PAPER_FLUID_VOXELS: [usize; 5] = [35179, 9528, 3813, 1818, 969];
/// The paper's CPU time per step (ms, no vortices, 3 GHz PC, 2005).
pub const PAPER_MS: [f64; 5] = [100.0, 26.0, 10.0, 5.0, 3.0];

/// One row: one voxel size, one projection method.
#[derive(Clone, Debug, Serialize)]
pub struct BenchRow {
    /// Voxel edge (m).
    pub voxel_m: f64,
    /// Projection method.
    pub method: ProjectionMethod,
    /// Voxels in the grid.
    pub voxels_total: usize,
    /// Fluid voxels.
    pub fluid_voxels: usize,
    /// Steps timed.
    pub steps: usize,
    /// Wall time per step (ms): mean, and standard error of the mean.
    pub ms_mean: f64,
    /// Standard error of the mean (ms).
    pub ms_sem: f64,
    /// Median (ms).
    pub ms_median: f64,
    /// 99th percentile (ms).
    pub ms_p99: f64,
    /// Every timed step's wall time (ms), to pool runs.
    #[serde(skip)]
    pub step_ms: Vec<f64>,
    /// CPU time per timed step of the whole process (every thread: the stepping thread, the
    /// fork-join helper, pool threads; their spinning included), ms, from
    /// `CLOCK_PROCESS_CPUTIME_ID` read just before and after the timed steps.
    pub cpu_ms_per_step: f64,
    /// CPU time per timed step of the stepping thread alone (`CLOCK_THREAD_CPUTIME_ID`), ms.
    pub caller_cpu_ms_per_step: f64,
    /// Projection share of the mean (ms).
    pub project_ms_mean: f64,
    /// Advection share of the mean (ms): centred velocity, extrapolation, the semi-Lagrangian (and
    /// MacCormack) passes.
    pub advect_ms_mean: f64,
    /// Body force and viscosity share of the mean (ms).
    pub diffuse_ms_mean: f64,
    /// The rest of the step (ms): boundary values, topology, substep bookkeeping.
    pub other_ms_mean: f64,
    /// Projection iterations per step (mean).
    pub iterations_mean: f64,
    /// Mean over steps of `max |div u| h / U` after projection.
    pub div_rel_mean: f64,
    /// Worst `max |div u| h / U` after projection.
    pub div_rel_max: f64,
}

/// Benchmark geometry.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Cavity {
    /// [`uterine_cavity`]: matches the paper's fluid-cell counts.
    #[default]
    Uterine,
    /// [`ellipsoid_cavity`]: the earlier analytic cavity (for comparison with older figures).
    Ellipsoid,
}

/// Runs `warmup + steps` steps of the uterine cavity at `voxel_m` with the jet at `jet_m_s` and
/// `dt_s`.
pub fn bench_cavity(
    voxel_m: f64,
    jet_m_s: f32,
    dt_s: f64,
    warmup: usize,
    steps: usize,
    params: FluidParams,
) -> Result<BenchRow, FluidError> {
    bench_shape(
        Cavity::Uterine,
        voxel_m,
        jet_m_s,
        dt_s,
        warmup,
        steps,
        params,
    )
}

/// As [`bench_cavity`] on the chosen geometry.
pub fn bench_shape(
    cavity: Cavity,
    voxel_m: f64,
    jet_m_s: f32,
    dt_s: f64,
    warmup: usize,
    steps: usize,
    params: FluidParams,
) -> Result<BenchRow, FluidError> {
    let grid = match cavity {
        Cavity::Uterine => uterine_cavity(voxel_m, jet_m_s)?,
        Cavity::Ellipsoid => ellipsoid_cavity(voxel_m, jet_m_s)?,
    };
    let voxels_total = grid.cell_count();
    let method = params.projection;
    let mut s = FluidSolver::new(grid, params)?;
    for _ in 0..warmup {
        s.step(dt_s)?;
    }
    let mut ms = Vec::with_capacity(steps);
    let (process0, thread0) = (cpu_s(CpuClock::Process), cpu_s(CpuClock::Thread));
    let (mut proj, mut adv, mut its, mut div, mut divmax) = (0.0, 0.0, 0usize, 0.0, 0.0f64);
    let (mut diffuse, mut total) = (0.0, 0.0);
    for _ in 0..steps {
        let t = Instant::now();
        let st = s.step(dt_s)?;
        ms.push(t.elapsed().as_secs_f64() * 1e3);
        proj += st.project_ms;
        adv += st.advect_ms;
        diffuse += st.diffuse_ms;
        total += st.total_ms;
        its += st.projection_iterations;
        div += st.max_div_rel;
        divmax = divmax.max(st.max_div_rel);
    }
    let (process1, thread1) = (cpu_s(CpuClock::Process), cpu_s(CpuClock::Thread));
    let n = steps.max(1) as f64;
    let times = StepTimes::of(&ms);
    Ok(BenchRow {
        voxel_m,
        method,
        voxels_total,
        fluid_voxels: s.fluid_cells(),
        steps,
        ms_mean: times.mean,
        ms_sem: times.sem,
        ms_median: times.median,
        ms_p99: times.p99,
        step_ms: ms,
        cpu_ms_per_step: (process1 - process0) * 1e3 / n,
        caller_cpu_ms_per_step: (thread1 - thread0) * 1e3 / n,
        project_ms_mean: proj / n,
        advect_ms_mean: adv / n,
        diffuse_ms_mean: diffuse / n,
        other_ms_mean: (total - adv - diffuse - proj) / n,
        iterations_mean: its as f64 / n,
        div_rel_mean: div / n,
        div_rel_max: divmax,
    })
}

/// Mean, standard error of the mean, median and 99th percentile (nearest rank) of step times.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct StepTimes {
    /// Steps.
    pub count: usize,
    /// Mean (ms).
    pub mean: f64,
    /// Standard error of the mean (ms).
    pub sem: f64,
    /// Median (ms; the mean of the two middle steps of an even count).
    pub median: f64,
    /// 99th percentile (ms; nearest rank).
    pub p99: f64,
}

impl StepTimes {
    /// The figures of the step times `ms` (all zero for none).
    pub fn of(ms: &[f64]) -> StepTimes {
        let count = ms.len();
        if count == 0 {
            return StepTimes::default();
        }
        let n = count as f64;
        let mean = ms.iter().sum::<f64>() / n;
        let var = ms.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
        let mut sorted = ms.to_vec();
        sorted.sort_by(|a, b| a.total_cmp(b));
        let median = if count % 2 == 1 {
            sorted[count / 2]
        } else {
            0.5 * (sorted[count / 2 - 1] + sorted[count / 2])
        };
        let p99 = sorted[((n * 0.99).ceil() as usize).clamp(1, count) - 1];
        StepTimes {
            count,
            mean,
            sem: (var / n).sqrt(),
            median,
            p99,
        }
    }
}

/// CPU time consumed so far on `clock`, s (nanosecond resolution; NaN where unavailable).
fn cpu_s(clock: CpuClock) -> f64 {
    cpu_time_ns(clock).map_or(f64::NAN, |ns| ns as f64 * 1e-9)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn step_times_of_known_samples() {
        let t = StepTimes::of(&[4.0, 1.0, 3.0, 2.0]);
        assert_eq!((t.count, t.mean, t.median, t.p99), (4, 2.5, 2.5, 4.0));
        // Sample variance 5/3, over 4 steps.
        assert!((t.sem - (5.0f64 / 3.0 / 4.0).sqrt()).abs() < 1e-12);
        let t = StepTimes::of(&(1..=200).map(f64::from).collect::<Vec<_>>());
        assert_eq!((t.median, t.p99), (100.5, 198.0));
        assert_eq!(StepTimes::of(&[7.0]).p99, 7.0);
        assert_eq!(StepTimes::of(&[]), StepTimes::default());
    }
}
