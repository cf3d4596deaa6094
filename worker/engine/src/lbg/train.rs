//! LBG training (Stahlhut §8, ARCHITECTURE §3.8): exact assignment of every
//! vector to its nearest seed (brute force, or Hamerly's bounds for L1), the move
//! step, and the partitions of the final seeds.

use std::ops::Range;
use std::time::Instant;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use super::sinks::AssignSink;
use super::{Codebook, LbgConfig, LbgStats, SeedBlocks, ROW_GROUP, SEED_BLOCK, TRAIN_CHUNK};
use crate::batch::QueryBatch;
use crate::error::{EngineError, Result};
use crate::kernel::{Params, Scan};
use crate::layout::{Layout, Metric, SLACK};
use crate::search::Engine;
use crate::space::{AlignedBytes, VectorSpace};

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

impl Trainer<'_> {
    /// The training subset: `cap` ChaCha-drawn vectors in ascending order,
    /// copied into their own buffer (with slack).
    fn subset(&self, rng: &mut ChaCha8Rng, cap: usize) -> AlignedBytes {
        let s = self.layout.stride();
        let mut idx = rand::seq::index::sample(rng, self.n, cap).into_vec();
        idx.sort_unstable();
        let mut buf = AlignedBytes::zeroed(cap * s + SLACK);
        for (slot, &i) in buf.as_mut_slice().chunks_exact_mut(s).zip(&idx) {
            slot.copy_from_slice(self.vector(i));
        }
        buf
    }

    /// The `k` initial seeds: ChaCha-drawn training vectors in ascending order.
    fn initial_seeds(&self, rng: &mut ChaCha8Rng, k: usize) -> Vec<u8> {
        let s = self.layout.stride();
        let mut picks = rand::seq::index::sample(rng, self.n, k).into_vec();
        picks.sort_unstable();
        let mut seeds = vec![0u8; k * s];
        for (slot, &i) in seeds.chunks_exact_mut(s).zip(&picks) {
            slot.copy_from_slice(self.vector(i));
        }
        seeds
    }

    /// Assign/move until the relative change of the total seed displacement
    /// falls below the threshold or the iteration cap is hit. Moves `seeds` to
    /// their final place and returns the assignment of the training vectors.
    fn iterate(
        &self,
        seeds: &mut Vec<u8>,
        k: usize,
        cfg: &LbgConfig,
        rng: &mut ChaCha8Rng,
        stats: &mut LbgStats,
    ) -> Assignment {
        let s = self.layout.stride();
        let (layout, params) = (&self.layout, &self.params);
        let prune = cfg.prune && params.metric == Metric::L1;
        let mut a = self.assign_full(seeds, k);
        let mut prev: Option<u64> = None;
        while stats.iterations < cfg.max_iterations {
            stats.iterations += 1;
            let (new, reseeded) = self.centres(seeds, &a.arg, k, rng);
            stats.reseeded += reseeded;
            let disp: u64 = seeds
                .chunks_exact(s)
                .zip(new.chunks_exact(s))
                .map(|(o, c)| full_distance(layout, params, o, c))
                .sum();
            stats.displacement.push(disp);
            if disp == 0 {
                // Nothing moved: the assignment is already the final one.
                stats.converged = true;
                break;
            }
            if prune {
                stats
                    .rescans
                    .push(self.assign_pruned(&mut a, seeds, &new, k));
            } else {
                a = self.assign_full(&new, k);
                stats.rescans.push(self.n as u64);
            }
            *seeds = new;
            if let Some(p) = prev {
                if (p.abs_diff(disp) as f64) < cfg.threshold * p as f64 {
                    stats.converged = true;
                    break;
                }
            }
            prev = Some(disp);
        }
        a
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
        let full = Trainer {
            engine,
            data: space.dense_slice(range.clone()).ok_or_else(|| {
                EngineError::Parameter(
                    "LBG trains on dense vectors; build the space with Storage::Dense".into(),
                )
            })?,
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
        let subset = (cap < n).then(|| full.subset(&mut rng, cap));
        let t = match &subset {
            Some(buf) => Trainer {
                data: buf.as_slice(),
                n: cap,
                ..full
            },
            None => full,
        };
        let mut seeds = t.initial_seeds(&mut rng, k);
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
        let mut a = t.iterate(&mut seeds, k, cfg, &mut rng, &mut stats);
        if subset.is_some() {
            // The partitions hold every vector: assign all of them exactly.
            a = full.assign_full(&seeds, k);
        }
        drop(subset);
        let mut cb = Self::partitioned(space, range, params, &seeds, k, &a.arg, stats);
        cb.stats.train_seconds = started.elapsed().as_secs_f64();
        Ok(cb)
    }

    /// The codebook of the final `seeds` and assignment `arg` of every vector of
    /// `range`: the non-empty cells' seeds and a contiguous copy of each
    /// partition, padded to [`ROW_GROUP`] rows; empty cells are dropped.
    fn partitioned(
        space: &VectorSpace,
        range: Range<u64>,
        params: &Params,
        seeds: &[u8],
        k: usize,
        arg: &[u32],
        mut stats: LbgStats,
    ) -> Self {
        let layout = space.layout();
        let s = layout.stride();
        let n = arg.len();
        let (offsets, members) = Trainer::groups(arg, k);
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
                    slot.copy_from_slice(&space.vector(g).expect("member inside the range"));
                }
            });
        stats.seeds = kk;
        Self {
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
        }
    }
}
