//! Exhaustive search on this machine (Stahlhut §8, ARCHITECTURE §3.8).

use anyhow::{bail, Result};
use texsyn_engine::{
    with_bounds, Engine, Hit, Params, PruneStats, QueryBatch, Storage, VectorSpace,
};

use super::{level_space, LevelData, SearchBackend};

/// Exhaustive search on this machine: the engine called in-process,
/// rayon over sub-ranges.
pub struct LocalSearch {
    engine: Engine,
    space: Option<VectorSpace>,
    params: Params,
    /// Pruning figures of the current level.
    prune: PruneStats,
    /// Most bytes a level's vectors may take (besides what the machine has).
    max_memory: Option<u64>,
    /// How a level's vectors are held.
    storage: Storage,
}

impl LocalSearch {
    pub fn new(engine: Engine) -> Self {
        Self {
            engine,
            space: None,
            params: Params::default(),
            prune: PruneStats::default(),
            max_memory: None,
            storage: Storage::Auto,
        }
    }

    /// Holds each level's vectors as `storage` says ([`Storage::Auto`]: dense
    /// while they fit comfortably, gathered from the planes beyond).
    pub fn with_storage(mut self, storage: Storage) -> Self {
        self.storage = storage;
        self
    }

    /// Caps the bytes of a level's vectors below what the machine has.
    pub fn with_max_memory(mut self, bytes: u64) -> Self {
        self.max_memory = Some(bytes);
        self
    }

    /// The storage for the level's vectors, refusing a level that would not
    /// fit the memory this process can still use (host or cgroup,
    /// ARCHITECTURE §3.8) or the cap.
    fn plan_storage(&self, level: &LevelData) -> Result<Storage> {
        let n = level.positions.len() as u64;
        let room = texsyn_engine::budget::available_bytes();
        let limit = match (room, self.max_memory) {
            (Some(r), Some(m)) => Some(r.min(m)),
            (r, m) => r.or(m),
        };
        let (storage, need) = match level.colour_vectors {
            Some((layout, _)) => (Storage::Dense, n * layout.stride() as u64),
            None => self.storage.plan(
                n * level.geometry.layout().dense_bytes_per_vector() as u64,
                level.sample.plane_bytes(),
                limit,
            ),
        };
        if let Some(limit) = limit {
            if need > limit {
                bail!(
                    "level {}: its {} reference vectors need {:.1} MB ({} storage) but this machine can give {:.1} MB; spread the search over workers (--workers or --local-workers N), use approximate search (--search auto), or a smaller sample or fewer --levels",
                    level.level,
                    n,
                    need as f64 / 1e6,
                    storage.name(),
                    limit as f64 / 1e6
                );
            }
        }
        Ok(storage)
    }
}

impl SearchBackend for LocalSearch {
    fn name(&self) -> String {
        format!("local({})", self.engine.kernel().name())
    }

    fn load_level(&mut self, level: &LevelData) -> Result<()> {
        self.space = None;
        let storage = self.plan_storage(level)?;
        self.space = Some(level_space(level, storage)?);
        tracing::debug!(
            level = level.level,
            storage = storage.name(),
            "level vectors built"
        );
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

    fn search_topk(&mut self, queries: &QueryBatch, k: usize) -> Result<Vec<Vec<Hit>>> {
        let space = self
            .space
            .as_ref()
            .ok_or_else(|| anyhow::anyhow!("search before load_level"))?;
        Ok(self
            .engine
            .search_topk(space, space.start()..space.end(), queries, &self.params, k)?)
    }

    fn search_near_ties(
        &mut self,
        queries: &QueryBatch,
        k: usize,
        slack: &[texsyn_engine::Slack],
    ) -> Result<Vec<Vec<Hit>>> {
        let space = self
            .space
            .as_ref()
            .ok_or_else(|| anyhow::anyhow!("search before load_level"))?;
        Ok(self.engine.search_near_ties(
            space,
            space.start()..space.end(),
            queries,
            &self.params,
            k,
            slack,
        )?)
    }

    fn level_prune(&self) -> Option<PruneStats> {
        Some(self.prune)
    }

    fn end_level(&mut self) {
        self.space = None;
    }
}
