//! The master's side of the `texsyn.v1.Worker` calls (ARCHITECTURE §4.1, §4.4:
//! bearer token, optional TLS). Every function takes and
//! returns owned values (clients are cheap clones), so the cluster can run one
//! per worker concurrently on its runtime; every call has a deadline, set both
//! as the gRPC timeout header and as a local timer (a stopped worker never
//! answers, so the local timer is what ends the wait).

use std::future::Future;
use std::ops::Range;
use std::sync::Arc;
use std::time::{Duration, Instant};

use texsyn_engine::Hit;
use texsyn_proto::auth::BearerAuth;
use texsyn_proto::tls::{error_chain, parse_address, ClientTls};
use texsyn_proto::v1 as pb;
use texsyn_proto::wire::{
    best_hits, bounds_from_proto, lowered_from_proto, lowered_to_proto, prune_from_proto,
    topk_hits, LINK_INTERVAL,
};
use tokio::sync::{mpsc, Notify};
use tokio_stream::wrappers::ReceiverStream;
use tonic::codegen::InterceptedService;
use tonic::transport::Channel;
use tonic::{Request, Status, Streaming};

use texsyn_engine::{check_linked_part, check_part, CalibrationSize, Link, PruneStats};

use super::error::{ClusterError, ClusterResult};

pub(crate) type Client = pb::worker_client::WorkerClient<InterceptedService<Channel, BearerAuth>>;

/// One worker the master should use.
#[derive(Clone, PartialEq, Eq)]
pub struct WorkerSpec {
    /// `host:port` (or `http(s)://host:port`) as the user wrote it.
    pub address: String,
    /// Shared token sent on every call, if the worker requires one.
    pub token: Option<String>,
}

impl std::fmt::Debug for WorkerSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("WorkerSpec")
            .field("address", &self.address)
            .field("token", &self.token.as_ref().map(|_| "<redacted>"))
            .finish()
    }
}

impl WorkerSpec {
    pub fn new(address: impl Into<String>, token: Option<String>) -> Self {
        Self {
            address: address.into(),
            token,
        }
    }
}

/// Splits `host:port` (also `[v6]:port`, optionally prefixed with `http://` or
/// `https://`) into host and port, checking both; other schemes and paths are
/// refused ([`texsyn_proto::tls::parse_address`]).
pub fn split_address(address: &str) -> anyhow::Result<(String, u16)> {
    let a = parse_address(address)?;
    Ok((a.host, a.port))
}

/// Largest answer the master decodes (answers are 24 bytes per query at most).
const MAX_DECODE: usize = 256 << 20;

/// A status as one line: `Unauthenticated: wrong token ...`.
pub(crate) fn status_text(s: &Status) -> String {
    format!("{:?}: {}", s.code(), s.message())
}

/// A status of a connection's first call, with its causes and what to do
/// when it is a TLS mismatch.
pub(crate) fn first_call_text(s: &Status, address: &str, tls: &ClientTls) -> String {
    let mut text = status_text(s);
    if let Some(src) = std::error::Error::source(s) {
        let chain = error_chain(src);
        if !text.contains(&chain) {
            text = format!("{text}: {chain}");
        }
    }
    tls.explain(address, text)
}

/// Runs `f` with a deadline of `d`: the result, or why there is none.
pub(crate) async fn within<T>(
    d: Duration,
    call: &'static str,
    f: impl Future<Output = Result<T, Status>>,
) -> ClusterResult<T> {
    match tokio::time::timeout(d, f).await {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(s)) => Err(ClusterError::Call {
            call,
            status: status_text(&s),
        }),
        Err(_) => Err(ClusterError::CallDeadline {
            call,
            ms: d.as_millis(),
        }),
    }
}

fn request<T>(msg: T, d: Duration) -> Request<T> {
    let mut r = Request::new(msg);
    r.set_timeout(d);
    r
}

/// Opens a channel to the worker with the token interceptor: TLS as the
/// address's scheme and `tls` say ([`ClientTls::use_tls`]).
pub(crate) async fn connect(
    spec: &WorkerSpec,
    tls: &ClientTls,
    timeout: Duration,
) -> ClusterResult<Client> {
    let endpoint = tls
        .endpoint(&spec.address, timeout)
        .map_err(|e| ClusterError::Address(format!("{e:#}")))?
        .tcp_nodelay(true)
        .http2_keep_alive_interval(Duration::from_secs(10))
        .keep_alive_timeout(Duration::from_secs(10))
        .keep_alive_while_idle(true);
    let channel = match tokio::time::timeout(timeout, endpoint.connect()).await {
        Ok(Ok(c)) => c,
        Ok(Err(e)) => {
            return Err(ClusterError::Connect(
                tls.explain(&spec.address, error_chain(&e)),
            ))
        }
        Err(_) => return Err(ClusterError::ConnectTimeout(timeout.as_millis())),
    };
    let auth = BearerAuth::new(spec.token.as_deref())
        .map_err(|e| ClusterError::Address(format!("{e:#}")))?;
    Ok(
        pb::worker_client::WorkerClient::with_interceptor(channel, auth)
            .max_decoding_message_size(MAX_DECODE),
    )
}

/// The Info call on a fresh connection, within `d`; TLS mismatches (which
/// show only at the first call) are explained.
pub(crate) async fn first_info(
    client: &mut Client,
    spec: &WorkerSpec,
    tls: &ClientTls,
    protocol: u32,
    d: Duration,
) -> ClusterResult<pb::InfoReply> {
    match tokio::time::timeout(
        d,
        client.info(request(
            pb::InfoRequest {
                protocol_version: protocol,
            },
            d,
        )),
    )
    .await
    {
        Ok(Ok(r)) => Ok(r.into_inner()),
        Ok(Err(s)) => Err(ClusterError::Call {
            call: "Info",
            status: first_call_text(&s, &spec.address, tls),
        }),
        Err(_) => Err(ClusterError::CallDeadline {
            call: "Info",
            ms: d.as_millis(),
        }),
    }
}

/// What the master keeps from a worker's Info and Calibrate.
#[derive(Debug, Clone)]
pub(crate) struct WorkerInfo {
    pub version: String,
    pub cores: u32,
    pub threads: u32,
    pub kernel: String,
    pub load_average: f64,
    pub max_message: u64,
}

/// The version handshake: a worker of another protocol version is refused
/// with a message naming both versions.
pub(crate) fn check_protocol(
    address: &str,
    ours: u32,
    reply: &pb::InfoReply,
) -> ClusterResult<WorkerInfo> {
    if reply.protocol_version != ours {
        return Err(ClusterError::ProtocolMismatch {
            address: address.to_string(),
            ours,
            theirs: reply.protocol_version,
            version: if reply.version.is_empty() {
                "?".to_string()
            } else {
                reply.version.clone()
            },
        });
    }
    Ok(WorkerInfo {
        version: reply.version.clone(),
        cores: reply.cores,
        threads: reply.threads,
        kernel: reply.kernel.clone(),
        load_average: reply.load_average,
        max_message: reply.max_message_bytes,
    })
}

/// Runs the worker's calibration; its throughput in reference × query pairs per second.
pub(crate) async fn calibrate(
    mut client: Client,
    size: CalibrationSize,
    d: Duration,
) -> ClusterResult<f64> {
    let r = within(
        d,
        "Calibrate",
        client.calibrate(request(
            pb::CalibrateRequest {
                seed: size.seed,
                vectors: size.vectors,
                dims: size.dims,
                queries: size.queries,
            },
            d,
        )),
    )
    .await?
    .into_inner();
    if !(r.pairs_per_second.is_finite() && r.pairs_per_second > 0.0) {
        return Err(ClusterError::InvalidThroughput(r.pairs_per_second));
    }
    Ok(r.pairs_per_second)
}

/// A connected worker that passed the version handshake.
pub(crate) struct Handshake {
    pub client: Client,
    pub info: WorkerInfo,
}

/// Connect and Info (version handshake).
pub(crate) async fn handshake(
    spec: WorkerSpec,
    tls: ClientTls,
    protocol: u32,
    connect_timeout: Duration,
    call_timeout: Duration,
) -> ClusterResult<Handshake> {
    let mut client = connect(&spec, &tls, connect_timeout).await?;
    let reply = first_info(&mut client, &spec, &tls, protocol, call_timeout).await?;
    let info = check_protocol(&spec.address, protocol, &reply)?;
    Ok(Handshake { client, info })
}

/// Sends a level as its `LoadLevel` stream of `parts`.
pub(crate) async fn load_level(
    mut client: Client,
    parts: impl Iterator<Item = pb::LoadLevelPart> + Send + 'static,
    d: Duration,
) -> ClusterResult<pb::LoadLevelReply> {
    let stream = tokio_stream::iter(parts);
    Ok(
        within(d, "LoadLevel", client.load_level(request(stream, d)))
            .await?
            .into_inner(),
    )
}

pub(crate) async fn assign(
    mut client: Client,
    req: pb::AssignRequest,
    d: Duration,
) -> ClusterResult<pb::AssignReply> {
    Ok(within(d, "Assign", client.assign(request(req, d)))
        .await?
        .into_inner())
}

pub(crate) async fn end_job(mut client: Client, job_id: String, d: Duration) -> ClusterResult<u64> {
    Ok(within(
        d,
        "EndJob",
        client.end_job(request(pb::EndJobRequest { job_id }, d)),
    )
    .await?
    .into_inner()
    .freed_bytes)
}

/// The long-lived bidirectional search stream to one worker.
pub(crate) struct SearchStream {
    tx: mpsc::Sender<pb::SearchBatch>,
    rx: Streaming<pb::SearchResult>,
}

pub(crate) async fn open_stream(mut client: Client, d: Duration) -> ClusterResult<SearchStream> {
    let (tx, rx) = mpsc::channel(8);
    let rx = within(
        d,
        "opening the search stream",
        client.search(ReceiverStream::new(rx)),
    )
    .await?
    .into_inner();
    Ok(SearchStream { tx, rx })
}

/// One worker's part of a batch: the chunks (each under the worker's message
/// limit), the range they search and the deadline for all of them.
pub(crate) struct Part {
    pub chunks: Vec<pb::SearchBatch>,
    pub range: Range<u64>,
    pub deadline: Instant,
    /// A linked batch's distances and wake-up, shared with the other parts.
    pub link: Option<BatchLink>,
}

/// A linked batch as its parts share it (ARCHITECTURE §4.7).
#[derive(Clone)]
pub(crate) struct BatchLink {
    /// The distances per query of the whole batch, shared with the other
    /// parts and the master's own share.
    pub link: Arc<Link>,
    /// Woken whenever a part takes in its worker's finds, so that the other
    /// parts forward them at once instead of at their next tick.
    pub found: Arc<Notify>,
}

/// The messages of a linked batch's part (ARCHITECTURE §4.7): the interim
/// reports its worker sent and the updates the master sent it.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(crate) struct LinkTraffic {
    pub reports: u64,
    pub updates: u64,
}

/// What came back for one part.
pub(crate) struct PartAnswer {
    /// The stream, for the next batch (None when it failed).
    pub stream: Option<SearchStream>,
    pub result: ClusterResult<Vec<Hit>>,
    /// Wall time from sending to the last answer.
    pub wall: f64,
    /// Search time the worker reported.
    pub search_seconds: f64,
    /// Pruning figures the worker reported.
    pub prune: PruneStats,
    /// Link messages while it ran (linked batches).
    pub traffic: LinkTraffic,
}

/// Sends the part's chunks one after the other on `stream` and reads each
/// answer, all before `deadline`; every answer is checked for shape and range.
pub(crate) async fn run_part(mut stream: SearchStream, part: Part) -> PartAnswer {
    let started = Instant::now();
    let mut hits = Vec::new();
    let mut search_seconds = 0.0;
    let mut prune = PruneStats::default();
    let mut traffic = LinkTraffic::default();
    let mut failure = None;
    let mut first = 0;
    for chunk in part.chunks {
        let link = part.link.as_ref().map(|b| (&*b.link, first, &*b.found));
        first += chunk.count as usize;
        match ask_chunk(
            &mut stream,
            chunk,
            part.deadline,
            started,
            &part.range,
            link,
            &mut traffic,
        )
        .await
        {
            Ok((h, seconds, p)) => {
                hits.extend(h);
                search_seconds += seconds;
                prune.add(&p);
            }
            Err(e) => {
                failure = Some(e);
                break;
            }
        }
    }
    let wall = started.elapsed().as_secs_f64();
    match failure {
        Some(e) => PartAnswer {
            stream: None,
            result: Err(e),
            wall,
            search_seconds,
            prune,
            traffic,
        },
        None => PartAnswer {
            stream: Some(stream),
            result: Ok(hits),
            wall,
            search_seconds,
            prune,
            traffic,
        },
    }
}

/// Sends one chunk and reads its answer before `deadline`: the checked hits
/// the search seconds the worker reported (0 when not a valid time) and its
/// pruning figures. A linked chunk (`link`: the batch's link, the chunk's
/// first query in it and the batch's wake-up) passes the worker's interim
/// finds into the link and wakes the other parts; it sends the link's newer
/// distances to the worker when woken so, and every [`LINK_INTERVAL`] (for
/// the master's own share, which lowers the link without waking). A
/// worker whose answer is worse than a distance it reported finding is
/// refused: its reports could have starved the other ranges' searches.
/// `traffic` counts the link messages either way.
async fn ask_chunk(
    stream: &mut SearchStream,
    mut chunk: pb::SearchBatch,
    deadline: Instant,
    started: Instant,
    range: &Range<u64>,
    link: Option<(&Link, usize, &Notify)>,
    traffic: &mut LinkTraffic,
) -> ClusterResult<(Vec<Hit>, f64, PruneStats)> {
    let missed = || ClusterError::Deadline(deadline.saturating_duration_since(started).as_millis());
    let at = tokio::time::Instant::from_std(deadline);
    let id = chunk.batch_id;
    let chunk_k = chunk.top_k;
    let count = chunk.count as usize;
    let bounds =
        bounds_from_proto(&chunk).map_err(|e| ClusterError::BadAnswer(e.message().into()))?;
    let cut = chunk.topk_cut.clone();
    chunk.linked = link.is_some();
    // What the worker knows per query (sent), and the least it reported.
    let mut sent: Vec<u64> = bounds.iter().map(|h| h.dist).collect();
    let mut reported = vec![u64::MAX; count];
    match tokio::time::timeout_at(at, stream.tx.send(chunk)).await {
        Ok(Ok(())) => {}
        Ok(Err(_)) => return Err(ClusterError::StreamClosed),
        Err(_) => return Err(missed()),
    }
    let mut tick = tokio::time::interval(LINK_INTERVAL);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let never = Notify::new();
    let found = link.map_or(&never, |(_, _, f)| f);
    let r = loop {
        let forward = async {
            tokio::select! {
                _ = tick.tick() => {}
                () = found.notified() => {}
            }
        };
        let r = tokio::select! {
            m = tokio::time::timeout_at(at, stream.rx.message()) => match m {
                Err(_) => return Err(missed()),
                Ok(Err(s)) => return Err(ClusterError::Search(status_text(&s))),
                Ok(Ok(None)) => return Err(ClusterError::StreamClosed),
                Ok(Ok(Some(r))) => r,
            },
            () = forward, if link.is_some() => {
                let (l, first, _) = link.expect("guarded");
                let changes = l.changes_from(first, &mut sent);
                if !changes.is_empty() {
                    let (lower_query, lower_distance) = lowered_to_proto(&changes);
                    let update = pb::SearchBatch {
                        batch_id: id,
                        update: true,
                        lower_query,
                        lower_distance,
                        ..Default::default()
                    };
                    traffic.updates += 1;
                    match tokio::time::timeout_at(at, stream.tx.send(update)).await {
                        Ok(Ok(())) => {}
                        Ok(Err(_)) => return Err(ClusterError::StreamClosed),
                        Err(_) => return Err(missed()),
                    }
                }
                continue;
            }
        };
        if !r.interim {
            break r;
        }
        let (Some((l, first, found)), true) = (link, r.batch_id == id) else {
            return Err(ClusterError::BadAnswer(format!(
                "an interim report for batch {} where none was asked",
                r.batch_id
            )));
        };
        traffic.reports += 1;
        let lowered = lowered_from_proto(&r.lower_query, &r.lower_distance, count)
            .map_err(ClusterError::BadAnswer)?;
        let mut lower = false;
        for (q, d) in lowered {
            reported[q] = reported[q].min(d);
            sent[q] = sent[q].min(d);
            lower |= l.lower(first + q, d);
        }
        if lower {
            found.notify_waiters();
        }
    };
    if r.batch_id != id {
        return Err(ClusterError::WrongBatch {
            answered: r.batch_id,
            asked: id,
        });
    }
    let k = chunk_k.max(1) as usize;
    let h = if k == 1 {
        let h =
            best_hits(&r, bounds.len()).map_err(|e| ClusterError::BadAnswer(format!("{e:#}")))?;
        if link.is_some() {
            check_linked_part(&h, &bounds, range)
        } else {
            check_part(&h, &bounds, range)
        }
        .map_err(ClusterError::BadAnswer)?;
        if let Some(q) = (0..count).find(|&q| h[q].dist > reported[q]) {
            return Err(ClusterError::BadAnswer(format!(
                "query {q}: reported finding distance {} while searching but answered {}",
                reported[q], h[q].dist
            )));
        }
        h
    } else {
        let lists =
            topk_hits(&r, bounds.len()).map_err(|e| ClusterError::BadAnswer(format!("{e:#}")))?;
        flat_topk(&lists, k, range, (!cut.is_empty()).then_some(&cut[..]))
            .map_err(ClusterError::BadAnswer)?
    };
    let seconds = if r.seconds.is_finite() && r.seconds >= 0.0 {
        r.seconds
    } else {
        0.0
    };
    Ok((h, seconds, prune_from_proto(&r)))
}

/// A worker's top-k lists checked and laid flat, `k` slots per query padded
/// with [`Hit::NONE`]: each list must be as long as the range allows
/// (`min(k, range length)`), sorted by (distance, index) without repeats, and
/// stay inside the range. Under a per-query `cut` a list holds only matches
/// below its cut and may end early (unpadded, or padded with [`Hit::NONE`]).
pub(crate) fn flat_topk(
    lists: &[Vec<Hit>],
    k: usize,
    range: &Range<u64>,
    cut: Option<&[u64]>,
) -> Result<Vec<Hit>, String> {
    let want = (k as u64).min(range.end.saturating_sub(range.start)) as usize;
    if cut.is_some_and(|c| c.len() != lists.len()) {
        return Err(format!(
            "answered {} lists for {} cuts",
            lists.len(),
            cut.map_or(0, <[u64]>::len)
        ));
    }
    let mut out = Vec::with_capacity(lists.len() * k);
    for (q, l) in lists.iter().enumerate() {
        let limit = cut.map(|c| c[q]);
        // The answer is the list up to its first padding slot; only a cut
        // may end it before `want`.
        let len = l.iter().position(Hit::is_none).unwrap_or(l.len());
        if l.len() > want || (limit.is_none_or(|c| c == u64::MAX) && len != want) {
            return Err(format!("answered {len} of the {want} best matches"));
        }
        if l[len..].iter().any(|h| !h.is_none()) {
            return Err("a top-k list goes on after its padding".into());
        }
        for (i, h) in l[..len].iter().enumerate() {
            if !range.contains(&h.index) || h.dist == u64::MAX {
                return Err(format!(
                    "answered index {} outside its range {}..{}",
                    h.index, range.start, range.end
                ));
            }
            if limit.is_some_and(|c| h.dist >= c) {
                return Err(format!(
                    "answered distance {} for a query cut at {}",
                    h.dist,
                    limit.unwrap_or(u64::MAX)
                ));
            }
            if i > 0 && h.key() <= l[i - 1].key() {
                return Err("top-k list not sorted by (distance, index)".into());
            }
        }
        out.extend_from_slice(&l[..len]);
        out.extend(std::iter::repeat_n(Hit::NONE, k - len));
    }
    Ok(out)
}

/// Runs `f` on `rt` from synchronous code. Inside another runtime's context
/// (an async caller) it blocks a helper thread instead of panicking.
pub(crate) fn block_on<F>(rt: &tokio::runtime::Runtime, f: F) -> F::Output
where
    F: Future + Send,
    F::Output: Send,
{
    if tokio::runtime::Handle::try_current().is_ok() {
        std::thread::scope(|s| match s.spawn(|| rt.block_on(f)).join() {
            Ok(v) => v,
            Err(p) => std::panic::resume_unwind(p),
        })
    } else {
        rt.block_on(f)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hit(index: u64, dist: u64) -> Hit {
        Hit { index, dist }
    }

    #[test]
    fn topk_lists_are_full_unless_a_cut_ends_them() {
        let range = 10..20;
        let full = vec![hit(12, 3), hit(15, 4), hit(11, 9)];
        let short = vec![hit(12, 3), Hit::NONE, Hit::NONE];
        // Without a cut a list holds min(k, range length) matches.
        assert!(flat_topk(std::slice::from_ref(&full), 3, &range, None).is_ok());
        assert!(flat_topk(std::slice::from_ref(&short), 3, &range, None).is_err());
        // A cut lets it end early, padded or not, and the answer is padded.
        let flat = flat_topk(std::slice::from_ref(&short), 3, &range, Some(&[5])).unwrap();
        assert_eq!(flat, short);
        let unpadded = vec![hit(12, 3)];
        assert_eq!(
            flat_topk(&[unpadded], 3, &range, Some(&[5])).unwrap(),
            short
        );
        // A cut of u64::MAX cuts nothing.
        assert!(flat_topk(std::slice::from_ref(&short), 3, &range, Some(&[u64::MAX])).is_err());
        // Nothing at or above the cut, nothing after the padding.
        assert!(flat_topk(std::slice::from_ref(&full), 3, &range, Some(&[9])).is_err());
        assert!(flat_topk(std::slice::from_ref(&full), 3, &range, Some(&[10])).is_ok());
        let gap = vec![hit(12, 3), Hit::NONE, hit(11, 4)];
        assert!(flat_topk(&[gap], 3, &range, Some(&[10])).is_err());
        // One cut per list.
        assert!(flat_topk(&[full], 3, &range, Some(&[10, 10])).is_err());
    }

    #[test]
    fn protocol_mismatch_names_both_versions() {
        let reply = pb::InfoReply {
            protocol_version: 7,
            version: "9.9.9".into(),
            ..Default::default()
        };
        let e = check_protocol("10.0.0.1:7878", 1, &reply)
            .unwrap_err()
            .to_string();
        assert!(e.contains("version 1") && e.contains("version 7"), "{e}");
        assert!(e.contains("10.0.0.1:7878") && e.contains("9.9.9"), "{e}");
        let ok = pb::InfoReply {
            protocol_version: 1,
            threads: 3,
            ..Default::default()
        };
        assert_eq!(check_protocol("a:1", 1, &ok).unwrap().threads, 3);
    }

    #[test]
    fn addresses_are_checked() {
        assert_eq!(
            split_address("127.0.0.2:7878").unwrap(),
            ("127.0.0.2".into(), 7878)
        );
        assert_eq!(split_address("[::1]:80").unwrap(), ("[::1]".into(), 80));
        assert_eq!(
            split_address("https://render-1.lan:443/").unwrap(),
            ("render-1.lan".into(), 443)
        );
        for bad in [
            "",
            "host",
            "host:",
            "host:0",
            "host:99999",
            ":80",
            "a b:80",
            "h/x:1",
            "grpc://h:1",
            "ftp://h:21",
            "https://h:1/api",
        ] {
            assert!(split_address(bad).is_err(), "{bad}");
        }
    }
}
