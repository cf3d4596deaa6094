//! Repetition control (ARCHITECTURE §3.13): among the near-ties of the exact
//! search, the reference block whose sample pixels were copied least.
//!
//! The search stays exact: the backend returns, of each query's `k` best
//! references sorted by (distance, index), the near-ties, those within `slack`
//! grey levels per known (weighted) component of the best distance; the same
//! lists on every thread and worker count. Of those, the block whose B×B
//! source pixels have the smallest use count wins, then the smaller distance,
//! then the smaller index. Use counts start from the pixels known
//! before the search (the placed sample counts as used once) and grow with
//! every copy, in the batch's copy order, so the choice is deterministic.
//!
//! The patch cap is the other rule: it bounds how much of a level one copy
//! offset (the displacement from sample to canvas) may cover, so that no
//! coherent patch grows past a share of the sample's side. Verbatim repeats
//! of the output are windows that two patches copied from the same sample
//! region both hold whole, so smaller patches repeat less; the cut that ends
//! a patch goes where the near-ties' stitched seams are least.

use texsyn_engine::Hit;

/// What the control does; `None` in the config turns it off.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct RepeatControl {
    /// References asked per query (k ≥ 2).
    pub candidates: usize,
    /// Near-tie slack in grey levels per known weighted component.
    pub slack: u32,
    /// Near-tie slack in percent of the best distance.
    pub percent: u32,
    /// Seam filter (path stitching only): only the near-ties whose stitched
    /// seam error is at most this percent above the exact best's are picked
    /// from.
    pub seam: Option<u32>,
    /// Patch cap: one copy offset covers at most (this percent of the level
    /// sample's shorter side)² pixels of a level; near-ties at the cap rank
    /// after the others, and of those the least stitched seam (path
    /// stitching) or else the nearest wins. Replaces the use counts; applies
    /// on the [`CAP_LEVELS`] finest levels.
    pub cap: Option<u32>,
}

impl Default for RepeatControl {
    fn default() -> Self {
        Self {
            candidates: 8,
            slack: 0,
            percent: 10,
            seam: None,
            cap: None,
        }
    }
}

impl RepeatControl {
    pub fn validate(&self) -> anyhow::Result<()> {
        anyhow::ensure!(
            (2..=64).contains(&self.candidates),
            "--repeat-candidates {} must be in 2..=64",
            self.candidates
        );
        anyhow::ensure!(
            self.slack <= 64,
            "--repeat-slack {} is too large; use 0..=64 grey levels",
            self.slack
        );
        anyhow::ensure!(
            self.percent <= 1000,
            "--repeat-percent {} is too large; use 0..=1000",
            self.percent
        );
        anyhow::ensure!(
            self.seam.is_none_or(|s| s <= 1000),
            "--repeat-seam {} is too large; use 0..=1000",
            self.seam.unwrap_or(0)
        );
        anyhow::ensure!(
            self.cap.is_none_or(|c| (1..=100).contains(&c)),
            "--repeat-cap {} must be in 1..=100 (percent of the sample's shorter side)",
            self.cap.unwrap_or(0)
        );
        anyhow::ensure!(
            self.cap.is_none() || self.seam.is_none(),
            "--repeat-cap and --repeat-seam are two ways to pick among the near-ties; give one"
        );
        anyhow::ensure!(
            self.slack > 0 || self.percent > 0,
            "repetition control needs a slack: --repeat-slack or --repeat-percent above 0"
        );
        Ok(())
    }
}

/// How often each pixel of a level sample has been copied.
pub(super) struct Usage {
    width: usize,
    height: usize,
    count: Vec<u16>,
}

impl Usage {
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            count: vec![0; width * height],
        }
    }

    /// One more copy of sample pixel (x, y).
    #[inline]
    pub fn add(&mut self, x: usize, y: usize) {
        if x < self.width && y < self.height {
            let c = &mut self.count[y * self.width + x];
            *c = c.saturating_add(1);
        }
    }

    /// Copies so far of the B×B block centred at `pos` (pixels outside the
    /// sample count nothing).
    pub fn block(&self, pos: [u32; 2], b: usize) -> u64 {
        let r = (b / 2) as isize;
        let (cx, cy) = (pos[0] as isize, pos[1] as isize);
        let mut sum = 0u64;
        for y in cy - r..=cy + r {
            if y < 0 || y as usize >= self.height {
                continue;
            }
            let row = &self.count[y as usize * self.width..][..self.width];
            for x in cx - r..=cx + r {
                if x >= 0 && (x as usize) < self.width {
                    sum += u64::from(row[x as usize]);
                }
            }
        }
        sum
    }
}

/// Levels, finest first, on which the patch cap cuts patches. Coarser levels
/// take the exact best match: their patches lay out the structure (stones,
/// bricks), and cutting them there merged and broke it; on the two finest
/// levels a cut changes the detail inside an unchanged layout. Against the
/// peer on 22 samples, capping every level gave fidelity and repeat both
/// better on 10, capping the two finest on 13.
pub(super) const CAP_LEVELS: usize = 2;

/// Pixels copied per copy offset on one level, for the patch cap.
pub(super) struct Offsets {
    covered: std::collections::HashMap<[i64; 2], u64>,
    /// Pixels one offset may cover.
    cap: u64,
}

impl Offsets {
    /// The tracker of a level whose sample is `width` × `height`, with the
    /// cap at `percent` of its shorter side (at least one pixel).
    pub fn new(width: usize, height: usize, percent: u32) -> Self {
        let side = (width.min(height) as u64 * u64::from(percent)).div_ceil(100);
        Self {
            covered: Default::default(),
            cap: (side * side).max(1),
        }
    }

    fn offset(canvas: [usize; 2], source: [u32; 2]) -> [i64; 2] {
        [
            canvas[0] as i64 - i64::from(source[0]),
            canvas[1] as i64 - i64::from(source[1]),
        ]
    }

    /// `pixels` more copied from `source` to `canvas` (any matching pair of
    /// points: a block's centres, or one pixel).
    pub fn add(&mut self, canvas: [usize; 2], source: [u32; 2], pixels: u64) {
        *self
            .covered
            .entry(Self::offset(canvas, source))
            .or_default() += pixels;
    }

    /// Whether copying `source` to `canvas` continues an offset at its cap.
    pub fn at_cap(&self, canvas: [usize; 2], source: [u32; 2]) -> bool {
        self.covered
            .get(&Self::offset(canvas, source))
            .is_some_and(|&c| c >= self.cap)
    }
}

/// The patch cap's pick among the near-ties `hits` (sorted by distance, then
/// index): those whose offset is under its cap first (`at_cap`), then the
/// least seam error (`seams[i]` for `hits[i]`, when stitching by path), then
/// the nearer, then the lower index.
pub(super) fn pick_capped(
    hits: &[Hit],
    seams: Option<&[f64]>,
    at_cap: impl Fn(&Hit) -> bool,
) -> Option<Hit> {
    let seam = |i: usize| seams.and_then(|s| s.get(i)).copied().unwrap_or(0.0);
    hits.iter()
        .enumerate()
        .min_by(|&(i, a), &(j, b)| {
            at_cap(a)
                .cmp(&at_cap(b))
                .then(seam(i).total_cmp(&seam(j)))
                .then(a.key().cmp(&b.key()))
        })
        .map(|(_, h)| *h)
}

/// The pick among the near-ties `hits` (sorted by distance, then index): the
/// least-used, then the nearer, then the lower index. `block_use` gives a
/// hit's use count.
pub(super) fn pick(hits: &[Hit], mut block_use: impl FnMut(&Hit) -> u64) -> Option<Hit> {
    hits.iter()
        .map(|h| (block_use(h), h.dist, h.index))
        .min()
        .map(|(_, dist, index)| Hit { index, dist })
}

/// The pick with the seam filter: of the near-ties `hits` (sorted by
/// distance), those whose seam error (`seams[i]` for `hits[i]`) is at most
/// `percent` above the exact best's, then [`pick`] among them. The exact best
/// always qualifies, and a near-tie with a worse seam never does: the bound is
/// the best's seam, not the least seam, which would favour flat references
/// (their seams are the smoothest) and erase thin structure.
pub(super) fn pick_within_seam(
    hits: &[Hit],
    seams: &[f64],
    percent: u32,
    block_use: impl FnMut(&Hit) -> u64,
) -> Option<Hit> {
    let best = seams.first().copied().unwrap_or(f64::INFINITY);
    let bound = best * (1.0 + f64::from(percent) / 100.0);
    let eligible: Vec<Hit> = hits
        .iter()
        .zip(seams)
        .filter(|(_, &e)| e <= bound)
        .map(|(h, _)| *h)
        .collect();
    pick(&eligible, block_use)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn hit(index: u64, dist: u64) -> Hit {
        Hit { index, dist }
    }

    #[test]
    fn the_least_used_near_tie_wins_then_the_nearer() {
        let hits = [hit(5, 100), hit(2, 110), hit(9, 130), hit(1, 130)];
        let used = |h: &Hit| match h.index {
            5 => 25,
            2 => 3,
            _ => 0,
        };
        // 9 and 1 are unused and equally near: the lower index.
        assert_eq!(pick(&hits, used), Some(hit(1, 130)));
        assert_eq!(pick(&hits[..2], used), Some(hit(2, 110)));
        assert_eq!(pick(&hits[..1], used), Some(hit(5, 100)));
        assert_eq!(pick(&[], used), None);
    }

    #[test]
    fn usage_counts_the_block_clipped_at_the_sample() {
        let mut u = Usage::new(6, 4);
        for y in 0..4 {
            for x in 0..6 {
                u.add(x, y);
            }
        }
        u.add(0, 0);
        u.add(9, 9); // outside: ignored
        assert_eq!(u.block([2, 2], 3), 9);
        assert_eq!(u.block([0, 0], 3), 4 + 1);
        assert_eq!(u.block([5, 3], 5), 9);
    }

    #[test]
    fn the_seam_filter_is_bounded_by_the_exact_best_seam() {
        let hits = [hit(5, 100), hit(2, 110), hit(9, 130), hit(1, 140)];
        let seams = [20.0, 10.0, 23.0, 30.0];
        let used = |h: &Hit| match h.index {
            5 => 9,
            2 => 7,
            _ => 0,
        };
        // Within 10% of the best's 20.0: hits 5 and 2 (the better seam
        // qualifies too); 2 is used less.
        assert_eq!(pick_within_seam(&hits, &seams, 10, used), Some(hit(2, 110)));
        // Within 20%: 9 (23.0) too, unused.
        assert_eq!(pick_within_seam(&hits, &seams, 20, used), Some(hit(9, 130)));
        // Within 0%: never a worse seam than the best's, however used.
        let used_all = |h: &Hit| u64::from(h.index != 1 && h.index != 2) * 50;
        assert_eq!(
            pick_within_seam(&hits, &seams, 0, used_all),
            Some(hit(2, 110))
        );
        // The best always qualifies.
        let worse = [20.0, 40.0, 50.0, 60.0];
        assert_eq!(pick_within_seam(&hits, &worse, 10, used), Some(hit(5, 100)));
        assert_eq!(pick_within_seam(&[], &[], 10, used), None);
    }

    #[test]
    fn offsets_reach_their_cap_per_displacement() {
        // 20% of the shorter side 48 is 9.6, rounded up: 10² = 100 pixels.
        let mut o = Offsets::new(64, 48, 20);
        assert_eq!(o.cap, 100);
        o.add([30, 30], [10, 12], 75);
        assert!(!o.at_cap([30, 30], [10, 12]));
        // The same displacement elsewhere is the same patch's offset.
        o.add([50, 41], [30, 23], 25);
        assert!(o.at_cap([35, 35], [15, 17]));
        assert!(!o.at_cap([35, 35], [15, 16]));
        // A tiny sample still caps at one pixel.
        assert_eq!(Offsets::new(3, 3, 1).cap, 1);
    }

    #[test]
    fn the_capped_pick_passes_over_capped_near_ties_then_takes_the_least_seam() {
        let hits = [hit(5, 100), hit(2, 110), hit(9, 130), hit(1, 140)];
        let seams = [0.0, 12.0, 8.0, 30.0];
        let capped = |h: &Hit| h.index == 5;
        // 5 continues a capped patch; of the rest, 9 has the least seam.
        assert_eq!(pick_capped(&hits, Some(&seams), capped), Some(hit(9, 130)));
        // Without seams (hard stitching) the nearest uncapped.
        assert_eq!(pick_capped(&hits, None, capped), Some(hit(2, 110)));
        // Nothing capped: the least seam, the exact best's continuation.
        assert_eq!(
            pick_capped(&hits, Some(&seams), |_| false),
            Some(hit(5, 100))
        );
        // All capped: as if none were.
        assert_eq!(pick_capped(&hits, None, |_| true), Some(hit(5, 100)));
        assert_eq!(pick_capped(&[], None, |_| false), None);
    }

    proptest! {
        /// The capped pick is under its cap whenever some near-tie is, and no
        /// near-tie in the same class has a smaller (seam, distance, index).
        #[test]
        fn capped_pick_is_the_least_seam_of_the_uncapped(
            mut d in prop::collection::vec(0u64..1000, 1..16),
            seams in prop::collection::vec(0.0f64..500.0, 16),
            capped in prop::collection::vec(any::<bool>(), 16),
        ) {
            d.sort_unstable();
            let hits: Vec<Hit> = d.iter().enumerate().map(|(i, &d)| hit(i as u64, d)).collect();
            let seams = &seams[..hits.len()];
            let at_cap = |h: &Hit| capped[h.index as usize];
            let p = pick_capped(&hits, Some(seams), at_cap).unwrap();
            let i = p.index as usize;
            if hits.iter().any(|h| !at_cap(h)) {
                prop_assert!(!at_cap(&p));
            }
            for h in hits.iter().filter(|h| at_cap(h) == at_cap(&p)) {
                let j = h.index as usize;
                prop_assert!(seams[j] > seams[i] || (seams[j] == seams[i] && h.key() >= p.key()));
            }
        }

        /// The seam-filtered pick has a seam within the bound, and no hit
        /// within it is used less, or as little and nearer.
        #[test]
        fn seam_pick_is_the_least_used_within_the_bound(
            mut d in prop::collection::vec(0u64..1000, 1..16),
            seams in prop::collection::vec(0.0f64..500.0, 16),
            uses in prop::collection::vec(0u64..50, 16),
            percent in 0u32..200,
        ) {
            d.sort_unstable();
            let hits: Vec<Hit> = d.iter().enumerate().map(|(i, &d)| hit(i as u64, d)).collect();
            let seams = &seams[..hits.len()];
            let used = |h: &Hit| uses[h.index as usize];
            let p = pick_within_seam(&hits, seams, percent, used).unwrap();
            let bound = seams[0] * (1.0 + f64::from(percent) / 100.0);
            prop_assert!(seams[p.index as usize] <= bound);
            for h in hits.iter().filter(|h| seams[h.index as usize] <= bound) {
                prop_assert!(used(h) > used(&p) || (used(h) == used(&p) && h.key() >= p.key()));
            }
        }


        /// No near-tie is used less than the pick, and none used as little is
        /// nearer.
        #[test]
        fn pick_is_the_least_used_then_nearest(
            mut d in prop::collection::vec(0u64..1000, 1..16),
            uses in prop::collection::vec(0u64..50, 16),
        ) {
            d.sort_unstable();
            let hits: Vec<Hit> = d.iter().enumerate().map(|(i, &d)| hit(i as u64, d)).collect();
            let used = |h: &Hit| uses[h.index as usize];
            let p = pick(&hits, used).unwrap();
            for h in &hits {
                prop_assert!(used(h) > used(&p) || (used(h) == used(&p) && h.key() >= p.key()));
            }
        }
    }
}
