//! `texsyn compare`: a texture against its sample, or a tile set directory
//! (ARCHITECTURE §8). Prints JSON.

use std::path::PathBuf;

use anyhow::{bail, Result};
use clap::Args;

use crate::compare::{self, Grid};
use crate::imaging;

#[derive(Args, Debug)]
pub struct CompareArgs {
    /// The reference texture (the sample), or a tile set directory written by
    /// `texsyn tiles make` (then give no second image).
    pub a: PathBuf,
    /// The texture compared with the sample.
    pub b: Option<PathBuf>,
    /// B is a grid of tiles of this size (WxH): its seam score is taken at
    /// the tile joints and its tiles are compared (default: B is one tileable
    /// image, its seam is the wrap-around).
    #[arg(long)]
    pub tile: Option<String>,
    /// With --tile: the grid wraps (a Somol set tiles the plane), so its outer
    /// edge is a joint too. An ω-tiling does not wrap.
    #[arg(long, requires = "tile")]
    pub wrap: bool,
}

/// The scores of B against A, with B's contrast and pixel checker against
/// A's.
#[derive(serde::Serialize)]
struct Pair {
    #[serde(flatten)]
    scores: compare::Scores,
    /// Per channel standard deviation of B over A's.
    contrast: [f64; 3],
    /// B's [`compare::checker_energy`] over A's.
    checker: f64,
}

pub fn run(a: &CompareArgs) -> Result<()> {
    let json = match &a.b {
        None if a.a.is_dir() => {
            if a.tile.is_some() {
                bail!("--tile belongs to a grid image; a tile set directory is measured as it is");
            }
            serde_json::to_string_pretty(&compare::set::set_scores(&a.a)?)?
        }
        None => bail!(
            "give the texture to compare with {} (texsyn compare sample.png out.png), or a tile set directory alone",
            a.a.display()
        ),
        Some(b) => {
            let (ia, ib) = (imaging::load_color(&a.a)?, imaging::load_color(b)?);
            let grid = match &a.tile {
                Some(t) => {
                    let (tile_width, tile_height) = super::args::parse_pair(t, "--tile")?;
                    Some(Grid {
                        tile_width,
                        tile_height,
                        wrap: a.wrap,
                    })
                }
                None => None,
            };
            let scores = compare::compare_with(&ia, &ib, grid)?;
            let ea = compare::checker_energy(&ia);
            serde_json::to_string_pretty(&Pair {
                scores,
                contrast: compare::contrast_ratio(&ia, &ib),
                checker: if ea > 0.0 {
                    compare::checker_energy(&ib) / ea
                } else {
                    0.0
                },
            })?
        }
    };
    println!("{json}");
    Ok(())
}
