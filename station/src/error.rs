//! Why the station could not start or stopped.

/// Why the station could not start or stopped.
#[derive(Debug, thiserror::Error)]
pub enum StationError {
    /// A flag is wrong.
    #[error("{0}")]
    Usage(String),
    /// The token.
    #[error(transparent)]
    Token(#[from] crate::auth::TokenError),
    /// I/O (binding the address, starting threads).
    #[error("{context}: {source}")]
    Io {
        /// What was being done.
        context: String,
        /// The error.
        source: std::io::Error,
    },
    /// The benchmark failed.
    #[error("bench: {0}")]
    Bench(String),
}

/// Maps an I/O error to [`StationError::Io`] naming what was being done.
pub(crate) fn io(context: impl Into<String>) -> impl FnOnce(std::io::Error) -> StationError {
    let context = context.into();
    move |source| StationError::Io { context, source }
}
