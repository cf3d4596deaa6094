//! The keyed index of a dense space: its vectors in key order with their
//! heads, and the sweep of a batch over the union of its queries' windows.

use std::ops::Range;

use rayon::prelude::*;

use super::parts::{balanced_parts, Bounds};
use super::{merged, reach, Dense, Sweep};
use crate::kernel::{head_bytes, prefetch, Params, PruneStats};
use crate::layout::{Layout, LANE};
use crate::link::Link;
use crate::merge::Hit;
use crate::space::AlignedBytes;

/// Slots tested between two looks at a query's best answer.
const BLOCK: usize = 64;
/// Parts of a keyed sweep per search thread: with the bounds shared between
/// parts, finer parts cost little extra work and shorten the wait for the
/// last one.
const PARTS_PER_THREAD: usize = 16;
/// Slots on each side of a query's key scored before the sweep: its seed.
/// Near the key lie the vectors whose lo part sums like the query's, so the
/// seed's best narrows the window before the sweep starts, whichever end of
/// it the sweep (or a thread of it) begins with.
const SEED: usize = 32;

const _: () = assert!(2 * SEED <= BLOCK, "a seed is scored as one block");

/// What scoring a block of slots for one probe works in: the heads'
/// distances, the survivors, and the pruning figures so far.
struct Scratch {
    dist: [u64; BLOCK],
    next: [u32; BLOCK],
    stats: PruneStats,
}

impl Default for Scratch {
    fn default() -> Self {
        Self {
            dist: [0; BLOCK],
            next: [0; BLOCK],
            stats: PruneStats::default(),
        }
    }
}

/// The vectors of a dense space in key order: keys, local indices and heads.
#[derive(Debug, Clone)]
pub(crate) struct KeyIndex {
    keys: Vec<u32>,
    ids: Vec<u32>,
    /// Bytes per head ([`head_bytes`]).
    hb: usize,
    heads: AlignedBytes,
}

/// One query of a sweep: values, mask, key, best answer and the window of
/// slots that can still hold a better one.
#[derive(Clone)]
struct Probe<'a> {
    q: &'a [u8],
    m: &'a [u8],
    key: u64,
    best: Hit,
    window: Range<usize>,
}

/// The key of a padded vector or query: the sum of its lo part.
fn key_of(layout: &Layout, v: &[u8]) -> u64 {
    let lo = layout.hi_pad..layout.hi_pad + layout.lo_len;
    v[lo].iter().map(|&b| u64::from(b)).sum()
}

/// The parts in the order they are swept: those holding the most query keys
/// first, where the best answers most likely lie, so that the bounds the parts
/// share fall early; ties in slot order.
fn nearest_first(mut cut: Vec<Range<usize>>, centres: &[usize]) -> Vec<Range<usize>> {
    let held = |r: &Range<usize>| centres.iter().filter(|c| r.contains(c)).count();
    cut.sort_by_cached_key(|r| (std::cmp::Reverse(held(r)), r.start));
    cut
}

/// Runs `f` over `items` on `threads` rayon tasks that take the items in
/// order, each the next one not yet taken: the first items start first
/// whatever the number of threads. The results come back in item order.
fn pull_in_order<T, R, F>(threads: usize, items: &[T], f: F) -> Vec<R>
where
    T: Sync,
    R: Send,
    F: Fn(&T) -> R + Sync,
{
    let next = std::sync::atomic::AtomicUsize::new(0);
    let timer = crate::profile::SweepTimer::enter(threads);
    let done: Vec<Vec<(usize, R)>> = (0..threads.clamp(1, items.len().max(1)))
        .into_par_iter()
        .map(|_| {
            let mut mine = Vec::new();
            loop {
                let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                let Some(item) = items.get(i) else { break };
                if mine.is_empty() {
                    timer.joined();
                }
                mine.push((i, f(item)));
            }
            if !mine.is_empty() {
                timer.done();
            }
            mine
        })
        .collect();
    drop(timer);
    let mut all: Vec<(usize, R)> = done.into_iter().flatten().collect();
    all.sort_by_key(|(i, _)| *i);
    all.into_iter().map(|(_, r)| r).collect()
}

impl KeyIndex {
    /// The index of `len` padded vectors in `data`; `None` when the layout has
    /// no lo part (the coarsest level) or the vectors do not fit `u32` indices.
    pub(crate) fn build(layout: &Layout, data: &[u8], len: usize) -> Option<Self> {
        if layout.lo_len == 0 || u32::try_from(len).is_err() {
            return None;
        }
        let s = layout.stride();
        let mut order: Vec<u64> = (0..len)
            .into_par_iter()
            .map(|i| key_of(layout, &data[i * s..]) << 32 | i as u64)
            .collect();
        order.par_sort_unstable();
        let hb = head_bytes(layout);
        let mut heads = AlignedBytes::zeroed(len * hb);
        let mut keys = Vec::with_capacity(len);
        let mut ids = Vec::with_capacity(len);
        for (slot, &o) in heads.as_mut_slice().chunks_exact_mut(hb).zip(&order) {
            let i = (o & 0xFFFF_FFFF) as usize;
            let h = i * s + layout.hi_pad;
            slot.copy_from_slice(&data[h..h + hb]);
            keys.push((o >> 32) as u32);
            ids.push(i as u32);
        }
        Some(Self {
            keys,
            ids,
            hb,
            heads,
        })
    }

    /// Bytes held.
    pub(crate) fn bytes(&self) -> u64 {
        (self.keys.capacity() * 4 + self.ids.capacity() * 4 + self.heads.as_slice().len()) as u64
    }

    /// Whether a query with this mask can be searched by window: it defines
    /// every lo component and the lo part has a weight.
    pub(crate) fn applies(layout: &Layout, params: &Params, mask: &[u8]) -> bool {
        layout.lo_len > 0
            && params.weights.lo > 0
            && mask[layout.hi_pad..layout.hi_pad + layout.lo_len]
                .iter()
                .all(|&b| b == 0xFF)
    }

    /// Largest key distance a vector can have and still score at most `best`.
    fn reach(sw: &Sweep, best: u64) -> u64 {
        reach(sw, sw.layout.lo_len as u64, best)
    }

    /// The slots whose keys lie within `reach` of `key`.
    fn window(&self, key: u64, reach: u64) -> Range<usize> {
        let a = self
            .keys
            .partition_point(|&k| u64::from(k) < key.saturating_sub(reach));
        let b = self
            .keys
            .partition_point(|&k| u64::from(k) <= key.saturating_add(reach));
        a..b
    }

    /// The best (distance, index) of each query `(values, mask)` over the
    /// global indices `sw.range`, starting from `start`: the start itself when
    /// nothing in the range beats it. Every query must pass [`KeyIndex::applies`].
    /// With a `link` (the batch's [`Link`] and each query's place in the
    /// batch), the sweep prunes against the other ranges' finds too and
    /// reports its own.
    pub(crate) fn search(
        &self,
        sw: &Sweep,
        dense: &Dense,
        queries: &[(&[u8], &[u8])],
        start: &[Hit],
        link: Option<(&Link, &[usize])>,
    ) -> (Vec<Hit>, PruneStats) {
        let linked = |i: usize| link.map_or(u64::MAX, |(l, at)| l.get(at[i]));
        let prep = crate::profile::Timer::prep();
        let seeded: Vec<(Probe, usize, PruneStats)> = queries
            .par_iter()
            .zip(start.par_iter())
            .enumerate()
            .map(|(i, (&(q, m), &best))| {
                let key = key_of(&sw.layout, q);
                let mut probe = Probe {
                    q,
                    m,
                    key,
                    best,
                    window: 0..0,
                };
                let (centre, stats) = self.seed(sw, dense, &mut probe);
                let bound = probe.best.dist.min(linked(i));
                probe.window = self.window(key, Self::reach(sw, bound));
                (probe, centre, stats)
            })
            .collect();
        let mut seed_stats = PruneStats::default();
        let mut centres = Vec::with_capacity(seeded.len());
        let mut probes = Vec::with_capacity(seeded.len());
        for (p, c, s) in seeded {
            seed_stats.add(&s);
            centres.push(c);
            probes.push(p);
        }
        let seeds: Vec<Hit> = probes.iter().map(|p| p.best).collect();
        let windows: Vec<Range<usize>> = probes.iter().map(|p| p.window.clone()).collect();
        let threads = rayon::current_num_threads().max(1);
        let cut = balanced_parts(&windows, threads * PARTS_PER_THREAD, sw.min_part.max(1));
        let cut = nearest_first(cut, &centres);
        let shared = Bounds::new(&seeds, link);
        drop(prep);
        let mut parts = pull_in_order(threads, &cut, |part| {
            self.sweep(sw, dense, probes.clone(), part.clone(), &shared)
        });
        parts.push((seeds, seed_stats));
        merged(sw, start, &parts)
    }

    /// Lowers the probe's best with the range's vectors in the [`SEED`]
    /// slots on each side of its key; returns the key's slot and the pruning
    /// figures of scoring them. The seed only lowers the starting bound: the
    /// sweep still visits every slot of the window, so the answer is the
    /// exhaustive one.
    fn seed(&self, sw: &Sweep, dense: &Dense, p: &mut Probe) -> (usize, PruneStats) {
        let _busy = crate::profile::Timer::busy();
        let at = self.keys.partition_point(|&k| u64::from(k) < p.key);
        let slots = at.saturating_sub(SEED)..(at + SEED).min(self.keys.len());
        let mut scratch = Scratch::default();
        let bound = p.best.dist;
        self.score_slots(sw, dense, slots, p, bound, &mut scratch);
        (at, scratch.stats)
    }

    /// Scores the slots `slots` (at most [`BLOCK`]) for probe `p`: heads
    /// first, then in full the vectors of the range whose heads are within
    /// `bound`. Lowers the probe's best with every hit that beats it within
    /// the bound, and returns the bound after the slots.
    fn score_slots(
        &self,
        sw: &Sweep,
        dense: &Dense,
        slots: Range<usize>,
        p: &mut Probe,
        mut bound: u64,
        w: &mut Scratch,
    ) -> u64 {
        let (s, hb) = (sw.layout.stride(), self.hb);
        let local = (sw.range.start - dense.base) as usize..(sw.range.end - dense.base) as usize;
        let n = slots.len();
        let heads = &self.heads.as_slice()[slots.start * hb..slots.end * hb];
        let qh = &p.q[sw.layout.hi_pad..sw.layout.hi_pad + hb];
        let wl = u64::from(sw.params.weights.lo);
        sw.kernel
            .heads(sw.params.metric, heads, hb, qh, wl, &mut w.dist);
        w.stats.chunks += n as u64 * (hb / LANE) as u64;
        // The survivors' vectors lie anywhere in the space: ask for all of
        // their cache lines before scoring the first one.
        let mut count = 0;
        for (k, &d) in w.dist[..n].iter().enumerate() {
            if d > bound {
                continue;
            }
            let id = self.ids[slots.start + k] as usize;
            if local.contains(&id) {
                prefetch(&dense.data[id * s..(id + 1) * s]);
                w.next[count] = k as u32;
                count += 1;
            }
        }
        for &k in &w.next[..count] {
            let (k, d) = (k as usize, w.dist[k as usize]);
            if d > bound {
                continue;
            }
            let id = self.ids[slots.start + k] as usize;
            let v = &dense.data[id * s..(id + 1) * s];
            let full = sw
                .kernel
                .finish(&sw.layout, &sw.params, hb, v, p.q, p.m, d, bound);
            w.stats.pruned += 1;
            w.stats.chunks += (s / LANE) as u64;
            let hit = Hit {
                index: dense.base + id as u64,
                dist: full,
            };
            // Above the bound `full` may be a partial sum: never an answer.
            if full <= bound && hit.key() < p.best.key() {
                p.best = hit;
                bound = full;
            }
        }
        bound
    }

    /// Sweeps the slots `part` for every probe whose window meets them, in
    /// blocks of [`BLOCK`]; returns the best per probe and the pruning figures
    /// (with `pruned` holding the pairs scored in full until the caller
    /// turns it round).
    fn sweep(
        &self,
        sw: &Sweep,
        dense: &Dense,
        mut probes: Vec<Probe>,
        part: Range<usize>,
        shared: &Bounds,
    ) -> (Vec<Hit>, PruneStats) {
        let _busy = crate::profile::Timer::busy();
        let mut scratch = Scratch::default();
        let mut a = part.start;
        while a < part.end {
            let block = a..(a + BLOCK).min(part.end);
            a = block.end;
            for (i, p) in probes.iter_mut().enumerate() {
                let slots = block.start.max(p.window.start)..block.end.min(p.window.end);
                if slots.is_empty() {
                    continue;
                }
                // The best any part has found so far: vectors above it
                // cannot win, whichever part holds them.
                let before = p.best;
                let bound = shared.get(i).min(before.dist);
                let bound = self.score_slots(sw, dense, slots, p, bound, &mut scratch);
                if p.best.dist < before.dist {
                    shared.lower(i, p.best.dist);
                }
                if bound < before.dist {
                    let w = self.window(p.key, Self::reach(sw, bound));
                    p.window = p.window.start.max(w.start)..p.window.end.min(w.end);
                }
            }
        }
        (probes.iter().map(|p| p.best).collect(), scratch.stats)
    }
}

#[cfg(test)]
mod tests {
    use super::{nearest_first, pull_in_order};
    use proptest::prelude::*;
    use std::ops::Range;

    proptest! {
        /// Every item runs once, the results come back in item order, and
        /// the outcome does not depend on the number of threads.
        #[test]
        fn pulled_items_run_once_in_order(n in 0usize..200, threads in 1usize..5) {
            let items: Vec<usize> = (0..n).collect();
            let calls = std::sync::atomic::AtomicUsize::new(0);
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            let out = pool.install(|| {
                pull_in_order(threads, &items, |&i| {
                    calls.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    i * 3
                })
            });
            prop_assert_eq!(calls.into_inner(), n);
            prop_assert_eq!(out, items.iter().map(|i| i * 3).collect::<Vec<_>>());
        }

        /// The order is a permutation of the cut, by query keys held
        /// (most first), then by slot.
        #[test]
        fn parts_with_more_keys_come_first(
            lens in proptest::collection::vec(1usize..50, 1..20),
            centres in proptest::collection::vec(0usize..600, 0..40),
        ) {
            let mut at = 0;
            let cut: Vec<Range<usize>> = lens
                .iter()
                .map(|&l| {
                    at += l;
                    at - l..at
                })
                .collect();
            let order = nearest_first(cut.clone(), &centres);
            let held = |r: &Range<usize>| centres.iter().filter(|c| r.contains(c)).count();
            let mut sorted = order.clone();
            sorted.sort_by_key(|r| r.start);
            prop_assert_eq!(&sorted, &cut);
            for w in order.windows(2) {
                let (a, b) = (held(&w[0]), held(&w[1]));
                prop_assert!(a > b || (a == b && w[0].start < w[1].start));
            }
        }
    }
}
