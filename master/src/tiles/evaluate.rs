//! The affinity evaluation of ω-tile patch sets (Dong, Zhou and Paul §4.2.2,
//! eq. 1–2): each intermediate tile's best translation in the sample, in
//! colour, at full resolution or a halved level of the sample.
//!
//! An intermediate tile is four patch quarters, so its correlation with the
//! sample at every translation is the sum of four quarter correlations. Each
//! quarter's is computed once per patch position by FFT and cached, and a
//! tile's squared error at every translation is then
//! `Σ T² + Σ I²(t) − 2·Σ_quarters corr(t)`, exact.

use std::collections::HashMap;
use std::sync::Arc;

use anyhow::{ensure, Result};
use rayon::prelude::*;
use rustfft::{num_complex::Complex, Fft, FftPlanner};

use crate::filters::fft2;

use super::ais::Gene;
use super::omega::OmegaSet;
use crate::imaging::ColorImage;

/// The evaluation level is halved until the sample's larger side is at most
/// this (a 256² sample is searched at half resolution, 160² and less at
/// full), keeping a tile at least [`LEAST_SIDE`] wide there.
pub const EVAL_MAX_SIDE: usize = 160;
/// Least tile side at the evaluation level.
pub const LEAST_SIDE: usize = 8;
/// Memory for cached quarter correlations.
const QUARTER_BYTES: usize = 256 << 20;

/// One patch quarter's correlation with the level at every tile translation.
struct Quarter {
    /// Σ of its squared (mean-removed) values.
    energy: f64,
    /// At tile translation `t` (row by row over the translations).
    corr: Vec<f32>,
}

/// The sample at the evaluation level, mean removed per channel.
struct Level {
    width: usize,
    height: usize,
    /// Three planes, row by row.
    planes: [Vec<f32>; 3],
}

impl Level {
    fn of(sample: &ColorImage, steps: usize) -> Self {
        let mut img = sample.clone();
        for _ in 0..steps {
            img = halve(&img);
        }
        let n = (img.width * img.height).max(1);
        let planes = std::array::from_fn(|c| {
            let v: Vec<f32> = img
                .rgb
                .iter()
                .skip(c)
                .step_by(3)
                .map(|&x| x as f32)
                .collect();
            let mean = v.iter().map(|&x| f64::from(x)).sum::<f64>() / n as f64;
            v.into_iter().map(|x| x - mean as f32).collect()
        });
        Self {
            width: img.width,
            height: img.height,
            planes,
        }
    }
}

/// A 2×2 box-filtered half of `img`.
fn halve(img: &ColorImage) -> ColorImage {
    let (w, h) = (img.width / 2, img.height / 2);
    let mut out = ColorImage::new(w, h);
    for y in 0..h {
        for x in 0..w {
            let p = [
                img.get(2 * x, 2 * y),
                img.get(2 * x + 1, 2 * y),
                img.get(2 * x, 2 * y + 1),
                img.get(2 * x + 1, 2 * y + 1),
            ];
            out.set(
                x,
                y,
                std::array::from_fn(|c| {
                    ((p.iter().map(|q| u32::from(q[c])).sum::<u32>() + 2) / 4) as u8
                }),
            );
        }
    }
    out
}

/// The evaluation of intermediate tiles: the level, its spectra, the window
/// energies at every tile translation and the caches of quarter
/// correlations and of `D` per tuple of corner positions.
pub struct Evaluator<'a> {
    pub(super) set: &'a OmegaSet,
    /// Tile side T in sample pixels.
    pub tile: usize,
    /// Halvings from the sample to the evaluation level.
    pub steps: usize,
    /// Tile side at the evaluation level (even).
    pub side: usize,
    level: Level,
    spectra: [Vec<Complex<f32>>; 3],
    /// `Σ I²` over the tile window at each translation.
    window: Vec<f64>,
    /// Translations per row and rows of translations.
    nt: (usize, usize),
    ffts: [Arc<dyn Fft<f32>>; 4],
    quarters: HashMap<(Gene, u8), Arc<Quarter>>,
    cache: HashMap<[Gene; 4], (f64, usize)>,
    /// Tile evaluations run (cache misses).
    pub searches: u64,
    /// Quarter correlations computed.
    pub quarter_maps: u64,
}

impl<'a> Evaluator<'a> {
    /// The evaluator at the level [`EVAL_MAX_SIDE`] picks.
    pub fn new(set: &'a OmegaSet, sample: &ColorImage, tile: usize) -> Result<Self> {
        let mut steps = 0;
        while sample.width.max(sample.height) >> steps > EVAL_MAX_SIDE
            && tile >> (steps + 1) >= LEAST_SIDE
        {
            steps += 1;
        }
        Self::at_level(set, sample, tile, steps)
    }

    /// The evaluator `steps` halvings below the sample (0: full resolution).
    pub fn at_level(
        set: &'a OmegaSet,
        sample: &ColorImage,
        tile: usize,
        steps: usize,
    ) -> Result<Self> {
        ensure!(
            tile >= 8 && tile.is_multiple_of(2),
            "the tile size must be even and at least 8 (got {tile})"
        );
        ensure!(
            tile < sample.width && tile < sample.height,
            "the tile size {tile} must be smaller than the sample ({}×{}); give a smaller --tile-size",
            sample.width,
            sample.height
        );
        let side = (tile >> steps) & !1;
        ensure!(
            steps < 16 && side >= 4,
            "{steps} halvings leave a tile of {side} pixels; evaluate nearer full resolution"
        );
        let level = Level::of(sample, steps);
        let (w, h) = (level.width, level.height);
        let mut planner = FftPlanner::new();
        let ffts = [
            planner.plan_fft_forward(w),
            planner.plan_fft_forward(h),
            planner.plan_fft_inverse(w),
            planner.plan_fft_inverse(h),
        ];
        let spectra = std::array::from_fn(|c| {
            let mut buf: Vec<Complex<f32>> = level.planes[c]
                .iter()
                .map(|&v| Complex::new(v, 0.0))
                .collect();
            fft2(&mut buf, (w, h), h, (&*ffts[0], &*ffts[1]));
            buf
        });
        // Summed-area table of Σ_c I², then each window's sum.
        let mut sat = vec![0.0f64; (w + 1) * (h + 1)];
        for y in 0..h {
            let mut row = 0.0;
            for x in 0..w {
                row += (0..3)
                    .map(|c| f64::from(level.planes[c][y * w + x]).powi(2))
                    .sum::<f64>();
                sat[(y + 1) * (w + 1) + x + 1] = sat[y * (w + 1) + x + 1] + row;
            }
        }
        let nt = (w - side + 1, h - side + 1);
        let at = |x: usize, y: usize| sat[y * (w + 1) + x];
        let window = (0..nt.1)
            .flat_map(|ty| (0..nt.0).map(move |tx| (tx, ty)))
            .map(|(tx, ty)| {
                at(tx + side, ty + side) - at(tx, ty + side) - at(tx + side, ty) + at(tx, ty)
            })
            .collect();
        Ok(Self {
            set,
            tile,
            steps,
            side,
            level,
            spectra,
            window,
            nt,
            ffts,
            quarters: HashMap::new(),
            cache: HashMap::new(),
            searches: 0,
            quarter_maps: 0,
        })
    }

    /// A gene at the evaluation level (clamped so the patch fits).
    fn level_gene(&self, g: Gene) -> Gene {
        let most = |len: usize| (len - self.side) as u32;
        (
            (g.0 >> self.steps).min(most(self.level.width)),
            (g.1 >> self.steps).min(most(self.level.height)),
        )
    }

    /// The corner genes of tile `j` at the evaluation level.
    fn key(&self, genes: &[Gene], j: usize) -> [Gene; 4] {
        self.set.tiles[j].map(|c| self.level_gene(genes[usize::from(c)]))
    }

    /// Quarter `q` (`2·bottom + right`) of the patch at level gene `g`:
    /// its correlation with the level where the tile shows it, that is at
    /// tile offset `((1 − right)·B, (1 − bottom)·B)` (§3: each tile quarter
    /// is the opposite quarter of its corner's patch).
    fn quarter(&self, g: Gene, q: u8) -> Quarter {
        let (w, h) = (self.level.width, self.level.height);
        let b = self.side / 2;
        let (qx, qy) = (usize::from(q & 1), usize::from(q >> 1));
        let (bx, by) = (g.0 as usize + qx * b, g.1 as usize + qy * b);
        let (ox, oy) = ((1 - qx) * b, (1 - qy) * b);
        let mut acc = vec![Complex::new(0.0f32, 0.0); w * h];
        let mut buf = vec![Complex::new(0.0f32, 0.0); w * h];
        let mut energy = 0.0f64;
        for c in 0..3 {
            buf.iter_mut().for_each(|v| *v = Complex::new(0.0, 0.0));
            let plane = &self.level.planes[c];
            for y in 0..b {
                for x in 0..b {
                    let v = plane[(by + y) * w + bx + x];
                    energy += f64::from(v).powi(2);
                    buf[y * w + x] = Complex::new(v, 0.0);
                }
            }
            fft2(&mut buf, (w, h), b, (&*self.ffts[0], &*self.ffts[1]));
            for ((a, s), f) in acc.iter_mut().zip(&buf).zip(&self.spectra[c]) {
                *a += s.conj() * f;
            }
        }
        fft2(&mut acc, (w, h), h, (&*self.ffts[2], &*self.ffts[3]));
        let scale = 1.0 / (w * h) as f32;
        let corr = (0..self.nt.1)
            .flat_map(|ty| (0..self.nt.0).map(move |tx| (tx, ty)))
            .map(|(tx, ty)| acc[(ty + oy) * w + tx + ox].re * scale)
            .collect();
        Quarter { energy, corr }
    }

    /// `D` of one tile from its four quarters: the least mean squared RGB
    /// error over all translations, and that translation's index.
    fn tile_error(&self, key: &[Gene; 4]) -> (f64, usize) {
        let qs: Vec<&Quarter> = (0..4u8)
            .map(|k| &*self.quarters[&(key[usize::from(k)], 3 - k)])
            .collect();
        let energy: f64 = qs.iter().map(|q| q.energy).sum();
        let mut best = (f64::INFINITY, 0);
        for (t, &wnd) in self.window.iter().enumerate() {
            let corr: f32 = qs.iter().map(|q| q.corr[t]).sum();
            let ssd = energy + wnd - 2.0 * f64::from(corr);
            if ssd < best.0 {
                best = (ssd, t);
            }
        }
        (best.0.max(0.0) / (self.side * self.side) as f64, best.1)
    }

    /// `D_j` of every tile of every antibody, evaluated where not cached.
    pub fn errors(&mut self, antibodies: &[Vec<Gene>]) -> Result<Vec<Vec<f64>>> {
        let per_map = self.nt.0 * self.nt.1 * 4 + 64;
        let cap = (QUARTER_BYTES / per_map).max(64);
        let chunk = (cap / (4 * self.set.colours.max(1))).clamp(1, 64);
        let mut out = Vec::with_capacity(antibodies.len());
        for abs in antibodies.chunks(chunk) {
            let mut keys: Vec<[Gene; 4]> = Vec::new();
            let mut seen = std::collections::HashSet::new();
            for genes in abs {
                for j in 0..self.set.tiles.len() {
                    let key = self.key(genes, j);
                    if !self.cache.contains_key(&key) && seen.insert(key) {
                        keys.push(key);
                    }
                }
            }
            let mut need: Vec<(Gene, u8)> = Vec::new();
            let mut seen_q = std::collections::HashSet::new();
            for key in &keys {
                for k in 0..4u8 {
                    let q = (key[usize::from(k)], 3 - k);
                    if !self.quarters.contains_key(&q) && seen_q.insert(q) {
                        need.push(q);
                    }
                }
            }
            if self.quarters.len() + need.len() > cap {
                self.quarters.clear();
                need = keys
                    .iter()
                    .flat_map(|key| (0..4u8).map(move |k| (key[usize::from(k)], 3 - k)))
                    .collect::<std::collections::BTreeSet<_>>()
                    .into_iter()
                    .collect();
            }
            let made: Vec<((Gene, u8), Quarter)> = need
                .par_iter()
                .map(|&(g, q)| ((g, q), self.quarter(g, q)))
                .collect();
            self.quarter_maps += made.len() as u64;
            for (k, q) in made {
                self.quarters.insert(k, Arc::new(q));
            }
            let found: Vec<([Gene; 4], (f64, usize))> = keys
                .par_iter()
                .map(|key| (*key, self.tile_error(key)))
                .collect();
            self.searches += found.len() as u64;
            self.cache.extend(found);
            for genes in abs {
                out.push(
                    (0..self.set.tiles.len())
                        .map(|j| self.cache[&self.key(genes, j)].0)
                        .collect(),
                );
            }
        }
        Ok(out)
    }

    /// The best translation of tile `j` found at the evaluation level, as a
    /// top-left corner in the sample (evaluated by [`Self::errors`] first).
    pub(super) fn coarse_match(&mut self, genes: &[Gene], j: usize) -> Result<Gene> {
        let key = self.key(genes, j);
        if !self.cache.contains_key(&key) {
            self.errors(&[genes.to_vec()])?;
        }
        let t = self.cache[&key].1;
        let (tx, ty) = (t % self.nt.0, t / self.nt.0);
        Ok(((tx as u32) << self.steps, (ty as u32) << self.steps))
    }
}

/// The affinity `f = 1/E` of an antibody whose tiles have errors `d`.
pub fn affinity(d: &[f64], lambda: f64) -> f64 {
    1.0 / energy(d, lambda).max(1e-12)
}

/// `E = λ·ΣD + (1−λ)·Var(D)` (eq. 2).
pub fn energy(d: &[f64], lambda: f64) -> f64 {
    let n = d.len() as f64;
    let mean = d.iter().sum::<f64>() / n;
    let var = d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n;
    lambda * d.iter().sum::<f64>() + (1.0 - lambda) * var
}

/// The intermediate tile (§3): the centre of the 2×2 block of the corner
/// patches, so each quadrant is the opposite quadrant of its patch. `px(x, y,
/// corner)` reads pixel `(x, y)` of the corner's patch (side `side`).
fn intermediate<T>(side: usize, px: impl Fn(usize, usize, usize) -> T) -> Vec<T> {
    let k = side / 2;
    let mut out = Vec::with_capacity(side * side);
    for y in 0..side {
        for x in 0..side {
            let (right, sx) = if x < k { (0, x + side - k) } else { (1, x - k) };
            let (bottom, sy) = if y < k { (0, y + side - k) } else { (1, y - k) };
            out.push(px(sx, sy, 2 * bottom + right));
        }
    }
    out
}

/// The intermediate tile of `corners` at full resolution.
pub fn intermediate_tile(sample: &ColorImage, tile: usize, corners: [Gene; 4]) -> ColorImage {
    let px = intermediate(tile, |x, y, c| {
        let (gx, gy) = corners[c];
        sample.get(gx as usize + x, gy as usize + y)
    });
    ColorImage::from_vec(tile, tile, px.into_iter().flatten().collect())
}

/// `D` of one intermediate tile by brute force over every translation at full
/// resolution: the reference [`Evaluator`] is checked against.
pub fn brute_force_error(sample: &ColorImage, tile: usize, corners: [Gene; 4]) -> f64 {
    let inter = intermediate_tile(sample, tile, corners);
    let mut best = f64::INFINITY;
    for ty in 0..=sample.height - tile {
        for tx in 0..=sample.width - tile {
            let mut s = 0u64;
            for y in 0..tile {
                for x in 0..tile {
                    let (p, q) = (inter.get(x, y), sample.get(tx + x, ty + y));
                    for c in 0..3 {
                        s += (i64::from(p[c]) - i64::from(q[c])).pow(2) as u64;
                    }
                }
            }
            best = best.min(s as f64);
        }
    }
    best / (tile * tile) as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn noise(w: usize, h: usize, seed: u64) -> ColorImage {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        ColorImage::from_vec(w, h, (0..w * h * 3).map(|_| rng.random()).collect())
    }

    /// The FFT evaluation equals brute force at full resolution, on a
    /// tile that is a sample region (error 0) and on mixed ones.
    #[test]
    fn quarter_correlations_give_the_brute_force_error() {
        let sample = noise(37, 29, 5);
        let set = OmegaSet::of_size(8).unwrap();
        let mut ev = Evaluator::at_level(&set, &sample, 12, 0).unwrap();
        let genes: Vec<Gene> = vec![(0, 0), (20, 3), (7, 15), (25, 17)];
        let d = ev.errors(std::slice::from_ref(&genes)).unwrap().remove(0);
        for (j, &dj) in d.iter().enumerate() {
            let corners = set.tiles[j].map(|c| genes[usize::from(c)]);
            let want = brute_force_error(&sample, 12, corners);
            assert!(
                (dj - want).abs() <= 1e-3 * want.max(1.0),
                "tile {j}: fft {dj} brute {want}"
            );
        }
        // Four quarters of neighbouring patches that make up one sample
        // region: the tile is found verbatim.
        let (x, y) = (3u32, 4u32);
        let corners = [(x, y), (x + 12, y), (x, y + 12), (x + 12, y + 12)];
        assert!(brute_force_error(&sample, 12, corners) < 1e-9);
        ev.cache.clear();
        let mut one = OmegaSet::of_size(8).unwrap();
        one.tiles = vec![[0, 1, 2, 3]];
        let mut ev1 = Evaluator::at_level(&one, &sample, 12, 0).unwrap();
        let d = ev1.errors(&[corners.to_vec()]).unwrap();
        assert!(d[0][0] < 1e-2, "{:?}", d[0]);
    }
}
