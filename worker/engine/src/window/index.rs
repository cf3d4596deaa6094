//! The keyed index of a dense space: its vectors in key order with their
//! heads, and the sweep of a batch over the union of its queries' windows.

use std::ops::Range;

use rayon::prelude::*;

use super::parts::{balanced_parts, Bounds};
use super::{merged, reach, Dense, Sweep};
use crate::kernel::{head_bytes, prefetch, Params, PruneStats};
use crate::layout::{Layout, LANE};
use crate::merge::Hit;
use crate::space::AlignedBytes;

/// Slots tested between two looks at a query's best answer.
const BLOCK: usize = 64;
/// Parts of a keyed sweep per search thread: with the bounds shared between
/// parts, finer parts cost little extra work and shorten the wait for the
/// last one.
const PARTS_PER_THREAD: usize = 8;

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
    pub(crate) fn search(
        &self,
        sw: &Sweep,
        dense: &Dense,
        queries: &[(&[u8], &[u8])],
        start: &[Hit],
    ) -> (Vec<Hit>, PruneStats) {
        let probes: Vec<Probe> = queries
            .iter()
            .zip(start)
            .map(|(&(q, m), &best)| {
                let key = key_of(&sw.layout, q);
                let window = self.window(key, Self::reach(sw, best.dist));
                Probe {
                    q,
                    m,
                    key,
                    best,
                    window,
                }
            })
            .collect();
        let windows: Vec<Range<usize>> = probes.iter().map(|p| p.window.clone()).collect();
        let threads = rayon::current_num_threads().max(1);
        let cut = balanced_parts(&windows, threads * PARTS_PER_THREAD, sw.min_part.max(1));
        let shared = Bounds::new(start);
        let parts: Vec<(Vec<Hit>, PruneStats)> = cut
            .into_par_iter()
            .map(|part| self.sweep(sw, dense, probes.clone(), part, &shared))
            .collect();
        merged(sw, start, &parts)
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
        let s = sw.layout.stride();
        let hb = self.hb;
        let wl = u64::from(sw.params.weights.lo);
        let chunks = (s / LANE) as u64;
        let local = (sw.range.start - dense.base) as usize..(sw.range.end - dense.base) as usize;
        let _busy = crate::search::BusyTimer::start();
        let mut stats = PruneStats::default();
        let mut dist = [0u64; BLOCK];
        let mut next = [0u32; BLOCK];
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
                let bound = shared.get(i).min(p.best.dist);
                let n = slots.len();
                let heads = &self.heads.as_slice()[slots.start * hb..slots.end * hb];
                let qh = &p.q[sw.layout.hi_pad..sw.layout.hi_pad + hb];
                sw.kernel
                    .heads(sw.params.metric, heads, hb, qh, wl, &mut dist);
                stats.chunks += n as u64 * (hb / LANE) as u64;
                // The survivors' vectors lie anywhere in the space: ask for
                // all of their cache lines before scoring the first one.
                let mut count = 0;
                for (k, &d) in dist[..n].iter().enumerate() {
                    if d > bound {
                        continue;
                    }
                    let id = self.ids[slots.start + k] as usize;
                    if local.contains(&id) {
                        prefetch(&dense.data[id * s..(id + 1) * s]);
                        next[count] = k as u32;
                        count += 1;
                    }
                }
                let mut bound = bound;
                let before = p.best;
                for &k in &next[..count] {
                    let (k, d) = (k as usize, dist[k as usize]);
                    if d > bound {
                        continue;
                    }
                    let id = self.ids[slots.start + k] as usize;
                    let v = &dense.data[id * s..(id + 1) * s];
                    let full = sw
                        .kernel
                        .finish(&sw.layout, &sw.params, hb, v, p.q, p.m, d, bound);
                    stats.pruned += 1;
                    stats.chunks += chunks;
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
                if p.best.dist < before.dist {
                    shared.lower(i, p.best.dist);
                }
                if bound < before.dist {
                    let w = self.window(p.key, Self::reach(sw, bound));
                    p.window = p.window.start.max(w.start)..p.window.end.min(w.end);
                }
            }
        }
        (probes.iter().map(|p| p.best).collect(), stats)
    }
}
