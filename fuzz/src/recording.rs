//! The MCAP recording reader (`Recording::from_bytes`, what `Recording::load`, `hydrometra record
//! info`, `debrief` and `--replay` run).
//!
//! Properties: an error starts with the file name; an accepted recording accounts for every
//! message once (per-channel counts = decoded rig chunks + statuses + alarms + events + skipped),
//! has each stream in time order and consistent channel spans, and its replay script builds.
//! The memory budget (`crate::TARGETS`) allows an LZ4 chunk's full expansion of the input and no
//! more: a size field alone must not reserve memory.

use std::path::Path;

use hydrometra_record::reader::Recording;

const ORIGIN: &str = "fuzz.mcap";

/// The recording target.
pub fn check(data: &[u8]) {
    match Recording::from_bytes(Path::new(ORIGIN), data) {
        Err(e) => {
            let msg = e.to_string();
            assert!(msg.starts_with(&format!("{ORIGIN}: ")), "{msg}");
        }
        Ok(rec) => {
            let counted: u64 = rec.channels.values().map(|c| c.messages).sum();
            let decoded = (rec.rx.len() + rec.statuses.len() + rec.alarms.len() + rec.events.len())
                as u64
                + rec.skipped;
            assert_eq!(counted, decoded, "messages counted per channel vs decoded");
            assert!(rec
                .rx
                .windows(2)
                .all(|w| w[0].host_monotonic_ns <= w[1].host_monotonic_ns));
            assert!(rec.statuses.windows(2).all(|w| w[0].0 <= w[1].0));
            assert!(rec.alarms.windows(2).all(|w| w[0].0 <= w[1].0));
            assert!(rec.events.windows(2).all(|w| w[0].0 <= w[1].0));
            for (topic, c) in &rec.channels {
                assert!(c.messages > 0, "{topic}");
                assert!(c.first_ns <= c.last_ns, "{topic}: {c:?}");
                assert!(c.max_gap_ns <= c.last_ns - c.first_ns, "{topic}: {c:?}");
            }
            if let Some((first, last)) = rec.span_ns() {
                assert!(first <= last);
            }
            let _ = rec.replay_script();
        }
    }
}
