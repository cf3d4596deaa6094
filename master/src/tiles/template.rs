//! The template tile (Somol–Haindl §3.1): the sample rectangle whose
//! opposite border strips match best, stitched across its own edges.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::stitch::{self, Belt, Cut, Side, StitchSettings};
use crate::imaging::ColorImage;
use crate::seams::rgb_distance;

/// A rectangle of an image.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Rect {
    pub x: usize,
    pub y: usize,
    pub width: usize,
    pub height: usize,
}

impl Rect {
    pub(super) fn intersection_area(&self, o: &Rect) -> usize {
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

/// The paper's criterion of visual consistency (§3.1) for every candidate
/// `(position p, size s)` with `s` in `sizes` along one axis: the mean
/// Euclidean RGB distance between the `w`-wide strips at `p` and `p + s`
/// (column strips, or row strips with `rows`), over `along` of the other
/// axis. Per size, one pass sums each line pair's distance and prefix sums
/// give every position: `O(sizes · len · along)`.
fn strip_errors(
    img: &ColorImage,
    rows: bool,
    sizes: std::ops::RangeInclusive<usize>,
    w: usize,
    along: (usize, usize),
) -> Vec<(f64, usize, usize)> {
    let len = if rows { img.height } else { img.width };
    let at = |across: usize, t: usize| {
        if rows {
            img.get(t, across)
        } else {
            img.get(across, t)
        }
    };
    let norm = (w * (along.1 - along.0)).max(1) as f64;
    sizes
        .filter(|&s| s + w <= len)
        .collect::<Vec<_>>()
        .into_par_iter()
        .flat_map_iter(|s| {
            let mut prefix = vec![0.0f64; len - s + 1];
            for c in 0..len - s {
                let d: f64 = (along.0..along.1)
                    .map(|t| f64::from(rgb_distance(at(c, t), at(c + s, t))))
                    .sum();
                prefix[c + 1] = prefix[c] + d;
            }
            (0..=len - s - w).map(move |p| ((prefix[p + w] - prefix[p]) / norm, p, s))
        })
        .collect()
}

/// Where the template tile comes from and how well its borders matched.
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
pub struct TemplateChoice {
    /// The tile's rectangle in the sample (the overlap continues right of and
    /// below it).
    pub rect: Rect,
    /// Mean RGB distance of the left/right and top/bottom border strips.
    pub horizontal_error: f64,
    pub vertical_error: f64,
    /// The overlap `w_T` the template was stitched with (0: not recorded).
    #[serde(default)]
    pub overlap: usize,
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
    let mut all = choose_templates(sample, min, max, overlap, 1, 1)?;
    Ok(all.remove(0))
}

/// The `k` best of the `scored` candidates, best first, each at least
/// `apart` away from the ones before it in position or size.
fn best_few(
    mut scored: Vec<(f64, usize, usize)>,
    k: usize,
    apart: usize,
) -> Vec<(f64, usize, usize)> {
    scored.sort_by(|a, b| a.0.total_cmp(&b.0).then((a.1, a.2).cmp(&(b.1, b.2))));
    let mut kept: Vec<(f64, usize, usize)> = Vec::new();
    for c in scored {
        if kept.len() >= k {
            break;
        }
        if kept
            .iter()
            .all(|o| o.1.abs_diff(c.1) >= apart || o.2.abs_diff(c.2) >= apart)
        {
            kept.push(c);
        }
    }
    kept
}

/// [`choose_template`]'s `kx` best column choices, each with its `ky` best
/// row choices, best first by column error: placements whose stitches can be
/// made and compared (the paper's strip error does not see whether a low-
/// error path exists, §2.1).
pub fn choose_templates(
    sample: &ColorImage,
    min: usize,
    max: usize,
    overlap: usize,
    kx: usize,
    ky: usize,
) -> anyhow::Result<Vec<TemplateChoice>> {
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
    let apart = w.max(2);
    let mut out = Vec::new();
    let columns = strip_errors(sample, false, min..=max, w, (0, sample.height));
    for (he, x, width) in best_few(columns, kx.max(1), apart) {
        let cols = (x, x + width + w);
        let rows = strip_errors(sample, true, min..=max, w, cols);
        for (ve, y, height) in best_few(rows, ky.max(1), apart) {
            out.push(TemplateChoice {
                rect: Rect {
                    x,
                    y,
                    width,
                    height,
                },
                horizontal_error: he,
                vertical_error: ve,
                overlap: w,
            });
        }
    }
    Ok(out)
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
