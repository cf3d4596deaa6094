//! The objective of the local search (Bourque–Dudek §3.2.2): a render
//! against the target by (1 − S_F) + S_L + the colour term (the measures
//! of `texsyn compare`), plus the distance of blurred spectra that gives
//! the search a slope towards a periodic target's peaks.

use std::sync::atomic::{AtomicU64, Ordering};

use anyhow::{ensure, Result};
use argmin::core::CostFunction;

use super::arrangement::Analysis;
use super::colour::ColourTarget;
use super::descriptor::Structure;
use super::periodicity::Periodicity;
use super::shaders::{colourise, Kind, Shader};
use crate::compare::Descriptors;
use crate::filters::box_blur_2d;
use crate::imaging::ColorImage;

/// The centred square of `img`, resampled to `size`².
pub fn analysis_image(img: &ColorImage, size: usize) -> ColorImage {
    let side = img.width.min(img.height);
    let sq = img.crop((img.width - side) / 2, (img.height - side) / 2, side, side);
    if side == size {
        return sq;
    }
    let buf = image::RgbImage::from_raw(side as u32, side as u32, sq.rgb).expect("rgb buffer");
    let r = image::imageops::resize(
        &buf,
        size as u32,
        size as u32,
        image::imageops::FilterType::Lanczos3,
    );
    ColorImage::from_vec(size, size, r.into_raw())
}

/// The periods of a square image's luminance and its arrangement.
pub fn periodicity_of(img: &ColorImage) -> (Periodicity, Analysis) {
    let l = crate::imaging::colour::luminance(img);
    let v: Vec<f64> = l.data.iter().map(|&x| f64::from(x)).collect();
    let n = l.width.min(l.height);
    let per = Periodicity::of_values(&v, n);
    let a = Analysis::of_values(&v, n, &per);
    (per, a)
}

/// What the local search compares each render with.
pub struct Target {
    pub image: ColorImage,
    pub descriptors: Descriptors,
    /// The S_F spectrum blurred at each of [`BLURS`].
    pub blurred: Vec<Vec<f64>>,
    pub structure: Structure,
    /// The periods of the target's luminance (the structure seeds and term).
    pub periodicity: Periodicity,
    /// How the target's features are arranged (the shaders tried).
    pub arrangement: Analysis,
    pub colours: ColourTarget,
}

impl Target {
    /// The target at the catalogue's analysis size.
    pub fn new(img: &ColorImage, size: usize) -> Result<Self> {
        ensure!(
            img.width >= 8 && img.height >= 8,
            "the target is {}×{}; give an image of at least 8×8 pixels",
            img.width,
            img.height
        );
        let image = analysis_image(img, size);
        let descriptors = Descriptors::of(&image)?;
        let (periodicity, arrangement) = periodicity_of(&image);
        Ok(Self {
            blurred: blurred_spectra(&descriptors),
            descriptors,
            structure: Structure::of_image(&image),
            periodicity,
            arrangement,
            colours: ColourTarget::of(&image),
            image,
        })
    }
}

/// Blurs of the spectrum in the refinement objective, as fractions of the
/// image side (in frequency bins).
pub const BLURS: [f64; 2] = [1.0 / 48.0, 1.0 / 16.0];

/// The Gaussian low-pass (cycles per pixel) on the blurred spectra: they
/// are there to lead the search to the fundamental's basin, and the high
/// harmonics of a sharp pattern (folded back by point sampling) move
/// erratically with its frequency.
pub const LOW_PASS: f64 = 0.12;

/// The S_F spectrum of `d`, low-passed by [`LOW_PASS`] and blurred
/// (wrapping; three box passes per axis, a close Gaussian) at each of
/// [`BLURS`], each of unit length. The spectrum of a periodic pattern is a
/// set of peaks, so S_F alone only sees a candidate very near the target;
/// the blurred spectra give the search a slope from further away.
pub fn blurred_spectra(d: &Descriptors) -> Vec<Vec<f64>> {
    let (w, h) = (d.width, d.height);
    let pass = |n: usize| -> Vec<f64> {
        (0..n)
            .map(|k| (-(crate::compare::frequency(k, n) / LOW_PASS).powi(2)).exp())
            .collect()
    };
    let (gx, gy) = (pass(w), pass(h));
    let low: Vec<f64> = (0..w * h)
        .map(|i| d.spectrum[i] * gx[i % w] * gy[i / w])
        .collect();
    BLURS
        .iter()
        .map(|&b| {
            let sigma = b * w.min(h) as f64;
            // Three boxes of width 2r + 1 have variance 3·((2r + 1)² − 1)/12.
            let r = (((4.0 * sigma * sigma + 1.0).sqrt() - 1.0) / 2.0).round() as usize;
            let mut out = low.clone();
            for _ in 0..3 {
                box_blur_2d(&mut out, w, h, r);
            }
            let norm = out.iter().map(|x| x * x).sum::<f64>().sqrt();
            if norm > 0.0 {
                out.iter_mut().for_each(|x| *x /= norm);
            }
            out
        })
        .collect()
}

/// One evaluated parameter vector.
#[derive(Clone, Debug)]
pub(super) struct Eval {
    pub params: Vec<f64>,
    pub colours: [[f64; 3]; 2],
    pub s_f: f64,
    pub s_l: f64,
    pub colour: f64,
    pub objective: f64,
}

/// The objective of one shader with its whole-number parameters fixed, on
/// the unit box of its other parameters.
pub(super) struct Problem<'a> {
    pub shader: &'static Shader,
    pub base: Vec<f64>,
    pub free: Vec<usize>,
    pub target: &'a Target,
    pub evals: &'a AtomicU64,
}

impl Problem<'_> {
    pub fn params(&self, x: &[f64]) -> Vec<f64> {
        self.shader.from_unit_box(&self.base, &self.free, x)
    }

    pub fn evaluate(&self, params: &[f64]) -> Eval {
        self.evals.fetch_add(1, Ordering::Relaxed);
        evaluate(self.shader, params, self.target)
    }
}

/// Renders `params` at the target's size with fitted colours and scores it.
pub(super) fn evaluate(shader: &'static Shader, params: &[f64], target: &Target) -> Eval {
    let size = target.image.width;
    let field = shader.render_field(params, size, size, size);
    let colours = target.colours.fit(&field);
    let img = colourise(&field, size, size, &colours);
    let Ok(d) = Descriptors::of(&img) else {
        unreachable!("analysis images are at least 32×32")
    };
    let (s_f, s_l, colour) = target.descriptors.scores(&d);
    let slope: f64 = blurred_spectra(&d)
        .iter()
        .zip(&target.blurred)
        .map(|(a, b)| 1.0 - crate::compare::spectra_similarity(a, b))
        .sum();
    Eval {
        params: params.to_vec(),
        colours,
        s_f,
        s_l,
        colour,
        objective: (1.0 - s_f) + s_l + colour + slope,
    }
}

impl CostFunction for Problem<'_> {
    type Param = Vec<f64>;
    type Output = f64;

    fn cost(&self, x: &Self::Param) -> Result<f64, argmin::core::Error> {
        // Outside the box the parameters are clamped; a gentle slope leads
        // the simplex back in.
        let out: f64 = self
            .free
            .iter()
            .zip(x)
            .filter(|(&i, _)| self.shader.params[i].kind != Kind::Periodic)
            .map(|(_, &t)| (t.clamp(0.0, 1.0) - t).powi(2))
            .sum();
        Ok(self.evaluate(&self.params(x)).objective + out)
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn box_blur_is_the_wrapped_moving_mean() {
        let (w, h) = (13, 7);
        let v: Vec<f64> = (0..w * h).map(|i| ((i * 37) % 11) as f64).collect();
        for r in 0..4 {
            let mut rows = v.clone();
            crate::filters::box_blur_lines(&mut rows, w, h, r, 1, w);
            let mut cols = v.clone();
            crate::filters::box_blur_lines(&mut cols, h, w, r, w, 1);
            for y in 0..h {
                for x in 0..w {
                    let n = (2 * r + 1) as f64;
                    let row: f64 = (0..=2 * r)
                        .map(|j| v[y * w + (x + w + j - r) % w])
                        .sum::<f64>()
                        / n;
                    let col: f64 = (0..=2 * r)
                        .map(|j| v[((y + h + j - r) % h) * w + x])
                        .sum::<f64>()
                        / n;
                    assert!((rows[y * w + x] - row).abs() < 1e-9);
                    assert!((cols[y * w + x] - col).abs() < 1e-9);
                }
            }
        }
    }
}
