//! One pyramid level's reference data, owned: the sample planes, the
//! neighbourhood geometry, the comparison parameters and the reference
//! positions in global-index order (ARCHITECTURE §5). The
//! worker holds one per loaded level, the cluster keeps one to rebuild vectors
//! after a repartition, and the wire converts it to and from `LoadLevel`.

use rayon::prelude::*;

use crate::batch::QueryBatch;
use crate::error::Result;
use crate::kernel::{distance, Params};
use crate::layout::Geometry;
use crate::merge::Hit;
use crate::plane::{gather, reference_positions, OwnedPlane, Sample};
use crate::positions::Positions;
use crate::search::kth_cut;

/// A level's sample planes, geometry, parameters and reference positions.
#[derive(Debug, Clone)]
pub struct OwnedLevel {
    /// Pyramid level (0 = finest).
    pub level: usize,
    pub geometry: Geometry,
    pub params: Params,
    pub fine: OwnedPlane,
    /// The parent plane; `None` exactly when `geometry.m == 0`.
    pub parent: Option<OwnedPlane>,
    /// All reference positions of the level in global-index order.
    pub positions: Positions,
}

impl OwnedLevel {
    /// A level with its reference positions computed from the planes.
    pub fn locate(
        level: usize,
        geometry: Geometry,
        params: Params,
        fine: OwnedPlane,
        parent: Option<OwnedPlane>,
    ) -> Result<Self> {
        let mut out = Self {
            level,
            geometry,
            params,
            fine,
            parent,
            positions: Positions::new(),
        };
        out.positions = reference_positions(&out.sample(), &out.geometry)?;
        Ok(out)
    }

    /// The planes borrowed as a [`Sample`].
    pub fn sample(&self) -> Sample<'_> {
        Sample {
            fine: self.fine.view(),
            parent: self.parent.as_ref().map(OwnedPlane::view),
        }
    }

    /// Number of reference vectors (global indices `0..total`).
    pub fn total(&self) -> u64 {
        self.positions.len() as u64
    }

    /// Sets each query's bound to the best of its bound and its coherence
    /// candidates, each scored from the planes with the scalar reference
    /// (ARCHITECTURE §3.5): how a master that holds no vectors gives its workers
    /// a tight bound to prune against. The candidates are used up: they are
    /// cleared, so no search scores them again.
    pub fn bound_queries(&self, queries: &mut QueryBatch) {
        let mut scorer = Scorer::new(self);
        for q in 0..queries.len() {
            let mut best = queries.bound(q);
            for &c in queries.candidates(q) {
                let Some(dist) = scorer.distance(c, queries, q) else {
                    continue;
                };
                let hit = Hit { index: c, dist };
                if hit.key() < best.key() {
                    best = hit;
                }
            }
            queries.set_bound(q, best);
            queries.set_candidates(q, Vec::new());
        }
    }

    /// Per query, a cut above every distance of its top-`k` over the whole
    /// level: one more than the `k`-th smallest distance of its distinct
    /// coherence candidates, scored from the planes, or `u64::MAX` when it
    /// has fewer than `k`. How a master that holds no vectors lets each
    /// worker search its range for only what can enter the merged top-k
    /// ([`crate::Engine::search_topk_below`], ARCHITECTURE §4.8).
    pub fn topk_cuts(&self, queries: &QueryBatch, k: usize) -> Vec<u64> {
        let all = 0..self.total();
        (0..queries.len())
            .into_par_iter()
            .map_init(
                || Scorer::new(self),
                |scorer, q| {
                    kth_cut(queries.candidates(q), &all, k, |i| {
                        scorer.distance(i, queries, q)
                    })
                },
            )
            .collect()
    }

    /// Bytes a plane-backed space of the whole level holds ([`Sample::plane_bytes`]).
    pub fn plane_bytes(&self) -> u64 {
        self.sample().plane_bytes()
    }

    /// Bytes held: planes and positions.
    pub fn bytes(&self) -> u64 {
        self.fine.bytes()
            + self.parent.as_ref().map_or(0, OwnedPlane::bytes)
            + self.positions.bytes()
    }
}

/// Scores single reference vectors of a level against queries, gathered from
/// the planes with the scalar reference distance: the coherence bounds, and
/// the master's check of every answer a worker returns (ARCHITECTURE §4.3).
pub struct Scorer<'a> {
    level: &'a OwnedLevel,
    sample: Sample<'a>,
    raw: Vec<u8>,
    padded: Vec<u8>,
}

impl<'a> Scorer<'a> {
    pub fn new(level: &'a OwnedLevel) -> Self {
        let layout = level.geometry.layout();
        Self {
            level,
            sample: level.sample(),
            raw: vec![0; layout.dims()],
            padded: vec![0; layout.stride()],
        }
    }

    /// The distance of reference vector `index` to query `q` of `queries`;
    /// None for an index outside the level.
    pub fn distance(&mut self, index: u64, queries: &QueryBatch, q: usize) -> Option<u64> {
        let [x, y] = self.level.positions.get(index)?;
        let layout = self.level.geometry.layout();
        gather(
            &self.sample,
            &self.level.geometry,
            x as usize,
            y as usize,
            &mut self.raw,
        );
        layout.scatter(&self.raw, &mut self.padded);
        Some(distance(
            &layout,
            &self.level.params,
            &self.padded,
            queries.values(q),
            queries.mask(q),
        ))
    }
}
