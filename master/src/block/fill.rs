//! Filling one level block by block (Stahlhut §4, §5; ARCHITECTURE §3.4):
//! pop a deterministic batch of blocks from the queue, search their
//! neighbourhoods, copy the best reference blocks, re-key the neighbours.

use std::time::Instant;

use anyhow::{ensure, Context, Result};
use texsyn_engine::{Geometry, Layout, Positions, QueryBatch};

use super::canvas::{set_pixel, Canvas};
use super::neighbourhood::{candidates, query, Shape};
use super::plan::LevelSample;
use super::queue::BlockQueue;
use super::{Config, Progress};
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

/// Search figures of one level.
pub(super) struct LevelStats {
    pub queries: u64,
    pub batches: u64,
    pub search_seconds: f64,
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
    progress.level_start(ctx.level, ctx.levels, queue.len() as u64);
    let shape = if ctx.scanline {
        Shape::Causal { block: b }
    } else {
        Shape::Symmetric
    };
    let dims = ctx.layout.dims();
    let (mut values, mut mask) = (vec![0u8; dims], vec![0u8; dims]);
    let mut stats = LevelStats {
        queries: 0,
        batches: 0,
        search_seconds: 0.0,
    };
    let mut batcher = Batcher::new(canvas, ctx.cfg.batch, n);
    let rekey_radius = ((n / 2 + b / 2) / b + 1) as isize;
    while !queue.is_empty() {
        batcher.choose(&mut queue, &grid);
        let mut batch = QueryBatch::new(ctx.layout);
        for &(cx, cy) in &batcher.centres {
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
            batch.push(&values, &mask)?;
            let cands = candidates(canvas, cx, cy, n, ctx.positions);
            batch.set_candidates(batch.len() - 1, cands);
        }
        let chosen = &batcher.chosen;
        let t = Instant::now();
        let hits = backend.search(&batch)?;
        stats.search_seconds += t.elapsed().as_secs_f64();
        ensure!(
            hits.len() == chosen.len(),
            "search returned {} answers for {} queries",
            hits.len(),
            chosen.len()
        );
        stats.queries += chosen.len() as u64;
        stats.batches += 1;
        for (&blk, hit) in chosen.iter().zip(&hits) {
            let pos = ctx.positions.get(hit.index).with_context(|| {
                format!(
                    "search answered index {} of {} references",
                    hit.index,
                    ctx.positions.len()
                )
            })?;
            copy_block(canvas, &grid, blk, pos, ctx);
            queue.remove(blk);
        }
        if !ctx.scanline {
            rekey(&mut queue, canvas, &grid, chosen, n, rekey_radius);
        }
        progress.advance(chosen.len() as u64);
    }
    progress.level_end(ctx.level);
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
fn copy_block(canvas: &mut Canvas, grid: &Grid, blk: u32, pos: [u32; 2], ctx: &LevelContext) {
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
            }
        }
    }
}

/// Re-keys the queued blocks within `radius` blocks of the copied ones.
fn rekey(
    queue: &mut BlockQueue,
    canvas: &Canvas,
    grid: &Grid,
    copied: &[u32],
    n: usize,
    radius: isize,
) {
    let (bw, bh) = (grid.bw as isize, grid.bh as isize);
    for &blk in copied {
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
                if queue.contains(nb) {
                    let (cx, cy) = grid.centre(nb);
                    queue.set(nb, canvas.undefined_in_window(cx, cy, n));
                }
            }
        }
    }
}
