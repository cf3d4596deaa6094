//! Lattice phase, shared by the methods that keep a grid sample's grid
//! (the block method, ARCHITECTURE §3.14; solids, §11): the grid's periods,
//! how far a copy offset lies from the lattice, and the grid found in a
//! sample (`--lattice auto`).

use anyhow::{ensure, Result};

use crate::filters::{autocorrelation, box_blur_2d};
use crate::imaging::{colour::luma, ColorImage};

/// The grid's periods along x and y, in sample pixels of the finest level;
/// 0 leaves that axis free (courses of brick whose joints along the course
/// do not keep one period).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Lattice {
    pub period: [f64; 2],
}

/// `--lattice`: the grid's periods as given, `auto`, the grid [`detect`]
/// finds in the sample (none where it finds none), or `none`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LatticeSpec {
    Given(Lattice),
    Auto,
    Off,
}

impl LatticeSpec {
    /// The periods as given; `None` for `auto`, which only the sample
    /// resolves, and for `none`.
    pub fn given(&self) -> Option<Lattice> {
        match self {
            Self::Given(l) => Some(*l),
            Self::Auto | Self::Off => None,
        }
    }
}

impl Lattice {
    /// Periods of at least 2 pixels and at most the sample's side, or 0 (that
    /// axis free), not both 0.
    pub fn validate(&self, sample: [usize; 2]) -> Result<()> {
        ensure!(
            self.period != [0.0, 0.0],
            "--lattice 0x0 keeps no phase; give the grid's period on at least one axis"
        );
        for (axis, (&p, &side)) in ["width", "height"]
            .iter()
            .zip(self.period.iter().zip(&sample))
        {
            if p == 0.0 {
                continue;
            }
            ensure!(
                p.is_finite() && p >= 2.0,
                "--lattice {axis} {p} must be at least 2 pixels (the grid's period: the distance from one joint to the next), or 0 to leave that axis free"
            );
            ensure!(
                p <= side as f64,
                "--lattice {axis} {p} is larger than the sample's {axis} {side}; give the period of one tile of the grid"
            );
        }
        Ok(())
    }

    /// The share of `img`'s colour variance (summed over R, G and B) that
    /// lies between the grid's cells: the variance of the cells' mean
    /// colours, over whole cells from the origin (a free axis is one cell
    /// long). Near 0 where every cell looks alike (a weave, one kind of
    /// tile), high where each cell has its own colour (coloured tiles); 0
    /// for a flat image.
    pub fn cell_share(&self, img: &ColorImage) -> f64 {
        let cells = |axis: usize, side: usize| {
            let p = self.period[axis];
            let n = if p == 0.0 {
                1
            } else {
                (side as f64 / p).floor() as usize
            };
            let at = move |i: usize| {
                if p == 0.0 {
                    0
                } else {
                    (i as f64 / p).floor() as usize
                }
            };
            (n, at)
        };
        let ((nx, cx), (ny, cy)) = (cells(0, img.width), cells(1, img.height));
        let mut sums = vec![[0.0f64; 3]; nx * ny];
        let mut counts = vec![0usize; nx * ny];
        let (mut total, mut total_sq, mut n) = ([0.0f64; 3], 0.0f64, 0usize);
        for y in 0..img.height {
            let row = cy(y);
            if row >= ny {
                continue;
            }
            for x in 0..img.width {
                let col = cx(x);
                if col >= nx {
                    continue;
                }
                let px = &img.rgb[3 * (y * img.width + x)..][..3];
                let cell = row * nx + col;
                for c in 0..3 {
                    let v = f64::from(px[c]);
                    sums[cell][c] += v;
                    total[c] += v;
                    total_sq += v * v;
                }
                counts[cell] += 1;
                n += 1;
            }
        }
        if n == 0 {
            return 0.0;
        }
        let mean = total.map(|t| t / n as f64);
        let variance = total_sq / n as f64 - mean.iter().map(|m| m * m).sum::<f64>();
        if variance <= 1e-9 {
            return 0.0;
        }
        let between: f64 = sums
            .iter()
            .zip(&counts)
            .filter(|(_, &k)| k > 0)
            .map(|(s, &k)| {
                (0..3)
                    .map(|c| (s[c] / k as f64 - mean[c]).powi(2))
                    .sum::<f64>()
                    * k as f64
            })
            .sum::<f64>()
            / n as f64;
        between / variance
    }

    /// A coordinate method's coordinate `c` on an exemplar of `size`, moved
    /// to the nearest one whose offset from `origin` (`h` times the pixel's
    /// or voxel's place in the exemplar's plane) lies on the grid, wrapped.
    pub fn snap(&self, c: [u32; 2], origin: [i64; 2], size: [usize; 2]) -> [u32; 2] {
        std::array::from_fn(|a| {
            let o = self.nearest(a, i64::from(c[a]) - origin[a]);
            (origin[a] + o).rem_euclid(size[a] as i64) as u32
        })
    }

    /// Whether the coordinate `q`'s offset from `origin` lies within
    /// [`PHASE_TOLERANCE`] of the grid on both axes.
    pub fn holds(&self, q: [u32; 2], origin: [i64; 2]) -> bool {
        (0..2).all(|a| self.axis_error(a, i64::from(q[a]) - origin[a], 1.0) <= PHASE_TOLERANCE)
    }

    /// How far, in tenths of a pixel of `level` (0 = finest), the copy
    /// `offset` lies from the lattice through `origin` (both canvas position
    /// less sample position on that level), rounded.
    pub fn phase_error(&self, offset: [i64; 2], origin: [i64; 2], level: usize) -> u32 {
        let scale = f64::from(1u32 << level.min(30));
        let off_axis = |axis: usize| self.axis_error(axis, offset[axis] - origin[axis], scale);
        let (ex, ey) = (off_axis(0), off_axis(1));
        (10.0 * (ex * ex + ey * ey).sqrt()).round() as u32
    }

    /// How far, in pixels, an offset `d` along `axis` lies from the nearest
    /// multiple of the period divided by `scale` (0 on a free axis).
    pub fn axis_error(&self, axis: usize, d: i64, scale: f64) -> f64 {
        if self.period[axis] == 0.0 {
            return 0.0;
        }
        let p = self.period[axis] / scale;
        let d = (d as f64).rem_euclid(p);
        d.min(p - d)
    }

    /// The multiple of the period along `axis` nearest to the offset `d`,
    /// in whole pixels of the finest level (`d` itself on a free axis).
    pub fn nearest(&self, axis: usize, d: i64) -> i64 {
        let p = self.period[axis];
        if p == 0.0 {
            return d;
        }
        ((d as f64 / p).round() * p).round() as i64
    }
}

/// How far, in exemplar pixels, a coordinate method's candidate offset
/// (coordinate less `h` times the pixel's or voxel's place) may lie from
/// the grid along each axis under lattice phase (ARCHITECTURE §10, §11).
/// Half a pixel let too few candidates through and a solid's weave blurred;
/// one and two pixels kept it alike.
pub const PHASE_TOLERANCE: f64 = 1.0;

/// Shortest period [`detect`] reports, in pixels.
const MIN_PERIOD: usize = 3;
/// A period's peak must rise this far above the lowest correlation before
/// it, and each repeat of it three quarters as far above the trough before
/// that repeat. Over the 30 samples of the bundled set and the shared
/// textures, a prototype of this rule (read to half the side, without the
/// test between repeats) found the same five grids at 0.12 to 0.15
/// (ARCHITECTURE §3.14).
const PROMINENCE: f64 = 0.15;
/// A period is a lattice's only where it repeats at least this many times
/// within [`REACH`]: a single hump at the objects' spacing is not a grid.
const REPEATS: usize = 3;
/// The longest lag read, as a share of the side: at three fifths, two
/// fifths of the pixels still overlap, and a sample six periods wide shows
/// three repeats.
const REACH: f64 = 0.6;
/// The repeats (the period itself first) whose peaks are read and fitted.
const FITTED: usize = 4;
/// The period is the shortest one whose peak is at least this share of the
/// strongest (a weaker earlier one is texture within a tile) and whose
/// repeats stand, on average, within half a [`PROMINENCE`] of the highest
/// (half the period of a grid whose joints have sharp edges repeats too,
/// but at every other repeat lower).
const FIRST_SHARE: f64 = 0.6;

/// The grid of a sample laid on a regular one (tiles, mosaics, a weave),
/// read from the autocorrelation of its luminance's detail (less a box blur
/// of a thirty-second of its side, so the joints count and the tiles'
/// shades do not): along each axis, the shortest period whose peak and
/// repeats stand clear and high ([`PROMINENCE`], [`REPEATS`],
/// [`FIRST_SHARE`]), refined to a
/// fraction of a pixel by a fit through its repeats. Where the rows of
/// such a grid are offset by half a period (running bond), the period
/// across them is doubled, so the lattice is rectangular. `None` where no
/// axis repeats.
pub fn detect(img: &ColorImage) -> Option<Lattice> {
    let (w, h) = (img.width, img.height);
    if w < 2 * REPEATS * MIN_PERIOD || h < 2 * REPEATS * MIN_PERIOD {
        return None;
    }
    let grey: Vec<f64> = img
        .rgb
        .chunks_exact(3)
        .map(|p| f64::from(luma(p[0], p[1], p[2])))
        .collect();
    let mut low = grey.clone();
    let r = (w.min(h) / 32).max(1);
    for _ in 0..2 {
        box_blur_2d(&mut low, w, h, r);
    }
    let detail: Vec<f64> = grey.iter().zip(&low).map(|(a, b)| a - b).collect();
    let rho = autocorrelation(&detail, (w, h));
    let at = |dx: usize, dy: usize| rho[(dy % (2 * h)) * 2 * w + dx % (2 * w)];
    let reach = |side: usize| (side as f64 * REACH) as usize;
    let along_x: Vec<f64> = (0..=reach(w)).map(|d| at(d, 0)).collect();
    let along_y: Vec<f64> = (0..=reach(h)).map(|d| at(0, d)).collect();
    let mut period = [axis_period(&along_x), axis_period(&along_y)];
    // Running bond: one axis's rows offset by half the other's period.
    if let [Some(px), Some(py)] = period {
        let half = |p: f64| (p / 2.0).round() as usize;
        let whole = |p: f64| p.round() as usize;
        if at(half(px), whole(py)) > at(0, whole(py)) && 2.0 * py <= reach(h) as f64 {
            period[1] = Some(2.0 * py);
        } else if at(whole(px), half(py)) > at(whole(px), 0) && 2.0 * px <= reach(w) as f64 {
            period[0] = Some(2.0 * px);
        }
    }
    match period {
        [None, None] => None,
        [x, y] => Some(Lattice {
            period: [x.unwrap_or(0.0), y.unwrap_or(0.0)],
        }),
    }
}

/// The period of one axis from its correlation profile `p` (index = lag,
/// 0 to [`REACH`] of the side), or `None` ([`detect`]).
fn axis_period(p: &[f64]) -> Option<f64> {
    let n = p.len();
    if n < 3 {
        return None;
    }
    let peak = |j: usize| j >= 1 && j + 1 < n && p[j] >= p[j - 1] && p[j] >= p[j + 1];
    // The lag and height of the peak at `j`, refined by the parabola
    // through its neighbours (a fractional period's peaks fall between the
    // lags, each by another fraction).
    let refined = |j: usize| {
        let (a, b, c) = (p[j - 1], p[j], p[j + 1]);
        let den = a - 2.0 * b + c;
        if den < -1e-12 {
            let shift = (0.5 * (a - c) / den).clamp(-0.5, 0.5);
            (j as f64 + shift, b - 0.125 * (a - c) * (a - c) / den)
        } else {
            (j as f64, b)
        }
    };
    let mut found: Vec<(f64, f64, f64)> = Vec::new(); // (period, rise, mean height)
    let mut low = f64::INFINITY;
    for d in 1..n - 1 {
        low = low.min(p[d]);
        let rise = p[d] - low;
        if d < MIN_PERIOD || !peak(d) || p[d] <= 0.0 || rise < PROMINENCE {
            continue;
        }
        let count = (n - 2) / d;
        if count < REPEATS {
            continue;
        }
        // Each repeat k: the highest correlation within k pixels of k·d, a
        // peak standing clear of the trough since the last repeat.
        let (lag, mut heights) = refined(d);
        let mut fit = vec![(1.0, lag)];
        let mut last = d;
        for k in 2..=count.min(FITTED) {
            let (lo, hi) = (
                (k * d).saturating_sub(k).max(last + 1),
                (k * d + k).min(n - 2),
            );
            let Some(j) = (lo..=hi).max_by(|&a, &b| p[a].total_cmp(&p[b]).then(b.cmp(&a))) else {
                break;
            };
            let trough = p[last..=j].iter().copied().fold(f64::INFINITY, f64::min);
            if !peak(j) || p[j] - trough < 0.75 * PROMINENCE {
                break;
            }
            // Nothing between two repeats (off their shoulders) as high as
            // either: quasi-regular streaks (rain) peak between them.
            let shoulder = (d / 4).max(2);
            let between = (last + shoulder + 1..j.saturating_sub(shoulder))
                .map(|i| p[i])
                .fold(f64::MIN, f64::max);
            if between >= p[last].min(p[j]) {
                break;
            }
            let (lag, height) = refined(j);
            fit.push((k as f64, lag));
            heights += height;
            last = j;
        }
        if fit.len() < count.min(FITTED) {
            continue;
        }
        // The least-squares period through the origin and the repeats.
        let period = fit.iter().map(|(k, x)| k * x).sum::<f64>()
            / fit.iter().map(|(k, _)| k * k).sum::<f64>();
        found.push((period, rise, heights / fit.len() as f64));
    }
    let top = found.iter().map(|f| f.1).fold(0.0, f64::max);
    let high = found.iter().map(|f| f.2).fold(f64::MIN, f64::max);
    found
        .iter()
        .find(|f| f.1 >= FIRST_SHARE * top && f.2 >= high - PROMINENCE / 2.0)
        .map(|f| f.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::parallel::tests::texture;
    use proptest::prelude::*;

    #[test]
    fn periods_must_fit_the_sample() {
        let ok = Lattice {
            period: [32.0, 24.5],
        };
        assert!(ok.validate([256, 256]).is_ok());
        assert!(Lattice {
            period: [0.0, 29.0]
        }
        .validate([96, 96])
        .is_ok());
        for period in [[1.5, 32.0], [32.0, 300.0], [f64::NAN, 8.0], [0.0, 0.0]] {
            let e = Lattice { period }.validate([256, 256]).unwrap_err();
            assert!(e.to_string().contains("--lattice"), "{e}");
        }
    }

    /// A `w`×`h` image whose grey value at `(x, y)` is `f(x, y)`.
    fn grey(w: usize, h: usize, f: impl Fn(usize, usize) -> u8) -> ColorImage {
        let rgb = (0..w * h)
            .flat_map(|i| {
                let v = f(i % w, i / w);
                [v, v, v]
            })
            .collect();
        ColorImage {
            width: w,
            height: h,
            rgb,
        }
    }

    /// Deterministic noise in 0..n for a pixel and a salt.
    fn hash(x: usize, y: usize, salt: usize, n: u64) -> u8 {
        let mut z = (x as u64) << 32 ^ (y as u64) << 8 ^ salt as u64;
        z = (z ^ (z >> 33)).wrapping_mul(0xff51afd7ed558ccd);
        z = (z ^ (z >> 33)).wrapping_mul(0xc4ceb9fe1a85ec53);
        ((z ^ (z >> 33)) % n) as u8
    }

    /// Tiles of a fractional period with random shades, grout and noise,
    /// each pixel the mean of 4×4 points within it (as a camera sees a
    /// joint that covers part of a pixel): the periods come back within a
    /// tenth of a pixel.
    #[test]
    fn a_planted_grid_s_fractional_periods_are_found() {
        for (px, py) in [(12.5, 17.0), (8.0, 10.667), (23.25, 9.5)] {
            let img = grey(200, 180, |x, y| {
                let mut sum = 0.0;
                for s in 0..16 {
                    let (u, v) = (
                        x as f64 + (s % 4) as f64 / 4.0 + 0.125,
                        y as f64 + (s / 4) as f64 / 4.0 + 0.125,
                    );
                    let (tx, ty) = ((u / px).floor(), (v / py).floor());
                    sum += if u / px - tx < 0.12 || v / py - ty < 0.12 {
                        40.0
                    } else {
                        120.0 + f64::from(hash(tx as usize, ty as usize, 2, 90))
                    };
                }
                (sum / 16.0) as u8 + hash(x, y, 1, 24)
            });
            let l = detect(&img).expect("a grid");
            assert!(
                (l.period[0] - px).abs() < 0.1 && (l.period[1] - py).abs() < 0.1,
                "planted {px}×{py}, found {:?}",
                l.period
            );
        }
    }

    /// Running bond: courses offset by half a brick. The lattice in phase
    /// is the brick's length by two courses, not by one.
    #[test]
    fn running_bond_doubles_the_course() {
        let (len, course) = (24usize, 10usize);
        let img = grey(192, 160, |x, y| {
            let row = y / course;
            let xs = x + (row % 2) * len / 2;
            let joint = y % course == 0 || xs % len == 0;
            if joint {
                30 + hash(x, y, 3, 16)
            } else {
                150 + hash(xs / len, row, 4, 60) + hash(x, y, 5, 16)
            }
        });
        let l = detect(&img).expect("a bond");
        assert!(
            (l.period[0] - len as f64).abs() < 0.2
                && (l.period[1] - 2.0 * course as f64).abs() < 0.2,
            "{:?}",
            l.period
        );
    }

    /// Lines along one axis leave the other free; noise, a flat image and
    /// one too small to repeat three times show no grid.
    #[test]
    fn stripes_free_an_axis_and_noise_has_no_grid() {
        let stripes = grey(128, 128, |x, y| {
            if y % 9 < 2 {
                50 + hash(x, y, 6, 20)
            } else {
                170 + hash(x, y, 7, 20)
            }
        });
        let l = detect(&stripes).expect("stripes");
        assert_eq!(l.period[0], 0.0);
        assert!((l.period[1] - 9.0).abs() < 0.1, "{:?}", l.period);
        assert_eq!(detect(&grey(128, 96, |x, y| hash(x, y, 8, 255))), None);
        assert_eq!(detect(&grey(64, 64, |_, _| 90)), None);
        assert_eq!(detect(&grey(12, 40, |x, _| (x % 3 * 100) as u8)), None);
    }

    /// The bundled grids are found at the periods measured by hand; the
    /// bundled photos of scattered objects show none, nor does the rain,
    /// whose streaks' spacing wanders (a peak between two repeats as high
    /// as they are; without that test it read as a 17.8-px grid).
    #[test]
    fn bundled_grids_are_found_and_photos_without_one_are_not() {
        let tiles = detect(&texture("tiles_color_256.png")).expect("tiles");
        assert!(
            tiles.period.iter().all(|p| (p - 32.0).abs() < 0.2),
            "{tiles:?}"
        );
        let facade = detect(&texture("facade_tiles_color_256.png")).expect("facade");
        assert!(
            (facade.period[0] - 8.0).abs() < 0.1 && (facade.period[1] - 32.0 / 3.0).abs() < 0.1
        );
        // Tiles of many colours differ cell to cell; a weave's cells do not.
        let burlap = texture("burlap_color_96.png");
        let weave = detect(&burlap).expect("burlap");
        assert!(tiles.cell_share(&texture("tiles_color_256.png")) > 0.5);
        assert!(
            weave.cell_share(&burlap) < 0.05,
            "{}",
            weave.cell_share(&burlap)
        );
        assert_eq!(tiles.cell_share(&grey(64, 64, |_, _| 90)), 0.0);
        for name in [
            "coffee_beans_color_256.png",
            "leaves_green_color_161.png",
            "stone33_color_156.png",
            "pink_marble_color_128.png",
            "brick_gray_64.png",
            "rain_color_108.png",
        ] {
            assert_eq!(detect(&texture(name)), None, "{name}");
        }
    }

    proptest! {
        /// The error is zero on the lattice through the origin, periodic,
        /// symmetric about it, and scales with the level.
        #[test]
        fn phase_error_is_a_distance_to_the_lattice(
            px in 2u32..64, py in 2u32..64,
            ox in -500i64..500, oy in -500i64..500,
            dx in -40i64..40, dy in -40i64..40,
            kx in -5i64..5, ky in -5i64..5,
        ) {
            let l = Lattice { period: [f64::from(px), f64::from(py)] };
            let origin = [ox, oy];
            let on = [ox + kx * i64::from(px), oy + ky * i64::from(py)];
            prop_assert_eq!(l.phase_error(on, origin, 0), 0);
            let at = [ox + dx, oy + dy];
            let shifted = [at[0] + kx * i64::from(px), at[1] + ky * i64::from(py)];
            let e = l.phase_error(at, origin, 0);
            prop_assert_eq!(e, l.phase_error(shifted, origin, 0));
            prop_assert_eq!(e, l.phase_error([ox - dx, oy - dy], origin, 0));
            let bound = 10.0 * ((dx * dx + dy * dy) as f64).sqrt();
            prop_assert!(f64::from(e) <= bound.round() + 1e-9);
            // One level coarser the periods halve: an offset of twice the
            // period there is twice the finest period's lattice step.
            let l2 = Lattice { period: [f64::from(2 * px), f64::from(2 * py)] };
            prop_assert_eq!(l2.phase_error(at, origin, 1), e);
            // A free axis counts nothing: only the other axis's error is left.
            let rows = Lattice { period: [0.0, f64::from(py)] };
            let dyp = (oy + dy - oy).rem_euclid(i64::from(py));
            let ey = 10 * dyp.min(i64::from(py) - dyp) as u32;
            prop_assert_eq!(rows.phase_error(at, origin, 0), ey);
        }
    }

    proptest! {
        /// `nearest` lands on the lattice within half a period's rounding,
        /// `axis_error` is the distance to it, and a free axis keeps the
        /// offset.
        #[test]
        fn nearest_is_on_the_lattice_and_the_error_its_distance(
            p in 2.0f64..64.0, d in -2000i64..2000,
        ) {
            let l = Lattice { period: [p, 0.0] };
            let n = l.nearest(0, d);
            prop_assert!(l.axis_error(0, n, 1.0) <= 0.5 + 1e-9);
            prop_assert!(((n - d) as f64).abs() <= p / 2.0 + 0.5 + 1e-9);
            let e = l.axis_error(0, d, 1.0);
            prop_assert!(e <= p / 2.0 + 1e-9);
            prop_assert!((e - ((d as f64) - (d as f64 / p).round() * p).abs()).abs() < 1e-6);
            prop_assert_eq!(l.nearest(1, d), d);
            prop_assert_eq!(l.axis_error(1, d, 1.0), 0.0);
        }
    }
}
