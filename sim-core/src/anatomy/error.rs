//! Errors of the anatomy generator.

use thiserror::Error;

/// Why an anatomy could not be generated.
#[derive(Debug, Error)]
pub enum AnatomyError {
    /// A parameter file could not be parsed (TOML syntax, unknown key, wrong type).
    #[error("anatomy parameters: {0}")]
    Parse(String),
    /// A single parameter is outside its plausible range.
    #[error("anatomy parameter `{key}` = {value}: expected {expected}")]
    OutOfRange {
        /// The parameter's key, as in the TOML file.
        key: String,
        /// The value given.
        value: f64,
        /// What was expected.
        expected: String,
    },
    /// Parameters that are each plausible but impossible together.
    #[error("anatomy parameters in conflict ({keys}): {reason}")]
    Conflict {
        /// The keys of the parameters in conflict, comma separated.
        keys: String,
        /// What is impossible, with the numbers.
        reason: String,
    },
    /// The mesher failed an internal consistency check (a bug or an untested parameter corner).
    #[error("anatomy mesher: {0}")]
    Mesher(String),
    /// Writing an output file failed.
    #[error("writing {path}: {source}")]
    Io {
        /// The file being written.
        path: String,
        /// The underlying error.
        source: std::io::Error,
    },
}

impl AnatomyError {
    pub(crate) fn conflict(keys: &[&str], reason: String) -> Self {
        AnatomyError::Conflict {
            keys: keys.join(", "),
            reason,
        }
    }
}
