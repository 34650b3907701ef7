//! Procedure recordings: one MCAP file per procedure (`docs/recording.md`), used by `hydrometrad`
//! (recorder), the `hydrometra` CLI (reader, debrief) and the instructor's station (debriefs).
//!
//! - [`format`]: topics, schemas and message layouts (the one copy of them).
//! - [`recorder`]: the recorder thread and its handle (start, stop, rotate), fed by non-blocking
//!   taps on the rig I/O thread and the publisher.
//! - [`reader`]: reads a recording back (also an unfinished one, e.g. after a kill -9).
//! - `scan`: the reader's one pass over the MCAP records, every length checked first.
//! - [`debrief`]: fluid-handling metrics and the instructor's report.

pub mod debrief;
pub mod format;
pub mod reader;
pub mod recorder;
mod scan;

/// A recording could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// File system error.
    #[error("{path}: {source}")]
    Io {
        /// The file or directory.
        path: String,
        /// The error.
        source: std::io::Error,
    },
    /// The MCAP library failed.
    #[error("{path}: MCAP: {message}")]
    Mcap {
        /// The file.
        path: String,
        /// The library's message.
        message: String,
    },
    /// The file is not a recording this build can read.
    #[error("{path}: {message}")]
    Format {
        /// The file.
        path: String,
        /// What is wrong.
        message: String,
    },
}
