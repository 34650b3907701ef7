//! Faults the emulated rig can inject, on a schedule (scenario `[faults]` table) or on request.
//!
//! ```toml
//! [faults]
//! chunk_max_bytes = 5        # optional: write every frame in random chunks of 1..=5 bytes
//! [[faults.event]]
//! at_s = 10.0                # seconds after the emulator started
//! kind = "garbage_burst"     # garbage_burst | bit_flips | drop_frames | heartbeat_stop |
//! bytes = 64                 #   unplug | wrong_version | fault_report | chunking
//! ```
//! Per kind: `garbage_burst` takes `bytes`; `bit_flips` and `drop_frames` take `count` (sample frames
//! affected); `heartbeat_stop` and `unplug` take `duration_s` (silence, or time until replug);
//! `wrong_version` takes `count` (host hellos answered with protocol version 2); `fault_report`
//! takes `code`, optional `severity` (default 1) and `detail` (default 0); `chunking` takes
//! `max_bytes` (0 switches chunking off).

use std::time::Duration;

use serde::Deserialize;
use toml::Spanned;

use super::scenario_error::{line_of, ScenarioError};

/// One fault.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Fault {
    /// Writes `bytes` random bytes between two frames.
    GarbageBurst {
        /// Number of garbage bytes.
        bytes: usize,
    },
    /// Flips one random bit in each of the next `count` sample frames (before COBS, so each is
    /// a CRC error at the host).
    BitFlips {
        /// Frames affected.
        count: u32,
    },
    /// Does not send the next `count` sample frames (their sequence numbers are used up).
    DropFrames {
        /// Frames dropped.
        count: u32,
    },
    /// The firmware hangs: no heartbeats, no samples, host frames ignored, port still open.
    HeartbeatStop {
        /// How long.
        duration: Duration,
    },
    /// Closes the pseudo-terminal (the cable is pulled) and opens a new one after `duration`.
    Unplug {
        /// Time until replug.
        duration: Duration,
    },
    /// Answers the next `count` host hellos with a protocol-version-2 device hello.
    WrongVersion {
        /// Hellos answered wrongly.
        count: u32,
    },
    /// Sends a device fault report.
    FaultReport {
        /// Fault code.
        code: u16,
        /// Severity 0..=2.
        severity: u8,
        /// Detail word.
        detail: u32,
    },
    /// Writes every following frame in random chunks of 1..=`max_bytes` bytes (0: whole frames).
    Chunking {
        /// Largest chunk.
        max_bytes: usize,
    },
}

/// A fault at a time after the emulator started.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FaultEvent {
    /// Seconds after start.
    pub at_s: f64,
    /// The fault.
    pub fault: Fault,
}

/// Which faults to inject and when.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct FaultPlan {
    /// Chunking from the start (0: off).
    pub chunk_max_bytes: usize,
    /// Timed events, in any order.
    pub events: Vec<FaultEvent>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct FaultPlanFile {
    #[serde(default)]
    chunk_max_bytes: Option<Spanned<i64>>,
    #[serde(default)]
    event: Vec<Spanned<FaultEventFile>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FaultEventFile {
    at_s: Spanned<f64>,
    kind: Spanned<String>,
    bytes: Option<Spanned<i64>>,
    count: Option<Spanned<i64>>,
    duration_s: Option<Spanned<f64>>,
    max_bytes: Option<Spanned<i64>>,
    code: Option<Spanned<i64>>,
    severity: Option<Spanned<i64>>,
    detail: Option<Spanned<i64>>,
}

impl FaultPlanFile {
    pub(crate) fn validate(self, text: &str, origin: &str) -> Result<FaultPlan, ScenarioError> {
        let err = |span: std::ops::Range<usize>, key: String, value: String, expected: &str| {
            ScenarioError::Invalid {
                origin: origin.to_string(),
                line: line_of(text, span.start),
                key,
                value,
                expected: expected.to_string(),
            }
        };
        let int = |v: &Spanned<i64>, key: String, lo: i64, hi: i64| -> Result<i64, ScenarioError> {
            let x = *v.get_ref();
            if (lo..=hi).contains(&x) {
                Ok(x)
            } else {
                Err(err(
                    v.span(),
                    key,
                    x.to_string(),
                    &format!("an integer in [{lo}, {hi}]"),
                ))
            }
        };
        let chunk_max_bytes = match &self.chunk_max_bytes {
            Some(v) => int(v, "faults.chunk_max_bytes".into(), 0, 4096)? as usize,
            None => 0,
        };
        let mut events = Vec::with_capacity(self.event.len());
        for (i, ev) in self.event.iter().enumerate() {
            let span = ev.span();
            let ev = ev.get_ref();
            let key = |name: &str| format!("faults.event[{i}].{name}");
            let at_s = *ev.at_s.get_ref();
            if !(at_s.is_finite() && at_s >= 0.0) {
                return Err(err(
                    ev.at_s.span(),
                    key("at_s"),
                    at_s.to_string(),
                    "a time >= 0 s",
                ));
            }
            let need_int = |v: &Option<Spanned<i64>>, name: &str, lo: i64, hi: i64| match v {
                Some(v) => int(v, key(name), lo, hi),
                None => Err(err(
                    span.clone(),
                    key(name),
                    "missing".into(),
                    &format!(
                        "an integer in [{lo}, {hi}] for kind `{}`",
                        ev.kind.get_ref()
                    ),
                )),
            };
            let need_duration = || match &ev.duration_s {
                Some(v) => {
                    let d = *v.get_ref();
                    if d.is_finite() && d > 0.0 && d <= 3600.0 {
                        Ok(Duration::from_secs_f64(d))
                    } else {
                        Err(err(
                            v.span(),
                            key("duration_s"),
                            d.to_string(),
                            "a duration in (0, 3600] s",
                        ))
                    }
                }
                None => Err(err(
                    span.clone(),
                    key("duration_s"),
                    "missing".into(),
                    &format!("a duration in (0, 3600] s for kind `{}`", ev.kind.get_ref()),
                )),
            };
            let fault =
                match ev.kind.get_ref().as_str() {
                    "garbage_burst" => Fault::GarbageBurst {
                        bytes: need_int(&ev.bytes, "bytes", 1, 65536)? as usize,
                    },
                    "bit_flips" => Fault::BitFlips {
                        count: need_int(&ev.count, "count", 1, 1_000_000)? as u32,
                    },
                    "drop_frames" => Fault::DropFrames {
                        count: need_int(&ev.count, "count", 1, 1_000_000)? as u32,
                    },
                    "heartbeat_stop" => Fault::HeartbeatStop {
                        duration: need_duration()?,
                    },
                    "unplug" => Fault::Unplug {
                        duration: need_duration()?,
                    },
                    "wrong_version" => Fault::WrongVersion {
                        count: need_int(&ev.count, "count", 1, 1000)? as u32,
                    },
                    "fault_report" => Fault::FaultReport {
                        code: need_int(&ev.code, "code", 0, 65535)? as u16,
                        severity: match &ev.severity {
                            Some(v) => int(v, key("severity"), 0, 2)? as u8,
                            None => 1,
                        },
                        detail: match &ev.detail {
                            Some(v) => int(v, key("detail"), 0, u32::MAX as i64)? as u32,
                            None => 0,
                        },
                    },
                    "chunking" => Fault::Chunking {
                        max_bytes: need_int(&ev.max_bytes, "max_bytes", 0, 4096)? as usize,
                    },
                    other => return Err(err(
                        ev.kind.span(),
                        key("kind"),
                        format!("{other:?}"),
                        "one of garbage_burst, bit_flips, drop_frames, heartbeat_stop, unplug, \
                         wrong_version, fault_report, chunking",
                    )),
                };
            events.push(FaultEvent { at_s, fault });
        }
        events.sort_by(|a, b| a.at_s.total_cmp(&b.at_s));
        Ok(FaultPlan {
            chunk_max_bytes,
            events,
        })
    }
}
