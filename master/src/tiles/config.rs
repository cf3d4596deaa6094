//! The validated settings of `tiles make`, with the papers' defaults: the
//! Somol–Haindl tile set (§3) and the ω-tile set of Dong, Zhou and Paul
//! (§4.4).

use std::ops::RangeInclusive;

use anyhow::{ensure, Result};

use super::ais::AisSettings;
use super::grid::check_grid;
use super::omega::OmegaSet;
use super::stitch::Blend;
use super::tileset::{PathSearch, TileSetSettings};
use crate::budget::Budget;
use crate::imaging::ColorImage;

/// Tiles of a Somol–Haindl set, the template included.
pub const TILES: RangeInclusive<usize> = 1..=99;
/// Random candidate patch positions per tile.
pub const CANDIDATES: RangeInclusive<usize> = 1..=10_000;
/// Antibodies of the immune search (N_p).
pub const POPULATION: RangeInclusive<usize> = 2..=1_000;
/// Generations of the immune search (N_g).
pub const GENERATIONS: RangeInclusive<usize> = 1..=10_000;
/// Generations without improvement before the search stops (N_o, 0 = never).
pub const PATIENCE: RangeInclusive<usize> = 0..=10_000;
/// Random patch sets of the baseline.
pub const BASELINE: RangeInclusive<usize> = 0..=10_000;
/// Overlap and belt width.
pub const OVERLAP: RangeInclusive<usize> = 1..=1 << 14;
/// Template placements stitched and compared.
pub const TEMPLATES: RangeInclusive<usize> = 1..=64;
/// Largest pull of the patch paths, per pixel of the belt.
pub const PULL_MAX: f32 = 1000.0;
/// Least pull of the patch paths towards the tile's edge by default (each
/// tile doubles it while the set's mean overlap is over budget).
pub const DEFAULT_PULL: f32 = 4.0;
/// Default weight of the template ring's atypicality (`--template-ring`).
pub const DEFAULT_TEMPLATE_RING: f64 = 1.0;
/// Greatest `--template-ring`.
pub const TEMPLATE_RING_MAX: f64 = 100.0;
/// Mean share of equal pixels between two tiles of a set that the pulls
/// keep to by default.
pub const DEFAULT_MAX_OVERLAP: f64 = 0.09;
/// Border strip of every derived tile that stays the template's: one pixel,
/// so both sides of every joint are the template's own continuation.
pub const MARGIN: usize = 0;

/// Correlation lengths a default belt spans (see [`default_belt`]).
pub const BELT_CORRELATION_LENGTHS: usize = 3;

/// The autocorrelation level at which the sample's correlation length is read.
pub const BELT_CORRELATION_LEVEL: f64 = 0.25;

/// Largest side of the centre crop whose correlation length sets the belt.
pub const BELT_CORRELATION_SIDE: usize = 512;

/// The patch belt of a `size`-pixel tile by default: the paper's
/// `w_P = w_T`, a tenth of the tile, at least 3 pixels, widened to
/// [`BELT_CORRELATION_LENGTHS`] times the sample's correlation length
/// `corr` (`filters::correlation_length` at [`BELT_CORRELATION_LEVEL`]), at
/// most a fifth of the tile. A path can only pass round an object the belt
/// holds: the 512² beans (correlation length 12, beans about 50 px across)
/// were sliced along most joints of 128-px tiles by the tenth's 12-px belt.
/// The template share budget, not the belt, keeps the template's band thin.
pub fn default_belt(size: usize, corr: usize) -> usize {
    (size / 10)
        .max(3)
        .max((BELT_CORRELATION_LENGTHS * corr).min(size / 5))
}

/// Tile side.
pub const TILE_SIZE: RangeInclusive<usize> = 4..=1 << 14;

/// Refuses `value` of `flag` outside `range`, naming both.
pub fn check_range(flag: &str, value: usize, range: &RangeInclusive<usize>) -> Result<()> {
    ensure!(
        range.contains(&value),
        "{flag} {value} is out of range: give {}..={}",
        range.start(),
        range.end()
    );
    Ok(())
}

/// A Somol–Haindl tile set to make (§3).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SomolConfig {
    /// Number of tiles, the template included.
    pub tiles: usize,
    /// Greatest template side S (searched in [0.8·S, S]); default half the
    /// sample's smaller side, at most 256.
    pub tile_size: Option<usize>,
    /// Template overlap `w_T`; default a tenth of the tile (§4).
    pub overlap: Option<usize>,
    /// Patch belt `w_P`; default [`default_belt`] (the paper's is `w_T`).
    pub belt: Option<usize>,
    /// Least pull of the patch paths towards the tile's edge (0 = the
    /// paper's search); each tile doubles it until the set's mean overlap
    /// is within `max_overlap`.
    pub pull: f32,
    /// Mean share of equal pixels between two tiles of the set (1 = no
    /// limit: the least pull everywhere).
    pub max_overlap: f64,
    /// Template placements stitched and compared (1 = the paper's single
    /// best by border error).
    pub template_candidates: usize,
    /// Weight of how far the template's border ring is from the sample's
    /// typical brightness, contrast and detail in the template choice (0 =
    /// border error alone).
    pub template_ring: f64,
    pub candidates: usize,
    pub path: PathSearch,
    /// How far from each path the stitch blends.
    pub blend: Blend,
    pub seed: u64,
}

impl Default for SomolConfig {
    fn default() -> Self {
        Self {
            tiles: 8,
            tile_size: None,
            overlap: None,
            belt: None,
            pull: DEFAULT_PULL,
            max_overlap: DEFAULT_MAX_OVERLAP,
            template_candidates: 3,
            template_ring: DEFAULT_TEMPLATE_RING,
            candidates: 48,
            path: PathSearch::Oscillating,
            blend: Blend::Feather,
            seed: 1,
        }
    }
}

impl SomolConfig {
    /// Checks every count against its range.
    pub fn validate(&self) -> Result<()> {
        check_range("--tiles", self.tiles, &TILES)?;
        check_range("--candidates", self.candidates, &CANDIDATES)?;
        if let Some(o) = self.overlap {
            check_range("--overlap", o, &OVERLAP)?;
        }
        if let Some(b) = self.belt {
            check_range("--belt", b, &OVERLAP)?;
        }
        check_range(
            "--template-candidates",
            self.template_candidates,
            &TEMPLATES,
        )?;
        ensure!(
            self.template_ring.is_finite()
                && (0.0..=TEMPLATE_RING_MAX).contains(&self.template_ring),
            "--template-ring {} is out of range: give 0..={TEMPLATE_RING_MAX}",
            self.template_ring
        );
        ensure!(
            self.pull.is_finite() && (0.0..=PULL_MAX).contains(&self.pull),
            "--pull {} is out of range: give 0..={PULL_MAX}",
            self.pull
        );
        ensure!(
            (0.0..=1.0).contains(&self.max_overlap),
            "--max-overlap {} is out of range: give 0..=1",
            self.max_overlap
        );
        if let Some(t) = self.tile_size {
            check_range("--tile-size", t, &TILE_SIZE)?;
        }
        Ok(())
    }

    /// The tile-set settings for `sample`, or for the side of a given
    /// `template` (its smaller side), checked so that the atlas of all tiles
    /// in one row fits the image limits and memory.
    pub fn settings(
        &self,
        sample: &ColorImage,
        template: Option<&ColorImage>,
    ) -> Result<TileSetSettings> {
        self.validate()?;
        let size = match (template, self.tile_size) {
            (Some(t), _) => t.width.min(t.height),
            (None, Some(s)) => s,
            (None, None) => (sample.width.min(sample.height) / 2).min(256),
        };
        // A tile side the user gave is the side of every tile; otherwise the
        // template's side is chosen from 4/5 of the default to it (§3.1).
        let min_size = match (template, self.tile_size) {
            (None, Some(_)) => size,
            _ => size * 4 / 5,
        };
        let overlap = self.overlap.unwrap_or((size / 10).max(2));
        ensure!(
            2 * overlap < size,
            "--overlap {overlap} must be under half the {size}-pixel tile: give a smaller --overlap or a larger --tile-size"
        );
        let belt = match self.belt {
            Some(b) => b,
            None => {
                // A centre crop bounds the FFT's memory on large samples;
                // it holds lags far beyond any belt's.
                let (cw, ch) = (
                    sample.width.min(BELT_CORRELATION_SIDE),
                    sample.height.min(BELT_CORRELATION_SIDE),
                );
                let crop = sample.crop((sample.width - cw) / 2, (sample.height - ch) / 2, cw, ch);
                let lum = crate::imaging::colour::luminance(&crop);
                let corr = crate::filters::correlation_length(
                    &lum.data,
                    (lum.width, lum.height),
                    BELT_CORRELATION_LEVEL,
                );
                default_belt(size, corr)
            }
        };
        ensure!(
            2 * (belt + MARGIN) < size,
            "--belt {belt} and the {MARGIN}-pixel margin must stay under half the {size}-pixel tile: give a smaller --belt or a larger --tile-size"
        );
        let atlas = "--tiles or --tile-size (the atlas)";
        check_grid(self.tiles, 1, (size, size), atlas, &Budget::default())?;
        Ok(TileSetSettings {
            tiles: self.tiles,
            min_size: min_size.max(2 * overlap + 1),
            max_size: size,
            overlap,
            belt,
            margin: MARGIN,
            pull: self.pull,
            max_overlap: self.max_overlap,
            template_candidates: self.template_candidates,
            ring_weight: self.template_ring,
            candidates: self.candidates,
            refine: 4,
            path: self.path,
            blend: self.blend,
            seed: self.seed,
        })
    }
}

/// An ω-tile set to make (Dong, Zhou and Paul).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct OmegaConfig {
    /// The set: 8 (4 patches), 17 (5) or 38 (6) tiles.
    pub set: usize,
    /// Tile side; default 5/8 of the sample's smaller side, even.
    pub tile_size: Option<usize>,
    /// N_p, N_g and N_o (0 = run all N_g) of the immune search.
    pub population: usize,
    pub generations: usize,
    pub patience: usize,
    /// Random patch sets whose affinity `ais.json` reports (0 = none).
    pub baseline: usize,
    pub seed: u64,
}

impl Default for OmegaConfig {
    fn default() -> Self {
        let ais = AisSettings::default();
        Self {
            set: 38,
            tile_size: None,
            population: ais.population,
            generations: ais.generations,
            patience: ais.patience,
            baseline: 100,
            seed: ais.seed,
        }
    }
}

impl OmegaConfig {
    /// Checks every count against its range and the set's size.
    pub fn validate(&self) -> Result<()> {
        check_range("--population", self.population, &POPULATION)?;
        check_range("--generations", self.generations, &GENERATIONS)?;
        check_range("--patience", self.patience, &PATIENCE)?;
        check_range("--baseline", self.baseline, &BASELINE)?;
        if let Some(t) = self.tile_size {
            check_range("--tile-size", t, &TILE_SIZE)?;
        }
        OmegaSet::of_size(self.set).map(drop)
    }

    /// The tile set's corner colours.
    pub fn omega_set(&self) -> Result<OmegaSet> {
        OmegaSet::of_size(self.set)
    }

    /// The tile side for `sample`.
    pub fn tile_side(&self, sample: &ColorImage) -> usize {
        self.tile_size
            .unwrap_or((sample.width.min(sample.height) * 5 / 8) & !1)
    }

    /// The immune search's settings: the paper's, with these counts.
    pub fn ais_settings(&self) -> AisSettings {
        AisSettings {
            population: self.population,
            generations: self.generations,
            patience: if self.patience == 0 {
                usize::MAX
            } else {
                self.patience
            },
            seed: self.seed,
            ..AisSettings::default()
        }
    }
}

/// The settings of `tiles make`, by method.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum MakeConfig {
    Somol(SomolConfig),
    Omega(OmegaConfig),
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_out_of_range_are_refused_by_flag() {
        assert!(SomolConfig::default().validate().is_ok());
        assert!(OmegaConfig::default().validate().is_ok());
        let huge = usize::MAX;
        let somol = [
            SomolConfig {
                candidates: huge,
                ..Default::default()
            },
            SomolConfig {
                overlap: Some(0),
                ..Default::default()
            },
            SomolConfig {
                tiles: 0,
                ..Default::default()
            },
        ];
        for (c, flag) in somol.iter().zip(["--candidates", "--overlap", "--tiles"]) {
            let e = c.validate().unwrap_err().to_string();
            assert!(e.contains(flag) && e.contains("out of range"), "{e}");
        }
        let omega = [
            OmegaConfig {
                population: huge,
                ..Default::default()
            },
            OmegaConfig {
                baseline: huge,
                ..Default::default()
            },
        ];
        for (c, flag) in omega.iter().zip(["--population", "--baseline"]) {
            let e = c.validate().unwrap_err().to_string();
            assert!(e.contains(flag) && e.contains("out of range"), "{e}");
        }
        let e = OmegaConfig {
            set: 9,
            ..Default::default()
        }
        .validate()
        .unwrap_err();
        assert!(e.to_string().contains("--set 8, 17 or 38"), "{e}");
    }

    #[test]
    fn the_overlap_must_stay_under_half_the_tile() {
        let sample = ColorImage::new(200, 200);
        let c = SomolConfig {
            tile_size: Some(96),
            overlap: Some(48),
            ..Default::default()
        };
        let e = c.settings(&sample, None).unwrap_err().to_string();
        assert!(e.contains("--overlap 48"), "{e}");
        let s = SomolConfig::default().settings(&sample, None).unwrap();
        assert_eq!(
            (s.max_size, s.min_size, s.overlap, s.belt, s.margin),
            (100, 80, 10, 10, 0),
            "the belt is the paper's w_P = w_T"
        );
        // Large objects widen it, up to a fifth of the tile; small ones
        // keep the tenth.
        assert_eq!(default_belt(128, 3), 12);
        assert_eq!(default_belt(128, 6), 18);
        assert_eq!(default_belt(128, 12), 25);
        assert_eq!(default_belt(20, 0), 3);
        // A sample of discs 24 px across (pitch 48) widens the default belt
        // of its 100-px tiles to a fifth; the flat one above keeps the tenth.
        let discs = ColorImage::from_vec(
            200,
            200,
            (0..200 * 200)
                .flat_map(|i: usize| {
                    let (x, y) = (i % 200 % 48, i / 200 % 48);
                    let inside = x.abs_diff(24).pow(2) + y.abs_diff(24).pow(2) <= 144;
                    [if inside { 210u8 } else { 30 }; 3]
                })
                .collect(),
        );
        let s = SomolConfig::default().settings(&discs, None).unwrap();
        assert_eq!((s.max_size, s.belt), (100, 20), "objects widen the belt");
        let overlaps = [-0.1, 1.5, f64::NAN].map(|bad| SomolConfig {
            max_overlap: bad,
            ..Default::default()
        });
        let rings =
            [-1.0, TEMPLATE_RING_MAX + 1.0, f64::INFINITY, f64::NAN].map(|bad| SomolConfig {
                template_ring: bad,
                ..Default::default()
            });
        let refused = (overlaps.iter().map(|c| ("--max-overlap", c)))
            .chain(rings.iter().map(|c| ("--template-ring", c)));
        for (flag, config) in refused {
            let e = config.validate().unwrap_err().to_string();
            assert!(e.contains(flag), "{e}");
        }
        let given = SomolConfig {
            tile_size: Some(64),
            ..Default::default()
        };
        let s = given.settings(&sample, None).unwrap();
        assert_eq!((s.max_size, s.min_size), (64, 64), "a given side is kept");
    }
}
