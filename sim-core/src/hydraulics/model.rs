//! The hydraulic model: implicit time stepping of the cavity volume balance, cumulative volumes,
//! port velocities and the deficit monitor.
//!
//! Each step solves the backward-Euler volume balance for the new cavity pressure `p`:
//!
//! ```text
//! F(p) = V(p) - V_n - dt q(p) = 0
//! ```
//! where `V(p)` is the cavity's pressure-volume curve and `q(p)` the net inflow of the
//! [`Circuit`]. `F` is strictly increasing (`V` increasing, `q` non-increasing), so the root is unique
//! and a safeguarded Newton iteration on a bracket finds it for any step size: no stiffness limit.
//! The step's volumes are then booked as `dt * Q_k(p)` for every flow `k` and the cavity volume as
//! `V_{n+1} = V_n + dt q(p)`, so the mass balance closes exactly (up to rounding) by construction,
//! whatever the solver tolerance.

use super::circuit::{Circuit, Flows};
use super::compliance::CavityCompliance;
use super::deficit::{DeficitMonitor, DeficitStatus};
use super::params::{conductance_si, HydraulicParams, ParamsError};
use super::procedure::{CumulativeVolumes, ProcedureInfo};
use super::solve::{expand_bracket, solve_bracketed};
use super::valve::sanitize_opening;
use crate::units::{ml_per_min_to_m3_per_s, mmhg_to_pa};

/// What the model reads each step (from the rig, through calibration, plus case events).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct HydraulicInputs {
    /// Inflow valve opening in [0, 1]; clamped, NaN counts as shut.
    pub valve_in_opening: f64,
    /// Outflow valve opening in [0, 1]; clamped, NaN counts as shut.
    pub valve_out_opening: f64,
    /// Pump set pressure, Pa; clamped to [0, `pump.max_pressure_mmhg`], NaN counts as 0.
    pub pump_set_pressure_pa: f64,
    /// The case's perforation event: once true, the perforation stays until a new procedure.
    pub perforation: bool,
}

/// The model's state after a step.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct HydraulicState {
    /// Procedure time, s (sum of accepted steps).
    pub time_s: f64,
    /// Cavity gauge pressure, Pa.
    pub cavity_pressure_pa: f64,
    /// Cavity volume, m^3.
    pub cavity_volume_m3: f64,
    /// The flows during the last step.
    pub flows: Flows,
    /// Mean velocity at the scope's inflow port (out of the scope), m/s.
    pub inflow_port_velocity_m_per_s: f64,
    /// Mean velocity at the scope's outflow port (into the scope), m/s.
    pub outflow_port_velocity_m_per_s: f64,
    /// The pump delivered its maximum flow during the last step.
    pub pump_flow_limited: bool,
    /// The pump was stopped because the procedure is terminated.
    pub pump_stopped: bool,
    /// A perforation is present.
    pub perforated: bool,
    /// Cavity volume when the procedure started, m^3.
    pub initial_cavity_volume_m3: f64,
    /// Cumulative volumes since the procedure started.
    pub totals: CumulativeVolumes,
    /// Deficit, rate and alarms.
    pub deficit: DeficitStatus,
}

impl HydraulicState {
    /// The deficit from its definition: fluid in - fluid collected - change of cavity volume, m^3.
    /// Equals `deficit.deficit_m3` (accumulated from the lost volumes) up to rounding.
    pub fn deficit_by_balance_m3(&self) -> f64 {
        self.totals.inflow_m3
            - self.totals.collected_m3()
            - (self.cavity_volume_m3 - self.initial_cavity_volume_m3)
    }
}

/// Counters of the model's work (rapier-style): what ran and how hard the solver worked.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct HydraulicCounters {
    /// Steps taken.
    pub steps: u64,
    /// Steps refused for a non-finite or non-positive `dt` (state unchanged).
    pub rejected_steps: u64,
    /// Input values that were NaN or out of range and were clamped.
    pub sanitized_inputs: u64,
    /// Total solver iterations.
    pub solver_iterations: u64,
    /// Most iterations in one step.
    pub max_solver_iterations: u32,
    /// Solver steps that fell back to bisection.
    pub bisections: u64,
    /// Steps where the solver hit its iteration limit or found no bracket (best estimate kept).
    pub unconverged_steps: u64,
}

/// The lumped hydraulic model of pump, lines, cavity, leak, absorption and perforation.
#[derive(Debug)]
pub struct HydraulicModel {
    params: HydraulicParams,
    compliance: Box<dyn CavityCompliance>,
    procedure: ProcedureInfo,
    state: HydraulicState,
    monitor: DeficitMonitor,
    counters: HydraulicCounters,
}

impl HydraulicModel {
    /// A model with the analytic compliance of `params.cavity`, at `cavity.initial_pressure_mmhg`.
    pub fn new(params: HydraulicParams) -> Result<Self, ParamsError> {
        let compliance = Box::new(params.cavity.compliance());
        Self::with_compliance(params, compliance)
    }

    /// A model with a caller-supplied compliance (e.g. the atlas P-V curve).
    pub fn with_compliance(
        params: HydraulicParams,
        compliance: Box<dyn CavityCompliance>,
    ) -> Result<Self, ParamsError> {
        params.validate("hydraulic parameters")?;
        let p0 = mmhg_to_pa(params.cavity.initial_pressure_mmhg);
        let v0 = compliance.volume_m3(p0);
        if !v0.is_finite() {
            return Err(ParamsError::Invalid {
                origin: "cavity compliance".into(),
                key: "cavity.initial_pressure_mmhg",
                value: params.cavity.initial_pressure_mmhg.to_string(),
                expected: "a pressure at which the compliance curve gives a finite volume",
            });
        }
        let monitor = DeficitMonitor::new(params.deficit.clone());
        let state = HydraulicState {
            cavity_pressure_pa: p0,
            cavity_volume_m3: v0,
            initial_cavity_volume_m3: v0,
            deficit: *monitor.status(),
            ..HydraulicState::default()
        };
        Ok(Self {
            params,
            compliance,
            procedure: ProcedureInfo::default(),
            state,
            monitor,
            counters: HydraulicCounters::default(),
        })
    }

    /// The parameters.
    pub fn params(&self) -> &HydraulicParams {
        &self.params
    }

    /// The current state.
    pub fn state(&self) -> &HydraulicState {
        &self.state
    }

    /// The work counters.
    pub fn counters(&self) -> &HydraulicCounters {
        &self.counters
    }

    /// The current procedure.
    pub fn procedure(&self) -> ProcedureInfo {
        self.procedure
    }

    /// The compliance in use.
    pub fn compliance(&self) -> &dyn CavityCompliance {
        self.compliance.as_ref()
    }

    /// Swaps the compliance (the atlas's P-V curve once the scene has loaded it, or another
    /// scene's). The cavity keeps its *pressure*, so status never jumps: a curve that starts from
    /// another resting volume would otherwise map the cavity's volume to a pressure far from the
    /// one just published (negative, for a cavity larger at rest). Its volume becomes the new
    /// curve's volume at that pressure; the change is the model's, not fluid gained or lost, so
    /// the procedure's volume baseline moves with it and the deficit (`in - collected - change of
    /// cavity volume`) is unchanged.
    pub fn set_compliance(&mut self, compliance: Box<dyn CavityCompliance>) {
        let s = &mut self.state;
        let p = s.cavity_pressure_pa;
        let v = compliance.volume_m3(p);
        if p.is_finite() && v.is_finite() && v > 0.0 {
            s.initial_cavity_volume_m3 += v - s.cavity_volume_m3;
            s.cavity_volume_m3 = v;
        } else if let Some(p) = compliance.pressure_pa(s.cavity_volume_m3) {
            s.cavity_pressure_pa = p;
        }
        self.compliance = compliance;
    }

    /// Starts a new procedure: cumulative volumes, deficit, alarms, the terminated latch and the
    /// perforation are reset; the cavity keeps its current volume and pressure.
    pub fn start_new_procedure(&mut self, procedure: ProcedureInfo) {
        self.procedure = procedure;
        self.monitor.reset();
        let s = &mut self.state;
        s.time_s = 0.0;
        s.totals = CumulativeVolumes::default();
        s.initial_cavity_volume_m3 = s.cavity_volume_m3;
        s.perforated = false;
        s.pump_stopped = false;
        s.deficit = *self.monitor.status();
    }

    /// The circuit for the given (sanitized) inputs.
    fn circuit(&self, valve_in: f64, valve_out: f64, pump_pa: f64) -> Circuit {
        let p = &self.params;
        let pump_stopped = self.monitor.pump_stopped();
        Circuit {
            pump_pressure_pa: pump_pa,
            pump_max_flow_m3_per_s: if pump_stopped {
                0.0
            } else {
                ml_per_min_to_m3_per_s(p.pump.max_flow_ml_per_min)
            },
            inflow_conductance: p.inflow.line().conductance_m3_per_s_pa(valve_in),
            outflow_conductance: p.outflow.line().conductance_m3_per_s_pa(valve_out),
            suction_pressure_pa: mmhg_to_pa(p.outflow.suction_pressure_mmhg),
            leak_conductance: conductance_si(p.cervix.leak_conductance_ml_per_min_per_mmhg),
            absorption_conductance: conductance_si(p.absorption.conductance_ml_per_min_per_mmhg),
            absorption_threshold_pa: mmhg_to_pa(p.absorption.threshold_pressure_mmhg),
            perforation_conductance: if self.state.perforated {
                conductance_si(p.perforation.conductance_ml_per_min_per_mmhg)
            } else {
                0.0
            },
        }
    }

    /// Sanitizes the inputs, counting every value that had to be changed.
    fn sanitize(&mut self, inputs: &HydraulicInputs) -> (f64, f64, f64) {
        let max_pump_pa = mmhg_to_pa(self.params.pump.max_pressure_mmhg);
        let valve_in = sanitize_opening(inputs.valve_in_opening);
        let valve_out = sanitize_opening(inputs.valve_out_opening);
        let pump = if inputs.pump_set_pressure_pa.is_nan() {
            0.0
        } else {
            inputs.pump_set_pressure_pa.clamp(0.0, max_pump_pa)
        };
        // NaN != anything, so a NaN input counts as changed.
        #[allow(clippy::float_cmp)]
        let changed = [
            (valve_in, inputs.valve_in_opening),
            (valve_out, inputs.valve_out_opening),
            (pump, inputs.pump_set_pressure_pa),
        ]
        .iter()
        .filter(|(a, b)| a != b)
        .count();
        self.counters.sanitized_inputs += changed as u64;
        (valve_in, valve_out, pump)
    }

    /// The circuit's linearised pressure time constant at the current inputs and pressure, s:
    /// `tau = C(p) / G(p)` with `C = dV/dp` and `G = -dq/dp` (the total conductance seen by the
    /// cavity). `None` when no conductance is connected (the cavity just holds its volume).
    pub fn time_constant_s(&mut self, inputs: &HydraulicInputs) -> Option<f64> {
        let (vi, vo, pump) = self.sanitize(inputs);
        let circuit = self.circuit(vi, vo, pump);
        let p = self.state.cavity_pressure_pa;
        let (_, g) = circuit.net_inflow_and_conductance(p);
        (g > 0.0).then(|| self.compliance.compliance_m3_per_pa(p) / g)
    }

    /// The steady-state cavity pressure for constant inputs (exact, on the piecewise-linear circuit),
    /// or `None` if not unique.
    pub fn steady_state_pressure_pa(&mut self, inputs: &HydraulicInputs) -> Option<f64> {
        let (vi, vo, pump) = self.sanitize(inputs);
        let mut circuit = self.circuit(vi, vo, pump);
        if inputs.perforation {
            circuit.perforation_conductance =
                conductance_si(self.params.perforation.conductance_ml_per_min_per_mmhg);
        }
        circuit.steady_state_pressure_pa()
    }

    /// Advances the model by `dt_s` seconds. A non-finite or non-positive `dt_s` is refused (counted,
    /// state unchanged). Any inputs, any step size: the result is finite.
    pub fn step(&mut self, inputs: &HydraulicInputs, dt_s: f64) -> &HydraulicState {
        if !(dt_s.is_finite() && dt_s > 0.0) {
            self.counters.rejected_steps += 1;
            return &self.state;
        }
        let (valve_in, valve_out, pump_pa) = self.sanitize(inputs);
        if inputs.perforation {
            self.state.perforated = true;
        }
        let circuit = self.circuit(valve_in, valve_out, pump_pa);
        let v_n = self.state.cavity_volume_m3;
        let p_n = self.state.cavity_pressure_pa;
        let compliance = self.compliance.as_ref();

        // F(p) = V(p) - V_n - dt q(p): strictly increasing, one root. Bracket from the pressure range
        // the circuit can drive the cavity to, widened if the volume drifted off the curve.
        let residual = |p: f64| {
            let (q, _) = circuit.net_inflow_and_conductance(p);
            compliance.volume_m3(p) - v_n - dt_s * q
        };
        let g_sum = circuit.inflow_conductance
            + circuit.outflow_conductance
            + circuit.leak_conductance
            + circuit.absorption_conductance
            + circuit.perforation_conductance;
        let slope_estimate = compliance.compliance_m3_per_pa(p_n) + dt_s * g_sum;
        let x_tol_pa = 1e-14 * v_n.abs() / slope_estimate;
        let x_tol_pa = if x_tol_pa.is_nan() {
            1e-9
        } else {
            x_tol_pa.clamp(1e-200, 1e-9)
        };
        let lo = p_n.min(circuit.suction_pressure_pa).min(0.0);
        let hi = p_n.max(circuit.pump_pressure_pa);
        let root = expand_bracket(residual, lo, hi).map(|(lo, hi)| {
            solve_bracketed(
                |p| {
                    let (q, g) = circuit.net_inflow_and_conductance(p);
                    (
                        compliance.volume_m3(p) - v_n - dt_s * q,
                        compliance.compliance_m3_per_pa(p) + dt_s * g,
                    )
                },
                p_n,
                lo,
                hi,
                // |F| is the volume booked off the curve: keep it at rounding level, also through
                // the pressure tolerance, which dt G magnifies on huge steps.
                1e-14 * v_n.abs(),
                x_tol_pa,
                1e-15,
            )
        });
        let p = match root {
            Some(root) => {
                self.counters.solver_iterations += u64::from(root.iterations);
                self.counters.max_solver_iterations =
                    self.counters.max_solver_iterations.max(root.iterations);
                self.counters.bisections += u64::from(root.bisections);
                if !root.converged {
                    self.counters.unconverged_steps += 1;
                }
                root.x
            }
            None => {
                // Only a compliance curve breaking its contract gets here: keep the pressure.
                self.counters.unconverged_steps += 1;
                p_n
            }
        };
        let p = if p.is_finite() { p } else { p_n };
        // The exact root obeys the maximum principle (between the lowest and highest source
        // pressure, or p_n); where the curve is flat (a collapsed cavity) the root's volume
        // tolerance admits pressures far outside it (the random-input test once got -80.8 mmHg,
        // below its suction pressure): keep the pressure in the bracket, which changes the volume
        // by rounding only.
        let p = p.clamp(lo, hi);

        let flows = circuit.flows(p);
        let d_in = dt_s * flows.inflow_m3_per_s;
        let d_out = dt_s * flows.outflow_m3_per_s;
        let d_leak = dt_s * flows.leak_m3_per_s;
        let d_abs = dt_s * flows.absorption_m3_per_s;
        let d_perf = dt_s * flows.perforation_m3_per_s;
        let collected_fraction = self.params.cervix.leak_collected_fraction;
        let d_leak_collected = collected_fraction * d_leak;

        let s = &mut self.state;
        s.time_s += dt_s;
        s.cavity_pressure_pa = p;
        s.cavity_volume_m3 = v_n + (d_in - d_out - d_leak - d_abs - d_perf);
        s.flows = flows;
        s.totals.inflow_m3 += d_in;
        s.totals.outflow_m3 += d_out;
        s.totals.leak_m3 += d_leak;
        s.totals.leak_collected_m3 += d_leak_collected;
        s.totals.absorbed_m3 += d_abs;
        s.totals.perforation_m3 += d_perf;
        s.pump_flow_limited = circuit.pump_max_flow_m3_per_s > 0.0
            && flows.inflow_m3_per_s >= circuit.pump_max_flow_m3_per_s;
        let inflow_line = self.params.inflow.line();
        let outflow_line = self.params.outflow.line();
        s.inflow_port_velocity_m_per_s = flows.inflow_m3_per_s / inflow_line.port_area_m2();
        s.outflow_port_velocity_m_per_s = flows.outflow_m3_per_s / outflow_line.port_area_m2();

        let lost = d_abs + d_perf + (d_leak - d_leak_collected);
        self.monitor.update(lost, dt_s, p, s.time_s);
        s.deficit = *self.monitor.status();
        s.pump_stopped = self.monitor.pump_stopped();
        self.counters.steps += 1;
        &self.state
    }

    /// The current procedure as a record to persist (`saved_unix_ms` from the caller's clock).
    pub fn record(&self, saved_unix_ms: u64) -> super::record::ProcedureRecord {
        super::record::ProcedureRecord {
            procedure: self.procedure,
            saved_unix_ms,
            time_s: self.state.time_s,
            cavity_volume_m3: self.state.cavity_volume_m3,
            cavity_pressure_pa: self.state.cavity_pressure_pa,
            initial_cavity_volume_m3: self.state.initial_cavity_volume_m3,
            perforated: self.state.perforated,
            totals: self.state.totals,
            deficit: self.state.deficit,
        }
    }

    /// Resumes a persisted procedure: cumulative volumes, deficit, latches, perforation and cavity
    /// volume as recorded. The limit comes from the current parameters.
    pub fn restore(&mut self, record: &super::record::ProcedureRecord) {
        self.procedure = record.procedure;
        self.monitor = DeficitMonitor::restore(self.params.deficit.clone(), record.deficit);
        let s = &mut self.state;
        s.time_s = record.time_s;
        s.totals = record.totals;
        s.initial_cavity_volume_m3 = record.initial_cavity_volume_m3;
        s.perforated = record.perforated;
        s.cavity_volume_m3 = record.cavity_volume_m3;
        // The recorded pressure solved the recorded volume balance; the next step re-solves it
        // against the current compliance anyway.
        s.cavity_pressure_pa = record.cavity_pressure_pa;
        s.flows = Flows::default();
        s.deficit = *self.monitor.status();
        s.pump_stopped = self.monitor.pump_stopped();
    }
}
