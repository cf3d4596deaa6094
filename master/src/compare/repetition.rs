//! Copy and repetition measures (ARCHITECTURE §8): what S_F, S_L and patch
//! fidelity cannot see, because a verbatim copy of the sample scores best on
//! all three.
//!
//! - `copy_share`: the share of B's 8×8 patches that occur verbatim in A at
//!   one offset (taken modulo A's size, so a tiling of A is one offset).
//! - `repeat_share`: the share of B's 8×8 patches that occur verbatim again in
//!   B at least 16 px away.
//! - `tile_overlap`: for a grid of tiles, the mean over pairs of distinct tile
//!   images of the share of their pixels that are equal.
//!
//! Exact matching by hashing: each patch gets a 64-bit polynomial hash of its
//! pixels (one pass per row, one per column), candidates are found by sorting
//! the hashes, and every candidate is confirmed pixel by pixel, so a hash
//! collision can cost time but never a wrong count.

use std::collections::HashMap;

use rayon::prelude::*;
use serde::Serialize;

use crate::imaging::ColorImage;

/// Side of the patches that are matched verbatim.
pub const PATCH: usize = 8;
/// Least distance (the larger of |dx| and |dy|) between two occurrences of a
/// patch for `repeat_share` to count them as a repeat: nearer ones overlap.
pub const REPEAT_DISTANCE: usize = 16;
/// A hash shared by more than this many patches of A is ambiguous (a flat
/// region) and does not vote for an offset.
const MAX_VOTERS: usize = 8;
/// Offsets with the most votes that are checked exactly.
const CANDIDATE_OFFSETS: usize = 4;

/// The pixels of an image packed one `u32` each, for fast equality.
struct Packed {
    width: usize,
    height: usize,
    px: Vec<u32>,
}

impl Packed {
    fn of(img: &ColorImage) -> Self {
        Self {
            width: img.width,
            height: img.height,
            px: img
                .rgb
                .chunks_exact(3)
                .map(|p| u32::from(p[0]) << 16 | u32::from(p[1]) << 8 | u32::from(p[2]))
                .collect(),
        }
    }

    fn at(&self, x: usize, y: usize) -> u32 {
        self.px[y * self.width + x]
    }

    /// Patch positions per row and per column (0 when the image is smaller
    /// than a patch).
    fn patches(&self) -> (usize, usize) {
        (
            (self.width + 1).saturating_sub(PATCH),
            (self.height + 1).saturating_sub(PATCH),
        )
    }

    /// Whether the patches at `(ax, ay)` of `self` and `(bx, by)` of `other`
    /// are equal pixel for pixel.
    fn same_patch(&self, ax: usize, ay: usize, other: &Packed, bx: usize, by: usize) -> bool {
        (0..PATCH).all(|j| {
            let a = (ay + j) * self.width + ax;
            let b = (by + j) * other.width + bx;
            self.px[a..a + PATCH] == other.px[b..b + PATCH]
        })
    }

    /// The hash of every patch, row-major over the patch positions.
    fn patch_hashes(&self) -> Vec<u64> {
        const KX: u64 = 0x9e37_79b9_7f4a_7c15;
        const KY: u64 = 0xc2b2_ae3d_27d4_eb4f;
        let (pw, ph) = self.patches();
        if pw == 0 || ph == 0 {
            return Vec::new();
        }
        // Horizontal pass: the hash of the PATCH pixels starting at each x.
        let rows: Vec<u64> = (0..self.height)
            .into_par_iter()
            .flat_map_iter(|y| {
                let row = &self.px[y * self.width..(y + 1) * self.width];
                (0..pw).map(move |x| {
                    row[x..x + PATCH].iter().fold(0u64, |h, &p| {
                        h.wrapping_mul(KX).wrapping_add(u64::from(p) + 1)
                    })
                })
            })
            .collect();
        // Vertical pass over PATCH row hashes, then a final mix.
        (0..ph)
            .into_par_iter()
            .flat_map_iter(|y| {
                let rows = &rows;
                (0..pw).map(move |x| {
                    let h = (0..PATCH).fold(0u64, |h, j| {
                        h.wrapping_mul(KY).wrapping_add(rows[(y + j) * pw + x])
                    });
                    mix(h)
                })
            })
            .collect()
    }
}

/// The finaliser of SplitMix64: spreads the polynomial hash's bits.
fn mix(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// `(hash, position)` pairs sorted by hash: equal patches sit side by side.
fn sorted_hashes(img: &Packed) -> Vec<(u64, u32)> {
    let mut v: Vec<(u64, u32)> = img
        .patch_hashes()
        .into_iter()
        .enumerate()
        .map(|(i, h)| (h, i as u32))
        .collect();
    v.par_sort_unstable();
    v
}

/// How much of B is a verbatim copy of A at one offset.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct CopyShare {
    /// The share of B's 8×8 patches equal to A's patch at `offset`: in [0, 1].
    pub share: f64,
    /// The offset `(ox, oy)`: B(x, y) = A((x + ox) mod A.width, (y + oy) mod
    /// A.height) on the copied patches.
    pub offset: [usize; 2],
}

/// The share of B's 8×8 patches found verbatim in A at the single most common
/// offset, modulo A's size (a tiling of A scores 1). Offsets are voted for by
/// the patches whose content occurs at most a few times among A's patches on
/// the torus (those across its edges too, as the share counts them), then
/// the best few are checked exactly against every patch of B.
pub fn copy_share(a: &ColorImage, b: &ColorImage) -> CopyShare {
    let (pa, pb) = (Packed::of(a), Packed::of(b));
    let (bw, bh) = pb.patches();
    let none = CopyShare {
        share: 0.0,
        offset: [0, 0],
    };
    if a.width == 0 || a.height == 0 || bw == 0 || bh == 0 {
        return none;
    }
    // A's patches on the torus, as the share counts them: A continued by
    // its own first columns and rows, one patch per pixel of A.
    let torus = Packed::of(&a.wrap_padded(PATCH - 1));
    let (aw, _) = torus.patches();
    let index = sorted_hashes(&torus);
    let hb = pb.patch_hashes();
    // Votes per offset, and one offset of any match (flat images only have
    // ambiguous matches).
    let (votes, any) = (0..bh)
        .into_par_iter()
        .fold(
            || (HashMap::<(usize, usize), u32>::new(), None),
            |(mut votes, mut any), y| {
                for x in 0..bw {
                    let h = hb[y * bw + x];
                    let start = index.partition_point(|e| e.0 < h);
                    let run = index[start..].iter().take_while(|e| e.0 == h);
                    let len = run.clone().count();
                    for &(_, i) in run.take(MAX_VOTERS) {
                        let (ax, ay) = (i as usize % aw, i as usize / aw);
                        if !torus.same_patch(ax, ay, &pb, x, y) {
                            continue;
                        }
                        let o = (
                            (ax + pa.width - x % pa.width) % pa.width,
                            (ay + pa.height - y % pa.height) % pa.height,
                        );
                        any.get_or_insert(o);
                        if len <= MAX_VOTERS {
                            *votes.entry(o).or_insert(0) += 1;
                        }
                    }
                }
                (votes, any)
            },
        )
        .reduce(
            || (HashMap::new(), None),
            |(mut v1, a1), (v2, a2)| {
                for (k, n) in v2 {
                    *v1.entry(k).or_insert(0) += n;
                }
                (v1, a1.or(a2))
            },
        );
    let mut ranked: Vec<((usize, usize), u32)> = votes.into_iter().collect();
    ranked.sort_unstable_by(|p, q| q.1.cmp(&p.1).then(p.0.cmp(&q.0)));
    let mut candidates: Vec<(usize, usize)> = ranked
        .into_iter()
        .take(CANDIDATE_OFFSETS)
        .map(|(o, _)| o)
        .collect();
    candidates.extend(any);
    candidates
        .into_iter()
        .map(|o| CopyShare {
            share: share_at_offset(&pa, &pb, o),
            offset: [o.0, o.1],
        })
        .fold(none, |best, c| if c.share > best.share { c } else { best })
}

/// The share of B's patches equal to A's (wrapped) patch at offset `o`: one
/// pass marks the equal pixels, a summed-area table counts each patch's
/// unequal ones.
fn share_at_offset(a: &Packed, b: &Packed, o: (usize, usize)) -> f64 {
    let (bw, bh) = b.patches();
    let w = b.width;
    // sat[(y)(w+1) + x]: unequal pixels above and left of (x, y).
    let mut sat = vec![0u32; (w + 1) * (b.height + 1)];
    for y in 0..b.height {
        let mut row = 0u32;
        let ay = (y + o.1) % a.height;
        for x in 0..w {
            row += u32::from(b.at(x, y) != a.at((x + o.0) % a.width, ay));
            sat[(y + 1) * (w + 1) + x + 1] = sat[y * (w + 1) + x + 1] + row;
        }
    }
    let at = |x: usize, y: usize| sat[y * (w + 1) + x];
    let copied = (0..bh)
        .flat_map(|y| (0..bw).map(move |x| (x, y)))
        .filter(|&(x, y)| {
            at(x + PATCH, y + PATCH) + at(x, y) == at(x + PATCH, y) + at(x, y + PATCH)
        })
        .count();
    copied as f64 / (bw * bh) as f64
}

/// The share of B's 8×8 patches that occur verbatim again in B at least
/// [`REPEAT_DISTANCE`] px away (in x or in y): 0 for a texture without exact
/// repeats, near 1 for a tiling.
pub fn repeat_share(b: &ColorImage) -> f64 {
    let pb = Packed::of(b);
    let (bw, bh) = pb.patches();
    if bw == 0 || bh == 0 {
        return 0.0;
    }
    let sorted = sorted_hashes(&pb);
    // Runs of one hash; within a run, groups of equal content.
    let mut runs = Vec::new();
    let mut start = 0;
    for i in 1..=sorted.len() {
        if i == sorted.len() || sorted[i].0 != sorted[start].0 {
            if i - start > 1 {
                runs.push(start..i);
            }
            start = i;
        }
    }
    let pos = |i: u32| (i as usize % bw, i as usize / bw);
    let repeated: usize = runs
        .into_par_iter()
        .map(|run| {
            let members = &sorted[run];
            // Each group: its representative and members.
            let mut groups: Vec<Vec<(usize, usize)>> = Vec::new();
            for &(_, i) in members {
                let p = pos(i);
                match groups
                    .iter_mut()
                    .find(|g| pb.same_patch(g[0].0, g[0].1, &pb, p.0, p.1))
                {
                    Some(g) => g.push(p),
                    None => groups.push(vec![p]),
                }
            }
            groups
                .iter()
                .filter(|g| g.len() > 1)
                .map(|g| {
                    let (x0, x1) = (
                        g.iter().map(|p| p.0).min().unwrap_or(0),
                        g.iter().map(|p| p.0).max().unwrap_or(0),
                    );
                    let (y0, y1) = (
                        g.iter().map(|p| p.1).min().unwrap_or(0),
                        g.iter().map(|p| p.1).max().unwrap_or(0),
                    );
                    let d = REPEAT_DISTANCE;
                    g.iter()
                        .filter(|&&(x, y)| x - x0 >= d || x1 - x >= d || y - y0 >= d || y1 - y >= d)
                        .count()
                })
                .sum::<usize>()
        })
        .sum();
    repeated as f64 / (bw * bh) as f64
}

/// Distinct tile images among `tiles` (all of one size): for each tile, the
/// index of the first tile equal to it.
pub fn distinct_tiles(tiles: &[ColorImage]) -> Vec<usize> {
    let mut first: Vec<usize> = Vec::with_capacity(tiles.len());
    for (i, t) in tiles.iter().enumerate() {
        let same = (0..i).find(|&j| first[j] == j && tiles[j].rgb == t.rgb);
        first.push(same.unwrap_or(i));
    }
    first
}

/// The mean, over pairs of distinct tile images among `tiles` (all of one
/// size), of the share of pixels that are equal in both; 1 when all tiles are
/// one image, `None` for fewer than two tiles.
pub fn tile_overlap(tiles: &[ColorImage]) -> Option<f64> {
    tile_measures(tiles).1
}

/// What unrelated tiles of the texture share by chance: the mean, over
/// ordered pairs of distinct tile images, of the share of equal pixels
/// between one tile and the other turned cyclically by half its size (so no
/// band, row or patch of one meets its copy in the other). Flat, quantised
/// samples score well above 0 here; [`tile_overlap`] above this is shared
/// content. `None` for fewer than two distinct tiles.
pub fn tile_overlap_chance(tiles: &[ColorImage]) -> Option<f64> {
    tile_measures(tiles).2
}

/// The number of distinct tile images among `tiles`, their
/// [`tile_overlap`] and [`tile_overlap_chance`], finding the distinct images
/// once.
pub fn tile_measures(tiles: &[ColorImage]) -> (usize, Option<f64>, Option<f64>) {
    let distinct: Vec<Packed> = distinct_images(tiles).map(Packed::of).collect();
    let count = distinct.len();
    if tiles.len() < 2 {
        return (count, None, None);
    }
    if distinct.len() < 2 {
        return (count, Some(1.0), None);
    }
    let n = distinct.len();
    let (w, h) = (distinct[0].width, distinct[0].height);
    let shared = |i: usize, j: usize, (dx, dy): (usize, usize)| {
        let (p, q) = (&distinct[i].px, &distinct[j].px);
        let equal = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .filter(|&(x, y)| p[y * w + x] == q[(y + dy) % h * w + (x + dx) % w])
            .count();
        equal as f64 / (w * h).max(1) as f64
    };
    let mean = |pairs: Vec<(usize, usize)>, shift: (usize, usize)| {
        let total: f64 = pairs.par_iter().map(|&(i, j)| shared(i, j, shift)).sum();
        total / pairs.len() as f64
    };
    let unordered = (0..n)
        .flat_map(|i| (i + 1..n).map(move |j| (i, j)))
        .collect();
    (
        count,
        Some(mean(unordered, (0, 0))),
        Some(mean(ordered_pairs(n), (w / 2, h / 2))),
    )
}

/// The first of each distinct image among `tiles` ([`distinct_tiles`]).
fn distinct_images(tiles: &[ColorImage]) -> impl Iterator<Item = &ColorImage> {
    let first = distinct_tiles(tiles);
    tiles
        .iter()
        .zip(first)
        .enumerate()
        .filter(|&(i, (_, f))| i == f)
        .map(|(_, (t, _))| t)
}

/// Every ordered pair `(i, j)`, `i ≠ j`, of `n` items.
fn ordered_pairs(n: usize) -> Vec<(usize, usize)> {
    (0..n)
        .flat_map(|i| (0..n).filter(move |&j| j != i).map(move |j| (i, j)))
        .collect()
}

/// Most distinct tiles [`tile_copy`] pairs (4032 ordered pairs, about a
/// second on 2 cores for 64² tiles).
pub const MAX_NEAREST_PAIR_TILES: usize = 64;

/// The nearest pair of a set: the largest, over ordered pairs of distinct
/// tile images, of the [`copy_share`] of one in the other. A tile whose
/// patch came from a few pixels beside another's source is a shifted copy
/// of it: [`tile_overlap`] (equal pixels in place) misses it, this does not.
/// `None` for fewer than two distinct tiles, or more than
/// [`MAX_NEAREST_PAIR_TILES`] (the pairs grow as its square: a tile set has
/// a few dozen, a synthesis cut into small cells thousands).
pub fn tile_copy(tiles: &[ColorImage]) -> Option<f64> {
    let distinct: Vec<&ColorImage> = distinct_images(tiles).collect();
    let n = distinct.len();
    if n > MAX_NEAREST_PAIR_TILES {
        return None;
    }
    ordered_pairs(n)
        .par_iter()
        .map(|&(i, j)| copy_share(distinct[i], distinct[j]).share)
        .reduce_with(f64::max)
}

/// The full `tw`×`th` cells of a grid image, row by row.
pub fn grid_cells(img: &ColorImage, tw: usize, th: usize) -> Vec<ColorImage> {
    let (cols, rows) = (img.width / tw.max(1), img.height / th.max(1));
    (0..rows)
        .flat_map(|r| (0..cols).map(move |c| (c, r)))
        .map(|(c, r)| img.crop(c * tw, r * th, tw, th))
        .collect()
}
