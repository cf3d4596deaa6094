//! Worker membership (ARCHITECTURE §4.2, §4.3): one slot per worker, joined
//! with the version handshake and a calibration, dropped on any fault, taken
//! back at the next level (rejoin), calibrated again when it turns slow; and
//! the partition applied to the members with `Assign` under a new epoch.

use std::ops::Range;
use std::time::Duration;

use anyhow::{bail, Context, Result};
use texsyn_engine::VectorSpace;
use texsyn_proto::v1 as pb;
use tracing::Instrument;

use super::conn::{self, block_on, Client, SearchStream, WorkerInfo, WorkerSpec};
use super::dispatch::join_all;
use super::error::{ClusterError, ClusterResult};
use super::policy::{self, call_deadline};
use super::report::{EventKind, PartStats};
use super::ClusterSearch;

/// One worker as the master sees it.
pub(super) struct Slot {
    pub spec: WorkerSpec,
    pub client: Option<Client>,
    pub stream: Option<SearchStream>,
    pub info: Option<WorkerInfo>,
    /// Calibrated reference × query pairs per second.
    pub rate: f64,
    pub range: Range<u64>,
    /// Level the worker has loaded (LoadLevel succeeded).
    pub loaded: Option<usize>,
    pub strikes: u32,
    pub stats: PartStats,
    pub drops: u32,
    pub down_reason: Option<String>,
    /// Last non-empty share of a level.
    pub last_share: f64,
    /// Returned a wrong answer: never used again in this run.
    pub distrusted: bool,
    /// This level's searched pairs (in calibration units) and reported seconds.
    pub level_pairs: f64,
    pub level_seconds: f64,
}

impl Slot {
    pub fn new(spec: WorkerSpec) -> Self {
        Self {
            spec,
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
            distrusted: false,
            level_pairs: 0.0,
            level_seconds: 0.0,
        }
    }

    pub fn active(&self) -> bool {
        self.client.is_some()
    }

    pub fn len(&self) -> u64 {
        self.range.end - self.range.start
    }
}

/// Per slot: the result of a call made on several workers.
type Results<T> = Vec<(usize, ClusterResult<T>)>;

impl ClusterSearch {
    /// Slots that pass `f`, in order.
    pub(super) fn slots_where(&self, f: impl Fn(&Slot) -> bool) -> Vec<usize> {
        (0..self.slots.len())
            .filter(|&i| f(&self.slots[i]))
            .collect()
    }

    pub(super) fn down_summary(&self) -> String {
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

    /// Drops a worker: its stream and client are closed and its range will be
    /// re-spread by the next partition.
    pub(super) fn drop_worker(&mut self, i: usize, reason: ClusterError) {
        let distrust = reason.is_untrustworthy();
        let reason = if distrust {
            format!("{reason}; the worker is not trusted again in this run")
        } else {
            reason.to_string()
        };
        let s = &mut self.slots[i];
        tracing::warn!(worker = %s.spec.address, %reason, "dropping worker");
        s.client = None;
        s.stream = None;
        s.loaded = None;
        s.range = 0..0;
        s.strikes = 0;
        s.drops += 1;
        s.distrusted |= distrust;
        s.down_reason = Some(reason.clone());
        let addr = s.spec.address.clone();
        self.event(EventKind::Drop, Some(addr), reason);
    }

    /// Calibrates the workers one after the other: run side by side, workers
    /// sharing a machine (or its memory bandwidth) would measure each other's
    /// load instead of their own speed. Failures are returned, not applied.
    fn calibrate_each(&self, clients: Vec<(usize, Client)>) -> Results<f64> {
        let (size, d) = (self.opts.calibration, self.opts.call_timeout);
        let mut results: Results<f64> = clients.iter().map(|(i, _)| (*i, Ok(0.0))).collect();
        // Two rounds over all workers, the best of each worker counts: a short
        // run is easily disturbed, and the first one on a machine runs cold.
        for _ in 0..2 {
            for ((i, c), (_, r)) in clients.iter().zip(results.iter_mut()) {
                let Ok(best) = r else { continue };
                let span = tracing::info_span!("worker", address = %self.slots[*i].spec.address);
                *r = block_on(
                    self.rt(),
                    conn::calibrate(c.clone(), size, d).instrument(span),
                )
                .map(|rate| rate.max(*best));
            }
        }
        results
    }

    /// Connect and Info (version handshake) with the slots `todo`, side by side.
    /// A worker already known to be down or dropped gets the short
    /// [`ClusterSearch::prompt_timeout`] for both: a worker still cut off or
    /// stopped at a level start then delays the level by that much, not by the
    /// full connect and call timeouts of a first contact.
    fn handshakes(&self, todo: &[usize]) -> Results<conn::Handshake> {
        let o = &self.opts;
        let jobs: Vec<_> = todo
            .iter()
            .map(|&i| {
                let slot = &self.slots[i];
                let (connect, call) = if slot.down_reason.is_some() || slot.drops > 0 {
                    (self.prompt_timeout(), self.prompt_timeout())
                } else {
                    (o.connect_timeout, o.call_timeout)
                };
                let spec = slot.spec.clone();
                let span = tracing::info_span!("worker", address = %spec.address);
                conn::handshake(spec, o.tls.clone(), o.protocol_version, connect, call)
                    .instrument(span)
            })
            .collect();
        let results = block_on(self.rt(), join_all(jobs));
        todo.iter().copied().zip(results).collect()
    }

    /// How long a call that asks no work of the worker may take: a retry of a
    /// known-down worker (connect and Info) and opening a search stream. The
    /// least search deadline, or the connect timeout if that is shorter: a
    /// healthy worker answers these in milliseconds, and a silent one must
    /// not hold a level for the full call timeout.
    pub(super) fn prompt_timeout(&self) -> Duration {
        self.opts.connect_timeout.min(self.opts.deadline_floor)
    }

    /// Connects (Info, then Calibrate) every worker not in use.
    pub(super) fn join_workers(&mut self) {
        let todo = self.slots_where(|s| !s.active() && !s.distrusted);
        if todo.is_empty() {
            return;
        }
        let mut ok = Vec::new();
        let mut errors = Vec::new();
        for (i, r) in self.handshakes(&todo) {
            match r {
                Ok(h) => ok.push((i, h)),
                Err(e) => errors.push((i, e)),
            }
        }
        let calibrated =
            self.calibrate_each(ok.iter().map(|(i, h)| (*i, h.client.clone())).collect());
        for ((i, h), (_, rate)) in ok.into_iter().zip(calibrated) {
            match rate {
                Ok(rate) => self.joined(i, h, rate),
                Err(e) => errors.push((i, e)),
            }
        }
        for (i, reason) in errors {
            let reason = reason.to_string();
            let was_down = self.slots[i].down_reason.is_some();
            let s = &mut self.slots[i];
            tracing::debug!(worker = %s.spec.address, %reason, "worker not available");
            s.down_reason = Some(reason.clone());
            if !was_down {
                let addr = s.spec.address.clone();
                self.event(EventKind::Unavailable, Some(addr), reason);
            }
        }
    }

    /// A worker passed the handshake and calibration: it is in use (again).
    fn joined(&mut self, i: usize, h: conn::Handshake, rate: f64) {
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
            self.event(EventKind::Rejoin, Some(addr), reason);
        }
    }

    /// LoadLevel on every active worker that does not have the level yet.
    pub(super) fn load_on_workers(&mut self) {
        let Some(level) = &self.level else { return };
        let lv = level.data.level;
        let todo = self.slots_where(|s| s.active() && s.loaded != Some(lv));
        if todo.is_empty() {
            return;
        }
        let total = level.total();
        let bytes = level.image_bytes();
        let d = call_deadline(self.opts.call_timeout, bytes as f64, 20e6);
        let jobs: Vec<_> = todo
            .iter()
            .map(|&i| {
                let s = &self.slots[i];
                let max_message = s.info.as_ref().map_or(4 << 20, |inf| inf.max_message);
                let parts = level.load_parts(&self.opts.job_id, max_message);
                let client = s.client.clone().expect("active");
                let span = tracing::info_span!("worker", address = %s.spec.address);
                conn::load_level(client, parts, d).instrument(span)
            })
            .collect();
        let results = block_on(self.rt(), join_all(jobs));
        for (i, r) in todo.into_iter().zip(results) {
            match r {
                Ok(reply) if reply.total_vectors == total => self.slots[i].loaded = Some(lv),
                Ok(reply) => self.drop_worker(
                    i,
                    ClusterError::VectorCount {
                        counted: reply.total_vectors,
                        total,
                    },
                ),
                Err(e) => self.drop_worker(i, e),
            }
        }
    }

    /// Calibrates every active worker again and cuts the level anew.
    pub(super) fn recalibrate(&mut self, reason: String) -> Result<()> {
        let clients = self
            .slots_where(Slot::active)
            .into_iter()
            .map(|i| (i, self.slots[i].client.clone().expect("active")))
            .collect();
        let mut rates = Vec::new();
        for (i, r) in self.calibrate_each(clients) {
            match r {
                Ok(rate) => {
                    self.slots[i].rate = rate;
                    rates.push(format!("{} {:.3e}", self.slots[i].spec.address, rate));
                }
                Err(e) => self.drop_worker(i, e),
            }
        }
        self.event(
            EventKind::Recalibrate,
            None,
            format!("{reason}; new rates (pairs/s): {}", rates.join(", ")),
        );
        // Workers that came back (or were never reached) are taken in here too.
        self.join_workers();
        self.load_on_workers();
        self.batches_since_recalibration = 0;
        self.repartition(EventKind::Repartition, format!("recalibrated: {reason}"))
    }

    /// Cuts the level over the active workers (and the master's share) in
    /// proportion to their throughput and assigns the ranges under a new epoch.
    /// Workers that fail are dropped and the cut is made again; with none left
    /// the master takes the whole level (or fails with `require_cluster`).
    pub(super) fn repartition(&mut self, kind: EventKind, reason: String) -> Result<()> {
        let Some(level) = &self.level else {
            bail!("no level loaded");
        };
        let lv = level.data.level;
        loop {
            let active = self.slots_where(|s| s.active() && s.loaded == Some(lv));
            self.epoch += 1;
            if active.is_empty() {
                return self.fall_back();
            }
            let mut weights: Vec<f64> = active.iter().map(|&i| self.slots[i].rate).collect();
            if self.opts.master_share {
                weights.push(self.master_rate()?);
            }
            let total = self.level.as_ref().map_or(0, |l| l.total());
            let ranges = policy::proportional(total, &weights);
            if !self.assign(&active, &ranges) {
                continue;
            }
            let master_range = if self.opts.master_share {
                ranges.last().cloned().unwrap_or(0..0)
            } else {
                0..0
            };
            self.set_master_range(master_range)?;
            self.partition_event(kind, &active, &reason);
            return Ok(());
        }
    }

    /// No worker left: the master searches the whole level (or, with
    /// `require_cluster`, the run fails).
    fn fall_back(&mut self) -> Result<()> {
        let level = self.level.as_ref().context("no level loaded")?;
        let (lv, total) = (level.data.level, level.total());
        for s in &mut self.slots {
            s.range = 0..0;
        }
        if self.opts.require_cluster {
            bail!(ClusterError::NoneLeft {
                level: lv,
                reasons: self.down_summary(),
            });
        }
        if self.master.range != (0..total) || self.master.space.is_none() {
            tracing::warn!(
                level = lv,
                reasons = %self.down_summary(),
                "no search worker left; searching this level locally"
            );
            self.event(
                EventKind::Fallback,
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
        Ok(())
    }

    /// `Assign` of `ranges` to the slots `active` under the current epoch.
    /// False when a worker failed (it is dropped; the cut must be made again).
    fn assign(&mut self, active: &[usize], ranges: &[Range<u64>]) -> bool {
        let Some(level) = &self.level else {
            return false;
        };
        let (lv, total) = (level.data.level, level.total());
        let stride = level.layout().stride() as f64;
        let jobs: Vec<_> = active
            .iter()
            .zip(ranges)
            .map(|(&i, r)| {
                let s = &self.slots[i];
                let len = r.end - r.start;
                let d = call_deadline(self.opts.call_timeout, len as f64 * stride, 100e6);
                let req = pb::AssignRequest {
                    job_id: self.opts.job_id.clone(),
                    level: lv as u32,
                    start: r.start,
                    end: r.end,
                    lbg_probes: policy::range_probes(self.lbg_probes, len),
                    epoch: self.epoch,
                };
                let span = tracing::info_span!("worker", address = %s.spec.address);
                conn::assign(s.client.clone().expect("active"), req, d).instrument(span)
            })
            .collect();
        let results = block_on(self.rt(), join_all(jobs));
        let mut failed = false;
        for ((&i, r), res) in active.iter().zip(ranges).zip(results) {
            let reply = match res {
                Ok(reply) if reply.vectors == r.end - r.start => reply,
                Ok(reply) => {
                    failed = true;
                    let e = ClusterError::AssignCount {
                        built: reply.vectors,
                        start: r.start,
                        end: r.end,
                    };
                    self.drop_worker(i, e);
                    continue;
                }
                Err(e) => {
                    failed = true;
                    self.drop_worker(i, e);
                    continue;
                }
            };
            if let Some(l) = self.level.as_mut() {
                if reply.build_seconds.is_finite() {
                    l.assign_seconds = l.assign_seconds.max(reply.build_seconds);
                }
            }
            let s = &mut self.slots[i];
            s.range = r.clone();
            s.strikes = 0;
            if !r.is_empty() {
                s.last_share = policy::share(r, total);
            }
        }
        !failed
    }

    /// The master's calibrated rate (calibrated once, on first use).
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
                let d = &level.data;
                self.master.space = Some(VectorSpace::build_with(
                    &d.sample(),
                    &d.geometry,
                    &d.positions,
                    range.clone(),
                    texsyn_engine::Storage::Auto,
                )?);
            }
        }
        self.master.range = range;
        Ok(())
    }

    /// Once per level, after some batches: if the workers' measured throughput
    /// says the calibrated partition is off ([`policy::rebalance`]), cut the
    /// level anew by the measured rates.
    pub(super) fn maybe_rebalance(&mut self) -> Result<()> {
        let Some(level) = &self.level else {
            return Ok(());
        };
        // (The master's own share keeps its calibrated weight, so it is left alone.)
        if level.rebalanced
            || self.opts.master_share
            || self.batches_since_recalibration < policy::REBALANCE_AFTER
        {
            return Ok(());
        }
        let parts = self.slots_where(|s| s.active() && s.len() > 0);
        let measured: Vec<policy::Measured> = parts
            .iter()
            .map(|&i| policy::Measured {
                len: self.slots[i].len(),
                pairs: self.slots[i].level_pairs,
                seconds: self.slots[i].level_seconds,
            })
            .collect();
        let progress = policy::LevelProgress {
            remaining_queries: level.expected_queries.saturating_sub(level.queries),
            assign_seconds: level.assign_seconds,
        };
        let Some(rates) = policy::rebalance(&measured, progress) else {
            return Ok(());
        };
        let lv = level.data.level;
        if let Some(l) = self.level.as_mut() {
            l.rebalanced = true;
        }
        let mut text = Vec::new();
        for (&i, r) in parts.iter().zip(&rates) {
            let s = &mut self.slots[i];
            text.push(format!(
                "{} {:.3e} (calibrated {:.3e})",
                s.spec.address, r, s.rate
            ));
            s.rate = *r;
        }
        tracing::info!(level = lv, rates = %text.join(", "), "rebalancing from measured throughput");
        self.repartition(
            EventKind::Repartition,
            format!(
                "rebalanced from measured throughput (pairs/s): {}",
                text.join(", ")
            ),
        )
    }
}
