//! `texsyn-bench faults`: the seeded fault campaign (ARCHITECTURE §4.6).
//!
//! Every run is a real cluster: `--workers` fresh `texsyn-worker` processes on
//! 127.0.0.2, .3, … and the `texsyn` master binary synthesising the same
//! texture. While the master works, the run injects faults drawn from its own
//! seed, at random times within the fault-free run time:
//!
//! - `kill`: SIGKILL; the worker stays dead.
//! - `stop`: SIGSTOP, then SIGCONT after a while.
//! - `partition`: every packet to and from the worker's port dropped
//!   (nftables, inside a private network namespace), then healed.
//! - `restart`: SIGKILL, then a new worker process on the same address.
//! - `slow`: the worker's threads pinned to one core with two busy processes
//!   pinned beside it, then freed.
//! - `lie`: SIGUSR1 to a worker started with `--fault-wrong-answers-on-sigusr1`;
//!   it answers every search wrongly from then on.
//!
//! Each run must exit 0 with an image byte-identical to the local engine's,
//! and leave nothing behind: no process it started, no file in the masters'
//! and workers' temporary directory, no temporary file beside the output. The
//! summary gives runs, faults by kind, identical runs, the worst time over the
//! fault-free time, and what was left behind. A run's faults depend only on
//! the campaign seed and the run's number; when they land in the master's
//! work depends on the machine.

use std::collections::BTreeMap;
use std::ffi::OsString;
use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, ensure, Context, Result};
use clap::{Args, ValueEnum};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use texsyn::launch::local::{new_token, spawn_worker_at, write_token_file, WorkerProcess};
use texsyn::launch::{end_with_parent, find_worker_binary};

use crate::cases::Textures;

/// nftables tables of the partitions are `PREFIX<worker>`.
const NFT_PREFIX: &str = "texsyn_faults_w";
/// Busy processes beside a slowed worker.
const HOGS: usize = 2;

#[derive(Args, Debug)]
pub struct FaultArgs {
    #[command(flatten)]
    pub textures: Textures,
    /// Runs with faults (after the local and the fault-free runs).
    #[arg(long, default_value_t = 50)]
    pub runs: usize,
    /// Campaign seed: run k draws its faults from (seed, k) alone.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Worker processes per run (1 search thread each).
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u8).range(1..=32))]
    pub workers: u8,
    /// Fault kinds to draw from.
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_value = "kill,stop,partition,restart,slow,lie"
    )]
    pub kinds: Vec<Kind>,
    /// Faults per run are drawn from 1..=this.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u8).range(1..=16))]
    pub max_faults: u8,
    /// The sample (in the texture directory, or a path).
    #[arg(long, default_value = "brick_color_96.png")]
    pub sample: String,
    /// Side of the synthesised texture.
    #[arg(long, default_value_t = 512)]
    pub size: usize,
    /// Pyramid levels; every one is searched on the cluster.
    #[arg(long, default_value_t = 4)]
    pub levels: usize,
    /// Fault-free cluster runs; their median time is the reference time.
    #[arg(long, default_value_t = 3)]
    pub fault_free: usize,
    /// The master's least batch deadline (`texsyn --worker-timeout`), seconds.
    #[arg(long, default_value = "1", value_parser = |s: &str| seconds(s, 0.1, 600.0))]
    pub worker_timeout: Duration,
    /// No run starts after this many seconds; the summary covers the runs done.
    #[arg(long, default_value = "1800", value_parser = |s: &str| seconds(s, 1.0, 86400.0))]
    pub time_limit: Duration,
    /// A run still going after this × the fault-free time + 60 s is killed and failed.
    #[arg(long, default_value_t = 20.0)]
    pub run_timeout_factor: f64,
    /// Keep every run's output, report and logs here (default: a temporary
    /// directory, removed at the end).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Write the summary and every run as JSON.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// The texsyn-worker executable (default: next to texsyn-bench, else PATH).
    #[arg(long)]
    pub worker_binary: Option<PathBuf>,
    /// The texsyn executable (default: next to texsyn-bench).
    #[arg(long)]
    pub master_binary: Option<PathBuf>,
}

fn seconds(s: &str, min: f64, max: f64) -> Result<Duration, String> {
    texsyn_proto::cli::parse_seconds(s, min, max).map(Duration::from_secs_f64)
}

/// A kind of fault.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Kind {
    Kill,
    Stop,
    Partition,
    Restart,
    Slow,
    Lie,
}

impl Kind {
    fn name(self) -> &'static str {
        match self {
            Kind::Kill => "kill",
            Kind::Stop => "stop",
            Kind::Partition => "partition",
            Kind::Restart => "restart",
            Kind::Slow => "slow",
            Kind::Lie => "lie",
        }
    }

    /// Has an end (SIGCONT, heal, start again, free).
    fn lasts(self) -> bool {
        matches!(
            self,
            Kind::Stop | Kind::Partition | Kind::Restart | Kind::Slow
        )
    }
}

/// One fault of a run's plan: `kind` on worker `worker` from `at` after the
/// master starts, for `lasts`.
#[derive(Clone, Debug, Serialize)]
pub struct Fault {
    pub kind: Kind,
    pub worker: usize,
    #[serde(serialize_with = "secs")]
    pub at: Duration,
    #[serde(serialize_with = "secs")]
    pub lasts: Duration,
    /// It began before the master finished.
    pub injected: bool,
}

fn secs<S: serde::Serializer>(d: &Duration, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_f64(d.as_secs_f64())
}

/// Run `run`'s faults: 1..=`max` of them, at times within 5–85 % of the
/// fault-free time `base`, lasting 20–150 % of it.
pub fn plan(
    seed: u64,
    run: usize,
    kinds: &[Kind],
    workers: usize,
    max: usize,
    base: Duration,
) -> Vec<Fault> {
    let mut rng =
        ChaCha8Rng::seed_from_u64(seed ^ (run as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15));
    let n = rng.random_range(1..=max);
    let mut faults: Vec<Fault> = (0..n)
        .map(|_| {
            let kind = kinds[rng.random_range(0..kinds.len())];
            let at = base.mul_f64(rng.random_range(0.05..0.85));
            let lasts = if kind.lasts() {
                base.mul_f64(rng.random_range(0.2..1.5))
            } else {
                Duration::ZERO
            };
            Fault {
                kind,
                worker: rng.random_range(0..workers),
                at,
                lasts,
                injected: false,
            }
        })
        .collect();
    faults.sort_by_key(|f| f.at);
    faults
}

/// What one run did.
#[derive(Debug, Serialize)]
pub struct RunResult {
    pub run: usize,
    pub faults: Vec<Fault>,
    pub seconds: f64,
    /// `seconds` over the fault-free time.
    pub ratio: f64,
    pub exit_ok: bool,
    pub identical: bool,
    pub timed_out: bool,
    /// Cluster events in the master's report: drop, rejoin, retry, …
    pub events: BTreeMap<String, usize>,
    /// Processes this run started still alive after it.
    pub processes_left: Vec<String>,
    /// Files left in the temporary directory or beside the output.
    pub files_left: Vec<String>,
    /// What went wrong, if anything.
    pub error: Option<String>,
}

impl RunResult {
    fn clean(&self) -> bool {
        self.exit_ok
            && self.identical
            && !self.timed_out
            && self.processes_left.is_empty()
            && self.files_left.is_empty()
    }
}

#[derive(Debug, Serialize)]
struct Summary {
    seed: u64,
    workers: u8,
    runs: usize,
    /// Faults that began while the master worked, by kind.
    injected: BTreeMap<Kind, usize>,
    /// Faults drawn but not reached (the master had finished).
    not_reached: usize,
    identical: usize,
    failed: usize,
    fault_free_seconds: f64,
    worst_ratio: f64,
    worst_run: Option<usize>,
    median_ratio: f64,
    processes_left: usize,
    files_left: usize,
    stopped_by_time_limit: bool,
    results: Vec<RunResult>,
}

/// The campaign's fixed parts: binaries, directories, token, sample, truth.
struct Campaign<'a> {
    args: &'a FaultArgs,
    worker_binary: PathBuf,
    master_binary: PathBuf,
    sample: PathBuf,
    root: PathBuf,
    /// TMPDIR of every master and worker: must be empty after each run.
    tmp: PathBuf,
    token_path: PathBuf,
    /// The local engine's image: what every run must equal byte for byte.
    truth: Vec<u8>,
    /// Median fault-free cluster time.
    base: Duration,
    /// The network namespace is private (partitions possible).
    private_network: bool,
}

pub fn run(args: &FaultArgs) -> Result<()> {
    ensure!(args.runs > 0, "--runs must be at least 1");
    ensure!(!args.kinds.is_empty(), "--kinds needs at least one kind");
    ensure!(args.fault_free > 0, "--fault-free must be at least 1");
    ensure!(
        args.size >= 16 && args.size <= 4096,
        "--size {} must be in 16..=4096",
        args.size
    );
    ensure!(
        args.run_timeout_factor.is_finite() && args.run_timeout_factor >= 2.0,
        "--run-timeout-factor must be a number ≥ 2"
    );
    // First, before any thread or process: the private network namespace
    // every process of the campaign is started in.
    let private_network = if args.kinds.contains(&Kind::Partition) {
        enter_private_network().context(
            "partition faults need a private network namespace and nftables: run as root \
             with nftables installed (apt-get install nftables iproute2), or leave them \
             out (--kinds kill,stop,restart,slow,lie)",
        )?;
        true
    } else {
        false
    };
    let started = Instant::now();
    let kept;
    let temp;
    let root = match &args.out {
        Some(dir) => {
            std::fs::create_dir_all(dir)
                .with_context(|| format!("cannot create --out {}", dir.display()))?;
            kept = dir.clone();
            kept.as_path()
        }
        None => {
            temp = tempfile::Builder::new()
                .prefix("texsyn-faults-")
                .tempdir()
                .context("cannot create a temporary directory")?;
            temp.path()
        }
    }
    .canonicalize()?;
    let tmp = root.join("tmp");
    std::fs::create_dir_all(&tmp)?;
    // Every process the campaign starts inherits this TMPDIR, so whatever
    // temporary file one leaves behind is found there. (Set while this
    // process has a single thread.)
    std::env::set_var("TMPDIR", &tmp);
    let token_path = root.join("token");
    write_token_file(&token_path, &new_token())?;
    let sample = {
        let p = PathBuf::from(&args.sample);
        if p.is_file() {
            p
        } else {
            args.textures.dir()?.join(&args.sample)
        }
    };
    ensure!(sample.is_file(), "no sample {}", sample.display());
    let master_binary =
        crate::cases::sibling_binary("texsyn", args.master_binary.as_deref(), "--master-binary")?;
    let mut c = Campaign {
        args,
        worker_binary: find_worker_binary(args.worker_binary.as_deref())?,
        master_binary,
        sample,
        root: root.clone(),
        tmp,
        token_path,
        truth: Vec::new(),
        base: Duration::ZERO,
        private_network,
    };

    let local = root.join("local.png");
    let status = c
        .master_command(&local, None, &["--search", &c.plan_of("local")])
        .status()?;
    ensure!(status.success(), "the local run failed");
    c.truth = std::fs::read(&local)?;
    let mut times = Vec::new();
    for k in 0..args.fault_free {
        let r = c.run(&format!("clean{k}"), Vec::new(), Duration::from_secs(600))?;
        ensure!(
            r.clean(),
            "the fault-free cluster run {k} is not clean: {}; left behind: {:?}",
            describe(&r),
            [&r.processes_left[..], &r.files_left[..]].concat()
        );
        times.push(r.seconds);
    }
    times.sort_by(f64::total_cmp);
    c.base = Duration::from_secs_f64(times[times.len() / 2]);
    println!(
        "fault campaign: seed {}, {} workers, {} runs, kinds {}; {}x{} from {}, {} levels",
        args.seed,
        args.workers,
        args.runs,
        args.kinds
            .iter()
            .map(|k| k.name())
            .collect::<Vec<_>>()
            .join(","),
        args.size,
        args.size,
        c.sample.display(),
        args.levels
    );
    println!(
        "fault-free cluster runs: {times:.2?} s, reference {:.2} s",
        c.base.as_secs_f64()
    );

    let timeout = c.base.mul_f64(args.run_timeout_factor) + Duration::from_secs(60);
    let mut results = Vec::new();
    let mut stopped = false;
    for k in 0..args.runs {
        if started.elapsed() >= args.time_limit {
            stopped = true;
            println!("time limit {:?} reached after {k} runs", args.time_limit);
            break;
        }
        let faults = plan(
            args.seed,
            k,
            &args.kinds,
            args.workers as usize,
            args.max_faults as usize,
            c.base,
        );
        let r = c.run(&format!("run{k:03}"), faults, timeout)?;
        println!("{}", describe(&r));
        results.push(r);
    }

    let summary = summarise(args, &c, results, stopped);
    print_summary(&summary);
    if let Some(path) = &args.json {
        let text = serde_json::to_string_pretty(&summary)?;
        texsyn::imaging::save_bytes(path, text.as_bytes())
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    let bad = summary.results.iter().filter(|r| !r.clean()).count();
    ensure!(
        bad == 0,
        "{bad} of {} runs failed, differ or left something behind (see above)",
        summary.runs
    );
    Ok(())
}

impl Campaign<'_> {
    fn plan_of(&self, kind: &str) -> String {
        vec![kind; self.args.levels].join(",")
    }

    /// `texsyn synth` of the campaign's texture into `out`, with its temporary
    /// directory the campaign's `tmp`.
    fn master_command(&self, out: &Path, log: Option<&Path>, extra: &[&str]) -> Command {
        let a = self.args;
        let mut c = Command::new(&self.master_binary);
        c.arg("synth")
            .arg(&self.sample)
            .arg("--size")
            .arg(format!("{}x{}", a.size, a.size))
            .arg("--levels")
            .arg(a.levels.to_string())
            .args(["--seed", "7", "-q", "-o"])
            .arg(out)
            .args(extra)
            .env("TMPDIR", &self.tmp)
            .env("RUST_LOG", "warn")
            .env("NO_COLOR", "1")
            .stdin(Stdio::null())
            .stdout(Stdio::null());
        if let Some(log) = log {
            if let Ok(f) = std::fs::File::create(log) {
                c.stderr(f);
            }
        }
        end_with_parent(&mut c);
        c
    }

    fn start_worker(
        &self,
        dir: &Path,
        k: usize,
        listen: SocketAddrV4,
        incarnation: usize,
    ) -> Result<WorkerProcess> {
        let args: Vec<OsString> = vec![
            "--threads".into(),
            "1".into(),
            "--token-file".into(),
            self.token_path.clone().into(),
            "--fault-wrong-answers-on-sigusr1".into(),
        ];
        let log = dir.join(format!("worker{k}.{incarnation}.log"));
        spawn_worker_at(&self.worker_binary, listen, &args, &log)
    }

    /// One run named `name` with `faults`; killed after `timeout`.
    fn run(&self, name: &str, mut faults: Vec<Fault>, timeout: Duration) -> Result<RunResult> {
        let dir = self.root.join(name);
        std::fs::create_dir_all(&dir)?;
        let mut cluster = Cluster::default();
        for k in 0..self.args.workers as usize {
            let ip = Ipv4Addr::new(127, 0, 0, 2 + k as u8);
            let w = self.start_worker(&dir, k, SocketAddrV4::new(ip, 0), 0)?;
            cluster.pids.push(w.pid());
            cluster.workers.push(Some(w));
            cluster
                .addresses
                .push(match cluster.workers[k].as_ref().unwrap().address {
                    SocketAddr::V4(a) => a,
                    SocketAddr::V6(a) => bail!("worker on {a}: expected IPv4"),
                });
            cluster.incarnations.push(0);
        }
        let list: Vec<String> = cluster.addresses.iter().map(|a| a.to_string()).collect();
        let out = dir.join("out.png");
        let report = dir.join("report.json");
        let timeout_arg = format!("{}", self.args.worker_timeout.as_secs_f64());
        let plan = self.plan_of("cluster");
        let mut cmd = self.master_command(
            &out,
            Some(&dir.join("master.log")),
            &[
                "--search",
                &plan,
                "--workers",
                &list.join(","),
                "--token-file",
                self.token_path
                    .to_str()
                    .context("token path is not UTF-8")?,
                "--worker-timeout",
                &timeout_arg,
                "--report",
                report.to_str().context("report path is not UTF-8")?,
            ],
        );
        let t = Instant::now();
        let mut master = cmd.spawn().context("cannot start the master")?;
        let master_pid = master.id();

        // Begins and ends, in time order: (time, fault, is_end).
        let mut steps: Vec<(Duration, usize, bool)> = Vec::new();
        for (i, f) in faults.iter().enumerate() {
            steps.push((f.at, i, false));
            if f.kind.lasts() {
                steps.push((f.at + f.lasts, i, true));
            }
        }
        steps.sort_by_key(|s| s.0);
        let mut next = 0;
        let mut error = None;
        let (status, timed_out) = loop {
            if let Some(s) = master.try_wait()? {
                break (Some(s), false);
            }
            if t.elapsed() > timeout {
                let _ = master.kill();
                let _ = master.wait();
                break (None, true);
            }
            while next < steps.len() && steps[next].0 <= t.elapsed() {
                let (_, i, end) = steps[next];
                if !end {
                    faults[i].injected = true;
                }
                if let Err(e) = self.apply(&mut cluster, &dir, &faults[i], end) {
                    error.get_or_insert(format!(
                        "{} {}: {e:#}",
                        faults[i].kind.name(),
                        if end { "end" } else { "begin" }
                    ));
                }
                next += 1;
            }
            std::thread::sleep(Duration::from_millis(2));
        };
        let seconds = t.elapsed().as_secs_f64();
        cluster.release(self);
        let exit_ok = status.is_some_and(|s| s.success());
        let identical = std::fs::read(&out).is_ok_and(|b| b == self.truth);
        if !exit_ok && error.is_none() {
            error = Some(format!(
                "the master {}: {}",
                if timed_out {
                    "timed out".to_string()
                } else {
                    format!("exited with {status:?}")
                },
                tail(&dir.join("master.log"))
            ));
        }
        let events = std::fs::read(&report)
            .ok()
            .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok())
            .map(|r| count_events(&r))
            .unwrap_or_default();
        let mut pids = cluster.pids.clone();
        pids.push(master_pid);
        pids.extend(cluster.hog_pids.iter().copied());
        let processes_left = leftover_processes(&pids, &self.root);
        let files_left = leftover_files(&self.tmp, &dir);
        Ok(RunResult {
            run: name
                .trim_start_matches(|c: char| c.is_alphabetic())
                .parse()
                .unwrap_or(0),
            faults,
            seconds,
            ratio: if self.base.is_zero() {
                1.0
            } else {
                seconds / self.base.as_secs_f64()
            },
            exit_ok,
            identical,
            timed_out,
            events,
            processes_left,
            files_left,
            error,
        })
    }

    /// Begins or ends `f`.
    fn apply(&self, c: &mut Cluster, dir: &Path, f: &Fault, end: bool) -> Result<()> {
        let k = f.worker;
        match (f.kind, end) {
            (Kind::Kill, _) | (Kind::Restart, false) => c.kill(k),
            (Kind::Stop, false) => c.signal(k, libc::SIGSTOP),
            (Kind::Stop, true) => c.signal(k, libc::SIGCONT),
            (Kind::Partition, false) => {
                ensure!(self.private_network, "partitions need the private network");
                cut(k, c.addresses[k].port())?;
            }
            (Kind::Partition, true) => heal(k)?,
            (Kind::Restart, true) => {
                if c.workers[k].is_none() {
                    c.incarnations[k] += 1;
                    let w = self.start_worker(dir, k, c.addresses[k], c.incarnations[k])?;
                    c.pids.push(w.pid());
                    c.workers[k] = Some(w);
                }
            }
            (Kind::Slow, false) => {
                if let Some(w) = &c.workers[k] {
                    let cpu = k % cores();
                    pin_threads(w.pid(), Some(cpu));
                    for _ in 0..HOGS {
                        let hog = spawn_hog(cpu, f.lasts + Duration::from_secs(1))?;
                        c.hog_pids.push(hog.id());
                        c.hogs.push((k, hog));
                    }
                }
            }
            (Kind::Slow, true) => c.free(k),
            (Kind::Lie, _) => c.signal(k, libc::SIGUSR1),
        }
        Ok(())
    }
}

/// The processes of one run.
#[derive(Default)]
struct Cluster {
    workers: Vec<Option<WorkerProcess>>,
    addresses: Vec<SocketAddrV4>,
    incarnations: Vec<usize>,
    /// Every worker process started, restarts included.
    pids: Vec<u32>,
    hogs: Vec<(usize, Child)>,
    hog_pids: Vec<u32>,
}

impl Cluster {
    fn signal(&self, k: usize, sig: libc::c_int) {
        if let Some(w) = &self.workers[k] {
            // SAFETY: kill(2) on a child this process started and has not reaped.
            unsafe {
                libc::kill(w.pid() as libc::pid_t, sig);
            }
        }
    }

    fn kill(&mut self, k: usize) {
        if let Some(mut w) = self.workers[k].take() {
            w.kill();
        }
    }

    /// Ends a slow fault on worker `k`: its busy neighbours killed, its threads free.
    fn free(&mut self, k: usize) {
        let (mine, rest): (Vec<_>, Vec<_>) = std::mem::take(&mut self.hogs)
            .into_iter()
            .partition(|(w, _)| *w == k);
        self.hogs = rest;
        for (_, mut h) in mine {
            let _ = h.kill();
            let _ = h.wait();
        }
        if let Some(w) = &self.workers[k] {
            pin_threads(w.pid(), None);
        }
    }

    /// After the master: every fault ended, every process gone.
    fn release(&mut self, c: &Campaign) {
        for k in 0..self.workers.len() {
            self.signal(k, libc::SIGCONT);
            self.free(k);
            if c.private_network {
                heal(k).ok();
            }
            self.kill(k);
        }
    }
}

fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// Pins every thread of `pid` to `cpu`, or frees it (None: every core).
fn pin_threads(pid: u32, cpu: Option<usize>) {
    // SAFETY: cpu_set_t is plain data; CPU_SET writes within it.
    let mut set: libc::cpu_set_t = unsafe { std::mem::zeroed() };
    for c in 0..cores() {
        if cpu.is_none_or(|p| p == c) {
            unsafe { libc::CPU_SET(c, &mut set) };
        }
    }
    let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else {
        return;
    };
    for t in tasks.flatten() {
        if let Some(tid) = t
            .file_name()
            .to_str()
            .and_then(|s| s.parse::<libc::pid_t>().ok())
        {
            // SAFETY: sched_setaffinity(2) reads `set`, a valid cpu_set_t.
            unsafe {
                libc::sched_setaffinity(tid, std::mem::size_of::<libc::cpu_set_t>(), &set);
            }
        }
    }
}

/// A busy process pinned to `cpu` for at most `lasts` (`texsyn-bench hog`).
fn spawn_hog(cpu: usize, lasts: Duration) -> Result<Child> {
    let mut c = Command::new(std::env::current_exe()?);
    c.args(["hog", "--cpu", &cpu.to_string(), "--seconds"])
        .arg(format!("{}", lasts.as_secs_f64()))
        .stdin(Stdio::null());
    end_with_parent(&mut c);
    Ok(c.spawn()?)
}

/// `texsyn-bench hog`: spins on one core for a while (the slow fault's neighbour).
#[derive(Args, Debug)]
pub struct HogArgs {
    #[arg(long)]
    pub cpu: usize,
    #[arg(long, value_parser = |s: &str| seconds(s, 0.0, 3600.0))]
    pub seconds: Duration,
}

pub fn hog(a: &HogArgs) -> Result<()> {
    pin_threads(std::process::id(), Some(a.cpu));
    let t = Instant::now();
    let mut x = 0u64;
    while t.elapsed() < a.seconds {
        for i in 0..100_000u64 {
            x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(i));
        }
    }
    std::hint::black_box(x);
    Ok(())
}

/// Makes this thread's network namespace a fresh one with loopback up, and
/// checks that nftables works in it.
fn enter_private_network() -> Result<()> {
    // SAFETY: unshare(2) changes only this thread's network namespace; the
    // processes it starts from now on inherit it.
    if unsafe { libc::unshare(libc::CLONE_NEWNET) } != 0 {
        bail!("unshare(CLONE_NEWNET): {}", std::io::Error::last_os_error());
    }
    let lo = Command::new("ip")
        .args(["link", "set", "lo", "up"])
        .output()
        .context("cannot run `ip` (iproute2)")?;
    ensure!(lo.status.success(), "`ip link set lo up` failed");
    nft(&format!("add table inet {NFT_PREFIX}probe"))?;
    nft(&format!("delete table inet {NFT_PREFIX}probe"))?;
    Ok(())
}

fn nft(script: &str) -> Result<()> {
    let mut child = Command::new("nft")
        .args(["-f", "-"])
        .stdin(Stdio::piped())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .context("cannot run `nft` (nftables)")?;
    std::io::Write::write_all(
        &mut child.stdin.take().context("nft stdin")?,
        script.as_bytes(),
    )?;
    let out = child.wait_with_output()?;
    ensure!(
        out.status.success(),
        "`nft` failed on {script:?}: {}",
        String::from_utf8_lossy(&out.stderr).trim()
    );
    Ok(())
}

/// Drops every packet to and from `port` (one nftables transaction).
fn cut(k: usize, port: u16) -> Result<()> {
    let t = format!("{NFT_PREFIX}{k}");
    nft(&format!(
        "add table inet {t}\n\
         add chain inet {t} input {{ type filter hook input priority 0; policy accept; }}\n\
         add rule inet {t} input tcp dport {port} drop\n\
         add rule inet {t} input tcp sport {port} drop\n"
    ))
}

/// Ends worker `k`'s partition (no error when there is none).
fn heal(k: usize) -> Result<()> {
    let t = format!("{NFT_PREFIX}{k}");
    nft(&format!("add table inet {t}\ndelete table inet {t}\n"))
}

/// The processes among `pids`, and any other whose command line names the
/// campaign directory, still alive (this process excepted).
fn leftover_processes(pids: &[u32], root: &Path) -> Vec<String> {
    let me = std::process::id();
    let root = root.to_string_lossy().into_owned();
    let mut left = Vec::new();
    let Ok(procs) = std::fs::read_dir("/proc") else {
        return left;
    };
    for p in procs.flatten() {
        let Some(pid) = p.file_name().to_str().and_then(|s| s.parse::<u32>().ok()) else {
            continue;
        };
        if pid == me || !alive(pid) {
            continue;
        }
        let cmdline = std::fs::read(p.path().join("cmdline"))
            .map(|b| String::from_utf8_lossy(&b).replace('\0', " "))
            .unwrap_or_default();
        if pids.contains(&pid) || cmdline.contains(&root) {
            left.push(format!("{pid}: {}", cmdline.trim()));
        }
    }
    left
}

/// True while the process exists and is not a zombie.
fn alive(pid: u32) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/stat")).is_ok_and(|s| {
        s.rsplit_once(')')
            .and_then(|(_, rest)| rest.split_whitespace().next())
            .is_some_and(|state| state != "Z" && state != "X")
    })
}

/// Whatever is in `tmp` (then removed, so the next run starts clean), and any
/// file in the run directory that is not the run's own output, report or log.
fn leftover_files(tmp: &Path, dir: &Path) -> Vec<String> {
    let mut left = Vec::new();
    for e in std::fs::read_dir(tmp).into_iter().flatten().flatten() {
        left.push(e.path().display().to_string());
        let _ = std::fs::remove_dir_all(e.path()).or_else(|_| std::fs::remove_file(e.path()));
    }
    for e in std::fs::read_dir(dir).into_iter().flatten().flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let expected = matches!(name.as_str(), "out.png" | "report.json" | "master.log")
            || (name.starts_with("worker") && name.ends_with(".log"));
        if !expected {
            left.push(e.path().display().to_string());
        }
    }
    left
}

fn count_events(report: &serde_json::Value) -> BTreeMap<String, usize> {
    let mut n = BTreeMap::new();
    for e in report["search_stats"]["cluster"]["events"]
        .as_array()
        .into_iter()
        .flatten()
    {
        if let Some(kind) = e["kind"].as_str() {
            if kind != "partition" {
                *n.entry(kind.to_string()).or_default() += 1;
            }
        }
    }
    n
}

fn tail(log: &Path) -> String {
    let s = std::fs::read_to_string(log).unwrap_or_default();
    let lines: Vec<&str> = s.lines().rev().take(3).collect();
    lines.into_iter().rev().collect::<Vec<_>>().join(" | ")
}

fn describe(r: &RunResult) -> String {
    let faults: Vec<String> = r
        .faults
        .iter()
        .map(|f| {
            let mut s = format!("{} w{}@{:.2}s", f.kind.name(), f.worker, f.at.as_secs_f64());
            if f.kind.lasts() {
                s += &format!("+{:.2}s", f.lasts.as_secs_f64());
            }
            if !f.injected {
                s += " (not reached)";
            }
            s
        })
        .collect();
    let events: Vec<String> = r.events.iter().map(|(k, v)| format!("{k} {v}")).collect();
    let verdict = if r.clean() {
        "identical".to_string()
    } else {
        format!(
            "FAILED: exit ok {}, identical {}, {} processes and {} files left{}",
            r.exit_ok,
            r.identical,
            r.processes_left.len(),
            r.files_left.len(),
            r.error
                .as_deref()
                .map(|e| format!("; {e}"))
                .unwrap_or_default()
        )
    };
    format!(
        "run {:3}  {:6.2} s ({:4.2}x)  {}  [{}]  {}",
        r.run,
        r.seconds,
        r.ratio,
        verdict,
        faults.join(", "),
        events.join(", ")
    )
}

fn summarise(args: &FaultArgs, c: &Campaign, results: Vec<RunResult>, stopped: bool) -> Summary {
    let mut injected = BTreeMap::new();
    let mut not_reached = 0;
    for f in results.iter().flat_map(|r| &r.faults) {
        if f.injected {
            *injected.entry(f.kind).or_insert(0) += 1;
        } else {
            not_reached += 1;
        }
    }
    let worst = results.iter().max_by(|a, b| a.ratio.total_cmp(&b.ratio));
    let mut ratios: Vec<f64> = results.iter().map(|r| r.ratio).collect();
    ratios.sort_by(f64::total_cmp);
    Summary {
        seed: args.seed,
        workers: args.workers,
        runs: results.len(),
        injected,
        not_reached,
        identical: results.iter().filter(|r| r.exit_ok && r.identical).count(),
        failed: results.iter().filter(|r| !r.clean()).count(),
        fault_free_seconds: c.base.as_secs_f64(),
        worst_ratio: worst.map_or(0.0, |r| r.ratio),
        worst_run: worst.map(|r| r.run),
        median_ratio: ratios.get(ratios.len() / 2).copied().unwrap_or(0.0),
        processes_left: results.iter().map(|r| r.processes_left.len()).sum(),
        files_left: results.iter().map(|r| r.files_left.len()).sum(),
        stopped_by_time_limit: stopped,
        results,
    }
}

fn print_summary(s: &Summary) {
    let kinds: Vec<String> = s
        .injected
        .iter()
        .map(|(k, n)| format!("{} {n}", k.name()))
        .collect();
    println!();
    println!("runs                      {}", s.runs);
    println!(
        "faults injected           {} ({}); {} drawn after the master had finished",
        s.injected.values().sum::<usize>(),
        kinds.join(", "),
        s.not_reached
    );
    println!("bit-identical runs        {} of {}", s.identical, s.runs);
    println!(
        "time over fault-free      worst {:.2}x (run {}), median {:.2}x; fault-free {:.2} s",
        s.worst_ratio,
        s.worst_run.map_or("-".into(), |r| r.to_string()),
        s.median_ratio,
        s.fault_free_seconds
    );
    println!("processes left behind     {}", s.processes_left);
    println!("temporary files left      {}", s.files_left);
    if s.failed > 0 {
        println!("runs with a failure       {}", s.failed);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plans_depend_on_seed_and_run_only() {
        let kinds = [
            Kind::Kill,
            Kind::Stop,
            Kind::Partition,
            Kind::Restart,
            Kind::Slow,
            Kind::Lie,
        ];
        let base = Duration::from_secs(2);
        let a = plan(7, 3, &kinds, 3, 3, base);
        let b = plan(7, 3, &kinds, 3, 3, base);
        assert_eq!(format!("{a:?}"), format!("{b:?}"));
        let all: Vec<Vec<Fault>> = (0..200).map(|r| plan(7, r, &kinds, 3, 3, base)).collect();
        for p in &all {
            assert!((1..=3).contains(&p.len()));
            assert!(p.windows(2).all(|w| w[0].at <= w[1].at), "sorted by time");
            for f in p {
                assert!(f.worker < 3);
                assert!(f.at >= base.mul_f64(0.05) && f.at < base.mul_f64(0.85));
                assert_eq!(f.lasts.is_zero(), !f.kind.lasts());
            }
        }
        // Every kind turns up over 200 runs.
        for k in kinds {
            assert!(
                all.iter().flatten().any(|f| f.kind == k),
                "{k:?} never drawn"
            );
        }
        assert_ne!(
            format!("{:?}", plan(8, 3, &kinds, 3, 3, base)),
            format!("{a:?}"),
            "another seed, another plan"
        );
    }
}
