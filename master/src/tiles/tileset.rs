//! Patched tile sets (Somol–Haindl §3): the template and tiles derived
//! from it, each with sample patches inserted over all but its first column
//! and row.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::config::PULL_MAX;
use super::patch::{insert_patch, paste_patch, patch_cuts, report, PatchReport};
use super::stitch::{Blend, StitchSettings};
use super::template::{choose_template, choose_templates, make_template, Rect, TemplateChoice};
use crate::imaging::ColorImage;
use crate::progress::Progress;
use crate::seams::Oscillating;

/// Settings of a tile set.
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
pub struct TileSetSettings {
    /// Number of tiles, the template included.
    pub tiles: usize,
    /// Least and greatest template side.
    pub min_size: usize,
    pub max_size: usize,
    /// Template overlap `w_T` and patch belt `w_P`.
    pub overlap: usize,
    pub belt: usize,
    /// Border strip of every tile that patches never touch (0: only the
    /// first column and row, see [`make_tile_set`]).
    pub margin: usize,
    /// Least pull of the patch paths towards the tile's edge, per pixel of
    /// the belt ([`StitchSettings::pull`]; 0 = the paper's search).
    #[serde(default)]
    pub pull: f32,
    /// Mean share of equal pixels between two tiles of the set (what
    /// `texsyn compare` reports as `tile_overlap`) that the pulls keep to:
    /// each tile's pull is doubled (up to [`PULL_MAX`]) while the mean over
    /// the pairs so far is over it (1 = no limit).
    #[serde(default = "no_limit")]
    pub max_overlap: f64,
    /// Template placements whose stitches are made and compared
    /// ([`choose_template`]'s best few by border error; 1 = the paper's).
    #[serde(default = "one")]
    pub template_candidates: usize,
    /// Weight of the template ring's atypicality in the template choice
    /// ([`RingStats::atypicality`]; 0 = border error alone, as before).
    #[serde(default)]
    pub ring_weight: f64,
    /// Random candidate patch positions tried per tile.
    pub candidates: usize,
    /// Half-width of the local refinement of the best candidate (the paper's
    /// neighbourhood n).
    pub refine: usize,
    /// How every stitch finds its path.
    pub path: PathSearch,
    /// How the patch stitches blend along their paths (the template's keep
    /// the paper's; a file without it was blended by error,
    /// [`Blend::recorded_default`]).
    #[serde(default = "Blend::recorded_default")]
    pub blend: Blend,
    pub seed: u64,
}

/// The path search of every stitch of a tile set (§2.1).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum PathSearch {
    /// The oscillating search from the seam start (within 1.15× of the
    /// optimum on the test maps, and much faster at wide belts).
    #[default]
    Oscillating,
    /// The exact path by dynamic programming, `O(h·w³)`.
    Optimal,
}

fn one() -> usize {
    1
}

fn no_limit() -> f64 {
    1.0
}

/// The pulls a tile's patch paths try, weakest first: `least`, then twice
/// it up to [`PULL_MAX`] (from 1 when `least` is 0).
fn pull_ladder(least: f32) -> impl Iterator<Item = f32> {
    std::iter::successors(Some(least), |&p| {
        let next = if p > 0.0 { 2.0 * p } else { 1.0 };
        (p < PULL_MAX).then_some(next.min(PULL_MAX))
    })
}

/// The share of `tile`'s pixels equal to `other`'s at the same place; of a
/// derived tile against the template, its template share (the first column
/// and row that every tile keeps included).
pub fn equal_share(tile: &ColorImage, other: &ColorImage) -> f64 {
    let (w, h) = (tile.width, tile.height);
    let kept = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .filter(|&(x, y)| tile.get(x, y) == other.get(x, y))
        .count();
    kept as f64 / (w * h).max(1) as f64
}

impl PathSearch {
    fn stitch_settings(self, pull: f32, blend: Blend) -> StitchSettings {
        StitchSettings {
            search: match self {
                Self::Oscillating => Some(Oscillating::default()),
                Self::Optimal => None,
            },
            pull,
            blend,
            ..StitchSettings::default()
        }
    }
}

/// One derived tile's patch and how it was chosen.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct DerivedTile {
    pub patch: PatchReport,
    /// Which of the tile's edges the patch reaches over, into the next
    /// tile's first column or row ([`make_tile_set`]).
    #[serde(default)]
    pub wrap: Wrap,
    /// The pull its paths took ([`pull_ladder`]) and the share of it that
    /// stayed the template's ([`equal_share`]).
    #[serde(default)]
    pub pull: f32,
    #[serde(default)]
    pub template_share: f64,
    /// The extra patches inside the main one (large tiles).
    #[serde(default)]
    pub extra: Vec<PatchReport>,
    /// The mean path error of the random candidates of this tile (what a
    /// random choice would have given, on average; once no place is free,
    /// of the random places on the least share rung that were scored).
    pub random_mean_path_error: f64,
    pub seconds: f64,
}

/// The edges a derived tile's patch reaches over: the right one (into the
/// next tile's first column), the bottom one (its first row), both, or
/// neither (the patch lies inside the tile's own edges).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Wrap {
    Both,
    Right,
    Bottom,
    #[default]
    Inside,
}

impl Wrap {
    /// The patch rectangle of a `tw`×`th` tile that wraps so, given the one
    /// that wraps both edges (one pixel wider and taller than the tile).
    fn target(self, both: Rect, tw: usize, th: usize) -> Rect {
        match self {
            Self::Both => both,
            Self::Right => Rect { height: th, ..both },
            Self::Bottom => Rect { width: tw, ..both },
            Self::Inside => Rect {
                width: tw,
                height: th,
                ..both
            },
        }
    }
}

/// One rung of a tile's pull ladder: where its patch wraps, the choice, the
/// tile (on the canvas) with the patch in, the pull, the template share and
/// the equal-pixel shares with the tiles before it, summed.
struct Rung {
    kind: Wrap,
    chosen: Chosen,
    tile: ColorImage,
    patch: PatchReport,
    pull: f32,
    share: f64,
    shared: f64,
}

/// A tile set: the template and the tiles derived from it.
#[derive(Clone, Debug)]
pub struct TileSet {
    pub tiles: Vec<ColorImage>,
    pub template: TemplateChoice,
    pub template_path_costs: [f64; 2],
    pub template_seconds: f64,
    pub derived: Vec<DerivedTile>,
}

/// Mean error per pixel of a template's two stitch paths.
fn mean_template_error(cuts: &[super::stitch::Cut; 2]) -> f64 {
    let pixels: usize = cuts.iter().map(|c| c.path.pixels().count()).sum();
    cuts.iter().map(|c| c.cost).sum::<f64>() / pixels.max(1) as f64
}

/// How a tile's wrap-around joints compare with its own interior: the mean
/// luminance step across its right|left and bottom|top joints over the
/// median step between its other columns and rows (about 1 when the joints
/// do not show).
pub fn wrap_ratio(tile: &ColorImage) -> f64 {
    let g = crate::imaging::colour::luminance(tile);
    let (w, h) = (g.width, g.height);
    let col = |a: usize, b: usize| {
        (0..h)
            .map(|y| f64::from(g.get(a, y).abs_diff(g.get(b, y))))
            .sum::<f64>()
            / h as f64
    };
    let row = |a: usize, b: usize| {
        (0..w)
            .map(|x| f64::from(g.get(x, a).abs_diff(g.get(x, b))))
            .sum::<f64>()
            / w as f64
    };
    let mut inner: Vec<f64> = (1..w).map(|x| col(x - 1, x)).collect();
    inner.extend((1..h).map(|y| row(y - 1, y)));
    inner.sort_by(f64::total_cmp);
    let median = inner.get(inner.len() / 2).copied().unwrap_or(0.0);
    let joint = (col(w - 1, 0) + row(h - 1, 0)) / 2.0;
    if median > 0.0 {
        joint / median
    } else if joint > 0.0 {
        f64::INFINITY
    } else {
        1.0
    }
}

/// Luminance statistics of an image's border ring (the pixels within
/// `width` of an edge; all of it with `None`): mean, standard deviation and
/// mean step between neighbours.
struct RingStats {
    mean: f64,
    deviation: f64,
    step: f64,
}

impl RingStats {
    fn of(img: &ColorImage, width: Option<usize>) -> Self {
        let g = crate::imaging::colour::luminance(img);
        let (w, h) = (g.width, g.height);
        let in_ring =
            |x: usize, y: usize| width.is_none_or(|r| x < r || y < r || x + r >= w || y + r >= h);
        let (mut n, mut sum, mut sq, mut steps, mut m) = (0.0f64, 0.0, 0.0, 0.0, 0.0f64);
        for y in 0..h {
            for x in 0..w {
                if !in_ring(x, y) {
                    continue;
                }
                let v = f64::from(g.get(x, y));
                n += 1.0;
                sum += v;
                sq += v * v;
                // Steps to the right and below; a ring's cross its
                // wrap-around joint too, since it is what meets the
                // neighbouring tiles (a whole sample does not wrap).
                for (nx, ny) in [(x + 1, y), (x, y + 1)] {
                    let (nx, ny) = match width {
                        Some(_) => (nx % w, ny % h),
                        None if nx < w && ny < h => (nx, ny),
                        None => continue,
                    };
                    steps += (v - f64::from(g.get(nx, ny))).abs();
                    m += 1.0;
                }
            }
        }
        let mean = sum / n.max(1.0);
        Self {
            mean,
            deviation: (sq / n.max(1.0) - mean * mean).max(0.0).sqrt(),
            step: steps / m.max(1.0),
        }
    }

    /// How far this ring is from the `typical` statistics of the sample:
    /// the offset of its mean in the sample's standard deviations plus the
    /// relative shortfall or excess of its contrast and detail. Every tile
    /// of the set keeps the template's ring, so a ring paler, flatter or
    /// busier than the sample draws the grid that the tiles are laid on.
    fn atypicality(&self, typical: &Self) -> f64 {
        let rel = |a: f64, b: f64| (a - b).abs() / b.max(1.0);
        2.0 * (self.mean - typical.mean).abs() / typical.deviation.max(1.0)
            + 0.5 * rel(self.deviation, typical.deviation)
            + 0.5 * rel(self.step, typical.step)
    }
}

/// A stitched template candidate: its rank (joints that show, then their
/// ratio or the path error), the tile, its placement and path costs.
type Made = ((bool, f64), ColorImage, TemplateChoice, [f64; 2]);

/// The template tile: `given` as it is, or chosen and stitched (§3.1). With
/// `template_candidates` above 1, the best few placements at the overlap
/// `w_T`, at twice it and, where the belt is wider still, at twice the belt
/// (room for the path to pass round the texture's objects) are all stitched; among those whose joints step no more than
/// their interior ([`wrap_ratio`] ≤ 1) the one whose paths have the least
/// mean error, scaled by `1 + ring_weight · atypicality` of its border ring
/// (the lines along its joints, which every derived tile keeps), is kept,
/// or else the one whose joints show least.
fn template_tile(
    sample: &ColorImage,
    given: Option<&ColorImage>,
    s: &TileSetSettings,
    stitch_settings: &StitchSettings,
) -> anyhow::Result<(ColorImage, TemplateChoice, [f64; 2])> {
    if let Some(t) = given {
        return Ok((
            t.clone(),
            TemplateChoice {
                rect: Rect {
                    x: 0,
                    y: 0,
                    width: t.width,
                    height: t.height,
                },
                horizontal_error: 0.0,
                vertical_error: 0.0,
                overlap: 0,
            },
            [0.0; 2],
        ));
    }
    if s.template_candidates <= 1 {
        let choice = choose_template(sample, s.min_size, s.max_size, s.overlap)?;
        let (t, cuts) = make_template(sample, &choice, s.overlap, stitch_settings);
        return Ok((t, choice, [cuts[0].cost, cuts[1].cost]));
    }
    let fits = |w: usize| 2 * w < s.min_size && s.min_size + w <= sample.width.min(sample.height);
    let mut overlaps = vec![s.overlap];
    let wide = 2 * s.overlap;
    if fits(wide) {
        overlaps.push(wide);
    }
    // A belt wider than the wide band was widened to hold the sample's
    // objects (`config::default_belt`): the template's joints, which every
    // tile repeats, get a band twice the belt too, or they slice those
    // objects where the patches' paths go round them.
    let objects = 2 * s.belt;
    if s.belt > wide && fits(objects) {
        overlaps.push(objects);
    }
    let mut choices = Vec::new();
    for &w in &overlaps {
        let k = s.template_candidates;
        choices.extend(choose_templates(
            sample,
            s.min_size,
            s.max_size,
            w,
            k,
            k.min(2),
        )?);
    }
    let typical = RingStats::of(sample, None);
    let made: Vec<Made> = choices
        .par_iter()
        .map(|c| {
            let (t, cuts) = make_template(sample, c, c.overlap, stitch_settings);
            let ratio = wrap_ratio(&t);
            let ring = RingStats::of(&t, Some(crate::compare::JOINT_LINE));
            let key = if ratio <= 1.0 {
                (
                    false,
                    mean_template_error(&cuts) * (1.0 + s.ring_weight * ring.atypicality(&typical)),
                )
            } else {
                (true, ratio)
            };
            (key, t, *c, [cuts[0].cost, cuts[1].cost])
        })
        .collect();
    let best = made
        .into_iter()
        .min_by(|a, b| a.0 .0.cmp(&b.0 .0).then(a.0 .1.total_cmp(&b.0 .1)))
        .expect("at least one template placement");
    Ok((best.1, best.2, best.3))
}

/// The shares (numerator, denominator) of the smaller of two rectangles
/// that a patch may have in common with the template's source or an earlier
/// patch, loosest last: a patch takes the least rung some candidate reaches,
/// and one on a rectangle already taken comes after all of them.
const SHARE_RUNGS: [(usize, usize); 7] = [(1, 4), (3, 8), (1, 2), (5, 8), (3, 4), (7, 8), (63, 64)];

/// How many times the seeded candidates are drawn, to find places on the
/// least share rung, once none of them is free.
const WIDER_DRAW: usize = 16;

/// A scored candidate: ((its wrap joints show, mean path error), x, y).
type Scored = ((bool, f64), usize, usize);

/// A candidate patch place with its cuts, before its joints are checked.
struct Candidate {
    error: f64,
    x: usize,
    y: usize,
    belts: [super::stitch::Belt; 4],
    cuts: Vec<super::stitch::Cut>,
}

/// The least of `candidates` by [`by_score`] (joints that hold first, then
/// the path error, then the place; `place` gives a candidate's error and
/// place), checking joints (`shows`) in order of error, a thread's worth at
/// a time, only until one holds: the same choice as scoring every
/// candidate, with most joint checks left out.
fn least_scored<C: Sync>(
    mut candidates: Vec<C>,
    place: impl Fn(&C) -> (f64, usize, usize),
    shows: impl Fn(&C) -> bool + Sync,
) -> Option<Scored> {
    candidates.sort_by(|a, b| {
        let (a, b) = (place(a), place(b));
        a.0.total_cmp(&b.0).then((a.1, a.2).cmp(&(b.1, b.2)))
    });
    let step = rayon::current_num_threads().max(1);
    for chunk in candidates.chunks(step) {
        let showing: Vec<bool> = chunk.par_iter().map(&shows).collect();
        if let Some(k) = showing.iter().position(|&s| !s) {
            let (error, x, y) = place(&chunk[k]);
            return Some(((false, error), x, y));
        }
    }
    candidates.first().map(|c| {
        let (error, x, y) = place(c);
        ((true, error), x, y)
    })
}

fn by_score(a: &Scored, b: &Scored) -> std::cmp::Ordering {
    (a.0 .0.cmp(&b.0 .0))
        .then(a.0 .1.total_cmp(&b.0 .1))
        .then((a.1, a.2).cmp(&(b.1, b.2)))
}

/// How a tile's patch is cut: the stitch settings, and where joints are
/// checked, the [`wrap_ratio`] the tile may reach and the tile's size (its
/// pixels are the canvas's top-left `tw`×`th`).
#[derive(Clone, Copy)]
struct Cutting<'a> {
    stitch: &'a StitchSettings,
    joints: Option<(f64, (usize, usize))>,
}

/// Where tile `k`'s patch comes from: the best of the seeded random
/// candidates that overlap no `taken` rectangle by more than the least
/// [`SHARE_RUNGS`] share any candidate reaches (a quarter while the sample
/// has room), refined pixel by pixel on its `±refine` neighbourhood; and the
/// candidates' mean path error. With a joint bound, each candidate is also
/// inserted, and those whose tile's wrap joints step more than the bound
/// rank after all whose joints hold, so a wrapping patch reaches the tile's
/// edges wherever some candidate can. The second value says whether the
/// chosen one's joints hold.
fn choose_patch(
    tile: &ColorImage,
    sample: &ColorImage,
    target: Rect,
    taken: &[Rect],
    k: usize,
    s: &TileSetSettings,
    cutting: Cutting,
) -> Chosen {
    let mut rng =
        ChaCha8Rng::seed_from_u64(s.seed ^ (k as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
    // A candidate's cuts and mean path error; whether its joints show is
    // found only as the choice needs it ([`least_scored`]), since pasting
    // the patch for the joint check costs more than the cuts.
    let cut = |&(x, y): &(usize, usize)| -> Candidate {
        let source = Rect { x, y, ..target };
        let (belts, cuts) = patch_cuts(tile, sample, source, target, s.belt, cutting.stitch);
        let error = report(source, target, &cuts).mean_path_error;
        Candidate {
            error,
            x,
            y,
            belts,
            cuts,
        }
    };
    let shows = |c: &Candidate| {
        cutting.joints.is_some_and(|(bound, (tw, th))| {
            let mut t = tile.clone();
            let source = Rect {
                x: c.x,
                y: c.y,
                ..target
            };
            let cut = (&c.belts, &c.cuts[..]);
            paste_patch(&mut t, sample, (source, target), cut, cutting.stitch);
            wrap_ratio(&t.crop(0, 0, tw, th)) > bound
        })
    };
    let (xs, ys) = (sample.width - target.width, sample.height - target.height);
    // The least rung of [`SHARE_RUNGS`] some candidate reaches: a patch
    // shares at most that much of the smaller of it and any taken rectangle
    // (a source a few pixels from another would make a shifted copy of its
    // tile, whose joints hold as well as the original's). Among the
    // candidates on that rung, the best by joints and path error.
    let rung_of = |x: usize, y: usize| {
        let r = Rect { x, y, ..target };
        let share_rung = |o: &Rect| {
            // The same place: taken, whatever the sizes (a patch that wraps
            // one edge is a pixel wider or taller than one that wraps the
            // other, and shares a little less than all of it).
            if (o.x, o.y) == (r.x, r.y) {
                return SHARE_RUNGS.len();
            }
            let (common, smaller) = (
                r.intersection_area(o),
                (r.width * r.height).min(o.width * o.height),
            );
            SHARE_RUNGS
                .iter()
                .position(|&(n, d)| common * d <= smaller * n)
                .unwrap_or(SHARE_RUNGS.len())
        };
        taken.iter().map(share_rung).max().unwrap_or(0)
    };
    let n = s.candidates.max(1);
    let mut draw = |count: usize| -> Vec<(usize, usize)> {
        (0..count)
            .map(|_| (rng.random_range(0..=xs), rng.random_range(0..=ys)))
            .collect()
    };
    let mut positions = draw(n);
    let least = |p: &[(usize, usize)]| p.iter().map(|&(x, y)| rung_of(x, y)).min();
    let mut rung = least(&positions).unwrap_or(0);
    if rung > 0 {
        // No free place among them: a draw [`WIDER_DRAW`] times as large,
        // whose places on its least rung (cheap to find) are the ones
        // scored, so the sample's remaining room is found, not missed.
        positions.extend(draw(n * (WIDER_DRAW - 1)));
        rung = least(&positions).unwrap_or(0);
        positions.retain(|&(x, y)| rung_of(x, y) == rung);
        positions.truncate(n);
    }
    let cut_all = |p: &[(usize, usize)]| -> Vec<Candidate> { p.par_iter().map(cut).collect() };
    let candidates = cut_all(&positions);
    let random_mean =
        candidates.iter().map(|c| c.error).sum::<f64>() / candidates.len().max(1) as f64;
    let on_rung: Vec<Candidate> = candidates
        .into_iter()
        .filter(|c| rung_of(c.x, c.y) <= rung)
        .collect();
    let place = |c: &Candidate| (c.error, c.x, c.y);
    let pick = least_scored(on_rung, place, shows).unwrap_or(((true, f64::INFINITY), 0, 0));
    // Local refinement on the ±refine neighbourhood, pixel by pixel (so
    // periodic structure can line up with the template's), on the same rung.
    let (x0, y0) = (pick.1, pick.2);
    let r = s.refine;
    let near: Vec<(usize, usize)> = (x0.saturating_sub(r)..=(x0 + r).min(xs))
        .flat_map(|x| (y0.saturating_sub(r)..=(y0 + r).min(ys)).map(move |y| (x, y)))
        .filter(|&(x, y)| rung_of(x, y) <= rung || (x, y) == (x0, y0))
        .collect();
    let best = least_scored(cut_all(&near), place, shows)
        .into_iter()
        .chain(std::iter::once(pick))
        .min_by(by_score)
        .unwrap_or(pick);
    Chosen {
        source: Rect {
            x: best.1,
            y: best.2,
            ..target
        },
        holds: !best.0 .0,
        error: best.0 .1,
        random_mean,
    }
}

/// A tile's chosen patch: its source rectangle, whether the tile's wrap
/// joints hold with it, its mean path error and the random candidates'.
#[derive(Clone, Copy)]
struct Chosen {
    source: Rect,
    holds: bool,
    error: f64,
    random_mean: f64,
}

/// The rectangles of the extra patches of a `tw`×`th` tile: none below
/// [`EXTRA_FROM`] pixels or where a half-size patch is narrower than
/// [`EXTRA_BELTS`] belts; else half-size patches centred on the cells of a
/// `n`×`n` grid (`n` = side / [`EXTRA_FROM`]), shifted by up to a quarter of
/// a cell (seeded) and kept inside the belts of the tile's own patch.
fn extra_targets(tw: usize, th: usize, s: &TileSetSettings, k: usize) -> Vec<Rect> {
    let side = tw.min(th);
    if side < EXTRA_FROM {
        return Vec::new();
    }
    let n = side / EXTRA_FROM;
    let p = side / 2;
    let (lo, hi_x, hi_y) = (
        s.margin + s.belt,
        tw.saturating_sub(s.margin + s.belt + p),
        th.saturating_sub(s.margin + s.belt + p),
    );
    if hi_x < lo || hi_y < lo || p < EXTRA_BELTS * s.belt {
        return Vec::new();
    }
    let mut rng =
        ChaCha8Rng::seed_from_u64(s.seed ^ 0x5EED ^ (k as u64).wrapping_mul(0xD1B5_4A32_D192_ED03));
    let place = |rng: &mut ChaCha8Rng, cell: usize, len: usize, hi: usize| {
        let c = (2 * cell + 1) * len / (2 * n);
        let j = (len / n / 4) as i64;
        let c = c as i64 + rng.random_range(-j..=j) - (p / 2) as i64;
        (c.max(lo as i64) as usize).min(hi)
    };
    (0..n * n)
        .map(|c| {
            let x = place(&mut rng, c % n, tw, hi_x);
            let y = place(&mut rng, c / n, th, hi_y);
            Rect {
                x,
                y,
                width: p,
                height: p,
            }
        })
        .collect()
}

/// Tiles at least this large (their smaller side) get extra patches inside
/// their main one, one per this many pixels of side, squared.
pub const EXTRA_FROM: usize = 128;

/// An extra patch is at least this many belts wide, so that inside its two
/// side belts it keeps an interior as wide as a belt. The belt is three
/// correlation lengths of the sample, about one object: a patch narrower
/// than this is all paths and shards of cut objects (on the 512² beans at
/// 128-px tiles, 64-px patches in 25-px belts set half beans over others).
pub const EXTRA_BELTS: usize = 3;

/// Makes a tile set from `sample` (§3): the template of [`choose_template`]
/// (or `template` as given), then `tiles - 1` tiles, each the template with
/// a patch from another place of the sample inserted inside its margin, so
/// every tile keeps the template's borders and connects to every other.
///
/// Patch positions are chosen, not drawn (the paper picks by hand): for each
/// tile, `candidates` random source positions (seeded) are scored by the mean
/// error along their four side paths; positions whose rectangle overlaps the
/// template's source or an earlier patch by more than a quarter are passed
/// over (so the tiles differ), or where the sample has no such room left,
/// all but those overlapping least ([`SHARE_RUNGS`]); the best is refined pixel by pixel on the
/// `±refine` neighbourhood, as the paper does. With no `margin`, the patch
/// covers the template continued by its first column and row
/// ([`ColorImage::wrap_padded`] by one): every tile keeps only that
/// column and row, which
/// its right and bottom neighbours see. A tile whose wrap joints
/// ([`wrap_ratio`]) step more than the template's, or its interior's
/// median, wraps one edge only ([`Wrap`]), or else takes the patch inside
/// its own edges. The paths are pulled towards the edge by the weakest pull
/// of [`pull_ladder`] that keeps the mean share of equal pixels over the
/// set's pairs of tiles so far within `max_overlap`, so the tile's own
/// content covers most of it (§4: "the patching process must affect most
/// of the tile image surface") while the paths
/// still bend round the texture's objects where the budget leaves room.
/// Large tiles then take half-size patches from yet other places inside
/// ([`extra_targets`]).
pub fn make_tile_set(
    sample: &ColorImage,
    template: Option<&ColorImage>,
    s: &TileSetSettings,
    progress: &dyn Progress,
) -> anyhow::Result<TileSet> {
    // The template's stitches are free in their bands (no pull), and keep
    // the paper's blend: feathered, they blur the objects their paths pass
    // round. The blend choice is the patches'.
    let template_stitch = s.path.stitch_settings(0.0, Blend::Error);
    let stitch_settings = s.path.stitch_settings(s.pull, s.blend);
    progress.start("tiles", s.tiles as u64, "tiles");
    let t0 = std::time::Instant::now();
    let (tile0, choice, costs) = template_tile(sample, template, s, &template_stitch)?;
    let template_seconds = t0.elapsed().as_secs_f64();
    progress.set_done(1);
    let (tw, th) = (tile0.width, tile0.height);
    anyhow::ensure!(
        tw > 2 * (s.margin + s.belt) && th > 2 * (s.margin + s.belt),
        "the tile ({tw}x{th}) is too small for a {}-pixel margin and a {}-pixel patch belt on each side",
        s.margin,
        s.belt
    );
    // With no margin, patches go into the template continued by its own
    // first column and row, and reach into that continuation.
    let wrap = s.margin == 0;
    let canvas = if wrap {
        tile0.wrap_padded(1)
    } else {
        tile0.clone()
    };
    let (cw, ch) = (canvas.width, canvas.height);
    let target = Rect {
        x: s.margin,
        y: s.margin,
        width: cw - 2 * s.margin,
        height: ch - 2 * s.margin,
    };
    let joint_bound = wrap_ratio(&tile0).max(1.0);
    anyhow::ensure!(
        sample.width >= target.width && sample.height >= target.height,
        "the sample ({}x{}) is smaller than a patch ({}x{})",
        sample.width,
        sample.height,
        target.width,
        target.height
    );
    let mut taken: Vec<Rect> = if template.is_none() {
        vec![choice.rect]
    } else {
        Vec::new()
    };
    let mut tiles = vec![tile0.clone()];
    let mut derived = Vec::new();
    // Equal-pixel shares summed over the pairs of tiles made so far.
    let (mut spent, mut pairs) = (0.0, 0usize);
    for k in 1..s.tiles {
        let t = std::time::Instant::now();
        // One rung of the pull ladder: the patch chosen and inserted with
        // its paths pulled so. It wraps both edges where its joints hold;
        // else the one edge whose joints hold with the lesser path error;
        // else it lies inside the tile's own edges. With a margin it lies
        // inside that.
        let rung = |pull: f32| {
            let settings = s.path.stitch_settings(pull, s.blend);
            let cutting = Cutting {
                stitch: &settings,
                joints: Some((joint_bound, (tw, th))),
            };
            let choose = |kind: Wrap| {
                let at = if wrap {
                    kind.target(target, tw, th)
                } else {
                    target
                };
                let chosen = choose_patch(&canvas, sample, at, &taken, k, s, cutting);
                (kind, at, chosen)
            };
            let (kind, at, chosen) = if !wrap {
                choose(Wrap::Inside)
            } else {
                Some(choose(Wrap::Both))
                    .filter(|c| c.2.holds)
                    .or_else(|| {
                        [choose(Wrap::Right), choose(Wrap::Bottom)]
                            .into_iter()
                            .filter(|c| c.2.holds)
                            .min_by(|a, b| a.2.error.total_cmp(&b.2.error))
                    })
                    .unwrap_or_else(|| choose(Wrap::Inside))
            };
            let mut tile = canvas.clone();
            let patch = insert_patch(&mut tile, sample, chosen.source, at, s.belt, &settings);
            let own = tile.crop(0, 0, tw, th);
            // Against every tile so far; the first is the template.
            let shares: Vec<f64> = tiles.iter().map(|t| equal_share(&own, t)).collect();
            let (share, shared) = (shares[0], shares.iter().sum());
            Rung {
                kind,
                chosen,
                tile,
                patch,
                pull,
                share,
                shared,
            }
        };
        // The weakest pull that keeps the mean share of equal pixels over
        // the pairs so far within the budget, or else the rung that shares
        // least with the tiles before it.
        let allowed = s.max_overlap * (pairs + k) as f64 - spent;
        let mut best: Option<Rung> = None;
        for pull in pull_ladder(s.pull) {
            let r = rung(pull);
            let within = r.shared <= allowed;
            if best.as_ref().is_none_or(|b| r.shared < b.shared) {
                best = Some(r);
            }
            if within {
                break;
            }
        }
        let Rung {
            kind,
            chosen,
            mut tile,
            patch,
            pull,
            share,
            shared,
        } = best.expect("the ladder has a first rung");
        spent += shared;
        pairs += k;
        let Chosen {
            source,
            random_mean,
            ..
        } = chosen;
        taken.push(source);
        let mut extra = Vec::new();
        for (e, inner) in extra_targets(tw, th, s, k).into_iter().enumerate() {
            let key = k + (e + 1) * 1000;
            let cutting = Cutting {
                stitch: &stitch_settings,
                joints: None,
            };
            let source = choose_patch(&tile, sample, inner, &taken, key, s, cutting).source;
            extra.push(insert_patch(
                &mut tile,
                sample,
                source,
                inner,
                s.belt,
                &stitch_settings,
            ));
            taken.push(source);
        }
        tiles.push(tile.crop(0, 0, tw, th));
        derived.push(DerivedTile {
            patch,
            wrap: kind,
            pull,
            template_share: share,
            extra,
            random_mean_path_error: random_mean,
            seconds: t.elapsed().as_secs_f64(),
        });
        tracing::info!(tile = k + 1, "tile done");
        progress.set_done(k as u64 + 1);
    }
    progress.finish();
    Ok(TileSet {
        tiles,
        template: choice,
        template_path_costs: costs,
        template_seconds,
        derived,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn extra_patches_keep_an_interior_a_belt_wide_and_stay_inside_the_belts() {
        // A 128-px tile takes one half-size patch (64 px) while its belt is
        // at most a third of it; a wider belt (the 512² beans' 25 px) would
        // leave an interior of 14 px, all paths and shards: none. A 256-px
        // tile takes four 128-px patches up to a 42-px belt.
        let sample = ColorImage::new(512, 512);
        for (tile, belt, want) in [
            (127, 8, 0),
            (128, 12, 1),
            (128, 21, 1),
            (128, 22, 0),
            (128, 25, 0),
            (256, 25, 4),
            (256, 42, 4),
            (256, 43, 0),
        ] {
            let s = crate::tiles::SomolConfig {
                tile_size: Some(tile),
                belt: Some(belt),
                ..Default::default()
            }
            .settings(&sample, None)
            .unwrap();
            for k in 1..4 {
                let got = extra_targets(tile, tile, &s, k);
                assert_eq!(got.len(), want, "tile {tile}, belt {belt}, tile {k}");
                for r in got {
                    assert!(r.width >= EXTRA_BELTS * belt && r.width - 2 * belt >= belt);
                    assert!(r.x >= belt && r.y >= belt, "{r:?} in the main patch's belt");
                    assert!(r.x + r.width <= tile - belt && r.y + r.height <= tile - belt);
                }
            }
        }
    }

    #[test]
    fn lazy_joint_checks_choose_what_checking_every_candidate_chooses() {
        // Random errors (with ties), places and joint verdicts, on pools
        // where none, some or all joints hold: the lazy choice must be the
        // least of all fully scored candidates, and check fewer joints.
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let mut saved = 0;
        for round in 0..300 {
            let len = rng.random_range(1..40usize);
            let holds_share = [0.0, 0.1, 0.5, 1.0][round % 4];
            let pool: Vec<(f64, usize, usize, bool)> = (0..len)
                .map(|_| {
                    (
                        f64::from(rng.random_range(0..12u8)) * 0.5,
                        rng.random_range(0..50usize),
                        rng.random_range(0..50usize),
                        !rng.random_bool(holds_share),
                    )
                })
                .collect();
            let full = pool
                .iter()
                .map(|&(e, x, y, shows)| ((shows, e), x, y))
                .min_by(by_score);
            let checked = std::sync::atomic::AtomicUsize::new(0);
            let lazy = least_scored(
                pool.clone(),
                |c| (c.0, c.1, c.2),
                |c| {
                    checked.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    c.3
                },
            );
            assert_eq!(lazy, full, "round {round}: {pool:?}");
            saved += len - checked.into_inner();
        }
        assert!(saved > 0, "no joint check was left out");
    }

    #[test]
    fn the_pull_ladder_doubles_from_the_least_pull_to_the_largest() {
        let from4: Vec<f32> = pull_ladder(4.0).collect();
        assert_eq!(from4.first(), Some(&4.0));
        assert_eq!(from4.last(), Some(&PULL_MAX));
        assert!(from4.windows(2).all(|p| p[1] > p[0] && p[1] <= 2.0 * p[0]));
        let from0: Vec<f32> = pull_ladder(0.0).take(3).collect();
        assert_eq!(from0, [0.0, 1.0, 2.0]);
        assert_eq!(pull_ladder(PULL_MAX).collect::<Vec<_>>(), [PULL_MAX]);
    }

    #[test]
    fn equal_share_counts_the_pixels_equal_to_the_other_image_s() {
        let mut t = ColorImage::new(4, 5);
        let template = t.clone();
        assert_eq!(equal_share(&t, &template), 1.0);
        for x in 1..4 {
            for y in 1..5 {
                t.set(x, y, [9, 9, 9]);
            }
        }
        // Only the first column and row (4 + 5 - 1 = 8 of 20) stay.
        assert!((equal_share(&t, &template) - 8.0 / 20.0).abs() < 1e-12);
    }
}
