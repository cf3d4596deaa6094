//! Even slice contrast (ARCHITECTURE §11; a departure from the paper, in the
//! spirit of Kopf et al. 2007's histogram matching): every slice across every
//! axis keeps its per-channel standard deviation within [`BAND`] of the
//! exemplars'.
//!
//! The colour's histogram is matched over the whole volume, so the volume's
//! spread is the exemplars', but a slice is one cut of it: where the low
//! frequencies of the volume fall, whole slices come out flatter or harsher
//! than the exemplar (a 108³ rain solid's slices ranged from 0.65 to 1.15 of
//! its contrast, a third of them under 0.8). A user cuts the solid anywhere,
//! so each slice is scaled about its own mean into the band, across x, then
//! y, then z, for [`ROUNDS`] rounds (each axis's scaling moves the others'
//! slices a little, less each round).

use rayon::prelude::*;

use crate::compare::channel_deviations;
use crate::imaging::ColorImage;

/// A slice's per-channel standard deviation is kept within this share of
/// the exemplars' (inside it, slices keep their own contrast).
pub const BAND: (f64, f64) = (0.9, 1.1);

/// Rounds over the three axes: measured on rain at 108³, the third round
/// leaves every slice within the band to two decimals.
pub const ROUNDS: usize = 3;

/// Most a slice is scaled by in one step: a nearly flat slice is not blown
/// up into noise.
const MAX_SCALE: f64 = 2.0;

/// The maps' standard deviation of channel `ch`, each map with its weight
/// (the root of their weighted mean variance; one map: its own).
fn target_deviation(maps: &[(&ColorImage, f64)], ch: usize) -> f64 {
    let weight: f64 = maps.iter().map(|m| m.1).sum();
    if weight <= 0.0 {
        return 0.0;
    }
    let var = maps
        .iter()
        .map(|&(m, w)| w * channel_deviations(m)[ch].powi(2))
        .sum::<f64>()
        / weight;
    var.sqrt()
}

/// Per slice across `axis` of `v` (a volume of `size`, x fastest): its mean
/// and standard deviation. Summed per z plane, then over the planes in
/// order, so the result does not depend on the thread count.
fn slice_moments(v: &[f32], size: [usize; 3], axis: usize) -> Vec<(f64, f64)> {
    let [nx, ny, _] = size;
    let slices = size[axis];
    let plane = nx * ny;
    let per_plane: Vec<Vec<(f64, f64)>> = v
        .par_chunks(plane)
        .map(|p| {
            let mut sums = vec![(0.0f64, 0.0f64); if axis == 2 { 1 } else { slices }];
            for (i, &x) in p.iter().enumerate() {
                let k = match axis {
                    0 => i % nx,
                    1 => i / nx,
                    _ => 0,
                };
                let x = f64::from(x);
                sums[k].0 += x;
                sums[k].1 += x * x;
            }
            sums
        })
        .collect();
    let count = (v.len() / slices.max(1)).max(1) as f64;
    let mut sums = vec![(0.0f64, 0.0f64); slices];
    for (z, p) in per_plane.iter().enumerate() {
        for (k, s) in p.iter().enumerate() {
            let k = if axis == 2 { z } else { k };
            sums[k].0 += s.0;
            sums[k].1 += s.1;
        }
    }
    sums.into_iter()
        .map(|(s, s2)| {
            let mean = s / count;
            (mean, (s2 / count - mean * mean).max(0.0).sqrt())
        })
        .collect()
}

/// Scales every slice of `v` across `axis` about its mean so its standard
/// deviation lies within [`BAND`] of `target`; whether any slice changed.
fn even_axis(v: &mut [f32], size: [usize; 3], axis: usize, target: f64) -> bool {
    let (lo, hi) = (BAND.0 * target, BAND.1 * target);
    let scales: Vec<(f32, f32)> = slice_moments(v, size, axis)
        .into_iter()
        .map(|(mean, sd)| {
            let scale = if sd > 1e-9 {
                (sd.clamp(lo, hi) / sd).min(MAX_SCALE)
            } else {
                1.0
            };
            (mean as f32, scale as f32)
        })
        .collect();
    if scales.iter().all(|s| s.1 == 1.0) {
        return false;
    }
    let [nx, ny, _] = size;
    v.par_chunks_mut(nx * ny).enumerate().for_each(|(z, p)| {
        for (i, x) in p.iter_mut().enumerate() {
            let k = match axis {
                0 => i % nx,
                1 => i / nx,
                _ => z,
            };
            let (mean, scale) = scales[k];
            if scale != 1.0 {
                *x = mean + (*x - mean) * scale;
            }
        }
    });
    true
}

/// Keeps every slice of `data` (a volume of `size`, `channels` bytes per
/// voxel, x fastest) within [`BAND`] of the `maps`' contrast (each map with
/// its weight), channel by channel. A channel whose slices all lie in the
/// band keeps its bytes.
pub fn even_slices(
    data: &mut [u8],
    size: [usize; 3],
    channels: usize,
    maps: &[(&ColorImage, f64)],
) {
    if !super::bands::holds_a_volume(data, size, channels, maps) {
        return;
    }
    for ch in 0..channels {
        let target = target_deviation(maps, ch);
        if target <= 0.0 {
            continue;
        }
        let mut v: Vec<f32> = data
            .par_chunks(channels)
            .map(|px| f32::from(px[ch]))
            .collect();
        let mut changed = false;
        for _ in 0..ROUNDS {
            let mut moved = false;
            for axis in 0..3 {
                moved |= even_axis(&mut v, size, axis, target);
            }
            changed |= moved;
            if !moved {
                break;
            }
        }
        if changed {
            data.par_chunks_mut(channels)
                .zip(v.par_iter())
                .for_each(|(px, &x)| px[ch] = x.round().clamp(0.0, 255.0) as u8);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// A scalar reference: the mean and standard deviation of the voxels
    /// whose coordinate along `axis` is `k`.
    fn reference(v: &[f32], size: [usize; 3], axis: usize, k: usize) -> (f64, f64) {
        let xs: Vec<f64> = (0..v.len())
            .filter(|&i| {
                let p = [
                    i % size[0],
                    (i / size[0]) % size[1],
                    i / (size[0] * size[1]),
                ];
                p[axis] == k
            })
            .map(|i| f64::from(v[i]))
            .collect();
        let n = xs.len() as f64;
        let mean = xs.iter().sum::<f64>() / n;
        let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n;
        (mean, var.sqrt())
    }

    proptest! {
        /// The slice moments equal a scalar reference on every axis, for
        /// odd and even sides.
        #[test]
        fn slice_moments_match_a_scalar_reference(
            x in 1usize..9, y in 1usize..9, z in 1usize..9, seed in any::<u64>()
        ) {
            let size = [x, y, z];
            let n = x * y * z;
            let v: Vec<f32> = (0..n as u64)
                .map(|i| ((i.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ seed) >> 56) as f32)
                .collect();
            for axis in 0..3 {
                let m = slice_moments(&v, size, axis);
                prop_assert_eq!(m.len(), size[axis]);
                for (k, &(mean, sd)) in m.iter().enumerate() {
                    let (rm, rs) = reference(&v, size, axis, k);
                    prop_assert!((mean - rm).abs() < 1e-6 && (sd - rs).abs() < 1e-4,
                        "axis {} slice {}: {} {} against {} {}", axis, k, mean, sd, rm, rs);
                }
            }
        }
    }

    /// A checker volume of `size` about 128 whose spread is `amp(z)` on
    /// channel 0 and half, three halves of it on the others.
    fn checker(size: [usize; 3], amp: impl Fn(usize) -> f64) -> Vec<u8> {
        let mut data = Vec::with_capacity(size.iter().product::<usize>() * 3);
        for z in 0..size[2] {
            for y in 0..size[1] {
                for x in 0..size[0] {
                    let d = if (x + y + z) % 2 == 0 { 1.0 } else { -1.0 };
                    for c in 0..3 {
                        let v = 128.0 + d * amp(z) * (c + 1) as f64 / 2.0;
                        data.push(v.round() as u8);
                    }
                }
            }
        }
        data
    }

    /// A volume whose contrast grows along z (slice z has spread 6 + 3z,
    /// against the exemplar's 20) comes out with every slice on every axis
    /// within the band, each slice's mean kept; a volume whose slices are
    /// already inside keeps its bytes.
    #[test]
    fn every_slice_ends_within_the_band_and_keeps_its_mean() {
        let size = [24, 20, 16];
        let ex_size = [32, 32, 1];
        let ex = ColorImage::from_vec(32, 32, checker(ex_size, |_| 20.0));
        let target: Vec<f64> = (0..3).map(|c| target_deviation(&[(&ex, 1.0)], c)).collect();
        let before = checker(size, |z| 6.0 + 3.0 * z as f64);
        let mut data = before.clone();
        even_slices(&mut data, size, 3, &[(&ex, 1.0)]);
        assert_ne!(data, before);
        for c in 0..3 {
            let v: Vec<f32> = data.chunks(3).map(|p| f32::from(p[c])).collect();
            let b: Vec<f32> = before.chunks(3).map(|p| f32::from(p[c])).collect();
            for axis in 0..3 {
                for k in 0..size[axis] {
                    let (mean, sd) = reference(&v, size, axis, k);
                    let r = sd / target[c];
                    // The rounding to bytes and the last round's moves on
                    // the other axes leave a little room.
                    assert!(
                        (0.87..=1.13).contains(&r),
                        "channel {c} axis {axis} slice {k}: {r:.3} of the exemplar's"
                    );
                    let (m0, _) = reference(&b, size, axis, k);
                    assert!((mean - m0).abs() < 1.0, "mean {m0} → {mean}");
                }
            }
        }
        // Inside the band everywhere (spread 21 against 20): left as it is.
        let inside = checker(size, |_| 21.0);
        let mut kept = inside.clone();
        even_slices(&mut kept, size, 3, &[(&ex, 1.0)]);
        assert_eq!(kept, inside);
    }
}
