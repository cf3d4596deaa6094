//! The plan of a run, made before any search (Stahlhut §4, §6; ARCHITECTURE
//! §3.1, §3.6, §3.8, §3.9): checks of the request, canvas size, number of
//! levels, the sample pyramids, the known part of the canvas and the seeded
//! random generator, and per level the sample the search copies from.

use anyhow::{ensure, Context, Result};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use texsyn_engine::layout::reference_positions;
use texsyn_engine::{Geometry, Params, Plane, Sample};

use super::canvas::{self, Placement};
use super::{Config, Mode, SynthMethod, MAX_CANVAS_PIXELS};
use crate::imaging::colour as ycbcr;
use crate::imaging::{self, ColorImage, Gray};
use crate::pyramid;

/// A pyramid of planes with their defined masks, finest first.
pub(super) type Pyramid = Vec<(Gray, Option<Vec<bool>>)>;

/// One level's sample: luminance (+ defined mask), its parent, and colour for
/// the finest level.
pub(super) struct LevelSample {
    pub lum: Gray,
    pub defined: Option<Vec<bool>>,
    pub parent: Option<(Gray, Option<Vec<bool>>)>,
    /// Cb, Cr of the level and of its parent (full-colour search only).
    pub chroma: Option<[Gray; 2]>,
    pub parent_chroma: Option<[Gray; 2]>,
}

/// A level sample's defined masks as the bytes a [`Plane`] borrows (1 = defined).
pub(super) struct MaskBytes {
    fine: Option<Vec<u8>>,
    parent: Option<Vec<u8>>,
}

impl LevelSample {
    pub fn mask_bytes(&self) -> MaskBytes {
        MaskBytes {
            fine: mask_bytes(self.defined.as_ref()),
            parent: self
                .parent
                .as_ref()
                .and_then(|(_, d)| mask_bytes(d.as_ref())),
        }
    }

    /// The level's sample as the search engine reads it: the fine plane and,
    /// below the coarsest level, the parent plane.
    pub fn planes<'s>(&'s self, masks: &'s MaskBytes, coarsest: bool) -> Result<Sample<'s>> {
        let fine = Plane::new(self.lum.width, self.lum.height, &self.lum.data, None)?;
        let fine = Plane {
            defined: masks.fine.as_deref(),
            ..fine
        };
        let parent = if coarsest {
            None
        } else {
            let (pg, _) = self
                .parent
                .as_ref()
                .context("level sample without a parent")?;
            Some(Plane::new(
                pg.width,
                pg.height,
                &pg.data,
                masks.parent.as_deref(),
            )?)
        };
        Ok(Sample { fine, parent })
    }
}

/// Everything decided before the first level is synthesised.
pub(super) struct Plan<'a> {
    pub cfg: &'a Config,
    /// The image placed on the canvas (the photo of a fill).
    pub sample: &'a ColorImage,
    /// The image copied from: the fill source, or else `sample`.
    pub reference: &'a ColorImage,
    pub mode_name: &'static str,
    /// Finest canvas size.
    pub canvas: [usize; 2],
    pub levels: usize,
    /// Parent window side M.
    pub m: usize,
    pub params: Params,
    /// Seeded once per run; drawn from in a fixed order (seed patch, then the
    /// noise of each level, coarsest first).
    pub rng: ChaCha8Rng,
    /// The known part of the finest canvas; `None` for scan-line full synthesis.
    pub placement: Option<Placement>,
    /// Known-pixel mask of the canvas per level, finest first.
    pub known: Vec<Vec<bool>>,
    sample_pyr: Pyramid,
    chroma_pyr: Option<[Pyramid; 2]>,
    /// A fill from another source: the photo's pyramids (luminance, then Cb
    /// and Cr for full-colour search), which seed the canvas.
    photo_pyr: Option<(Pyramid, Option<[Pyramid; 2]>)>,
}

impl<'a> Plan<'a> {
    /// Checks the request and plans the run (`cfg` is already validated).
    pub fn new(sample: &'a ColorImage, mode: &'a Mode, cfg: &'a Config) -> Result<Self> {
        let (sw, sh) = (sample.width, sample.height);
        imaging::check_size(sw, sh, "sample")?;
        let n = cfg.neighbourhood;
        let holes_defined: Option<Vec<bool>> = match mode {
            Mode::Fill { holes, .. } => Some(holes.iter().map(|&h| !h).collect()),
            _ => None,
        };
        // What the search copies from, and which of its pixels it may use.
        let (reference, reference_defined) = match mode {
            Mode::Fill {
                source: Some(s), ..
            } => {
                check_source(s, n)?;
                (&s.image, s.region.as_ref().map(|r| r.to_vec()))
            }
            _ => (sample, holes_defined.clone()),
        };
        let (rw, rh) = (reference.width, reference.height);
        ensure!(
            rw >= n && rh >= n,
            "the sample is {rw}×{rh} pixels, smaller than the {n}×{n} neighbourhood; use a larger sample or a smaller --neighbourhood"
        );
        let (canvas, mode_name) = canvas_size(mode, [sw, sh])?;
        let mut levels = checked_levels(mode, [rw, rh], cfg)?;

        let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
        let main_lum = ycbcr::luminance(reference);
        let mut sample_pyr =
            pyramid::pyramid(&main_lum, reference_defined.as_deref(), levels + 1, false);
        if cfg.levels == 0 && reference_defined.is_some() {
            // Holes grow on coarse levels: drop levels until the coarsest still has
            // enough fully known neighbourhoods to copy from.
            while levels > 1 && coarsest_references(&sample_pyr, levels - 1, n)? < 16 {
                levels -= 1;
            }
            sample_pyr.truncate(levels + 1);
        }
        let align = 1usize << (levels - 1);
        let placement = canvas::placement(mode, [sw, sh], canvas, n, align, &mut rng)?;
        let known = canvas::known_masks(placement, holes_defined.as_deref(), sw, canvas, levels);
        let chroma_pyr: Option<[Pyramid; 2]> = cfg.colour_search.then(|| {
            ycbcr::chroma_planes(reference)
                .map(|g| pyramid::pyramid(&g, reference_defined.as_deref(), levels + 1, false))
        });
        let photo_pyr = (!std::ptr::eq(reference, sample)).then(|| {
            let d = holes_defined.as_deref();
            let lum = pyramid::pyramid(&ycbcr::luminance(sample), d, levels + 1, false);
            let chroma = cfg.colour_search.then(|| {
                ycbcr::chroma_planes(sample).map(|g| pyramid::pyramid(&g, d, levels + 1, false))
            });
            (lum, chroma)
        });
        Ok(Self {
            cfg,
            sample,
            reference,
            mode_name,
            canvas,
            levels,
            m: cfg.parent_window(),
            params: Params {
                metric: cfg.metric,
                weights: cfg.weights,
            },
            rng,
            placement,
            known,
            sample_pyr,
            chroma_pyr,
            photo_pyr,
        })
    }

    /// What seeds the known pixels of level `l` when they do not come from
    /// the level's sample: the photo of a fill from another source.
    pub fn photo_level(&self, l: usize) -> Option<LevelSample> {
        let (lum, chroma) = self.photo_pyr.as_ref()?;
        Some(LevelSample {
            lum: lum[l].0.clone(),
            defined: None,
            parent: None,
            chroma: chroma
                .as_ref()
                .map(|c| [c[0][l].0.clone(), c[1][l].0.clone()]),
            parent_chroma: None,
        })
    }

    /// The sample of level `l` and its parent (texture mixing replaces some).
    pub fn level_sample(&self, l: usize) -> LevelSample {
        let cfg = self.cfg;
        if let Some((_, img)) = cfg.level_samples.iter().find(|(k, _)| *k == l) {
            let lum = ycbcr::luminance(img);
            let parent = pyramid::downsample(&lum, None, false);
            let (chroma, parent_chroma) = if cfg.colour_search {
                let c = ycbcr::chroma_planes(img);
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
            let (g, d) = self.sample_pyr[l].clone();
            LevelSample {
                lum: g,
                defined: d,
                parent: Some(self.sample_pyr[l + 1].clone()),
                chroma: self
                    .chroma_pyr
                    .as_ref()
                    .map(|c| [c[0][l].0.clone(), c[1][l].0.clone()]),
                parent_chroma: self
                    .chroma_pyr
                    .as_ref()
                    .map(|c| [c[0][l + 1].0.clone(), c[1][l + 1].0.clone()]),
            }
        }
    }
}

/// The finest canvas size and the mode's name in the report, after checking
/// the mode against the `sample` size and the canvas against the limits.
fn canvas_size(mode: &Mode, sample: [usize; 2]) -> Result<([usize; 2], &'static str)> {
    let [sw, sh] = sample;
    let (cw, ch, mode_name) = match mode {
        Mode::Fill { holes, .. } => {
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
    Ok(([cw, ch], mode_name))
}

/// Checks a fill source's region against its image: same size, and enough of
/// it marked to hold a neighbourhood.
fn check_source(s: &super::FillSource, n: usize) -> Result<()> {
    let (w, h) = (s.image.width, s.image.height);
    imaging::check_size(w, h, "fill source")?;
    ensure!(
        w >= n && h >= n,
        "the fill source is {w}×{h} pixels, smaller than the {n}×{n} neighbourhood; use a larger --source or a smaller --neighbourhood"
    );
    if let Some(r) = &s.region {
        ensure!(
            r.len() == w * h,
            "the source mask has {} pixels but the source is {w}×{h}; give a --source-mask of the same size",
            r.len()
        );
        ensure!(
            r.iter().any(|&d| d),
            "the source mask marks nothing (no white pixel): nothing to copy from; mark the region to copy from white"
        );
    }
    Ok(())
}

/// The number of levels, checked against the sample and the per-level samples.
fn checked_levels(mode: &Mode, sample: [usize; 2], cfg: &Config) -> Result<usize> {
    let [sw, sh] = sample;
    let n = cfg.neighbourhood;
    let levels = resolve_levels(sw, sh, cfg);
    if let Some(l) = &cfg.lattice {
        l.validate(sample)?;
    }
    let (lw, lh) = pyramid::level_size(sw, sh, levels - 1);
    ensure!(
        lw >= n && lh >= n,
        "{levels} levels shrink the {sw}×{sh} sample to {lw}×{lh} on the coarsest level, smaller than the {n}×{n} neighbourhood; use fewer --levels (at most {}) or a smaller neighbourhood",
        automatic_levels_max(sw, sh, n)
    );
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
    Ok(levels)
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

/// A defined mask as the bytes a [`Plane`] takes (1 = defined).
fn mask_bytes(defined: Option<&Vec<bool>>) -> Option<Vec<u8>> {
    defined.map(|d| d.iter().map(|&b| u8::from(b)).collect())
}

/// Reference neighbourhoods of level `l` when it is the coarsest (no parent part).
fn coarsest_references(pyr: &[(Gray, Option<Vec<bool>>)], l: usize, n: usize) -> Result<usize> {
    let (g, d) = &pyr[l];
    let bytes = mask_bytes(d.as_ref());
    let plane = Plane::new(g.width, g.height, &g.data, bytes.as_deref())?;
    let sample = Sample {
        fine: plane,
        parent: None,
    };
    Ok(reference_positions(&sample, &Geometry::new(n, 0)?)?.len())
}
