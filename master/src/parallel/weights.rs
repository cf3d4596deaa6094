//! Weight maps of a morph (Manke–Wünsche §4): one per exemplar, the size of
//! the output, normalised so they sum to 1 at every pixel. They come from
//! grey images or from a linear ramp.

use std::path::Path;

use anyhow::{ensure, Context, Result};

use crate::imaging;

/// The axis of a ramp.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Axis {
    X,
    Y,
}

/// `m` maps ramping along `axis`: exemplar j has weight 1 at the j-th of `m`
/// evenly spaced stations (the first at the left or top edge, the last at the
/// other), falling linearly to 0 at the stations next to it. Already
/// normalised.
pub fn ramp(m: usize, axis: Axis, width: usize, height: usize) -> Vec<Vec<f32>> {
    let len = match axis {
        Axis::X => width,
        Axis::Y => height,
    };
    (0..m)
        .map(|j| {
            (0..width * height)
                .map(|i| {
                    if m == 1 {
                        return 1.0;
                    }
                    let p = if axis == Axis::X {
                        i % width
                    } else {
                        i / width
                    };
                    let t = if len > 1 {
                        p as f64 / (len - 1) as f64
                    } else {
                        0.0
                    };
                    let d = (t * (m - 1) as f64 - j as f64).abs();
                    (1.0 - d).max(0.0) as f32
                })
                .collect()
        })
        .collect()
}

/// Normalises maps so they sum to 1 at every pixel; where all are 0 each
/// gets `1/m`.
pub fn normalise(maps: &mut [Vec<f32>]) {
    let Some(n) = maps.first().map(Vec::len) else {
        return;
    };
    let m = maps.len() as f32;
    for i in 0..n {
        let sum: f32 = maps.iter().map(|w| w[i]).sum();
        for w in maps.iter_mut() {
            w[i] = if sum > 0.0 { w[i] / sum } else { 1.0 / m };
        }
    }
}

/// Reads weight maps (grey levels of any image, 0 to 1 over the image's
/// range) that must be `width`×`height`, then normalises them.
pub fn load(paths: &[&Path], width: usize, height: usize) -> Result<Vec<Vec<f32>>> {
    let mut maps = Vec::with_capacity(paths.len());
    for p in paths {
        let img = imaging::load_image(p)?;
        ensure!(
            (img.width, img.height) == (width, height),
            "weight map {} is {}x{}; it must be the output size {width}x{height} (--size)",
            p.display(),
            img.width,
            img.height
        );
        let grey = img.to_dynamic().into_luma16();
        maps.push(
            grey.pixels()
                .map(|v| f32::from(v.0[0]) / 65535.0)
                .collect::<Vec<f32>>(),
        );
    }
    normalise(&mut maps);
    Ok(maps)
}

/// Parses `x` or `y`.
pub fn parse_axis(s: &str) -> Result<Axis> {
    match s.trim().to_ascii_lowercase().as_str() {
        "x" => Ok(Axis::X),
        "y" => Ok(Axis::Y),
        _ => None.with_context(|| format!("ramp axis '{s}' is not x or y")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ramps_sum_to_one_and_run_across() {
        for m in 1..5 {
            let maps = ramp(m, Axis::X, 37, 5);
            for i in 0..37 * 5 {
                let s: f32 = maps.iter().map(|w| w[i]).sum();
                assert!((s - 1.0).abs() < 1e-5, "{m} {i} {s}");
            }
            assert_eq!(maps[0][0], 1.0);
            assert_eq!(maps[m - 1][36], 1.0);
        }
        let y = ramp(2, Axis::Y, 4, 11);
        assert_eq!(y[1][10 * 4], 1.0);
        assert_eq!(y[1][3], 0.0);
    }

    #[test]
    fn normalising_makes_sums_one_and_splits_zeros_evenly() {
        let mut maps = vec![vec![0.0, 0.2, 3.0], vec![0.0, 0.6, 1.0]];
        normalise(&mut maps);
        assert_eq!((maps[0][0], maps[1][0]), (0.5, 0.5));
        assert!((maps[0][1] - 0.25).abs() < 1e-6 && (maps[1][2] - 0.25).abs() < 1e-6);
    }
}
