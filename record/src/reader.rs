//! Reads a recording back into memory. An unfinished file (the daemon was killed) is read up to
//! its last complete chunk; [`Recording::truncated`] then says where reading stopped.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use hydrometra_ipc::Status;

use super::format::{self, AlarmChange, ControlEvent};
use super::RecordError;

/// One received chunk of rig bytes.
#[derive(Debug, Clone, PartialEq)]
pub struct RxRecord {
    /// MCAP log time, ns since the Unix epoch.
    pub log_time_ns: u64,
    /// Host `CLOCK_MONOTONIC` of the read, ns.
    pub host_monotonic_ns: u64,
    /// The bytes as read.
    pub bytes: Vec<u8>,
}

/// Count and time span of one channel.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ChannelSummary {
    /// Messages read.
    pub messages: u64,
    /// First and last log time, ns.
    pub first_ns: u64,
    /// Last log time, ns.
    pub last_ns: u64,
    /// The longest interval between two consecutive messages, ns.
    pub max_gap_ns: u64,
    /// Log time at which that interval started.
    pub max_gap_at_ns: u64,
    /// Schema name.
    pub schema: String,
    /// Message encoding.
    pub encoding: String,
}

/// A recording in memory.
#[derive(Debug, Clone, Default)]
pub struct Recording {
    /// The file.
    pub path: PathBuf,
    /// The `hydrometra` metadata record.
    pub metadata: BTreeMap<String, String>,
    /// Received rig bytes.
    pub rx: Vec<RxRecord>,
    /// Statuses with their log time, ns.
    pub statuses: Vec<(u64, Status)>,
    /// Alarm changes with their log time, ns.
    pub alarms: Vec<(u64, AlarmChange)>,
    /// Control events with their log time, ns.
    pub events: Vec<(u64, ControlEvent)>,
    /// Per topic.
    pub channels: BTreeMap<String, ChannelSummary>,
    /// Messages on topics this build does not know, or that did not decode.
    pub skipped: u64,
    /// Why reading stopped before a proper end (an unfinished file), if it did.
    pub truncated: Option<String>,
}

impl Recording {
    /// Reads `path`.
    pub fn load(path: &Path) -> Result<Self, RecordError> {
        let buf = std::fs::read(path).map_err(|source| RecordError::Io {
            path: path.display().to_string(),
            source,
        })?;
        Self::from_bytes(path, &buf)
    }

    /// Parses a recording held in memory; `path` names it in errors.
    pub fn from_bytes(path: &Path, buf: &[u8]) -> Result<Self, RecordError> {
        let name = path.display().to_string();
        if !buf.starts_with(mcap::MAGIC) {
            return Err(RecordError::Format {
                path: name,
                message: "not an MCAP file (no MCAP magic at the start)".into(),
            });
        }
        let mut rec = Recording {
            path: path.to_path_buf(),
            ..Default::default()
        };
        let options: mcap::read::Options = mcap::read::Options::IgnoreEndMagic;
        // Metadata records sit between chunks: one linear pass over the top-level records.
        if let Ok(records) = mcap::read::LinearReader::new_with_options(buf, options.into()) {
            for r in records {
                match r {
                    Ok(mcap::records::Record::Metadata(m)) if m.name == format::METADATA_NAME => {
                        rec.metadata = m.metadata;
                    }
                    Ok(_) => {}
                    Err(_) => break,
                }
            }
        }
        let stream = mcap::MessageStream::new_with_options(buf, options.into()).map_err(|e| {
            RecordError::Mcap {
                path: name.clone(),
                message: e.to_string(),
            }
        })?;
        for m in stream {
            let m = match m {
                Ok(m) => m,
                Err(e) => {
                    rec.truncated = Some(e.to_string());
                    break;
                }
            };
            let topic = m.channel.topic.clone();
            let c = rec
                .channels
                .entry(topic.clone())
                .or_insert_with(|| ChannelSummary {
                    first_ns: m.log_time,
                    last_ns: m.log_time,
                    schema: m
                        .channel
                        .schema
                        .as_ref()
                        .map(|s| s.name.clone())
                        .unwrap_or_default(),
                    encoding: m.channel.message_encoding.clone(),
                    ..Default::default()
                });
            if c.messages > 0 {
                let gap = m.log_time.saturating_sub(c.last_ns);
                if gap > c.max_gap_ns {
                    c.max_gap_ns = gap;
                    c.max_gap_at_ns = c.last_ns;
                }
            }
            c.messages += 1;
            c.first_ns = c.first_ns.min(m.log_time);
            c.last_ns = c.last_ns.max(m.log_time);
            let ok = match topic.as_str() {
                format::TOPIC_RIG_RX => format::split_rx(&m.data).map(|(t, bytes)| {
                    rec.rx.push(RxRecord {
                        log_time_ns: m.log_time,
                        host_monotonic_ns: t,
                        bytes: bytes.to_vec(),
                    })
                }),
                format::TOPIC_STATUS => {
                    format::status_from_bytes(&m.data).map(|s| rec.statuses.push((m.log_time, s)))
                }
                format::TOPIC_ALARMS => serde_json::from_slice::<AlarmChange>(&m.data)
                    .ok()
                    .map(|a| rec.alarms.push((m.log_time, a))),
                format::TOPIC_EVENTS => serde_json::from_slice::<ControlEvent>(&m.data)
                    .ok()
                    .map(|e| rec.events.push((m.log_time, e))),
                _ => None,
            };
            if ok.is_none() {
                rec.skipped += 1;
            }
        }
        // Chunks are written in time order per flush, but a late status may follow a chunk of
        // reads: order each stream by time.
        rec.rx.sort_by_key(|r| r.host_monotonic_ns);
        rec.statuses.sort_by_key(|(t, _)| *t);
        rec.alarms.sort_by_key(|(t, _)| *t);
        rec.events.sort_by_key(|(t, _)| *t);
        Ok(rec)
    }

    /// First and last log time over all channels, ns.
    pub fn span_ns(&self) -> Option<(u64, u64)> {
        let first = self.channels.values().map(|c| c.first_ns).min()?;
        let last = self.channels.values().map(|c| c.last_ns).max()?;
        Some((first, last))
    }

    /// The replay script of the received bytes (see `hydrometra_drivers::emulator::replay`).
    pub fn replay_script(&self) -> hydrometra_drivers::emulator::ReplayScript {
        hydrometra_drivers::emulator::ReplayScript::from_chunks(
            self.rx
                .iter()
                .map(|r| (r.host_monotonic_ns, r.bytes.as_slice())),
        )
    }
}
