//! How a texture's tones break into pieces (Bourque–Dudek §3.3: the
//! structure that tells textures apart, before colour).
//!
//! Split at its median, a texture of scattered features (spots, beans,
//! stones, caustic cells) is one connected tone holding separate pieces of
//! the other: the ground joins up, the features do not. Noise (clouds, burl,
//! rock) splits into two tones that are both fragmented, in pieces of every
//! size. The spectrum and the autocorrelation do not tell the two apart on
//! photos (both show a hump at the features' spacing); this does.
//!
//! [`Pieces::separation`] is the difference of the two tones' largest-piece
//! shares: near 1 for scattered features, near 0.2–0.4 for noise; and
//! [`Pieces::count`] is how many features the broken tone holds, the seed of
//! a scattered shader's count.

use crate::filters::box_blur_2d;

/// Pieces smaller than this (pixels at the analysis size) are grain, not
/// features, and are not counted.
const MIN_PIECE: usize = 4;

/// The pieces of a texture's two tones.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Pieces {
    /// Each tone's largest piece as a share of that tone's area, one share
    /// less the other, in absolute value (0 for a flat image).
    pub separation: f64,
    /// The broken tone's (the one of the smaller largest share) effective
    /// number of pieces: its area over its area-weighted mean piece size,
    /// so that grain and slivers count for little (0 for a flat image).
    pub count: f64,
}

/// The pieces of the `n`×`n` grey values `v` (row-major): tones split at
/// the median of a high-pass, pieces 4-connected.
pub fn pieces(v: &[f64], n: usize) -> Pieces {
    if n < 4 || v.len() != n * n {
        return Pieces::default();
    }
    // A light blur against pixel grain, less a wide one against shading.
    let mut fine = v.to_vec();
    box_blur_2d(&mut fine, n, n, 1);
    let mut low = fine.clone();
    let r = (n / 8).max(1);
    box_blur_2d(&mut low, n, n, r);
    let high: Vec<f64> = fine.iter().zip(&low).map(|(a, b)| a - b).collect();
    let mut sorted = high.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    if sorted[0] == sorted[sorted.len() - 1] {
        return Pieces::default();
    }
    let upper: Vec<bool> = high.iter().map(|&x| x > median).collect();
    let (hi, lo) = (sizes(&upper, n, true), sizes(&upper, n, false));
    let (a, b) = (largest_share(&hi), largest_share(&lo));
    let broken = if a < b { &hi } else { &lo };
    let kept: Vec<f64> = broken
        .iter()
        .filter(|&&x| x >= MIN_PIECE)
        .map(|&x| x as f64)
        .collect();
    let area: f64 = kept.iter().sum();
    let count = if area > 0.0 {
        area * area / kept.iter().map(|x| x * x).sum::<f64>()
    } else {
        0.0
    };
    Pieces {
        separation: (a - b).abs(),
        count,
    }
}

/// The largest of the piece `sizes` of a tone as a share of the tone's
/// area (pieces under [`MIN_PIECE`] left out of the largest only); 0 when
/// there are none.
fn largest_share(sizes: &[usize]) -> f64 {
    let area: usize = sizes.iter().sum();
    let top = sizes.iter().copied().filter(|&x| x >= MIN_PIECE).max();
    top.map_or(0.0, |t| t as f64 / area as f64)
}

/// The sizes of the 4-connected pieces of pixels equal to `tone`.
fn sizes(mask: &[bool], n: usize, tone: bool) -> Vec<usize> {
    let mut seen = vec![false; mask.len()];
    let mut stack = Vec::new();
    let mut out = Vec::new();
    for start in 0..mask.len() {
        if seen[start] || mask[start] != tone {
            continue;
        }
        seen[start] = true;
        stack.push(start);
        let mut size = 0;
        while let Some(i) = stack.pop() {
            size += 1;
            let (x, y) = (i % n, i / n);
            let mut visit = |j: usize| {
                if !seen[j] && mask[j] == tone {
                    seen[j] = true;
                    stack.push(j);
                }
            };
            if x > 0 {
                visit(i - 1);
            }
            if x + 1 < n {
                visit(i + 1);
            }
            if y > 0 {
                visit(i - n);
            }
            if y + 1 < n {
                visit(i + n);
            }
        }
        out.push(size);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Dark discs of radius `r` on a light ground, `k` per side.
    fn spots(n: usize, k: usize, r: f64) -> Vec<f64> {
        let cell = n as f64 / k as f64;
        (0..n * n)
            .map(|i| {
                let (x, y) = ((i % n) as f64 + 0.5, (i / n) as f64 + 0.5);
                let (dx, dy) = (x % cell - cell / 2.0, y % cell - cell / 2.0);
                if dx.hypot(dy) < r {
                    0.0
                } else {
                    1.0
                }
            })
            .collect()
    }

    #[test]
    fn scattered_spots_separate_and_a_checkerboard_of_pieces_does_not() {
        let n = 128;
        let s = pieces(&spots(n, 8, 6.5), n);
        assert!(s.separation > 0.8, "spots: {s:?}");
        // 64 spots, all of one size.
        assert!((s.count - 64.0).abs() < 1e-9, "spots: {s:?}");
        // Horizontal bands: both tones in pieces of one size (each band its
        // own piece), so neither joins up.
        let bands: Vec<f64> = (0..n * n)
            .map(|i| f64::from((i / n / 8 % 2) as u8))
            .collect();
        let b = pieces(&bands, n).separation;
        assert!(b < 0.2, "bands: {b}");
        assert_eq!(pieces(&vec![0.5; n * n], n), Pieces::default());
    }

    #[test]
    fn the_largest_share_counts_four_connected_pieces() {
        // Two pieces of true (3 and 1 pixels; the lone one is under
        // MIN_PIECE) and one of false.
        #[rustfmt::skip]
        let m = [
            true,  true,  false, false,
            true,  false, false, true,
            false, false, false, false,
            false, false, false, false,
        ];
        assert_eq!(sizes(&m, 4, true), vec![3, 1]);
        assert_eq!(sizes(&m, 4, false), vec![12]);
        assert_eq!(largest_share(&sizes(&m, 4, true)), 0.0);
        assert_eq!(largest_share(&sizes(&m, 4, false)), 1.0);
        let mut m2 = m;
        m2[4 + 2] = true;
        m2[4 + 3] = true;
        // The pieces {0,1,4} and {6,7}: neither reaches 4 pixels.
        assert_eq!(largest_share(&sizes(&m2, 4, true)), 0.0);
        m2[2] = true;
        // {0,1,2,4,6,7} joined through 2 and 6: one piece of 6.
        assert_eq!(largest_share(&sizes(&m2, 4, true)), 1.0);
    }
}
