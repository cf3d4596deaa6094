//! Key-ordered search windows: a lower-bound cascade computed once per space
//! (ARCHITECTURE §3.5).
//!
//! Every vector gets a key, the sum of its lo part (the parent window). For a
//! query that defines the whole lo part, the triangle inequality gives
//! D(q, v) ≥ w_lo·|K(q) − K(v)| for L1, and by Cauchy–Schwarz
//! D(q, v) ≥ w_lo·(K(q) − K(v))² / lo_len for L2. The vectors are indexed in
//! key order, so every vector that can still beat a query's best answer lies
//! in one contiguous window around the query's key, which narrows as the best
//! answer improves.
//!
//! A batch sweeps the union of its queries' windows once, block by block, so
//! the block is read from memory once for all queries whose windows cover it.
//! Inside a window each vector's *head* (its lo part, up to two lanes, kept in
//! key order beside the keys) is tested first; only heads whose partial
//! distance does not exceed the query's best are scored in full. Answers
//! compare (distance, index), so neither the order of the sweep nor its split
//! over threads changes them: the result is the exhaustive one.

mod index;
mod keyplane;
mod parts;

use std::ops::Range;

use crate::kernel::{Kernel, Params, PruneStats};
use crate::layout::{Layout, Metric, LANE};
use crate::merge::{merge_best, Hit};

pub(crate) use index::KeyIndex;
pub(crate) use keyplane::KeyPlane;

/// What a sweep needs besides the keys: how to score and what to search.
pub(crate) struct Sweep {
    pub kernel: Kernel,
    pub layout: Layout,
    pub params: Params,
    /// Global indices searched.
    pub range: Range<u64>,
    /// Fewest slots (or vectors) one rayon task sweeps.
    pub min_part: usize,
}

/// A dense space's padded vectors: local index 0 first, at global index `base`.
pub(crate) struct Dense<'a> {
    pub data: &'a [u8],
    pub base: u64,
}

/// Per query the best of `start` and the parts' answers, and the parts'
/// figures completed: `pruned` arrives as the pairs scored in full and leaves
/// as the pairs skipped.
fn merged(sw: &Sweep, start: &[Hit], parts: &[(Vec<Hit>, PruneStats)]) -> (Vec<Hit>, PruneStats) {
    let mut best = start.to_vec();
    let mut stats = PruneStats::default();
    for (p, s) in parts {
        merge_best(&mut best, p);
        stats.add(s);
    }
    let chunks = (sw.layout.stride() / LANE) as u64;
    let pairs = (sw.range.end - sw.range.start) * start.len() as u64;
    stats.pairs = pairs;
    stats.chunks_full = pairs * chunks;
    stats.pruned = pairs.saturating_sub(stats.pruned);
    (best, stats)
}

/// Where a key-plane sweep finds its vectors: their positions, and each
/// vector gathered from the planes (a plane-backed space) or read in place
/// (a dense one).
pub(crate) trait PlaneVectors: Sync {
    /// The runs (first global index, x, y, length) that cover `range`.
    fn runs(&self, range: Range<u64>) -> Vec<(u64, u32, u32, u32)>;
    /// Bytes of the buffer [`PlaneVectors::fetch`] may write.
    fn span(&self) -> usize;
    /// The padded vector of global index `index` at position (x, y), in
    /// `buf` or in place.
    fn fetch<'b>(&'b self, index: u64, x: usize, y: usize, buf: &'b mut [u8]) -> &'b [u8];
}

/// Largest key distance a vector can have over a part of `count` lo
/// components and still score at most `best`.
fn reach(sw: &Sweep, count: u64, best: u64) -> u64 {
    let wl = u64::from(sw.params.weights.lo);
    match sw.params.metric {
        Metric::L1 => best / wl,
        Metric::L2 => {
            let x = u128::from(best) * u128::from(count) / u128::from(wl);
            u64::try_from(x.isqrt()).unwrap_or(u64::MAX)
        }
    }
}
