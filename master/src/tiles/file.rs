//! The files of a tile-set directory: `tile_NN.png`, `atlas.png`,
//! `tileset.json` (one typed [`TileSetFile`], written and read by the same
//! type) and, for ω-tiles, `ais.json`.

use std::path::{Path, PathBuf};

use anyhow::{ensure, Result};
use serde::{Deserialize, Serialize};

use super::ais::{AisResult, AisSettings, Gene, OmegaTile};
use super::omega::{OmegaSet, COLOUR_NAMES};
use super::template::TemplateChoice;
use super::tileset::{DerivedTile, TileSetSettings};
use crate::imaging::{self, ColorImage};

/// The description of a set in its directory.
pub const TILESET_JSON: &str = "tileset.json";
/// Largest `tileset.json` read.
pub const MAX_TILESET_BYTES: u64 = 16 << 20;

/// The file name of tile `n` (from 1).
pub fn tile_name(n: usize) -> String {
    format!("tile_{n:02}.png")
}

/// The path of tile `n` (from 1) in `dir`.
pub fn tile_path(dir: &Path, n: usize) -> PathBuf {
    dir.join(tile_name(n))
}

/// `tileset.json`: the method is its `"method"` field.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(tag = "method", rename_all = "lowercase")]
pub enum TileSetFile {
    Somol(SomolSetFile),
    Omega(OmegaSetFile),
}

/// `tileset.json` of a Somol–Haindl set.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SomolSetFile {
    pub sample: String,
    pub tile_width: usize,
    pub tile_height: usize,
    pub settings: TileSetSettings,
    pub template: TemplateChoice,
    pub template_given: bool,
    pub template_path_costs: [f64; 2],
    pub template_seconds: f64,
    pub tiles: Vec<SomolEntry>,
    pub seconds: f64,
}

/// One tile of a Somol–Haindl set; the template has no `derived`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SomolEntry {
    pub number: usize,
    pub file: String,
    pub derived: Option<DerivedTile>,
}

/// `tileset.json` of an ω-tile set.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct OmegaSetFile {
    pub sample: String,
    pub tile_width: usize,
    pub tile_height: usize,
    /// Corner colours of each tile (top-left, top-right, bottom-left,
    /// bottom-right), e.g. "BYYR".
    pub set: Vec<String>,
    /// The sample patch of each colour (top-left corner), R, G, B, Y, C, M.
    pub patches: Vec<Gene>,
    pub tiles: Vec<OmegaEntry>,
    pub search_seconds: f64,
    pub build_seconds: f64,
    pub seconds: f64,
}

/// One ω-tile.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct OmegaEntry {
    pub number: usize,
    pub file: String,
    #[serde(flatten)]
    pub tile: OmegaTile,
}

/// `ais.json`: the immune search of an ω-tile set and its random baseline.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct AisFile {
    pub settings: AisSettings,
    pub evaluation_steps: usize,
    pub evaluation_side: usize,
    pub result: AisResult,
    pub random_mean_f: Option<f64>,
    pub random_best_f: Option<f64>,
    pub random_sets: usize,
    /// The same at full resolution (Table 2's comparison): the search's
    /// patches and the random sets' mean and best affinity.
    #[serde(default)]
    pub full_f: Option<f64>,
    #[serde(default)]
    pub full_random_mean_f: Option<f64>,
    #[serde(default)]
    pub full_random_best_f: Option<f64>,
    /// Seconds of the full-resolution comparison.
    #[serde(default)]
    pub full_seconds: f64,
}

impl TileSetFile {
    /// Writes `dir/tileset.json`.
    pub fn write(&self, dir: &Path) -> Result<()> {
        imaging::save_bytes(&dir.join(TILESET_JSON), &serde_json::to_vec_pretty(self)?)
    }

    /// Reads `dir/tileset.json` (a regular file of at most
    /// [`MAX_TILESET_BYTES`]); a cut or malformed file is an error naming it
    /// and the fix.
    pub fn read(dir: &Path) -> Result<Self> {
        let path = dir.join(TILESET_JSON);
        ensure!(
            path.is_file(),
            "{} has no {TILESET_JSON}; make one with `texsyn tiles make`",
            dir.display()
        );
        let bytes = imaging::read_regular(&path, MAX_TILESET_BYTES, "tile-set file")?;
        Self::parse(&bytes, &path)
    }

    /// Parses the bytes of `path` (for messages).
    pub fn parse(bytes: &[u8], path: &Path) -> Result<Self> {
        serde_json::from_slice(bytes).map_err(|e| {
            anyhow::anyhow!(
                "{} is damaged, cut or malformed ({e}); make the set again with `texsyn tiles make`",
                path.display()
            )
        })
    }

    /// The number of tiles listed.
    pub fn tile_count(&self) -> usize {
        match self {
            Self::Somol(f) => f.tiles.len(),
            Self::Omega(f) => f.set.len(),
        }
    }

    /// The ω-tile set described, if it is one.
    pub fn omega_set(&self) -> Result<Option<OmegaSet>> {
        let Self::Omega(f) = self else {
            return Ok(None);
        };
        let tiles = f
            .set
            .iter()
            .map(|n| {
                let corners: Vec<u8> = n
                    .chars()
                    .filter_map(|c| COLOUR_NAMES.iter().position(|&k| k == c))
                    .map(|k| k as u8)
                    .collect();
                <[u8; 4]>::try_from(corners).map_err(|_| {
                    anyhow::anyhow!(
                        "{TILESET_JSON}: '{n}' is not four corner colours; the set is damaged, make it again with `texsyn tiles make`"
                    )
                })
            })
            .collect::<Result<Vec<_>>>()?;
        let colours = tiles
            .iter()
            .flatten()
            .map(|&c| usize::from(c) + 1)
            .max()
            .unwrap_or(0);
        Ok(Some(OmegaSet { colours, tiles }))
    }
}

impl AisFile {
    /// Writes `dir/ais.json`.
    pub fn write(&self, dir: &Path) -> Result<()> {
        imaging::save_bytes(&dir.join("ais.json"), &serde_json::to_vec_pretty(self)?)
    }
}

/// The tile files of a set directory: `tile_01.png` on, up to the first
/// missing number.
pub fn tile_paths(dir: &Path) -> Vec<PathBuf> {
    (1..)
        .map(|n| tile_path(dir, n))
        .take_while(|p| p.is_file())
        .collect()
}

/// The tiles at `paths`, of the set `file` describes in `dir`: as many as it
/// lists, all of one size.
pub fn load_tiles(dir: &Path, paths: &[PathBuf], file: &TileSetFile) -> Result<Vec<ColorImage>> {
    ensure!(!paths.is_empty(), "{} holds no tile_01.png", dir.display());
    ensure!(
        file.tile_count() == paths.len(),
        "{TILESET_JSON} lists {} tiles but {} holds {}: the set is damaged, make it again with `texsyn tiles make`",
        file.tile_count(),
        dir.display(),
        paths.len()
    );
    let tiles = paths
        .iter()
        .map(|p| imaging::load_color(p))
        .collect::<Result<Vec<_>>>()?;
    let (tw, th) = (tiles[0].width, tiles[0].height);
    ensure!(
        tiles.iter().all(|t| (t.width, t.height) == (tw, th)),
        "the tiles of {} differ in size: the set is damaged, make it again with `texsyn tiles make`",
        dir.display()
    );
    Ok(tiles)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cut_or_malformed_file_is_an_error_naming_it_and_the_fix() {
        let p = Path::new("set/tileset.json");
        for bad in [
            &b"{\"method\": \"omega\", \"sample\": \"a.png\", \"tile_"[..],
            b"[]",
            b"{\"method\": 3}",
            b"",
        ] {
            let e = TileSetFile::parse(bad, p).unwrap_err().to_string();
            assert!(
                e.contains("set/tileset.json") && e.contains("texsyn tiles make"),
                "{e}"
            );
        }
    }
}
