//! The synthesis on coordinates in a plane (Lefebvre and Hoppe 2005/2006 as
//! Manke and Wünsche §3–4 summarise it) and the morph of several exemplars
//! (§4): the [`Lattice`] of pixels that the level loop of
//! [`super::driver`] drives. Every pixel of a correction sub-pass takes the
//! k-coherence candidate whose exemplar neighbourhood best matches its own.

use anyhow::{ensure, Result};
use rayon::prelude::*;

use super::appearance::Pca;
use super::coords::{wrap, CoordMap};
use super::driver::{
    blend, check_exemplar, exemplar_seed, run_levels, Lattice, LevelExemplars, Start,
};
use super::exemplar::ExemplarLevel;
use super::histogram::Matching;
use crate::imaging::ColorImage;
use crate::lattice::Lattice as Grid;
use crate::progress::Progress;
use crate::search::SearchBackend;

pub use super::driver::{MorphColour, ParallelSettings};
pub use super::neighbourhood::Neighbourhood;

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

/// Synthesises a `width`×`height` image from one exemplar: the morph of one
/// exemplar with weight 1 everywhere.
pub fn synthesize(
    exemplar: &ColorImage,
    width: usize,
    height: usize,
    s: &ParallelSettings,
    backend: &mut dyn SearchBackend,
    progress: &dyn Progress,
) -> Result<Synthesis> {
    let ones = vec![1.0f32; width * height];
    morph(&[exemplar], &[ones], width, height, s, backend, progress)
}

/// Morphs `exemplars` (Manke–Wünsche §4): `weights[j]` is exemplar j's
/// weight map at the output size, normalised (they sum to 1 per pixel).
/// Every exemplar has its own coordinate pyramid; neighbourhoods are gathered
/// from the weighted blend of the exemplars' appearance (eq. 2) and every
/// exemplar's level takes its best match against that blend (eq. 3). The
/// output colour is drawn as `s.colour` says ([`MorphColour`]).
pub fn morph(
    exemplars: &[&ColorImage],
    weights: &[Vec<f32>],
    width: usize,
    height: usize,
    s: &ParallelSettings,
    backend: &mut dyn SearchBackend,
    progress: &dyn Progress,
) -> Result<Synthesis> {
    ensure!(!exemplars.is_empty(), "no exemplar to synthesise from");
    ensure!(
        weights.len() == exemplars.len(),
        "{} weight maps for {} exemplars",
        weights.len(),
        exemplars.len()
    );
    for (j, e) in exemplars.iter().enumerate() {
        check_exemplar(e, &format!("exemplar {}", j + 1))?;
    }
    ensure!(width > 0 && height > 0, "the output size must not be empty");
    ensure!(
        weights.iter().all(|w| w.len() == width * height),
        "every weight map must be {width}×{height}"
    );
    let pca = Pca::fit(exemplars)?;
    let need = memory_needed(width, height, exemplars, pca.components.len(), s);
    s.budget.check(
        &format!(
            "a {width}×{height} synthesis on coordinates from {} exemplar(s)",
            exemplars.len()
        ),
        need,
        "choose a smaller --size",
    )?;
    let mut plane = Plane {
        exemplars,
        weights,
        width,
        height,
        seed: s.seed,
        start: s.start,
        histogram: s.histogram,
        copy_guard: s.copy_guard,
        phase: s.lattice,
        maps: vec![None; exemplars.len()],
        level: None,
        blend: Vec::new(),
        fit: Vec::new(),
    };
    let strides = run_levels(&mut plane, exemplars, &pca, s, backend, progress)?;
    let coords: Vec<CoordMap> = std::mem::take(&mut plane.maps)
        .into_iter()
        .map(|c| c.expect("a level"))
        .collect();
    let image = match s.colour {
        MorphColour::Weighted => blend_colour(exemplars, weights, &coords, width, height),
        MorphColour::Best => best_colour(exemplars, weights, &coords, &plane.fit, width, height),
    };
    Ok(Synthesis {
        image,
        coords,
        levels: strides.len(),
        candidate_strides: strides,
        explained_variance: pca.explained,
    })
}

/// Bytes a `width`×`height` synthesis or morph needs at its finest level:
/// per pixel and exemplar the coordinates three times (the level, the
/// sub-pass's copy, the maps), the level's weight and the caller's, plus the
/// appearance blend and the colour; per exemplar pixel its appearance, its
/// neighbourhood table (when kept) and its candidates.
pub fn memory_needed(
    width: usize,
    height: usize,
    exemplars: &[&ColorImage],
    dims: usize,
    s: &ParallelSettings,
) -> u64 {
    let pixels = width as u64 * height as u64;
    let m = exemplars.len() as u64;
    let points = s.most_points() as u64;
    let per_exemplar_pixel = 4 * dims as u64 * (1 + points) + 8 * s.k as u64;
    let exemplar_pixels: u64 = exemplars
        .iter()
        .map(|e| e.width as u64 * e.height as u64)
        .sum();
    pixels * (32 * m + 4 * dims as u64 + 3) + exemplar_pixels * per_exemplar_pixel
}

/// The weighted colour `Σ Wʲ·Eʲ(Sʲ(P))`, rounded to the nearest level.
pub fn blend_colour(
    exemplars: &[&ColorImage],
    weights: &[Vec<f32>],
    coords: &[CoordMap],
    width: usize,
    height: usize,
) -> ColorImage {
    let rgb = blend(width * height, exemplars.len(), 3, |i, j| {
        let [x, y] = coords[j].coords[i];
        (weights[j][i], exemplars[j].get(x as usize, y as usize))
    });
    ColorImage::from_vec(width, height, rgb)
}

/// Radius of the box that smooths each exemplar's misfit before the choice
/// of [`best_colour`]: regions, not single pixels, change exemplar.
const FIT_RADIUS: usize = 2;

/// The colour of [`MorphColour::Best`]: per pixel the colour of exemplar
/// `j` minimising `fit_j·√((1 − Wʲ)/Wʲ)`, where `fit_j` is its misfit
/// (`fit`, pixel-major, `m` per pixel: the distance of its neighbourhood at
/// its coordinate to the blended neighbourhood, eq. 3) box-smoothed over
/// `2·FIT_RADIUS + 1` pixels and divided by its mean weighted by `Wʲ` (its
/// typical misfit where it shows, so an exemplar whose distances run larger
/// is not put at a disadvantage).
/// Weight 1 always wins and weight 0 never does; at even weights the
/// better-fitting exemplar does, and the square root of the odds widens the
/// band where both show. Ties go to the first.
pub fn best_colour(
    exemplars: &[&ColorImage],
    weights: &[Vec<f32>],
    coords: &[CoordMap],
    fit: &[f32],
    width: usize,
    height: usize,
) -> ColorImage {
    let m = exemplars.len();
    let n = width * height;
    if fit.len() != n * m {
        return blend_colour(exemplars, weights, coords, width, height);
    }
    let smooth = box_smooth(fit, width, height, m, FIT_RADIUS);
    let mean: Vec<f32> = (0..m)
        .map(|j| {
            let (sum, mass) = (0..n).fold((0.0f64, 0.0f64), |(s, c), i| {
                let w = f64::from(weights[j][i]);
                (s + w * f64::from(smooth[i * m + j]), c + w)
            });
            if mass > 0.0 && sum > 0.0 {
                (sum / mass) as f32
            } else {
                1.0
            }
        })
        .collect();
    let rgb: Vec<u8> = (0..n)
        .into_par_iter()
        .flat_map_iter(|i| {
            let mut best = (f32::INFINITY, 0usize);
            for j in 0..m {
                let w = weights[j][i];
                if w <= 0.0 {
                    continue;
                }
                let cost = if w >= 1.0 {
                    f32::NEG_INFINITY
                } else {
                    smooth[i * m + j] / mean[j] * ((1.0 - w) / w).sqrt()
                };
                if cost < best.0 || best.0 == f32::INFINITY {
                    best = (cost, j);
                }
            }
            let [x, y] = coords[best.1].coords[i];
            exemplars[best.1].get(x as usize, y as usize)
        })
        .collect();
    ColorImage::from_vec(width, height, rgb)
}

/// A wrapping box mean of radius `r` over a `width`×`height` plane of `m`
/// values per pixel.
fn box_smooth(v: &[f32], width: usize, height: usize, m: usize, r: usize) -> Vec<f32> {
    let pass = |src: &[f32], horizontal: bool| -> Vec<f32> {
        let mut out = vec![0.0f32; src.len()];
        out.par_chunks_mut(m).enumerate().for_each(|(i, o)| {
            let (x, y) = (i % width, i / width);
            for d in 0..=2 * r {
                let j = if horizontal {
                    y * width + (x + width * (r + 1) + d - r) % width
                } else {
                    ((y + height * (r + 1) + d - r) % height) * width + x
                };
                for (a, b) in o.iter_mut().zip(&src[j * m..(j + 1) * m]) {
                    *a += b;
                }
            }
            let k = (2 * r + 1) as f32;
            o.iter_mut().for_each(|a| *a /= k);
        });
        out
    };
    pass(&pass(v, true), false)
}

/// The plane of a synthesis or morph: every exemplar's coordinate map.
struct Plane<'a> {
    exemplars: &'a [&'a ColorImage],
    weights: &'a [Vec<f32>],
    width: usize,
    height: usize,
    seed: u64,
    start: Start,
    /// Strength of the histogram matching of the blend.
    histogram: f32,
    /// The copy guard's share ([`ParallelSettings::copy_guard`]).
    copy_guard: Option<f32>,
    /// The grid every offset keeps ([`ParallelSettings::lattice`]).
    phase: Option<Grid>,
    /// Every exemplar's coordinates of the last finished level.
    maps: Vec<Option<CoordMap>>,
    /// The level being corrected, and its weight maps.
    level: Option<(Levels, Vec<Vec<f32>>)>,
    blend: Vec<f32>,
    /// After the finest level, every exemplar's misfit at every pixel
    /// (pixel-major) for [`best_colour`].
    fit: Vec<f32>,
}

impl Lattice for Plane<'_> {
    const SUB_PASSES: usize = 4;

    fn prepare(&mut self, level: usize, h: usize, r: f64) {
        let (lw, lh) = (self.width.div_ceil(h), self.height.div_ceil(h));
        let level_weights: Vec<Vec<f32>> = self
            .weights
            .iter()
            .map(|w| downsample(w, self.width, self.height, h))
            .collect();
        let mut level_maps: Vec<CoordMap> = Vec::with_capacity(self.exemplars.len());
        for (j, e) in self.exemplars.iter().enumerate() {
            let dims = (e.width, e.height);
            let mut map = match self.maps[j].take() {
                None => match self.start {
                    Start::Tiled => CoordMap::initial(lw, lh, dims, h as u32),
                    Start::Random => CoordMap::random(lw, lh, dims, exemplar_seed(self.seed, j)),
                },
                Some(c) => c.upsample(lw, lh, dims, h as u32),
            };
            map.jitter(dims, h as u32, r, level as u32, exemplar_seed(self.seed, j));
            if let Some(l) = &self.phase {
                // Back onto the lattice the jitter moved it off.
                for (i, c) in map.coords.iter_mut().enumerate() {
                    let origin = [(i % lw * h) as i64, (i / lw * h) as i64];
                    *c = l.snap(*c, origin, [e.width, e.height]);
                }
            }
            level_maps.push(map);
        }
        self.level = Some((Levels::of(&level_maps), level_weights));
    }

    fn correct(
        &mut self,
        ex: &LevelExemplars,
        points: &[Vec<[i32; 2]>],
        passes: usize,
        coherence: f32,
        progress: &dyn Progress,
    ) {
        let (mut lv, level_weights) = self.level.take().expect("prepared");
        let strength = self.histogram;
        let matching = (strength > 0.0 && passes > 0).then(|| {
            let sources: Vec<(&[f32], f64)> = ex
                .ex
                .iter()
                .zip(&level_weights)
                .map(|(e, w)| {
                    let mean = w.iter().map(|&v| f64::from(v)).sum::<f64>() / w.len().max(1) as f64;
                    (e.appearance.as_slice(), mean)
                })
                .collect();
            Matching::new(ex.ex[0].dims, &sources)
        });
        let mut matched = Vec::new();
        for _ in 0..passes {
            for sub in [(0, 0), (1, 1), (1, 0), (0, 1)] {
                lv = correct(
                    &lv,
                    &level_weights,
                    &ex.ex,
                    points,
                    &ex.cands,
                    sub,
                    &mut self.blend,
                    matching.as_ref().map(|m| (m, strength)),
                    &mut matched,
                    coherence,
                    (self.copy_guard, self.phase.as_ref()),
                );
                progress.advance(1);
            }
        }
        if ex.ex.first().is_some_and(|e| e.h == 1) && self.exemplars.len() > 1 {
            self.fit = misfit(&lv, &level_weights, &ex.ex, points, &mut self.blend);
        }
        for (slot, map) in self.maps.iter_mut().zip(lv.into_maps()) {
            *slot = Some(map);
        }
    }
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

/// The blended neighbourhood `N_S(P)` of eq. 2 at pixel `(x, y)`, from the
/// blend of every pixel (`dims` each), into `want`.
fn gather(
    blend: &[f32],
    (width, height): (usize, usize),
    dims: usize,
    points: &[Vec<[i32; 2]>],
    (x, y): (i64, i64),
    want: &mut Vec<f32>,
) {
    want.clear();
    for pt in points {
        let start = want.len();
        want.extend(std::iter::repeat_n(0.0f32, dims));
        let share = 1.0 / pt.len() as f32;
        for o in pt {
            let j = wrap(y + i64::from(o[1]), height) * width + wrap(x + i64::from(o[0]), width);
            for (a, v) in want[start..]
                .iter_mut()
                .zip(&blend[j * dims..(j + 1) * dims])
            {
                *a += v * share;
            }
        }
    }
}

/// Every exemplar's misfit at every pixel (pixel-major, `m` per pixel): the
/// squared distance of its neighbourhood at its coordinate to the blended
/// neighbourhood, the quantity eq. 3 minimises.
fn misfit(
    lv: &Levels,
    weights: &[Vec<f32>],
    ex: &[ExemplarLevel],
    points: &[Vec<[i32; 2]>],
    blend: &mut Vec<f32>,
) -> Vec<f32> {
    blend_appearance(lv, weights, ex, blend);
    let blend = &*blend;
    let (width, m, dims) = (lv.width, lv.m, ex[0].dims);
    let mut out = vec![0.0f32; lv.width * lv.height * m];
    out.par_chunks_mut(m).enumerate().for_each_init(
        || (Vec::new(), Vec::new()),
        |(want, buf), (i, o)| {
            let (x, y) = ((i % width) as i64, (i / width) as i64);
            gather(blend, (width, lv.height), dims, points, (x, y), want);
            for (e, (exl, f)) in ex.iter().zip(o.iter_mut()).enumerate() {
                let have = exl.neighbourhood(lv.coords[i * m + e], points, buf);
                *f = want.iter().zip(have).map(|(a, b)| (a - b) * (a - b)).sum();
            }
        },
    );
    out
}

/// Per exemplar, the offsets ([`ExemplarLevel::offset`]) that more than
/// `guard` of the level's pixels hold, sorted: no pixel may move into one
/// of them, so no coherent copy grows past that share. None: no guard.
fn crowded_offsets(lv: &Levels, ex: &[ExemplarLevel], guard: Option<f32>) -> Vec<Vec<[u32; 2]>> {
    let Some(share) = guard else {
        return vec![Vec::new(); ex.len()];
    };
    let n = lv.width * lv.height;
    let limit = (f64::from(share) * n as f64) as usize;
    ex.iter()
        .enumerate()
        .map(|(e, exl)| {
            // Offsets lie in the exemplar: one counter per exemplar pixel.
            let ew = exl.width;
            let mut counts = vec![0usize; ew * exl.height];
            for i in 0..n {
                let at = ((i % lv.width) as i64, (i / lv.width) as i64);
                let o = exl.offset(lv.coords[i * lv.m + e], at);
                counts[o[1] as usize * ew + o[0] as usize] += 1;
            }
            let mut crowded: Vec<[u32; 2]> = (0..counts.len())
                .filter(|&j| counts[j] > limit)
                .map(|j| [(j % ew) as u32, (j / ew) as u32])
                .collect();
            crowded.sort_unstable();
            crowded
        })
        .collect()
}

/// One correction sub-pass (eq. 2 and 3): the pixels with
/// `(x % 2, y % 2) == sub` take, in every exemplar's level, the k-coherence
/// candidate whose neighbourhood best matches the blended neighbourhood
/// around them, weighted by `coherence` towards the candidates their
/// neighbours continue ([`ParallelSettings::coherence`]); the others keep
/// theirs. Every pixel reads the levels as they were before the sub-pass, so
/// the result does not depend on threads.
#[allow(clippy::too_many_arguments)]
fn correct(
    lv: &Levels,
    weights: &[Vec<f32>],
    ex: &[ExemplarLevel],
    points: &[Vec<[i32; 2]>],
    cands: &[(usize, Vec<[u32; 2]>)],
    sub: (usize, usize),
    blend: &mut Vec<f32>,
    matching: Option<(&Matching, f32)>,
    matched: &mut Vec<f32>,
    coherence: f32,
    (guard, phase): (Option<f32>, Option<&Grid>),
) -> Levels {
    blend_appearance(lv, weights, ex, blend);
    let blend: &[f32] = match matching {
        Some((m, strength)) => {
            m.apply(blend, strength, matched);
            matched
        }
        None => blend,
    };
    let (width, height, m) = (lv.width, lv.height, lv.m);
    let dims = ex[0].dims;
    let crowded = crowded_offsets(lv, ex, guard);
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
                    gather(blend, (width, height), dims, points, (x, y), want);
                    for (e, (exl, (k, table))) in ex.iter().zip(cands).enumerate() {
                        let i = y as usize * width + x as usize;
                        let bases = exl.bases(|dx, dy| {
                            let ni = wrap(y + dy, height) * width + wrap(x + dx, width);
                            lv.coords[ni * m + e]
                        });
                        row[x as usize * m + e] = exl.best_candidate(
                            &bases,
                            (*k, table),
                            points,
                            (want, buf),
                            lv.coords[i * m + e],
                            (coherence, |q| {
                                // Most levels close nothing: no offset to take.
                                let closed = !crowded[e].is_empty()
                                    && crowded[e].binary_search(&exl.offset(q, (x, y))).is_ok();
                                let off_grid =
                                    phase.is_some_and(|l| !l.holds(q, [exl.h * x, exl.h * y]));
                                (!closed && !off_grid).then_some(1.0)
                            }),
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

#[cfg(test)]
mod tests {
    use super::*;

    use crate::parallel::tests::texture;

    #[test]
    fn the_best_colour_shows_whole_pixels_of_one_exemplar_and_both_in_the_middle() {
        let a = texture("pink_marble_color_128.png");
        let b = texture("leaves_green_color_161.png");
        let (w, h) = (96, 48);
        let maps = crate::parallel::weights::ramp(2, crate::parallel::weights::Axis::X, w, h);
        let mut backend = crate::search::LocalSearch::new(texsyn_engine::Engine::default());
        let out = morph(
            &[&a, &b],
            &maps,
            w,
            h,
            &ParallelSettings::default(),
            &mut backend,
            &crate::progress::Silent,
        )
        .unwrap();
        let mut middle = [0usize; 2];
        for y in 0..h {
            for x in 0..w {
                let px = out.image.get(x, y);
                let [ca, cb] = [out.coords[0].get(x, y), out.coords[1].get(x, y)];
                let from_a = px == a.get(ca[0] as usize, ca[1] as usize);
                let from_b = px == b.get(cb[0] as usize, cb[1] as usize);
                assert!(from_a || from_b, "({x}, {y}) is a mixture");
                if x == 0 {
                    assert!(from_a, "weight 1 of the first exemplar lost at ({x}, {y})");
                }
                if x == w - 1 {
                    assert!(from_b, "weight 1 of the second exemplar lost at ({x}, {y})");
                }
                if (w / 3..2 * w / 3).contains(&x) {
                    middle[usize::from(!from_a)] += 1;
                }
            }
        }
        assert!(
            middle.iter().all(|&c| c > w * h / 30),
            "the middle third is not both: {middle:?}"
        );
    }

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
                    synthesize(&ex, 96, 80, &s, &mut b, &crate::progress::Silent).unwrap()
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

    /// The largest share of pixels whose offset (coordinate − position)
    /// falls in one class modulo `s`, as a multiple of the uniform share.
    fn phase_peak(c: &CoordMap, s: u32) -> f64 {
        let mut bins = vec![0usize; (s * s) as usize];
        for y in 0..c.height {
            for x in 0..c.width {
                let [cx, cy] = c.get(x, y);
                let ox = (i64::from(cx) - x as i64).rem_euclid(i64::from(s));
                let oy = (i64::from(cy) - y as i64).rem_euclid(i64::from(s));
                bins[(oy * i64::from(s) + ox) as usize] += 1;
            }
        }
        let peak = *bins.iter().max().unwrap() as f64;
        peak / (c.width * c.height) as f64 * f64::from(s * s)
    }

    /// A `side`² synthesis of `ex` with the 7×7 neighbourhood and the
    /// defaults, changed by `tweak`.
    fn seven(ex: &ColorImage, side: usize, tweak: impl FnOnce(&mut ParallelSettings)) -> Synthesis {
        let mut s = ParallelSettings {
            neighbourhood: Neighbourhood::Full(7),
            ..ParallelSettings::default()
        };
        tweak(&mut s);
        let mut b = crate::search::LocalSearch::new(texsyn_engine::Engine::default());
        synthesize(ex, side, side, &s, &mut b, &crate::progress::Silent).unwrap()
    }

    /// The largest share of pixels at one offset (coordinate − position,
    /// modulo the `dims` exemplar): 1.0 for a tiled copy.
    fn largest_offset_share(c: &CoordMap, dims: (usize, usize)) -> f64 {
        let mut count = std::collections::HashMap::new();
        for y in 0..c.height {
            for x in 0..c.width {
                let [cx, cy] = c.get(x, y);
                let ox = (i64::from(cx) - x as i64).rem_euclid(dims.0 as i64);
                let oy = (i64::from(cy) - y as i64).rem_euclid(dims.1 as i64);
                *count.entry((ox, oy)).or_insert(0usize) += 1;
            }
        }
        *count.values().max().unwrap() as f64 / (c.width * c.height) as f64
    }

    /// No collapse: a 7×7 neighbourhood at 2× the exemplar's side, which
    /// copied the exemplar when every level was corrected (the paper's
    /// choice, still the planted case here), keeps no offset on more than a
    /// tenth of the output once the levels where it spans half the exemplar
    /// or more are only jittered.
    #[test]
    fn a_wide_neighbourhood_does_not_copy_its_exemplar() {
        let ex = texture("walnut_color_128.png");
        let run = |every_level| {
            let out = seven(&ex, 256, |s| s.every_level = every_level);
            largest_offset_share(&out.coords[0], (ex.width, ex.height))
        };
        let ours = run(false);
        assert!(ours <= 0.10, "one offset holds {ours:.3} of the output");
        let paper = run(true);
        assert!(
            paper > 0.5,
            "correcting every level no longer copies ({paper:.3}): the test lost its planted case"
        );
    }

    /// The copy guard holds a copy to its share: the planted case above
    /// (every level corrected, a tiled copy over more than half the output)
    /// keeps no offset on more than a little over a tenth with a guard of
    /// 0.1, and the guard changes nothing where no offset reaches it.
    #[test]
    fn the_copy_guard_stops_a_copy_growing_past_its_share() {
        let ex = texture("walnut_color_128.png");
        let run = |guard| {
            let out = seven(&ex, 256, |s| {
                s.every_level = true;
                s.copy_guard = guard;
            });
            largest_offset_share(&out.coords[0], (ex.width, ex.height))
        };
        let open = run(None);
        assert!(open > 0.5, "no planted copy ({open:.3})");
        let guarded = run(Some(0.1));
        assert!(
            guarded <= 0.12,
            "one offset holds {guarded:.3} under a 0.1 guard"
        );
        let free = seven(&ex, 256, |_| {});
        let loose = seven(&ex, 256, |s| s.copy_guard = Some(0.9));
        assert!(free.coords[0].get(17, 5) == loose.coords[0].get(17, 5));
        assert!(
            free.image == loose.image,
            "a guard no offset reaches changed the output"
        );
    }

    /// Histogram matching (Kopf et al.) keeps thin features: the cracks of
    /// `cracked_color_144` survive a 7×7 synthesis at 2× its side with the
    /// blend matched, and thin out to flat grey without it (the paper's
    /// plain method, the planted case), as the Laplacian-histogram distance
    /// to the exemplar shows.
    #[test]
    fn histogram_matching_keeps_thin_features() {
        let ex = texture("cracked_color_144.png");
        let run = |histogram| {
            let out = seven(&ex, 288, |s| s.histogram = histogram);
            crate::compare::compare(&ex, &out.image).unwrap().s_l
        };
        let matched = run(1.0);
        let plain = run(0.0);
        assert!(
            matched < 0.6 * plain,
            "S_L {matched:.3} with the matching against {plain:.3} without"
        );
    }

    /// No phase lock: over a large output the offsets between output and
    /// exemplar take every class modulo 4 alike (within 2× of uniform),
    /// where the tiled start of §4.1 piles them up on one class.
    #[test]
    fn offsets_have_no_preferred_phase() {
        let ex = texture("tiles_color_256.png");
        let run = |start| {
            let s = ParallelSettings {
                start,
                ..ParallelSettings::default()
            };
            let mut b = crate::search::LocalSearch::new(texsyn_engine::Engine::default());
            synthesize(&ex, 768, 768, &s, &mut b, &crate::progress::Silent).unwrap()
        };
        let random = phase_peak(&run(Start::Random).coords[0], 4);
        assert!(
            random < 2.0,
            "offset classes mod 4 peak at {random:.2}× uniform"
        );
        let tiled = phase_peak(&run(Start::Tiled).coords[0], 4);
        assert!(
            tiled > random,
            "tiled start {tiled:.2} vs random {random:.2}"
        );
    }

    /// The share of horizontally and vertically adjacent pixel pairs whose
    /// coordinates continue each other (modulo the `dims` exemplar).
    fn coherent_pairs(c: &CoordMap, dims: (usize, usize)) -> f64 {
        let (w, h) = (dims.0 as i64, dims.1 as i64);
        let mut hits = 0usize;
        for y in 0..c.height {
            for x in 0..c.width {
                let [ax, ay] = c.get(x, y);
                let [rx, ry] = c.get((x + 1) % c.width, y);
                let [dx, dy] = c.get(x, (y + 1) % c.height);
                let step = |a: u32, b: u32, m: i64| (i64::from(b) - i64::from(a)).rem_euclid(m);
                hits += usize::from(step(ax, rx, w) == 1 && step(ay, ry, h) == 0);
                hits += usize::from(step(ax, dx, w) == 0 && step(ay, dy, h) == 1);
            }
        }
        hits as f64 / (2 * c.width * c.height) as f64
    }

    /// The coherence weight: the reduced neighbourhood's four averaged
    /// points cannot tell a pixel's exact alignment, so with the paper's
    /// plain choice (the planted case, weight 0) its corrections leave
    /// many neighbours incoherent and the output's patches far from the
    /// exemplar's. With the default weight more pairs continue each other
    /// and the patches come nearer, without a copy. Every level is reduced
    /// here (no 7×7 coarse levels, which take the plain choice), so the
    /// weight acts on each.
    #[test]
    fn the_coherence_weight_keeps_reduced_corrections_coherent() {
        let ex = texture("walnut_color_128.png");
        let dims = (ex.width, ex.height);
        let run = |coherence| {
            let s = ParallelSettings {
                coherence,
                coarse: None,
                ..ParallelSettings::defaults_for(Neighbourhood::Reduced, false)
            };
            let mut b = crate::search::LocalSearch::new(texsyn_engine::Engine::default());
            let out = synthesize(&ex, 256, 256, &s, &mut b, &crate::progress::Silent).unwrap();
            let fidelity = crate::compare::compare(&ex, &out.image)
                .unwrap()
                .patch_fidelity;
            (out, fidelity)
        };
        let (weighted, w_fid) = run(super::super::driver::default_coherence(
            Neighbourhood::Reduced,
        ));
        let (plain, p_fid) = run(0.0);
        let (w_pairs, p_pairs) = (
            coherent_pairs(&weighted.coords[0], dims),
            coherent_pairs(&plain.coords[0], dims),
        );
        assert!(
            w_pairs > p_pairs + 0.05,
            "coherent pairs {w_pairs:.3} with the weight, {p_pairs:.3} without"
        );
        assert!(
            w_fid < 0.95 * p_fid,
            "patch fidelity {w_fid:.2} with the weight, {p_fid:.2} without"
        );
        let share = largest_offset_share(&weighted.coords[0], dims);
        assert!(share <= 0.10, "one offset holds {share:.3} of the output");
    }
}
