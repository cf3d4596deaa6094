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

mod campaign;
mod inject;
mod summary;

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{ensure, Context, Result};
use clap::{Args, ValueEnum};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use crate::cases::Textures;
use campaign::Campaign;
use inject::enter_private_network;
pub use inject::{hog, HogArgs};

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

pub fn run(args: &FaultArgs) -> Result<()> {
    check(args)?;
    // First, before any thread or process: the private network namespace
    // every process of the campaign is started in.
    let private_network = private_network(args)?;
    let started = Instant::now();
    let (_temp, root) = campaign_root(args)?;
    let mut c = Campaign::new(args, root, private_network)?;
    let times = c.reference()?;
    c.announce(&times);
    let (results, stopped) = c.fault_runs(started)?;
    summary::report(args, &c, results, stopped)
}

/// Errors unless the arguments make a campaign.
fn check(args: &FaultArgs) -> Result<()> {
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
    Ok(())
}

/// Enters the private network namespace when partitions are drawn; whether
/// it did.
fn private_network(args: &FaultArgs) -> Result<bool> {
    Ok(if args.kinds.contains(&Kind::Partition) {
        enter_private_network().context(
            "partition faults need a private network namespace and nftables: run as root \
             with nftables installed (apt-get install nftables iproute2), or leave them \
             out (--kinds kill,stop,restart,slow,lie)",
        )?;
        true
    } else {
        false
    })
}

/// The campaign directory, canonical: `--out`, or a temporary directory
/// (removed when the returned one is dropped).
fn campaign_root(args: &FaultArgs) -> Result<(Option<tempfile::TempDir>, PathBuf)> {
    let (temp, root) = match &args.out {
        Some(dir) => {
            std::fs::create_dir_all(dir)
                .with_context(|| format!("cannot create --out {}", dir.display()))?;
            (None, dir.clone())
        }
        None => {
            let temp = tempfile::Builder::new()
                .prefix("texsyn-faults-")
                .tempdir()
                .context("cannot create a temporary directory")?;
            let path = temp.path().to_path_buf();
            (Some(temp), path)
        }
    };
    Ok((temp, root.canonicalize()?))
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
