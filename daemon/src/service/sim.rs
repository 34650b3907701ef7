//! The fixed-rate simulation loop: reads the rig once per tick, applies the safe-state rule,
//! steps the simulation stages and hands a status frame to its sink (the status publisher, on
//! the same thread) every N ticks.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{SyncSender, TrySendError};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use hydrometra_drivers::state::{LinkDownReason, LinkState, ScopePose};
use hydrometra_drivers::transport::monotonic_ns;
use hydrometra_ipc::status::link_down_reason as reason;
use hydrometra_ipc::{alarms, Status};

use super::latency::{LatencyHistogram, LatencySummary};
use super::realtime::sleep_until_monotonic_ns;
use super::rig_source::{RigSource, RigView};

/// The inputs a simulation stage sees on one tick: the rig's calibrated values, or the safe
/// inputs when the rig is lost or stale.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SimInputs {
    /// Inflow valve opening in [0, 1].
    pub valve_in_opening: f64,
    /// Outflow valve opening in [0, 1].
    pub valve_out_opening: f64,
    /// Pump set pressure, Pa.
    pub pump_set_pressure_pa: f64,
    /// Scope pose (the last known one while the link is down, flagged invalid).
    pub scope: ScopePose,
    /// True when these are the safe inputs, not the rig's.
    pub safe_state: bool,
    /// Host arrival time of the rig sample these inputs come from (none in the safe state).
    pub sample_received_at: Option<Instant>,
}

/// The scope pose before any sample: at the external os looking along +z, invalid.
pub const INITIAL_SCOPE: ScopePose = ScopePose {
    tip_position_m: [0.0, 0.0, 0.0],
    view_direction: [0.0, 0.0, 1.0],
    orientation: [1.0, 0.0, 0.0, 0.0],
    valid: false,
};

/// The safe-state rule. The rig's sample is used only while the link is `Connected` and the
/// sample is younger than `timeout`; otherwise both valves count as closed and the pump as
/// stopped (0 Pa), so the simulated cavity is isolated and can neither fill nor drain, and the
/// scope holds its last pose, flagged invalid.
pub fn inputs_from(view: &RigView, timeout: Duration) -> SimInputs {
    let fresh = view.link_state == LinkState::Connected
        && view.last_sample_age.is_some_and(|age| age <= timeout);
    match (fresh, view.latest) {
        (true, Some(s)) => SimInputs {
            valve_in_opening: s.valve_in_opening,
            valve_out_opening: s.valve_out_opening,
            pump_set_pressure_pa: s.pump_set_pressure_pa,
            scope: s.scope,
            safe_state: false,
            sample_received_at: Some(s.received_at),
        },
        (_, latest) => SimInputs {
            valve_in_opening: 0.0,
            valve_out_opening: 0.0,
            pump_set_pressure_pa: 0.0,
            scope: ScopePose {
                valid: false,
                ..latest.map_or(INITIAL_SCOPE, |s| s.scope)
            },
            safe_state: true,
            sample_received_at: None,
        },
    }
}

/// `Status::link_down_reason` and `link_down_detail` for the transport's reason.
pub fn link_down_fields(down: Option<LinkDownReason>) -> (u32, u32) {
    match down {
        None => (reason::NONE, 0),
        Some(LinkDownReason::DeviceNotFound) => (reason::DEVICE_NOT_FOUND, 0),
        Some(LinkDownReason::UsbDeviceNotFound) => (reason::USB_DEVICE_NOT_FOUND, 0),
        Some(LinkDownReason::PermissionDenied { gid }) => (
            reason::PERMISSION_DENIED,
            gid.unwrap_or(reason::DETAIL_UNKNOWN),
        ),
        Some(LinkDownReason::DeviceBusy) => (reason::DEVICE_BUSY, 0),
        Some(LinkDownReason::OpenFailed) => (reason::OPEN_FAILED, 0),
        Some(LinkDownReason::NoHandshake) => (reason::NO_HANDSHAKE, 0),
        Some(LinkDownReason::IncompatibleVersion { version }) => {
            (reason::INCOMPATIBLE_VERSION, u32::from(version))
        }
        Some(LinkDownReason::Timeout) => (reason::TIMEOUT, 0),
        Some(LinkDownReason::Lost) => (reason::LOST, 0),
    }
}

/// One stage of the simulation (hydraulics, deformation, ...), stepped on every tick.
///
/// A stage decides itself whether it has work to do; it must never block and must stay finite
/// whatever the inputs and `dt_s`.
pub trait Stage: Send {
    /// Short name for logs and counters.
    fn name(&self) -> &'static str;
    /// Advances the stage by `dt_s` seconds with these inputs.
    fn step(&mut self, inputs: &SimInputs, dt_s: f64);
    /// Writes the stage's fields (and alarm bits) into the status about to be published.
    fn write_status(&self, status: &mut Status);
}

/// A status ready to publish, with what the publisher needs to measure latency.
#[derive(Debug, Clone, Copy)]
pub struct StatusFrame {
    /// The status; the publisher fills `sequence`, `publish_monotonic_ns` and latency figures.
    pub status: Status,
    /// Host arrival time of the rig sample this status is the first to reflect, if any.
    pub new_sample_received_at: Option<Instant>,
}

/// Counters shared by the loop, the publisher and the supervisor (logs, watchdog).
#[derive(Debug, Default)]
pub struct Telemetry {
    /// Ticks executed.
    pub ticks: AtomicU64,
    /// Ticks that finished late or were skipped.
    pub deadline_misses: AtomicU64,
    /// Longest tick compute time, ns.
    pub tick_work_max_ns: AtomicU64,
    /// Statuses a sink could not take (a full channel; 0 with the inline publisher).
    pub statuses_dropped: AtomicU64,
    /// Statuses published.
    pub statuses_published: AtomicU64,
    /// Failed loans/sends/notifications in the publisher.
    pub publish_errors: AtomicU64,
    /// Rig-sample-to-status latency since start (locked by the loop's thread alone while it
    /// runs; others read `latency_summary`).
    pub latency: Mutex<LatencyHistogram>,
    /// What the real-time side got from the system (`realtime::RealtimeMode` as u64).
    pub realtime_mode: AtomicU64,
    /// The latency percentiles as last computed by the publisher (p50, p99, max as f64 bits,
    /// count), so the supervisor never takes the histogram's lock from the loop.
    latency_summary: [AtomicU64; 4],
}

impl Telemetry {
    /// Stores the latency figures for [`Telemetry::latency_summary`].
    pub fn store_latency_summary(&self, s: &LatencySummary) {
        let values = [
            s.p50_s.to_bits(),
            s.p99_s.to_bits(),
            s.max_s.to_bits(),
            s.count,
        ];
        for (slot, v) in self.latency_summary.iter().zip(values) {
            slot.store(v, Ordering::Relaxed);
        }
    }

    /// The latency figures the publisher last computed (every
    /// `publisher::LATENCY_SUMMARY_INTERVAL`, and exactly when it stops).
    pub fn latency_summary(&self) -> LatencySummary {
        let [p50, p99, max, count] = &self.latency_summary;
        if count.load(Ordering::Relaxed) == 0 {
            return LatencySummary::EMPTY;
        }
        LatencySummary {
            count: count.load(Ordering::Relaxed),
            p50_s: f64::from_bits(p50.load(Ordering::Relaxed)),
            p99_s: f64::from_bits(p99.load(Ordering::Relaxed)),
            max_s: f64::from_bits(max.load(Ordering::Relaxed)),
        }
    }
}

/// Where the loop hands each status: the iceoryx2 publisher on the loop's own thread in the
/// daemon, a channel in tests.
pub trait StatusSink {
    /// Takes one status without blocking; false when nobody takes statuses any more (the loop
    /// stops).
    fn publish(&mut self, frame: StatusFrame, telemetry: &Telemetry) -> bool;
}

/// A bounded channel: a full one drops the status and counts it (`statuses_dropped`).
impl StatusSink for SyncSender<StatusFrame> {
    fn publish(&mut self, frame: StatusFrame, telemetry: &Telemetry) -> bool {
        match self.try_send(frame) {
            Ok(()) => true,
            Err(TrySendError::Full(_)) => {
                telemetry.statuses_dropped.fetch_add(1, Ordering::Relaxed);
                true
            }
            Err(TrySendError::Disconnected(_)) => false,
        }
    }
}

/// Loop settings.
#[derive(Debug, Clone, Copy)]
pub struct LoopSettings {
    /// Tick period.
    pub tick: Duration,
    /// Status every this many ticks.
    pub ticks_per_status: u64,
    /// Safe-state timeout.
    pub safe_state_timeout: Duration,
    /// Identifies this daemon run in every status.
    pub run_id: u64,
}

/// The simulation loop and its stages.
pub struct SimLoop {
    settings: LoopSettings,
    stages: Vec<Box<dyn Stage>>,
}

impl SimLoop {
    /// A loop with no stages yet (status reflects the rig only).
    pub fn new(settings: LoopSettings) -> Self {
        Self {
            settings,
            stages: Vec::new(),
        }
    }

    /// Adds a stage; stages run in the order added.
    pub fn with_stage(mut self, stage: Box<dyn Stage>) -> Self {
        self.stages.push(stage);
        self
    }

    /// Runs until `stop` is set or the sink hangs up. Never blocks on the sink.
    pub fn run(
        mut self,
        rig: &dyn RigSource,
        out: &mut dyn StatusSink,
        stop: &AtomicBool,
        telemetry: &Telemetry,
    ) {
        let period = self.settings.tick;
        let period_ns = period.as_nanos().max(1) as u64;
        // The loop keeps time in CLOCK_MONOTONIC ns (what it sleeps on, one clock read per
        // wake-up); `start` maps those readings to the `Instant`s of rig samples (the same clock,
        // read once more here: the mapping is off by the ~100 ns between the two reads).
        let start = Instant::now();
        let start_ns = monotonic_ns();
        let mut tick_index: u64 = 0; // index of the next scheduled tick
        let mut ticks_since_status: u64 = 0;
        // A sample that arrived before the loop started is not a latency sample: it waited for
        // start-up, not for a tick.
        let mut last_reported_sample: Option<Instant> = rig.view().latest.map(|s| s.received_at);
        let mut last_miss: Option<Instant> = None;
        let mut sim_time_s = 0.0;
        let mut ticks_run: u64 = 0;
        while !stop.load(Ordering::Relaxed) {
            let scheduled_ns = start_ns.saturating_add(period_ns.saturating_mul(tick_index));
            sleep_until_monotonic_ns(scheduled_ns);
            let woke_ns = monotonic_ns();
            let woke = start + Duration::from_nanos(woke_ns.saturating_sub(start_ns));
            // Whole periods that passed without a tick are skipped (not replayed in a burst) and
            // count as misses; the step covers them with a longer dt so sim time tracks real time.
            let late_periods = woke_ns.saturating_sub(scheduled_ns) / period_ns;
            if late_periods > 0 {
                telemetry
                    .deadline_misses
                    .fetch_add(late_periods, Ordering::Relaxed);
                last_miss = Some(woke);
            }
            let dt_s = period.as_secs_f64() * (1 + late_periods) as f64;
            tick_index += 1 + late_periods;
            sim_time_s += dt_s;
            ticks_run += 1;

            let view = rig.view_at(woke);
            let inputs = inputs_from(&view, self.settings.safe_state_timeout);
            for stage in &mut self.stages {
                stage.step(&inputs, dt_s);
            }

            ticks_since_status += 1;
            if ticks_since_status >= self.settings.ticks_per_status {
                ticks_since_status = 0;
                let new_sample_received_at = view
                    .latest
                    .map(|s| s.received_at)
                    .filter(|at| Some(*at) != last_reported_sample);
                if new_sample_received_at.is_some() {
                    last_reported_sample = new_sample_received_at;
                }
                let mut status = self.status(&view, &inputs, sim_time_s, ticks_run, telemetry);
                if last_miss.is_some_and(|t| woke.duration_since(t) < Duration::from_secs(1)) {
                    status.alarm_bits |= alarms::DEADLINE_MISSED;
                }
                let frame = StatusFrame {
                    status,
                    new_sample_received_at,
                };
                if !out.publish(frame, telemetry) {
                    break;
                }
            }

            telemetry.ticks.store(ticks_run, Ordering::Relaxed);
            let work = woke.elapsed();
            telemetry
                .tick_work_max_ns
                .fetch_max(work.as_nanos() as u64, Ordering::Relaxed);
            if work > period {
                telemetry.deadline_misses.fetch_add(1, Ordering::Relaxed);
                last_miss = Some(woke);
            }
        }
    }

    fn status(
        &self,
        view: &RigView,
        inputs: &SimInputs,
        sim_time_s: f64,
        ticks: u64,
        telemetry: &Telemetry,
    ) -> Status {
        let c = &view.counters;
        let mut s = Status {
            run_id: self.settings.run_id,
            sim_time_s,
            link_frames: c.frames,
            link_crc_errors: c.crc_errors,
            link_malformed: c.malformed,
            link_sequence_gaps: c.sequence_gaps,
            link_resyncs: c.resyncs,
            link_reconnects: c.reconnects,
            link_clamped_values: c.clamped_values,
            link_device_faults: c.device_faults,
            last_sample_age_s: view.last_sample_age.map_or(f64::NAN, |a| a.as_secs_f64()),
            valve_in_opening: inputs.valve_in_opening,
            valve_out_opening: inputs.valve_out_opening,
            pump_set_pressure_pa: inputs.pump_set_pressure_pa,
            scope_tip_position_m: inputs.scope.tip_position_m,
            scope_view_direction: inputs.scope.view_direction,
            scope_orientation_wxyz: inputs.scope.orientation,
            scope_pose_valid: u32::from(inputs.scope.valid),
            safe_state: u32::from(inputs.safe_state),
            tick_rate_hz: 1.0 / self.settings.tick.as_secs_f64(),
            ticks,
            deadline_misses: telemetry.deadline_misses.load(Ordering::Relaxed),
            tick_work_max_s: telemetry.tick_work_max_ns.load(Ordering::Relaxed) as f64 * 1e-9,
            statuses_dropped: telemetry.statuses_dropped.load(Ordering::Relaxed),
            link_state: view.link_state as u32,
            realtime_mode: telemetry.realtime_mode.load(Ordering::Relaxed) as u32,
            ..Status::default()
        };
        (s.link_down_reason, s.link_down_detail) = link_down_fields(view.down_reason);
        if let Some(latest) = view.latest {
            s.rig_device_time_us = latest.device_time_us;
            s.rig_sequence = latest.sequence;
            s.rig_valve_in_opening = latest.valve_in_opening;
            s.rig_valve_out_opening = latest.valve_out_opening;
            s.rig_pump_set_pressure_pa = latest.pump_set_pressure_pa;
            s.buttons = latest.buttons;
        }
        if view.link_state != LinkState::Connected {
            s.alarm_bits |= alarms::RIG_LINK_LOST;
        }
        if view.link_state == LinkState::Incompatible {
            s.alarm_bits |= alarms::RIG_INCOMPATIBLE;
        }
        if inputs.safe_state {
            s.alarm_bits |= alarms::RIG_SAFE_STATE | alarms::RIG_LINK_LOST;
        }
        if !inputs.scope.valid {
            s.alarm_bits |= alarms::SCOPE_POSE_INVALID;
        }
        for stage in &self.stages {
            stage.write_status(&mut s);
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use hydrometra_drivers::state::{LinkCounters, RigState};
    use std::sync::mpsc::sync_channel;
    use std::sync::Arc;

    fn sample(valve_in: f64, age: Duration) -> (RigState, Duration) {
        let s = RigState {
            device_time_us: 1_000,
            received_at: Instant::now(),
            sequence: 7,
            valve_in_opening: valve_in,
            valve_out_opening: 0.25,
            pump_set_pressure_pa: 13_332.2,
            scope: ScopePose {
                tip_position_m: [0.0, 0.001, 0.05],
                view_direction: [0.0, 0.0, 1.0],
                orientation: [1.0, 0.0, 0.0, 0.0],
                valid: true,
            },
            buttons: 1,
        };
        (s, age)
    }

    fn view(state: LinkState, s: Option<(RigState, Duration)>) -> RigView {
        RigView {
            link_state: state,
            counters: LinkCounters::default(),
            latest: s.map(|x| x.0),
            last_sample_age: s.map(|x| x.1),
            down_reason: None,
        }
    }

    const TIMEOUT: Duration = Duration::from_millis(100);

    #[test]
    fn fresh_connected_sample_is_used_as_is() {
        let v = view(
            LinkState::Connected,
            Some(sample(0.6, Duration::from_millis(3))),
        );
        let i = inputs_from(&v, TIMEOUT);
        assert!(!i.safe_state && i.scope.valid);
        assert_eq!((i.valve_in_opening, i.valve_out_opening), (0.6, 0.25));
        assert_eq!(i.pump_set_pressure_pa, 13_332.2);
    }

    #[test]
    fn stale_lost_or_incompatible_links_give_the_safe_inputs() {
        let cases = [
            view(
                LinkState::Connected,
                Some(sample(0.6, Duration::from_millis(101))),
            ),
            view(
                LinkState::Disconnected,
                Some(sample(0.6, Duration::from_millis(1))),
            ),
            view(
                LinkState::Stale,
                Some(sample(0.6, Duration::from_millis(50))),
            ),
            view(LinkState::Incompatible, None),
            view(LinkState::Connected, None),
        ];
        for v in cases {
            let i = inputs_from(&v, TIMEOUT);
            assert!(i.safe_state, "{v:?}");
            assert_eq!(
                (
                    i.valve_in_opening,
                    i.valve_out_opening,
                    i.pump_set_pressure_pa
                ),
                (0.0, 0.0, 0.0)
            );
            assert!(!i.scope.valid);
            // The last known pose is held (the renderer keeps its view), only flagged invalid.
            if let Some(s) = v.latest {
                assert_eq!(i.scope.tip_position_m, s.scope.tip_position_m);
            }
        }
    }

    /// A scripted rig: a view that the test changes while the loop runs.
    struct Scripted(Mutex<RigView>);
    impl RigSource for Scripted {
        fn view_at(&self, _now: Instant) -> RigView {
            *self.0.lock().unwrap()
        }
    }

    /// Counts its steps and the dt it was given; writes its count into `reserved0`.
    struct CountingStage {
        steps: u32,
        dt_total_s: f64,
    }
    impl Stage for CountingStage {
        fn name(&self) -> &'static str {
            "counting"
        }
        fn step(&mut self, inputs: &SimInputs, dt_s: f64) {
            assert!(inputs.valve_in_opening.is_finite());
            self.steps += 1;
            self.dt_total_s += dt_s;
        }
        fn write_status(&self, status: &mut Status) {
            status.reserved0 = self.steps;
            // Sim time is the sum of the dt handed to the stages: nothing lost or doubled.
            assert!((status.sim_time_s - self.dt_total_s).abs() < 1e-9);
        }
    }

    #[test]
    fn loop_publishes_every_n_ticks_and_reflects_each_new_sample_once() {
        let (s, age) = sample(0.5, Duration::from_millis(1));
        let rig = Arc::new(Scripted(Mutex::new(view(
            LinkState::Connected,
            Some((s, age)),
        ))));
        let (mut tx, rx) = sync_channel(1024);
        let stop = Arc::new(AtomicBool::new(false));
        let telemetry = Arc::new(Telemetry::default());
        let settings = LoopSettings {
            tick: Duration::from_millis(1),
            ticks_per_status: 4,
            safe_state_timeout: TIMEOUT,
            run_id: 42,
        };
        let handle = {
            let (rig, stop, telemetry) = (rig.clone(), stop.clone(), telemetry.clone());
            std::thread::spawn(move || {
                SimLoop::new(settings)
                    .with_stage(Box::new(CountingStage {
                        steps: 0,
                        dt_total_s: 0.0,
                    }))
                    .run(&*rig, &mut tx, &stop, &telemetry)
            })
        };
        let first: Vec<StatusFrame> = (0..5).map(|_| rx.recv().unwrap()).collect();
        // A second, newer sample and then a lost link.
        let (mut s2, _) = sample(0.7, Duration::from_millis(1));
        s2.received_at = Instant::now();
        *rig.0.lock().unwrap() = view(LinkState::Connected, Some((s2, Duration::from_millis(1))));
        let mut frames: Vec<StatusFrame> = Vec::new();
        while !frames.iter().any(|f| f.status.valve_in_opening == 0.7) {
            frames.push(rx.recv().unwrap());
        }
        *rig.0.lock().unwrap() = view(
            LinkState::Disconnected,
            Some((s2, Duration::from_millis(5))),
        );
        while frames.last().unwrap().status.safe_state == 0 {
            frames.push(rx.recv().unwrap());
        }
        stop.store(true, Ordering::Relaxed);
        handle.join().unwrap();

        // The sample present before the loop started is not a latency sample; the second one is
        // reported as new exactly once.
        let all: Vec<&StatusFrame> = first.iter().chain(frames.iter()).collect();
        let new: Vec<Instant> = all
            .iter()
            .filter_map(|f| f.new_sample_received_at)
            .collect();
        assert_eq!(new, vec![s2.received_at]);
        // Every status is 4 ticks after the previous one (the stage counts steps).
        for w in all.windows(2) {
            let (a, b) = (w[0].status, w[1].status);
            assert!(b.ticks > a.ticks);
            assert_eq!(b.reserved0 - a.reserved0, (b.ticks - a.ticks) as u32);
            assert_eq!(b.run_id, 42);
        }
        let lost = frames.last().unwrap().status;
        assert_eq!(lost.safe_state, 1);
        assert_ne!(lost.alarm_bits & alarms::RIG_LINK_LOST, 0);
        assert_eq!(
            (lost.valve_in_opening, lost.rig_valve_in_opening),
            (0.0, 0.7)
        );
        assert_eq!(lost.link_state, LinkState::Disconnected as u32);
    }

    #[test]
    fn a_full_channel_drops_statuses_instead_of_blocking_the_loop() {
        let rig = Scripted(Mutex::new(RigView::disconnected()));
        let (mut tx, rx) = sync_channel(2);
        let stop = AtomicBool::new(false);
        let telemetry = Telemetry::default();
        let settings = LoopSettings {
            tick: Duration::from_micros(500),
            ticks_per_status: 1,
            safe_state_timeout: TIMEOUT,
            run_id: 1,
        };
        std::thread::scope(|scope| {
            scope.spawn(|| SimLoop::new(settings).run(&rig, &mut tx, &stop, &telemetry));
            // Nobody reads: the loop must keep ticking.
            while telemetry.ticks.load(Ordering::Relaxed) < 50 {
                std::thread::sleep(Duration::from_millis(1));
            }
            stop.store(true, Ordering::Relaxed);
        });
        let ticks = telemetry.ticks.load(Ordering::Relaxed);
        let dropped = telemetry.statuses_dropped.load(Ordering::Relaxed);
        assert_eq!(
            dropped + 2,
            ticks,
            "every status after the first two is dropped"
        );
        assert_eq!(rx.try_iter().count(), 2);
    }

    /// Stalls once for `stall` on its `at`-th step.
    struct StallingStage {
        steps: u32,
        at: u32,
        stall: Duration,
        max_dt_s: f64,
    }
    impl Stage for StallingStage {
        fn name(&self) -> &'static str {
            "stalling"
        }
        fn step(&mut self, _inputs: &SimInputs, dt_s: f64) {
            self.steps += 1;
            self.max_dt_s = self.max_dt_s.max(dt_s);
            if self.steps == self.at {
                std::thread::sleep(self.stall);
            }
        }
        fn write_status(&self, status: &mut Status) {
            status.reserved0 = (self.max_dt_s * 1e6) as u32;
        }
    }

    #[test]
    fn a_stalled_tick_counts_misses_and_the_next_step_covers_the_skipped_time() {
        let rig = Scripted(Mutex::new(RigView::disconnected()));
        let (mut tx, rx) = sync_channel(4096);
        let stop = AtomicBool::new(false);
        let telemetry = Telemetry::default();
        let settings = LoopSettings {
            tick: Duration::from_millis(1),
            ticks_per_status: 1,
            safe_state_timeout: TIMEOUT,
            run_id: 1,
        };
        let stage = StallingStage {
            steps: 0,
            at: 10,
            stall: Duration::from_millis(6),
            max_dt_s: 0.0,
        };
        std::thread::scope(|scope| {
            scope.spawn(|| {
                SimLoop::new(settings)
                    .with_stage(Box::new(stage))
                    .run(&rig, &mut tx, &stop, &telemetry)
            });
            while telemetry.ticks.load(Ordering::Relaxed) < 30 {
                std::thread::sleep(Duration::from_millis(1));
            }
            stop.store(true, Ordering::Relaxed);
        });
        // The 6 ms stall: its own tick overran (1) and at least 4 whole periods were skipped.
        assert!(telemetry.deadline_misses.load(Ordering::Relaxed) >= 5);
        let statuses: Vec<Status> = rx.try_iter().map(|f| f.status).collect();
        // The step after the stall covered the skipped periods in one longer dt (>= 5 ms), and
        // sim time still equals the sum of the steps' dt (checked per tick: ticks * 1 ms plus
        // the skipped periods, so it is ahead of the tick count).
        let last = statuses.last().unwrap();
        assert!(last.reserved0 >= 5_000, "max dt {} us", last.reserved0);
        assert!(last.sim_time_s >= (last.ticks + 4) as f64 * 1e-3 - 1e-9);
        assert_ne!(last.alarm_bits & alarms::DEADLINE_MISSED, 0);
    }
}
