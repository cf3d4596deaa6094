//! Building ω-tiles from the chosen patches (Dong, Zhou and Paul §3, §4.3):
//! each intermediate tile merged with its best-matching sample patch by a
//! graph cut, and its seams smoothed.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::ais::{upper, Gene};
use super::evaluate::{intermediate_tile, Evaluator};
use super::graphcut;
use super::omega::OmegaSet;
use crate::imaging::ColorImage;

/// One finished ω-tile and how it was made.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct OmegaTile {
    pub corners: String,
    /// Top-left corner of the matching patch in the sample.
    pub matching_patch: Gene,
    /// Mean squared RGB error of the intermediate tile against it.
    pub match_error: f64,
    /// Share of the tile's pixels taken from the matching patch.
    pub patch_share: f64,
}

/// Builds every tile of the set from the chosen genes (§3, §4.3): the
/// intermediate tile, its matching patch (the evaluation level's best
/// translation, refined at full resolution over ±2^steps pixels by the RGB
/// error), the graph-cut merge and Poisson smoothing of the quarter seams and
/// the cut.
pub fn build_tiles(
    evaluator: &mut Evaluator,
    sample: &ColorImage,
    genes: &[Gene],
) -> anyhow::Result<(Vec<ColorImage>, Vec<OmegaTile>)> {
    let t = evaluator.tile;
    let u = upper(sample, t);
    let reach = 1i64 << evaluator.steps;
    let matches = (0..evaluator.set.tiles.len())
        .map(|j| evaluator.coarse_match(genes, j))
        .collect::<anyhow::Result<Vec<Gene>>>()?;
    let evaluator = &*evaluator;
    Ok((0..evaluator.set.tiles.len())
        .into_par_iter()
        .map(|j| {
            let corners = evaluator.set.tiles[j].map(|c| genes[usize::from(c)]);
            let inter = intermediate_tile(sample, t, corners);
            let (cx, cy) = matches[j];
            let mut best = (f64::INFINITY, (cx.min(u.0), cy.min(u.1)));
            for dy in -reach..=reach {
                for dx in -reach..=reach {
                    let (x, y) = (i64::from(cx) + dx, i64::from(cy) + dy);
                    if x < 0 || y < 0 || x > i64::from(u.0) || y > i64::from(u.1) {
                        continue;
                    }
                    let patch = sample.crop(x as usize, y as usize, t, t);
                    let e = mean_squared(&inter, &patch);
                    if e < best.0 {
                        best = (e, (x as u32, y as u32));
                    }
                }
            }
            let patch = sample.crop(best.1 .0 as usize, best.1 .1 as usize, t, t);
            let merged = graphcut::merge(&inter, &patch);
            let k = t / 2;
            let from = &merged.from_patch;
            let seam = |p: usize, q: usize| {
                if from[p] != from[q] {
                    return true;
                }
                // Quarter junctions of the intermediate tile, where it shows.
                !from[p] && ((p % t < k) != (q % t < k) || (p / t < k) != (q / t < k))
            };
            let image = graphcut::poisson_smooth(&merged.image, seam, 200);
            let share = from.iter().filter(|&&b| b).count() as f64 / (t * t) as f64;
            (
                image,
                OmegaTile {
                    corners: OmegaSet::name(evaluator.set.tiles[j]),
                    matching_patch: best.1,
                    match_error: best.0,
                    patch_share: share,
                },
            )
        })
        .unzip())
}

fn mean_squared(a: &ColorImage, b: &ColorImage) -> f64 {
    let (w, h) = (a.width, a.height);
    let mut s = 0u64;
    for y in 0..h {
        for x in 0..w {
            let (p, q) = (a.get(x, y), b.get(x, y));
            for c in 0..3 {
                s += (i64::from(p[c]) - i64::from(q[c])).pow(2) as u64;
            }
        }
    }
    s as f64 / (w * h) as f64
}
