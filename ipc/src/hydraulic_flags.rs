//! Bits of [`crate::Status::hydraulic_flags`], set by the daemon's hydraulics stage
//! (docs/hydraulics.md). Bits 5-63 are reserved, always 0.

/// The hydraulics stage is active: the hydraulic fields of the status are valid.
pub const ACTIVE: u64 = 1 << 0;
/// The cavity is perforated.
pub const PERFORATED: u64 = 1 << 1;
/// The pump is stopped because the procedure is terminated.
pub const PUMP_STOPPED: u64 = 1 << 2;
/// The pump delivers its maximum flow.
pub const PUMP_FLOW_LIMITED: u64 = 1 << 3;
/// The procedure was restored from the record when the daemon started.
pub const RESTORED: u64 = 1 << 4;

/// Every defined bit with its name, lowest bit first (for monitors and logs).
pub const ALL: [(u64, &str); 5] = [
    (ACTIVE, "active"),
    (PERFORATED, "perforated"),
    (PUMP_STOPPED, "pump-stopped"),
    (PUMP_FLOW_LIMITED, "pump-flow-limited"),
    (RESTORED, "restored"),
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bits_are_distinct_and_contiguous_from_bit_0() {
        let mut seen = 0u64;
        for (bit, _) in ALL {
            assert_eq!(bit.count_ones(), 1);
            assert_eq!(seen & bit, 0);
            seen |= bit;
        }
        assert_eq!(seen, (1 << ALL.len()) - 1);
    }
}
