//! Errors of the search engine: every bad input is one of these, never a panic.
use thiserror::Error;

/// What went wrong in the engine, with the fix in the message where there is one.
#[derive(Debug, Error, Clone, PartialEq, Eq)]
pub enum EngineError {
    #[error("invalid geometry: {0}")]
    Geometry(String),
    #[error("invalid weights: {0}")]
    Weights(String),
    #[error("length mismatch: {what} has {got} bytes, expected {expected}")]
    Length {
        what: &'static str,
        got: usize,
        expected: usize,
    },
    #[error("empty {0}: nothing to search")]
    Empty(&'static str),
    #[error("index range {start}..{end} is not inside the space {space_start}..{space_end}")]
    Range {
        start: u64,
        end: u64,
        space_start: u64,
        space_end: u64,
    },
    #[error("invalid image: {0}")]
    Image(String),
    #[error("kernel {0} is not supported by this CPU; use one of: {1}")]
    Kernel(&'static str, String),
    #[error("invalid parameter: {0}")]
    Parameter(String),
}

/// Result with [`EngineError`].
pub type Result<T, E = EngineError> = std::result::Result<T, E>;
