//! A small harness for multi-process tests: real `texsyn-worker` processes on
//! 127.0.0.x with port 0 (the real port is read from their `listening on ADDR`
//! line), a shared token in a 0600 file, signals (SIGKILL, SIGSTOP, SIGCONT),
//! and every process killed when its handle is dropped; and the synthesis the
//! cluster tests run (sample, configuration, plan, thread pool).
#![allow(dead_code)]

use std::ffi::OsString;
use std::net::{Ipv4Addr, SocketAddr};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use texsyn::block::Silent;
use texsyn::cluster::WorkerSpec;
use texsyn::imaging::{self, ColorImage};
use texsyn::launch::local::{new_token, spawn_worker, write_token_file, WorkerProcess};
use texsyn::search::{LocalSearch, Plan, PlannedSearch, SearchBackend, Strategy};
use texsyn::{synthesize, Config, Mode, Output, SynthMethod};
use texsyn_engine::Engine;

/// `target/<profile>/`, the parent of this test executable's `deps/`.
pub fn target_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("test executable path");
    exe.parent()
        .and_then(Path::parent)
        .expect("test executable in target/<profile>/deps")
        .to_path_buf()
}

/// `target/<profile>/NAME`, built with cargo if it is missing (a
/// `cargo test --workspace` builds both binaries before any test runs).
pub fn binary(name: &str) -> PathBuf {
    static BUILT: OnceLock<()> = OnceLock::new();
    let p = target_dir().join(format!("{name}{}", std::env::consts::EXE_SUFFIX));
    if !p.is_file() {
        BUILT.get_or_init(|| {
            let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
            let mut cmd = std::process::Command::new(cargo);
            cmd.args(["build", "-p", "texsyn", "-p", "texsyn-worker"]);
            // target/<dir>: the profile that built this test (debug is `dev`).
            match target_dir().file_name().and_then(|n| n.to_str()) {
                Some("debug") | None => {}
                Some(profile) => {
                    cmd.args(["--profile", profile]);
                }
            }
            let status = cmd.status().expect("run cargo build");
            assert!(status.success(), "cargo build of the binaries failed");
        });
    }
    assert!(p.is_file(), "{} is not built", p.display());
    p
}

/// A token file shared by the workers and the master of one test.
pub struct Token {
    pub value: String,
    pub path: PathBuf,
    pub dir: tempfile::TempDir,
}

impl Token {
    pub fn new() -> Self {
        let dir = tempfile::tempdir().expect("temp dir");
        let value = new_token();
        let path = dir.path().join("token");
        write_token_file(&path, &value).expect("token file");
        Self { value, path, dir }
    }
}

/// One worker process on 127.0.0.`host`.
pub struct Worker {
    pub process: WorkerProcess,
    pub address: SocketAddr,
    _logs: tempfile::TempDir,
}

impl Worker {
    /// Starts `texsyn-worker serve --listen 127.0.0.HOST:0 ARGS...`.
    pub fn start(host: u8, args: &[&str]) -> Self {
        let logs = tempfile::tempdir().expect("temp dir");
        let args: Vec<OsString> = args.iter().map(OsString::from).collect();
        let process = spawn_worker(
            &binary("texsyn-worker"),
            Ipv4Addr::new(127, 0, 0, host),
            &args,
            &logs.path().join("worker.log"),
        )
        .expect("worker starts");
        let address = process.address;
        Self {
            process,
            address,
            _logs: logs,
        }
    }

    /// Starts a worker that requires `token`, with `threads` search threads.
    pub fn with_token(host: u8, token: &Token, threads: usize) -> Self {
        let t = threads.to_string();
        let path = token.path.to_str().expect("utf-8 temp path").to_string();
        Self::start(host, &["--threads", &t, "--token-file", &path])
    }

    pub fn spec(&self, token: Option<&Token>) -> WorkerSpec {
        WorkerSpec::new(self.address.to_string(), token.map(|t| t.value.clone()))
    }

    pub fn pid(&self) -> u32 {
        self.process.pid()
    }

    pub fn log(&self) -> String {
        std::fs::read_to_string(&self.process.log).unwrap_or_default()
    }
}

/// Sends `sig` to `pid` (ignores a process that is already gone).
pub fn signal(pid: u32, sig: libc::c_int) {
    // SAFETY: kill(2) with a pid of a child this test started; no memory is shared.
    unsafe {
        libc::kill(pid as libc::pid_t, sig);
    }
}

pub fn sigkill(pid: u32) {
    signal(pid, libc::SIGKILL);
}

/// Stops the process and waits (up to 2 s) until every thread of it is stopped:
/// SIGSTOP takes effect asynchronously, and a worker could otherwise still
/// answer a batch sent right after the signal.
pub fn sigstop(pid: u32) {
    signal(pid, libc::SIGSTOP);
    let t = std::time::Instant::now();
    while t.elapsed() < std::time::Duration::from_secs(2) && !stopped(pid) {
        std::thread::sleep(std::time::Duration::from_micros(200));
    }
}

/// Every thread of `pid` is in the stopped state (T).
pub fn stopped(pid: u32) -> bool {
    let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else {
        return false;
    };
    tasks.flatten().all(|t| {
        std::fs::read_to_string(t.path().join("stat"))
            .ok()
            .and_then(|s| {
                s.rsplit_once(')')
                    .and_then(|(_, rest)| rest.split_whitespace().next().map(str::to_string))
            })
            .is_some_and(|state| state == "T" || state == "t")
    })
}

pub fn sigcont(pid: u32) {
    signal(pid, libc::SIGCONT);
}

/// True while the process exists and is not a zombie.
pub fn alive(pid: u32) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/stat"))
        .map(|s| {
            s.rsplit_once(')')
                .and_then(|(_, rest)| rest.split_whitespace().next())
                .is_some_and(|state| state != "Z" && state != "X")
        })
        .unwrap_or(false)
}

/// `assets/textures/NAME`.
/// Runs `texsyn` with these arguments and asserts it succeeds.
pub fn texsyn_ok<S: AsRef<std::ffi::OsStr>>(args: &[S]) -> std::process::Output {
    let r = std::process::Command::new(binary("texsyn"))
        .args(args)
        .output()
        .unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    r
}

pub fn texture_path(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../assets/textures")
        .join(name)
}

/// Pyramid levels of the test synthesis.
pub const LEVELS: usize = 3;

/// The sample of the test synthesis: `brick_color_96.png`.
pub fn sample() -> &'static ColorImage {
    static S: OnceLock<ColorImage> = OnceLock::new();
    S.get_or_init(|| imaging::load_color(&texture_path("brick_color_96.png")).unwrap())
}

pub fn config() -> Config {
    Config {
        block: 3,
        neighbourhood: 9,
        levels: LEVELS,
        batch: 16,
        seed: 5,
        ..Config::default()
    }
}

/// A `side`×`side` texture grown from the sample.
pub fn mode(side: usize) -> Mode {
    Mode::Synth {
        width: side,
        height: side,
        method: SynthMethod::Grow,
    }
}

pub fn pool() -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap()
}

/// Every level searched with `strategy` (the cluster ones on `cluster`).
pub fn planned(strategy: Strategy, cluster: Option<Box<dyn SearchBackend>>) -> PlannedSearch {
    let backend = PlannedSearch::new(
        Plan::Levels(vec![strategy; LEVELS]),
        LocalSearch::new(Engine::default()),
    );
    match cluster {
        Some(c) => backend.with_cluster(c),
        None => backend,
    }
}

/// The test synthesis of a `side`×`side` texture on `backend`, on 2 threads.
pub fn synth(backend: &mut PlannedSearch, side: usize) -> anyhow::Result<Output> {
    pool().install(|| synthesize(sample(), &mode(side), &config(), backend, &Silent))
}

/// A test that this machine cannot run says why: `SKIP: <reason>` on the
/// process's stderr (the harness captures `eprintln!` of passing tests, and a
/// skip must be seen), and passes, except under `CI=true`, where CI runs as
/// root with what `.ci/run` installs, so it fails instead.
pub fn skip(what: &str, reason: &str) {
    use std::io::Write;
    if std::env::var("CI").is_ok_and(|v| v == "true") {
        panic!("{what} cannot run under CI=true: {reason}");
    }
    let _ = writeln!(std::io::stderr(), "SKIP: {what}: {reason}");
}

/// A child's stderr followed line by line on a thread of its own, with the
/// time each line was read (terminal colours stripped); the lines seen so far
/// are kept for failure messages.
pub struct Log {
    lines: std::sync::mpsc::Receiver<(std::time::Instant, String)>,
    seen: Vec<String>,
}

impl Log {
    pub fn follow(stderr: impl std::io::Read + Send + 'static) -> Self {
        use std::io::BufRead;
        let (tx, lines) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            for line in std::io::BufReader::new(stderr)
                .lines()
                .map_while(Result::ok)
            {
                if tx
                    .send((std::time::Instant::now(), strip_ansi(&line)))
                    .is_err()
                {
                    break;
                }
            }
        });
        Self {
            lines,
            seen: Vec::new(),
        }
    }

    /// Waits (up to `timeout`) for a line that passes `f`; when it was read.
    pub fn wait_for(
        &mut self,
        timeout: std::time::Duration,
        f: impl Fn(&str) -> bool,
    ) -> Option<std::time::Instant> {
        let end = std::time::Instant::now() + timeout;
        while let Some(left) = end.checked_duration_since(std::time::Instant::now()) {
            match self.lines.recv_timeout(left) {
                Ok((t, line)) => {
                    let hit = f(&line);
                    self.seen.push(line);
                    if hit {
                        return Some(t);
                    }
                }
                Err(_) => return None,
            }
        }
        None
    }

    /// Reads what is left (the child has exited; up to 2 s of silence).
    pub fn drain(&mut self) {
        while let Ok((_, line)) = self.lines.recv_timeout(std::time::Duration::from_secs(2)) {
            self.seen.push(line);
        }
    }

    /// The lines seen so far.
    pub fn text(&self) -> String {
        self.seen.join("\n")
    }
}

/// `line` without terminal colour sequences (`ESC [ ... letter`).
pub fn strip_ansi(line: &str) -> String {
    let mut out = String::with_capacity(line.len());
    let mut chars = line.chars();
    while let Some(c) = chars.next() {
        if c == '\u{1b}' {
            for d in chars.by_ref() {
                if d.is_ascii_alphabetic() {
                    break;
                }
            }
        } else {
            out.push(c);
        }
    }
    out
}
