//! Network partitions: a worker cut off by the network mid-level.
//!
//! The test cluster runs inside a private network namespace: the test thread
//! calls `unshare(CLONE_NEWNET)`, brings its loopback up, and everything it
//! starts from then on (two real `texsyn-worker` processes, the `texsyn` master
//! binary, `nft`) lives in that namespace. An nftables rule dropping every
//! packet to and from one worker's port cuts it off without stopping it (no
//! reset, no error: the connection just goes silent); deleting the rule heals
//! the partition. The run must finish bit-identical to a local run, within a
//! time budget, and take the worker back at a later level.
//!
//! Needs root (for the namespace) and `nft` (package nftables). Without them
//! the test prints `SKIP: <reason>` and passes, except with `CI=true`, where
//! it fails: CI runs as root and installs nftables (`.ci/run`).

use crate::harness;

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use harness::{texture_path, Token, Worker};
use serde_json::Value;

/// Pyramid levels of the test synthesis (coarsest is `LEVELS - 1`).
const LEVELS: usize = 4;
/// The level during which the worker is cut off; levels below it come later.
const CUT_LEVEL: usize = 1;
/// Side of the synthesised texture.
const SIDE: usize = 512;
/// The master's least batch deadline (`--worker-timeout`), in seconds.
const WORKER_TIMEOUT: &str = "1";
/// nftables table of the partition.
const TABLE: &str = "texsyn_partition";

/// Why this machine cannot run the partition tests, if it cannot.
fn enter_private_network() -> Result<(), String> {
    // SAFETY: unshare(2) changes only this thread's network namespace; the
    // processes it starts from now on inherit it.
    if unsafe { libc::unshare(libc::CLONE_NEWNET) } != 0 {
        let e = std::io::Error::last_os_error();
        return Err(format!(
            "cannot make a network namespace (unshare CLONE_NEWNET: {e}); run as root"
        ));
    }
    let lo = Command::new("ip")
        .args(["link", "set", "lo", "up"])
        .output()
        .map_err(|e| format!("cannot run `ip` (iproute2): {e}"))?;
    if !lo.status.success() {
        return Err(format!(
            "`ip link set lo up` failed: {}",
            String::from_utf8_lossy(&lo.stderr).trim()
        ));
    }
    // The namespace is a fresh one: loopback is its only interface.
    let links = Command::new("ip")
        .args(["-o", "link", "show"])
        .output()
        .map_err(|e| e.to_string())?;
    let links = String::from_utf8_lossy(&links.stdout);
    if links.lines().count() != 1 || !links.contains(": lo:") {
        return Err(format!("the new namespace is not empty: {links}"));
    }
    nft(&format!("add table inet {TABLE}")).map_err(|e| {
        format!("nftables does not work here ({e}); install it: apt-get install nftables")
    })?;
    nft(&format!("delete table inet {TABLE}"))?;
    Ok(())
}

/// Runs `nft CMD` (split on whitespace; braces in one argument).
fn nft(cmd: &str) -> Result<(), String> {
    let out = Command::new("nft")
        .arg(cmd)
        .output()
        .map_err(|e| format!("cannot run `nft`: {e}"))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!(
            "`nft {cmd}` failed: {}",
            String::from_utf8_lossy(&out.stderr).trim()
        ))
    }
}

/// Drops every packet to and from `port` on this namespace's loopback: one
/// atomic nftables transaction, so the cut is at one instant.
fn cut(port: u16) {
    let script = format!(
        "add table inet {TABLE}\n\
         add chain inet {TABLE} input {{ type filter hook input priority 0; policy accept; }}\n\
         add rule inet {TABLE} input tcp dport {port} drop\n\
         add rule inet {TABLE} input tcp sport {port} drop\n"
    );
    let mut child = Command::new("nft")
        .args(["-f", "-"])
        .stdin(Stdio::piped())
        .spawn()
        .expect("run nft");
    std::io::Write::write_all(&mut child.stdin.take().unwrap(), script.as_bytes()).unwrap();
    assert!(child.wait().unwrap().success(), "nft -f: {script}");
}

fn heal() {
    nft(&format!("delete table inet {TABLE}")).unwrap();
}

/// Runs `scenario` on a thread of its own inside a fresh network namespace,
/// or reports why it cannot: `SKIP: <reason>` on stderr, or a failure under
/// `CI=true`.
fn in_private_network(scenario: impl FnOnce() + Send + 'static) {
    let t = std::thread::spawn(move || {
        enter_private_network()?;
        scenario();
        Ok::<(), String>(())
    });
    match t.join() {
        Ok(Ok(())) => {}
        Ok(Err(reason)) => harness::skip("partition tests", &reason),
        Err(panic) => std::panic::resume_unwind(panic),
    }
}

/// `texsyn synth` of the test texture into `out`, with `extra` flags.
fn synth_command(out: &Path, extra: &[&str]) -> Command {
    let mut c = Command::new(harness::binary("texsyn"));
    let (size, levels) = (format!("{SIDE}x{SIDE}"), LEVELS.to_string());
    c.arg("synth")
        .arg(texture_path("brick_color_96.png"))
        .args(["--size", &size, "--levels", &levels, "--seed", "7", "-q"])
        .arg("-o")
        .arg(out)
        .args(extra)
        .stdin(Stdio::null());
    c
}

fn search_plan(kind: &str) -> String {
    [kind; LEVELS].join(",")
}

/// The master of a cluster run: its log lines as they come, with the time
/// each one was read.
struct Master {
    child: std::process::Child,
    log: harness::Log,
}

impl Master {
    fn start(out: &Path, report: &Path, workers: &[&Worker], token: &Token) -> Self {
        let list: Vec<String> = workers.iter().map(|w| w.address.to_string()).collect();
        let mut cmd = synth_command(
            out,
            &[
                "--search",
                &search_plan("cluster"),
                "--workers",
                &list.join(","),
                "--token-file",
                token.path.to_str().unwrap(),
                "--require-cluster",
                "--worker-timeout",
                WORKER_TIMEOUT,
                "--report",
                report.to_str().unwrap(),
            ],
        );
        // Info, and the membership's debug lines: they name a worker that
        // could not be reached when a level starts.
        cmd.env("RUST_LOG", "texsyn=info,texsyn::cluster::membership=debug")
            .env("NO_COLOR", "1")
            .stderr(Stdio::piped());
        let mut child = cmd.spawn().expect("start the master");
        let log = harness::Log::follow(child.stderr.take().unwrap());
        Self { child, log }
    }

    /// Waits (up to `timeout`) for a log line that passes `f`.
    fn wait_for(&mut self, timeout: Duration, f: impl Fn(&str) -> bool) -> Option<Instant> {
        self.log.wait_for(timeout, f)
    }

    /// Waits for the exit; the whole log.
    fn finish(mut self, timeout: Duration) -> (std::process::ExitStatus, String) {
        let end = Instant::now() + timeout;
        let status = loop {
            if let Some(s) = self.child.try_wait().unwrap() {
                break s;
            }
            if Instant::now() > end {
                let _ = self.child.kill();
                let _ = self.child.wait();
                panic!(
                    "the master did not finish within {timeout:?}: {}",
                    self.log.text()
                );
            }
            std::thread::sleep(Duration::from_millis(20));
        };
        self.log.drain();
        (status, self.log.text())
    }
}

impl Drop for Master {
    /// A test that fails midway leaves no master running.
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The log line the master prints when `level` has been cut over the workers.
fn level_start(level: usize) -> impl Fn(&str) -> bool {
    move |l: &str| l.contains(" partition ") && l.contains(&format!("level={level}"))
}

fn events<'a>(report: &'a Value, kind: &str) -> Vec<&'a Value> {
    report["search_stats"]["cluster"]["events"]
        .as_array()
        .expect("cluster events in the report")
        .iter()
        .filter(|e| e["kind"] == kind)
        .collect()
}

/// The workers with a non-empty share in the partition of `level`.
fn shares_at(report: &Value, level: usize) -> Vec<String> {
    events(report, "partition")
        .into_iter()
        .filter(|e| e["level"] == level)
        .flat_map(|e| e["shares"].as_array().unwrap().iter())
        .filter(|s| s["share"].as_f64().unwrap_or(0.0) > 0.0)
        .map(|s| s["worker"].as_str().unwrap_or("").to_string())
        .collect()
}

/// Two workers, the local engine's output, and the fault-free cluster run.
struct Setup {
    dir: tempfile::TempDir,
    token: Token,
    a: Worker,
    b: Worker,
    /// The local engine's PNG: what every run must equal byte for byte.
    truth: Vec<u8>,
    /// The fault-free cluster run (master process start to exit).
    fault_free: Duration,
    /// How long level `CUT_LEVEL` takes in the fault-free run.
    level_time: Duration,
}

impl Setup {
    fn new() -> Self {
        let dir = tempfile::tempdir().unwrap();
        let token = Token::new();
        let a = Worker::with_token(2, &token, 1);
        let b = Worker::with_token(3, &token, 1);
        let local = dir.path().join("local.png");
        let r = synth_command(&local, &["--search", &search_plan("local")])
            .output()
            .unwrap();
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
        let truth = std::fs::read(&local).unwrap();

        let clean = dir.path().join("clean.png");
        let t = Instant::now();
        let mut m = Master::start(&clean, &dir.path().join("clean.json"), &[&a, &b], &token);
        let cut_start = m.wait_for(Duration::from_secs(60), level_start(CUT_LEVEL));
        let cut_end = m.wait_for(Duration::from_secs(60), level_start(CUT_LEVEL - 1));
        let (status, log) = m.finish(Duration::from_secs(60));
        let fault_free = t.elapsed();
        assert!(status.success(), "fault-free cluster run failed: {log}");
        assert!(
            std::fs::read(&clean).unwrap() == truth,
            "the fault-free cluster run differs from the local engine"
        );
        let level_time = cut_end.unwrap() - cut_start.unwrap();
        eprintln!("fault-free cluster run: {fault_free:?} (level {CUT_LEVEL}: {level_time:?})");
        Self {
            dir,
            token,
            a,
            b,
            truth,
            fault_free,
            level_time,
        }
    }

    /// Starts the master of a run whose output and report are `NAME.png`, `NAME.json`.
    fn master(&self, name: &str) -> Master {
        Master::start(
            &self.dir.path().join(format!("{name}.png")),
            &self.dir.path().join(format!("{name}.json")),
            &[&self.a, &self.b],
            &self.token,
        )
    }

    /// The run `name` is done: it succeeded, its image equals the local
    /// engine's, and it took at most `budget`. Its report.
    fn check(&self, name: &str, master: Master, started: Instant, budget: Duration) -> Value {
        let (status, log) = master.finish(Duration::from_secs(120));
        let took = started.elapsed();
        eprintln!("{name}: {took:?} (fault-free {:?})", self.fault_free);
        assert!(status.success(), "{name}: the run failed: {log}");
        assert!(
            std::fs::read(self.dir.path().join(format!("{name}.png"))).unwrap() == self.truth,
            "{name}: the output differs from the local engine"
        );
        assert!(
            took <= budget,
            "{name}: took {took:?}, over its budget {budget:?} (fault-free {:?})",
            self.fault_free
        );
        let report = std::fs::read(self.dir.path().join(format!("{name}.json"))).unwrap();
        serde_json::from_slice(&report).unwrap()
    }

    /// The event of `kind` about worker B.
    fn b_event<'a>(&self, report: &'a Value, kind: &str) -> &'a Value {
        let baddr = self.b.address.to_string();
        events(report, kind)
            .into_iter()
            .find(|e| e["worker"] == baddr.as_str())
            .unwrap_or_else(|| panic!("no {kind} event for {baddr}: {report:#}"))
    }

    /// B rejoined after its drop at `drop_level`, searched every later level
    /// with A, and is active at the end (never stopped: it was only cut off).
    fn assert_rejoined(&self, report: &Value, drop_level: usize) -> usize {
        let rejoin = self.b_event(report, "rejoin");
        eprintln!("rejoin: {rejoin}");
        let rejoin_level = rejoin["level"].as_u64().unwrap() as usize;
        assert!(
            rejoin_level < drop_level,
            "rejoined at level {rejoin_level}, not after the drop at {drop_level}"
        );
        let (aaddr, baddr) = (self.a.address.to_string(), self.b.address.to_string());
        for level in 0..=rejoin_level {
            let shares = shares_at(report, level);
            assert!(
                shares.contains(&baddr) && shares.contains(&aaddr),
                "level {level} after the rejoin is searched by both workers: {shares:?}"
            );
        }
        let w = report["search_stats"]["cluster"]["workers"]
            .as_array()
            .unwrap()
            .iter()
            .find(|w| w["address"] == baddr.as_str())
            .unwrap();
        assert_eq!(w["state"], "active", "{w:#}");
        assert!(
            harness::alive(self.b.pid()),
            "the cut-off worker was never stopped"
        );
        rejoin_level
    }

    /// B's drop: while searching a batch of `level` (mid-level, not at its
    /// start), caught by its deadline.
    fn assert_dropped_mid_level(&self, report: &Value, level: usize) {
        let drop = self.b_event(report, "drop");
        eprintln!("drop: {drop}");
        assert_eq!(drop["level"], level, "{drop:#}");
        assert!(
            !drop["batch"].is_null(),
            "dropped while searching a batch (mid-level), not at a level start: {drop:#}"
        );
        assert!(
            drop["reason"].as_str().unwrap().contains("deadline"),
            "a silent worker is caught by its deadline: {drop:#}"
        );
    }
}

fn dropping(addr: &str) -> impl Fn(&str) -> bool + '_ {
    move |l: &str| l.contains("dropping worker") && l.contains(addr)
}

/// The partition starts a tenth into level `CUT_LEVEL` and heals as soon as
/// the master has dropped the worker: it is back for the next level.
#[test]
fn worker_cut_off_mid_level_is_dropped_output_unchanged_and_rejoins_once_healed() {
    in_private_network(|| {
        let s = Setup::new();
        let baddr = s.b.address.to_string();
        let t = Instant::now();
        let mut m = s.master("cut");
        m.wait_for(Duration::from_secs(60), level_start(CUT_LEVEL))
            .unwrap_or_else(|| panic!("level {CUT_LEVEL} never started: {}", m.log.text()));
        std::thread::sleep(s.level_time / 10);
        cut(s.b.address.port());
        let cut_at = t.elapsed();
        let dropped = m.wait_for(Duration::from_secs(30), dropping(&baddr));
        heal();
        eprintln!("cut at {cut_at:?}, healed at {:?}", t.elapsed());
        assert!(
            dropped.is_some(),
            "the master never dropped {baddr}: {}",
            m.log.text()
        );
        let report = s.check("cut", m, t, s.fault_free * 4 + Duration::from_secs(5));
        s.assert_dropped_mid_level(&report, CUT_LEVEL);
        assert_eq!(s.assert_rejoined(&report, CUT_LEVEL), CUT_LEVEL - 1);
    });
}

/// The partition starts as the first level begins and lasts past the start
/// of the level after the one B is dropped in: there the master cannot reach
/// the worker (its connect timeout runs out on the silent port), reports it
/// unavailable and searches the level without it; healed, the worker rejoins
/// at the level after.
///
/// The coarse levels take tens of milliseconds, less than spawning `nft`, so
/// the master is held (SIGSTOP) from the moment its first level starts until
/// the cut is in place: B still owes batches of that level when the master
/// goes on, whatever the machine's load. Which level B is dropped in is read
/// from the report; it must leave two levels after it.
#[test]
fn worker_still_cut_off_at_a_level_start_is_skipped_there_and_rejoins_later() {
    in_private_network(|| {
        let s = Setup::new();
        let baddr = s.b.address.to_string();
        let t = Instant::now();
        let mut m = s.master("long");
        m.wait_for(Duration::from_secs(60), level_start(LEVELS - 1))
            .unwrap_or_else(|| panic!("level {} never started: {}", LEVELS - 1, m.log.text()));
        harness::sigstop(m.child.id());
        cut(s.b.address.port());
        harness::sigcont(m.child.id());
        let cut_at = t.elapsed();
        let dropped = m.wait_for(Duration::from_secs(30), dropping(&baddr));
        let dropped_at = t.elapsed();
        let unreachable = m.wait_for(Duration::from_secs(30), |l| {
            l.contains("worker not available") && l.contains(&baddr)
        });
        let unreachable_at = t.elapsed();
        // The next level's partition line: the level searched without B.
        let next = m.wait_for(Duration::from_secs(30), |l| l.contains(" partition "));
        heal();
        eprintln!(
            "cut at {cut_at:?}, dropped at {dropped_at:?}, found unreachable at \
             {unreachable_at:?}, healed at {:?}",
            t.elapsed()
        );
        assert!(
            dropped.is_some(),
            "the master never dropped {baddr}: {}",
            m.log.text()
        );
        assert!(
            unreachable.is_some(),
            "the master never tried {baddr} again while it was cut off: {}",
            m.log.text()
        );
        assert!(
            next.is_some(),
            "no level started after {baddr} was unreachable: {}",
            m.log.text()
        );
        // The silent worker costs a retry timeout (`--worker-timeout`, 1 s) at
        // the level start, not the 5 s connect timeout of a first contact.
        let budget = s.fault_free * 4 + Duration::from_secs(3);
        let report = s.check("long", m, t, budget);
        let drop_level = s.b_event(&report, "drop")["level"].as_u64().unwrap() as usize;
        assert!(
            drop_level >= 2,
            "B was dropped at level {drop_level}, too late for a skipped level and a rejoin"
        );
        s.assert_dropped_mid_level(&report, drop_level);
        // Whether the master was held before or after it opened its search
        // stream to B, the silence is caught within the worker timeout, not
        // the 10 s call timeout of a control call.
        let reason = s.b_event(&report, "drop")["reason"].as_str().unwrap();
        let ms: f64 = reason
            .split("deadline of ")
            .nth(1)
            .and_then(|r| r.split(' ').next())
            .and_then(|n| n.parse().ok())
            .unwrap_or_else(|| panic!("no deadline in the drop reason {reason:?}"));
        let limit = WORKER_TIMEOUT.parse::<f64>().unwrap() * 1000.0 + 500.0;
        assert!(
            ms <= limit,
            "B was given {ms} ms, over {limit} ms: {reason}"
        );
        let skipped = drop_level - 1;
        assert_eq!(
            shares_at(&report, skipped),
            vec![s.a.address.to_string()],
            "level {skipped} is searched without the cut-off worker"
        );
        let w = report["search_stats"]["cluster"]["workers"]
            .as_array()
            .unwrap()
            .iter()
            .find(|w| w["address"] == baddr.as_str())
            .unwrap();
        assert_eq!(
            w["drops"], 1,
            "dropped once, then only not reachable: {w:#}"
        );
        assert_eq!(s.assert_rejoined(&report, skipped), skipped - 1);
    });
}
