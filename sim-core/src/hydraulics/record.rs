//! The procedure record: what must survive a daemon crash and restart.
//!
//! File format (version 1), UTF-8 text, two lines:
//!
//! ```text
//! hydrometra-procedure 1 crc32=1a2b3c4d
//! {"procedure":{"id":...,"started_unix_ms":...},"saved_unix_ms":...,...}
//! ```
//! The first line names the format, its version and the CRC-32 (IEEE 802.3, reflected, polynomial
//! 0xEDB88320, init and final xor 0xFFFFFFFF; "123456789" -> cbf43926) of the second line's bytes
//! (without the newline) in lower-case hex. The second line is the JSON of [`ProcedureRecord`].
//! [`ProcedureRecord::save`] writes atomically: a temporary file in the same directory, fsync,
//! rename over the record, fsync of the directory. A reader sees the old record or the new one,
//! never a torn one.

use std::io::Write;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::deficit::DeficitStatus;
use super::procedure::{CumulativeVolumes, ProcedureInfo};

/// Magic word on the header line.
pub const RECORD_MAGIC: &str = "hydrometra-procedure";
/// Current format version.
pub const RECORD_VERSION: u32 = 1;
/// The record's file name inside a state directory (hydrometrad's `[paths] state_dir`).
pub const RECORD_FILE_NAME: &str = "procedure.rec";

/// Where the procedure record is: `record` if given, else [`RECORD_FILE_NAME`] in `state_dir`,
/// else nowhere (the deficit is not persisted). hydrometrad's `[hydraulics] record` and
/// `[paths] state_dir`, and the CLI reading that configuration, all go through this.
pub fn record_path(record: Option<&Path>, state_dir: Option<&Path>) -> Option<PathBuf> {
    record
        .map(Path::to_path_buf)
        .or_else(|| state_dir.map(|d| d.join(RECORD_FILE_NAME)))
}

/// The file whose presence asks the daemon to start a new procedure: `<record>.reset`
/// (`hydrometra procedure reset` writes it; the daemon deletes it and resets).
pub fn reset_request_path(record: &Path) -> PathBuf {
    let mut name = record.as_os_str().to_owned();
    name.push(".reset");
    PathBuf::from(name)
}

/// Errors reading or writing a procedure record.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// File system error.
    #[error("procedure record {path}: {action}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What was being done.
        action: &'static str,
        /// The cause.
        source: std::io::Error,
    },
    /// The content is not a valid record.
    #[error("procedure record {path}: {problem}")]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// What is wrong, e.g. the checksum mismatch with both values.
        problem: String,
    },
}

/// Everything of a procedure that must survive a restart.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ProcedureRecord {
    /// Which procedure.
    pub procedure: ProcedureInfo,
    /// Wall-clock time of this save, ms since the Unix epoch.
    pub saved_unix_ms: u64,
    /// Procedure time, s.
    pub time_s: f64,
    /// Cavity volume, m^3.
    pub cavity_volume_m3: f64,
    /// Cavity pressure, Pa.
    pub cavity_pressure_pa: f64,
    /// Cavity volume at the start of the procedure, m^3.
    pub initial_cavity_volume_m3: f64,
    /// A perforation is present.
    pub perforated: bool,
    /// Cumulative volumes.
    pub totals: CumulativeVolumes,
    /// Deficit and latches.
    pub deficit: DeficitStatus,
}

impl ProcedureRecord {
    /// The file content.
    pub fn to_text(&self) -> String {
        // ok: a struct of numbers and bools always serialises (non-finite floats become null and
        // are rejected on load).
        let json = serde_json::to_string(self).unwrap_or_default();
        format!(
            "{RECORD_MAGIC} {RECORD_VERSION} crc32={:08x}\n{json}\n",
            crc32fast::hash(json.as_bytes())
        )
    }

    /// Parses file content; `path` names the file in errors.
    pub fn from_text(text: &str, path: &Path) -> Result<Self, RecordError> {
        let corrupt = |problem: String| RecordError::Corrupt {
            path: path.to_path_buf(),
            problem,
        };
        let mut lines = text.lines();
        let header = lines.next().unwrap_or_default();
        let json = lines
            .next()
            .ok_or_else(|| corrupt("line 2: missing (expected the JSON record)".into()))?;
        let fields: Vec<&str> = header.split(' ').collect();
        if fields.len() != 3 || fields[0] != RECORD_MAGIC {
            return Err(corrupt(format!(
                "line 1: `{header}` is not a header (expected `{RECORD_MAGIC} <version> crc32=<hex>`)"
            )));
        }
        if fields[1] != RECORD_VERSION.to_string() {
            return Err(corrupt(format!(
                "line 1: format version `{}` is not supported (expected {RECORD_VERSION})",
                fields[1]
            )));
        }
        let stored = fields[2]
            .strip_prefix("crc32=")
            .and_then(|h| u32::from_str_radix(h, 16).ok())
            .ok_or_else(|| {
                corrupt(format!(
                    "line 1: `{}` is not a checksum (expected crc32=<8 hex digits>)",
                    fields[2]
                ))
            })?;
        let actual = crc32fast::hash(json.as_bytes());
        if actual != stored {
            return Err(corrupt(format!(
                "line 2: checksum mismatch (header says {stored:08x}, content has {actual:08x})"
            )));
        }
        let record: ProcedureRecord = serde_json::from_str(json)
            .map_err(|e| corrupt(format!("line 2: invalid record: {e}")))?;
        record
            .check()
            .map_err(|p| corrupt(format!("line 2: {p}")))?;
        Ok(record)
    }

    /// Rejects values no model could have written.
    fn check(&self) -> Result<(), String> {
        let t = &self.totals;
        let volumes = [
            ("totals.inflow_m3", t.inflow_m3),
            ("totals.outflow_m3", t.outflow_m3),
            ("totals.leak_m3", t.leak_m3),
            ("totals.leak_collected_m3", t.leak_collected_m3),
            ("totals.absorbed_m3", t.absorbed_m3),
            ("totals.perforation_m3", t.perforation_m3),
            ("deficit.deficit_m3", self.deficit.deficit_m3),
            ("deficit.rate_m3_per_s", self.deficit.rate_m3_per_s),
            ("time_s", self.time_s),
        ];
        for (key, v) in volumes {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!("`{key}` = {v}: expected a finite number >= 0"));
            }
        }
        for (key, v) in [
            ("cavity_volume_m3", self.cavity_volume_m3),
            ("cavity_pressure_pa", self.cavity_pressure_pa),
            ("initial_cavity_volume_m3", self.initial_cavity_volume_m3),
        ] {
            if !v.is_finite() {
                return Err(format!("`{key}` = {v}: expected a finite number"));
            }
        }
        Ok(())
    }

    /// Reads a record; `Ok(None)` if the file does not exist (no procedure to resume).
    pub fn load(path: &Path) -> Result<Option<Self>, RecordError> {
        match std::fs::read_to_string(path) {
            Ok(text) => Self::from_text(&text, path).map(Some),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(source) => Err(RecordError::Io {
                path: path.to_path_buf(),
                action: "read",
                source,
            }),
        }
    }

    /// Writes the record atomically (temporary file, fsync, rename, directory fsync).
    pub fn save(&self, path: &Path) -> Result<(), RecordError> {
        let io = |action: &'static str| {
            move |source| RecordError::Io {
                path: path.to_path_buf(),
                action,
                source,
            }
        };
        let dir = match path.parent() {
            Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let file_name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "procedure".into());
        let tmp = dir.join(format!(".{file_name}.tmp-{}", std::process::id()));
        {
            let mut f = std::fs::File::create(&tmp).map_err(io("create temporary file"))?;
            f.write_all(self.to_text().as_bytes())
                .map_err(io("write temporary file"))?;
            f.sync_all().map_err(io("fsync temporary file"))?;
        }
        std::fs::rename(&tmp, path).map_err(io("rename temporary file over the record"))?;
        // The rename is durable only once the directory entry is on disk.
        if let Ok(d) = std::fs::File::open(&dir) {
            d.sync_all().map_err(io("fsync directory"))?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::units::mmhg_to_pa;
    /// A record as the model writes it mid-procedure (built by hand: these tests are about the
    /// file, not the model; values with full 53-bit mantissas so a lossy round trip would show).
    fn sample_record() -> ProcedureRecord {
        let ml = 1e-6;
        ProcedureRecord {
            procedure: ProcedureInfo {
                id: 7,
                started_unix_ms: 1_700_000_000_000,
            },
            saved_unix_ms: 1_700_000_002_000,
            time_s: 2.0 / 3.0 + 1.0,
            cavity_volume_m3: 7.0 * ml / 3.0,
            cavity_pressure_pa: mmhg_to_pa(120.0) / 7.0,
            initial_cavity_volume_m3: ml / 3.0,
            perforated: true,
            totals: CumulativeVolumes {
                inflow_m3: 40.0 * ml / 3.0,
                outflow_m3: 20.0 * ml / 7.0,
                leak_m3: ml / 11.0,
                leak_collected_m3: ml / 13.0,
                absorbed_m3: ml / 17.0,
                perforation_m3: 5.0 * ml / 3.0,
            },
            deficit: DeficitStatus {
                deficit_m3: 8.0 * ml / 3.0,
                rate_m3_per_s: ml / 9.0,
                limit_m3: 1000.0 * ml,
                warning_stage: 1,
                rate_alarm: true,
                terminated: false,
                terminated_at_s: None,
                overpressure: false,
            },
        }
    }

    #[test]
    fn crc32_matches_the_standard_test_vector() {
        assert_eq!(crc32fast::hash(b"123456789"), 0xCBF4_3926);
        assert_eq!(crc32fast::hash(b""), 0);
    }

    #[test]
    fn record_round_trips_exactly_through_a_file() {
        let dir = std::env::temp_dir().join(format!("hydrometra-record-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("procedure.rec");
        let _ = std::fs::remove_file(&path);
        assert!(ProcedureRecord::load(&path).unwrap().is_none());
        let r = sample_record();
        assert!(r.deficit.deficit_m3 > 0.0 && r.perforated);
        r.save(&path).unwrap();
        assert_eq!(ProcedureRecord::load(&path).unwrap(), Some(r));
        // Overwriting leaves exactly the new record and no temporary file behind.
        let mut r2 = r;
        r2.saved_unix_ms += 1;
        r2.save(&path).unwrap();
        assert_eq!(ProcedureRecord::load(&path).unwrap(), Some(r2));
        let leftovers: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .filter_map(|e| e.ok())
            .filter(|e| e.file_name().to_string_lossy().contains(".tmp-"))
            .collect();
        assert!(leftovers.is_empty());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn every_corruption_is_detected_and_named() {
        let text = sample_record().to_text();
        let p = Path::new("/var/lib/hydrometra/procedure.rec");
        // Flip every byte of the JSON line in turn (one at a time).
        let json_start = text.find('\n').unwrap() + 1;
        let bytes = text.as_bytes();
        for i in json_start..bytes.len() - 1 {
            let mut b = bytes.to_vec();
            b[i] ^= 0x01;
            let Ok(s) = String::from_utf8(b) else {
                continue;
            };
            let e = ProcedureRecord::from_text(&s, p).unwrap_err().to_string();
            assert!(e.contains("procedure.rec"), "{e}");
        }
        let e = ProcedureRecord::from_text(&text.replacen(" 1 ", " 2 ", 1), p)
            .unwrap_err()
            .to_string();
        assert!(e.contains("version `2`"), "{e}");
        let e = ProcedureRecord::from_text("garbage", p)
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 2"), "{e}");
        let e = ProcedureRecord::from_text("", p).unwrap_err().to_string();
        assert!(e.contains("missing"), "{e}");
    }

    #[test]
    fn a_valid_checksum_over_impossible_values_is_still_rejected() {
        let mut r = sample_record();
        r.deficit.deficit_m3 = -1.0;
        let e = ProcedureRecord::from_text(&r.to_text(), Path::new("x"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("deficit.deficit_m3"), "{e}");
    }

    #[test]
    fn the_record_path_prefers_the_explicit_file_and_the_reset_request_sits_beside_it() {
        let state = Path::new("/var/lib/hm");
        let explicit = Path::new("/tmp/p.rec");
        assert_eq!(
            record_path(Some(explicit), Some(state)),
            Some(explicit.to_path_buf())
        );
        assert_eq!(
            record_path(None, Some(state)),
            Some(PathBuf::from("/var/lib/hm/procedure.rec"))
        );
        assert_eq!(record_path(None, None), None);
        assert_eq!(
            reset_request_path(explicit),
            PathBuf::from("/tmp/p.rec.reset")
        );
    }
}
