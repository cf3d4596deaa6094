//! `texsyn-bench scale` (ARCHITECTURE §6): how exact synthesis scales with
//! threads and local workers. Each configuration is one `texsyn synth` process
//! with `--report`; the table gives its time, speed-up and efficiency against
//! the first configuration of its size, whether its output is the same bytes,
//! and where the finest level's time went (search, the share of the search
//! threads' time left idle, the keyed sweeps' wall time before and inside
//! their parallel sections with the thread time lost joining them and
//! waiting for their last part, and the serial steps between searches).

use std::path::{Path, PathBuf};
use std::process::Stdio;

use anyhow::{ensure, Context, Result};
use clap::Args;
use serde_json::Value;

#[derive(Args, Debug)]
pub struct ScaleArgs {
    /// The sample.
    pub sample: PathBuf,
    /// Output size of the thread sweep (WxH).
    #[arg(long, default_value = "1024x1024")]
    pub size: String,
    /// Thread counts of the sweep.
    #[arg(long, value_delimiter = ',', default_value = "1,2")]
    pub threads: Vec<usize>,
    /// Output size of the worker configurations (WxH; default: --size).
    #[arg(long)]
    pub cluster_size: Option<String>,
    /// Local-worker configurations WORKERSxTHREADS, each against the local
    /// engine with WORKERS × THREADS threads at --cluster-size (e.g. 4x4,8x2).
    #[arg(long, value_delimiter = ',')]
    pub workers: Vec<String>,
    /// Keep outputs and reports here (default: a temporary directory).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// The texsyn binary (default: next to texsyn-bench).
    #[arg(long)]
    pub texsyn: Option<PathBuf>,
    /// One more argument for every texsyn run, repeatable (e.g.
    /// `--texsyn-arg=--spin-us=0` to compare the wait policies).
    #[arg(long, value_name = "ARG", allow_hyphen_values = true)]
    pub texsyn_arg: Vec<String>,
}

/// One configuration's run.
struct Run {
    label: String,
    size: String,
    /// Threads in all (workers × their threads).
    cores: usize,
    seconds: f64,
    bytes: Vec<u8>,
    report: Value,
}

fn pair(s: &str, what: &str) -> Result<(usize, usize)> {
    let (a, b) = s
        .split_once('x')
        .with_context(|| format!("{what} '{s}' is not AxB"))?;
    Ok((a.parse()?, b.parse()?))
}

fn run_one(a: &ScaleArgs, dir: &Path, label: &str, size: &str, extra: &[String]) -> Result<Run> {
    let texsyn = crate::cases::sibling_binary("texsyn", a.texsyn.as_deref(), "--texsyn")?;
    let stem = label.replace([' ', '×'], "_");
    let out = dir.join(format!("{stem}.png"));
    let report = dir.join(format!("{stem}.json"));
    let mut m = crate::cases::measured(&texsyn)?;
    m.cmd
        .arg("synth")
        .arg(&a.sample)
        .arg("-o")
        .arg(&out)
        .args(["--size", size, "-q", "--report"])
        .arg(&report)
        .args(extra)
        .args(&a.texsyn_arg)
        .stdout(Stdio::null());
    let (seconds, _) = m.run().with_context(|| format!("run {label}"))?;
    Ok(Run {
        label: label.to_string(),
        size: size.to_string(),
        cores: 0,
        seconds,
        bytes: std::fs::read(&out)?,
        report: serde_json::from_slice(&std::fs::read(&report)?)?,
    })
}

/// Level 0's breakdown: search seconds, idle share, serial seconds.
fn finest(report: &Value) -> String {
    let levels = report["per_level"].as_array();
    let Some(l0) = levels.and_then(|l| l.iter().find(|l| l["level"] == 0)) else {
        return "-".into();
    };
    let f = |k: &str| l0[k].as_f64().unwrap_or(0.0);
    let idle = l0["search_idle_share"]
        .as_f64()
        .map_or("-".into(), |x| format!("{:.0}%", 100.0 * x));
    let w = &l0["sweeps"];
    let sweeps = if w.is_object() {
        let g = |k: &str| w[k].as_f64().unwrap_or(0.0);
        format!(
            "{:.2} s | {:.2} s | {:.1} | {:.1}",
            g("prep_seconds"),
            g("wall_seconds"),
            g("lag_thread_seconds"),
            g("tail_thread_seconds")
        )
    } else {
        "- | - | - | -".into()
    };
    format!(
        "{:.2} s | {idle} | {sweeps} | {:.2} s | {:.2} s | {:.2} s | {}",
        f("search_seconds"),
        f("choose_seconds"),
        f("query_seconds"),
        f("copy_seconds"),
        l0["batches"]
    )
}

pub fn run(a: &ScaleArgs) -> Result<()> {
    ensure!(a.sample.is_file(), "no sample {}", a.sample.display());
    let tmp = tempfile::tempdir()?;
    let dir = a.out.clone().unwrap_or_else(|| tmp.path().to_path_buf());
    std::fs::create_dir_all(&dir)?;
    let mut runs: Vec<Run> = Vec::new();
    for &t in &a.threads {
        let mut r = run_one(
            a,
            &dir,
            &format!("local {t}"),
            &a.size,
            &["--threads".into(), t.to_string()],
        )?;
        r.cores = t;
        eprintln!("{}: {:.2} s", r.label, r.seconds);
        runs.push(r);
    }
    let csize = a.cluster_size.clone().unwrap_or_else(|| a.size.clone());
    for w in &a.workers {
        let (n, t) = pair(w, "--workers")?;
        let cores = n * t;
        if !runs
            .iter()
            .any(|r| r.size == csize && r.cores == cores && r.label.starts_with("local"))
        {
            let mut r = run_one(
                a,
                &dir,
                &format!("local {cores} at {csize}"),
                &csize,
                &["--threads".into(), cores.to_string()],
            )?;
            r.cores = cores;
            eprintln!("{}: {:.2} s", r.label, r.seconds);
            runs.push(r);
        }
        let extra = [
            "--local-workers".to_string(),
            n.to_string(),
            "--local-worker-threads".into(),
            t.to_string(),
            "--threads".into(),
            t.to_string(),
        ];
        let mut r = run_one(a, &dir, &format!("{n} workers × {t}"), &csize, &extra)?;
        r.cores = cores;
        eprintln!("{}: {:.2} s", r.label, r.seconds);
        runs.push(r);
    }
    println!(
        "sample {} | thread sweep at {} | workers at {csize}{}",
        a.sample.display(),
        a.size,
        if a.texsyn_arg.is_empty() {
            String::new()
        } else {
            format!(" | texsyn {}", a.texsyn_arg.join(" "))
        }
    );
    println!("| run | size | threads | time | speed-up | efficiency | of local | identical | level 0 search | idle | before sweeps | in sweeps | lag (thread-s) | tail (thread-s) | choose | queries | copy | batches |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for r in &runs {
        let base = runs
            .iter()
            .find(|b| b.size == r.size)
            .expect("a run of its size");
        let speed = base.seconds / r.seconds;
        let eff = speed * base.cores as f64 / r.cores.max(1) as f64;
        let local = runs
            .iter()
            .find(|b| b.size == r.size && b.cores == r.cores && b.label.starts_with("local"))
            .map_or("-".into(), |b| format!("{:.2}", b.seconds / r.seconds));
        println!(
            "| {} | {} | {} | {:.2} s | {speed:.2}× | {:.0}% | {local} | {} | {} |",
            r.label,
            r.size,
            r.cores,
            r.seconds,
            100.0 * eff,
            if r.bytes == base.bytes { "yes" } else { "NO" },
            finest(&r.report)
        );
    }
    Ok(())
}
