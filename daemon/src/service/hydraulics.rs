//! The hydraulics stage of hydrometrad: runs the lumped model on every tick, writes its fields and
//! alarms into status, persists the procedure record on its own thread (file I/O never runs on the
//! sim thread) and applies reset requests. See docs/hydraulics.md.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, RecvTimeoutError, SyncSender};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use anyhow::Context;
use hydrometra_drivers::emulator::Scenario;
use hydrometra_ipc::{alarms, hydraulic_flags, Status};
use hydrometra_sim::hydraulics::{
    reset_request_path, CaseScript, DeficitStatus, HydraulicInputs, HydraulicModel,
    HydraulicParams, ProcedureInfo, ProcedureRecord, MAX_WARNING_STAGES,
};

use super::sim::{SimInputs, Stage};

/// The hydraulic case script of a scenario's `[hydraulics]` table (empty without one).
pub fn case_script(scenario: &Scenario) -> anyhow::Result<CaseScript> {
    Ok(CaseScript::from_scenario_table(
        scenario.hydraulics.as_ref(),
        &scenario.origin,
    )?)
}

// Every stage the configuration may ask for has its status bit (the configuration is validated
// against MAX_WARNING_STAGES).
const _: () = assert!(alarms::DEFICIT_WARNING_STAGES.len() == MAX_WARNING_STAGES);

/// The status alarm bits of the deficit (docs/ipc.md, "Alarm bits"): the stage bits follow the
/// configured warning stages reached, so they cannot disagree with `deficit_warning_stage`.
pub fn deficit_alarm_bits(d: &DeficitStatus) -> u64 {
    let mut bits = alarms::deficit_warning_bits(usize::from(d.warning_stage));
    for (on, bit) in [
        (d.limit_reached(), alarms::DEFICIT_LIMIT),
        (d.rate_alarm, alarms::DEFICIT_RATE),
        (d.terminated, alarms::PROCEDURE_TERMINATED),
        (d.overpressure, alarms::OVERPRESSURE),
    ] {
        if on {
            bits |= bit;
        }
    }
    bits
}

fn now_unix_ms() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as u64)
}

fn new_procedure() -> ProcedureInfo {
    let now = now_unix_ms();
    ProcedureInfo {
        id: now,
        started_unix_ms: now,
    }
}

/// The control plane's handle on the procedure: asks for a new one and reads the current one.
/// The 1 kHz loop applies the request on its next tick and publishes its figures through
/// atomics, so neither side ever waits for the other.
#[derive(Debug, Default)]
pub struct ProcedureControl {
    /// Shared with the record thread, which sets it for a `<record>.reset` file.
    reset: Arc<AtomicBool>,
    procedure_id: AtomicU64,
    deficit_m3_bits: AtomicU64,
}

impl ProcedureControl {
    /// Asks the loop to start a new procedure on its next tick (deficit and alarms reset).
    pub fn request_new_procedure(&self) {
        self.reset.store(true, Ordering::Release);
    }

    /// Id of the current procedure (0 before the stage started).
    pub fn procedure_id(&self) -> u64 {
        self.procedure_id.load(Ordering::Acquire)
    }

    /// The current procedure's fluid deficit after the last tick, m³.
    pub fn deficit_m3(&self) -> f64 {
        f64::from_bits(self.deficit_m3_bits.load(Ordering::Relaxed))
    }

    fn publish(&self, procedure_id: u64, deficit_m3: f64) {
        self.deficit_m3_bits
            .store(deficit_m3.to_bits(), Ordering::Relaxed);
        self.procedure_id.store(procedure_id, Ordering::Release);
    }
}

/// What the stage is built from.
pub struct HydraulicsSetup {
    /// Parameters (the config's, unless the case replaces them).
    pub params: HydraulicParams,
    /// Case events (empty for a real rig).
    pub case: CaseScript,
    /// Length of a looping scenario, s, so case events repeat with it.
    pub case_period_s: Option<f64>,
    /// The procedure record, if persisted.
    pub record: Option<PathBuf>,
    /// Save interval.
    pub save_interval: Duration,
    /// Start a new procedure instead of restoring the record.
    pub new_procedure: bool,
    /// The scene's hand-over: the stage offers its state every tick and takes the atlas's
    /// compliance from it when the scene is ready.
    pub scene: Option<Arc<super::scene::SceneFeed>>,
    /// The control plane's handle (new procedure on request).
    pub control: Arc<ProcedureControl>,
}

/// The record writer thread and its channel.
struct Persister {
    tx: Option<SyncSender<ProcedureRecord>>,
    thread: Option<JoinHandle<()>>,
}

/// Writes records as they arrive (the newest pending one wins) and watches for reset requests.
fn persist_loop(
    path: PathBuf,
    rx: Receiver<ProcedureRecord>,
    reset: Arc<AtomicBool>,
    poll: Duration,
) {
    let request = reset_request_path(&path);
    let mut failing = false;
    loop {
        let mut latest = match rx.recv_timeout(poll) {
            Ok(r) => Some(r),
            Err(RecvTimeoutError::Timeout) => None,
            Err(RecvTimeoutError::Disconnected) => break,
        };
        while let Ok(r) = rx.try_recv() {
            latest = Some(r);
        }
        if let Some(record) = latest {
            match record.save(&path) {
                Ok(()) => {
                    if failing {
                        tracing::info!(path = %path.display(), "procedure record writable again");
                    }
                    failing = false;
                }
                Err(e) => {
                    if !failing {
                        tracing::error!("{e}; the deficit is kept in memory and retried");
                    }
                    failing = true;
                }
            }
        }
        if request.exists() {
            match std::fs::remove_file(&request) {
                Ok(()) => {
                    tracing::info!(request = %request.display(), "new procedure requested");
                    reset.store(true, Ordering::Relaxed);
                }
                Err(e) => {
                    tracing::warn!(request = %request.display(), "cannot remove reset request: {e}")
                }
            }
        }
    }
}

/// The hydraulics stage.
pub struct HydraulicsStage {
    model: HydraulicModel,
    case: CaseScript,
    case_period_s: Option<f64>,
    clock_s: f64,
    flags: u64,
    persister: Option<Persister>,
    save_interval_s: f64,
    since_save_s: f64,
    last_alarm_bits: u64,
    reset: Arc<AtomicBool>,
    scene: Option<Arc<super::scene::SceneFeed>>,
    control: Arc<ProcedureControl>,
}

impl HydraulicsStage {
    /// Builds the model, restores the procedure record (or starts a new procedure) and starts the
    /// record writer.
    pub fn start(setup: HydraulicsSetup) -> anyhow::Result<Self> {
        let mut model =
            HydraulicModel::new(setup.params).context("invalid hydraulic parameters")?;
        let mut flags = hydraulic_flags::ACTIVE;
        let reset = setup.control.reset.clone();
        let mut persister = None;
        match &setup.record {
            None => {
                tracing::warn!(
                    "no procedure record configured ([hydraulics] record or [paths] state_dir): \
                     the fluid deficit will not survive a restart"
                );
                model.start_new_procedure(new_procedure());
            }
            Some(path) => {
                let requested = reset_request_path(path);
                let reset_pending = requested.exists();
                if reset_pending {
                    let _ = std::fs::remove_file(&requested);
                }
                if setup.new_procedure || reset_pending {
                    model.start_new_procedure(new_procedure());
                    tracing::info!(record = %path.display(), "starting a new procedure");
                } else {
                    match ProcedureRecord::load(path) {
                        Ok(Some(record)) => {
                            model.restore(&record);
                            flags |= hydraulic_flags::RESTORED;
                            tracing::info!(
                                record = %path.display(),
                                procedure = record.procedure.id,
                                deficit_ml = record.deficit.deficit_m3 * 1e6,
                                terminated = record.deficit.terminated,
                                "procedure restored"
                            );
                        }
                        Ok(None) => {
                            model.start_new_procedure(new_procedure());
                            tracing::info!(record = %path.display(), "no saved procedure; starting a new one");
                        }
                        Err(e) => {
                            // Never silently drop a deficit: keep the bad file for inspection.
                            let aside = PathBuf::from(format!(
                                "{}.corrupt-{}",
                                path.display(),
                                now_unix_ms()
                            ));
                            let _ = std::fs::rename(path, &aside);
                            tracing::error!(
                                "{e}; moved aside to {} and starting a new procedure",
                                aside.display()
                            );
                            model.start_new_procedure(new_procedure());
                        }
                    }
                }
                if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
                    std::fs::create_dir_all(dir).with_context(|| {
                        format!("creating the procedure record directory {}", dir.display())
                    })?;
                }
                // Write the (new or restored) procedure at once so a crash now keeps it.
                model
                    .record(now_unix_ms())
                    .save(path)
                    .with_context(|| format!("writing the procedure record {}", path.display()))?;
                let (tx, rx) = sync_channel(8);
                let thread = {
                    let (path, reset) = (path.clone(), reset.clone());
                    let poll = setup.save_interval;
                    std::thread::Builder::new()
                        .name("hm-record".into())
                        .spawn(move || persist_loop(path, rx, reset, poll))
                        .context("cannot start the procedure record thread")?
                };
                persister = Some(Persister {
                    tx: Some(tx),
                    thread: Some(thread),
                });
            }
        }
        let last_alarm_bits = deficit_alarm_bits(&model.state().deficit);
        setup
            .control
            .publish(model.procedure().id, model.state().deficit.deficit_m3);
        Ok(Self {
            model,
            case: setup.case,
            case_period_s: setup.case_period_s.filter(|p| *p > 0.0),
            clock_s: 0.0,
            flags,
            persister,
            save_interval_s: setup.save_interval.as_secs_f64(),
            since_save_s: 0.0,
            last_alarm_bits,
            reset,
            scene: setup.scene,
            control: setup.control,
        })
    }

    fn send_record(&mut self) {
        if let Some(tx) = self.persister.as_ref().and_then(|p| p.tx.as_ref()) {
            // Never blocks the sim thread; a full channel means a newer record follows shortly.
            let _ = tx.try_send(self.model.record(now_unix_ms()));
        }
        self.since_save_s = 0.0;
    }
}

impl Stage for HydraulicsStage {
    fn name(&self) -> &'static str {
        "hydraulics"
    }

    fn step(&mut self, inputs: &SimInputs, dt_s: f64) {
        if self.reset.swap(false, Ordering::Acquire) {
            let ended = (
                self.model.procedure().id,
                self.model.state().deficit.deficit_m3,
            );
            let mut next = new_procedure();
            // A new procedure always gets a new id (the recording rotates on it), even when
            // asked for within the millisecond the last one started.
            next.id = next.id.max(ended.0 + 1);
            self.model.start_new_procedure(next);
            self.flags &= !hydraulic_flags::RESTORED;
            tracing::info!(
                procedure = self.model.procedure().id,
                ended_procedure = ended.0,
                ended_deficit_ml = ended.1 * 1e6,
                "new procedure started; the deficit is reset"
            );
            self.send_record();
        }
        if let Some(compliance) = self.scene.as_ref().and_then(|f| f.take_compliance()) {
            // The cavity keeps its volume; its pressure follows the atlas's P-V curve from now.
            self.model.set_compliance(compliance);
        }
        self.clock_s += dt_s;
        let case_t = match self.case_period_s {
            Some(period) => self.clock_s.rem_euclid(period),
            None => self.clock_s,
        };
        let h = HydraulicInputs {
            valve_in_opening: inputs.valve_in_opening,
            valve_out_opening: inputs.valve_out_opening,
            pump_set_pressure_pa: inputs.pump_set_pressure_pa,
            perforation: self.case.perforated_at(case_t),
        };
        let bits = deficit_alarm_bits(&self.model.step(&h, dt_s).deficit);
        self.control.publish(
            self.model.procedure().id,
            self.model.state().deficit.deficit_m3,
        );
        if let Some(feed) = &self.scene {
            feed.offer(inputs, self.model.state(), h.perforation);
        }
        self.since_save_s += dt_s;
        if bits != self.last_alarm_bits || self.since_save_s >= self.save_interval_s {
            if bits != self.last_alarm_bits {
                let d = self.model.state().deficit;
                tracing::warn!(
                    deficit_ml = d.deficit_m3 * 1e6,
                    limit_ml = d.limit_m3 * 1e6,
                    warning_stage = d.warning_stage,
                    rate_alarm = d.rate_alarm,
                    terminated = d.terminated,
                    "hydraulic alarms changed"
                );
            }
            self.last_alarm_bits = bits;
            self.send_record();
        }
    }

    fn write_status(&self, status: &mut Status) {
        let s = self.model.state();
        let d = &s.deficit;
        status.cavity_pressure_pa = s.cavity_pressure_pa;
        status.cavity_volume_m3 = s.cavity_volume_m3;
        status.inflow_m3_per_s = s.flows.inflow_m3_per_s;
        status.outflow_m3_per_s = s.flows.outflow_m3_per_s;
        status.leak_m3_per_s = s.flows.leak_m3_per_s;
        status.absorption_m3_per_s = s.flows.absorption_m3_per_s;
        status.perforation_m3_per_s = s.flows.perforation_m3_per_s;
        status.inflow_port_velocity_m_per_s = s.inflow_port_velocity_m_per_s;
        status.outflow_port_velocity_m_per_s = s.outflow_port_velocity_m_per_s;
        status.fluid_in_m3 = s.totals.inflow_m3;
        status.fluid_collected_m3 = s.totals.collected_m3();
        status.deficit_m3 = d.deficit_m3;
        status.deficit_rate_m3_per_s = d.rate_m3_per_s;
        status.deficit_limit_m3 = d.limit_m3;
        status.procedure_id = self.model.procedure().id;
        status.procedure_time_s = s.time_s;
        status.deficit_warning_stage = u64::from(d.warning_stage);
        let mut flags = self.flags;
        if s.perforated {
            flags |= hydraulic_flags::PERFORATED;
        }
        if s.pump_stopped {
            flags |= hydraulic_flags::PUMP_STOPPED;
        }
        if s.pump_flow_limited {
            flags |= hydraulic_flags::PUMP_FLOW_LIMITED;
        }
        status.hydraulic_flags = flags;
        status.alarm_bits |= deficit_alarm_bits(d);
    }
}

impl Drop for HydraulicsStage {
    fn drop(&mut self) {
        // Final save on a clean shutdown, then let the writer finish.
        self.send_record();
        if let Some(mut p) = self.persister.take() {
            drop(p.tx.take());
            if let Some(t) = p.thread.take() {
                let _ = t.join();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::service::config::Config;
    use crate::service::sim::INITIAL_SCOPE;
    use hydrometra_units::mmhg_to_pa;

    /// Runs a perforated cavity to termination under `deficit_toml` (a `[hydraulics.params.deficit]`
    /// table with a 100 ml limit) and returns, per alarm bit, the deficit fractions of the limit
    /// on the tick before and the tick on which the published bit first came on.
    fn first_published(deficit_toml: &str) -> Vec<(u64, Option<(f64, f64)>)> {
        let config = Config::from_toml_str(
            &format!(
                "[hydraulics.params.deficit]\nlimit = \"custom\"\ncustom_limit_ml = 100.0\n\
                 {deficit_toml}"
            ),
            "test",
        )
        .expect("config");
        let mut stage = HydraulicsStage::start(HydraulicsSetup {
            params: config.hydraulics.params.clone(),
            case: CaseScript {
                perforation_at_s: Some(0.0),
                params: None,
            },
            case_period_s: None,
            record: None,
            save_interval: Duration::from_millis(200),
            new_procedure: true,
            scene: None,
            control: Arc::new(ProcedureControl::default()),
        })
        .expect("hydraulics stage");
        let inputs = SimInputs {
            valve_in_opening: 1.0,
            valve_out_opening: 0.0,
            pump_set_pressure_pa: mmhg_to_pa(100.0),
            scope: INITIAL_SCOPE,
            safe_state: false,
            sample_received_at: None,
        };
        let watched = [
            alarms::DEFICIT_WARNING_50,
            alarms::DEFICIT_WARNING_75,
            alarms::DEFICIT_WARNING_90,
            alarms::DEFICIT_LIMIT,
        ];
        let mut first: Vec<(u64, Option<(f64, f64)>)> =
            watched.iter().map(|&b| (b, None)).collect();
        let mut previous = (0.0, 0u64);
        for _ in 0..600_000 {
            stage.step(&inputs, 1e-3);
            let mut status = Status::default();
            stage.write_status(&mut status);
            let fraction = status.deficit_m3 / status.deficit_limit_m3;
            let bits = status.alarm_bits;
            for (bit, at) in &mut first {
                if bits & *bit != 0 && at.is_none() {
                    *at = Some((previous.0, fraction));
                }
            }
            // Within a procedure the deficit bits never clear.
            assert_eq!(previous.1 & !bits & watched.iter().fold(0, |a, b| a | b), 0);
            assert_eq!(
                alarms::deficit_warning_bits(status.deficit_warning_stage as usize),
                bits & (alarms::DEFICIT_WARNING_50
                    | alarms::DEFICIT_WARNING_75
                    | alarms::DEFICIT_WARNING_90),
                "the stage bits and deficit_warning_stage agree"
            );
            previous = (fraction, bits);
            if bits & alarms::PROCEDURE_TERMINATED != 0 {
                return first;
            }
        }
        panic!("the perforated cavity never reached the 100 ml limit in 600 s");
    }

    /// Asserts that each bit came on exactly on the tick the deficit crossed its fraction (or
    /// never, for `None`).
    fn assert_thresholds(deficit_toml: &str, want: [(u64, Option<f64>); 4]) {
        let got = first_published(deficit_toml);
        for ((bit, at), (want_bit, threshold)) in got.into_iter().zip(want) {
            assert_eq!(bit, want_bit);
            let name = alarms::names(bit).join("");
            match (at, threshold) {
                (None, None) => {}
                (Some((before, on)), Some(t)) => assert!(
                    before < t && on >= t,
                    "{deficit_toml}: {name} came on between {before} and {on} of the limit, \
                     not when crossing {t}"
                ),
                (at, t) => panic!("{deficit_toml}: {name} came on at {at:?}, want {t:?}"),
            }
        }
    }

    #[test]
    fn deficit_alarm_bits_come_on_at_the_configured_warning_fractions() {
        use alarms::{DEFICIT_LIMIT, DEFICIT_WARNING_50, DEFICIT_WARNING_75, DEFICIT_WARNING_90};
        assert_thresholds(
            "warning_fractions = [0.3, 0.9]\n",
            [
                (DEFICIT_WARNING_50, Some(0.3)),
                (DEFICIT_WARNING_75, Some(0.9)),
                (DEFICIT_WARNING_90, None),
                (DEFICIT_LIMIT, Some(1.0)),
            ],
        );
        // The default stages: the bits where their names say.
        assert_thresholds(
            "",
            [
                (DEFICIT_WARNING_50, Some(0.5)),
                (DEFICIT_WARNING_75, Some(0.75)),
                (DEFICIT_WARNING_90, Some(0.9)),
                (DEFICIT_LIMIT, Some(1.0)),
            ],
        );
        assert_thresholds(
            "warning_fractions = []\n",
            [
                (DEFICIT_WARNING_50, None),
                (DEFICIT_WARNING_75, None),
                (DEFICIT_WARNING_90, None),
                (DEFICIT_LIMIT, Some(1.0)),
            ],
        );
    }

    #[test]
    fn a_configuration_cannot_ask_for_more_warning_stages_than_alarm_bits() {
        let e = Config::from_toml_str(
            "[hydraulics.params.deficit]\nwarning_fractions = [0.2, 0.4, 0.6, 0.8]\n",
            "hm.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("hm.toml") && e.contains("deficit.warning_fractions"),
            "{e}"
        );
    }
}
