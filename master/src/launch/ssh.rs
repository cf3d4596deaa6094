//! `--hosts FILE --launch`: workers started over ssh for one run (Stahlhut §8
//! "checks for available resources and launches the clients remotely").
//!
//! Each host with `ssh = "user@host"` is checked first with the system OpenSSH
//! client in BatchMode (`nproc`, `/proc/loadavg`, `MemAvailable`, `BINARY
//! --version`); unreachable or unsuitable hosts are skipped with a reason. Then
//! `BINARY serve --listen HOST:PORT --token-stdin --exit-on-stdin-close` is
//! started over ssh; a fresh token (per run) goes in as the first stdin line —
//! never on a command line — and the ssh client's stdin stays open for the run.
//! When the run ends (drop, error), or the master dies (its end of the pipe
//! closes; on Linux the ssh client also gets SIGTERM), the remote worker sees
//! EOF on stdin and exits.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, ensure, Context, Result};
use texsyn_proto::wire::parse_listening_line;

use super::local::{new_token, spawn_registered, temp_dir};
use super::{end_with_parent, first_line, LaunchSpec, WorkerSpec, START_TIMEOUT};
use crate::cleanup::Registration;

/// How long the resource check of one host may take.
pub const CHECK_TIMEOUT: Duration = Duration::from_secs(20);

/// Least free memory for a host to be used.
pub const MIN_FREE_MEMORY: u64 = 64 << 20;
/// Most free memory a host may report (1 PiB); more is a garbled answer.
pub const MAX_FREE_MEMORY: u64 = 1 << 50;
/// Most cores a host may report; more is a garbled answer.
pub const MAX_CORES: usize = 1 << 16;

/// What the check found on a host.
#[derive(Clone, Debug, PartialEq)]
pub struct HostReport {
    pub cores: usize,
    pub load: f64,
    pub mem_available: u64,
    pub version: String,
}

/// A host that was not used, and why.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Skipped {
    pub ssh: String,
    pub reason: String,
}

/// Quotes `s` for a POSIX shell.
fn shell_quote(s: &str) -> String {
    if !s.is_empty()
        && s.bytes()
            .all(|b| b.is_ascii_alphanumeric() || b"/._-+=:@,".contains(&b))
    {
        s.to_string()
    } else {
        format!("'{}'", s.replace('\'', "'\\''"))
    }
}

fn ssh_command(spec: &LaunchSpec, remote: &str) -> Command {
    let mut cmd = Command::new("ssh");
    cmd.args(["-o", "BatchMode=yes", "-o", "ConnectTimeout=5"])
        .args(&spec.ssh_options)
        .arg("--")
        .arg(&spec.ssh)
        .arg(remote);
    cmd
}

/// Parses the output of the check command.
pub fn parse_check_output(out: &str) -> Result<HostReport> {
    let mut lines = out.lines().map(str::trim).filter(|l| !l.is_empty());
    let cores: usize = lines
        .next()
        .and_then(|l| l.parse().ok())
        .context("nproc gave no core count")?;
    ensure!(
        (1..=MAX_CORES).contains(&cores),
        "nproc gave {cores} cores, not a plausible count (1..={MAX_CORES}); check the host"
    );
    let load: f64 = lines
        .next()
        .and_then(|l| l.split_whitespace().next())
        .and_then(|l| l.parse().ok())
        .context("no /proc/loadavg")?;
    ensure!(
        load.is_finite() && load >= 0.0,
        "/proc/loadavg gave a load of {load}; check the host"
    );
    let mem_kb: u64 = lines
        .next()
        .filter(|l| l.starts_with("MemAvailable:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|l| l.parse().ok())
        .context("no MemAvailable in /proc/meminfo")?;
    let mem_available = mem_kb
        .checked_mul(1024)
        .filter(|&b| b <= MAX_FREE_MEMORY)
        .with_context(|| {
            format!(
                "MemAvailable of {mem_kb} kB is not plausible (over {} TiB); check /proc/meminfo on the host",
                MAX_FREE_MEMORY >> 40
            )
        })?;
    let version = lines
        .next()
        .context("the worker binary printed no version (is it installed there?)")?
        .to_string();
    Ok(HostReport {
        cores,
        load,
        mem_available,
        version,
    })
}

/// Runs `child` to completion with a timeout; kills it when the time is up.
fn output_with_timeout(mut child: Child, timeout: Duration) -> Result<std::process::Output> {
    let stdout = child.stdout.take();
    let stderr = child.stderr.take();
    let read = |s: Option<Box<dyn std::io::Read + Send>>| {
        std::thread::spawn(move || {
            let mut v = Vec::new();
            if let Some(mut s) = s {
                let _ = s.read_to_end(&mut v);
            }
            v
        })
    };
    let out_t = read(stdout.map(|s| Box::new(s) as _));
    let err_t = read(stderr.map(|s| Box::new(s) as _));
    let start = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait()? {
            break s;
        }
        if start.elapsed() > timeout {
            let _ = child.kill();
            let _ = child.wait();
            bail!("no answer within {timeout:?}");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    Ok(std::process::Output {
        status,
        stdout: out_t.join().unwrap_or_default(),
        stderr: err_t.join().unwrap_or_default(),
    })
}

/// Checks a host over ssh: reachable, cores, load, free memory, the worker binary
/// present and of this version.
pub fn check_host(spec: &LaunchSpec) -> Result<HostReport> {
    let remote = format!(
        "nproc; cat /proc/loadavg; grep MemAvailable /proc/meminfo; {} --version",
        shell_quote(&spec.binary)
    );
    let mut cmd = ssh_command(spec, &remote);
    cmd.stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    end_with_parent(&mut cmd);
    let child = cmd
        .spawn()
        .context("cannot run ssh (is the OpenSSH client installed?)")?;
    let out =
        output_with_timeout(child, CHECK_TIMEOUT).with_context(|| format!("ssh {}", spec.ssh))?;
    if !out.status.success() {
        bail!(
            "ssh {} failed ({}): {}",
            spec.ssh,
            out.status,
            String::from_utf8_lossy(&out.stderr).trim()
        );
    }
    let report = parse_check_output(&String::from_utf8_lossy(&out.stdout))?;
    let ours = env!("CARGO_PKG_VERSION");
    if !report.version.split_whitespace().any(|w| w == ours) {
        bail!(
            "{} is '{}', this master is {ours}",
            spec.binary,
            report.version
        );
    }
    if report.mem_available < MIN_FREE_MEMORY {
        bail!(
            "only {} MiB of memory available",
            report.mem_available >> 20
        );
    }
    Ok(report)
}

/// One worker running under an ssh session.
#[derive(Debug)]
pub struct SshWorker {
    pub address: String,
    pub ssh: String,
    pub report: HostReport,
    child: Child,
    stdin: Option<ChildStdin>,
    /// Ends the ssh client on a signal; dropped before it is reaped.
    registration: Option<Registration>,
}

impl SshWorker {
    /// Pid of the local ssh client.
    pub fn ssh_pid(&self) -> u32 {
        self.child.id()
    }

    /// Closes the session's stdin (the worker exits), then ends the ssh client.
    pub fn stop(&mut self) {
        drop(self.stdin.take());
        self.registration = None;
        let start = Instant::now();
        while start.elapsed() < Duration::from_secs(3) {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for SshWorker {
    fn drop(&mut self) {
        self.stop();
    }
}

/// The command that starts the worker on the remote host: its listen address,
/// threads, the token from stdin and, with TLS, its certificate files.
pub fn remote_command(spec: &LaunchSpec, threads: usize) -> String {
    let listen = format!("{}:{}", spec.host, spec.port);
    let mut remote = format!(
        "exec {} serve --listen {} --threads {threads} --token-stdin --exit-on-stdin-close",
        shell_quote(&spec.binary),
        shell_quote(&listen)
    );
    if let Some(tls) = &spec.tls {
        remote += &format!(
            " --tls-cert {} --tls-key {}",
            shell_quote(&tls.cert),
            shell_quote(&tls.key)
        );
        if let Some(ca) = &tls.client_ca {
            remote += &format!(" --tls-client-ca {}", shell_quote(ca));
        }
    }
    remote
}

/// Starts the worker of a checked host.
fn launch_one(spec: &LaunchSpec, report: HostReport, token: &str, log: &Path) -> Result<SshWorker> {
    let threads = spec.threads.unwrap_or(report.cores.max(1));
    let remote = remote_command(spec, threads);
    let log_file = std::fs::File::create(log)
        .with_context(|| format!("cannot create the log {}", log.display()))?;
    let mut cmd = ssh_command(spec, &remote);
    cmd.stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::from(log_file));
    end_with_parent(&mut cmd);
    let (child, registration) = spawn_registered(&mut cmd, true, Path::new("ssh"))?;
    let mut worker = SshWorker {
        address: String::new(),
        ssh: spec.ssh.clone(),
        report,
        child,
        stdin: None,
        registration: Some(registration),
    };
    let (Some(mut stdin), Some(stdout)) = (worker.child.stdin.take(), worker.child.stdout.take())
    else {
        worker.stop();
        bail!("ssh to {} gave no stdin or stdout pipe", spec.ssh);
    };
    if let Err(e) = writeln!(stdin, "{token}").and_then(|()| stdin.flush()) {
        worker.stop();
        bail!("cannot send the token to {}: {e}", spec.ssh);
    }
    worker.stdin = Some(stdin);
    let line = match first_line(stdout, "texsyn-ssh-stdout")? {
        Some(line) => line,
        None => {
            worker.stop();
            let log_text = std::fs::read_to_string(log).unwrap_or_default();
            bail!(
                "the worker on {} did not print its listening line within {START_TIMEOUT:?}: {}",
                spec.ssh,
                log_text.trim()
            );
        }
    };
    let Some(bound) = parse_listening_line(&line) else {
        worker.stop();
        bail!(
            "the worker on {} printed '{line}' instead of 'listening on ADDR'",
            spec.ssh
        );
    };
    let scheme = if spec.tls.is_some() { "https://" } else { "" };
    worker.address = format!("{scheme}{}:{}", spec.host, bound.port());
    Ok(worker)
}

/// The workers launched over ssh for one run; dropping this stops them.
pub struct SshWorkers {
    pub workers: Vec<SshWorker>,
    pub skipped: Vec<Skipped>,
    token: String,
    dir: tempfile::TempDir,
    /// Removes `dir` on a signal.
    _dir_registration: Registration,
}

impl std::fmt::Debug for SshWorkers {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SshWorkers")
            .field("workers", &self.workers)
            .field("skipped", &self.skipped)
            .field("token", &"<redacted>")
            .finish()
    }
}

impl SshWorkers {
    /// Checks every host and launches a worker on each suitable one. Hosts that
    /// fail are skipped (with a warning and a reason in [`Self::skipped`]).
    pub fn launch(hosts: &[LaunchSpec]) -> Result<Self> {
        let (dir, dir_registration) = temp_dir("ssh-workers")?;
        let mut out = Self {
            workers: Vec::new(),
            skipped: Vec::new(),
            token: new_token(),
            dir,
            _dir_registration: dir_registration,
        };
        for (k, spec) in hosts.iter().enumerate() {
            let result = check_host(spec).and_then(|report| {
                let log = out.dir.path().join(format!("ssh-worker-{}.log", k + 1));
                launch_one(spec, report, &out.token, &log)
            });
            match result {
                Ok(w) => {
                    tracing::info!(address = %w.address, ssh = %w.ssh, cores = w.report.cores, load = w.report.load, "worker launched over ssh");
                    out.workers.push(w);
                }
                Err(e) => {
                    let reason = format!("{e:#}");
                    tracing::warn!(ssh = %spec.ssh, %reason, "host skipped");
                    out.skipped.push(Skipped {
                        ssh: spec.ssh.clone(),
                        reason,
                    });
                }
            }
        }
        Ok(out)
    }

    /// The launched workers as the master addresses them.
    pub fn specs(&self) -> Vec<WorkerSpec> {
        self.workers
            .iter()
            .map(|w| WorkerSpec::new(w.address.clone(), Some(self.token.clone())))
            .collect()
    }

    /// Directory of the ssh session logs (deleted on drop).
    pub fn dir(&self) -> &Path {
        self.dir.path()
    }

    pub fn log_dir(&self) -> PathBuf {
        self.dir.path().to_path_buf()
    }

    /// Stops every worker now.
    pub fn stop(&mut self) {
        for w in &mut self.workers {
            drop(w.stdin.take());
        }
        for w in &mut self.workers {
            w.stop();
        }
    }
}

impl Drop for SshWorkers {
    fn drop(&mut self) {
        self.stop();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn check_output_is_parsed() {
        let r = parse_check_output(
            "8\n0.52 0.40 0.30 1/200 1234\nMemAvailable:   1024000 kB\ntexsyn-worker 0.1.0\n",
        )
        .unwrap();
        assert_eq!(r.cores, 8);
        assert_eq!(r.mem_available, 1024000 * 1024);
        assert_eq!(r.version, "texsyn-worker 0.1.0");
        assert!(parse_check_output("8\n0.5 0 0\nMemAvailable: 10 kB\n").is_err());
        assert!(parse_check_output("").is_err());
    }

    #[test]
    fn absurd_host_figures_are_rejected() {
        let check = |cores: &str, load: &str, mem: &str| {
            parse_check_output(&format!(
                "{cores}\n{load} 0 0 1/2 3\nMemAvailable: {mem} kB\ntexsyn-worker 0.1.0\n"
            ))
        };
        assert!(check("4", "0.5", "1024").is_ok());
        for mem in [
            "18446744073709551615",
            "18014398509481984",
            "1125899906842625",
        ] {
            let e = format!("{:#}", check("4", "0.5", mem).unwrap_err());
            assert!(e.contains("MemAvailable") && e.contains(mem), "{e}");
        }
        assert!(check("0", "0.5", "1024").is_err());
        assert!(check("99999999999", "0.5", "1024").is_err());
        assert!(check("4", "nan", "1024").is_err());
        assert!(check("4", "-1", "1024").is_err());
    }

    #[test]
    fn remote_command_passes_the_tls_files() {
        let mut spec = LaunchSpec {
            host: "10.0.0.2".into(),
            port: 7000,
            ssh: "me@10.0.0.2".into(),
            binary: "texsyn-worker".into(),
            threads: None,
            ssh_options: Vec::new(),
            tls: None,
        };
        let plain = remote_command(&spec, 4);
        assert!(
            plain.contains("--listen 10.0.0.2:7000 --threads 4"),
            "{plain}"
        );
        assert!(!plain.contains("--tls"), "{plain}");
        spec.tls = Some(super::super::hosts::LaunchTls {
            cert: "/etc/t/c.pem".into(),
            key: "/etc/t/my key.pem".into(),
            client_ca: Some("/etc/t/ca.pem".into()),
        });
        let tls = remote_command(&spec, 4);
        assert!(
            tls.ends_with(
                " --tls-cert /etc/t/c.pem --tls-key '/etc/t/my key.pem' --tls-client-ca /etc/t/ca.pem"
            ),
            "{tls}"
        );
    }

    #[test]
    fn quoting() {
        assert_eq!(
            shell_quote("/usr/bin/texsyn-worker"),
            "/usr/bin/texsyn-worker"
        );
        assert_eq!(shell_quote("a b'c"), "'a b'\\''c'");
    }
}
