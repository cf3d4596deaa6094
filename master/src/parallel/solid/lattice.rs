//! The volume of a solid synthesis (Manke–Wünsche §5): the [`Lattice`] of
//! voxels the level loop drives. Coordinates start at random (a departure
//! from §5.1, see [`initial`]), upsample by eq. 4 and are corrected in eight sub-passes (§5.3),
//! each view against the blend's neighbourhood in its plane (eq. 5), the
//! blend histogram-matched to the exemplars' appearance after every sub-pass
//! ([`super::histogram`]), and the choice weighted by how often the volume
//! already uses each exemplar pixel ([`Usage`]). With a lattice phase every
//! view's offsets stay on the exemplar's grid ([`crate::lattice::PHASE_TOLERANCE`]).

use rayon::prelude::*;

use super::weights::{downsample3, ViewWeights};
use super::View;
use crate::lattice::Lattice as Grid;
use crate::parallel::coords::{jitter_offset, random_pixel, wrap};
use crate::parallel::driver::{exemplar_seed, Lattice, LevelExemplars};
use crate::parallel::exemplar::ExemplarLevel;
use crate::parallel::histogram::Matching;
use crate::progress::Progress;

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

/// A solid's volume being synthesised.
pub(super) struct Volume<'a> {
    pub views: &'a [View<'a>],
    /// Per view, its distinct exemplar.
    pub view_ex: &'a [usize],
    pub size: [usize; 3],
    pub seed: u64,
    /// Strength of the histogram matching.
    pub histogram: f32,
    /// Weight of the index histogram matching ([`Usage`]; 0: off).
    pub index_histogram: f32,
    pub dims: usize,
    /// Per material, its weight at every voxel of the full size (several
    /// materials only).
    pub full_weights: Option<Vec<Vec<f32>>>,
    /// The level's neighbourhood points per view as voxel offsets in its
    /// plane (eq. 5), laid out by [`voxel_offsets`] at every level (levels
    /// may differ: [`crate::parallel::driver::CoarseLevels`]).
    pub points3: Vec<Vec<Vec<[i64; 3]>>>,
    /// Every view's coordinate at every voxel of the current level (view
    /// fastest), and the level's size.
    pub coords: Vec<[u32; 2]>,
    pub level_size: [usize; 3],
    /// The current level's view weights.
    pub weights: Option<ViewWeights>,
    pub blend: Vec<f32>,
    /// The blend histogram-matched, which the neighbourhoods are gathered
    /// from (empty when the strength is 0).
    pub matched: Vec<f32>,
    /// The exemplars' grid, which every view's offsets keep ([`crate::lattice::PHASE_TOLERANCE`]).
    pub phase: Option<Grid>,
}

impl Lattice for Volume<'_> {
    const SUB_PASSES: usize = SUB_PASSES.len();

    fn prepare(&mut self, level: usize, h: usize, r: f64) {
        let ls = self.size.map(|n| n.div_ceil(h));
        let material_of: Vec<usize> = self.views.iter().map(|v| v.material).collect();
        let volumes = self
            .full_weights
            .as_ref()
            .map(|f| f.iter().map(|w| downsample3(w, self.size, h)).collect());
        self.weights = Some(ViewWeights::new(&material_of, volumes));
        let mut coords = if level == 0 {
            initial(ls, self.views, self.seed)
        } else {
            upsample(&self.coords, self.level_size, ls, self.views, h)
        };
        let (views, seed, m, phase) = (self.views, self.seed, self.views.len(), self.phase);
        coords.par_chunks_mut(m).enumerate().for_each(|(i, cs)| {
            let p = [
                (i % ls[0]) as i64,
                (i / ls[0] % ls[1]) as i64,
                (i / (ls[0] * ls[1])) as i64,
            ];
            for (j, (c, v)) in cs.iter_mut().zip(views).enumerate() {
                let [jx, jy] = jitter_offset(p, r, level as u32, exemplar_seed(seed, j));
                let (ew, eh) = (v.exemplar.width as i64, v.exemplar.height as i64);
                c[0] = (i64::from(c[0]) + jx * h as i64).rem_euclid(ew) as u32;
                c[1] = (i64::from(c[1]) + jy * h as i64).rem_euclid(eh) as u32;
                if let Some(l) = &phase {
                    // Back onto the lattice the jitter moved it off.
                    let [u, w] = v.axis.plane();
                    let origin = [h as i64 * p[u], h as i64 * p[w]];
                    *c = l.snap(*c, origin, [ew as usize, eh as usize]);
                }
            }
        });
        self.coords = coords;
        self.level_size = ls;
    }

    fn correct(
        &mut self,
        ex: &LevelExemplars,
        points: &[Vec<[i32; 2]>],
        passes: usize,
        coherence: f32,
        progress: &dyn Progress,
    ) {
        let ls = self.level_size;
        let m = self.views.len();
        self.points3 = voxel_offsets(self.views, points);
        let lw = self.weights.as_ref().expect("prepared");
        let n = ls.iter().product::<usize>();
        // The target of the matching: each exemplar's appearance with the
        // mean weight of its views.
        let mut mass = vec![0.0f64; ex.ex.len()];
        for (j, &e) in self.view_ex.iter().enumerate() {
            mass[e] += (0..n).map(|i| f64::from(lw.at(j, i))).sum::<f64>() / n as f64;
        }
        let sources: Vec<(&[f32], f64)> = ex
            .ex
            .iter()
            .zip(&mass)
            .map(|(e, &w)| (e.appearance.as_slice(), w))
            .collect();
        let matching = (self.histogram > 0.0).then(|| Matching::new(self.dims, &sources));
        let ctx = Level {
            size: ls,
            m,
            dims: self.dims,
            ex: &ex.ex,
            view_ex: self.view_ex,
            planes: self.views.iter().map(|v| v.axis.plane()).collect(),
            points2: points,
            points: &self.points3,
            cands: &ex.cands,
            weights: lw,
            matching,
            strength: self.histogram,
            coherence,
            index_histogram: self.index_histogram,
            phase: self.phase,
        };
        ctx.blend_all(&self.coords, &mut self.blend);
        for _ in 0..passes {
            for sub in SUB_PASSES {
                ctx.correct(&mut self.coords, &mut self.blend, &mut self.matched, sub);
                progress.advance(1);
            }
        }
    }
}

/// The coarsest level's start: every voxel and view a random exemplar pixel,
/// drawn by a hash of the voxel, the view and `seed` (a departure from
/// §5.1). The paper's `S(P) = P_{u,v}·h mod s_e` tiles each view's exemplar
/// along its plane; with the planes cyclic, any smooth gradient of the
/// exemplar then adds up, over the three views, to a function of `x + y + z`,
/// and the solid grows sheets across the (1, 1, 1) diagonal, seen on every
/// slice as streaks along one diagonal. Random starts have no such order;
/// the coarsest correction makes them coherent.
pub(super) fn initial(ls: [usize; 3], views: &[View], seed: u64) -> Vec<[u32; 2]> {
    let n = ls.iter().product::<usize>();
    (0..n)
        .into_par_iter()
        .flat_map_iter(|i| {
            let p = [
                (i % ls[0]) as i64,
                (i / ls[0] % ls[1]) as i64,
                (i / (ls[0] * ls[1])) as i64,
            ];
            views.iter().enumerate().map(move |(j, v)| {
                random_pixel(
                    p,
                    (v.exemplar.width, v.exemplar.height),
                    exemplar_seed(seed, j),
                )
            })
        })
        .collect()
}

/// Coordinate upsampling (eq. 4): a voxel takes its parent's coordinate plus
/// `h·Δ` of its parity in the view's plane; the parity along the view's own
/// axis adds nothing, so the two children across the view repeat the
/// coordinate.
pub(super) fn upsample(
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
    /// The histogram matching of the blend, and its strength.
    matching: Option<Matching>,
    strength: f32,
    coherence: f32,
    index_histogram: f32,
    phase: Option<Grid>,
}

/// Index histogram matching (after Chen and Wang 2010, "High quality solid
/// texture synthesis using position and index histogram matching"). Left
/// alone, the three views agree most easily on the exemplar's plain
/// regions, and thin features (veins) fade from the slices. So the volume's
/// uses of each exemplar pixel are counted from the coordinates before a
/// sub-pass, and a voxel's view scales a candidate's distance by
/// `1 + w·max(0, uses/even − 1)`, where `even` is the count if every pixel
/// were used alike. Pixels, not the level's `h`×`h` cells (Chen and Wang
/// count a level's own pixels): at coarse levels few voxels share many
/// pixels, so any reuse is penalised and the coarse layout spreads over the
/// whole exemplar; counted per cell, the slices' S_L fell about half as
/// much (ARCHITECTURE §11). The counts are integers over the whole volume,
/// so the choice stays independent of the threads.
struct Usage {
    weight: f32,
    /// Per distinct exemplar, the uses of each pixel (row-major).
    counts: Vec<Vec<u32>>,
    /// Per distinct exemplar: its width and `1 / even`.
    grid: Vec<(usize, f32)>,
}

/// Voxels per parallel chunk of the usage count.
const USAGE_CHUNK: usize = 1 << 15;

impl Usage {
    fn count(ctx: &Level, coords: &[[u32; 2]]) -> Self {
        let m = ctx.m;
        let voxels = ctx.size.iter().product::<usize>();
        let grid: Vec<(usize, f32)> = ctx
            .ex
            .iter()
            .enumerate()
            .map(|(e, ex)| {
                let views = ctx.view_ex.iter().filter(|&&v| v == e).count();
                let even = (voxels * views) as f32 / (ex.width * ex.height).max(1) as f32;
                (ex.width, if even > 0.0 { 1.0 / even } else { 0.0 })
            })
            .collect();
        let zero = || {
            ctx.ex
                .iter()
                .map(|ex| vec![0u32; ex.width * ex.height])
                .collect::<Vec<_>>()
        };
        let counts = coords
            .par_chunks(USAGE_CHUNK * m)
            .fold(zero, |mut acc, chunk| {
                for (t, c) in chunk.iter().enumerate() {
                    let e = ctx.view_ex[t % m];
                    acc[e][c[1] as usize * grid[e].0 + c[0] as usize] += 1;
                }
                acc
            })
            .reduce(zero, |mut a, b| {
                for (x, y) in a.iter_mut().zip(b) {
                    for (p, q) in x.iter_mut().zip(y) {
                        *p += q;
                    }
                }
                a
            });
        Self {
            weight: ctx.index_histogram,
            counts,
            grid,
        }
    }

    /// The factor of candidate `q` of exemplar `e`.
    #[inline]
    fn factor(&self, e: usize, q: [u32; 2]) -> f32 {
        let (w, inv_even) = self.grid[e];
        let uses = self.counts[e][q[1] as usize * w + q[0] as usize] as f32;
        1.0 + self.weight * (uses * inv_even - 1.0).max(0.0)
    }
}

impl Level<'_> {
    #[inline]
    fn index(&self, p: [i64; 3]) -> usize {
        let s = self.size;
        let [x, y, z] = [0, 1, 2].map(|a| wrap(p[a], s[a]));
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

    /// One sub-pass: the blend histogram-matched to the exemplars
    /// ([`Matching`]); then the voxels of parity `sub` take, in every view,
    /// the candidate whose exemplar neighbourhood best matches the matched
    /// blend's neighbourhood in the view's plane (eq. 5, eq. 3). Every voxel
    /// reads the blend and the coordinates as they were before the sub-pass
    /// (the voxels it reads have another parity, or are itself), so the
    /// result does not depend on the threads. The blend is then brought up
    /// to date at the voxels that changed.
    fn correct(
        &self,
        coords: &mut [[u32; 2]],
        blend: &mut [f32],
        matched: &mut Vec<f32>,
        sub: [usize; 3],
    ) {
        let [w, h, d] = self.size;
        let m = self.m;
        if let Some(mt) = &self.matching {
            mt.apply(blend, self.strength, matched);
        }
        let zs: Vec<usize> = (sub[2]..d).step_by(2).collect();
        let usage = (self.index_histogram > 0.0).then(|| Usage::count(self, coords));
        let usage = usage.as_ref();
        let updates: Vec<Vec<[u32; 2]>> = {
            let coords = &*coords;
            let gather: &[f32] = if self.matching.is_some() {
                matched
            } else {
                blend
            };
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
                                    out.push(self.best(p, i, j, coords, gather, usage, want, buf));
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
        usage: Option<&Usage>,
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
        let bases = exl.bases(|du, dv| {
            let mut q = p;
            q[u] += du;
            q[v] += dv;
            coords[self.index(q) * self.m + j]
        });
        exl.best_candidate(
            &bases,
            (*k, table),
            self.points2,
            (want, buf),
            coords[i * self.m + j],
            (self.coherence, |q| {
                if let Some(l) = &self.phase {
                    if !l.holds(q, [exl.h * p[u], exl.h * p[v]]) {
                        return None;
                    }
                }
                Some(usage.map_or(1.0, |u| u.factor(self.view_ex[j], q)))
            }),
        )
    }
}

/// Each view's neighbourhood `points` as voxel offsets in its plane (eq. 5).
fn voxel_offsets(views: &[View], points: &[Vec<[i32; 2]>]) -> Vec<Vec<Vec<[i64; 3]>>> {
    views
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
        .collect()
}
