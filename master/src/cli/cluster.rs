//! The cluster's command line (ARCHITECTURE §4.2, §4.4): the cluster options
//! of the synthesis commands (`--workers`, `--hosts`, `--local-workers`, ...),
//! turned into validated [`ClusterOptions`] plus the worker processes started
//! for the run, and `texsyn cluster status`.

use std::ffi::OsString;
use std::path::PathBuf;

use anyhow::{bail, ensure, Result};
use clap::Args;
use texsyn_proto::auth::read_token_file;
use texsyn_proto::tls::{ClientTls, TlsArgs};

use super::{parse_seconds, seconds};
use crate::cluster::{status, ClusterOptions, WorkerSpec};
use crate::launch::{
    find_worker_binary, parse_worker_list, read_hosts_file, read_hosts_file_launch, LaunchSpec,
    LocalWorkers, SshWorkers,
};

#[derive(Args, Debug, Clone, Default)]
#[command(next_help_heading = "Search cluster")]
pub struct ClusterArgs {
    /// Search workers (texsyn-worker), host:port,... ; levels planned as `cluster` search on them.
    #[arg(long, value_delimiter = ',', value_name = "HOST:PORT,...")]
    pub workers: Vec<String>,
    /// Shared token of the workers (the file holds the secret).
    #[arg(long, value_name = "FILE")]
    pub token_file: Option<PathBuf>,
    #[command(flatten)]
    pub tls: TlsArgs,
    /// Hosts file (TOML): [[worker]] entries with address = "host:port" and optional token_file.
    #[arg(long, value_name = "FILE")]
    pub hosts: Option<PathBuf>,
    /// Launch workers over ssh on the --hosts entries with ssh = "user@host" for this run (stopped at the end).
    #[arg(long, requires = "hosts")]
    pub launch: bool,
    /// Start N local worker processes on 127.0.0.2, 127.0.0.3, ... for this run (stopped at the end).
    #[arg(long, default_value_t = 0, value_name = "N")]
    pub local_workers: usize,
    /// Search threads per local worker (default: the cores divided among them).
    #[arg(long, value_name = "N")]
    pub local_worker_threads: Option<usize>,
    /// The texsyn-worker executable for --local-workers (default: next to texsyn, else PATH).
    #[arg(long, value_name = "PATH")]
    pub worker_binary: Option<PathBuf>,
    /// Fail instead of finishing locally when no worker is left.
    #[arg(long)]
    pub require_cluster: bool,
    /// The master searches a share of each cluster level itself.
    #[arg(long)]
    pub master_share: bool,
    /// Least time a worker gets to answer a batch, in seconds (its deadline is
    /// this plus a multiple of the time its calibration predicts).
    #[arg(long, default_value_t = 2.0, value_name = "SECONDS",
          value_parser = |s: &str| parse_seconds(s, WORKER_TIMEOUT.0, WORKER_TIMEOUT.1))]
    pub worker_timeout: f64,
}

/// Range of `--worker-timeout`, in seconds.
const WORKER_TIMEOUT: (f64, f64) = (0.01, 3600.0);
/// Range of `cluster status --timeout`, in seconds.
const STATUS_TIMEOUT: (f64, f64) = (0.1, 600.0);

pub use crate::launch::ClusterSetup;

impl ClusterArgs {
    /// True when any worker source is given.
    pub fn any(&self) -> bool {
        !self.workers.is_empty() || self.hosts.is_some() || self.local_workers > 0
    }

    /// Validates the flags, reads token and hosts files, starts the local
    /// workers. `None` when no worker source is given.
    pub fn setup(&self) -> Result<Option<ClusterSetup>> {
        self.setup_with(&[])
    }

    /// [`ClusterArgs::setup`], with `worker_args` added to each local
    /// worker's command line.
    pub fn setup_with(&self, worker_args: &[OsString]) -> Result<Option<ClusterSetup>> {
        if !self.any() {
            self.check_no_cluster_flags()?;
            return Ok(None);
        }
        self.check_flags()?;
        let token = self
            .token_file
            .as_deref()
            .map(read_token_file)
            .transpose()?;
        let mut workers = parse_worker_list(&self.workers, token.as_deref())?;
        let mut launch = Vec::new();
        if let Some(h) = &self.hosts {
            let (running, to_launch) = read_hosts_file_launch(h, token.as_deref(), self.launch)?;
            workers.extend(running);
            launch = to_launch;
        }
        if self.launch && launch.is_empty() {
            bail!("--launch: the hosts file has no [[worker]] entry with ssh = \"user@host\"");
        }
        let tls = self.tls.load()?;
        check_launch_tls(&launch, &tls)?;
        let local = self.start_local_workers(worker_args)?;
        if let Some(l) = &local {
            workers.extend(l.specs());
        }
        let ssh = launch_over_ssh(&launch)?;
        let mut skipped_hosts = Vec::new();
        if let Some(s) = &ssh {
            skipped_hosts.extend(s.skipped.iter().map(|k| (k.ssh.clone(), k.reason.clone())));
            workers.extend(s.specs());
        }
        let options = ClusterOptions {
            tls,
            skipped_hosts,
            ..self.options(workers)?
        };
        Ok(Some(ClusterSetup {
            options,
            local,
            ssh,
        }))
    }

    /// Without a worker source, no other cluster flag may be given.
    fn check_no_cluster_flags(&self) -> Result<()> {
        for (set, flag) in [
            (self.require_cluster, "--require-cluster"),
            (self.master_share, "--master-share"),
            (self.token_file.is_some(), "--token-file"),
            (self.tls.tls_ca.is_some(), "--tls-ca"),
            (self.tls.tls_domain.is_some(), "--tls-domain"),
            (self.tls.tls_client_cert.is_some(), "--tls-client-cert"),
            (self.worker_binary.is_some(), "--worker-binary"),
            (
                self.local_worker_threads.is_some(),
                "--local-worker-threads",
            ),
        ] {
            if set {
                bail!("{flag} needs workers: add --workers, --hosts or --local-workers");
            }
        }
        Ok(())
    }

    /// The flags that do not need any file or process.
    fn check_flags(&self) -> Result<()> {
        seconds(
            "--worker-timeout",
            self.worker_timeout,
            WORKER_TIMEOUT.0,
            WORKER_TIMEOUT.1,
        )?;
        if let Some(t) = self.local_worker_threads {
            ensure!(
                (1..=1024).contains(&t),
                "--local-worker-threads {t} must be in 1..=1024"
            );
        }
        if self.local_workers > 0 && self.tls.any() {
            bail!("--tls-* options cannot be used with --local-workers: local workers listen on loopback without TLS; give the workers with --workers or --hosts instead");
        }
        if self.local_workers == 0 && self.local_worker_threads.is_some() {
            bail!("--local-worker-threads needs --local-workers N");
        }
        Ok(())
    }

    /// `--local-workers N`, if given.
    fn start_local_workers(&self, worker_args: &[OsString]) -> Result<Option<LocalWorkers>> {
        if self.local_workers == 0 {
            return Ok(None);
        }
        let binary = find_worker_binary(self.worker_binary.as_deref())?;
        let l = LocalWorkers::spawn(
            &binary,
            self.local_workers,
            self.local_worker_threads,
            worker_args,
        )?;
        Ok(Some(l))
    }

    /// The cluster options for `workers` (each listed once), without TLS.
    pub fn options(&self, workers: Vec<WorkerSpec>) -> Result<ClusterOptions> {
        let mut seen = std::collections::HashSet::new();
        for w in &workers {
            if !seen.insert(w.address.as_str()) {
                bail!("worker {} is listed twice", w.address);
            }
        }
        Ok(ClusterOptions {
            workers,
            require_cluster: self.require_cluster,
            master_share: self.master_share,
            deadline_floor: seconds(
                "--worker-timeout",
                self.worker_timeout,
                WORKER_TIMEOUT.0,
                WORKER_TIMEOUT.1,
            )?,
            ..ClusterOptions::default()
        })
    }
}

/// With TLS options, every worker `--launch` starts must serve TLS: its hosts
/// entry needs `tls_cert` and `tls_key` (paths on that host).
fn check_launch_tls(launch: &[LaunchSpec], tls: &ClientTls) -> Result<()> {
    if !tls.any() {
        return Ok(());
    }
    for l in launch {
        if l.tls.is_none() {
            bail!(
                "--tls-* options are given but the worker launched on {} would serve without TLS; add tls_cert and tls_key (paths on that host) to its [[worker]] entry in the hosts file",
                l.ssh
            );
        }
    }
    Ok(())
}

/// `--launch`: the workers started over ssh (None when there are no hosts to
/// launch on); the hosts skipped are named on stderr.
fn launch_over_ssh(launch: &[LaunchSpec]) -> Result<Option<SshWorkers>> {
    if launch.is_empty() {
        return Ok(None);
    }
    let s = SshWorkers::launch(launch)?;
    for k in &s.skipped {
        eprintln!("texsyn: host {} skipped: {}", k.ssh, k.reason);
    }
    Ok(Some(s))
}

#[derive(Args, Debug, Clone)]
pub struct StatusArgs {
    /// Hosts file (TOML) with [[worker]] address = "host:port" entries.
    #[arg(long, value_name = "FILE", required_unless_present = "workers")]
    pub hosts: Option<PathBuf>,
    /// Workers host:port,...
    #[arg(long, value_delimiter = ',', value_name = "HOST:PORT,...")]
    pub workers: Vec<String>,
    /// Shared token of the workers.
    #[arg(long, value_name = "FILE")]
    pub token_file: Option<PathBuf>,
    #[command(flatten)]
    pub tls: TlsArgs,
    /// Seconds to wait for each worker (0.1 to 600).
    #[arg(long, default_value_t = 3.0, value_name = "SECONDS",
          value_parser = |s: &str| parse_seconds(s, STATUS_TIMEOUT.0, STATUS_TIMEOUT.1))]
    pub timeout: f64,
}

/// `texsyn cluster status`.
pub fn run_status(a: &StatusArgs) -> Result<()> {
    let token = a.token_file.as_deref().map(read_token_file).transpose()?;
    let mut workers = parse_worker_list(&a.workers, token.as_deref())?;
    if let Some(h) = &a.hosts {
        workers.extend(read_hosts_file(h, token.as_deref())?);
    }
    if workers.is_empty() {
        bail!("no workers: give --hosts FILE or --workers HOST:PORT,...");
    }
    let tls = a.tls.load()?;
    let addresses: Vec<&str> = workers.iter().map(|w| w.address.as_str()).collect();
    tls.check(&addresses)?;
    let timeout = seconds("--timeout", a.timeout, STATUS_TIMEOUT.0, STATUS_TIMEOUT.1)?;
    let rows = status::query(&workers, &tls, timeout)?;
    print!("{}", status::format_table(&rows));
    if rows.iter().all(|(_, r)| r.is_err()) {
        bail!("no worker answered");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cluster_flags_without_workers_are_refused() {
        assert!(ClusterArgs::default().setup().unwrap().is_none());
        let a = ClusterArgs {
            require_cluster: true,
            ..Default::default()
        };
        let e = a.setup().unwrap_err().to_string();
        assert!(
            e.contains("--require-cluster") && e.contains("--workers"),
            "{e}"
        );
    }

    #[test]
    fn workers_and_options_are_validated() {
        let a = ClusterArgs {
            workers: vec!["127.0.0.1:7000".into(), "127.0.0.2:7000".into()],
            worker_timeout: 2.0,
            master_share: true,
            ..Default::default()
        };
        let s = a.setup().unwrap().unwrap();
        assert_eq!(s.options.workers.len(), 2);
        assert!(s.options.master_share);
        assert!(s.local.is_none());
        for bad in [
            ClusterArgs {
                workers: vec!["a:1".into(), "a:1".into()],
                ..a.clone()
            },
            ClusterArgs {
                worker_timeout: 0.0,
                ..a.clone()
            },
            ClusterArgs {
                workers: vec!["nope".into()],
                ..a.clone()
            },
            ClusterArgs {
                local_worker_threads: Some(1),
                ..a.clone()
            },
            ClusterArgs {
                token_file: Some("/nonexistent/token".into()),
                ..a.clone()
            },
        ] {
            assert!(bad.setup().is_err(), "{bad:?}");
        }
    }
}
