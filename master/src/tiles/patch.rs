//! Patch insertion (Somol–Haindl §2.3): a sample patch cut into a tile along
//! four minimum-error side paths and blended.

use serde::{Deserialize, Serialize};

use super::stitch::{self, Belt, Cut, Side, StitchSettings};
use super::template::Rect;
use crate::imaging::ColorImage;

/// How a patch went in.
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
pub struct PatchReport {
    /// The patch's rectangle in the sample.
    pub source: Rect,
    /// Its rectangle in the tile; a patch that wraps (`DerivedTile::wrap`)
    /// is one pixel wider and taller than the tile, reaching into the next
    /// tile's first column and row.
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
/// Where the target's last column and row are the tile's periodic
/// continuation (the next tile's first column and row, a patch that wraps),
/// the pull of the right and bottom paths aims at them: a path pixel keeps
/// the canvas's colour, so a path there leaves the whole tile to the patch,
/// and its cost is the error against the real neighbour.
pub(super) fn patch_cuts(
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

pub(super) fn report(source: Rect, target: Rect, cuts: &[Cut]) -> PatchReport {
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
    paste_patch(tile, sample, (source, target), (&belts, &cuts), settings);
    report(source, target, &cuts)
}

/// Writes the patch `source` at `target` along cuts already found by
/// [`patch_cuts`] (what [`insert_patch`] does after finding them), blending
/// as `settings` say.
pub(super) fn paste_patch(
    tile: &mut ColorImage,
    sample: &ColorImage,
    (source, target): (Rect, Rect),
    (belts, cuts): (&[Belt; 4], &[Cut]),
    settings: &StitchSettings,
) {
    let rho = settings.rho;
    let r1 = patch_pixels(sample, source, target);
    // Per belt and row, the first path column within the blend's reach of
    // the row: a pixel more than the reach left of it is farther than ρ from
    // every path pixel the blend looks at, so it takes the patch unblended
    // (α = 1) without the search.
    let reach = rho.max(0.0).ceil() as usize;
    let near: Vec<Vec<usize>> = cuts
        .iter()
        .map(|cut| {
            let rows = cut.starts.len();
            (0..rows)
                .map(|j| {
                    let window = j.saturating_sub(reach)..=(j + reach).min(rows - 1);
                    cut.starts[window]
                        .iter()
                        .copied()
                        .min()
                        .unwrap_or(usize::MAX)
                })
                .collect()
        })
        .collect();
    let mut out = tile.clone();
    for y in target.y..target.y + target.height {
        for x in target.x..target.x + target.width {
            let mut inside = true;
            let mut weight: Option<(f32, [u8; 3])> = None;
            for ((b, cut), near) in belts.iter().zip(cuts).zip(&near) {
                let Some((i, j)) = canonical(b, x, y) else {
                    continue;
                };
                if !cut.path.takes_r1(i, j) {
                    inside = false;
                    break;
                }
                if i + reach < near[j] {
                    continue;
                }
                let (alpha, (m, n)) = stitch::blend_weight(cut, settings, i, j);
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
}
