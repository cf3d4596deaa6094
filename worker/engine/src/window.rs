//! Key-ordered search windows: a lower-bound cascade computed once per space
//! (ARCHITECTURE §3.5).
//!
//! Every vector gets a key, the sum of its lo part (the parent window). For a
//! query that defines the whole lo part, the triangle inequality gives
//! D(q, v) ≥ w_lo·|K(q) − K(v)| for L1, and by Cauchy–Schwarz
//! D(q, v) ≥ w_lo·(K(q) − K(v))² / lo_len for L2. The vectors are indexed in
//! key order, so every vector that can still beat a query's best answer lies
//! in one contiguous window around the query's key, which narrows as the best
//! answer improves.
//!
//! A batch sweeps the union of its queries' windows once, block by block, so
//! the block is read from memory once for all queries whose windows cover it.
//! Inside a window each vector's *head* (its lo part, up to two lanes, kept in
//! key order beside the keys) is tested first; only heads whose partial
//! distance does not exceed the query's best are scored in full. Answers
//! compare (distance, index), so neither the order of the sweep nor its split
//! over threads changes them: the result is the exhaustive one.

use std::ops::Range;

use std::sync::atomic::{AtomicU64, Ordering};

use rayon::prelude::*;

use crate::kernel::{head_bytes, prefetch, Kernel, Params, PruneStats};
use crate::layout::{Layout, Metric, LANE};
use crate::merge::{merge_best, Hit};
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

/// What a sweep needs besides the keys: how to score and what to search.
pub(crate) struct Sweep {
    pub kernel: Kernel,
    pub layout: Layout,
    pub params: Params,
    /// Global indices searched.
    pub range: Range<u64>,
    /// Fewest slots (or vectors) one rayon task sweeps.
    pub min_part: usize,
}

/// A dense space's padded vectors: local index 0 first, at global index `base`.
pub(crate) struct Dense<'a> {
    pub data: &'a [u8],
    pub base: u64,
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

/// Per query the least distance any part of a sweep has found so far,
/// shared by the parts: each part prunes against the best of all of them,
/// so splitting a batch over more threads adds little work. Only vectors
/// strictly above a distance already found are skipped, and the parts'
/// answers are merged by (distance, index), so the answers are the same
/// whatever the order in which the parts run; only the pruning figures vary.
struct Bounds(Vec<AtomicU64>);

impl Bounds {
    fn new(start: &[Hit]) -> Self {
        Self(start.iter().map(|h| AtomicU64::new(h.dist)).collect())
    }

    fn get(&self, i: usize) -> u64 {
        self.0[i].load(Ordering::Relaxed)
    }

    fn lower(&self, i: usize, d: u64) {
        self.0[i].fetch_min(d, Ordering::Relaxed);
    }
}

/// Cuts the slots the `windows` cover into at most `parts` ranges of about
/// equal work, the work of a slot being the number of windows over it, and
/// none with less than `min_work` (slot, window) pairs. Where windows pile
/// up the ranges are short, so that no thread gets most of a batch's work
/// while the others wait; the answers do not depend on the cut.
fn balanced_parts(windows: &[Range<usize>], parts: usize, min_work: usize) -> Vec<Range<usize>> {
    let from = windows.iter().map(|w| w.start).min().unwrap_or(0);
    let to = windows.iter().map(|w| w.end).max().unwrap_or(0);
    let total: usize = windows.iter().map(|w| w.len()).sum();
    if to <= from || total == 0 {
        return std::iter::once(from..to.max(from)).collect();
    }
    let parts = parts.clamp(1, total.div_ceil(min_work).max(1));
    let per = total.div_ceil(parts);
    // Coverage changes at each window's ends.
    let mut events: Vec<(usize, isize)> = windows
        .iter()
        .filter(|w| !w.is_empty())
        .flat_map(|w| [(w.start, 1), (w.end, -1)])
        .collect();
    events.sort_unstable();
    let mut cuts = vec![from];
    let (mut cover, mut done, mut at) = (0usize, 0usize, from);
    for (pos, delta) in events {
        // Slots at..pos carry `cover` windows each.
        while cover > 0 && at < pos && cuts.len() < parts {
            let need = (per * cuts.len()).saturating_sub(done).max(1);
            let fits = (pos - at) * cover;
            if fits < need {
                done += fits;
                at = pos;
            } else {
                let step = need.div_ceil(cover).clamp(1, pos - at);
                at += step;
                done += step * cover;
                if at < to && cuts.len() < parts {
                    cuts.push(at);
                }
            }
        }
        at = pos;
        cover = cover.checked_add_signed(delta).unwrap_or(0);
    }
    cuts.push(to);
    cuts.dedup();
    cuts.windows(2).map(|c| c[0]..c[1]).collect()
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

/// Per query the best of `start` and the parts' answers, and the parts'
/// figures completed: `pruned` arrives as the pairs scored in full and leaves
/// as the pairs skipped.
fn merged(sw: &Sweep, start: &[Hit], parts: &[(Vec<Hit>, PruneStats)]) -> (Vec<Hit>, PruneStats) {
    let mut best = start.to_vec();
    let mut stats = PruneStats::default();
    for (p, s) in parts {
        merge_best(&mut best, p);
        stats.add(s);
    }
    let chunks = (sw.layout.stride() / LANE) as u64;
    let pairs = (sw.range.end - sw.range.start) * start.len() as u64;
    stats.pairs = pairs;
    stats.chunks_full = pairs * chunks;
    stats.pruned = pairs - stats.pruned;
    (best, stats)
}

/// Where a plane-backed sweep finds its vectors: their positions and each
/// vector gathered from the planes.
pub(crate) trait PlaneVectors: Sync {
    /// The runs (first global index, x, y, length) that cover `range`.
    fn runs(&self, range: Range<u64>) -> Vec<(u64, u32, u32, u32)>;
    /// Bytes [`PlaneVectors::gather`] may write.
    fn span(&self) -> usize;
    /// Writes the padded vector of position (x, y) to the start of `dst`.
    fn gather(&self, x: usize, y: usize, dst: &mut [u8]);
}

/// Fine positions looked at between two tests of all the probes' windows
/// (at most 32, so their parents fit one bit mask).
const GROUP: usize = 32;

/// The keys of a plane-backed space as a summed-area table of its parent
/// rows: any box of a parent window sums in four reads. A query whose
/// defined lo components form a rectangle of its parent window (all of them,
/// or the part inside the canvas at a border) is bounded by the sum over
/// that rectangle alone: the triangle inequality and Cauchy–Schwarz hold for
/// any subset of the components. Four bytes per parent pixel, one per sample
/// pixel; the vectors are not reordered, so a sweep visits every position
/// but gathers and scores only those inside some query's window.
#[derive(Debug, Clone)]
pub(crate) struct KeyPlane {
    /// Table width: parent width + 1.
    width: usize,
    /// Parent row of table row 0 (table row j sums parent rows row0..row0 + j).
    row0: usize,
    m: usize,
    /// Sums mod 2³²: a box of at most m²·255 comes out exact by wrapping
    /// arithmetic.
    sums: Vec<u32>,
}

/// The defined part of a query's lo part when it is a rectangle of the
/// parent window: rows r0..r1, columns c0..c1.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Rect {
    r0: usize,
    r1: usize,
    c0: usize,
    c1: usize,
}

impl Rect {
    /// The rectangle of defined components in an `m`×`m` lo mask, if they
    /// form one (and at least one is defined).
    fn of(mask: &[u8], m: usize) -> Option<Self> {
        let on = |r: usize, c: usize| mask[r * m + c] == 0xFF;
        let rows: Vec<usize> = (0..m).filter(|&r| (0..m).any(|c| on(r, c))).collect();
        let cols: Vec<usize> = (0..m).filter(|&c| (0..m).any(|r| on(r, c))).collect();
        let (r0, r1) = (*rows.first()?, *rows.last()? + 1);
        let (c0, c1) = (*cols.first()?, *cols.last()? + 1);
        let full = (r0..r1).all(|r| (c0..c1).all(|c| on(r, c)));
        full.then_some(Self { r0, r1, c0, c1 })
    }

    fn count(&self) -> u64 {
        ((self.r1 - self.r0) * (self.c1 - self.c0)) as u64
    }
}

/// One query of a plane sweep: its rectangle, the key over it, its best
/// answer and its window of keys.
#[derive(Clone)]
struct PlaneProbe<'a> {
    q: &'a [u8],
    m: &'a [u8],
    rect: Rect,
    key: u64,
    best: Hit,
    /// Lowest key in the window and the window's width: a key k is inside
    /// when k − lo (wrapping) ≤ span.
    lo: u32,
    span: u32,
    /// Per parent pixel of the current group, whether its key is inside.
    inside: u32,
}

impl PlaneProbe<'_> {
    fn aim(&mut self, sw: &Sweep) {
        let reach = reach(sw, self.rect.count(), self.best.dist);
        let lo = self.key.saturating_sub(reach);
        let hi = self.key.saturating_add(reach).min(u64::from(u32::MAX));
        self.lo = lo as u32;
        self.span = (hi - lo) as u32;
    }
}

/// Largest key distance a vector can have over a part of `count` lo
/// components and still score at most `best`.
fn reach(sw: &Sweep, count: u64, best: u64) -> u64 {
    let wl = u64::from(sw.params.weights.lo);
    match sw.params.metric {
        Metric::L1 => best / wl,
        Metric::L2 => {
            let x = u128::from(best) * u128::from(count) / u128::from(wl);
            u64::try_from(x.isqrt()).unwrap_or(u64::MAX)
        }
    }
}

impl KeyPlane {
    /// The table of an `m`×`m` parent window over the parent plane whose rows
    /// `row0..` are `pixels` (`width` per row); `None` when m = 0.
    pub(crate) fn build(pixels: &[u8], width: usize, row0: usize, m: usize) -> Option<Self> {
        if m == 0 || width == 0 {
            return None;
        }
        let rows = pixels.len() / width;
        let w = width + 1;
        let mut sums = vec![0u32; (rows + 1) * w];
        // Row sums in parallel, then the running sum down the columns.
        sums[w..]
            .par_chunks_mut(w)
            .zip(pixels.par_chunks(width))
            .for_each(|(out, row)| {
                let mut acc = 0u32;
                for (o, &p) in out[1..].iter_mut().zip(row) {
                    acc = acc.wrapping_add(u32::from(p));
                    *o = acc;
                }
            });
        for j in 1..=rows {
            let (above, here) = sums.split_at_mut(j * w);
            for (h, &a) in here[..w].iter_mut().zip(&above[(j - 1) * w..]) {
                *h = h.wrapping_add(a);
            }
        }
        Some(Self {
            width: w,
            row0,
            m,
            sums,
        })
    }

    /// Whether a query with this mask can be searched here: the lo part has a
    /// weight and its defined components form a rectangle.
    pub(crate) fn applies(&self, layout: &Layout, params: &Params, mask: &[u8]) -> bool {
        params.weights.lo > 0
            && Rect::of(&mask[layout.hi_pad..layout.hi_pad + layout.lo_len], self.m).is_some()
    }

    /// Bytes held.
    pub(crate) fn bytes(&self) -> u64 {
        (self.sums.capacity() * 4) as u64
    }

    /// As [`KeyIndex::search`], over a plane-backed space: sweeps `sw.range`
    /// in index order, and gathers and scores only vectors whose key lies in
    /// some query's window. Every query must pass [`KeyPlane::applies`].
    pub(crate) fn search(
        &self,
        sw: &Sweep,
        src: &impl PlaneVectors,
        queries: &[(&[u8], &[u8])],
        start: &[Hit],
    ) -> (Vec<Hit>, PruneStats) {
        let l = &sw.layout;
        let probes: Vec<PlaneProbe> = queries
            .iter()
            .zip(start)
            .map(|(&(q, m), &best)| {
                let lo = l.hi_pad..l.hi_pad + l.lo_len;
                let rect = Rect::of(&m[lo.clone()], self.m).expect("the query passed `applies`");
                let key = (rect.r0..rect.r1)
                    .flat_map(|r| (rect.c0..rect.c1).map(move |c| r * self.m + c))
                    .map(|i| u64::from(q[lo.start + i]))
                    .sum();
                let mut p = PlaneProbe {
                    q,
                    m,
                    rect,
                    key,
                    best,
                    lo: 0,
                    span: 0,
                    inside: 0,
                };
                p.aim(sw);
                p
            })
            .collect();
        let n = (sw.range.end - sw.range.start) as usize;
        let threads = rayon::current_num_threads().max(1);
        let per = n.div_ceil(threads * 4).max(sw.min_part.max(1)) as u64;
        let parts: Vec<(Vec<Hit>, PruneStats)> = (sw.range.start..sw.range.end)
            .step_by(per as usize)
            .collect::<Vec<_>>()
            .into_par_iter()
            .map(|a| self.sweep(sw, src, probes.clone(), a..(a + per).min(sw.range.end)))
            .collect();
        merged(sw, start, &parts)
    }

    /// Marks in `p.inside` the parent pixels `px..px + count` of parent row
    /// `py` whose key over the probe's rectangle lies in its window.
    #[inline(always)]
    fn test(&self, p: &mut PlaneProbe, px: usize, py: usize, count: usize) {
        let h = self.m / 2;
        // Table rows and columns of the rectangle of the window centred at
        // (px, py): rows py − h + r0 .. py − h + r1, columns likewise.
        let top = (py + p.rect.r0 - h - self.row0) * self.width;
        let bottom = (py + p.rect.r1 - h - self.row0) * self.width;
        let left = px + p.rect.c0 - h;
        let right = px + p.rect.c1 - h;
        let row = |base: usize, col: usize| &self.sums[base + col..base + col + count];
        let (a, b) = (row(bottom, right), row(top, right));
        let (c, d) = (row(bottom, left), row(top, left));
        let mut inside = 0u32;
        for i in 0..count {
            let k = a[i]
                .wrapping_sub(b[i])
                .wrapping_sub(c[i])
                .wrapping_add(d[i]);
            inside |= u32::from(k.wrapping_sub(p.lo) <= p.span) << i;
        }
        p.inside = inside;
    }

    /// Sweeps the global indices `part` for every probe, [`GROUP`] positions
    /// at a time: a group none of whose keys is in a window is passed over.
    fn sweep(
        &self,
        sw: &Sweep,
        src: &impl PlaneVectors,
        mut probes: Vec<PlaneProbe>,
        part: Range<u64>,
    ) -> (Vec<Hit>, PruneStats) {
        let _busy = crate::search::BusyTimer::start();
        let chunks = (sw.layout.stride() / LANE) as u64;
        let mut stats = PruneStats::default();
        let mut buf = vec![0u8; src.span()];
        for (first, x, y, len) in src.runs(part) {
            let (x, y, len) = (x as usize, y as usize, len as usize);
            let mut i = 0;
            while i < len {
                let end = (i + GROUP).min(len);
                let px0 = (x + i) / 2;
                let count = (x + end - 1) / 2 - px0 + 1;
                let mut any = 0;
                for p in probes.iter_mut() {
                    self.test(p, px0, y / 2, count);
                    any |= p.inside;
                }
                if any != 0 {
                    for j in i..end {
                        let bit = 1u32 << ((x + j) / 2 - px0);
                        if any & bit == 0 {
                            continue;
                        }
                        src.gather(x + j, y, &mut buf);
                        for p in probes.iter_mut() {
                            if p.inside & bit == 0 {
                                continue;
                            }
                            let d = sw.kernel.finish(
                                &sw.layout,
                                &sw.params,
                                0,
                                &buf,
                                p.q,
                                p.m,
                                0,
                                p.best.dist,
                            );
                            stats.pruned += 1;
                            stats.chunks += chunks;
                            let hit = Hit {
                                index: first + j as u64,
                                dist: d,
                            };
                            if hit.key() < p.best.key() {
                                let narrower = hit.dist < p.best.dist;
                                p.best = hit;
                                if narrower {
                                    // The rest of the group keeps the old
                                    // window: wider, so still exact.
                                    p.aim(sw);
                                }
                            }
                        }
                    }
                }
                i = end;
            }
        }
        (probes.iter().map(|p| p.best).collect(), stats)
    }
}

#[cfg(test)]
mod tests {
    use super::balanced_parts;
    use proptest::prelude::*;
    use std::ops::Range;

    fn work(windows: &[Range<usize>], part: &Range<usize>) -> usize {
        windows
            .iter()
            .map(|w| w.end.min(part.end).saturating_sub(w.start.max(part.start)))
            .sum()
    }

    proptest! {
        /// The parts tile the covered span in order, there are at most as
        /// many as asked, and none holds much more than an equal share.
        #[test]
        fn parts_tile_the_span_with_equal_work(
            raw in proptest::collection::vec((0usize..5000, 0usize..3000), 1..80),
            parts in 1usize..80,
            min_work in 1usize..5000,
        ) {
            let windows: Vec<Range<usize>> = raw.iter().map(|&(a, l)| a..a + l).collect();
            let cut = balanced_parts(&windows, parts, min_work);
            let total: usize = windows.iter().map(|w| w.len()).sum();
            prop_assert!(!cut.is_empty() && cut.len() <= parts);
            for w in cut.windows(2) {
                prop_assert_eq!(w[0].end, w[1].start);
            }
            if total > 0 {
                let from = windows.iter().map(|w| w.start).min().unwrap();
                let to = windows.iter().map(|w| w.end).max().unwrap();
                prop_assert_eq!(cut[0].start, from);
                prop_assert_eq!(cut.last().unwrap().end, to);
                let share = total.div_ceil(parts.clamp(1, total.div_ceil(min_work).max(1)));
                for p in &cut[..cut.len() - 1] {
                    // Each cut lands within one slot's coverage of its target.
                    prop_assert!(work(&windows, p) <= share + windows.len(), "{:?}", p);
                }
                prop_assert_eq!(cut.iter().map(|p| work(&windows, p)).sum::<usize>(), total);
            }
        }
    }
}
