//! `texsyn-bench kernel`: throughput of the search kernel on this machine
//! (ARCHITECTURE §6). Prints GB/s of vector bytes scanned per core for single
//! queries and for batches, the dispatched kernel and queries per second.
//! `bench/faiss_compare.py` runs it on raw files with `--json`.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{bail, ensure, Context, Result};
use clap::Args;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use texsyn_engine::{Engine, Hit, Kernel, Layout, Params, QueryBatch, VectorSpace};

#[derive(Args, Debug)]
pub struct KernelArgs {
    /// Number of reference vectors.
    #[arg(long, default_value_t = 240_000)]
    vectors: usize,
    /// Components per vector (hi part).
    #[arg(long, default_value_t = 192)]
    dims: usize,
    /// Components of the lo (parent) part.
    #[arg(long, default_value_t = 0)]
    lo_dims: usize,
    /// Queries per batch.
    #[arg(long, default_value_t = 64)]
    queries: usize,
    /// Rayon threads (GB/s are reported per thread).
    #[arg(long, default_value_t = 1)]
    threads: usize,
    /// Kernel: auto, scalar, avx2, avx512.
    #[arg(long, default_value = "auto")]
    kernel: String,
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Share of query components defined (masks), 0..=1.
    #[arg(long, default_value_t = 1.0)]
    defined: f64,
    /// Minimum seconds per measurement (best repetition reported), 0..=3600.
    #[arg(long, default_value_t = 1.0, value_parser = min_time)]
    min_time: f64,
    /// Raw u8 vector file (`vectors × (dims + lo-dims)` bytes) instead of random vectors.
    #[arg(long)]
    vectors_file: Option<PathBuf>,
    /// Raw u8 query file (`queries × (dims + lo-dims)` bytes) instead of random queries.
    #[arg(long)]
    queries_file: Option<PathBuf>,
    /// Write the batched answers ("index distance" per line) to this file.
    #[arg(long)]
    answers_file: Option<PathBuf>,
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
}

/// One measured mode.
#[derive(Debug, Clone, Serialize)]
pub struct ModeReport {
    pub queries: usize,
    pub seconds: f64,
    /// Vector bytes compared per second per core (each query counts a full pass).
    pub gb_per_s_per_core: f64,
    pub queries_per_s: f64,
}

/// Everything the bench prints.
#[derive(Debug, Clone, Serialize)]
pub struct KernelReport {
    pub kernel: Kernel,
    pub threads: usize,
    pub vectors: usize,
    pub dims: usize,
    pub stride: usize,
    pub space_bytes: usize,
    pub single: ModeReport,
    pub batched: ModeReport,
}

fn read_exact(path: &Path, len: usize, what: &'static str) -> Result<Vec<u8>> {
    let data = std::fs::read(path)
        .with_context(|| format!("cannot read {what} file {}", path.display()))?;
    ensure!(
        data.len() == len,
        "{what} file {} has {} bytes, expected {len}",
        path.display(),
        data.len()
    );
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

/// The reference vectors and the query batch (from the files or random).
fn data(a: &KernelArgs, layout: Layout) -> Result<(VectorSpace, QueryBatch)> {
    let d = layout.dims();
    let mut rng = ChaCha8Rng::seed_from_u64(a.seed);
    let raw = match &a.vectors_file {
        Some(p) => read_exact(p, a.vectors * d, "vectors")?,
        None => (0..a.vectors * d).map(|_| rng.random()).collect(),
    };
    let qraw = match &a.queries_file {
        Some(p) => read_exact(p, a.queries * d, "queries")?,
        None => (0..a.queries * d).map(|_| rng.random()).collect(),
    };
    let space = VectorSpace::from_unpadded(layout, 0, &raw)?;
    drop(raw);
    let mut batch = QueryBatch::new(layout);
    for q in qraw.chunks(d) {
        let mask: Vec<u8> = (0..d)
            .map(|_| u8::from(rng.random_bool(a.defined)))
            .collect();
        batch.push(q, &mask)?;
    }
    Ok((space, batch))
}

/// Measures single queries and the batch; the answers of both modes must agree.
fn measure(a: &KernelArgs, kernel: Kernel) -> Result<KernelReport> {
    let layout = Layout::checked(a.dims, a.lo_dims)?;
    let (space, batch) = data(a, layout)?;
    let singles: Vec<QueryBatch> = (0..a.queries.min(8))
        .map(|q| {
            let mut b = QueryBatch::new(layout);
            let (values, mask) = batch.unpadded_range(q..q + 1);
            b.push(&values, &mask).map(|_| b)
        })
        .collect::<std::result::Result<_, _>>()?;
    let threads = a.threads.max(1);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .context("thread pool")?;
    let min_time = Duration::try_from_secs_f64(a.min_time)?;
    let engine = Engine::new(kernel);
    let params = Params::default();
    let range = space.start()..space.end();
    let mut batched_hits: Vec<Hit> = Vec::new();
    let batched = pool.install(|| {
        time_best(min_time, || {
            batched_hits = engine.search_best(&space, range.clone(), &batch, &params)?;
            Ok(())
        })
    })?;
    let mut single_hits = Vec::new();
    let single = pool.install(|| {
        time_best(min_time, || {
            single_hits.clear();
            for b in &singles {
                single_hits.extend(engine.search_best(&space, range.clone(), b, &params)?);
            }
            Ok(())
        })
    })?;
    if single_hits[..] != batched_hits[..singles.len()] {
        bail!("single and batched answers differ: kernel bug");
    }
    if let Some(p) = &a.answers_file {
        let text: String = batched_hits
            .iter()
            .map(|h| format!("{} {}\n", h.index, h.dist))
            .collect();
        std::fs::write(p, text).with_context(|| format!("cannot write {}", p.display()))?;
    }
    let bytes = space.bytes() as f64;
    let mode = |n: usize, secs: f64| ModeReport {
        queries: n,
        seconds: secs,
        gb_per_s_per_core: bytes * n as f64 / secs / threads as f64 / 1e9,
        queries_per_s: n as f64 / secs,
    };
    Ok(KernelReport {
        kernel,
        threads,
        vectors: a.vectors,
        dims: layout.dims(),
        stride: layout.stride(),
        space_bytes: space.bytes(),
        single: mode(singles.len(), single),
        batched: mode(a.queries, batched),
    })
}

pub fn run(a: KernelArgs) -> Result<()> {
    ensure!(
        a.vectors > 0 && a.queries > 0 && a.dims > 0,
        "vectors, queries and dims must be ≥ 1"
    );
    ensure!(
        (0.0..=1.0).contains(&a.defined),
        "defined share {} is not in 0..=1",
        a.defined
    );
    let kernel = Kernel::from_name(&a.kernel)?;
    kernel.check()?;
    let report = measure(&a, kernel)?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print!("{report}");
    }
    Ok(())
}

impl std::fmt::Display for KernelReport {
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

/// `--min-time`: finite seconds in 0..=3600.
fn min_time(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && (0.0..=3600.0).contains(&v) => Ok(v),
        _ => Err(format!("'{s}' is not a time in seconds between 0 and 3600")),
    }
}

#[cfg(test)]
mod min_time_tests {
    #[test]
    fn min_time_refuses_what_a_duration_cannot_hold() {
        for bad in ["inf", "nan", "-1", "1e300", "x"] {
            assert!(super::min_time(bad).is_err(), "{bad}");
        }
        assert_eq!(super::min_time("0.5"), Ok(0.5));
    }
}
