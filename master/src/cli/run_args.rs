//! The run flags every searching command shares: threads, the search
//! (kernel, vector store, memory cap, plan, LBG), the cluster and `--quiet`.
//! They open the search through the library's one [`crate::search::open`].

use anyhow::{ensure, Context, Result};
use clap::Args;

use super::ClusterArgs;
use crate::budget::Budget;
use crate::search::{OpenSearch, Plan, SearchOptions};

#[derive(Args, Debug, Clone)]
pub struct RunArgs {
    /// Search threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Search kernel: auto, scalar, avx2, avx512.
    #[arg(long, default_value = "auto")]
    pub kernel: String,
    /// Search plan per pyramid level, coarsest first, each local, cluster, lbg or
    /// cluster-lbg: e.g. local,local,lbg or cluster,cluster,cluster; or exact (exhaustive everywhere, the cluster for large
    /// levels when workers are given); or auto (LBG, approximate, for levels above the cost budget).
    #[arg(long, default_value = "exact")]
    pub search: String,
    /// LBG: partitions searched per query (the P nearest seeds; 1..=seeds of the level).
    #[arg(long, default_value_t = crate::search::lbg::DEFAULT_PROBES)]
    pub lbg_probes: usize,
    /// LBG: stop training when the relative change of the total seed displacement
    /// falls below this (0 < T < 1).
    #[arg(long, default_value_t = texsyn_engine::lbg::DEFAULT_THRESHOLD)]
    pub lbg_threshold: f64,
    /// Most megabytes the reference vectors of one level may take on this
    /// machine (default: what the host or its cgroup still has). A level over
    /// the budget stops the run with an error before it is built.
    #[arg(long, value_name = "MB")]
    pub max_memory: Option<u64>,
    /// How a level's vectors are held on this machine: dense (built once,
    /// fastest), planes (gathered from the sample as they are scanned: about
    /// one byte per sample pixel, for large samples) or auto (dense up to
    /// 1 GiB and half the memory left, planes beyond). Same output either way.
    #[arg(long, value_name = "STORE", default_value = "auto")]
    pub vector_store: String,
    /// Microseconds the search threads (and those of --local-workers) spin
    /// for more work after each search before they sleep (0: sleep at once).
    /// Spinning spares the next search their wake-up; the output is the same
    /// bytes either way.
    #[arg(long, value_name = "US", default_value_t = texsyn_engine::search::DEFAULT_SPIN.as_micros() as u64,
          value_parser = clap::value_parser!(u64).range(0..=1_000_000))]
    pub spin_us: u64,
    /// No progress bars.
    #[arg(long, short)]
    pub quiet: bool,
    #[command(flatten)]
    pub cluster: ClusterArgs,
}

impl RunArgs {
    /// The thread pool of `--threads`.
    pub fn pool(&self) -> Result<rayon::ThreadPool> {
        thread_pool(self.threads)
    }

    /// The memory budget of `--max-memory`.
    pub fn budget(&self) -> Budget {
        Budget::of_mib(self.max_memory)
    }

    /// The library's search options of these flags; `seed` seeds LBG and
    /// `largest_sample` (pixels) bounds its probes.
    pub fn options(&self, seed: u64, largest_sample: usize) -> Result<SearchOptions> {
        let plan: Plan = self.search.parse()?;
        Ok(SearchOptions {
            spin: std::time::Duration::from_micros(self.spin_us),
            kernel: self.kernel.clone(),
            vector_store: self.vector_store.clone(),
            max_memory: self.budget().cap,
            plan,
            lbg_probes: self.lbg_probes,
            lbg_threshold: self.lbg_threshold,
            seed,
            largest_sample,
            // Local workers wait as this process's threads do.
            cluster: self
                .cluster
                .setup_with(&["--spin-us".into(), self.spin_us.to_string().into()])?,
        })
    }

    /// Opens the search (starting the local workers, if any).
    pub fn open(&self, seed: u64, largest_sample: usize) -> Result<OpenSearch> {
        crate::search::open(self.options(seed, largest_sample)?)
    }
}

/// A pool of `threads` threads (all cores when `None`), checked.
pub fn thread_pool(threads: Option<usize>) -> Result<rayon::ThreadPool> {
    let mut b = rayon::ThreadPoolBuilder::new();
    if let Some(t) = threads {
        ensure!((1..=1024).contains(&t), "--threads {t} must be in 1..=1024");
        b = b.num_threads(t);
    }
    b.build().context("cannot start the search threads")
}
