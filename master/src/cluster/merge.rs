//! Merging the workers' local best answers (DESIGN §3.5, §4): per query the
//! minimum distance, ties to the lowest global index. Distances are integers,
//! so the merge gives the same answer whatever the number of parts, their
//! order or how the index range was split: that is what makes an N-worker
//! cluster bit-identical to the local engine.

use std::ops::Range;

use texsyn_worker::Hit;

/// Best answer per query over all `parts` (each a best-1 answer per query of
/// one part of the index range). A query no part answered gets [`Hit::NONE`].
///
/// Parts shorter than `queries` are treated as not answering the missing
/// queries; callers check shapes first with [`check_part`].
pub fn merge_answers(queries: usize, parts: &[&[Hit]]) -> Vec<Hit> {
    let mut best = vec![Hit::NONE; queries];
    for part in parts {
        for (b, h) in best.iter_mut().zip(part.iter()) {
            if (h.dist, h.index) < (b.dist, b.index) {
                *b = *h;
            }
        }
    }
    best
}

/// Checks one worker's answer to `queries` queries over its assigned `range`:
/// one hit per query, every index inside the range. An answer that fails is
/// never merged (the worker is dropped and the batch asked again).
pub fn check_part(hits: &[Hit], queries: usize, range: &Range<u64>) -> Result<(), String> {
    if hits.len() != queries {
        return Err(format!(
            "answered {} hits for {queries} queries",
            hits.len()
        ));
    }
    if range.is_empty() {
        return match hits.iter().find(|h| !h.is_none()) {
            Some(h) => Err(format!(
                "answered index {} although its range is empty",
                h.index
            )),
            None => Ok(()),
        };
    }
    match hits
        .iter()
        .find(|h| !range.contains(&h.index) || h.dist == u64::MAX)
    {
        Some(h) => Err(format!(
            "answered index {} (distance {}) outside its range {}..{}",
            h.index, h.dist, range.start, range.end
        )),
        None => Ok(()),
    }
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
        assert!(check_part(&[h(5, 1), h(9, 0)], 2, &(5..10)).is_ok());
        assert!(check_part(&[h(5, 1)], 2, &(5..10)).is_err());
        assert!(check_part(&[h(10, 1), h(9, 0)], 2, &(5..10)).is_err());
        assert!(check_part(&[h(4, 1)], 1, &(5..10)).is_err());
        assert!(check_part(&[Hit::NONE], 1, &(5..10)).is_err());
        assert!(check_part(&[Hit::NONE], 1, &(5..5)).is_ok());
        assert!(check_part(&[h(5, 0)], 1, &(5..5)).is_err());
    }
}
