//! Reads a recording back into memory. An unfinished file (the daemon was killed) is read up to
//! its last complete chunk; [`Recording::truncated`] then says where reading stopped.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use hydrometra_ipc::Status;

use super::format::{self, AlarmChange, ControlEvent};
use super::scan::{self, Item};
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
        let truncated = scan::for_each_item(buf, |item| {
            let m = match item {
                Item::Metadata(metadata) => {
                    rec.metadata = metadata;
                    return;
                }
                Item::Message(m) => m,
            };
            let topic = m.channel.topic.clone();
            let c = rec
                .channels
                .entry(topic.clone())
                .or_insert_with(|| ChannelSummary {
                    first_ns: m.log_time,
                    last_ns: m.log_time,
                    schema: m.channel.schema.clone(),
                    encoding: m.channel.encoding.clone(),
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
                format::TOPIC_RIG_RX => format::split_rx(m.data).map(|(t, bytes)| {
                    rec.rx.push(RxRecord {
                        log_time_ns: m.log_time,
                        host_monotonic_ns: t,
                        bytes: bytes.to_vec(),
                    })
                }),
                format::TOPIC_STATUS => {
                    format::status_from_bytes(m.data).map(|s| rec.statuses.push((m.log_time, s)))
                }
                format::TOPIC_ALARMS => serde_json::from_slice::<AlarmChange>(m.data)
                    .ok()
                    .map(|a| rec.alarms.push((m.log_time, a))),
                format::TOPIC_EVENTS => serde_json::from_slice::<ControlEvent>(m.data)
                    .ok()
                    .map(|e| rec.events.push((m.log_time, e))),
                _ => None,
            };
            if ok.is_none() {
                rec.skipped += 1;
            }
        });
        rec.truncated = truncated;
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A file with one uncompressed chunk holding one message on `/events`.
    fn one_message_file() -> Vec<u8> {
        let mut out = std::io::Cursor::new(Vec::new());
        let mut w = mcap::WriteOptions::new()
            .compression(None)
            .create(&mut out)
            .unwrap();
        let schema = w
            .add_schema(format::SCHEMA_EVENT, "jsonschema", b"{}")
            .unwrap();
        let none = BTreeMap::new();
        let channel = w
            .add_channel(schema, format::TOPIC_EVENTS, "json", &none)
            .unwrap();
        let data = br#"{"kind":"recording_started","detail":"t"}"#;
        let header = mcap::records::MessageHeader {
            channel_id: channel,
            sequence: 0,
            log_time: 7,
            publish_time: 7,
        };
        w.write_to_known_channel(&header, data).unwrap();
        w.finish().unwrap();
        drop(w);
        out.into_inner()
    }

    #[test]
    fn a_well_formed_file_reads_whole() {
        let rec = Recording::from_bytes(Path::new("ok.mcap"), &one_message_file()).unwrap();
        assert_eq!(rec.events.len(), 1);
        assert_eq!(rec.events[0].0, 7);
        assert_eq!(rec.truncated, None);
    }

    // Found by fuzzing (fuzz target `recording`): the MCAP magic and a record claiming
    // 2^64 - 1 bytes overflowed the library's length arithmetic and, as a capacity overflow,
    // panicked `hydrometra record info`.
    #[test]
    fn a_top_level_record_longer_than_the_file_stops_reading_with_a_reason() {
        let mut bytes = mcap::MAGIC.to_vec();
        bytes.push(0x01);
        bytes.extend_from_slice(&u64::MAX.to_le_bytes());
        let rec = Recording::from_bytes(Path::new("huge.mcap"), &bytes).unwrap();
        let why = rec.truncated.expect("a truncation reason");
        assert!(why.contains("too large") || why.contains("record"), "{why}");
        assert!(rec.channels.is_empty());
    }

    // Found by fuzzing (fuzz target `recording`): a metadata record whose name claimed 64 MiB
    // made mcap's parser reserve them (any u32 length, up to 4 GiB) for a 31 kB file.
    #[test]
    fn a_string_longer_than_its_record_stops_reading_with_a_reason() {
        let mut bytes = mcap::MAGIC.to_vec();
        let mut body = 0x0400_0000u32.to_le_bytes().to_vec(); // the name's length
        body.extend_from_slice(b"hydrometra");
        body.extend_from_slice(&0u32.to_le_bytes()); // an empty map
        bytes.push(mcap::records::op::METADATA);
        bytes.extend_from_slice(&(body.len() as u64).to_le_bytes());
        bytes.extend_from_slice(&body);
        let rec = Recording::from_bytes(Path::new("long.mcap"), &bytes).unwrap();
        let why = rec.truncated.expect("a truncation reason");
        assert!(
            why.contains("metadata name") && why.contains("runs past the record's 18 bytes"),
            "{why}"
        );
        assert!(rec.metadata.is_empty());
    }

    #[test]
    fn the_metadata_record_is_read_from_the_data_section() {
        let mut out = std::io::Cursor::new(Vec::new());
        let mut w = mcap::WriteOptions::new().create(&mut out).unwrap();
        let metadata = BTreeMap::from([("run_id".to_string(), "42".to_string())]);
        w.write_metadata(&mcap::records::Metadata {
            name: format::METADATA_NAME.into(),
            metadata: metadata.clone(),
        })
        .unwrap();
        w.finish().unwrap();
        drop(w);
        let rec = Recording::from_bytes(Path::new("meta.mcap"), &out.into_inner()).unwrap();
        assert_eq!(rec.metadata, metadata);
        assert_eq!(rec.truncated, None);
    }

    // Found by fuzzing: a record inside a chunk claiming more bytes than the file made the reader
    // reserve them (a capacity-overflow panic, or an abort for a size that fits usize).
    #[test]
    fn a_record_in_a_chunk_claiming_more_than_the_file_is_refused_without_allocating() {
        let good = one_message_file();
        // The message record inside the chunk: opcode 0x05, u64 length, channel id 1.
        let at = good
            .windows(11)
            .position(|w| w[0] == 0x05 && w[9..11] == 1u16.to_le_bytes())
            .expect("the message record");
        for claimed in [u64::MAX, 1 << 40, good.len() as u64 * 4096] {
            let mut bad = good.clone();
            bad[at + 1..at + 9].copy_from_slice(&claimed.to_le_bytes());
            let rec = Recording::from_bytes(Path::new("bad.mcap"), &bad).unwrap();
            assert!(rec.truncated.is_some(), "length {claimed} accepted");
            assert!(rec.events.is_empty());
        }
    }
}
