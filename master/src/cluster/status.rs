//! `texsyn cluster status`: one Info call per worker, printed as a table.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{bail, Context, Result};
use texsyn_proto::v1 as pb;
use texsyn_proto::PROTOCOL_VERSION;

use super::conn::{connect, within};
use super::hosts::{parse_worker_list, read_hosts_file, WorkerSpec};
use texsyn_proto::auth::read_token_file;

#[derive(clap::Args, Debug, Clone)]
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
    /// Seconds to wait for each worker.
    #[arg(long, default_value_t = 3.0)]
    pub timeout: f64,
}

/// One row of the table: the worker's Info, or why it did not answer.
pub type StatusRow = (String, std::result::Result<pb::InfoReply, String>);

/// Asks every worker for its Info.
pub fn query(workers: &[WorkerSpec], timeout: Duration) -> Result<Vec<StatusRow>> {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    Ok(runtime.block_on(async {
        let mut rows = Vec::new();
        for w in workers {
            let r = async {
                let mut client = connect(w, None, timeout).await?;
                let mut req = tonic::Request::new(pb::InfoRequest {
                    protocol_version: PROTOCOL_VERSION,
                });
                req.set_timeout(timeout);
                Ok(within(timeout, "Info", client.info(req))
                    .await?
                    .into_inner())
            }
            .await;
            rows.push((w.address.clone(), r));
        }
        rows
    }))
}

fn mib(b: u64) -> String {
    format!("{:.0} MiB", b as f64 / (1u64 << 20) as f64)
}

/// The table printed by `texsyn cluster status`.
pub fn format_table(rows: &[StatusRow]) -> String {
    let mut out = format!(
        "{:<24} {:<10} {:>5} {:>7} {:>6} {:>16} {:>12}  {}\n",
        "ADDRESS", "VERSION", "CORES", "THREADS", "LOAD", "PAIRS/S (CALIB)", "MEMORY", "STATE"
    );
    for (addr, r) in rows {
        match r {
            Ok(i) => {
                let calib = if i.calibrated_vectors_per_second > 0.0 {
                    format!("{:.3e}", i.calibrated_vectors_per_second)
                } else {
                    "-".into()
                };
                out += &format!(
                    "{:<24} {:<10} {:>5} {:>7} {:>6.2} {:>16} {:>12}  ok ({} jobs, kernel {})\n",
                    addr,
                    i.version,
                    i.cores,
                    i.threads,
                    i.load_average,
                    calib,
                    mib(i.memory_in_use),
                    i.jobs,
                    i.kernel
                );
            }
            Err(e) => {
                out += &format!(
                    "{:<24} {:<10} {:>5} {:>7} {:>6} {:>16} {:>12}  error: {e}\n",
                    addr, "-", "-", "-", "-", "-", "-"
                );
            }
        }
    }
    out
}

/// `texsyn cluster status`.
pub fn run(a: &StatusArgs) -> Result<()> {
    let token = a.token_file.as_deref().map(read_token_file).transpose()?;
    let mut workers = parse_worker_list(&a.workers, token.as_deref())?;
    if let Some(h) = &a.hosts {
        workers.extend(read_hosts_file(h, token.as_deref())?);
    }
    if workers.is_empty() {
        bail!("no workers: give --hosts FILE or --workers HOST:PORT,...");
    }
    let timeout = Duration::from_secs_f64(a.timeout.clamp(0.1, 600.0));
    let rows = query(&workers, timeout)?;
    print!("{}", format_table(&rows));
    if rows.iter().all(|(_, r)| r.is_err()) {
        bail!("no worker answered");
    }
    Ok(())
}
