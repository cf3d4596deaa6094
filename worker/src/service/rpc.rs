//! The `texsyn.v1.Worker` RPCs.

use std::future::Future;
use std::ops::Range;
use std::pin::Pin;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Instant;

use texsyn_engine::calibrate::{calibrate, CalibrationSize};
use texsyn_engine::layout::SLACK;
use texsyn_engine::lbg::{check_probes, default_seeds, range_seed};
use texsyn_engine::{
    Codebook, Engine, Hit, LbgConfig, Link, OwnedLevel, PruneStats, QueryBatch, Storage,
    VectorSpace,
};
use texsyn_proto::v1 as proto;
use texsyn_proto::v1::worker_server::Worker;
use texsyn_proto::wire::{
    bounds_from_proto, check_job_id, engine_status, invalid, lowered_from_proto, lowered_to_proto,
    prune_to_proto, LevelAssembly, LINK_INTERVAL, MAX_QUERIES, MAX_TOP_K,
};
use texsyn_proto::PROTOCOL_VERSION;
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status, Streaming};

use super::state::{Assigned, Level, Shared};

/// Upper bound of one encoded `Hit` in a `SearchResult` (tag, two varints, length).
const HIT_WIRE_BYTES: usize = 24;
/// A search call's bytes per query component: values and masks as received
/// (2), and the query batch built from them with its padding (4).
const BATCH_BYTES_PER_COMPONENT: u64 = 6;
/// A search call's bytes per answer: the engine's hit and top-k heap entry,
/// the protobuf hit and its encoding.
const ANSWER_BYTES_PER_HIT: u64 = 16 + 16 + 24 + HIT_WIRE_BYTES as u64;
/// A call's fixed buffers (per-thread sweep masks and bookkeeping).
const CALL_OVERHEAD_BYTES: u64 = 256 << 10;

/// The gRPC service: one per server, cheap to clone.
#[derive(Clone)]
pub struct WorkerService {
    shared: Arc<Shared>,
}

impl WorkerService {
    pub(crate) fn new(shared: Arc<Shared>) -> Self {
        Self { shared }
    }
}

fn exhausted(msg: impl Into<String>) -> Status {
    Status::resource_exhausted(msg)
}

/// The 1-minute load average from /proc/loadavg (0 where unavailable).
fn load_average() -> f64 {
    std::fs::read_to_string("/proc/loadavg")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse().ok())
        .unwrap_or(0.0)
}

#[tonic::async_trait]
impl Worker for WorkerService {
    async fn info(
        &self,
        request: Request<proto::InfoRequest>,
    ) -> Result<Response<proto::InfoReply>, Status> {
        let asked = request.get_ref().protocol_version;
        if asked != PROTOCOL_VERSION {
            return Err(Status::failed_precondition(format!(
                "protocol version mismatch: the master speaks version {asked}, this worker ({}) speaks version {PROTOCOL_VERSION}; run the same texsyn release on both",
                env!("CARGO_PKG_VERSION")
            )));
        }
        let s = &self.shared;
        Ok(Response::new(proto::InfoReply {
            protocol_version: PROTOCOL_VERSION,
            version: env!("CARGO_PKG_VERSION").to_string(),
            cores: std::thread::available_parallelism().map_or(1, |n| n.get()) as u32,
            threads: s.threads as u32,
            load_average: load_average(),
            memory_in_use: s.memory_in_use(),
            memory_limit: s.budget.limit(),
            kernel: s.engine.kernel().name().to_string(),
            calibrated_vectors_per_second: s.calibrated(),
            max_message_bytes: s.max_message as u64,
            jobs: s.job_count() as u32,
            memory_peak: s.budget.peak(),
        }))
    }

    async fn calibrate(
        &self,
        request: Request<proto::CalibrateRequest>,
    ) -> Result<Response<proto::CalibrateReply>, Status> {
        let r = request.into_inner();
        let size = CalibrationSize {
            seed: r.seed,
            vectors: r.vectors,
            dims: r.dims,
            queries: r.queries,
        }
        .or_default();
        size.check(self.shared.budget.limit())
            .map_err(engine_status)?;
        let memory = self
            .shared
            .budget
            .reserve(size.bytes().map_err(engine_status)?, "calibration")?;
        let engine = self.shared.engine;
        let c = self
            .shared
            .run(move || calibrate(&engine, size))
            .await?
            .map_err(engine_status)?;
        drop(memory);
        let (pairs_per_second, seconds) = (c.pairs_per_second, c.seconds);
        let CalibrationSize {
            vectors,
            dims,
            queries,
            ..
        } = size;
        self.shared.set_calibrated(pairs_per_second);
        tracing::info!(vectors, dims, queries, pairs_per_second, "calibrated");
        Ok(Response::new(proto::CalibrateReply {
            pairs_per_second,
            seconds,
        }))
    }

    async fn load_level(
        &self,
        request: Request<Streaming<proto::LoadLevelPart>>,
    ) -> Result<Response<proto::LoadLevelReply>, Status> {
        let mut parts = request.into_inner();
        let first = parts
            .message()
            .await?
            .ok_or_else(|| invalid("the LoadLevel stream is empty; send a header first"))?;
        let mut assembly = LevelAssembly::start(first)?;
        // The job's previous level is dropped first, so its memory is free
        // for the new one (the master never searches a level it replaces).
        self.shared.begin_level(assembly.job_id())?;
        // Worst case, reserved before a byte of the planes is held: pixels and
        // defined-masks of both planes, and every sample pixel a reference
        // position (8 bytes each).
        let bound = assembly
            .pixels()
            .saturating_mul(2)
            .saturating_add(assembly.sample_pixels().saturating_mul(8));
        let memory = self
            .shared
            .budget
            .reserve(bound, &format!("a level of job '{}'", assembly.job_id()))?;
        while let Some(part) = parts.message().await? {
            assembly.add(part)?;
        }
        let r = assembly.finish()?;
        let t = Instant::now();
        let (job_id, number) = (r.job_id.clone(), r.level);
        let level = self
            .shared
            .run(move || r.locate())
            .await?
            .map_err(engine_status)?;
        let level = Level::new(level, memory)?;
        let (total, bytes) = (level.total(), level.bytes());
        self.shared.install_level(&job_id, Arc::new(level));
        tracing::info!(
            job = job_id,
            level = number,
            total,
            bytes,
            seconds = t.elapsed().as_secs_f64(),
            "level loaded"
        );
        Ok(Response::new(proto::LoadLevelReply {
            total_vectors: total,
            bytes,
        }))
    }

    async fn assign(
        &self,
        request: Request<proto::AssignRequest>,
    ) -> Result<Response<proto::AssignReply>, Status> {
        let r = request.into_inner();
        check_job_id(&r.job_id)?;
        let level = self.shared.level(&r.job_id, r.level)?;
        let total = level.total();
        if r.start > r.end || r.end > total {
            return Err(invalid(format!(
                "range {}..{} is not inside the level's 0..{total} reference vectors",
                r.start, r.end
            )));
        }
        let count = r.end - r.start;
        // LBG (lbg_probes > 0): the range is quantised into ⌈√count⌉ partitions.
        let probes = r.lbg_probes as usize;
        if probes > 0 && count > 0 {
            check_probes(probes, default_seeds(count as usize)).map_err(engine_status)?;
        }
        let dense = count
            .checked_mul(level.geometry.layout().dense_bytes_per_vector() as u64)
            .and_then(|b| b.checked_add(SLACK as u64))
            .unwrap_or(u64::MAX);
        // The job's previous range is dropped first, so its memory is free.
        self.shared.clear_assignment(&r.job_id, &level);
        let budget = &self.shared.budget;
        let room = budget.limit().saturating_sub(budget.used());
        // LBG trains on dense vectors and holds them twice (the space and the
        // partition copies); exact search may gather them from the planes.
        let (storage, need) = if probes > 0 {
            (Storage::Dense, dense.saturating_mul(2))
        } else {
            self.shared
                .storage
                .plan(dense, level.plane_bytes(), Some(room))
        };
        let mut memory = budget.reserve(
            need,
            &format!("range {}..{} of job '{}'", r.start, r.end, r.job_id),
        )?;
        let lv = level.clone();
        let (start, end) = (r.start, r.end);
        let t = Instant::now();
        let engine = self.shared.engine;
        let (space, lbg) = self
            .shared
            .run(move || build_range(&engine, &lv, start..end, probes, storage))
            .await?
            .map_err(engine_status)?;
        let build_seconds = t.elapsed().as_secs_f64();
        let vectors = match &lbg {
            Some((cb, _)) => cb.range().end - cb.range().start,
            None => space.len() as u64,
        };
        let held = space.storage().name();
        let bytes = space.held_bytes() + lbg.as_ref().map_or(0, |(cb, _)| cb.bytes() as u64);
        memory.resize(bytes, "the built range")?;
        self.shared.install_assignment(
            &r.job_id,
            Arc::new(Assigned {
                level,
                epoch: r.epoch,
                space,
                bytes,
                lbg,
                _memory: memory,
            }),
        )?;
        tracing::info!(
            job = r.job_id,
            level = r.level,
            start,
            end,
            epoch = r.epoch,
            bytes,
            storage = held,
            build_seconds,
            "range assigned"
        );
        Ok(Response::new(proto::AssignReply {
            vectors,
            bytes,
            build_seconds,
        }))
    }

    type SearchStream = ReceiverStream<Result<proto::SearchResult, Status>>;

    async fn search(
        &self,
        request: Request<Streaming<proto::SearchBatch>>,
    ) -> Result<Response<Self::SearchStream>, Status> {
        let inbound = request.into_inner();
        let (tx, rx) = tokio::sync::mpsc::channel(4);
        let shared = self.shared.clone();
        tokio::spawn(serve_stream(shared, inbound, tx));
        Ok(Response::new(ReceiverStream::new(rx)))
    }

    async fn end_job(
        &self,
        request: Request<proto::EndJobRequest>,
    ) -> Result<Response<proto::EndJobReply>, Status> {
        let r = request.into_inner();
        check_job_id(&r.job_id)?;
        let freed_bytes = self.shared.end_job(&r.job_id);
        tracing::info!(job = r.job_id, freed_bytes, "job ended");
        Ok(Response::new(proto::EndJobReply { freed_bytes }))
    }
}

/// A batch being searched on a stream: its id, its link to the other ranges
/// (linked batches), the distances the master already knows of, and the
/// search.
struct InFlight {
    id: u64,
    link: Option<(Arc<Link>, Vec<u64>)>,
    /// Fault injection ([`Shared::low_reports`]): the first report says 0
    /// for every query.
    lie: bool,
    task: Pin<Box<dyn Future<Output = Result<proto::SearchResult, Status>> + Send>>,
}

impl InFlight {
    fn start(shared: &Arc<Shared>, b: proto::SearchBatch) -> Self {
        let link = (b.linked && b.count as usize <= MAX_QUERIES).then(|| {
            let count = b.count as usize;
            // What the master sent as bounds it knows already: not echoed.
            let mut sent = vec![u64::MAX; count];
            if b.bound_distance.len() == count {
                sent.copy_from_slice(&b.bound_distance);
            }
            (Arc::new(Link::new(count)), sent)
        });
        Self {
            id: b.batch_id,
            lie: shared.low_reports,
            task: Box::pin(search_batch(
                shared.clone(),
                b,
                link.as_ref().map(|l| l.0.clone()),
            )),
            link,
        }
    }

    /// The distances its search lowered since the last report, as an
    /// interim result (None when there are none).
    fn report(&mut self) -> Option<proto::SearchResult> {
        let (link, sent) = self.link.as_mut()?;
        let changes = if std::mem::take(&mut self.lie) {
            (0..sent.len() as u32).map(|q| (q, 0)).collect()
        } else {
            link.changes(sent)
        };
        if changes.is_empty() {
            return None;
        }
        let (lower_query, lower_distance) = lowered_to_proto(&changes);
        Some(proto::SearchResult {
            batch_id: self.id,
            interim: true,
            lower_query,
            lower_distance,
            ..Default::default()
        })
    }

    /// Takes in the master's `update` for this batch: the other ranges' finds.
    fn update(&mut self, u: &proto::SearchBatch) -> Result<(), Status> {
        let Some((link, sent)) = self.link.as_mut() else {
            return Ok(());
        };
        let lowered =
            lowered_from_proto(&u.lower_query, &u.lower_distance, sent.len()).map_err(invalid)?;
        for (q, d) in lowered {
            link.lower(q, d);
            sent[q] = sent[q].min(d);
        }
        Ok(())
    }
}

/// One `Search` stream: batches are searched one at a time, in order; while
/// a linked batch runs, its finds go out every [`LINK_INTERVAL`] and the
/// master's updates come in (ARCHITECTURE §4.7).
async fn serve_stream(
    shared: Arc<Shared>,
    mut inbound: Streaming<proto::SearchBatch>,
    tx: tokio::sync::mpsc::Sender<Result<proto::SearchResult, Status>>,
) {
    let mut stop = shared.stop.clone();
    let mut running: Option<InFlight> = None;
    let mut queued: Option<proto::SearchBatch> = None;
    // The master closed its side: what is in flight is still answered.
    let mut closed = false;
    let mut tick = tokio::time::interval(LINK_INTERVAL);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        if running.is_none() {
            if let Some(b) = queued.take() {
                running = Some(InFlight::start(&shared, b));
            }
        }
        if closed && running.is_none() {
            break;
        }
        let linked = running.as_ref().is_some_and(|r| r.link.is_some());
        let reply = tokio::select! {
            m = inbound.message(), if queued.is_none() && !closed => match m {
                Ok(Some(b)) if b.update => {
                    if b.lower_query.len() != b.lower_distance.len() {
                        Some(Err(invalid(format!(
                            "an update with {} lower_query and {} lower_distance entries; send one distance per query",
                            b.lower_query.len(),
                            b.lower_distance.len()
                        ))))
                    } else {
                        match running.as_mut().filter(|r| r.id == b.batch_id) {
                            Some(r) => r.update(&b).err().map(Err),
                            None => None,
                        }
                    }
                }
                Ok(Some(b)) => {
                    queued = Some(b);
                    None
                }
                Ok(None) => {
                    closed = true;
                    None
                }
                Err(status) => Some(Err(super::size_status(status))),
            },
            done = async { running.as_mut().expect("guarded").task.as_mut().await }, if running.is_some() => {
                running = None;
                Some(done)
            }
            _ = tick.tick(), if linked => running.as_mut().and_then(InFlight::report).map(Ok),
            () = async { let _ = stop.wait_for(|s| *s).await; } => {
                let _ = tx
                    .send(Err(Status::unavailable("the worker is shutting down")))
                    .await;
                break;
            }
            () = tx.closed() => break,
        };
        let Some(reply) = reply else { continue };
        let failed = reply.is_err();
        if let Err(e) = &reply {
            tracing::debug!(code = ?e.code(), message = e.message(), "search batch rejected");
        }
        if tx.send(reply).await.is_err() || failed {
            break;
        }
    }
}

/// Validates one batch and searches it over the job's assigned range; a
/// linked batch's keyed sweep shares its bounds through `link`.
async fn search_batch(
    shared: Arc<Shared>,
    b: proto::SearchBatch,
    link: Option<Arc<Link>>,
) -> Result<proto::SearchResult, Status> {
    let shared = &shared;
    check_job_id(&b.job_id)?;
    let k = match b.top_k as usize {
        0 | 1 => 1,
        k if k > MAX_TOP_K => {
            return Err(invalid(format!("top_k {k} exceeds the limit {MAX_TOP_K}")));
        }
        k => k,
    };
    let count = b.count as usize;
    if count == 0 || count > MAX_QUERIES {
        return Err(invalid(format!(
            "count {count} must be in 1..={MAX_QUERIES}"
        )));
    }
    let bounds = bounds_from_proto(&b)?;
    let bounded = bounds.iter().any(|h| !h.is_none());
    let a = shared.assigned(&b.job_id, b.level, b.epoch)?;
    if bounded && (a.lbg.is_some() || k > 1) {
        return Err(invalid(
            "bounds are for exhaustive best-1 search; send none with top_k > 1 or on an LBG assignment",
        ));
    }
    let cut = b.topk_cut;
    if !cut.is_empty() && (k == 1 || cut.len() != count) {
        return Err(invalid(format!(
            "topk_cut has {} entries: send none, or one per query ({count}) with top_k > 1",
            cut.len()
        )));
    }
    if a.lbg.is_some() && k > 1 {
        return Err(invalid(format!(
            "top_k {k} is not available on an LBG assignment; send top_k 0 or 1"
        )));
    }
    let layout = a.space.layout();
    let dims = layout.dims();
    let expected = count
        .checked_mul(dims)
        .ok_or_else(|| invalid("count × dims overflows"))?;
    for (what, len) in [("values", b.values.len()), ("masks", b.masks.len())] {
        if len != expected {
            return Err(invalid(format!(
                "{what} has {len} bytes, expected count {count} × {dims} components = {expected}"
            )));
        }
    }
    let per_query = if k == 1 { 1 } else { k.min(a.space.len()) };
    let reply_bytes = count * per_query * HIT_WIRE_BYTES + 64;
    if reply_bytes > shared.max_message {
        return Err(exhausted(format!(
            "the answer to {count} queries × {per_query} hits may need {reply_bytes} bytes, over the {} byte message limit; send smaller batches",
            shared.max_message
        )));
    }
    // The call's buffers: the request as received, the batch built from it,
    // the engine's answers and top-k lists, and the encoded reply.
    let transient = (expected as u64)
        .saturating_mul(BATCH_BYTES_PER_COMPONENT)
        .saturating_add((count * per_query) as u64 * ANSWER_BYTES_PER_HIT)
        .saturating_add(CALL_OVERHEAD_BYTES);
    let memory = shared.budget.reserve(
        transient,
        &format!("a search batch of {count} queries of job '{}'", b.job_id),
    )?;
    let engine = shared.engine;
    let job_id = b.job_id;
    let held = a.space.start()..a.space.end();
    let (hits, prune, seconds) = shared
        .run(
            move || -> texsyn_engine::Result<(Vec<Hit>, Option<PruneStats>, f64)> {
                let t = Instant::now();
                let mut q = QueryBatch::new(layout);
                for (v, m) in b.values.chunks_exact(dims).zip(b.masks.chunks_exact(dims)) {
                    q.push(v, m)?;
                }
                for (i, h) in bounds.into_iter().enumerate() {
                    q.set_bound(i, h);
                }
                let space = &a.space;
                let params = &a.level.params;
                let range = space.start()..space.end();
                let mut prune = None;
                let hits = if let Some((cb, probes)) = &a.lbg {
                    cb.search(&engine, &q, *probes)?
                } else if space.is_empty() {
                    if k == 1 {
                        vec![Hit::NONE; count]
                    } else {
                        Vec::new()
                    }
                } else if k == 1 {
                    let (hits, stats) =
                        engine.search_best_linked(space, range, &q, params, link.as_deref())?;
                    prune = Some(stats);
                    hits
                } else {
                    let lists = if cut.is_empty() {
                        engine.search_topk(space, range, &q, params, k)?
                    } else {
                        engine.search_topk_below(space, range, &q, params, k, &cut)?
                    };
                    // Only a cut may end a list early; its slots are padded.
                    if lists
                        .iter()
                        .any(|l| l.len() > per_query || (cut.is_empty() && l.len() != per_query))
                    {
                        return Err(texsyn_engine::EngineError::Parameter(
                            "top-k lists of unequal length".into(),
                        ));
                    }
                    lists
                        .into_iter()
                        .flat_map(|l| {
                            let pad = per_query - l.len();
                            l.into_iter().chain(std::iter::repeat_n(Hit::NONE, pad))
                        })
                        .collect()
                };
                Ok((hits, prune, t.elapsed().as_secs_f64()))
            },
        )
        .await?
        .map_err(engine_status)?;
    shared.touch(&job_id);
    drop(memory);
    let hits = if shared.wrong_answers.load(Ordering::Relaxed) {
        lie(hits, held)
    } else {
        hits
    };
    Ok(proto::SearchResult {
        batch_id: b.batch_id,
        hits: hits.into_iter().map(|h| proto::Hit::from(&h)).collect(),
        per_query: per_query as u32,
        seconds,
        prune: prune.as_ref().map(prune_to_proto),
        ..Default::default()
    })
}

/// Fault injection: each answer moved to another reference of the range, at
/// distance 0, which would win any merge that does not check it.
fn lie(hits: Vec<Hit>, range: Range<u64>) -> Vec<Hit> {
    let len = range.end - range.start;
    if len < 2 {
        return hits;
    }
    hits.into_iter()
        .enumerate()
        .map(|(q, h)| {
            let index = if h.is_none() {
                range.start + q as u64 % len
            } else {
                range.start + (h.index - range.start + 1) % len
            };
            Hit { index, dist: 0 }
        })
        .collect()
}

/// The vectors of `range` of the level, or (with `probes` > 0) the LBG
/// codebook trained over them and an empty placeholder space (Stahlhut §8,
/// ARCHITECTURE §3.8).
fn build_range(
    engine: &Engine,
    lv: &OwnedLevel,
    range: Range<u64>,
    probes: usize,
    storage: Storage,
) -> texsyn_engine::Result<(VectorSpace, Option<(Codebook, usize)>)> {
    let space = VectorSpace::build_with(
        &lv.sample(),
        &lv.geometry,
        &lv.positions,
        range.clone(),
        storage,
    )?;
    if probes == 0 || space.is_empty() {
        return Ok((space, None));
    }
    // Deterministic per (level, range): a re-assigned range is
    // re-quantised into the same codebook on any worker.
    let cfg = LbgConfig {
        seed: range_seed(0, lv.level as u32, &range),
        ..LbgConfig::default()
    };
    let start = range.start;
    let cb = Codebook::train(engine, &space, range, &lv.params, &cfg)?;
    let placeholder = VectorSpace::from_unpadded(space.layout(), start, &[])?;
    Ok((placeholder, Some((cb, probes))))
}
