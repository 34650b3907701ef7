//! The error of a bad scenario file (keyframes or `[faults]` table), shared by `scenario` and
//! `faults`.

/// A bad scenario file; the message names the origin, line and key.
#[derive(Debug, thiserror::Error)]
pub enum ScenarioError {
    /// The file could not be read.
    #[error("cannot read scenario file {path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The OS error.
        source: std::io::Error,
    },
    /// Neither a built-in name nor a readable file (see `Scenario::resolve`).
    #[error(
        "scenario `{spec}`: not a built-in scenario ({builtins}) and no such file ({source}); \
         a built-in name always means the built-in, anything else is a file path"
    )]
    NotFound {
        /// The argument as given.
        spec: String,
        /// The built-in names, comma-separated.
        builtins: String,
        /// The OS error of opening `spec` as a file.
        source: std::io::Error,
    },
    /// TOML syntax, unknown key or wrong type (the parser's message has line and column).
    #[error("scenario {origin}: {message}")]
    Parse {
        /// File name or other origin.
        origin: String,
        /// The parser's message.
        message: String,
    },
    /// A value out of range.
    #[error("scenario {origin}, line {line}: key `{key}` = {value}: expected {expected}")]
    Invalid {
        /// File name or other origin.
        origin: String,
        /// 1-based line of the value.
        line: usize,
        /// Key path, e.g. `keyframe[3].valve_in`.
        key: String,
        /// The offending value.
        value: String,
        /// What is allowed.
        expected: String,
    },
}

/// 1-based line of a byte offset.
pub(crate) fn line_of(text: &str, offset: usize) -> usize {
    text.as_bytes()[..offset.min(text.len())]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
        + 1
}
