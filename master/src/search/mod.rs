//! Where the nearest-neighbour search of a level happens (Stahlhut §8,
//! ARCHITECTURE §3.8).
//!
//! A synthesis method talks only to [`SearchBackend`]; the local engine
//! ([`LocalSearch`]), LBG ([`LbgSearch`]) and the cluster
//! (`crate::cluster::ClusterSearch`) plug in behind it, side by side, and
//! [`PlannedSearch`] routes each pyramid level to one of them.

pub mod lbg;
mod local;
mod open;
mod plan;

pub use lbg::LbgSearch;
pub use local::LocalSearch;
pub use open::{open, OpenSearch, SearchOptions};
pub use plan::{level_cost, Plan, PlannedSearch, Strategy};

use anyhow::{ensure, Result};
use texsyn_engine::{
    Geometry, Hit, Layout, OwnedLevel, OwnedPlane, Params, Positions, PruneStats, QueryBatch,
    Sample, Storage, VectorSpace,
};

/// A level's reference data as the search sees it: the sample planes (the level
/// and its parent), the geometry and the comparison parameters.
pub struct LevelData<'a> {
    pub level: usize,
    pub geometry: Geometry,
    pub params: Params,
    pub sample: Sample<'a>,
    /// All reference positions of the level in global-index order.
    pub positions: &'a Positions,
    /// Pyramid levels of the run (level 0 = finest).
    pub levels: usize,
    /// Blocks still to be synthesised on this level (about the number of queries).
    pub expected_queries: u64,
    /// Full-colour search: the level's vectors gathered by the master (Y, Cb, Cr
    /// windows per part) in this layout, instead of luminance vectors built from
    /// `sample`. Only backends on this machine accept it.
    pub colour_vectors: Option<(Layout, &'a [u8])>,
}

impl<'a> LevelData<'a> {
    /// A single-plane level compared whole in L2 (no parent part, equal
    /// weights): what the coordinate method's candidate sets and the ω-tile
    /// search hand the engine.
    pub fn single_plane(
        level: usize,
        levels: usize,
        geometry: Geometry,
        fine: texsyn_engine::Plane<'a>,
        positions: &'a Positions,
        expected_queries: u64,
    ) -> Result<Self> {
        Ok(LevelData {
            level,
            geometry,
            params: Params {
                metric: texsyn_engine::Metric::L2,
                weights: texsyn_engine::Weights::new(1, 1)?,
            },
            sample: Sample { fine, parent: None },
            positions,
            levels,
            expected_queries,
            colour_vectors: None,
        })
    }

    /// A copy of the level's planes, geometry, parameters and positions (what
    /// a backend keeps to rebuild vectors later).
    pub fn owned_level(&self) -> OwnedLevel {
        OwnedLevel {
            level: self.level,
            geometry: self.geometry,
            params: self.params,
            fine: OwnedPlane::of(&self.sample.fine),
            parent: self.sample.parent.as_ref().map(OwnedPlane::of),
            positions: self.positions.clone(),
        }
    }
}

/// The level's reference vectors on this machine: luminance vectors built from
/// the sample planes and held as `storage` says, or the master's full-colour
/// vectors (always dense).
pub fn level_space(level: &LevelData, storage: Storage) -> Result<VectorSpace> {
    let n = level.positions.len() as u64;
    Ok(match level.colour_vectors {
        Some((layout, raw)) => VectorSpace::from_unpadded(layout, 0, raw)?,
        None => VectorSpace::build_with(
            &level.sample,
            &level.geometry,
            level.positions,
            0..n,
            storage,
        )?,
    })
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
    /// The `k` best references per query, sorted by (distance, index): what
    /// k-coherence candidate sets are made of. Exact backends only.
    fn search_topk(&mut self, queries: &QueryBatch, k: usize) -> Result<Vec<Vec<Hit>>> {
        let _ = (queries, k);
        anyhow::bail!("{} cannot give the k best matches", self.name())
    }
    /// Repetition control's near-ties: of the `k` best references per query,
    /// those within `slack[q]` of its best distance. Exact backends answer the
    /// same lists whichever way they search; the default filters the top-k.
    fn search_near_ties(
        &mut self,
        queries: &QueryBatch,
        k: usize,
        slack: &[texsyn_engine::Slack],
    ) -> Result<Vec<Vec<Hit>>> {
        let mut lists = self.search_topk(queries, k)?;
        texsyn_engine::Slack::keep_near_ties(&mut lists, slack);
        Ok(lists)
    }
    /// Releases the level's memory.
    fn end_level(&mut self) {}
    /// Asks for LBG with `probes` instead of exhaustive search from the next
    /// level on (0 = exhaustive); only backends that can quantise accept it.
    fn set_lbg_probes(&mut self, probes: u32) -> Result<()> {
        ensure!(probes == 0, "{} cannot search with LBG", self.name());
        Ok(())
    }
    /// Backend-specific figures for the run report (workers, drops, codebooks...).
    fn stats(&self) -> serde_json::Value {
        serde_json::Value::Null
    }
    /// What pruning saved on the current level, for backends that count it.
    fn level_prune(&self) -> Option<PruneStats> {
        None
    }
}
