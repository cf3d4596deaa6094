//! Band histogram matching of a finished solid (after Heeger and Bergen
//! 1995, "Pyramid-based texture analysis/synthesis", whose solids match a
//! 3-D pyramid to a 2-D exemplar's; ARCHITECTURE §11).
//!
//! The coordinates put the exemplar's features in the right places, but a
//! voxel is the blend of three views that agree only roughly, so thin veins
//! and fine grain come out softer than the exemplar's: the slices' Laplacian
//! bands are narrower than the exemplar's (a higher S_L). Here each colour
//! component (the principal axes of the exemplars' colours, so that matching
//! one does not tint another) is split into a wrapping Laplacian pyramid in
//! 3-D, each band's histogram over the volume is matched to the same band of
//! the exemplars' 2-D pyramids, the component is rebuilt and its own
//! histogram matched; [`ITERATIONS`] rounds. First, the component's pixel
//! grain is taken out ([`Grid::without_nyquist`]): part of the finest
//! band's energy is the sub-passes' parity checker, and matched as it is
//! the band's spread would go to it, raising the slices' energy at the pixel
//! Nyquist frequency over the exemplar's (measured on 20 of 22 samples at
//! 64³). Every value is computed in a fixed order, so the thread count
//! changes no byte.

use rayon::prelude::*;

use super::super::histogram::Matching;
use crate::imaging::ColorImage;

/// Default rounds of the band matching (0: off). Measured on pink marble
/// and walnut at 128³ (ARCHITECTURE §11): three rounds lower the centre
/// slices' worst S_L by about a third; the rounds converge slowly, and on
/// burlap, crinkled paper and mossy rock 8 rounds took the worst slice
/// another 10–15 % lower than 3.
pub const ITERATIONS: usize = 8;

/// Most rounds `--band-matching` takes.
pub const MAX_ITERATIONS: usize = 16;

/// Band-pass levels matched (S_L's count, `compare::laplacian_distance`).
const BANDS: usize = 4;

/// Most whole passes of the checker damping per axis pair
/// ([`Grid::checker_at_most`]).
const CHECKER_PASSES: usize = 16;

/// Share of the exemplars' checker energy the planes are capped at: the
/// rounding to bytes adds to it.
const CHECKER_MARGIN: f64 = 0.8;

/// Bisection steps of the last pass's strength (2⁻¹⁰ of β).
const CHECKER_STEPS: usize = 10;

/// Binomial taps of the pyramid's reduce (Burt and Adelson).
const TAPS: [f32; 5] = [1.0 / 16.0, 4.0 / 16.0, 6.0 / 16.0, 4.0 / 16.0, 1.0 / 16.0];

/// Values on a wrapping grid, x fastest, then y, then z (a 2-D image has
/// one z).
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Grid {
    pub size: [usize; 3],
    pub v: Vec<f32>,
}

impl Grid {
    fn index(&self, p: [usize; 3]) -> usize {
        (p[2] * self.size[1] + p[1]) * self.size[0] + p[0]
    }

    /// A grid of `size` whose value at `p` is `f(p)`.
    fn from_fn(size: [usize; 3], f: impl Fn([usize; 3]) -> f32 + Sync) -> Self {
        let plane = size[0] * size[1];
        let mut v = vec![0.0f32; plane * size[2]];
        v.par_chunks_mut(plane.max(1))
            .enumerate()
            .for_each(|(z, out)| {
                for (y, row) in out.chunks_mut(size[0].max(1)).enumerate() {
                    for (x, o) in row.iter_mut().enumerate() {
                        *o = f([x, y, z]);
                    }
                }
            });
        Self { size, v }
    }

    /// Reduced by two along `axis`: the binomial filter, then every other
    /// sample (an odd side keeps its last).
    fn reduce_axis(&self, axis: usize) -> Self {
        let n = self.size[axis];
        let mut size = self.size;
        size[axis] = n.div_ceil(2);
        let taps: Vec<[usize; 5]> = (0..size[axis])
            .map(|i| std::array::from_fn(|k| (2 * i + n + k - 2) % n))
            .collect();
        Self::from_fn(size, |p| {
            let mut q = p;
            TAPS.iter()
                .zip(&taps[p[axis]])
                .map(|(&t, &j)| {
                    q[axis] = j;
                    t * self.v[self.index(q)]
                })
                .sum()
        })
    }

    /// Brought back to `n` samples along `axis`: the samples on the even
    /// places, zeros between, filtered by twice the taps.
    fn expand_axis(&self, axis: usize, n: usize) -> Self {
        let mut size = self.size;
        size[axis] = n;
        let taps: Vec<[usize; 5]> = (0..n)
            .map(|i| std::array::from_fn(|k| (i + n + 2 - k) % n))
            .collect();
        Self::from_fn(size, |p| {
            let mut q = p;
            let mut s = 0.0f32;
            for (&t, &j) in TAPS.iter().zip(&taps[p[axis]]) {
                if j.is_multiple_of(2) {
                    q[axis] = j / 2;
                    s += 2.0 * t * self.v[self.index(q)];
                }
            }
            s
        })
    }

    /// Filtered by `[1, 2, 1] / 4` along every axis longer than one
    /// (wrapping), which takes out the Nyquist frequency of each: the pixel
    /// checker.
    fn without_nyquist(&self) -> Self {
        (0..3)
            .filter(|&a| self.size[a] > 1)
            .fold(self.clone(), |g, a| {
                let (back, ahead) = (steps(g.size[a], true), steps(g.size[a], false));
                Self::from_fn(g.size, |p| {
                    let (mut l, mut r) = (p, p);
                    l[a] = back[p[a]];
                    r[a] = ahead[p[a]];
                    0.25 * g.v[g.index(l)] + 0.5 * g.v[g.index(p)] + 0.25 * g.v[g.index(r)]
                })
            })
    }

    /// The pixel checker of the planes spanned by axes `a` and `b`: the mean
    /// over every 2×2 square of those planes (wrapping) of
    /// `(¼ (v₀₀ − v₁₀ − v₀₁ + v₁₁))²`, the measure `compare` takes of an
    /// image's luminance (its `checker`), here of one colour component.
    /// Summed plane by plane in a fixed order, so the thread count changes
    /// no bit.
    fn checker(&self, a: usize, b: usize) -> f64 {
        let m = self.mixed_difference(a, b);
        let plane = (self.size[0] * self.size[1]).max(1);
        let sums: Vec<f64> =
            m.v.par_chunks(plane)
                .map(|c| c.iter().map(|&x| f64::from(x / 4.0).powi(2)).sum())
                .collect();
        sums.iter().sum::<f64>() / m.v.len().max(1) as f64
    }

    /// `v(p) − v(p + a) − v(p + b) + v(p + a + b)` (wrapping; `sign` −1
    /// steps back along both axes instead, the adjoint).
    fn mixed(&self, a: usize, b: usize, back: bool) -> Self {
        let (ta, tb) = (steps(self.size[a], back), steps(self.size[b], back));
        Self::from_fn(self.size, |p| {
            let (mut pa, mut pb, mut pab) = (p, p, p);
            pa[a] = ta[p[a]];
            pb[b] = tb[p[b]];
            pab[a] = pa[a];
            pab[b] = pb[b];
            self.v[self.index(p)] - self.v[self.index(pa)] - self.v[self.index(pb)]
                + self.v[self.index(pab)]
        })
    }

    fn mixed_difference(&self, a: usize, b: usize) -> Self {
        self.mixed(a, b, false)
    }

    /// The grid with its checker in the planes of `a` and `b` damped by
    /// `beta` in [0, 1]: `v − β/16 · MᵀM v`, where `M` is the mixed
    /// difference. Its frequency response is `1 − β sin²(ωa/2) sin²(ωb/2)`:
    /// the pixel checker (both at Nyquist) is scaled by `1 − β`, what varies
    /// along one axis only (an edge along the other) is untouched.
    #[cfg(test)]
    fn damp_checker(&self, a: usize, b: usize, beta: f64) -> Self {
        self.damped(&self.mixed_difference(a, b).mixed(a, b, true), beta)
    }

    /// `v − β/16 · mtm`, with `mtm` this grid's `MᵀM v` worked out once for
    /// every β tried.
    fn damped(&self, mtm: &Grid, beta: f64) -> Self {
        let k = (beta / 16.0) as f32;
        let v = self
            .v
            .par_iter()
            .zip(&mtm.v)
            .map(|(x, y)| x - k * y)
            .collect();
        Self { size: self.size, v }
    }

    /// The grid with the checker of each plane (across each axis, so of
    /// each slice) brought down to at most `target` where it is above
    /// ([`Grid::plane_checker_at_most`]); planes at or under it keep their
    /// values. The axis pairs are taken in the order x–y… as listed, each
    /// plane on its own, so the thread count changes no bit.
    fn checker_at_most(&self, target: f64) -> Self {
        let mut g = self.clone();
        for (a, b) in [(1, 2), (0, 2), (0, 1)] {
            if g.size[a] < 2 || g.size[b] < 2 {
                continue;
            }
            let c = 3 - a - b;
            let planes: Vec<Grid> = (0..g.size[c])
                .into_par_iter()
                .map(|k| g.plane(a, b, k).plane_checker_at_most(target))
                .collect();
            for (k, p) in planes.iter().enumerate() {
                for j in 0..g.size[b] {
                    for i in 0..g.size[a] {
                        let mut q = [0; 3];
                        (q[a], q[b], q[c]) = (i, j, k);
                        let at = g.index(q);
                        g.v[at] = p.v[j * g.size[a] + i];
                    }
                }
            }
        }
        g
    }

    /// The plane of axes `a` and `b` at `k` along the third, as a 2-D grid
    /// (`a` its x).
    fn plane(&self, a: usize, b: usize, k: usize) -> Self {
        let c = 3 - a - b;
        let (na, nb) = (self.size[a], self.size[b]);
        let mut v = Vec::with_capacity(na * nb);
        for j in 0..nb {
            for i in 0..na {
                let mut q = [0; 3];
                (q[a], q[b], q[c]) = (i, j, k);
                v.push(self.v[self.index(q)]);
            }
        }
        Self {
            size: [na, nb, 1],
            v,
        }
    }

    /// A 2-D grid with its checker brought down to at most `target`:
    /// whole passes of [`Grid::damp_checker`] at β = 1 while one is not
    /// enough (at most [`CHECKER_PASSES`]), then the least β (bisection)
    /// that reaches it. At or under the target it is returned as it is.
    fn plane_checker_at_most(self, target: f64) -> Self {
        let mut g = self;
        let mut now = g.checker(0, 1);
        for _ in 0..CHECKER_PASSES {
            if now <= target {
                break;
            }
            let mtm = g.mixed_difference(0, 1).mixed(0, 1, true);
            let full = g.damped(&mtm, 1.0);
            let after = full.checker(0, 1);
            if after > target {
                (g, now) = (full, after);
                continue;
            }
            let (mut lo, mut hi) = (0.0f64, 1.0f64);
            for _ in 0..CHECKER_STEPS {
                let mid = 0.5 * (lo + hi);
                if g.damped(&mtm, mid).checker(0, 1) > target {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            g = g.damped(&mtm, hi);
            break;
        }
        g
    }

    fn reduce(&self) -> Self {
        (0..3)
            .filter(|&a| self.size[a] > 1)
            .fold(self.clone(), |g, a| g.reduce_axis(a))
    }

    fn expand(&self, to: [usize; 3]) -> Self {
        (0..3)
            .filter(|&a| to[a] > 1)
            .fold(self.clone(), |g, a| g.expand_axis(a, to[a]))
    }
}

/// The neighbour one step ahead (or back) of each of `n` places on a
/// wrapping axis: looked up instead of a division per value.
fn steps(n: usize, back: bool) -> Vec<usize> {
    (0..n)
        .map(|i| if back { (i + n - 1) % n } else { (i + 1) % n })
        .collect()
}

/// Levels a grid of `size` can be split into: while every side longer
/// than one is at least 8 (as S_L's pyramid), at most [`BANDS`].
fn levels_of(mut size: [usize; 3]) -> usize {
    let mut levels = 0;
    while levels < BANDS && size.iter().all(|&n| n == 1 || n >= 8) && size.iter().any(|&n| n > 1) {
        levels += 1;
        size = size.map(|n| n.div_ceil(2));
    }
    levels
}

/// The Laplacian pyramid of `g`: `levels` band-pass grids, finest first,
/// and the low-pass rest.
pub(crate) fn pyramid(g: &Grid, levels: usize) -> (Vec<Grid>, Grid) {
    let mut bands = Vec::with_capacity(levels);
    let mut a = g.clone();
    for _ in 0..levels {
        let r = a.reduce();
        let e = r.expand(a.size);
        let v = a.v.par_iter().zip(&e.v).map(|(x, y)| x - y).collect();
        bands.push(Grid { size: a.size, v });
        a = r;
    }
    (bands, a)
}

/// The grid whose [`pyramid`] is `bands` and `low`.
pub(crate) fn reconstruct(bands: &[Grid], low: Grid) -> Grid {
    bands.iter().rev().fold(low, |a, b| {
        let mut e = a.expand(b.size);
        e.v.par_iter_mut().zip(&b.v).for_each(|(x, y)| *x += y);
        e
    })
}

/// Principal axes of the maps' colours (each map with its weight), as rows,
/// and their mean; the identity for one channel.
fn colour_axes(maps: &[(&ColorImage, f64)], channels: usize) -> (Vec<[f32; 3]>, [f32; 3]) {
    if channels == 1 {
        return (vec![[1.0, 0.0, 0.0]], [0.0; 3]);
    }
    let total: f64 = maps.iter().map(|m| m.1).sum::<f64>().max(f64::MIN_POSITIVE);
    let share = |m: &(&ColorImage, f64)| m.1 / total / m.0.len().max(1) as f64;
    let mut mean = [0.0f64; 3];
    for m in maps {
        for p in m.0.rgb.chunks_exact(3) {
            for c in 0..3 {
                mean[c] += share(m) * f64::from(p[c]);
            }
        }
    }
    let mut cov = nalgebra::Matrix3::<f64>::zeros();
    for m in maps {
        for p in m.0.rgb.chunks_exact(3) {
            let d = nalgebra::Vector3::from_fn(|c, _| f64::from(p[c]) - mean[c]);
            cov += share(m) * d * d.transpose();
        }
    }
    let eig = nalgebra::SymmetricEigen::new(cov);
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let axes = order
        .iter()
        .map(|&k| {
            let v = eig.eigenvectors.column(k);
            [v[0] as f32, v[1] as f32, v[2] as f32]
        })
        .collect();
    (axes, mean.map(|m| m as f32))
}

/// Matches the bands of `data` (a volume of `size`, `channels` bytes per
/// voxel, x fastest) to those of `maps`, each with its weight, for
/// `iterations` rounds, in place.
pub fn match_bands(
    data: &mut [u8],
    size: [usize; 3],
    channels: usize,
    maps: &[(&ColorImage, f64)],
    iterations: usize,
) {
    let voxels: usize = size.iter().product();
    let levels = maps
        .iter()
        .map(|m| levels_of([m.0.width, m.0.height, 1]))
        .chain(std::iter::once(levels_of(size)))
        .min()
        .unwrap_or(0);
    if iterations == 0 || voxels == 0 || levels == 0 || data.len() != voxels * channels {
        return;
    }
    let (axes, mean) = colour_axes(maps, channels);
    let components: Vec<Grid> = axes
        .iter()
        .map(|a| {
            let v = data
                .par_chunks(channels)
                .map(|px| project(px, a, mean))
                .collect();
            let mut g = Grid { size, v }.without_nyquist();
            // Each map's pyramid of this component, and its values.
            let theirs: Vec<(Vec<Grid>, Vec<f32>, f64)> = maps
                .iter()
                .map(|&(m, w)| {
                    let e = image_component(m, channels, a, mean);
                    let (bands, _) = pyramid(&e, levels);
                    (bands, e.v, w)
                })
                .collect();
            let band_targets: Vec<Matching> = (0..levels)
                .map(|l| {
                    let sources: Vec<(&[f32], f64)> =
                        theirs.iter().map(|t| (&t.0[l].v[..], t.2)).collect();
                    Matching::new(1, &sources)
                })
                .collect();
            let value_sources: Vec<(&[f32], f64)> =
                theirs.iter().map(|t| (&t.1[..], t.2)).collect();
            let values = Matching::new(1, &value_sources);
            let mut out = Vec::new();
            for _ in 0..iterations {
                let (mut bands, low) = pyramid(&g, levels);
                for (b, t) in bands.iter_mut().zip(&band_targets) {
                    t.apply(&b.v, 1.0, &mut out);
                    std::mem::swap(&mut b.v, &mut out);
                }
                g = reconstruct(&bands, low);
                values.apply(&g.v, 1.0, &mut out);
                std::mem::swap(&mut g.v, &mut out);
            }
            g
        })
        .collect();
    recombine(data, channels, &axes, mean, &components);
}

/// A pixel's or voxel's value on colour axis `a` about `mean`.
fn project(px: &[u8], a: &[f32; 3], mean: [f32; 3]) -> f32 {
    px.iter()
        .zip(a)
        .zip(mean)
        .map(|((&v, &w), m)| w * (f32::from(v) - m))
        .sum()
}

/// Image `m`'s component on colour axis `a` about `mean`, as a 2-D grid.
fn image_component(m: &ColorImage, channels: usize, a: &[f32; 3], mean: [f32; 3]) -> Grid {
    Grid {
        size: [m.width, m.height, 1],
        v: m.rgb
            .chunks_exact(3)
            .map(|px| project(&px[..channels], a, mean))
            .collect(),
    }
}

/// Each voxel of `data` rebuilt from its `components` along `axes` about
/// `mean`, rounded to bytes.
fn recombine(
    data: &mut [u8],
    channels: usize,
    axes: &[[f32; 3]],
    mean: [f32; 3],
    components: &[Grid],
) {
    data.par_chunks_mut(channels)
        .enumerate()
        .for_each(|(i, px)| {
            for (c, o) in px.iter_mut().enumerate() {
                let v: f32 = axes
                    .iter()
                    .zip(components)
                    .map(|(a, g)| a[c] * g.v[i])
                    .sum::<f32>()
                    + mean[c];
                *o = v.round().clamp(0.0, 255.0) as u8;
            }
        });
}

/// Whether `data` is a non-empty volume of `size` with `channels` bytes per
/// voxel and there are `maps` to match it to: the steps on the colour
/// leave anything else as it is.
pub(super) fn holds_a_volume(
    data: &[u8],
    size: [usize; 3],
    channels: usize,
    maps: &[(&ColorImage, f64)],
) -> bool {
    let voxels: usize = size.iter().product();
    voxels > 0 && !maps.is_empty() && data.len() == voxels * channels
}

/// Caps the pixel checker of every slice of `data` (a volume of `size`,
/// `channels` bytes per voxel) at the `maps`' (each with its weight): each
/// colour component (as [`match_bands`] splits them) has each plane across
/// each axis damped at the pixel Nyquist frequency of that plane
/// ([`Grid::checker_at_most`]) until its checker is at most
/// [`CHECKER_MARGIN`] of the maps' weighted mean checker. Slices already
/// under it keep their bytes, and a volume whose slices all are is left
/// as it is.
///
/// The last step on a band-matched solid: matched to exemplars that have
/// almost no energy at the pixel scale (the lattice photos), the rubble a
/// solid makes of a lattice has hard, oblique edges whose pixel checker
/// was up to 7× the exemplar's (ARCHITECTURE §11).
pub fn cap_checker(
    data: &mut [u8],
    size: [usize; 3],
    channels: usize,
    maps: &[(&ColorImage, f64)],
) {
    if !holds_a_volume(data, size, channels, maps) {
        return;
    }
    let (axes, mean) = colour_axes(maps, channels);
    let weight: f64 = maps.iter().map(|m| m.1).sum();
    let mut changed = false;
    let components: Vec<Grid> = axes
        .iter()
        .map(|a| {
            let checker = maps
                .iter()
                .map(|&(m, w)| {
                    let e = image_component(m, channels, a, mean);
                    w * e.checker(0, 1)
                })
                .sum::<f64>()
                / weight.max(f64::MIN_POSITIVE);
            let v = data
                .par_chunks(channels)
                .map(|px| project(px, a, mean))
                .collect();
            let g = Grid { size, v };
            let capped = g.checker_at_most(CHECKER_MARGIN * checker);
            changed |= capped != g;
            capped
        })
        .collect();
    if changed {
        recombine(data, channels, &axes, mean, &components);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn noise(size: [usize; 3], seed: u32) -> Grid {
        Grid::from_fn(size, |p| {
            let h = (p[0] as u32)
                .wrapping_mul(0x9E37_79B1)
                .wrapping_add((p[1] as u32).wrapping_mul(0x85EB_CA77))
                .wrapping_add((p[2] as u32).wrapping_mul(0xC2B2_AE3D))
                ^ seed;
            (h.wrapping_mul(0x27D4_EB2F) >> 24) as f32
        })
    }

    proptest! {
        /// The pyramid loses nothing: its bands and rest rebuild the grid,
        /// for odd and even sides, flat images and volumes.
        #[test]
        fn a_pyramid_rebuilds_its_grid(
            x in 1usize..40, y in 1usize..40, z in 1usize..12, seed in any::<u32>()
        ) {
            let g = noise([x, y, z], seed);
            let levels = levels_of(g.size);
            let (bands, low) = pyramid(&g, levels);
            prop_assert_eq!(bands.len(), levels);
            let back = reconstruct(&bands, low);
            prop_assert_eq!(back.size, g.size);
            for (a, b) in back.v.iter().zip(&g.v) {
                prop_assert!((a - b).abs() < 1e-3, "{} against {}", a, b);
            }
        }
    }

    /// The damping against a scalar reference of its frequency response:
    /// the pixel checker of its planes is scaled by `1 − β`, what varies
    /// along one of the two axes only is untouched, and the checker
    /// measure is `compare`'s.
    #[test]
    fn damping_scales_the_checker_and_leaves_one_axis_variation() {
        let checker = Grid::from_fn(
            [8, 6, 4],
            |p| if (p[0] + p[2]) % 2 == 0 { 1.0 } else { -1.0 },
        );
        // ¼ (1 + 1 + 1 + 1) per square, squared.
        assert!((checker.checker(0, 2) - 1.0).abs() < 1e-9);
        assert!(
            checker.checker(0, 1) < 1e-9,
            "(x, y) planes vary along x only: no mixed difference"
        );
        for beta in [0.0, 0.25, 1.0] {
            let d = checker.damp_checker(0, 2, beta);
            for (a, b) in d.v.iter().zip(&checker.v) {
                assert!(
                    (a - (1.0 - beta as f32) * b).abs() < 1e-5,
                    "β {beta}: {a} against {b}"
                );
            }
        }
        let ramp = noise([8, 1, 6], 9);
        let along_x = Grid::from_fn([8, 5, 6], |p| ramp.v[p[0]]);
        assert_eq!(along_x.damp_checker(0, 1, 1.0), along_x);
    }

    /// The cap brings a planted pixel checker down to the exemplar's in
    /// every slice, and leaves a volume already under it byte for byte.
    #[test]
    fn cap_checker_takes_a_planted_checker_down_to_the_exemplar_s() {
        let n = 16;
        let smooth = |p: [usize; 3]| 100.0 + 40.0 * ((p[0] + p[1] + p[2]) as f32 * 0.3).sin();
        let image = |f: &dyn Fn(usize, usize) -> f32| ColorImage {
            width: n,
            height: n,
            rgb: (0..n * n)
                .flat_map(|i| [f(i % n, i / n).round() as u8; 3])
                .collect(),
        };
        let ex = image(&|x, y| smooth([x, y, 0]));
        let ce = crate::compare::checker_energy(&ex);
        let volume = |f: &(dyn Fn([usize; 3]) -> f32 + Sync)| -> Vec<u8> {
            let g = Grid::from_fn([n; 3], f);
            g.v.iter().flat_map(|&v| [v.round() as u8; 3]).collect()
        };
        let slices_worst = |d: &[u8]| {
            let v = crate::imaging::volume::Volume::new([n; 3], 3, d.to_vec()).unwrap();
            crate::imaging::volume::Axis::ALL
                .into_iter()
                .flat_map(|a| (0..n).map(move |k| (a, k)))
                .map(|(a, k)| crate::compare::checker_energy(&v.slice_rgb(a, k)) / ce)
                .fold(0.0f64, f64::max)
        };
        let mut planted = volume(&|p| {
            smooth(p)
                + if (p[0] + p[1] + p[2]) % 2 == 0 {
                    12.0
                } else {
                    -12.0
                }
        });
        assert!(slices_worst(&planted) > 10.0, "{}", slices_worst(&planted));
        cap_checker(&mut planted, [n; 3], 3, &[(&ex, 1.0)]);
        assert!(slices_worst(&planted) <= 1.0, "{}", slices_worst(&planted));
        let mut calm = volume(&|p| 100.0 + 0.5 * (smooth([p[0], p[1], 0]) - 100.0));
        let before = calm.clone();
        cap_checker(&mut calm, [n; 3], 3, &[(&ex, 1.0)]);
        assert_eq!(calm, before);
    }

    /// Reduce is the binomial filter of a scalar reference, wrapping.
    #[test]
    fn reduce_is_the_wrapping_binomial_filter() {
        let g = noise([9, 1, 1], 7);
        let r = g.reduce_axis(0);
        assert_eq!(r.size, [5, 1, 1]);
        for i in 0..5 {
            let want: f32 = (0..5).map(|k| TAPS[k] * g.v[(2 * i + 9 + k - 2) % 9]).sum();
            assert!((r.v[i] - want).abs() < 1e-4);
        }
        // A constant stays constant through reduce and expand.
        let c = Grid::from_fn([8, 6, 4], |_| 3.0);
        assert!(c
            .reduce()
            .expand(c.size)
            .v
            .iter()
            .all(|&v| (v - 3.0).abs() < 1e-5));
    }

    /// A volume of smoothed noise, matched to a sharp exemplar, takes the
    /// exemplar's finer bands: their spread grows towards the exemplar's.
    #[test]
    fn matching_gives_a_soft_volume_the_exemplar_s_band_spread() {
        let n = 32;
        let sharp = noise([n, n, 1], 3);
        let ex = ColorImage {
            width: n,
            height: n,
            rgb: sharp.v.iter().flat_map(|&v| [v as u8; 3]).collect(),
        };
        // Soft: the noise reduced and expanded (its finest band is weak).
        let soft = noise([n, n, n], 5).reduce().expand([n, n, n]);
        let mut data: Vec<u8> = soft.v.iter().flat_map(|&v| [v.round() as u8; 3]).collect();
        let spread = |g: &Grid| {
            let (b, _) = pyramid(g, 1);
            let m = b[0].v.iter().sum::<f32>() / b[0].v.len() as f32;
            (b[0].v.iter().map(|v| (v - m).powi(2)).sum::<f32>() / b[0].v.len() as f32).sqrt()
        };
        let grey = |d: &[u8]| Grid {
            size: [n, n, n],
            v: d.chunks_exact(3).map(|p| f32::from(p[0])).collect(),
        };
        let (before, target) = (spread(&grey(&data)), spread(&sharp));
        match_bands(&mut data, [n, n, n], 3, &[(&ex, 1.0)], ITERATIONS);
        let after = spread(&grey(&data));
        assert!(
            after > before + 0.3 * (target - before),
            "finest band spread {before:.2} → {after:.2}, exemplar {target:.2}"
        );
        // No rounds: the bytes stay.
        let mut same: Vec<u8> = soft.v.iter().flat_map(|&v| [v.round() as u8; 3]).collect();
        let copy = same.clone();
        match_bands(&mut same, [n, n, n], 3, &[(&ex, 1.0)], 0);
        assert_eq!(same, copy);
    }
}
