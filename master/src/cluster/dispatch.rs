//! One batch on the cluster (ARCHITECTURE §4.1, §4.3): the queries go to every
//! worker with a range (in chunks under its message limit, on its long-lived
//! `Search` stream, with a deadline from its calibration) while the master
//! searches its own share; the answers are checked and merged
//! ([`texsyn_engine::merge_answers`]: minimum distance, ties to the lowest
//! global index). Every answer is checked: the master scores each returned
//! reference itself, and a worker whose distance is wrong is dropped for the
//! rest of the run. When any worker fails, nothing of the round is used: the
//! failed workers are dropped, the level is cut anew and the whole batch is
//! asked again; when every worker missed its deadline (more likely a stall of
//! the master's machine or network than of all workers), the round is first
//! asked once more with longer deadlines.

use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result};
use texsyn_engine::{Hit, Link, QueryBatch};
use texsyn_proto::v1 as pb;
use tracing::Instrument;

use super::conn::{self, block_on, PartAnswer};
use super::error::ClusterError;
use super::policy;
use super::report::EventKind;
use super::ClusterSearch;

/// One round of a batch: the merged answers, or the workers that failed
/// (slot, reason) and how many took part.
type Round = std::result::Result<Vec<Hit>, (Vec<(usize, ClusterError)>, usize)>;

/// How much longer the deadlines of the one retry are when every worker
/// missed its deadline.
const RETRY_STRETCH: f64 = 4.0;

/// A batch as sent: its id and the queries without padding.
struct Outgoing<'a> {
    batch: &'a QueryBatch,
    id: u64,
    /// Matches per query: 1 = best match (answers one hit per query); more
    /// = top-k (answers `k` slots per query, padded with `Hit::NONE`).
    k: usize,
    /// Top-k only: per query, a cut above its whole-space top-k
    /// ([`texsyn_engine::OwnedLevel::topk_cuts`]), so each range answers
    /// only what can enter the merge.
    cut: Option<&'a [u64]>,
    values: &'a [u8],
    masks: &'a [u8],
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

/// Awaits every future, concurrently, in order.
pub(super) async fn join_all<F>(futures: Vec<F>) -> Vec<F::Output>
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

impl ClusterSearch {
    /// Searches one batch until a round completes; each failed round drops at
    /// least one worker and cuts the level anew (ARCHITECTURE §4.3).
    pub(super) fn search_batch(
        &mut self,
        batch: &QueryBatch,
        id: u64,
        k: usize,
        cut: Option<&[u64]>,
    ) -> Result<Vec<Hit>> {
        let (values, masks) = batch.unpadded();
        let out = Outgoing {
            batch,
            id,
            k,
            cut,
            values: &values,
            masks: &masks,
        };
        let mut rounds = 0;
        let mut stretch = 1.0;
        loop {
            rounds += 1;
            let (failures, took_part) = match self.try_batch(&out, stretch)? {
                Ok(hits) => return Ok(hits),
                Err(f) => f,
            };
            let all_missed = took_part > 0
                && failures.len() == took_part
                && failures
                    .iter()
                    .all(|(_, e)| matches!(e, ClusterError::Deadline(_)));
            if all_missed && stretch == 1.0 {
                stretch = RETRY_STRETCH;
                for &(i, _) in &failures {
                    // Their streams may still carry the late answers.
                    self.slots[i].stream = None;
                }
                self.event(
                    EventKind::Retry,
                    None,
                    format!(
                        "every worker missed its deadline; batch {id} asked again with {RETRY_STRETCH}× the deadlines"
                    ),
                );
                continue;
            }
            let mut names = Vec::new();
            for (i, reason) in failures {
                names.push(self.slots[i].spec.address.clone());
                self.drop_worker(i, reason);
            }
            // Each round but the one retry drops at least one worker, so this ends.
            debug_assert!(rounds <= self.slots.len() + 2);
            self.repartition(
                EventKind::Repartition,
                format!("dropped {}; batch {id} asked again", names.join(", ")),
            )?;
        }
    }

    /// Opens the search stream of every slot in `participants` that has none
    /// (streams are kept across batches and levels), each within the prompt
    /// timeout × `stretch` (a retried batch's workers were all late); the
    /// failures.
    fn open_streams(&mut self, participants: &[usize], stretch: f64) -> Vec<(usize, ClusterError)> {
        let need: Vec<usize> = participants
            .iter()
            .copied()
            .filter(|&i| self.slots[i].stream.is_none())
            .collect();
        if need.is_empty() {
            return Vec::new();
        }
        let d = self.prompt_timeout().mul_f64(stretch);
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
        failures
    }

    /// Slot `i`'s part of the batch: the chunks under its message limit, its
    /// range and its deadline from `now` (`stretch` × the usual one).
    fn part_for(
        &mut self,
        i: usize,
        out: &Outgoing,
        expected: f64,
        stretch: f64,
        now: Instant,
        link: Option<conn::BatchLink>,
    ) -> conn::Part {
        let s = &self.slots[i];
        let (n, dims) = (out.batch.len(), out.batch.layout().dims());
        let lv = self.level.as_ref().map_or(0, |l| l.data.level);
        let deadline = now
            + policy::batch_deadline(
                expected,
                self.opts.deadline_factor,
                self.opts.deadline_floor,
            )
            .mul_f64(stretch);
        let per = queries_per_chunk(s.info.as_ref().map_or(4 << 20, |x| x.max_message), dims);
        let first_chunk = self.next_chunk;
        let chunks: Vec<pb::SearchBatch> = (0..n)
            .step_by(per)
            .enumerate()
            .map(|(k, q0)| {
                let q1 = (q0 + per).min(n);
                let (bound_index, bound_distance) =
                    texsyn_proto::wire::bounds_to_proto(out.batch, q0..q1);
                pb::SearchBatch {
                    job_id: self.opts.job_id.clone(),
                    level: lv as u32,
                    batch_id: first_chunk.wrapping_add(k as u64),
                    top_k: out.k as u32,
                    count: (q1 - q0) as u32,
                    values: out.values[q0 * dims..q1 * dims].to_vec(),
                    masks: out.masks[q0 * dims..q1 * dims].to_vec(),
                    epoch: self.epoch,
                    bound_index,
                    bound_distance,
                    topk_cut: out.cut.map_or_else(Vec::new, |c| c[q0..q1].to_vec()),
                    ..Default::default()
                }
            })
            .collect();
        self.next_chunk = self.next_chunk.wrapping_add(chunks.len() as u64);
        conn::Part {
            chunks,
            range: s.range.clone(),
            deadline,
            link,
        }
    }

    /// Searches the master's own share, if it has one (linked with the
    /// workers' parts through `link`).
    fn search_master_share(
        &mut self,
        batch: &QueryBatch,
        k: usize,
        cut: Option<&[u64]>,
        link: Option<&Link>,
    ) -> Result<Option<Vec<Hit>>> {
        let (Some(space), Some(level)) = (&self.master.space, &self.level) else {
            return Ok(None);
        };
        let t = Instant::now();
        let range = self.master.range.clone();
        let hits = if k == 1 {
            let (hits, prune) =
                self.engine
                    .search_best_linked(space, range, batch, &level.data.params, link)?;
            self.level_prune.add(&prune);
            hits
        } else {
            let params = &level.data.params;
            let lists = match cut {
                Some(c) => {
                    self.engine
                        .search_topk_below(space, range.clone(), batch, params, k, c)?
                }
                None => self
                    .engine
                    .search_topk(space, range.clone(), batch, params, k)?,
            };
            conn::flat_topk(&lists, k, &range, cut).map_err(anyhow::Error::msg)?
        };
        self.master.stats.search_seconds += t.elapsed().as_secs_f64();
        self.master.stats.queries += batch.len() as u64;
        self.master.stats.batches += 1;
        Ok(Some(hits))
    }

    /// Searches one batch on the current partition. Err(failures) when any
    /// worker failed: nothing of this round is used.
    fn try_batch(&mut self, out: &Outgoing, stretch: f64) -> Result<Round> {
        let level = self.level.as_ref().context("search before load_level")?;
        let cost = policy::pair_cost(level.layout().stride(), self.opts.calibration.dims);
        let n = out.batch.len();
        let participants = self.slots_where(|s| s.active() && s.len() > 0);
        let failures = self.open_streams(&participants, stretch);
        if !failures.is_empty() {
            return Ok(Err((failures, participants.len())));
        }
        // No worker waits longer than a share searched at the cap's speed
        // (a fraction of the typical participant's, or the master's own).
        let mut rates: Vec<f64> = participants.iter().map(|&i| self.slots[i].rate).collect();
        rates.extend(self.master.rate);
        let floor_rate = policy::deadline_rate_floor(&rates);

        // A best-1 batch split over several searchers is linked: each range
        // prunes against the others' finds as they come (ARCHITECTURE §4.7).
        let searchers = participants.len() + usize::from(self.master.space.is_some());
        let link = (out.k == 1 && searchers > 1).then(|| Arc::new(Link::new(n)));
        let shared = link.as_ref().map(|l| conn::BatchLink {
            link: l.clone(),
            found: Arc::new(tokio::sync::Notify::new()),
        });
        // Send every worker its part; the tasks run while the master searches its own share.
        let now = Instant::now();
        let mut handles = Vec::with_capacity(participants.len());
        let mut expected = Vec::with_capacity(participants.len());
        for &i in &participants {
            let s = &self.slots[i];
            let exp = policy::expected_seconds(s.len(), n, cost, s.rate.max(floor_rate));
            let span = tracing::debug_span!("worker", address = %s.spec.address, batch = out.id);
            let part = self.part_for(i, out, exp, stretch, now, shared.clone());
            let stream = self.slots[i].stream.take().expect("opened above");
            handles.push(
                self.rt()
                    .spawn(conn::run_part(stream, part).instrument(span)),
            );
            expected.push(exp);
        }
        let mut parts: Vec<Vec<Hit>> = Vec::new();
        parts.extend(self.search_master_share(out.batch, out.k, out.cut, link.as_deref())?);
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
            let checked = match a {
                Ok(a) => self
                    .take_answer(i, a, n, cost, exp, &mut slow)
                    .and_then(|hits| self.check_answers(out.batch, hits, out.k)),
                Err(e) => Err(ClusterError::Task(e.to_string())),
            };
            match checked {
                Ok(hits) => parts.push(hits),
                Err(e) => failures.push((i, e)),
            }
        }
        if !failures.is_empty() {
            return Ok(Err((failures, participants.len())));
        }
        let merged = if out.k == 1 {
            let refs: Vec<&[Hit]> = parts.iter().map(Vec::as_slice).collect();
            texsyn_engine::with_bounds(out.batch.bounds(), &texsyn_engine::merge_answers(n, &refs))
        } else {
            merge_flat_topk(&parts, n, out.k)
        };
        self.after_batch(n, slow)?;
        Ok(Ok(merged))
    }

    /// Takes slot `i`'s answer to a batch of `n` queries expected to take
    /// `exp` seconds: its stream back, its statistics and strikes; `slow` gets
    /// the reason for a recalibration when it struck out (the first one only).
    fn take_answer(
        &mut self,
        i: usize,
        a: PartAnswer,
        n: usize,
        cost: f64,
        exp: f64,
        slow: &mut Option<String>,
    ) -> std::result::Result<Vec<Hit>, ClusterError> {
        let s = &mut self.slots[i];
        s.stream = a.stream;
        // The messages were exchanged whether or not the answer holds.
        s.stats.link_reports += a.traffic.reports;
        s.stats.link_updates += a.traffic.updates;
        let hits = a.result?;
        self.level_prune.add(&a.prune);
        s.level_pairs += s.len() as f64 * n as f64 * cost;
        s.level_seconds += a.search_seconds;
        s.stats.queries += n as u64;
        s.stats.batches += 1;
        s.stats.search_seconds += a.search_seconds;
        s.stats.round_trip_seconds += a.wall;
        // Busy: much slower than its calibration predicts.
        let is_slow = policy::is_slow(a.wall, exp, self.opts.slow_factor);
        s.strikes = policy::strikes_after(s.strikes, is_slow);
        if is_slow && policy::strikes_out(s.strikes, self.opts.slow_strikes) && slow.is_none() {
            *slow = Some(format!(
                "worker {} answered {} batches in a row slower than {}× its calibration (last {:.1} ms, expected {:.1} ms)",
                s.spec.address,
                s.strikes,
                self.opts.slow_factor,
                a.wall * 1e3,
                exp * 1e3
            ));
        }
        Ok(hits)
    }

    /// Scores every reference a worker returned against its query, from the
    /// level the master holds (O(dims) per answer): an answer is accepted
    /// only with the distance its reference really has, so a faulty or lying
    /// worker cannot win the merge with a made-up distance.
    fn check_answers(
        &self,
        batch: &QueryBatch,
        hits: Vec<Hit>,
        k: usize,
    ) -> std::result::Result<Vec<Hit>, ClusterError> {
        let Some(level) = self.level.as_ref() else {
            return Ok(hits);
        };
        let mut scorer = texsyn_engine::Scorer::new(&level.data);
        for (slot, h) in hits.iter().enumerate() {
            if h.is_none() {
                continue;
            }
            let q = slot / k;
            let actual = scorer.distance(h.index, batch, q);
            if actual != Some(h.dist) {
                return Err(ClusterError::WrongAnswer {
                    query: q,
                    index: h.index,
                    claimed: h.dist,
                    actual: actual.unwrap_or(u64::MAX),
                });
            }
        }
        Ok(hits)
    }

    /// After a complete batch: count it, then recalibrate (a worker struck
    /// out and the cooldown is over) or consider a rebalance. The answer is
    /// complete already; a new partition serves the next batch.
    fn after_batch(&mut self, n: usize, slow: Option<String>) -> Result<()> {
        self.batches_since_recalibration += 1;
        if let Some(l) = self.level.as_mut() {
            l.queries += n as u64;
        }
        match slow {
            Some(reason) => {
                if policy::cooldown_over(
                    self.batches_since_recalibration,
                    self.opts.recalibrate_cooldown,
                ) {
                    self.recalibrate(reason)?;
                }
                Ok(())
            }
            None => self.maybe_rebalance(),
        }
    }
}

/// Merges flat top-k answers (`k` slots per query, padded with
/// `Hit::NONE`) of disjoint ranges into one flat answer.
fn merge_flat_topk(parts: &[Vec<Hit>], n: usize, k: usize) -> Vec<Hit> {
    let mut out = Vec::with_capacity(n * k);
    for q in 0..n {
        let mut best: Vec<Hit> = Vec::new();
        for p in parts {
            let list: Vec<Hit> = p[q * k..(q + 1) * k]
                .iter()
                .copied()
                .filter(|h| !h.is_none())
                .collect();
            best = texsyn_engine::merge_topk(&best, &list, k);
        }
        let len = best.len();
        out.extend(best);
        out.extend(std::iter::repeat_n(Hit::NONE, k - len));
    }
    out
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
}
