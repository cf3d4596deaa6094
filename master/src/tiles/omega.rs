//! ω-tile sets (Dong, Zhou and Paul §3, after Ng et al.): square tiles with a
//! colour at each corner, where a colour stands for a sample patch and a tile
//! is cut from the centre of a 2×2 block of those patches.
//!
//! Tiles meet at lattice vertices: the four tiles around a vertex show the
//! four quarters of the one patch whose colour the vertex has, so a tiling
//! is valid when every tile's corners equal the colours of its vertices.
//! Corners are stored as `[top-left, top-right, bottom-left, bottom-right]`,
//! the order of the paper's tuples (`⟨B, Y, Y, R⟩` has its two yellow squares
//! on a diagonal).

use anyhow::{bail, ensure, Result};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Corner colours, by index. The paper names them R, G, B, Y, then C (the
/// first extension) and M (the second).
pub const COLOUR_NAMES: [char; 6] = ['R', 'G', 'B', 'Y', 'C', 'M'];
const R: u8 = 0;
const G: u8 = 1;
const B: u8 = 2;
const Y: u8 = 3;
const C: u8 = 4;
const M: u8 = 5;

/// The base set 𝔹 of 8 tiles over {R, G, B, Y} (§3, Fig. 3a).
///
/// The paper gives these tuples only in a figure. This set is reconstructed
/// from everything its text says of them: it holds `⟨R,G,G,B⟩` and
/// `⟨B,Y,Y,R⟩`; `⟨R,G,G,B⟩` is the only tile without yellow and `⟨B,Y,Y,R⟩`
/// the only one with two; the extension rule turns it into exactly 17 and 38
/// tiles; and without the two additional tiles the 15 tiles of ℕ′₁ do get
/// stuck, as Fig. 4 says they must. A search over tile sets grown from the two
/// named tiles found no other complete set of 8 meeting all of these. The
/// tests prove it, ℕ₁ and ℕ₂ complete with [`check_complete`].
pub const BASE: [[u8; 4]; 8] = [
    [R, R, Y, R],
    [R, G, G, B],
    [R, Y, R, G],
    [G, R, B, Y],
    [G, B, B, Y],
    [B, Y, Y, R],
    [Y, R, R, G],
    [Y, G, G, B],
];

/// An ω-tile set: the corner colours of each tile.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct OmegaSet {
    /// Number of colours (sample patches).
    pub colours: usize,
    pub tiles: Vec<[u8; 4]>,
}

impl OmegaSet {
    /// 𝔹 (8 tiles, 4 colours), ℕ₁ (17 tiles, 5) or ℕ₂ (38 tiles, 6).
    pub fn of_size(size: usize) -> Result<Self> {
        let base = Self {
            colours: 4,
            tiles: BASE.to_vec(),
        };
        Ok(match size {
            8 => base,
            17 => base.extended(Y, C),
            38 => base.extended(Y, C).extended(R, M),
            _ => bail!("there is no ω-tile set of {size} tiles; use --set 8, 17 or 38"),
        })
    }

    /// The paper's extension rule (§3.2): every tile holding the `reference`
    /// colour is copied with it replaced by the new colour `new`; a tile that
    /// holds it twice also gives the two tiles with only one of them replaced
    /// (they are needed where both colours meet at one placement, Fig. 4).
    pub fn extended(&self, reference: u8, new: u8) -> Self {
        let mut tiles = self.tiles.clone();
        let mut additional = Vec::new();
        for t in &self.tiles {
            let at: Vec<usize> = (0..4).filter(|&k| t[k] == reference).collect();
            if at.is_empty() {
                continue;
            }
            tiles.push(t.map(|c| if c == reference { new } else { c }));
            if at.len() == 2 {
                for &k in &at {
                    let mut one = *t;
                    one[k] = new;
                    additional.push(one);
                }
            }
        }
        tiles.extend(additional);
        Self {
            colours: self.colours.max(usize::from(new) + 1),
            tiles,
        }
    }

    /// A tile's corners as letters, e.g. `"BYYR"`.
    pub fn name(corners: [u8; 4]) -> String {
        corners
            .iter()
            .map(|&c| COLOUR_NAMES.get(usize::from(c)).copied().unwrap_or('?'))
            .collect()
    }

    /// The tiles whose corners match the given ones (`None`: any colour).
    fn fitting(&self, want: [Option<u8>; 4]) -> impl Iterator<Item = usize> + '_ {
        self.tiles.iter().enumerate().filter_map(move |(k, t)| {
            (0..4)
                .all(|i| want[i].is_none_or(|c| t[i] == c))
                .then_some(k)
        })
    }
}

/// A placement the scan-line tiler cannot make: the corners its neighbours
/// fix (`None`: free), and the row it was found on.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Stuck {
    pub want: [Option<u8>; 4],
    pub width: usize,
}

impl std::fmt::Display for Stuck {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s: String = self
            .want
            .iter()
            .map(|c| c.map_or('*', |c| COLOUR_NAMES[usize::from(c)]))
            .collect();
        write!(f, "no tile fits {s} on a strip {} tiles wide", self.width)
    }
}

/// The completeness checker: proves that the scan-line tiler, whatever tile it
/// picks among those that fit, never gets stuck on a strip of any width up to
/// `max_width` and any height.
///
/// A strip's state between rows is the colours of the vertices under the last
/// row; the checker enumerates every row the tiler can lay under every
/// reachable state (the first row: any first tile, then tiles matching their
/// left neighbour), until no new state appears. Each state lists at most
/// `colours^(width+1)` values, so this is exact and finite.
pub fn check_complete(set: &OmegaSet, max_width: usize) -> std::result::Result<(), Stuck> {
    for width in 1..=max_width {
        check_width(set, width)?;
    }
    Ok(())
}

fn check_width(set: &OmegaSet, width: usize) -> std::result::Result<(), Stuck> {
    use std::collections::HashSet;
    // Every row the tiler can lay under the vertices `above`.
    fn rows(
        set: &OmegaSet,
        width: usize,
        above: &[u8],
        x: usize,
        bottom: &mut Vec<u8>,
        out: &mut HashSet<Vec<u8>>,
    ) -> std::result::Result<(), Stuck> {
        if x == width {
            out.insert(bottom.clone());
            return Ok(());
        }
        // The row above fixes the top corners, the left neighbour the
        // bottom-left one.
        let want = [
            Some(above[x]),
            Some(above[x + 1]),
            bottom.last().copied(),
            None,
        ];
        let fits: Vec<usize> = set.fitting(want).collect();
        if fits.is_empty() {
            return Err(Stuck { want, width });
        }
        for k in fits {
            let t = set.tiles[k];
            let pushed = if x == 0 { 2 } else { 1 };
            if x == 0 {
                bottom.push(t[2]);
            }
            bottom.push(t[3]);
            rows(set, width, above, x + 1, bottom, out)?;
            bottom.truncate(bottom.len() - pushed);
        }
        Ok(())
    }
    // The first row: its top vertices are free, so a row is a chain of tiles
    // each matching its left neighbour's right corners.
    let mut first = HashSet::new();
    for (k, t) in set.tiles.iter().enumerate() {
        let mut chains = vec![(vec![t[2], t[3]], set.tiles[k])];
        for _ in 1..width {
            let mut next = Vec::new();
            for (bottom, last) in &chains {
                let want = [Some(last[1]), None, Some(last[3]), None];
                let fits: Vec<usize> = set.fitting(want).collect();
                if fits.is_empty() {
                    return Err(Stuck { want, width });
                }
                for f in fits {
                    let mut b = bottom.clone();
                    b.push(set.tiles[f][3]);
                    next.push((b, set.tiles[f]));
                }
            }
            next.sort();
            next.dedup();
            chains = next;
        }
        first.extend(chains.into_iter().map(|(b, _)| b));
    }
    let mut seen: HashSet<Vec<u8>> = first.clone();
    let mut todo: Vec<Vec<u8>> = first.into_iter().collect();
    while let Some(above) = todo.pop() {
        let mut out = HashSet::new();
        rows(set, width, &above, 0, &mut Vec::new(), &mut out)?;
        for r in out {
            if seen.insert(r.clone()) {
                todo.push(r);
            }
        }
    }
    Ok(())
}

/// Lays a `cols`×`rows` tiling in scan-line order (§3.1): each tile is drawn
/// at random (seeded) among those whose corners match its left and top
/// neighbours. Returns tile indices (from 0) row by row, or where it got stuck.
pub fn scan_line_tiling(
    set: &OmegaSet,
    cols: usize,
    rows: usize,
    seed: u64,
) -> Result<Vec<Vec<usize>>> {
    ensure!(!set.tiles.is_empty(), "the ω-tile set is empty");
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut out: Vec<Vec<usize>> = Vec::with_capacity(rows);
    for y in 0..rows {
        let mut row: Vec<usize> = Vec::with_capacity(cols);
        let above = out.last().cloned();
        for x in 0..cols {
            let left = row.last().map(|&k| set.tiles[k]);
            let top = above.as_ref().map(|a| set.tiles[a[x]]);
            let want = [
                left.map(|l| l[1]).or(top.map(|t| t[2])),
                top.map(|t| t[3]),
                left.map(|l| l[3]),
                None,
            ];
            let fits: Vec<usize> = set.fitting(want).collect();
            if fits.is_empty() {
                bail!(
                    "the tiler got stuck at ({x}, {y}): {}",
                    Stuck { want, width: cols }
                );
            }
            row.push(fits[rng.random_range(0..fits.len())]);
        }
        out.push(row);
    }
    Ok(out)
}

/// Whether a tiling is valid: every pair of neighbours agrees on the corners
/// they share.
pub fn tiling_is_valid(set: &OmegaSet, tiling: &[Vec<usize>]) -> bool {
    tiling.iter().enumerate().all(|(y, row)| {
        row.iter().enumerate().all(|(x, &k)| {
            let t = set.tiles[k];
            let left_ok = x == 0 || {
                let l = set.tiles[row[x - 1]];
                l[1] == t[0] && l[3] == t[2]
            };
            let top_ok = y == 0 || {
                let a = set.tiles[tiling[y - 1][x]];
                a[2] == t[0] && a[3] == t[1]
            };
            left_ok && top_ok
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_sets_have_8_17_and_38_distinct_tiles_and_are_complete() {
        for (size, colours) in [(8, 4), (17, 5), (38, 6)] {
            let set = OmegaSet::of_size(size).unwrap();
            assert_eq!(set.tiles.len(), size);
            assert_eq!(set.colours, colours);
            let mut distinct = set.tiles.clone();
            distinct.sort();
            distinct.dedup();
            assert_eq!(distinct.len(), size, "a tile repeats in the {size}-set");
            let width = if size == 38 { 4 } else { 5 };
            check_complete(&set, width).unwrap_or_else(|s| panic!("{size}-set: {s}"));
        }
    }

    #[test]
    fn the_text_s_claims_about_the_base_set_hold() {
        let names: Vec<String> = BASE.iter().map(|&t| OmegaSet::name(t)).collect();
        assert!(names.contains(&"RGGB".into()) && names.contains(&"BYYR".into()));
        let yellow: Vec<&String> = names.iter().filter(|n| n.contains('Y')).collect();
        assert_eq!(yellow.len(), 7, "only ⟨R,G,G,B⟩ lacks yellow");
        let double: Vec<&&String> = yellow
            .iter()
            .filter(|n| n.matches('Y').count() == 2)
            .collect();
        assert_eq!(double, [&&"BYYR".to_string()]);
        // ℕ′₁ (ℕ₁ without its two additional tiles) gets stuck (Fig. 4).
        let mut n1 = OmegaSet::of_size(17).unwrap();
        n1.tiles.truncate(15);
        assert!(check_complete(&n1, 4).is_err());
    }

    #[test]
    fn the_checker_finds_sets_that_get_stuck_and_the_tiler_does_too() {
        let base = OmegaSet::of_size(8).unwrap();
        let mut failed = 0;
        for k in 0..8 {
            let mut set = base.clone();
            set.tiles.remove(k);
            if let Err(stuck) = check_complete(&set, 4) {
                failed += 1;
                assert!(set.fitting(stuck.want).next().is_none(), "{stuck}");
                // Random tilings of that width run into it too.
                let hit =
                    (0..2000).any(|seed| scan_line_tiling(&set, stuck.width, 8, seed).is_err());
                assert!(hit, "tile {k} removed: no random tiling got stuck");
            }
        }
        assert!(failed >= 4, "only {failed} of 8 reduced sets get stuck");
    }

    #[test]
    fn ten_thousand_random_tilings_never_get_stuck() {
        for size in [8, 17, 38] {
            let set = OmegaSet::of_size(size).unwrap();
            for seed in 0..10_000u64 {
                let (cols, rows) = (1 + (seed % 12) as usize, 1 + (seed / 12 % 12) as usize);
                let t = scan_line_tiling(&set, cols, rows, seed)
                    .unwrap_or_else(|e| panic!("{size}-set, seed {seed}: {e}"));
                assert!(tiling_is_valid(&set, &t));
            }
        }
    }
}
