//! Splitting a keyed sweep over threads: the bounds its parts share and the
//! cut of the slots into parts of about equal work.

use std::ops::Range;

use std::sync::atomic::{AtomicU64, Ordering};

use crate::link::Link;
use crate::merge::Hit;

/// Per query the least distance any part of a sweep has found so far,
/// shared by the parts: each part prunes against the best of all of them,
/// so splitting a batch over more threads adds little work. Only vectors
/// strictly above a distance already found are skipped, and the parts'
/// answers are merged by (distance, index), so the answers are the same
/// whatever the order in which the parts run; only the pruning figures vary.
pub(super) struct Bounds<'a> {
    own: Vec<AtomicU64>,
    /// The batch's [`Link`] to its other ranges and, per query here, its
    /// place in the batch.
    link: Option<(&'a Link, &'a [usize])>,
}

impl<'a> Bounds<'a> {
    pub(super) fn new(start: &[Hit], link: Option<(&'a Link, &'a [usize])>) -> Self {
        let own = start.iter().map(|h| AtomicU64::new(h.dist)).collect();
        let b = Self { own, link };
        for (i, h) in start.iter().enumerate() {
            b.lower(i, h.dist);
        }
        b
    }

    pub(super) fn get(&self, i: usize) -> u64 {
        let own = self.own[i].load(Ordering::Relaxed);
        match self.link {
            Some((link, at)) => own.min(link.get(at[i])),
            None => own,
        }
    }

    pub(super) fn lower(&self, i: usize, d: u64) {
        self.own[i].fetch_min(d, Ordering::Relaxed);
        if let Some((link, at)) = self.link {
            if d < u64::MAX {
                link.lower(at[i], d);
            }
        }
    }
}

/// Cuts the slots the `windows` cover into at most `parts` ranges of about
/// equal work, the work of a slot being the number of windows over it, and
/// none with less than `min_work` (slot, window) pairs. Where windows pile
/// up the ranges are short, so that no thread gets most of a batch's work
/// while the others wait; the answers do not depend on the cut.
pub(super) fn balanced_parts(
    windows: &[Range<usize>],
    parts: usize,
    min_work: usize,
) -> Vec<Range<usize>> {
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
