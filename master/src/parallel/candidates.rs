//! k-coherence candidate sets (Tong et al., as Lefebvre and Hoppe use them;
//! Manke–Wünsche §3): for every exemplar pixel, the exemplar pixels whose
//! appearance is most alike, found once per level by the engine's exact
//! all-pairs top-k search, so the correction compares only a handful of
//! candidates per pixel.
//!
//! The search goes through [`SearchBackend`], locally or on the cluster, so
//! the sets are the same bytes on any number of threads or workers. The
//! engine compares square windows of a plane, so each reference vector, the
//! first [`SEARCH_DIMS`] appearance components quantised to bytes, is laid
//! out as one 3×3 cell of a plane and searched as a window of that size: the
//! window's distance is the vectors'. Spaces this small are searched through
//! the engine's k-d tree, whose answers are the exhaustive scan's.
//!
//! Every pixel is a query and every pixel a reference, up to
//! [`EXACT_PIXELS`] per level; above, a grid of pixels (see there). Each pixel's set is
//! itself first (the coherent candidate), then its nearest references in
//! (distance, index) order, passing over any within the level's near-duplicate
//! radius of one already taken. Since every pixel has its own list, a
//! candidate's phase is free: nothing ties it to its query's position modulo
//! a grid (on a gridded large level, a candidate keeps its pixel's phase
//! modulo the stride, which the random start of [`super::coords`] leaves
//! free in the output).

use anyhow::{ensure, Result};
use rayon::prelude::*;
use texsyn_engine::{Geometry, Plane, QueryBatch, Sample};

use crate::progress::Progress;
use crate::search::{LevelData, SearchBackend};

/// Largest k.
pub const MAX_K: usize = 16;
/// Appearance components the sets are searched on (the paper's appearance
/// space keeps 8; one 3×3 cell holds 9).
pub const SEARCH_DIMS: usize = 9;
/// Side of the plane cell one vector occupies.
const CELL: usize = 3;
/// Most pixels of a level whose sets are searched exactly, every pixel
/// against every pixel. A larger level (an exemplar over 512²) is searched
/// on a grid of the smallest stride that fits, queries and references alike,
/// and pixel `q` takes its grid pixel `g`'s list shifted by `q − g` (the
/// shift of k-coherence itself): the exact search of a 1024² level took
/// minutes on 2 cores. The stride is at least the level's near-duplicate
/// radius: on a level blurred over `h` pixels the pixels within `h/2` of one
/// another are one candidate, so a reference per such square keeps every
/// candidate a set could take (a 1024² exemplar's blurred levels: strides 4
/// to 64 where 2 searched 262 144 vectors each).
pub const EXACT_PIXELS: usize = 512 * 512;
/// Queries per batch handed to the backend.
const BATCH: usize = 8192;
/// Every this many distinct vectors, one is searched to choose the first
/// pass of a sharp level (see [`Candidates::search`]).
const SAMPLE_EVERY: usize = 64;
/// The short first pass is taken when at most one sampled set in this many
/// falls short of k.
const SHORT_SHARE: usize = 20;

/// The candidate sets of one exemplar level: `k` per pixel, row by row.
pub struct Candidates {
    k: usize,
    stride: usize,
    width: usize,
    height: usize,
    table: Vec<[u32; 2]>,
}

/// How a level's sets are searched: the reference grid's stride and the
/// near-duplicate radius.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Spacing {
    /// Stride of the reference grid (1: every pixel).
    pub stride: usize,
    /// A candidate within this Chebyshev distance (wrapping) of one already
    /// taken is passed over.
    pub radius: u32,
}

impl Spacing {
    /// The spacing of the stack level of step `h`: every pixel a reference,
    /// near-duplicates within `max(2, h/2)` pixels (on a level blurred over
    /// `h` pixels, closer pixels are the same candidate).
    pub fn of_step(h: usize) -> Self {
        Self {
            stride: 1,
            radius: (h / 2).max(2) as u32,
        }
    }
}

/// What decides one level's sets: the level's appearance vectors (`dims`
/// each, row by row, `size` pixels), the spacing and k. The search's input,
/// and the key of [`super::cache`].
pub struct SetsOf<'a> {
    pub appearance: &'a [f32],
    pub size: (usize, usize),
    pub dims: usize,
    pub spacing: Spacing,
    pub k: usize,
}

impl Candidates {
    /// Searches the sets of `of`. `level` names the level to the backend.
    pub fn search(
        of: &SetsOf<'_>,
        level: usize,
        backend: &mut dyn SearchBackend,
        progress: &dyn Progress,
    ) -> Result<Self> {
        let SetsOf {
            appearance,
            size: (width, height),
            dims,
            spacing,
            k,
        } = *of;
        ensure!((1..=MAX_K).contains(&k), "k must be in 1..={MAX_K}");
        ensure!(appearance.len() == width * height * dims, "appearance size");
        let stride = grid_stride((width, height), spacing);
        let (grid_w, grid_h) = (width.div_ceil(stride), height.div_ceil(stride));
        let used = dims.min(SEARCH_DIMS);
        let (lo, hi) = appearance
            .chunks_exact(dims)
            .flat_map(|v| &v[..used])
            .fold((f32::MAX, f32::MIN), |(a, b), &v| (a.min(v), b.max(v)));
        let scale = if hi > lo { 255.0 / (hi - lo) } else { 0.0 };
        let cell_of = |i: usize| -> [u8; CELL * CELL] {
            let mut c = [0u8; CELL * CELL];
            for (slot, &a) in c.iter_mut().zip(&appearance[i * dims..i * dims + used]) {
                *slot = ((a - lo) * scale).round().clamp(0.0, 255.0) as u8;
            }
            c
        };
        // Cells sit `CELL + 1` apart with a line of undefined pixels between
        // them, so the only windows clear of undefined pixels, the reference
        // positions a worker derives from the plane, are the cells.
        let pitch = CELL + 1;
        let (pw, ph) = (grid_w * pitch, grid_h * pitch);
        let mut pixels = vec![0u8; pw * ph];
        let mut defined = vec![0u8; pw * ph];
        for gy in 0..grid_h {
            for gx in 0..grid_w {
                let c = cell_of(gy * stride * width + gx * stride);
                for r in 0..CELL {
                    let at = (gy * pitch + r) * pw + gx * pitch;
                    pixels[at..at + CELL].copy_from_slice(&c[r * CELL..(r + 1) * CELL]);
                    defined[at..at + CELL].fill(1);
                }
            }
        }
        let geometry = Geometry::new(CELL, 0)?;
        let fine = Plane::new(pw, ph, &pixels, Some(&defined))?;
        let sample = Sample { fine, parent: None };
        let positions = texsyn_engine::plane::reference_positions(&sample, &geometry)?;
        // Row by row, so reference g is grid pixel (g mod grid_w, g / grid_w).
        ensure!(
            positions.len() == grid_w * grid_h,
            "{} cells gave {} reference windows",
            grid_w * grid_h,
            positions.len()
        );
        backend.load_level(&LevelData::single_plane(
            level,
            level + 1,
            geometry,
            fine,
            &positions,
            (grid_w * grid_h) as u64,
        )?)?;
        // Enough neighbours that the near-duplicates passed over leave k.
        let extra = (4 * k + 8).min(grid_w * grid_h);
        let radius = spacing.radius;
        let size = (width as u32, height as u32);
        // The queries: the grid pixels (every pixel at stride 1). Pixels
        // with the same quantised vector have the same neighbours (on a
        // blurred level, many): each distinct vector is searched once, in the
        // order first met.
        let n = width * height;
        let mut distinct: std::collections::HashMap<[u8; CELL * CELL], u32> =
            std::collections::HashMap::new();
        let mut vectors: Vec<[u8; CELL * CELL]> = Vec::new();
        let mut first: Vec<usize> = Vec::new();
        let of_grid: Vec<u32> = (0..grid_w * grid_h)
            .map(|g| {
                let c = cell_of((g / grid_w) * stride * width + (g % grid_w) * stride);
                *distinct.entry(c).or_insert_with(|| {
                    vectors.push(c);
                    first.push(g);
                    (vectors.len() - 1) as u32
                })
            })
            .collect();
        drop(distinct);
        let search = |backend: &mut dyn SearchBackend,
                      which: &[usize],
                      want: usize,
                      report: bool|
         -> Result<Vec<Vec<u32>>> {
            let mut lists = Vec::with_capacity(which.len());
            for chunk in which.chunks(BATCH) {
                let mut batch = QueryBatch::new(geometry.layout());
                for (j, &v) in chunk.iter().enumerate() {
                    batch.push_full(&vectors[v])?;
                    batch.set_candidates(j, window_of(first[v], (grid_w, grid_h), extra));
                }
                for hits in backend.search_topk(&batch, want)? {
                    lists.push(hits.iter().map(|h| h.index as u32).collect());
                }
                if report {
                    progress.advance(chunk.len() as u64);
                }
            }
            Ok(lists)
        };
        let grid_pos = |g: usize| {
            [
                ((g % grid_w) * stride) as u32,
                ((g / grid_w) * stride) as u32,
            ]
        };
        // Whether the list of grid pixel `g` (of its vector) holds a whole set.
        let whole = |g: usize, list: &[u32]| {
            let refs = list.iter().map(|&r| grid_pos(r as usize));
            apart(grid_pos(g), refs, k, radius, size).len() == k
        };
        // Two passes, one answer. A pixel's set takes the first k entries of
        // its list that are apart (`set_of`), so when the first `first_k`
        // nearest already give k, the rest of the `extra` cannot change it:
        // every vector is searched for its `first_k` nearest (a smaller ball,
        // a cheaper proof), and only those whose sets fall short at some grid
        // pixel are searched again for all `extra`. The sets are the ones a
        // single search for `extra` gives, whatever `first_k` is; it only
        // decides the time:
        // - where a pixel's own near-duplicate square on the grid holds
        //   `2k + 4` pixels or more (the blurred levels), its nearest are
        //   mostly those and nearly every set would need the second pass: one
        //   pass for `extra` there;
        // - else `k + 4` when a sample of every [`SAMPLE_EVERY`]-th vector
        //   falls short at most once in [`SHORT_SHARE`] (the sharpest
        //   levels), and `2k + 4` otherwise.
        let dup_side = 2 * (radius as usize / stride) + 1;
        let first_k = if dup_side * dup_side >= 2 * k + 4 {
            extra
        } else {
            let sample: Vec<usize> = (0..vectors.len()).step_by(SAMPLE_EVERY).collect();
            let lists = search(backend, &sample, k + 4, false)?;
            let short = sample
                .iter()
                .zip(&lists)
                .filter(|(&v, l)| !whole(first[v], l))
                .count();
            tracing::debug!(
                short,
                sample = sample.len(),
                "k-coherence first pass sampled"
            );
            if short * SHORT_SHARE <= sample.len() {
                k + 4
            } else {
                2 * k + 4
            }
        }
        .min(extra);
        let all: Vec<usize> = (0..vectors.len()).collect();
        progress.start("k-coherence sets", vectors.len() as u64, "pixels");
        let mut lists = search(backend, &all, first_k, true)?;
        progress.finish();
        let mut again: Vec<usize> = (0..grid_w * grid_h)
            .into_par_iter()
            .filter(|_| first_k < extra)
            .filter_map(|g| {
                let v = of_grid[g] as usize;
                (!whole(g, &lists[v])).then_some(v)
            })
            .collect();
        again.sort_unstable();
        again.dedup();
        if !again.is_empty() {
            progress.start("k-coherence sets, wider", again.len() as u64, "pixels");
            for (v, list) in again.iter().zip(search(backend, &again, extra, true)?) {
                lists[*v] = list;
            }
            progress.finish();
        }
        tracing::debug!(first_k, extra, again = again.len(), "k-coherence passes");
        let short = lists.iter().filter(|l| l.len() < k).count();
        tracing::debug!(
            short,
            pixels = n,
            distinct = vectors.len(),
            references = grid_w * grid_h,
            "k-coherence queries"
        );
        let table: Vec<[u32; 2]> = (0..n)
            .into_par_iter()
            .flat_map_iter(|i| {
                let (x, y) = (i % width, i / width);
                // The grid pixel at or before q, and q's shift from it.
                let (gx, gy) = (x / stride, y / stride);
                let (dx, dy) = ((x - gx * stride) as u32, (y - gy * stride) as u32);
                let refs = lists[of_grid[gy * grid_w + gx] as usize].iter().map(|&g| {
                    let g = g as usize;
                    [
                        (((g % grid_w) * stride) as u32 + dx) % size.0,
                        (((g / grid_w) * stride) as u32 + dy) % size.1,
                    ]
                });
                set_of([x as u32, y as u32], refs, k, radius, size)
            })
            .collect();
        backend.end_level();
        Ok(Self {
            k,
            stride,
            width,
            height,
            table,
        })
    }

    /// Sets read back from a cache ([`super::cache`]): `k` per pixel of a
    /// `size` level, row by row, searched on a grid of `stride`.
    pub(super) fn from_parts(
        k: usize,
        stride: usize,
        size: (usize, usize),
        table: Vec<[u32; 2]>,
    ) -> Self {
        debug_assert_eq!(table.len(), size.0 * size.1 * k);
        Self {
            k,
            stride,
            width: size.0,
            height: size.1,
            table,
        }
    }

    /// Every pixel's candidates, row by row, `k` slots each.
    pub fn entries(&self) -> &[[u32; 2]] {
        &self.table
    }

    /// Stride of the reference grid (1 = every pixel a reference).
    pub fn stride(&self) -> usize {
        self.stride
    }

    /// Every pixel's candidates, row by row, `k` slots each (a short set
    /// repeats its first entry, which changes no choice).
    pub fn table(self) -> Vec<[u32; 2]> {
        self.table
    }

    /// k of the sets.
    pub fn k(&self) -> usize {
        self.k
    }

    /// The candidates of pixel `q`.
    pub fn of(&self, q: [u32; 2]) -> &[[u32; 2]] {
        let i = (q[1] as usize * self.width + q[0] as usize) * self.k;
        &self.table[i..i + self.k]
    }

    /// Size of the level.
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }
}

/// The stride of the grid a `size` level with `spacing` is searched on:
/// the spacing's, or on a level over [`EXACT_PIXELS`] the smallest that
/// fits and at least the near-duplicate radius.
fn grid_stride((width, height): (usize, usize), spacing: Spacing) -> usize {
    let large = ((width * height) as f64 / EXACT_PIXELS as f64)
        .sqrt()
        .ceil() as usize;
    let large = if large > 1 {
        large.max(spacing.radius as usize)
    } else {
        large
    };
    spacing.stride.max(large).clamp(1, width.min(height))
}

/// The smallest square window of grid pixels around grid pixel `g`
/// (wrapping, `g` included) that holds `n` pixels: on a coherent level its
/// nearest neighbours in appearance are among them, so their distances give
/// the search a tight first cut (the answer is the same without it).
fn window_of(g: usize, (gw, gh): (usize, usize), n: usize) -> Vec<u64> {
    let mut r = 0i64;
    while ((2 * r + 1) * (2 * r + 1)) < n as i64 {
        r += 1;
    }
    let (x, y) = ((g % gw) as i64, (g / gw) as i64);
    let mut out = Vec::with_capacity(((2 * r + 1) * (2 * r + 1)) as usize);
    for dy in -r..=r {
        for dx in -r..=r {
            let nx = (x + dx).rem_euclid(gw as i64) as u64;
            let ny = (y + dy).rem_euclid(gh as i64) as u64;
            out.push(ny * gw as u64 + nx);
        }
    }
    out
}

/// Chebyshev distance between two pixels of a `size` torus.
pub fn torus_distance(a: [u32; 2], b: [u32; 2], size: (u32, u32)) -> u32 {
    let axis = |p: u32, q: u32, n: u32| {
        let d = p.abs_diff(q);
        d.min(n - d)
    };
    axis(a[0], b[0], size.0).max(axis(a[1], b[1], size.1))
}

/// The set of pixel `q` from its references in order: `q` first, then each
/// reference farther than `radius` from all taken, `k` in all; a short set
/// is filled up with `q`.
fn set_of(
    q: [u32; 2],
    refs: impl Iterator<Item = [u32; 2]>,
    k: usize,
    radius: u32,
    size: (u32, u32),
) -> Vec<[u32; 2]> {
    let mut out = apart(q, refs, k, radius, size);
    out.resize(k, q);
    out
}

/// `q`, then each reference farther than `radius` from all taken, until
/// there are `k` (fewer when the references run out).
fn apart(
    q: [u32; 2],
    refs: impl Iterator<Item = [u32; 2]>,
    k: usize,
    radius: u32,
    size: (u32, u32),
) -> Vec<[u32; 2]> {
    let mut out = Vec::with_capacity(k);
    out.push(q);
    for c in refs {
        if out.len() == k {
            break;
        }
        if out.iter().all(|&o| torus_distance(o, c, size) > radius) {
            out.push(c);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::search::LocalSearch;
    use proptest::prelude::*;
    use texsyn_engine::Engine;

    fn random_appearance(n: usize, seed: u32) -> Vec<f32> {
        let mut s = seed;
        (0..n)
            .map(|_| {
                s = s.wrapping_mul(1_103_515_245).wrapping_add(12345);
                ((s >> 16) % 64) as f32 / 64.0 * 10.0 - 5.0
            })
            .collect()
    }

    /// A smooth field with a little noise: a pixel's nearest vectors are
    /// mostly its own near-duplicates, so sets need the wider second pass.
    fn smooth_appearance(w: usize, h: usize, dims: usize) -> Vec<f32> {
        let noise = random_appearance(w * h * dims, 777);
        (0..w * h * dims)
            .map(|i| {
                let (p, d) = (i / dims, (i % dims) as f32);
                let (x, y) = ((p % w) as f32, (p / w) as f32);
                5.0 * (0.08 * x * (1.0 + 0.1 * d) + 0.11 * y + d).sin() + 0.02 * noise[i]
            })
            .collect()
    }

    /// The sets against a brute-force scan of the quantised vectors over
    /// every reference of the grid, near-duplicates passed over: on a noisy
    /// and on a smooth level, whose sets need more than the first pass's
    /// `2k + 4` nearest.
    #[test]
    fn the_sets_are_the_exact_nearest_vectors() {
        let (w, h, dims, k) = (80, 60, 12, 5);
        let grid = Spacing {
            stride: 3,
            radius: 2,
        };
        let mut widened = 0;
        for (app, spacing) in [
            (random_appearance(w * h * dims, 12345), Spacing::of_step(1)),
            (random_appearance(w * h * dims, 12345), Spacing::of_step(8)),
            (random_appearance(w * h * dims, 12345), grid),
            (smooth_appearance(w, h, dims), Spacing::of_step(1)),
            (smooth_appearance(w, h, dims), grid),
            // Two passes (a 3×3 near-duplicate square), many sets widened.
            (
                smooth_appearance(w, h, dims),
                Spacing {
                    stride: 1,
                    radius: 1,
                },
            ),
        ] {
            let mut backend = LocalSearch::new(Engine::default());
            let of = SetsOf {
                appearance: &app,
                size: (w, h),
                dims,
                spacing,
                k,
            };
            let c = Candidates::search(&of, 0, &mut backend, &crate::progress::Silent).unwrap();
            assert_eq!(c.stride(), spacing.stride);
            let probes = (0..w * h).step_by(37).chain([17, 555, 1199, 4799]);
            widened += check_sets(&c, &app, (w, h), dims, spacing, probes);
        }
        assert!(widened > 0, "no checked set needed the second pass");
    }

    /// Checks the sets of `c` at the pixels `probes` against a brute-force
    /// scan of the quantised vectors of `app` over every reference of the
    /// grid, near-duplicates passed over; returns how many of them needed
    /// more than the first pass's `2k + 4` nearest.
    fn check_sets(
        c: &Candidates,
        app: &[f32],
        (w, h): (usize, usize),
        dims: usize,
        spacing: Spacing,
        probes: impl Iterator<Item = usize>,
    ) -> usize {
        let (k, stride) = (c.k, c.stride());
        let used: Vec<f32> = app
            .chunks_exact(dims)
            .flat_map(|v| v[..SEARCH_DIMS].to_vec())
            .collect();
        let (lo, hi) = used
            .iter()
            .fold((f32::MAX, f32::MIN), |(a, b), &v| (a.min(v), b.max(v)));
        let q = |v: f32| ((v - lo) * 255.0 / (hi - lo)).round().clamp(0.0, 255.0) as i64;
        let dist = |a: usize, b: usize| -> i64 {
            (0..SEARCH_DIMS)
                .map(|d| (q(used[a * SEARCH_DIMS + d]) - q(used[b * SEARCH_DIMS + d])).pow(2))
                .sum()
        };
        let refs: Vec<usize> = (0..h)
            .step_by(stride)
            .flat_map(|y| (0..w).step_by(stride).map(move |x| y * w + x))
            .collect();
        let mut widened = 0;
        for p in probes {
            let (x, y) = (p % w, p / w);
            // The grid pixel the query is searched from, and the shift.
            let g = y / stride * stride * w + x / stride * stride;
            let (dx, dy) = (x % stride, y % stride);
            let mut all: Vec<(i64, usize)> = refs
                .iter()
                .enumerate()
                .map(|(i, &r)| (dist(g, r), i))
                .collect();
            all.sort();
            let pos = [x as u32, y as u32];
            let nearest = |n: usize| {
                all.iter().take(n).map(|&(_, i)| {
                    let r = refs[i];
                    [((r % w + dx) % w) as u32, ((r / w + dy) % h) as u32]
                })
            };
            let size = (w as u32, h as u32);
            let want = set_of(pos, nearest(4 * k + 8), k, spacing.radius, size);
            assert_eq!(c.of(pos), &want[..], "pixel {p}");
            assert_eq!(c.of(pos)[0], pos);
            widened +=
                usize::from(apart(pos, nearest(2 * k + 4), k, spacing.radius, size).len() < k);
        }
        widened
    }

    /// A level over [`EXACT_PIXELS`] is gridded at the smallest stride that
    /// fits, or at its near-duplicate radius where that is coarser; a
    /// smaller level keeps its spacing's stride.
    #[test]
    fn a_large_level_is_gridded_at_its_near_duplicate_radius() {
        let big = (1024, 257);
        assert_eq!(grid_stride(big, Spacing::of_step(1)), 2);
        assert_eq!(grid_stride(big, Spacing::of_step(4)), 2);
        assert_eq!(grid_stride(big, Spacing::of_step(16)), 8);
        assert_eq!(grid_stride((2048, 2048), Spacing::of_step(8)), 4);
        assert_eq!(grid_stride((2048, 2048), Spacing::of_step(1)), 4);
        assert_eq!(grid_stride((512, 512), Spacing::of_step(64)), 1);
        assert_eq!(grid_stride((4096, 128), Spacing::of_step(512)), 128);
        // The sets of the coarser grid are still the exact nearest of its
        // references, shifted to each pixel.
        let (dims, k) = (9, 4);
        let app = random_appearance(big.0 * big.1 * dims, 4242);
        let spacing = Spacing::of_step(16);
        let of = SetsOf {
            appearance: &app,
            size: big,
            dims,
            spacing,
            k,
        };
        let mut backend = LocalSearch::new(Engine::default());
        let c = Candidates::search(&of, 0, &mut backend, &crate::progress::Silent).unwrap();
        assert_eq!(c.stride(), 8);
        let probes = (0..big.0 * big.1).step_by(4099).chain([1, 8 * 1024 + 9]);
        check_sets(&c, &app, big, dims, spacing, probes);
    }

    proptest! {
        /// A set starts with its pixel, and any two distinct entries lie
        /// farther apart than the radius.
        #[test]
        fn sets_keep_their_entries_apart(
            refs in proptest::collection::vec((0u32..40, 0u32..30), 0..60),
            k in 1usize..=MAX_K,
            radius in 0u32..6,
            q in (0u32..40, 0u32..30),
        ) {
            let q = [q.0, q.1];
            let set = set_of(q, refs.iter().map(|&(x, y)| [x, y]), k, radius, (40, 30));
            prop_assert_eq!(set.len(), k);
            prop_assert_eq!(set[0], q);
            for (i, a) in set.iter().enumerate() {
                for b in &set[i + 1..] {
                    prop_assert!(a == b || torus_distance(*a, *b, (40, 30)) > radius);
                }
            }
        }
    }
}
