//! Hydraulics: the lumped circuit of pump, tubing, valves, cavity compliance, cervical leak,
//! absorption and perforation, and the fluid deficit with its warnings, rate alarm and terminated
//! latch. The equations, parameters and defaults are specified in `docs/hydraulics.md`.
//!
//! ```
//! use hydrometra_sim::hydraulics::{HydraulicInputs, HydraulicModel, HydraulicParams};
//! use hydrometra_sim::units::{mmhg_to_pa, pa_to_mmhg};
//!
//! let mut model = HydraulicModel::new(HydraulicParams::default())?;
//! let inputs = HydraulicInputs {
//!     valve_in_opening: 1.0,
//!     valve_out_opening: 0.5,
//!     pump_set_pressure_pa: mmhg_to_pa(100.0),
//!     perforation: false,
//! };
//! for _ in 0..5000 {
//!     model.step(&inputs, 1e-3); // the daemon's 1 kHz tick
//! }
//! let state = model.state();
//! assert!(pa_to_mmhg(state.cavity_pressure_pa) > 40.0); // distended
//! assert!(state.deficit.deficit_m3 >= 0.0);
//! # Ok::<(), hydrometra_sim::hydraulics::ParamsError>(())
//! ```

mod case;
mod circuit;
mod compliance;
mod deficit;
mod model;
mod params;
mod procedure;
mod record;
mod solve;
mod valve;

pub use case::CaseScript;
pub use circuit::{Circuit, Flows};
pub use compliance::{
    AnalyticCompliance, CavityCompliance, ComplianceError, LinearCompliance, TabulatedCompliance,
};
pub use deficit::{DeficitMonitor, DeficitStatus};
pub use model::{HydraulicCounters, HydraulicInputs, HydraulicModel, HydraulicState};
pub use params::{
    conductance_si, AbsorptionParams, CavityParams, CervixParams, DeficitLimit, DeficitParams,
    HydraulicParams, InflowParams, LineParams, OutflowParams, ParamsError, PerforationParams,
    PumpParams, MAX_WARNING_STAGES,
};
pub use procedure::{CumulativeVolumes, ProcedureInfo};
pub use record::{
    record_path, reset_request_path, ProcedureRecord, RecordError, RECORD_FILE_NAME, RECORD_MAGIC,
    RECORD_VERSION,
};
pub use valve::{sanitize_opening, ValveCurve};

#[cfg(test)]
mod compliance_tests;
#[cfg(test)]
mod tests;
