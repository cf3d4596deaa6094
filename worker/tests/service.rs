//! The gRPC worker in-process on 127.0.0.1:0, driven by the generated client:
//! cluster answers equal the local engine, and every bad call gets the right
//! status without taking the worker down.

use std::net::SocketAddr;
use std::time::Duration;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use texsyn_engine::{
    merge_best, merge_topk, Engine, Geometry, Hit, Metric, OwnedLevel, OwnedPlane, Params, Plane,
    QueryBatch, Sample, VectorSpace, Weights,
};
use texsyn_proto::auth::{read_token_file, BearerAuth};
use texsyn_proto::v1 as pb;
use texsyn_proto::wire::{best_hits, lowered_from_proto, topk_hits};
use texsyn_proto::PROTOCOL_VERSION;
use texsyn_worker::service::{self, WorkerConfig};
use tokio::net::TcpListener;
use tokio::sync::oneshot;
use tonic::codegen::InterceptedService;
use tonic::transport::Channel;
use tonic::{Code, Status};

type Client = pb::worker_client::WorkerClient<InterceptedService<Channel, BearerAuth>>;

struct Worker {
    addr: SocketAddr,
    stop: oneshot::Sender<()>,
    handle: tokio::task::JoinHandle<anyhow::Result<()>>,
}

impl Worker {
    async fn start(config: WorkerConfig) -> Self {
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let (stop, rx) = oneshot::channel::<()>();
        let handle = tokio::spawn(service::serve(config, listener, async {
            let _ = rx.await;
        }));
        Self { addr, stop, handle }
    }

    async fn shutdown(self) {
        let _ = self.stop.send(());
        tokio::time::timeout(Duration::from_secs(10), self.handle)
            .await
            .expect("worker stops within the grace period")
            .unwrap()
            .unwrap();
    }
}

fn config() -> WorkerConfig {
    WorkerConfig {
        threads: 1,
        max_memory: 256 << 20,
        ..WorkerConfig::default()
    }
}

async fn channel(addr: SocketAddr) -> Channel {
    Channel::from_shared(format!("http://{addr}"))
        .unwrap()
        .connect_timeout(Duration::from_secs(5))
        .timeout(Duration::from_secs(30))
        .connect()
        .await
        .unwrap()
}

/// A worker started with `config` and a client without a token.
async fn start(config: WorkerConfig) -> (Worker, Client) {
    let w = Worker::start(config).await;
    let c = connect(w.addr, None).await;
    (w, c)
}

async fn connect(addr: SocketAddr, token: Option<&str>) -> Client {
    pb::worker_client::WorkerClient::with_interceptor(
        channel(addr).await,
        BearerAuth::new(token).unwrap(),
    )
}

/// A small random level: a 40×40 sample with a few undefined pixels, its 20×20
/// parent, Geometry 5/3. Pixel values come from 4 levels so that ties are common.
struct Level {
    sample: Vec<u8>,
    defined: Vec<u8>,
    parent: Vec<u8>,
    geometry: Geometry,
    params: Params,
}

impl Level {
    fn new(seed: u64, side: usize) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let sample = (0..side * side)
            .map(|_| rng.random_range(0..4u8) * 60)
            .collect();
        let defined = (0..side * side)
            .map(|_| u8::from(rng.random_range(0..50) != 0))
            .collect();
        let ps = side / 2;
        let parent = (0..ps * ps)
            .map(|_| rng.random_range(0..4u8) * 60)
            .collect();
        Self {
            sample,
            defined,
            parent,
            geometry: Geometry::new(5, 3).unwrap(),
            params: Params {
                metric: Metric::L1,
                weights: Weights::new(2, 1).unwrap(),
            },
        }
    }

    fn side(&self) -> usize {
        (self.sample.len() as f64).sqrt() as usize
    }

    fn planes(&self) -> Sample<'_> {
        let s = self.side();
        Sample {
            fine: Plane::new(s, s, &self.sample, Some(&self.defined)).unwrap(),
            parent: Some(Plane::new(s / 2, s / 2, &self.parent, None).unwrap()),
        }
    }

    fn load(&self, job: &str, level: u32) -> pb::LoadLevelRequest {
        texsyn_proto::wire::load_level_request(
            job,
            level,
            &self.geometry,
            &self.params,
            &self.planes(),
        )
    }

    /// The level's `LoadLevel` stream in pieces of `piece` bytes.
    fn parts(&self, job: &str, piece: usize) -> Vec<pb::LoadLevelPart> {
        let p = self.planes();
        let owned = OwnedLevel::locate(
            0,
            self.geometry,
            self.params,
            OwnedPlane::of(&p.fine),
            p.parent.as_ref().map(OwnedPlane::of),
        )
        .unwrap();
        texsyn_proto::wire::load_level_parts(job, std::sync::Arc::new(owned), piece).collect()
    }

    fn dims(&self) -> usize {
        self.geometry.layout().dims()
    }

    /// Random queries with random masks; query 0 is fully masked out (every
    /// distance 0, so the lowest index must win everywhere).
    fn queries(&self, seed: u64, count: usize) -> (Vec<u8>, Vec<u8>) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let d = self.dims();
        let values = (0..count * d)
            .map(|_| rng.random_range(0..4u8) * 60)
            .collect();
        let masks = (0..count * d)
            .map(|i| u8::from(i >= d && rng.random_range(0..3) != 0))
            .collect();
        (values, masks)
    }
}

fn batch(
    job: &str,
    level: u32,
    id: u64,
    top_k: u32,
    count: usize,
    q: &(Vec<u8>, Vec<u8>),
) -> pb::SearchBatch {
    pb::SearchBatch {
        job_id: job.into(),
        level,
        batch_id: id,
        top_k,
        count: count as u32,
        values: q.0.clone(),
        masks: q.1.clone(),
        epoch: 0,
        ..Default::default()
    }
}

fn assign(job: &str, level: u32, start: u64, end: u64) -> pb::AssignRequest {
    pb::AssignRequest {
        job_id: job.into(),
        level,
        start,
        end,
        lbg_probes: 0,
        epoch: 0,
    }
}

/// Sends the batches on one stream and collects the answers in order.
async fn search(
    client: &mut Client,
    batches: Vec<pb::SearchBatch>,
) -> Result<Vec<pb::SearchResult>, Status> {
    let n = batches.len();
    let mut stream = client
        .search(tokio_stream::iter(batches))
        .await?
        .into_inner();
    let mut out = Vec::new();
    while let Some(r) = stream.message().await? {
        out.push(r);
    }
    assert_eq!(out.len(), n, "one answer per batch");
    Ok(out)
}

/// Loads `level` as level 0 of job `job`; its number of reference vectors.
async fn load(client: &mut Client, level: &Level, job: &str) -> u64 {
    client
        .load_level(one(level.load(job, 0)))
        .await
        .unwrap()
        .into_inner()
        .total_vectors
}

fn code<T: std::fmt::Debug>(r: Result<T, Status>) -> Code {
    r.expect_err("the call must fail").code()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cluster_of_one_two_three_workers_equals_local_engine() {
    let level = Level::new(7, 40);
    let count = 24;
    let q = level.queries(11, count);
    let k = 5;

    // The local answer over the whole range.
    let sample = level.planes();
    let positions = texsyn_engine::layout::reference_positions(&sample, &level.geometry).unwrap();
    let total = positions.len() as u64;
    assert!(total > 500, "the level has {total} reference vectors");
    let space = VectorSpace::build(&sample, &level.geometry, 0..total).unwrap();
    let mut qb = QueryBatch::new(level.geometry.layout());
    let d = level.dims();
    for (v, m) in q.0.chunks(d).zip(q.1.chunks(d)) {
        qb.push(v, m).unwrap();
    }
    let engine = Engine::default().with_min_chunk(64);
    let local = engine
        .search_best(&space, 0..total, &qb, &level.params)
        .unwrap();
    let local_topk = engine
        .search_topk(&space, 0..total, &qb, &level.params, k)
        .unwrap();
    assert_eq!(local[0].index, 0, "a fully masked query ties everywhere");

    for n in 1..=3u64 {
        let mut workers = Vec::new();
        let mut clients = Vec::new();
        for _ in 0..n {
            let w = Worker::start(config()).await;
            clients.push(connect(w.addr, None).await);
            workers.push(w);
        }
        let mut best = vec![Hit::NONE; count];
        let mut topk = vec![Vec::new(); count];
        let mut cut_topk = vec![Vec::new(); count];
        // The tightest cut a master may send: one above each query's k-th
        // distance over the whole level.
        let cuts: Vec<u64> = local_topk.iter().map(|l| l[k - 1].dist + 1).collect();
        for (i, c) in clients.iter_mut().enumerate() {
            let i = i as u64;
            // Uneven parts: the first worker gets less.
            let cut = |j: u64| {
                if j == 0 {
                    0
                } else {
                    (total * (2 * j - 1)) / (2 * n - 1)
                }
            };
            let (start, end) = (cut(i), if i + 1 == n { total } else { cut(i + 1) });
            let loaded = c
                .load_level(one(level.load("job", 3)))
                .await
                .unwrap()
                .into_inner();
            assert_eq!(loaded.total_vectors, total);
            let a = c.assign(assign("job", 3, start, end)).await.unwrap();
            assert_eq!(a.into_inner().vectors, end - start);
            let answers = search(
                c,
                vec![
                    batch("job", 3, 10, 1, count, &q),
                    batch("job", 3, 11, k as u32, count, &q),
                    pb::SearchBatch {
                        topk_cut: cuts.clone(),
                        ..batch("job", 3, 12, k as u32, count, &q)
                    },
                ],
            )
            .await
            .unwrap();
            assert_eq!((answers[0].batch_id, answers[1].batch_id), (10, 11));
            // Under the cut a list holds only what is below it, padded.
            let lists = topk_hits(&answers[2], count).unwrap();
            for (q, l) in lists.iter().enumerate() {
                assert_eq!(l.len(), k, "query {q}: per_query slots");
                let real = l.iter().take_while(|h| !h.is_none()).count();
                assert!(
                    l[real..].iter().all(Hit::is_none),
                    "query {q}: padding last"
                );
                assert!(l[..real]
                    .iter()
                    .all(|h| h.dist < cuts[q] && (start..end).contains(&h.index)));
                let real_list = l[..real].to_vec();
                cut_topk[q] = merge_topk(&cut_topk[q], &real_list, k);
            }
            let part = best_hits(&answers[0], count).unwrap();
            assert!(part.iter().all(|h| (start..end).contains(&h.index)));
            merge_best(&mut best, &part);
            for (acc, l) in topk.iter_mut().zip(topk_hits(&answers[1], count).unwrap()) {
                *acc = merge_topk(acc, &l, k);
            }
        }
        assert_eq!(best, local, "{n} worker(s)");
        assert_eq!(topk, local_topk, "{n} worker(s), top-{k}");
        assert_eq!(cut_topk, local_topk, "{n} worker(s), top-{k} under cuts");
        for (c, w) in clients.iter_mut().zip(workers) {
            let freed = c
                .end_job(pb::EndJobRequest {
                    job_id: "job".into(),
                })
                .await
                .unwrap()
                .into_inner()
                .freed_bytes;
            assert!(freed > 0);
            w.shutdown().await;
        }
    }
}

/// A linked batch (ARCHITECTURE §4.7) answers as the same batch unlinked,
/// with the master's update of the exact answers' distances arriving while
/// it runs or after: interim reports name only the batch's queries, with
/// distances no lower than the answers', and come before its answer.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_linked_batch_answers_as_an_unlinked_one() {
    let level = Level::new(7, 40);
    let count = 24;
    let q = level.queries(5, count);
    let w = Worker::start(config()).await;
    let mut c = connect(w.addr, None).await;
    let total = load(&mut c, &level, "job").await;
    c.assign(assign("job", 0, 0, total)).await.unwrap();
    let plain = search(&mut c, vec![batch("job", 0, 1, 1, count, &q)])
        .await
        .unwrap();
    let want = best_hits(&plain[0], count).unwrap();
    let update = pb::SearchBatch {
        batch_id: 2,
        update: true,
        lower_query: (0..count as u32).collect(),
        lower_distance: want.iter().map(|h| h.dist).collect(),
        ..Default::default()
    };
    for told in [false, true] {
        let mut msgs = vec![pb::SearchBatch {
            linked: true,
            ..batch("job", 0, 2, 1, count, &q)
        }];
        if told {
            msgs.push(update.clone());
        }
        let mut stream = c
            .search(tokio_stream::iter(msgs))
            .await
            .unwrap()
            .into_inner();
        let answer = loop {
            let r = stream.message().await.unwrap().expect("an answer");
            assert_eq!(r.batch_id, 2);
            if !r.interim {
                break r;
            }
            assert!(r.hits.is_empty());
            let lowered = lowered_from_proto(&r.lower_query, &r.lower_distance, count).unwrap();
            for (q, d) in lowered {
                assert!(
                    d >= want[q].dist,
                    "query {q}: reported {d} below the answer"
                );
            }
        };
        assert_eq!(best_hits(&answer, count).unwrap(), want, "told {told}");
    }
    w.shutdown().await;
}

/// LBG on the cluster: each worker quantises its own range; with every
/// partition probed the merged answer is the exhaustive one, with P = 1 every
/// answer is a real vector of the worker's range, a range re-assigned to
/// another worker gives the same answers, and top-k is refused.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn lbg_workers_quantise_their_ranges() {
    use texsyn_engine::lbg::default_seeds;
    let level = Level::new(9, 40);
    let count = 19;
    let q = level.queries(13, count);
    let sample = level.planes();
    let positions = texsyn_engine::layout::reference_positions(&sample, &level.geometry).unwrap();
    let total = positions.len() as u64;
    let space = VectorSpace::build(&sample, &level.geometry, 0..total).unwrap();
    let mut qb = QueryBatch::new(level.geometry.layout());
    let d = level.dims();
    for (v, m) in q.0.chunks(d).zip(q.1.chunks(d)) {
        qb.push(v, m).unwrap();
    }
    let local = Engine::default()
        .search_best(&space, 0..total, &qb, &level.params)
        .unwrap();
    let cut = total / 3;
    let ranges = [0..cut, cut..total];
    let mut workers = Vec::new();
    let mut clients = Vec::new();
    for _ in 0..2 {
        let (w, mut c) = start(config()).await;
        c.load_level(one(level.load("job", 0))).await.unwrap();
        clients.push(c);
        workers.push(w);
    }
    let mut all = vec![Hit::NONE; count];
    let mut one = Vec::new();
    for (c, r) in clients.iter_mut().zip(&ranges) {
        for (probes, epoch) in [(default_seeds((r.end - r.start) as usize), 1), (1, 2)] {
            let mut a = assign("job", 0, r.start, r.end);
            a.lbg_probes = probes as u32;
            a.epoch = epoch;
            let reply = c.assign(a).await.unwrap().into_inner();
            assert_eq!(reply.vectors, r.end - r.start);
            let mut b = batch("job", 0, epoch, 1, count, &q);
            b.epoch = epoch;
            let part = best_hits(&search(c, vec![b]).await.unwrap()[0], count).unwrap();
            assert!(part.iter().all(|h| r.contains(&h.index)));
            if probes == 1 {
                one.push(part);
            } else {
                merge_best(&mut all, &part);
            }
        }
        let mut b = batch("job", 0, 9, 2, count, &q);
        b.epoch = 2;
        assert_eq!(code(search(c, vec![b]).await), Code::InvalidArgument);
    }
    assert_eq!(all, local);
    // The first range re-assigned to the other worker: the same codebook.
    let c = &mut clients[1];
    let mut a = assign("job", 0, ranges[0].start, ranges[0].end);
    a.lbg_probes = 1;
    a.epoch = 3;
    c.assign(a).await.unwrap();
    let mut b = batch("job", 0, 1, 1, count, &q);
    b.epoch = 3;
    let again = best_hits(&search(c, vec![b]).await.unwrap()[0], count).unwrap();
    assert_eq!(again, one[0]);
    for w in workers {
        w.shutdown().await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn empty_range_answers_none_hits() {
    let level = Level::new(3, 24);
    let (w, mut c) = start(config()).await;
    c.load_level(one(level.load("j", 0))).await.unwrap();
    c.assign(assign("j", 0, 5, 5)).await.unwrap();
    let q = level.queries(1, 3);
    let r = search(
        &mut c,
        vec![batch("j", 0, 1, 1, 3, &q), batch("j", 0, 2, 4, 3, &q)],
    )
    .await
    .unwrap();
    assert_eq!(best_hits(&r[0], 3).unwrap(), vec![Hit::NONE; 3]);
    assert_eq!(r[1].per_query, 0);
    assert_eq!(topk_hits(&r[1], 3).unwrap(), vec![Vec::new(); 3]);
    w.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn wrong_or_missing_token_is_unauthenticated_and_worker_keeps_serving() {
    let dir = tempfile::tempdir().unwrap();
    let token_file = dir.path().join("token");
    std::fs::write(&token_file, "  s3cret-token\n").unwrap();
    let token = read_token_file(&token_file).unwrap();
    assert_eq!(token, "s3cret-token");
    let w = Worker::start(WorkerConfig {
        token: Some(token),
        ..config()
    })
    .await;
    let info = || pb::InfoRequest {
        protocol_version: PROTOCOL_VERSION,
    };
    for t in [None, Some("wrong"), Some("s3cret-token2"), Some("")] {
        let mut c = connect(w.addr, t).await;
        assert_eq!(code(c.info(info()).await), Code::Unauthenticated, "{t:?}");
        let level = Level::new(1, 24);
        assert_eq!(
            code(c.load_level(one(level.load("j", 0))).await),
            Code::Unauthenticated
        );
        assert_eq!(
            code(search(&mut c, vec![batch("j", 0, 0, 1, 1, &level.queries(0, 1))]).await),
            Code::Unauthenticated
        );
        let mut health = tonic_health::pb::health_client::HealthClient::new(channel(w.addr).await);
        let check = tonic_health::pb::HealthCheckRequest {
            service: String::new(),
        };
        assert_eq!(code(health.check(check).await), Code::Unauthenticated);
    }
    let mut c = connect(w.addr, Some("s3cret-token")).await;
    let reply = c.info(info()).await.unwrap().into_inner();
    assert_eq!(reply.protocol_version, PROTOCOL_VERSION);
    w.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn oversized_message_is_resource_exhausted() {
    let (w, mut c) = start(WorkerConfig {
        max_message: 64 << 10,
        ..config()
    })
    .await;
    let big = Level::new(2, 300);
    assert_eq!(
        code(c.load_level(one(big.load("j", 0))).await),
        Code::ResourceExhausted
    );
    let small = Level::new(2, 40);
    c.load_level(one(small.load("j", 0))).await.unwrap();
    c.assign(assign("j", 0, 0, 100)).await.unwrap();
    let n = 3000; // 3000 × 34 × 2 bytes > 64 KiB
    let q = small.queries(1, n);
    assert_eq!(
        code(search(&mut c, vec![batch("j", 0, 0, 1, n, &q)]).await),
        Code::ResourceExhausted
    );
    // The worker still answers a correct call.
    let q = small.queries(1, 10);
    search(&mut c, vec![batch("j", 0, 0, 1, 10, &q)])
        .await
        .unwrap();
    let info = c
        .info(pb::InfoRequest {
            protocol_version: PROTOCOL_VERSION,
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(info.max_message_bytes, 64 << 10);
    w.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn malformed_requests_get_a_status_not_a_crash() {
    let (w, mut c) = start(config()).await;
    let level = Level::new(5, 40);
    let good = || level.load("job", 2);

    malformed_load_levels(&mut c, good).await;

    // Nothing loaded yet.
    assert_eq!(
        code(c.assign(assign("job", 2, 0, 10)).await),
        Code::FailedPrecondition
    );
    let q = level.queries(3, 4);
    assert_eq!(
        code(search(&mut c, vec![batch("job", 2, 0, 1, 4, &q)]).await),
        Code::FailedPrecondition
    );

    let total = c
        .load_level(one(good()))
        .await
        .unwrap()
        .into_inner()
        .total_vectors;
    // Assign.
    for (s, e) in [(0, total + 1), (10, 5), (total + 1, total + 2)] {
        assert_eq!(
            code(c.assign(assign("job", 2, s, e)).await),
            Code::InvalidArgument,
            "{s}..{e}"
        );
    }
    assert_eq!(
        code(c.assign(assign("other", 2, 0, 10)).await),
        Code::FailedPrecondition
    );
    assert_eq!(
        code(c.assign(assign("job", 1, 0, 10)).await),
        Code::FailedPrecondition
    );
    // LBG over 0..10 has ⌈√10⌉ = 4 seeds: 5 probes are too many.
    let mut lbg = assign("job", 2, 0, 10);
    lbg.lbg_probes = 5;
    assert_eq!(code(c.assign(lbg).await), Code::InvalidArgument);

    // Loaded but not assigned.
    assert_eq!(
        code(search(&mut c, vec![batch("job", 2, 0, 1, 4, &q)]).await),
        Code::FailedPrecondition
    );
    c.assign(assign("job", 2, 0, total)).await.unwrap();

    malformed_searches(&mut c, &q).await;

    // A new level replaces the old one: searches of the old level are refused.
    c.load_level(one(level.load("job", 1))).await.unwrap();
    assert_eq!(
        code(search(&mut c, vec![batch("job", 2, 0, 1, 4, &q)]).await),
        Code::FailedPrecondition
    );
    assert_eq!(
        code(search(&mut c, vec![batch("job", 1, 0, 1, 4, &q)]).await),
        Code::FailedPrecondition,
        "level 1 is loaded but not assigned"
    );
    // Still serving, and ending a job twice is harmless.
    let end = || pb::EndJobRequest {
        job_id: "job".into(),
    };
    assert!(c.end_job(end()).await.unwrap().into_inner().freed_bytes > 0);
    assert_eq!(c.end_job(end()).await.unwrap().into_inner().freed_bytes, 0);
    w.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_level_sent_in_pieces_searches_as_one_sent_whole() {
    let (w, mut c) = start(config()).await;
    let level = Level::new(3, 40);
    let total = load(&mut c, &level, "whole").await;
    c.assign(assign("whole", 0, 0, total)).await.unwrap();
    let q = level.queries(5, 16);
    let want = search(&mut c, vec![batch("whole", 0, 0, 3, 16, &q)])
        .await
        .unwrap();
    // Pieces of one byte, of a size that does not divide a plane, and larger
    // than every plane (header and one piece per buffer).
    for piece in [1, 333, 1 << 20] {
        let parts = level.parts("pieces", piece);
        assert!(parts.len() >= 4, "header, pixels, mask, parent");
        let r = c.load_level(tokio_stream::iter(parts)).await.unwrap();
        assert_eq!(r.into_inner().total_vectors, total, "piece {piece}");
        c.assign(assign("pieces", 0, 0, total)).await.unwrap();
        let got = search(&mut c, vec![batch("pieces", 0, 0, 3, 16, &q)])
            .await
            .unwrap();
        assert_eq!(
            topk_hits(&got[0], 16).unwrap(),
            topk_hits(&want[0], 16).unwrap(),
            "piece {piece}"
        );
    }
    w.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn malformed_load_level_streams_get_invalid_argument() {
    let (w, mut c) = start(config()).await;
    let level = Level::new(3, 40);
    let parts = level.parts("j", 500);
    let piece = |buffer: pb::PlaneBuffer, data: Vec<u8>| pb::LoadLevelPart {
        header: None,
        piece: Some(pb::PlanePiece {
            buffer: buffer as i32,
            data,
        }),
    };
    let mut no_parent = parts[0].clone();
    no_parent.header.as_mut().unwrap().parent = None;
    let cases: Vec<(&str, Vec<pb::LoadLevelPart>)> = vec![
        ("empty stream", vec![]),
        ("piece before the header", parts[1..].to_vec()),
        ("header twice", [&parts[..], &parts[..1]].concat()),
        ("a piece past its plane", {
            let mut p = parts.clone();
            p.push(piece(pb::PlaneBuffer::SamplePixels, vec![0]));
            p
        }),
        ("a short plane", parts[..parts.len() - 1].to_vec()),
        ("unknown buffer", {
            let mut p = parts.clone();
            p[1].piece.as_mut().unwrap().buffer = 9;
            p
        }),
        ("a message with neither", {
            let mut p = parts.clone();
            p.insert(1, pb::LoadLevelPart::default());
            p
        }),
        ("a piece for a plane the header lacks", {
            let mut p = parts.clone();
            p[0] = no_parent;
            p
        }),
    ];
    for (what, parts) in cases {
        let r = c.load_level(tokio_stream::iter(parts)).await;
        assert_eq!(code(r), Code::InvalidArgument, "{what}");
    }
    // Still serving.
    let r = c.load_level(tokio_stream::iter(parts)).await.unwrap();
    assert!(r.into_inner().total_vectors > 0);
    w.shutdown().await;
}

/// A whole `LoadLevel` request as a stream of one message.
fn one(r: pb::LoadLevelRequest) -> tokio_stream::Iter<std::array::IntoIter<pb::LoadLevelPart, 1>> {
    tokio_stream::iter([pb::LoadLevelPart::from(r)])
}

/// A change that makes a good `LoadLevel` request malformed.
type Spoil = fn(&mut pb::LoadLevelRequest);

/// Every malformed `LoadLevel` (a mutation of the good request) is INVALID_ARGUMENT.
async fn malformed_load_levels(c: &mut Client, good: impl Fn() -> pb::LoadLevelRequest) {
    let cases: [(&str, Spoil); 12] = [
        ("even neighbourhood", |r| {
            r.geometry.as_mut().unwrap().neighbourhood = 4
        }),
        ("even parent window", |r| {
            r.geometry.as_mut().unwrap().parent_window = 2
        }),
        ("no geometry", |r| r.geometry = None),
        ("unknown metric", |r| {
            r.geometry.as_mut().unwrap().metric = 9
        }),
        ("zero weights", |r| {
            let g = r.geometry.as_mut().unwrap();
            (g.weight_hi, g.weight_lo) = (0, 0);
        }),
        ("short pixels", |r| {
            r.sample.as_mut().unwrap().pixels.pop();
        }),
        ("short mask", |r| {
            r.sample.as_mut().unwrap().defined.truncate(7)
        }),
        ("huge plane", |r| {
            let s = r.sample.as_mut().unwrap();
            (s.width, s.height) = (u32::MAX, u32::MAX);
        }),
        ("no parent", |r| r.parent = None),
        ("no sample", |r| r.sample = None),
        ("empty job id", |r| r.job_id = String::new()),
        ("long job id", |r| r.job_id = "x".repeat(129)),
    ];
    for (what, spoil) in cases {
        let mut r = good();
        spoil(&mut r);
        assert_eq!(
            code(c.load_level(one(r)).await),
            Code::InvalidArgument,
            "{what}"
        );
    }
}

/// Malformed or misdirected search batches get their status; a bad batch ends
/// its stream after the answers before it.
async fn malformed_searches(c: &mut Client, q: &(Vec<u8>, Vec<u8>)) {
    // Search.
    let bad_batches = [
        (batch("job", 2, 0, 1, 5, q), Code::InvalidArgument), // count × dims ≠ len
        (
            pb::SearchBatch {
                masks: vec![1; 3],
                ..batch("job", 2, 0, 1, 4, q)
            },
            Code::InvalidArgument,
        ),
        (
            batch("job", 2, 0, 1, 0, &(vec![], vec![])),
            Code::InvalidArgument,
        ),
        (batch("job", 2, 0, 100_000, 4, q), Code::InvalidArgument),
        (batch("", 2, 0, 1, 4, q), Code::InvalidArgument),
        (batch("nope", 2, 0, 1, 4, q), Code::FailedPrecondition),
        (batch("job", 7, 0, 1, 4, q), Code::FailedPrecondition),
        (
            pb::SearchBatch {
                epoch: 9,
                ..batch("job", 2, 0, 1, 4, q)
            },
            Code::FailedPrecondition,
        ),
        // Bounds: one per query in both fields, and only for best-1 search.
        (
            pb::SearchBatch {
                bound_index: vec![0; 3],
                bound_distance: vec![0; 4],
                ..batch("job", 2, 0, 1, 4, q)
            },
            Code::InvalidArgument,
        ),
        (
            pb::SearchBatch {
                bound_index: vec![0; 4],
                bound_distance: vec![0; 4],
                ..batch("job", 2, 0, 3, 4, q)
            },
            Code::InvalidArgument,
        ),
    ];
    // Top-k cuts: one per query, and only for top-k search.
    let cut_batches = [
        pb::SearchBatch {
            topk_cut: vec![9; 3],
            ..batch("job", 2, 0, 3, 4, q)
        },
        pb::SearchBatch {
            topk_cut: vec![9; 4],
            ..batch("job", 2, 0, 1, 4, q)
        },
    ];
    let bad_batches = bad_batches
        .into_iter()
        .chain(cut_batches.map(|b| (b, Code::InvalidArgument)));
    for (b, want) in bad_batches {
        let desc = format!("{} {} {} {}", b.job_id, b.level, b.count, b.epoch);
        assert_eq!(code(search(c, vec![b]).await), want, "{desc}");
    }
    // A malformed update (of a linked batch's bounds) ends the stream too.
    let update = pb::SearchBatch {
        batch_id: 3,
        update: true,
        lower_query: vec![0, 1],
        lower_distance: vec![5],
        ..Default::default()
    };
    let linked = pb::SearchBatch {
        linked: true,
        ..batch("job", 2, 3, 1, 4, q)
    };
    let mut stream = c
        .search(tokio_stream::iter(vec![linked, update]))
        .await
        .unwrap()
        .into_inner();
    let code = loop {
        match stream.message().await {
            Ok(Some(r)) => assert_eq!(r.batch_id, 3),
            Ok(None) => panic!("the malformed update was taken"),
            Err(s) => break s.code(),
        }
    };
    assert_eq!(code, Code::InvalidArgument);
    // A bad batch ends its stream; the answers before it still arrive.
    let mut stream = c
        .search(tokio_stream::iter(vec![
            batch("job", 2, 1, 1, 4, q),
            batch("job", 2, 2, 1, 5, q),
        ]))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(stream.message().await.unwrap().unwrap().batch_id, 1);
    assert_eq!(
        stream.message().await.unwrap_err().code(),
        Code::InvalidArgument
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn memory_limit_is_resource_exhausted() {
    // Dense vectors only: a range over --max-memory is refused.
    let (w, mut c) = start(WorkerConfig {
        max_memory: 1 << 20,
        storage: texsyn_engine::Storage::Dense,
        ..config()
    })
    .await;
    let level = Level::new(9, 200);
    let total = load(&mut c, &level, "j").await;
    assert_eq!(
        code(c.assign(assign("j", 0, 0, total)).await),
        Code::ResourceExhausted
    );
    let r = c
        .assign(assign("j", 0, 0, 1000))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.vectors, 1000);
    w.shutdown().await;

    // Auto: the same range is held as planes (a few KB) instead of refused.
    let (w, mut c) = start(WorkerConfig {
        max_memory: 1 << 20,
        ..config()
    })
    .await;
    let total = load(&mut c, &level, "j").await;
    let r = c
        .assign(assign("j", 0, 0, total))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.vectors, total);
    assert!(r.bytes < 1 << 20, "planes take {} bytes", r.bytes);
    w.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn jobs_share_one_memory_budget() {
    // Two jobs that each ask for over half of --max-memory: the second is
    // refused until the first ends, and concurrent Assigns never hold more
    // than the cap.
    let max = 6u64 << 20;
    let (w, mut c) = start(WorkerConfig {
        max_memory: max,
        storage: texsyn_engine::Storage::Dense,
        ..config()
    })
    .await;
    let level = Level::new(9, 300);
    let total = load(&mut c, &level, "a").await;
    load(&mut c, &level, "b").await;
    let small = c
        .assign(assign("a", 0, 0, 1000))
        .await
        .unwrap()
        .into_inner();
    let large = c
        .assign(assign("a", 0, 0, 3000))
        .await
        .unwrap()
        .into_inner();
    let per_vector = (large.bytes - small.bytes) / 2000;
    let n = total;
    assert!(
        n * per_vector > max / 2,
        "each job's range must need more than half the budget"
    );
    c.assign(assign("a", 0, 0, n)).await.unwrap();
    let e = c.assign(assign("b", 0, 0, n)).await.unwrap_err();
    assert_eq!(e.code(), Code::ResourceExhausted, "{e:?}");
    assert!(e.message().contains("--max-memory"), "{}", e.message());
    c.end_job(pb::EndJobRequest { job_id: "a".into() })
        .await
        .unwrap();
    c.assign(assign("b", 0, 0, n)).await.unwrap();

    // Eight concurrent Assigns of job b, each over half the cap.
    let calls = (0..8).map(|_| {
        let mut c = c.clone();
        tokio::spawn(async move { c.assign(assign("b", 0, 0, n)).await })
    });
    let mut ok = 0;
    for call in calls {
        match call.await.unwrap() {
            Ok(_) => ok += 1,
            Err(e) => assert!(
                matches!(e.code(), Code::ResourceExhausted | Code::FailedPrecondition),
                "{e:?}"
            ),
        }
    }
    assert!(ok >= 1, "at least one Assign succeeds");
    let info = c
        .info(pb::InfoRequest {
            protocol_version: PROTOCOL_VERSION,
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(info.memory_limit, max);
    assert!(
        info.memory_peak <= max,
        "peak {} over {max}",
        info.memory_peak
    );
    assert!(info.memory_in_use <= max);
    // A search still works on what was installed last.
    let q = level.queries(3, 4);
    search(&mut c, vec![batch("b", 0, 1, 1, 4, &q)])
        .await
        .unwrap();
    c.end_job(pb::EndJobRequest { job_id: "b".into() })
        .await
        .unwrap();
    let info = c
        .info(pb::InfoRequest {
            protocol_version: PROTOCOL_VERSION,
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(info.memory_in_use, 0, "ending every job frees every byte");
    w.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn oversized_parents_and_top_k_are_refused_before_allocation() {
    let (w, mut c) = start(config()).await;
    let level = Level::new(4, 40);
    let mut big_parent = level.load("j", 0);
    if let Some(p) = big_parent.parent.as_mut() {
        p.width = 65536;
        p.height = 65536;
        p.pixels.clear();
        p.defined.clear();
    }
    let e = c.load_level(one(big_parent)).await.unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument, "{e:?}");
    assert!(e.message().contains("parent"), "{}", e.message());
    // A whole 65536² sample is over any budget here: refused before it is sent.
    let mut big = level.load("j", 0);
    if let Some(s) = big.sample.as_mut() {
        s.width = 65536;
        s.height = 65536;
        s.pixels.clear();
        s.defined.clear();
    }
    big.parent = None;
    big.geometry.as_mut().unwrap().parent_window = 0;
    let e = c.load_level(one(big)).await.unwrap_err();
    assert_eq!(e.code(), Code::ResourceExhausted, "{e:?}");
    let total = load(&mut c, &level, "j").await;
    c.assign(assign("j", 0, 0, total)).await.unwrap();
    let q = level.queries(1, 2);
    let e = search(&mut c, vec![batch("j", 0, 1, 1_000_000, 2, &q)])
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument, "{e:?}");
    w.shutdown().await;
}

/// Reads from `s` until the peer closes it (or 5 s pass): how long that took.
async fn closed_after(s: &mut tokio::net::TcpStream) -> Option<Duration> {
    use tokio::io::AsyncReadExt;
    let t = std::time::Instant::now();
    let mut buf = [0u8; 4096];
    loop {
        match tokio::time::timeout(Duration::from_secs(5), s.read(&mut buf)).await {
            Ok(Ok(0)) | Ok(Err(_)) => return Some(t.elapsed()),
            Ok(Ok(_)) => continue,
            Err(_) => return None,
        }
    }
}

/// The HTTP/2 client preface and an empty SETTINGS frame.
const PREFACE: &[u8] = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n\x00\x00\x00\x04\x00\x00\x00\x00\x00";

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn silent_unauthenticated_and_surplus_connections_are_closed() {
    use tokio::io::AsyncWriteExt;
    use tokio::net::TcpStream;
    let limits = service::ConnectionLimits {
        max_connections: 8,
        first_byte: Duration::from_millis(300),
        authenticate: Duration::from_millis(800),
    };
    let w = Worker::start(WorkerConfig {
        token: Some("0123456789abcdef".into()),
        connections: limits,
        ..config()
    })
    .await;
    // Silent: closed after the first-byte timeout.
    let mut silent = TcpStream::connect(w.addr).await.unwrap();
    let took = closed_after(&mut silent)
        .await
        .expect("a silent socket is closed");
    assert!(
        took >= Duration::from_millis(250) && took < Duration::from_secs(2),
        "{took:?}"
    );

    // An HTTP/2 client that never makes an authenticated call: closed after
    // the authentication timeout, even though it answers pings.
    let mut h2 = TcpStream::connect(w.addr).await.unwrap();
    h2.write_all(PREFACE).await.unwrap();
    let took = closed_after(&mut h2)
        .await
        .expect("an idle HTTP/2 connection is closed");
    assert!(
        took >= Duration::from_millis(600) && took < Duration::from_secs(3),
        "{took:?}"
    );

    // A client with the wrong token gets UNAUTHENTICATED and is then closed.
    let mut wrong = connect(w.addr, Some("wrong-token-000000")).await;
    let e = wrong
        .info(pb::InfoRequest {
            protocol_version: PROTOCOL_VERSION,
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::Unauthenticated);

    // A real client keeps its connection past both timeouts.
    let mut good = connect(w.addr, Some("0123456789abcdef")).await;
    let info = pb::InfoRequest {
        protocol_version: PROTOCOL_VERSION,
    };
    good.info(info).await.unwrap();
    tokio::time::sleep(Duration::from_millis(1200)).await;
    good.info(info).await.unwrap();

    // Over the connection limit: with every slot held by connections that
    // speak (`good` and 7 more), one more speaking connection is closed at
    // once, before the first-byte timeout.
    let mut held = Vec::new();
    for _ in 0..7 {
        let mut s = TcpStream::connect(w.addr).await.unwrap();
        s.write_all(PREFACE).await.unwrap();
        held.push(s);
    }
    tokio::time::sleep(Duration::from_millis(50)).await;
    let mut surplus = TcpStream::connect(w.addr).await.unwrap();
    surplus.write_all(PREFACE).await.unwrap();
    let took = closed_after(&mut surplus)
        .await
        .expect("the surplus is closed");
    assert!(took < Duration::from_millis(250), "{took:?}");
    good.info(info).await.unwrap();
    drop(held);
    w.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_flood_of_silent_sockets_does_not_keep_a_client_out() {
    use tokio::net::TcpStream;
    let w = Worker::start(WorkerConfig {
        connections: service::ConnectionLimits {
            max_connections: 4096,
            ..Default::default()
        },
        ..config()
    })
    .await;
    let mut flood = Vec::new();
    for _ in 0..2000 {
        flood.push(TcpStream::connect(w.addr).await.unwrap());
    }
    // The 5 s first-byte timeout has not passed: the silent sockets were
    // pushed out by newer ones, so a new client gets in at once.
    let t = std::time::Instant::now();
    let mut c = connect(w.addr, None).await;
    c.info(pb::InfoRequest {
        protocol_version: PROTOCOL_VERSION,
    })
    .await
    .unwrap();
    assert!(t.elapsed() < Duration::from_secs(2), "{:?}", t.elapsed());
    drop(flood);
    w.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn protocol_version_mismatch_is_failed_precondition() {
    let (w, mut c) = start(config()).await;
    let s = c
        .info(pb::InfoRequest {
            protocol_version: PROTOCOL_VERSION + 1,
        })
        .await
        .unwrap_err();
    assert_eq!(s.code(), Code::FailedPrecondition);
    assert!(s.message().contains(&(PROTOCOL_VERSION + 1).to_string()));
    assert!(s.message().contains(&PROTOCOL_VERSION.to_string()));
    let info = c
        .info(pb::InfoRequest {
            protocol_version: PROTOCOL_VERSION,
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(info.threads, 1);
    assert!(info.cores >= 1);
    assert!(!info.kernel.is_empty());
    assert_eq!(info.memory_limit, 256 << 20);
    assert_eq!(info.version, env!("CARGO_PKG_VERSION"));
    w.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn calibration_reports_throughput_and_caps_sizes() {
    let (w, mut c) = start(config()).await;
    let r = c
        .calibrate(pb::CalibrateRequest {
            seed: 42,
            vectors: 4096,
            dims: 50,
            queries: 8,
        })
        .await
        .unwrap()
        .into_inner();
    assert!(r.pairs_per_second > 0.0 && r.seconds > 0.0);
    let info = c
        .info(pb::InfoRequest {
            protocol_version: PROTOCOL_VERSION,
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(info.calibrated_vectors_per_second, r.pairs_per_second);
    for bad in [
        pb::CalibrateRequest {
            seed: 1,
            vectors: u32::MAX,
            dims: 50,
            queries: 8,
        },
        pb::CalibrateRequest {
            seed: 1,
            vectors: 10,
            dims: 100_000,
            queries: 8,
        },
        pb::CalibrateRequest {
            seed: 1,
            vectors: 10,
            dims: 50,
            queries: 100_000,
        },
    ] {
        assert_eq!(code(c.calibrate(bad).await), Code::InvalidArgument);
    }
    w.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn health_check_reports_serving() {
    let w = Worker::start(config()).await;
    let mut health = tonic_health::pb::health_client::HealthClient::new(channel(w.addr).await);
    for name in ["", "texsyn.v1.Worker"] {
        let r = health
            .check(tonic_health::pb::HealthCheckRequest {
                service: name.into(),
            })
            .await
            .unwrap()
            .into_inner();
        assert_eq!(
            r.status,
            tonic_health::pb::health_check_response::ServingStatus::Serving as i32,
            "{name:?}"
        );
    }
    w.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn idle_timeout_frees_the_job() {
    let (w, mut c) = start(WorkerConfig {
        idle_timeout: Some(Duration::from_millis(200)),
        ..config()
    })
    .await;
    let level = Level::new(4, 40);
    c.load_level(one(level.load("j", 0))).await.unwrap();
    c.assign(assign("j", 0, 0, 100)).await.unwrap();
    let info = || pb::InfoRequest {
        protocol_version: PROTOCOL_VERSION,
    };
    let i = c.info(info()).await.unwrap().into_inner();
    assert!(i.memory_in_use > 0);
    assert_eq!(i.jobs, 1);
    tokio::time::sleep(Duration::from_millis(600)).await;
    let i = c.info(info()).await.unwrap().into_inner();
    assert_eq!((i.memory_in_use, i.jobs), (0, 0));
    assert_eq!(
        code(c.assign(assign("j", 0, 0, 100)).await),
        Code::FailedPrecondition
    );
    w.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_ends_open_search_streams() {
    let (w, mut c) = start(config()).await;
    let level = Level::new(4, 40);
    c.load_level(one(level.load("j", 0))).await.unwrap();
    c.assign(assign("j", 0, 0, 100)).await.unwrap();
    let (tx, rx) = tokio::sync::mpsc::channel(1);
    let mut stream = c
        .search(tokio_stream::wrappers::ReceiverStream::new(rx))
        .await
        .unwrap()
        .into_inner();
    tx.send(batch("j", 0, 1, 1, 2, &level.queries(1, 2)))
        .await
        .unwrap();
    assert_eq!(stream.message().await.unwrap().unwrap().batch_id, 1);
    // The stream stays open (tx alive) while the worker shuts down.
    let t = std::time::Instant::now();
    w.shutdown().await;
    assert!(t.elapsed() < Duration::from_secs(4));
    assert!(stream.message().await.is_err());
    drop(tx);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tls_with_token_serves() {
    let dir = tempfile::tempdir().unwrap();
    let Some((cert, key)) = texsyn_integration::self_signed_certificate(dir.path()) else {
        return;
    };
    let tls = service::TlsIdentity::from_files(&cert, &key).unwrap();
    let w = Worker::start(WorkerConfig {
        tls: Some(tls),
        token: Some("t0ken".into()),
        ..config()
    })
    .await;
    let pem = std::fs::read(&cert).unwrap();
    let ch = Channel::from_shared(format!("https://{}", w.addr))
        .unwrap()
        .tls_config(
            tonic::transport::ClientTlsConfig::new()
                .ca_certificate(tonic::transport::Certificate::from_pem(pem))
                .domain_name("localhost"),
        )
        .unwrap()
        .connect()
        .await
        .unwrap();
    let mut c = pb::worker_client::WorkerClient::with_interceptor(
        ch,
        BearerAuth::new(Some("t0ken")).unwrap(),
    );
    let info = c
        .info(pb::InfoRequest {
            protocol_version: PROTOCOL_VERSION,
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(info.protocol_version, PROTOCOL_VERSION);
    // Plain text to a TLS worker fails.
    let plain = Channel::from_shared(format!("http://{}", w.addr))
        .unwrap()
        .timeout(Duration::from_secs(5))
        .connect()
        .await;
    if let Ok(ch) = plain {
        let mut c = pb::worker_client::WorkerClient::with_interceptor(
            ch,
            BearerAuth::new(Some("t0ken")).unwrap(),
        );
        assert!(c
            .info(pb::InfoRequest {
                protocol_version: PROTOCOL_VERSION,
            })
            .await
            .is_err());
    }
    w.shutdown().await;
}

/// Mutual TLS (`TlsIdentity::client_ca_pem`): a client without a certificate
/// or with one of another CA gets no answer; one signed by the client CA does,
/// through the same client TLS code the master uses.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn mutual_tls_requires_a_client_certificate_of_the_client_ca() {
    use texsyn_proto::tls::TlsArgs;
    let dir = tempfile::tempdir().unwrap();
    let Some(pki) = texsyn_integration::test_pki(dir.path()) else {
        return;
    };
    let tls = service::TlsIdentity::from_files(&pki.server_cert, &pki.server_key)
        .unwrap()
        .with_client_ca(&pki.client_ca)
        .unwrap();
    let w = Worker::start(WorkerConfig {
        tls: Some(tls),
        ..config()
    })
    .await;
    let address = format!("https://127.0.0.1:{}", w.addr.port());
    let info = |client: Option<(&std::path::Path, &std::path::Path)>| {
        let args = TlsArgs {
            tls_ca: Some(pki.ca.clone()),
            tls_client_cert: client.map(|c| c.0.to_path_buf()),
            tls_client_key: client.map(|c| c.1.to_path_buf()),
            ..Default::default()
        };
        let address = address.clone();
        async move {
            let endpoint = args
                .load()
                .unwrap()
                .endpoint(&address, Duration::from_secs(5))
                .unwrap();
            let ch = endpoint.connect().await.map_err(|e| e.to_string())?;
            let mut c = pb::worker_client::WorkerClient::new(ch);
            c.info(pb::InfoRequest {
                protocol_version: PROTOCOL_VERSION,
            })
            .await
            .map(|r| r.into_inner().protocol_version)
            .map_err(|s| s.to_string())
        }
    };
    assert!(info(None).await.is_err());
    assert!(info(Some((&pki.other_client_cert, &pki.other_client_key)))
        .await
        .is_err());
    assert_eq!(
        info(Some((&pki.client_cert, &pki.client_key))).await,
        Ok(PROTOCOL_VERSION)
    );
    w.shutdown().await;
}
