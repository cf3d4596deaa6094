//! Filling one level block by block (Stahlhut §4, §5; ARCHITECTURE §3.4):
//! pop a deterministic batch of blocks from the queue, search their
//! neighbourhoods, copy the best reference blocks, re-key the neighbours.

use std::time::Instant;

use anyhow::{ensure, Context, Result};
use rayon::prelude::*;
use texsyn_engine::{Geometry, Hit, Layout, Metric, Positions, QueryBatch, Slack};

use super::canvas::{set_pixel, Canvas};
use super::lattice;
use super::neighbourhood::{candidates, query, Shape};
use super::plan::LevelSample;
use super::queue::BlockQueue;
use super::repeats::{self, Offsets, RepeatControl, Usage};
use super::{Config, Progress, Stitch};
use crate::search::SearchBackend;

/// What filling a level reads besides the canvas it writes.
pub(super) struct LevelContext<'a> {
    /// The finished coarser level (`None` on the coarsest).
    pub parent: Option<&'a Canvas>,
    pub sample: &'a LevelSample,
    /// The search vector layout (luminance, or Y, Cb and Cr for colour search).
    pub layout: Layout,
    /// Reference block centres in the level sample, by reference index.
    pub positions: &'a Positions,
    pub geometry: &'a Geometry,
    pub cfg: &'a Config,
    /// Scan-line full synthesis: every block is searched and overwritten.
    pub scanline: bool,
    pub level: usize,
    pub levels: usize,
}

/// Search figures of one level, and where its time went.
#[derive(Default)]
pub(super) struct LevelStats {
    pub queries: u64,
    pub batches: u64,
    /// Wall time in the backend's search.
    pub search_seconds: f64,
    /// This process's engine's figures over those searches: thread time and
    /// sweeps (all zero when the search ran elsewhere).
    pub profile: texsyn_engine::Profile,
    /// Picking each batch's blocks from the queue.
    pub choose_seconds: f64,
    /// Building the batches' query vectors and candidates.
    pub query_seconds: f64,
    /// Copying the answers' blocks, stitching and re-keying the queue.
    pub copy_seconds: f64,
}

/// The canvas as B×B blocks in scan-line order; the last column and row of
/// blocks may be clipped by the canvas edge.
#[derive(Debug, Clone, Copy)]
struct Grid {
    b: usize,
    w: usize,
    h: usize,
    bw: usize,
    bh: usize,
}

impl Grid {
    fn new(canvas: &Canvas, b: usize) -> Self {
        let (w, h) = (canvas.width, canvas.height);
        Self {
            b,
            w,
            h,
            bw: w.div_ceil(b),
            bh: h.div_ceil(b),
        }
    }

    fn xy(&self, blk: u32) -> (usize, usize) {
        (blk as usize % self.bw, blk as usize / self.bw)
    }

    fn centre(&self, blk: u32) -> (isize, isize) {
        let (bx, by) = self.xy(blk);
        let b = self.b;
        ((bx * b + b / 2) as isize, (by * b + b / 2) as isize)
    }

    fn has_undefined(&self, c: &Canvas, blk: u32) -> bool {
        let (bx, by) = self.xy(blk);
        let (b, w, h) = (self.b, self.w, self.h);
        (by * b..(by * b + b).min(h))
            .any(|y| (bx * b..(bx * b + b).min(w)).any(|x| !c.defined[y * w + x]))
    }
}

/// Fills every undefined pixel of `canvas` (Stahlhut §4); in scan-line
/// synthesis every block, in scan-line order.
pub(super) fn fill_level(
    ctx: &LevelContext,
    canvas: &mut Canvas,
    backend: &mut dyn SearchBackend,
    progress: &dyn Progress,
) -> Result<LevelStats> {
    let (b, n) = (ctx.cfg.block, ctx.geometry.n);
    let grid = Grid::new(canvas, b);
    let mut queue = initial_queue(canvas, &grid, n, ctx.scanline);
    progress.start(
        &format!(
            "level {} ({}/{})",
            ctx.level,
            ctx.levels - ctx.level,
            ctx.levels
        ),
        queue.len() as u64,
        "blocks",
    );
    let shape = if ctx.scanline {
        Shape::Causal { block: b }
    } else {
        Shape::Symmetric
    };
    let dims = ctx.layout.dims();
    let mut stats = LevelStats::default();
    let mut batcher = Batcher::new(canvas, ctx.cfg.batch, n);
    let rekey_radius = ((n / 2 + b / 2) / b + 1) as isize;
    // Pixels known before the search (placed sample, kept photo, seed) are
    // never re-stitched.
    let stitch = (ctx.cfg.stitch == Stitch::Path && !ctx.scanline)
        .then(|| (canvas.defined.clone(), stitch_band(b, n)))
        .filter(|(_, o)| *o > 0);
    // Repetition control: what is known before the search counts as used
    // (or, under the patch cap, as covered by its offset).
    let (sw, sh) = (ctx.sample.lum.width, ctx.sample.lum.height);
    // The patch cap leaves the coarse levels, which lay out the structure,
    // to the exact best match.
    let control = ctx
        .cfg
        .repeats
        .filter(|r| r.cap.is_none() || ctx.level < repeats::CAP_LEVELS);
    // The lattice rule asks for near-ties as the control does, more of them.
    let grid_rule = ctx.cfg.lattice;
    let near_ties = control.or(grid_rule.map(|_| RepeatControl {
        candidates: lattice::CANDIDATES,
        percent: lattice::PERCENT,
        ..RepeatControl::default()
    }));
    // The lattice runs through the offset of the first known pixel.
    let origin = grid_rule
        .and_then(|_| (0..canvas.defined.len()).find(|&k| canvas.defined[k]))
        .map_or([0, 0], |k| {
            let [sx, sy] = canvas.copy[k];
            [
                (k % canvas.width) as i64 - i64::from(sx),
                (k / canvas.width) as i64 - i64::from(sy),
            ]
        });
    let known: Vec<([usize; 2], [u32; 2])> = match control {
        Some(_) => (0..canvas.defined.len())
            .filter(|&k| canvas.defined[k])
            .map(|k| ([k % canvas.width, k / canvas.width], canvas.copy[k]))
            .collect(),
        None => Vec::new(),
    };
    let mut usage = control.filter(|r| r.cap.is_none()).map(|_| {
        let mut u = Usage::new(sw, sh);
        for &(_, [x, y]) in &known {
            u.add(x as usize, y as usize);
        }
        u
    });
    let mut offsets = control.and_then(|r| r.cap).map(|percent| {
        let mut o = Offsets::new(sw, sh, percent);
        for &(at, from) in &known {
            o.add(at, from, 1);
        }
        o
    });
    while !queue.is_empty() {
        let t = Instant::now();
        batcher.choose(&mut queue, &grid);
        stats.choose_seconds += t.elapsed().as_secs_f64();
        let t = Instant::now();
        let mut batch = QueryBatch::new(ctx.layout);
        // Each block's query read from the canvas in parallel, pushed in order.
        let built: Vec<(Vec<u8>, Vec<u8>, Vec<u64>)> = {
            let canvas = &*canvas;
            batcher
                .centres
                .par_iter()
                .map(|&(cx, cy)| {
                    let (mut values, mut mask) = (vec![0u8; dims], vec![0u8; dims]);
                    query(
                        canvas,
                        ctx.parent,
                        cx,
                        cy,
                        n,
                        ctx.geometry.m,
                        shape,
                        &mut values,
                        &mut mask,
                    );
                    (values, mask, candidates(canvas, cx, cy, n, ctx.positions))
                })
                .collect()
        };
        for (values, mask, cands) in built {
            batch.push(&values, &mask)?;
            batch.set_candidates(batch.len() - 1, cands);
        }
        let chosen = &batcher.chosen;
        stats.query_seconds += t.elapsed().as_secs_f64();
        let (t, before) = (Instant::now(), texsyn_engine::Profile::now());
        let lists = match &near_ties {
            Some(r) => {
                let slack: Vec<Slack> =
                    (0..batch.len()).map(|q| slack(ctx, r, &batch, q)).collect();
                backend.search_near_ties(&batch, r.candidates, &slack)?
            }
            None => backend
                .search(&batch)?
                .into_iter()
                .map(|h| vec![h])
                .collect(),
        };
        stats.search_seconds += t.elapsed().as_secs_f64();
        let spent = texsyn_engine::Profile::now().since(&before);
        stats.profile.add(&spent);
        let t = Instant::now();
        ensure!(
            lists.len() == chosen.len(),
            "search returned {} answers for {} queries",
            lists.len(),
            chosen.len()
        );
        stats.queries += chosen.len() as u64;
        stats.batches += 1;
        // The pixels the copies will define, for re-keying their neighbours.
        let newly: Vec<Vec<(isize, isize)>> = if ctx.scanline {
            Vec::new()
        } else {
            chosen
                .iter()
                .map(|&blk| undefined_in(canvas, &grid, blk))
                .collect()
        };
        for (&blk, hits) in chosen.iter().zip(&lists) {
            // The seam filter's bands of the picked reference, kept for its
            // stitch (copying the block leaves the bands outside it as they are).
            let mut picked_bands = None;
            let centre = {
                let (x, y) = grid.centre(blk);
                [x as usize, y as usize]
            };
            // Each near-tie's stitch bands and seam error (path stitching).
            let seams = |hits: &[Hit]| {
                stitch.as_ref().map(|(known, band)| {
                    let sides: Vec<Option<Vec<Side>>> = hits
                        .iter()
                        .map(|h| {
                            ctx.positions
                                .get(h.index)
                                .map(|p| bands(canvas, &grid, blk, p, ctx, known, *band))
                        })
                        .collect();
                    let costs: Vec<f64> = sides
                        .iter()
                        .map(|s| s.as_deref().map_or(f64::INFINITY, seam_error))
                        .collect();
                    (sides, costs)
                })
            };
            let hit = match (&usage, &offsets, &control, &grid_rule) {
                (_, _, _, Some(l)) => lattice::pick(hits, |h| {
                    ctx.positions.get(h.index).map_or(u32::MAX, |p| {
                        let offset = [
                            centre[0] as i64 - i64::from(p[0]),
                            centre[1] as i64 - i64::from(p[1]),
                        ];
                        l.phase_error(offset, origin, ctx.level)
                    })
                }),
                (_, Some(o), Some(_), _) => {
                    let at_cap = |h: &Hit| {
                        ctx.positions
                            .get(h.index)
                            .is_none_or(|p| o.at_cap(centre, p))
                    };
                    let seams = seams(hits);
                    let hit =
                        repeats::pick_capped(hits, seams.as_ref().map(|(_, c)| &c[..]), at_cap);
                    picked_bands = seams.and_then(|(sides, _)| bands_of(hits, hit, sides));
                    hit
                }
                (Some(u), _, Some(r), _) => {
                    let block_use = |h: &Hit| {
                        ctx.positions
                            .get(h.index)
                            .map_or(u64::MAX, |p| u.block(p, b))
                    };
                    // The bands are only stitched in the head for the filter.
                    match r.seam.and_then(|p| seams(hits).map(|s| (p, s))) {
                        Some((percent, (sides, costs))) => {
                            let hit = repeats::pick_within_seam(hits, &costs, percent, block_use);
                            picked_bands = bands_of(hits, hit, sides);
                            hit
                        }
                        None => repeats::pick(hits, block_use),
                    }
                }
                _ => hits.first().copied(),
            }
            .context("search returned no answer")?;
            let pos = ctx.positions.get(hit.index).with_context(|| {
                format!(
                    "search answered index {} of {} references",
                    hit.index,
                    ctx.positions.len()
                )
            })?;
            copy_block(canvas, &grid, blk, pos, ctx, usage.as_mut());
            if let Some(o) = offsets.as_mut() {
                o.add(centre, pos, (b * b) as u64);
            }
            if let Some((known, band)) = &stitch {
                let sides = picked_bands
                    .unwrap_or_else(|| bands(canvas, &grid, blk, pos, ctx, known, *band));
                stitch_block(canvas, ctx, sides, *band);
            }
            queue.remove(blk);
        }
        if !ctx.scanline {
            rekey(&mut queue, canvas, &grid, chosen, &newly, n, rekey_radius);
        }
        stats.copy_seconds += t.elapsed().as_secs_f64();
        progress.advance(chosen.len() as u64);
    }
    progress.finish();
    tracing::info!(level = ctx.level, "level done");
    Ok(stats)
}

/// Every block with an undefined pixel, keyed by the undefined pixels of its
/// N×N window; in scan-line synthesis every block with key 0.
fn initial_queue(canvas: &Canvas, grid: &Grid, n: usize, scanline: bool) -> BlockQueue {
    let mut queue = BlockQueue::new(grid.bw * grid.bh, (n * n) as u32);
    for blk in 0..(grid.bw * grid.bh) as u32 {
        if scanline {
            queue.set(blk, 0);
        } else if grid.has_undefined(canvas, blk) {
            let (cx, cy) = grid.centre(blk);
            queue.set(blk, canvas.undefined_in_window(cx, cy, n));
        }
    }
    queue
}

/// Picks the blocks of one search batch from the head of the queue.
struct Batcher {
    batch: usize,
    scan_limit: usize,
    /// Window side N: two windows overlap when their centres are closer.
    reach: isize,
    wrap: bool,
    w: isize,
    h: isize,
    chosen: Vec<u32>,
    centres: Vec<(isize, isize)>,
    examined: Vec<(isize, isize)>,
}

impl Batcher {
    fn new(canvas: &Canvas, batch: usize, n: usize) -> Self {
        Self {
            batch,
            scan_limit: batch.saturating_mul(8).max(64),
            reach: n as isize,
            wrap: canvas.wrap,
            w: canvas.width as isize,
            h: canvas.height as isize,
            chosen: Vec::with_capacity(batch),
            centres: Vec::with_capacity(batch),
            examined: Vec::new(),
        }
    }

    /// Windows of blocks in one batch must not overlap, so the batch's result
    /// does not depend on the order of its copies (ARCHITECTURE §3.4).
    fn overlaps(&self, a: (isize, isize), c: (isize, isize)) -> bool {
        let (mut dx, mut dy) = ((a.0 - c.0).abs(), (a.1 - c.1).abs());
        if self.wrap {
            dx = dx.min(self.w - dx);
            dy = dy.min(self.h - dy);
        }
        dx < self.reach && dy < self.reach
    }

    /// Fills `chosen` and `centres`. A block joins the batch only if its window
    /// overlaps no block examined before it (taken or skipped), so no block goes
    /// before a higher-priority block it depends on; for K = 1 this is the
    /// paper's strict order.
    fn choose(&mut self, queue: &mut BlockQueue, grid: &Grid) {
        self.chosen.clear();
        self.centres.clear();
        self.examined.clear();
        for blk in queue.iter().take(self.scan_limit) {
            let c = grid.centre(blk);
            if self.examined.iter().all(|&o| !self.overlaps(o, c)) {
                self.chosen.push(blk);
                self.centres.push(c);
                if self.chosen.len() == self.batch {
                    break;
                }
            }
            self.examined.push(c);
        }
    }
}

/// Copies the reference block centred at `pos` into block `blk`: only its
/// undefined pixels, or all of them in scan-line synthesis.
/// The stitch bands of the picked `hit`, of those computed for the near-ties
/// `hits` (kept for its stitch).
fn bands_of(
    hits: &[Hit],
    hit: Option<Hit>,
    mut sides: Vec<Option<Vec<Side>>>,
) -> Option<Vec<Side>> {
    let h = hit?;
    let i = hits.iter().position(|x| x.index == h.index)?;
    sides.swap_remove(i)
}

fn copy_block(
    canvas: &mut Canvas,
    grid: &Grid,
    blk: u32,
    pos: [u32; 2],
    ctx: &LevelContext,
    mut usage: Option<&mut Usage>,
) {
    let (b, w, h) = (grid.b, grid.w, grid.h);
    let (bx, by) = grid.xy(blk);
    let (rx, ry) = (pos[0] as usize - b / 2, pos[1] as usize - b / 2);
    for j in 0..b {
        let y = by * b + j;
        if y >= h {
            break;
        }
        for i in 0..b {
            let x = bx * b + i;
            if x >= w {
                break;
            }
            let k = y * w + x;
            if ctx.scanline || !canvas.defined[k] {
                set_pixel(canvas, k, ctx.sample, rx + i, ry + j);
                if let Some(u) = usage.as_deref_mut() {
                    u.add(rx + i, ry + j);
                }
            }
        }
    }
}

/// Repetition control's slack of query `q`: `slack` grey levels per known
/// component, weighted as the distance weighs them (squared under L2), and
/// `percent` of the best distance.
fn slack(ctx: &LevelContext, r: &RepeatControl, batch: &QueryBatch, q: usize) -> Slack {
    let mask = batch.mask(q);
    let l = ctx.layout;
    let known = |m: &[u8]| m.iter().filter(|&&m| m != 0).count() as u64;
    let (hi, lo) = (
        known(&mask[..l.hi_len]),
        known(&mask[l.hi_pad..l.hi_pad + l.lo_len]),
    );
    let w = ctx.cfg.weights;
    let per = match ctx.cfg.metric {
        Metric::L1 => u64::from(r.slack),
        Metric::L2 => u64::from(r.slack).pow(2),
    };
    Slack {
        absolute: (u64::from(w.hi) * hi + u64::from(w.lo) * lo) * per,
        per_mille: r.percent * 10,
    }
}

/// Width of the band a copied block may extend into: what its reference
/// window still covers beyond the block, (N − B)/2, at most
/// [`MAX_STITCH_BAND`] pixels.
fn stitch_band(b: usize, n: usize) -> usize {
    ((n - b) / 2).min(MAX_STITCH_BAND)
}

/// The widest stitching band (ARCHITECTURE §3.12). `synth`'s default N = 13
/// with B = 5 reaches it; at 3 (the N = 11 band) the same N = 13 runs were
/// ahead of the peer on the Laplacian histogram on 20 of 22 samples, at 4 on
/// 21, with patch fidelity on 21 either way; a wider band needs N ≥ 15, which
/// lost S_L on 5.
const MAX_STITCH_BAND: usize = 4;

/// The stitching bands of the reference block at `pos` copied into block
/// `blk` (ARCHITECTURE §3.12): up to four sides, each `band` pixels wide and
/// one block long outside the block, with the optimal path over the
/// luminance error of continuing the reference into each cell. A side is left out if any band pixel is
/// outside the canvas, not yet defined or known before the search.
fn bands(
    canvas: &Canvas,
    grid: &Grid,
    blk: u32,
    pos: [u32; 2],
    ctx: &LevelContext,
    known: &[bool],
    band: usize,
) -> Vec<Side> {
    use crate::seams::ErrorMap;
    let b = grid.b;
    let (bx, by) = grid.xy(blk);
    let (x0, y0) = ((bx * b) as isize, (by * b) as isize);
    let (rx, ry) = (
        pos[0] as isize - (b / 2) as isize,
        pos[1] as isize - (b / 2) as isize,
    );
    // The block's extent (clipped at the canvas edge).
    let bw = b.min(grid.w - bx * b) as isize;
    let bh = b.min(grid.h - by * b) as isize;
    let ls = ctx.sample;
    let (sw, sh) = (ls.lum.width as isize, ls.lum.height as isize);
    // Per side: (offset of canonical (i, j) from the block origin), length.
    type Offset = fn(isize, isize, isize, isize) -> (isize, isize);
    let sides: [(Offset, isize); 4] = [
        (|i, j, _, _| (-1 - i, j), bh),
        (|i, j, w, _| (w + i, j), bh),
        (|i, j, _, _| (j, -1 - i), bw),
        (|i, j, _, h| (j, h + i), bw),
    ];
    let mut out = Vec::new();
    for (offset, along) in sides {
        let mut cells = Vec::with_capacity(band * along as usize);
        let mut ok = true;
        let mut src_out = false;
        'scan: for j in 0..along {
            for i in 0..band as isize {
                let (dx, dy) = offset(i, j, bw, bh);
                let Some(k) = canvas.index(x0 + dx, y0 + dy) else {
                    ok = false;
                    break 'scan;
                };
                let (sx, sy) = (rx + dx, ry + dy);
                let inside = sx >= 0 && sy >= 0 && sx < sw && sy < sh;
                let source_defined = inside
                    && ls
                        .defined
                        .as_ref()
                        .is_none_or(|d| d[(sy * sw + sx) as usize]);
                if !canvas.defined[k] || known[k] {
                    ok = false;
                    break 'scan;
                }
                if !source_defined {
                    ok = false;
                    src_out = true;
                    break 'scan;
                }
                cells.push((k, sx as usize, sy as usize));
            }
        }
        if src_out {
            out.push(Side::SourceOut(along as usize));
            continue;
        }
        if !ok || cells.is_empty() {
            continue;
        }
        let e = cells
            .iter()
            .map(|&(k, sx, sy)| f32::from(canvas.lum[k].abs_diff(ls.lum.get(sx, sy))))
            .collect();
        let map = ErrorMap::new(band, along as usize, e);
        let path = crate::seams::optimal(&map);
        let cost = path.cost(&map);
        out.push(Side::Band { cells, path, cost });
    }
    out
}

/// One side of a copied block's stitching band.
enum Side {
    /// The band's cells (canvas index, sample x, y), row by row; the optimal
    /// path over the error of continuing the reference into each, and the
    /// path's error.
    Band {
        cells: Vec<(usize, usize, usize)>,
        path: crate::seams::Path,
        cost: f64,
    },
    /// The reference's continuation leaves the sample after `along` rows: the
    /// block keeps its square edge there.
    SourceOut(usize),
}

/// Grey-level error charged per row of a side whose reference continuation
/// leaves the sample (a square edge, no path).
const SQUARE_EDGE_ERROR: f64 = 64.0;

/// The error along the seams a reference block would leave if copied and
/// stitched, from its `bands` (repetition control's seam filter,
/// ARCHITECTURE §3.13): the optimal path's error on each side, and
/// `SQUARE_EDGE_ERROR` per row of a side that cannot be stitched.
fn seam_error(sides: &[Side]) -> f64 {
    sides
        .iter()
        .map(|s| match s {
            Side::Band { cost, .. } => *cost,
            Side::SourceOut(along) => SQUARE_EDGE_ERROR * *along as f64,
        })
        .sum()
}

/// Extends the block just copied, whose `bands` are `sides`, into the already
/// synthesised pixels around it, up to a minimum-error path (ARCHITECTURE §3.12; Somol–Haindl §2.1).
/// Each side is a band `band` pixels wide and one block long outside the
/// block; the error is the luminance difference between the canvas and the
/// block's reference continued into the band; the optimal path over it
/// decides, per row, how far the reference continues. Pixels are copied whole
/// from the sample, so the copy map stays exact (no blending). A side is left
/// as it is if any band pixel is outside the canvas, not yet defined, known
/// before the search, or has no defined reference pixel. Bands stay inside the
/// block's N×N window, which no other block of the batch overlaps, so the
/// result does not depend on the order of the batch's copies.
fn stitch_block(canvas: &mut Canvas, ctx: &LevelContext, sides: Vec<Side>, band: usize) {
    let ls = ctx.sample;
    for side in sides {
        let Side::Band { cells, path, .. } = side else {
            continue;
        };
        for (j, &c) in path.c.iter().enumerate() {
            for &(k, sx, sy) in &cells[j * band..=j * band + c] {
                set_pixel(canvas, k, ls, sx, sy);
            }
        }
    }
}

/// The undefined pixels of block `blk`.
fn undefined_in(canvas: &Canvas, grid: &Grid, blk: u32) -> Vec<(isize, isize)> {
    let (bx, by) = grid.xy(blk);
    let b = grid.b;
    (by * b..(by * b + b).min(grid.h))
        .flat_map(|y| (bx * b..(bx * b + b).min(grid.w)).map(move |x| (x, y)))
        .filter(|&(x, y)| !canvas.defined[y * grid.w + x])
        .map(|(x, y)| (x as isize, y as isize))
        .collect()
}

/// Re-keys the queued blocks within `radius` blocks of the `copied` ones
/// (Stahlhut §4: a copy changes its neighbours' undefined counts): each key
/// drops by the pixels `newly` defined inside its window, which equals
/// recounting the window. Where a wrapped canvas is narrower than a window or
/// than the block neighbourhood (a window would meet a pixel twice), the
/// windows are recounted.
fn rekey(
    queue: &mut BlockQueue,
    canvas: &Canvas,
    grid: &Grid,
    copied: &[u32],
    newly: &[Vec<(isize, isize)>],
    n: usize,
    radius: isize,
) {
    let (bw, bh) = (grid.bw as isize, grid.bh as isize);
    let (w, h) = (canvas.width as isize, canvas.height as isize);
    let r = (n / 2) as isize;
    let span = 2 * radius + 1;
    let recount = canvas.wrap && (w < n as isize || h < n as isize || bw < span || bh < span);
    // Whether coordinate `p` lies within `r` of `c` on an axis of `size`.
    let near = |p: isize, c: isize, size: isize| {
        if canvas.wrap {
            let d = (p - c).rem_euclid(size);
            d <= r || d >= size - r
        } else {
            (p - c).abs() <= r
        }
    };
    for (&blk, px) in copied.iter().zip(newly) {
        let (bx, by) = grid.xy(blk);
        let (bx, by) = (bx as isize, by as isize);
        for dy in -radius..=radius {
            for dx in -radius..=radius {
                let (mut nx, mut ny) = (bx + dx, by + dy);
                if canvas.wrap {
                    nx = nx.rem_euclid(bw);
                    ny = ny.rem_euclid(bh);
                } else if nx < 0 || ny < 0 || nx >= bw || ny >= bh {
                    continue;
                }
                let nb = (ny as usize * grid.bw + nx as usize) as u32;
                let Some(key) = queue.key(nb) else { continue };
                let (cx, cy) = grid.centre(nb);
                let fresh = if recount {
                    canvas.undefined_in_window(cx, cy, n)
                } else {
                    let gone = px
                        .iter()
                        .filter(|&&(x, y)| near(x, cx, w) && near(y, cy, h))
                        .count() as u32;
                    if gone == 0 {
                        continue;
                    }
                    key.checked_sub(gone)
                        .unwrap_or_else(|| canvas.undefined_in_window(cx, cy, n))
                };
                queue.set(nb, fresh);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The band is what the window covers beyond the block, up to 4 pixels:
    /// 3 at the paper's N = 11, 4 at `synth`'s N = 13, and never past the
    /// window, which no other block of a batch overlaps.
    #[test]
    fn the_stitching_band_widens_with_the_window_up_to_four_pixels() {
        assert_eq!(stitch_band(5, 11), 3);
        assert_eq!(stitch_band(5, 13), 4);
        assert_eq!(stitch_band(5, 21), 4);
        assert_eq!(stitch_band(3, 7), 2);
        for b in (1..=11).step_by(2) {
            for n in (b + 2..=31).step_by(2) {
                let band = stitch_band(b, n);
                assert!(band <= (n - b) / 2 && band <= 4, "B {b}, N {n}: {band}");
            }
        }
    }

    proptest! {
        /// Lowering the neighbours' keys by the pixels a batch defines gives
        /// the keys of recounting every window, on plain and wrapped canvases
        /// of any size, with part of the canvas known beforehand.
        #[test]
        fn rekeying_by_the_copied_pixels_equals_recounting(
            (w, h) in (1usize..48, 1usize..48),
            wrap in any::<bool>(),
            (b, n) in prop_oneof![Just((5usize, 11usize)), Just((3, 7)), Just((4, 9)), Just((2, 5))],
            known in proptest::collection::vec(any::<bool>(), 48 * 48),
            picks in proptest::collection::vec(any::<proptest::sample::Index>(), 1..6),
        ) {
            let mut canvas = Canvas::new(w, h, wrap);
            for (d, &k) in canvas.defined.iter_mut().zip(&known) {
                *d = k;
            }
            let grid = Grid::new(&canvas, b);
            let mut queue = initial_queue(&canvas, &grid, n, false);
            let radius = ((n / 2 + b / 2) / b + 1) as isize;
            let queued: Vec<u32> = (0..(grid.bw * grid.bh) as u32).filter(|&k| queue.contains(k)).collect();
            prop_assume!(!queued.is_empty());
            let mut copied: Vec<u32> = picks.iter().map(|i| queued[i.index(queued.len())]).collect();
            copied.sort_unstable();
            copied.dedup();
            let newly: Vec<Vec<(isize, isize)>> =
                copied.iter().map(|&blk| undefined_in(&canvas, &grid, blk)).collect();
            for px in &newly {
                for &(x, y) in px {
                    canvas.defined[y as usize * w + x as usize] = true;
                }
            }
            for &blk in &copied {
                queue.remove(blk);
            }
            rekey(&mut queue, &canvas, &grid, &copied, &newly, n, radius);
            for blk in 0..(grid.bw * grid.bh) as u32 {
                if let Some(key) = queue.key(blk) {
                    let (cx, cy) = grid.centre(blk);
                    prop_assert_eq!(key, canvas.undefined_in_window(cx, cy, n), "block {}", blk);
                }
            }
        }
    }
}
