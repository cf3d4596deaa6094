//! `texsyn cluster status` (ARCHITECTURE §4.1): one Info call per worker,
//! printed as a table.

use std::time::Duration;

use anyhow::{Context, Result};
use texsyn_proto::v1 as pb;
use texsyn_proto::PROTOCOL_VERSION;

use texsyn_proto::tls::ClientTls;

use super::conn::{connect, first_info, WorkerSpec};
use super::error::ClusterResult;

/// One row of the table: the worker's Info, or why it did not answer.
pub type StatusRow = (String, ClusterResult<pb::InfoReply>);

/// Asks every worker for its Info (TLS as the addresses and `tls` say).
pub fn query(workers: &[WorkerSpec], tls: &ClientTls, timeout: Duration) -> Result<Vec<StatusRow>> {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    Ok(runtime.block_on(async {
        let mut rows = Vec::new();
        for w in workers {
            let r = async {
                let mut client = connect(w, tls, timeout).await?;
                first_info(&mut client, w, tls, PROTOCOL_VERSION, timeout).await
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
