//! Index-matrix tiling (Somol–Haindl §3, Fig. 10): a tile set laid out in
//! a grid by an index matrix of tile numbers, read from CSV or JSON or drawn
//! at random, checked against the image and memory limits before any work.

use std::path::Path;

use anyhow::{Context, Result};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::omega::{scan_line_tiling, tiling_is_valid, OmegaSet};
use crate::budget::Budget;
use crate::imaging::{self, ColorImage};

/// Largest index-matrix file read.
pub const MAX_INDEX_BYTES: u64 = 16 << 20;

/// Checks, before anything is allocated, that `cols`×`rows` tiles of
/// `tile` (width, height) make an image within the format limits
/// ([`imaging::MAX_SIDE`], [`imaging::MAX_PIXELS`]) whose assembly fits the
/// `budget`; `flag` (e.g. `--grid`) names what to change.
pub fn check_grid(
    cols: usize,
    rows: usize,
    tile: (usize, usize),
    flag: &str,
    budget: &Budget,
) -> Result<()> {
    let (tw, th) = tile;
    let (w, h) = (cols.saturating_mul(tw), rows.saturating_mul(th));
    imaging::check_size(w, h, "the assembled grid").with_context(|| {
        format!("{flag}: {cols}x{rows} tiles of {tw}x{th} are too many; give a smaller {flag}")
    })?;
    // The image and the encoder's copy of it.
    let needed = (w as u64) * (h as u64) * 3 * 2;
    budget.check(
        &format!("a {cols}x{rows} grid of {tw}x{th} tiles ({w}x{h} pixels)"),
        needed,
        &format!("give a smaller {flag}"),
    )
}

/// Checks that `index` is a non-empty rectangle of tile numbers in
/// `1..=tiles`; its (columns, rows).
pub fn check_index(index: &[Vec<usize>], tiles: usize) -> Result<(usize, usize)> {
    let rows = index.len();
    let cols = index.first().map_or(0, Vec::len);
    anyhow::ensure!(
        rows > 0 && cols > 0 && index.iter().all(|r| r.len() == cols),
        "the index matrix must be a non-empty rectangle"
    );
    for (r, row) in index.iter().enumerate() {
        for (c, &n) in row.iter().enumerate() {
            anyhow::ensure!(
                (1..=tiles).contains(&n),
                "tile {n} at row {} column {} is not in 1..={tiles}",
                r + 1,
                c + 1,
            );
        }
    }
    Ok((cols, rows))
}

/// Lays tiles in a grid: `index[row][col]` is a tile number from 1 (as in
/// the paper's index matrices).
pub fn assemble(tiles: &[ColorImage], index: &[Vec<usize>]) -> Result<ColorImage> {
    anyhow::ensure!(!tiles.is_empty(), "no tiles");
    let (tw, th) = (tiles[0].width, tiles[0].height);
    anyhow::ensure!(
        tiles.iter().all(|t| (t.width, t.height) == (tw, th)),
        "the tiles differ in size"
    );
    let (cols, rows) = check_index(index, tiles.len())?;
    imaging::check_size(
        cols.saturating_mul(tw),
        rows.saturating_mul(th),
        "the assembled grid",
    )?;
    let mut out = ColorImage::new(cols * tw, rows * th);
    for (r, row) in index.iter().enumerate() {
        for (c, &n) in row.iter().enumerate() {
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

/// Where the index matrix of a grid comes from.
#[derive(Clone, Copy, Debug)]
pub enum Layout<'a> {
    /// An index-matrix file ([`read_index`]).
    Index(&'a Path),
    /// `cols`×`rows` tiles drawn with `seed`.
    Grid { cols: usize, rows: usize, seed: u64 },
}

/// The index matrix of `layout` for a set of `tiles` tiles of size `tile`,
/// checked ([`check_index`], [`check_grid`]) before any image is made: a
/// drawn grid of ω-tiles of `omega` comes from the scan-line tiler (§3.1 of
/// Dong, Zhou and Paul), one of other tiles from [`random_index`]; a given
/// matrix of ω-tiles must agree on every shared corner.
pub fn layout(
    layout: Layout,
    tiles: usize,
    tile: (usize, usize),
    omega: Option<&OmegaSet>,
    budget: &Budget,
) -> Result<Vec<Vec<usize>>> {
    match layout {
        Layout::Index(p) => {
            let index = read_index(p)?;
            let (cols, rows) = check_index(&index, tiles)?;
            check_grid(cols, rows, tile, "--index", budget)?;
            if let Some(o) = omega {
                let zero: Vec<Vec<usize>> = index
                    .iter()
                    .map(|r| r.iter().map(|&n| n - 1).collect())
                    .collect();
                anyhow::ensure!(
                    tiling_is_valid(o, &zero),
                    "{}: neighbouring ω-tiles must agree on their shared corner colours",
                    p.display()
                );
            }
            Ok(index)
        }
        Layout::Grid { cols, rows, seed } => {
            check_grid(cols, rows, tile, "--grid", budget)?;
            Ok(match omega {
                Some(o) => scan_line_tiling(o, cols, rows, seed)?
                    .into_iter()
                    .map(|r| r.into_iter().map(|k| k + 1).collect())
                    .collect(),
                None => random_index(tiles, cols, rows, seed),
            })
        }
    }
}

/// Reads an index matrix of tile numbers from 1: JSON (an array of arrays)
/// or CSV (comma, semicolon or whitespace separated; `#` starts a comment).
pub fn read_index(path: &Path) -> Result<Vec<Vec<usize>>> {
    let bytes = imaging::read_regular(path, MAX_INDEX_BYTES, "index matrix")?;
    let text = String::from_utf8(bytes).map_err(|_| {
        anyhow::anyhow!(
            "index matrix {} is not UTF-8 text; give a CSV or JSON file of tile numbers",
            path.display()
        )
    })?;
    parse_index(&text, path)
}

/// Parses the text of an index matrix read from `path` (for messages).
pub fn parse_index(text: &str, path: &Path) -> Result<Vec<Vec<usize>>> {
    if text.trim_start().starts_with('[') {
        return serde_json::from_str(text).with_context(|| {
            format!(
                "{} is not a JSON array of rows of tile numbers, e.g. [[1,2],[2,1]]",
                path.display()
            )
        });
    }
    let mut rows = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let row = line
            .split(|c: char| c == ',' || c == ';' || c.is_whitespace())
            .filter(|s| !s.is_empty())
            .map(|s| {
                s.parse::<usize>().with_context(|| {
                    format!(
                        "{} line {}: '{s}' is not a tile number",
                        path.display(),
                        n + 1
                    )
                })
            })
            .collect::<Result<Vec<_>>>()?;
        rows.push(row);
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grids_past_the_limits_are_refused_by_flag() {
        let b = Budget::of_mib(Some(1));
        assert!(check_grid(4, 4, (64, 64), "--grid", &b).is_ok());
        let e = format!(
            "{:#}",
            check_grid(2000, 2000, (64, 64), "--grid", &b).unwrap_err()
        );
        assert!(e.contains("--grid") && e.contains("over the limit"), "{e}");
        let e = format!(
            "{:#}",
            check_grid(100_000, 1, (32, 32), "--grid", &b).unwrap_err()
        );
        assert!(e.contains("per side"), "{e}");
        let e = check_grid(16, 16, (64, 64), "--index", &b)
            .unwrap_err()
            .to_string();
        assert!(e.contains("--max-memory") && e.contains("--index"), "{e}");
    }

    #[test]
    fn index_matrices_parse_and_bad_ones_name_the_line() {
        let p = Path::new("m.csv");
        let csv = parse_index("# fig 10\n1, 2;3\n\n4 5 6 # end\n", p).unwrap();
        assert_eq!(csv, vec![vec![1, 2, 3], vec![4, 5, 6]]);
        assert_eq!(parse_index(" [[1,2,3],[4,5,6]]", p).unwrap(), csv);
        let e = parse_index("1,2\n3,x\n", p).unwrap_err().to_string();
        assert!(e.contains("line 2") && e.contains("'x'"), "{e}");
        assert!(parse_index("[[1,2],", p).is_err());
    }
}
