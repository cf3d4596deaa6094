//! Exact nearest-neighbour search (Stahlhut §7, ARCHITECTURE §3.5).
//!
//! The range is cut into sub-ranges that rayon scores in parallel with one
//! kernel pass each; the per-sub-range answers are merged by (distance, global
//! index). Distances are integers and ties go to the lowest index, so the
//! answer does not depend on the number of threads, the split, the kernel or
//! (in the cluster) the number of workers.
//!
//! The search is exhaustive in its answers but not in its work: it starts from
//! each query's known answer (its bound) improved by the coherence candidates
//! inside the range, and the kernels abandon a vector as soon as its partial
//! distance exceeds the best so far. Only vectors that cannot win are skipped,
//! so the answer is the exhaustive one.

use std::borrow::Cow;
use std::ops::Range;
use std::time::Duration;

use rayon::prelude::*;

use crate::batch::QueryBatch;
use crate::error::{EngineError, Result};
use crate::kdtree::KdTree;
use crate::kernel::{distance, Kernel, Params, PruneStats, Scan, Sink};
use crate::link::Link;
use crate::merge::{merge_best, merge_topk, regroup, Hit, Slack};
use crate::profile::Timer;
use crate::space::VectorSpace;
use crate::spin::Searching;
use crate::window::Sweep;

/// Fewest queries in a top-k batch for which the k-d tree is used (and
/// built, on first use).
const TREE_MIN_QUERIES: usize = 64;

/// Per query the best (distance, index) so far, started from the query's
/// bound. Comparisons are on the pair, so a vector that ties the bound with a
/// lower index still wins.
struct BestSink {
    dist: Vec<u64>,
    index: Vec<u64>,
    stats: PruneStats,
    prune: bool,
}

impl BestSink {
    fn from(start: &[Hit], prune: bool) -> Self {
        Self {
            dist: start.iter().map(|h| h.dist).collect(),
            index: start.iter().map(|h| h.index).collect(),
            stats: PruneStats::default(),
            prune,
        }
    }
}

impl Sink for BestSink {
    #[inline(always)]
    fn row(&mut self, index: u64, d: &[u64]) {
        for ((bd, bi), &x) in self.dist.iter_mut().zip(self.index.iter_mut()).zip(d) {
            let better = x < *bd || (x == *bd && index < *bi);
            *bd = if better { x } else { *bd };
            *bi = if better { index } else { *bi };
        }
    }

    #[inline(always)]
    fn run(&mut self, q: usize, first: u64, d: &[u64]) {
        let (mut bd, mut bi) = (self.dist[q], self.index[q]);
        for (k, &x) in d.iter().enumerate() {
            let index = first + k as u64;
            if x < bd || (x == bd && index < bi) {
                bd = x;
                bi = index;
            }
        }
        self.dist[q] = bd;
        self.index[q] = bi;
    }

    fn bounds(&self) -> Option<&[u64]> {
        self.prune.then_some(&self.dist[..])
    }

    fn stats(&mut self, stats: PruneStats) {
        self.stats.add(&stats);
    }
}

/// Per query a sorted list of the best k; a candidate must beat the current k-th
/// (vectors arrive in ascending index order, so an equal distance never displaces).
struct TopKSink {
    k: usize,
    lists: Vec<Vec<Hit>>,
    worst: Vec<u64>,
}

impl TopKSink {
    #[inline(always)]
    fn offer(&mut self, q: usize, index: u64, dist: u64) {
        if dist >= self.worst[q] {
            return;
        }
        let list = &mut self.lists[q];
        let pos = list.partition_point(|h| h.dist <= dist);
        list.insert(pos, Hit { index, dist });
        if list.len() > self.k {
            list.pop();
        }
        if list.len() == self.k {
            self.worst[q] = list[self.k - 1].dist;
        }
    }
}

impl Sink for TopKSink {
    fn bounds(&self) -> Option<&[u64]> {
        Some(&self.worst)
    }

    #[inline(always)]
    fn row(&mut self, index: u64, d: &[u64]) {
        for (q, &x) in d.iter().enumerate() {
            if x < self.worst[q] {
                self.offer(q, index, x);
            }
        }
    }

    #[inline(always)]
    fn run(&mut self, q: usize, first: u64, d: &[u64]) {
        for (k, &x) in d.iter().enumerate() {
            if x < self.worst[q] {
                self.offer(q, first + k as u64, x);
            }
        }
    }
}

/// Collects every distance into a query-major matrix.
struct MatrixSink {
    start: u64,
    n: usize,
    out: Vec<u64>,
}

impl Sink for MatrixSink {
    fn row(&mut self, index: u64, d: &[u64]) {
        let i = (index - self.start) as usize;
        for (q, &x) in d.iter().enumerate() {
            self.out[q * self.n + i] = x;
        }
    }

    fn run(&mut self, q: usize, first: u64, d: &[u64]) {
        let i = (first - self.start) as usize;
        self.out[q * self.n + i..q * self.n + i + d.len()].copy_from_slice(d);
    }
}

/// The search engine: a kernel and the way a range is split for rayon.
/// The master's local search and the gRPC worker both call this.
#[derive(Debug, Clone, Copy)]
pub struct Engine {
    kernel: Kernel,
    /// Smallest sub-range handed to one rayon task, in vectors.
    min_chunk: usize,
    /// Prune (candidates and partial distance elimination); off, every
    /// component of every vector is scored, with the same answers.
    prune: bool,
    /// How long the pool's threads spin for more work after a search
    /// ([`crate::spin`]); zero lets them sleep at once.
    spin: Duration,
}

/// The spin time `texsyn` and `texsyn-worker` give their engines (a library
/// engine starts with none: [`Engine::with_spin`]).
pub const DEFAULT_SPIN: Duration = Duration::from_micros(500);

impl Default for Engine {
    fn default() -> Self {
        Self::new(Kernel::detect())
    }
}

impl Engine {
    pub fn new(kernel: Kernel) -> Self {
        Self {
            kernel,
            min_chunk: 2048,
            prune: true,
            spin: Duration::ZERO,
        }
    }

    /// An engine with a named kernel, checked against this CPU.
    pub fn with_kernel_name(name: &str) -> Result<Self> {
        Ok(Self::new(Kernel::from_name(name)?))
    }

    /// Sets the smallest sub-range per rayon task (tests use tiny values to force splits).
    pub fn with_min_chunk(mut self, min_chunk: usize) -> Self {
        self.min_chunk = min_chunk.max(1);
        self
    }

    /// Turns pruning off (or on): the unpruned exhaustive scan, for benchmarks
    /// and tests; the answers are the same.
    pub fn with_pruning(mut self, prune: bool) -> Self {
        self.prune = prune;
        self
    }

    /// Sets how long the pool's threads spin for more work after each search
    /// instead of sleeping ([`crate::spin`]); zero turns spinning off. The
    /// answers are the same either way.
    pub fn with_spin(mut self, spin: Duration) -> Self {
        self.spin = spin;
        self
    }

    pub fn kernel(&self) -> Kernel {
        self.kernel
    }

    fn check(&self, space: &VectorSpace, range: &Range<u64>, queries: &QueryBatch) -> Result<()> {
        self.kernel.check()?;
        if queries.layout() != space.layout() {
            let (a, b) = (queries.layout(), space.layout());
            return Err(EngineError::Geometry(format!(
                "queries have {}+{} components but the space has {}+{}; build both from the same geometry",
                a.hi_len, a.lo_len, b.hi_len, b.lo_len
            )));
        }
        if queries.is_empty() {
            return Err(EngineError::Empty("query batch"));
        }
        space.check_range(range)?;
        Ok(())
    }

    fn chunks(&self, range: &Range<u64>) -> Vec<Range<u64>> {
        let n = (range.end - range.start) as usize;
        let threads = rayon::current_num_threads().max(1);
        // A few tasks per thread for balance, never smaller than `min_chunk`.
        let per = n.div_ceil(threads * 4).max(self.min_chunk);
        (0..n.div_ceil(per))
            .map(|i| {
                let a = range.start + (i * per) as u64;
                a..(a + per as u64).min(range.end)
            })
            .collect()
    }

    /// Runs the kernel over the vectors of `r` into `sink`, block by block for
    /// a plane-backed space (the sink sees the vectors in index order either way).
    fn scan<S: Sink>(
        &self,
        space: &VectorSpace,
        r: Range<u64>,
        queries: &QueryBatch,
        params: &Params,
        sink: &mut S,
    ) {
        space.for_each_block(r, |vectors, count, base| {
            let scan = Scan::new(space.layout(), *params, vectors, count, base, queries);
            self.kernel.scan(&scan, sink);
        });
    }

    /// Best match per query in the global index `range` of `space` that is
    /// better than the query's bound ([`QueryBatch::bound`]): the exhaustive
    /// answer when the query has no bound, [`Hit::NONE`] when nothing in the
    /// range beats it. Callers take the final answer with
    /// [`crate::merge::with_bounds`].
    pub fn search_best(
        &self,
        space: &VectorSpace,
        range: Range<u64>,
        queries: &QueryBatch,
        params: &Params,
    ) -> Result<Vec<Hit>> {
        Ok(self.search_best_counted(space, range, queries, params)?.0)
    }

    /// [`Engine::search_best`] with the pruning figures of the search.
    pub fn search_best_counted(
        &self,
        space: &VectorSpace,
        range: Range<u64>,
        queries: &QueryBatch,
        params: &Params,
    ) -> Result<(Vec<Hit>, PruneStats)> {
        self.search_best_linked(space, range, queries, params, None)
    }

    /// [`Engine::search_best_counted`] as one range of a batch whose other
    /// ranges are searched at the same time elsewhere: the keyed sweep prunes
    /// against the least distance `link` holds and lowers it with its own
    /// finds ([`Link`]). The answers are those of the search without it.
    pub fn search_best_linked(
        &self,
        space: &VectorSpace,
        range: Range<u64>,
        queries: &QueryBatch,
        params: &Params,
        link: Option<&Link>,
    ) -> Result<(Vec<Hit>, PruneStats)> {
        self.check(space, &range, queries)?;
        let _searching = Searching::start(self.spin);
        if let Some(l) = link {
            if l.len() != queries.len() {
                return Err(EngineError::Geometry(format!(
                    "a link of {} queries for a batch of {}; make one per batch",
                    l.len(),
                    queries.len()
                )));
            }
        }
        let start = {
            let _prep = Timer::prep();
            self.start_from_candidates(space, &range, queries, params)
        };
        let layout = space.layout();
        let (windowed, scanned): (Vec<usize>, Vec<usize>) =
            (0..queries.len()).partition(|&q| self.prune && space.keyed(params, queries.mask(q)));
        // The two kinds of query are searched side by side, so that the tail
        // of one overlaps the other instead of leaving threads idle.
        let keyed = || -> Option<(Vec<Hit>, PruneStats)> {
            if windowed.is_empty() {
                return None;
            }
            let sweep = Sweep {
                kernel: self.kernel,
                layout,
                params: *params,
                range: range.clone(),
                min_part: self.min_chunk,
            };
            let qs: Vec<(&[u8], &[u8])> = windowed
                .iter()
                .map(|&q| (queries.values(q), queries.mask(q)))
                .collect();
            let from: Vec<Hit> = windowed.iter().map(|&q| start[q]).collect();
            let link = link.map(|l| (l, windowed.as_slice()));
            Some(space.search_keyed(&sweep, &qs, &from, link))
        };
        let scan = || -> Option<(Vec<Hit>, PruneStats)> {
            if scanned.is_empty() {
                return None;
            }
            let sub = if windowed.is_empty() {
                Cow::Borrowed(queries)
            } else {
                Cow::Owned(queries.select(scanned.iter().copied()))
            };
            let sub_start: Vec<Hit> = scanned.iter().map(|&q| start[q]).collect();
            let parts: Vec<(Vec<Hit>, PruneStats)> = self
                .chunks(&range)
                .into_par_iter()
                .map(|r| {
                    let _busy = Timer::busy();
                    let mut sink = BestSink::from(&sub_start, self.prune);
                    self.scan(space, r, &sub, params, &mut sink);
                    let hits = sink
                        .dist
                        .iter()
                        .zip(&sink.index)
                        .map(|(&dist, &index)| Hit { index, dist })
                        .collect();
                    (hits, sink.stats)
                })
                .collect();
            let mut sub_best = sub_start;
            let mut stats = PruneStats::default();
            for (p, s) in &parts {
                merge_best(&mut sub_best, p);
                stats.add(s);
            }
            Some((sub_best, stats))
        };
        let (keyed, scan) = rayon::join(keyed, scan);
        let (mut best, stats) = regroup(start, [(&windowed, keyed), (&scanned, scan)]);
        for (q, b) in best.iter_mut().enumerate() {
            if *b == queries.bound(q) {
                *b = Hit::NONE;
            }
        }
        Ok((best, stats))
    }

    /// Per query its bound, improved by its coherence candidates inside `range`
    /// (scored with the scalar reference: a handful per query).
    fn start_from_candidates(
        &self,
        space: &VectorSpace,
        range: &Range<u64>,
        queries: &QueryBatch,
        params: &Params,
    ) -> Vec<Hit> {
        let layout = space.layout();
        // Parallel over the queries: a batch's candidates are as many
        // distances as a sizeable part of its sweep, and done serially they
        // left the other threads idle.
        (0..queries.len())
            .into_par_iter()
            .map(|q| {
                let _busy = Timer::busy();
                let mut best = queries.bound(q);
                let candidates = if self.prune {
                    queries.candidates(q)
                } else {
                    &[]
                };
                for &c in candidates {
                    if !range.contains(&c) {
                        continue;
                    }
                    if let Some(v) = space.vector(c) {
                        let dist =
                            distance(&layout, params, &v, queries.values(q), queries.mask(q));
                        let hit = Hit { index: c, dist };
                        if hit.key() < best.key() {
                            best = hit;
                        }
                    }
                }
                best
            })
            .collect()
    }

    /// Every distance of the range, query-major (`queries × range` values), from
    /// one kernel pass; for tests against the scalar reference and for calibration.
    pub fn distance_matrix(
        &self,
        space: &VectorSpace,
        range: Range<u64>,
        queries: &QueryBatch,
        params: &Params,
    ) -> Result<Vec<u64>> {
        self.check(space, &range, queries)?;
        let n = (range.end - range.start) as usize;
        let mut sink = MatrixSink {
            start: range.start,
            n,
            out: vec![0; n * queries.len()],
        };
        self.scan(space, range, queries, params, &mut sink);
        Ok(sink.out)
    }

    /// The `k` best matches per query, sorted by (distance, index); fewer when
    /// the range holds fewer than `k` vectors.
    ///
    /// A query's coherence candidates only speed it up: when `k` distinct
    /// ones lie in `range`, the `k`-th smallest of their distances bounds the
    /// answer (every vector of the top-k is at most that far), so the search
    /// starts from that cut instead of from nothing. The answer is the same.
    pub fn search_topk(
        &self,
        space: &VectorSpace,
        range: Range<u64>,
        queries: &QueryBatch,
        params: &Params,
        k: usize,
    ) -> Result<Vec<Vec<Hit>>> {
        self.check(space, &range, queries)?;
        let worst = self.topk_cut_from_candidates(space, &range, queries, params, k);
        self.topk_below(space, range, queries, params, k, worst)
    }

    /// [`Engine::search_topk`] over one range of a space split between
    /// searchers, with each query's cut computed over the whole space
    /// ([`crate::OwnedLevel::topk_cuts`]): only matches below `cut[q]` are
    /// answered, so a list may be shorter than `k` where the other ranges
    /// hold the better matches. Merged over the ranges, the lists give the
    /// whole space's top-k exactly, as long as each cut is above the whole
    /// space's `k`-th distance (ARCHITECTURE §4.8).
    pub fn search_topk_below(
        &self,
        space: &VectorSpace,
        range: Range<u64>,
        queries: &QueryBatch,
        params: &Params,
        k: usize,
        cut: &[u64],
    ) -> Result<Vec<Vec<Hit>>> {
        self.check(space, &range, queries)?;
        let _searching = Searching::start(self.spin);
        one_per_query(cut.len(), "top-k cuts", queries)?;
        let own = self.topk_cut_from_candidates(space, &range, queries, params, k);
        let worst = own.iter().zip(cut).map(|(&a, &b)| a.min(b)).collect();
        self.topk_below(space, range, queries, params, k, worst)
    }

    /// Per query, one more than the `k`-th smallest distance of its distinct
    /// candidates in `range`, or `u64::MAX` when it has fewer than `k`.
    fn topk_cut_from_candidates(
        &self,
        space: &VectorSpace,
        range: &Range<u64>,
        queries: &QueryBatch,
        params: &Params,
        k: usize,
    ) -> Vec<u64> {
        let layout = space.layout();
        (0..queries.len())
            .into_par_iter()
            .map(|q| {
                if !self.prune {
                    return u64::MAX;
                }
                kth_cut(queries.candidates(q), range, k, |i| {
                    space
                        .vector(i)
                        .map(|v| distance(&layout, params, &v, queries.values(q), queries.mask(q)))
                })
            })
            .collect()
    }

    /// The near-ties of each query: of its `k` best references in `range`,
    /// those within `slack[q]` of its best distance (up to its limit), sorted by (distance,
    /// index); exactly what [`Engine::search_topk`] answers less the entries
    /// farther than that. The search is cut at the coherence candidates' best
    /// distance plus the slack, so it prunes almost as well as best-1.
    pub fn search_near_ties(
        &self,
        space: &VectorSpace,
        range: Range<u64>,
        queries: &QueryBatch,
        params: &Params,
        k: usize,
        slack: &[Slack],
    ) -> Result<Vec<Vec<Hit>>> {
        self.check(space, &range, queries)?;
        let _searching = Searching::start(self.spin);
        one_per_query(slack.len(), "slacks", queries)?;
        let start = self.start_from_candidates(space, &range, queries, params);
        let worst = start
            .iter()
            .zip(slack)
            .map(|(h, s)| s.limit(h.dist).saturating_add(1))
            .collect();
        let mut lists = self.topk_below(space, range, queries, params, k, worst)?;
        Slack::keep_near_ties(&mut lists, slack);
        Ok(lists)
    }

    /// The space's k-d tree when it can answer a top-k search of `queries`
    /// (pruning on, every component of every query known, a large enough
    /// batch for the tree to pay; [`crate::kdtree`]). Its answers are the
    /// scan's, so the choice changes only the time.
    fn tree_for<'a>(&self, space: &'a VectorSpace, queries: &QueryBatch) -> Option<&'a KdTree> {
        if !self.prune || queries.len() < TREE_MIN_QUERIES || !KdTree::applies(&space.layout()) {
            return None;
        }
        let layout = space.layout();
        let full = (0..queries.len()).all(|q| {
            let m = queries.mask(q);
            m[..layout.hi_len].iter().all(|&b| b != 0)
                && m[layout.hi_pad..layout.hi_pad + layout.lo_len]
                    .iter()
                    .all(|&b| b != 0)
        });
        if !full {
            return None;
        }
        space.kd_tree()
    }

    /// The `k` best references per query with a distance below `worst[q]`.
    fn topk_below(
        &self,
        space: &VectorSpace,
        range: Range<u64>,
        queries: &QueryBatch,
        params: &Params,
        k: usize,
        worst: Vec<u64>,
    ) -> Result<Vec<Vec<Hit>>> {
        self.check(space, &range, queries)?;
        if k == 0 {
            return Err(EngineError::Parameter("top-k needs k ≥ 1".into()));
        }
        let nq = queries.len();
        if let Some(tree) = self.tree_for(space, queries) {
            let _busy = Timer::busy();
            let qs: Vec<&[u8]> = (0..nq).map(|q| queries.values(q)).collect();
            return Ok(tree.search_topk(&qs, params, range, k, &worst, self.kernel));
        }
        let parts: Vec<Vec<Vec<Hit>>> = self
            .chunks(&range)
            .into_par_iter()
            .map(|r| {
                let _busy = Timer::busy();
                let mut sink = TopKSink {
                    k,
                    lists: vec![Vec::with_capacity(k + 1); nq],
                    worst: worst.clone(),
                };
                self.scan(space, r, queries, params, &mut sink);
                sink.lists
            })
            .collect();
        let mut out = vec![Vec::new(); nq];
        for p in &parts {
            for (o, l) in out.iter_mut().zip(p) {
                *o = merge_topk(o, l, k);
            }
        }
        Ok(out)
    }
}

/// An error unless `len` (of the `what` given) is one per query.
fn one_per_query(len: usize, what: &str, queries: &QueryBatch) -> Result<()> {
    if len == queries.len() {
        return Ok(());
    }
    Err(EngineError::Parameter(format!(
        "{len} {what} for {} queries",
        queries.len()
    )))
}

/// One more than the `k`-th smallest distance of the distinct `candidates`
/// in `range` that `distance` can score, or `u64::MAX` when fewer than `k`
/// are: a cut above every distance of the top-k, since the candidates are
/// `k` vectors at most that far.
pub(crate) fn kth_cut(
    candidates: &[u64],
    range: &Range<u64>,
    k: usize,
    mut distance: impl FnMut(u64) -> Option<u64>,
) -> u64 {
    let mut c: Vec<u64> = candidates
        .iter()
        .copied()
        .filter(|c| range.contains(c))
        .collect();
    c.sort_unstable();
    c.dedup();
    if k == 0 || c.len() < k {
        return u64::MAX;
    }
    let mut d: Vec<u64> = c.into_iter().filter_map(&mut distance).collect();
    if d.len() < k {
        return u64::MAX;
    }
    let (_, kth, _) = d.select_nth_unstable(k - 1);
    kth.saturating_add(1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn merge_prefers_lower_index_on_ties() {
        let mut a = vec![Hit { index: 5, dist: 3 }, Hit::NONE];
        merge_best(
            &mut a,
            &[Hit { index: 2, dist: 3 }, Hit { index: 9, dist: 1 }],
        );
        assert_eq!(
            a,
            vec![Hit { index: 2, dist: 3 }, Hit { index: 9, dist: 1 }]
        );
        merge_best(
            &mut a,
            &[Hit { index: 7, dist: 3 }, Hit { index: 1, dist: 2 }],
        );
        assert_eq!(a[0].index, 2);
        assert_eq!(a[1].index, 9);
    }

    #[test]
    fn merge_topk_is_sorted_and_truncated() {
        let a = [Hit { index: 1, dist: 1 }, Hit { index: 4, dist: 5 }];
        let b = [Hit { index: 0, dist: 1 }, Hit { index: 3, dist: 2 }];
        let m = merge_topk(&a, &b, 3);
        assert_eq!(m.iter().map(|h| h.index).collect::<Vec<_>>(), vec![0, 1, 3]);
    }
}
