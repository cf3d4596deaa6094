//! The cluster's rules as pure functions (ARCHITECTURE §4.2, §4.3): the
//! partition table (a level's global index range `0..total` cut into one
//! contiguous range per participant, in proportion to the calibrated
//! throughput), the deadlines derived from the calibration, when a worker
//! counts as slow and when slowness triggers recalibration, and when the
//! measured throughput pays for a rebalance. They only decide who searches
//! what and how long to wait; the merged answer does not depend on them.

use std::ops::Range;
use std::time::Duration;

use texsyn_engine::Layout;

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

/// `x` seconds as a duration, clamped to 0..=10⁶ s (never panics).
pub fn capped_secs(x: f64) -> Duration {
    Duration::from_secs_f64(if x.is_finite() {
        x.clamp(0.0, 1e6)
    } else {
        1e6
    })
}

/// Cost of one reference × query pair of a level whose vectors have `stride`
/// bytes, in calibration pairs (vectors of `calibration_dims` dimensions): the
/// work grows more or less with the bytes compared.
pub fn pair_cost(stride: usize, calibration_dims: u32) -> f64 {
    stride as f64 / Layout::new(calibration_dims.max(1) as usize, 0).stride() as f64
}

/// Seconds a worker calibrated at `rate` pairs per second is expected to take
/// for `queries` queries over `len` reference vectors of cost `cost`.
pub fn expected_seconds(len: u64, queries: usize, cost: f64, rate: f64) -> f64 {
    len as f64 * queries as f64 * cost / rate.max(1.0)
}

/// The slowest speed a deadline is computed from: a participant that
/// calibrated slower than this fraction of the median speed of the
/// participants (the master's own included) is given the time of this speed,
/// so a worker that calibrates slowly and then hangs cannot stretch a batch's
/// deadline without bound.
pub const DEADLINE_RATE_FRACTION: f64 = 0.25;

/// [`DEADLINE_RATE_FRACTION`] × the median of the positive finite `rates`
/// (0 when there are none).
pub fn deadline_rate_floor(rates: &[f64]) -> f64 {
    let mut r: Vec<f64> = rates
        .iter()
        .copied()
        .filter(|x| x.is_finite() && *x > 0.0)
        .collect();
    if r.is_empty() {
        return 0.0;
    }
    r.sort_by(f64::total_cmp);
    let median = if r.len() % 2 == 1 {
        r[r.len() / 2]
    } else {
        (r[r.len() / 2 - 1] + r[r.len() / 2]) / 2.0
    };
    median * DEADLINE_RATE_FRACTION
}

/// Time a worker gets for a batch: its expected time × `factor` + `floor`
/// (a stopped worker is detected by this, ARCHITECTURE §4.3).
pub fn batch_deadline(expected: f64, factor: f64, floor: Duration) -> Duration {
    capped_secs(expected * factor) + floor
}

/// Time a control call gets when it moves or builds `amount` units at
/// `per_second` units a second: the call timeout plus that transfer time.
pub fn call_deadline(call_timeout: Duration, amount: f64, per_second: f64) -> Duration {
    call_timeout + capped_secs(amount / per_second)
}

/// A batch is slow (the worker is busy) when it took longer than `factor` ×
/// its expected time (plus 5 ms of transport).
pub fn is_slow(wall: f64, expected: f64, factor: f64) -> bool {
    wall > factor * (expected + 0.005)
}

/// The worker's strikes after a batch: one more when slow, back to 0 when not.
pub fn strikes_after(strikes: u32, slow: bool) -> u32 {
    if slow {
        strikes + 1
    } else {
        0
    }
}

/// Enough slow batches in a row to ask for recalibration.
pub fn strikes_out(strikes: u32, limit: u32) -> bool {
    strikes >= limit
}

/// A recalibration asked for is done once `cooldown` batches have passed
/// since the last one.
pub fn cooldown_over(batches_since: u64, cooldown: u64) -> bool {
    batches_since >= cooldown
}

/// LBG probes sent with a range of `len` vectors: each worker quantises its own
/// range, and more probes than its seeds means all of them (exact).
pub fn range_probes(probes: u32, len: u64) -> u32 {
    if probes == 0 || len == 0 {
        0
    } else {
        (probes as usize).min(texsyn_engine::lbg::default_seeds(len as usize)) as u32
    }
}

/// Batches of a level after which the measured throughput is trusted.
pub const REBALANCE_AFTER: u64 = 8;

/// What one worker did on this level so far.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Measured {
    /// Vectors in its range.
    pub len: u64,
    /// Pairs searched (in calibration units).
    pub pairs: f64,
    /// Search seconds it reported.
    pub seconds: f64,
}

/// The level so far, for [`rebalance`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LevelProgress {
    /// Queries still expected on the level.
    pub remaining_queries: u64,
    /// Longest Assign build time of the current partition, in seconds.
    pub assign_seconds: f64,
}

/// The measured rates (pairs per second) to cut the level anew by, when the
/// calibrated partition is off by more than 20% (a short calibration is
/// easily disturbed) and the rest of the level pays for rebuilding the ranges
/// (the gain is at least 3× the Assign time); `None` to keep the partition.
/// Needs at least 2 workers, each with 20 ms of measured search.
pub fn rebalance(parts: &[Measured], level: LevelProgress) -> Option<Vec<f64>> {
    if parts.len() < 2 || parts.iter().any(|p| p.seconds < 0.02 || p.pairs <= 0.0) {
        return None;
    }
    let measured: Vec<f64> = parts.iter().map(|p| p.pairs / p.seconds).collect();
    // Seconds per query of each part now, and with a partition by the measured rates.
    let per_query: Vec<f64> = parts
        .iter()
        .zip(&measured)
        .map(|(p, r)| p.len as f64 / r)
        .collect();
    let slowest = per_query.iter().copied().fold(0.0, f64::max);
    let fastest = per_query.iter().copied().fold(f64::INFINITY, f64::min);
    let covered: f64 = parts.iter().map(|p| p.len as f64).sum();
    let balanced = covered / measured.iter().sum::<f64>();
    let gain = (slowest - balanced) * level.remaining_queries as f64;
    if slowest <= 1.2 * fastest || gain < 3.0 * level.assign_seconds.max(0.01) {
        return None;
    }
    Some(measured)
}

#[cfg(test)]
mod tests {
    #[test]
    fn slow_calibrations_do_not_stretch_deadlines_without_bound() {
        assert_eq!(deadline_rate_floor(&[]), 0.0);
        assert_eq!(deadline_rate_floor(&[f64::NAN, -1.0, 0.0]), 0.0);
        assert_eq!(deadline_rate_floor(&[4e9]), 1e9);
        assert_eq!(deadline_rate_floor(&[1.0, 4e9, 4e9]), 1e9);
        assert_eq!(deadline_rate_floor(&[2e9, 6e9]), 1e9);
        // A worker calibrated at 1 pair/s next to 4e9 pairs/s peers is given
        // the time of 1e9 pairs/s: seconds, not centuries.
        let floor = deadline_rate_floor(&[1.0, 4e9, 4e9, 4e9]);
        let exp = expected_seconds(1_000_000, 256, 1.0, 1.0f64.max(floor));
        assert!(batch_deadline(exp, 8.0, Duration::from_secs(2)) < Duration::from_secs(5));
    }

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

    #[test]
    fn deadlines_follow_the_calibration() {
        assert_eq!(capped_secs(f64::NAN), Duration::from_secs(1_000_000));
        assert_eq!(capped_secs(-3.0), Duration::ZERO);
        assert_eq!(capped_secs(1.5), Duration::from_millis(1500));
        // 1000 vectors × 10 queries at 1e6 pairs/s: 10 ms expected, × 8 + 2 s.
        let exp = expected_seconds(1000, 10, 1.0, 1e6);
        assert!((exp - 0.01).abs() < 1e-12);
        let d = batch_deadline(exp, 8.0, Duration::from_secs(2));
        assert!(d.abs_diff(Duration::from_millis(2080)) < Duration::from_micros(1));
        // A rate of 0 counts as 1 pair per second, never a division by 0.
        assert_eq!(expected_seconds(3, 2, 1.0, 0.0), 6.0);
        assert_eq!(
            call_deadline(Duration::from_secs(10), 40e6, 20e6),
            Duration::from_secs(12)
        );
        // Vectors of the calibration's own size cost 1; longer ones more.
        assert_eq!(pair_cost(Layout::new(106, 0).stride(), 106), 1.0);
        assert!(pair_cost(Layout::new(212, 0).stride(), 106) > 1.0);
    }

    #[test]
    fn slow_batches_strike_and_trigger_recalibration() {
        assert!(!is_slow(0.03, 0.005, 4.0));
        assert!(is_slow(0.05, 0.005, 4.0));
        let mut strikes = 0;
        for slow in [true, true] {
            strikes = strikes_after(strikes, slow);
        }
        assert_eq!(strikes, 2);
        assert!(!strikes_out(strikes, 3));
        strikes = strikes_after(strikes, true);
        assert!(strikes_out(strikes, 3));
        assert_eq!(strikes_after(strikes, false), 0);
        assert!(cooldown_over(16, 16) && !cooldown_over(15, 16) && cooldown_over(0, 0));
    }

    #[test]
    fn probes_per_range() {
        assert_eq!(range_probes(0, 1000), 0);
        assert_eq!(range_probes(4, 0), 0);
        assert_eq!(range_probes(1, 1000), 1);
        let all = texsyn_engine::lbg::default_seeds(1000) as u32;
        assert_eq!(range_probes(u32::MAX, 1000), all);
    }

    #[test]
    fn rebalance_only_when_off_and_worth_it() {
        let level = LevelProgress {
            remaining_queries: 10_000,
            assign_seconds: 0.01,
        };
        let part = |len, rate: f64| Measured {
            len,
            pairs: rate,
            seconds: 1.0,
        };
        // Equal rates, equal ranges: balanced.
        assert_eq!(rebalance(&[part(500, 1e6), part(500, 1e6)], level), None);
        // One worker twice as fast on an equal range: cut by the measured rates.
        assert_eq!(
            rebalance(&[part(500, 2e6), part(500, 1e6)], level),
            Some(vec![2e6, 1e6])
        );
        // Not worth it near the end of the level.
        let late = LevelProgress {
            remaining_queries: 0,
            ..level
        };
        assert_eq!(rebalance(&[part(500, 2e6), part(500, 1e6)], late), None);
        // Too little measured, or a single worker.
        let short = Measured {
            seconds: 0.01,
            ..part(500, 2e6)
        };
        assert_eq!(rebalance(&[short, part(500, 1e6)], level), None);
        assert_eq!(rebalance(&[part(500, 2e6)], level), None);
    }
}
