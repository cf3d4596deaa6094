//! The colour-free structure descriptor of a pattern (Bourque–Dudek §3.2.1,
//! §3.3): what the catalogue stores per sample, so the global search, the
//! adaptive subdivision and the transformation graph compare textures
//! without re-rendering them.
//!
//! A shader's colours are a straight mix of its grey pattern, so a render's
//! luminance is the pattern scaled and shifted, possibly negated. The
//! descriptor is taken from the standardised grey values (zero mean, unit
//! deviation) and the distance takes the better of the two signs, so a
//! pattern and any colouring of it have the same descriptor:
//!
//! - the S_F spectrum (radially weighted, normalised) summed into 16 radial
//!   × 12 orientation bins;
//! - the histograms of the first 4 Laplacian bands, each band scaled by its
//!   own RMS (their shape: sparse edges or Gaussian-like noise), as in S_L;
//! - 17 quantiles of the grey values (the pattern's histogram).

use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};

use serde::{Deserialize, Serialize};

use crate::compare::{frequency as freq, laplacian_bands_of, weighted_spectrum};
use crate::imaging::colour::luminance;
use crate::imaging::ColorImage;

const RADIAL: usize = 16;
const ANGULAR: usize = 12;
const BAND_BINS: usize = 32;
const BAND_RANGE: f64 = 4.0;
const QUANTILES: usize = 17;

/// The structure descriptor of one grey pattern.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Structure {
    /// Spectrum energy per (radius, orientation) bin, unit length.
    pub spectrum: Vec<f32>,
    /// Normalised band histograms, finest first.
    pub bands: Vec<Vec<f32>>,
    /// Quantiles of the standardised values, lowest first.
    pub quantiles: Vec<f32>,
}

impl Structure {
    /// The descriptor of a `w`×`h` grey pattern.
    pub fn of_values(values: &[f64], w: usize, h: usize) -> Self {
        let n = values.len().max(1) as f64;
        let mean = values.iter().sum::<f64>() / n;
        let sd = (values.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n).sqrt();
        let z: Vec<f64> = if sd > 1e-9 {
            values.iter().map(|v| (v - mean) / sd).collect()
        } else {
            vec![0.0; values.len()]
        };
        Self {
            spectrum: binned_spectrum(&z, w, h),
            bands: laplacian_bands_of(z.clone(), w, h, 4)
                .iter()
                .map(|b| band_histogram(b))
                .collect(),
            quantiles: quantiles(&z),
        }
    }

    /// The descriptor of a pattern rendered as floats.
    pub fn of_field(field: &[f32], w: usize, h: usize) -> Self {
        let v: Vec<f64> = field.iter().map(|&x| f64::from(x)).collect();
        Self::of_values(&v, w, h)
    }

    /// The descriptor of an image's luminance.
    pub fn of_image(img: &ColorImage) -> Self {
        let l = luminance(img);
        let v: Vec<f64> = l.data.iter().map(|&x| f64::from(x)).collect();
        Self::of_values(&v, l.width, l.height)
    }

    /// Distance in [0, 1]: the mean of the spectrum distance (as in S_F),
    /// the band-histogram distance (as in S_L) and the quantile distance,
    /// the last two for the better sign of `other`.
    pub fn distance(&self, other: &Self) -> f64 {
        let d_f = self
            .spectrum
            .iter()
            .zip(&other.spectrum)
            .map(|(a, b)| f64::from(a - b).powi(2))
            .sum::<f64>()
            .sqrt()
            / std::f64::consts::SQRT_2;
        let levels = self.bands.len().min(other.bands.len()).max(1);
        let bands = |flip: bool| {
            let mut s = 0.0;
            for (a, b) in self.bands.iter().zip(&other.bands) {
                let n = b.len();
                s += 0.5
                    * a.iter()
                        .enumerate()
                        .map(|(i, &x)| f64::from((x - b[if flip { n - 1 - i } else { i }]).abs()))
                        .sum::<f64>();
            }
            s / levels as f64
        };
        let quants = |flip: bool| {
            let n = other.quantiles.len();
            let s: f64 = self
                .quantiles
                .iter()
                .enumerate()
                .map(|(i, &x)| {
                    let y = if flip {
                        -other.quantiles[n - 1 - i]
                    } else {
                        other.quantiles[i]
                    };
                    f64::from((x - y).abs())
                })
                .sum();
            (s / n.max(1) as f64 / 2.0).min(1.0)
        };
        let up = bands(false) + quants(false);
        let down = bands(true) + quants(true);
        (d_f.min(1.0) + up.min(down)) / 3.0
    }
}

/// Per frequency its bin ([`spectrum_bins`]).
type Bins = Arc<Vec<Option<u16>>>;

/// Per frequency of a `w`×`h` spectrum its radius × orientation bin, or
/// `None` at zero and beyond the Nyquist radius; made once per size (every
/// descriptor of a catalogue and of a search has the same few sizes).
fn spectrum_bins(w: usize, h: usize) -> Bins {
    static BINS: OnceLock<Mutex<HashMap<(usize, usize), Bins>>> = OnceLock::new();
    let cache = BINS.get_or_init(Default::default);
    if let Some(b) = cache.lock().expect("bins cache").get(&(w, h)) {
        return b.clone();
    }
    let bins: Vec<Option<u16>> = (0..w * h)
        .map(|i| {
            let (fx, fy) = (freq(i % w, w), freq(i / w, h));
            let r = fx.hypot(fy);
            if r == 0.0 || r >= 0.5 {
                return None;
            }
            let rb = ((r / 0.5) * RADIAL as f64) as usize;
            let a = fy.atan2(fx).rem_euclid(std::f64::consts::PI);
            let ab = ((a / std::f64::consts::PI) * ANGULAR as f64) as usize % ANGULAR;
            Some((rb.min(RADIAL - 1) * ANGULAR + ab) as u16)
        })
        .collect();
    let bins = Arc::new(bins);
    cache
        .lock()
        .expect("bins cache")
        .insert((w, h), bins.clone());
    bins
}

/// The S_F spectrum of `z` summed (as energy) into radius × orientation
/// bins up to the Nyquist radius, then unit length.
fn binned_spectrum(z: &[f64], w: usize, h: usize) -> Vec<f32> {
    let s = weighted_spectrum(z, w, h);
    let mut bins = vec![0.0f64; RADIAL * ANGULAR];
    for (b, m) in spectrum_bins(w, h).iter().zip(&s) {
        if let Some(b) = b {
            bins[usize::from(*b)] += m * m;
        }
    }
    let mut out: Vec<f64> = bins.iter().map(|e| e.sqrt()).collect();
    let norm = out.iter().map(|x| x * x).sum::<f64>().sqrt();
    if norm > 0.0 {
        out.iter_mut().for_each(|x| *x /= norm);
    }
    out.iter().map(|&x| x as f32).collect()
}

/// Histogram of a band scaled by its RMS: 32 bins over [−4, 4], outliers in
/// the end bins, normalised.
fn band_histogram(band: &[f64]) -> Vec<f32> {
    let n = band.len().max(1) as f64;
    let rms = (band.iter().map(|x| x * x).sum::<f64>() / n).sqrt();
    let mut h = vec![0.0f64; BAND_BINS];
    if rms < 1e-9 {
        h[BAND_BINS / 2] = 1.0;
    } else {
        for &x in band {
            let t = (x / rms + BAND_RANGE) / (2.0 * BAND_RANGE) * BAND_BINS as f64;
            h[(t.floor().max(0.0) as usize).min(BAND_BINS - 1)] += 1.0 / n;
        }
    }
    h.iter().map(|&x| x as f32).collect()
}

fn quantiles(z: &[f64]) -> Vec<f32> {
    let mut v = z.to_vec();
    v.sort_by(f64::total_cmp);
    (0..QUANTILES)
        .map(|i| {
            if v.is_empty() {
                0.0
            } else {
                v[((v.len() - 1) * i) / (QUANTILES - 1)] as f32
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::procedural::shaders::{by_name, colourise};

    #[test]
    fn a_pattern_and_its_colourings_have_one_descriptor() {
        let s = by_name("marble").unwrap();
        let f = s.render_field(&[3.0, 30.0, 1.0], 64, 64, 64);
        let a = Structure::of_field(&f, 64, 64);
        let dark_on_light = colourise(&f, 64, 64, &[[240.0, 230.0, 200.0], [40.0, 30.0, 20.0]]);
        let b = Structure::of_image(&dark_on_light);
        assert!(a.distance(&b) < 0.03, "{}", a.distance(&b));
        let other = Structure::of_field(&s.render_field(&[6.0, 120.0, 2.0], 64, 64, 64), 64, 64);
        assert!(a.distance(&other) > 0.1, "{}", a.distance(&other));
        assert_eq!(a.distance(&a), 0.0);
    }
}
