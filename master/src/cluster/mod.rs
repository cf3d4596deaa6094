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

pub mod args;
pub mod conn;
pub mod hosts;
pub mod local;
pub mod partition;
pub mod ssh;
pub mod status;

use std::ops::Range;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use rand::Rng;
use texsyn_engine::{
    Engine, Geometry, Hit, Layout, OwnedPlane, Params, QueryBatch, Sample, VectorSpace,
};
use texsyn_proto::v1 as pb;
use texsyn_proto::wire::geometry_to_proto;
use texsyn_proto::PROTOCOL_VERSION;
use tracing::Instrument;

pub use args::{ClusterArgs, ClusterSetup};
pub use hosts::{parse_worker_list, read_hosts_file, WorkerSpec};
pub use local::{find_worker_binary, LocalWorkers};
pub use texsyn_engine::CalibrationSize;

use crate::search::{LevelData, SearchBackend};
use conn::{block_on, Client, SearchStream, WorkerInfo};

/// How the master talks to its workers. [`ClusterOptions::default`] suits a LAN.
#[derive(Clone)]
pub struct ClusterOptions {
    pub workers: Vec<WorkerSpec>,
    /// Hosts of a `--launch` that were skipped, with the reason (for the report).
    pub skipped_hosts: Vec<(String, String)>,
    /// PEM CA certificate that signed the workers' TLS certificates; TLS is on
    /// when this is set (the host part of each address is the server name).
    pub tls_ca: Option<Vec<u8>>,
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
            .field("tls", &self.tls_ca.is_some())
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
            tls_ca: None,
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

/// One entry of the run report's event list.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Event {
    /// `unavailable`, `drop`, `rejoin`, `partition`, `repartition`,
    /// `recalibrate` or `fallback`.
    pub kind: &'static str,
    pub level: Option<usize>,
    /// The batch during which it happened (None between batches).
    pub batch: Option<u64>,
    pub epoch: u64,
    pub worker: Option<String>,
    pub reason: String,
    /// Shares after a (re)partition: address (or "master") and index range.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub shares: Vec<ShareEntry>,
}

#[derive(Debug, Clone, serde::Serialize)]
pub struct ShareEntry {
    pub worker: String,
    pub start: u64,
    pub end: u64,
    pub share: f64,
}

#[derive(Debug, Clone, Default, serde::Serialize)]
struct PartStats {
    queries: u64,
    batches: u64,
    /// Search time reported by the worker (or spent by the master).
    search_seconds: f64,
    /// Wall time from sending a batch to its answer.
    round_trip_seconds: f64,
}

struct Slot {
    spec: WorkerSpec,
    client: Option<Client>,
    stream: Option<SearchStream>,
    info: Option<WorkerInfo>,
    /// Calibrated reference × query pairs per second.
    rate: f64,
    range: Range<u64>,
    /// Level the worker has loaded (LoadLevel succeeded).
    loaded: Option<usize>,
    strikes: u32,
    stats: PartStats,
    drops: u32,
    down_reason: Option<String>,
    /// Last non-empty share of a level.
    last_share: f64,
    /// This level's searched pairs (in calibration units) and reported seconds.
    level_pairs: f64,
    level_seconds: f64,
}

impl Slot {
    fn active(&self) -> bool {
        self.client.is_some()
    }

    fn len(&self) -> u64 {
        self.range.end - self.range.start
    }
}

/// The level's data, owned: needed again when the master must build vectors
/// for a range after a repartition or a fallback.
struct LevelState {
    level: usize,
    geometry: Geometry,
    params: Params,
    fine: OwnedPlane,
    parent: Option<OwnedPlane>,
    positions: Vec<[u32; 2]>,
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
    fn sample(&self) -> Sample<'_> {
        Sample {
            fine: self.fine.view(),
            parent: self.parent.as_ref().map(OwnedPlane::view),
        }
    }

    fn total(&self) -> u64 {
        self.positions.len() as u64
    }

    fn layout(&self) -> Layout {
        self.geometry.layout()
    }

    fn load_request(&self, job_id: &str) -> pb::LoadLevelRequest {
        let s = self.sample();
        pb::LoadLevelRequest {
            job_id: job_id.to_string(),
            level: self.level as u32,
            geometry: Some(geometry_to_proto(&self.geometry, &self.params)),
            sample: Some(pb::Plane::from(&s.fine)),
            parent: s.parent.as_ref().map(pb::Plane::from),
        }
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
    /// Batch being searched (for events).
    current_batch: Option<u64>,
    batches_since_recalibration: u64,
    events: Vec<Event>,
    local_levels: Vec<usize>,
    /// LBG probes on the workers for the current level (0 = exhaustive).
    lbg_probes: u32,
}

/// `x` seconds as a duration, clamped to 0..=10⁶ s (never panics).
fn capped_secs(x: f64) -> Duration {
    Duration::from_secs_f64(if x.is_finite() {
        x.clamp(0.0, 1e6)
    } else {
        1e6
    })
}

/// Queries per message that stay under a worker's message limit.
fn queries_per_chunk(max_message: u64, dims: usize) -> usize {
    let room = max_message.saturating_sub(4096) as usize;
    let by_request = room / (2 * dims + 8).max(1);
    let by_answer = room / 24;
    by_request
        .min(by_answer)
        .clamp(1, texsyn_proto::wire::MAX_QUERIES)
}

impl ClusterSearch {
    /// Connects to the workers, checks their protocol version and calibrates
    /// them. Unreachable workers are retried at each level; when none is
    /// reachable the run goes on locally (with a warning), unless
    /// `require_cluster` is set, which makes this an error.
    pub fn connect(opts: ClusterOptions, engine: Engine) -> Result<Self> {
        if opts.workers.is_empty() {
            bail!("no workers given; add --workers, --hosts or --local-workers");
        }
        if !(opts.deadline_factor.is_finite() && opts.deadline_factor >= 1.0) {
            bail!("deadline factor {} must be ≥ 1", opts.deadline_factor);
        }
        for w in &opts.workers {
            hosts::split_address(&w.address)?;
        }
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .thread_name("texsyn-cluster")
            .enable_all()
            .build()
            .context("cannot start the cluster's async runtime")?;
        let slots = opts
            .workers
            .iter()
            .map(|spec| Slot {
                spec: spec.clone(),
                client: None,
                stream: None,
                info: None,
                rate: 0.0,
                range: 0..0,
                loaded: None,
                strikes: 0,
                stats: PartStats::default(),
                drops: 0,
                down_reason: None,
                last_share: 0.0,
                level_pairs: 0.0,
                level_seconds: 0.0,
            })
            .collect();
        let mut me = Self {
            rt: Some(rt),
            opts,
            engine,
            slots,
            master: MasterPart::default(),
            level: None,
            epoch: 0,
            next_batch: 0,
            current_batch: None,
            batches_since_recalibration: 0,
            events: Vec::new(),
            local_levels: Vec::new(),
            lbg_probes: 0,
        };
        me.join_workers();
        let up = me.slots.iter().filter(|s| s.active()).count();
        if up == 0 {
            let why = me.down_summary();
            if me.opts.require_cluster {
                bail!("no search worker could be used ({why}); --require-cluster forbids searching locally");
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

    fn down_summary(&self) -> String {
        self.slots
            .iter()
            .filter(|s| !s.active())
            .map(|s| {
                format!(
                    "{}: {}",
                    s.spec.address,
                    s.down_reason.as_deref().unwrap_or("not connected")
                )
            })
            .collect::<Vec<_>>()
            .join("; ")
    }

    fn event(&mut self, kind: &'static str, worker: Option<String>, reason: String) {
        self.events.push(Event {
            kind,
            level: self.level.as_ref().map(|l| l.level),
            batch: self.current_batch,
            epoch: self.epoch,
            worker,
            reason,
            shares: Vec::new(),
        });
    }

    /// Drops a worker: its stream and client are closed and its range will be
    /// re-spread by the next partition.
    fn drop_worker(&mut self, i: usize, reason: String) {
        let s = &mut self.slots[i];
        tracing::warn!(worker = %s.spec.address, %reason, "dropping worker");
        s.client = None;
        s.stream = None;
        s.loaded = None;
        s.range = 0..0;
        s.strikes = 0;
        s.drops += 1;
        s.down_reason = Some(reason.clone());
        let addr = s.spec.address.clone();
        self.event("drop", Some(addr), reason);
    }

    /// Calibrates the workers one after the other: run side by side, workers
    /// sharing a machine (or its memory bandwidth) would measure each other's
    /// load instead of their own speed. Failures are returned, not applied.
    fn calibrate_each(&self, clients: Vec<(usize, Client)>) -> Vec<(usize, Result<f64, String>)> {
        let (size, d) = (self.opts.calibration, self.opts.call_timeout);
        let rt = self.rt.as_ref().expect("the runtime lives until drop");
        let mut results: Vec<(usize, Result<f64, String>)> =
            clients.iter().map(|(i, _)| (*i, Ok(0.0))).collect();
        // Two rounds over all workers, the best of each worker counts: a short
        // run is easily disturbed, and the first one on a machine runs cold.
        for _ in 0..2 {
            for ((i, c), (_, r)) in clients.iter().zip(results.iter_mut()) {
                let Ok(best) = r else { continue };
                let span = tracing::info_span!("worker", address = %self.slots[*i].spec.address);
                *r = block_on(rt, conn::calibrate(c.clone(), size, d).instrument(span))
                    .map(|rate| rate.max(*best));
            }
        }
        results
    }

    /// Connects (Info, then Calibrate) every worker not in use.
    fn join_workers(&mut self) {
        let todo: Vec<usize> = (0..self.slots.len())
            .filter(|&i| !self.slots[i].active())
            .collect();
        if todo.is_empty() {
            return;
        }
        let o = &self.opts;
        let jobs: Vec<_> = todo
            .iter()
            .map(|&i| {
                let spec = self.slots[i].spec.clone();
                let span = tracing::info_span!("worker", address = %spec.address);
                conn::handshake(
                    spec,
                    o.tls_ca.clone(),
                    o.protocol_version,
                    o.connect_timeout,
                    o.call_timeout,
                )
                .instrument(span)
            })
            .collect();
        let results = block_on(self.rt(), join_all(jobs));
        let mut ok = Vec::new();
        let mut errors = Vec::new();
        for (i, r) in todo.into_iter().zip(results) {
            match r {
                Ok(h) => ok.push((i, h)),
                Err(e) => errors.push((i, e)),
            }
        }
        let calibrated =
            self.calibrate_each(ok.iter().map(|(i, h)| (*i, h.client.clone())).collect());
        for ((i, h), (_, rate)) in ok.into_iter().zip(calibrated) {
            match rate {
                Ok(rate) => {
                    let was_down = self.slots[i].down_reason.is_some();
                    let ever = self.slots[i].info.is_some();
                    let s = &mut self.slots[i];
                    tracing::info!(
                        worker = %s.spec.address,
                        threads = h.info.threads,
                        kernel = %h.info.kernel,
                        pairs_per_second = rate,
                        "worker joined"
                    );
                    s.client = Some(h.client);
                    s.info = Some(h.info);
                    s.rate = rate;
                    s.stream = None;
                    s.loaded = None;
                    s.strikes = 0;
                    s.down_reason = None;
                    if ever || was_down {
                        let addr = s.spec.address.clone();
                        let reason = format!("reconnected; calibrated at {rate:.3e} pairs/s");
                        self.event("rejoin", Some(addr), reason);
                    }
                }
                Err(e) => errors.push((i, e)),
            }
        }
        for (i, reason) in errors {
            let was_down = self.slots[i].down_reason.is_some();
            let s = &mut self.slots[i];
            tracing::debug!(worker = %s.spec.address, %reason, "worker not available");
            s.down_reason = Some(reason.clone());
            if !was_down {
                let addr = s.spec.address.clone();
                self.event("unavailable", Some(addr), reason);
            }
        }
    }

    /// LoadLevel on every active worker that does not have the level yet.
    fn load_on_workers(&mut self) {
        let Some(level) = &self.level else { return };
        let todo: Vec<usize> = (0..self.slots.len())
            .filter(|&i| self.slots[i].active() && self.slots[i].loaded != Some(level.level))
            .collect();
        if todo.is_empty() {
            return;
        }
        let req = level.load_request(&self.opts.job_id);
        let total = level.total();
        let lv = level.level;
        let bytes = (level.fine.pixels.len() * 2) as u64
            + level.parent.as_ref().map_or(0, |p| p.pixels.len() * 2) as u64;
        let d = self.opts.call_timeout + capped_secs(bytes as f64 / 20e6);
        let jobs: Vec<_> = todo
            .iter()
            .map(|&i| {
                let s = &self.slots[i];
                let too_big = s
                    .info
                    .as_ref()
                    .is_some_and(|inf| bytes + 4096 > inf.max_message);
                let client = s.client.clone().expect("active");
                let req = req.clone();
                let span = tracing::info_span!("worker", address = %s.spec.address);
                async move {
                    if too_big {
                        return Err(format!(
                            "the level images ({bytes} bytes) exceed the worker's message limit; start it with a larger --max-message"
                        ));
                    }
                    conn::load_level(client, req, d).await
                }
                .instrument(span)
            })
            .collect();
        let results = block_on(self.rt(), join_all(jobs));
        for (i, r) in todo.into_iter().zip(results) {
            match r {
                Ok(reply) if reply.total_vectors == total => self.slots[i].loaded = Some(lv),
                Ok(reply) => self.drop_worker(
                    i,
                    format!(
                        "LoadLevel counted {} reference vectors where the master counts {total} (different texsyn versions?)",
                        reply.total_vectors
                    ),
                ),
                Err(e) => self.drop_worker(i, e),
            }
        }
    }

    /// Cuts the level over the active workers (and the master's share) in
    /// proportion to their throughput and assigns the ranges under a new epoch.
    /// Workers that fail are dropped and the cut is made again; with none left
    /// the master takes the whole level (or fails with `require_cluster`).
    fn repartition(&mut self, kind: &'static str, reason: String) -> Result<()> {
        let Some(level) = &self.level else {
            bail!("no level loaded");
        };
        let total = level.total();
        let lv = level.level;
        let stride = level.layout().stride() as f64;
        loop {
            let active: Vec<usize> = (0..self.slots.len())
                .filter(|&i| self.slots[i].active() && self.slots[i].loaded == Some(lv))
                .collect();
            self.epoch += 1;
            if active.is_empty() {
                for s in &mut self.slots {
                    s.range = 0..0;
                }
                if self.opts.require_cluster {
                    bail!(
                        "no search worker left at level {lv} ({}); --require-cluster forbids finishing locally",
                        self.down_summary()
                    );
                }
                if self.master.range != (0..total) || self.master.space.is_none() {
                    tracing::warn!(
                        level = lv,
                        reasons = %self.down_summary(),
                        "no search worker left; searching this level locally"
                    );
                    self.event(
                        "fallback",
                        None,
                        format!(
                            "no worker left ({}); master searches locally",
                            self.down_summary()
                        ),
                    );
                    if self.local_levels.last() != Some(&lv) {
                        self.local_levels.push(lv);
                    }
                    self.set_master_range(0..total)?;
                }
                return Ok(());
            }
            let mut weights: Vec<f64> = active.iter().map(|&i| self.slots[i].rate).collect();
            if self.opts.master_share {
                weights.push(self.master_rate()?);
            }
            let ranges = partition::proportional(total, &weights);
            let epoch = self.epoch;
            let job = self.opts.job_id.clone();
            let jobs: Vec<_> = active
                .iter()
                .zip(&ranges)
                .map(|(&i, r)| {
                    let s = &self.slots[i];
                    let d = self.opts.call_timeout
                        + capped_secs((r.end - r.start) as f64 * stride / 100e6);
                    let req = pb::AssignRequest {
                        job_id: job.clone(),
                        level: lv as u32,
                        start: r.start,
                        end: r.end,
                        // LBG on the cluster: each worker quantises its own range;
                        // more probes than its seeds means all of them (exact).
                        lbg_probes: if self.lbg_probes == 0 || r.is_empty() {
                            0
                        } else {
                            (self.lbg_probes as usize).min(texsyn_engine::lbg::default_seeds(
                                (r.end - r.start) as usize,
                            )) as u32
                        },
                        epoch,
                    };
                    let span = tracing::info_span!("worker", address = %s.spec.address);
                    conn::assign(s.client.clone().expect("active"), req, d).instrument(span)
                })
                .collect();
            let results = block_on(self.rt(), join_all(jobs));
            let mut failed = false;
            for ((&i, r), res) in active.iter().zip(&ranges).zip(results) {
                match res {
                    Ok(reply) if reply.vectors == r.end - r.start => {
                        if let Some(l) = self.level.as_mut() {
                            if reply.build_seconds.is_finite() {
                                l.assign_seconds = l.assign_seconds.max(reply.build_seconds);
                            }
                        }
                        let s = &mut self.slots[i];
                        s.range = r.clone();
                        s.strikes = 0;
                        if !r.is_empty() {
                            s.last_share = partition::share(r, total);
                        }
                    }
                    Ok(reply) => {
                        failed = true;
                        self.drop_worker(
                            i,
                            format!(
                                "Assign built {} vectors for the range {}..{} of {} vectors",
                                reply.vectors,
                                r.start,
                                r.end,
                                r.end - r.start
                            ),
                        );
                    }
                    Err(e) => {
                        failed = true;
                        self.drop_worker(i, e);
                    }
                }
            }
            if failed {
                continue;
            }
            let master_range = if self.opts.master_share {
                ranges.last().cloned().unwrap_or(0..0)
            } else {
                0..0
            };
            self.set_master_range(master_range)?;
            let mut shares: Vec<ShareEntry> = active
                .iter()
                .map(|&i| {
                    let s = &self.slots[i];
                    ShareEntry {
                        worker: s.spec.address.clone(),
                        start: s.range.start,
                        end: s.range.end,
                        share: partition::share(&s.range, total),
                    }
                })
                .collect();
            if self.opts.master_share {
                shares.push(ShareEntry {
                    worker: "master".into(),
                    start: self.master.range.start,
                    end: self.master.range.end,
                    share: partition::share(&self.master.range, total),
                });
            }
            tracing::info!(level = lv, epoch, ?shares, %reason, "partition");
            self.events.push(Event {
                kind,
                level: Some(lv),
                batch: self.current_batch,
                epoch,
                worker: None,
                reason: reason.clone(),
                shares,
            });
            return Ok(());
        }
    }

    fn master_rate(&mut self) -> Result<f64> {
        if let Some(r) = self.master.rate {
            return Ok(r);
        }
        let r = texsyn_engine::calibrate(&self.engine, self.opts.calibration)?.pairs_per_second;
        tracing::info!(pairs_per_second = r, "master calibrated");
        self.master.rate = Some(r);
        Ok(r)
    }

    /// Builds the master's vectors for `range` (none for an empty range).
    fn set_master_range(&mut self, range: Range<u64>) -> Result<()> {
        let level = self.level.as_ref().context("no level loaded")?;
        let same = self
            .master
            .space
            .as_ref()
            .is_some_and(|s| s.start() == range.start && s.end() == range.end);
        if !same {
            self.master.space = None;
            if !range.is_empty() {
                self.master.space = Some(VectorSpace::build_from_positions(
                    &level.sample(),
                    &level.geometry,
                    &level.positions,
                    range.clone(),
                )?);
            }
        }
        self.master.range = range;
        Ok(())
    }

    /// Calibrates every active worker again and cuts the level anew.
    fn recalibrate(&mut self, reason: String) -> Result<()> {
        let active: Vec<usize> = (0..self.slots.len())
            .filter(|&i| self.slots[i].active())
            .collect();
        let clients = active
            .iter()
            .map(|&i| (i, self.slots[i].client.clone().expect("active")))
            .collect();
        let results = self.calibrate_each(clients);
        let mut rates = Vec::new();
        for (i, r) in results {
            match r {
                Ok(rate) => {
                    self.slots[i].rate = rate;
                    rates.push(format!("{} {:.3e}", self.slots[i].spec.address, rate));
                }
                Err(e) => self.drop_worker(i, e),
            }
        }
        self.event(
            "recalibrate",
            None,
            format!("{reason}; new rates (pairs/s): {}", rates.join(", ")),
        );
        // Workers that came back (or were never reached) are taken in here too.
        self.join_workers();
        self.load_on_workers();
        self.batches_since_recalibration = 0;
        self.repartition("repartition", format!("recalibrated: {reason}"))
    }

    /// Once per level, after some batches: if the workers' measured throughput
    /// says the calibrated partition is off by more than 20% (a short
    /// calibration is easily disturbed), and the rest of the level is long
    /// enough to pay for rebuilding the ranges, cut the level anew by the
    /// measured rates.
    fn maybe_rebalance(&mut self) -> Result<()> {
        let Some(level) = &self.level else {
            return Ok(());
        };
        // (The master's own share keeps its calibrated weight, so it is left alone.)
        if level.rebalanced || self.opts.master_share || self.batches_since_recalibration < 8 {
            return Ok(());
        }
        let parts: Vec<usize> = (0..self.slots.len())
            .filter(|&i| self.slots[i].active() && self.slots[i].len() > 0)
            .collect();
        if parts.len() < 2
            || parts
                .iter()
                .any(|&i| self.slots[i].level_seconds < 0.02 || self.slots[i].level_pairs <= 0.0)
        {
            return Ok(());
        }
        let measured: Vec<f64> = parts
            .iter()
            .map(|&i| self.slots[i].level_pairs / self.slots[i].level_seconds)
            .collect();
        // Seconds per query of each part now, and with a partition by the measured rates.
        let per_query: Vec<f64> = parts
            .iter()
            .zip(&measured)
            .map(|(&i, r)| self.slots[i].len() as f64 / r)
            .collect();
        let slowest = per_query.iter().copied().fold(0.0, f64::max);
        let fastest = per_query.iter().copied().fold(f64::INFINITY, f64::min);
        let covered: f64 = parts.iter().map(|&i| self.slots[i].len() as f64).sum();
        let balanced = covered / measured.iter().sum::<f64>();
        let remaining = level.expected_queries.saturating_sub(level.queries) as f64;
        let gain = (slowest - balanced) * remaining;
        if slowest <= 1.2 * fastest || gain < 3.0 * level.assign_seconds.max(0.01) {
            return Ok(());
        }
        let lv = level.level;
        if let Some(l) = self.level.as_mut() {
            l.rebalanced = true;
        }
        let mut text = Vec::new();
        for (&i, r) in parts.iter().zip(&measured) {
            let s = &mut self.slots[i];
            text.push(format!(
                "{} {:.3e} (calibrated {:.3e})",
                s.spec.address, r, s.rate
            ));
            s.rate = *r;
        }
        tracing::info!(level = lv, rates = %text.join(", "), "rebalancing from measured throughput");
        self.repartition(
            "repartition",
            format!(
                "rebalanced from measured throughput (pairs/s): {}",
                text.join(", ")
            ),
        )
    }

    /// Searches one batch on the current partition. Err(failures) when any
    /// worker failed: nothing of this round is used.
    fn try_batch(
        &mut self,
        batch: &QueryBatch,
        values: &[u8],
        masks: &[u8],
        batch_id: u64,
    ) -> Result<Round> {
        let level = self.level.as_ref().context("search before load_level")?;
        let (lv, dims) = (level.level, level.layout().dims());
        // Calibration pairs are vectors of the calibration's stride; this level's
        // cost more or less in proportion to their bytes.
        let cost = level.layout().stride() as f64
            / Layout::new(self.opts.calibration.dims.max(1) as usize, 0).stride() as f64;
        let n = batch.len();
        let participants: Vec<usize> = (0..self.slots.len())
            .filter(|&i| self.slots[i].active() && self.slots[i].len() > 0)
            .collect();

        // Streams: opened once per worker and kept across batches and levels.
        let need: Vec<usize> = participants
            .iter()
            .copied()
            .filter(|&i| self.slots[i].stream.is_none())
            .collect();
        if !need.is_empty() {
            let d = self.opts.call_timeout;
            let jobs: Vec<_> = need
                .iter()
                .map(|&i| conn::open_stream(self.slots[i].client.clone().expect("active"), d))
                .collect();
            let opened = block_on(self.rt(), join_all(jobs));
            let mut failures = Vec::new();
            for (i, r) in need.into_iter().zip(opened) {
                match r {
                    Ok(s) => self.slots[i].stream = Some(s),
                    Err(e) => failures.push((i, e)),
                }
            }
            if !failures.is_empty() {
                return Ok(Err(failures));
            }
        }

        // Send every worker its part; the tasks run while the master searches its own share.
        let now = Instant::now();
        let mut handles = Vec::with_capacity(participants.len());
        let mut expected = Vec::with_capacity(participants.len());
        for &i in &participants {
            let s = &mut self.slots[i];
            let exp = s.len() as f64 * n as f64 * cost / s.rate.max(1.0);
            let deadline =
                now + capped_secs(exp * self.opts.deadline_factor) + self.opts.deadline_floor;
            let per = queries_per_chunk(s.info.as_ref().map_or(4 << 20, |x| x.max_message), dims);
            let chunks: Vec<pb::SearchBatch> = (0..n)
                .step_by(per)
                .enumerate()
                .map(|(k, q0)| {
                    let q1 = (q0 + per).min(n);
                    pb::SearchBatch {
                        job_id: self.opts.job_id.clone(),
                        level: lv as u32,
                        batch_id: batch_id * 1024 + k as u64,
                        top_k: 1,
                        count: (q1 - q0) as u32,
                        values: values[q0 * dims..q1 * dims].to_vec(),
                        masks: masks[q0 * dims..q1 * dims].to_vec(),
                        epoch: self.epoch,
                    }
                })
                .collect();
            let part = conn::Part {
                chunks,
                range: s.range.clone(),
                deadline,
            };
            let stream = s.stream.take().expect("opened above");
            let span = tracing::debug_span!("worker", address = %s.spec.address, batch = batch_id);
            let rt = self.rt.as_ref().expect("the runtime lives until drop");
            handles.push(rt.spawn(conn::run_part(stream, part).instrument(span)));
            expected.push(exp);
        }

        let mut parts: Vec<Vec<Hit>> = Vec::new();
        if let Some(space) = &self.master.space {
            let t = Instant::now();
            let hits =
                self.engine
                    .search_best(space, self.master.range.clone(), batch, &level.params)?;
            self.master.stats.search_seconds += t.elapsed().as_secs_f64();
            self.master.stats.queries += n as u64;
            self.master.stats.batches += 1;
            parts.push(hits);
        }

        let answers = block_on(self.rt(), async move {
            let mut out = Vec::with_capacity(handles.len());
            for h in handles {
                out.push(h.await);
            }
            out
        });
        let mut failures = Vec::new();
        let mut slow: Option<String> = None;
        for ((&i, exp), a) in participants.iter().zip(expected).zip(answers) {
            let s = &mut self.slots[i];
            let a = match a {
                Ok(a) => a,
                Err(e) => {
                    failures.push((i, format!("search task failed: {e}")));
                    continue;
                }
            };
            s.stream = a.stream;
            match a.result {
                Ok(hits) => {
                    s.level_pairs += s.len() as f64 * n as f64 * cost;
                    s.level_seconds += a.search_seconds;
                    s.stats.queries += n as u64;
                    s.stats.batches += 1;
                    s.stats.search_seconds += a.search_seconds;
                    s.stats.round_trip_seconds += a.wall;
                    // Busy: much slower than its calibration predicts.
                    if a.wall > self.opts.slow_factor * (exp + 0.005) {
                        s.strikes += 1;
                        if s.strikes >= self.opts.slow_strikes && slow.is_none() {
                            slow = Some(format!(
                                "worker {} answered {} batches in a row slower than {}× its calibration (last {:.1} ms, expected {:.1} ms)",
                                s.spec.address,
                                s.strikes,
                                self.opts.slow_factor,
                                a.wall * 1e3,
                                exp * 1e3
                            ));
                        }
                    } else {
                        s.strikes = 0;
                    }
                    parts.push(hits);
                }
                Err(e) => failures.push((i, e)),
            }
        }
        if !failures.is_empty() {
            return Ok(Err(failures));
        }
        let refs: Vec<&[Hit]> = parts.iter().map(Vec::as_slice).collect();
        let merged = texsyn_engine::merge_answers(n, &refs);
        self.batches_since_recalibration += 1;
        if let Some(l) = self.level.as_mut() {
            l.queries += n as u64;
        }
        if let Some(reason) = slow {
            if self.batches_since_recalibration >= self.opts.recalibrate_cooldown {
                // The answer above is complete; the new partition serves the next batch.
                self.recalibrate(reason)?;
            }
        } else {
            self.maybe_rebalance()?;
        }
        Ok(Ok(merged))
    }
}

/// One round of a batch: the merged answers, or the workers that failed (slot, reason).
type Round = std::result::Result<Vec<Hit>, Vec<(usize, String)>>;

/// Awaits every future, concurrently, in order.
async fn join_all<F>(futures: Vec<F>) -> Vec<F::Output>
where
    F: std::future::Future + Send + 'static,
    F::Output: Send + 'static,
{
    let handles: Vec<_> = futures.into_iter().map(tokio::spawn).collect();
    let mut out = Vec::with_capacity(handles.len());
    for h in handles {
        match h.await {
            Ok(v) => out.push(v),
            Err(e) => std::panic::resume_unwind(e.into_panic()),
        }
    }
    out
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
            level: data.level,
            geometry: data.geometry,
            params: data.params,
            fine: OwnedPlane::of(&data.sample.fine),
            parent: data.sample.parent.as_ref().map(OwnedPlane::of),
            positions: data.positions.to_vec(),
            expected_queries: data.expected_queries,
            queries: 0,
            rebalanced: false,
            assign_seconds: 0.0,
        });
        self.master.space = None;
        self.master.range = 0..0;
        for s in &mut self.slots {
            s.range = 0..0;
            s.level_pairs = 0.0;
            s.level_seconds = 0.0;
        }
        // Dropped and new workers are taken (back) in here.
        self.join_workers();
        self.load_on_workers();
        self.batches_since_recalibration = 0;
        self.repartition("partition", format!("level {} start", data.level))
    }

    fn search(&mut self, batch: &QueryBatch) -> Result<Vec<Hit>> {
        let n = batch.len();
        if n == 0 {
            return Ok(Vec::new());
        }
        let level = self.level.as_ref().context("search before load_level")?;
        if batch.layout() != level.layout() {
            bail!("the queries do not have the loaded level's layout");
        }
        let batch_id = self.next_batch;
        self.next_batch += 1;
        self.current_batch = Some(batch_id);
        let span =
            tracing::debug_span!("batch", level = level.level, batch = batch_id, queries = n);
        let _enter = span.enter();
        let (values, masks) = batch.unpadded();
        let mut rounds = 0;
        loop {
            rounds += 1;
            match self.try_batch(batch, &values, &masks, batch_id)? {
                Ok(hits) => return Ok(hits),
                Err(failures) => {
                    let mut names = Vec::new();
                    for (i, reason) in failures {
                        names.push(self.slots[i].spec.address.clone());
                        self.drop_worker(i, reason);
                    }
                    // Each round drops at least one worker, so this ends.
                    debug_assert!(rounds <= self.slots.len() + 1);
                    self.repartition(
                        "repartition",
                        format!("dropped {}; batch {batch_id} asked again", names.join(", ")),
                    )?;
                }
            }
        }
    }

    fn end_level(&mut self) {
        self.master.space = None;
        self.master.range = 0..0;
        self.current_batch = None;
    }

    fn stats(&self) -> serde_json::Value {
        let total = self.level.as_ref().map_or(0, LevelState::total);
        let workers: Vec<_> = self
            .slots
            .iter()
            .map(|s| {
                serde_json::json!({
                    "address": s.spec.address,
                    "state": if s.active() { "active" } else { "dropped" },
                    "share": if s.active() && total > 0 { partition::share(&s.range, total) } else { 0.0 },
                    "last_share": s.last_share,
                    "queries": s.stats.queries,
                    "batches": s.stats.batches,
                    "seconds": s.stats.search_seconds,
                    "round_trip_seconds": s.stats.round_trip_seconds,
                    "calibrated_pairs_per_second": s.rate,
                    "threads": s.info.as_ref().map(|i| i.threads),
                    "cores": s.info.as_ref().map(|i| i.cores),
                    "kernel": s.info.as_ref().map(|i| i.kernel.clone()),
                    "version": s.info.as_ref().map(|i| i.version.clone()),
                    "load_average": s.info.as_ref().map(|i| i.load_average),
                    "drops": s.drops,
                    "down_reason": s.down_reason,
                })
            })
            .collect();
        serde_json::json!({
            "job": self.opts.job_id,
            "workers": workers,
            "master": {
                "share_enabled": self.opts.master_share,
                "calibrated_pairs_per_second": self.master.rate,
                "queries": self.master.stats.queries,
                "batches": self.master.stats.batches,
                "seconds": self.master.stats.search_seconds,
            },
            "local_fallback_levels": self.local_levels,
            "skipped_hosts": self
                .opts
                .skipped_hosts
                .iter()
                .map(|(host, reason)| serde_json::json!({"ssh": host, "reason": reason}))
                .collect::<Vec<_>>(),
            "epochs": self.epoch,
            "events": self.events,
        })
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
    fn chunks_fit_the_message_limit() {
        assert_eq!(
            queries_per_chunk(64 << 20, 106),
            texsyn_proto::wire::MAX_QUERIES.min((64 << 20) / 220)
        );
        let per = queries_per_chunk(64 << 10, 106);
        assert!(per * (2 * 106 + 8) + 4096 <= 64 << 10);
        assert_eq!(queries_per_chunk(0, 106), 1);
    }

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
        assert_eq!(c.events()[0].kind, "unavailable");
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
