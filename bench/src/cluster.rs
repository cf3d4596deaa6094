//! `texsyn-bench cluster`: the cluster on loopback against the local engine
//! (ARCHITECTURE §4, §5, §6). On the finest level of the paper's configuration
//! (b) (500×500 sample, 11×11 neighbourhood, 7×7 parent window) it measures
//!
//! - the round-trip latency per batch (and per 1-query batch), against the
//!   search time the workers report;
//! - the throughput of 2 local worker processes with 1 search thread each,
//!   over the local engine with 2 threads on the same queries (target ≥ 0.95);
//! - each worker's peak memory (VmHWM) against the bytes of its vector range
//!   (target ≤ 1.2 × range bytes + 64 MB).
//!
//! The cluster's answers are checked against the local engine's on every batch.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{ensure, Context, Result};
use clap::Args;
use rand::{Rng, SeedableRng};
use texsyn::cluster::{ClusterOptions, ClusterSearch};
use texsyn::imaging;
use texsyn::launch::{find_worker_binary, LocalWorkers};
use texsyn::pyramid;
use texsyn::search::{LevelData, LocalSearch, SearchBackend};
use texsyn_engine::{
    Engine, Geometry, Hit, Metric, Params, Plane, PruneStats, QueryBatch, Sample, VectorSpace,
    Weights,
};

use crate::cases::Textures;

/// Batches searched before the measured ones.
const WARM: usize = 3;

#[derive(Args, Debug)]
pub struct ClusterArgs {
    #[command(flatten)]
    pub textures: Textures,
    /// Queries per batch (K).
    #[arg(long, default_value_t = 64)]
    pub batch: usize,
    /// Batches measured (after 3 warm-up batches).
    #[arg(long, default_value_t = 60)]
    pub batches: usize,
    /// Rounds, alternating local and cluster; the best of each is compared.
    #[arg(long, default_value_t = 5)]
    pub reps: usize,
    /// The texsyn-worker executable (default: next to texsyn-bench, else PATH).
    #[arg(long)]
    pub worker_binary: Option<PathBuf>,
    /// One more argument for both workers, repeatable (e.g.
    /// `--worker-arg=--spin-us=0` to compare the wait policies).
    #[arg(long, value_name = "ARG", allow_hyphen_values = true)]
    pub worker_arg: Vec<String>,
}

/// Peak resident memory (VmHWM) of a process in bytes, from /proc.
fn peak_memory(pid: u32) -> Option<u64> {
    let s = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    let i = ((sorted.len() - 1) as f64 * p).round() as usize;
    sorted[i.min(sorted.len() - 1)]
}

fn ms(s: f64) -> String {
    format!("{:.3} ms", s * 1e3)
}

/// Random query batches made from reference vectors with about a third of the
/// hi components masked out (as on a partly synthesised canvas).
fn make_batches(
    space: &VectorSpace,
    count: usize,
    per: usize,
    seed: u64,
) -> Result<Vec<QueryBatch>> {
    let l = space.layout();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut out = Vec::with_capacity(count);
    for _ in 0..count {
        let mut b = QueryBatch::new(l);
        for _ in 0..per {
            let idx = rng.random_range(space.start()..space.end());
            let v = space.vector(idx).context("vector")?;
            let mut values = Vec::with_capacity(l.dims());
            l.unpad_into(&v, &mut values);
            for x in &mut values {
                *x = x.saturating_add(rng.random_range(0..3));
            }
            let mask: Vec<u8> = (0..l.dims())
                .map(|i| u8::from(i >= l.hi_len || rng.random_range(0..3) != 0))
                .collect();
            b.push(&values, &mask)?;
        }
        out.push(b);
    }
    Ok(out)
}

/// The best round of the local engine and of the cluster.
#[derive(Default)]
struct Rounds {
    local_qps: f64,
    cluster_qps: f64,
    /// Cluster over local throughput of each round, sorted.
    ratios: Vec<f64>,
    /// Round trips of the cluster's best round, sorted.
    rtts: Vec<f64>,
    /// The workers' own search seconds per batch in the cluster's best round.
    worker_per_batch: [f64; 2],
    /// CPU by thread role over every round's measured cluster batches.
    cpu: ThreadCpu,
    /// Wall time of those batches, every round.
    cluster_wall: f64,
}

/// Each worker's search seconds so far, from the cluster's stats.
fn worker_seconds(c: &ClusterSearch) -> Vec<f64> {
    c.stats()["workers"]
        .as_array()
        .map(|w| w.iter().filter_map(|x| x["seconds"].as_f64()).collect())
        .unwrap_or_default()
}

/// Rounds alternate the two, so a noisy neighbour on the machine hits both alike.
fn measure(
    a: &ClusterArgs,
    pool: &rayon::ThreadPool,
    local: &mut LocalSearch,
    cluster: &mut ClusterSearch,
    batches: &[QueryBatch],
    worker_pids: &[u32],
) -> Result<Rounds> {
    let queries = (a.batches * a.batch) as f64;
    let mut r = Rounds::default();
    for _ in 0..a.reps.max(1) {
        let mut truth: Vec<Vec<Hit>> = Vec::new();
        let mut local_seconds = 0.0;
        pool.install(|| -> Result<()> {
            for (i, q) in batches.iter().enumerate() {
                let t = Instant::now();
                let h = local.search(q)?;
                if i >= WARM {
                    local_seconds += t.elapsed().as_secs_f64();
                }
                truth.push(h);
            }
            Ok(())
        })?;
        let mut round_rtts = Vec::new();
        let mut cluster_seconds = 0.0;
        let mut before = worker_seconds(cluster);
        let mut cpu_before = ThreadCpu::now(worker_pids);
        for (i, q) in batches.iter().enumerate() {
            if i == WARM {
                before = worker_seconds(cluster);
                cpu_before = ThreadCpu::now(worker_pids);
            }
            let t = Instant::now();
            let h = cluster.search(q)?;
            let dt = t.elapsed().as_secs_f64();
            ensure!(
                h == truth[i],
                "batch {i}: the cluster's answers differ from the local engine's"
            );
            if i >= WARM {
                cluster_seconds += dt;
                round_rtts.push(dt);
            }
        }
        let after = worker_seconds(cluster);
        if let (Some(b), Some(e)) = (cpu_before, ThreadCpu::now(worker_pids)) {
            r.cpu.add(&e.since(&b));
            r.cluster_wall += cluster_seconds;
        }
        let (lq, cq) = (queries / local_seconds, queries / cluster_seconds);
        r.ratios.push(cq / lq);
        if cq > r.cluster_qps {
            r.cluster_qps = cq;
            r.rtts = round_rtts;
            for (k, w) in r.worker_per_batch.iter_mut().enumerate() {
                *w = (after.get(k).unwrap_or(&0.0) - before.get(k).unwrap_or(&0.0))
                    / a.batches as f64;
            }
        }
        r.local_qps = r.local_qps.max(lq);
    }
    r.ratios.sort_by(f64::total_cmp);
    Ok(r)
}

/// Round trips of 1-query batches (the first query of the first 20 batches):
/// the fixed cost of a round trip, sorted.
fn one_query_trips(cluster: &mut ClusterSearch, batches: &[QueryBatch]) -> Result<Vec<f64>> {
    let mut small = Vec::new();
    for q in batches.iter().take(20) {
        let mut one = QueryBatch::new(q.layout());
        let (values, mask) = q.unpadded_range(0..1);
        one.push(&values, &mask)?;
        let t = Instant::now();
        cluster.search(&one)?;
        small.push(t.elapsed().as_secs_f64());
    }
    small.sort_by(f64::total_cmp);
    Ok(small)
}

pub fn run(a: &ClusterArgs) -> Result<()> {
    ensure!(
        a.batch >= 1 && a.batches >= 1,
        "--batch and --batches must be ≥ 1"
    );
    let file = a.textures.dir()?.join("gravel_gray_500.png");
    let img = imaging::load_color(&file)?;
    let lum = texsyn::imaging::colour::luminance(&img);
    let parent = pyramid::downsample(&lum, None, false);
    let geometry = Geometry::new(11, Geometry::parent_window_for(11))?;
    let params = Params {
        metric: Metric::L1,
        weights: Weights::new(1, 2)?,
    };
    let sample = Sample {
        fine: Plane::new(lum.width, lum.height, &lum.data, None)?,
        parent: Some(Plane::new(parent.width, parent.height, &parent.data, None)?),
    };
    let positions = texsyn_engine::layout::reference_positions(&sample, &geometry)?;
    let data = LevelData {
        level: 0,
        geometry,
        params,
        sample,
        positions: &positions,
        levels: 1,
        expected_queries: (a.batch * a.batches) as u64,
        colour_vectors: None,
    };
    let engine = Engine::default();
    let stride = geometry.layout().stride();
    let total = positions.len();
    println!(
        "level: {}x{} sample {}, {}x{} neighbourhood + {}x{} parent window: {} reference vectors x {} bytes = {:.1} MB; kernel {}",
        lum.width,
        lum.height,
        file.display(),
        geometry.n,
        geometry.n,
        geometry.m,
        geometry.m,
        total,
        stride,
        (total * stride) as f64 / 1e6,
        engine.kernel().name()
    );

    // The local engine, 2 threads, and 2 local workers with 1 search thread each.
    let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build()?;
    let mut local = LocalSearch::new(engine);
    pool.install(|| local.load_level(&data))?;
    let full =
        VectorSpace::build_from_positions(&data.sample, &geometry, &positions, 0..total as u64)?;
    let batches = make_batches(&full, WARM + a.batches, a.batch, 11)?;
    drop(full);
    let binary = find_worker_binary(a.worker_binary.as_deref())?;
    let extra: Vec<std::ffi::OsString> = a.worker_arg.iter().map(Into::into).collect();
    let workers = LocalWorkers::spawn(&binary, 2, Some(1), &extra)?;
    let mut cluster = ClusterSearch::connect(
        ClusterOptions {
            workers: workers.specs(),
            require_cluster: true,
            ..ClusterOptions::default()
        },
        engine,
    )?;
    let t = Instant::now();
    cluster.load_level(&data)?;
    let load_seconds = t.elapsed().as_secs_f64();

    let pids: Vec<u32> = workers.workers.iter().map(|w| w.pid()).collect();
    let mut rounds = measure(a, &pool, &mut local, &mut cluster, &batches, &pids)?;
    let work = local.level_prune().zip(cluster.level_prune());
    local.end_level();
    drop(local);
    let stats = cluster.stats();
    let small = one_query_trips(&mut cluster, &batches)?;
    rounds.rtts.sort_by(f64::total_cmp);
    print_workers(&stats, load_seconds);
    print_figures(a, &rounds, &small, total);
    if let Some((l, c)) = work {
        print_work(a, &rounds, &l, &c);
    }
    print_traffic(&stats, &rounds);
    print_memory(&stats, &workers, stride as u64);
    drop(cluster);
    drop(workers);
    Ok(())
}

/// CPU time of the threads at work in the cluster rounds, by role, from
/// Linux's per-thread `schedstat` (nanoseconds on the CPU): the workers'
/// search threads (`texsyn-search-*`), the workers' other threads (their
/// async runtime: the stream, the link reports), and this process's cluster
/// runtime (`texsyn-cluster`: sending, merging, forwarding). Where the
/// search threads get less than the cores, the rest is what slows them.
#[derive(Debug, Clone, Copy, Default)]
struct ThreadCpu {
    search: f64,
    worker_other: f64,
    master: f64,
}

impl ThreadCpu {
    /// The counters now, or None where `/proc` has no `schedstat`.
    fn now(worker_pids: &[u32]) -> Option<Self> {
        let mut c = Self::default();
        for &pid in worker_pids {
            for (name, secs) in thread_times(pid)? {
                if name.starts_with("texsyn-search") {
                    c.search += secs;
                } else {
                    c.worker_other += secs;
                }
            }
        }
        c.master = thread_times(std::process::id())?
            .into_iter()
            .filter(|(name, _)| name.starts_with("texsyn-cluster"))
            .map(|(_, secs)| secs)
            .sum();
        Some(c)
    }

    fn since(&self, b: &Self) -> Self {
        Self {
            search: self.search - b.search,
            worker_other: self.worker_other - b.worker_other,
            master: self.master - b.master,
        }
    }

    fn add(&mut self, o: &Self) {
        self.search += o.search;
        self.worker_other += o.worker_other;
        self.master += o.master;
    }
}

/// (name, seconds on the CPU) of every thread of `pid`.
fn thread_times(pid: u32) -> Option<Vec<(String, f64)>> {
    let dir = std::fs::read_dir(format!("/proc/{pid}/task")).ok()?;
    let mut out = Vec::new();
    for t in dir.flatten() {
        let p = t.path();
        let (Ok(name), Ok(stat)) = (
            std::fs::read_to_string(p.join("comm")),
            std::fs::read_to_string(p.join("schedstat")),
        ) else {
            continue; // the thread ended between the listing and the read
        };
        let ns: f64 = stat.split_whitespace().next()?.parse().ok()?;
        out.push((name.trim().to_string(), ns / 1e9));
    }
    Some(out)
}

/// The link's messages per batch (ARCHITECTURE §4.7) and where the cluster
/// rounds' CPU went.
fn print_traffic(stats: &serde_json::Value, r: &Rounds) {
    if let Some(w) = stats["workers"].as_array() {
        let per_batch = |x: &serde_json::Value, k: &str| {
            x[k].as_f64().unwrap_or(0.0) / x["batches"].as_f64().unwrap_or(0.0).max(1.0)
        };
        println!(
            "link messages per batch: {}",
            w.iter()
                .map(|x| format!(
                    "{} {:.1} reports in, {:.1} updates out",
                    x["address"].as_str().unwrap_or("?"),
                    per_batch(x, "link_reports"),
                    per_batch(x, "link_updates")
                ))
                .collect::<Vec<_>>()
                .join("; ")
        );
    }
    let (c, wall) = (&r.cpu, r.cluster_wall);
    if wall > 0.0 {
        let share = |s: f64| 100.0 * s / (2.0 * wall);
        println!(
            "CPU in the measured cluster batches (share of 2 cores over {:.2} s): workers' search threads {:.1}%, workers' other threads {:.1}%, master's cluster runtime {:.1}%",
            wall,
            share(c.search),
            share(c.worker_other),
            share(c.master)
        );
    }
}

/// The workers and their calibrated throughput.
fn print_workers(stats: &serde_json::Value, load_seconds: f64) {
    println!(
        "cluster: 2 local workers x 1 thread ({}), level loaded and assigned in {}",
        stats["workers"]
            .as_array()
            .map(|w| w
                .iter()
                .map(|x| format!(
                    "{} calibrated {:.3e} pairs/s",
                    x["address"].as_str().unwrap_or("?"),
                    x["calibrated_pairs_per_second"].as_f64().unwrap_or(0.0)
                ))
                .collect::<Vec<_>>()
                .join(", "))
            .unwrap_or_default(),
        ms(load_seconds)
    );
}

/// Latency per batch and per query, and the throughput ratio.
fn print_figures(a: &ClusterArgs, r: &Rounds, small: &[f64], total: usize) {
    let rounds = a.reps.max(1);
    let slowest = r.worker_per_batch.iter().copied().fold(0.0, f64::max);
    let mean_rtt = r.rtts.iter().sum::<f64>() / r.rtts.len().max(1) as f64;
    println!(
        "round trip per batch of {} queries (best of {} rounds): median {}  p90 {}  max {}; the workers' own search time per batch {} (slowest {}), so transport + merge + imbalance ≈ {} per batch",
        a.batch,
        rounds,
        ms(percentile(&r.rtts, 0.5)),
        ms(percentile(&r.rtts, 0.9)),
        ms(percentile(&r.rtts, 1.0)),
        r.worker_per_batch.iter().map(|&w| ms(w)).collect::<Vec<_>>().join(" / "),
        ms(slowest),
        ms(mean_rtt - slowest)
    );
    println!(
        "round trip per batch of 1 query: median {}  p90 {}",
        ms(percentile(small, 0.5)),
        ms(percentile(small, 0.9))
    );
    let ratio = r.cluster_qps / r.local_qps;
    println!(
        "throughput (best of {} rounds): local engine 2 threads {:.0} queries/s ({:.2} G pairs/s); cluster 2 workers x 1 thread {:.0} queries/s; ratio {:.3} (target >= 0.95: {}); per-round ratios min {:.3} median {:.3} max {:.3}",
        rounds,
        r.local_qps,
        r.local_qps * total as f64 / 1e9,
        r.cluster_qps,
        ratio,
        if ratio >= 0.95 { "met" } else { "NOT met" },
        percentile(&r.ratios, 0.0),
        percentile(&r.ratios, 0.5),
        percentile(&r.ratios, 1.0)
    );
}

/// The search work of both paths over all rounds (they search the same
/// batches): how much of the cluster's gap is extra work, because a range
/// prunes against the other ranges' finds only once they arrive (ARCHITECTURE
/// §4.7), and how fast each path does a unit of it (thread time of the best
/// round per component chunk: the local engine's 2 threads, the workers' own
/// search seconds), which leaves transport and waiting.
fn print_work(a: &ClusterArgs, r: &Rounds, local: &PruneStats, cluster: &PruneStats) {
    let full = |p: &PruneStats| p.pairs.saturating_sub(p.pruned);
    let per = |a: u64, b: u64| a as f64 / b.max(1) as f64;
    println!(
        "search work (all rounds): local engine {:.3} G component chunks, {:.1} M pairs scored in full; cluster {:.3} G, {:.1} M: {:.3}x and {:.3}x the local engine's",
        local.chunks as f64 / 1e9,
        full(local) as f64 / 1e6,
        cluster.chunks as f64 / 1e9,
        full(cluster) as f64 / 1e6,
        per(cluster.chunks, local.chunks),
        per(full(cluster), full(local)),
    );
    // Every round searches WARM + batches batches on each path.
    let searched = (a.reps.max(1) * (WARM + a.batches)) as f64;
    let local_chunks = local.chunks as f64 / searched;
    let cluster_chunks = cluster.chunks as f64 / searched;
    if r.local_qps > 0.0 && local_chunks > 0.0 && cluster_chunks > 0.0 {
        let local_thread = 2.0 * a.batch as f64 / r.local_qps;
        let cluster_thread: f64 = r.worker_per_batch.iter().sum();
        let (l, c) = (
            local_thread / local_chunks * 1e9,
            cluster_thread / cluster_chunks * 1e9,
        );
        println!(
            "thread time per G component chunks (best rounds): local engine {:.2} s, workers {:.2} s ({:.3}x)",
            l,
            c,
            c / l
        );
    }
}

/// Each worker's vector range (address, vectors) in the last partition of the run report.
fn worker_ranges(stats: &serde_json::Value) -> Vec<(String, u64)> {
    stats["events"]
        .as_array()
        .and_then(|e| {
            e.iter()
                .rev()
                .find(|e| e["shares"].as_array().is_some_and(|s| !s.is_empty()))
        })
        .and_then(|e| e["shares"].as_array())
        .map(|s| {
            s.iter()
                .map(|x| {
                    (
                        x["worker"].as_str().unwrap_or("").to_string(),
                        x["end"].as_u64().unwrap_or(0) - x["start"].as_u64().unwrap_or(0),
                    )
                })
                .collect()
        })
        .unwrap_or_default()
}

/// Peak memory against each worker's range.
fn print_memory(stats: &serde_json::Value, workers: &LocalWorkers, stride: u64) {
    let ranges = worker_ranges(stats);
    for w in &workers.workers {
        let addr = w.address.to_string();
        let len = ranges
            .iter()
            .find(|(a, _)| *a == addr)
            .map_or(0, |(_, l)| *l);
        let range_bytes = len * stride;
        let limit = range_bytes as f64 * 1.2 + 64e6;
        match peak_memory(w.pid()) {
            Some(hwm) => println!(
                "worker {addr}: {len} vectors = {:.1} MB of range; peak memory (VmHWM) {:.1} MB; limit 1.2 x range + 64 MB = {:.1} MB: {}",
                range_bytes as f64 / 1e6,
                hwm as f64 / 1e6,
                limit / 1e6,
                if (hwm as f64) <= limit { "met" } else { "NOT met" }
            ),
            None => println!("worker {addr}: peak memory not readable (no /proc)"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// This thread's own CPU clock, in seconds.
    fn own_cpu() -> f64 {
        let mut t = libc::timespec {
            tv_sec: 0,
            tv_nsec: 0,
        };
        // SAFETY: `t` is a valid timespec for the call to fill in.
        let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut t) };
        assert_eq!(rc, 0);
        t.tv_sec as f64 + t.tv_nsec as f64 / 1e9
    }

    /// What `thread_times` reads of a named thread agrees with the thread's
    /// own CPU clock, busy or asleep (however loaded the machine is).
    #[test]
    fn thread_times_agree_with_the_thread_s_own_clock() {
        let pid = std::process::id();
        let run = |name: &str, busy: bool| -> (f64, f64) {
            let (tx, rx) = std::sync::mpsc::channel();
            let (go, wait) = std::sync::mpsc::channel::<()>();
            let h = std::thread::Builder::new()
                .name(name.into())
                .spawn(move || {
                    tx.send(0.0).unwrap();
                    let _ = wait.recv();
                    let start = own_cpu();
                    if busy {
                        while own_cpu() - start < 0.15 {
                            std::hint::black_box(start);
                        }
                    } else {
                        std::thread::sleep(std::time::Duration::from_millis(100));
                    }
                    tx.send(own_cpu() - start).unwrap();
                    let _ = wait.recv();
                })
                .unwrap();
            rx.recv().unwrap();
            let read = || -> f64 {
                thread_times(pid)
                    .expect("/proc/PID/task/*/schedstat")
                    .into_iter()
                    .filter(|(t, _)| t == name)
                    .map(|(_, s)| s)
                    .sum()
            };
            let before = read();
            go.send(()).unwrap();
            let own = rx.recv().unwrap();
            let read_delta = read() - before;
            go.send(()).unwrap();
            h.join().unwrap();
            (read_delta, own)
        };
        for (name, busy) in [("texsyn-search-9", true), ("texsyn-asleep", false)] {
            let (read, own) = run(name, busy);
            assert!(
                (read - own).abs() < 0.02,
                "{name}: schedstat {read} s, own clock {own} s"
            );
            assert_eq!(read > 0.1, busy, "{name}: {read} s");
        }
        // This process standing in for a worker: its main and test threads
        // are the "other" threads.
        let c = ThreadCpu::now(&[pid]).unwrap();
        assert!(c.worker_other > 0.0, "{c:?}");
    }
}
