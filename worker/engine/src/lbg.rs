//! LBG (Linde–Buzo–Gray) vector quantisation of a reference range
//! (Stahlhut §8, ARCHITECTURE §3.8): an approximate, much faster search.
//!
//! Training: about √N seeds are drawn from the range with the run's seed
//! (ChaCha), every vector is assigned to its nearest seed (the same masked
//! distance as the exhaustive search, with full masks, ties to the lowest seed
//! index), every seed moves to the rounded centre of its group, and this repeats
//! until the relative change of the total seed displacement between two
//! iterations falls below a threshold (default 5 %) or an iteration cap is hit.
//! The assignment is exact: brute force with the batched kernel, accelerated for
//! L1 by Hamerly's bounds (triangle inequality on integer distances; a vector is
//! skipped only when its seed is *strictly* the nearest, so the result equals the
//! brute-force assignment bit for bit). An empty cell is re-seeded from the
//! largest cell (ChaCha-drawn member); cells still empty at the end are dropped.
//!
//! The partitions are stored as contiguous copies of their vectors (ascending
//! global index inside each, padded to 8 rows for the SIMD kernels). A query
//! scores every seed with the batched kernel under its own mask, then searches
//! the partitions of its `P` nearest seeds exactly (ties to the lowest global
//! index). With `P` = number of seeds the answer is the exhaustive one.
//!
//! Everything is integer arithmetic and every per-vector / per-query result is
//! computed independently of how rayon splits the work, so training and answers
//! do not depend on the number of threads. A [`Codebook`] covers any global
//! index range, so a cluster worker quantises the range it owns and answers
//! from it; the master merges per query by (distance, index) as usual.

use std::ops::Range;
use std::time::Instant;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::error::{EngineError, Result};
use crate::kernel::{Params, Scan, Sink};
use crate::layout::{AlignedBytes, Layout, Metric, QueryBatch, VectorSpace, SLACK};
use crate::merge::{merge_best, Hit};
use crate::search::Engine;

/// Default relative-change threshold of the total seed displacement (Stahlhut: 5 %).
pub const DEFAULT_THRESHOLD: f64 = 0.05;
/// Default cap on assign/move iterations.
pub const DEFAULT_MAX_ITERATIONS: usize = 50;
/// Default training vectors per seed (see [`LbgConfig::sample_per_seed`]).
pub const DEFAULT_SAMPLE_PER_SEED: usize = 32;
/// Largest accepted iteration cap.
pub const MAX_ITERATIONS: usize = 10_000;

/// Rows per SIMD group: partitions and the seed table are padded to a multiple
/// of this, so the kernels never fall back to their scalar tail.
const ROW_GROUP: usize = 8;
/// Vectors per rayon task while training (their bytes stay in L2 while every
/// seed block is scored against them).
const TRAIN_CHUNK: usize = 1024;
/// Seeds scored per kernel pass while training (their bytes stay in L1).
const SEED_BLOCK: usize = 48;

type SeedBlocks = Vec<QueryBatch>;
/// Queries per rayon task while searching (one AVX-512 query group).
const QUERY_CHUNK: usize = 8;

/// How a codebook is trained.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LbgConfig {
    /// Number of seeds; 0 = ⌈√N⌉ for N vectors (Stahlhut: √N is optimal).
    pub seeds: usize,
    /// Stop when |D_t − D_{t−1}| / D_{t−1} < threshold, D_t = total seed
    /// displacement of iteration t (0 < threshold < 1).
    pub threshold: f64,
    /// Cap on assign/move iterations (≥ 1).
    pub max_iterations: usize,
    /// The run's random seed (initial seed draw and re-seeding of empty cells).
    pub seed: u64,
    /// Training set size per seed: the assign/move iterations run on a
    /// ChaCha-drawn subset of `sample_per_seed × seeds` vectors (0 = all
    /// vectors); the final partitions always assign every vector exactly.
    pub sample_per_seed: usize,
    /// Use exact triangle-inequality pruning (Hamerly) for L1; `false` forces
    /// the brute-force assignment (same result, slower; for tests).
    pub prune: bool,
}

impl Default for LbgConfig {
    fn default() -> Self {
        Self {
            seeds: 0,
            threshold: DEFAULT_THRESHOLD,
            max_iterations: DEFAULT_MAX_ITERATIONS,
            seed: 1,
            sample_per_seed: DEFAULT_SAMPLE_PER_SEED,
            prune: true,
        }
    }
}

impl LbgConfig {
    /// Checks the parameters; messages say what is accepted.
    pub fn validate(&self) -> Result<()> {
        check_threshold(self.threshold)?;
        if self.max_iterations == 0 || self.max_iterations > MAX_ITERATIONS {
            return Err(EngineError::Parameter(format!(
                "LBG iteration cap {} must be in 1..={MAX_ITERATIONS}",
                self.max_iterations
            )));
        }
        Ok(())
    }

    /// The number of seeds used for `n` vectors.
    pub fn seeds_for(&self, n: usize) -> usize {
        if self.seeds == 0 {
            default_seeds(n)
        } else {
            self.seeds
        }
    }
}

/// The codebook seed of a range: a mix (SplitMix64) of the run's seed, the
/// level and the range, so a range re-assigned to another worker is
/// re-quantised into exactly the same codebook.
pub fn range_seed(run_seed: u64, level: u32, range: &Range<u64>) -> u64 {
    let mut z = run_seed;
    for x in [u64::from(level), range.start, range.end] {
        z = z.wrapping_add(x).wrapping_add(0x9E37_79B9_7F4A_7C15);
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
    }
    z
}

/// ⌈√n⌉ (at least 1): the seed count Stahlhut recommends.
pub fn default_seeds(n: usize) -> usize {
    let r = n.isqrt();
    (if r * r < n { r + 1 } else { r }).max(1)
}

/// Errors unless `0 < threshold < 1`.
pub fn check_threshold(threshold: f64) -> Result<()> {
    if !(threshold.is_finite() && threshold > 0.0 && threshold < 1.0) {
        return Err(EngineError::Parameter(format!(
            "LBG threshold {threshold} must be strictly between 0 and 1 (e.g. 0.05 for 5 %)"
        )));
    }
    Ok(())
}

/// Errors unless `1 ≤ probes ≤ seeds`.
pub fn check_probes(probes: usize, seeds: usize) -> Result<()> {
    if probes == 0 {
        return Err(EngineError::Parameter(
            "LBG probes must be at least 1 (the partition of the nearest seed)".into(),
        ));
    }
    if probes > seeds {
        return Err(EngineError::Parameter(format!(
            "LBG probes {probes} exceed the {seeds} seeds of the codebook; use 1..={seeds}"
        )));
    }
    Ok(())
}

/// What training did, for the run report.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LbgStats {
    /// Vectors quantised.
    pub vectors: usize,
    /// Vectors the assign/move iterations ran on (all, or a subset).
    pub trained_on: usize,
    /// Seeds drawn.
    pub seeds_requested: usize,
    /// Seeds (= non-empty partitions) in the codebook.
    pub seeds: usize,
    /// Assign/move iterations run.
    pub iterations: usize,
    /// Whether the threshold was reached (false = stopped by the cap).
    pub converged: bool,
    /// Total seed displacement per iteration.
    pub displacement: Vec<u64>,
    /// Empty cells re-seeded during training.
    pub reseeded: usize,
    /// Vectors whose assignment had to be recomputed against all seeds after
    /// the first assignment (Hamerly pruning skips the others), per iteration.
    pub rescans: Vec<u64>,
    /// Vectors in the largest partition.
    pub largest_partition: usize,
    /// Wall time of the training, including building the partitions.
    pub train_seconds: f64,
}

/// A trained LBG codebook over one global index range: the seeds and, per
/// seed, a contiguous copy of its partition.
#[derive(Debug, Clone)]
pub struct Codebook {
    layout: Layout,
    params: Params,
    range: Range<u64>,
    seeds_requested: usize,
    /// Seeds (non-empty partitions).
    k: usize,
    /// k rounded up to [`ROW_GROUP`] rows (padding rows zero) + slack.
    seed_data: AlignedBytes,
    seed_rows: usize,
    /// Row offsets of the partitions in `data` (k + 1 entries).
    part_rows: Vec<usize>,
    /// Offsets of the partitions in `members` (k + 1 entries).
    part_members: Vec<usize>,
    /// Global indices, partition by partition, ascending inside each.
    members: Vec<u64>,
    /// Global index of every row of `data`; `u64::MAX` for padding rows.
    row_index: Vec<u64>,
    data: AlignedBytes,
    stats: LbgStats,
}

/// Full-mask distance between two padded vectors: exactly what the kernels
/// compute for a query whose components are all defined.
fn full_distance(layout: &Layout, params: &Params, a: &[u8], b: &[u8]) -> u64 {
    fn part(a: &[u8], b: &[u8], l2: bool) -> u64 {
        let s: u32 = if l2 {
            a.iter()
                .zip(b)
                .map(|(&x, &y)| {
                    let d = u32::from(x.abs_diff(y));
                    d * d
                })
                .sum()
        } else {
            a.iter()
                .zip(b)
                .map(|(&x, &y)| u32::from(x.abs_diff(y)))
                .sum()
        };
        u64::from(s)
    }
    let l2 = params.metric == Metric::L2;
    let hi = part(&a[..layout.hi_len], &b[..layout.hi_len], l2);
    let lo_range = layout.hi_pad..layout.hi_pad + layout.lo_len;
    let lo = part(&a[lo_range.clone()], &b[lo_range], l2);
    u64::from(params.weights.hi) * hi + u64::from(params.weights.lo) * lo
}

/// Nearest and second-nearest seed of every vector of a chunk. The seeds are
/// the queries; per vector they arrive in ascending seed order, so a strict `<`
/// keeps the lowest seed index among ties.
struct AssignSink {
    best: Vec<u64>,
    arg: Vec<u32>,
    second: Vec<u64>,
    /// Index of the first seed of the block being scanned.
    base: u32,
}

impl AssignSink {
    fn new(n: usize) -> Self {
        Self {
            best: vec![u64::MAX; n],
            arg: vec![0; n],
            second: vec![u64::MAX; n],
            base: 0,
        }
    }

    #[inline(always)]
    fn offer(&mut self, i: usize, seed: u32, x: u64) {
        if x < self.best[i] {
            self.second[i] = self.best[i];
            self.best[i] = x;
            self.arg[i] = seed;
        } else if x < self.second[i] {
            self.second[i] = x;
        }
    }
}

impl Sink for AssignSink {
    #[inline(always)]
    fn row(&mut self, index: u64, d: &[u64]) {
        let i = index as usize;
        let (mut b, mut a, mut s) = (self.best[i], self.arg[i], self.second[i]);
        for (j, &x) in d.iter().enumerate() {
            if x < b {
                s = b;
                b = x;
                a = self.base + j as u32;
            } else if x < s {
                s = x;
            }
        }
        self.best[i] = b;
        self.arg[i] = a;
        self.second[i] = s;
    }

    #[inline(always)]
    fn run(&mut self, q: usize, first: u64, d: &[u64]) {
        for (t, &x) in d.iter().enumerate() {
            self.offer(first as usize + t, self.base + q as u32, x);
        }
    }
}

/// The `p` nearest seeds of every query, sorted by (distance, seed index).
/// Seed rows at or beyond `k` are padding and ignored.
struct TopSeedSink {
    p: usize,
    k: usize,
    lists: Vec<Vec<(u64, u32)>>,
    worst: Vec<u64>,
}

impl TopSeedSink {
    fn new(nq: usize, p: usize, k: usize) -> Self {
        Self {
            p,
            k,
            lists: vec![Vec::with_capacity(p + 1); nq],
            worst: vec![u64::MAX; nq],
        }
    }

    #[inline(always)]
    fn offer(&mut self, q: usize, seed: usize, x: u64) {
        if x >= self.worst[q] || seed >= self.k {
            return;
        }
        let list = &mut self.lists[q];
        let pos = list.partition_point(|e| e.0 <= x);
        list.insert(pos, (x, seed as u32));
        if list.len() > self.p {
            list.pop();
        }
        if list.len() == self.p {
            self.worst[q] = list[self.p - 1].0;
        }
    }
}

impl Sink for TopSeedSink {
    #[inline(always)]
    fn row(&mut self, index: u64, d: &[u64]) {
        for (q, &x) in d.iter().enumerate() {
            self.offer(q, index as usize, x);
        }
    }

    #[inline(always)]
    fn run(&mut self, q: usize, first: u64, d: &[u64]) {
        for (t, &x) in d.iter().enumerate() {
            self.offer(q, first as usize + t, x);
        }
    }
}

/// Best (distance, global index) of each query over partition rows; rows are
/// in ascending global order inside a partition, padding rows are skipped.
struct PartSink<'a> {
    row_index: &'a [u64],
    best: Vec<Hit>,
}

impl Sink for PartSink<'_> {
    #[inline(always)]
    fn row(&mut self, index: u64, d: &[u64]) {
        let g = self.row_index[index as usize];
        if g == u64::MAX {
            return;
        }
        for (b, &x) in self.best.iter_mut().zip(d) {
            if x < b.dist {
                *b = Hit { index: g, dist: x };
            }
        }
    }

    #[inline(always)]
    fn run(&mut self, q: usize, first: u64, d: &[u64]) {
        let mut b = self.best[q];
        for (t, &x) in d.iter().enumerate() {
            if x < b.dist {
                let g = self.row_index[first as usize + t];
                if g != u64::MAX {
                    b = Hit { index: g, dist: x };
                }
            }
        }
        self.best[q] = b;
    }
}

/// Training state: per vector its seed, an upper bound on the distance to it
/// and a lower bound on the distance to every other seed (both exact right
/// after a full assignment).
struct Assignment {
    arg: Vec<u32>,
    upper: Vec<u64>,
    lower: Vec<u64>,
}

/// Assign/move over `n` padded vectors in `data` (followed by [`SLACK`] bytes).
#[derive(Clone, Copy)]
struct Trainer<'a> {
    engine: &'a Engine,
    data: &'a [u8],
    n: usize,
    layout: Layout,
    params: Params,
}

impl Trainer<'_> {
    fn n(&self) -> usize {
        self.n
    }

    fn vector(&self, i: usize) -> &[u8] {
        let s = self.layout.stride();
        &self.data[i * s..(i + 1) * s]
    }

    /// Rows `r` plus the slack the kernels may read.
    fn rows(&self, r: &Range<usize>) -> &[u8] {
        let s = self.layout.stride();
        &self.data[r.start * s..r.end * s + SLACK]
    }

    fn chunks(&self) -> Vec<Range<usize>> {
        let n = self.n();
        (0..n.div_ceil(TRAIN_CHUNK))
            .map(|c| c * TRAIN_CHUNK..((c + 1) * TRAIN_CHUNK).min(n))
            .collect()
    }

    /// Brute-force nearest / second-nearest seed of the vectors in `data`
    /// (`count` padded rows plus slack).
    fn score(&self, data: &[u8], count: usize, seeds: &SeedBlocks) -> AssignSink {
        let mut sink = AssignSink::new(count);
        for (b, q) in seeds.iter().enumerate() {
            sink.base = (b * SEED_BLOCK) as u32;
            let scan = Scan::new(self.layout, self.params, data, count, 0, q);
            self.engine.kernel().scan(&scan, &mut sink);
        }
        sink
    }

    /// The seeds as query batches of [`SEED_BLOCK`] (every component defined).
    fn seed_blocks(&self, seeds: &[u8], k: usize) -> SeedBlocks {
        let s = self.layout.stride();
        (0..k.div_ceil(SEED_BLOCK))
            .map(|b| {
                let r = b * SEED_BLOCK..((b + 1) * SEED_BLOCK).min(k);
                QueryBatch::full_from_padded(self.layout, &seeds[r.start * s..r.end * s], r.len())
            })
            .collect()
    }

    /// Exact assignment of every vector against all seeds.
    fn assign_full(&self, seeds: &[u8], k: usize) -> Assignment {
        let q = self.seed_blocks(seeds, k);
        let parts: Vec<AssignSink> = self
            .chunks()
            .into_par_iter()
            .map(|r| self.score(self.rows(&r), r.len(), &q))
            .collect();
        let mut a = Assignment {
            arg: Vec::with_capacity(self.n()),
            upper: Vec::with_capacity(self.n()),
            lower: Vec::with_capacity(self.n()),
        };
        for p in parts {
            a.arg.extend(p.arg);
            a.upper.extend(p.best);
            a.lower.extend(p.second);
        }
        a
    }

    /// Hamerly's update after the seeds moved from `old` to `new`: bounds are
    /// loosened by the seed displacements, vectors whose seed is provably the
    /// strict nearest keep it, the rest are re-assigned exactly. Returns the
    /// number of vectors re-assigned against all seeds.
    fn assign_pruned(&self, a: &mut Assignment, old: &[u8], new: &[u8], k: usize) -> u64 {
        let s = self.layout.stride();
        let (layout, params) = (&self.layout, &self.params);
        let delta: Vec<u64> = old
            .chunks_exact(s)
            .zip(new.chunks_exact(s))
            .take(k)
            .map(|(o, c)| full_distance(layout, params, o, c))
            .collect();
        // Largest displacement and the largest among the other seeds.
        let (mut m1, mut m1_at, mut m2) = (0u64, usize::MAX, 0u64);
        for (j, &d) in delta.iter().enumerate() {
            if d > m1 {
                m2 = m1;
                m1 = d;
                m1_at = j;
            } else if d > m2 {
                m2 = d;
            }
        }
        // Half the distance to the nearest other seed, kept doubled: a vector
        // with 2·u < sep[a] is strictly nearer to its seed than to any other.
        // The distance of a seed to itself (0) is the smallest of its row, so
        // the second smallest is the distance to the nearest other seed.
        let q = self.seed_blocks(new, k);
        let sep = {
            let mut rows = AlignedBytes::zeroed(k * s + SLACK);
            rows.as_mut_slice()[..k * s].copy_from_slice(&new[..k * s]);
            self.score(rows.as_slice(), k, &q).second
        };
        a.arg
            .par_chunks_mut(TRAIN_CHUNK)
            .zip(a.upper.par_chunks_mut(TRAIN_CHUNK))
            .zip(a.lower.par_chunks_mut(TRAIN_CHUNK))
            .enumerate()
            .map(|(c, ((arg, upper), lower))| {
                let r = c * TRAIN_CHUNK..c * TRAIN_CHUNK + arg.len();
                let mut rescan: Vec<usize> = Vec::new();
                for t in 0..r.len() {
                    let j = arg[t] as usize;
                    let u = upper[t].saturating_add(delta[j]);
                    let l = lower[t].saturating_sub(if j == m1_at { m2 } else { m1 });
                    lower[t] = l;
                    if u < l || u.saturating_mul(2) < sep[j] {
                        upper[t] = u;
                        continue;
                    }
                    let exact = full_distance(
                        layout,
                        params,
                        self.vector(r.start + t),
                        &new[j * s..(j + 1) * s],
                    );
                    upper[t] = exact;
                    if exact < l || exact.saturating_mul(2) < sep[j] {
                        continue;
                    }
                    rescan.push(t);
                }
                if rescan.is_empty() {
                    return 0u64;
                }
                let mut buf = AlignedBytes::zeroed(rescan.len() * s + SLACK);
                for (slot, &t) in buf.as_mut_slice().chunks_exact_mut(s).zip(&rescan) {
                    slot.copy_from_slice(self.vector(r.start + t));
                }
                let sink = self.score(buf.as_slice(), rescan.len(), &q);
                for (x, &t) in rescan.iter().enumerate() {
                    arg[t] = sink.arg[x];
                    upper[t] = sink.best[x];
                    lower[t] = sink.second[x];
                }
                rescan.len() as u64
            })
            .sum()
    }

    /// Members of every seed, ascending global order inside each (counting sort).
    fn groups(arg: &[u32], k: usize) -> (Vec<usize>, Vec<u32>) {
        let mut offsets = vec![0usize; k + 1];
        for &a in arg {
            offsets[a as usize + 1] += 1;
        }
        for j in 0..k {
            offsets[j + 1] += offsets[j];
        }
        let mut fill = offsets.clone();
        let mut members = vec![0u32; arg.len()];
        for (i, &a) in arg.iter().enumerate() {
            members[fill[a as usize]] = i as u32;
            fill[a as usize] += 1;
        }
        (offsets, members)
    }

    /// The move step: every seed goes to the rounded centre of its group; an
    /// empty cell takes a ChaCha-drawn member of the currently largest cell (or
    /// stays where it is when no cell has two members).
    /// Returns the new seeds and the number of re-seeded cells.
    fn centres(&self, old: &[u8], arg: &[u32], k: usize, rng: &mut ChaCha8Rng) -> (Vec<u8>, usize) {
        let s = self.layout.stride();
        let (offsets, members) = Self::groups(arg, k);
        let mut new = old.to_vec();
        new.par_chunks_mut(s).enumerate().for_each(|(j, out)| {
            let m = &members[offsets[j]..offsets[j + 1]];
            if m.is_empty() {
                return;
            }
            let mut sum = vec![0u64; s];
            for &i in m {
                for (acc, &x) in sum.iter_mut().zip(self.vector(i as usize)) {
                    *acc += u64::from(x);
                }
            }
            let c = m.len() as u64;
            for (o, &t) in out.iter_mut().zip(&sum) {
                *o = ((t + c / 2) / c) as u8;
            }
        });
        let mut size: Vec<usize> = (0..k).map(|j| offsets[j + 1] - offsets[j]).collect();
        let mut reseeded = 0;
        for j in 0..k {
            if offsets[j + 1] > offsets[j] {
                continue;
            }
            // Largest cell, ties to the lowest index.
            let big = (0..k)
                .max_by(|&a, &b| size[a].cmp(&size[b]).then(b.cmp(&a)))
                .unwrap_or(0);
            let cell = &members[offsets[big]..offsets[big + 1]];
            if cell.len() < 2 {
                continue;
            }
            let pick = cell[rng.random_range(0..cell.len())] as usize;
            new[j * s..(j + 1) * s].copy_from_slice(self.vector(pick));
            size[big] /= 2;
            reseeded += 1;
        }
        (new, reseeded)
    }
}

impl Codebook {
    /// Trains a codebook over the global index range `range` of `space` with the
    /// comparison parameters of the search.
    pub fn train(
        engine: &Engine,
        space: &VectorSpace,
        range: Range<u64>,
        params: &Params,
        cfg: &LbgConfig,
    ) -> Result<Self> {
        let started = Instant::now();
        engine.kernel().check()?;
        cfg.validate()?;
        space.check_range(&range)?;
        let n = (range.end - range.start) as usize;
        if n > u32::MAX as usize {
            return Err(EngineError::Parameter(format!(
                "LBG over {n} vectors exceeds the limit of {} per codebook; split the range",
                u32::MAX
            )));
        }
        let k = cfg.seeds_for(n);
        if k > n {
            return Err(EngineError::Parameter(format!(
                "{k} LBG seeds for only {n} vectors; use at most {n} (or 0 for ⌈√N⌉)"
            )));
        }
        let layout = space.layout();
        let s = layout.stride();
        let full = Trainer {
            engine,
            data: space.slice(range.clone()),
            n,
            layout,
            params: *params,
        };
        let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
        // The training set: all vectors, or a ChaCha-drawn subset (ascending order).
        let cap = match cfg.sample_per_seed {
            0 => n,
            c => c.saturating_mul(k).min(n),
        };
        let subset = (cap < n).then(|| {
            let mut idx = rand::seq::index::sample(&mut rng, n, cap).into_vec();
            idx.sort_unstable();
            let mut buf = AlignedBytes::zeroed(cap * s + SLACK);
            for (slot, &i) in buf.as_mut_slice().chunks_exact_mut(s).zip(&idx) {
                slot.copy_from_slice(full.vector(i));
            }
            buf
        });
        let t = match &subset {
            Some(buf) => Trainer {
                engine,
                data: buf.as_slice(),
                n: cap,
                layout,
                params: *params,
            },
            None => full,
        };
        let mut picks = rand::seq::index::sample(&mut rng, cap, k).into_vec();
        picks.sort_unstable();
        let mut seeds = vec![0u8; k * s];
        for (slot, &i) in seeds.chunks_exact_mut(s).zip(&picks) {
            slot.copy_from_slice(t.vector(i));
        }
        let prune = cfg.prune && params.metric == Metric::L1;
        let mut a = t.assign_full(&seeds, k);
        let mut stats = LbgStats {
            vectors: n,
            trained_on: cap,
            seeds_requested: k,
            seeds: k,
            iterations: 0,
            converged: false,
            displacement: Vec::new(),
            reseeded: 0,
            rescans: Vec::new(),
            largest_partition: 0,
            train_seconds: 0.0,
        };
        let mut prev: Option<u64> = None;
        while stats.iterations < cfg.max_iterations {
            stats.iterations += 1;
            let (new, reseeded) = t.centres(&seeds, &a.arg, k, &mut rng);
            stats.reseeded += reseeded;
            let disp: u64 = seeds
                .chunks_exact(s)
                .zip(new.chunks_exact(s))
                .map(|(o, c)| full_distance(&layout, params, o, c))
                .sum();
            stats.displacement.push(disp);
            if disp == 0 {
                // Nothing moved: the assignment is already the final one.
                stats.converged = true;
                break;
            }
            if prune {
                stats.rescans.push(t.assign_pruned(&mut a, &seeds, &new, k));
            } else {
                a = t.assign_full(&new, k);
                stats.rescans.push(cap as u64);
            }
            seeds = new;
            if let Some(p) = prev {
                if (p.abs_diff(disp) as f64) < cfg.threshold * p as f64 {
                    stats.converged = true;
                    break;
                }
            }
            prev = Some(disp);
        }

        if subset.is_some() {
            // The partitions hold every vector: assign all of them exactly.
            a = full.assign_full(&seeds, k);
        }
        drop(subset);
        // Partitions of the final seeds; empty cells are dropped.
        let (offsets, members) = Trainer::groups(&a.arg, k);
        let keep: Vec<usize> = (0..k).filter(|&j| offsets[j + 1] > offsets[j]).collect();
        let kk = keep.len();
        let seed_rows = kk.div_ceil(ROW_GROUP) * ROW_GROUP;
        let mut seed_data = AlignedBytes::zeroed(seed_rows * s + SLACK);
        for (slot, &j) in seed_data.as_mut_slice().chunks_exact_mut(s).zip(&keep) {
            slot.copy_from_slice(&seeds[j * s..(j + 1) * s]);
        }
        let mut part_rows = Vec::with_capacity(kk + 1);
        let mut part_members = Vec::with_capacity(kk + 1);
        let (mut rows, mut mem) = (0usize, 0usize);
        for &j in &keep {
            part_rows.push(rows);
            part_members.push(mem);
            let len = offsets[j + 1] - offsets[j];
            rows += len.div_ceil(ROW_GROUP) * ROW_GROUP;
            mem += len;
        }
        part_rows.push(rows);
        part_members.push(mem);
        let mut data = AlignedBytes::zeroed(rows * s + SLACK);
        let mut row_index = vec![u64::MAX; rows];
        let mut global = Vec::with_capacity(n);
        for (p, &j) in keep.iter().enumerate() {
            let m = &members[offsets[j]..offsets[j + 1]];
            let r0 = part_rows[p];
            for (x, &i) in m.iter().enumerate() {
                let g = range.start + u64::from(i);
                row_index[r0 + x] = g;
                global.push(g);
            }
            stats.largest_partition = stats.largest_partition.max(m.len());
        }
        data.as_mut_slice()[..rows * s]
            .par_chunks_mut(s)
            .zip(row_index.par_iter())
            .for_each(|(slot, &g)| {
                if g != u64::MAX {
                    slot.copy_from_slice(space.vector(g).expect("member inside the range"));
                }
            });
        stats.seeds = kk;
        stats.train_seconds = started.elapsed().as_secs_f64();
        Ok(Self {
            layout,
            params: *params,
            range,
            seeds_requested: k,
            k: kk,
            seed_data,
            seed_rows,
            part_rows,
            part_members,
            members: global,
            row_index,
            data,
            stats,
        })
    }

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
        let scan = Scan::new(self.layout, self.params, self.seed_data.as_slice(), self.seed_rows, 0, q);
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
        let scan = Scan::new(self.layout, self.params, &self.data.as_slice()[r0 * s..r1 * s + SLACK], r1 - r0, r0 as u64, q);
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
