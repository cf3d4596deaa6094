//! The finish of a run (Stahlhut §7, §9; ARCHITECTURE §3.7, §3.10): colour
//! rebuilt from the copy map of the finest level, optional chroma blur, and
//! the outputs and run report.

use std::time::Instant;

use anyhow::{Context, Result};

use super::canvas::Canvas;
use super::colour;
use super::plan::Plan;
use super::{LevelReport, Output, Report};
use crate::imaging::Gray;
use crate::search::SearchBackend;

/// Builds the outputs from the finished levels (`finished`, coarsest first)
/// and the finest level's sample luminance.
pub(super) fn finish(
    plan: &Plan,
    finished: &[Canvas],
    finest_sample_lum: Option<Gray>,
    per_level: Vec<LevelReport>,
    started: Instant,
    backend: &mut dyn SearchBackend,
) -> Result<Output> {
    let cfg = plan.cfg;
    let [cw, ch] = plan.canvas;
    let finest = finished.last().context("no level was synthesised")?;
    let finest_sample_lum = finest_sample_lum.context("no finest level")?;
    let colour_source = cfg
        .level_samples
        .iter()
        .find(|(k, _)| *k == 0)
        .map(|(_, img)| img)
        .unwrap_or(plan.reference);
    // A fill from another source keeps the photo's own pixels (their copy-map
    // entries point into the photo).
    let kept = (!std::ptr::eq(plan.reference, plan.sample)).then(|| plan.known[0].clone());
    let mut image = colour::rebuild_except(colour_source, &finest.copy, cw, ch, kept.as_deref())?;
    if let Some(kept) = &kept {
        for (i, _) in kept.iter().enumerate().filter(|(_, &k)| k) {
            let (x, y) = (i % cw, i / cw);
            image.set(x, y, plan.sample.get(x, y));
        }
    }
    if cfg.chroma_blur > 0 {
        colour::chroma_blur_borders(&mut image, &finest.copy, cfg.chroma_blur);
    }
    let luminance = Gray::from_vec(cw, ch, finest.lum.clone());
    debug_assert!(finest
        .copy
        .iter()
        .zip(&finest.lum)
        .enumerate()
        .filter(|(i, _)| kept.as_ref().is_none_or(|k| !k[*i]))
        .all(|(_, (c, &v))| finest_sample_lum.get(c[0] as usize, c[1] as usize) == v));
    let levels_out = finished
        .iter()
        .rev()
        .map(|c| Gray::from_vec(c.width, c.height, c.lum.clone()))
        .collect();
    let report = Report {
        mode: plan.mode_name.into(),
        canvas: [cw, ch],
        sample: [plan.sample.width, plan.sample.height],
        block: cfg.block,
        neighbourhood: cfg.neighbourhood,
        parent_window: plan.m,
        levels: plan.levels,
        weights: [cfg.weights.hi, cfg.weights.lo],
        metric: cfg.metric,
        tileable: cfg.tileable,
        seed: cfg.seed,
        batch: cfg.batch,
        search: backend.name(),
        lattice: cfg.lattice.map(|l| l.period),
        per_level,
        synthesis_seconds: started.elapsed().as_secs_f64(),
        search_stats: backend.stats(),
    };
    Ok(Output {
        image,
        luminance,
        copy_map: finest.copy.clone(),
        kept,
        sample_size: [colour_source.width, colour_source.height],
        levels: levels_out,
        report,
    })
}
