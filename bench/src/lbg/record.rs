//! An exhaustive run that records its queries and exact answers per level, and
//! LBG's answers measured against them (Stahlhut §8, ARCHITECTURE §6).

use std::time::Instant;

use anyhow::{Context, Result};
use texsyn::search::{LevelData, LocalSearch, SearchBackend};
use texsyn_engine::{Hit, OwnedLevel, QueryBatch};

/// One level of an exhaustive run: its reference data, every query batch and
/// the exact answers.
pub struct RecordedLevel {
    pub data: OwnedLevel,
    pub batches: Vec<QueryBatch>,
    pub exact: Vec<Vec<Hit>>,
    pub search_seconds: f64,
}

/// Exhaustive search that records what it was asked and answered.
pub struct Recorder {
    inner: LocalSearch,
    pub levels: Vec<RecordedLevel>,
}

impl Recorder {
    pub fn new(inner: LocalSearch) -> Self {
        Self {
            inner,
            levels: Vec::new(),
        }
    }
}

impl SearchBackend for Recorder {
    fn name(&self) -> String {
        self.inner.name()
    }

    fn load_level(&mut self, level: &LevelData) -> Result<()> {
        self.levels.push(RecordedLevel {
            data: level.owned_level(),
            batches: Vec::new(),
            exact: Vec::new(),
            search_seconds: 0.0,
        });
        self.inner.load_level(level)
    }

    fn search(&mut self, queries: &QueryBatch) -> Result<Vec<Hit>> {
        let t = Instant::now();
        let hits = self.inner.search(queries)?;
        let l = self.levels.last_mut().context("search before load_level")?;
        l.search_seconds += t.elapsed().as_secs_f64();
        l.batches.push(queries.clone());
        l.exact.push(hits.clone());
        Ok(hits)
    }

    fn end_level(&mut self) {
        self.inner.end_level();
    }
}

/// LBG answers against the exact ones.
pub struct LbgErrors {
    /// Share of queries whose answer (index) differs from the exhaustive one.
    pub differ: f64,
    /// Share of queries whose answer has a larger distance.
    pub worse: f64,
    /// Mean over queries with an exact distance > 0 of (d_lbg − d_exact) / d_exact.
    pub mean_excess: f64,
    /// Σ (d_lbg − d_exact) / Σ d_exact over all queries.
    pub total_excess: f64,
}

impl LbgErrors {
    pub fn of(exact: &[Vec<Hit>], got: &[Vec<Hit>]) -> Self {
        let (mut n, mut differ, mut worse) = (0usize, 0usize, 0usize);
        let (mut rel, mut rel_n, mut sum_e, mut sum_x) = (0.0f64, 0usize, 0.0f64, 0.0f64);
        for (e, g) in exact.iter().flatten().zip(got.iter().flatten()) {
            n += 1;
            differ += usize::from(e.index != g.index);
            worse += usize::from(g.dist > e.dist);
            let x = g.dist.saturating_sub(e.dist) as f64;
            if e.dist > 0 {
                rel += x / e.dist as f64;
                rel_n += 1;
            }
            sum_e += e.dist as f64;
            sum_x += x;
        }
        let n = n.max(1) as f64;
        Self {
            differ: differ as f64 / n,
            worse: worse as f64 / n,
            mean_excess: rel / rel_n.max(1) as f64,
            total_excess: sum_x / sum_e.max(1.0),
        }
    }
}
