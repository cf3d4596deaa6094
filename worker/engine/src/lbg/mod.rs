//! LBG (Linde–Buzo–Gray) vector quantisation of a reference range
//! (Stahlhut §8, ARCHITECTURE §3.8): an approximate, much faster search.
//!
//! Training: about √N seeds are drawn from the range with the run's seed
//! (ChaCha), every vector is assigned to its nearest seed (the same masked
//! distance as the exhaustive search, with full masks, ties to the lowest seed
//! index), every seed moves to the rounded centre of its group, and this repeats
//! until the relative change of the total seed displacement between two
//! iterations falls below a threshold (default 5 %) or an iteration cap is hit.
//! The assignment is exact: brute force with the batched kernel, accelerated for
//! L1 by Hamerly's bounds (triangle inequality on integer distances; a vector is
//! skipped only when its seed is *strictly* the nearest, so the result equals the
//! brute-force assignment bit for bit). An empty cell is re-seeded from the
//! largest cell (ChaCha-drawn member); cells still empty at the end are dropped.
//!
//! The partitions are stored as contiguous copies of their vectors (ascending
//! global index inside each, padded to 8 rows for the SIMD kernels). A query
//! scores every seed with the batched kernel under its own mask, then searches
//! the partitions of its `P` nearest seeds exactly (ties to the lowest global
//! index). With `P` = number of seeds the answer is the exhaustive one.
//!
//! Everything is integer arithmetic and every per-vector / per-query result is
//! computed independently of how rayon splits the work, so training and answers
//! do not depend on the number of threads. A [`Codebook`] covers any global
//! index range, so a cluster worker quantises the range it owns and answers
//! from it; the master merges per query by (distance, index) as usual.

//!
//! The module: [`LbgConfig`] and the parameter checks here, training in
//! `train` (assign/move with Hamerly pruning, then the partitions), the search
//! of a trained [`Codebook`] in `codebook`, and the kernel sinks both use in
//! `sinks`.

use std::ops::Range;

use crate::batch::QueryBatch;
use crate::error::{EngineError, Result};

mod codebook;
mod sinks;
mod train;

pub use codebook::Codebook;

/// Default relative-change threshold of the total seed displacement (Stahlhut: 5 %).
pub const DEFAULT_THRESHOLD: f64 = 0.05;
/// Default cap on assign/move iterations.
pub const DEFAULT_MAX_ITERATIONS: usize = 50;
/// Default training vectors per seed (see [`LbgConfig::sample_per_seed`]).
pub const DEFAULT_SAMPLE_PER_SEED: usize = 32;
/// Largest accepted iteration cap.
pub const MAX_ITERATIONS: usize = 10_000;

/// Rows per SIMD group: partitions and the seed table are padded to a multiple
/// of this, so the kernels never fall back to their scalar tail.
pub(super) const ROW_GROUP: usize = 8;
/// Vectors per rayon task while training (their bytes stay in L2 while every
/// seed block is scored against them).
pub(super) const TRAIN_CHUNK: usize = 1024;
/// Seeds scored per kernel pass while training (their bytes stay in L1).
pub(super) const SEED_BLOCK: usize = 48;

pub(super) type SeedBlocks = Vec<QueryBatch>;
/// Queries per rayon task while searching (one AVX-512 query group).
pub(super) const QUERY_CHUNK: usize = 8;

/// How a codebook is trained.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LbgConfig {
    /// Number of seeds; 0 = ⌈√N⌉ for N vectors (Stahlhut: √N is optimal).
    pub seeds: usize,
    /// Stop when |D_t − D_{t−1}| / D_{t−1} < threshold, D_t = total seed
    /// displacement of iteration t (0 < threshold < 1).
    pub threshold: f64,
    /// Cap on assign/move iterations (≥ 1).
    pub max_iterations: usize,
    /// The run's random seed (initial seed draw and re-seeding of empty cells).
    pub seed: u64,
    /// Training set size per seed: the assign/move iterations run on a
    /// ChaCha-drawn subset of `sample_per_seed × seeds` vectors (0 = all
    /// vectors); the final partitions always assign every vector exactly.
    pub sample_per_seed: usize,
    /// Use exact triangle-inequality pruning (Hamerly) for L1; `false` forces
    /// the brute-force assignment (same result, slower; for tests).
    pub prune: bool,
}

impl Default for LbgConfig {
    fn default() -> Self {
        Self {
            seeds: 0,
            threshold: DEFAULT_THRESHOLD,
            max_iterations: DEFAULT_MAX_ITERATIONS,
            seed: 1,
            sample_per_seed: DEFAULT_SAMPLE_PER_SEED,
            prune: true,
        }
    }
}

impl LbgConfig {
    /// Checks the parameters; messages say what is accepted.
    pub fn validate(&self) -> Result<()> {
        check_threshold(self.threshold)?;
        if self.max_iterations == 0 || self.max_iterations > MAX_ITERATIONS {
            return Err(EngineError::Parameter(format!(
                "LBG iteration cap {} must be in 1..={MAX_ITERATIONS}",
                self.max_iterations
            )));
        }
        Ok(())
    }

    /// The number of seeds used for `n` vectors.
    pub fn seeds_for(&self, n: usize) -> usize {
        if self.seeds == 0 {
            default_seeds(n)
        } else {
            self.seeds
        }
    }
}

/// The codebook seed of a range: a mix (SplitMix64) of the run's seed, the
/// level and the range, so a range re-assigned to another worker is
/// re-quantised into exactly the same codebook.
pub fn range_seed(run_seed: u64, level: u32, range: &Range<u64>) -> u64 {
    let mut z = run_seed;
    for x in [u64::from(level), range.start, range.end] {
        z = z.wrapping_add(x).wrapping_add(0x9E37_79B9_7F4A_7C15);
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
    }
    z
}

/// ⌈√n⌉ (at least 1): the seed count Stahlhut recommends.
pub fn default_seeds(n: usize) -> usize {
    let r = n.isqrt();
    (if r * r < n { r + 1 } else { r }).max(1)
}

/// Errors unless `0 < threshold < 1`.
pub fn check_threshold(threshold: f64) -> Result<()> {
    if !(threshold.is_finite() && threshold > 0.0 && threshold < 1.0) {
        return Err(EngineError::Parameter(format!(
            "LBG threshold {threshold} must be strictly between 0 and 1 (e.g. 0.05 for 5 %)"
        )));
    }
    Ok(())
}

/// Errors unless `1 ≤ probes ≤ seeds`.
pub fn check_probes(probes: usize, seeds: usize) -> Result<()> {
    if probes == 0 {
        return Err(EngineError::Parameter(
            "LBG probes must be at least 1 (the partition of the nearest seed)".into(),
        ));
    }
    if probes > seeds {
        return Err(EngineError::Parameter(format!(
            "LBG probes {probes} exceed the {seeds} seeds of the codebook; use 1..={seeds}"
        )));
    }
    Ok(())
}

/// What training did, for the run report.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LbgStats {
    /// Vectors quantised.
    pub vectors: usize,
    /// Vectors the assign/move iterations ran on (all, or a subset).
    pub trained_on: usize,
    /// Seeds drawn.
    pub seeds_requested: usize,
    /// Seeds (= non-empty partitions) in the codebook.
    pub seeds: usize,
    /// Assign/move iterations run.
    pub iterations: usize,
    /// Whether the threshold was reached (false = stopped by the cap).
    pub converged: bool,
    /// Total seed displacement per iteration.
    pub displacement: Vec<u64>,
    /// Empty cells re-seeded during training.
    pub reseeded: usize,
    /// Vectors whose assignment had to be recomputed against all seeds after
    /// the first assignment (Hamerly pruning skips the others), per iteration.
    pub rescans: Vec<u64>,
    /// Vectors in the largest partition.
    pub largest_partition: usize,
    /// Wall time of the training, including building the partitions.
    pub train_seconds: f64,
}
