//! A trained LBG codebook and its approximate search (Stahlhut §8, ARCHITECTURE
//! §3.8): score the seeds, then search the partitions of the `P` nearest exactly.

use std::ops::Range;

use rayon::prelude::*;

use super::sinks::{PartSink, TopSeedSink};
use super::{check_probes, LbgStats, QUERY_CHUNK};
use crate::batch::QueryBatch;
use crate::error::{EngineError, Result};
use crate::kernel::{Params, Scan};
use crate::layout::{Layout, SLACK};
use crate::merge::{merge_best, Hit};
use crate::search::Engine;
use crate::space::AlignedBytes;

/// A trained LBG codebook over one global index range: the seeds and, per
/// seed, a contiguous copy of its partition.
#[derive(Debug, Clone)]
pub struct Codebook {
    pub(super) layout: Layout,
    pub(super) params: Params,
    pub(super) range: Range<u64>,
    pub(super) seeds_requested: usize,
    /// Seeds (non-empty partitions).
    pub(super) k: usize,
    /// k rounded up to [`ROW_GROUP`](super::ROW_GROUP) rows (padding rows zero) + slack.
    pub(super) seed_data: AlignedBytes,
    pub(super) seed_rows: usize,
    /// Row offsets of the partitions in `data` (k + 1 entries).
    pub(super) part_rows: Vec<usize>,
    /// Offsets of the partitions in `members` (k + 1 entries).
    pub(super) part_members: Vec<usize>,
    /// Global indices, partition by partition, ascending inside each.
    pub(super) members: Vec<u64>,
    /// Global index of every row of `data`; `u64::MAX` for padding rows.
    pub(super) row_index: Vec<u64>,
    pub(super) data: AlignedBytes,
    pub(super) stats: LbgStats,
}

impl Codebook {
    /// Seeds (= partitions) of the codebook.
    pub fn seeds(&self) -> usize {
        self.k
    }

    /// Seeds drawn before empty cells were dropped (the limit for probes).
    pub fn seeds_requested(&self) -> usize {
        self.seeds_requested
    }

    /// The global index range the codebook covers.
    pub fn range(&self) -> Range<u64> {
        self.range.clone()
    }

    pub fn layout(&self) -> Layout {
        self.layout
    }

    /// The parameters the codebook was trained with (and searches with).
    pub fn params(&self) -> Params {
        self.params
    }

    pub fn stats(&self) -> &LbgStats {
        &self.stats
    }

    /// Padded bytes of seed `j`.
    pub fn seed(&self, j: usize) -> Option<&[u8]> {
        let s = self.layout.stride();
        (j < self.k).then(|| &self.seed_data.as_slice()[j * s..(j + 1) * s])
    }

    /// Global indices of partition `j`, ascending.
    pub fn partition(&self, j: usize) -> Option<&[u64]> {
        (j < self.k).then(|| &self.members[self.part_members[j]..self.part_members[j + 1]])
    }

    /// Bytes held (seeds, partition copies and index tables).
    pub fn bytes(&self) -> usize {
        self.seed_rows * self.layout.stride()
            + self.row_index.len() * (self.layout.stride() + 8)
            + self.members.len() * 8
    }

    /// The `probes` nearest seeds of every query, by (distance, seed index).
    pub fn nearest_seeds(
        &self,
        engine: &Engine,
        queries: &QueryBatch,
        probes: usize,
    ) -> Result<Vec<Vec<(u64, u32)>>> {
        self.check(engine, queries, probes)?;
        Ok(self.score_seeds(engine, queries, probes.min(self.k)))
    }

    fn check(&self, engine: &Engine, queries: &QueryBatch, probes: usize) -> Result<()> {
        engine.kernel().check()?;
        if queries.layout() != self.layout {
            let (a, b) = (queries.layout(), self.layout);
            return Err(EngineError::Geometry(format!(
                "queries have {}+{} components but the codebook has {}+{}; build both from the same geometry",
                a.hi_len, a.lo_len, b.hi_len, b.lo_len
            )));
        }
        if queries.is_empty() {
            return Err(EngineError::Empty("query batch"));
        }
        check_probes(probes, self.seeds_requested)
    }

    fn score_seeds(&self, engine: &Engine, q: &QueryBatch, p: usize) -> Vec<Vec<(u64, u32)>> {
        let mut sink = TopSeedSink::new(q.len(), p, self.k);
        let scan = Scan::new(
            self.layout,
            self.params,
            self.seed_data.as_slice(),
            self.seed_rows,
            0,
            q,
        );
        engine.kernel().scan(&scan, &mut sink);
        sink.lists
    }

    /// Best hit of the one query in `q` over partition `j`.
    fn scan_partition(&self, engine: &Engine, q: &QueryBatch, j: usize) -> Hit {
        let s = self.layout.stride();
        let (r0, r1) = (self.part_rows[j], self.part_rows[j + 1]);
        let mut sink = PartSink {
            row_index: &self.row_index,
            best: vec![Hit::NONE; q.len()],
        };
        let scan = Scan::new(
            self.layout,
            self.params,
            &self.data.as_slice()[r0 * s..r1 * s + SLACK],
            r1 - r0,
            r0 as u64,
            q,
        );
        engine.kernel().scan(&scan, &mut sink);
        sink.best[0]
    }

    /// Approximate best match per query: the exact best over the partitions
    /// of its `probes` nearest seeds (distance, then lowest global index).
    /// `probes` must be in 1..=[`Codebook::seeds_requested`]; with every seed
    /// probed the answer equals the exhaustive search.
    pub fn search(&self, engine: &Engine, queries: &QueryBatch, probes: usize) -> Result<Vec<Hit>> {
        self.check(engine, queries, probes)?;
        let p = probes.min(self.k);
        let nq = queries.len();
        let parts: Vec<Vec<Hit>> = (0..nq.div_ceil(QUERY_CHUNK))
            .into_par_iter()
            .map(|c| {
                let r = c * QUERY_CHUNK..((c + 1) * QUERY_CHUNK).min(nq);
                let sub;
                let q = if r.len() == nq {
                    queries
                } else {
                    sub = queries.select(r.clone());
                    &sub
                };
                let near = self.score_seeds(engine, q, p);
                near.iter()
                    .enumerate()
                    .map(|(qi, list)| {
                        let one = q.select([qi]);
                        let mut best = [Hit::NONE];
                        for &(_, j) in list {
                            merge_best(&mut best, &[self.scan_partition(engine, &one, j as usize)]);
                        }
                        best[0]
                    })
                    .collect()
            })
            .collect();
        Ok(parts.into_iter().flatten().collect())
    }
}
