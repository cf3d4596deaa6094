//! Template tiles, patched tile sets and index-matrix tiling (Somol–Haindl
//! §2.3, §3.1, §3.2).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::Serialize;

use super::stitch::{self, Belt, Cut, Side, StitchSettings};
use crate::imaging::ColorImage;
use crate::seams::{rgb_distance, Oscillating};

/// A rectangle of an image.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct Rect {
    pub x: usize,
    pub y: usize,
    pub width: usize,
    pub height: usize,
}

impl Rect {
    fn intersection_area(&self, o: &Rect) -> usize {
        let w = (self.x + self.width)
            .min(o.x + o.width)
            .saturating_sub(self.x.max(o.x));
        let h = (self.y + self.height)
            .min(o.y + o.height)
            .saturating_sub(self.y.max(o.y));
        w * h
    }
}

fn crop(img: &ColorImage, r: Rect) -> ColorImage {
    img.crop(r.x, r.y, r.width, r.height)
}

/// Mean Euclidean RGB distance between two `w`-wide strips that start at `a`
/// and `b` across the image and span `along` (the paper's criterion of visual
/// consistency, §3.1): column strips, or row strips with `rows`.
fn strip_error(
    img: &ColorImage,
    rows: bool,
    (a, b): (usize, usize),
    w: usize,
    along: (usize, usize),
) -> f64 {
    let at = |across: usize, t: usize| {
        if rows {
            img.get(t, across)
        } else {
            img.get(across, t)
        }
    };
    let mut sum = 0.0;
    for t in along.0..along.1 {
        for i in 0..w {
            sum += f64::from(rgb_distance(at(a + i, t), at(b + i, t)));
        }
    }
    sum / (w * (along.1 - along.0)) as f64
}

/// Where the template tile comes from and how well its borders matched.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct TemplateChoice {
    /// The tile's rectangle in the sample (the overlap continues right of and
    /// below it).
    pub rect: Rect,
    /// Mean RGB distance of the left/right and top/bottom border strips.
    pub horizontal_error: f64,
    pub vertical_error: f64,
}

/// Chooses the template's size (each side in `min..=max`) and position so
/// that opposite border strips of width `overlap` match best (§3.1). As in the
/// paper, in two independent phases: width and x on whole columns first,
/// then height and y on the chosen columns.
pub fn choose_template(
    sample: &ColorImage,
    min: usize,
    max: usize,
    overlap: usize,
) -> anyhow::Result<TemplateChoice> {
    let w = overlap;
    let need = min + w;
    anyhow::ensure!(
        min > 2 * w && min <= max,
        "tile size range {min}..={max} with overlap {w}: the least size must be above twice the overlap and at most the greatest"
    );
    anyhow::ensure!(
        sample.width >= need && sample.height >= need,
        "the sample ({}x{}) is smaller than a {min}-pixel tile plus its {w}-pixel overlap; give a smaller --tile-size or a larger sample",
        sample.width,
        sample.height
    );
    let best = |cands: Vec<(usize, usize)>, err: &(dyn Fn(usize, usize) -> f64 + Sync)| {
        cands
            .into_par_iter()
            .map(|(p, s)| (err(p, s), p, s))
            .min_by(|a, b| a.0.total_cmp(&b.0).then((a.1, a.2).cmp(&(b.1, b.2))))
            .unwrap()
    };
    let cands = |len: usize| -> Vec<(usize, usize)> {
        (min..=max.min(len - w))
            .flat_map(|s| (0..=len - s - w).map(move |p| (p, s)))
            .collect()
    };
    let (he, x, width) = best(cands(sample.width), &|x, s| {
        strip_error(sample, false, (x, x + s), w, (0, sample.height))
    });
    let cols = (x, x + width + w);
    let (ve, y, height) = best(cands(sample.height), &|y, s| {
        strip_error(sample, true, (y, y + s), w, cols)
    });
    Ok(TemplateChoice {
        rect: Rect {
            x,
            y,
            width,
            height,
        },
        horizontal_error: he,
        vertical_error: ve,
    })
}

/// The seamless template: the chosen rectangle with the strip right of it
/// stitched over its left border and then the strip below it over its top
/// border (§3.1), so the tile continues across its own edges.
pub fn make_template(
    sample: &ColorImage,
    choice: &TemplateChoice,
    overlap: usize,
    settings: &StitchSettings,
) -> (ColorImage, [Cut; 2]) {
    let r = choice.rect;
    let w = overlap;
    let ext = crop(
        sample,
        Rect {
            x: r.x,
            y: r.y,
            width: r.width + w,
            height: r.height + w,
        },
    );
    // Right over left, on all rows (the rows below the tile are needed by the
    // second stitch).
    let mut tall = crop(
        &ext,
        Rect {
            x: 0,
            y: 0,
            width: r.width,
            height: r.height + w,
        },
    );
    let belt = Belt {
        x: 0,
        y: 0,
        across: w,
        along: r.height + w,
        r1: Side::Left,
    };
    let right = |x: usize, y: usize| ext.get(x + r.width, y);
    let c1 = stitch::stitch(&mut tall, &belt, right, settings, |_, _| true);
    // Bottom over top.
    let below = tall.clone();
    let belt = Belt {
        x: 0,
        y: 0,
        across: w,
        along: r.width,
        r1: Side::Top,
    };
    let c2 = stitch::stitch(
        &mut tall,
        &belt,
        |x, y| below.get(x, y + r.height),
        settings,
        |_, _| true,
    );
    let tile = crop(
        &tall,
        Rect {
            x: 0,
            y: 0,
            width: r.width,
            height: r.height,
        },
    );
    (tile, [c1, c2])
}

/// How a patch went in.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct PatchReport {
    /// The patch's rectangle in the sample.
    pub source: Rect,
    /// Its rectangle in the tile.
    pub target: Rect,
    /// ε of the four side paths.
    pub path_costs: [f64; 4],
    /// Mean error per path pixel over the four sides.
    pub mean_path_error: f64,
}

fn side_belts(t: Rect, b: usize) -> [Belt; 4] {
    [
        Belt {
            x: t.x,
            y: t.y,
            across: b,
            along: t.height,
            r1: Side::Right,
        },
        Belt {
            x: t.x + t.width - b,
            y: t.y,
            across: b,
            along: t.height,
            r1: Side::Left,
        },
        Belt {
            x: t.x,
            y: t.y,
            across: b,
            along: t.width,
            r1: Side::Bottom,
        },
        Belt {
            x: t.x,
            y: t.y + t.height - b,
            across: b,
            along: t.width,
            r1: Side::Top,
        },
    ]
}

/// Canonical `(i, j)` of canvas `(x, y)` in `belt`, if it lies in it.
fn canonical(belt: &Belt, x: usize, y: usize) -> Option<(usize, usize)> {
    let (w, l) = (belt.across, belt.along);
    let (dx, dy) = (x.checked_sub(belt.x)?, y.checked_sub(belt.y)?);
    let (i, j) = match belt.r1 {
        Side::Left => (dx, dy),
        Side::Right => (w.checked_sub(1 + dx)?, dy),
        Side::Top => (dy, dx),
        Side::Bottom => (w.checked_sub(1 + dy)?, dx),
    };
    (i < w && j < l).then_some((i, j))
}

/// The patch's pixel at tile coordinates (x, y) inside `target`.
fn patch_pixels(
    sample: &ColorImage,
    source: Rect,
    target: Rect,
) -> impl Fn(usize, usize) -> [u8; 3] + Copy + '_ {
    move |x, y| sample.get(source.x + x - target.x, source.y + y - target.y)
}

/// The four side cuts of a patch of `source` placed at `target` in `tile`.
fn patch_cuts(
    tile: &ColorImage,
    sample: &ColorImage,
    source: Rect,
    target: Rect,
    belt: usize,
    settings: &StitchSettings,
) -> ([Belt; 4], Vec<Cut>) {
    let belts = side_belts(target, belt);
    let r1 = patch_pixels(sample, source, target);
    let cuts = belts
        .iter()
        .map(|b| stitch::find_cut(b, r1, |x, y| tile.get(x, y), settings))
        .collect();
    (belts, cuts)
}

fn report(source: Rect, target: Rect, cuts: &[Cut]) -> PatchReport {
    let pixels: usize = cuts.iter().map(|c| c.path.pixels().count()).sum();
    let total: f64 = cuts.iter().map(|c| c.cost).sum();
    PatchReport {
        source,
        target,
        path_costs: std::array::from_fn(|k| cuts[k].cost),
        mean_path_error: total / pixels.max(1) as f64,
    }
}

/// Inserts the patch `source` of the sample at `target` of the tile (§2.3):
/// the interior is copied, the four side belts of width `belt` are cut along
/// minimum-error paths and blended. The corners, where two belts cross, take
/// the patch only where both side cuts give it to the patch, so the patch is
/// bounded by one continuous path (the paper searches separate corner paths
/// with fixed end points; the intersection keeps the same continuity without
/// them). Nothing outside `target` changes.
pub fn insert_patch(
    tile: &mut ColorImage,
    sample: &ColorImage,
    source: Rect,
    target: Rect,
    belt: usize,
    settings: &StitchSettings,
) -> PatchReport {
    let (belts, cuts) = patch_cuts(tile, sample, source, target, belt, settings);
    let r1 = patch_pixels(sample, source, target);
    let mut out = tile.clone();
    for y in target.y..target.y + target.height {
        for x in target.x..target.x + target.width {
            let mut inside = true;
            let mut weight: Option<(f32, [u8; 3])> = None;
            for (b, cut) in belts.iter().zip(&cuts) {
                let Some((i, j)) = canonical(b, x, y) else {
                    continue;
                };
                if !cut.path.takes_r1(i, j) {
                    inside = false;
                    break;
                }
                let (alpha, (m, n)) = stitch::blend_weight(cut, settings.rho, i, j);
                if weight.is_none_or(|(a, _)| alpha < a) {
                    let (px, py) = b.pixel(m, n);
                    weight = Some((alpha, tile.get(px, py)));
                }
            }
            if !inside {
                continue;
            }
            let a = r1(x, y);
            let colour = match weight {
                Some((alpha, b)) if alpha < 1.0 => std::array::from_fn(|k| {
                    (f32::from(a[k]) * alpha + f32::from(b[k]) * (1.0 - alpha)).round() as u8
                }),
                _ => a,
            };
            out.set(x, y, colour);
        }
    }
    *tile = out;
    report(source, target, &cuts)
}

/// Settings of a tile set.
#[derive(Clone, Copy, Debug, Serialize)]
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
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, clap::ValueEnum)]
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
#[derive(Clone, Debug, Serialize)]
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
    progress: &(dyn Fn(usize) + Sync),
) -> anyhow::Result<TileSet> {
    let stitch_settings = s.path.stitch_settings();
    let t0 = std::time::Instant::now();
    let (tile0, choice, costs) = match template {
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
            let (t, cuts) = make_template(sample, &choice, s.overlap, &stitch_settings);
            (t, choice, [cuts[0].cost, cuts[1].cost])
        }
    };
    let template_seconds = t0.elapsed().as_secs_f64();
    progress(1);
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
        let mut rng =
            ChaCha8Rng::seed_from_u64(s.seed ^ (k as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
        let score = |x: usize, y: usize| {
            let source = Rect { x, y, ..target };
            let (_, cuts) = patch_cuts(&tile0, sample, source, target, s.belt, &stitch_settings);
            report(source, target, &cuts).mean_path_error
        };
        let positions: Vec<(usize, usize)> = (0..s.candidates.max(1))
            .map(|_| {
                (
                    rng.random_range(0..=sample.width - target.width),
                    rng.random_range(0..=sample.height - target.height),
                )
            })
            .collect();
        let scored: Vec<(f64, usize, usize)> = positions
            .par_iter()
            .map(|&(x, y)| (score(x, y), x, y))
            .collect();
        let random_mean = scored.iter().map(|c| c.0).sum::<f64>() / scored.len() as f64;
        let area = target.width * target.height;
        let free = |x: usize, y: usize| {
            let r = Rect { x, y, ..target };
            taken.iter().all(|o| r.intersection_area(o) * 4 <= area)
        };
        let order = |a: &&(f64, usize, usize), b: &&(f64, usize, usize)| {
            a.0.total_cmp(&b.0).then((a.1, a.2).cmp(&(b.1, b.2)))
        };
        // The best free candidate, or the best of all if none is free.
        let pick = *scored
            .iter()
            .filter(|c| free(c.1, c.2))
            .min_by(order)
            .or_else(|| scored.iter().min_by(order))
            .unwrap();
        // Local refinement on the ±refine neighbourhood, in steps of 2.
        let (x0, y0) = (pick.1, pick.2);
        let r = s.refine;
        let near: Vec<(usize, usize)> = (x0.saturating_sub(r)
            ..=(x0 + r).min(sample.width - target.width))
            .step_by(2)
            .flat_map(|x| {
                (y0.saturating_sub(r)..=(y0 + r).min(sample.height - target.height))
                    .step_by(2)
                    .map(move |y| (x, y))
            })
            .filter(|&(x, y)| free(x, y) || (x, y) == (x0, y0))
            .collect();
        let best = near
            .par_iter()
            .map(|&(x, y)| (score(x, y), x, y))
            .chain(rayon::iter::once(pick))
            .min_by(|a, b| a.0.total_cmp(&b.0).then((a.1, a.2).cmp(&(b.1, b.2))))
            .unwrap();
        let source = Rect {
            x: best.1,
            y: best.2,
            ..target
        };
        let mut tile = tile0.clone();
        let patch = insert_patch(&mut tile, sample, source, target, s.belt, &stitch_settings);
        taken.push(source);
        tiles.push(tile);
        derived.push(DerivedTile {
            patch,
            random_mean_path_error: random_mean,
            seconds: t.elapsed().as_secs_f64(),
        });
        progress(k + 1);
    }
    Ok(TileSet {
        tiles,
        template: choice,
        template_path_costs: costs,
        template_seconds,
        derived,
    })
}

/// Lays tiles in a grid: `index[row][col]` is a tile number from 1 (as in
/// the paper's index matrices).
pub fn assemble(tiles: &[ColorImage], index: &[Vec<usize>]) -> anyhow::Result<ColorImage> {
    anyhow::ensure!(!tiles.is_empty(), "no tiles");
    let (tw, th) = (tiles[0].width, tiles[0].height);
    anyhow::ensure!(
        tiles.iter().all(|t| (t.width, t.height) == (tw, th)),
        "the tiles differ in size"
    );
    let rows = index.len();
    let cols = index.first().map_or(0, Vec::len);
    anyhow::ensure!(
        rows > 0 && cols > 0 && index.iter().all(|r| r.len() == cols),
        "the index matrix must be a non-empty rectangle"
    );
    crate::imaging::check_size(
        cols.saturating_mul(tw),
        rows.saturating_mul(th),
        "the assembled grid",
    )?;
    let mut out = ColorImage::new(cols * tw, rows * th);
    for (r, row) in index.iter().enumerate() {
        for (c, &n) in row.iter().enumerate() {
            anyhow::ensure!(
                (1..=tiles.len()).contains(&n),
                "tile {n} at row {} column {} is not in 1..={}",
                r + 1,
                c + 1,
                tiles.len()
            );
            let t = &tiles[n - 1];
            for y in 0..th {
                let d = ((r * th + y) * out.width + c * tw) * 3;
                out.rgb[d..d + tw * 3].copy_from_slice(&t.rgb[y * tw * 3..(y + 1) * tw * 3]);
            }
        }
    }
    Ok(out)
}

/// A random index matrix (seeded): no tile equals its left or upper
/// neighbour when there are at least 3 tiles.
pub fn random_index(tiles: usize, cols: usize, rows: usize, seed: u64) -> Vec<Vec<usize>> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut m: Vec<Vec<usize>> = Vec::with_capacity(rows);
    for _ in 0..rows {
        let mut row: Vec<usize> = Vec::with_capacity(cols);
        for c in 0..cols {
            let left = row.last().copied();
            let up = m.last().map(|above| above[c]);
            let n = loop {
                let n = rng.random_range(1..=tiles);
                if tiles < 3 || (Some(n) != left && Some(n) != up) {
                    break n;
                }
            };
            row.push(n);
        }
        m.push(row);
    }
    m
}
