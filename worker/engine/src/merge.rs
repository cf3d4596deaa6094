//! Merging best answers: per query the minimum distance, ties to the lowest
//! global index (ARCHITECTURE §5). Distances are integers,
//! so a merge gives the same answer whatever the number of parts, their order
//! or how the index range was split. The engine merges its rayon sub-ranges
//! with these functions and the cluster merges its workers' answers with them:
//! that is what makes any split of the search bit-identical to one scan.

use std::ops::Range;

use crate::kernel::PruneStats;

/// One answer: a global reference index and its distance to the query.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub struct Hit {
    pub index: u64,
    pub dist: u64,
}

/// How far from a query's best distance a near-tie may be: `absolute` plus
/// `per_mille` thousandths of the best distance.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Slack {
    pub absolute: u64,
    pub per_mille: u32,
}

impl Slack {
    /// The largest distance that is a near-tie of `best`.
    pub fn limit(&self, best: u64) -> u64 {
        let rel = (u128::from(best) * u128::from(self.per_mille) / 1000).min(u128::from(u64::MAX));
        best.saturating_add(self.absolute)
            .saturating_add(rel as u64)
    }

    /// Drops from each sorted list what lies beyond its slack of its first
    /// (best) entry: top-k lists become near-tie lists.
    pub fn keep_near_ties(lists: &mut [Vec<Hit>], slack: &[Slack]) {
        for (l, s) in lists.iter_mut().zip(slack) {
            if let Some(best) = l.first().map(|h| h.dist) {
                l.retain(|h| h.dist <= s.limit(best));
            }
        }
    }
}

impl Hit {
    /// The "nothing found yet" hit; loses against every real one.
    pub const NONE: Hit = Hit {
        index: u64::MAX,
        dist: u64::MAX,
    };

    /// Ordering key: smaller distance first, then lower index.
    pub fn key(&self) -> (u64, u64) {
        (self.dist, self.index)
    }

    pub fn is_none(&self) -> bool {
        *self == Hit::NONE
    }
}

/// Merges best-1 answers of another part into `acc`, query by query
/// (min distance, ties to the lowest index). Used for sub-ranges and workers alike.
pub fn merge_best(acc: &mut [Hit], other: &[Hit]) {
    for (a, b) in acc.iter_mut().zip(other) {
        if b.key() < a.key() {
            *a = *b;
        }
    }
}

/// Merges two sorted top-k lists into the best `k`, ordered by (distance, index).
pub fn merge_topk(a: &[Hit], b: &[Hit], k: usize) -> Vec<Hit> {
    let mut out = Vec::with_capacity(k.min(a.len() + b.len()));
    let (mut i, mut j) = (0, 0);
    while out.len() < k && (i < a.len() || j < b.len()) {
        let take_a = j >= b.len() || (i < a.len() && a[i].key() <= b[j].key());
        if take_a {
            out.push(a[i]);
            i += 1;
        } else {
            out.push(b[j]);
            j += 1;
        }
    }
    out
}

/// Best answer per query over all `parts` (each a best-1 answer per query of
/// one part of the index range). A query no part answered gets [`Hit::NONE`].
///
/// Parts shorter than `queries` are treated as not answering the missing
/// queries; callers check shapes first with [`check_part`].
pub fn merge_answers(queries: usize, parts: &[&[Hit]]) -> Vec<Hit> {
    let mut best = vec![Hit::NONE; queries];
    for part in parts {
        merge_best(&mut best, part);
    }
    best
}

/// The final answer of a bounded search: per query the better of the
/// query's known answer (its bound) and what the search found beyond it.
pub fn with_bounds(bounds: &[Hit], found: &[Hit]) -> Vec<Hit> {
    let mut out = bounds.to_vec();
    merge_best(&mut out, found);
    out
}

/// Checks one worker's answer over its assigned `range` to queries with the
/// known answers `bounds` (one per query, [`Hit::NONE`] for none): one hit per
/// query, each inside the range and strictly better than the query's bound, or
/// [`Hit::NONE`] when the range holds nothing better than a real bound (an
/// unbounded query over a non-empty range always has an answer). An answer
/// that fails is never merged (the worker is dropped and the batch asked again).
pub fn check_part(hits: &[Hit], bounds: &[Hit], range: &Range<u64>) -> Result<(), String> {
    check(hits, bounds, range, false)
}

/// [`check_part`] for a linked part (ARCHITECTURE §4.7): it may answer
/// [`Hit::NONE`] for an unbounded query too, when another range reported a
/// distance its own vectors cannot beat.
pub fn check_linked_part(hits: &[Hit], bounds: &[Hit], range: &Range<u64>) -> Result<(), String> {
    check(hits, bounds, range, true)
}

fn check(hits: &[Hit], bounds: &[Hit], range: &Range<u64>, linked: bool) -> Result<(), String> {
    let queries = bounds.len();
    if hits.len() != queries {
        return Err(format!(
            "answered {} hits for {queries} queries",
            hits.len()
        ));
    }
    for (h, b) in hits.iter().zip(bounds) {
        if h.is_none() {
            if b.is_none() && !range.is_empty() && !linked {
                return Err(format!(
                    "answered nothing for a query over its range {}..{}",
                    range.start, range.end
                ));
            }
        } else if !range.contains(&h.index) || h.dist == u64::MAX {
            return Err(format!(
                "answered index {} (distance {}) outside its range {}..{}",
                h.index, h.dist, range.start, range.end
            ));
        } else if h.key() >= b.key() {
            return Err(format!(
                "answered index {} (distance {}), no better than the bound {} (distance {})",
                h.index, h.dist, b.index, b.dist
            ));
        }
    }
    Ok(())
}

/// One group's answers and pruning figures.
pub(crate) type Answers = (Vec<Hit>, PruneStats);

/// The answers of a batch searched as groups of its queries: each group's
/// hits put back at its queries' places (`start` where no group answered),
/// and the groups' pruning figures added up.
pub(crate) fn regroup<const N: usize>(
    mut start: Vec<Hit>,
    groups: [(&[usize], Option<Answers>); N],
) -> (Vec<Hit>, PruneStats) {
    let mut stats = PruneStats::default();
    for (ids, found) in groups {
        if let Some((hits, s)) = found {
            for (&q, h) in ids.iter().zip(hits) {
                start[q] = h;
            }
            stats.add(&s);
        }
    }
    (start, stats)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn h(index: u64, dist: u64) -> Hit {
        Hit { index, dist }
    }

    #[test]
    fn minimum_distance_wins() {
        let a = [h(3, 10), h(4, 7)];
        let b = [h(50, 9), h(60, 8)];
        assert_eq!(merge_answers(2, &[&a, &b]), vec![h(50, 9), h(4, 7)]);
    }

    #[test]
    fn ties_go_to_the_lowest_index_in_any_order() {
        let a = [h(100, 5)];
        let b = [h(7, 5)];
        let c = [h(42, 5)];
        let want = vec![h(7, 5)];
        assert_eq!(merge_answers(1, &[&a, &b, &c]), want);
        assert_eq!(merge_answers(1, &[&c, &b, &a]), want);
        assert_eq!(merge_answers(1, &[&b, &a, &c]), want);
    }

    #[test]
    fn none_loses_and_nothing_gives_none() {
        let a = [Hit::NONE, h(1, u64::MAX - 1)];
        let b = [h(9, 0), Hit::NONE];
        assert_eq!(
            merge_answers(2, &[&a, &b]),
            vec![h(9, 0), h(1, u64::MAX - 1)]
        );
        assert_eq!(merge_answers(2, &[]), vec![Hit::NONE; 2]);
        assert_eq!(merge_answers(0, &[&a]), vec![]);
    }

    #[test]
    fn merge_equals_a_single_scan_for_any_split() {
        // Distances of one query over 0..40 with many ties; every split into
        // contiguous parts merges to the global (min distance, lowest index).
        let dist: Vec<u64> = (0..40u64).map(|i| (i * 7919 + 13) % 5).collect();
        let global = (0..40u64)
            .map(|i| h(i, dist[i as usize]))
            .min_by_key(|x| (x.dist, x.index))
            .unwrap();
        for cut1 in 1..39u64 {
            for cut2 in cut1 + 1..40u64 {
                let best = |r: Range<u64>| {
                    r.map(|i| h(i, dist[i as usize]))
                        .min_by_key(|x| (x.dist, x.index))
                        .unwrap()
                };
                let parts = [[best(cut2..40)], [best(0..cut1)], [best(cut1..cut2)]];
                let refs: Vec<&[Hit]> = parts.iter().map(|p| &p[..]).collect();
                assert_eq!(merge_answers(1, &refs), vec![global]);
            }
        }
    }

    #[test]
    fn answers_are_checked_against_the_range() {
        let free = [Hit::NONE; 2];
        assert!(check_part(&[h(5, 1), h(9, 0)], &free, &(5..10)).is_ok());
        assert!(check_part(&[h(5, 1)], &free, &(5..10)).is_err());
        assert!(check_part(&[h(10, 1), h(9, 0)], &free, &(5..10)).is_err());
        assert!(check_part(&[h(4, 1)], &free[..1], &(5..10)).is_err());
        assert!(check_part(&[Hit::NONE], &free[..1], &(5..10)).is_err());
        assert!(check_part(&[Hit::NONE], &free[..1], &(5..5)).is_ok());
        assert!(check_part(&[h(5, 0)], &free[..1], &(5..5)).is_err());
    }

    #[test]
    fn answers_must_beat_the_bound() {
        let b = [h(20, 3)];
        assert!(check_part(&[Hit::NONE], &b, &(5..10)).is_ok());
        assert!(check_part(&[h(6, 2)], &b, &(5..10)).is_ok());
        // A tie with a lower index beats the bound; with a higher one it does not.
        assert!(check_part(&[h(6, 3)], &b, &(5..10)).is_ok());
        assert!(check_part(&[h(6, 4)], &b, &(5..10)).is_err());
        assert!(check_part(&[h(6, 3)], &[h(2, 3)], &(5..10)).is_err());
        assert_eq!(with_bounds(&b, &[Hit::NONE]), vec![h(20, 3)]);
        assert_eq!(with_bounds(&b, &[h(6, 3)]), vec![h(6, 3)]);
    }
}
