//! LBG-accelerated search on this machine (Stahlhut §8, ARCHITECTURE §3.8): per level
//! a codebook of about √N seeds is trained over the level's reference vectors,
//! and a query searches exactly only the partitions of its `P` nearest seeds.
//! Approximate; the run report records per level the codebook's training
//! time, seeds, iterations and the probes used.

use std::time::Instant;

use anyhow::{ensure, Context, Result};
use texsyn_engine::lbg::{check_probes, check_threshold, default_seeds, DEFAULT_MAX_ITERATIONS};
use texsyn_engine::{Codebook, Engine, Hit, LbgConfig, LbgStats, QueryBatch};

use crate::search::{LevelData, SearchBackend};

/// Default number of partitions searched per query.
pub const DEFAULT_PROBES: usize = 1;

/// What LBG did on one level, for the run report: the engine's training
/// figures plus the level, the probes and the search counters.
#[derive(Debug, Clone, serde::Serialize)]
pub struct LbgLevelReport {
    pub level: usize,
    pub probes: usize,
    /// Building the level's reference vectors before training.
    pub build_seconds: f64,
    pub queries: u64,
    pub search_seconds: f64,
    #[serde(flatten)]
    pub training: LbgStats,
}

/// LBG search with the engine, in-process.
pub struct LbgSearch {
    engine: Engine,
    probes: usize,
    config: LbgConfig,
    codebook: Option<Codebook>,
    reports: Vec<LbgLevelReport>,
}

/// The seed of a level's codebook: the run's seed mixed with the level, so
/// every level draws its own seeds and the result depends on nothing else.
pub fn level_seed(seed: u64, level: usize) -> u64 {
    seed ^ (level as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15)
}

impl LbgSearch {
    /// `probes` ≥ 1 partitions per query, `threshold` in (0, 1), `seed` = the run's seed.
    pub fn new(engine: Engine, probes: usize, threshold: f64, seed: u64) -> Result<Self> {
        ensure!(
            probes >= 1,
            "--lbg-probes {probes} must be at least 1 (1 = only the nearest seed's partition)"
        );
        check_threshold(threshold).context("--lbg-threshold")?;
        Ok(Self {
            engine,
            probes,
            config: LbgConfig {
                seeds: 0,
                threshold,
                max_iterations: DEFAULT_MAX_ITERATIONS,
                seed,
                ..LbgConfig::default()
            },
            codebook: None,
            reports: Vec::new(),
        })
    }

    /// Caps the assign/move iterations per level (1..=10000).
    pub fn with_max_iterations(mut self, n: usize) -> Result<Self> {
        self.config.max_iterations = n;
        self.config.validate()?;
        Ok(self)
    }

    /// Training vectors per seed (0 = train on every vector).
    pub fn with_sample_per_seed(mut self, n: usize) -> Self {
        self.config.sample_per_seed = n;
        self
    }

    pub fn probes(&self) -> usize {
        self.probes
    }

    /// Errors unless a level of `vectors` reference vectors can be searched
    /// with the configured probes (its codebook has ⌈√vectors⌉ seeds).
    pub fn check_vectors(&self, vectors: usize) -> Result<()> {
        check_probes(self.probes, default_seeds(vectors)).with_context(|| {
            format!(
                "--lbg-probes {} is more than the ⌈√{vectors}⌉ = {} LBG seeds of a level with {vectors} reference vectors",
                self.probes,
                default_seeds(vectors)
            )
        })?;
        Ok(())
    }

    /// The current level's codebook.
    pub fn codebook(&self) -> Option<&Codebook> {
        self.codebook.as_ref()
    }

    /// Per-level reports so far.
    pub fn reports(&self) -> &[LbgLevelReport] {
        &self.reports
    }
}

impl SearchBackend for LbgSearch {
    fn name(&self) -> String {
        format!("lbg({},P={})", self.engine.kernel().name(), self.probes)
    }

    fn load_level(&mut self, level: &LevelData) -> Result<()> {
        self.codebook = None;
        let n = level.positions.len();
        self.check_vectors(n)
            .with_context(|| format!("level {}", level.level))?;
        let t = Instant::now();
        let space = crate::search::level_space(level, texsyn_engine::Storage::Dense)?;
        let build_seconds = t.elapsed().as_secs_f64();
        let cfg = LbgConfig {
            seed: level_seed(self.config.seed, level.level),
            ..self.config
        };
        let cb = Codebook::train(&self.engine, &space, 0..n as u64, &level.params, &cfg)
            .with_context(|| format!("LBG training of level {}", level.level))?;
        drop(space);
        let s = cb.stats();
        tracing::info!(
            level = level.level,
            seeds = s.seeds,
            iterations = s.iterations,
            seconds = s.train_seconds,
            "LBG codebook trained"
        );
        self.reports.push(LbgLevelReport {
            level: level.level,
            probes: self.probes,
            build_seconds,
            queries: 0,
            search_seconds: 0.0,
            training: s.clone(),
        });
        self.codebook = Some(cb);
        Ok(())
    }

    fn search(&mut self, queries: &QueryBatch) -> Result<Vec<Hit>> {
        let cb = self
            .codebook
            .as_ref()
            .context("LBG search before load_level")?;
        let t = Instant::now();
        let hits = cb.search(&self.engine, queries, self.probes)?;
        if let Some(r) = self.reports.last_mut() {
            r.queries += queries.len() as u64;
            r.search_seconds += t.elapsed().as_secs_f64();
        }
        Ok(hits)
    }

    fn end_level(&mut self) {
        self.codebook = None;
    }

    fn stats(&self) -> serde_json::Value {
        serde_json::json!({
            "probes": self.probes,
            "threshold": self.config.threshold,
            "max_iterations": self.config.max_iterations,
            "levels": self.reports,
        })
    }
}
