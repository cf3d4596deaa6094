//! How a [`VectorSpace`](super::VectorSpace) holds its vectors: [`Storage`]
//! and the rule that picks it for a range.

use crate::error::{EngineError, Result};

/// How a [`VectorSpace`] holds its vectors.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, Default, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum Storage {
    /// [`Storage::Dense`] when the vectors take at most [`DENSE_LIMIT`] bytes
    /// and half the memory the machine can still give, [`Storage::Planes`]
    /// otherwise.
    #[default]
    Auto,
    /// Every padded vector built once: fastest, `stride` bytes per vector.
    Dense,
    /// Only the sample planes: vectors are gathered block by block as they
    /// are scanned, so memory is about the size of the sample.
    Planes,
}

/// Largest vector data [`Storage::Auto`] builds densely.
pub const DENSE_LIMIT: u64 = 1 << 30;

impl Storage {
    /// Parses `auto`, `dense` or `planes`.
    pub fn from_name(name: &str) -> Result<Self> {
        match name.to_ascii_lowercase().as_str() {
            "auto" => Ok(Self::Auto),
            "dense" => Ok(Self::Dense),
            "planes" => Ok(Self::Planes),
            _ => Err(EngineError::Parameter(format!(
                "unknown vector storage '{name}'; use auto, dense or planes"
            ))),
        }
    }

    pub fn name(&self) -> &'static str {
        match self {
            Self::Auto => "auto",
            Self::Dense => "dense",
            Self::Planes => "planes",
        }
    }

    /// The storage to use and the bytes it needs, for a range whose vectors
    /// take `dense` bytes built and whose planes take `planes` bytes, when
    /// `room` bytes are left (`None`: unknown). The one rule the master's
    /// local search and the worker both apply before building a range.
    pub fn plan(self, dense: u64, planes: u64, room: Option<u64>) -> (Self, u64) {
        match self.resolve(dense, room) {
            Self::Dense => (Self::Dense, dense),
            _ => (Self::Planes, planes),
        }
    }

    /// The storage for `vector_bytes` of dense vectors when `room` bytes are
    /// left on this machine (`None`: unknown).
    pub fn resolve(self, vector_bytes: u64, room: Option<u64>) -> Self {
        match self {
            Self::Auto => {
                let fits =
                    vector_bytes <= DENSE_LIMIT && room.is_none_or(|r| vector_bytes <= r / 2);
                if fits {
                    Self::Dense
                } else {
                    Self::Planes
                }
            }
            other => other,
        }
    }
}
