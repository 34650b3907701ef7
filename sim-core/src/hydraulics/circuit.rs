//! The lumped circuit for one time step: every flow as a function of the cavity pressure.
//!
//! ```text
//!  pump (p_set, Q_max) --G_in--> cavity (p, V(p)) --G_out--> suction (p_suc)
//!                                   |--G_leak--> cervix (atmosphere, 0)
//!                                   |--G_abs---> circulation above p_abs (mean arterial pressure)
//!                                   '--G_perf--> peritoneum (0), only once perforated
//!
//!  Q_in   = clamp(G_in (p_set - p), 0, Q_max)     roller pump: never runs backwards
//!  Q_out  = max(G_out (p - p_suc), 0)             the canister never flows back
//!  Q_leak = G_leak max(p, 0)
//!  Q_abs  = G_abs  max(p - p_abs, 0)
//!  Q_perf = G_perf max(p, 0)
//! ```
//! Gauge pressures. Every flow is piecewise linear and the net inflow
//! `q(p) = Q_in - Q_out - Q_leak - Q_abs - Q_perf` is non-increasing in `p`, which makes the implicit
//! volume balance of [`super::model`] a monotone scalar equation with exactly one root.

/// Conductances (m^3/(s Pa)) and pressures (Pa) of the circuit, frozen for one step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Circuit {
    /// Pump set pressure, Pa.
    pub pump_pressure_pa: f64,
    /// Pump flow limit, m^3/s (0 when the pump is stopped).
    pub pump_max_flow_m3_per_s: f64,
    /// Inflow line (tubing and valve in series).
    pub inflow_conductance: f64,
    /// Outflow line (valve and tubing in series).
    pub outflow_conductance: f64,
    /// Suction gauge pressure, Pa.
    pub suction_pressure_pa: f64,
    /// Cervical leak.
    pub leak_conductance: f64,
    /// Absorption above the threshold.
    pub absorption_conductance: f64,
    /// Absorption threshold, Pa.
    pub absorption_threshold_pa: f64,
    /// Perforation leak (0 while intact).
    pub perforation_conductance: f64,
}

/// The flows at one cavity pressure, m^3/s, each >= 0 in its own direction.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Flows {
    /// Pump -> cavity.
    pub inflow_m3_per_s: f64,
    /// Cavity -> suction canister.
    pub outflow_m3_per_s: f64,
    /// Cavity -> cervix (out of the body).
    pub leak_m3_per_s: f64,
    /// Cavity -> circulation.
    pub absorption_m3_per_s: f64,
    /// Cavity -> peritoneum.
    pub perforation_m3_per_s: f64,
}

impl Flows {
    /// Net flow into the cavity, m^3/s.
    pub fn net_m3_per_s(&self) -> f64 {
        self.inflow_m3_per_s
            - self.outflow_m3_per_s
            - self.leak_m3_per_s
            - self.absorption_m3_per_s
            - self.perforation_m3_per_s
    }
}

impl Circuit {
    /// All flows at cavity pressure `p`.
    pub fn flows(&self, pressure_pa: f64) -> Flows {
        let p = pressure_pa;
        Flows {
            inflow_m3_per_s: (self.inflow_conductance * (self.pump_pressure_pa - p))
                .clamp(0.0, self.pump_max_flow_m3_per_s),
            outflow_m3_per_s: (self.outflow_conductance * (p - self.suction_pressure_pa)).max(0.0),
            leak_m3_per_s: self.leak_conductance * p.max(0.0),
            absorption_m3_per_s: self.absorption_conductance
                * (p - self.absorption_threshold_pa).max(0.0),
            perforation_m3_per_s: self.perforation_conductance * p.max(0.0),
        }
    }

    /// Net inflow `q(p)` and `-dq/dp` (the total conductance seen by the cavity, >= 0). At a kink
    /// the conductance of the side of higher pressure is taken.
    pub fn net_inflow_and_conductance(&self, pressure_pa: f64) -> (f64, f64) {
        let p = pressure_pa;
        let flows = self.flows(p);
        let mut g = 0.0;
        let q_in_free = self.inflow_conductance * (self.pump_pressure_pa - p);
        if q_in_free > 0.0 && q_in_free < self.pump_max_flow_m3_per_s {
            g += self.inflow_conductance;
        }
        if p >= self.suction_pressure_pa {
            g += self.outflow_conductance;
        }
        if p >= 0.0 {
            g += self.leak_conductance + self.perforation_conductance;
        }
        if p >= self.absorption_threshold_pa {
            g += self.absorption_conductance;
        }
        (flows.net_m3_per_s(), g)
    }

    /// The steady-state cavity pressure (`q(p) = 0`), solved exactly on the linear pieces, or `None`
    /// when it is not unique (e.g. everything shut: the cavity keeps whatever it holds).
    pub fn steady_state_pressure_pa(&self) -> Option<f64> {
        let q = |p: f64| self.flows(p).net_m3_per_s();
        let mut x = vec![
            0.0,
            self.suction_pressure_pa,
            self.absorption_threshold_pa,
            self.pump_pressure_pa,
        ];
        if self.inflow_conductance > 0.0 {
            x.push(self.pump_pressure_pa - self.pump_max_flow_m3_per_s / self.inflow_conductance);
        }
        x.retain(|v| v.is_finite());
        x.sort_by(f64::total_cmp);
        x.dedup();
        let first = x[0] - 1000.0;
        let last = x[x.len() - 1] + 1000.0;
        x.insert(0, first);
        x.push(last);
        // A zero set wider than a point: no unique steady state.
        let n = x.len();
        if x.windows(2).any(|w| q(w[0]) == 0.0 && q(w[1]) == 0.0) {
            return None;
        }
        let q0 = q(x[0]);
        if q0 < 0.0 {
            let slope = (q(x[1]) - q0) / (x[1] - x[0]);
            return (slope < 0.0).then(|| x[0] - q0 / slope);
        }
        let qn = q(x[n - 1]);
        if qn > 0.0 {
            let slope = (qn - q(x[n - 2])) / (x[n - 1] - x[n - 2]);
            return (slope < 0.0).then(|| x[n - 1] - qn / slope);
        }
        x.windows(2).find_map(|w| {
            let (qa, qb) = (q(w[0]), q(w[1]));
            (qa >= 0.0 && qb <= 0.0).then(|| {
                if qa == qb {
                    w[0]
                } else {
                    w[0] + qa * (w[1] - w[0]) / (qa - qb)
                }
            })
        })
    }
}
