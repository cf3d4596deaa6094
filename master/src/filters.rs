//! Wrapping box filters shared by the methods: the running-sum box blur of
//! the coordinate method's stack levels (Manke–Wünsche §3) and the blurred
//! spectra of procedural matching (Bourque–Dudek §3.2); and the 2-D FFT
//! that `compare`, the tile evaluation and the periodicity analysis share;
//! the normalised autocorrelation that the periodicity analysis and lattice
//! detection read; and the correlation length, the scale of a texture's
//! objects.

use std::ops::{Add, Sub};

use rustfft::num_complex::Complex;
use rustfft::{Fft, FftNum};

use crate::imaging::ColorImage;

/// `(k − r) mod n` without going below zero: the first index of the window
/// at `k` (shared by [`window_sums`] and [`box_blur_lines`]).
fn wrap_back(k: usize, n: usize, r: usize) -> usize {
    (k + n * (r / n + 1) - r) % n
}

/// The sums of every window of radius `r` along a wrapped line of `n`
/// values: `emit(k, Σ value(k − r ..= k + r))` for each `k`. The first sum
/// adds the `2r + 1` values in order; each next one adds the entering value
/// minus the leaving one, so the cost does not grow with `r`.
pub fn window_sums<S>(
    n: usize,
    r: usize,
    value: impl Fn(usize) -> S,
    mut emit: impl FnMut(usize, S),
) where
    S: Copy + std::iter::Sum + Add<Output = S> + Sub<Output = S>,
{
    if n == 0 {
        return;
    }
    let back = |k: usize| wrap_back(k, n, r);
    let mut sum: S = (0..=2 * r).map(|j| value(back(j))).sum();
    for k in 0..n {
        emit(k, sum);
        sum = sum + (value((k + r + 1) % n) - value(back(k)));
    }
}

/// A wrapping box blur of radius `r` of an RGB image: a horizontal then a
/// vertical pass of running sums, each pass rounded to bytes.
pub fn box_blur_rgb(img: &ColorImage, r: usize) -> ColorImage {
    if r == 0 {
        return img.clone();
    }
    let n = (2 * r + 1) as i64;
    let (w, h) = (img.width, img.height);
    // One pass along `count` lines of `len` pixels, pixel (line, i) at `index(line, i)`.
    let pass = |src: &[u8], len: usize, count: usize, index: &dyn Fn(usize, usize) -> usize| {
        let mut out = vec![0u8; src.len()];
        for line in 0..count {
            for c in 0..3 {
                let value = |i: usize| i64::from(src[index(line, i) * 3 + c]);
                window_sums(len, r, value, |i, sum| {
                    out[index(line, i) * 3 + c] = ((sum + n / 2) / n) as u8;
                });
            }
        }
        out
    };
    let rows = pass(&img.rgb, w, h, &|line, i| line * w + i);
    let cols = pass(&rows, h, w, &|line, i| i * w + line);
    ColorImage::from_vec(w, h, cols)
}

/// A wrapping box blur (the mean over `2r + 1` values) of radius `r` along
/// `lines` lines of `n` values `step` apart, the lines `stride` apart, in place.
pub fn box_blur_lines(v: &mut [f64], n: usize, lines: usize, r: usize, step: usize, stride: usize) {
    if r == 0 || n == 0 {
        return;
    }
    let width = (2 * r + 1) as f64;
    // The wrapped indices of `window_sums`, taken once for all lines: the
    // first window's values in order, then per k the entering and the
    // leaving value.
    let back = |k: usize| wrap_back(k, n, r);
    let first: Vec<usize> = (0..=2 * r).map(back).collect();
    let enter: Vec<usize> = (0..n).map(|k| (k + r + 1) % n).collect();
    let leave: Vec<usize> = (0..n).map(back).collect();
    if stride == 1 && step >= lines {
        // Lines side by side (the columns of a row-major buffer): every line
        // takes the same steps as one line alone, all of them at once, so
        // each step runs along contiguous values.
        let copy: Vec<f64> = (0..n)
            .flat_map(|k| v[k * step..k * step + lines].iter().copied())
            .collect();
        let row = |k: usize| &copy[k * lines..(k + 1) * lines];
        // `Sum` for floats starts at −0.0.
        let mut sum = vec![-0.0f64; lines];
        for &j in &first {
            sum.iter_mut().zip(row(j)).for_each(|(s, &x)| *s += x);
        }
        for k in 0..n {
            let out = &mut v[k * step..k * step + lines];
            out.iter_mut().zip(&sum).for_each(|(o, &s)| *o = s / width);
            for ((s, &e), &l) in sum.iter_mut().zip(row(enter[k])).zip(row(leave[k])) {
                *s += e - l;
            }
        }
        return;
    }
    let mut line = vec![0.0; n];
    for l in 0..lines {
        let at = |k: usize| l * stride + k * step;
        for (k, x) in line.iter_mut().enumerate() {
            *x = v[at(k)];
        }
        let mut sum: f64 = first.iter().map(|&j| line[j]).sum();
        for k in 0..n {
            v[at(k)] = sum / width;
            sum += line[enter[k]] - line[leave[k]];
        }
    }
}

/// [`box_blur_lines`] along the rows, then the columns, of a `w`×`h`
/// buffer (row-major), in place: a wrapping 2-D box blur of radius `r`.
pub fn box_blur_2d(v: &mut [f64], w: usize, h: usize, r: usize) {
    box_blur_lines(v, w, h, r, 1, w);
    box_blur_lines(v, h, w, r, w, 1);
}

/// 2-D FFT in place of a `w`×`h` buffer (row by row): rows `0..rows` (the
/// only ones that may be non-zero) through `row_fft`, then every column
/// through `col_fft`. The plans' direction decides forward or inverse.
pub fn fft2<T: FftNum>(
    buf: &mut [Complex<T>],
    (w, h): (usize, usize),
    rows: usize,
    (row_fft, col_fft): (&dyn Fft<T>, &dyn Fft<T>),
) {
    for row in buf.chunks_exact_mut(w).take(rows) {
        row_fft.process(row);
    }
    let mut col = vec![Complex::new(T::zero(), T::zero()); h];
    for x in 0..w {
        for y in 0..h {
            col[y] = buf[y * w + x];
        }
        col_fft.process(&mut col);
        for y in 0..h {
            buf[y * w + x] = col[y];
        }
    }
}

/// The normalised linear autocorrelation of the `w`×`h` values `v`
/// (row-major, mean removed), on the wrapped lag grid of 2w×2h (lag
/// `(dx, dy)` at `(dx mod 2w, dy mod 2h)`): each lag divided by its overlap,
/// then by the variance, so lag 0 is 1; lags of a side or more, and every
/// lag of a flat image, are 0.
pub fn autocorrelation(v: &[f64], (w, h): (usize, usize)) -> Vec<f64> {
    let (pw, ph) = (2 * w, 2 * h);
    let len = v.len().max(1) as f64;
    let mean = v.iter().sum::<f64>() / len;
    let mut buf = vec![Complex::new(0.0, 0.0); pw * ph];
    for y in 0..h {
        for x in 0..w {
            buf[y * pw + x] = Complex::new(v.get(y * w + x).copied().unwrap_or(mean) - mean, 0.0);
        }
    }
    let mut planner = rustfft::FftPlanner::new();
    let (rows, cols) = (planner.plan_fft_forward(pw), planner.plan_fft_forward(ph));
    fft2(&mut buf, (pw, ph), ph, (&*rows, &*cols));
    buf.iter_mut()
        .for_each(|c| *c = Complex::new(c.norm_sqr(), 0.0));
    let (rows, cols) = (planner.plan_fft_inverse(pw), planner.plan_fft_inverse(ph));
    fft2(&mut buf, (pw, ph), ph, (&*rows, &*cols));
    let zero = buf[0].re;
    let lag = |k: usize, n: usize| if k > n { 2 * n - k } else { k };
    (0..pw * ph)
        .map(|i| {
            let (x, y) = (lag(i % pw, w), lag(i / pw, h));
            if zero <= 1e-12 || x >= w || y >= h {
                return 0.0;
            }
            let overlap = ((w - x) * (h - y)) as f64 / (w * h) as f64;
            buf[i].re / overlap / zero
        })
        .collect()
}

/// The correlation length of a `w`×`h` grey image: the least radius, in
/// pixels, at which the radially averaged autocorrelation of its
/// mean-removed values falls below `level` (0 < level < 1), or the image's
/// larger side if it never does. The autocorrelation is the linear one
/// (zero-padded FFT), so lags near the side count fewer pixel pairs. A flat
/// image has length 0.
pub fn correlation_length(values: &[u8], (w, h): (usize, usize), level: f64) -> usize {
    assert_eq!(values.len(), w * h, "grey buffer size");
    if w == 0 || h == 0 {
        return 0;
    }
    let mean = values.iter().map(|&v| f64::from(v)).sum::<f64>() / (w * h) as f64;
    let (pw, ph) = (2 * w, 2 * h);
    let mut buf = vec![Complex::new(0.0f64, 0.0); pw * ph];
    for y in 0..h {
        for x in 0..w {
            buf[y * pw + x].re = f64::from(values[y * w + x]) - mean;
        }
    }
    let mut planner = rustfft::FftPlanner::new();
    let (rows, cols) = (planner.plan_fft_forward(pw), planner.plan_fft_forward(ph));
    fft2(&mut buf, (pw, ph), h, (&*rows, &*cols));
    for c in &mut buf {
        *c = Complex::new(c.norm_sqr(), 0.0);
    }
    let (rows, cols) = (planner.plan_fft_inverse(pw), planner.plan_fft_inverse(ph));
    fft2(&mut buf, (pw, ph), ph, (&*rows, &*cols));
    let zero = buf[0].re;
    if zero <= 0.0 {
        return 0;
    }
    // Radial average over whole-pixel radii, lags read both ways round.
    let side = w.max(h);
    let (mut sum, mut count) = (vec![0.0f64; side + 1], vec![0u32; side + 1]);
    for y in 0..ph {
        let dy = y.min(ph - y);
        for x in 0..pw {
            let dx = x.min(pw - x);
            let r = ((dx * dx + dy * dy) as f64).sqrt().round() as usize;
            if r <= side {
                sum[r] += buf[y * pw + x].re / zero;
                count[r] += 1;
            }
        }
    }
    (0..=side)
        .find(|&r| count[r] > 0 && sum[r] / f64::from(count[r]) < level)
        .unwrap_or(side)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn correlation_length_grows_with_the_size_of_the_objects() {
        // Discs of radius `r` on a grid of pitch 4r: the autocorrelation
        // falls to a quarter at about the discs' radius.
        let discs = |r: usize| -> Vec<u8> {
            let (n, pitch) = (256usize, 4 * r);
            (0..n * n)
                .map(|i| {
                    let (x, y) = (i % n, i / n);
                    let (cx, cy) = (x % pitch, y % pitch);
                    let d2 = cx.abs_diff(pitch / 2).pow(2) + cy.abs_diff(pitch / 2).pow(2);
                    if d2 <= r * r {
                        200
                    } else {
                        40
                    }
                })
                .collect()
        };
        let lengths: Vec<usize> = [3, 6, 12]
            .iter()
            .map(|&r| correlation_length(&discs(r), (256, 256), 0.25))
            .collect();
        assert!(
            lengths[0] < lengths[1] && lengths[1] < lengths[2],
            "{lengths:?}"
        );
        for (l, r) in lengths.iter().zip([3usize, 6, 12]) {
            assert!(
                (r / 2..=2 * r).contains(l),
                "radius {r}: correlation length {l}"
            );
        }
        // White noise decorrelates within a pixel; a flat image has none.
        let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(7);
        let noise: Vec<u8> = (0..128 * 128)
            .map(|_| rand::Rng::random::<u8>(&mut rng))
            .collect();
        assert!(correlation_length(&noise, (128, 128), 0.25) <= 1);
        assert_eq!(correlation_length(&[90; 64], (8, 8), 0.25), 0);
    }

    #[test]
    fn window_sums_match_a_direct_sum() {
        for n in 1..9usize {
            for r in 0..12usize {
                let vals: Vec<i64> = (0..n as i64).map(|i| i * i - 3 * i + 7).collect();
                let mut got = vec![0i64; n];
                window_sums(n, r, |k| vals[k], |k, s| got[k] = s);
                for (k, g) in got.iter().enumerate() {
                    let direct: i64 = (0..=2 * r)
                        .map(|j| vals[((k + j) as i64 - r as i64).rem_euclid(n as i64) as usize])
                        .sum();
                    assert_eq!(*g, direct, "n {n} r {r} k {k}");
                }
            }
        }
    }

    #[test]
    fn columns_blurred_side_by_side_are_the_rows_of_the_transpose_bit_for_bit() {
        // The column pass takes every column's steps at once; the row pass
        // one line at a time. Same sums in the same order: same bits.
        let (w, h) = (11, 9);
        let v: Vec<f64> = (0..w * h)
            .map(|i| ((i * 7919) % 1013) as f64 / 7.0 - 60.0)
            .collect();
        let t: Vec<f64> = (0..w * h).map(|i| v[(i % h) * w + i / h]).collect();
        for r in [0, 1, 3, 4, 9, 12] {
            let mut cols = v.clone();
            box_blur_lines(&mut cols, h, w, r, w, 1);
            let mut rows = t.clone();
            box_blur_lines(&mut rows, h, w, r, 1, h);
            for y in 0..h {
                for x in 0..w {
                    assert_eq!(
                        cols[y * w + x].to_bits(),
                        rows[x * h + y].to_bits(),
                        "r {r} at ({x}, {y})"
                    );
                }
            }
        }
    }

    #[test]
    fn box_blur_of_a_constant_is_the_constant() {
        let img = ColorImage::from_vec(5, 3, [10u8, 200, 33].repeat(15));
        assert_eq!(box_blur_rgb(&img, 4).rgb, img.rgb);
        let mut v = vec![2.5; 12];
        box_blur_lines(&mut v, 4, 3, 2, 1, 4);
        assert!(v.iter().all(|x| (x - 2.5).abs() < 1e-12));
    }
}
