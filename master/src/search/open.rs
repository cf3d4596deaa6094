//! The one way every method opens its search (ARCHITECTURE §3.8): the local
//! engine with its kernel, vector store and memory cap, LBG, and the cluster
//! when workers are given, routed per level by the plan.

use anyhow::Result;
use texsyn_engine::{Engine, Storage};

use super::{LbgSearch, LocalSearch, Plan, PlannedSearch};
use crate::launch::{ClusterSetup, LocalWorkers, SshWorkers};

/// What a run's search is made of: the common search flags of every method.
#[derive(Debug)]
pub struct SearchOptions {
    /// Distance kernel: auto, scalar, avx2, avx512.
    pub kernel: String,
    /// How a level's vectors are held: auto, dense or planes.
    pub vector_store: String,
    /// Cap of one level's reference vectors on this machine, in bytes.
    pub max_memory: Option<u64>,
    /// The strategy per level.
    pub plan: Plan,
    /// LBG partitions searched per query.
    pub lbg_probes: usize,
    /// LBG training threshold.
    pub lbg_threshold: f64,
    /// Seed of LBG's training.
    pub seed: u64,
    /// Pixels of the largest sample a level is built from: more LBG probes
    /// than such a level can have seeds are refused now (0: not known yet,
    /// not checked here).
    pub largest_sample: usize,
    /// How long the search threads spin for more work after each search.
    pub spin: std::time::Duration,
    /// The workers, when the run uses a cluster.
    pub cluster: Option<ClusterSetup>,
}

/// An open search: the planned backend, and the workers it uses (stopped
/// after the backend is dropped, which ends its job on them).
pub struct OpenSearch {
    pub search: PlannedSearch,
    pub engine: Engine,
    _local: Option<LocalWorkers>,
    _ssh: Option<SshWorkers>,
}

/// Opens the search `o` describes.
pub fn open(o: SearchOptions) -> Result<OpenSearch> {
    let engine = Engine::with_kernel_name(&o.kernel)?.with_spin(o.spin);
    let lbg = LbgSearch::new(engine, o.lbg_probes, o.lbg_threshold, o.seed)?;
    if o.largest_sample > 0 {
        lbg.check_vectors(o.largest_sample)?;
    }
    let mut local = LocalSearch::new(engine).with_storage(Storage::from_name(&o.vector_store)?);
    if let Some(bytes) = o.max_memory {
        local = local.with_max_memory(bytes);
    }
    let mut search = PlannedSearch::new(o.plan, local).with_lbg(Box::new(lbg));
    search.lbg_probes = u32::try_from(o.lbg_probes).unwrap_or(u32::MAX);
    let (mut local_workers, mut ssh) = (None, None);
    if let Some(c) = o.cluster {
        (local_workers, ssh) = (c.local, c.ssh);
        let cluster = crate::cluster::ClusterSearch::connect(c.options, engine)?;
        search = search.with_cluster(Box::new(cluster));
    }
    Ok(OpenSearch {
        search,
        engine,
        _local: local_workers,
        _ssh: ssh,
    })
}
