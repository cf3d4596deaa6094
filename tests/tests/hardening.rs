//! A real `texsyn-worker` process under load it was not built for, driven by
//! a raw gRPC client (ARCHITECTURE §4.5): jobs that together ask for more than
//! the memory budget, a thousand concurrent search streams on one connection,
//! two thousand idle sockets, and a worker inside a memory control group that
//! would be OOM-killed if it took its default cap from the host's RAM. The
//! worker answers each call with a result or a status, keeps serving, and its
//! reservations and its peak RSS stay within the budget.

use crate::harness;

use std::ffi::OsString;
use std::net::Ipv4Addr;
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use harness::{alive, Token, Worker};
use texsyn::launch::local::{spawn_worker, WorkerProcess};
use texsyn_proto::auth::BearerAuth;
use texsyn_proto::v1 as pb;
use texsyn_proto::PROTOCOL_VERSION;
use tonic::Code;

type RawClient = pb::worker_client::WorkerClient<
    tonic::codegen::InterceptedService<tonic::transport::Channel, BearerAuth>,
>;

/// Budget of the worker under test.
const BUDGET: u64 = 64 << 20;
/// What the process holds beyond its reservations: the binary, thread stacks,
/// the runtime and HTTP/2 buffers of the connections.
const BASE_RSS: u64 = 96 << 20;

async fn client(addr: std::net::SocketAddr, token: &str) -> RawClient {
    let ch = tonic::transport::Channel::from_shared(format!("http://{addr}"))
        .unwrap()
        .timeout(Duration::from_secs(60))
        .connect()
        .await
        .unwrap();
    pb::worker_client::WorkerClient::with_interceptor(ch, BearerAuth::new(Some(token)).unwrap())
}

fn info() -> pb::InfoRequest {
    pb::InfoRequest {
        protocol_version: PROTOCOL_VERSION,
    }
}

/// A `side`² level of job `job` with a 9×9 neighbourhood and its parent.
fn level(job: &str, side: u32) -> pb::LoadLevelPart {
    let px = |w: u32, h: u32, seed: u32| pb::Plane {
        width: w,
        height: h,
        pixels: (0..w * h)
            .map(|i| (i.wrapping_mul(2_654_435_761).wrapping_add(seed) >> 13) as u8)
            .collect(),
        defined: Vec::new(),
    };
    pb::LoadLevelPart::from(pb::LoadLevelRequest {
        job_id: job.into(),
        level: 0,
        geometry: Some(pb::Geometry {
            neighbourhood: 9,
            parent_window: 5,
            weight_hi: 1,
            weight_lo: 1,
            metric: 0,
        }),
        sample: Some(px(side, side, 1)),
        parent: Some(px(side.div_ceil(2), side.div_ceil(2), 2)),
    })
}

fn assign(job: &str, end: u64) -> pb::AssignRequest {
    pb::AssignRequest {
        job_id: job.into(),
        level: 0,
        start: 0,
        end,
        lbg_probes: 0,
        epoch: 0,
    }
}

/// Peak resident set size of `pid` (VmHWM), in bytes.
fn peak_rss(pid: u32) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<u64>().ok())
        })
        .map_or(0, |kb| kb * 1024)
}

#[test]
fn competing_jobs_and_a_thousand_streams_stay_within_the_budget() {
    let token = Token::new();
    let budget = format!("{}", BUDGET);
    let path = token.path.to_str().unwrap().to_string();
    let w = Worker::start(
        30,
        &[
            "--threads",
            "2",
            "--token-file",
            &path,
            "--max-memory",
            &budget,
            "--vector-store",
            "dense",
        ],
    );
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let c = client(w.address, &token.value).await;
        // Four jobs, each with a level whose whole range needs over half the budget.
        let jobs = ["j0", "j1", "j2", "j3"];
        let mut total = 0;
        for j in jobs {
            let r = c
                .clone()
                .load_level(tokio_stream::iter([level(j, 560)]))
                .await
                .unwrap()
                .into_inner();
            total = r.total_vectors;
        }
        let calls: Vec<_> = jobs
            .iter()
            .map(|j| {
                let mut c = c.clone();
                let j = j.to_string();
                tokio::spawn(async move { (j.clone(), c.assign(assign(&j, total)).await) })
            })
            .collect();
        let mut held = Vec::new();
        for call in calls {
            let (j, r) = call.await.unwrap();
            match r {
                Ok(a) => {
                    let bytes = a.into_inner().bytes;
                    assert!(bytes > BUDGET / 2, "{bytes}");
                    held.push(j);
                }
                Err(e) => assert_eq!(e.code(), Code::ResourceExhausted, "{e:?}"),
            }
        }
        assert_eq!(held.len(), 1, "exactly one range fits: {held:?}");

        // A thousand search streams at once on the one connection.
        let dims = 81 + 25;
        let calls: Vec<_> = (0..1000u64)
            .map(|k| {
                let mut c = c.clone();
                let job = held[0].clone();
                tokio::spawn(async move {
                    let batch = pb::SearchBatch {
                        job_id: job,
                        level: 0,
                        batch_id: k,
                        top_k: 1,
                        count: 8,
                        values: (0..8 * dims).map(|i| (i as u64 * 31 + k) as u8).collect(),
                        masks: vec![1; 8 * dims],
                        epoch: 0,
                        ..Default::default()
                    };
                    let mut s = c.search(tokio_stream::iter([batch])).await?.into_inner();
                    let r = s.message().await?;
                    Ok::<_, tonic::Status>(r.map(|r| r.hits.len()))
                })
            })
            .collect();
        let (mut ok, mut refused) = (0, 0);
        for call in calls {
            match call.await.unwrap() {
                Ok(Some(n)) => {
                    assert_eq!(n, 8);
                    ok += 1;
                }
                Ok(None) => panic!("a stream ended without an answer or a status"),
                Err(e) => {
                    assert_eq!(e.code(), Code::ResourceExhausted, "{e:?}");
                    refused += 1;
                }
            }
        }
        assert!(ok > 0, "some streams are served ({refused} refused)");
        let i = c.clone().info(info()).await.unwrap().into_inner();
        assert!(i.memory_peak <= BUDGET, "reserved {} > {BUDGET}", i.memory_peak);
        let rss = peak_rss(w.pid());
        eprintln!(
            "1000 streams: {ok} answered, {refused} refused; reserved peak {} MiB of {} MiB; worker peak RSS {} MiB",
            i.memory_peak >> 20,
            BUDGET >> 20,
            rss >> 20
        );
        assert!(rss > 0 && rss <= BUDGET + BASE_RSS, "peak RSS {rss}");
    });
    assert!(alive(w.pid()));
}

#[test]
fn two_thousand_idle_sockets_do_not_stop_a_worker_from_serving() {
    let token = Token::new();
    let w = Worker::with_token(31, &token, 1);
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let mut c = client(w.address, &token.value).await;
        c.info(info()).await.unwrap();
        let mut idle = Vec::new();
        for _ in 0..2000 {
            match tokio::net::TcpStream::connect(w.address).await {
                Ok(s) => idle.push(s),
                Err(e) => panic!("connect {} failed: {e}", idle.len()),
            }
        }
        // The open connection keeps working, and a new client gets in at once.
        let t = Instant::now();
        c.info(info()).await.unwrap();
        let mut fresh = client(w.address, &token.value).await;
        fresh.info(info()).await.unwrap();
        assert!(t.elapsed() < Duration::from_secs(3), "{:?}", t.elapsed());
        drop(idle);
        // Every silent socket is closed within the first-byte timeout: the
        // worker holds a handful of descriptors again.
        tokio::time::sleep(Duration::from_secs(6)).await;
        let fds = std::fs::read_dir(format!("/proc/{}/fd", w.pid()))
            .map(|d| d.count())
            .unwrap_or(0);
        assert!(fds < 64, "the worker still holds {fds} descriptors");
    });
    assert!(alive(w.pid()));
}

/// A memory control group made for one test (v1 or v2), removed on drop.
struct Cgroup {
    dir: PathBuf,
}

impl Cgroup {
    /// A new group limited to `limit` bytes, or why this machine cannot make one.
    fn new(limit: u64) -> Result<Self, String> {
        let own = std::fs::read_to_string("/proc/self/cgroup")
            .map_err(|e| format!("cannot read /proc/self/cgroup: {e}"))?;
        let name = format!("texsyn-test-{}", std::process::id());
        let v1 = own.lines().find_map(|l| {
            let mut p = l.splitn(3, ':').skip(1);
            let (c, path) = (p.next()?, p.next()?);
            c.split(',')
                .any(|c| c == "memory")
                .then(|| path.to_string())
        });
        let (dir, limit_file) = if let Some(path) = v1 {
            // v1: a child of this process's own memory group.
            let base = Path::new("/sys/fs/cgroup/memory").join(path.trim_start_matches('/'));
            let base = if base.exists() {
                base
            } else {
                PathBuf::from("/sys/fs/cgroup/memory")
            };
            (base.join(name), "memory.limit_in_bytes")
        } else if Path::new("/sys/fs/cgroup/cgroup.controllers").exists() {
            // v2: a sibling of this process's group (a group with children
            // cannot hold processes), with memory enabled in the parent.
            let path = own
                .lines()
                .find_map(|l| l.strip_prefix("0::"))
                .unwrap_or("/")
                .trim_matches('/');
            let parent = Path::new("/sys/fs/cgroup").join(match path.rfind('/') {
                Some(i) => &path[..i],
                None => "",
            });
            let _ = std::fs::write(parent.join("cgroup.subtree_control"), "+memory");
            (parent.join(name), "memory.max")
        } else {
            return Err("no cgroup memory controller under /sys/fs/cgroup".into());
        };
        std::fs::create_dir(&dir).map_err(|e| {
            format!(
                "cannot make the control group {}: {e}; run as root",
                dir.display()
            )
        })?;
        let group = Self { dir };
        std::fs::write(group.dir.join(limit_file), limit.to_string())
            .map_err(|e| format!("cannot set {}: {e}", group.dir.join(limit_file).display()))?;
        Ok(group)
    }

    /// Starts a worker inside the group: a shell moves itself in, then
    /// becomes the worker, so the worker reads its limit from its first line.
    fn worker(&self, scripts: &Path, host: u8, args: &[&str]) -> WorkerProcess {
        let script = scripts.join("in-cgroup");
        std::fs::write(
            &script,
            format!(
                "#!/bin/sh\necho $$ > '{}/cgroup.procs' || exit 1\nexec '{}' \"$@\"\n",
                self.dir.display(),
                harness::binary("texsyn-worker").display()
            ),
        )
        .unwrap();
        std::fs::set_permissions(&script, std::fs::Permissions::from_mode(0o755)).unwrap();
        let args: Vec<OsString> = args.iter().map(OsString::from).collect();
        spawn_worker(
            &script,
            Ipv4Addr::new(127, 0, 0, host),
            &args,
            &scripts.join("worker.log"),
        )
        .expect("worker starts in its control group")
    }

    /// The group's peak memory use, where the kernel reports it.
    fn peak(&self) -> Option<u64> {
        ["memory.max_usage_in_bytes", "memory.peak"]
            .iter()
            .find_map(|f| std::fs::read_to_string(self.dir.join(f)).ok())
            .and_then(|s| s.trim().parse().ok())
    }

    /// How often the kernel refused the group memory (v1) or OOM-killed in it (v2).
    fn oom_events(&self) -> u64 {
        if let Ok(s) = std::fs::read_to_string(self.dir.join("memory.failcnt")) {
            return s.trim().parse().unwrap_or(0);
        }
        std::fs::read_to_string(self.dir.join("memory.events"))
            .ok()
            .and_then(|s| {
                s.lines()
                    .find_map(|l| l.strip_prefix("oom_kill ")?.trim().parse().ok())
            })
            .unwrap_or(0)
    }
}

impl Drop for Cgroup {
    fn drop(&mut self) {
        // The worker is killed before this runs; its group empties shortly after.
        for _ in 0..50 {
            if std::fs::remove_dir(&self.dir).is_ok() || !self.dir.exists() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

#[test]
fn a_worker_in_a_control_group_takes_its_cap_from_the_group_and_refuses_instead_of_dying() {
    const LIMIT: u64 = 512 << 20;
    let group = match Cgroup::new(LIMIT) {
        Ok(g) => g,
        Err(reason) => return harness::skip("the control-group test", &reason),
    };
    let token = Token::new();
    let scripts = tempfile::tempdir().unwrap();
    let path = token.path.to_str().unwrap().to_string();
    // No --max-memory: the default is what is under test.
    let mut w = group.worker(
        scripts.path(),
        32,
        &[
            "--threads",
            "2",
            "--token-file",
            &path,
            "--vector-store",
            "dense",
        ],
    );
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    let cap = LIMIT / 4 * 3;
    rt.block_on(async {
        let c = client(w.address, &token.value).await;
        let i = c.clone().info(info()).await.unwrap().into_inner();
        assert_eq!(
            i.memory_limit, cap,
            "the default cap is ¾ of the group's limit, not of the host's RAM"
        );
        // Two jobs, each with a range of about 0.7 of the cap: together they
        // would need more than the group allows, and the kernel would kill
        // the worker; the budget refuses the second instead.
        let mut granted = Vec::new();
        for j in ["a", "b"] {
            let r = c
                .clone()
                .load_level(tokio_stream::iter([level(j, 1500)]))
                .await
                .unwrap()
                .into_inner();
            match c.clone().assign(assign(j, r.total_vectors)).await {
                Ok(a) => {
                    let bytes = a.into_inner().bytes;
                    assert!(bytes > cap / 2 && bytes < cap, "{bytes} of {cap}");
                    granted.push(bytes);
                }
                Err(e) => assert_eq!(e.code(), Code::ResourceExhausted, "{e:?}"),
            }
        }
        assert_eq!(granted.len(), 1, "exactly one of the two ranges fits");
        let i = c.clone().info(info()).await.unwrap().into_inner();
        assert!(i.memory_peak <= cap, "reserved {} > {cap}", i.memory_peak);
        let peak = group.peak();
        eprintln!(
            "control group of {} MiB: cap {} MiB, range {} MiB granted once and refused once, \
             reserved peak {} MiB, group peak {:?} MiB, OOM events {}",
            LIMIT >> 20,
            cap >> 20,
            granted[0] >> 20,
            i.memory_peak >> 20,
            peak.map(|p| p >> 20),
            group.oom_events()
        );
        assert!(peak.is_none_or(|p| p < LIMIT), "group peak {peak:?}");
    });
    assert!(
        alive(w.pid()),
        "the worker was killed inside its control group"
    );
    assert_eq!(
        group.oom_events(),
        0,
        "the kernel had to refuse the group memory"
    );
    w.kill();
}
