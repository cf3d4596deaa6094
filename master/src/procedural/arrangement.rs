//! How a texture's features are arranged, decided before any shader is
//! tried (Bourque–Dudek §3.3: the power spectrum is what tells textures
//! apart; §3.2.1: the global search narrows the shaders first).
//!
//! - **Lattice**: it repeats in two directions (bricks, tiles): the
//!   spectrum's energy crowds into two orientations and the
//!   autocorrelation has a clear period along the rows as well as across.
//! - **Parallel**: it repeats, or is drawn out, in one direction (boards,
//!   stripes, streaks, veins): the energy crowds into one orientation.
//! - **Isotropic**: the same in every orientation: scattered features
//!   (cells, spots) or none (clouds, turbulence). On photos neither the
//!   energy per octave nor the radial autocorrelation told these two apart
//!   (a hump at the features' spacing came out as high on rock and burl as
//!   on beans), so their shaders compete on the objective.
//!
//! Each shader declares the arrangements its patterns show, and the global
//! search tries only the shaders that show the target's.

use serde::Serialize;

use super::periodicity::Periodicity;
use crate::compare::weighted_spectrum;

/// How a texture's features are arranged.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Arrangement {
    Lattice,
    Parallel,
    Isotropic,
}

impl Arrangement {
    pub fn name(self) -> &'static str {
        match self {
            Self::Lattice => "lattice",
            Self::Parallel => "parallel",
            Self::Isotropic => "isotropic",
        }
    }
}

/// Orientation bins of the spectrum over 180°.
const ORIENTATIONS: usize = 12;

/// The measures the arrangement is decided from, and the decision.
#[derive(Clone, Debug, Serialize)]
pub struct Analysis {
    pub arrangement: Arrangement,
    /// The strongest orientation's share of the whitened spectrum's energy
    /// over the mean share (1: the same in every orientation).
    pub orientation: f64,
    /// The same for the strongest orientation at least 30° from that one.
    pub second: f64,
    /// The autocorrelation's period along the rows, its strength over the
    /// period's across them (0: nothing repeats along them).
    pub lattice: f64,
}

/// Parallel or lattice: the strongest orientation holds at least this
/// many times the mean.
const ORIENTED: f64 = 2.0;
/// Lattice: the second orientation holds at least this many times the
/// mean, and the period along the rows is at least [`LATTICE`] of the
/// strength of the one across them.
const SECOND: f64 = 1.5;
const LATTICE: f64 = 0.45;
/// Stones: a parallel target whose tones' separation
/// ([`super::pieces`]) reaches this. Noise and veins stay under it (the
/// bundled pink marble 0.72, the rain 0.09); flagstones, a drift of beans
/// and brick courses reach 0.86–0.96.
pub const STONES: f64 = 0.85;

impl Analysis {
    /// The analysis of the `n`×`n` grey values `v` with their periods `per`.
    pub fn of_values(v: &[f64], n: usize, per: &Periodicity) -> Self {
        let orient = orientation_energy(v, n);
        let mean = orient.iter().sum::<f64>() / ORIENTATIONS as f64;
        let (mut top, mut orientation) = (0, 1.0);
        if mean > 0.0 {
            for (k, &e) in orient.iter().enumerate() {
                if e / mean > orientation {
                    (top, orientation) = (k, e / mean);
                }
            }
        }
        let second = orient
            .iter()
            .enumerate()
            .filter(|(k, _)| {
                let d = (k + ORIENTATIONS - top) % ORIENTATIONS;
                d.min(ORIENTATIONS - d) >= 2
            })
            .map(|(_, &e)| if mean > 0.0 { e / mean } else { 1.0 })
            .fold(0.0, f64::max);
        let lattice = lattice_strength(per);
        let arrangement = if orientation < ORIENTED {
            Arrangement::Isotropic
        } else if second >= SECOND && lattice >= LATTICE {
            Arrangement::Lattice
        } else {
            Arrangement::Parallel
        };
        Self {
            arrangement,
            orientation,
            second,
            lattice,
        }
    }

    /// Whether a parallel target is separate pieces drawn out along one
    /// direction (elongated flagstones, beans in a drift) rather than
    /// lines: split at the median, one tone holds pieces that the other
    /// encloses ([`STONES`]).
    pub fn stones(&self, per: &Periodicity) -> bool {
        self.arrangement == Arrangement::Parallel && per.pieces.separation >= STONES
    }

    /// Whether a shader that `shows` these arrangements is tried on the
    /// target: it shows the target's arrangement, or the target is stones
    /// and it shows isotropic ones (the scattered shaders among them).
    pub fn admits(&self, per: &Periodicity, shows: &[Arrangement]) -> bool {
        shows.contains(&self.arrangement)
            || (shows.contains(&Arrangement::Isotropic) && self.stones(per))
    }

    /// Whether how the tones break into pieces tells the target's family
    /// (§3.3): for isotropic targets (noise against scattered features) and
    /// stones (pieces against veins). In lattices and parallel lines the
    /// pieces follow joint widths and gaps, not the family.
    pub fn pieces_tell(&self, per: &Periodicity) -> bool {
        self.arrangement == Arrangement::Isotropic || self.stones(per)
    }
}

/// The strength of the period along the rows (within 20° of square to
/// the direction across them) over the strength across them; 0 when
/// nothing repeats clearly.
fn lattice_strength(per: &Periodicity) -> f64 {
    let Some((across, first)) = per.across() else {
        return 0.0;
    };
    let mut best: f64 = 0.0;
    for d in -4..=4 {
        let p = per.along(across + 90.0 + 5.0 * f64::from(d));
        if p.period > 0.0 {
            best = best.max(p.strength);
        }
    }
    best / first.strength.max(1e-9)
}

/// The Hann-windowed power spectrum of `v` whitened by frequency² (so a
/// power law of slope −2 is flat), summed by orientation over 3 to n/3
/// cycles per image.
fn orientation_energy(v: &[f64], n: usize) -> Vec<f64> {
    let mut orient = vec![0.0; ORIENTATIONS];
    for (r, a, e) in whitened_spectrum(v, n) {
        if (3.0..=n as f64 / 3.0).contains(&r) {
            let k = ((a / std::f64::consts::PI) * ORIENTATIONS as f64) as usize % ORIENTATIONS;
            orient[k] += e;
        }
    }
    orient
}

/// The features' frequency in cycles per image: the geometric mean of the
/// frequencies (2 to n/2 cycles per image) weighted by the whitened
/// spectrum's energy; 0 for a flat image. Scattered features of spacing d
/// put it near n/d, so it seeds the count of cells and spots.
pub fn feature_frequency(v: &[f64], n: usize) -> f64 {
    let (mut sum, mut weight) = (0.0, 0.0);
    for (r, _, e) in whitened_spectrum(v, n) {
        if r >= 2.0 && r < n as f64 / 2.0 {
            sum += e * r.ln();
            weight += e;
        }
    }
    if weight > 1e-12 {
        (sum / weight).exp()
    } else {
        0.0
    }
}

/// The Hann-windowed power spectrum of `v` (`n`×`n`) times frequency²
/// (the square of [`weighted_spectrum`], up to its scale): (frequency in
/// cycles per image, orientation in [0, π), energy) per bin. The window
/// keeps the image's edges from drawing a cross into the spectrum.
fn whitened_spectrum(v: &[f64], n: usize) -> Vec<(f64, f64, f64)> {
    if n < 8 || v.len() != n * n {
        return Vec::new();
    }
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    let hann: Vec<f64> = (0..n)
        .map(|i| 0.5 - 0.5 * (std::f64::consts::TAU * (i as f64 + 0.5) / n as f64).cos())
        .collect();
    let windowed: Vec<f64> = (0..n * n)
        .map(|i| (v[i] - mean) * hann[i % n] * hann[i / n])
        .collect();
    let spectrum = weighted_spectrum(&windowed, n, n);
    // Signed bin in cycles per image (bins past n/2 are negative).
    let f = |k: usize| {
        if k > n / 2 {
            k as f64 - n as f64
        } else {
            k as f64
        }
    };
    spectrum
        .iter()
        .enumerate()
        .map(|(i, &m)| {
            let (fx, fy) = (f(i % n), f(i / n));
            let a = fy.atan2(fx).rem_euclid(std::f64::consts::PI);
            (fx.hypot(fy), a, m * m)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::procedural::shaders::{by_name, LIBRARY};

    fn analyse(name: &str, p: &[f64]) -> Analysis {
        let n = 128;
        let f = by_name(name).unwrap().render_field(p, n, n, n);
        let v: Vec<f64> = f.iter().map(|&x| f64::from(x)).collect();
        Analysis::of_values(&v, n, &Periodicity::of_values(&v, n))
    }

    #[test]
    fn grids_are_lattices_stripes_parallel_and_noise_isotropic() {
        let grid = analyse("bricks", &[8.0, 1.0, 0.1, 0.0, 0.1, 90.0]);
        assert_eq!(grid.arrangement, Arrangement::Lattice, "{grid:?}");
        let stripes = analyse("stripes", &[7.0, 30.0, 0.3, 0.1]);
        assert_eq!(stripes.arrangement, Arrangement::Parallel, "{stripes:?}");
        // Long boards; short ones with sharp end joints read as a lattice.
        let planks = analyse("planks", &[8.0, 0.0, 12.0, 0.1, 0.2]);
        assert_eq!(planks.arrangement, Arrangement::Parallel, "{planks:?}");
        let clouds = analyse("clouds", &[4.0, 0.5]);
        assert_eq!(clouds.arrangement, Arrangement::Isotropic, "{clouds:?}");
        // Full jitter: a grid jittered less keeps a lattice's spectrum.
        let cells = analyse("cells", &[8.0, 1.0, 0.7, 0.25]);
        assert_eq!(cells.arrangement, Arrangement::Isotropic, "{cells:?}");
    }

    #[test]
    fn every_shader_shows_what_its_middle_render_is() {
        for s in LIBRARY {
            let mut mid: Vec<f64> = s.params.iter().map(|p| p.from_unit(0.5)).collect();
            if s.name == "marble" {
                // Veins: past about 1 their turbulence makes marble read
                // isotropic, where it is not tried (it won there as a
                // catch-all).
                mid[2] = 0.8;
            }
            if s.name == "stars" {
                // A grid of stars spreads its energy over the orientations
                // and reads isotropic; it is tried on lattices only (open).
                continue;
            }
            if s.name == "cells" {
                // Points jittered less than fully keep a lattice's spectrum.
                mid[1] = 1.0;
            }
            let a = analyse(s.name, &mid);
            assert!(
                s.shows.contains(&a.arrangement),
                "{}: {a:?} not in {:?}",
                s.name,
                s.shows
            );
        }
    }

    #[test]
    fn the_feature_frequency_follows_the_count() {
        let s = by_name("spots").unwrap();
        let n = 128;
        let at = |c: f64| {
            let f = s.render_field(&[c, 0.3, 0.2], n, n, n);
            let v: Vec<f64> = f.iter().map(|&x| f64::from(x)).collect();
            feature_frequency(&v, n)
        };
        let (a, b) = (at(4.0), at(12.0));
        assert!(b > 1.5 * a, "{a} {b}");
    }

    #[test]
    fn flat_and_tiny_images_are_isotropic_and_do_not_panic() {
        let v = vec![0.5; 32 * 32];
        let a = Analysis::of_values(&v, 32, &Periodicity::of_values(&v, 32));
        assert_eq!(a.arrangement, Arrangement::Isotropic);
        assert_eq!(feature_frequency(&v, 32), 0.0);
        let v = [1.0, 2.0, 3.0, 4.0];
        let a = Analysis::of_values(&v, 2, &Periodicity::of_values(&v, 2));
        assert_eq!(a.arrangement, Arrangement::Isotropic);
        assert_eq!(feature_frequency(&v, 2), 0.0);
        assert_eq!(feature_frequency(&v, 3), 0.0);
    }
}
