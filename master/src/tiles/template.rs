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
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
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
