//! Where the nearest-neighbour search of a level happens (Stahlhut §8, DESIGN §3.8).
//!
//! The synthesis talks only to [`SearchBackend`]; the local engine, the cluster
//! and LBG plug in behind it without touching the synthesis code.

use anyhow::Result;
use texsyn_worker::{Engine, Geometry, Hit, Params, QueryBatch, Sample, VectorSpace};

/// A level's reference data as the search sees it: the sample planes (the level
/// and its parent), the geometry and the comparison parameters.
pub struct LevelData<'a> {
    pub level: usize,
    pub geometry: Geometry,
    pub params: Params,
    pub sample: Sample<'a>,
    /// All reference positions of the level in global-index order.
    pub positions: &'a [[u32; 2]],
}

/// A search strategy for one level at a time.
pub trait SearchBackend: Send {
    /// Short name for logs and the run report.
    fn name(&self) -> String;
    /// Prepares the level's reference vectors.
    fn load_level(&mut self, level: &LevelData) -> Result<()>;
    /// Best reference (global index, distance) per query; exact backends tie to
    /// the lowest index.
    fn search(&mut self, queries: &QueryBatch) -> Result<Vec<Hit>>;
    /// Releases the level's memory.
    fn end_level(&mut self) {}
}

/// Exhaustive search on this machine: the worker's engine called in-process,
/// rayon over sub-ranges.
pub struct LocalSearch {
    engine: Engine,
    space: Option<VectorSpace>,
    params: Params,
}

impl LocalSearch {
    pub fn new(engine: Engine) -> Self {
        Self {
            engine,
            space: None,
            params: Params::default(),
        }
    }
}

impl SearchBackend for LocalSearch {
    fn name(&self) -> String {
        format!("local({})", self.engine.kernel().name())
    }

    fn load_level(&mut self, level: &LevelData) -> Result<()> {
        let n = level.positions.len() as u64;
        self.space = Some(VectorSpace::build_from_positions(
            &level.sample,
            &level.geometry,
            level.positions,
            0..n,
        )?);
        self.params = level.params;
        Ok(())
    }

    fn search(&mut self, queries: &QueryBatch) -> Result<Vec<Hit>> {
        let space = self
            .space
            .as_ref()
            .ok_or_else(|| anyhow::anyhow!("search before load_level"))?;
        Ok(self
            .engine
            .search_best(space, space.start()..space.end(), queries, &self.params)?)
    }

    fn end_level(&mut self) {
        self.space = None;
    }
}
