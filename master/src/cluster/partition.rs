//! The partition table: a level's global index range `0..total` cut into one
//! contiguous range per participant, sized in proportion to the measured
//! throughput (ARCHITECTURE §4 "Calibration"). The table only decides who searches
//! what; the merged answer does not depend on it.

use std::ops::Range;

/// Cuts `0..total` into `weights.len()` contiguous ranges, in order, with
/// lengths proportional to `weights` (largest remainder, so the lengths add up
/// to `total` exactly). Non-finite or negative weights count as 0; if no weight
/// is positive the range is cut evenly.
pub fn proportional(total: u64, weights: &[f64]) -> Vec<Range<u64>> {
    let n = weights.len();
    if n == 0 {
        return Vec::new();
    }
    let clean: Vec<f64> = weights
        .iter()
        .map(|&w| if w.is_finite() && w > 0.0 { w } else { 0.0 })
        .collect();
    let sum: f64 = clean.iter().sum();
    let clean = if sum > 0.0 { clean } else { vec![1.0; n] };
    let sum: f64 = clean.iter().sum();
    // Floor of each exact share, then the remainder to the largest fractions
    // (ties to the earlier participant).
    let exact: Vec<f64> = clean.iter().map(|w| w / sum * total as f64).collect();
    let mut lens: Vec<u64> = exact
        .iter()
        .map(|e| (e.floor() as u64).min(total))
        .collect();
    let mut given: u64 = lens.iter().sum();
    while given > total {
        // Rounding pushed the sum over: take from the largest.
        let i = (0..n).max_by_key(|&i| lens[i]).unwrap_or(0);
        lens[i] -= 1;
        given -= 1;
    }
    let mut order: Vec<usize> = (0..n).filter(|&i| clean[i] > 0.0).collect();
    order.sort_by(|&a, &b| {
        let fa = exact[a] - exact[a].floor();
        let fb = exact[b] - exact[b].floor();
        fb.total_cmp(&fa).then(a.cmp(&b))
    });
    let mut k = 0;
    while given < total && !order.is_empty() {
        lens[order[k % order.len()]] += 1;
        given += 1;
        k += 1;
    }
    let mut start = 0;
    lens.iter()
        .map(|&l| {
            let r = start..start + l;
            start += l;
            r
        })
        .collect()
}

/// Fraction of `total` that `range` covers (0 for an empty level).
pub fn share(range: &Range<u64>, total: u64) -> f64 {
    if total == 0 {
        0.0
    } else {
        (range.end - range.start) as f64 / total as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check_cover(total: u64, parts: &[Range<u64>]) {
        let mut at = 0;
        for p in parts {
            assert_eq!(p.start, at, "{parts:?}");
            assert!(p.end >= p.start);
            at = p.end;
        }
        assert_eq!(at, total, "{parts:?}");
    }

    #[test]
    fn proportional_to_weights_and_covering() {
        let p = proportional(1000, &[1.0, 3.0]);
        assert_eq!(p, vec![0..250, 250..1000]);
        let p = proportional(10, &[1.0, 1.0, 1.0]);
        check_cover(10, &p);
        let lens: Vec<u64> = p.iter().map(|r| r.end - r.start).collect();
        assert_eq!(lens, vec![4, 3, 3]);
    }

    #[test]
    fn degenerate_weights() {
        assert_eq!(proportional(7, &[]), Vec::<Range<u64>>::new());
        assert_eq!(proportional(7, &[0.0, 0.0]), vec![0..4, 4..7]);
        assert_eq!(proportional(7, &[f64::NAN, 2.0]), vec![0..0, 0..7]);
        assert_eq!(
            proportional(7, &[-1.0, f64::INFINITY, 1.0]),
            vec![0..0, 0..0, 0..7]
        );
        assert_eq!(proportional(0, &[1.0, 2.0]), vec![0..0, 0..0]);
        assert_eq!(proportional(2, &[1.0, 1.0, 1.0]), vec![0..1, 1..2, 2..2]);
    }

    #[test]
    fn always_covers_exactly() {
        let weights = [
            vec![1.0],
            vec![0.3, 0.3, 0.4],
            vec![1e9, 1.0, 1e-9],
            vec![5.5, 2.25, 7.125, 0.0, 3.0],
        ];
        for total in [0u64, 1, 2, 3, 17, 1000, 240_100, u32::MAX as u64 + 7] {
            for w in &weights {
                check_cover(total, &proportional(total, w));
            }
        }
    }

    #[test]
    fn share_is_a_fraction() {
        assert_eq!(share(&(0..25), 100), 0.25);
        assert_eq!(share(&(0..0), 0), 0.0);
    }
}
