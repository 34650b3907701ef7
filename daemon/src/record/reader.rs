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
        let truncated = for_each_message(buf, |m| {
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

/// A message's channel as the reader needs it.
struct ChannelInfo {
    topic: String,
    schema: String,
    encoding: String,
}

/// One message of the data section.
struct MessageRef<'a> {
    channel: &'a ChannelInfo,
    log_time: u64,
    data: &'a [u8],
}

/// The largest record accepted, bytes: the file's size (a record inside an LZ4 chunk can be
/// larger than its compressed bytes, but not than a file that holds them and its headers), at
/// least 1 MiB. A corrupt length field beyond it is an error, not an allocation.
fn record_length_limit(file_len: usize) -> usize {
    file_len.max(1 << 20)
}

/// Calls `on_message` for every message of the data section, in file order, chunks decompressed,
/// up to the data end record; returns why reading stopped early, if it did (a file cut short by
/// a kill, or corrupt).
///
/// `mcap::MessageStream` sets no record length limit, so a length field of a corrupt file made it
/// reserve that many bytes (a capacity-overflow panic or an abort); this drives the library's
/// sans-io reader with one.
fn for_each_message(buf: &[u8], mut on_message: impl FnMut(MessageRef<'_>)) -> Option<String> {
    use mcap::records::Record;
    use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};

    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_skip_end_magic(true)
            .with_record_length_limit(record_length_limit(buf.len())),
    );
    let mut schemas: BTreeMap<u16, String> = BTreeMap::new();
    let mut channels: BTreeMap<u16, ChannelInfo> = BTreeMap::new();
    let mut rest = buf;
    while let Some(event) = reader.next_event() {
        let (opcode, data) = match event {
            Ok(LinearReadEvent::ReadRequest(need)) => {
                let len = need.min(rest.len());
                reader.insert(len).copy_from_slice(&rest[..len]);
                reader.notify_read(len);
                rest = &rest[len..];
                continue;
            }
            Ok(LinearReadEvent::Record { data, opcode }) => (opcode, data),
            Err(e) => return Some(e.to_string()),
        };
        match mcap::parse_record(opcode, data) {
            Ok(Record::Schema { header, .. }) => {
                schemas.insert(header.id, header.name);
            }
            Ok(Record::Channel(c)) => {
                let schema = match (c.schema_id, schemas.get(&c.schema_id)) {
                    (0, _) => String::new(),
                    (_, Some(name)) => name.clone(),
                    (id, None) => {
                        return Some(format!(
                            "channel {} ({}) refers to schema {id}, which is not defined",
                            c.id, c.topic
                        ))
                    }
                };
                channels.insert(
                    c.id,
                    ChannelInfo {
                        topic: c.topic,
                        schema,
                        encoding: c.message_encoding,
                    },
                );
            }
            Ok(Record::Message { header, data }) => {
                let Some(channel) = channels.get(&header.channel_id) else {
                    return Some(format!(
                        "message on channel {}, which is not defined",
                        header.channel_id
                    ));
                };
                on_message(MessageRef {
                    channel,
                    log_time: header.log_time,
                    data: &data,
                });
            }
            Ok(Record::DataEnd(_)) => return None,
            Ok(_) => {}
            Err(e) => return Some(e.to_string()),
        }
    }
    None
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
