//! Choosing the sample patches of an ω-tile set by an artificial immune
//! system (Dong, Zhou and Paul §4), and building the tiles from them.
//!
//! An antibody is `n` patch positions, one per corner colour. Its affinity is
//! `f = 1/E` with `E = λ·ΣD_j + (1−λ)·Var(D)` (eq. 2), where `D_j` is the mean
//! squared error of intermediate tile `j` against its best translation in the
//! sample (eq. 1). Those searches are exact and go through the project's
//! search backend, so they run in-process or on the cluster with the same
//! answers; they are batched per generation and cached per tuple of corner
//! positions.

use std::collections::HashMap;
use std::time::Instant;

use anyhow::{ensure, Result};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use texsyn_engine::{Geometry, Metric, Params, Plane, Positions, QueryBatch, Sample, Weights};

use super::graphcut;
use super::omega::OmegaSet;
use crate::imaging::colour::luminance;
use crate::imaging::{ColorImage, Gray};
use crate::pyramid::downsample;
use crate::search::{LevelData, SearchBackend};

/// The immune search's parameters; the defaults are the paper's (§4.4).
#[derive(Clone, Copy, Debug, Serialize)]
pub struct AisSettings {
    /// N_p: antibodies in the population.
    pub population: usize,
    /// s_min, s_max: the memory unit's least and greatest share.
    pub memory_min: f64,
    pub memory_max: f64,
    /// α: clone threshold; β: clone multiplying factor.
    pub alpha: f64,
    pub beta: f64,
    /// N_d: the worst antibodies replaced by random ones each generation.
    pub deaths: usize,
    /// N_g: generations at most; N_o: generations without improvement at most.
    pub generations: usize,
    pub patience: usize,
    /// λ: weight of the error sum against the variance.
    pub lambda: f64,
    pub seed: u64,
}

impl Default for AisSettings {
    fn default() -> Self {
        Self {
            population: 40,
            memory_min: 0.2,
            memory_max: 0.4,
            alpha: 0.4,
            beta: 4.0,
            deaths: 10,
            generations: 50,
            patience: 6,
            lambda: 0.8,
            seed: 1,
        }
    }
}

/// A patch position (top-left corner in the sample), one gene.
pub type Gene = (u32, u32);

/// The evaluation of intermediate tiles: a coarse copy of the sample where a
/// tile fits the engine's odd window, the reference positions (every
/// translation of a tile inside the sample) and the cache of `D` per tuple.
pub struct Evaluator<'a> {
    set: &'a OmegaSet,
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
        backend.load_level(&LevelData {
            level: 0,
            geometry: Geometry::new(self.side, 0)?,
            params: Params {
                metric: Metric::L2,
                weights: Weights::new(1, 1)?,
            },
            sample: Sample {
                fine: plane,
                parent: None,
            },
            positions: &self.positions,
            levels: 1,
            expected_queries: 1 << 16,
            colour_vectors: None,
        })
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
    fn coarse_match(&self, genes: &[Gene], j: usize) -> Gene {
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

/// Sorts antibodies from high affinity to low (stable: ties keep their order).
fn sort_by_affinity(population: &mut Vec<Vec<Gene>>, f: &mut Vec<f64>) {
    let mut pairs: Vec<(f64, Vec<Gene>)> = f.drain(..).zip(population.drain(..)).collect();
    pairs.sort_by(|a, b| b.0.total_cmp(&a.0));
    for (v, g) in pairs {
        f.push(v);
        population.push(g);
    }
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

/// One generation of the search, for `ais.json`.
#[derive(Clone, Debug, Serialize)]
pub struct Generation {
    pub generation: usize,
    pub best_f: f64,
    pub mean_f: f64,
    /// Diversity h and memory-unit size N_m of this generation.
    pub diversity: f64,
    pub memory: usize,
    pub searches: u64,
    pub seconds: f64,
}

/// The outcome of the immune search.
#[derive(Clone, Debug, Serialize)]
pub struct AisResult {
    pub genes: Vec<Gene>,
    pub best_f: f64,
    pub history: Vec<Generation>,
    pub searches: u64,
    pub seconds: f64,
}

/// Sample-space bounds of the genes: `l = (0, 0)`, `u = (W − T, H − T)`.
fn upper(sample: &ColorImage, tile: usize) -> Gene {
    ((sample.width - tile) as u32, (sample.height - tile) as u32)
}

/// The genes live on the evaluation level's grid (every `2^steps` sample
/// pixels): finer moves could not change an affinity. This is that grid's
/// upper bound; a grid gene `g` is the sample position `g << steps`.
fn grid_upper(sample: &ColorImage, ev: &Evaluator) -> Gene {
    let u = upper(sample, ev.tile);
    (u.0 >> ev.steps, u.1 >> ev.steps)
}

fn to_sample(g: Gene, steps: usize) -> Gene {
    (g.0 << steps, g.1 << steps)
}

fn random_gene(rng: &mut ChaCha8Rng, u: Gene) -> Gene {
    (rng.random_range(0..=u.0), rng.random_range(0..=u.1))
}

/// `n` genes, one from each of `n` equal cells of the valid region, shuffled
/// (§4.2.1, the spread half of the first population).
fn spread_antibody(rng: &mut ChaCha8Rng, u: Gene, n: usize) -> Vec<Gene> {
    let cols = (n as f64).sqrt().ceil() as usize;
    let rows = n.div_ceil(cols);
    let mut genes: Vec<Gene> = (0..n)
        .map(|k| {
            let (cx, cy) = ((k % cols) as u64, (k / cols) as u64);
            let cell = |len: u32, i: u64, parts: usize| {
                let span = u64::from(len) + 1;
                let lo = span * i / parts as u64;
                let hi = (span * (i + 1) / parts as u64).max(lo + 1);
                (lo as u32, hi as u32 - 1)
            };
            let (x0, x1) = cell(u.0, cx, cols);
            let (y0, y1) = cell(u.1, cy, rows);
            (rng.random_range(x0..=x1), rng.random_range(y0..=y1))
        })
        .collect();
    for i in (1..n).rev() {
        genes.swap(i, rng.random_range(0..=i));
    }
    genes
}

/// BGA mutation of one grid coordinate (§4.2.5): `g ± 0.1·δ·(u − l)` with
/// `δ = Σ γ_i 2^−i` over 16 bits that are each 1 with probability 1/16; a
/// value outside `[l, u]` becomes `(g + 0.2·(u − l))/1.4`. The paper writes
/// it for a gene as a whole; it is applied to each coordinate here, and a
/// step that rounds to nothing moves one grid cell, so a mutation mutates.
fn bga(rng: &mut ChaCha8Rng, g: u32, u: u32) -> u32 {
    let delta: f64 = (0..16)
        .filter(|_| rng.random_range(0..16) == 0)
        .map(|i| 0.5f64.powi(i))
        .sum();
    let step = (0.1 * delta * f64::from(u)).max(1.0);
    let mut v = if rng.random_bool(0.5) {
        f64::from(g) + step
    } else {
        f64::from(g) - step
    };
    if !(0.0..=f64::from(u)).contains(&v) {
        v = (v + 0.2 * f64::from(u)) / 1.4;
    }
    v.round().clamp(0.0, f64::from(u)) as u32
}

/// The immune search (§4.2) for the `set.colours` patch positions.
pub fn search(
    evaluator: &mut Evaluator,
    backend: &mut dyn SearchBackend,
    sample: &ColorImage,
    s: &AisSettings,
    progress: &dyn Fn(&Generation),
) -> Result<AisResult> {
    let t0 = Instant::now();
    let n = evaluator.set.colours;
    let np = s.population.max(2);
    let steps = evaluator.steps;
    let u = grid_upper(sample, evaluator);
    let diagonal = (f64::from(u.0).powi(2) + f64::from(u.1).powi(2))
        .sqrt()
        .max(1.0);
    let mut rng = ChaCha8Rng::seed_from_u64(s.seed);
    // §4.2.1: half at random, half spread over the valid region.
    let mut population: Vec<Vec<Gene>> = (0..np)
        .map(|i| {
            if i < np / 2 {
                (0..n).map(|_| random_gene(&mut rng, u)).collect()
            } else {
                spread_antibody(&mut rng, u, n)
            }
        })
        .collect();
    let affinities = |ev: &mut Evaluator,
                      backend: &mut dyn SearchBackend,
                      abs: &[Vec<Gene>]|
     -> Result<Vec<f64>> {
        let at: Vec<Vec<Gene>> = abs
            .iter()
            .map(|a| a.iter().map(|&g| to_sample(g, steps)).collect())
            .collect();
        Ok(ev
            .errors(backend, &at)?
            .iter()
            .map(|d| affinity(d, s.lambda))
            .collect())
    };
    let mut f = affinities(evaluator, backend, &population)?;
    let mut history = Vec::new();
    let (mut best_f, mut stale) = (f64::MIN, 0);
    for generation in 1..=s.generations.max(1) {
        // §4.2.2: from high affinity to low.
        sort_by_affinity(&mut population, &mut f);
        // §4.2.3: diversity h and the memory unit.
        let mut h_sum = 0.0;
        for a in &population {
            for b in &population {
                h_sum += a
                    .iter()
                    .zip(b)
                    .map(|(p, q)| {
                        (f64::from(p.0) - f64::from(q.0)).hypot(f64::from(p.1) - f64::from(q.1))
                    })
                    .sum::<f64>();
            }
        }
        let h = ((h_sum / ((np - 1) * np) as f64).sqrt() / diagonal).clamp(0.0, 1.0);
        let nm = ((np as f64 * (s.memory_min + h).min(s.memory_max)).floor() as usize).min(np);
        // §4.2.4: mutation probabilities.
        let pc = (s.memory_min + h) / 2.0;
        let (pm, pab) = ((1.4 * pc).min(0.3), (3.0 * pc).min(0.8));
        let total_f: f64 = f.iter().sum();
        // §4.2.5: clone, mutate, keep the best clone if it beats its parent.
        // The printed clone count is ambiguous (μ is defined but unused):
        // here μ = β·N_p·f_i/Σf sets the count, at least 1, capped by the
        // printed thresholds, max(α·N_p, N_p/3) for memory cells and
        // min(α·N_p, N_p/3) for the others.
        let cap_memory = (s.alpha * np as f64).max(np as f64 / 3.0);
        let cap_generic = (s.alpha * np as f64).min(np as f64 / 3.0);
        let mut clones: Vec<(usize, Vec<Gene>)> = Vec::new();
        for (i, parent) in population.iter().enumerate() {
            let share = f[i] / total_f;
            let mut p = pc + 1.0 / (1.0 + (n as f64 * share).exp());
            let cap = if i < nm {
                p = p.min(pm);
                cap_memory
            } else {
                p = p.max(pab);
                cap_generic
            };
            let count = (s.beta * np as f64 * share)
                .round()
                .clamp(1.0, cap.max(1.0)) as usize;
            for _ in 0..count {
                let mut c = parent.clone();
                if rng.random_bool(p.clamp(0.0, 1.0)) {
                    let k = rng.random_range(0..n);
                    c[k] = (bga(&mut rng, c[k].0, u.0), bga(&mut rng, c[k].1, u.1));
                }
                clones.push((i, c));
            }
        }
        let genes: Vec<Vec<Gene>> = clones.iter().map(|(_, c)| c.clone()).collect();
        let cf = affinities(evaluator, backend, &genes)?;
        let mut best_clone: Vec<Option<(f64, usize)>> = vec![None; np];
        for (k, (i, _)) in clones.iter().enumerate() {
            if best_clone[*i].is_none_or(|(b, _)| cf[k] > b) {
                best_clone[*i] = Some((cf[k], k));
            }
        }
        for (i, b) in best_clone.iter().enumerate() {
            if let Some((v, k)) = *b {
                if v > f[i] {
                    f[i] = v;
                    population[i] = clones[k].1.clone();
                }
            }
        }
        // §4.2.6: the N_d worst die and are replaced by random antibodies.
        sort_by_affinity(&mut population, &mut f);
        let generation_best = f[0];
        let deaths = s.deaths.min(np - 1);
        let newcomers: Vec<Vec<Gene>> = (0..deaths)
            .map(|_| (0..n).map(|_| random_gene(&mut rng, u)).collect())
            .collect();
        let nf = affinities(evaluator, backend, &newcomers)?;
        for (k, (g, v)) in newcomers.into_iter().zip(nf).enumerate() {
            population[np - deaths + k] = g;
            f[np - deaths + k] = v;
        }
        // §4.2.7: stop after N_g generations or N_o without improvement.
        if generation_best > best_f * (1.0 + 1e-12) {
            best_f = generation_best;
            stale = 0;
        } else {
            stale += 1;
        }
        let record = Generation {
            generation,
            best_f,
            mean_f: f.iter().sum::<f64>() / np as f64,
            diversity: h,
            memory: nm,
            searches: evaluator.searches,
            seconds: t0.elapsed().as_secs_f64(),
        };
        progress(&record);
        history.push(record);
        if stale >= s.patience {
            break;
        }
    }
    let best = (0..np)
        .max_by(|&a, &b| f[a].total_cmp(&f[b]).then(b.cmp(&a)))
        .unwrap();
    Ok(AisResult {
        genes: population[best]
            .iter()
            .map(|&g| to_sample(g, steps))
            .collect(),
        best_f: f[best],
        history,
        searches: evaluator.searches,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// The affinities of `count` random antibodies (the paper's "random" and
/// "semi-random" baselines are their mean and their best).
pub fn random_affinities(
    evaluator: &mut Evaluator,
    backend: &mut dyn SearchBackend,
    sample: &ColorImage,
    count: usize,
    lambda: f64,
    seed: u64,
) -> Result<Vec<f64>> {
    let u = grid_upper(sample, evaluator);
    let n = evaluator.set.colours;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let abs: Vec<Vec<Gene>> = (0..count)
        .map(|_| {
            (0..n)
                .map(|_| to_sample(random_gene(&mut rng, u), evaluator.steps))
                .collect()
        })
        .collect();
    Ok(evaluator
        .errors(backend, &abs)?
        .iter()
        .map(|d| affinity(d, lambda))
        .collect())
}

/// One finished ω-tile and how it was made.
#[derive(Clone, Debug, Serialize)]
pub struct OmegaTile {
    pub corners: String,
    /// Top-left corner of the matching patch in the sample.
    pub matching_patch: Gene,
    /// Mean squared RGB error of the intermediate tile against it.
    pub match_error: f64,
    /// Share of the tile's pixels taken from the matching patch.
    pub patch_share: f64,
}

/// Builds every tile of the set from the chosen genes (§3, §4.3): the
/// intermediate tile, its matching patch (the evaluation level's best
/// translation, refined at full resolution over ±2^steps pixels by the RGB
/// error), the graph-cut merge and Poisson smoothing of the quarter seams and
/// the cut.
pub fn build_tiles(
    evaluator: &Evaluator,
    sample: &ColorImage,
    genes: &[Gene],
) -> (Vec<ColorImage>, Vec<OmegaTile>) {
    use rayon::prelude::*;
    let t = evaluator.tile;
    let u = upper(sample, t);
    let reach = 1i64 << evaluator.steps;
    (0..evaluator.set.tiles.len())
        .into_par_iter()
        .map(|j| {
            let corners = evaluator.set.tiles[j].map(|c| genes[usize::from(c)]);
            let inter = intermediate_tile(sample, t, corners);
            let (cx, cy) = evaluator.coarse_match(genes, j);
            let mut best = (f64::INFINITY, (cx.min(u.0), cy.min(u.1)));
            for dy in -reach..=reach {
                for dx in -reach..=reach {
                    let (x, y) = (i64::from(cx) + dx, i64::from(cy) + dy);
                    if x < 0 || y < 0 || x > i64::from(u.0) || y > i64::from(u.1) {
                        continue;
                    }
                    let patch = sample.crop(x as usize, y as usize, t, t);
                    let e = mean_squared(&inter, &patch);
                    if e < best.0 {
                        best = (e, (x as u32, y as u32));
                    }
                }
            }
            let patch = sample.crop(best.1 .0 as usize, best.1 .1 as usize, t, t);
            let merged = graphcut::merge(&inter, &patch);
            let k = t / 2;
            let from = &merged.from_patch;
            let seam = |p: usize, q: usize| {
                if from[p] != from[q] {
                    return true;
                }
                // Quarter junctions of the intermediate tile, where it shows.
                !from[p] && ((p % t < k) != (q % t < k) || (p / t < k) != (q / t < k))
            };
            let image = graphcut::poisson_smooth(&merged.image, seam, 200);
            let share = from.iter().filter(|&&b| b).count() as f64 / (t * t) as f64;
            (
                image,
                OmegaTile {
                    corners: OmegaSet::name(evaluator.set.tiles[j]),
                    matching_patch: best.1,
                    match_error: best.0,
                    patch_share: share,
                },
            )
        })
        .unzip()
}

fn mean_squared(a: &ColorImage, b: &ColorImage) -> f64 {
    let (w, h) = (a.width, a.height);
    let mut s = 0u64;
    for y in 0..h {
        for x in 0..w {
            let (p, q) = (a.get(x, y), b.get(x, y));
            for c in 0..3 {
                s += (i64::from(p[c]) - i64::from(q[c])).pow(2) as u64;
            }
        }
    }
    s as f64 / (w * h) as f64
}
