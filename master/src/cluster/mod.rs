//! The search cluster, master side (Stahlhut §8 last part, ARCHITECTURE §4).
//!
//! [`ClusterSearch`] is a [`SearchBackend`]: per level it sends the level images
//! and geometry to every worker once (`LoadLevel`), cuts the level's global
//! index range into contiguous ranges proportional to each worker's calibrated
//! throughput (`Assign`, with a new partition epoch each time), and per batch
//! sends the queries over one long-lived `Search` stream per worker and merges
//! the local bests ([`texsyn_engine::merge_answers`]: minimum distance, ties to the
//! lowest global index). The master may keep a share for itself, searched
//! in-process with the same [`Engine`].
//!
//! The master keeps the truth: the canvas lives only in the synthesis, the
//! partition table and the level data only here; workers hold caches that can
//! be rebuilt. So a fault never loses or doubles work: a worker that errors,
//! disconnects, answers malformed data or misses its deadline (expected time
//! from its calibration × factor + floor) is dropped, its range is re-spread
//! over the others (new epoch, so a stale answer cannot be mistaken for a
//! current one), and the whole batch is asked again; `search` returns only
//! complete answers. A worker much slower than its calibration (busy) triggers
//! recalibration and a new partition. Dropped and new workers are retried at
//! the next level. With no worker left the master finishes locally (or, with
//! `require_cluster`, fails).
//!
//! The rooms: [`membership`] (worker slots: join, drop, rejoin, recalibrate,
//! the partition applied with `Assign`), [`policy`] (the partition table and
//! the deadline and slow-worker rules, pure), [`dispatch`] (one batch sent and
//! merged), [`report`] (the run report and its events), [`conn`] (the calls,
//! each with a deadline), [`error`] and [`status`] (`texsyn cluster status`).

pub mod conn;
mod dispatch;
pub mod error;
mod membership;
pub mod policy;
pub mod report;
pub mod status;

use std::ops::Range;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{bail, Context, Result};
use rand::Rng;
use texsyn_engine::{Engine, Hit, Layout, OwnedLevel, PruneStats, QueryBatch, VectorSpace};
use texsyn_proto::tls::ClientTls;
use texsyn_proto::v1 as pb;
use texsyn_proto::wire::load_level_parts;
use texsyn_proto::PROTOCOL_VERSION;

pub use conn::{split_address, WorkerSpec};
pub use error::{ClusterError, ClusterResult};
pub use report::{Event, EventKind, ShareEntry};
pub use texsyn_engine::CalibrationSize;

use crate::search::{LevelData, SearchBackend};
use conn::block_on;
use dispatch::join_all;
use membership::Slot;
use report::PartStats;

/// How the master talks to its workers. [`ClusterOptions::default`] suits a LAN.
#[derive(Clone)]
pub struct ClusterOptions {
    pub workers: Vec<WorkerSpec>,
    /// Hosts of a `--launch` that were skipped, with the reason (for the report).
    pub skipped_hosts: Vec<(String, String)>,
    /// Client TLS: `https://` addresses always use TLS, `host:port` ones when
    /// any option is set, `http://` ones never (an error when options are set).
    pub tls: ClientTls,
    /// Fail instead of finishing locally when no worker is left.
    pub require_cluster: bool,
    /// The master searches a share of each level itself, sized by its own calibration.
    pub master_share: bool,
    /// Search deadline = expected time from calibration × this + `deadline_floor`.
    pub deadline_factor: f64,
    pub deadline_floor: Duration,
    /// Deadline of the control calls (Info, Calibrate, LoadLevel, Assign; Assign
    /// also gets time in proportion to the vectors it builds).
    pub call_timeout: Duration,
    pub connect_timeout: Duration,
    /// A batch taking longer than this × its expected time counts as slow ...
    pub slow_factor: f64,
    /// ... and this many slow batches in a row trigger recalibration.
    pub slow_strikes: u32,
    /// Batches between two recalibrations at least.
    pub recalibrate_cooldown: u64,
    pub calibration: CalibrationSize,
    /// Protocol version announced in the handshake (tests change it).
    pub protocol_version: u32,
    /// Job id on the workers; unique per run by default.
    pub job_id: String,
}

impl std::fmt::Debug for ClusterOptions {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ClusterOptions")
            .field("workers", &self.workers)
            .field("tls", &self.tls)
            .field("require_cluster", &self.require_cluster)
            .field("master_share", &self.master_share)
            .field("deadline_factor", &self.deadline_factor)
            .field("deadline_floor", &self.deadline_floor)
            .field("call_timeout", &self.call_timeout)
            .field("job_id", &self.job_id)
            .finish_non_exhaustive()
    }
}

/// A job id unique to this run: `texsyn-<pid>-<random>`.
pub fn new_job_id() -> String {
    let r: u32 = rand::rng().random();
    format!("texsyn-{}-{r:08x}", std::process::id())
}

impl Default for ClusterOptions {
    fn default() -> Self {
        Self {
            workers: Vec::new(),
            skipped_hosts: Vec::new(),
            tls: ClientTls::default(),
            require_cluster: false,
            master_share: false,
            deadline_factor: 8.0,
            deadline_floor: Duration::from_secs(2),
            call_timeout: Duration::from_secs(10),
            connect_timeout: Duration::from_secs(5),
            slow_factor: 4.0,
            slow_strikes: 3,
            recalibrate_cooldown: 16,
            calibration: CalibrationSize::default(),
            protocol_version: PROTOCOL_VERSION,
            job_id: new_job_id(),
        }
    }
}

/// Largest piece of a level's planes in one `LoadLevel` message.
const LOAD_PIECE: usize = 4 << 20;

/// The level being searched. Its data is owned: needed again when the master
/// must build vectors for a range after a repartition or a fallback.
struct LevelState {
    /// Shared with the `LoadLevel` streams that send it to workers.
    data: Arc<OwnedLevel>,
    /// About how many queries the level will ask.
    expected_queries: u64,
    /// Queries answered so far.
    queries: u64,
    /// The partition was corrected from measured throughput once.
    rebalanced: bool,
    /// Longest Assign build time of the last partition, in seconds.
    assign_seconds: f64,
}

impl LevelState {
    fn total(&self) -> u64 {
        self.data.total()
    }

    fn layout(&self) -> Layout {
        self.data.geometry.layout()
    }

    /// Bytes of the level images on the wire (pixels and defined masks).
    fn image_bytes(&self) -> u64 {
        (self.data.fine.pixels.len() * 2) as u64
            + self.data.parent.as_ref().map_or(0, |p| p.pixels.len() * 2) as u64
    }

    /// The level's `LoadLevel` stream, in pieces that fit `max_message`.
    fn load_parts(
        &self,
        job_id: &str,
        max_message: u64,
    ) -> impl Iterator<Item = pb::LoadLevelPart> + Send + 'static {
        let piece = (max_message / 2).clamp(1, LOAD_PIECE as u64) as usize;
        load_level_parts(job_id, self.data.clone(), piece)
    }
}

/// The master's own share (with `master_share`) or the whole level (fallback).
#[derive(Default)]
struct MasterPart {
    rate: Option<f64>,
    range: Range<u64>,
    space: Option<VectorSpace>,
    stats: PartStats,
}

/// Exhaustive search on a cluster of `texsyn-worker`s; see the module docs.
pub struct ClusterSearch {
    rt: Option<tokio::runtime::Runtime>,
    opts: ClusterOptions,
    engine: Engine,
    slots: Vec<Slot>,
    master: MasterPart,
    level: Option<LevelState>,
    epoch: u64,
    next_batch: u64,
    /// Id of the next search message (unique within the run).
    next_chunk: u64,
    /// Batch being searched (for events).
    current_batch: Option<u64>,
    batches_since_recalibration: u64,
    events: Vec<Event>,
    local_levels: Vec<usize>,
    /// LBG probes on the workers for the current level (0 = exhaustive).
    lbg_probes: u32,
    /// Pruning figures of the current level: the workers' and the master's.
    level_prune: PruneStats,
}

impl ClusterSearch {
    /// Checks that `batch` has the loaded level's layout and gives it the
    /// next batch number.
    fn number_batch(&mut self, batch: &QueryBatch) -> Result<u64> {
        let level = self.level.as_ref().context("search before load_level")?;
        if batch.layout() != level.layout() {
            bail!("the queries do not have the loaded level's layout");
        }
        let batch_id = self.next_batch;
        self.next_batch += 1;
        self.current_batch = Some(batch_id);
        Ok(batch_id)
    }

    /// Connects to the workers, checks their protocol version and calibrates
    /// them. Unreachable workers are retried at each level; when none is
    /// reachable the run goes on locally (with a warning), unless
    /// `require_cluster` is set, which makes this an error.
    pub fn connect(opts: ClusterOptions, engine: Engine) -> Result<Self> {
        if opts.workers.is_empty() {
            bail!(ClusterError::NoWorkers);
        }
        if !(opts.deadline_factor.is_finite() && opts.deadline_factor >= 1.0) {
            bail!(ClusterError::DeadlineFactor(opts.deadline_factor));
        }
        let addresses: Vec<&str> = opts.workers.iter().map(|w| w.address.as_str()).collect();
        opts.tls.check(&addresses)?;
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .thread_name("texsyn-cluster")
            .enable_all()
            .build()
            .context("cannot start the cluster's async runtime")?;
        let slots = opts.workers.iter().cloned().map(Slot::new).collect();
        let mut me = Self {
            rt: Some(rt),
            opts,
            engine,
            slots,
            master: MasterPart::default(),
            level: None,
            epoch: 0,
            next_batch: 0,
            next_chunk: 0,
            current_batch: None,
            batches_since_recalibration: 0,
            events: Vec::new(),
            local_levels: Vec::new(),
            lbg_probes: 0,
            level_prune: PruneStats::default(),
        };
        me.join_workers();
        if me.active_workers() == 0 {
            let why = me.down_summary();
            if me.opts.require_cluster {
                bail!(ClusterError::NoneUsable(why));
            }
            tracing::warn!(
                reasons = %why,
                "no search worker could be used; searching locally and retrying them at each level"
            );
        }
        Ok(me)
    }

    /// Workers currently in use.
    pub fn active_workers(&self) -> usize {
        self.slots.iter().filter(|s| s.active()).count()
    }

    /// Every drop, rejoin, (re)partition, recalibration and fallback so far.
    pub fn events(&self) -> &[Event] {
        &self.events
    }

    fn rt(&self) -> &tokio::runtime::Runtime {
        self.rt.as_ref().expect("the runtime lives until drop")
    }
}

impl SearchBackend for ClusterSearch {
    fn name(&self) -> String {
        format!("cluster({} workers)", self.slots.len())
    }

    fn set_lbg_probes(&mut self, probes: u32) -> Result<()> {
        self.lbg_probes = probes;
        Ok(())
    }

    fn load_level(&mut self, data: &LevelData) -> Result<()> {
        anyhow::ensure!(
            data.colour_vectors.is_none(),
            "full-colour search runs on this machine only; use --search local (or lbg) with --colour-search"
        );
        let span = tracing::info_span!("level", level = data.level);
        let _enter = span.enter();
        self.current_batch = None;
        self.level = Some(LevelState {
            data: Arc::new(data.owned_level()),
            expected_queries: data.expected_queries,
            queries: 0,
            rebalanced: false,
            assign_seconds: 0.0,
        });
        self.master.space = None;
        self.master.range = 0..0;
        self.level_prune = PruneStats::default();
        for s in &mut self.slots {
            s.range = 0..0;
            s.level_pairs = 0.0;
            s.level_seconds = 0.0;
        }
        // Dropped and new workers are taken (back) in here.
        self.join_workers();
        self.load_on_workers();
        self.batches_since_recalibration = 0;
        self.repartition(EventKind::Partition, format!("level {} start", data.level))
    }

    fn search(&mut self, batch: &QueryBatch) -> Result<Vec<Hit>> {
        if batch.is_empty() {
            return Ok(Vec::new());
        }
        let batch_id = self.number_batch(batch)?;
        let level = self.level.as_ref().context("search before load_level")?;
        let span = tracing::debug_span!(
            "batch",
            level = level.data.level,
            batch = batch_id,
            queries = batch.len()
        );
        let _enter = span.enter();
        // Exhaustive search starts from the coherence candidates' best, scored
        // here from the planes, so every worker prunes against it (ARCHITECTURE
        // §3.5); LBG answers are approximate and take no bound.
        let batch = if self.lbg_probes == 0 {
            let mut b = batch.clone();
            level.data.bound_queries(&mut b);
            b
        } else {
            batch.without_hints()
        };
        self.search_batch(&batch, batch_id, 1, None)
    }

    fn search_topk(&mut self, batch: &QueryBatch, k: usize) -> Result<Vec<Vec<Hit>>> {
        anyhow::ensure!(k >= 1, "top-k needs k ≥ 1");
        anyhow::ensure!(
            self.lbg_probes == 0,
            "top-k search is exhaustive; LBG levels answer the best match only"
        );
        if batch.is_empty() {
            return Ok(Vec::new());
        }
        let batch_id = self.number_batch(batch)?;
        let span = tracing::debug_span!("top-k batch", batch = batch_id, queries = batch.len(), k);
        let _enter = span.enter();
        // Each range answers only what can enter the merged top-k: the
        // cut of the queries' coherence candidates, scored here from the
        // planes (ARCHITECTURE §4.8).
        let level = self.level.as_ref().context("search before load_level")?;
        let cut = level.data.topk_cuts(batch, k);
        // A batch without candidates has no cut: nothing to send.
        let cut = cut.iter().any(|&c| c != u64::MAX).then_some(cut);
        let flat = self.search_batch(&batch.without_hints(), batch_id, k, cut.as_deref())?;
        Ok(flat
            .chunks_exact(k)
            .map(|c| c.iter().copied().filter(|h| !h.is_none()).collect())
            .collect())
    }

    /// The workers' and the master's pruning figures of the level; none for
    /// LBG levels, whose searches do not prune.
    fn level_prune(&self) -> Option<PruneStats> {
        (self.level_prune.pairs > 0).then_some(self.level_prune)
    }

    fn end_level(&mut self) {
        self.master.space = None;
        self.master.range = 0..0;
        self.current_batch = None;
    }

    fn stats(&self) -> serde_json::Value {
        self.report()
    }
}

impl Drop for ClusterSearch {
    fn drop(&mut self) {
        let Some(rt) = self.rt.take() else { return };
        let jobs: Vec<_> = self
            .slots
            .iter_mut()
            .filter_map(|s| {
                s.stream = None;
                s.client.take()
            })
            .map(|c| conn::end_job(c, self.opts.job_id.clone(), Duration::from_secs(2)))
            .collect();
        if !jobs.is_empty() {
            let freed = block_on(&rt, join_all(jobs));
            tracing::debug!(?freed, "jobs ended on the workers");
        }
        rt.shutdown_background();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn connect_needs_workers_and_valid_addresses() {
        let e = ClusterSearch::connect(ClusterOptions::default(), Engine::default());
        assert!(e.is_err());
        let o = ClusterOptions {
            workers: vec![WorkerSpec::new("no-port", None)],
            ..Default::default()
        };
        assert!(ClusterSearch::connect(o, Engine::default()).is_err());
    }

    #[test]
    fn unreachable_workers_fall_back_or_fail_with_require_cluster() {
        // A port nobody listens on: bind, read the port, close.
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let o = ClusterOptions {
            workers: vec![WorkerSpec::new(format!("127.0.0.1:{port}"), None)],
            connect_timeout: Duration::from_millis(500),
            ..Default::default()
        };
        let c = ClusterSearch::connect(o.clone(), Engine::default()).unwrap();
        assert_eq!(c.active_workers(), 0);
        assert_eq!(c.events()[0].kind, EventKind::Unavailable);
        let e = ClusterSearch::connect(
            ClusterOptions {
                require_cluster: true,
                ..o
            },
            Engine::default(),
        )
        .err()
        .unwrap();
        assert!(format!("{e:#}").contains("--require-cluster"), "{e:#}");
    }
}
