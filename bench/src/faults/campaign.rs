//! The campaign and its runs: the fixed parts every run shares, one run's
//! cluster of worker processes and master, and the faults begun and ended
//! while the master works.

use std::collections::BTreeMap;
use std::ffi::OsString;
use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, ensure, Context, Result};
use texsyn::launch::local::{new_token, spawn_worker_at, write_token_file, WorkerProcess};
use texsyn::launch::{end_with_parent, find_worker_binary};

use super::inject::{
    cores, cut, heal, leftover_files, leftover_processes, pin_threads, spawn_hog, HOGS,
};
use super::summary::describe;
use super::{plan, Fault, FaultArgs, Kind, RunResult};

/// The campaign's fixed parts: binaries, directories, token, sample, truth.
pub(super) struct Campaign<'a> {
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
    pub(super) base: Duration,
    /// The network namespace is private (partitions possible).
    private_network: bool,
}

impl<'a> Campaign<'a> {
    /// The campaign's directories, token, sample and binaries under `root`;
    /// sets this process's TMPDIR to the campaign's `tmp`.
    pub(super) fn new(args: &'a FaultArgs, root: PathBuf, private_network: bool) -> Result<Self> {
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
        let master_binary = crate::cases::sibling_binary(
            "texsyn",
            args.master_binary.as_deref(),
            "--master-binary",
        )?;
        Ok(Campaign {
            args,
            worker_binary: find_worker_binary(args.worker_binary.as_deref())?,
            master_binary,
            sample,
            root,
            tmp,
            token_path,
            truth: Vec::new(),
            base: Duration::ZERO,
            private_network,
        })
    }
}

impl Campaign<'_> {
    /// The local engine's image (the truth), then the fault-free cluster
    /// runs, whose median time becomes the reference time; returns their
    /// times, sorted.
    pub(super) fn reference(&mut self) -> Result<Vec<f64>> {
        let args = self.args;
        let local = self.root.join("local.png");
        let status = self
            .master_command(&local, None, &["--search", &self.plan_of("local")])
            .status()?;
        ensure!(status.success(), "the local run failed");
        self.truth = std::fs::read(&local)?;
        let mut times = Vec::new();
        for k in 0..args.fault_free {
            let r = self.run(&format!("clean{k}"), Vec::new(), Duration::from_secs(600))?;
            ensure!(
                r.clean(),
                "the fault-free cluster run {k} is not clean: {}; left behind: {:?}",
                describe(&r),
                [&r.processes_left[..], &r.files_left[..]].concat()
            );
            times.push(r.seconds);
        }
        times.sort_by(f64::total_cmp);
        self.base = Duration::from_secs_f64(times[times.len() / 2]);
        Ok(times)
    }

    /// Prints what the campaign does and the fault-free times.
    pub(super) fn announce(&self, times: &[f64]) {
        let args = self.args;
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
            self.sample.display(),
            args.levels
        );
        println!(
            "fault-free cluster runs: {times:.2?} s, reference {:.2} s",
            self.base.as_secs_f64()
        );
    }

    /// The runs with faults, until `--runs` or the time limit since
    /// `started`; whether the time limit stopped them.
    pub(super) fn fault_runs(&self, started: Instant) -> Result<(Vec<RunResult>, bool)> {
        let args = self.args;
        let timeout = self.base.mul_f64(args.run_timeout_factor) + Duration::from_secs(60);
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
                self.base,
            );
            let r = self.run(&format!("run{k:03}"), faults, timeout)?;
            println!("{}", describe(&r));
            results.push(r);
        }
        Ok((results, stopped))
    }

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
        let mut cluster = self.start_cluster(&dir)?;
        let out = dir.join("out.png");
        let report = dir.join("report.json");
        let mut cmd = self.cluster_master(&cluster, &dir, &out, &report)?;
        let t = Instant::now();
        let mut master = cmd.spawn().context("cannot start the master")?;
        let master_pid = master.id();
        let (status, timed_out, mut error) =
            self.drive(&mut master, t, timeout, &mut cluster, &dir, &mut faults)?;
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

    /// Worker processes on 127.0.0.2, .3, …, their logs in `dir`.
    fn start_cluster(&self, dir: &Path) -> Result<Cluster> {
        let mut cluster = Cluster::default();
        for k in 0..self.args.workers as usize {
            let ip = Ipv4Addr::new(127, 0, 0, 2 + k as u8);
            let w = self.start_worker(dir, k, SocketAddrV4::new(ip, 0), 0)?;
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
        Ok(cluster)
    }

    /// The master of a run on `cluster`, writing `out` and `report`, its log in `dir`.
    fn cluster_master(
        &self,
        cluster: &Cluster,
        dir: &Path,
        out: &Path,
        report: &Path,
    ) -> Result<Command> {
        let list: Vec<String> = cluster.addresses.iter().map(|a| a.to_string()).collect();
        let timeout_arg = format!("{}", self.args.worker_timeout.as_secs_f64());
        let plan = self.plan_of("cluster");
        let cmd = self.master_command(
            out,
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
        Ok(cmd)
    }

    /// Waits for the master, beginning and ending `faults` on time (from `t`),
    /// and kills it after `timeout`. Returns its exit status (None: killed),
    /// whether it timed out and what went wrong first in a fault.
    fn drive(
        &self,
        master: &mut Child,
        t: Instant,
        timeout: Duration,
        cluster: &mut Cluster,
        dir: &Path,
        faults: &mut [Fault],
    ) -> Result<(Option<ExitStatus>, bool, Option<String>)> {
        let steps = schedule(faults);
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
                if let Err(e) = self.apply(cluster, dir, &faults[i], end) {
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
        Ok((status, timed_out, error))
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

/// The begins and ends of `faults`, in time order: (time, fault, is_end).
fn schedule(faults: &[Fault]) -> Vec<(Duration, usize, bool)> {
    let mut steps: Vec<(Duration, usize, bool)> = Vec::new();
    for (i, f) in faults.iter().enumerate() {
        steps.push((f.at, i, false));
        if f.kind.lasts() {
            steps.push((f.at + f.lasts, i, true));
        }
    }
    steps.sort_by_key(|s| s.0);
    steps
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
