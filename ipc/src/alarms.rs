//! Alarm bits of [`crate::Status::alarm_bits`]. Bits 0-7: daemon and rig; 8-15: hydraulics
//! (docs/hydraulics.md); 16-63: reserved, always 0.

/// The rig link is not `connected` (disconnected, handshaking, stale or incompatible).
pub const RIG_LINK_LOST: u64 = 1 << 0;
/// The simulation runs on the safe inputs: valves closed, pump at 0 Pa (see `docs/ipc.md`).
pub const RIG_SAFE_STATE: u64 = 1 << 1;
/// The rig speaks an incompatible wire protocol version.
pub const RIG_INCOMPATIBLE: u64 = 1 << 2;
/// The scope pose is invalid (tracker occluded or out of range) or not current.
pub const SCOPE_POSE_INVALID: u64 = 1 << 3;
/// A simulation tick missed its deadline within the last second.
pub const DEADLINE_MISSED: u64 = 1 << 4;
/// The procedure recording stopped on an error (disk full, directory not writable); the
/// procedure and its deficit go on. Clears when a recording starts again.
pub const RECORDING_FAILED: u64 = 1 << 5;

/// Hydraulics: fluid deficit reached 50 % of the configured limit.
pub const DEFICIT_WARNING_50: u64 = 1 << 8;
/// Hydraulics: fluid deficit reached 75 % of the configured limit.
pub const DEFICIT_WARNING_75: u64 = 1 << 9;
/// Hydraulics: fluid deficit reached the configured limit.
pub const DEFICIT_LIMIT: u64 = 1 << 10;
/// Hydraulics: the deficit rises faster than the configured rate limit.
pub const DEFICIT_RATE: u64 = 1 << 11;
/// Hydraulics: the procedure is terminated (limit reached).
pub const PROCEDURE_TERMINATED: u64 = 1 << 12;
/// Hydraulics: cavity pressure above the configured maximum.
pub const OVERPRESSURE: u64 = 1 << 13;

/// Every defined bit with its name, lowest bit first (for monitors and logs).
pub const ALL: [(u64, &str); 12] = [
    (RIG_LINK_LOST, "rig-link-lost"),
    (RIG_SAFE_STATE, "rig-safe-state"),
    (RIG_INCOMPATIBLE, "rig-incompatible"),
    (SCOPE_POSE_INVALID, "scope-pose-invalid"),
    (DEADLINE_MISSED, "deadline-missed"),
    (RECORDING_FAILED, "recording-failed"),
    (DEFICIT_WARNING_50, "deficit-50"),
    (DEFICIT_WARNING_75, "deficit-75"),
    (DEFICIT_LIMIT, "deficit-limit"),
    (DEFICIT_RATE, "deficit-rate"),
    (PROCEDURE_TERMINATED, "terminated"),
    (OVERPRESSURE, "overpressure"),
];

/// Names of the bits set in `bits`, lowest first; unknown bits as `bit<N>`.
pub fn names(bits: u64) -> Vec<String> {
    (0..64)
        .filter(|i| bits & (1u64 << i) != 0)
        .map(|i| {
            ALL.iter()
                .find(|(b, _)| *b == 1u64 << i)
                .map(|(_, n)| (*n).to_string())
                .unwrap_or_else(|| format!("bit{i}"))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bits_are_distinct_and_named() {
        let mut seen = 0u64;
        for (bit, _) in ALL {
            assert_eq!(bit.count_ones(), 1);
            assert_eq!(seen & bit, 0);
            seen |= bit;
        }
        assert_eq!(
            names(RIG_LINK_LOST | DEFICIT_LIMIT | (1 << 40)),
            vec!["rig-link-lost", "deficit-limit", "bit40"]
        );
    }
}
