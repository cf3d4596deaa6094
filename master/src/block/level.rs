//! One pyramid level of a run (Stahlhut §4, §6; ARCHITECTURE §3.2–§3.4, §3.8):
//! seed the canvas with the known pixels, hand the level's reference vectors
//! to the search backend, fill the canvas block by block, report.

use std::time::Instant;

use anyhow::{bail, Result};
use texsyn_engine::layout::reference_positions;
use texsyn_engine::{Geometry, Layout};

use super::canvas::{self, Canvas};
use super::fill::{fill_level, LevelContext};
use super::neighbourhood::colour_vectors;
use super::plan::Plan;
use super::{LevelReport, Progress, SweepReport};
use crate::imaging::Gray;
use crate::pyramid;
use crate::search::{LevelData, SearchBackend};

/// A finished level.
pub(super) struct Level {
    pub canvas: Canvas,
    pub report: LevelReport,
    /// The level's sample luminance (the copy map points into it).
    pub sample_lum: Gray,
}

/// Synthesises level `l`; `parent` is the finished coarser level (`None` on
/// the coarsest).
pub(super) fn run_level(
    plan: &mut Plan,
    l: usize,
    parent: Option<&Canvas>,
    backend: &mut dyn SearchBackend,
    progress: &dyn Progress,
) -> Result<Level> {
    let level_started = Instant::now();
    let cfg = plan.cfg;
    let (n, levels) = (cfg.neighbourhood, plan.levels);
    let coarsest = l == levels - 1;
    let scanline = plan.placement.is_none();
    let ls = plan.level_sample(l);
    let (lw, lh) = pyramid::level_size(plan.canvas[0], plan.canvas[1], l);
    let mut canvas = Canvas::new(lw, lh, cfg.tileable);
    if cfg.colour_search {
        canvas = canvas.with_chroma();
    }
    let photo = plan.photo_level(l);
    canvas::seed_level(
        &mut canvas,
        plan.placement,
        &plan.known[l],
        photo.as_ref().unwrap_or(&ls),
        l,
        &mut plan.rng,
    );

    let geometry = Geometry::new(n, if coarsest { 0 } else { plan.m })?;
    let masks = ls.mask_bytes();
    let sample_planes = ls.planes(&masks, coarsest)?;
    let positions = reference_positions(&sample_planes, &geometry)?;
    if positions.is_empty() {
        bail!(
            "level {l}: no {n}×{n} neighbourhood of the {}×{} level sample is fully known; use fewer --levels, a smaller --neighbourhood or a smaller hole",
            ls.lum.width,
            ls.lum.height
        );
    }
    let build_started = Instant::now();
    let colour = if cfg.colour_search {
        let lm = if coarsest { 0 } else { plan.m };
        let layout = Layout::new(3 * n * n, 3 * lm * lm);
        Some((layout, colour_vectors(&ls, &positions, n, lm)?))
    } else {
        None
    };
    backend.load_level(&LevelData {
        level: l,
        geometry,
        params: plan.params,
        sample: sample_planes,
        positions: &positions,
        levels,
        expected_queries: expected_queries(&canvas, cfg.block, scanline),
        colour_vectors: colour.as_ref().map(|(l, v)| (*l, v.as_slice())),
    })?;
    let build_seconds = build_started.elapsed().as_secs_f64();

    let ctx = LevelContext {
        parent,
        sample: &ls,
        layout: colour
            .as_ref()
            .map_or_else(|| geometry.layout(), |(layout, _)| *layout),
        positions: &positions,
        geometry: &geometry,
        cfg,
        scanline,
        level: l,
        levels,
    };
    let stats = fill_level(&ctx, &mut canvas, backend, progress)?;
    let prune = backend.level_prune();
    backend.end_level();
    let threads = rayon::current_num_threads();
    let busy = (stats.profile.busy > 0).then_some(stats.profile.busy as f64 * 1e-9);
    tracing::info!(
        level = l,
        search = stats.search_seconds,
        idle = busy.map(|b| 1.0 - b / (threads as f64 * stats.search_seconds).max(1e-12)),
        choose = stats.choose_seconds,
        queries = stats.query_seconds,
        copy = stats.copy_seconds,
        "level time"
    );
    progress.note(&format!(
        "level {l}: {} queries in {} batches; search {:.3} s{} on {threads} threads{}, choose {:.3} s, queries {:.3} s, copy {:.3} s",
        stats.queries,
        stats.batches,
        stats.search_seconds,
        busy.map(|b| format!(" ({:.0}% idle)", 100.0 * (1.0 - b / (threads as f64 * stats.search_seconds).max(1e-12)).max(0.0)))
            .unwrap_or_default(),
        SweepReport::of(&stats.profile)
            .map(|w| format!(
                " (before the sweeps {:.3} s; in them {:.3} s, with {:.3} thread-s idle before a thread's first part and {:.3} after its last)",
                w.prep_seconds, w.wall_seconds, w.lag_thread_seconds, w.tail_thread_seconds
            ))
            .unwrap_or_default(),
        stats.choose_seconds,
        stats.query_seconds,
        stats.copy_seconds
    ));
    let report = LevelReport {
        level: l,
        canvas: [lw, lh],
        sample: [ls.lum.width, ls.lum.height],
        reference_vectors: positions.len(),
        vector_bytes: positions.len() as u64 * ctx.layout.stride() as u64,
        queries: stats.queries,
        batches: stats.batches,
        build_seconds,
        search_seconds: stats.search_seconds,
        total_seconds: level_started.elapsed().as_secs_f64(),
        choose_seconds: stats.choose_seconds,
        query_seconds: stats.query_seconds,
        copy_seconds: stats.copy_seconds,
        threads,
        search_busy_seconds: busy,
        search_idle_share: busy.map(|b| {
            let offered = threads as f64 * stats.search_seconds;
            if offered > 0.0 {
                (1.0 - b / offered).max(0.0)
            } else {
                0.0
            }
        }),
        sweeps: SweepReport::of(&stats.profile),
        prune,
        pairs_skipped: prune.map(|p| p.pairs_skipped()),
        components_skipped: prune.map(|p| p.components_skipped()),
    };
    Ok(Level {
        canvas,
        report,
        sample_lum: ls.lum,
    })
}

/// How many queries the level will ask (for the backend's planning): one per
/// block of undefined pixels, or every block in scan-line synthesis.
fn expected_queries(canvas: &Canvas, b: usize, scanline: bool) -> u64 {
    let undefined = canvas.defined.iter().filter(|&&d| !d).count();
    undefined.div_ceil(b * b).max(if scanline {
        canvas.width.div_ceil(b) * canvas.height.div_ceil(b)
    } else {
        0
    }) as u64
}
