//! Patched tile sets (Somol–Haindl §3): the template and tiles derived
//! from it, each with one sample patch inserted inside its margin.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::patch::{insert_patch, patch_cuts, report, PatchReport};
use super::stitch::StitchSettings;
use super::template::{choose_template, make_template, Rect, TemplateChoice};
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
    /// Border strip of every tile that patches never touch.
    pub margin: usize,
    /// Random candidate patch positions tried per tile.
    pub candidates: usize,
    /// Half-width of the local refinement of the best candidate (the paper's
    /// neighbourhood n).
    pub refine: usize,
    /// How every stitch finds its path.
    pub path: PathSearch,
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

impl PathSearch {
    fn stitch_settings(self) -> StitchSettings {
        StitchSettings {
            search: match self {
                Self::Oscillating => Some(Oscillating::default()),
                Self::Optimal => None,
            },
            ..StitchSettings::default()
        }
    }
}

/// One derived tile's patch and how it was chosen.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct DerivedTile {
    pub patch: PatchReport,
    /// The mean path error of the random candidates of this tile (what a
    /// random choice would have given, on average).
    pub random_mean_path_error: f64,
    pub seconds: f64,
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

/// The template tile: `given` as it is, or chosen and stitched (§3.1).
fn template_tile(
    sample: &ColorImage,
    given: Option<&ColorImage>,
    s: &TileSetSettings,
    stitch_settings: &StitchSettings,
) -> anyhow::Result<(ColorImage, TemplateChoice, [f64; 2])> {
    Ok(match given {
        Some(t) => (
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
            },
            [0.0; 2],
        ),
        None => {
            let choice = choose_template(sample, s.min_size, s.max_size, s.overlap)?;
            let (t, cuts) = make_template(sample, &choice, s.overlap, stitch_settings);
            (t, choice, [cuts[0].cost, cuts[1].cost])
        }
    })
}

/// A scored candidate: (mean path error, x, y).
type Scored = (f64, usize, usize);

fn by_score(a: &Scored, b: &Scored) -> std::cmp::Ordering {
    a.0.total_cmp(&b.0).then((a.1, a.2).cmp(&(b.1, b.2)))
}

/// Where tile `k`'s patch comes from: the best of the seeded random
/// candidates that overlaps no `taken` rectangle by more than a quarter,
/// refined on its `±refine` neighbourhood; and the candidates' mean score.
fn choose_patch(
    tile0: &ColorImage,
    sample: &ColorImage,
    target: Rect,
    taken: &[Rect],
    k: usize,
    s: &TileSetSettings,
    stitch_settings: &StitchSettings,
) -> (Rect, f64) {
    let mut rng =
        ChaCha8Rng::seed_from_u64(s.seed ^ (k as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
    let score = |x: usize, y: usize| {
        let source = Rect { x, y, ..target };
        let (_, cuts) = patch_cuts(tile0, sample, source, target, s.belt, stitch_settings);
        report(source, target, &cuts).mean_path_error
    };
    let (xs, ys) = (sample.width - target.width, sample.height - target.height);
    let positions: Vec<(usize, usize)> = (0..s.candidates.max(1))
        .map(|_| (rng.random_range(0..=xs), rng.random_range(0..=ys)))
        .collect();
    let scored: Vec<Scored> = positions
        .par_iter()
        .map(|&(x, y)| (score(x, y), x, y))
        .collect();
    let random_mean = scored.iter().map(|c| c.0).sum::<f64>() / scored.len() as f64;
    let area = target.width * target.height;
    let free = |x: usize, y: usize| {
        let r = Rect { x, y, ..target };
        taken.iter().all(|o| r.intersection_area(o) * 4 <= area)
    };
    // The best free candidate, or the best of all if none is free.
    let pick = scored
        .iter()
        .filter(|c| free(c.1, c.2))
        .min_by(|a, b| by_score(a, b))
        .or_else(|| scored.iter().min_by(|a, b| by_score(a, b)))
        .copied()
        .unwrap_or((f64::INFINITY, 0, 0));
    // Local refinement on the ±refine neighbourhood, in steps of 2.
    let (x0, y0) = (pick.1, pick.2);
    let r = s.refine;
    let near: Vec<(usize, usize)> = (x0.saturating_sub(r)..=(x0 + r).min(xs))
        .step_by(2)
        .flat_map(|x| {
            (y0.saturating_sub(r)..=(y0 + r).min(ys))
                .step_by(2)
                .map(move |y| (x, y))
        })
        .filter(|&(x, y)| free(x, y) || (x, y) == (x0, y0))
        .collect();
    let best = near
        .par_iter()
        .map(|&(x, y)| (score(x, y), x, y))
        .chain(rayon::iter::once(pick))
        .min_by(by_score)
        .unwrap_or(pick);
    (
        Rect {
            x: best.1,
            y: best.2,
            ..target
        },
        random_mean,
    )
}

/// Makes a tile set from `sample` (§3): the template of [`choose_template`]
/// (or `template` as given), then `tiles - 1` tiles, each the template with
/// one patch from another place of the sample inserted inside its margin, so
/// every tile keeps the template's borders and connects to every other.
///
/// Patch positions are chosen, not drawn (the paper picks by hand): for each
/// tile, `candidates` random source positions (seeded) are scored by the mean
/// error along their four side paths; positions whose rectangle overlaps the
/// template's source or an earlier tile's patch by more than a quarter are
/// passed over (so the tiles differ); the best is refined on the
/// `±refine` neighbourhood, as the paper does.
pub fn make_tile_set(
    sample: &ColorImage,
    template: Option<&ColorImage>,
    s: &TileSetSettings,
    progress: &dyn Progress,
) -> anyhow::Result<TileSet> {
    let stitch_settings = s.path.stitch_settings();
    progress.start("tiles", s.tiles as u64, "tiles");
    let t0 = std::time::Instant::now();
    let (tile0, choice, costs) = template_tile(sample, template, s, &stitch_settings)?;
    let template_seconds = t0.elapsed().as_secs_f64();
    progress.set_done(1);
    let (tw, th) = (tile0.width, tile0.height);
    anyhow::ensure!(
        tw > 2 * (s.margin + s.belt) && th > 2 * (s.margin + s.belt),
        "the tile ({tw}x{th}) is too small for a {}-pixel margin and a {}-pixel patch belt on each side",
        s.margin,
        s.belt
    );
    let target = Rect {
        x: s.margin,
        y: s.margin,
        width: tw - 2 * s.margin,
        height: th - 2 * s.margin,
    };
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
    for k in 1..s.tiles {
        let t = std::time::Instant::now();
        let (source, random_mean) =
            choose_patch(&tile0, sample, target, &taken, k, s, &stitch_settings);
        let mut tile = tile0.clone();
        let patch = insert_patch(&mut tile, sample, source, target, s.belt, &stitch_settings);
        taken.push(source);
        tiles.push(tile);
        derived.push(DerivedTile {
            patch,
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
