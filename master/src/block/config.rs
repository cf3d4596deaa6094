//! What to make and with which parameters (Stahlhut §4–§6, §9, §10.3;
//! ARCHITECTURE §3.1, §3.6, §3.9).

use anyhow::{ensure, Result};
use texsyn_engine::{Geometry, Metric, Weights};

use super::repeats::RepeatControl;
use crate::imaging::{self, ColorImage};
use crate::lattice::Lattice;

/// How full synthesis grows a new texture.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum SynthMethod {
    /// Grow outwards from a seeded sample patch placed at the canvas centre.
    Grow,
    /// The paper's scan-line full synthesis: causal L-shaped neighbourhood,
    /// canvas initialised with noise drawn from the sample (ARCHITECTURE §3.6).
    Scanline,
}

/// How a copied block meets the canvas around it (ARCHITECTURE §3.12).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Stitch {
    /// The block's square edge (the paper's copy).
    Hard,
    /// A minimum-error path through a band of already synthesised pixels
    /// around the block (Somol–Haindl §2.1): the block's reference continues
    /// up to the path.
    Path,
}

/// Where the sample goes in an `extend` canvas.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Position {
    Center,
    At(usize, usize),
}

/// What to make (ARCHITECTURE §3.1).
#[derive(Debug, Clone)]
pub enum Mode {
    /// Constrained synthesis of the holes (true = fill) of the sample: copied
    /// from the sample itself, or from `source` when given.
    Fill {
        holes: Vec<bool>,
        source: Option<FillSource>,
    },
    /// A larger canvas with the sample placed in it.
    Extend {
        width: usize,
        height: usize,
        position: Position,
    },
    /// A new texture of any size.
    Synth {
        width: usize,
        height: usize,
        method: SynthMethod,
    },
}

/// Another image to fill the holes from (ARCHITECTURE §3.1): the search and
/// the copies use only it, or only its `region` (true = may be copied from),
/// while the photo's own pixels stay as they are.
#[derive(Debug, Clone)]
pub struct FillSource {
    pub image: ColorImage,
    pub region: Option<Vec<bool>>,
}

/// Synthesis parameters; [`Config::default`] gives good results without tuning.
#[derive(Debug, Clone)]
pub struct Config {
    /// Block side B (odd, 1..=11).
    pub block: usize,
    /// Neighbourhood side N (odd, > B).
    pub neighbourhood: usize,
    /// Parent window side M; `None` = the smallest odd window covering N.
    pub parent_window: Option<usize>,
    /// Pyramid levels; 0 = automatic.
    pub levels: usize,
    pub weights: Weights,
    pub metric: Metric,
    pub tileable: bool,
    pub seed: u64,
    /// Deterministic batch size K (1 = the paper's strict order).
    pub batch: usize,
    /// Chroma blur radius at patch borders (0 = off).
    pub chroma_blur: usize,
    /// Per-level samples for texture mixing (§10.3): level → image used as that
    /// level's sample at its own resolution.
    pub level_samples: Vec<(usize, ColorImage)>,
    /// Full-colour search: compare Y, Cb and Cr neighbourhoods (three times the
    /// vector size) for textures whose structure and colour disagree (§9).
    pub colour_search: bool,
    /// How copied blocks meet their neighbours.
    pub stitch: Stitch,
    /// Repetition control over the exact search's near-ties (`None` = off).
    pub repeats: Option<RepeatControl>,
    /// Lattice phase: keep a grid sample's grid (`None` = off).
    pub lattice: Option<Lattice>,
}

/// Why the lattice phase and repetition control cannot run together.
pub const LATTICE_WITH_REPEATS: &str = "--lattice and repetition control both pick among the near-ties; give one (--no-repeat-control turns the control off)";

impl Default for Config {
    fn default() -> Self {
        Self {
            block: 5,
            neighbourhood: 11,
            parent_window: None,
            levels: 0,
            weights: Weights { hi: 1, lo: 2 },
            metric: Metric::L1,
            tileable: false,
            seed: 1,
            batch: 16,
            chroma_blur: 0,
            level_samples: Vec::new(),
            colour_search: false,
            stitch: Stitch::Hard,
            repeats: None,
            lattice: None,
        }
    }
}

/// The neighbourhood N of growth stitched by path (`synth`'s default; the
/// library's default keeps the paper's 11). Its stitching band is 4 pixels
/// against N = 11's 3 (ARCHITECTURE §3.12): against the peer on 22 samples at
/// 2× their side, the Laplacian histogram better on 21 (N = 11: 19), patch
/// fidelity on 21 (20), colour on 19 (17), at about 1.3× the time.
pub const PATH_GROWTH_NEIGHBOURHOOD: usize = 13;

/// The neighbourhood of growth stitched by path when none is given:
/// [`PATH_GROWTH_NEIGHBOURHOOD`] where the coarsest of `levels` levels (0 =
/// automatic, which fits the levels to N) of a `sample` (width, height) holds
/// it, else the paper's 11, so that `--levels` that fit 11 still run.
pub fn growth_neighbourhood(sample: [usize; 2], levels: usize) -> usize {
    let (w, h) = crate::pyramid::level_size(sample[0], sample[1], levels.max(1) - 1);
    if w.min(h) >= PATH_GROWTH_NEIGHBOURHOOD {
        PATH_GROWTH_NEIGHBOURHOOD
    } else {
        Config::default().neighbourhood
    }
}

/// Largest canvas accepted (pixels); larger requests are refused up front.
pub const MAX_CANVAS_PIXELS: usize = imaging::MAX_PIXELS;

impl Config {
    /// Checks the parameters against each other; messages name both sides.
    pub fn validate(&self) -> Result<()> {
        let b = self.block;
        let n = self.neighbourhood;
        ensure!(
            b % 2 == 1 && (1..=11).contains(&b),
            "block size {b} must be odd and in 1..=11 (e.g. --block 3)"
        );
        ensure!(
            n % 2 == 1 && (3..=31).contains(&n),
            "neighbourhood {n} must be odd and in 3..=31 (e.g. --neighbourhood 9)"
        );
        ensure!(
            n > b,
            "neighbourhood {n} must be larger than the block size {b}"
        );
        if let Some(m) = self.parent_window {
            ensure!(
                m % 2 == 1 && (1..=31).contains(&m),
                "parent window {m} must be odd and in 1..=31"
            );
        }
        ensure!(
            self.levels <= 10,
            "{} levels is too many; use at most 10",
            self.levels
        );
        ensure!(
            (1..=4096).contains(&self.batch),
            "batch {} must be in 1..=4096 (1 = the paper's strict order)",
            self.batch
        );
        if let Some(r) = &self.repeats {
            ensure!(
                r.seam.is_none() || self.stitch == Stitch::Path,
                "--repeat-seam filters by the stitched seam's error and needs --stitch path"
            );
        }
        ensure!(
            self.lattice.is_none() || self.repeats.is_none(),
            "{LATTICE_WITH_REPEATS}"
        );
        Weights::new(self.weights.hi, self.weights.lo)?;
        if let Some(r) = &self.repeats {
            r.validate()?;
        }
        ensure!(
            self.chroma_blur <= 8,
            "chroma blur radius {} is too large; use 0..=8",
            self.chroma_blur
        );
        Ok(())
    }

    pub(super) fn parent_window(&self) -> usize {
        self.parent_window
            .unwrap_or_else(|| Geometry::parent_window_for(self.neighbourhood))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// N = 13 where the coarsest level holds it, else 11; automatic levels
    /// need only the sample to hold it.
    #[test]
    fn growth_takes_thirteen_where_the_coarsest_level_holds_it() {
        assert_eq!(growth_neighbourhood([96, 96], 3), 13);
        assert_eq!(growth_neighbourhood([96, 96], 4), 11);
        assert_eq!(growth_neighbourhood([96, 200], 4), 11);
        assert_eq!(growth_neighbourhood([104, 104], 4), 13);
        assert_eq!(growth_neighbourhood([13, 13], 0), 13);
        assert_eq!(growth_neighbourhood([12, 40], 0), 11);
    }
}
