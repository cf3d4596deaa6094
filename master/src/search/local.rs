//! Exhaustive search on this machine (Stahlhut §8, ARCHITECTURE §3.8).

use anyhow::Result;
use texsyn_engine::{with_bounds, Engine, Hit, Params, PruneStats, QueryBatch, VectorSpace};

use super::{level_space, LevelData, SearchBackend};

/// Exhaustive search on this machine: the engine called in-process,
/// rayon over sub-ranges.
pub struct LocalSearch {
    engine: Engine,
    space: Option<VectorSpace>,
    params: Params,
    /// Pruning figures of the current level.
    prune: PruneStats,
}

impl LocalSearch {
    pub fn new(engine: Engine) -> Self {
        Self {
            engine,
            space: None,
            params: Params::default(),
            prune: PruneStats::default(),
        }
    }
}

impl SearchBackend for LocalSearch {
    fn name(&self) -> String {
        format!("local({})", self.engine.kernel().name())
    }

    fn load_level(&mut self, level: &LevelData) -> Result<()> {
        self.space = Some(level_space(level)?);
        self.params = level.params;
        self.prune = PruneStats::default();
        Ok(())
    }

    fn search(&mut self, queries: &QueryBatch) -> Result<Vec<Hit>> {
        let space = self
            .space
            .as_ref()
            .ok_or_else(|| anyhow::anyhow!("search before load_level"))?;
        let (found, stats) = self.engine.search_best_counted(
            space,
            space.start()..space.end(),
            queries,
            &self.params,
        )?;
        self.prune.add(&stats);
        Ok(with_bounds(queries.bounds(), &found))
    }

    fn level_prune(&self) -> Option<PruneStats> {
        Some(self.prune)
    }

    fn end_level(&mut self) {
        self.space = None;
    }
}
