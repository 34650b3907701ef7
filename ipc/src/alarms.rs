//! Alarm bits of [`crate::Status::alarm_bits`]. Bits 0-7: daemon and rig; 8-15: hydraulics
//! (docs/hydraulics.md); 16-63: reserved, always 0. Specified in docs/ipc.md, "Alarm bits".

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

/// Hydraulics: the fluid deficit reached warning stage 1, `deficit.warning_fractions[0]` of the
/// limit (the name is the default fraction, 0.5).
pub const DEFICIT_WARNING_50: u64 = 1 << 8;
/// Hydraulics: the fluid deficit reached warning stage 2, `deficit.warning_fractions[1]` of the
/// limit (the name is the default fraction, 0.75).
pub const DEFICIT_WARNING_75: u64 = 1 << 9;
/// Hydraulics: fluid deficit reached the configured limit.
pub const DEFICIT_LIMIT: u64 = 1 << 10;
/// Hydraulics: the deficit rises faster than the configured rate limit.
pub const DEFICIT_RATE: u64 = 1 << 11;
/// Hydraulics: the procedure is terminated (limit reached).
pub const PROCEDURE_TERMINATED: u64 = 1 << 12;
/// Hydraulics: cavity pressure above the configured maximum.
pub const OVERPRESSURE: u64 = 1 << 13;
/// Hydraulics: the fluid deficit reached warning stage 3, `deficit.warning_fractions[2]` of the
/// limit (the name is the default fraction, 0.9).
pub const DEFICIT_WARNING_90: u64 = 1 << 14;

/// The warning-stage bits in stage order: `DEFICIT_WARNING_STAGES[i]` is set once the deficit
/// reached warning stage `i + 1` of the configured `deficit.warning_fractions`. The daemon accepts
/// no more stages than there are bits here.
pub const DEFICIT_WARNING_STAGES: [u64; 3] =
    [DEFICIT_WARNING_50, DEFICIT_WARNING_75, DEFICIT_WARNING_90];

/// The bits of the warning stages reached: the first `stages_reached` of
/// [`DEFICIT_WARNING_STAGES`].
pub fn deficit_warning_bits(stages_reached: usize) -> u64 {
    DEFICIT_WARNING_STAGES
        .iter()
        .take(stages_reached)
        .fold(0, |bits, bit| bits | bit)
}

/// Every defined bit with its name, lowest bit first (for monitors and logs).
pub const ALL: [(u64, &str); 13] = [
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
    (DEFICIT_WARNING_90, "deficit-90"),
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
        for w in ALL.windows(2) {
            assert!(w[0].0 < w[1].0, "ALL is lowest bit first");
        }
    }

    #[test]
    fn warning_stages_set_their_bits_in_stage_order() {
        assert_eq!(deficit_warning_bits(0), 0);
        assert_eq!(deficit_warning_bits(1), DEFICIT_WARNING_50);
        assert_eq!(
            deficit_warning_bits(2),
            DEFICIT_WARNING_50 | DEFICIT_WARNING_75
        );
        let all = DEFICIT_WARNING_50 | DEFICIT_WARNING_75 | DEFICIT_WARNING_90;
        assert_eq!(deficit_warning_bits(3), all);
        assert_eq!(deficit_warning_bits(200), all);
    }
}
