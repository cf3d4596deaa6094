//! Making a tile set into a directory: the tiles, their atlas (all tiles in
//! one row) and `tileset.json`; for ω-tiles also `ais.json`.

use std::path::Path;
use std::time::Instant;

use anyhow::Result;

use super::ais::{self, Evaluator};
use super::config::OmegaConfig;
use super::file::{
    tile_name, tile_path, AisFile, OmegaEntry, OmegaSetFile, SomolEntry, SomolSetFile, TileSetFile,
};
use super::grid::{assemble, check_grid};
use super::omega::OmegaSet;
use super::tileset::{make_tile_set, TileSetSettings};
use crate::budget::Budget;
use crate::imaging::{self, ColorImage};
use crate::progress::Progress;

/// What a run made, for its report.
#[derive(Clone, Debug)]
pub struct Made {
    pub tiles: usize,
    pub tile_width: usize,
    pub tile_height: usize,
    /// The immune search's best affinity (ω-tiles).
    pub best_f: Option<f64>,
    /// Seconds since `started`.
    pub seconds: f64,
}

/// Writes the tiles and their atlas into `dir`.
fn write_tiles(dir: &Path, tiles: &[ColorImage]) -> Result<()> {
    for (k, t) in tiles.iter().enumerate() {
        imaging::save_color(&tile_path(dir, k + 1), t)?;
    }
    let index = vec![(1..=tiles.len()).collect::<Vec<_>>()];
    imaging::save_color(&dir.join("atlas.png"), &assemble(tiles, &index)?)
}

/// Makes a Somol–Haindl tile set (§3) of `sample` (named `sample_name` in
/// `tileset.json`) into `dir`, from the template given or one chosen, with
/// `settings` of [`super::SomolConfig::settings`].
pub fn make_somol(
    settings: &TileSetSettings,
    sample: (&ColorImage, &str),
    template: Option<&ColorImage>,
    dir: &Path,
    progress: &dyn Progress,
    started: Instant,
) -> Result<Made> {
    let set = make_tile_set(sample.0, template, settings, progress)?;
    write_tiles(dir, &set.tiles)?;
    let entries = (0..set.tiles.len())
        .map(|k| SomolEntry {
            number: k + 1,
            file: tile_name(k + 1),
            derived: k.checked_sub(1).map(|d| set.derived[d].clone()),
        })
        .collect();
    let (tw, th) = (set.tiles[0].width, set.tiles[0].height);
    let seconds = started.elapsed().as_secs_f64();
    TileSetFile::Somol(SomolSetFile {
        sample: sample.1.to_string(),
        tile_width: tw,
        tile_height: th,
        settings: *settings,
        template: set.template,
        template_given: template.is_some(),
        template_path_costs: set.template_path_costs,
        template_seconds: set.template_seconds,
        tiles: entries,
        seconds,
    })
    .write(dir)?;
    Ok(Made {
        tiles: set.tiles.len(),
        tile_width: tw,
        tile_height: th,
        best_f: None,
        seconds,
    })
}

/// The evaluator of an ω-tile set of `sample`, checked before any search.
pub fn omega_evaluator<'a>(
    cfg: &OmegaConfig,
    set: &'a OmegaSet,
    sample: &ColorImage,
) -> Result<Evaluator<'a>> {
    cfg.validate()?;
    let side = cfg.tile_side(sample);
    let evaluator = Evaluator::new(set, sample, side)?;
    check_grid(
        set.tiles.len(),
        1,
        (side, side),
        "--set or --tile-size (the atlas)",
        &Budget::default(),
    )?;
    Ok(evaluator)
}

/// Makes an ω-tile set (§4) of `sample` (named `sample_name` in
/// `tileset.json`) into `dir`: the immune search for its patches, the random
/// baselines (at the search's level and at full resolution) and the tiles.
pub fn make_omega(
    cfg: &OmegaConfig,
    evaluator: &mut Evaluator,
    sample: (&ColorImage, &str),
    dir: &Path,
    progress: &dyn Progress,
    started: Instant,
) -> Result<Made> {
    let image = sample.0;
    let settings = cfg.ais_settings();
    let result = ais::search(evaluator, image, &settings, progress)?;
    let sets = ais::random_sets(evaluator, image, cfg.baseline, cfg.seed ^ 0x5eed);
    let random = ais::sample_affinities(evaluator, &sets, settings.lambda)?;
    let t = Instant::now();
    let (full_f, full_random) = if evaluator.steps == 0 {
        (Some(result.best_f), random.clone())
    } else if cfg.baseline > 0 {
        let mut full = Evaluator::at_level(evaluator.set, image, evaluator.tile, 0)?;
        let f = ais::sample_affinities(
            &mut full,
            std::slice::from_ref(&result.genes),
            settings.lambda,
        )?;
        (
            f.first().copied(),
            ais::sample_affinities(&mut full, &sets, settings.lambda)?,
        )
    } else {
        (None, Vec::new())
    };
    let full_seconds = t.elapsed().as_secs_f64();
    let mean = |v: &[f64]| (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64);
    let t = Instant::now();
    let (images, built) = ais::build_tiles(evaluator, image, &result.genes)?;
    let build_seconds = t.elapsed().as_secs_f64();
    write_tiles(dir, &images)?;
    let set: Vec<String> = built.iter().map(|b| b.corners.clone()).collect();
    let entries = built
        .into_iter()
        .enumerate()
        .map(|(k, tile)| OmegaEntry {
            number: k + 1,
            file: tile_name(k + 1),
            tile,
        })
        .collect();
    AisFile {
        settings,
        evaluation_steps: evaluator.steps,
        evaluation_side: evaluator.side,
        result: result.clone(),
        random_mean_f: mean(&random),
        random_best_f: random.iter().copied().reduce(f64::max),
        random_sets: random.len(),
        full_f,
        full_random_mean_f: mean(&full_random),
        full_random_best_f: full_random.iter().copied().reduce(f64::max),
        full_seconds,
    }
    .write(dir)?;
    let side = evaluator.tile;
    let seconds = started.elapsed().as_secs_f64();
    TileSetFile::Omega(OmegaSetFile {
        sample: sample.1.to_string(),
        tile_width: side,
        tile_height: side,
        set,
        patches: result.genes,
        tiles: entries,
        search_seconds: result.seconds,
        build_seconds,
        seconds,
    })
    .write(dir)?;
    Ok(Made {
        tiles: images.len(),
        tile_width: side,
        tile_height: side,
        best_f: Some(result.best_f),
        seconds,
    })
}
