//! The recordings of a rig on this machine and their debriefs (`hydrometra-record`): listed from
//! the daemon's recordings directory, a debrief computed on request and kept while the file is
//! unchanged. Only names listed in that directory are ever opened.

use std::collections::HashMap;
use std::path::Path;
use std::sync::Mutex;
use std::time::SystemTime;

use hydrometra_record::debrief::{self, DebriefSettings, Metrics};
use hydrometra_record::reader::Recording;
use serde::Serialize;

/// Points of a debrief's plot series at most.
const SERIES_POINTS: usize = 1500;

/// One recording in a listing.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Entry {
    /// File name (no directory).
    pub name: String,
    /// Size, bytes.
    pub size_bytes: u64,
    /// Last modification, s since the Unix epoch.
    pub modified_unix_s: f64,
}

/// A recording's debrief for the page: the metrics of `hydrometra debrief` and a thinned series
/// to plot (SI units).
#[derive(Debug, Clone, Serialize)]
pub struct Debrief {
    /// The metrics (docs/debrief.md).
    pub metrics: Metrics,
    /// Time since the first recorded status, s.
    pub t_s: Vec<f64>,
    /// Cavity pressure, Pa.
    pub cavity_pressure_pa: Vec<f64>,
    /// Pump set pressure, Pa.
    pub pump_set_pressure_pa: Vec<f64>,
    /// Fluid deficit, m³.
    pub deficit_m3: Vec<f64>,
    /// Deficit limit, m³.
    pub deficit_limit_m3: Vec<f64>,
}

/// Why a listing or a debrief failed.
#[derive(Debug, thiserror::Error)]
pub enum RecordingsError {
    /// The name is not a recording of the listing.
    #[error("no recording named {0:?}")]
    NotFound(String),
    /// The directory or file could not be read.
    #[error("{0}")]
    Io(String),
    /// The recording could not be debriefed.
    #[error("debrief of {name}: {message}")]
    Debrief {
        /// The file name.
        name: String,
        /// Why.
        message: String,
    },
}

/// A recording file name: `*.mcap`, plain characters, no path.
pub fn valid_name(name: &str) -> bool {
    name.len() <= 200
        && name.ends_with(".mcap")
        && !name.starts_with('.')
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'-' | b'_' | b'.'))
}

/// The recordings in `dir`, newest first.
pub fn list(dir: &Path) -> Result<Vec<Entry>, RecordingsError> {
    let read = std::fs::read_dir(dir)
        .map_err(|e| RecordingsError::Io(format!("{}: {e}", dir.display())))?;
    let mut out: Vec<Entry> = read
        .filter_map(Result::ok)
        .filter_map(|e| {
            let name = e.file_name().into_string().ok()?;
            let meta = e.metadata().ok()?;
            (valid_name(&name) && meta.is_file()).then(|| Entry {
                name,
                size_bytes: meta.len(),
                modified_unix_s: meta
                    .modified()
                    .ok()
                    .and_then(|m| m.duration_since(SystemTime::UNIX_EPOCH).ok())
                    .map_or(0.0, |d| d.as_secs_f64()),
            })
        })
        .collect();
    out.sort_by(|a, b| b.modified_unix_s.total_cmp(&a.modified_unix_s));
    Ok(out)
}

/// A cached debrief: the file's size and modification time it was computed for, and it.
type CachedDebrief = (u64, f64, std::sync::Arc<Debrief>);

/// Debriefs kept per (name, size, modification time).
#[derive(Default)]
pub struct DebriefCache {
    entries: Mutex<HashMap<String, CachedDebrief>>,
}

impl DebriefCache {
    /// The debrief of recording `name` in `dir` (computed unless cached for the same file).
    pub fn get(&self, dir: &Path, name: &str) -> Result<std::sync::Arc<Debrief>, RecordingsError> {
        let entry = list(dir)?
            .into_iter()
            .find(|e| e.name == name)
            .ok_or_else(|| RecordingsError::NotFound(name.to_string()))?;
        let key = |e: &Entry| (e.size_bytes, e.modified_unix_s);
        let cached = {
            let map = self.entries.lock().unwrap_or_else(|p| p.into_inner());
            map.get(name)
                .filter(|(s, m, _)| (*s, *m) == key(&entry))
                .map(|(_, _, d)| d.clone())
        };
        if let Some(d) = cached {
            return Ok(d);
        }
        let d = std::sync::Arc::new(compute(&dir.join(&entry.name), name)?);
        self.entries
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .insert(
                name.to_string(),
                (entry.size_bytes, entry.modified_unix_s, d.clone()),
            );
        Ok(d)
    }
}

fn compute(path: &Path, name: &str) -> Result<Debrief, RecordingsError> {
    let fail = |message: String| RecordingsError::Debrief {
        name: name.to_string(),
        message,
    };
    let rec = Recording::load(path).map_err(|e| fail(e.to_string()))?;
    let metrics = debrief::metrics(&rec, &DebriefSettings::default()).map_err(fail)?;
    let t0 = rec.statuses.first().map_or(0, |(t, _)| *t);
    let stride = rec.statuses.len().div_ceil(SERIES_POINTS).max(1);
    let picked: Vec<_> = rec.statuses.iter().step_by(stride).collect();
    Ok(Debrief {
        metrics,
        t_s: picked
            .iter()
            .map(|(t, _)| t.saturating_sub(t0) as f64 * 1e-9)
            .collect(),
        cavity_pressure_pa: picked.iter().map(|(_, s)| s.cavity_pressure_pa).collect(),
        pump_set_pressure_pa: picked.iter().map(|(_, s)| s.pump_set_pressure_pa).collect(),
        deficit_m3: picked.iter().map(|(_, s)| s.deficit_m3).collect(),
        deficit_limit_m3: picked.iter().map(|(_, s)| s.deficit_limit_m3).collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_plain_mcap_names_are_valid() {
        for ok in ["procedure-1764338400000.mcap", "a_b.c.mcap"] {
            assert!(valid_name(ok), "{ok}");
        }
        for bad in [
            "../x.mcap",
            "/etc/passwd",
            "x.mcap/..",
            ".hidden.mcap",
            "a b.mcap",
            "x.txt",
            "%2e%2e.mcap",
            "",
        ] {
            assert!(!valid_name(bad), "{bad}");
        }
    }

    #[test]
    fn a_listing_names_only_recordings_and_unknown_names_are_not_found() {
        let dir = std::env::temp_dir().join(format!("station-rec-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("procedure-1.mcap"), b"not really").unwrap();
        std::fs::write(dir.join("notes.txt"), b"x").unwrap();
        let names: Vec<String> = list(&dir).unwrap().into_iter().map(|e| e.name).collect();
        assert_eq!(names, vec!["procedure-1.mcap"]);
        let cache = DebriefCache::default();
        assert!(matches!(
            cache.get(&dir, "notes.txt"),
            Err(RecordingsError::NotFound(_))
        ));
        // A listed file that is no recording: an error naming it, not a panic.
        let err = cache.get(&dir, "procedure-1.mcap").unwrap_err().to_string();
        assert!(err.contains("procedure-1.mcap"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
