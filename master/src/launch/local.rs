//! A local multi-process cluster (`--local-workers N`, ARCHITECTURE §4.2):
//! `texsyn-worker` processes on 127.0.0.2, 127.0.0.3, ... with port 0, a fresh
//! random token in a 0600 file, their ports read from the `listening on ADDR`
//! line. They are killed when [`LocalWorkers`] is dropped, on success and on
//! error alike.

use std::ffi::OsString;
use std::io::{Read, Seek};
use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};

use anyhow::{bail, Context, Result};
use texsyn_proto::wire::parse_listening_line;

use super::{end_with_parent, first_line, WorkerSpec, START_TIMEOUT};
use crate::cleanup::{self, Registration, Temporary};

/// The error of a start refused because the process is ending on a signal.
fn interrupted() -> anyhow::Error {
    anyhow::anyhow!("interrupted: the process is ending")
}

/// A temporary directory `texsyn-<what>-*`, registered for removal on a signal.
pub(super) fn temp_dir(what: &str) -> Result<(tempfile::TempDir, Registration)> {
    cleanup::register(
        || {
            tempfile::Builder::new()
                .prefix(&format!("texsyn-{what}-"))
                .tempdir()
                .with_context(|| format!("cannot create a temporary directory for the {what}"))
        },
        |d| Temporary::Dir(d.path().to_path_buf()),
        interrupted,
    )
}

/// Spawns `cmd`, registered to be killed (or, with `terminate`, asked to
/// end) on a signal.
pub(super) fn spawn_registered(
    cmd: &mut Command,
    terminate: bool,
    what: &Path,
) -> Result<(Child, Registration)> {
    cleanup::register(
        || {
            cmd.spawn()
                .with_context(|| format!("cannot start {}", what.display()))
        },
        |c| {
            if terminate {
                Temporary::Terminate(c.id())
            } else {
                Temporary::Kill(c.id())
            }
        },
        interrupted,
    )
}

/// Name of the worker executable.
pub const WORKER_BINARY: &str = "texsyn-worker";

/// Finds `texsyn-worker`: `explicit` if given, else next to the current
/// executable (the same target directory, also from `target/*/deps/`), else on PATH.
pub fn find_worker_binary(explicit: Option<&Path>) -> Result<PathBuf> {
    if let Some(p) = explicit {
        if p.is_file() {
            return Ok(p.to_path_buf());
        }
        bail!("--worker-binary {} is not a file", p.display());
    }
    let name = format!("{WORKER_BINARY}{}", std::env::consts::EXE_SUFFIX);
    if let Ok(exe) = std::env::current_exe() {
        let mut dir = exe.parent().map(Path::to_path_buf);
        for _ in 0..2 {
            let Some(d) = dir else { break };
            let candidate = d.join(&name);
            if candidate.is_file() {
                return Ok(candidate);
            }
            dir = d.parent().map(Path::to_path_buf);
        }
    }
    if let Some(path) = std::env::var_os("PATH") {
        for d in std::env::split_paths(&path) {
            let candidate = d.join(&name);
            if candidate.is_file() {
                return Ok(candidate);
            }
        }
    }
    bail!(
        "cannot find {name} next to this executable or on PATH; build it (cargo build --release) or give --worker-binary PATH"
    )
}

/// A fresh random token (32 hex digits from the thread-local CSPRNG).
pub fn new_token() -> String {
    use rand::Rng;
    let bytes: [u8; 16] = rand::rng().random();
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// Writes `token` to `path`, readable by the owner only.
pub fn write_token_file(path: &Path, token: &str) -> Result<()> {
    let mut opts = std::fs::OpenOptions::new();
    opts.write(true).create_new(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        opts.mode(0o600);
    }
    let mut f = opts
        .open(path)
        .with_context(|| format!("cannot create the token file {}", path.display()))?;
    std::io::Write::write_all(&mut f, token.as_bytes())
        .with_context(|| format!("cannot write the token file {}", path.display()))?;
    Ok(())
}

/// One started worker process.
#[derive(Debug)]
pub struct WorkerProcess {
    pub address: SocketAddr,
    pub child: Child,
    /// Where its stderr goes.
    pub log: PathBuf,
    /// Kills it on a signal; dropped before it is reaped.
    registration: Option<Registration>,
}

impl WorkerProcess {
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Kills the process (SIGKILL) and reaps it; harmless when it already exited.
    pub fn kill(&mut self) {
        let _ = self.child.kill();
        self.registration = None;
        let _ = self.child.wait();
    }
}

impl Drop for WorkerProcess {
    fn drop(&mut self) {
        self.kill();
    }
}

/// The last `max` bytes of a log file, for error messages.
fn log_tail(path: &Path, max: u64) -> String {
    let Ok(mut f) = std::fs::File::open(path) else {
        return String::new();
    };
    let len = f.metadata().map(|m| m.len()).unwrap_or(0);
    let _ = f.seek(std::io::SeekFrom::Start(len.saturating_sub(max)));
    let mut s = String::new();
    let _ = f.read_to_string(&mut s);
    s.trim().to_string()
}

/// Starts `binary serve --listen IP:0 ARGS...` with stderr to `log` and waits
/// for its `listening on ADDR` line. The process is killed if it does not
/// come up.
pub fn spawn_worker(
    binary: &Path,
    ip: Ipv4Addr,
    args: &[OsString],
    log: &Path,
) -> Result<WorkerProcess> {
    spawn_worker_at(binary, SocketAddrV4::new(ip, 0), args, log)
}

/// [`spawn_worker`] on a given port (0: any), e.g. a worker restarted where
/// its master expects it.
pub fn spawn_worker_at(
    binary: &Path,
    listen: SocketAddrV4,
    args: &[OsString],
    log: &Path,
) -> Result<WorkerProcess> {
    let ip = listen.ip();
    let log_file = std::fs::File::create(log)
        .with_context(|| format!("cannot create the worker log {}", log.display()))?;
    let mut cmd = Command::new(binary);
    cmd.arg("serve")
        .arg("--listen")
        .arg(listen.to_string())
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::from(log_file));
    if std::env::var_os("RUST_LOG").is_none() {
        cmd.env("RUST_LOG", "warn");
    }
    end_with_parent(&mut cmd);
    let (child, registration) = spawn_registered(&mut cmd, false, binary)?;
    let mut process = WorkerProcess {
        address: SocketAddr::from(([0, 0, 0, 0], 0)),
        log: log.to_path_buf(),
        registration: Some(registration),
        child,
    };
    let stdout = process.child.stdout.take().context("worker stdout")?;
    let line = match first_line(stdout, "texsyn-worker-stdout")? {
        Some(line) => line,
        None => {
            process.kill();
            bail!(
                "the worker {} on {ip} did not print its listening line within {:?}: {}",
                binary.display(),
                START_TIMEOUT,
                log_tail(log, 2000)
            );
        }
    };
    match parse_listening_line(&line) {
        Some(a) => process.address = a,
        None => {
            process.kill();
            bail!("the worker printed '{line}' instead of 'listening on ADDR'");
        }
    }
    Ok(process)
}

/// `--local-workers N`: N worker processes on 127.0.0.2..=127.0.0.(N+1) sharing a
/// fresh token. Dropping this kills them and deletes the token file.
pub struct LocalWorkers {
    pub workers: Vec<WorkerProcess>,
    token: String,
    dir: tempfile::TempDir,
    /// Removes `dir` on a signal.
    _dir_registration: Registration,
}

impl std::fmt::Debug for LocalWorkers {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LocalWorkers")
            .field("workers", &self.workers)
            .field("token", &"<redacted>")
            .finish()
    }
}

impl LocalWorkers {
    /// Starts `n` workers (1..=253) with `threads` search threads each (default:
    /// the cores divided among them) and any `extra` worker arguments.
    pub fn spawn(
        binary: &Path,
        n: usize,
        threads: Option<usize>,
        extra: &[OsString],
    ) -> Result<Self> {
        if n == 0 || n > 253 {
            bail!("--local-workers {n} must be in 1..=253");
        }
        let cores = std::thread::available_parallelism().map_or(1, |c| c.get());
        let threads = threads.unwrap_or((cores / n).max(1));
        let (dir, dir_registration) = temp_dir("local-workers")?;
        let token = new_token();
        let token_path = dir.path().join("token");
        write_token_file(&token_path, &token)?;
        let mut workers = Vec::with_capacity(n);
        for k in 0..n {
            let ip = Ipv4Addr::new(127, 0, 0, (k + 2) as u8);
            let mut args: Vec<OsString> = vec![
                "--threads".into(),
                threads.to_string().into(),
                "--token-file".into(),
                token_path.clone().into(),
            ];
            args.extend(extra.iter().cloned());
            let log = dir.path().join(format!("worker-{}.log", k + 1));
            // On error the workers started so far are killed by their Drop.
            let w = spawn_worker(binary, ip, &args, &log)?;
            tracing::info!(address = %w.address, pid = w.pid(), threads, "local worker started");
            workers.push(w);
        }
        Ok(Self {
            workers,
            token,
            dir,
            _dir_registration: dir_registration,
        })
    }

    /// The workers as the master addresses them (with the shared token).
    pub fn specs(&self) -> Vec<WorkerSpec> {
        self.workers
            .iter()
            .map(|w| WorkerSpec::new(w.address.to_string(), Some(self.token.clone())))
            .collect()
    }

    pub fn token(&self) -> &str {
        &self.token
    }

    /// Directory of the token file and the worker logs (deleted on drop).
    pub fn dir(&self) -> &Path {
        self.dir.path()
    }

    /// Kills every worker now.
    pub fn stop(&mut self) {
        for w in &mut self.workers {
            w.kill();
        }
    }
}

impl Drop for LocalWorkers {
    fn drop(&mut self) {
        self.stop();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tokens_are_fresh_hex() {
        let (a, b) = (new_token(), new_token());
        assert_eq!(a.len(), 32);
        assert!(a.bytes().all(|c| c.is_ascii_hexdigit()));
        assert_ne!(a, b);
    }

    #[cfg(unix)]
    #[test]
    fn token_file_is_private() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t");
        write_token_file(&p, "abc").unwrap();
        let mode = std::fs::metadata(&p).unwrap().permissions().mode();
        assert_eq!(mode & 0o777, 0o600);
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "abc");
        assert!(write_token_file(&p, "again").is_err(), "never overwrites");
    }

    #[test]
    fn missing_explicit_binary_is_an_error() {
        assert!(find_worker_binary(Some(Path::new("/nonexistent/texsyn-worker"))).is_err());
    }
}
