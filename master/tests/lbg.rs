//! LBG in the synthesis (Stahlhut §8, ARCHITECTURE §3.8): probing every partition
//! synthesises exactly what the exhaustive search does, LBG runs are
//! deterministic across thread counts, the run report records each level's
//! codebook, and bad LBG parameters are clear errors (library and CLI).

use crate::common;

use anyhow::Result;
use common::{assets, s, texsyn};
use texsyn::block::Silent;
use texsyn::imaging::{self, ColorImage};
use texsyn::search::lbg::LbgSearch;
use texsyn::search::{LevelData, LocalSearch, Plan, PlannedSearch, SearchBackend};
use texsyn::{synthesize, Config, Mode, Output, SynthMethod};
use texsyn_engine::lbg::default_seeds;
use texsyn_engine::{Engine, Hit, QueryBatch};

fn texture(name: &str) -> ColorImage {
    imaging::load_color(&assets().join(name)).unwrap()
}

fn cfg() -> Config {
    Config {
        block: 3,
        neighbourhood: 7,
        levels: 2,
        batch: 8,
        seed: 5,
        ..Config::default()
    }
}

fn mode() -> Mode {
    Mode::Synth {
        width: 72,
        height: 64,
        method: SynthMethod::Grow,
    }
}

fn run(backend: &mut dyn SearchBackend, threads: usize) -> Result<Output> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    let sample = texture("brick_gray_64.png");
    pool.install(|| synthesize(&sample, &mode(), &cfg(), backend, &Silent))
}

fn lbg_plan(probes: usize, threads: usize) -> Output {
    let lbg = LbgSearch::new(Engine::default(), probes, 0.05, cfg().seed).unwrap();
    let mut b = PlannedSearch::new(
        "local,lbg".parse().unwrap(),
        LocalSearch::new(Engine::default()),
    )
    .with_lbg(Box::new(lbg));
    run(&mut b, threads).unwrap()
}

/// LBG that probes every partition of each level (P = seeds of that level).
struct AllProbes {
    inner: Option<LbgSearch>,
}

impl SearchBackend for AllProbes {
    fn name(&self) -> String {
        "lbg(all)".into()
    }
    fn load_level(&mut self, level: &LevelData) -> Result<()> {
        let p = default_seeds(level.positions.len());
        let mut l = LbgSearch::new(Engine::default(), p, 0.05, 9)?;
        l.load_level(level)?;
        self.inner = Some(l);
        Ok(())
    }
    fn search(&mut self, q: &QueryBatch) -> Result<Vec<Hit>> {
        self.inner.as_mut().unwrap().search(q)
    }
}

#[test]
fn all_probes_synthesise_exactly_like_exhaustive() {
    let exact = run(&mut LocalSearch::new(Engine::default()), 2).unwrap();
    let lbg = run(&mut AllProbes { inner: None }, 2).unwrap();
    assert_eq!(lbg.image, exact.image);
    assert_eq!(lbg.copy_map, exact.copy_map);
}

#[test]
fn lbg_runs_are_deterministic_across_threads() {
    let a = lbg_plan(1, 1);
    for threads in [2, 4] {
        let b = lbg_plan(1, threads);
        assert_eq!(a.image, b.image, "{threads} threads");
        assert_eq!(a.copy_map, b.copy_map, "{threads} threads");
    }
    let c = lbg_plan(2, 2);
    assert_eq!(c.image, lbg_plan(2, 1).image);
}

#[test]
fn report_records_plan_and_codebooks() {
    let out = lbg_plan(2, 2);
    let s = &out.report.search_stats;
    let plan: Vec<&str> = s["plan"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["strategy"].as_str().unwrap())
        .collect();
    assert_eq!(plan, vec!["local", "lbg"]);
    let levels = s["lbg"]["levels"].as_array().unwrap();
    assert_eq!(levels.len(), 1);
    let l = &levels[0];
    assert_eq!(l["level"], 0);
    assert_eq!(l["probes"], 2);
    let n = l["vectors"].as_u64().unwrap() as usize;
    assert_eq!(n, out.report.per_level[1].reference_vectors);
    assert_eq!(
        l["seeds_requested"].as_u64().unwrap() as usize,
        default_seeds(n)
    );
    assert!(l["seeds"].as_u64().unwrap() >= 1);
    assert!(l["iterations"].as_u64().unwrap() >= 1);
    assert!(l["train_seconds"].as_f64().unwrap() > 0.0);
    assert_eq!(
        l["queries"].as_u64().unwrap(),
        out.report.per_level[1].queries
    );
}

#[test]
fn bad_lbg_parameters_are_errors() {
    let e = Engine::default();
    assert!(LbgSearch::new(e, 0, 0.05, 1).is_err());
    for t in [0.0, 1.0, -1.0, 2.0, f64::NAN] {
        let err = LbgSearch::new(e, 1, t, 1).err().expect("bad threshold");
        assert!(format!("{err:#}").contains("threshold"), "{err:#}");
    }
    assert!(LbgSearch::new(e, 1, 0.05, 1)
        .unwrap()
        .with_max_iterations(0)
        .is_err());
    let l = LbgSearch::new(e, 65, 0.05, 1).unwrap();
    assert!(l.check_vectors(64 * 64).is_err(), "65 probes > √4096 seeds");
    assert!(l.check_vectors(65 * 65).is_ok());
    // Probes above the seeds of the level being loaded: a clear error, no panic.
    let lbg = LbgSearch::new(e, 60, 0.05, 1).unwrap();
    let mut b = PlannedSearch::new("local,lbg".parse().unwrap(), LocalSearch::new(e))
        .with_lbg(Box::new(lbg));
    let err = run(&mut b, 2).err().expect("too many probes");
    let msg = format!("{err:#}");
    assert!(msg.contains("probes") && msg.contains("60"), "{msg}");
    // A plan of the wrong length, and LBG without a backend.
    let b = PlannedSearch::new("local,local,lbg".parse().unwrap(), LocalSearch::new(e))
        .with_lbg(Box::new(LbgSearch::new(e, 1, 0.05, 1).unwrap()));
    assert!(b.check_levels(2).is_err());
    assert!(b.check_levels(3).is_ok());
    let b = PlannedSearch::new(Plan::Levels(vec![]), LocalSearch::new(e));
    assert!(b.check_levels(2).is_err());
    assert!(
        PlannedSearch::new("local,lbg".parse().unwrap(), LocalSearch::new(e))
            .check_levels(2)
            .is_err()
    );
    assert!("local,fast".parse::<Plan>().is_err());
}

#[test]
fn cli_lbg_flags() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.png");
    let report = dir.path().join("run.json");
    let sample = assets().join("brick_gray_64.png");
    let base = [
        "synth",
        s(&sample),
        "-o",
        s(&out),
        "--size",
        "80x80",
        "--block",
        "3",
        "--neighbourhood",
        "7",
        "--levels",
        "2",
        "-q",
    ];
    let bad: [(&[&str], &[&str]); 6] = [
        (&["--lbg-probes", "0"], &["probes"]),
        (&["--lbg-probes", "65"], &["probes", "65"]),
        (&["--lbg-threshold", "0"], &["threshold"]),
        (&["--lbg-threshold", "1"], &["threshold"]),
        (&["--lbg-threshold=-0.5"], &["threshold"]),
        (&["--search", "local,local,lbg"], &["plan", "level"]),
    ];
    for (extra, words) in bad {
        let mut args = base.to_vec();
        args.extend_from_slice(extra);
        let o = texsyn(&args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{err}");
        let line = err.lines().find(|l| l.contains("error")).unwrap_or("");
        for w in words {
            assert!(
                line.to_lowercase().contains(w),
                "{args:?}: '{line}' lacks {w}"
            );
        }
        assert!(!out.exists());
    }
    let mut args = base.to_vec();
    args.extend_from_slice(&[
        "--search",
        "local,lbg",
        "--lbg-probes",
        "3",
        "--lbg-threshold",
        "0.1",
        "--report",
        s(&report),
    ]);
    let o = texsyn(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    let lbg = &r["search_stats"]["lbg"];
    assert_eq!(lbg["probes"], 3);
    assert_eq!(lbg["threshold"], 0.1);
    assert_eq!(lbg["levels"][0]["level"], 0);
    let train = lbg["levels"][0]["train_seconds"].as_f64().unwrap();
    assert!(train > 0.0 && train.is_finite(), "training took {train} s");
}
