//! The affinity evaluation of ω-tile patch sets (Dong, Zhou and Paul §4,
//! eq. 1–2): each intermediate tile's best translation in a coarse copy of
//! the sample. The searches are exact and go through the project's search
//! backend, so they run in-process or on the cluster with the same answers;
//! they are batched per generation and cached per tuple of corner positions.

use std::collections::HashMap;

use anyhow::{ensure, Result};
use texsyn_engine::{Geometry, Plane, Positions, QueryBatch, Sample};

use super::ais::Gene;
use super::omega::OmegaSet;
use crate::imaging::colour::luminance;
use crate::imaging::{ColorImage, Gray};
use crate::pyramid::downsample;
use crate::search::{LevelData, SearchBackend};

/// The evaluation of intermediate tiles: a coarse copy of the sample where a
/// tile fits the engine's odd window, the reference positions (every
/// translation of a tile inside the sample) and the cache of `D` per tuple.
pub struct Evaluator<'a> {
    pub(super) set: &'a OmegaSet,
    /// Tile side T in sample pixels.
    pub tile: usize,
    /// Pyramid steps from the sample to the evaluation level.
    pub steps: usize,
    /// Tile side at the evaluation level (odd).
    pub side: usize,
    coarse: Gray,
    positions: Positions,
    cache: HashMap<[Gene; 4], (f64, u64)>,
    /// Tile searches run (cache misses).
    pub searches: u64,
}

/// Largest tile side searched at the evaluation level: the sample is halved
/// until a tile is at most this wide, so one tile is at most 23² values.
const EVAL_SIDE: usize = 23;

impl<'a> Evaluator<'a> {
    pub fn new(set: &'a OmegaSet, sample: &ColorImage, tile: usize) -> Result<Self> {
        ensure!(
            tile >= 8 && tile.is_multiple_of(2),
            "the tile size must be even and at least 8 (got {tile})"
        );
        ensure!(
            tile < sample.width && tile < sample.height,
            "the tile size {tile} must be smaller than the sample ({}×{}); give a smaller --tile-size",
            sample.width,
            sample.height
        );
        let mut coarse = luminance(sample);
        let mut steps = 0;
        while tile >> steps > EVAL_SIDE {
            coarse = downsample(&coarse, None, false);
            steps += 1;
        }
        let side = ((tile >> steps) - 1) | 1;
        let plane = Plane::new(coarse.width, coarse.height, &coarse.data, None)?;
        let sample_planes = Sample {
            fine: plane,
            parent: None,
        };
        let positions =
            texsyn_engine::plane::reference_positions(&sample_planes, &Geometry::new(side, 0)?)?;
        ensure!(!positions.is_empty(), "the sample has no tile-sized window");
        Ok(Self {
            set,
            tile,
            steps,
            side,
            coarse,
            positions,
            cache: HashMap::new(),
            searches: 0,
        })
    }

    /// Hands the evaluation level to the backend.
    pub fn load(&self, backend: &mut dyn SearchBackend) -> Result<()> {
        let plane = Plane::new(
            self.coarse.width,
            self.coarse.height,
            &self.coarse.data,
            None,
        )?;
        backend.load_level(&LevelData::single_plane(
            0,
            1,
            Geometry::new(self.side, 0)?,
            plane,
            &self.positions,
            1 << 16,
        )?)
    }

    /// A gene at the evaluation level (clamped so the patch fits).
    fn coarse_gene(&self, g: Gene) -> Gene {
        let most = |len: usize| (len - self.side) as u32;
        (
            (g.0 >> self.steps).min(most(self.coarse.width)),
            (g.1 >> self.steps).min(most(self.coarse.height)),
        )
    }

    /// The corner genes of tile `j` at the evaluation level.
    fn key(&self, genes: &[Gene], j: usize) -> [Gene; 4] {
        self.set.tiles[j].map(|c| self.coarse_gene(genes[usize::from(c)]))
    }

    /// `D_j` of every tile of every antibody: searched where not cached.
    pub fn errors(
        &mut self,
        backend: &mut dyn SearchBackend,
        antibodies: &[Vec<Gene>],
    ) -> Result<Vec<Vec<f64>>> {
        let mut missing: Vec<[Gene; 4]> = Vec::new();
        let mut queued = std::collections::HashSet::new();
        for genes in antibodies {
            for j in 0..self.set.tiles.len() {
                let key = self.key(genes, j);
                if !self.cache.contains_key(&key) && queued.insert(key) {
                    missing.push(key);
                }
            }
        }
        let geometry = Geometry::new(self.side, 0)?;
        for chunk in missing.chunks(1024) {
            let mut batch = QueryBatch::new(geometry.layout());
            for key in chunk {
                batch.push_full(&intermediate_gray(&self.coarse, self.side, key))?;
            }
            let hits = backend.search(&batch)?;
            ensure!(hits.len() == chunk.len(), "the search lost answers");
            let area = (self.side * self.side) as f64;
            for (key, hit) in chunk.iter().zip(hits) {
                self.cache.insert(*key, (hit.dist as f64 / area, hit.index));
            }
            self.searches += chunk.len() as u64;
        }
        Ok(antibodies
            .iter()
            .map(|genes| {
                (0..self.set.tiles.len())
                    .map(|j| self.cache[&self.key(genes, j)].0)
                    .collect()
            })
            .collect())
    }

    /// The best translation of tile `j` found at the evaluation level, as a
    /// top-left corner in the sample.
    pub(super) fn coarse_match(&self, genes: &[Gene], j: usize) -> Gene {
        let index = self.cache[&self.key(genes, j)].1;
        let [cx, cy] = self.positions.get(index).expect("hit inside the level");
        let r = (self.side / 2) as u32;
        ((cx - r) << self.steps, (cy - r) << self.steps)
    }
}

/// The affinity `f = 1/E` of an antibody whose tiles have errors `d`.
pub fn affinity(d: &[f64], lambda: f64) -> f64 {
    1.0 / energy(d, lambda).max(1e-12)
}

/// `E = λ·ΣD + (1−λ)·Var(D)` (eq. 2).
pub fn energy(d: &[f64], lambda: f64) -> f64 {
    let n = d.len() as f64;
    let mean = d.iter().sum::<f64>() / n;
    let var = d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n;
    lambda * d.iter().sum::<f64>() + (1.0 - lambda) * var
}

/// The intermediate tile (§3): the centre of the 2×2 block of the corner
/// patches, so each quadrant is the opposite quadrant of its patch. `px(x, y,
/// corner)` reads pixel `(x, y)` of the corner's patch (side `side`).
fn intermediate<T>(side: usize, px: impl Fn(usize, usize, usize) -> T) -> Vec<T> {
    let k = side / 2;
    let mut out = Vec::with_capacity(side * side);
    for y in 0..side {
        for x in 0..side {
            let (right, sx) = if x < k { (0, x + side - k) } else { (1, x - k) };
            let (bottom, sy) = if y < k { (0, y + side - k) } else { (1, y - k) };
            out.push(px(sx, sy, 2 * bottom + right));
        }
    }
    out
}

fn intermediate_gray(g: &Gray, side: usize, key: &[Gene; 4]) -> Vec<u8> {
    intermediate(side, |x, y, c| {
        let (gx, gy) = key[c];
        g.get(gx as usize + x, gy as usize + y)
    })
}

/// The intermediate tile of `corners` at full resolution.
pub fn intermediate_tile(sample: &ColorImage, tile: usize, corners: [Gene; 4]) -> ColorImage {
    let px = intermediate(tile, |x, y, c| {
        let (gx, gy) = corners[c];
        sample.get(gx as usize + x, gy as usize + y)
    });
    ColorImage::from_vec(tile, tile, px.into_iter().flatten().collect())
}
