//! The keys of a plane-backed space: a summed-area table of its parent rows,
//! and the sweep that gathers and scores only the positions inside some
//! query's window.

use std::ops::Range;

use rayon::prelude::*;

use super::{merged, reach, PlaneVectors, Sweep};
use crate::kernel::{Params, PruneStats};
use crate::layout::{Layout, LANE};
use crate::merge::Hit;

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

    /// As [`KeyIndex::search`](super::KeyIndex::search), over a plane-backed space: sweeps `sw.range`
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
        let _busy = crate::profile::Timer::busy();
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
                        let v = src.fetch(first + j as u64, x + j, y, &mut buf);
                        for p in probes.iter_mut() {
                            if p.inside & bit == 0 {
                                continue;
                            }
                            let d = sw.kernel.finish(
                                &sw.layout,
                                &sw.params,
                                0,
                                v,
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
