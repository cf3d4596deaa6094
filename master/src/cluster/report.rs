//! The cluster's part of the run report (ARCHITECTURE §4.3): every drop,
//! rejoin, (re)partition, recalibration and fallback as an [`Event`], and per
//! worker its share, queries, times, calibration and state.

use serde::Serialize;

use super::policy::share;
use super::{ClusterSearch, LevelState};

/// What happened; serialised as the lower-case name (`"drop"`, ...).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum EventKind {
    /// A worker could not be reached or refused the handshake.
    Unavailable,
    /// A worker failed, missed its deadline or answered malformed data.
    Drop,
    /// A dropped or unreachable worker was taken (back) in.
    Rejoin,
    /// The first cut of a level.
    Partition,
    /// A new cut of the level (after a drop, a recalibration or a rebalance).
    Repartition,
    /// The workers were calibrated again.
    Recalibrate,
    /// No worker left: the master searches the level itself.
    Fallback,
    /// Every worker missed its deadline: the batch was asked again with
    /// longer deadlines before any worker was dropped.
    Retry,
}

/// One entry of the run report's event list.
#[derive(Debug, Clone, Serialize)]
pub struct Event {
    pub kind: EventKind,
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

#[derive(Debug, Clone, Serialize)]
pub struct ShareEntry {
    pub worker: String,
    pub start: u64,
    pub end: u64,
    pub share: f64,
}

/// What one participant (a worker or the master) searched so far.
#[derive(Debug, Clone, Default, Serialize)]
pub(super) struct PartStats {
    pub queries: u64,
    pub batches: u64,
    /// Search time reported by the worker (or spent by the master).
    pub search_seconds: f64,
    /// Wall time from sending a batch to its answer.
    pub round_trip_seconds: f64,
    /// Interim reports the worker sent and updates the master forwarded to
    /// it while linked batches ran (ARCHITECTURE §4.7).
    pub link_reports: u64,
    pub link_updates: u64,
}

impl ClusterSearch {
    /// Records an event at the current level, batch and epoch.
    pub(super) fn event(&mut self, kind: EventKind, worker: Option<String>, reason: String) {
        self.events.push(Event {
            kind,
            level: self.level.as_ref().map(|l| l.data.level),
            batch: self.current_batch,
            epoch: self.epoch,
            worker,
            reason,
            shares: Vec::new(),
        });
    }

    /// Records a (re)partition of the level with the shares of `active`
    /// workers (and the master's, with `master_share`).
    pub(super) fn partition_event(&mut self, kind: EventKind, active: &[usize], reason: &str) {
        let Some(level) = &self.level else { return };
        let (lv, total, epoch) = (level.data.level, level.total(), self.epoch);
        let mut shares: Vec<ShareEntry> = active
            .iter()
            .map(|&i| {
                let s = &self.slots[i];
                ShareEntry {
                    worker: s.spec.address.clone(),
                    start: s.range.start,
                    end: s.range.end,
                    share: share(&s.range, total),
                }
            })
            .collect();
        if self.opts.master_share {
            shares.push(ShareEntry {
                worker: "master".into(),
                start: self.master.range.start,
                end: self.master.range.end,
                share: share(&self.master.range, total),
            });
        }
        tracing::info!(level = lv, epoch, ?shares, %reason, "partition");
        self.events.push(Event {
            kind,
            level: Some(lv),
            batch: self.current_batch,
            epoch,
            worker: None,
            reason: reason.to_string(),
            shares,
        });
    }

    /// The run report: workers, the master's share, fallbacks and events.
    pub(super) fn report(&self) -> serde_json::Value {
        let total = self.level.as_ref().map_or(0, LevelState::total);
        let workers: Vec<_> = self
            .slots
            .iter()
            .map(|s| {
                serde_json::json!({
                    "address": s.spec.address,
                    "state": if s.active() { "active" } else { "dropped" },
                    "share": if s.active() && total > 0 { share(&s.range, total) } else { 0.0 },
                    "last_share": s.last_share,
                    "queries": s.stats.queries,
                    "batches": s.stats.batches,
                    "seconds": s.stats.search_seconds,
                    "round_trip_seconds": s.stats.round_trip_seconds,
                    "link_reports": s.stats.link_reports,
                    "link_updates": s.stats.link_updates,
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn event_kinds_serialise_as_their_names() {
        let kinds = [
            (EventKind::Unavailable, "unavailable"),
            (EventKind::Drop, "drop"),
            (EventKind::Rejoin, "rejoin"),
            (EventKind::Partition, "partition"),
            (EventKind::Repartition, "repartition"),
            (EventKind::Recalibrate, "recalibrate"),
            (EventKind::Fallback, "fallback"),
            (EventKind::Retry, "retry"),
        ];
        for (k, name) in kinds {
            assert_eq!(serde_json::to_value(k).unwrap(), name);
        }
        let e = Event {
            kind: EventKind::Drop,
            level: Some(1),
            batch: None,
            epoch: 3,
            worker: Some("a:1".into()),
            reason: "gone".into(),
            shares: Vec::new(),
        };
        assert_eq!(
            serde_json::to_string(&e).unwrap(),
            r#"{"kind":"drop","level":1,"batch":null,"epoch":3,"worker":"a:1","reason":"gone"}"#
        );
    }
}
