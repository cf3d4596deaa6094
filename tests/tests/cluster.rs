//! The search cluster with real `texsyn-worker` processes on 127.0.0.x
//! (ARCHITECTURE §3.5, §4): the output is bit-identical to the local engine with 1,
//! 2 and 3 workers, with unequal worker speeds, when a worker is killed or
//! stopped mid-level, and when every worker is gone; bad calls are rejected
//! with the right status and the worker keeps serving.

use crate::harness;

use std::sync::{Arc, Mutex, OnceLock};
use std::time::{Duration, Instant};

use harness::{
    alive, planned, sample, sigcont, sigkill, sigstop, synth, texture_path, Token, Worker, LEVELS,
};
use serde_json::Value;
use texsyn::cluster::{ClusterOptions, ClusterSearch, WorkerSpec};
use texsyn::search::{LevelData, SearchBackend, Strategy};
use texsyn::Output;
use texsyn_engine::{Engine, Hit, OwnedLevel, QueryBatch};
use texsyn_proto::auth::BearerAuth;
use texsyn_proto::v1 as pb;
use texsyn_proto::wire;
use texsyn_proto::PROTOCOL_VERSION;

/// Side of the synthesised texture.
const SIDE: usize = 128;

/// Image bytes and copy map of the local engine: the truth every cluster run must equal.
fn reference() -> &'static (Vec<u8>, Vec<[u32; 2]>) {
    static R: OnceLock<(Vec<u8>, Vec<[u32; 2]>)> = OnceLock::new();
    R.get_or_init(|| {
        let out = synth(&mut planned(Strategy::Local, None), SIDE).unwrap();
        (out.image.rgb, out.copy_map)
    })
}

/// Options for tests: short control-call timeouts, a 2 s batch deadline floor.
fn options(workers: Vec<WorkerSpec>) -> ClusterOptions {
    ClusterOptions {
        workers,
        deadline_floor: Duration::from_secs(2),
        call_timeout: Duration::from_secs(5),
        connect_timeout: Duration::from_secs(2),
        ..ClusterOptions::default()
    }
}

/// Runs the synthesis with every level on `cluster`.
fn run(cluster: Box<dyn SearchBackend>) -> anyhow::Result<Output> {
    synth(&mut planned(Strategy::Cluster, Some(cluster)), SIDE)
}

fn assert_same_as_local(out: &Output, what: &str) {
    let (rgb, copy) = reference();
    assert!(
        out.image.rgb == *rgb,
        "{what}: image differs from the local engine"
    );
    assert!(
        out.copy_map == *copy,
        "{what}: copy map differs from the local engine"
    );
}

/// Every level that searched reports the pruning its searches did, counted
/// where they ran (workers and master): each (vector, query) pair once.
fn assert_pruning_reported(out: &Output, what: &str) {
    for l in &out.report.per_level {
        let Some(p) = l.prune else {
            assert_eq!(
                l.queries, 0,
                "{what}: level {} searched but reports no pruning",
                l.level
            );
            continue;
        };
        assert_eq!(
            p.pairs,
            l.reference_vectors as u64 * l.queries,
            "{what}: level {} pairs {p:?}",
            l.level
        );
        assert!(
            p.pruned <= p.pairs && p.chunks <= p.chunks_full,
            "{what}: {p:?}"
        );
        assert!(
            p.pruned > 0,
            "{what}: level {} pruned nothing: {p:?}",
            l.level
        );
    }
}

fn cluster_stats(out: &Output) -> &Value {
    &out.report.search_stats["cluster"]
}

fn events<'a>(stats: &'a Value, kind: &str) -> Vec<&'a Value> {
    stats["events"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["kind"] == kind)
        .collect()
}

fn worker_stats<'a>(stats: &'a Value, address: &str) -> &'a Value {
    stats["workers"]
        .as_array()
        .unwrap()
        .iter()
        .find(|w| w["address"] == address)
        .unwrap_or_else(|| panic!("no stats for {address}: {stats:#}"))
}

/// What the fault hooks see.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Point {
    /// Before the level is loaded.
    Level(usize),
    /// Before search call `n` (from 0) of a level.
    Search(usize, usize),
}

type Hook = Box<dyn FnMut(Point) + Send>;
/// Duration of every search call, with the point it was made at.
type Durations = Arc<Mutex<Vec<(Point, Duration)>>>;

/// A cluster backend with a hook before each level and each search, and the
/// duration of every search call.
struct Hooked {
    inner: ClusterSearch,
    hook: Hook,
    level: usize,
    call: usize,
    durations: Durations,
}

impl Hooked {
    fn new(inner: ClusterSearch, hook: Hook) -> (Self, Durations) {
        let durations = Arc::new(Mutex::new(Vec::new()));
        (
            Self {
                inner,
                hook,
                level: 0,
                call: 0,
                durations: durations.clone(),
            },
            durations,
        )
    }
}

impl SearchBackend for Hooked {
    fn name(&self) -> String {
        self.inner.name()
    }

    fn load_level(&mut self, level: &LevelData) -> anyhow::Result<()> {
        (self.hook)(Point::Level(level.level));
        self.level = level.level;
        self.call = 0;
        self.inner.load_level(level)
    }

    fn search(&mut self, queries: &QueryBatch) -> anyhow::Result<Vec<Hit>> {
        let p = Point::Search(self.level, self.call);
        (self.hook)(p);
        self.call += 1;
        let t = Instant::now();
        let r = self.inner.search(queries);
        self.durations.lock().unwrap().push((p, t.elapsed()));
        r
    }

    fn end_level(&mut self) {
        self.inner.end_level();
    }

    fn stats(&self) -> Value {
        self.inner.stats()
    }
}

/// A hook that kills the processes `pids` (SIGKILL) at `point`.
fn kill_at(point: Point, pids: Vec<u32>) -> Hook {
    Box::new(move |p| {
        if p == point {
            pids.iter().for_each(|&pid| sigkill(pid));
        }
    })
}

fn connect(opts: ClusterOptions) -> ClusterSearch {
    ClusterSearch::connect(opts, Engine::default()).unwrap()
}

#[test]
fn one_two_and_three_workers_match_the_local_engine() {
    let token = Token::new();
    let workers: Vec<Worker> = (1..=3).map(|k| Worker::with_token(k, &token, 1)).collect();
    for n in 1..=3 {
        let specs = workers[..n].iter().map(|w| w.spec(Some(&token))).collect();
        let out = run(Box::new(connect(options(specs)))).unwrap();
        assert_same_as_local(&out, &format!("{n} worker(s)"));
        assert_pruning_reported(&out, &format!("{n} worker(s)"));
        let stats = cluster_stats(&out);
        for w in &workers[..n] {
            let s = worker_stats(stats, &w.address.to_string());
            assert!(s["queries"].as_u64().unwrap() > 0, "{n} workers: {s:#}");
            assert_eq!(s["state"], "active");
            assert!(s["share"].as_f64().unwrap() > 0.0);
        }
        assert!(events(stats, "partition").len() == LEVELS, "{stats:#}");
        assert!(stats["local_fallback_levels"]
            .as_array()
            .unwrap()
            .is_empty());
    }
}

#[test]
fn master_share_matches_the_local_engine() {
    let token = Token::new();
    let w = Worker::with_token(19, &token, 1);
    let out = run(Box::new(connect(ClusterOptions {
        master_share: true,
        ..options(vec![w.spec(Some(&token))])
    })))
    .unwrap();
    assert_same_as_local(&out, "master share");
    assert_pruning_reported(&out, "master share");
    let stats = cluster_stats(&out);
    assert!(
        stats["master"]["queries"].as_u64().unwrap() > 0,
        "{stats:#}"
    );
    assert!(
        worker_stats(stats, &w.address.to_string())["queries"]
            .as_u64()
            .unwrap()
            > 0
    );
    let p = &events(stats, "partition")[0];
    let shares = p["shares"].as_array().unwrap();
    assert_eq!(shares.len(), 2, "{p:#}");
    assert_eq!(shares[1]["worker"], "master");
}

/// Workers that gather their ranges' vectors from the planes (as they do for
/// samples too large to hold densely) answer exactly like dense ones.
#[test]
fn plane_backed_workers_match_the_local_engine() {
    let token = Token::new();
    let path = token.path.to_str().unwrap().to_string();
    let args = [
        "--threads",
        "1",
        "--token-file",
        &path,
        "--vector-store",
        "planes",
    ];
    let workers: Vec<Worker> = [23, 24]
        .into_iter()
        .map(|h| Worker::start(h, &args))
        .collect();
    let specs = workers.iter().map(|w| w.spec(Some(&token))).collect();
    let out = run(Box::new(connect(options(specs)))).unwrap();
    assert_same_as_local(&out, "plane-backed workers");
    assert_pruning_reported(&out, "plane-backed workers");
    for w in &workers {
        assert!(alive(w.pid()), "worker {} exited", w.address);
    }
}

#[test]
fn unequal_worker_speeds_match_the_local_engine() {
    let token = Token::new();
    let one = Worker::with_token(4, &token, 1);
    let two = Worker::with_token(5, &token, 2);
    let bursty = Worker::with_token(6, &token, 1);
    // The third worker runs in bursts: stopped 15 ms out of every 25 ms.
    let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let pid = bursty.pid();
    let toggler = {
        let stop = stop.clone();
        std::thread::spawn(move || {
            while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                sigstop(pid);
                std::thread::sleep(Duration::from_millis(15));
                sigcont(pid);
                std::thread::sleep(Duration::from_millis(10));
            }
            sigcont(pid);
        })
    };
    let specs = [&one, &two, &bursty]
        .iter()
        .map(|w| w.spec(Some(&token)))
        .collect();
    let out = run(Box::new(connect(options(specs))));
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    toggler.join().unwrap();
    let out = out.unwrap();
    assert_same_as_local(&out, "unequal speeds");
    let stats = cluster_stats(&out);
    for w in [&one, &two] {
        let s = worker_stats(stats, &w.address.to_string());
        assert!(s["queries"].as_u64().unwrap() > 0, "{s:#}");
    }
}

#[test]
fn worker_killed_mid_level_output_unchanged() {
    let token = Token::new();
    let a = Worker::with_token(7, &token, 1);
    let b = Worker::with_token(8, &token, 1);
    let victim = b.pid();
    let hook = kill_at(Point::Search(1, 2), vec![victim]);
    let (backend, _) = Hooked::new(
        connect(options(vec![a.spec(Some(&token)), b.spec(Some(&token))])),
        hook,
    );
    let out = run(Box::new(backend)).unwrap();
    assert_same_as_local(&out, "worker killed");
    let stats = cluster_stats(&out);
    let baddr = b.address.to_string();
    let drops = events(stats, "drop");
    assert!(
        drops
            .iter()
            .any(|e| e["worker"] == baddr.as_str() && e["level"] == 1),
        "the report names the drop: {stats:#}"
    );
    let rep = events(stats, "repartition");
    let r = rep
        .iter()
        .find(|e| e["level"] == 1 && e["reason"].as_str().unwrap().contains(&baddr))
        .unwrap_or_else(|| panic!("the report names the repartition: {stats:#}"));
    let shares = r["shares"].as_array().unwrap();
    assert_eq!(shares.len(), 1, "{r:#}");
    assert_eq!(shares[0]["worker"], a.address.to_string().as_str());
    assert_eq!(shares[0]["share"], 1.0);
    assert_eq!(worker_stats(stats, &baddr)["state"], "dropped");
}

#[test]
fn worker_stopped_mid_level_is_dropped_by_deadline_and_taken_back_later() {
    let token = Token::new();
    let a = Worker::with_token(9, &token, 1);
    let b = Worker::with_token(10, &token, 1);
    let pid = b.pid();
    let hook: Hook = Box::new(move |p| match p {
        Point::Search(2, 1) => sigstop(pid),
        // Back before the next level: the master takes it in again there.
        Point::Level(1) => sigcont(pid),
        _ => {}
    });
    let floor = Duration::from_millis(500);
    let (backend, durations) = Hooked::new(
        connect(ClusterOptions {
            deadline_floor: floor,
            ..options(vec![a.spec(Some(&token)), b.spec(Some(&token))])
        }),
        hook,
    );
    let out = run(Box::new(backend));
    sigcont(pid);
    let out = out.unwrap();
    assert_same_as_local(&out, "worker stopped");
    let took = durations
        .lock()
        .unwrap()
        .iter()
        .find(|(p, _)| *p == Point::Search(2, 1))
        .map(|(_, d)| *d)
        .unwrap();
    assert!(
        took >= floor && took < floor + Duration::from_millis(2500),
        "the stopped worker is detected by its deadline ({floor:?} + expected time), not waited for: {took:?}"
    );
    let stats = cluster_stats(&out);
    let baddr = b.address.to_string();
    let drop = events(stats, "drop")
        .into_iter()
        .find(|e| e["worker"] == baddr.as_str())
        .unwrap_or_else(|| panic!("no drop event: {stats:#}"));
    assert_eq!(drop["level"], 2);
    assert!(
        drop["reason"].as_str().unwrap().contains("deadline"),
        "{drop:#}"
    );
    let rejoin = events(stats, "rejoin")
        .into_iter()
        .find(|e| e["worker"] == baddr.as_str())
        .unwrap_or_else(|| panic!("no rejoin event: {stats:#}"));
    assert_eq!(rejoin["level"], 1);
    let s = worker_stats(stats, &baddr);
    assert_eq!(s["state"], "active", "{s:#}");
    // Level 0 was searched by both again.
    let last = events(stats, "partition")
        .into_iter()
        .find(|e| e["level"] == 0)
        .unwrap();
    assert_eq!(last["shares"].as_array().unwrap().len(), 2, "{last:#}");
}

/// A run on an honest worker (host `hosts.0`) and one started with the
/// fault flag `fault` (host `hosts.1`), 1 thread each: its output, checked
/// against the local engine's, the faulty worker's address and the one drop
/// event it must have.
fn run_beside_a_faulty_worker(hosts: (u8, u8), fault: &str) -> (Output, String, Value) {
    let token = Token::new();
    let a = Worker::with_token(hosts.0, &token, 1);
    let path = token.path.to_str().unwrap().to_string();
    let b = Worker::start(hosts.1, &["--threads", "1", "--token-file", &path, fault]);
    let out = run(Box::new(connect(options(vec![
        a.spec(Some(&token)),
        b.spec(Some(&token)),
    ]))))
    .unwrap();
    assert_same_as_local(&out, fault);
    let baddr = b.address.to_string();
    let stats = cluster_stats(&out);
    let drops: Vec<Value> = events(stats, "drop")
        .into_iter()
        .filter(|e| e["worker"] == baddr.as_str())
        .cloned()
        .collect();
    assert_eq!(drops.len(), 1, "dropped once, never taken back: {stats:#}");
    assert_eq!(worker_stats(stats, &baddr)["state"], "dropped");
    assert_eq!(
        worker_stats(stats, &a.address.to_string())["state"],
        "active"
    );
    let drop = drops[0].clone();
    (out, baddr, drop)
}

#[test]
fn lying_worker_is_caught_dropped_and_never_taken_back() {
    // Worker b answers every query with another reference at distance 0,
    // which would win every merge; the master scores each answer itself.
    let (out, baddr, drop) = run_beside_a_faulty_worker((13, 14), "--fault-wrong-answers");
    let reason = drop["reason"].as_str().unwrap();
    assert!(
        reason.contains("distance 0") && reason.contains("not trusted again"),
        "{reason}"
    );
    assert_eq!(drop["level"], LEVELS - 1, "caught at its first batch");
    let stats = cluster_stats(&out);
    assert!(
        !events(stats, "rejoin")
            .iter()
            .any(|e| e["worker"] == baddr.as_str()),
        "a lying worker is not taken back: {stats:#}"
    );
}

#[test]
fn a_worker_reporting_distances_it_cannot_answer_is_dropped() {
    // Worker b, while it searches a linked batch (ARCHITECTURE §4.7), reports
    // distance 0 for every query, which starves worker a's pruning, and then
    // answers truthfully. Its answer is worse than what it reported, so the
    // master refuses it, drops it and asks the batch again of a alone.
    let (out, baddr, drop) = run_beside_a_faulty_worker((41, 42), "--fault-low-reports");
    let reason = drop["reason"].as_str().unwrap();
    assert!(reason.contains("reported finding distance 0"), "{reason}");
    assert_eq!(drop["level"], LEVELS - 1, "caught at its first batch");
    // The report that gave it away is counted in its link traffic, although
    // its answer was refused.
    let b = worker_stats(cluster_stats(&out), &baddr);
    assert!(b["link_reports"].as_u64().unwrap() >= 1, "{b:#}");
    assert!(b["link_updates"].as_u64().is_some(), "{b:#}");
}

#[test]
fn every_worker_missing_its_deadline_retries_once_before_dropping() {
    // The only worker stops for 1.5 s: its 0.5 s deadline passes, and with
    // every worker late the batch is asked again with 4× the deadline (2 s),
    // which it meets once it runs again. Nobody is dropped.
    let token = Token::new();
    let a = Worker::with_token(15, &token, 1);
    let pid = a.pid();
    let hook: Hook = Box::new(move |p| {
        if p == Point::Search(1, 1) {
            sigstop(pid);
            std::thread::spawn(move || {
                std::thread::sleep(Duration::from_millis(1500));
                sigcont(pid);
            });
        }
    });
    let (backend, _) = Hooked::new(
        connect(ClusterOptions {
            deadline_floor: Duration::from_millis(500),
            require_cluster: true,
            ..options(vec![a.spec(Some(&token))])
        }),
        hook,
    );
    let out = run(Box::new(backend));
    sigcont(pid);
    let out = out.unwrap();
    assert_same_as_local(&out, "retry");
    let stats = cluster_stats(&out);
    let retries = events(stats, "retry");
    assert_eq!(retries.len(), 1, "{stats:#}");
    assert_eq!(retries[0]["level"], 1);
    assert!(events(stats, "drop").is_empty(), "{stats:#}");
    assert_eq!(
        worker_stats(stats, &a.address.to_string())["state"],
        "active"
    );
}

#[test]
fn worker_much_slower_than_its_calibration_triggers_recalibration_and_repartition() {
    let token = Token::new();
    let a = Worker::with_token(17, &token, 1);
    let b = Worker::with_token(18, &token, 1);
    let pid = b.pid();
    // Three batches in a row, the second worker is held for 150 ms: slow, not dead.
    let hook: Hook = Box::new(move |p| {
        if let Point::Search(0, 2..=4) = p {
            sigstop(pid);
            std::thread::spawn(move || {
                std::thread::sleep(Duration::from_millis(150));
                sigcont(pid);
            });
        }
    });
    let (backend, _) = Hooked::new(
        connect(ClusterOptions {
            slow_strikes: 3,
            recalibrate_cooldown: 0,
            ..options(vec![a.spec(Some(&token)), b.spec(Some(&token))])
        }),
        hook,
    );
    let out = run(Box::new(backend)).unwrap();
    sigcont(pid);
    assert_same_as_local(&out, "slow worker");
    let stats = cluster_stats(&out);
    let baddr = b.address.to_string();
    let recal = events(stats, "recalibrate");
    assert!(
        recal
            .iter()
            .any(|e| e["level"] == 0 && e["reason"].as_str().unwrap().contains(&baddr)),
        "{stats:#}"
    );
    assert!(
        events(stats, "repartition").iter().any(|e| e["level"] == 0
            && e["reason"].as_str().unwrap().starts_with("recalibrated")
            && e["shares"].as_array().unwrap().len() == 2),
        "{stats:#}"
    );
    assert!(
        events(stats, "drop").is_empty(),
        "slow is not dead: {stats:#}"
    );
}

#[test]
fn all_workers_killed_falls_back_to_local_search_bit_identical() {
    let token = Token::new();
    let a = Worker::with_token(11, &token, 1);
    let b = Worker::with_token(12, &token, 1);
    let hook = kill_at(Point::Search(1, 1), vec![a.pid(), b.pid()]);
    let (backend, _) = Hooked::new(
        connect(options(vec![a.spec(Some(&token)), b.spec(Some(&token))])),
        hook,
    );
    let out = run(Box::new(backend)).unwrap();
    assert_same_as_local(&out, "all workers killed");
    let stats = cluster_stats(&out);
    assert_eq!(stats["local_fallback_levels"], serde_json::json!([1, 0]));
    assert!(!events(stats, "fallback").is_empty(), "{stats:#}");
    assert_eq!(events(stats, "drop").len(), 2, "{stats:#}");
}

#[test]
fn require_cluster_fails_cleanly_when_no_worker_is_left() {
    let token = Token::new();
    let a = Worker::with_token(13, &token, 1);
    let b = Worker::with_token(14, &token, 1);
    let hook = kill_at(Point::Search(1, 1), vec![a.pid(), b.pid()]);
    let (backend, _) = Hooked::new(
        connect(ClusterOptions {
            require_cluster: true,
            ..options(vec![a.spec(Some(&token)), b.spec(Some(&token))])
        }),
        hook,
    );
    let t = Instant::now();
    let err = run(Box::new(backend)).err().expect("the run fails");
    let msg = format!("{err:#}");
    assert!(
        msg.contains("no search worker left") && msg.contains("--require-cluster"),
        "{msg}"
    );
    assert!(t.elapsed() < Duration::from_secs(15), "{:?}", t.elapsed());
}

type RawClient = pb::worker_client::WorkerClient<
    tonic::codegen::InterceptedService<tonic::transport::Channel, BearerAuth>,
>;

async fn raw_client(addr: std::net::SocketAddr, token: Option<&str>) -> RawClient {
    let ch = tonic::transport::Channel::from_shared(format!("http://{addr}"))
        .unwrap()
        .timeout(Duration::from_secs(10))
        .connect()
        .await
        .unwrap();
    pb::worker_client::WorkerClient::with_interceptor(ch, BearerAuth::new(token).unwrap())
}

fn info() -> pb::InfoRequest {
    pb::InfoRequest {
        protocol_version: PROTOCOL_VERSION,
    }
}

/// A whole `LoadLevel` request as a stream of one message.
fn one(r: pb::LoadLevelRequest) -> tokio_stream::Iter<std::array::IntoIter<pb::LoadLevelPart, 1>> {
    tokio_stream::iter([pb::LoadLevelPart::from(r)])
}

fn load_request(side: u32, neighbourhood: u32) -> pb::LoadLevelRequest {
    pb::LoadLevelRequest {
        job_id: "bad-calls".into(),
        level: 0,
        geometry: Some(pb::Geometry {
            neighbourhood,
            parent_window: 0,
            weight_hi: 1,
            weight_lo: 1,
            metric: 0,
        }),
        sample: Some(pb::Plane {
            width: side,
            height: side,
            pixels: vec![7; (side * side) as usize],
            defined: Vec::new(),
        }),
        parent: None,
    }
}

#[test]
fn bad_calls_are_rejected_with_the_right_status_and_the_worker_keeps_serving() {
    let token = Token::new();
    let path = token.path.to_str().unwrap().to_string();
    let w = Worker::start(
        15,
        &[
            "--threads",
            "1",
            "--token-file",
            &path,
            "--max-message",
            "64K",
        ],
    );
    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(async {
        let good = Some(token.value.as_str());
        let code = |r: Result<tonic::Response<pb::InfoReply>, tonic::Status>| {
            r.map(|_| ())
                .map_err(|s| (s.code(), s.message().to_string()))
        };
        // Missing and wrong token.
        let mut none = raw_client(w.address, None).await;
        let e = code(none.info(info()).await).unwrap_err();
        assert_eq!(e.0, tonic::Code::Unauthenticated, "{e:?}");
        let mut wrong = raw_client(w.address, Some("not-the-token")).await;
        let e = code(wrong.info(info()).await).unwrap_err();
        assert_eq!(e.0, tonic::Code::Unauthenticated, "{e:?}");
        let mut c = raw_client(w.address, good).await;
        assert!(
            c.info(info()).await.is_ok(),
            "still serving after bad tokens"
        );

        // Version mismatch: refused, the message names both versions.
        let e = code(
            c.info(pb::InfoRequest {
                protocol_version: 99,
            })
            .await,
        )
        .unwrap_err();
        assert_eq!(e.0, tonic::Code::FailedPrecondition, "{e:?}");
        assert!(
            e.1.contains("99") && e.1.contains(&format!("version {PROTOCOL_VERSION}")),
            "{e:?}"
        );
        assert!(c.info(info()).await.is_ok());

        // Malformed geometry (even neighbourhood) and an over-large one.
        for n in [4, 0, 65] {
            let e = c.load_level(one(load_request(32, n))).await.unwrap_err();
            assert_eq!(e.code(), tonic::Code::InvalidArgument, "n={n}: {e:?}");
        }
        // A plane whose byte count does not match its size.
        let mut bad = load_request(32, 5);
        bad.sample.as_mut().unwrap().pixels.pop();
        let e = c.load_level(one(bad)).await.unwrap_err();
        assert_eq!(e.code(), tonic::Code::InvalidArgument, "{e:?}");

        // Over the 64 KiB message limit in one message; the same level in
        // pieces that fit the limit loads.
        let e = c.load_level(one(load_request(300, 5))).await.unwrap_err();
        assert_eq!(e.code(), tonic::Code::ResourceExhausted, "{e:?}");
        let big = load_request(300, 5);
        let (geometry, params) = wire::geometry_from_proto(big.geometry.as_ref()).unwrap();
        let plane = wire::plane_from_proto(big.sample.unwrap(), "sample").unwrap();
        let level = OwnedLevel::locate(0, geometry, params, plane, None).unwrap();
        let total = level.total();
        let parts = wire::load_level_parts("bad-calls", Arc::new(level), 32 << 10);
        let r = c
            .load_level(tokio_stream::iter(parts))
            .await
            .unwrap()
            .into_inner();
        assert_eq!(r.total_vectors, total);
        assert_eq!(total, 296 * 296);
        let e = c
            .calibrate(pb::CalibrateRequest {
                seed: 1,
                vectors: u32::MAX,
                dims: 106,
                queries: 1,
            })
            .await
            .unwrap_err();
        assert_eq!(e.code(), tonic::Code::InvalidArgument, "{e:?}");

        // Still serving: a valid level loads.
        let r = c
            .load_level(one(load_request(32, 5)))
            .await
            .unwrap()
            .into_inner();
        assert_eq!(r.total_vectors, 28 * 28);
    });
    drop(rt);
    assert!(
        harness::alive(w.pid()),
        "the worker survived every bad call"
    );
    // And a whole synthesis on it still equals the local engine.
    let out = run(Box::new(connect(options(vec![w.spec(Some(&token))])))).unwrap();
    assert_same_as_local(&out, "after bad calls");
}

#[test]
fn master_refuses_wrong_token_and_version_mismatch_with_clear_errors() {
    let token = Token::new();
    let w = Worker::with_token(16, &token, 1);
    let strict = |spec: WorkerSpec| ClusterOptions {
        require_cluster: true,
        ..options(vec![spec])
    };
    let err = |o: ClusterOptions| {
        format!(
            "{:#}",
            ClusterSearch::connect(o, Engine::default())
                .err()
                .expect("refused")
        )
    };
    let e = err(strict(WorkerSpec::new(w.address.to_string(), None)));
    assert!(
        e.contains("Unauthenticated") && e.contains("missing"),
        "{e}"
    );
    let e = err(strict(WorkerSpec::new(
        w.address.to_string(),
        Some("wrong".into()),
    )));
    assert!(
        e.contains("Unauthenticated") && e.contains("wrong token"),
        "{e}"
    );
    let e = err(ClusterOptions {
        protocol_version: PROTOCOL_VERSION + 1,
        ..strict(w.spec(Some(&token)))
    });
    assert!(
        e.contains(&format!("version {}", PROTOCOL_VERSION + 1))
            && e.contains(&format!("version {PROTOCOL_VERSION}")),
        "{e}"
    );
    // Without --require-cluster the run goes on locally, and says so in the report.
    let c = ClusterSearch::connect(
        options(vec![WorkerSpec::new(w.address.to_string(), None)]),
        Engine::default(),
    )
    .unwrap();
    assert_eq!(c.active_workers(), 0);
    let out = run(Box::new(c)).unwrap();
    assert_same_as_local(&out, "no usable worker");
    let stats = cluster_stats(&out);
    assert_eq!(stats["local_fallback_levels"], serde_json::json!([2, 1, 0]));
    // The worker kept serving the right token throughout.
    let c = connect(options(vec![w.spec(Some(&token))]));
    assert_eq!(c.active_workers(), 1);
}

#[test]
fn tls_cluster_matches_the_local_engine() {
    let dir = tempfile::tempdir().unwrap();
    let Some((cert, key)) = texsyn_integration::self_signed_certificate(dir.path()) else {
        return;
    };
    let token = Token::new();
    let w = Worker::start(
        1,
        &[
            "--threads",
            "1",
            "--token-file",
            token.path.to_str().unwrap(),
            "--tls-cert",
            cert.to_str().unwrap(),
            "--tls-key",
            key.to_str().unwrap(),
        ],
    );
    let spec = WorkerSpec::new(
        format!("localhost:{}", w.address.port()),
        Some(token.value.clone()),
    );
    let c = connect(ClusterOptions {
        tls: texsyn_proto::tls::ClientTls {
            ca_pem: Some(std::fs::read(&cert).unwrap()),
            ..Default::default()
        },
        require_cluster: true,
        ..options(vec![spec.clone()])
    });
    let out = run(Box::new(c)).unwrap();
    assert_same_as_local(&out, "TLS");
    // Plain text to the TLS worker is refused.
    let e = ClusterSearch::connect(
        ClusterOptions {
            require_cluster: true,
            ..options(vec![spec])
        },
        Engine::default(),
    );
    assert!(e.is_err());
}

#[test]
fn cli_local_workers_match_local_search_and_are_stopped_afterwards() {
    let dir = tempfile::tempdir().unwrap();
    let texsyn = harness::binary("texsyn");
    let sample = texture_path("brick_color_96.png");
    let common = |out: &str| {
        let mut c = std::process::Command::new(&texsyn);
        c.arg("synth")
            .arg(&sample)
            .args([
                "--size", "96x96", "--levels", "3", "--seed", "3", "-q", "-o",
            ])
            .arg(dir.path().join(out));
        c
    };
    let local = common("local.png")
        .args(["--search", "local,local,local"])
        .output()
        .unwrap();
    assert!(
        local.status.success(),
        "{}",
        String::from_utf8_lossy(&local.stderr)
    );
    let report = dir.path().join("report.json");
    let cluster = common("cluster.png")
        .args([
            "--search",
            "cluster,cluster,cluster",
            "--local-workers",
            "2",
        ])
        .args(["--require-cluster", "--report"])
        .arg(&report)
        .output()
        .unwrap();
    assert!(
        cluster.status.success(),
        "{}",
        String::from_utf8_lossy(&cluster.stderr)
    );
    let a = std::fs::read(dir.path().join("local.png")).unwrap();
    let b = std::fs::read(dir.path().join("cluster.png")).unwrap();
    assert!(a == b, "--local-workers output differs from local search");
    let r: Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    let workers = r["search_stats"]["cluster"]["workers"].as_array().unwrap();
    assert_eq!(workers.len(), 2);
    for w in workers {
        assert!(w["queries"].as_u64().unwrap() > 0, "{w:#}");
        // The worker process is gone: nothing listens on its port any more.
        let addr: std::net::SocketAddr = w["address"].as_str().unwrap().parse().unwrap();
        assert!(
            std::net::TcpStream::connect_timeout(&addr, Duration::from_secs(1)).is_err(),
            "local worker {addr} still listening after the run"
        );
    }
    // Cluster flags without workers are refused with a message naming both.
    let bad = common("x.png").arg("--require-cluster").output().unwrap();
    assert!(!bad.status.success());
    let msg = String::from_utf8_lossy(&bad.stderr);
    assert!(
        msg.contains("--require-cluster") && msg.contains("--workers"),
        "{msg}"
    );
}

/// LBG on the cluster (issue: approximate search per level): each worker
/// quantises its own range. With probes ≥ every worker's seeds the answers are
/// exhaustive, so the output equals the local engine; with one probe the run
/// completes, the plan is recorded and the answers are valid references.
#[test]
fn lbg_on_the_cluster_is_exact_with_all_probes_and_runs_with_one() {
    let token = Token::new();
    let workers: Vec<Worker> = (1..=2).map(|k| Worker::with_token(k, &token, 1)).collect();
    let specs: Vec<WorkerSpec> = workers.iter().map(|w| w.spec(Some(&token))).collect();
    for probes in [u32::MAX, 1] {
        let mut backend = planned(
            Strategy::ClusterLbg,
            Some(Box::new(connect(options(specs.clone())))),
        );
        backend.lbg_probes = probes;
        let out = synth(&mut backend, SIDE).unwrap();
        let plan = out.report.search_stats["plan"].as_array().unwrap();
        assert_eq!(plan.len(), LEVELS);
        assert!(
            plan.iter().all(|p| p["strategy"] == "cluster-lbg"),
            "{plan:?}"
        );
        let stats = cluster_stats(&out);
        assert!(
            stats["local_fallback_levels"]
                .as_array()
                .unwrap()
                .is_empty(),
            "{stats:#}"
        );
        if probes == u32::MAX {
            assert_same_as_local(&out, "cluster LBG with all probes");
        } else {
            // One probe really is approximate (the workers quantised) ...
            assert!(
                out.copy_map != reference().1,
                "P = 1 gave the exhaustive answer everywhere"
            );
            // ... and every output pixel still comes from the sample it names.
            let w = out.image.width;
            for (i, c) in out.copy_map.iter().enumerate() {
                assert_eq!(
                    out.image.get(i % w, i / w),
                    sample().get(c[0] as usize, c[1] as usize)
                );
            }
        }
    }
}

/// `--stitch path` (blocks meet the canvas along minimum-error paths) gives
/// the same bytes on local worker processes as on the local engine: the
/// stitch runs on the master after each exact search.
#[test]
fn path_stitching_on_workers_matches_the_local_engine() {
    let dir = tempfile::tempdir().unwrap();
    let sample = harness::texture_path("brick_color_96.png");
    let run = |name: &str, extra: &[&str]| {
        let out = dir.path().join(name);
        let (sample, out_arg) = (sample.to_str().unwrap(), out.to_str().unwrap());
        let args = ["synth", sample, "--size", "192x192", "--seed", "3"];
        harness::texsyn_ok(
            &[&args[..], &["--stitch", "path", "-q", "-o", out_arg], extra].concat(),
        );
        std::fs::read(out).unwrap()
    };
    let cluster = run(
        "cluster.png",
        &[
            "--local-workers",
            "2",
            "--search",
            "cluster,cluster,cluster",
            "--levels",
            "3",
        ],
    );
    let local3 = run("local3.png", &["--levels", "3"]);
    assert!(
        cluster == local3,
        "cluster and local differ with --stitch path"
    );
}

/// ω-tiles (Dong–Zhou–Paul): the immune search's affinity searches run on two
/// workers and give the same patches, the same f per generation and the same
/// tiles as the in-process engine.
#[test]
fn omega_tiles_on_workers_match_the_local_engine() {
    let dir = tempfile::tempdir().unwrap();
    let sample = harness::texture_path("pink_marble_color_128.png");
    let run = |name: &str, extra: &[&str]| {
        let out = dir.path().join(name);
        let (sample, out_arg) = (sample.to_str().unwrap(), out.to_str().unwrap());
        let method = ["tiles", "make", sample, "--method", "omega", "--set", "17"];
        let search = [
            "--tile-size",
            "64",
            "--generations",
            "8",
            "--baseline",
            "10",
        ];
        let rest = ["--seed", "5", "-q", "-o", out_arg];
        harness::texsyn_ok(&[&method[..], &search, &rest, extra].concat());
        let json = |f: &str| -> serde_json::Value {
            serde_json::from_slice(&std::fs::read(out.join(f)).unwrap()).unwrap()
        };
        let history: Vec<serde_json::Value> = json("ais.json")["result"]["history"]
            .as_array()
            .unwrap()
            .iter()
            .map(|g| g["best_f"].clone())
            .collect();
        let tiles: Vec<Vec<u8>> = (1..=17)
            .map(|k| std::fs::read(out.join(format!("tile_{k:02}.png"))).unwrap())
            .collect();
        (json("tileset.json")["patches"].clone(), history, tiles)
    };
    let cluster = run("cluster", &["--local-workers", "2"]);
    let local = run("local", &[]);
    assert_eq!(cluster.0, local.0, "patches");
    assert_eq!(cluster.1, local.1, "f per generation");
    assert!(cluster.2 == local.2, "tiles differ");
}

/// The synthesis on coordinates takes its k-coherence sets from the
/// cluster's top-k search: with 2 local workers the synthesis and a morph
/// are byte-identical to the local engine's.
#[test]
fn parallel_synthesis_and_morph_on_local_workers_match_the_local_engine() {
    let dir = tempfile::tempdir().unwrap();
    let texsyn = harness::binary("texsyn");
    let a = texture_path("pink_marble_color_128.png");
    let b = texture_path("brick_color_96.png");
    let run = |args: &[&std::ffi::OsStr], out: &str, cluster: bool| {
        let mut c = std::process::Command::new(&texsyn);
        c.args(args)
            .args(["--size", "160x128", "-q", "-o"])
            .arg(dir.path().join(out))
            .arg("--coords")
            .arg(dir.path().join(format!("c_{out}")));
        if cluster {
            c.args(["--local-workers", "2", "--require-cluster"]);
        }
        let r = c.output().unwrap();
        assert!(
            r.status.success(),
            "{out}: {}",
            String::from_utf8_lossy(&r.stderr)
        );
    };
    let synth: Vec<&std::ffi::OsStr> = vec![
        "synth".as_ref(),
        a.as_os_str(),
        "--method".as_ref(),
        "parallel".as_ref(),
        "--neighbourhood".as_ref(),
        "half".as_ref(),
    ];
    let morph: Vec<&std::ffi::OsStr> = vec![
        "morph".as_ref(),
        a.as_os_str(),
        b.as_os_str(),
        "--ramp".as_ref(),
        "x".as_ref(),
    ];
    run(&synth, "synth_local.png", false);
    run(&synth, "synth_cluster.png", true);
    run(&morph, "morph_local.png", false);
    run(&morph, "morph_cluster.png", true);
    let read = |f: &str| std::fs::read(dir.path().join(f)).unwrap();
    for f in [
        "synth_%.png",
        "c_synth_%.png",
        "morph_%.png",
        "c_morph_%_1.png",
        "c_morph_%_2.png",
    ] {
        assert!(
            read(&f.replace('%', "local")) == read(&f.replace('%', "cluster")),
            "{f}: the cluster's output differs from the local engine's"
        );
    }
}

#[test]
fn solid_on_local_workers_matches_the_local_engine() {
    let dir = tempfile::tempdir().unwrap();
    let texsyn = harness::binary("texsyn");
    let a = texture_path("pink_marble_color_128.png");
    let b = texture_path("brick_color_96.png");
    let run = |out: &str, cluster: bool| {
        let mut c = std::process::Command::new(&texsyn);
        c.arg("solid")
            .arg("--view")
            .arg(format!("xyz={}", a.display()))
            .arg("--view")
            .arg(format!("2:xz={}", b.display()))
            .args([
                "--ramp", "y", "--size", "24", "--slices", "none", "-q", "-o",
            ])
            .arg(dir.path().join(out));
        if cluster {
            c.args(["--local-workers", "2", "--require-cluster"]);
        }
        let r = c.output().unwrap();
        assert!(
            r.status.success(),
            "{out}: {}",
            String::from_utf8_lossy(&r.stderr)
        );
        std::fs::read(dir.path().join(out).join("solid.raw")).unwrap()
    };
    assert!(
        run("local", false) == run("cluster", true),
        "the cluster's solid differs from the local engine's"
    );
}

/// Repetition control answers from the exact search's near-ties: the same
/// bytes on 1 and 2 threads and with 2 local worker processes (whose top-k
/// lists the master filters), and a different output from the plain best
/// match.
#[test]
fn repetition_control_is_identical_over_threads_and_workers() {
    let dir = tempfile::tempdir().unwrap();
    let run = |name: &str, extra: &[&str]| -> Vec<u8> {
        let out = dir.path().join(format!("{name}.png"));
        let r = std::process::Command::new(harness::binary("texsyn"))
            .arg("synth")
            .arg(texture_path("brick_color_96.png"))
            .args([
                "--size", "160x144", "--levels", "3", "--seed", "3", "-q", "-o",
            ])
            .arg(&out)
            .args(extra)
            .stdin(std::process::Stdio::null())
            .output()
            .unwrap();
        assert!(
            r.status.success(),
            "{name}: {}",
            String::from_utf8_lossy(&r.stderr)
        );
        std::fs::read(&out).unwrap()
    };
    harness::binary("texsyn-worker");
    let cluster = [
        "--search",
        "cluster,cluster,cluster",
        "--local-workers",
        "2",
        "--require-cluster",
    ];
    let control = ["--repeat-percent", "25"];
    let one = run("one", &[&control[..], &["--threads", "1"]].concat());
    let two = run("two", &[&control[..], &["--threads", "2"]].concat());
    assert!(one == two, "repetition control differs on 1 and 2 threads");
    let workers = run("workers", &[&control[..], &cluster[..]].concat());
    assert!(
        one == workers,
        "repetition control differs on 2 local workers"
    );
    let plain = run("plain", &["--threads", "2"]);
    assert!(one != plain, "repetition control changed nothing");
    // The output of `flags` on 1 thread, checked equal on 2 local workers.
    let same_on_workers = |name: &str, flags: &[&str]| {
        let on_one = run(
            &format!("{name}-one"),
            &[flags, &["--threads", "1"]].concat(),
        );
        let on_workers = run(&format!("{name}-workers"), &[flags, &cluster[..]].concat());
        assert!(on_one == on_workers, "{name} differs on 2 local workers");
        on_one
    };
    // The seam filter runs on the master too: the same bytes on 1 thread and
    // on 2 workers, and a different pick from the same slack without it.
    let seam_one = same_on_workers("seam", &["--repeat-seam", "15"]);
    let unfiltered = run("unfiltered", &["--repeat-percent", "150", "--threads", "2"]);
    assert!(seam_one != unfiltered, "the seam filter changed nothing");
    // So does the patch cap: its offsets are counted on the master, in the
    // batch's copy order.
    let cap_one = same_on_workers("cap", &["--repeat-cap", "20"]);
    assert!(cap_one != one, "the patch cap picks as the use counts do");
    // The lattice rule (ARCHITECTURE §3.14) picks among the same near-tie
    // lists by phase, on the master.
    let lattice_one = same_on_workers("lattice", &["--lattice", "40x58"]);
    assert!(lattice_one != plain, "the lattice rule changed nothing");
}
