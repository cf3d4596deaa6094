//! `texsyn-worker bench`: throughput of the search kernel on this machine
//! (ARCHITECTURE §6). Prints GB/s of vector bytes scanned per core for single queries
//! and for batches, the dispatched kernel and queries per second.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use texsyn_engine::{
    Engine, EngineError, Hit, Kernel, Layout, Params, QueryBatch, Result, VectorSpace,
};

/// What to measure.
#[derive(Debug, Clone)]
pub struct BenchConfig {
    pub vectors: usize,
    /// Components of the hi part.
    pub dims: usize,
    /// Components of the lo part (0 = none).
    pub lo_dims: usize,
    pub queries: usize,
    pub threads: usize,
    pub kernel: Kernel,
    pub seed: u64,
    /// Share of query components that are defined (1.0 = all).
    pub defined: f64,
    /// Minimum time per measurement; the best repetition is reported.
    pub min_time: Duration,
    /// Raw u8 vectors (`vectors × (dims + lo_dims)` bytes) instead of random ones.
    pub vectors_file: Option<PathBuf>,
    /// Raw u8 queries (`queries × (dims + lo_dims)` bytes) instead of random ones.
    pub queries_file: Option<PathBuf>,
    /// Also write the batched answers (index, distance per line) here.
    pub answers_file: Option<PathBuf>,
}

impl Default for BenchConfig {
    fn default() -> Self {
        Self {
            vectors: 240_000,
            dims: 192,
            lo_dims: 0,
            queries: 64,
            threads: 1,
            kernel: Kernel::detect(),
            seed: 1,
            defined: 1.0,
            min_time: Duration::from_millis(1000),
            vectors_file: None,
            queries_file: None,
            answers_file: None,
        }
    }
}

/// One measured mode.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ModeReport {
    pub queries: usize,
    pub seconds: f64,
    /// Vector bytes compared per second per core (each query counts a full pass).
    pub gb_per_s_per_core: f64,
    pub queries_per_s: f64,
}

/// Everything the bench prints.
#[derive(Debug, Clone, serde::Serialize)]
pub struct BenchReport {
    pub kernel: Kernel,
    pub threads: usize,
    pub vectors: usize,
    pub dims: usize,
    pub stride: usize,
    pub space_bytes: usize,
    pub single: ModeReport,
    pub batched: ModeReport,
}

fn read_exact(path: &PathBuf, len: usize, what: &'static str) -> Result<Vec<u8>> {
    let data = std::fs::read(path).map_err(|e| {
        EngineError::Parameter(format!("cannot read {what} file {}: {e}", path.display()))
    })?;
    if data.len() != len {
        return Err(EngineError::Length {
            what,
            got: data.len(),
            expected: len,
        });
    }
    Ok(data)
}

fn time_best(min: Duration, mut f: impl FnMut() -> Result<()>) -> Result<f64> {
    let start = Instant::now();
    let mut best = f64::INFINITY;
    let mut reps = 0;
    while reps < 2 || start.elapsed() < min {
        let t = Instant::now();
        f()?;
        best = best.min(t.elapsed().as_secs_f64());
        reps += 1;
    }
    Ok(best)
}

/// Runs the benchmark and returns the figures; the answers of both modes are
/// checked to agree.
pub fn run(cfg: &BenchConfig) -> Result<BenchReport> {
    if cfg.vectors == 0 || cfg.queries == 0 || cfg.dims == 0 {
        return Err(EngineError::Parameter(
            "vectors, queries and dims must be ≥ 1".into(),
        ));
    }
    if !(0.0..=1.0).contains(&cfg.defined) {
        return Err(EngineError::Parameter(format!(
            "defined share {} is not in 0..=1",
            cfg.defined
        )));
    }
    cfg.kernel.check()?;
    let layout = Layout::checked(cfg.dims, cfg.lo_dims)?;
    let d = layout.dims();
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    let raw = match &cfg.vectors_file {
        Some(p) => read_exact(p, cfg.vectors * d, "vectors")?,
        None => (0..cfg.vectors * d).map(|_| rng.random()).collect(),
    };
    let qraw = match &cfg.queries_file {
        Some(p) => read_exact(p, cfg.queries * d, "queries")?,
        None => (0..cfg.queries * d).map(|_| rng.random()).collect(),
    };
    let space = VectorSpace::from_unpadded(layout, 0, &raw)?;
    drop(raw);
    let mut batch = QueryBatch::new(layout);
    for q in qraw.chunks(d) {
        let mask: Vec<u8> = (0..d)
            .map(|_| u8::from(rng.random_bool(cfg.defined)))
            .collect();
        batch.push(q, &mask)?;
    }
    let singles: Vec<QueryBatch> = (0..cfg.queries.min(8))
        .map(|q| {
            let mut b = QueryBatch::new(layout);
            let dims = layout.dims();
            let mut vals = vec![0u8; dims];
            let mut mask = vec![0u8; dims];
            vals[..layout.hi_len].copy_from_slice(&batch.values(q)[..layout.hi_len]);
            mask[..layout.hi_len].copy_from_slice(&batch.mask(q)[..layout.hi_len]);
            vals[layout.hi_len..]
                .copy_from_slice(&batch.values(q)[layout.hi_pad..layout.hi_pad + layout.lo_len]);
            mask[layout.hi_len..]
                .copy_from_slice(&batch.mask(q)[layout.hi_pad..layout.hi_pad + layout.lo_len]);
            b.push(&vals, &mask).map(|_| b)
        })
        .collect::<Result<_>>()?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(cfg.threads.max(1))
        .build()
        .map_err(|e| EngineError::Parameter(format!("thread pool: {e}")))?;
    let engine = Engine::new(cfg.kernel);
    let params = Params::default();
    let range = space.start()..space.end();
    let mut batched_hits: Vec<Hit> = Vec::new();
    let batched = pool.install(|| {
        time_best(cfg.min_time, || {
            batched_hits = engine.search_best(&space, range.clone(), &batch, &params)?;
            Ok(())
        })
    })?;
    let mut single_hits = Vec::new();
    let single = pool.install(|| {
        time_best(cfg.min_time, || {
            single_hits.clear();
            for b in &singles {
                single_hits.extend(engine.search_best(&space, range.clone(), b, &params)?);
            }
            Ok(())
        })
    })?;
    if single_hits[..] != batched_hits[..singles.len()] {
        return Err(EngineError::Parameter(
            "single and batched answers differ: kernel bug".into(),
        ));
    }
    if let Some(p) = &cfg.answers_file {
        let text: String = batched_hits
            .iter()
            .map(|h| format!("{} {}\n", h.index, h.dist))
            .collect();
        std::fs::write(p, text)
            .map_err(|e| EngineError::Parameter(format!("cannot write {}: {e}", p.display())))?;
    }
    let bytes = space.bytes() as f64;
    let cores = cfg.threads.max(1) as f64;
    let mode = |n: usize, secs: f64| ModeReport {
        queries: n,
        seconds: secs,
        gb_per_s_per_core: bytes * n as f64 / secs / cores / 1e9,
        queries_per_s: n as f64 / secs,
    };
    Ok(BenchReport {
        kernel: cfg.kernel,
        threads: cfg.threads.max(1),
        vectors: cfg.vectors,
        dims: d,
        stride: layout.stride(),
        space_bytes: space.bytes(),
        single: mode(singles.len(), single),
        batched: mode(cfg.queries, batched),
    })
}

impl std::fmt::Display for BenchReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "kernel {} | {} thread(s) | {} vectors × {} dims ({} B padded) = {:.1} MB",
            self.kernel.name(),
            self.threads,
            self.vectors,
            self.dims,
            self.stride,
            self.space_bytes as f64 / 1e6
        )?;
        for (name, m) in [("single", &self.single), ("batched", &self.batched)] {
            writeln!(
                f,
                "{name:>8}: {:>3} queries in {:.4} s | {:>7.2} GB/s per core | {:>9.1} queries/s",
                m.queries, m.seconds, m.gb_per_s_per_core, m.queries_per_s
            )?;
        }
        Ok(())
    }
}
