//! Bounds one batch shares with the searches of its other ranges while they
//! run (ARCHITECTURE §4.7).
//!
//! A batch split over workers is searched range by range. Each range's sweep
//! prunes against the best distance found so far; without a link it knows
//! only its own finds, so the range that lacks a query's answer prunes against
//! a much worse one. A [`Link`] holds, per query, the least distance any range
//! has reported: the sweep reads it with its own bound and lowers it with
//! every find, and whoever carries the batch (the worker's stream, the
//! master's dispatch) forwards the changes between ranges. Distances are of
//! real vectors, so a range prunes only what cannot beat an answer some range
//! holds, and it keeps ties: the merged answer is the exhaustive one whatever
//! arrives when. Only the work, never an answer, depends on the timing.

use std::sync::atomic::{AtomicU64, Ordering};

/// Per query of a batch the least distance known to any of its ranges.
#[derive(Debug)]
pub struct Link(Vec<AtomicU64>);

impl Link {
    /// A link for `queries` queries, none with a distance yet.
    pub fn new(queries: usize) -> Self {
        Self((0..queries).map(|_| AtomicU64::new(u64::MAX)).collect())
    }

    pub fn len(&self) -> usize {
        self.0.len()
    }

    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// Query `q`'s least distance so far (`u64::MAX`: none).
    pub fn get(&self, q: usize) -> u64 {
        self.0[q].load(Ordering::Relaxed)
    }

    /// Lowers query `q`'s distance to `d`; whether it was lowered.
    pub fn lower(&self, q: usize, d: u64) -> bool {
        self.0[q].fetch_min(d, Ordering::Relaxed) > d
    }

    /// The queries whose distance is below `sent`'s, with the distances; `sent`
    /// is brought up to date (what a carrier forwards since its last look).
    pub fn changes(&self, sent: &mut [u64]) -> Vec<(u32, u64)> {
        self.changes_from(0, sent)
    }

    /// [`Link::changes`] of queries `first..first + sent.len()`, numbered
    /// from `first` (a chunk of the batch).
    pub fn changes_from(&self, first: usize, sent: &mut [u64]) -> Vec<(u32, u64)> {
        let mut out = Vec::new();
        for (q, s) in sent.iter_mut().enumerate() {
            let d = self.get(first + q);
            if d < *s {
                *s = d;
                out.push((q as u32, d));
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn changes_report_each_lowering_once() {
        let link = Link::new(3);
        let mut sent = vec![u64::MAX; 3];
        assert!(link.changes(&mut sent).is_empty());
        assert!(link.lower(1, 40));
        assert!(!link.lower(1, 50), "a higher distance lowers nothing");
        assert!(link.lower(2, 7));
        assert_eq!(link.changes(&mut sent), [(1, 40), (2, 7)]);
        assert!(link.changes(&mut sent).is_empty());
        assert!(link.lower(1, 39));
        assert_eq!(link.changes(&mut sent), [(1, 39)]);
        // A chunk of the batch: queries 1..3 numbered from 0.
        let mut chunk = vec![u64::MAX, 7];
        assert_eq!(link.changes_from(1, &mut chunk), [(0, 39)]);
        assert_eq!(chunk, [39, 7]);
    }
}
