//! The synthesis on coordinates (Lefebvre and Hoppe 2005/2006 as Manke and
//! Wünsche §3–4 summarise it): per level, upsample, jitter, then correction
//! passes of four sub-passes each, where every pixel takes the k-coherence
//! candidate whose exemplar neighbourhood best matches its own.
//!
//! Neighbourhoods are sets of points in units of the level's step `h`, each
//! the mean of some pixels' appearance vectors:
//! - `Full(5)`, `Full(7)`: every pixel of the 5×5 or 7×7 window;
//! - `Reduced`: the four diagonal points (±1, ±1), each the mean of the
//!   diagonal pixel and the two axis pixels next to it (Lefebvre and Hoppe
//!   2006);
//! - `Half` (Manke–Wünsche Fig. 2, which shows only a picture): the reduced
//!   four, the centre, and the four axis points (±2, 0), (0, ±2), each the
//!   mean of the three pixels across the axis there. Nine points, a
//!   superset of the reduced neighbourhood, covering the 5×5 window.

use anyhow::{ensure, Result};
use rayon::prelude::*;

use super::appearance::{descriptor_spaced, Pca};
use super::candidates::Candidates;
use super::coords::CoordMap;
use crate::imaging::ColorImage;
use crate::search::SearchBackend;

/// The neighbourhood compared during correction.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Neighbourhood {
    Reduced,
    Half,
    Full(usize),
}

impl Neighbourhood {
    /// Points: each a list of pixel offsets whose values are averaged.
    pub fn points(self) -> Vec<Vec<[i32; 2]>> {
        let diag = |sx: i32, sy: i32| vec![[sx, sy], [sx, 0], [0, sy]];
        let reduced = vec![diag(-1, -1), diag(1, -1), diag(-1, 1), diag(1, 1)];
        match self {
            Self::Reduced => reduced,
            Self::Half => {
                let mut p = reduced;
                p.push(vec![[0, 0]]);
                for (ax, ay) in [(-2, 0), (2, 0), (0, -2), (0, 2)] {
                    p.push(if ax != 0 {
                        vec![[ax, -1], [ax, 0], [ax, 1]]
                    } else {
                        vec![[-1, ay], [0, ay], [1, ay]]
                    });
                }
                p
            }
            Self::Full(n) => {
                let r = (n / 2) as i32;
                (-r..=r)
                    .flat_map(|y| (-r..=r).map(move |x| vec![[x, y]]))
                    .collect()
            }
        }
    }
}

/// Settings of a synthesis on coordinates.
#[derive(Clone, Debug)]
pub struct ParallelSettings {
    pub neighbourhood: Neighbourhood,
    /// Jitter strength `r_i` per level, coarsest first (the last value
    /// repeats).
    pub jitter: Vec<f64>,
    /// Correction passes per level (each of 4 sub-passes).
    pub passes: usize,
    /// k of the k-coherence candidate sets.
    pub k: usize,
    pub seed: u64,
}

impl Default for ParallelSettings {
    fn default() -> Self {
        Self {
            neighbourhood: Neighbourhood::Reduced,
            jitter: vec![0.4],
            passes: 2,
            k: 4,
            seed: 1,
        }
    }
}

/// What a synthesis reports as it goes: `(level, levels)` when a level
/// starts, coarsest first.
pub type LevelProgress<'a> = &'a (dyn Fn(usize, usize) + Sync);

/// A finished synthesis or morph: the colour and, per exemplar, its
/// finest-level coordinates.
pub struct Synthesis {
    pub image: ColorImage,
    pub coords: Vec<CoordMap>,
    /// Levels of the coordinate pyramid.
    pub levels: usize,
    /// Grid stride of each level's candidate sets (1 = every pixel).
    pub candidate_strides: Vec<usize>,
    /// Share of the descriptor variance the appearance space keeps.
    pub explained_variance: f64,
}

/// Neighbourhood tables above this many floats are not kept; their entries
/// are computed when asked for (same values).
const TABLE_LIMIT: usize = 1 << 25;

/// One level of one exemplar: its appearance vectors at this level's blur,
/// its neighbourhood vectors at step `h` and its candidate sets.
pub(super) struct ExemplarLevel {
    pub(super) width: usize,
    pub(super) height: usize,
    pub(super) dims: usize,
    pub(super) h: i64,
    pub(super) appearance: Vec<f32>,
    /// Per pixel the neighbourhood vector (points × dims), when it fits.
    table: Option<Vec<f32>>,
    stride: usize,
}

impl ExemplarLevel {
    /// The exemplar at the stack level of step `h`: blurred by a box of
    /// width about `h`, and each pixel's appearance taken from its 5×5
    /// window with samples `h` pixels apart. That window is what a pyramid
    /// level's own 5×5 window covers, so a coarse level's appearance
    /// describes the structure at its scale (with adjacent samples of the
    /// blurred image it would hold little more than the blur, and bricks
    /// break up into rubble).
    pub(super) fn build(img: &ColorImage, h: usize, pca: &Pca, points: &[Vec<[i32; 2]>]) -> Self {
        let blur = blurred(img, h);
        let dims = pca.components.len();
        let projected: Vec<f64> = (0..img.width * img.height)
            .into_par_iter()
            .flat_map_iter(|i| {
                pca.project(&descriptor_spaced(&blur, i % img.width, i / img.width, h))
            })
            .collect();
        // Centred on the exemplar's own mean (see `morph`).
        let mut mean = vec![0.0f64; dims];
        for v in projected.chunks_exact(dims) {
            for (m, a) in mean.iter_mut().zip(v) {
                *m += a;
            }
        }
        let n = (img.width * img.height) as f64;
        let appearance: Vec<f32> = projected
            .chunks_exact(dims)
            .flat_map(|v| v.iter().zip(&mean).map(move |(a, m)| (a - m / n) as f32))
            .collect();
        let mut ex = Self {
            width: img.width,
            height: img.height,
            dims,
            h: h as i64,
            appearance,
            table: None,
            stride: points.len() * dims,
        };
        if ex.width * ex.height * ex.stride <= TABLE_LIMIT {
            let table: Vec<f32> = (0..ex.width * ex.height)
                .into_par_iter()
                .flat_map_iter(|i| {
                    let mut v = Vec::with_capacity(ex.stride);
                    ex.gather(
                        [(i % ex.width) as u32, (i / ex.width) as u32],
                        points,
                        &mut v,
                    );
                    v
                })
                .collect();
            ex.table = Some(table);
        }
        ex
    }

    pub(super) fn at(&self, x: u32, y: u32) -> &[f32] {
        let i = (y as usize * self.width + x as usize) * self.dims;
        &self.appearance[i..i + self.dims]
    }

    /// The neighbourhood vector of exemplar pixel `q`, computed.
    fn gather(&self, q: [u32; 2], points: &[Vec<[i32; 2]>], out: &mut Vec<f32>) {
        out.clear();
        let (w, hh) = (self.width as i64, self.height as i64);
        for pt in points {
            let start = out.len();
            out.extend(std::iter::repeat_n(0.0, self.dims));
            let share = 1.0 / pt.len() as f32;
            for o in pt {
                let x = (i64::from(q[0]) + self.h * i64::from(o[0])).rem_euclid(w) as u32;
                let y = (i64::from(q[1]) + self.h * i64::from(o[1])).rem_euclid(hh) as u32;
                for (a, v) in out[start..].iter_mut().zip(self.at(x, y)) {
                    *a += v * share;
                }
            }
        }
    }

    /// The bases of k-coherence at a pixel: the coordinates of its 3×3
    /// neighbours (`neighbour(dx, dy)`, offsets in the level's plane) shifted
    /// back by `h·(dx, dy)`. Coherent neighbours shift back to the same
    /// exemplar pixel: each such base is taken once.
    pub(super) fn bases(&self, neighbour: impl Fn(i64, i64) -> [u32; 2]) -> ([[u32; 2]; 9], usize) {
        let (ew, eh) = (self.width as i64, self.height as i64);
        let mut bases = [[u32::MAX; 2]; 9];
        let mut nb = 0;
        for dy in -1..=1i64 {
            for dx in -1..=1i64 {
                let n = neighbour(dx, dy);
                let base = [
                    (i64::from(n[0]) - self.h * dx).rem_euclid(ew) as u32,
                    (i64::from(n[1]) - self.h * dy).rem_euclid(eh) as u32,
                ];
                if !bases[..nb].contains(&base) {
                    bases[nb] = base;
                    nb += 1;
                }
            }
        }
        (bases, nb)
    }

    /// The choice of eq. 3: of the candidates of `bases` (`k` each in
    /// `table`), the one whose neighbourhood is nearest to `want` after
    /// adding its `penalty`; `current` when none is nearer than infinity.
    /// A candidate seen twice scores the same twice, and ties go to the
    /// smaller coordinate, so the order candidates are met in does not
    /// matter and candidates are not deduplicated.
    pub(super) fn best_candidate(
        &self,
        bases: &[[u32; 2]],
        (k, table): (usize, &[[u32; 2]]),
        points: &[Vec<[i32; 2]>],
        (want, buf): (&[f32], &mut Vec<f32>),
        current: [u32; 2],
        penalty: impl Fn([u32; 2]) -> f32,
    ) -> [u32; 2] {
        let mut best = (f32::INFINITY, current);
        for base in bases {
            let at = (base[1] as usize * self.width + base[0] as usize) * k;
            for &q in &table[at..at + k] {
                let pen = penalty(q);
                if pen > best.0 {
                    continue;
                }
                let have = self.neighbourhood(q, points, buf);
                let Some(d) = ssd_below(want, have, best.0 - pen) else {
                    continue;
                };
                let d = d + pen;
                if d < best.0 || (d == best.0 && (q[1], q[0]) < (best.1[1], best.1[0])) {
                    best = (d, q);
                }
            }
        }
        best.1
    }

    /// The neighbourhood vector of `q`: from the table, or computed into
    /// `buf`.
    fn neighbourhood<'a>(
        &'a self,
        q: [u32; 2],
        points: &[Vec<[i32; 2]>],
        buf: &'a mut Vec<f32>,
    ) -> &'a [f32] {
        match &self.table {
            Some(t) => {
                let i = (q[1] as usize * self.width + q[0] as usize) * self.stride;
                &t[i..i + self.stride]
            }
            None => {
                self.gather(q, points, buf);
                buf
            }
        }
    }
}

/// A blur of the exemplar for the stack level of step `h`: a wrapping box
/// of radius `h/2` ([`crate::filters::box_blur_rgb`]).
pub(super) fn blurred(img: &ColorImage, h: usize) -> ColorImage {
    crate::filters::box_blur_rgb(img, if h <= 1 { 0 } else { h / 2 })
}

/// Synthesises a `width`×`height` image from one exemplar: the morph of one
/// exemplar with weight 1 everywhere.
pub fn synthesize(
    exemplar: &ColorImage,
    width: usize,
    height: usize,
    s: &ParallelSettings,
    backend: &mut dyn SearchBackend,
    progress: LevelProgress,
) -> Result<Synthesis> {
    let ones = vec![1.0f32; width * height];
    morph(&[exemplar], &[ones], width, height, s, backend, progress)
}

/// Morphs `exemplars` (Manke–Wünsche §4): `weights[j]` is exemplar j's
/// weight map at the output size, normalised (they sum to 1 per pixel).
/// Every exemplar has its own coordinate pyramid; neighbourhoods are gathered
/// from the weighted blend of the exemplars' appearance (eq. 2) and every
/// exemplar's level takes its best match against that blend (eq. 3). The
/// output is the weighted colour `Σ Wʲ·Eʲ(Sʲ)`, rounded.
pub fn morph(
    exemplars: &[&ColorImage],
    weights: &[Vec<f32>],
    width: usize,
    height: usize,
    s: &ParallelSettings,
    backend: &mut dyn SearchBackend,
    progress: LevelProgress,
) -> Result<Synthesis> {
    ensure!(!exemplars.is_empty(), "no exemplar to synthesise from");
    ensure!(
        weights.len() == exemplars.len(),
        "{} weight maps for {} exemplars",
        weights.len(),
        exemplars.len()
    );
    for (j, e) in exemplars.iter().enumerate() {
        ensure!(
            e.width >= 8 && e.height >= 8,
            "exemplar {} is {}×{}; it must be at least 8×8",
            j + 1,
            e.width,
            e.height
        );
        ensure!(
            e.width <= 65535 && e.height <= 65535,
            "exemplar {} is wider or taller than 65535 pixels, which a coordinate map cannot hold",
            j + 1
        );
    }
    ensure!(width > 0 && height > 0, "the output size must not be empty");
    ensure!(
        weights.iter().all(|w| w.len() == width * height),
        "every weight map must be {width}×{height}"
    );
    let levels = level_count(exemplars);
    let pca = Pca::fit(exemplars)?;
    let points = s.neighbourhood.points();
    let m = exemplars.len();
    let mut maps: Vec<Option<CoordMap>> = vec![None; m];
    let mut strides = Vec::with_capacity(levels);
    let mut blend = Vec::new();
    for level in 0..levels {
        progress(level, levels);
        let h = 1usize << (levels - 1 - level);
        let (lw, lh) = (width.div_ceil(h), height.div_ceil(h));
        let level_weights: Vec<Vec<f32>> = weights
            .iter()
            .map(|w| downsample(w, width, height, h))
            .collect();
        let mut ex = Vec::with_capacity(m);
        let mut cands = Vec::with_capacity(m);
        let (mut t_build, mut t_search) = (0.0, 0.0);
        for (j, e) in exemplars.iter().enumerate() {
            let t = std::time::Instant::now();
            let level_ex = ExemplarLevel::build(e, h, &pca, &points);
            t_build += t.elapsed().as_secs_f64();
            let t = std::time::Instant::now();
            let c = Candidates::search(
                &level_ex.appearance,
                (level_ex.width, level_ex.height),
                h / 2,
                level_ex.dims,
                s.k,
                // Each exemplar's level is a level of its own to the backend
                // (a worker keeps one level per number).
                level * m + j,
                backend,
            )?;
            if cands.is_empty() {
                strides.push(c.stride());
            }
            ex.push(level_ex);
            cands.push((c.k(), c.table()));
            t_search += t.elapsed().as_secs_f64();
        }
        let r = *s.jitter.get(level).or(s.jitter.last()).unwrap_or(&0.0);
        let mut level_maps: Vec<CoordMap> = Vec::with_capacity(m);
        for (j, e) in exemplars.iter().enumerate() {
            let dims = (e.width, e.height);
            let mut map = match maps[j].take() {
                None => CoordMap::initial(lw, lh, dims, h as u32),
                Some(c) => c.upsample(lw, lh, dims, h as u32),
            };
            map.jitter(dims, h as u32, r, level as u32, exemplar_seed(s.seed, j));
            level_maps.push(map);
        }
        let t = std::time::Instant::now();
        let mut lv = Levels::of(&level_maps);
        for _ in 0..s.passes {
            for sub in [(0, 0), (1, 1), (1, 0), (0, 1)] {
                lv = correct(&lv, &level_weights, &ex, &points, &cands, sub, &mut blend);
            }
        }
        tracing::debug!(
            level,
            exemplar_levels = t_build,
            candidate_sets = t_search,
            correction = t.elapsed().as_secs_f64(),
            "level timings (s)"
        );
        for (slot, map) in maps.iter_mut().zip(lv.into_maps()) {
            *slot = Some(map);
        }
    }
    let coords: Vec<CoordMap> = maps.into_iter().map(|c| c.expect("a level")).collect();
    let image = blend_colour(exemplars, weights, &coords, width, height);
    Ok(Synthesis {
        image,
        coords,
        levels,
        candidate_strides: strides,
        explained_variance: pca.explained,
    })
}

/// Levels of a synthesis from `exemplars`: the coarsest step is the largest
/// power of two up to a quarter of the smallest exemplar side.
pub(super) fn level_count(exemplars: &[&ColorImage]) -> usize {
    let smallest = exemplars
        .iter()
        .map(|e| e.width.min(e.height))
        .min()
        .unwrap_or(8);
    (usize::BITS - (smallest / 4).max(1).leading_zeros()) as usize
}

/// Exemplar j's jitter seed (exemplar 0 keeps `seed`, so a one-exemplar
/// morph is the plain synthesis).
pub(super) fn exemplar_seed(seed: u64, j: usize) -> u64 {
    seed.wrapping_add((j as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15))
}

/// The weighted colour `Σ Wʲ·Eʲ(Sʲ(P))`, rounded to the nearest level.
pub fn blend_colour(
    exemplars: &[&ColorImage],
    weights: &[Vec<f32>],
    coords: &[CoordMap],
    width: usize,
    height: usize,
) -> ColorImage {
    let mut img = ColorImage::new(width, height);
    for (i, px) in img.rgb.chunks_exact_mut(3).enumerate() {
        let mut acc = [0.0f32; 3];
        for ((e, w), c) in exemplars.iter().zip(weights).zip(coords) {
            let [x, y] = c.coords[i];
            let p = e.get(x as usize, y as usize);
            for (a, v) in acc.iter_mut().zip(p) {
                *a += w[i] * f32::from(v);
            }
        }
        for (o, a) in px.iter_mut().zip(acc) {
            *o = a.round().clamp(0.0, 255.0) as u8;
        }
    }
    img
}

/// A weight map at the level of step `h`: each pixel the mean of its `h×h`
/// block of the full-size map (blocks cut at the border), so the maps
/// still sum to 1 per pixel.
fn downsample(w: &[f32], width: usize, height: usize, h: usize) -> Vec<f32> {
    if h == 1 {
        return w.to_vec();
    }
    let (lw, lh) = (width.div_ceil(h), height.div_ceil(h));
    let mut out = Vec::with_capacity(lw * lh);
    for ly in 0..lh {
        for lx in 0..lw {
            let (x1, y1) = (((lx + 1) * h).min(width), ((ly + 1) * h).min(height));
            let mut sum = 0.0f64;
            for y in ly * h..y1 {
                sum += w[y * width + lx * h..y * width + x1]
                    .iter()
                    .map(|&v| f64::from(v))
                    .sum::<f64>();
            }
            out.push((sum / ((x1 - lx * h) * (y1 - ly * h)) as f64) as f32);
        }
    }
    out
}

/// The levels of all exemplars at one synthesis level, interleaved: pixel
/// `i` of exemplar `e` is `coords[i * m + e]`, so a pixel's `m` coordinates
/// sit together and a row of the output is one slice.
struct Levels {
    width: usize,
    height: usize,
    m: usize,
    coords: Vec<[u32; 2]>,
}

impl Levels {
    fn of(maps: &[CoordMap]) -> Self {
        let (width, height, m) = (maps[0].width, maps[0].height, maps.len());
        let coords = (0..width * height)
            .flat_map(|i| maps.iter().map(move |c| c.coords[i]))
            .collect();
        Self {
            width,
            height,
            m,
            coords,
        }
    }

    fn into_maps(self) -> Vec<CoordMap> {
        (0..self.m)
            .map(|e| CoordMap {
                width: self.width,
                height: self.height,
                coords: self
                    .coords
                    .iter()
                    .skip(e)
                    .step_by(self.m)
                    .copied()
                    .collect(),
            })
            .collect()
    }
}

/// C(i, X) of eq. 2 for every pixel: the weighted appearance of the
/// exemplars at the pixel's coordinates, into `blend` (`dims` per pixel).
fn blend_appearance(lv: &Levels, weights: &[Vec<f32>], ex: &[ExemplarLevel], blend: &mut Vec<f32>) {
    let dims = ex[0].dims;
    blend.resize(lv.width * lv.height * dims, 0.0);
    blend
        .par_chunks_mut(dims)
        .zip(lv.coords.par_chunks(lv.m))
        .enumerate()
        .for_each(|(i, (acc, cs))| {
            acc.fill(0.0);
            for ((&[x, y], w), e) in cs.iter().zip(weights).zip(ex) {
                for (a, v) in acc.iter_mut().zip(e.at(x, y)) {
                    *a += w[i] * v;
                }
            }
        });
}

/// One correction sub-pass (eq. 2 and 3): the pixels with
/// `(x % 2, y % 2) == sub` take, in every exemplar's level, the k-coherence
/// candidate whose neighbourhood best matches the blended neighbourhood
/// around them; the others keep theirs. Every pixel reads the levels as they
/// were before the sub-pass, so the result does not depend on threads.
#[allow(clippy::too_many_arguments)]
fn correct(
    lv: &Levels,
    weights: &[Vec<f32>],
    ex: &[ExemplarLevel],
    points: &[Vec<[i32; 2]>],
    cands: &[(usize, Vec<[u32; 2]>)],
    sub: (usize, usize),
    blend: &mut Vec<f32>,
) -> Levels {
    blend_appearance(lv, weights, ex, blend);
    let blend = &*blend;
    let (width, height, m) = (lv.width, lv.height, lv.m);
    let dims = ex[0].dims;
    let (w, hh) = (width as i64, height as i64);
    let mut out = lv.coords.clone();
    out.par_chunks_mut(width * m)
        .enumerate()
        .filter(|(y, _)| y % 2 == sub.1)
        .for_each_init(
            || (Vec::new(), Vec::new()),
            |(want, buf), (y, row)| {
                let y = y as i64;
                for x in (sub.0..width).step_by(2) {
                    let x = x as i64;
                    // N_S(P), eq. 2: the blend at the neighbourhood's points.
                    want.clear();
                    for pt in points {
                        let start = want.len();
                        want.extend(std::iter::repeat_n(0.0f32, dims));
                        let share = 1.0 / pt.len() as f32;
                        for o in pt {
                            let j = (y + i64::from(o[1])).rem_euclid(hh) as usize * width
                                + (x + i64::from(o[0])).rem_euclid(w) as usize;
                            for (a, v) in want[start..]
                                .iter_mut()
                                .zip(&blend[j * dims..(j + 1) * dims])
                            {
                                *a += v * share;
                            }
                        }
                    }
                    for (e, (exl, (k, table))) in ex.iter().zip(cands).enumerate() {
                        let i = y as usize * width + x as usize;
                        let (bases, nb) = exl.bases(|dx, dy| {
                            let ni = (y + dy).rem_euclid(hh) as usize * width
                                + (x + dx).rem_euclid(w) as usize;
                            lv.coords[ni * m + e]
                        });
                        row[x as usize * m + e] = exl.best_candidate(
                            &bases[..nb],
                            (*k, table),
                            points,
                            (want, buf),
                            lv.coords[i * m + e],
                            |_| 0.0,
                        );
                    }
                }
            },
        );
    Levels {
        width,
        height,
        m,
        coords: out,
    }
}

/// The sum of squared differences, or `None` as soon as it exceeds `bound`.
/// Eight lanes at a time (one AVX register), summed in a fixed order, so a
/// complete sum is the same number whatever the bound.
pub(super) fn ssd_below(a: &[f32], b: &[f32], bound: f32) -> Option<f32> {
    let mut d = 0.0f32;
    let (mut ca, mut cb) = (a.chunks_exact(8), b.chunks_exact(8));
    for (x, y) in (&mut ca).zip(&mut cb) {
        let mut lanes = [0.0f32; 8];
        for l in 0..8 {
            let t = x[l] - y[l];
            lanes[l] = t * t;
        }
        d += ((lanes[0] + lanes[4]) + (lanes[1] + lanes[5]))
            + ((lanes[2] + lanes[6]) + (lanes[3] + lanes[7]));
        if d > bound {
            return None;
        }
    }
    for (x, y) in ca.remainder().iter().zip(cb.remainder()) {
        d += (x - y) * (x - y);
    }
    (d <= bound).then_some(d)
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::parallel::tests::texture;

    #[test]
    fn every_output_pixel_is_its_coordinate_s_exemplar_pixel_and_threads_do_not_matter() {
        let ex = texture("pink_marble_color_128.png");
        let s = ParallelSettings::default();
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| {
                    let mut b = crate::search::LocalSearch::new(texsyn_engine::Engine::default());
                    synthesize(&ex, 96, 80, &s, &mut b, &|_, _| {}).unwrap()
                })
        };
        let a = run(1);
        let b = run(2);
        assert!(a.image.rgb == b.image.rgb, "1 and 2 threads differ");
        assert_eq!(a.coords, b.coords);
        for y in 0..80 {
            for x in 0..96 {
                let c = a.coords[0].get(x, y);
                assert_eq!(a.image.get(x, y), ex.get(c[0] as usize, c[1] as usize));
            }
        }
    }

    #[test]
    fn the_stack_blur_is_a_wrapping_box_filter() {
        let ex = texture("brick_color_96.png");
        let b = blurred(&ex, 4);
        // Against the direct two-pass sum at a few pixels, wrapping.
        let (w, h) = (ex.width as i64, ex.height as i64);
        for (x, y) in [(0i64, 0i64), (95, 3), (40, 95), (17, 60)] {
            for c in 0..3 {
                let rows: Vec<u8> = (-2..=2)
                    .map(|dy| {
                        let s: u32 = (-2..=2)
                            .map(|dx| {
                                u32::from(
                                    ex.get(
                                        (x + dx).rem_euclid(w) as usize,
                                        (y + dy).rem_euclid(h) as usize,
                                    )[c],
                                )
                            })
                            .sum();
                        ((s + 2) / 5) as u8
                    })
                    .collect();
                let s: u32 = rows.iter().map(|&v| u32::from(v)).sum();
                assert_eq!(b.get(x as usize, y as usize)[c], ((s + 2) / 5) as u8);
            }
        }
    }

    #[test]
    fn the_half_reduced_neighbourhood_holds_the_reduced_one() {
        let r = Neighbourhood::Reduced.points();
        let h = Neighbourhood::Half.points();
        assert_eq!(h.len(), 9);
        assert!(r.iter().all(|p| h.contains(p)));
        assert_eq!(Neighbourhood::Full(7).points().len(), 49);
    }
}
