//! The flags of `fill`, `extend` and `synth` and the block method's
//! [`Config`] they make (checked by [`Config::validate`]).

use std::path::PathBuf;

use anyhow::{ensure, Context, Result};
use clap::{Args, ValueEnum};
use texsyn_engine::{Metric, Weights};

use super::RunArgs;
use crate::block::{self, Config, Position};
use crate::imaging;
use crate::lattice::LatticeSpec;

#[derive(Args, Debug, Clone)]
pub struct Common {
    /// Output image (png, jpg, tif, bmp, webp, exr); written atomically, at the
    /// input's depth and channels (the format must hold them: 16-bit in png or
    /// tif, float in exr or tif, alpha not in jpg).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Block size B (odd, 1..=11; default 5).
    #[arg(long)]
    pub block: Option<usize>,
    /// Neighbourhood size N (odd, larger than the block; default 11, and 13
    /// for `synth`'s path-stitched growth where the coarsest level holds it).
    /// With `synth --method parallel`: reduced (default), half, 5 or 7.
    #[arg(long, alias = "neighborhood")]
    pub neighbourhood: Option<String>,
    /// Parent window M on the coarser level (odd; default covers N).
    #[arg(long)]
    pub parent_window: Option<usize>,
    /// Pyramid levels (0 = automatic, the default).
    #[arg(long)]
    pub levels: Option<usize>,
    /// Weights of the two neighbourhood parts, HI,LO (integers; default 1,2).
    #[arg(long)]
    pub weights: Option<String>,
    /// Distance metric (default l1).
    #[arg(long, value_enum)]
    pub metric: Option<MetricArg>,
    /// Make the output tile seamlessly (toroidal canvas).
    #[arg(long)]
    pub tileable: bool,
    /// Random seed (seed patch, noise).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Deterministic batch size K (1 = the paper's strict block order; default 16).
    #[arg(long)]
    pub batch: Option<usize>,
    /// Chroma blur radius at patch borders (0 = off).
    #[arg(long, default_value_t = 0)]
    pub chroma_blur: usize,
    /// How a copied block meets the pixels around it: `hard` (the block's square
    /// edge) or `path` (its reference continues into a band of (N − B)/2
    /// synthesised pixels, at most 4, up to a minimum-error path;
    /// Somol–Haindl). Default:
    /// path for `synth`, which measures better against the peer; hard for
    /// `fill` and `extend`.
    #[arg(long, value_enum)]
    pub stitch: Option<StitchArg>,
    /// Repetition control: of the exact search's near-ties (within
    /// --repeat-percent of the best match's distance plus this many grey levels
    /// per known neighbourhood component), copy the block whose sample pixels
    /// were copied least, so the output repeats the sample less.
    /// Deterministic, and the same across threads and workers.
    #[arg(long, value_name = "GREY")]
    pub repeat_slack: Option<u32>,
    /// Repetition control: near-tie slack in percent of the best distance;
    /// `--repeat-percent 0 --repeat-slack 0` (or `--no-repeat-control`) turns
    /// it off.
    #[arg(long, value_name = "PERCENT")]
    pub repeat_percent: Option<u32>,
    /// Turn repetition control off: the exact best match, as in the paper.
    #[arg(long)]
    pub no_repeat_control: bool,
    /// Repetition control: the best matches each block chooses from (2..=64).
    #[arg(long, value_name = "K")]
    pub repeat_candidates: Option<usize>,
    /// Repetition control's seam filter (with `--stitch path`): choose only
    /// among the near-ties whose stitched seam error is at most this percent
    /// above the exact best match's, so breaking a repeat costs no worse seam
    /// (e.g. 25, with --neighbourhood 13). Turns the control on (with
    /// `--repeat-percent 150` unless given).
    #[arg(long, value_name = "PERCENT")]
    pub repeat_seam: Option<u32>,
    /// Repetition control's patch cap: one copy offset (a coherent patch)
    /// covers at most (this percent of the sample's shorter side)² pixels of
    /// each level, so no patch grows large enough to be seen again elsewhere;
    /// of the near-ties, those under their cap win, and of those the least
    /// stitched seam (`--stitch path`) or else the nearest. On the two finest
    /// levels; coarser ones keep the exact best. Turns the control on (with
    /// `--repeat-percent 60` unless given); e.g. 25 with --neighbourhood 13.
    #[arg(long, value_name = "PERCENT")]
    pub repeat_cap: Option<u32>,
    /// Lattice phase, for samples on a regular grid (tiles, mosaics,
    /// stack-bond brick): the grid's period WxH in sample pixels (fractions
    /// allowed, e.g. 32x32 or 31.5x32; for running-bond brick the brick's
    /// length by two courses, or 0x29 to keep only courses 29 px apart: 0
    /// leaves an axis free). Of the exact search's near-ties each block
    /// takes the one whose copy offset lies nearest the grid's phase, so
    /// tiles stay whole and joints line up. `auto` finds the grid in the
    /// sample (the autocorrelation's period along each axis, where it
    /// repeats cleanly at least three times) and runs without the phase
    /// where there is none; `none` is off, the block method's default.
    /// Deterministic, and the same across threads and workers; cannot be
    /// combined with repetition control. With --method parallel the grid
    /// is found by default: every pixel's offset from the sample is kept
    /// within a pixel of the grid's phase.
    #[arg(long, value_name = "WxH|auto|none", value_parser = super::args::parse_lattice)]
    pub lattice: Option<crate::lattice::LatticeSpec>,
    /// Full-colour search: compare Y, Cb and Cr neighbourhoods (3× the work), for
    /// textures whose structure and colour disagree. Runs on this machine.
    #[arg(long)]
    pub colour_search: bool,
    /// Also write the copy map: a 16-bit RGB PNG with R = source x, G =
    /// source y (exact; `texsyn replay` reads it).
    #[arg(long, alias = "coords")]
    pub copy_map: Option<PathBuf>,
    /// Also write each level's luminance into this directory.
    #[arg(long)]
    pub levels_dir: Option<PathBuf>,
    /// Also write a JSON run report.
    #[arg(long)]
    pub report: Option<PathBuf>,
    #[command(flatten)]
    pub run: RunArgs,
}

#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum StitchArg {
    Hard,
    Path,
}

#[derive(ValueEnum, Debug, Clone, Copy)]
pub enum MetricArg {
    L1,
    L2,
}

#[derive(Args, Debug)]
pub struct FillArgs {
    /// The image with holes.
    pub input: PathBuf,
    /// Mask image of the same size: white = fill, black = keep (a pixel is a
    /// hole when its luminance times its opacity is at least half the range;
    /// 8- or 16-bit).
    #[arg(long, required_unless_present = "mask_from_alpha")]
    pub mask: Option<PathBuf>,
    /// Take the holes from the image's own alpha channel: a pixel is a hole
    /// where its alpha is below half the range (128 of 255, 32768 of 65535, 0.5).
    #[arg(long, conflicts_with = "mask")]
    pub mask_from_alpha: bool,
    /// Fill from this image instead of the photo itself: the search and the
    /// copies use only it (converted to the photo's depth and channels).
    #[arg(long)]
    pub source: Option<PathBuf>,
    /// Copy only from the white part of the --source (same size as the source;
    /// read like --mask).
    #[arg(long, requires = "source")]
    pub source_mask: Option<PathBuf>,
    #[command(flatten)]
    pub common: Common,
}

#[derive(Args, Debug)]
pub struct ExtendArgs {
    /// The sample texture.
    pub input: PathBuf,
    /// Canvas size WxH.
    #[arg(long)]
    pub size: String,
    /// Where the sample goes: center or X,Y (top-left corner).
    #[arg(long, default_value = "center")]
    pub position: String,
    #[command(flatten)]
    pub common: Common,
}

#[derive(Args, Debug)]
pub struct SynthArgs {
    /// The sample texture.
    pub input: PathBuf,
    /// Output size WxH.
    #[arg(long)]
    pub size: String,
    /// grow: from a seeded sample patch; scanline: Stahlhut's full synthesis;
    /// parallel: pixels on exemplar coordinates (Lefebvre–Hoppe, Manke–Wünsche).
    #[arg(long, value_enum, default_value_t = MethodArg::Grow)]
    pub method: MethodArg,
    /// --method parallel: jitter strength r in [0, 1], or one per level,
    /// coarsest first (r1,r2,...; default 1,0.8,0.6,0.4, 1,0.8,0.7,0.6 for
    /// --neighbourhood 5 and 1,0.8,0.5,0.3 for reduced).
    #[arg(long)]
    pub jitter: Option<String>,
    /// --method parallel: the coarsest level's start, random (default) or
    /// tiled (the paper's §4.1, prone to copying the sample).
    #[arg(long)]
    pub start: Option<String>,
    /// --method parallel: correct every level, as the paper does (by default
    /// a level whose neighbourhood spans half the sample's smaller side or
    /// more is only jittered, so no offset copies the sample over the output).
    #[arg(long)]
    pub correct_every_level: bool,
    /// --method parallel: correction passes per level (1 to 64; default 5
    /// for --neighbourhood 7, 9 for 5, 8 for half, 4 for reduced; the
    /// paper's is 2); levels with their own coarse neighbourhood take
    /// --coarse-passes.
    #[arg(long)]
    pub passes: Option<usize>,
    /// --method parallel: correction passes of the finest level (1 to 64;
    /// default 8 for reduced and half, else as --passes).
    #[arg(long)]
    pub fine_passes: Option<usize>,
    /// --method parallel: copy guard, the largest share of the output one
    /// offset from the sample may grow to (0 < share < 1; 0: off; default
    /// 0.08).
    #[arg(long)]
    pub copy_guard: Option<f32>,
    /// --method parallel: k of the k-coherence candidate sets (1 to 16;
    /// default 8 for --neighbourhood 7 and half, 4 for the others).
    #[arg(long)]
    pub k: Option<usize>,
    /// --method parallel: coherence weight c ≥ 0 of the correction's choice
    /// (a candidate that v of the pixel's 3×3 neighbours continue has its
    /// distance scaled by 1 + c·(1 − v/9); default 10 for reduced and half,
    /// 0, the paper's plain choice, for 5 and 7).
    #[arg(long)]
    pub coherence: Option<f32>,
    /// --method parallel: the neighbourhood of every level above the
    /// finest (reduced, half, 5, 7 or same; default 7 for reduced, half and
    /// 5, same for 7).
    #[arg(long, alias = "coarse-neighborhood")]
    pub coarse_neighbourhood: Option<String>,
    /// --method parallel: correction passes of the levels above the finest
    /// where they have their own neighbourhood (1 to 64; default 16).
    #[arg(long)]
    pub coarse_passes: Option<usize>,
    /// --method parallel: strength of the histogram matching of the blend
    /// before every correction sub-pass, 0 to 1 (default 1; 0: the paper's
    /// plain method, which loses thin features).
    #[arg(long)]
    pub histogram: Option<f32>,
    /// --method parallel: keep each level's k-coherence candidate sets in
    /// this directory, so a later run from the same sample skips their search.
    #[arg(long, value_name = "DIR")]
    pub candidate_cache: Option<PathBuf>,
    /// Texture mixing: use FILE as the sample of pyramid level L (0 = finest), as L=FILE.
    #[arg(long = "level-sample", value_name = "L=FILE")]
    pub level_samples: Vec<String>,
    #[command(flatten)]
    pub common: Common,
}

#[derive(ValueEnum, Debug, Clone, Copy)]
pub enum MethodArg {
    Grow,
    Scanline,
    Parallel,
}

fn parse_weights(s: &str) -> Result<Weights> {
    let (a, b) = s
        .split_once(',')
        .with_context(|| format!("weights '{s}' are not HI,LO, e.g. --weights 1,2"))?;
    let hi: u32 = a
        .trim()
        .parse()
        .with_context(|| format!("weight '{a}' is not a whole number"))?;
    let lo: u32 = b
        .trim()
        .parse()
        .with_context(|| format!("weight '{b}' is not a whole number"))?;
    Ok(Weights::new(hi, lo)?)
}

pub(super) fn parse_position(s: &str) -> Result<Position> {
    if s.eq_ignore_ascii_case("center") || s.eq_ignore_ascii_case("centre") {
        return Ok(Position::Center);
    }
    let (x, y) = s
        .split_once(',')
        .with_context(|| format!("position '{s}' is not 'center' or X,Y, e.g. --position 10,20"))?;
    let coordinate = |name: &str, v: &str| -> Result<usize> {
        let n: u64 = v.trim().parse().with_context(|| {
            format!("{name} '{v}' in --position '{s}' is not a whole number ≥ 0")
        })?;
        ensure!(
            n < imaging::MAX_SIDE as u64,
            "{name} {n} in --position '{s}' is outside any canvas (at most {} pixels per side); give X,Y inside the --size canvas",
            imaging::MAX_SIDE
        );
        Ok(n as usize)
    };
    Ok(Position::At(coordinate("x", x)?, coordinate("y", y)?))
}

impl TryFrom<&Common> for Config {
    type Error = anyhow::Error;

    fn try_from(c: &Common) -> Result<Self> {
        let d = Config::default();
        config_with_defaults(c, d.stitch, d.neighbourhood)
    }
}

/// The validated config of the common flags, with `stitch` where `--stitch`
/// is not given and `neighbourhood` where `--neighbourhood` is not (each
/// command's own defaults).
pub fn config_with_defaults(
    c: &Common,
    stitch: block::Stitch,
    neighbourhood: usize,
) -> Result<Config> {
    let d = Config::default();
    let cfg = Config {
        block: c.block.unwrap_or(d.block),
        neighbourhood: match c.neighbourhood.as_deref() {
            None => neighbourhood,
            Some(n) => n.trim().parse().with_context(|| {
                format!(
                    "--neighbourhood '{n}' is not a whole number; \
                     names like reduced or half belong to --method parallel"
                )
            })?,
        },
        parent_window: c.parent_window,
        levels: c.levels.unwrap_or(d.levels),
        weights: match &c.weights {
            Some(w) => parse_weights(w)?,
            None => d.weights,
        },
        metric: match c.metric {
            None => d.metric,
            Some(MetricArg::L1) => Metric::L1,
            Some(MetricArg::L2) => Metric::L2,
        },
        tileable: c.tileable,
        seed: c.seed,
        batch: c.batch.unwrap_or(d.batch),
        chroma_blur: c.chroma_blur,
        level_samples: Vec::new(),
        colour_search: c.colour_search,
        stitch: match c.stitch {
            None => stitch,
            Some(StitchArg::Hard) => block::Stitch::Hard,
            Some(StitchArg::Path) => block::Stitch::Path,
        },
        repeats: repeats(c, d.repeats)?,
        lattice: c.lattice.and_then(|l| l.given()),
    };
    cfg.validate()?;
    ensure!(
        c.lattice != Some(LatticeSpec::Auto) || cfg.repeats.is_none(),
        "{}",
        block::LATTICE_WITH_REPEATS
    );
    Ok(cfg)
}

/// The near-tie slack the seam filter starts from: wide, since the filter
/// keeps only near-tie seams.
const SEAM_PERCENT: u32 = 150;
/// The near-tie slack the patch cap starts from: the ends of patches are cut
/// among near-ties this close to the best match.
const CAP_PERCENT: u32 = 60;

/// The repetition control of `--repeat-slack`, `--repeat-percent`,
/// `--repeat-candidates` and `--no-repeat-control` over the default.
fn repeats(
    c: &Common,
    default: Option<block::RepeatControl>,
) -> Result<Option<block::RepeatControl>> {
    let given = c.repeat_slack.is_some()
        || c.repeat_percent.is_some()
        || c.repeat_candidates.is_some()
        || c.repeat_seam.is_some()
        || c.repeat_cap.is_some();
    if c.no_repeat_control {
        ensure!(
            !given,
            "--no-repeat-control turns repetition control off; drop --repeat-slack, --repeat-percent, --repeat-candidates, --repeat-seam and --repeat-cap"
        );
        return Ok(None);
    }
    if !given {
        return Ok(default);
    }
    let base = default.unwrap_or_default();
    let seam = c.repeat_seam.or(base.seam);
    let r = block::RepeatControl {
        slack: c.repeat_slack.unwrap_or(base.slack),
        percent: c.repeat_percent.unwrap_or(if seam.is_some() {
            SEAM_PERCENT
        } else if c.repeat_cap.is_some() {
            CAP_PERCENT
        } else {
            base.percent
        }),
        candidates: c.repeat_candidates.unwrap_or(base.candidates),
        seam,
        cap: c.repeat_cap,
    };
    if r.slack == 0 && r.percent == 0 {
        ensure!(
            c.repeat_candidates.is_none() && c.repeat_seam.is_none() && c.repeat_cap.is_none(),
            "--repeat-candidates, --repeat-seam and --repeat-cap need repetition control; drop them or give a slack above 0"
        );
        return Ok(None);
    }
    Ok(Some(r))
}
