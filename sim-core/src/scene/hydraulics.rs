//! The hydraulics stage: the cavity's pressure and volume and the frame's flows, from the scene's
//! own [`HydraulicModel`] (stepped with the rig's valves and pump, the offline runner) or from the
//! newest state of another loop (the daemon's 1 kHz loop).

use std::time::Instant;

use super::counters::StageCounters;
use super::types::{FrameFlows, HydraulicsInput};
use crate::hydraulics::{HydraulicInputs, HydraulicModel, HydraulicState};

/// Hydraulic figures at the end of the previous frame.
#[derive(Debug, Clone, Copy)]
struct HydraulicMark {
    time_s: f64,
    pressure_pa: f64,
    volume_m3: f64,
    inflow_m3: f64,
    outflow_m3: f64,
    lost_m3: f64,
}

impl HydraulicMark {
    fn of(h: &HydraulicState) -> Self {
        let t = &h.totals;
        Self {
            time_s: h.time_s,
            pressure_pa: h.cavity_pressure_pa,
            volume_m3: h.cavity_volume_m3,
            inflow_m3: t.inflow_m3,
            outflow_m3: t.outflow_m3,
            lost_m3: t.leak_m3 + t.absorbed_m3 + t.perforation_m3,
        }
    }
}

/// The hydraulics as the scene follows them.
pub struct HydraulicStage {
    model: HydraulicModel,
    state: HydraulicState,
    last: Option<HydraulicMark>,
}

impl HydraulicStage {
    /// The stage around the scene's own model (its state is the model's until another loop's is
    /// followed).
    pub fn new(model: HydraulicModel) -> Self {
        Self {
            state: *model.state(),
            model,
            last: None,
        }
    }

    /// The state the last step followed.
    pub fn state(&self) -> &HydraulicState {
        &self.state
    }

    /// The scene's own model (stepped under [`HydraulicsInput::Own`]).
    pub fn model_mut(&mut self) -> &mut HydraulicModel {
        &mut self.model
    }

    /// Steps the own model by `dt_s` with `rig` (in 1 ms substeps, the daemon's tick) or takes
    /// another loop's state, as `source` says; returns the frame's flows (the flux the fluid's
    /// ports and walls must carry).
    pub fn step(
        &mut self,
        rig: &HydraulicInputs,
        source: HydraulicsInput<'_>,
        dt_s: f64,
        counters: &mut StageCounters,
    ) -> FrameFlows {
        let t = Instant::now();
        match source {
            HydraulicsInput::Own => {
                // The daemon's 1 kHz tick: the same substeps offline.
                let n = (dt_s / 1e-3).ceil().max(1.0) as usize;
                for _ in 0..n {
                    self.model.step(rig, dt_s / n as f64);
                }
                self.state = *self.model.state();
                counters.present = true;
                counters.ran_since(t);
            }
            HydraulicsInput::External(state) => {
                self.state = *state;
                counters.skipped();
            }
        }
        let now = HydraulicMark::of(&self.state);
        let flows = self.frame_flows(now, dt_s);
        self.last = Some(now);
        flows
    }

    /// Frame-mean flows from the cumulative totals, and `dp/dt`. The first frame, a new procedure
    /// or a zero `dt` give the instantaneous flows.
    fn frame_flows(&self, now: HydraulicMark, dt_s: f64) -> FrameFlows {
        let f = &self.state.flows;
        let volume_m3 = now.volume_m3;
        match self.last {
            Some(prev) if now.time_s > prev.time_s && now.inflow_m3 >= prev.inflow_m3 => {
                let dt = now.time_s - prev.time_s;
                FrameFlows {
                    inflow_m3_per_s: (now.inflow_m3 - prev.inflow_m3) / dt,
                    outflow_m3_per_s: (now.outflow_m3 - prev.outflow_m3) / dt,
                    losses_m3_per_s: (now.lost_m3 - prev.lost_m3) / dt,
                    dvdt_m3_per_s: (now.volume_m3 - prev.volume_m3) / dt,
                    dpdt_pa_per_s: (now.pressure_pa - prev.pressure_pa) / dt,
                    volume_m3,
                }
            }
            // The external model did not advance: nothing flowed.
            Some(prev) if dt_s > 0.0 && now.time_s == prev.time_s => FrameFlows {
                volume_m3,
                ..FrameFlows::default()
            },
            _ => FrameFlows {
                inflow_m3_per_s: f.inflow_m3_per_s,
                outflow_m3_per_s: f.outflow_m3_per_s,
                losses_m3_per_s: f.leak_m3_per_s + f.absorption_m3_per_s + f.perforation_m3_per_s,
                dvdt_m3_per_s: f.net_m3_per_s(),
                dpdt_pa_per_s: 0.0,
                volume_m3,
            },
        }
    }
}
