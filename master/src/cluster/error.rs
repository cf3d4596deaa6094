//! Why a worker could not be used, or why the cluster cannot go on
//! (ARCHITECTURE §4.3). A worker error drops that worker (its text is the
//! `reason` of the run report's `drop` or `unavailable` event); the
//! cluster-wide errors end the run.

/// A cluster error. The texts are those of the run report's `reason` fields.

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ClusterError {
    /// A worker address that is not `host:port`, or a token that cannot be sent.
    #[error("{0}")]
    Address(String),
    #[error("invalid address: {0}")]
    InvalidAddress(String),
    #[error("TLS setup failed: {0}")]
    Tls(String),
    #[error("cannot connect: {0}")]
    Connect(String),
    #[error("cannot connect within {0} ms")]
    ConnectTimeout(u128),
    /// A call answered with an error status (`status` as `Code: message`).
    #[error("{call} failed: {status}")]
    Call { call: &'static str, status: String },
    #[error("{call} missed its deadline of {ms} ms")]
    CallDeadline { call: &'static str, ms: u128 },
    #[error(
        "protocol version mismatch: this master speaks version {ours}, worker {address} (texsyn {version}) speaks version {theirs}; run the same texsyn release on both"
    )]
    ProtocolMismatch {
        address: String,
        ours: u32,
        theirs: u32,
        /// The worker's texsyn version ("?" when it sent none).
        version: String,
    },
    #[error("Calibrate answered an invalid throughput {0}")]
    InvalidThroughput(f64),
    #[error(
        "LoadLevel counted {counted} reference vectors where the master counts {total} (different texsyn versions?)"
    )]
    VectorCount { counted: u64, total: u64 },
    #[error("Assign built {built} vectors for the range {start}..{end} of {} vectors", .end - .start)]
    AssignCount { built: u64, start: u64, end: u64 },
    /// A search part did not come back before its deadline.
    #[error("missed its deadline of {0} ms")]
    Deadline(u128),
    #[error("closed the search stream")]
    StreamClosed,
    #[error("search failed: {0}")]
    Search(String),
    #[error("answered batch {answered} when batch {asked} was asked")]
    WrongBatch { answered: u64, asked: u64 },
    /// A malformed answer or one outside the worker's range
    /// ([`texsyn_engine::check_part`], `wire::best_hits`).
    #[error("{0}")]
    BadAnswer(String),
    #[error("search task failed: {0}")]
    Task(String),
    /// An answer whose distance is not the distance of the vector it names
    /// (the master scores every returned index itself).
    #[error(
        "answered query {query} with reference {index} at distance {claimed}, but that reference is at distance {actual}"
    )]
    WrongAnswer {
        query: usize,
        index: u64,
        claimed: u64,
        actual: u64,
    },
    // Cluster-wide: the run cannot go on.
    #[error("no workers given; add --workers, --hosts or --local-workers")]
    NoWorkers,
    #[error("deadline factor {0} must be ≥ 1")]
    DeadlineFactor(f64),
    #[error("no search worker could be used ({0}); --require-cluster forbids searching locally")]
    NoneUsable(String),
    #[error(
        "no search worker left at level {level} ({reasons}); --require-cluster forbids finishing locally"
    )]
    NoneLeft { level: usize, reasons: String },
}

/// A result with a [`ClusterError`].
pub type ClusterResult<T> = std::result::Result<T, ClusterError>;

impl ClusterError {
    /// The worker answered something that cannot be right: malformed, out of
    /// its range, or with a wrong distance. It is not used again in the run.
    pub fn is_untrustworthy(&self) -> bool {
        matches!(self, Self::WrongAnswer { .. } | Self::BadAnswer(_))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn texts_name_what_failed() {
        let e = ClusterError::AssignCount {
            built: 3,
            start: 10,
            end: 14,
        };
        assert_eq!(
            e.to_string(),
            "Assign built 3 vectors for the range 10..14 of 4 vectors"
        );
        let e = ClusterError::CallDeadline {
            call: "Info",
            ms: 250,
        };
        assert_eq!(e.to_string(), "Info missed its deadline of 250 ms");
        assert_eq!(
            ClusterError::Deadline(7).to_string(),
            "missed its deadline of 7 ms"
        );
    }
}
