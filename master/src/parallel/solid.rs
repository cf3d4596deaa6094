//! Solid textures from 2-D views (Manke–Wünsche §5; ARCHITECTURE §11).
//!
//! Each *view* is a 2-D exemplar that shows the material cut across one axis
//! of the volume, and keeps its own volume of exemplar coordinates (§5.1).
//! Per level the coordinates are initialised or upsampled in the view's plane
//! and copied along the third axis (eq. 4), jittered by a hash of the 3-D
//! position, and corrected in eight sub-passes, a 2×2×2 pattern (§5.3). For a
//! voxel and a view, the neighbourhood is gathered in that view's plane from
//! the blend of every view's appearance (eq. 5), and the view takes the
//! k-coherence candidate that matches it best (eq. 3). Several materials,
//! each with its views, morph under weight volumes as the 2-D morph does
//! under weight maps (§4): a view's weight is its material's weight shared
//! evenly among the material's views.

use anyhow::{bail, ensure, Result};
use rayon::prelude::*;

use super::appearance::Pca;
use super::candidates::Candidates;
use super::coords::jitter_offset;
use super::synth::{exemplar_seed, level_count, ExemplarLevel, Neighbourhood, ParallelSettings};
use crate::imaging::ColorImage;
use crate::search::SearchBackend;

pub use crate::imaging::volume::Axis;

/// One exemplar view: material `material` (0-based) seen across `axis`.
#[derive(Clone, Copy)]
pub struct View<'a> {
    pub axis: Axis,
    pub exemplar: &'a ColorImage,
    pub material: usize,
}

/// How the materials share the volume.
#[derive(Clone, Debug)]
pub enum MaterialWeights {
    /// One material everywhere.
    Single,
    /// A linear ramp along an axis: material `j` of `m` has weight 1 at the
    /// `j`-th of `m` evenly spaced stations and falls to 0 at the next ones
    /// (as the 2-D `--ramp`).
    Ramp(Axis),
    /// One weight volume per material (x fastest, then y, then z), any
    /// non-negative scale; normalised per voxel (all zero: evenly shared).
    Volumes(Vec<Vec<f32>>),
}

/// Progress: `(level, levels, step, steps)`, a step being one sub-pass.
pub type SolidProgress<'a> = &'a (dyn Fn(usize, usize, usize, usize) + Sync);

/// The eight sub-passes, a 2×2×2 pattern of `(x, y, z)` parities (§5.3),
/// ordered so that consecutive ones differ in at least two axes.
pub const SUB_PASSES: [[usize; 3]; 8] = [
    [0, 0, 0],
    [1, 1, 1],
    [1, 1, 0],
    [0, 0, 1],
    [1, 0, 1],
    [0, 1, 0],
    [0, 1, 1],
    [1, 0, 0],
];

/// A finished solid.
pub struct Solid {
    pub size: [usize; 3],
    /// RGB per voxel, x fastest, then y, then z.
    pub colour: Vec<u8>,
    /// Per view, its finest-level exemplar coordinate at every voxel.
    pub coords: Vec<Vec<[u32; 2]>>,
    /// Every view's weight at every voxel of the finest level.
    pub weights: ViewWeights,
    pub levels: usize,
    /// Components of the appearance space and the variance they keep.
    pub dims: usize,
    pub explained_variance: f64,
}

/// The weight `Wʲ` of every view at every voxel of one level: the view's
/// share of its material times the material's weight there.
#[derive(Clone, Debug)]
pub struct ViewWeights {
    share: Vec<f32>,
    material_of: Vec<usize>,
    /// Per material, per voxel; `None` for one material.
    volumes: Option<Vec<Vec<f32>>>,
}

impl ViewWeights {
    /// The weight of view `j` at voxel `i`.
    #[inline]
    pub fn at(&self, j: usize, i: usize) -> f32 {
        match &self.volumes {
            None => self.share[j],
            Some(v) => self.share[j] * v[self.material_of[j]][i],
        }
    }
}

/// Bytes a solid of `size` with `views` views, `materials` materials and
/// `dims` appearance components needs at its finest level: coordinates
/// (twice at the end, when they are split per view), the sub-pass's new
/// coordinates, the appearance blend, the weight volumes (full size and
/// level), and the colour (twice, as it is written).
pub fn memory_needed(size: [usize; 3], views: usize, materials: usize, dims: usize) -> u64 {
    let v = size.iter().map(|&s| s as u64).product::<u64>();
    let m = views as u64;
    let weights = if materials > 1 {
        8 * materials as u64
    } else {
        0
    };
    v * (17 * m + 4 * dims as u64 + weights + 6)
}

/// Synthesises a solid of `size` voxels from `views`; a solid larger than
/// the memory limit is refused before any work, naming the memory it needs.
pub fn synthesize(
    views: &[View],
    weights: &MaterialWeights,
    size: [usize; 3],
    settings: &SolidSettings,
    backend: &mut dyn SearchBackend,
    progress: SolidProgress,
) -> Result<Solid> {
    let s = &settings.base;
    ensure!(
        settings.histogram.is_finite() && settings.histogram >= 0.0,
        "the histogram matching strength must be 0 or more"
    );
    ensure!(
        !views.is_empty(),
        "no view to synthesise from; give --view AXIS=IMAGE"
    );
    ensure!(
        size.iter().all(|&n| n >= 1),
        "the solid size must not be empty"
    );
    if s.neighbourhood == Neighbourhood::Reduced {
        bail!(
            "the reduced neighbourhood fails in 3-D (Manke–Wünsche §5.4); use half (the default), 5 or 7"
        );
    }
    let materials = views.iter().map(|v| v.material).max().unwrap_or(0) + 1;
    for mat in 0..materials {
        let axes: Vec<Axis> = views
            .iter()
            .filter(|v| v.material == mat)
            .map(|v| v.axis)
            .collect();
        ensure!(
            !axes.is_empty(),
            "material {} has no view; number materials 1, 2, ... without gaps",
            mat + 1
        );
        for a in Axis::ALL {
            ensure!(
                axes.iter().filter(|&&b| b == a).count() <= 1,
                "material {} has two views across {}; give one exemplar per axis",
                mat + 1,
                a.name()
            );
        }
    }
    for v in views {
        let e = v.exemplar;
        ensure!(
            e.width >= 8 && e.height >= 8,
            "the view across {} is {}×{}; an exemplar must be at least 8×8",
            v.axis.name(),
            e.width,
            e.height
        );
        ensure!(
            e.width <= 65535 && e.height <= 65535,
            "the view across {} is wider or taller than 65535 pixels",
            v.axis.name()
        );
    }
    let voxels = size.iter().product::<usize>();
    let full_weights: Option<Vec<Vec<f32>>> = match weights {
        MaterialWeights::Single => {
            ensure!(
                materials == 1,
                "{materials} materials need weight volumes or a ramp"
            );
            None
        }
        MaterialWeights::Ramp(axis) => (materials > 1).then(|| ramp(materials, *axis, size)),
        MaterialWeights::Volumes(v) => {
            ensure!(
                v.len() == materials,
                "{} weight volumes for {materials} materials; give one per material",
                v.len()
            );
            ensure!(
                v.iter().all(|w| w.len() == voxels),
                "every weight volume must be {}×{}×{}, the solid's size",
                size[0],
                size[1],
                size[2]
            );
            let mut v = v.clone();
            super::weights::normalise(&mut v);
            Some(v)
        }
    };
    // Views that share an exemplar share its levels and candidate sets.
    let mut uniq: Vec<&ColorImage> = Vec::new();
    let view_ex: Vec<usize> = views
        .iter()
        .map(|v| {
            match uniq.iter().position(|u| {
                (u.width, u.height) == (v.exemplar.width, v.exemplar.height)
                    && u.rgb == v.exemplar.rgb
            }) {
                Some(k) => k,
                None => {
                    uniq.push(v.exemplar);
                    uniq.len() - 1
                }
            }
        })
        .collect();
    let levels = level_count(&uniq);
    let pca = Pca::fit(&uniq)?;
    let dims = pca.components.len();
    let need = memory_needed(size, views.len(), materials, dims);
    settings.budget.check(
        &format!(
            "a {}×{}×{} solid with {} views",
            size[0],
            size[1],
            size[2],
            views.len()
        ),
        need,
        "choose a smaller --size",
    )?;
    let m = views.len();
    let mut share = vec![0.0f32; m];
    for (j, v) in views.iter().enumerate() {
        share[j] = 1.0 / views.iter().filter(|w| w.material == v.material).count() as f32;
    }
    let material_of: Vec<usize> = views.iter().map(|v| v.material).collect();
    let points = s.neighbourhood.points();
    // Each view's neighbourhood points as voxel offsets in its plane (eq. 5).
    let points3: Vec<Vec<Vec<[i64; 3]>>> = views
        .iter()
        .map(|v| {
            let [u, w] = v.axis.plane();
            points
                .iter()
                .map(|pt| {
                    pt.iter()
                        .map(|o| {
                            let mut d = [0i64; 3];
                            d[u] = i64::from(o[0]);
                            d[w] = i64::from(o[1]);
                            d
                        })
                        .collect()
                })
                .collect()
        })
        .collect();
    let mut state: Option<(Vec<[u32; 2]>, [usize; 3])> = None;
    let mut blend = Vec::new();
    let mut last_weights = None;
    for level in 0..levels {
        let h = 1usize << (levels - 1 - level);
        let ls = size.map(|n| n.div_ceil(h));
        let lw = ViewWeights {
            share: share.clone(),
            material_of: material_of.clone(),
            volumes: full_weights
                .as_ref()
                .map(|f| f.iter().map(|w| downsample3(w, size, h)).collect()),
        };
        let t = std::time::Instant::now();
        let mut ex = Vec::with_capacity(uniq.len());
        let mut cands = Vec::with_capacity(uniq.len());
        for (e, img) in uniq.iter().enumerate() {
            let level_ex = ExemplarLevel::build(img, h, &pca, &points);
            let c = Candidates::search(
                &level_ex.appearance,
                (level_ex.width, level_ex.height),
                h / 2,
                level_ex.dims,
                s.k,
                level * uniq.len() + e,
                backend,
            )?;
            ex.push(level_ex);
            cands.push((c.k(), c.table()));
        }
        let t_exemplars = t.elapsed().as_secs_f64();
        let r = *s.jitter.get(level).or(s.jitter.last()).unwrap_or(&0.0);
        let mut coords = match state.take() {
            None => initial(ls, views, h),
            Some((prev, ps)) => upsample(&prev, ps, ls, views, h),
        };
        coords.par_chunks_mut(m).enumerate().for_each(|(i, cs)| {
            let p = [
                (i % ls[0]) as i64,
                (i / ls[0] % ls[1]) as i64,
                (i / (ls[0] * ls[1])) as i64,
            ];
            for (j, (c, v)) in cs.iter_mut().zip(views).enumerate() {
                let [jx, jy] = jitter_offset(p, r, level as u32, exemplar_seed(s.seed, j));
                let (ew, eh) = (v.exemplar.width as i64, v.exemplar.height as i64);
                c[0] = (i64::from(c[0]) + jx * h as i64).rem_euclid(ew) as u32;
                c[1] = (i64::from(c[1]) + jy * h as i64).rem_euclid(eh) as u32;
            }
        });
        let bins = Bins::over(&ex);
        let mut target = vec![0.0f64; BINS];
        let n = ls.iter().product::<usize>();
        for (j, &e) in view_ex.iter().enumerate() {
            let mean = (0..n).map(|i| f64::from(lw.at(j, i))).sum::<f64>() / n as f64;
            for (t, v) in target.iter_mut().zip(bins.histogram(&ex[e])) {
                *t += mean * v;
            }
        }
        let ctx = Level {
            bins,
            target,
            size: ls,
            m,
            dims,
            ex: &ex,
            view_ex: &view_ex,
            planes: views.iter().map(|v| v.axis.plane()).collect(),
            points2: &points,
            points: &points3,
            cands: &cands,
            weights: &lw,
            scale: ex
                .iter()
                .map(|e| {
                    let n = (e.appearance.len() / e.dims.max(1)).max(1) as f64;
                    let var = e
                        .appearance
                        .iter()
                        .map(|&a| f64::from(a) * f64::from(a))
                        .sum::<f64>()
                        / n;
                    (var * points.len() as f64) as f32
                })
                .collect(),
            balance: settings.histogram,
        };
        ctx.blend_all(&coords, &mut blend);
        let t = std::time::Instant::now();
        let steps = s.passes * SUB_PASSES.len();
        for pass in 0..s.passes {
            for (k, sub) in SUB_PASSES.iter().enumerate() {
                progress(level, levels, pass * SUB_PASSES.len() + k, steps);
                ctx.correct(&mut coords, &mut blend, *sub);
            }
        }
        progress(level, levels, steps, steps);
        tracing::debug!(
            level,
            voxels = ls.iter().product::<usize>(),
            exemplar_levels_and_candidates = t_exemplars,
            correction = t.elapsed().as_secs_f64(),
            "solid level timings (s)"
        );
        state = Some((coords, ls));
        last_weights = Some(lw);
    }
    // The blend is done with; freed before the colour and the per-view
    // split, which are the peak.
    drop(blend);
    let (coords, _) = state.expect("at least one level");
    let weights = last_weights.expect("at least one level");
    let mut colour = vec![0u8; voxels * 3];
    colour
        .par_chunks_mut(3)
        .zip(coords.par_chunks(m))
        .enumerate()
        .for_each(|(i, (px, cs))| {
            let mut acc = [0.0f32; 3];
            for (j, (c, v)) in cs.iter().zip(views).enumerate() {
                let w = weights.at(j, i);
                for (a, p) in acc
                    .iter_mut()
                    .zip(v.exemplar.get(c[0] as usize, c[1] as usize))
                {
                    *a += w * f32::from(p);
                }
            }
            for (o, a) in px.iter_mut().zip(acc) {
                *o = a.round().clamp(0.0, 255.0) as u8;
            }
        });
    let per_view = (0..m)
        .map(|j| coords.iter().skip(j).step_by(m).copied().collect())
        .collect();
    Ok(Solid {
        size,
        colour,
        coords: per_view,
        weights,
        levels,
        dims,
        explained_variance: pca.explained,
    })
}

/// The coarsest level's start (§5.1): `S(P) = P_{u,v}·h mod s_e` in each
/// view's plane.
fn initial(ls: [usize; 3], views: &[View], h: usize) -> Vec<[u32; 2]> {
    let n = ls.iter().product::<usize>();
    (0..n)
        .into_par_iter()
        .flat_map_iter(|i| {
            let p = [i % ls[0], i / ls[0] % ls[1], i / (ls[0] * ls[1])];
            views.iter().map(move |v| {
                let [u, w] = v.axis.plane();
                [
                    (p[u] * h % v.exemplar.width) as u32,
                    (p[w] * h % v.exemplar.height) as u32,
                ]
            })
        })
        .collect()
}

/// Coordinate upsampling (eq. 4): a voxel takes its parent's coordinate plus
/// `h·Δ` of its parity in the view's plane; the parity along the view's own
/// axis adds nothing, so the two children across the view repeat the
/// coordinate.
fn upsample(
    prev: &[[u32; 2]],
    ps: [usize; 3],
    ls: [usize; 3],
    views: &[View],
    h: usize,
) -> Vec<[u32; 2]> {
    let m = views.len();
    let n = ls.iter().product::<usize>();
    (0..n)
        .into_par_iter()
        .flat_map_iter(|i| {
            let q = [i % ls[0], i / ls[0] % ls[1], i / (ls[0] * ls[1])];
            let p = [
                (q[0] / 2).min(ps[0] - 1),
                (q[1] / 2).min(ps[1] - 1),
                (q[2] / 2).min(ps[2] - 1),
            ];
            let pi = (p[2] * ps[1] + p[1]) * ps[0] + p[0];
            views.iter().enumerate().map(move |(j, v)| {
                let [u, w] = v.axis.plane();
                let c = prev[pi * m + j];
                [
                    (c[0] + (h * (q[u] % 2)) as u32) % v.exemplar.width as u32,
                    (c[1] + (h * (q[w] % 2)) as u32) % v.exemplar.height as u32,
                ]
            })
        })
        .collect()
}

/// Material weights ramping along `axis`, at full size.
fn ramp(m: usize, axis: Axis, size: [usize; 3]) -> Vec<Vec<f32>> {
    let len = size[axis.index()];
    let profile = super::weights::ramp(m, super::weights::Axis::X, len, 1);
    let n = size.iter().product::<usize>();
    profile
        .iter()
        .map(|p| {
            (0..n)
                .map(|i| {
                    let c = [i % size[0], i / size[0] % size[1], i / (size[0] * size[1])];
                    p[c[axis.index()]]
                })
                .collect()
        })
        .collect()
}

/// A weight volume at the level of step `h`: each voxel the mean of its
/// `h×h×h` block (cut at the border), so the materials still sum to 1.
fn downsample3(w: &[f32], size: [usize; 3], h: usize) -> Vec<f32> {
    if h == 1 {
        return w.to_vec();
    }
    let ls = size.map(|n| n.div_ceil(h));
    (0..ls.iter().product::<usize>())
        .into_par_iter()
        .map(|i| {
            let l = [i % ls[0], i / ls[0] % ls[1], i / (ls[0] * ls[1])];
            let lo = l.map(|c| c * h);
            let hi = [0, 1, 2].map(|a| ((l[a] + 1) * h).min(size[a]));
            let mut sum = 0.0f64;
            for z in lo[2]..hi[2] {
                for y in lo[1]..hi[1] {
                    let row = (z * size[1] + y) * size[0];
                    sum += w[row + lo[0]..row + hi[0]]
                        .iter()
                        .map(|&v| f64::from(v))
                        .sum::<f64>();
                }
            }
            let count = (0..3).map(|a| hi[a] - lo[a]).product::<usize>();
            (sum / count as f64) as f32
        })
        .collect()
}

/// Bins of the histogram matching.
pub const BINS: usize = 32;
/// Settings of a solid synthesis.
#[derive(Clone, Debug)]
pub struct SolidSettings {
    /// Neighbourhood (half, 5 or 7), jitter, passes, k and seed.
    pub base: ParallelSettings,
    /// Strength of the histogram matching; 0 is the paper's plain method.
    pub histogram: f32,
    /// The memory the run may take: a larger solid is refused before any work.
    pub budget: crate::budget::Budget,
}

/// Default strength of the histogram matching: strong enough that solids
/// keep about two thirds of their exemplar's contrast instead of a third,
/// weak enough not to turn to grain (ARCHITECTURE §11).
pub const HISTOGRAM: f32 = 4.0;

impl Default for SolidSettings {
    fn default() -> Self {
        Self {
            base: ParallelSettings {
                neighbourhood: Neighbourhood::Half,
                ..ParallelSettings::default()
            },
            histogram: HISTOGRAM,
            budget: crate::budget::Budget::default(),
        }
    }
}

/// Bins of the first appearance component over `[lo, hi]`.
#[derive(Clone, Copy)]
struct Bins {
    lo: f32,
    scale: f32,
}

impl Bins {
    fn over(ex: &[ExemplarLevel]) -> Self {
        let (lo, hi) = ex
            .iter()
            .flat_map(|e| e.appearance.iter().step_by(e.dims.max(1)))
            .fold((f32::MAX, f32::MIN), |(a, b), &v| (a.min(v), b.max(v)));
        let scale = if hi > lo {
            BINS as f32 / (hi - lo)
        } else {
            0.0
        };
        Self { lo, scale }
    }

    #[inline]
    fn of(self, v: f32) -> usize {
        (((v - self.lo) * self.scale) as usize).min(BINS - 1)
    }

    /// The histogram of an exemplar level's first component.
    fn histogram(self, e: &ExemplarLevel) -> Vec<f64> {
        let mut h = vec![0.0; BINS];
        let mut n = 0.0;
        for &v in e.appearance.iter().step_by(e.dims.max(1)) {
            h[self.of(v)] += 1.0;
            n += 1.0;
        }
        h.iter_mut().for_each(|v| *v /= n);
        h
    }
}

/// Everything a correction sub-pass of one level reads.
struct Level<'a> {
    size: [usize; 3],
    m: usize,
    dims: usize,
    /// Per distinct exemplar.
    ex: &'a [ExemplarLevel],
    /// Per view, its exemplar in `ex`.
    view_ex: &'a [usize],
    planes: Vec<[usize; 2]>,
    /// The neighbourhood's points in a view's plane, and per view as voxel
    /// offsets.
    points2: &'a [Vec<[i32; 2]>],
    points: &'a [Vec<Vec<[i64; 3]>>],
    /// Per distinct exemplar, `k` and every pixel's candidates.
    cands: &'a [(usize, Vec<[u32; 2]>)],
    weights: &'a ViewWeights,
    /// Strength of the usage penalty (see [`Level::usage`]).
    balance: f32,
    /// Per distinct exemplar, the variance of its appearance vectors times
    /// the neighbourhood's points: the size of a typical distance.
    scale: Vec<f32>,
    /// Bins of the first appearance component.
    bins: Bins,
    /// The histogram of the first component the solid should have: the
    /// exemplars' histograms weighted by their views' mean weights.
    target: Vec<f64>,
}

impl Level<'_> {
    #[inline]
    fn index(&self, p: [i64; 3]) -> usize {
        let s = self.size;
        let x = p[0].rem_euclid(s[0] as i64) as usize;
        let y = p[1].rem_euclid(s[1] as i64) as usize;
        let z = p[2].rem_euclid(s[2] as i64) as usize;
        (z * s[1] + y) * s[0] + x
    }

    /// `C(i, X)` of eq. 2 at voxel `i`: the weighted appearance of every
    /// view at its coordinate.
    #[inline]
    fn blend_at(&self, i: usize, coords: &[[u32; 2]], acc: &mut [f32]) {
        acc.fill(0.0);
        for (j, c) in coords[i * self.m..(i + 1) * self.m].iter().enumerate() {
            let w = self.weights.at(j, i);
            for (a, v) in acc.iter_mut().zip(self.ex[self.view_ex[j]].at(c[0], c[1])) {
                *a += w * v;
            }
        }
    }

    fn blend_all(&self, coords: &[[u32; 2]], blend: &mut Vec<f32>) {
        let n = self.size.iter().product::<usize>();
        blend.clear();
        blend.resize(n * self.dims, 0.0);
        blend
            .par_chunks_mut(self.dims)
            .enumerate()
            .for_each(|(i, acc)| self.blend_at(i, coords, acc));
    }

    /// One sub-pass: the voxels of parity `sub` take, in every view, the
    /// candidate whose exemplar neighbourhood best matches the blend's
    /// neighbourhood in the view's plane (eq. 5, eq. 3). Every voxel reads
    /// the blend and the coordinates as they were before the sub-pass (the
    /// voxels it reads have another parity, or are itself), so the result
    /// does not depend on the threads. The blend is then brought up to date
    /// at the voxels that changed.
    fn correct(&self, coords: &mut [[u32; 2]], blend: &mut [f32], sub: [usize; 3]) {
        let [w, h, d] = self.size;
        let m = self.m;
        let pen = self.penalties(blend);
        let pen = &pen;
        let zs: Vec<usize> = (sub[2]..d).step_by(2).collect();
        let updates: Vec<Vec<[u32; 2]>> = {
            let coords = &*coords;
            let blend = &*blend;
            zs.par_iter()
                .map_init(
                    || (Vec::new(), Vec::new()),
                    |(want, buf), &z| {
                        let mut out = Vec::new();
                        for y in (sub[1]..h).step_by(2) {
                            for x in (sub[0]..w).step_by(2) {
                                let p = [x as i64, y as i64, z as i64];
                                let i = (z * h + y) * w + x;
                                for j in 0..m {
                                    out.push(self.best(p, i, j, coords, blend, pen, want, buf));
                                }
                            }
                        }
                        out
                    },
                )
                .collect()
        };
        for (&z, slab) in zs.iter().zip(&updates) {
            let mut it = slab.chunks_exact(m);
            for y in (sub[1]..h).step_by(2) {
                for x in (sub[0]..w).step_by(2) {
                    let i = (z * h + y) * w + x;
                    coords[i * m..(i + 1) * m].copy_from_slice(it.next().expect("one per voxel"));
                }
            }
        }
        let coords = &*coords;
        blend
            .par_chunks_mut(w * h * self.dims)
            .enumerate()
            .filter(|(z, _)| z % 2 == sub[2])
            .for_each(|(z, slab)| {
                for y in (sub[1]..h).step_by(2) {
                    for x in (sub[0]..w).step_by(2) {
                        let at = y * w + x;
                        self.blend_at(
                            z * w * h + at,
                            coords,
                            &mut slab[at * self.dims..(at + 1) * self.dims],
                        );
                    }
                }
            });
    }

    /// Histogram matching (after Kopf et al.'s use of it against the
    /// wash-out of solid synthesis), on the first appearance component (the
    /// brightness of a pixel's 5×5 window, so it restores contrast at the
    /// window's scale, not as grain): per bin, the penalty a candidate of
    /// that bin pays, `balance·(H/T − 1)` (times the exemplar's `scale`)
    /// where the solid's blend `H` holds more of the bin than the
    /// exemplars' `T`, 0 otherwise. Counted on the blend before the
    /// sub-pass, so it does not depend on the threads.
    fn penalties(&self, blend: &[f32]) -> Vec<f32> {
        let n = blend.len() / self.dims;
        let counts = blend
            .par_chunks(self.dims * 4096)
            .fold(
                || vec![0u64; BINS],
                |mut acc, chunk| {
                    for v in chunk.iter().step_by(self.dims) {
                        acc[self.bins.of(*v)] += 1;
                    }
                    acc
                },
            )
            .reduce(
                || vec![0u64; BINS],
                |mut a, b| {
                    for (x, y) in a.iter_mut().zip(b) {
                        *x += y;
                    }
                    a
                },
            );
        counts
            .iter()
            .zip(&self.target)
            .map(|(&c, &t)| {
                let h = c as f64 / n as f64;
                (self.balance as f64 * (h / t.max(1e-4) - 1.0).max(0.0)) as f32
            })
            .collect()
    }

    /// View `j`'s best candidate at voxel `p` (index `i`).
    #[allow(clippy::too_many_arguments)]
    #[inline]
    fn best(
        &self,
        p: [i64; 3],
        i: usize,
        j: usize,
        coords: &[[u32; 2]],
        blend: &[f32],
        pen: &[f32],
        want: &mut Vec<f32>,
        buf: &mut Vec<f32>,
    ) -> [u32; 2] {
        let dims = self.dims;
        // N_S(P) in the view's plane (eq. 5).
        want.clear();
        for pt in &self.points[j] {
            let start = want.len();
            want.extend(std::iter::repeat_n(0.0f32, dims));
            let share = 1.0 / pt.len() as f32;
            for o in pt {
                let n = self.index([p[0] + o[0], p[1] + o[1], p[2] + o[2]]);
                for (a, v) in want[start..]
                    .iter_mut()
                    .zip(&blend[n * dims..(n + 1) * dims])
                {
                    *a += v * share;
                }
            }
        }
        let exl = &self.ex[self.view_ex[j]];
        let (k, table) = &self.cands[self.view_ex[j]];
        let [u, v] = self.planes[j];
        // k-coherence from the 3×3 neighbours in the view's plane.
        let (bases, nb) = exl.bases(|du, dv| {
            let mut q = p;
            q[u] += du;
            q[v] += dv;
            coords[self.index(q) * self.m + j]
        });
        let scale = self.scale[self.view_ex[j]];
        exl.best_candidate(
            &bases[..nb],
            (*k, table),
            self.points2,
            (want, buf),
            coords[i * self.m + j],
            |q| scale * pen[self.bins.of(exl.at(q[0], q[1])[0])],
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plain(w: usize, h: usize) -> ColorImage {
        ColorImage::from_vec(w, h, vec![0; w * h * 3])
    }

    #[test]
    fn initial_and_upsampled_coordinates_follow_eq_4_in_each_view_s_plane() {
        let e = plain(16, 16);
        let views: Vec<View> = Axis::ALL
            .into_iter()
            .map(|axis| View {
                axis,
                exemplar: &e,
                material: 0,
            })
            .collect();
        let (ps, ls) = ([3, 2, 4], [6, 4, 8]);
        let coarse = initial(ps, &views, 4);
        let fine = upsample(&coarse, ps, ls, &views, 2);
        let at = |c: &[[u32; 2]], s: [usize; 3], p: [usize; 3], j: usize| {
            c[((p[2] * s[1] + p[1]) * s[0] + p[0]) * 3 + j]
        };
        for z in 0..ls[2] {
            for y in 0..ls[1] {
                for x in 0..ls[0] {
                    let q = [x, y, z];
                    let p = [x / 2, y / 2, z / 2];
                    for (j, v) in views.iter().enumerate() {
                        let [u, w] = v.axis.plane();
                        // §5.1: the coarse level is P_{u,v}·h mod s_e.
                        assert_eq!(
                            at(&coarse, ps, p, j),
                            [(p[u] * 4 % 16) as u32, (p[w] * 4 % 16) as u32]
                        );
                        // Eq. 4 in pyramid units (stack coordinates / h):
                        // 2·S(P) + Δ_{u,v}, the same for both children
                        // across the view's own axis.
                        let s = at(&coarse, ps, p, j).map(|c| c / 4);
                        let want = [
                            (2 * s[0] + (q[u] % 2) as u32) % 8,
                            (2 * s[1] + (q[w] % 2) as u32) % 8,
                        ];
                        assert_eq!(at(&fine, ls, q, j).map(|c| c / 2), want);
                    }
                }
            }
        }
    }

    #[test]
    fn weight_volumes_downsample_to_block_means_that_still_sum_to_one() {
        let size = [7, 5, 6];
        let maps = ramp(3, Axis::Y, size);
        for h in [1, 2, 4] {
            let down: Vec<Vec<f32>> = maps.iter().map(|w| downsample3(w, size, h)).collect();
            let n = size.map(|s| s.div_ceil(h)).iter().product::<usize>();
            for i in 0..n {
                let sum: f32 = down.iter().map(|w| w[i]).sum();
                assert!((sum - 1.0).abs() < 1e-5, "h {h} voxel {i}: {sum}");
            }
        }
        // A block mean, by hand: h = 2, voxel (1, 1, 0) covers x 2..4,
        // y 2..4, z 0..2.
        let d = downsample3(&maps[0], size, 2);
        let mut sum = 0.0;
        for z in 0..2 {
            for y in 2..4 {
                for x in 2..4 {
                    sum += maps[0][(z * 5 + y) * 7 + x];
                }
            }
        }
        assert!((d[4 + 1] - sum / 8.0).abs() < 1e-6);
    }

    #[test]
    fn memory_grows_with_the_voxels_and_a_solid_too_large_is_refused_first() {
        let a = memory_needed([64; 3], 3, 1, 8);
        assert_eq!(memory_needed([128; 3], 3, 1, 8), 8 * a);
        let e = plain(16, 16);
        let views = [View {
            axis: Axis::Z,
            exemplar: &e,
            material: 0,
        }];
        let settings = SolidSettings {
            budget: crate::budget::Budget { cap: Some(1 << 20) },
            ..SolidSettings::default()
        };
        let mut b = crate::search::LocalSearch::new(texsyn_engine::Engine::default());
        let err = synthesize(
            &views,
            &MaterialWeights::Single,
            [64; 3],
            &settings,
            &mut b,
            &|_, _, _, _| {},
        )
        .err()
        .unwrap();
        assert!(format!("{err}").contains("GiB of memory"), "{err}");
    }
}
