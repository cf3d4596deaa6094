//! Multi-scale block synthesis (Stahlhut §4–§6 and §9, ARCHITECTURE §3).
//!
//! Levels are processed coarsest first. On each level the canvas starts with
//! the pixels known there (the placed sample, the unmasked photo, the seed
//! patch or, for full synthesis, noise), the block list is keyed by undefined
//! neighbourhood pixels, and blocks are filled by copying the best-matching
//! reference block. Finer levels compare a second, low-resolution part taken
//! from the finished coarser level. Colour is rebuilt from the copy map.

use std::time::Instant;

use anyhow::{bail, ensure, Context, Result};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use texsyn_engine::layout::reference_positions;
use texsyn_engine::{Geometry, Layout, Metric, Params, Plane, QueryBatch, Sample, Weights};

use crate::colour;
use crate::imaging::{self, ColorImage, Gray};
use crate::neighbourhood::{query, Canvas, Shape};
use crate::pyramid;
use crate::queue::BlockQueue;
use crate::search::{LevelData, SearchBackend};

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

/// Where the sample goes in an `extend` canvas.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Position {
    Center,
    At(usize, usize),
}

/// What to make (ARCHITECTURE §3.1).
#[derive(Debug, Clone)]
pub enum Mode {
    /// Constrained synthesis of the holes (true = fill) of the sample itself.
    Fill { holes: Vec<bool> },
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
}

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
        }
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
        Weights::new(self.weights.hi, self.weights.lo)?;
        ensure!(
            self.chroma_blur <= 8,
            "chroma blur radius {} is too large; use 0..=8",
            self.chroma_blur
        );
        Ok(())
    }

    fn parent_window(&self) -> usize {
        self.parent_window
            .unwrap_or_else(|| Geometry::parent_window_for(self.neighbourhood))
    }
}

/// Receives progress; the CLI draws a bar per level.
pub trait Progress: Sync {
    fn level_start(&self, _level: usize, _levels: usize, _blocks: u64) {}
    fn advance(&self, _blocks: u64) {}
    fn level_end(&self, _level: usize) {}
}

/// No progress output.
pub struct Silent;
impl Progress for Silent {}

/// Figures of one level for the run report.
#[derive(Debug, Clone, serde::Serialize)]
pub struct LevelReport {
    pub level: usize,
    pub canvas: [usize; 2],
    pub sample: [usize; 2],
    pub reference_vectors: usize,
    pub queries: u64,
    pub batches: u64,
    pub build_seconds: f64,
    pub search_seconds: f64,
    pub total_seconds: f64,
}

/// The machine-readable run report.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Report {
    pub mode: String,
    pub canvas: [usize; 2],
    pub sample: [usize; 2],
    pub block: usize,
    pub neighbourhood: usize,
    pub parent_window: usize,
    pub levels: usize,
    pub weights: [u32; 2],
    pub metric: Metric,
    pub tileable: bool,
    pub seed: u64,
    pub batch: usize,
    pub search: String,
    pub per_level: Vec<LevelReport>,
    pub synthesis_seconds: f64,
    /// What the search backend reports (plan used, workers, LBG codebooks).
    pub search_stats: serde_json::Value,
}

/// Everything a run produces.
pub struct Output {
    pub image: ColorImage,
    pub luminance: Gray,
    /// Per output pixel, its source coordinate in the finest sample.
    pub copy_map: Vec<[u32; 2]>,
    pub sample_size: [usize; 2],
    /// Finished luminance per level, finest first.
    pub levels: Vec<Gray>,
    pub report: Report,
}

/// The known part of the finest canvas: `size` pixels of the sample starting at
/// `sample_at` go to `canvas_at`; both offsets are multiples of 2^(levels-1) so
/// the placement is exact on every level.
#[derive(Debug, Clone, Copy)]
struct Placement {
    canvas_at: [usize; 2],
    sample_at: [usize; 2],
    size: [usize; 2],
}

/// One level's sample: luminance (+ defined mask), its parent, and colour for
/// the finest level.
struct LevelSample {
    lum: Gray,
    defined: Option<Vec<bool>>,
    parent: Option<(Gray, Option<Vec<bool>>)>,
    /// Cb, Cr of the level and of its parent (full-colour search only).
    chroma: Option<[Gray; 2]>,
    parent_chroma: Option<[Gray; 2]>,
}

/// A pyramid of planes with their defined masks, finest first.
type Pyramid = Vec<(Gray, Option<Vec<bool>>)>;

/// Cb and Cr planes of an image (BT.601, integer).
fn chroma_planes(img: &ColorImage) -> [Gray; 2] {
    let n = img.width * img.height;
    let (mut cb, mut cr) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for p in img.rgb.chunks_exact(3) {
        let (r, g, b) = (i64::from(p[0]), i64::from(p[1]), i64::from(p[2]));
        cb.push(((-168_736 * r - 331_264 * g + 500_000 * b) / 1_000_000 + 128).clamp(0, 255) as u8);
        cr.push(((500_000 * r - 418_688 * g - 81_312 * b) / 1_000_000 + 128).clamp(0, 255) as u8);
    }
    [
        Gray::from_vec(img.width, img.height, cb),
        Gray::from_vec(img.width, img.height, cr),
    ]
}

/// Unpadded full-colour reference vectors: per position the Y, Cb and Cr N×N
/// windows, then (below the coarsest level) the parent's Y, Cb and Cr M×M windows.
fn colour_vectors(ls: &LevelSample, positions: &[[u32; 2]], n: usize, m: usize) -> Result<Vec<u8>> {
    let chroma = ls
        .chroma
        .as_ref()
        .context("colour search without chroma planes")?;
    let fine = [&ls.lum, &chroma[0], &chroma[1]];
    let parent: Vec<&Gray> = match (&ls.parent, &ls.parent_chroma, m) {
        (_, _, 0) => Vec::new(),
        (Some((p, _)), Some(pc), _) => vec![p, &pc[0], &pc[1]],
        _ => bail!("colour search without parent chroma planes"),
    };
    let (r, pr) = (n / 2, m / 2);
    let dims = 3 * (n * n + if parent.is_empty() { 0 } else { m * m });
    let mut out = Vec::with_capacity(positions.len() * dims);
    for p in positions {
        let (x, y) = (p[0] as usize, p[1] as usize);
        for plane in fine {
            for yy in y - r..=y + r {
                out.extend_from_slice(&plane.row(yy)[x - r..=x + r]);
            }
        }
        for plane in &parent {
            let (px, py) = (x / 2, y / 2);
            for yy in py - pr..=py + pr {
                out.extend_from_slice(&plane.row(yy)[px - pr..=px + pr]);
            }
        }
    }
    Ok(out)
}

fn align_down(v: usize, a: usize) -> usize {
    v / a * a
}

fn scaled(v: usize, level: usize) -> usize {
    v >> level
}

fn level_size(w: usize, h: usize, level: usize) -> (usize, usize) {
    let (mut w, mut h) = (w, h);
    for _ in 0..level {
        (w, h) = pyramid::coarse_size(w, h);
    }
    (w, h)
}

/// The number of levels a run with `cfg` uses on a `sample_w`×`sample_h` sample.
pub fn resolve_levels(sample_w: usize, sample_h: usize, cfg: &Config) -> usize {
    if cfg.levels == 0 {
        automatic_levels((sample_w, sample_h), cfg.neighbourhood)
    } else {
        cfg.levels
    }
}

fn automatic_levels(sample: (usize, usize), n: usize) -> usize {
    let mut levels = 1;
    let (mut w, mut h) = sample;
    while levels < 4 {
        let (cw, ch) = pyramid::coarse_size(w, h);
        if cw.min(ch) < n + 4 {
            break;
        }
        (w, h) = (cw, ch);
        levels += 1;
    }
    levels
}

/// Runs the synthesis with `backend` doing the searches.
pub fn synthesize(
    sample: &ColorImage,
    mode: &Mode,
    cfg: &Config,
    backend: &mut dyn SearchBackend,
    progress: &dyn Progress,
) -> Result<Output> {
    cfg.validate()?;
    let started = Instant::now();
    let (sw, sh) = (sample.width, sample.height);
    imaging::check_size(sw, sh, "sample")?;
    let n = cfg.neighbourhood;
    ensure!(
        sw >= n && sh >= n,
        "the sample is {sw}×{sh} pixels, smaller than the {n}×{n} neighbourhood; use a larger sample or a smaller --neighbourhood"
    );
    let (cw, ch, mode_name) = match mode {
        Mode::Fill { holes } => {
            ensure!(
                holes.len() == sw * sh,
                "the mask has {} pixels but the image has {sw}×{sh}; give a mask of the same size",
                holes.len()
            );
            let count = holes.iter().filter(|&&h| h).count();
            ensure!(
                count > 0,
                "the mask has no hole (no white pixel): nothing to fill"
            );
            ensure!(
                count < holes.len(),
                "the mask is all hole (all white): nothing is left to copy from; mark only the holes white"
            );
            (sw, sh, "fill")
        }
        Mode::Extend { width, height, .. } => {
            ensure!(
                *width >= sw && *height >= sh,
                "extend canvas {width}×{height} is smaller than the {sw}×{sh} sample; use fill or synth, or a larger --size"
            );
            (*width, *height, "extend")
        }
        Mode::Synth {
            width,
            height,
            method,
        } => (
            *width,
            *height,
            match method {
                SynthMethod::Grow => "synth",
                SynthMethod::Scanline => "synth-scanline",
            },
        ),
    };
    ensure!(
        cw > 0
            && ch > 0
            && cw.saturating_mul(ch) <= MAX_CANVAS_PIXELS
            && cw.max(ch) <= imaging::MAX_SIDE,
        "canvas {cw}×{ch} is outside the limit (at most {} pixels and {} per side)",
        MAX_CANVAS_PIXELS,
        imaging::MAX_SIDE
    );
    let mut levels = resolve_levels(sw, sh, cfg);
    {
        let (lw, lh) = level_size(sw, sh, levels - 1);
        ensure!(
            lw >= n && lh >= n,
            "{levels} levels shrink the {sw}×{sh} sample to {lw}×{lh} on the coarsest level, smaller than the {n}×{n} neighbourhood; use fewer --levels (at most {}) or a smaller neighbourhood",
            automatic_levels_max(sw, sh, n)
        );
    }
    for (l, img) in &cfg.level_samples {
        ensure!(
            *l < levels,
            "--level-sample for level {l}, but the run has {levels} levels (0 = finest .. {})",
            levels - 1
        );
        ensure!(
            img.width >= n && img.height >= n,
            "the level-{l} sample is {}×{}, smaller than the {n}×{n} neighbourhood",
            img.width,
            img.height
        );
        ensure!(
            matches!(mode, Mode::Synth { .. }),
            "per-level samples (texture mixing) work with `synth` only"
        );
    }

    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    let main_lum = imaging::luminance(sample);
    let holes_defined: Option<Vec<bool>> = match mode {
        Mode::Fill { holes } => Some(holes.iter().map(|&h| !h).collect()),
        _ => None,
    };
    let mut sample_pyr = pyramid::pyramid(&main_lum, holes_defined.as_deref(), levels + 1, false);
    if cfg.levels == 0 && holes_defined.is_some() {
        // Holes grow on coarse levels: drop levels until the coarsest still has
        // enough fully known neighbourhoods to copy from.
        while levels > 1 && coarsest_references(&sample_pyr, levels - 1, n)? < 16 {
            levels -= 1;
        }
        sample_pyr.truncate(levels + 1);
    }
    let align = 1usize << (levels - 1);

    // The known part of the finest canvas.
    let placement = match mode {
        Mode::Fill { .. } => Some(Placement {
            canvas_at: [0, 0],
            sample_at: [0, 0],
            size: [sw, sh],
        }),
        Mode::Extend { position, .. } => {
            let (x, y) = match position {
                Position::Center => ((cw - sw) / 2, (ch - sh) / 2),
                Position::At(x, y) => {
                    ensure!(
                        x + sw <= cw && y + sh <= ch,
                        "position {x},{y} puts the {sw}×{sh} sample outside the {cw}×{ch} canvas"
                    );
                    (*x, *y)
                }
            };
            Some(Placement {
                canvas_at: [align_down(x, align), align_down(y, align)],
                sample_at: [0, 0],
                size: [sw, sh],
            })
        }
        Mode::Synth {
            method: SynthMethod::Grow,
            ..
        } => {
            // A seed patch of a few coarse neighbourhoods, from a seeded place.
            let side = (n * align)
                .max(sw.min(sh) / 4)
                .min(sw)
                .min(sh)
                .min(cw)
                .min(ch);
            let pw = side.min(sw);
            let ph = side.min(sh);
            let sx = align_down(rng.random_range(0..=sw - pw), align);
            let sy = align_down(rng.random_range(0..=sh - ph), align);
            Some(Placement {
                canvas_at: [
                    align_down((cw - pw) / 2, align),
                    align_down((ch - ph) / 2, align),
                ],
                sample_at: [sx, sy],
                size: [pw, ph],
            })
        }
        Mode::Synth {
            method: SynthMethod::Scanline,
            ..
        } => None,
    };
    let scanline = placement.is_none();

    // Finest defined mask of the canvas and its pyramid.
    let canvas_mask_pyr: Vec<Vec<bool>> = {
        let mut m = vec![false; cw * ch];
        if let Some(p) = placement {
            for y in 0..p.size[1] {
                for x in 0..p.size[0] {
                    let (sx, sy) = (p.sample_at[0] + x, p.sample_at[1] + y);
                    let known = holes_defined.as_ref().is_none_or(|d| d[sy * sw + sx]);
                    m[(p.canvas_at[1] + y) * cw + p.canvas_at[0] + x] = known;
                }
            }
        }
        let mut out = vec![m];
        let (mut w, mut h) = (cw, ch);
        for _ in 1..levels {
            let next = pyramid::downsample_mask(out.last().unwrap(), w, h);
            (w, h) = pyramid::coarse_size(w, h);
            out.push(next);
        }
        out
    };

    // Per-level samples (texture mixing replaces some).
    let chroma_pyr: Option<[Pyramid; 2]> = cfg.colour_search.then(|| {
        chroma_planes(sample)
            .map(|g| pyramid::pyramid(&g, holes_defined.as_deref(), levels + 1, false))
    });
    let level_sample = |l: usize| -> LevelSample {
        if let Some((_, img)) = cfg.level_samples.iter().find(|(k, _)| *k == l) {
            let lum = imaging::luminance(img);
            let parent = pyramid::downsample(&lum, None, false);
            let (chroma, parent_chroma) = if cfg.colour_search {
                let c = chroma_planes(img);
                let pc = [
                    pyramid::downsample(&c[0], None, false),
                    pyramid::downsample(&c[1], None, false),
                ];
                (Some(c), Some(pc))
            } else {
                (None, None)
            };
            LevelSample {
                lum,
                defined: None,
                parent: Some((parent, None)),
                chroma,
                parent_chroma,
            }
        } else {
            let (g, d) = sample_pyr[l].clone();
            LevelSample {
                lum: g,
                defined: d,
                parent: Some(sample_pyr[l + 1].clone()),
                chroma: chroma_pyr
                    .as_ref()
                    .map(|c| [c[0][l].0.clone(), c[1][l].0.clone()]),
                parent_chroma: chroma_pyr
                    .as_ref()
                    .map(|c| [c[0][l + 1].0.clone(), c[1][l + 1].0.clone()]),
            }
        }
    };

    let m = cfg.parent_window();
    let params = Params {
        metric: cfg.metric,
        weights: cfg.weights,
    };
    let mut per_level = Vec::new();
    let mut finished: Vec<Canvas> = Vec::new(); // coarsest first
    let mut finest_sample_lum = None;
    for l in (0..levels).rev() {
        let level_started = Instant::now();
        let coarsest = l == levels - 1;
        let ls = level_sample(l);
        let (lw, lh) = level_size(cw, ch, l);
        let mut canvas = Canvas::new(lw, lh, cfg.tileable);
        if cfg.colour_search {
            canvas = canvas.with_chroma();
        }
        // Known pixels of this level.
        if let Some(p) = placement {
            let mask = &canvas_mask_pyr[l];
            let (cx0, cy0) = (scaled(p.canvas_at[0], l), scaled(p.canvas_at[1], l));
            let (sx0, sy0) = (scaled(p.sample_at[0], l), scaled(p.sample_at[1], l));
            for y in 0..lh {
                for x in 0..lw {
                    let i = y * lw + x;
                    if !mask[i] {
                        continue;
                    }
                    let (sx, sy) = (x - cx0 + sx0, y - cy0 + sy0);
                    set_pixel(&mut canvas, i, &ls, sx, sy);
                }
            }
        } else {
            // Full synthesis: noise drawn from the sample's pixels.
            for i in 0..lw * lh {
                let (sx, sy) = (
                    rng.random_range(0..ls.lum.width),
                    rng.random_range(0..ls.lum.height),
                );
                set_pixel(&mut canvas, i, &ls, sx, sy);
            }
        }

        let geometry = Geometry::new(n, if coarsest { 0 } else { m })?;
        let fine = Plane::new(ls.lum.width, ls.lum.height, &ls.lum.data, None)?;
        let defined_bytes: Option<Vec<u8>> = ls
            .defined
            .as_ref()
            .map(|d| d.iter().map(|&b| u8::from(b)).collect());
        let fine = Plane {
            defined: defined_bytes.as_deref(),
            ..fine
        };
        let parent_bytes: Option<Vec<u8>> = ls
            .parent
            .as_ref()
            .and_then(|(_, d)| d.as_ref().map(|d| d.iter().map(|&b| u8::from(b)).collect()));
        let parent = if coarsest {
            None
        } else {
            let (pg, _) = ls
                .parent
                .as_ref()
                .context("level sample without a parent")?;
            Some(Plane::new(
                pg.width,
                pg.height,
                &pg.data,
                parent_bytes.as_deref(),
            )?)
        };
        let sample_planes = Sample { fine, parent };
        let positions = reference_positions(&sample_planes, &geometry)?;
        if positions.is_empty() {
            bail!(
                "level {l}: no {n}×{n} neighbourhood of the {}×{} level sample is fully known; use fewer --levels, a smaller --neighbourhood or a smaller hole",
                ls.lum.width,
                ls.lum.height
            );
        }
        let build_started = Instant::now();
        let colour = if cfg.colour_search {
            let lm = if coarsest { 0 } else { m };
            let layout = Layout::new(3 * n * n, 3 * lm * lm);
            Some((layout, colour_vectors(&ls, &positions, n, lm)?))
        } else {
            None
        };
        backend.load_level(&LevelData {
            level: l,
            geometry,
            params,
            sample: sample_planes,
            positions: &positions,
            levels,
            expected_queries: canvas
                .defined
                .iter()
                .filter(|&&d| !d)
                .count()
                .div_ceil(cfg.block * cfg.block)
                .max(if scanline {
                    lw.div_ceil(cfg.block) * lh.div_ceil(cfg.block)
                } else {
                    0
                }) as u64,
            colour_vectors: colour.as_ref().map(|(l, v)| (*l, v.as_slice())),
        })?;
        let build_seconds = build_started.elapsed().as_secs_f64();

        let parent_canvas = if coarsest { None } else { finished.last() };
        let stats = fill_level(
            &mut canvas,
            parent_canvas,
            &ls,
            colour.as_ref().map(|(l, _)| *l),
            &positions,
            &geometry,
            cfg,
            scanline,
            backend,
            progress,
            l,
            levels,
        )?;
        backend.end_level();
        per_level.push(LevelReport {
            level: l,
            canvas: [lw, lh],
            sample: [ls.lum.width, ls.lum.height],
            reference_vectors: positions.len(),
            queries: stats.queries,
            batches: stats.batches,
            build_seconds,
            search_seconds: stats.search_seconds,
            total_seconds: level_started.elapsed().as_secs_f64(),
        });
        if l == 0 {
            finest_sample_lum = Some(ls.lum.clone());
        }
        finished.push(canvas);
    }
    let finest = finished.last().context("no level was synthesised")?;
    let finest_sample_lum = finest_sample_lum.context("no finest level")?;
    let colour_source = cfg
        .level_samples
        .iter()
        .find(|(k, _)| *k == 0)
        .map(|(_, img)| img)
        .unwrap_or(sample);
    let mut image = colour::rebuild(colour_source, &finest.copy, cw, ch)?;
    if cfg.chroma_blur > 0 {
        colour::chroma_blur_borders(&mut image, &finest.copy, cfg.chroma_blur);
    }
    let luminance = Gray::from_vec(cw, ch, finest.lum.clone());
    debug_assert!(finest
        .copy
        .iter()
        .zip(&finest.lum)
        .all(|(c, &v)| finest_sample_lum.get(c[0] as usize, c[1] as usize) == v));
    let levels_out = finished
        .iter()
        .rev()
        .map(|c| Gray::from_vec(c.width, c.height, c.lum.clone()))
        .collect();
    let report = Report {
        mode: mode_name.into(),
        canvas: [cw, ch],
        sample: [sw, sh],
        block: cfg.block,
        neighbourhood: n,
        parent_window: m,
        levels,
        weights: [cfg.weights.hi, cfg.weights.lo],
        metric: cfg.metric,
        tileable: cfg.tileable,
        seed: cfg.seed,
        batch: cfg.batch,
        search: backend.name(),
        per_level,
        synthesis_seconds: started.elapsed().as_secs_f64(),
        search_stats: backend.stats(),
    };
    Ok(Output {
        image,
        luminance,
        copy_map: finest.copy.clone(),
        sample_size: [colour_source.width, colour_source.height],
        levels: levels_out,
        report,
    })
}

/// Reference neighbourhoods of level `l` when it is the coarsest (no parent part).
fn coarsest_references(pyr: &[(Gray, Option<Vec<bool>>)], l: usize, n: usize) -> Result<usize> {
    let (g, d) = &pyr[l];
    let bytes: Option<Vec<u8>> = d.as_ref().map(|d| d.iter().map(|&b| u8::from(b)).collect());
    let plane = Plane::new(g.width, g.height, &g.data, bytes.as_deref())?;
    let sample = Sample {
        fine: plane,
        parent: None,
    };
    Ok(reference_positions(&sample, &Geometry::new(n, 0)?)?.len())
}

fn automatic_levels_max(sw: usize, sh: usize, n: usize) -> usize {
    let mut l = 1;
    let (mut w, mut h) = (sw, sh);
    loop {
        let (cw, ch) = pyramid::coarse_size(w, h);
        if cw < n || ch < n || l >= 10 {
            return l;
        }
        (w, h) = (cw, ch);
        l += 1;
    }
}

struct LevelStats {
    queries: u64,
    batches: u64,
    search_seconds: f64,
}

/// Fills every undefined pixel of `canvas` (Stahlhut §4): pop a deterministic
/// batch of blocks from the queue, search, copy, re-key the neighbours.
#[allow(clippy::too_many_arguments)]
/// Sets canvas pixel `i` to sample pixel (sx, sy) and records it in the copy map.
fn set_pixel(canvas: &mut Canvas, i: usize, ls: &LevelSample, sx: usize, sy: usize) {
    canvas.lum[i] = ls.lum.get(sx, sy);
    canvas.defined[i] = true;
    canvas.copy[i] = [sx as u32, sy as u32];
    if let (Some([cb, cr]), Some(src)) = (canvas.chroma.as_mut(), ls.chroma.as_ref()) {
        cb[i] = src[0].get(sx, sy);
        cr[i] = src[1].get(sx, sy);
    }
}

#[allow(clippy::too_many_arguments)]
fn fill_level(
    canvas: &mut Canvas,
    parent: Option<&Canvas>,
    sample: &LevelSample,
    colour_layout: Option<Layout>,
    positions: &[[u32; 2]],
    geometry: &Geometry,
    cfg: &Config,
    scanline: bool,
    backend: &mut dyn SearchBackend,
    progress: &dyn Progress,
    level: usize,
    levels: usize,
) -> Result<LevelStats> {
    let b = cfg.block;
    let n = geometry.n;
    let (w, h) = (canvas.width, canvas.height);
    let (bw, bh) = (w.div_ceil(b), h.div_ceil(b));
    let centre = |blk: u32| -> (isize, isize) {
        let (bx, by) = (blk as usize % bw, blk as usize / bw);
        ((bx * b + b / 2) as isize, (by * b + b / 2) as isize)
    };
    let block_has_undefined = |c: &Canvas, blk: u32| -> bool {
        let (bx, by) = (blk as usize % bw, blk as usize / bw);
        (by * b..(by * b + b).min(h))
            .any(|y| (bx * b..(bx * b + b).min(w)).any(|x| !c.defined[y * w + x]))
    };
    let mut queue = BlockQueue::new(bw * bh, (n * n) as u32);
    for blk in 0..(bw * bh) as u32 {
        if scanline {
            queue.set(blk, 0);
        } else if block_has_undefined(canvas, blk) {
            let (cx, cy) = centre(blk);
            queue.set(blk, canvas.undefined_in_window(cx, cy, n));
        }
    }
    progress.level_start(level, levels, queue.len() as u64);
    let shape = if scanline {
        Shape::Causal { block: b }
    } else {
        Shape::Symmetric
    };
    let layout = colour_layout.unwrap_or_else(|| geometry.layout());
    let dims = layout.dims();
    let (mut values, mut mask) = (vec![0u8; dims], vec![0u8; dims]);
    let mut stats = LevelStats {
        queries: 0,
        batches: 0,
        search_seconds: 0.0,
    };
    // Windows of blocks in one batch must not overlap, so the batch's result does
    // not depend on the order of its copies (ARCHITECTURE §3.4).
    let reach = n as isize;
    let wrap = canvas.wrap;
    let overlaps = |a: (isize, isize), c: (isize, isize)| -> bool {
        let (mut dx, mut dy) = ((a.0 - c.0).abs(), (a.1 - c.1).abs());
        if wrap {
            dx = dx.min(w as isize - dx);
            dy = dy.min(h as isize - dy);
        }
        dx < reach && dy < reach
    };
    let scan_limit = cfg.batch.saturating_mul(8).max(64);
    let rekey_radius = ((n / 2 + b / 2) / b + 1) as isize;
    let mut chosen: Vec<u32> = Vec::with_capacity(cfg.batch);
    let mut examined: Vec<(isize, isize)> = Vec::new();
    while !queue.is_empty() {
        // A block joins the batch only if its window overlaps no block examined
        // before it (taken or skipped), so no block goes before a higher-priority
        // block it depends on; for K = 1 this is the paper's strict order.
        chosen.clear();
        let mut centres: Vec<(isize, isize)> = Vec::with_capacity(cfg.batch);
        examined.clear();
        for blk in queue.iter().take(scan_limit) {
            let c = centre(blk);
            if examined.iter().all(|&o| !overlaps(o, c)) {
                chosen.push(blk);
                centres.push(c);
                if chosen.len() == cfg.batch {
                    break;
                }
            }
            examined.push(c);
        }
        let mut batch = QueryBatch::new(layout);
        for &(cx, cy) in &centres {
            query(
                canvas,
                parent,
                cx,
                cy,
                n,
                geometry.m,
                shape,
                &mut values,
                &mut mask,
            );
            batch.push(&values, &mask)?;
        }
        let t = Instant::now();
        let hits = backend.search(&batch)?;
        stats.search_seconds += t.elapsed().as_secs_f64();
        ensure!(
            hits.len() == chosen.len(),
            "search returned {} answers for {} queries",
            hits.len(),
            chosen.len()
        );
        stats.queries += chosen.len() as u64;
        stats.batches += 1;
        for (&blk, hit) in chosen.iter().zip(&hits) {
            let pos = *positions.get(hit.index as usize).with_context(|| {
                format!(
                    "search answered index {} of {} references",
                    hit.index,
                    positions.len()
                )
            })?;
            let (bx, by) = (blk as usize % bw, blk as usize / bw);
            let (rx, ry) = (pos[0] as usize - b / 2, pos[1] as usize - b / 2);
            for j in 0..b {
                let y = by * b + j;
                if y >= h {
                    break;
                }
                for i in 0..b {
                    let x = bx * b + i;
                    if x >= w {
                        break;
                    }
                    let k = y * w + x;
                    if scanline || !canvas.defined[k] {
                        set_pixel(canvas, k, sample, rx + i, ry + j);
                    }
                }
            }
            queue.remove(blk);
        }
        if !scanline {
            for &blk in &chosen {
                let (bx, by) = ((blk as usize % bw) as isize, (blk as usize / bw) as isize);
                for dy in -rekey_radius..=rekey_radius {
                    for dx in -rekey_radius..=rekey_radius {
                        let (mut nx, mut ny) = (bx + dx, by + dy);
                        if canvas.wrap {
                            nx = nx.rem_euclid(bw as isize);
                            ny = ny.rem_euclid(bh as isize);
                        } else if nx < 0 || ny < 0 || nx >= bw as isize || ny >= bh as isize {
                            continue;
                        }
                        let nb = (ny as usize * bw + nx as usize) as u32;
                        if queue.contains(nb) {
                            let (cx, cy) = centre(nb);
                            queue.set(nb, canvas.undefined_in_window(cx, cy, n));
                        }
                    }
                }
            }
        }
        progress.advance(chosen.len() as u64);
    }
    progress.level_end(level);
    Ok(stats)
}
