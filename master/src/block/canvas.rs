//! The output canvas of one level and what is known on it before the search
//! (Stahlhut §4, §5; ARCHITECTURE §3.1, §3.6).
//!
//! A [`Canvas`] holds a level's luminance, defined flags and copy map. The
//! known part of the finest canvas (placed sample, unmasked photo or seed
//! patch) is a [`Placement`], aligned so it is exact on every level; full
//! scan-line synthesis starts from noise drawn from the sample instead.

use anyhow::{ensure, Result};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use super::plan::LevelSample;
use super::{Mode, Position, SynthMethod};
use crate::pyramid;

/// One pyramid level of the output: luminance, which pixels are defined, and
/// for each defined pixel the sample coordinate it came from (the copy map).
#[derive(Debug, Clone)]
pub struct Canvas {
    pub width: usize,
    pub height: usize,
    pub lum: Vec<u8>,
    pub defined: Vec<bool>,
    /// Source coordinate in this level's sample, valid where `defined`.
    pub copy: Vec<[u32; 2]>,
    pub wrap: bool,
    /// Cb and Cr of each defined pixel, for full-colour search (ARCHITECTURE §3.7).
    pub chroma: Option<[Vec<u8>; 2]>,
}

impl Canvas {
    pub fn new(width: usize, height: usize, wrap: bool) -> Self {
        let n = width * height;
        Self {
            width,
            height,
            lum: vec![0; n],
            defined: vec![false; n],
            copy: vec![[0, 0]; n],
            wrap,
            chroma: None,
        }
    }

    /// Adds Cb/Cr planes so queries compare colour too.
    pub fn with_chroma(mut self) -> Self {
        let n = self.width * self.height;
        self.chroma = Some([vec![128; n], vec![128; n]]);
        self
    }

    /// The planes a query reads: luminance, then Cb and Cr when searching in colour.
    pub(super) fn planes(&self) -> Vec<&[u8]> {
        let mut v: Vec<&[u8]> = vec![&self.lum];
        if let Some([cb, cr]) = &self.chroma {
            v.push(cb);
            v.push(cr);
        }
        v
    }

    /// Index of (x, y), wrapped on a torus or `None` outside a plain canvas.
    #[inline]
    pub fn index(&self, x: isize, y: isize) -> Option<usize> {
        let (w, h) = (self.width as isize, self.height as isize);
        if self.wrap {
            Some((y.rem_euclid(h) * w + x.rem_euclid(w)) as usize)
        } else if x >= 0 && y >= 0 && x < w && y < h {
            Some((y * w + x) as usize)
        } else {
            None
        }
    }

    /// Undefined pixels inside the N×N window around (cx, cy); pixels outside a
    /// plain canvas never become defined and are not counted.
    pub fn undefined_in_window(&self, cx: isize, cy: isize, n: usize) -> u32 {
        let r = (n / 2) as isize;
        let mut count = 0;
        for y in cy - r..=cy + r {
            for x in cx - r..=cx + r {
                if let Some(i) = self.index(x, y) {
                    count += u32::from(!self.defined[i]);
                }
            }
        }
        count
    }
}

/// The known part of the finest canvas: `size` pixels of the sample starting at
/// `sample_at` go to `canvas_at`; both offsets are multiples of 2^(levels-1) so
/// the placement is exact on every level.
#[derive(Debug, Clone, Copy)]
pub(super) struct Placement {
    pub canvas_at: [usize; 2],
    pub sample_at: [usize; 2],
    pub size: [usize; 2],
}

fn align_down(v: usize, a: usize) -> usize {
    v / a * a
}

fn scaled(v: usize, level: usize) -> usize {
    v >> level
}

/// Where the known sample pixels go on the finest `canvas` (`None` for
/// scan-line full synthesis). Draws the seed patch position of `grow` from `rng`.
pub(super) fn placement(
    mode: &Mode,
    sample: [usize; 2],
    canvas: [usize; 2],
    n: usize,
    align: usize,
    rng: &mut ChaCha8Rng,
) -> Result<Option<Placement>> {
    let ([sw, sh], [cw, ch]) = (sample, canvas);
    Ok(match mode {
        Mode::Fill { .. } => Some(Placement {
            canvas_at: [0, 0],
            sample_at: [0, 0],
            size: [sw, sh],
        }),
        Mode::Extend { position, .. } => {
            let (x, y) = match position {
                Position::Center => ((cw - sw) / 2, (ch - sh) / 2),
                Position::At(x, y) => {
                    let inside = |at: usize, side: usize, canvas: usize| {
                        at.checked_add(side).is_some_and(|end| end <= canvas)
                    };
                    ensure!(
                        inside(*x, sw, cw) && inside(*y, sh, ch),
                        "position {x},{y} puts the {sw}×{sh} sample outside the {cw}×{ch} canvas; give X ≤ {} and Y ≤ {}",
                        cw.saturating_sub(sw),
                        ch.saturating_sub(sh)
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
    })
}

/// The known-pixel mask of the canvas on each level, finest first: the
/// placement minus the sample's holes (`sample_defined`, one flag per sample
/// pixel of a `sample_w`-wide sample), then shrunk level by level.
pub(super) fn known_masks(
    placement: Option<Placement>,
    sample_defined: Option<&[bool]>,
    sample_w: usize,
    canvas: [usize; 2],
    levels: usize,
) -> Vec<Vec<bool>> {
    let [cw, ch] = canvas;
    let mut m = vec![false; cw * ch];
    if let Some(p) = placement {
        for y in 0..p.size[1] {
            for x in 0..p.size[0] {
                let (sx, sy) = (p.sample_at[0] + x, p.sample_at[1] + y);
                let known = sample_defined.is_none_or(|d| d[sy * sample_w + sx]);
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
}

/// Sets canvas pixel `i` to sample pixel (sx, sy) and records it in the copy map.
pub(super) fn set_pixel(canvas: &mut Canvas, i: usize, ls: &LevelSample, sx: usize, sy: usize) {
    canvas.lum[i] = ls.lum.get(sx, sy);
    canvas.defined[i] = true;
    canvas.copy[i] = [sx as u32, sy as u32];
    if let (Some([cb, cr]), Some(src)) = (canvas.chroma.as_mut(), ls.chroma.as_ref()) {
        cb[i] = src[0].get(sx, sy);
        cr[i] = src[1].get(sx, sy);
    }
}

/// Writes the pixels known on level `level` before its search: the placed
/// sample pixels under `known`, or, without a placement (full synthesis),
/// noise drawn from the level sample's pixels with `rng`.
pub(super) fn seed_level(
    canvas: &mut Canvas,
    placement: Option<Placement>,
    known: &[bool],
    ls: &LevelSample,
    level: usize,
    rng: &mut ChaCha8Rng,
) {
    let (lw, lh) = (canvas.width, canvas.height);
    if let Some(p) = placement {
        let (cx0, cy0) = (scaled(p.canvas_at[0], level), scaled(p.canvas_at[1], level));
        let (sx0, sy0) = (scaled(p.sample_at[0], level), scaled(p.sample_at[1], level));
        for y in 0..lh {
            for x in 0..lw {
                let i = y * lw + x;
                if !known[i] {
                    continue;
                }
                let (sx, sy) = (x - cx0 + sx0, y - cy0 + sy0);
                set_pixel(canvas, i, ls, sx, sy);
            }
        }
    } else {
        // Full synthesis: noise drawn from the sample's pixels.
        for i in 0..lw * lh {
            let (sx, sy) = (
                rng.random_range(0..ls.lum.width),
                rng.random_range(0..ls.lum.height),
            );
            set_pixel(canvas, i, ls, sx, sy);
        }
    }
}
