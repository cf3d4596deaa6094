//! Choosing the sample patches of an ω-tile set by an artificial immune
//! system (Dong, Zhou and Paul §4).
//!
//! An antibody is `n` patch positions, one per corner colour. Its affinity is
//! `f = 1/E` with `E = λ·ΣD_j + (1−λ)·Var(D)` (eq. 2), where `D_j` is the mean
//! squared error of intermediate tile `j` against its best translation in the
//! sample (eq. 1), found by the [`Evaluator`].

use std::time::Instant;

use anyhow::Result;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

pub use super::build::{build_tiles, OmegaTile};
pub use super::evaluate::{affinity, brute_force_error, energy, intermediate_tile, Evaluator};
use crate::imaging::ColorImage;
use crate::progress::Progress;

/// The immune search's parameters; the defaults are the paper's (§4.4).
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
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

/// Sorts antibodies from high affinity to low (stable: ties keep their order).
fn sort_by_affinity(population: &mut Vec<Vec<Gene>>, f: &mut Vec<f64>) {
    let mut pairs: Vec<(f64, Vec<Gene>)> = f.drain(..).zip(population.drain(..)).collect();
    pairs.sort_by(|a, b| b.0.total_cmp(&a.0));
    for (v, g) in pairs {
        f.push(v);
        population.push(g);
    }
}

/// One generation of the search, for `ais.json`.
#[derive(Clone, Debug, Serialize, Deserialize)]
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
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct AisResult {
    pub genes: Vec<Gene>,
    pub best_f: f64,
    /// The best affinity the immune search itself reached, before the
    /// closing descent ([`polish`]).
    #[serde(default)]
    pub search_f: f64,
    /// Moves the descent kept.
    #[serde(default)]
    pub polish_moves: usize,
    pub history: Vec<Generation>,
    pub searches: u64,
    pub seconds: f64,
}

/// Sample-space bounds of the genes: `l = (0, 0)`, `u = (W − T, H − T)`.
pub(super) fn upper(sample: &ColorImage, tile: usize) -> Gene {
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

/// The share of a `t`×`t` patch at `a` that the one at `b` covers.
pub fn patch_cover(a: Gene, b: Gene, t: usize) -> f64 {
    let d = |p: u32, q: u32| t.saturating_sub(p.abs_diff(q) as usize);
    (d(a.0, b.0) * d(a.1, b.1)) as f64 / (t * t).max(1) as f64
}

/// Patches of two colours are distinct when neither covers half of the
/// other (the measure `texsyn compare SET_DIR` counts as `distinct_patches`).
pub const MAX_COVER: f64 = 0.5;

/// Whether grid gene `g` for colour `k` keeps clear of the other colours'
/// patches (`side` is the patch side in grid cells).
fn clear_of(genes: &[Gene], k: usize, g: Gene, side: usize) -> bool {
    genes
        .iter()
        .enumerate()
        .all(|(i, &o)| i == k || patch_cover(g, o, side) < MAX_COVER)
}

/// Tries a new gene `draw` for colour `k` until it keeps clear of the
/// others (§3: a colour is a patch of its own); after `TRIES` draws the
/// one covering the least is kept.
fn clear_gene(
    rng: &mut ChaCha8Rng,
    genes: &[Gene],
    k: usize,
    side: usize,
    mut draw: impl FnMut(&mut ChaCha8Rng) -> Gene,
) -> Gene {
    const TRIES: usize = 32;
    let worst = |g: Gene| {
        genes
            .iter()
            .enumerate()
            .filter(|&(i, _)| i != k)
            .map(|(_, &o)| patch_cover(g, o, side))
            .fold(0.0, f64::max)
    };
    let mut best = (f64::INFINITY, (0, 0));
    for _ in 0..TRIES {
        let g = draw(rng);
        if clear_of(genes, k, g, side) {
            return g;
        }
        let w = worst(g);
        if w < best.0 {
            best = (w, g);
        }
    }
    best.1
}

/// `n` random grid genes whose patches keep clear of each other.
fn random_antibody(rng: &mut ChaCha8Rng, u: Gene, n: usize, side: usize) -> Vec<Gene> {
    let mut genes: Vec<Gene> = Vec::with_capacity(n);
    for k in 0..n {
        let g = clear_gene(rng, &genes, k, side, |r| random_gene(r, u));
        genes.push(g);
    }
    genes
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

/// The first population (§4.2.1): half at random, half spread over the
/// valid region.
fn first_population(
    rng: &mut ChaCha8Rng,
    u: Gene,
    n: usize,
    np: usize,
    side: usize,
) -> Vec<Vec<Gene>> {
    (0..np)
        .map(|i| {
            if i < np / 2 {
                random_antibody(rng, u, n, side)
            } else {
                let mut genes = spread_antibody(rng, u, n);
                for k in 0..n {
                    if !clear_of(&genes, k, genes[k], side) {
                        genes[k] = clear_gene(rng, &genes, k, side, |r| random_gene(r, u));
                    }
                }
                genes
            }
        })
        .collect()
}

/// The diversity h of the population (§4.2.3): the root mean pairwise gene
/// distance over the valid region's diagonal.
fn diversity(population: &[Vec<Gene>], diagonal: f64) -> f64 {
    let np = population.len();
    let mut h_sum = 0.0;
    for a in population {
        for b in population {
            h_sum += a
                .iter()
                .zip(b)
                .map(|(p, q)| {
                    (f64::from(p.0) - f64::from(q.0)).hypot(f64::from(p.1) - f64::from(q.1))
                })
                .sum::<f64>();
        }
    }
    ((h_sum / ((np - 1) * np) as f64).sqrt() / diagonal).clamp(0.0, 1.0)
}

/// The clones of every antibody (§4.2.4, §4.2.5), each mutated with its
/// probability: (parent, genes). The printed clone count is ambiguous (μ is
/// defined but unused): here μ = β·N_p·f_i/Σf sets the count, at least 1,
/// capped by the printed thresholds, max(α·N_p, N_p/3) for the `nm` memory
/// cells and min(α·N_p, N_p/3) for the others.
fn clones(
    rng: &mut ChaCha8Rng,
    population: &[Vec<Gene>],
    f: &[f64],
    (h, nm): (f64, usize),
    (u, side): (Gene, usize),
    s: &AisSettings,
) -> Vec<(usize, Vec<Gene>)> {
    let (np, n) = (population.len(), population[0].len());
    let pc = (s.memory_min + h) / 2.0;
    let (pm, pab) = ((1.4 * pc).min(0.3), (3.0 * pc).min(0.8));
    let total_f: f64 = f.iter().sum();
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
                // A mutation that would put two colours on one patch is
                // drawn again (and dropped if it keeps doing so).
                let k = rng.random_range(0..n);
                for _ in 0..8 {
                    let g = (bga(rng, c[k].0, u.0), bga(rng, c[k].1, u.1));
                    if clear_of(&c, k, g, side) {
                        c[k] = g;
                        break;
                    }
                }
            }
            clones.push((i, c));
        }
    }
    clones
}

/// Each antibody takes its best clone if that beats it (§4.2.5).
fn keep_better_clones(
    population: &mut [Vec<Gene>],
    f: &mut [f64],
    clones: &[(usize, Vec<Gene>)],
    cf: &[f64],
) {
    let mut best_clone: Vec<Option<(f64, usize)>> = vec![None; population.len()];
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
}

/// The affinities of antibodies on the evaluation grid, each divided by
/// `1 + 4·c` for its `c` pairs of colours whose patches cover half of each
/// other (the draws avoid them but may fail to where patches must crowd).
fn affinities(ev: &mut Evaluator, abs: &[Vec<Gene>], lambda: f64) -> Result<Vec<f64>> {
    let at: Vec<Vec<Gene>> = abs
        .iter()
        .map(|a| a.iter().map(|&g| to_sample(g, ev.steps)).collect())
        .collect();
    let side = grid_side(ev);
    let f = sample_affinities(ev, &at, lambda)?;
    Ok(abs
        .iter()
        .zip(f)
        .map(|(a, f)| {
            let clashes = (0..a.len())
                .flat_map(|i| (i + 1..a.len()).map(move |j| (i, j)))
                .filter(|&(i, j)| patch_cover(a[i], a[j], side) >= MAX_COVER)
                .count();
            f / (1.0 + 4.0 * clashes as f64)
        })
        .collect())
}

/// The affinities of patch sets given in sample pixels.
pub fn sample_affinities(ev: &mut Evaluator, sets: &[Vec<Gene>], lambda: f64) -> Result<Vec<f64>> {
    Ok(ev
        .errors(sets)?
        .iter()
        .map(|d| affinity(d, lambda))
        .collect())
}

/// The patch side in grid cells (for the distinctness of patches).
fn grid_side(ev: &Evaluator) -> usize {
    (ev.tile >> ev.steps).max(1)
}

/// The immune search (§4.2) for the `set.colours` patch positions; reports
/// each generation to `progress`.
pub fn search(
    evaluator: &mut Evaluator,
    sample: &ColorImage,
    s: &AisSettings,
    progress: &dyn Progress,
) -> Result<AisResult> {
    let t0 = Instant::now();
    let n = evaluator.set.colours;
    let np = s.population.max(2);
    let u = grid_upper(sample, evaluator);
    let diagonal = (f64::from(u.0).powi(2) + f64::from(u.1).powi(2))
        .sqrt()
        .max(1.0);
    let side = grid_side(evaluator);
    let mut rng = ChaCha8Rng::seed_from_u64(s.seed);
    let mut population = first_population(&mut rng, u, n, np, side);
    let mut f = affinities(evaluator, &population, s.lambda)?;
    let mut history = Vec::new();
    let (mut best_f, mut stale) = (f64::MIN, 0);
    progress.start("immune search", s.generations.max(1) as u64, "generations");
    for generation in 1..=s.generations.max(1) {
        // §4.2.2: from high affinity to low; §4.2.3: the memory unit.
        sort_by_affinity(&mut population, &mut f);
        let h = diversity(&population, diagonal);
        let nm = ((np as f64 * (s.memory_min + h).min(s.memory_max)).floor() as usize).min(np);
        let clones = clones(&mut rng, &population, &f, (h, nm), (u, side), s);
        let genes: Vec<Vec<Gene>> = clones.iter().map(|(_, c)| c.clone()).collect();
        let cf = affinities(evaluator, &genes, s.lambda)?;
        keep_better_clones(&mut population, &mut f, &clones, &cf);
        // §4.2.6: the N_d worst die and are replaced by random antibodies.
        sort_by_affinity(&mut population, &mut f);
        let generation_best = f[0];
        let deaths = s.deaths.min(np - 1);
        let newcomers: Vec<Vec<Gene>> = (0..deaths)
            .map(|_| random_antibody(&mut rng, u, n, side))
            .collect();
        let nf = affinities(evaluator, &newcomers, s.lambda)?;
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
        history.push(Generation {
            generation,
            best_f,
            mean_f: f.iter().sum::<f64>() / np as f64,
            diversity: h,
            memory: nm,
            searches: evaluator.searches,
            seconds: t0.elapsed().as_secs_f64(),
        });
        tracing::info!(generation, best_f, "generation done");
        progress.set_done(generation as u64);
        if stale >= s.patience {
            break;
        }
    }
    progress.finish();
    // The descent starts from each of the best few distinct antibodies (a
    // local optimum near the best may lie below one near the runner-up);
    // the best outcome is kept, the first on ties.
    sort_by_affinity(&mut population, &mut f);
    let mut starts: Vec<usize> = Vec::new();
    for i in 0..np {
        if starts.len() >= POLISH_STARTS {
            break;
        }
        if starts.iter().all(|&k| population[k] != population[i]) {
            starts.push(i);
        }
    }
    let search_f = f[0];
    let mut best: Option<(Vec<Gene>, f64, usize)> = None;
    for &i in &starts {
        let p = polish(evaluator, population[i].clone(), f[i], (u, side), s.lambda)?;
        if best.as_ref().is_none_or(|b| p.1 > b.1) {
            best = Some(p);
        }
    }
    let (genes, best_f, polish_moves) = best.unwrap_or((population[0].clone(), f[0], 0));
    Ok(AisResult {
        genes: genes
            .iter()
            .map(|&g| to_sample(g, evaluator.steps))
            .collect(),
        best_f,
        search_f,
        polish_moves,
        history,
        searches: evaluator.searches,
        seconds: t0.elapsed().as_secs_f64(),
    })
}
/// A closing descent on one antibody (beyond the paper, which stops at
/// the immune search): each gene in turn tries steps of 16, 8, 4, 2 and 1
/// grid cells along each axis and keeps any that raises the affinity and
/// keeps the patches clear of each other, until a round keeps none (at most
/// [`POLISH_ROUNDS`]). Returns the genes, their affinity and the moves kept.
fn polish(
    ev: &mut Evaluator,
    mut genes: Vec<Gene>,
    mut f: f64,
    (u, side): (Gene, usize),
    lambda: f64,
) -> Result<(Vec<Gene>, f64, usize)> {
    let mut kept = 0;
    for _ in 0..POLISH_ROUNDS {
        let before = kept;
        for k in 0..genes.len() {
            for step in [16i64, 8, 4, 2, 1] {
                let moves: Vec<Vec<Gene>> = [(step, 0), (-step, 0), (0, step), (0, -step)]
                    .iter()
                    .filter_map(|&(dx, dy)| {
                        let (x, y) = (i64::from(genes[k].0) + dx, i64::from(genes[k].1) + dy);
                        let inside =
                            (0..=i64::from(u.0)).contains(&x) && (0..=i64::from(u.1)).contains(&y);
                        let g = (x as u32, y as u32);
                        (inside && clear_of(&genes, k, g, side)).then(|| {
                            let mut c = genes.clone();
                            c[k] = g;
                            c
                        })
                    })
                    .collect();
                let mf = affinities(ev, &moves, lambda)?;
                if let Some((i, &v)) = mf
                    .iter()
                    .enumerate()
                    .max_by(|a, b| a.1.total_cmp(b.1).then(b.0.cmp(&a.0)))
                {
                    if v > f * (1.0 + 1e-12) {
                        f = v;
                        genes = moves[i].clone();
                        kept += 1;
                    }
                }
            }
        }
        if kept == before {
            break;
        }
    }
    Ok((genes, f, kept))
}

/// Rounds of the closing descent at most.
const POLISH_ROUNDS: usize = 8;

/// Distinct antibodies of the last population the descent starts from.
const POLISH_STARTS: usize = 4;

/// `count` random patch sets in sample pixels, each colour's patch clear of
/// the others' as in the search (the paper's "random" and "semi-random"
/// baselines are their mean affinity and their best, Table 2).
pub fn random_sets(ev: &Evaluator, sample: &ColorImage, count: usize, seed: u64) -> Vec<Vec<Gene>> {
    let u = grid_upper(sample, ev);
    let (n, side) = (ev.set.colours, grid_side(ev));
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..count)
        .map(|_| {
            random_antibody(&mut rng, u, n, side)
                .into_iter()
                .map(|g| to_sample(g, ev.steps))
                .collect()
        })
        .collect()
}
