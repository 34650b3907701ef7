//! Topics, schemas and payload layouts of a recording (specified in `docs/recording.md`).
//!
//! Every message's MCAP `log_time` and `publish_time` are host wall-clock ns since the Unix epoch,
//! derived from `CLOCK_MONOTONIC` with one offset per file (metadata `clock`), so the time line
//! never jumps; payloads that need the monotonic time carry it.

use hydrometra_ipc::Status;
use serde::{Deserialize, Serialize};

/// Value of the MCAP header's `profile`.
pub const PROFILE: &str = "hydrometra";
/// Version of this recording format (metadata `hydrometra.format_version`).
pub const FORMAT_VERSION: u32 = 1;
/// Message encoding of the binary channels: little-endian, layout given by the schema.
pub const BINARY_ENCODING: &str = "hydrometra.binary";
/// Schema encoding of the binary channels' schemas: a plain-text description of the layout.
pub const LAYOUT_SCHEMA_ENCODING: &str = "hydrometra.layout";

/// Raw bytes as the host read them from the rig.
pub const TOPIC_RIG_RX: &str = "/rig/rx";
/// The status record of `docs/ipc.md`, at the recording's status rate.
pub const TOPIC_STATUS: &str = "/status";
/// Alarm bits raised or cleared (JSON).
pub const TOPIC_ALARMS: &str = "/alarms";
/// Control events: recording started and stopped, procedure changes, link state changes (JSON).
pub const TOPIC_EVENTS: &str = "/events";

/// Schema name of [`TOPIC_RIG_RX`].
pub const SCHEMA_RIG_RX: &str = "hydrometra.v1.RigRxChunk";
/// Schema text of [`TOPIC_RIG_RX`].
pub const SCHEMA_RIG_RX_TEXT: &str = "u64 host_monotonic_ns (LE) | u8[] bytes as read from the \
    rig's serial port (docs/rig-protocol.md framing; not yet decoded)";
/// Schema name of [`TOPIC_STATUS`] (the iceoryx2 payload type name).
pub const SCHEMA_STATUS: &str = "hydrometra.v1.Status";
/// Schema text of [`TOPIC_STATUS`].
pub const SCHEMA_STATUS_TEXT: &str =
    "hydrometra.v1.Status, repr(C) little-endian, layout of docs/ipc.md (size_bytes field gives \
     the writer's size)";
/// Schema name of [`TOPIC_ALARMS`].
pub const SCHEMA_ALARM: &str = "hydrometra.v1.AlarmChange";
/// Schema name of [`TOPIC_EVENTS`].
pub const SCHEMA_EVENT: &str = "hydrometra.v1.ControlEvent";
/// JSON schema of [`TOPIC_ALARMS`].
pub const SCHEMA_ALARM_JSON: &str = r#"{"type":"object","properties":{"sim_time_s":{"type":"number"},"procedure_time_s":{"type":"number"},"alarm_bits":{"type":"integer"},"raised":{"type":"array","items":{"type":"string"}},"cleared":{"type":"array","items":{"type":"string"}}}}"#;
/// JSON schema of [`TOPIC_EVENTS`].
pub const SCHEMA_EVENT_JSON: &str =
    r#"{"type":"object","properties":{"kind":{"type":"string"},"detail":{"type":"string"}}}"#;

/// Name of the MCAP metadata record describing the recording.
pub const METADATA_NAME: &str = "hydrometra";

/// Size of a [`TOPIC_RIG_RX`] payload's header (the monotonic time).
pub const RX_HEADER_LEN: usize = 8;

/// One alarm change.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AlarmChange {
    /// `sim_time_s` of the status that showed it.
    pub sim_time_s: f64,
    /// `procedure_time_s` of that status.
    pub procedure_time_s: f64,
    /// The whole alarm bit field after the change.
    pub alarm_bits: u64,
    /// Names of the bits that became set.
    pub raised: Vec<String>,
    /// Names of the bits that became clear.
    pub cleared: Vec<String>,
}

/// One control event.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ControlEvent {
    /// `recording_started`, `recording_stopped`, `procedure_changed`, `link_state` or `tap_drops`.
    pub kind: String,
    /// Free text (e.g. the reason, the new link state, drop counts).
    pub detail: String,
}

/// The bytes of a status as laid out in `docs/ipc.md`.
pub fn status_bytes(status: &Status) -> &[u8] {
    // SAFETY: `Status` is `repr(C)`, `Copy`, made of u32/u64/f64 fields with no implicit padding
    // (docs/ipc.md; the ipc crate's layout test checks every offset), so all its bytes are
    // initialised; the slice borrows `status` for its lifetime.
    unsafe {
        std::slice::from_raw_parts(
            (status as *const Status).cast::<u8>(),
            std::mem::size_of::<Status>(),
        )
    }
}

/// A status from its recorded bytes; `None` unless exactly one v1 status of this build's size.
pub fn status_from_bytes(bytes: &[u8]) -> Option<Status> {
    if bytes.len() != std::mem::size_of::<Status>() {
        return None;
    }
    // SAFETY: the length is checked; every bit pattern is a valid `Status` (integers and floats
    // only) and `read_unaligned` does not need the slice to be aligned.
    let status = unsafe { std::ptr::read_unaligned(bytes.as_ptr().cast::<Status>()) };
    (status.schema_version == hydrometra_ipc::SCHEMA_VERSION).then_some(status)
}

/// Splits a [`TOPIC_RIG_RX`] payload into the host monotonic time and the bytes.
pub fn split_rx(payload: &[u8]) -> Option<(u64, &[u8])> {
    let (head, bytes) = payload.split_at_checked(RX_HEADER_LEN)?;
    let t = u64::from_le_bytes(head.try_into().ok()?);
    Some((t, bytes))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn status_round_trips_through_its_bytes() {
        let s = Status {
            sequence: 17,
            cavity_pressure_pa: 1234.5,
            deficit_m3: 2.5e-4,
            alarm_bits: 1 << 13,
            ..Status::default()
        };
        let bytes = status_bytes(&s).to_vec();
        assert_eq!(bytes.len(), std::mem::size_of::<Status>());
        let back = status_from_bytes(&bytes).expect("decodes");
        assert_eq!(back.sequence, 17);
        assert_eq!(back.cavity_pressure_pa, 1234.5);
        assert_eq!(back.alarm_bits, 1 << 13);
        assert!(status_from_bytes(&bytes[1..]).is_none());
    }
}
