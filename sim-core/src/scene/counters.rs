//! Per-stage counters: runs, skips and the time of recent runs (p50, p99), allocation-free.

use std::time::Instant;

use serde::Serialize;

/// Runs whose times are kept for the percentiles.
pub const RECENT_RUNS: usize = 512;

/// The pipeline's stages, in order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Stage {
    /// Pump, valves, cavity pressure, deficit.
    Hydraulics = 0,
    /// Atlas replay of the cavity surface.
    Deformation = 1,
    /// Cavity surface to cell states.
    Voxelize = 2,
    /// Labels of scope, ports, walls; port and wall velocities.
    Ports = 3,
    /// The fluid step.
    Fluid = 4,
    /// Rankine vortices.
    Vortices = 5,
    /// Particles and view clarity.
    Particles = 6,
}

impl Stage {
    /// Every stage in order.
    pub const ALL: [Stage; 7] = [
        Stage::Hydraulics,
        Stage::Deformation,
        Stage::Voxelize,
        Stage::Ports,
        Stage::Fluid,
        Stage::Vortices,
        Stage::Particles,
    ];
    /// Its name.
    pub fn name(self) -> &'static str {
        match self {
            Stage::Hydraulics => "hydraulics",
            Stage::Deformation => "deformation",
            Stage::Voxelize => "voxelize",
            Stage::Ports => "ports",
            Stage::Fluid => "fluid",
            Stage::Vortices => "vortices",
            Stage::Particles => "particles",
        }
    }
}

/// Counters of one stage.
#[derive(Debug, Clone)]
pub struct StageCounters {
    /// Whether the scene has this stage at all.
    pub present: bool,
    /// Times it ran.
    pub runs: u64,
    /// Times it was skipped (inputs unchanged, nothing to do, or idle).
    pub skips: u64,
    /// Whether it ran in the last step.
    pub ran_last: bool,
    /// Time of the last run, ms.
    pub last_ms: f64,
    /// Sum of run times, ms.
    pub total_ms: f64,
    recent: [f32; RECENT_RUNS],
    next: usize,
}

impl Default for StageCounters {
    fn default() -> Self {
        Self {
            present: false,
            runs: 0,
            skips: 0,
            ran_last: false,
            last_ms: 0.0,
            total_ms: 0.0,
            recent: [0.0; RECENT_RUNS],
            next: 0,
        }
    }
}

impl StageCounters {
    /// Counts a run of `ms`.
    pub fn ran(&mut self, ms: f64) {
        self.runs += 1;
        self.ran_last = true;
        self.last_ms = ms;
        self.total_ms += ms;
        self.recent[self.next % RECENT_RUNS] = ms as f32;
        self.next += 1;
    }
    /// Counts a run that started at `started`.
    pub fn ran_since(&mut self, started: Instant) {
        self.ran(started.elapsed().as_secs_f64() * 1e3);
    }
    /// Adds the time since `started` to the run just counted (work of the same run done by a
    /// second part of the stage, e.g. the voxelize stage's cut cells); nothing without a run.
    pub fn extend_last_run_since(&mut self, started: Instant) {
        if self.next == 0 || !self.ran_last {
            return;
        }
        let ms = started.elapsed().as_secs_f64() * 1e3;
        self.last_ms += ms;
        self.total_ms += ms;
        self.recent[(self.next - 1) % RECENT_RUNS] = self.last_ms as f32;
    }
    /// Counts a skip.
    pub fn skipped(&mut self) {
        self.skips += 1;
        self.ran_last = false;
    }
    /// Mean run time, ms (0 before any run).
    pub fn mean_ms(&self) -> f64 {
        if self.runs == 0 {
            0.0
        } else {
            self.total_ms / self.runs as f64
        }
    }
    /// Percentile `q` in [0, 1] of the last [`RECENT_RUNS`] run times, ms (nearest rank).
    pub fn percentile_ms(&self, q: f64) -> f64 {
        let n = self.next.min(RECENT_RUNS);
        if n == 0 {
            return 0.0;
        }
        let mut v = self.recent;
        let rank = ((q.clamp(0.0, 1.0) * n as f64).ceil() as usize).clamp(1, n);
        // A selection, not a sort: the daemon asks for every stage's p99 every scene frame.
        let (_, nth, _) = v[..n].select_nth_unstable_by(rank - 1, f32::total_cmp);
        *nth as f64
    }
    /// Median of the recent run times, ms.
    pub fn p50_ms(&self) -> f64 {
        self.percentile_ms(0.5)
    }
    /// 99th percentile of the recent run times, ms.
    pub fn p99_ms(&self) -> f64 {
        self.percentile_ms(0.99)
    }
}

/// The counters of every stage, indexed by [`Stage`].
#[derive(Debug, Clone, Default)]
pub struct Counters {
    /// One per stage.
    pub stages: [StageCounters; 7],
    /// Whole steps.
    pub step: StageCounters,
}

impl Counters {
    /// The counters of `stage`.
    pub fn get(&self, stage: Stage) -> &StageCounters {
        &self.stages[stage as usize]
    }
    /// The counters of `stage`, mutable.
    pub fn get_mut(&mut self, stage: Stage) -> &mut StageCounters {
        &mut self.stages[stage as usize]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_are_nearest_rank_over_the_recent_window() {
        let mut c = StageCounters::default();
        for i in 1..=100 {
            c.ran(i as f64);
        }
        assert_eq!(c.p50_ms(), 50.0);
        assert_eq!(c.p99_ms(), 99.0);
        assert_eq!(c.runs, 100);
        c.skipped();
        assert_eq!((c.skips, c.ran_last), (1, false));
        for _ in 0..RECENT_RUNS {
            c.ran(1.0);
        }
        assert_eq!(c.p99_ms(), 1.0);
        assert!(
            (c.mean_ms() - (5050.0 + RECENT_RUNS as f64) / (100 + RECENT_RUNS) as f64).abs() < 1e-9
        );
    }
}
