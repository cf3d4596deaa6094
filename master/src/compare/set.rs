//! `texsyn compare SET_DIR`: the measures of a tile set itself (ARCHITECTURE
//! §8): how many distinct tile images it holds, the pixels its tiles share
//! and, for ω-tiles, whether each corner colour got a sample patch of its own.

use std::path::Path;

use anyhow::{ensure, Context, Result};
use serde::{Deserialize, Serialize};

use super::repetition::{tile_copy, tile_measures};
use crate::imaging::{self, ColorImage};

/// Largest `tileset.json` read.
const MAX_SET_FILE: u64 = 16 << 20;

/// The fields of `tileset.json` these measures read.
#[derive(Deserialize)]
struct SetFile {
    method: String,
    tile_width: usize,
    tile_height: usize,
    /// ω-tiles: the sample patch (top-left corner) of each corner colour.
    #[serde(default)]
    patches: Vec<[u32; 2]>,
}

/// The measures of a tile set.
#[derive(Clone, Debug, Serialize)]
pub struct SetScores {
    pub method: String,
    pub tiles: usize,
    /// Distinct tile images (equal pixel for pixel counts once).
    pub distinct_tiles: usize,
    /// Mean over pairs of distinct tile images of the share of equal pixels.
    pub tile_overlap: f64,
    /// The same share between unrelated positions of the tiles (what the
    /// texture's flat regions give by chance; see
    /// [`super::repetition::tile_overlap_chance`]).
    pub tile_overlap_chance: f64,
    /// The nearest pair: the largest share of one tile that is a verbatim
    /// copy of another at one offset (see [`super::repetition::tile_copy`];
    /// absent for one distinct tile or very many).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tile_copy: Option<f64>,
    /// ω-tiles: corner colours, each with its sample patch.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub colours: Option<usize>,
    /// ω-tiles: colours whose sample patch overlaps no earlier colour's patch
    /// by half its area or more.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub distinct_patches: Option<usize>,
    /// ω-tiles: the mean over pairs of colours of the share of a patch's area
    /// that the other patch covers.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub patch_overlap: Option<f64>,
}

/// The share of a `t`×`t` patch at `p` covered by the one at `q`.
fn patch_cover(p: [u32; 2], q: [u32; 2], tw: usize, th: usize) -> f64 {
    let d = |a: u32, b: u32, t: usize| t.saturating_sub(a.abs_diff(b) as usize);
    (d(p[0], q[0], tw) * d(p[1], q[1], th)) as f64 / (tw * th).max(1) as f64
}

/// The measures of the tile set written by `texsyn tiles make` into `dir`.
pub fn set_scores(dir: &Path) -> Result<SetScores> {
    let json = dir.join("tileset.json");
    let meta = std::fs::metadata(&json).with_context(|| {
        format!(
            "{} has no tileset.json: give a directory written by `texsyn tiles make`",
            dir.display()
        )
    })?;
    ensure!(
        meta.is_file() && meta.len() <= MAX_SET_FILE,
        "{} must be a regular file of at most {} MiB",
        json.display(),
        MAX_SET_FILE >> 20
    );
    let file: SetFile = serde_json::from_slice(&std::fs::read(&json)?).with_context(|| {
        format!(
            "{} is not a tile set description; make the set again with `texsyn tiles make`",
            json.display()
        )
    })?;
    let mut tiles: Vec<ColorImage> = Vec::new();
    for n in 1..=999 {
        let p = dir.join(format!("tile_{n:02}.png"));
        if !p.is_file() {
            break;
        }
        let t = imaging::load_color(&p)?;
        ensure!(
            (t.width, t.height) == (file.tile_width, file.tile_height),
            "{} is {}x{} but tileset.json says {}x{}: the set is damaged, make it again",
            p.display(),
            t.width,
            t.height,
            file.tile_width,
            file.tile_height
        );
        tiles.push(t);
    }
    ensure!(
        !tiles.is_empty(),
        "{} holds no tile_01.png: give a directory written by `texsyn tiles make`",
        dir.display()
    );
    let (distinct, overlap, chance) = tile_measures(&tiles);
    let omega = file.method == "omega";
    let (tw, th) = (file.tile_width, file.tile_height);
    let p = &file.patches;
    let distinct_patches = (0..p.len())
        .filter(|&i| (0..i).all(|j| patch_cover(p[i], p[j], tw, th) < 0.5))
        .count();
    let pairs: Vec<f64> = (0..p.len())
        .flat_map(|i| (i + 1..p.len()).map(move |j| (i, j)))
        .map(|(i, j)| patch_cover(p[i], p[j], tw, th))
        .collect();
    Ok(SetScores {
        method: file.method.clone(),
        tiles: tiles.len(),
        distinct_tiles: distinct,
        tile_overlap: overlap.unwrap_or(0.0),
        tile_overlap_chance: chance.unwrap_or(0.0),
        tile_copy: tile_copy(&tiles),
        colours: omega.then_some(p.len()),
        distinct_patches: omega.then_some(distinct_patches),
        patch_overlap: omega.then(|| pairs.iter().sum::<f64>() / pairs.len().max(1) as f64),
    })
}
