//! The calibrated rig state handed to the daemon: SI units, organ frame, timestamped.

use std::time::Instant;

/// Pose of the scope in the organ frame (see `hydrometra_sim::mesh` for the frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScopePose {
    /// Position of the scope tip (after the tool-tip offset), metres.
    pub tip_position_m: [f64; 3],
    /// Unit vector along the scope's viewing axis.
    pub view_direction: [f64; 3],
    /// Orientation as a unit quaternion `[w, x, y, z]`.
    pub orientation: [f64; 4],
    /// False when the tracker reported the pose as invalid (occluded, out of range).
    pub valid: bool,
}

/// One calibrated rig sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigState {
    /// Device timestamp of the sample, microseconds since the device booted.
    pub device_time_us: u64,
    /// Host time at which the sample's frame was decoded.
    pub received_at: Instant,
    /// Wire sequence number of the sample frame.
    pub sequence: u32,
    /// Inflow valve opening in [0, 1] (0 closed).
    pub valve_in_opening: f64,
    /// Outflow valve opening in [0, 1] (0 closed).
    pub valve_out_opening: f64,
    /// Pump set pressure, Pa.
    pub pump_set_pressure_pa: f64,
    /// Scope pose in the organ frame.
    pub scope: ScopePose,
    /// Button bit field as reported by the device.
    pub buttons: u32,
}

/// State of the link to the rig.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum LinkState {
    /// No port open; waiting to (re)connect.
    Disconnected = 0,
    /// Port open, handshake in progress.
    Handshaking = 1,
    /// Handshake done, samples flowing.
    Connected = 2,
    /// Port open but no valid frame within the timeout.
    Stale = 3,
    /// The device speaks an incompatible protocol version; retried with backoff.
    Incompatible = 4,
}

/// Cumulative link counters since the transport started.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LinkCounters {
    /// Valid frames decoded.
    pub frames: u64,
    /// Frames rejected for a bad CRC.
    pub crc_errors: u64,
    /// Frames rejected for malformed content (bad COBS, length, type, version).
    pub malformed: u64,
    /// Sequence numbers skipped by the device's frames (sum of gap sizes).
    pub sequence_gaps: u64,
    /// Times the decoder discarded bytes to find the next frame boundary.
    pub resyncs: u64,
    /// Successful reconnections after a loss.
    pub reconnects: u64,
    /// Sensor values clamped or rejected by calibration (out of range, NaN).
    pub clamped_values: u64,
    /// Device fault reports received.
    pub device_faults: u64,
}

/// Why the link is not connected: the last failure the transport saw (cleared by a successful
/// handshake). Each carries what a user needs to act on it; the full message is in
/// `LinkSnapshot::last_error`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum LinkDownReason {
    /// The device path does not exist (wrong path, rig not plugged in, udev rule missing).
    DeviceNotFound,
    /// No USB serial device with the configured vendor/product id (and serial number).
    UsbDeviceNotFound,
    /// The device exists but this user may not open it.
    PermissionDenied {
        /// Group id owning the device node (the group to join), if it could be read.
        gid: Option<u32>,
    },
    /// Another process holds the port (exclusive lock).
    DeviceBusy,
    /// Opening or configuring the port failed for another reason.
    OpenFailed,
    /// The port opened but the device never answered the handshake.
    NoHandshake,
    /// The device answered with another wire protocol version.
    IncompatibleVersion {
        /// The version the device speaks.
        version: u8,
    },
    /// No valid frame within the link timeout (a hung firmware); the port was reopened.
    Timeout,
    /// The port failed or hung up during a session (cable pulled).
    Lost,
}
