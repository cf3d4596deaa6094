//! `texsyn bench`: the paper's two configurations end to end (Stahlhut Table 1
//! and §10.2, ARCHITECTURE §6), with times per level and in total.

use std::path::PathBuf;

use std::time::Instant;

use anyhow::{Context, Result};
use texsyn_engine::{
    Codebook, Engine, Geometry, Hit, LbgConfig, OwnedPlane, Params, QueryBatch, Sample, VectorSpace,
};

use crate::cli::{existing_dir, BenchArgs};
use crate::imaging;
use crate::lbg::LbgSearch;
use crate::search::{LevelData, LocalSearch, Plan, PlannedSearch, SearchBackend};
use crate::synth::{self, Config, Mode, Silent, SynthMethod};

struct Case {
    name: &'static str,
    file: &'static str,
    size: usize,
    block: usize,
    neighbourhood: usize,
    levels: usize,
}

impl Case {
    /// The configuration and mode of this case with batch size `batch`.
    fn run(&self, batch: usize) -> (Config, Mode) {
        let cfg = Config {
            block: self.block,
            neighbourhood: self.neighbourhood,
            levels: self.levels,
            batch,
            ..Config::default()
        };
        let mode = Mode::Synth {
            width: self.size,
            height: self.size,
            method: SynthMethod::Grow,
        };
        (cfg, mode)
    }
}

const CASES: [Case; 2] = [
    Case {
        name: "a",
        file: "brick_gray_64.png",
        size: 192,
        block: 3,
        neighbourhood: 9,
        levels: 3,
    },
    Case {
        name: "b",
        file: "gravel_gray_500.png",
        size: 1000,
        block: 5,
        neighbourhood: 11,
        levels: 4,
    },
];

fn textures_dir(arg: &Option<PathBuf>) -> PathBuf {
    arg.clone().unwrap_or_else(|| {
        let here = PathBuf::from("../shared/textures");
        if here.is_dir() {
            here
        } else {
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/textures")
        }
    })
}

pub(crate) fn run(a: &BenchArgs) -> Result<()> {
    if a.which == "lbg" {
        return run_lbg(a);
    }
    if a.which == "cluster" {
        let dir = textures_dir(&a.textures);
        existing_dir(&dir).context("texture directory for the bench (give --textures DIR)")?;
        return crate::cluster::bench::run(&crate::cluster::bench::ClusterBench {
            textures: &dir,
            batch: a.batch,
            batches: a.batches,
            rounds: a.reps,
            worker_binary: a.worker_binary.as_deref(),
        });
    }
    let dir = textures_dir(&a.textures);
    existing_dir(&dir).context("texture directory for the bench (give --textures DIR)")?;
    let pool = {
        let mut b = rayon::ThreadPoolBuilder::new();
        if let Some(t) = a.threads {
            b = b.num_threads(t);
        }
        b.build()?
    };
    let which: Vec<&Case> = CASES
        .iter()
        .filter(|c| a.which == "paper" || a.which == c.name)
        .collect();
    anyhow::ensure!(
        !which.is_empty(),
        "unknown bench '{}': use a, b, paper or lbg",
        a.which
    );
    println!(
        "kernel {} | {} thread(s) | batch K = {}",
        Engine::default().kernel().name(),
        pool.current_num_threads(),
        a.batch
    );
    for case in which {
        let sample = imaging::load_color(&dir.join(case.file))?;
        let (cfg, mode) = case.run(a.batch);
        let reps = if case.name == "a" { a.reps.max(1) } else { 1 };
        let mut best: Option<synth::Output> = None;
        for _ in 0..reps {
            let mut backend = LocalSearch::new(Engine::default());
            let out =
                pool.install(|| synth::synthesize(&sample, &mode, &cfg, &mut backend, &Silent))?;
            if best
                .as_ref()
                .is_none_or(|b| out.report.synthesis_seconds < b.report.synthesis_seconds)
            {
                best = Some(out);
            }
        }
        let out = best.context("no run")?;
        let r = &out.report;
        println!(
            "({}) {}x{} from {} ({}x{}), {}x{} neighbourhood, {}x{} blocks, {} levels, exhaustive, best of {reps}:",
            case.name,
            case.size,
            case.size,
            case.file,
            sample.width,
            sample.height,
            case.neighbourhood,
            case.neighbourhood,
            case.block,
            case.block,
            r.levels
        );
        for l in &r.per_level {
            println!(
                "    level {} canvas {:>4}x{:<4} refs {:>7} queries {:>6}  build {:>7.4} s  search {:>8.4} s  level {:>8.4} s",
                l.level, l.canvas[0], l.canvas[1], l.reference_vectors, l.queries, l.build_seconds, l.search_seconds, l.total_seconds
            );
        }
        println!("    total synthesis time {:.4} s", r.synthesis_seconds);
        if let Some(o) = &a.out {
            std::fs::create_dir_all(o)?;
            imaging::save_color(&o.join(format!("bench_{}.png", case.name)), &out.image)?;
        }
    }
    Ok(())
}

// ---------------------------------------------------------------- bench lbg

/// One level of an exhaustive run: its reference data, every query batch and
/// the exact answers.
struct RecordedLevel {
    level: usize,
    geometry: Geometry,
    params: Params,
    fine: OwnedPlane,
    parent: Option<OwnedPlane>,
    positions: Vec<[u32; 2]>,
    batches: Vec<QueryBatch>,
    exact: Vec<Vec<Hit>>,
    search_seconds: f64,
}

/// Exhaustive search that records what it was asked and answered.
struct Recorder {
    inner: LocalSearch,
    levels: Vec<RecordedLevel>,
}

impl SearchBackend for Recorder {
    fn name(&self) -> String {
        self.inner.name()
    }

    fn load_level(&mut self, level: &LevelData) -> Result<()> {
        self.levels.push(RecordedLevel {
            level: level.level,
            geometry: level.geometry,
            params: level.params,
            fine: OwnedPlane::of(&level.sample.fine),
            parent: level.sample.parent.as_ref().map(OwnedPlane::of),
            positions: level.positions.to_vec(),
            batches: Vec::new(),
            exact: Vec::new(),
            search_seconds: 0.0,
        });
        self.inner.load_level(level)
    }

    fn search(&mut self, queries: &QueryBatch) -> Result<Vec<Hit>> {
        let t = Instant::now();
        let hits = self.inner.search(queries)?;
        let l = self.levels.last_mut().context("search before load_level")?;
        l.search_seconds += t.elapsed().as_secs_f64();
        l.batches.push(queries.clone());
        l.exact.push(hits.clone());
        Ok(hits)
    }

    fn end_level(&mut self) {
        self.inner.end_level();
    }
}

/// LBG answers against the exact ones.
struct LbgErrors {
    /// Share of queries whose answer (index) differs from the exhaustive one.
    differ: f64,
    /// Share of queries whose answer has a larger distance.
    worse: f64,
    /// Mean over queries with an exact distance > 0 of (d_lbg − d_exact) / d_exact.
    mean_excess: f64,
    /// Σ (d_lbg − d_exact) / Σ d_exact over all queries.
    total_excess: f64,
}

fn lbg_errors(exact: &[Vec<Hit>], got: &[Vec<Hit>]) -> LbgErrors {
    let (mut n, mut differ, mut worse) = (0usize, 0usize, 0usize);
    let (mut rel, mut rel_n, mut sum_e, mut sum_x) = (0.0f64, 0usize, 0.0f64, 0.0f64);
    for (e, g) in exact.iter().flatten().zip(got.iter().flatten()) {
        n += 1;
        differ += usize::from(e.index != g.index);
        worse += usize::from(g.dist > e.dist);
        let x = g.dist.saturating_sub(e.dist) as f64;
        if e.dist > 0 {
            rel += x / e.dist as f64;
            rel_n += 1;
        }
        sum_e += e.dist as f64;
        sum_x += x;
    }
    let n = n.max(1) as f64;
    LbgErrors {
        differ: differ as f64 / n,
        worse: worse as f64 / n,
        mean_excess: rel / rel_n.max(1) as f64,
        total_excess: sum_x / sum_e.max(1.0),
    }
}

fn lbg_config(a: &BenchArgs, seed: u64, level: usize) -> LbgConfig {
    LbgConfig {
        threshold: a.lbg_threshold,
        max_iterations: a.lbg_max_iterations,
        sample_per_seed: a.lbg_sample_per_seed,
        seed: crate::lbg::level_seed(seed, level),
        ..LbgConfig::default()
    }
}

/// `texsyn bench lbg`: per level of (a) and (b), LBG with P = 1, 2, 4 against
/// the exhaustive search on the very queries of an exhaustive run; then (b)
/// end to end with `--search local,local,local,lbg`.
fn run_lbg(a: &BenchArgs) -> Result<()> {
    let dir = textures_dir(&a.textures);
    existing_dir(&dir).context("texture directory for the bench (give --textures DIR)")?;
    anyhow::ensure!(
        !a.lbg_probes.is_empty() && a.lbg_probes.iter().all(|&p| p >= 1),
        "--lbg-probes needs values ≥ 1, e.g. 1,2,4"
    );
    texsyn_engine::lbg::check_threshold(a.lbg_threshold)?;
    let pool = {
        let mut b = rayon::ThreadPoolBuilder::new();
        if let Some(t) = a.threads {
            b = b.num_threads(t);
        }
        b.build()?
    };
    let engine = Engine::default();
    println!(
        "kernel {} | {} thread(s) | batch K = {} | LBG threshold {} | training set {} per seed | iteration cap {}",
        engine.kernel().name(),
        pool.current_num_threads(),
        a.batch,
        a.lbg_threshold,
        if a.lbg_sample_per_seed == 0 {
            "all vectors".to_string()
        } else {
            format!("{} vectors", a.lbg_sample_per_seed)
        },
        a.lbg_max_iterations
    );
    let mut exhaustive_b: Option<synth::Output> = None;
    for case in &CASES {
        let sample = imaging::load_color(&dir.join(case.file))?;
        let (cfg, mode) = case.run(a.batch);
        let mut rec = Recorder {
            inner: LocalSearch::new(engine),
            levels: Vec::new(),
        };
        let out = pool.install(|| synth::synthesize(&sample, &mode, &cfg, &mut rec, &Silent))?;
        println!(
            "({}) {}x{} from {} ({}x{}), {}x{} neighbourhood, {}x{} blocks, {} levels; exhaustive run {:.3} s",
            case.name,
            case.size,
            case.size,
            case.file,
            sample.width,
            sample.height,
            case.neighbourhood,
            case.neighbourhood,
            case.block,
            case.block,
            out.report.levels,
            out.report.synthesis_seconds
        );
        println!(
            "    level   refs  queries seeds iters  train s |  P  exh. search s  LBG search s  speed-up  incl. train | differ   worse  mean excess total excess"
        );
        for l in &rec.levels {
            let sample_planes = Sample {
                fine: l.fine.view(),
                parent: l.parent.as_ref().map(OwnedPlane::view),
            };
            let n = l.positions.len() as u64;
            let space =
                VectorSpace::build_from_positions(&sample_planes, &l.geometry, &l.positions, 0..n)?;
            let lcfg = lbg_config(a, cfg.seed, l.level);
            let cb = pool.install(|| Codebook::train(&engine, &space, 0..n, &l.params, &lcfg))?;
            let st = cb.stats().clone();
            let queries: usize = l.batches.iter().map(QueryBatch::len).sum();
            for &p in &a.lbg_probes {
                if p > cb.seeds_requested() {
                    println!(
                        "    {:>5} {:>6} {:>8} {:>5} {:>5} {:>8.4} | {p:>2}  (more probes than seeds; skipped)",
                        l.level, n, queries, st.seeds, st.iterations, st.train_seconds
                    );
                    continue;
                }
                let t = Instant::now();
                let got = pool.install(|| {
                    l.batches
                        .iter()
                        .map(|b| cb.search(&engine, b, p))
                        .collect::<std::result::Result<Vec<_>, _>>()
                })?;
                let secs = t.elapsed().as_secs_f64();
                let err = lbg_errors(&l.exact, &got);
                println!(
                    "    {:>5} {:>6} {:>8} {:>5} {:>5} {:>8.4} | {p:>2} {:>14.4} {:>13.4} {:>8.1}x {:>11.1}x | {:>5.1}% {:>6.1}% {:>9.2}% {:>9.2}%",
                    l.level,
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
            if a.lbg_grid && case.name == "b" && l.level == 0 {
                println!("    grid on level 0, P = 1 (training set per seed × iteration cap):");
                for per_seed in [0usize, 256, 64, 32, 16] {
                    for cap in [3usize, 5, 10, 20, 50] {
                        let gcfg = LbgConfig {
                            sample_per_seed: per_seed,
                            max_iterations: cap,
                            ..lcfg
                        };
                        let cb = pool
                            .install(|| Codebook::train(&engine, &space, 0..n, &l.params, &gcfg))?;
                        let got = pool.install(|| {
                            l.batches
                                .iter()
                                .map(|b| cb.search(&engine, b, 1))
                                .collect::<std::result::Result<Vec<_>, _>>()
                        })?;
                        let err = lbg_errors(&l.exact, &got);
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
            }
        }
        if case.name == "b" {
            exhaustive_b = Some(out);
        }
    }

    // (b) end to end with LBG on the finest level only.
    let case = &CASES[1];
    let sample = imaging::load_color(&dir.join(case.file))?;
    let cfg = Config {
        block: case.block,
        neighbourhood: case.neighbourhood,
        levels: case.levels,
        batch: a.batch,
        ..Config::default()
    };
    let mode = Mode::Synth {
        width: case.size,
        height: case.size,
        method: SynthMethod::Grow,
    };
    let plan: Plan = "local,local,local,lbg".parse()?;
    let p1 = a.lbg_probes[0];
    let reps = a.reps.max(1);
    let mut runs: Vec<synth::Output> = Vec::with_capacity(reps);
    for _ in 0..reps {
        let lbg = LbgSearch::new(engine, p1, a.lbg_threshold, cfg.seed)?
            .with_max_iterations(a.lbg_max_iterations)?
            .with_sample_per_seed(a.lbg_sample_per_seed);
        let mut backend =
            PlannedSearch::new(plan.clone(), LocalSearch::new(engine)).with_lbg(Box::new(lbg));
        runs.push(pool.install(|| synth::synthesize(&sample, &mode, &cfg, &mut backend, &Silent))?);
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
    let out = &runs[0];
    let r = &out.report;
    println!(
        "(b) end to end, --search local,local,local,lbg, P = {p1}: total synthesis time {:.4} s (best of {reps}; median {:.4} s, worst {:.4} s)",
        r.synthesis_seconds,
        runs[reps / 2].report.synthesis_seconds,
        runs[reps - 1].report.synthesis_seconds
    );
    let exh = exhaustive_b.as_ref().map(|o| &o.report);
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
    if let Some(o) = &a.out {
        std::fs::create_dir_all(o)?;
        imaging::save_color(&o.join("bench_b_lbg.png"), &out.image)?;
        if let Some(e) = &exhaustive_b {
            imaging::save_color(&o.join("bench_b_exhaustive.png"), &e.image)?;
        }
    }
    Ok(())
}
