//! The status record: one per published simulation frame, small, history 1.

use iceoryx2::node::Node;
use iceoryx2::prelude::ZeroCopySend;
use iceoryx2::service::builder::publish_subscribe::{
    PublishSubscribeOpenError, PublishSubscribeOpenOrCreateError,
};
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;
use iceoryx2::service::Service;

use crate::names::ServiceNames;

/// Status of the simulation, published every `status_rate_hz` (default every 1 kHz tick).
///
/// SI units throughout (m, s, Pa); clinical units are for the renderer to derive. The layout is
/// fixed for schema v1 (see `docs/ipc.md`, which a test keeps identical to this struct): 8-byte
/// fields first, then 4-byte fields, no implicit padding.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("hydrometra.v1.Status")]
pub struct Status {
    /// [`crate::SCHEMA_VERSION`] of the writer.
    pub schema_version: u32,
    /// `size_of::<Status>()` of the writer, bytes.
    pub size_bytes: u32,
    /// Publication counter: 0 for the first status of a daemon run, +1 for every status.
    pub sequence: u64,
    /// Identifies one daemon run; changes on every start (the sequence restarts at 0 then).
    pub run_id: u64,
    /// Simulated time since the daemon started, s. Advances in real time by whole ticks.
    pub sim_time_s: f64,
    /// Host `CLOCK_MONOTONIC` when the status was written, ns.
    pub publish_monotonic_ns: u64,
    /// Rig link: valid frames decoded.
    pub link_frames: u64,
    /// Rig link: frames rejected for a bad CRC.
    pub link_crc_errors: u64,
    /// Rig link: frames rejected for malformed content.
    pub link_malformed: u64,
    /// Rig link: sequence numbers skipped by the device (sum of gap sizes).
    pub link_sequence_gaps: u64,
    /// Rig link: decoder resynchronisations.
    pub link_resyncs: u64,
    /// Rig link: successful reconnections after a loss.
    pub link_reconnects: u64,
    /// Rig link: sensor values clamped or rejected by calibration.
    pub link_clamped_values: u64,
    /// Rig link: device fault reports received.
    pub link_device_faults: u64,
    /// Age of the last rig sample when this status was written, s; NaN before the first sample.
    pub last_sample_age_s: f64,
    /// Device timestamp of the last rig sample, µs since the device booted; 0 before the first.
    pub rig_device_time_us: u64,
    /// Inflow valve opening last reported by the rig, [0, 1]; 0 before the first sample.
    pub rig_valve_in_opening: f64,
    /// Outflow valve opening last reported by the rig, [0, 1]; 0 before the first sample.
    pub rig_valve_out_opening: f64,
    /// Pump set pressure last reported by the rig, Pa; 0 before the first sample.
    pub rig_pump_set_pressure_pa: f64,
    /// Inflow valve opening the simulation uses, [0, 1] (0 in the safe state).
    pub valve_in_opening: f64,
    /// Outflow valve opening the simulation uses, [0, 1] (0 in the safe state).
    pub valve_out_opening: f64,
    /// Pump set pressure the simulation uses, Pa (0 in the safe state).
    pub pump_set_pressure_pa: f64,
    /// Scope tip position in the organ frame, m (last known pose while the link is down).
    pub scope_tip_position_m: [f64; 3],
    /// Unit vector along the scope's viewing axis, organ frame.
    pub scope_view_direction: [f64; 3],
    /// Scope orientation as a unit quaternion `[w, x, y, z]`, organ frame.
    pub scope_orientation_wxyz: [f64; 4],
    /// Alarm bit field, bits in [`crate::alarms`].
    pub alarm_bits: u64,
    /// Configured simulation tick rate, Hz.
    pub tick_rate_hz: f64,
    /// Simulation ticks executed since start.
    pub ticks: u64,
    /// Ticks that finished after their deadline or were skipped, since start.
    pub deadline_misses: u64,
    /// Longest compute time of one tick since start, s.
    pub tick_work_max_s: f64,
    /// Rig-sample-to-status latency, median since start, s (NaN before the first sample).
    pub latency_p50_s: f64,
    /// Rig-sample-to-status latency, 99th percentile since start, s (NaN before the first sample).
    pub latency_p99_s: f64,
    /// Rig-sample-to-status latency, maximum since start, s (NaN before the first sample).
    pub latency_max_s: f64,
    /// Rig samples whose latency was measured since start.
    pub latency_samples: u64,
    /// Statuses the simulation loop produced but could not hand to the publisher, since start.
    pub statuses_dropped: u64,
    /// Rig link state: 0 disconnected, 1 handshaking, 2 connected, 3 stale, 4 incompatible.
    pub link_state: u32,
    /// Wire sequence number of the last rig sample.
    pub rig_sequence: u32,
    /// Button bit field of the last rig sample.
    pub buttons: u32,
    /// 1 when the scope pose is valid and current, 0 otherwise.
    pub scope_pose_valid: u32,
    /// 1 when the simulation runs on the safe inputs (rig lost or stale), 0 otherwise.
    pub safe_state: u32,
    /// Reserved, 0.
    pub reserved0: u32,
    /// Hydraulics: cavity gauge pressure.
    pub cavity_pressure_pa: f64,
    /// Hydraulics: cavity volume.
    pub cavity_volume_m3: f64,
    /// Hydraulics: pump -> cavity flow during the last tick.
    pub inflow_m3_per_s: f64,
    /// Hydraulics: cavity -> suction canister flow.
    pub outflow_m3_per_s: f64,
    /// Hydraulics: leak through the cervix.
    pub leak_m3_per_s: f64,
    /// Hydraulics: absorption into the circulation (above the mean arterial pressure).
    pub absorption_m3_per_s: f64,
    /// Hydraulics: loss through a perforation (0 while intact).
    pub perforation_m3_per_s: f64,
    /// Hydraulics: mean jet velocity out of the scope's inflow port.
    pub inflow_port_velocity_m_per_s: f64,
    /// Hydraulics: mean velocity into the scope's outflow port.
    pub outflow_port_velocity_m_per_s: f64,
    /// Hydraulics: fluid delivered by the pump since the procedure started.
    pub fluid_in_m3: f64,
    /// Hydraulics: fluid collected (canister plus the drape's share of the leak) since the procedure started.
    pub fluid_collected_m3: f64,
    /// Hydraulics: fluid deficit = in - collected - change of cavity volume; never decreases within a procedure.
    pub deficit_m3: f64,
    /// Hydraulics: deficit rate, exponentially averaged (docs/hydraulics.md).
    pub deficit_rate_m3_per_s: f64,
    /// Hydraulics: the configured deficit limit.
    pub deficit_limit_m3: f64,
    /// Hydraulics: id of the current procedure (its start, ms since the Unix epoch); survives restarts.
    pub procedure_id: u64,
    /// Hydraulics: time since the procedure started (accumulated across restarts).
    pub procedure_time_s: f64,
    /// Hydraulics: number of configured warning fractions the deficit has reached.
    pub deficit_warning_stage: u64,
    /// Hydraulics: bits in [`crate::hydraulic_flags`]: 0 stage active (hydraulic fields valid), 1 perforated, 2 pump stopped (terminated), 3 pump at its flow limit, 4 procedure restored from the record at start.
    pub hydraulic_flags: u64,
    /// Rig link: why the link is down, a [`link_down_reason`] value (0 while connected and before
    /// the first failure).
    pub link_down_reason: u32,
    /// Rig link: detail of `link_down_reason`: the device's group id for `permission-denied`
    /// ([`link_down_reason::DETAIL_UNKNOWN`] if unreadable), the device's protocol version for
    /// `incompatible-version`, otherwise 0.
    pub link_down_detail: u32,
    /// Scene: one of [`scene_state`] (0 none, 1 preparing, 2 running, 3 idle, 4 failed).
    pub scene_state: u64,
    /// Scene: frames stepped since the scene started.
    pub scene_frames: u64,
    /// Scene: runs per stage since the scene started, indexed by [`scene_stage`].
    pub scene_stage_runs: [u64; 7],
    /// Scene: skips per stage (inputs unchanged, nothing to do, at rest), indexed by [`scene_stage`].
    pub scene_stage_skips: [u64; 7],
    /// Scene: 99th percentile of each stage's recent run times, s, indexed by [`scene_stage`].
    pub scene_stage_p99_s: [f64; 7],
    /// Scene: 99th percentile of the recent whole scene steps, s.
    pub scene_step_p99_s: f64,
    /// Scene: view clarity in front of the scope in [0, 1] (1 clear); NaN without a particle stage.
    pub view_clarity: f64,
    /// Scene: volume enclosed by the last published cavity surface, m^3 (NaN before the first).
    pub cavity_surface_volume_m3: f64,
    /// Scene: share of the inflow channel's area that opens on fluid in the flow field, [0, 1]
    /// (1: the jet leaves at `inflow_port_velocity_m_per_s`; less: tissue covers part of the tip
    /// and the jet is faster by 1 / this); NaN without a scene or before its first frame.
    pub inflow_port_open_fraction: f64,
    /// What the rig I/O and 1 kHz loop threads got from the system ([`realtime_mode`]): below
    /// `SCHED_FIFO` the daemon runs degraded (other processes can delay the loop).
    pub realtime_mode: u32,
    /// Scene: degradation level under overload, 0 full quality .. 3 (docs/daemon.md, "Overload").
    pub scene_degradation: u32,
    /// Scene: frames that started a frame period or more after they were due, since the scene
    /// started.
    pub scene_frames_late: u64,
    /// Scene: frame slots not stepped, since the scene started: nothing new from the loop (no
    /// frame is published twice) or passed while a late frame ran.
    pub scene_frames_skipped: u64,
    /// Longest time between two consecutive statuses since start, s (publication times).
    pub status_gap_max_s: f64,
}

/// Why the rig link is down, as carried in [`Status::link_down_reason`]. The daemon logs the full
/// message (with the device path) once per change of reason.
pub mod link_down_reason {
    /// The link is connected, or no attempt has failed yet.
    pub const NONE: u32 = 0;
    /// The device path does not exist (wrong path, rig not plugged in, udev rule missing).
    pub const DEVICE_NOT_FOUND: u32 = 1;
    /// The device exists but the daemon's user may not open it: join the group in
    /// `link_down_detail` (its id).
    pub const PERMISSION_DENIED: u32 = 2;
    /// Another program holds the port.
    pub const DEVICE_BUSY: u32 = 3;
    /// Opening or configuring the port failed for another reason (see the daemon's log).
    pub const OPEN_FAILED: u32 = 4;
    /// The port opened but the device never answered the handshake.
    pub const NO_HANDSHAKE: u32 = 5;
    /// The device speaks another wire protocol version (in `link_down_detail`).
    pub const INCOMPATIBLE_VERSION: u32 = 6;
    /// No valid frame within the link timeout (a hung firmware).
    pub const TIMEOUT: u32 = 7;
    /// The port failed or hung up during a session (cable pulled).
    pub const LOST: u32 = 8;
    /// No USB serial device with the configured ids.
    pub const USB_DEVICE_NOT_FOUND: u32 = 9;
    /// `link_down_detail` when the detail could not be read.
    pub const DETAIL_UNKNOWN: u32 = u32::MAX;

    /// Human-readable name of a reason value.
    pub fn name(value: u32) -> &'static str {
        match value {
            NONE => "none",
            DEVICE_NOT_FOUND => "device-not-found",
            PERMISSION_DENIED => "permission-denied",
            DEVICE_BUSY => "device-busy",
            OPEN_FAILED => "open-failed",
            NO_HANDSHAKE => "no-handshake",
            INCOMPATIBLE_VERSION => "incompatible-version",
            TIMEOUT => "timeout",
            LOST => "lost",
            USB_DEVICE_NOT_FOUND => "usb-device-not-found",
            _ => "unknown",
        }
    }
}

/// What the rig I/O and 1 kHz loop threads got from the system, as carried in
/// [`Status::realtime_mode`].
pub mod realtime_mode {
    /// Normal scheduling: no real-time privilege (or `loop.realtime_priority = 0`); degraded.
    pub const NORMAL: u32 = 0;
    /// Normal scheduling with a raised nice value (`loop.fallback_nice`); degraded.
    pub const NICE: u32 = 1;
    /// `SCHED_FIFO`: the loop preempts every ordinary thread of the machine.
    pub const FIFO: u32 = 2;

    /// Human-readable name of a value.
    pub fn name(value: u32) -> &'static str {
        match value {
            NORMAL => "normal (degraded)",
            NICE => "nice (degraded)",
            FIFO => "SCHED_FIFO",
            _ => "unknown",
        }
    }
}

/// Values of [`Status::scene_state`].
pub mod scene_state {
    /// No scene (disabled in the configuration).
    pub const NONE: u64 = 0;
    /// The scene's atlas is being loaded or built; the scene services do not exist yet.
    pub const PREPARING: u64 = 1;
    /// The scene steps and publishes; the fluid moves.
    pub const RUNNING: u64 = 2;
    /// The scene steps and publishes positions, but the fluid stage is at rest (skipped).
    pub const IDLE: u64 = 3;
    /// The scene could not be prepared (the log says why); hydraulics and status go on.
    pub const FAILED: u64 = 4;

    /// Human-readable name of a scene state value.
    pub fn name(value: u64) -> &'static str {
        match value {
            NONE => "none",
            PREPARING => "preparing",
            RUNNING => "running",
            IDLE => "idle",
            FAILED => "failed",
            _ => "unknown",
        }
    }
}

/// Indices of the per-stage arrays [`Status::scene_stage_runs`], `scene_stage_skips` and
/// `scene_stage_p99_s`: the scene pipeline's stages in order.
pub mod scene_stage {
    /// Names, by index.
    pub const NAMES: [&str; 7] = [
        "hydraulics",
        "deformation",
        "voxelize",
        "ports",
        "fluid",
        "vortices",
        "particles",
    ];
    /// The scene following the 1 kHz loop's hydraulic state.
    pub const HYDRAULICS: usize = 0;
    /// Atlas replay of the cavity surface.
    pub const DEFORMATION: usize = 1;
    /// Cavity surface to cell labels.
    pub const VOXELIZE: usize = 2;
    /// Scope, port and wall cells and their velocities.
    pub const PORTS: usize = 3;
    /// The fluid step.
    pub const FLUID: usize = 4;
    /// Rankine vortices.
    pub const VORTICES: usize = 5;
    /// Particles and view clarity.
    pub const PARTICLES: usize = 6;
}

/// Rig link states as carried in [`Status::link_state`].
pub mod link_state {
    /// No port open; waiting to (re)connect.
    pub const DISCONNECTED: u32 = 0;
    /// Port open, handshake in progress.
    pub const HANDSHAKING: u32 = 1;
    /// Handshake done, samples flowing.
    pub const CONNECTED: u32 = 2;
    /// Port open but no valid frame within the timeout.
    pub const STALE: u32 = 3;
    /// The device speaks an incompatible protocol version.
    pub const INCOMPATIBLE: u32 = 4;

    /// Human-readable name of a link state value.
    pub fn name(value: u32) -> &'static str {
        match value {
            DISCONNECTED => "disconnected",
            HANDSHAKING => "handshaking",
            CONNECTED => "connected",
            STALE => "stale",
            INCOMPATIBLE => "incompatible",
            _ => "unknown",
        }
    }
}

impl Default for Status {
    fn default() -> Self {
        Self {
            schema_version: crate::SCHEMA_VERSION,
            size_bytes: core::mem::size_of::<Status>() as u32,
            sequence: 0,
            run_id: 0,
            sim_time_s: 0.0,
            publish_monotonic_ns: 0,
            link_frames: 0,
            link_crc_errors: 0,
            link_malformed: 0,
            link_sequence_gaps: 0,
            link_resyncs: 0,
            link_reconnects: 0,
            link_clamped_values: 0,
            link_device_faults: 0,
            last_sample_age_s: f64::NAN,
            rig_device_time_us: 0,
            rig_valve_in_opening: 0.0,
            rig_valve_out_opening: 0.0,
            rig_pump_set_pressure_pa: 0.0,
            valve_in_opening: 0.0,
            valve_out_opening: 0.0,
            pump_set_pressure_pa: 0.0,
            scope_tip_position_m: [0.0; 3],
            scope_view_direction: [0.0, 0.0, 1.0],
            scope_orientation_wxyz: [1.0, 0.0, 0.0, 0.0],
            alarm_bits: 0,
            tick_rate_hz: 0.0,
            ticks: 0,
            deadline_misses: 0,
            tick_work_max_s: 0.0,
            latency_p50_s: f64::NAN,
            latency_p99_s: f64::NAN,
            latency_max_s: f64::NAN,
            latency_samples: 0,
            statuses_dropped: 0,
            link_state: link_state::DISCONNECTED,
            rig_sequence: 0,
            buttons: 0,
            scope_pose_valid: 0,
            safe_state: 1,
            reserved0: 0,
            cavity_pressure_pa: 0.0,
            cavity_volume_m3: 0.0,
            inflow_m3_per_s: 0.0,
            outflow_m3_per_s: 0.0,
            leak_m3_per_s: 0.0,
            absorption_m3_per_s: 0.0,
            perforation_m3_per_s: 0.0,
            inflow_port_velocity_m_per_s: 0.0,
            outflow_port_velocity_m_per_s: 0.0,
            fluid_in_m3: 0.0,
            fluid_collected_m3: 0.0,
            deficit_m3: 0.0,
            deficit_rate_m3_per_s: 0.0,
            deficit_limit_m3: 0.0,
            procedure_id: 0,
            procedure_time_s: 0.0,
            deficit_warning_stage: 0,
            hydraulic_flags: 0,
            link_down_reason: link_down_reason::NONE,
            link_down_detail: 0,
            scene_state: scene_state::NONE,
            scene_frames: 0,
            scene_stage_runs: [0; 7],
            scene_stage_skips: [0; 7],
            scene_stage_p99_s: [0.0; 7],
            scene_step_p99_s: 0.0,
            view_clarity: f64::NAN,
            cavity_surface_volume_m3: f64::NAN,
            inflow_port_open_fraction: f64::NAN,
            realtime_mode: realtime_mode::NORMAL,
            scene_degradation: 0,
            scene_frames_late: 0,
            scene_frames_skipped: 0,
            status_gap_max_s: 0.0,
        }
    }
}

/// Samples kept for late subscribers: the latest status.
pub const HISTORY_SIZE: usize = 1;
/// Samples buffered per subscriber; older ones are overwritten (safe overflow), never blocking.
pub const SUBSCRIBER_MAX_BUFFER_SIZE: usize = 64;
/// Subscribers the service admits at once (renderers, monitors, tools).
pub const MAX_SUBSCRIBERS: usize = 16;
/// Exactly one publisher: a second daemon on the same prefix is refused.
pub const MAX_PUBLISHERS: usize = 1;
/// Nodes that may hold the service open at once.
pub const MAX_NODES: usize = 32;

/// Shared memory (bytes, in `/dev/shm`) the daemon's status publisher pre-allocates: every
/// subscriber's buffer and borrowed samples, the history and the publisher's loans (an estimate:
/// iceoryx2 adds a few kB of management data).
pub fn shared_memory_bytes() -> usize {
    let qos = crate::slice::SliceQos {
        history_size: HISTORY_SIZE,
        subscriber_max_buffer_size: SUBSCRIBER_MAX_BUFFER_SIZE,
        max_subscribers: MAX_SUBSCRIBERS,
    };
    crate::slice::preallocated_samples(qos) * core::mem::size_of::<Status>()
}

/// The status service as the publishing daemon creates it (or re-opens it after a restart):
/// every quality-of-service setting of `docs/ipc.md` is set and verified.
pub fn create<S: Service>(
    node: &Node<S>,
    names: &ServiceNames,
) -> Result<PortFactory<S, Status, ()>, PublishSubscribeOpenOrCreateError> {
    node.service_builder(names.status())
        .publish_subscribe::<Status>()
        .history_size(HISTORY_SIZE)
        .subscriber_max_buffer_size(SUBSCRIBER_MAX_BUFFER_SIZE)
        .max_subscribers(MAX_SUBSCRIBERS)
        .max_publishers(MAX_PUBLISHERS)
        .max_nodes(MAX_NODES)
        .enable_safe_overflow(true)
        .open_or_create()
}

/// The status service as a subscriber opens it: fails with `DoesNotExist` while no daemon runs
/// on the prefix, and with `IncompatibleTypes` when the daemon speaks another schema version.
pub fn open<S: Service>(
    node: &Node<S>,
    names: &ServiceNames,
) -> Result<PortFactory<S, Status, ()>, PublishSubscribeOpenError> {
    node.service_builder(names.status())
        .publish_subscribe::<Status>()
        .open()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn status_has_no_implicit_padding() {
        // The sum of the field sizes equals the struct size: nothing hidden between fields.
        // 30 scalar 8-byte fields, 10 f64 in arrays, 8 u32 (2 at the start, 6 at the end), then
        // the 18 appended 8-byte hydraulic fields, then the 2 appended u32 link-down fields, then
        // the scene's 2 + 3 * 7 + 3 8-byte fields, then the appended inflow port open fraction,
        // then the scheduling and pace fields (2 u32, 3 8-byte).
        let fields =
            8 * 30 + 8 * 10 + 4 * 8 + 8 * 18 + 4 * 2 + 8 * (2 + 3 * 7 + 3) + 8 + 4 * 2 + 8 * 3;
        assert_eq!(core::mem::size_of::<Status>(), fields);
        assert_eq!(core::mem::size_of::<Status>() % 8, 0);
        assert_eq!(core::mem::align_of::<Status>(), 8);
        assert_eq!(
            Status::default().size_bytes as usize,
            core::mem::size_of::<Status>()
        );
    }

    #[test]
    fn type_name_carries_the_schema_version() {
        use iceoryx2::prelude::ZeroCopySend;
        // SAFETY: only reads the name; the layout it vouches for is checked by the layout test.
        let name = unsafe { <Status as ZeroCopySend>::type_name() };
        assert_eq!(
            name,
            format!("hydrometra.v{}.Status", crate::SCHEMA_VERSION)
        );
    }

    #[test]
    fn link_state_names_match_drivers_numbering() {
        assert_eq!(link_state::name(2), "connected");
        assert_eq!(link_state::name(4), "incompatible");
        assert_eq!(link_state::name(99), "unknown");
    }
}
