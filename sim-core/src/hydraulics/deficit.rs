//! The fluid deficit: staged warnings, the deficit-rate alarm, overpressure and the terminated latch.
//!
//! The deficit itself is accumulated by the model from the step's lost volumes (absorbed, through a
//! perforation, and the uncollected part of the cervical leak), each `>= 0`, so it can only grow.
//! Only [`DeficitMonitor::reset`] (a new procedure) sets it back to zero.

use serde::{Deserialize, Serialize};

use super::params::DeficitParams;
use crate::units::{ml_per_min_to_m3_per_s, ml_to_m3, mmhg_to_pa};

/// The monitor's state; also what the procedure record persists.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
pub struct DeficitStatus {
    /// Fluid deficit, m^3 (never decreases within a procedure).
    pub deficit_m3: f64,
    /// Exponentially averaged deficit rate, m^3/s.
    pub rate_m3_per_s: f64,
    /// The active limit, m^3.
    pub limit_m3: f64,
    /// Number of warning stages reached (0 = none).
    pub warning_stage: u8,
    /// Rate alarm active.
    pub rate_alarm: bool,
    /// Limit reached; latched until a new procedure.
    pub terminated: bool,
    /// Procedure time (s) at which the limit was reached.
    pub terminated_at_s: Option<f64>,
    /// Cavity pressure above the overpressure threshold (not latched).
    pub overpressure: bool,
}

impl DeficitStatus {
    /// Deficit as a fraction of the limit.
    pub fn fraction_of_limit(&self) -> f64 {
        if self.limit_m3 > 0.0 {
            self.deficit_m3 / self.limit_m3
        } else {
            0.0
        }
    }

    /// The deficit reached the limit (the step that does so terminates the procedure).
    pub fn limit_reached(&self) -> bool {
        self.fraction_of_limit() >= 1.0
    }
}

/// Watches the deficit and raises the alarms.
#[derive(Debug, Clone, PartialEq)]
pub struct DeficitMonitor {
    params: DeficitParams,
    status: DeficitStatus,
}

impl DeficitMonitor {
    /// A monitor at zero deficit.
    pub fn new(params: DeficitParams) -> Self {
        let status = DeficitStatus {
            limit_m3: ml_to_m3(params.limit_ml()),
            ..DeficitStatus::default()
        };
        Self { params, status }
    }

    /// Resumes from a persisted status; the limit comes from the current parameters, the deficit
    /// and the latches from the record (a restart never clears them).
    pub fn restore(params: DeficitParams, saved: DeficitStatus) -> Self {
        let mut monitor = Self::new(params);
        let deficit = if saved.deficit_m3.is_finite() {
            saved.deficit_m3.max(0.0)
        } else {
            0.0
        };
        monitor.status.deficit_m3 = deficit;
        monitor.status.rate_m3_per_s = if saved.rate_m3_per_s.is_finite() {
            saved.rate_m3_per_s.max(0.0)
        } else {
            0.0
        };
        // A record written under more stages than are configured now keeps only those.
        let configured = u8::try_from(monitor.params.warning_fractions.len()).unwrap_or(u8::MAX);
        monitor.status.warning_stage = saved.warning_stage.min(configured);
        monitor.status.rate_alarm = saved.rate_alarm;
        monitor.status.terminated = saved.terminated;
        monitor.status.terminated_at_s = saved.terminated_at_s;
        monitor.apply_thresholds(saved.terminated_at_s.unwrap_or(0.0));
        monitor
    }

    /// Back to zero: a new procedure.
    pub fn reset(&mut self) {
        *self = Self::new(self.params.clone());
    }

    /// The current status.
    pub fn status(&self) -> &DeficitStatus {
        &self.status
    }

    /// Adds a step's lost volume (m^3, clamped to `>= 0`) over `dt_s`, at cavity pressure
    /// `pressure_pa`, at procedure time `time_s`.
    pub fn update(&mut self, increment_m3: f64, dt_s: f64, pressure_pa: f64, time_s: f64) {
        let increment = if increment_m3.is_finite() {
            increment_m3.max(0.0)
        } else {
            0.0
        };
        self.status.deficit_m3 += increment;
        if dt_s > 0.0 && dt_s.is_finite() {
            // Exact update of the first-order filter dr/dt = (rate - r) / tau for a rate constant
            // over the step: stable for any dt.
            let instant_rate = increment / dt_s;
            let alpha = -(-dt_s / self.params.rate_time_constant_s).exp_m1();
            self.status.rate_m3_per_s += alpha * (instant_rate - self.status.rate_m3_per_s);
        }
        let threshold = ml_per_min_to_m3_per_s(self.params.rate_alarm_ml_per_min);
        if self.status.rate_m3_per_s >= threshold {
            self.status.rate_alarm = true;
        } else if self.status.rate_m3_per_s < threshold * self.params.rate_alarm_clear_fraction {
            self.status.rate_alarm = false;
        }
        self.status.overpressure = pressure_pa > mmhg_to_pa(self.params.overpressure_mmhg);
        self.apply_thresholds(time_s);
    }

    fn apply_thresholds(&mut self, time_s: f64) {
        let fraction = self.status.fraction_of_limit();
        let reached = self
            .params
            .warning_fractions
            .iter()
            .filter(|&&w| fraction >= w)
            .count() as u8;
        self.status.warning_stage = self.status.warning_stage.max(reached);
        if self.status.limit_reached() && !self.status.terminated {
            self.status.terminated = true;
            self.status.terminated_at_s = Some(time_s);
        }
    }

    /// Whether the pump must be stopped (terminated and `stop_pump_when_terminated`).
    pub fn pump_stopped(&self) -> bool {
        self.status.terminated && self.params.stop_pump_when_terminated
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::units::m3_to_ml;

    fn params() -> DeficitParams {
        DeficitParams {
            limit: super::super::params::DeficitLimit::Custom,
            custom_limit_ml: 1000.0,
            warning_fractions: vec![0.5, 0.75, 0.9],
            rate_alarm_ml_per_min: 100.0,
            rate_time_constant_s: 4.0,
            rate_alarm_clear_fraction: 0.8,
            overpressure_mmhg: 120.0,
            stop_pump_when_terminated: true,
        }
    }

    /// Feeds a constant deficit rate (ml/min) and returns the times (s) at which each stage, the
    /// rate alarm and termination first appeared.
    fn run(rate_ml_per_min: f64, dt: f64, seconds: f64) -> (Vec<f64>, Option<f64>, Option<f64>) {
        let mut m = DeficitMonitor::new(params());
        let inc = ml_per_min_to_m3_per_s(rate_ml_per_min) * dt;
        let mut stages = vec![];
        let mut rate_at = None;
        let steps = (seconds / dt).round() as usize;
        for i in 1..=steps {
            let t = i as f64 * dt;
            m.update(inc, dt, 0.0, t);
            let s = m.status();
            while stages.len() < s.warning_stage as usize {
                stages.push(t);
            }
            if s.rate_alarm && rate_at.is_none() {
                rate_at = Some(t);
            }
        }
        (stages, rate_at, m.status().terminated_at_s)
    }

    #[test]
    fn warnings_and_termination_fire_at_the_configured_fractions() {
        // 60 ml/min -> 1 ml/s: 50 % of 1000 ml at 500 s, 75 % at 750 s, 90 % at 900 s, 100 % at 1000 s.
        let dt = 0.01;
        let (stages, rate_at, terminated_at) = run(60.0, dt, 1100.0);
        for (got, want) in stages.iter().zip([500.0, 750.0, 900.0]) {
            assert!(
                (got - want).abs() <= 2.0 * dt,
                "stage at {got}, want {want}"
            );
        }
        assert_eq!(stages.len(), 3);
        assert_eq!(
            rate_at, None,
            "60 ml/min is below the 100 ml/min rate alarm"
        );
        let t = terminated_at.expect("terminated");
        assert!((t - 1000.0).abs() <= 2.0 * dt, "terminated at {t}");
    }

    #[test]
    fn rate_alarm_fires_after_the_filter_delay() {
        // Constant rate R from zero: r(t) = R (1 - e^{-t/tau}) crosses the threshold T at
        // t = -tau ln(1 - T/R); R = 150, T = 100, tau = 4 -> 4 ln 3 = 4.394 s.
        let dt = 0.001;
        let (_, rate_at, _) = run(150.0, dt, 10.0);
        let t = rate_at.expect("rate alarm");
        let want = 4.0 * 3f64.ln();
        assert!(
            (t - want).abs() <= 2.0 * dt,
            "rate alarm at {t}, want {want}"
        );
        // The filter is exact for piecewise-constant rates, so a coarse step agrees too.
        let (_, rate_at, _) = run(150.0, 0.25, 10.0);
        assert!(
            (rate_at.unwrap() - 4.5).abs() < 1e-9,
            "first step after {want}"
        );
    }

    #[test]
    fn rate_alarm_clears_with_hysteresis() {
        let mut m = DeficitMonitor::new(params());
        let dt = 0.01;
        let rate = |ml_min: f64| ml_per_min_to_m3_per_s(ml_min) * dt;
        for _ in 0..3000 {
            m.update(rate(200.0), dt, 0.0, 0.0);
        }
        assert!(m.status().rate_alarm);
        // Settle at 90 ml/min: below the alarm (100) but above the clear level (80): stays on.
        for _ in 0..6000 {
            m.update(rate(90.0), dt, 0.0, 0.0);
        }
        assert!(m.status().rate_alarm);
        for _ in 0..6000 {
            m.update(rate(70.0), dt, 0.0, 0.0);
        }
        assert!(!m.status().rate_alarm);
    }

    #[test]
    fn termination_latches_until_reset_and_the_deficit_never_decreases() {
        let mut m = DeficitMonitor::new(params());
        m.update(ml_to_m3(1000.0), 1.0, 0.0, 12.0);
        assert!(m.status().terminated && m.pump_stopped());
        assert_eq!(m.status().terminated_at_s, Some(12.0));
        let before = m.status().deficit_m3;
        for bad in [-1.0, f64::NAN, f64::NEG_INFINITY, f64::INFINITY] {
            m.update(bad, 1.0, 0.0, 13.0);
            assert!(m.status().deficit_m3 >= before);
            assert!(m.status().deficit_m3.is_finite());
        }
        assert!(m.status().terminated);
        assert_eq!(m.status().warning_stage, 3);
        m.reset();
        assert_eq!(m.status().deficit_m3, 0.0);
        assert!(!m.status().terminated);
        assert_eq!(m.status().warning_stage, 0);
        assert!(!m.status().limit_reached());
    }

    #[test]
    fn restore_keeps_the_latches_and_no_more_stages_than_configured() {
        let mut m = DeficitMonitor::new(params());
        m.update(ml_to_m3(800.0), 1.0, mmhg_to_pa(130.0), 5.0);
        let s = *m.status();
        assert!(s.warning_stage == 2 && s.rate_alarm && s.overpressure && !s.limit_reached());
        let r = DeficitMonitor::restore(params(), s);
        assert!((m3_to_ml(r.status().deficit_m3) - 800.0).abs() < 1e-9);
        assert_eq!(r.status().warning_stage, 2);
        assert!(r.status().rate_alarm);
        // Restored under a configuration with one stage: stage 1, not a stage that no longer exists.
        let one_stage = DeficitParams {
            warning_fractions: vec![0.95],
            ..params()
        };
        assert_eq!(
            DeficitMonitor::restore(one_stage, s).status().warning_stage,
            1
        );
    }
}
