//! Texture similarity (ARCHITECTURE §8): the objective check of every mode.
//!
//! - S_F, the power-spectrum similarity of Bourque and Dudek (§3.3 of their
//!   paper): 1 for the same spectrum, invariant to circular shifts.
//! - S_L, their Laplacian-pyramid histogram distance: 0 for the same band
//!   statistics.
//! - A colour term, which both of theirs ignore.
//! - Patch fidelity: how far each patch of B is from its nearest patch of A,
//!   found by exact search on the project's engine.
//! - A seam score: the step across given columns and rows (tile joints, the
//!   wrap of a tileable image) against the steps inside.
//! - Copy and repetition ([`repetition`]): the share of B copied verbatim from
//!   A at one offset, the share of B repeated verbatim inside B, and for tile
//!   grids the pixels the tiles share. The four above reward a copy of the
//!   sample; these are what catch it.

pub mod repetition;
pub mod set;
#[cfg(test)]
mod tests;

pub use repetition::{
    copy_share, repeat_share, tile_copy, tile_overlap, tile_overlap_chance, CopyShare,
};

use anyhow::{ensure, Result};
use rustfft::{num_complex::Complex, FftPlanner};
use serde::Serialize;
use texsyn_engine::{
    Engine, Geometry, Hit, Metric, Params, Plane, QueryBatch, Sample, VectorSpace, Weights,
};

use crate::imaging::colour::luminance;
use crate::imaging::{ColorImage, Gray};

/// The scores of B against A.
#[derive(Clone, Debug, Serialize)]
pub struct Scores {
    /// Power-spectrum similarity in [0, 1]; 1 = the same spectrum.
    pub s_f: f64,
    /// Laplacian-pyramid histogram distance in [0, 1]; 0 = the same.
    pub s_l: f64,
    /// Colour distance in [0, 1]: the mean over R, G, B of the earth mover's
    /// distance of the two histograms, in units of the full range.
    pub colour: f64,
    /// RMS difference per pixel (0..255 luminance) between each 7×7 patch of B
    /// (every 3rd position, at most 4096 patches) and its nearest patch of A.
    pub patch_fidelity: f64,
    /// Seam score of B as a tileable image: its wrap-around steps against its
    /// interior steps (below 1: no worse than inside); with a tile grid, at the
    /// grid's joints.
    pub seam: SeamScore,
    /// The share of B's 8×8 patches found verbatim in A at the single most
    /// common offset (modulo A's size): near 1 for a copy or tiling of A.
    pub copy_share: f64,
    /// That offset: B(x, y) = A((x + ox) mod A.width, (y + oy) mod A.height).
    pub copy_offset: [usize; 2],
    /// The share of B's 8×8 patches that occur verbatim again in B at least
    /// 16 px away.
    pub repeat_share: f64,
    /// With a tile grid: its tiles, how many distinct images they are and the
    /// pixels the distinct images share.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tiles: Option<GridScores>,
}

/// The tile measures of a grid image.
#[derive(Clone, Debug, Serialize)]
pub struct GridScores {
    pub tile_width: usize,
    pub tile_height: usize,
    /// Whole cells in the grid.
    pub cells: usize,
    /// Distinct tile images among the cells.
    pub distinct_tiles: usize,
    /// Mean over pairs of distinct tile images of the share of equal pixels
    /// (1 when every cell holds one image).
    pub tile_overlap: f64,
    /// What unrelated tiles of the texture share by chance
    /// ([`repetition::tile_overlap_chance`]); `tile_overlap` above it is
    /// shared content.
    pub tile_overlap_chance: f64,
    /// The nearest pair of distinct tile images ([`repetition::tile_copy`]):
    /// the largest share of one that is a shifted copy of another; absent
    /// for a grid of more than [`repetition::MAX_NEAREST_PAIR_TILES`]
    /// distinct cells.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tile_copy: Option<f64>,
    /// How far the lines along the joints are from the image's mean
    /// luminance, in its standard deviations ([`joint_offset`]): a tile set
    /// whose tiles share a pale or dark border draws its grid with it.
    pub joint_offset: f64,
    /// Whether the outer edge counts as a joint (a grid that wraps).
    pub wrap: bool,
}

/// A grid of `tile_width`×`tile_height` tiles; `wrap` when its outer edge is a
/// joint too (the grid tiles the plane).
#[derive(Clone, Copy, Debug)]
pub struct Grid {
    pub tile_width: usize,
    pub tile_height: usize,
    pub wrap: bool,
}

/// Most pixels per image `compare` takes: the patch-fidelity search holds a
/// vector per pixel of A (about 1 GiB at this size) and S_F a complex FFT.
pub const MAX_COMPARE_PIXELS: usize = 4096 * 4096;

/// Compares B with A on every measure; B is taken as tileable (its seam is
/// the wrap-around).
pub fn compare(a: &ColorImage, b: &ColorImage) -> Result<Scores> {
    compare_with(a, b, None)
}

/// Compares B with A on every measure; with a `grid`, B is a grid of tiles
/// whose seam is taken at its joints and whose tiles are compared.
pub fn compare_with(a: &ColorImage, b: &ColorImage, grid: Option<Grid>) -> Result<Scores> {
    for (img, what) in [(a, "the sample"), (b, "the compared texture")] {
        ensure!(
            img.len() <= MAX_COMPARE_PIXELS,
            "{what} is {}x{} pixels; compare takes at most {} Mi pixels per image (4096x4096): compare a crop",
            img.width,
            img.height,
            MAX_COMPARE_PIXELS >> 20
        );
    }
    let timed = |what: &str, t: std::time::Instant| {
        tracing::info!(seconds = t.elapsed().as_secs_f64(), "compare: {what}");
    };
    let t = std::time::Instant::now();
    let copy = copy_share(a, b);
    let repeat = repeat_share(b);
    timed("copy_share and repeat_share", t);
    let (seam, tiles) = match grid {
        None => (seam_score(b, &[0], &[0]), None),
        Some(g) => {
            ensure!(
                g.tile_width >= 1
                    && g.tile_height >= 1
                    && g.tile_width <= b.width
                    && g.tile_height <= b.height,
                "the tile size {}x{} does not fit the {}x{} image: give --tile WxH of one tile",
                g.tile_width,
                g.tile_height,
                b.width,
                b.height
            );
            let cells = repetition::grid_cells(b, g.tile_width, g.tile_height);
            let (distinct, overlap, chance) = repetition::tile_measures(&cells);
            let overlap = overlap.unwrap_or(0.0);
            (
                grid_seam(b, g),
                Some(GridScores {
                    tile_width: g.tile_width,
                    tile_height: g.tile_height,
                    cells: cells.len(),
                    distinct_tiles: distinct,
                    tile_overlap: overlap,
                    tile_overlap_chance: chance.unwrap_or(0.0),
                    tile_copy: repetition::tile_copy(&cells),
                    joint_offset: joint_offset(b, g),
                    wrap: g.wrap,
                }),
            )
        }
    };
    let t = std::time::Instant::now();
    let (s_f, s_l, colour) = (
        spectrum_similarity(a, b)?,
        laplacian_distance(a, b)?,
        colour_distance(a, b),
    );
    timed("S_F, S_L and colour", t);
    let t = std::time::Instant::now();
    let patch_fidelity = patch_fidelity(a, b)?;
    timed("patch fidelity", t);
    Ok(Scores {
        s_f,
        s_l,
        colour,
        patch_fidelity,
        seam,
        copy_share: copy.share,
        copy_offset: copy.offset,
        repeat_share: repeat,
        tiles,
    })
}

/// The centred `w`×`h` crop of a grey image as floats.
fn centre_crop(g: &Gray, w: usize, h: usize) -> Vec<f64> {
    let (x0, y0) = ((g.width - w) / 2, (g.height - h) / 2);
    let mut v = Vec::with_capacity(w * h);
    for y in 0..h {
        for x in 0..w {
            v.push(f64::from(g.get(x0 + x, y0 + y)));
        }
    }
    v
}

/// The signed frequency of FFT bin `k` of `n`, in cycles per pixel
/// (bins past `n/2` are the negative frequencies).
pub(crate) fn frequency(k: usize, n: usize) -> f64 {
    let k = if k > n / 2 {
        k as f64 - n as f64
    } else {
        k as f64
    };
    k / n as f64
}

/// The radially weighted, normalised Fourier magnitude of a `w`×`h` image:
/// the mean is removed, each magnitude is multiplied by its frequency's
/// radius (which flattens the 1/f fall-off of natural images, so that all
/// scales count; DC gets 0), and the result has unit length.
pub(crate) fn weighted_spectrum(v: &[f64], w: usize, h: usize) -> Vec<f64> {
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    let mut buf: Vec<Complex<f64>> = v.iter().map(|&x| Complex::new(x - mean, 0.0)).collect();
    let mut planner = FftPlanner::new();
    let (rows, cols) = (planner.plan_fft_forward(w), planner.plan_fft_forward(h));
    crate::filters::fft2(&mut buf, (w, h), h, (&*rows, &*cols));
    let mut out: Vec<f64> = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| {
            let r = frequency(x, w).hypot(frequency(y, h));
            buf[y * w + x].norm() * r
        })
        .collect();
    let norm = out.iter().map(|x| x * x).sum::<f64>().sqrt();
    if norm > 0.0 {
        out.iter_mut().for_each(|x| *x /= norm);
    }
    out
}

/// S_F = 1 − ‖F(A) − F(B)‖ / √2 over the weighted, normalised magnitude
/// spectra of the luminance of the two images' common centred crop. In
/// [0, 1]; a flat image against a flat image scores 1, against a textured
/// one 1 − 1/√2.
pub fn spectrum_similarity(a: &ColorImage, b: &ColorImage) -> Result<f64> {
    let (w, h) = (a.width.min(b.width), a.height.min(b.height));
    ensure!(w >= 8 && h >= 8, "images under 8×8 cannot be compared");
    let (la, lb) = (luminance(a), luminance(b));
    let fa = weighted_spectrum(&centre_crop(&la, w, h), w, h);
    let fb = weighted_spectrum(&centre_crop(&lb, w, h), w, h);
    Ok(spectra_similarity(&fa, &fb))
}

/// S_F of two spectra made by [`Descriptors::of`] from images of one size.
pub fn spectra_similarity(fa: &[f64], fb: &[f64]) -> f64 {
    let d = fa
        .iter()
        .zip(fb)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f64>()
        .sqrt();
    (1.0 - d / std::f64::consts::SQRT_2).clamp(0.0, 1.0)
}

/// The measures' descriptors of one image, computed once: S_F, S_L and the
/// colour term of many candidates against one target (procedural matching,
/// ARCHITECTURE §12) then cost one pass over each candidate.
#[derive(Clone, Debug)]
pub struct Descriptors {
    pub width: usize,
    pub height: usize,
    /// The weighted, normalised magnitude spectrum of the luminance.
    pub spectrum: Vec<f64>,
    /// The histograms of the first 4 Laplacian band-pass levels.
    pub bands: Vec<Vec<f64>>,
    /// The cumulative histograms of R, G and B.
    pub cdfs: [Vec<f64>; 3],
}

impl Descriptors {
    /// The descriptors of `img` (at least 8×8).
    pub fn of(img: &ColorImage) -> Result<Self> {
        ensure!(
            img.width >= 8 && img.height >= 8,
            "images under 8×8 cannot be compared"
        );
        let l = luminance(img);
        let (w, h) = (l.width, l.height);
        let v: Vec<f64> = l.data.iter().map(|&x| f64::from(x)).collect();
        Ok(Self {
            width: w,
            height: h,
            spectrum: weighted_spectrum(&v, w, h),
            bands: laplacian_bands(&l, 4)
                .iter()
                .map(|b| band_histogram(b))
                .collect(),
            cdfs: colour_cdfs(img),
        })
    }

    /// S_F, S_L and the colour term of `other` against `self` (same size).
    pub fn scores(&self, other: &Self) -> (f64, f64, f64) {
        (
            spectra_similarity(&self.spectrum, &other.spectrum),
            histograms_distance(&self.bands, &other.bands),
            cdfs_distance(&self.cdfs, &other.cdfs),
        )
    }
}

/// S_L of two sets of band histograms: the mean over the common levels of
/// half the L1 distance.
fn histograms_distance(a: &[Vec<f64>], b: &[Vec<f64>]) -> f64 {
    let levels = a.len().min(b.len());
    if levels == 0 {
        return 0.0;
    }
    let mut s = 0.0;
    for i in 0..levels {
        s += 0.5
            * a[i]
                .iter()
                .zip(&b[i])
                .map(|(x, y)| (x - y).abs())
                .sum::<f64>();
    }
    s / levels as f64
}

/// Band-pass levels of a Laplacian pyramid: each level minus its reduced
/// level brought back up (nearest neighbour).
fn laplacian_bands(g: &Gray, levels: usize) -> Vec<Vec<f64>> {
    let v: Vec<f64> = g.data.iter().map(|&x| f64::from(x)).collect();
    laplacian_bands_of(v, g.width, g.height, levels)
}

/// [`laplacian_bands`] of a `w`×`h` float image.
pub(crate) fn laplacian_bands_of(
    mut v: Vec<f64>,
    mut w: usize,
    mut h: usize,
    levels: usize,
) -> Vec<Vec<f64>> {
    let mut bands = Vec::new();
    for _ in 0..levels {
        if w < 8 || h < 8 {
            break;
        }
        let (r, rw, _) = crate::pyramid::reduce_f64(&v, w, h);
        let band: Vec<f64> = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| v[y * w + x] - r[(y / 2) * rw + x / 2])
            .collect();
        bands.push(band);
        let (nw, nh) = (w.div_ceil(2), h.div_ceil(2));
        v = r;
        w = nw;
        h = nh;
    }
    bands
}

/// Normalised histogram of a band: 64 bins over [−64, 64), outliers in the
/// end bins.
fn band_histogram(band: &[f64]) -> Vec<f64> {
    let mut h = vec![0.0; 64];
    for &x in band {
        let b = ((x + 64.0) / 2.0).floor().clamp(0.0, 63.0) as usize;
        h[b] += 1.0;
    }
    let n = band.len().max(1) as f64;
    h.iter_mut().for_each(|x| *x /= n);
    h
}

/// S_L = Σ_i w_i · ½ Σ |H(L_i(A)) − H(L_i(B))| over the first 4 band-pass
/// levels, with equal weights w_i = 1/levels: in [0, 1].
pub fn laplacian_distance(a: &ColorImage, b: &ColorImage) -> Result<f64> {
    let (ba, bb) = (
        laplacian_bands(&luminance(a), 4),
        laplacian_bands(&luminance(b), 4),
    );
    ensure!(
        !ba.is_empty() && !bb.is_empty(),
        "images under 8×8 cannot be compared"
    );
    let ha: Vec<Vec<f64>> = ba.iter().map(|b| band_histogram(b)).collect();
    let hb: Vec<Vec<f64>> = bb.iter().map(|b| band_histogram(b)).collect();
    Ok(histograms_distance(&ha, &hb))
}

/// Per channel (R, G, B) standard deviation of B over A's: 1 when B has
/// A's contrast (a washed-out solid slice is well under 1).
pub fn contrast_ratio(a: &ColorImage, b: &ColorImage) -> [f64; 3] {
    let (sa, sb) = (channel_deviations(a), channel_deviations(b));
    [0, 1, 2].map(|c| if sa[c] > 0.0 { sb[c] / sa[c] } else { 0.0 })
}

/// Per channel standard deviation.
pub fn channel_deviations(img: &ColorImage) -> [f64; 3] {
    let n = img.len().max(1) as f64;
    let mut sum = [0.0f64; 3];
    let mut sq = [0.0f64; 3];
    for p in img.rgb.chunks_exact(3) {
        for c in 0..3 {
            let v = f64::from(p[c]);
            sum[c] += v;
            sq[c] += v * v;
        }
    }
    [0, 1, 2].map(|c| (sq[c] / n - (sum[c] / n).powi(2)).max(0.0).sqrt())
}

/// Energy of the pixel checker, the luminance's component at the Nyquist
/// frequency in both axes: the mean over every 2×2 block (wrapping) of
/// `(¼ Σ (−1)^(x+y) L)²`, in squared grey levels. A texture that alternates
/// pixel by pixel has far more of it than one smooth at the pixel scale.
pub fn checker_energy(img: &ColorImage) -> f64 {
    let l = luminance(img);
    let (w, h) = (l.width, l.height);
    if w < 2 || h < 2 {
        return 0.0;
    }
    let mut e = 0.0f64;
    for y in 0..h {
        for x in 0..w {
            let (x1, y1) = ((x + 1) % w, (y + 1) % h);
            let c = f64::from(l.get(x, y)) - f64::from(l.get(x1, y)) - f64::from(l.get(x, y1))
                + f64::from(l.get(x1, y1));
            e += (c / 4.0).powi(2);
        }
    }
    e / (w * h) as f64
}

/// Mean over R, G, B of the 1-D earth mover's distance between the two
/// images' normalised histograms, divided by 255: in [0, 1].
pub fn colour_distance(a: &ColorImage, b: &ColorImage) -> f64 {
    cdfs_distance(&colour_cdfs(a), &colour_cdfs(b))
}

/// The cumulative normalised histograms of R, G and B.
fn colour_cdfs(img: &ColorImage) -> [Vec<f64>; 3] {
    let n = img.len().max(1) as f64;
    std::array::from_fn(|k| {
        let mut h = vec![0.0f64; 256];
        for p in img.rgb.chunks_exact(3) {
            h[p[k] as usize] += 1.0;
        }
        let mut c = 0.0;
        h.iter_mut().for_each(|x| {
            c += *x / n;
            *x = c;
        });
        h
    })
}

/// The colour term of two sets of cumulative histograms: the mean over R, G,
/// B of the earth mover's distance, divided by 255.
fn cdfs_distance(a: &[Vec<f64>; 3], b: &[Vec<f64>; 3]) -> f64 {
    let mut total = 0.0;
    for k in 0..3 {
        let emd: f64 = a[k].iter().zip(&b[k]).map(|(x, y)| (x - y).abs()).sum();
        total += emd / 255.0;
    }
    total / 3.0
}

/// Side of the patches of [`patch_fidelity`].
const PATCH: usize = 7;
/// Least step between the query patches of B.
const PATCH_STEP: usize = 3;
/// Most query patches: larger images are sampled with a wider step.
const MAX_QUERIES: usize = 4096;

/// The 7×7 luminance window with top-left corner `(x, y)`, row by row.
fn window(g: &Gray, x: usize, y: usize) -> Vec<u8> {
    (0..PATCH)
        .flat_map(|j| (0..PATCH).map(move |i| (i, j)))
        .map(|(i, j)| g.get(x + i, y + j))
        .collect()
}

/// RMS luminance difference per pixel between each 7×7 patch of `b` (every
/// third position, or a wider step that keeps at most 4096 patches) and its
/// nearest patch anywhere in `a`: an exact search
/// on the engine (in-process, all cores). 0 when every patch of B occurs in A.
pub fn patch_fidelity(a: &ColorImage, b: &ColorImage) -> Result<f64> {
    ensure!(
        a.width >= PATCH && a.height >= PATCH && b.width >= PATCH && b.height >= PATCH,
        "images under {PATCH}×{PATCH} have no patch to compare"
    );
    let (la, lb) = (luminance(a), luminance(b));
    let geometry = Geometry::new(PATCH, 0)?;
    let plane = Plane::new(la.width, la.height, &la.data, None)?;
    let sample = Sample {
        fine: plane,
        parent: None,
    };
    let positions = texsyn_engine::plane::reference_positions(&sample, &geometry)?;
    let n = positions.len() as u64;
    let space = VectorSpace::build_from_positions(&sample, &geometry, &positions, 0..n)?;
    let params = Params {
        metric: Metric::L2,
        weights: Weights::new(1, 1)?,
    };
    let engine = Engine::default();
    let mut total = 0.0f64;
    let mut count = 0usize;
    let (qw, qh) = (lb.width - PATCH + 1, lb.height - PATCH + 1);
    let step = PATCH_STEP.max(((qw * qh) as f64 / MAX_QUERIES as f64).sqrt().ceil() as usize);
    let ys: Vec<usize> = (0..qh).step_by(step).collect();
    let xs: Vec<usize> = (0..qw).step_by(step).collect();
    for rows in ys.chunks(16) {
        let mut batch = QueryBatch::new(geometry.layout());
        for &y in rows {
            for &x in &xs {
                batch.push_full(&window(&lb, x, y))?;
            }
        }
        let hits: Vec<Hit> = engine.search_best(&space, 0..n, &batch, &params)?;
        for h in hits {
            total += h.dist as f64;
            count += 1;
        }
    }
    Ok((total / (count * PATCH * PATCH) as f64).sqrt())
}

/// The steps across chosen columns and rows of an image.
#[derive(Clone, Debug, Serialize)]
pub struct SeamScore {
    /// Mean absolute luminance step across the chosen joints (a joint at
    /// column c lies between columns c − 1 and c; 0 is the wrap-around).
    pub joint_step: f64,
    /// Median and 95th percentile of the steps between the other columns and
    /// rows.
    pub interior_median: f64,
    pub interior_p95: f64,
    /// `joint_step / interior_median`: about 1 or below when the joints do not
    /// show.
    pub ratio: f64,
    /// Mean step across the boundaries one pixel either side of the joints
    /// (between a joint's first and second column, and its last but one and
    /// last before it), where a stitch that hugs the joint cuts: joints that
    /// are seamless themselves still draw a double line there.
    pub beside_step: f64,
    /// `beside_step / interior_median`.
    pub beside_ratio: f64,
}

/// Seam score of `img` at joint columns `cols` and joint rows `rows` (0 = the
/// wrap-around of a tileable image): each column joint's mean absolute
/// luminance step, against the same for every other column and row boundary.
pub fn seam_score(img: &ColorImage, cols: &[usize], rows: &[usize]) -> SeamScore {
    steps_score(img, cols, rows, true)
}

/// Seam score of a grid image at its real joints: the inner tile boundaries,
/// and the outer edge only when the grid wraps. A grid that does not wrap
/// (an ω-tiling) leaves its outer edge out of the joints and of the interior.
pub fn grid_seam(img: &ColorImage, grid: Grid) -> SeamScore {
    let first = usize::from(!grid.wrap);
    let cols: Vec<usize> = (first..)
        .map(|k| k * grid.tile_width)
        .take_while(|&c| c < img.width)
        .collect();
    let rows: Vec<usize> = (first..)
        .map(|k| k * grid.tile_height)
        .take_while(|&r| r < img.height)
        .collect();
    steps_score(img, &cols, &rows, grid.wrap)
}

/// Pixels on each side of a joint that [`joint_offset`] takes as its line.
pub const JOINT_LINE: usize = 2;

/// How much a grid's joints stand out by brightness: the mean luminance of
/// the [`JOINT_LINE`] columns and rows on each side of every joint, less the
/// image's mean, in the image's standard deviations of luminance. A step
/// across a joint is what [`grid_seam`] sees; this sees the band that every
/// tile of a set shares along its edges (a template's pale or dark border is
/// a grid line in every cell, however seamless the joints are). 0 for a
/// grid whose joints fall on typical texture, and for an empty tile size.
pub fn joint_offset(img: &ColorImage, grid: Grid) -> f64 {
    if grid.tile_width == 0 || grid.tile_height == 0 {
        return 0.0;
    }
    let g = luminance(img);
    let (w, h) = (g.width, g.height);
    // Whether coordinate `k` lies within JOINT_LINE of a joint: the
    // boundary before a multiple of the tile side, the outer edge (0) only
    // where the grid wraps.
    let near = |k: usize, tile: usize, len: usize| {
        let before = k - k % tile;
        let after = before + tile;
        let joint = |j: usize| if j == 0 || j >= len { grid.wrap } else { true };
        (k < before + JOINT_LINE && joint(before)) || (k + JOINT_LINE >= after && joint(after))
    };
    let (mut sum, mut sq, mut line, mut lines) = (0.0f64, 0.0f64, 0.0f64, 0usize);
    for y in 0..h {
        for x in 0..w {
            let v = f64::from(g.get(x, y));
            sum += v;
            sq += v * v;
            if near(x, grid.tile_width, w) || near(y, grid.tile_height, h) {
                line += v;
                lines += 1;
            }
        }
    }
    let n = (w * h).max(1) as f64;
    let mean = sum / n;
    let deviation = (sq / n - mean * mean).max(0.0).sqrt();
    if lines == 0 || deviation == 0.0 {
        return 0.0;
    }
    (line / lines as f64 - mean).abs() / deviation
}

/// The seam score of [`seam_score`]; without `wrap`, the boundary between the
/// last and first column (and row) is left out.
fn steps_score(img: &ColorImage, cols: &[usize], rows: &[usize], wrap: bool) -> SeamScore {
    let g = luminance(img);
    let (w, h) = (g.width, g.height);
    // Mean absolute step across the boundary before column (or row) `k`,
    // the last one wrapping round to the first.
    let step = |k: usize, rows: bool| {
        let (n, len) = if rows { (h, w) } else { (w, h) };
        let (a, b) = ((k + n - 1) % n, k % n);
        let at = |c: usize, t: usize| if rows { g.get(t, c) } else { g.get(c, t) };
        (0..len)
            .map(|t| f64::from(at(a, t).abs_diff(at(b, t))))
            .sum::<f64>()
            / len as f64
    };
    let mut joints = Vec::new();
    let mut interior = Vec::new();
    let mut beside = Vec::new();
    let first = usize::from(!wrap);
    // Whether boundary `k` of `n` lies one pixel from a joint of `at` (the
    // outer edge, 0, is one only where the caller lists it).
    let near = |k: usize, n: usize, at: &[usize]| {
        at.contains(&((k + 1) % n)) || at.contains(&((k + n - 1) % n))
    };
    for c in first..w {
        if cols.contains(&c) {
            joints.push(step(c, false));
        } else {
            if near(c, w, cols) {
                beside.push(step(c, false));
            }
            interior.push(step(c, false));
        }
    }
    for r in first..h {
        if rows.contains(&r) {
            joints.push(step(r, true));
        } else {
            if near(r, h, rows) {
                beside.push(step(r, true));
            }
            interior.push(step(r, true));
        }
    }
    interior.sort_by(f64::total_cmp);
    let q = |p: f64| {
        if interior.is_empty() {
            0.0
        } else {
            interior[((interior.len() - 1) as f64 * p).round() as usize]
        }
    };
    let joint_step = joints.iter().sum::<f64>() / joints.len().max(1) as f64;
    let beside_step = beside.iter().sum::<f64>() / beside.len().max(1) as f64;
    let median = q(0.5);
    let ratio = |step: f64| {
        if median > 0.0 {
            step / median
        } else if step > 0.0 {
            f64::INFINITY
        } else {
            1.0
        }
    };
    SeamScore {
        joint_step,
        interior_median: median,
        interior_p95: q(0.95),
        ratio: ratio(joint_step),
        beside_step,
        beside_ratio: ratio(beside_step),
    }
}
