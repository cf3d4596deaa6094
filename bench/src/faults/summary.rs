//! The campaign's summary: one line per run, the totals, and the JSON of
//! every run.

use std::collections::BTreeMap;

use anyhow::{ensure, Context, Result};
use serde::Serialize;

use super::campaign::Campaign;
use super::{FaultArgs, Kind, RunResult};

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

/// Summarises and prints the runs, writes `--json`, and fails unless every
/// run was clean.
pub(super) fn report(
    args: &FaultArgs,
    c: &Campaign,
    results: Vec<RunResult>,
    stopped: bool,
) -> Result<()> {
    let summary = summarise(args, c, results, stopped);
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

pub(super) fn describe(r: &RunResult) -> String {
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
