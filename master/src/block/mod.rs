//! Stahlhut's multi-scale block method (Stahlhut §4–§9; ARCHITECTURE §3).
//!
//! Levels are processed coarsest first. On each level the canvas starts with
//! the pixels known there (the placed sample, the unmasked photo, the seed
//! patch or, for full synthesis, noise), the block list is keyed by undefined
//! neighbourhood pixels, and blocks are filled by copying the best-matching
//! reference block. Finer levels compare a second, low-resolution part taken
//! from the finished coarser level. Colour is rebuilt from the copy map.
//!
//! [`synthesize`] runs three steps: `plan` (checks, levels, pyramids, the known
//! part of the canvas), `level` once per level (with `fill`, the block loop)
//! and `finish` (colour and report). The other modules are the method's parts:
//! `config` (what to make), `canvas`, `queue`, `neighbourhood`, `pyramid` and
//! `colour`.

use std::time::Instant;

use anyhow::Result;
use texsyn_engine::Metric;

use crate::imaging::{ColorImage, Gray};
use crate::search::SearchBackend;

pub mod canvas;
pub mod colour;
mod config;
mod fill;
mod finish;
mod lattice;
mod level;
pub mod neighbourhood;
mod plan;
pub mod queue;
mod repeats;

pub use crate::lattice::Lattice;
pub use config::{
    growth_neighbourhood, Config, FillSource, Mode, Position, Stitch, SynthMethod,
    LATTICE_WITH_REPEATS, MAX_CANVAS_PIXELS, PATH_GROWTH_NEIGHBOURHOOD,
};
pub use plan::resolve_levels;
pub use repeats::RepeatControl;

pub use crate::progress::{Progress, Silent};

/// Figures of one level for the run report.
#[derive(Debug, Clone, serde::Serialize)]
pub struct LevelReport {
    pub level: usize,
    pub canvas: [usize; 2],
    pub sample: [usize; 2],
    pub reference_vectors: usize,
    /// Bytes of the level's padded reference vectors (on this machine or
    /// spread over the workers).
    pub vector_bytes: u64,
    pub queries: u64,
    pub batches: u64,
    pub build_seconds: f64,
    pub search_seconds: f64,
    pub total_seconds: f64,
    /// Where the level's time went besides the search: picking each batch
    /// from the queue, building its queries, copying the answers (with
    /// stitching and re-keying).
    pub choose_seconds: f64,
    pub query_seconds: f64,
    pub copy_seconds: f64,
    /// Threads of this process's search pool.
    pub threads: usize,
    /// Thread time in this process's engine during the searches, and the share
    /// of `threads × search_seconds` it leaves idle (waiting for the slowest
    /// part, or outside the parallel section). `None` when the search ran on
    /// workers only.
    pub search_busy_seconds: Option<f64>,
    pub search_idle_share: Option<f64>,
    /// Inside this process's searches: how the keyed sweeps spent their wall
    /// time. `None` when no sweep ran here.
    pub sweeps: Option<SweepReport>,
    /// What pruning saved (ARCHITECTURE §3.5), where the backend counts it:
    /// pairs scored and abandoned, chunks of components computed.
    pub prune: Option<texsyn_engine::PruneStats>,
    /// Share of (vector, query) pairs abandoned before their last component.
    pub pairs_skipped: Option<f64>,
    /// Share of the component work a full scan does that was skipped.
    pub components_skipped: Option<f64>,
}

/// The keyed sweeps of a level on this process's search threads: the wall
/// time before them (each query's start from its candidates and its seed),
/// inside their parallel sections, and the thread time those sections left
/// idle before a thread's first part (lag) and after its last (tail).
#[derive(Debug, Clone, serde::Serialize)]
pub struct SweepReport {
    pub sweeps: u64,
    pub prep_seconds: f64,
    pub wall_seconds: f64,
    pub lag_thread_seconds: f64,
    pub tail_thread_seconds: f64,
}

impl SweepReport {
    pub fn of(p: &texsyn_engine::Profile) -> Option<Self> {
        (p.sweeps > 0).then_some(Self {
            sweeps: p.sweeps,
            prep_seconds: p.prep as f64 * 1e-9,
            wall_seconds: p.sweep_wall as f64 * 1e-9,
            lag_thread_seconds: p.sweep_lag as f64 * 1e-9,
            tail_thread_seconds: p.sweep_tail as f64 * 1e-9,
        })
    }
}

/// The machine-readable run report.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Report {
    pub mode: String,
    pub canvas: [usize; 2],
    pub sample: [usize; 2],
    pub block: usize,
    pub neighbourhood: usize,
    pub parent_window: usize,
    pub levels: usize,
    pub weights: [u32; 2],
    pub metric: Metric,
    pub tileable: bool,
    pub seed: u64,
    pub batch: usize,
    pub search: String,
    /// The lattice phase's periods (`--lattice`, given or found), if on.
    pub lattice: Option<[f64; 2]>,
    pub per_level: Vec<LevelReport>,
    pub synthesis_seconds: f64,
    /// What the search backend reports (plan used, workers, LBG codebooks).
    pub search_stats: serde_json::Value,
}

/// Everything a run produces.
pub struct Output {
    pub image: ColorImage,
    pub luminance: Gray,
    /// Per output pixel, its source coordinate in the finest sample (in the
    /// fill source for a fill from another source, except where `kept`).
    pub copy_map: Vec<[u32; 2]>,
    /// A fill from another source: the photo's pixels kept as they are (their
    /// copy-map entry is their own coordinate in the photo). `None` otherwise.
    pub kept: Option<Vec<bool>>,
    pub sample_size: [usize; 2],
    /// Finished luminance per level, finest first.
    pub levels: Vec<Gray>,
    pub report: Report,
}

/// Runs the synthesis with `backend` doing the searches.
pub fn synthesize(
    sample: &ColorImage,
    mode: &Mode,
    cfg: &Config,
    backend: &mut dyn SearchBackend,
    progress: &dyn Progress,
) -> Result<Output> {
    cfg.validate()?;
    let started = Instant::now();
    let mut plan = plan::Plan::new(sample, mode, cfg)?;
    let mut per_level = Vec::new();
    let mut finished: Vec<canvas::Canvas> = Vec::new(); // coarsest first
    let mut finest_sample_lum = None;
    for l in (0..plan.levels).rev() {
        let parent = if l == plan.levels - 1 {
            None
        } else {
            finished.last()
        };
        let done = level::run_level(&mut plan, l, parent, backend, progress)?;
        per_level.push(done.report);
        if l == 0 {
            finest_sample_lum = Some(done.sample_lum);
        }
        finished.push(done.canvas);
    }
    finish::finish(
        &plan,
        &finished,
        finest_sample_lum,
        per_level,
        started,
        backend,
    )
}
