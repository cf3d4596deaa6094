//! `texsyn-bench lbg`: LBG (Stahlhut §8) against the exhaustive search on the
//! very queries of an exhaustive run, per level of the paper's configurations
//! (a) and (b) and for P = 1, 2, 4; then (b) end to end with
//! `--search local,local,local,lbg` (ARCHITECTURE §6).

mod record;

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Result;
use clap::Args;
use rayon::ThreadPool;
use texsyn::block::Silent;
use texsyn::imaging::load_color;
use texsyn::search::lbg::LbgSearch;
use texsyn::search::{LocalSearch, Plan, PlannedSearch};
use texsyn::{synthesize, Output};
use texsyn_engine::{Codebook, Engine, Hit, LbgConfig, QueryBatch, VectorSpace};

use crate::cases::{Case, RunArgs, CASES};
use record::{LbgErrors, RecordedLevel, Recorder};

#[derive(Args, Debug)]
pub struct LbgArgs {
    #[command(flatten)]
    pub run: RunArgs,
    /// Probes to measure (comma-separated).
    #[arg(long, value_delimiter = ',', default_value = "1,2,4")]
    pub lbg_probes: Vec<usize>,
    /// Training threshold (relative change of the seed displacement).
    #[arg(long, default_value_t = texsyn_engine::lbg::DEFAULT_THRESHOLD)]
    pub lbg_threshold: f64,
    /// Training vectors per seed (0 = all vectors).
    #[arg(long, default_value_t = texsyn_engine::lbg::DEFAULT_SAMPLE_PER_SEED)]
    pub lbg_sample_per_seed: usize,
    /// Cap on training iterations.
    #[arg(long, default_value_t = texsyn_engine::lbg::DEFAULT_MAX_ITERATIONS)]
    pub lbg_max_iterations: usize,
    /// Also sweep training set size × iteration cap on the finest level of (b).
    #[arg(long)]
    pub lbg_grid: bool,
}

/// What every step of the bench uses.
struct Bench<'a> {
    args: &'a LbgArgs,
    pool: ThreadPool,
    engine: Engine,
    dir: PathBuf,
}

pub fn run(a: &LbgArgs) -> Result<()> {
    let dir = a.run.textures.dir()?;
    anyhow::ensure!(
        !a.lbg_probes.is_empty() && a.lbg_probes.iter().all(|&p| p >= 1),
        "--lbg-probes needs values ≥ 1, e.g. 1,2,4"
    );
    texsyn_engine::lbg::check_threshold(a.lbg_threshold)?;
    let bench = Bench {
        args: a,
        pool: a.run.pool()?,
        engine: Engine::default(),
        dir,
    };
    println!(
        "kernel {} | {} thread(s) | batch K = {} | LBG threshold {} | training set {} per seed | iteration cap {}",
        bench.engine.kernel().name(),
        bench.pool.current_num_threads(),
        a.run.batch,
        a.lbg_threshold,
        if a.lbg_sample_per_seed == 0 {
            "all vectors".to_string()
        } else {
            format!("{} vectors", a.lbg_sample_per_seed)
        },
        a.lbg_max_iterations
    );
    let mut exhaustive_b: Option<Output> = None;
    for case in &CASES {
        let out = bench.case_levels(case)?;
        if case.name == "b" {
            exhaustive_b = Some(out);
        }
    }
    bench.end_to_end(exhaustive_b.as_ref())
}

impl Bench<'_> {
    fn lbg_config(&self, seed: u64, level: usize) -> LbgConfig {
        LbgConfig {
            threshold: self.args.lbg_threshold,
            max_iterations: self.args.lbg_max_iterations,
            sample_per_seed: self.args.lbg_sample_per_seed,
            seed: texsyn::search::lbg::level_seed(seed, level),
            ..LbgConfig::default()
        }
    }

    /// LBG's answers with `probes` partitions to every recorded batch of `l`.
    fn search_all(&self, cb: &Codebook, l: &RecordedLevel, probes: usize) -> Result<Vec<Vec<Hit>>> {
        let got = self.pool.install(|| {
            l.batches
                .iter()
                .map(|b| cb.search(&self.engine, b, probes))
                .collect::<std::result::Result<Vec<_>, _>>()
        })?;
        Ok(got)
    }

    /// The exhaustive run of `case`, then LBG per level on its queries.
    fn case_levels(&self, case: &Case) -> Result<Output> {
        let sample = load_color(&self.dir.join(case.file))?;
        let (cfg, mode) = case.run(self.args.run.batch);
        let mut rec = Recorder::new(LocalSearch::new(self.engine));
        let out = self
            .pool
            .install(|| synthesize(&sample, &mode, &cfg, &mut rec, &Silent))?;
        println!(
            "{}; exhaustive run {:.3} s",
            case.describe(&sample, out.report.levels),
            out.report.synthesis_seconds
        );
        println!(
            "    level   refs  queries seeds iters  train s |  P  exh. search s  LBG search s  speed-up  incl. train | differ   worse  mean excess total excess"
        );
        for l in &rec.levels {
            self.level_rows(l, cfg.seed, case.name == "b")?;
        }
        Ok(out)
    }

    /// One row per probe count for level `l`; the grid on level 0 of (b).
    fn level_rows(&self, l: &RecordedLevel, seed: u64, case_b: bool) -> Result<()> {
        let d = &l.data;
        let n = d.total();
        let space =
            VectorSpace::build_from_positions(&d.sample(), &d.geometry, &d.positions, 0..n)?;
        let lcfg = self.lbg_config(seed, d.level);
        let cb = self
            .pool
            .install(|| Codebook::train(&self.engine, &space, 0..n, &d.params, &lcfg))?;
        let st = cb.stats().clone();
        let queries: usize = l.batches.iter().map(QueryBatch::len).sum();
        for &p in &self.args.lbg_probes {
            if p > cb.seeds_requested() {
                println!(
                    "    {:>5} {:>6} {:>8} {:>5} {:>5} {:>8.4} | {p:>2}  (more probes than seeds; skipped)",
                    d.level, n, queries, st.seeds, st.iterations, st.train_seconds
                );
                continue;
            }
            let t = Instant::now();
            let got = self.search_all(&cb, l, p)?;
            let secs = t.elapsed().as_secs_f64();
            let err = LbgErrors::of(&l.exact, &got);
            println!(
                "    {:>5} {:>6} {:>8} {:>5} {:>5} {:>8.4} | {p:>2} {:>14.4} {:>13.4} {:>8.1}x {:>11.1}x | {:>5.1}% {:>6.1}% {:>9.2}% {:>9.2}%",
                d.level,
                n,
                queries,
                st.seeds,
                st.iterations,
                st.train_seconds,
                l.search_seconds,
                secs,
                l.search_seconds / secs,
                l.search_seconds / (secs + st.train_seconds),
                err.differ * 100.0,
                err.worse * 100.0,
                err.mean_excess * 100.0,
                err.total_excess * 100.0
            );
        }
        if self.args.lbg_grid && case_b && d.level == 0 {
            self.grid(l, &space, &lcfg)?;
        }
        Ok(())
    }

    /// Training set per seed × iteration cap on level `l`, P = 1.
    fn grid(&self, l: &RecordedLevel, space: &VectorSpace, lcfg: &LbgConfig) -> Result<()> {
        let n = l.data.total();
        println!("    grid on level 0, P = 1 (training set per seed × iteration cap):");
        for per_seed in [0usize, 256, 64, 32, 16] {
            for cap in [3usize, 5, 10, 20, 50] {
                let gcfg = LbgConfig {
                    sample_per_seed: per_seed,
                    max_iterations: cap,
                    ..*lcfg
                };
                let cb = self.pool.install(|| {
                    Codebook::train(&self.engine, space, 0..n, &l.data.params, &gcfg)
                })?;
                let got = self.search_all(&cb, l, 1)?;
                let err = LbgErrors::of(&l.exact, &got);
                let s = cb.stats();
                println!(
                    "      per seed {:>4} cap {:>2}: iterations {:>2} converged {:<5} train {:>7.4} s | differ {:>5.1}% worse {:>5.1}% mean rel. excess {:.2}% total excess {:.2}%",
                    if per_seed == 0 { "all".to_string() } else { per_seed.to_string() },
                    cap,
                    s.iterations,
                    s.converged,
                    s.train_seconds,
                    err.differ * 100.0,
                    err.worse * 100.0,
                    err.mean_excess * 100.0,
                    err.total_excess * 100.0
                );
            }
        }
        Ok(())
    }

    /// (b) end to end with LBG on the finest level only, best of `--reps`.
    fn end_to_end(&self, exhaustive_b: Option<&Output>) -> Result<()> {
        let a = self.args;
        let case = &CASES[1];
        let sample = load_color(&self.dir.join(case.file))?;
        let (cfg, mode) = case.run(a.run.batch);
        let plan: Plan = "local,local,local,lbg".parse()?;
        let p1 = a.lbg_probes[0];
        let reps = a.run.reps.max(1);
        let mut runs: Vec<Output> = Vec::with_capacity(reps);
        for _ in 0..reps {
            let lbg = LbgSearch::new(self.engine, p1, a.lbg_threshold, cfg.seed)?
                .with_max_iterations(a.lbg_max_iterations)?
                .with_sample_per_seed(a.lbg_sample_per_seed);
            let mut backend = PlannedSearch::new(plan.clone(), LocalSearch::new(self.engine))
                .with_lbg(Box::new(lbg));
            runs.push(
                self.pool
                    .install(|| synthesize(&sample, &mode, &cfg, &mut backend, &Silent))?,
            );
        }
        runs.sort_by(|x, y| {
            x.report
                .synthesis_seconds
                .total_cmp(&y.report.synthesis_seconds)
        });
        anyhow::ensure!(
            runs.windows(2).all(|w| w[0].image == w[1].image),
            "LBG runs of the same configuration gave different images"
        );
        print_end_to_end(&runs, exhaustive_b, p1);
        a.run.save("bench_b_lbg.png", &runs[0].image)?;
        if let Some(e) = exhaustive_b {
            a.run.save("bench_b_exhaustive.png", &e.image)?;
        }
        Ok(())
    }
}

/// The end-to-end runs (sorted, fastest first) against the exhaustive run.
fn print_end_to_end(runs: &[Output], exhaustive_b: Option<&Output>, p1: usize) {
    let reps = runs.len();
    let r = &runs[0].report;
    println!(
        "(b) end to end, --search local,local,local,lbg, P = {p1}: total synthesis time {:.4} s (best of {reps}; median {:.4} s, worst {:.4} s)",
        r.synthesis_seconds,
        runs[reps / 2].report.synthesis_seconds,
        runs[reps - 1].report.synthesis_seconds
    );
    let exh = exhaustive_b.map(|o| &o.report);
    for l in &r.per_level {
        let base = exh.and_then(|e| e.per_level.iter().find(|x| x.level == l.level));
        println!(
            "    level {} canvas {:>4}x{:<4} refs {:>7} queries {:>6}  build+train {:>7.4} s  search {:>8.4} s  level {:>8.4} s{}",
            l.level,
            l.canvas[0],
            l.canvas[1],
            l.reference_vectors,
            l.queries,
            l.build_seconds,
            l.search_seconds,
            l.total_seconds,
            base.map(|b| format!(
                "  (exhaustive: search {:.4} s, level {:.4} s)",
                b.search_seconds, b.total_seconds
            ))
            .unwrap_or_default()
        );
    }
    println!("    search stats: {}", r.search_stats);
    if let Some(e) = exh {
        println!(
            "    exhaustive run of the same configuration: {:.4} s",
            e.synthesis_seconds
        );
    }
}
