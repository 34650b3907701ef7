//! One pass over an MCAP file's data section with every length field checked before anything is
//! reserved for it: the records [`super::reader`] needs (the `hydrometra` metadata, schemas,
//! channels, messages), chunks decompressed, up to the data end record.
//!
//! The `mcap` crate trusts two kinds of length: a record's (its `MessageStream` sets no limit)
//! and a string's inside a record (its parser reserves the claimed u32 length before reading, up
//! to 4 GiB). A corrupt file therefore made `hydrometra record info` panic or reserve gigabytes
//! (both found by the `recording` fuzz target); here a record is limited to the file's size and a
//! string to the bytes left in its record, and a violation ends reading with the reason.

use std::collections::BTreeMap;

use mcap::records::{op, Record};
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};

use super::format;

/// A message's channel as the reader needs it.
pub(crate) struct ChannelInfo {
    pub topic: String,
    pub schema: String,
    pub encoding: String,
}

/// One message of the data section.
pub(crate) struct MessageRef<'a> {
    pub channel: &'a ChannelInfo,
    pub log_time: u64,
    pub data: &'a [u8],
}

/// What the data section holds for the reader, in file order.
pub(crate) enum Item<'a> {
    /// The `hydrometra` metadata record's key-value pairs.
    Metadata(BTreeMap<String, String>),
    /// A message.
    Message(MessageRef<'a>),
}

/// The largest record accepted, bytes: the file's size (a record inside an LZ4 chunk can be
/// larger than its compressed bytes, but not than a file that holds them and its headers), at
/// least 1 MiB. A corrupt length field beyond it is an error, not an allocation.
fn record_length_limit(file_len: usize) -> usize {
    file_len.max(1 << 20)
}

/// Calls `on_item` for the metadata and every message of the data section, in file order, chunks
/// decompressed, up to the data end record; returns why reading stopped early, if it did (a file
/// cut short by a kill, or corrupt).
pub(crate) fn for_each_item(buf: &[u8], mut on_item: impl FnMut(Item<'_>)) -> Option<String> {
    // mcap's reader subtracts an uncompressed chunk's record lengths from the chunk's size without
    // a check (an overflow panic in a build with overflow checks, a misread otherwise): such a
    // chunk, and what follows it, is not handed to it.
    let (buf, bad_chunk) = match overrun_in_uncompressed_chunk(buf) {
        Some((offset, why)) => (&buf[..offset], Some(why)),
        None => (buf, None),
    };
    let why = read_records(buf, &mut on_item);
    why.or(bad_chunk)
}

fn read_records(buf: &[u8], on_item: &mut impl FnMut(Item<'_>)) -> Option<String> {
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
        // Only the records used are parsed (the others may hold strings of any claimed length).
        if !matches!(
            opcode,
            op::SCHEMA | op::CHANNEL | op::MESSAGE | op::METADATA | op::DATA_END
        ) {
            continue;
        }
        if let Err(e) = strings_fit(opcode, data) {
            return Some(format!("record 0x{opcode:02x}: {e}"));
        }
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
            Ok(Record::Metadata(m)) if m.name == format::METADATA_NAME => {
                on_item(Item::Metadata(m.metadata));
            }
            Ok(Record::Message { header, data }) => {
                let Some(channel) = channels.get(&header.channel_id) else {
                    return Some(format!(
                        "message on channel {}, which is not defined",
                        header.channel_id
                    ));
                };
                on_item(Item::Message(MessageRef {
                    channel,
                    log_time: header.log_time,
                    data: &data,
                }));
            }
            Ok(Record::DataEnd(_)) => return None,
            Ok(_) => {}
            Err(e) => return Some(e.to_string()),
        }
    }
    None
}

/// The offset of the first top-level uncompressed chunk holding a record that runs past the
/// chunk's records, and why; `None` if there is none (or the top level ends before one).
fn overrun_in_uncompressed_chunk(buf: &[u8]) -> Option<(usize, String)> {
    let mut at = mcap::MAGIC.len();
    while let Some(header) = buf.get(at..at.checked_add(OPCODE_LEN)?) {
        let len = usize::try_from(u64_le(&header[1..])).ok()?;
        // mcap streams a chunk's records before its end is read: a chunk cut short by the end of
        // the file is checked as far as it goes.
        let end = (at + OPCODE_LEN).checked_add(len)?;
        let body = &buf[at + OPCODE_LEN..end.min(buf.len())];
        match header[0] {
            op::CHUNK => {
                if let Some(why) = chunk_record_overrun(body) {
                    return Some((at, format!("chunk at offset {at}: {why}")));
                }
            }
            op::DATA_END | op::FOOTER => return None,
            _ => {}
        }
        if end >= buf.len() {
            return None;
        }
        at = end;
    }
    None
}

/// A record's opcode and length, bytes.
const OPCODE_LEN: usize = 9;

fn u64_le(b: &[u8]) -> u64 {
    let mut v = [0u8; 8];
    v.copy_from_slice(&b[..8]);
    u64::from_le_bytes(v)
}

/// In an uncompressed chunk's body (start and end times, uncompressed size and CRC, compression,
/// records length, records), the first record that runs past the records' length.
fn chunk_record_overrun(body: &[u8]) -> Option<String> {
    let mut f = Fields { body, at: 0 };
    f.skip(28, "chunk header").ok()?;
    let compression_len = f.u32("compression").ok()?;
    if compression_len != 0 {
        return None; // decompressed by mcap with its own bounds
    }
    let start = f.at;
    f.skip(8, "records length").ok()?;
    let records_len = u64_le(&body[start..]);
    let mut at = 0u64;
    let mut rest = &body[f.at..];
    while at < records_len {
        let Some(header) = rest.get(..OPCODE_LEN) else {
            return None; // a chunk cut short: mcap reports it
        };
        let len = u64_le(&header[1..]);
        let end = at
            .checked_add(OPCODE_LEN as u64)
            .and_then(|e| e.checked_add(len));
        match end {
            Some(end) if end <= records_len => {}
            _ => {
                return Some(format!(
                    "record 0x{:02x} of {len} bytes at offset {at} of its records runs past their {records_len} bytes",
                    header[0]
                ))
            }
        }
        rest = rest.get(OPCODE_LEN + usize::try_from(len).ok()?..)?;
        at += OPCODE_LEN as u64 + len;
    }
    None
}

/// Checks that every length-prefixed string of a schema, channel or metadata record (the MCAP
/// specification's layouts) fits in the bytes left in the record, before `mcap::parse_record`
/// reserves them. Other records pass unchecked.
fn strings_fit(opcode: u8, body: &[u8]) -> Result<(), String> {
    let mut r = Fields { body, at: 0 };
    match opcode {
        op::SCHEMA => {
            r.skip(2, "schema id")?;
            r.string("schema name")?;
            r.string("schema encoding")
        }
        op::CHANNEL => {
            r.skip(4, "channel and schema ids")?;
            r.string("channel topic")?;
            r.string("message encoding")?;
            r.string_map()
        }
        op::METADATA => {
            r.string("metadata name")?;
            r.string_map()
        }
        _ => Ok(()),
    }
}

/// A walk over a record's fields.
struct Fields<'a> {
    body: &'a [u8],
    at: usize,
}

impl Fields<'_> {
    fn skip(&mut self, n: usize, what: &str) -> Result<(), String> {
        match self.at.checked_add(n) {
            Some(end) if end <= self.body.len() => {
                self.at = end;
                Ok(())
            }
            _ => Err(format!(
                "{what} of {n} bytes at offset {} runs past the record's {} bytes",
                self.at,
                self.body.len()
            )),
        }
    }

    fn u32(&mut self, what: &str) -> Result<usize, String> {
        let start = self.at;
        self.skip(4, what)?;
        let b = &self.body[start..self.at];
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize)
    }

    fn string(&mut self, what: &str) -> Result<(), String> {
        let start = self.at;
        let len = self.u32(what)?;
        self.at = start;
        self.skip(4 + len, what)
    }

    /// A map's byte length, then key and value strings up to it.
    fn string_map(&mut self) -> Result<(), String> {
        let len = self.u32("map length")?;
        let end = self.at.saturating_add(len);
        while self.at < end {
            self.string("map key")?;
            self.string("map value")?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn string(s: &str) -> Vec<u8> {
        let mut b = (s.len() as u32).to_le_bytes().to_vec();
        b.extend_from_slice(s.as_bytes());
        b
    }

    fn metadata_record(name: &str, pairs: &[(&str, &str)]) -> Vec<u8> {
        let mut map = Vec::new();
        for (k, v) in pairs {
            map.extend(string(k));
            map.extend(string(v));
        }
        let mut b = string(name);
        b.extend((map.len() as u32).to_le_bytes());
        b.extend(map);
        b
    }

    #[test]
    fn well_formed_records_pass_and_parse() {
        let body = metadata_record("hydrometra", &[("run_id", "7"), ("rig_mode", "emulated")]);
        assert_eq!(strings_fit(op::METADATA, &body), Ok(()));
        let Ok(Record::Metadata(m)) = mcap::parse_record(op::METADATA, &body) else {
            panic!("the metadata record does not parse");
        };
        assert_eq!(m.metadata.len(), 2);
        let mut channel = vec![1, 0, 2, 0];
        channel.extend(string("/status"));
        channel.extend(string("hydrometra.status"));
        channel.extend(0u32.to_le_bytes());
        assert_eq!(strings_fit(op::CHANNEL, &channel), Ok(()));
    }

    // Found by fuzzing (fuzz target `recording`): a record inside an uncompressed chunk claiming
    // more than the chunk's records underflowed mcap's count of the bytes left in the chunk.
    #[test]
    fn a_record_running_past_its_uncompressed_chunk_ends_reading_before_the_chunk() {
        let mut message = vec![op::MESSAGE];
        message.extend(22u64.to_le_bytes()); // claims 22 bytes: channel, sequence, times
        message.extend([0u8; 22]);
        let mut chunk = vec![0u8; 28]; // times, uncompressed size and CRC
        chunk.extend(0u32.to_le_bytes()); // no compression
        chunk.extend(20u64.to_le_bytes()); // records: 20 bytes, the message needs 31
        chunk.extend(&message);
        let mut file = mcap::MAGIC.to_vec();
        file.push(op::CHUNK);
        file.extend((chunk.len() as u64).to_le_bytes());
        file.extend(&chunk);
        let at = mcap::MAGIC.len();
        let (offset, why) = overrun_in_uncompressed_chunk(&file).expect("the overrun");
        assert_eq!(offset, at);
        assert_eq!(
            why,
            format!(
                "chunk at offset {at}: record 0x05 of 22 bytes at offset 0 of its records runs past their 20 bytes"
            )
        );
        let mut messages = 0;
        let stop = for_each_item(&file, |_| messages += 1);
        assert_eq!(stop, Some(why));
        assert_eq!(messages, 0);
        // Cut short by the end of the file (the chunk claims more than follows): checked as far
        // as it goes.
        let mut cut = file.clone();
        cut[at + 1..at + 9].copy_from_slice(&(1u64 << 20).to_le_bytes());
        assert_eq!(
            overrun_in_uncompressed_chunk(&cut).map(|(o, _)| o),
            Some(at)
        );
        // The same chunk with a records length that holds the message passes the check.
        let fixed_at = at + OPCODE_LEN + 32;
        file[fixed_at..fixed_at + 8].copy_from_slice(&31u64.to_le_bytes());
        assert_eq!(overrun_in_uncompressed_chunk(&file), None);
    }

    #[test]
    fn a_string_claiming_more_than_its_record_is_named_with_its_offset() {
        let good = metadata_record("hydrometra", &[("run_id", "7")]);
        // The map's first key length (after the name and the map's own length).
        let key_at = 4 + "hydrometra".len() + 4;
        for (at, what) in [(0, "metadata name"), (key_at, "map key")] {
            let mut bad = good.clone();
            bad[at..at + 4].copy_from_slice(&0x0400_0000u32.to_le_bytes());
            let e = strings_fit(op::METADATA, &bad).unwrap_err();
            assert!(
                e.starts_with(what) && e.contains(&format!("at offset {at}")),
                "{e}"
            );
            assert!(e.contains(&format!("record's {} bytes", bad.len())), "{e}");
        }
        // A record cut inside a length field.
        assert!(strings_fit(op::SCHEMA, &[1, 0, 5]).is_err());
    }
}
