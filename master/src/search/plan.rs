//! The search plan: which backend searches each pyramid level (Stahlhut §8,
//! ARCHITECTURE §3.8).

use anyhow::{bail, ensure, Result};
use texsyn_engine::{Hit, QueryBatch};

use super::{LevelData, LocalSearch, SearchBackend};

/// How one pyramid level is searched (Stahlhut §8: the user picks per level).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Strategy {
    /// Exhaustive on this machine.
    Local,
    /// Exhaustive on the cluster of workers.
    Cluster,
    /// LBG vector quantisation (approximate).
    Lbg,
    /// LBG on the cluster: each worker quantises its own range.
    #[serde(rename = "cluster-lbg")]
    ClusterLbg,
}

impl std::str::FromStr for Strategy {
    type Err = anyhow::Error;
    fn from_str(s: &str) -> Result<Self> {
        Ok(match s.trim().to_ascii_lowercase().as_str() {
            "local" | "exhaustive" | "smp" => Strategy::Local,
            "cluster" => Strategy::Cluster,
            "lbg" => Strategy::Lbg,
            "cluster-lbg" => Strategy::ClusterLbg,
            other => {
                bail!("unknown search strategy '{other}'; use local (exhaustive), cluster, lbg or cluster-lbg")
            }
        })
    }
}

/// The search plan of a run: one strategy per level, or automatic.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Plan {
    /// Strategies coarsest level first, as the user writes them.
    Levels(Vec<Strategy>),
    /// Exhaustive on every level: on the cluster for the large levels when one
    /// is attached, else on this machine. The default: exact answers.
    Exact,
    /// Picked per level from the estimated cost; LBG (approximate) for levels
    /// above the budget.
    Auto,
}

impl std::str::FromStr for Plan {
    type Err = anyhow::Error;
    fn from_str(s: &str) -> Result<Self> {
        if s.trim().eq_ignore_ascii_case("auto") {
            return Ok(Plan::Auto);
        }
        if s.trim().eq_ignore_ascii_case("exact") {
            return Ok(Plan::Exact);
        }
        let v = s
            .split(',')
            .map(str::parse)
            .collect::<Result<Vec<Strategy>>>()?;
        ensure!(
            !v.is_empty(),
            "empty search plan; use e.g. --search local,local,lbg or auto"
        );
        Ok(Plan::Levels(v))
    }
}

/// Work of a level in vector bytes compared: references × queries × stride.
pub fn level_cost(level: &LevelData) -> f64 {
    level.positions.len() as f64
        * level.expected_queries as f64
        * level.geometry.layout().stride() as f64
}

/// A backend that follows a [`Plan`], handing each level to the local engine,
/// the cluster or LBG. The synthesis sees one [`SearchBackend`].
pub struct PlannedSearch {
    plan: Plan,
    local: LocalSearch,
    cluster: Option<Box<dyn SearchBackend>>,
    lbg: Option<Box<dyn SearchBackend>>,
    current: Strategy,
    /// Strategy used per level, in processing order.
    used: Vec<(usize, Strategy)>,
    /// Budget of `auto`: levels cheaper than this many compared bytes stay exhaustive.
    pub auto_budget: f64,
    /// Probes of `cluster-lbg` levels.
    pub lbg_probes: u32,
}

impl PlannedSearch {
    pub fn new(plan: Plan, local: LocalSearch) -> Self {
        Self {
            plan,
            local,
            cluster: None,
            lbg: None,
            current: Strategy::Local,
            used: Vec::new(),
            lbg_probes: 1,
            auto_budget: 2e11,
        }
    }

    pub fn with_cluster(mut self, cluster: Box<dyn SearchBackend>) -> Self {
        self.cluster = Some(cluster);
        self
    }

    pub fn with_lbg(mut self, lbg: Box<dyn SearchBackend>) -> Self {
        self.lbg = Some(lbg);
        self
    }

    /// Checks the plan against the run's level count before any work.
    pub fn check_levels(&self, levels: usize) -> Result<()> {
        if let Plan::Levels(v) = &self.plan {
            ensure!(
                v.len() == levels,
                "the search plan names {} level(s) but the run has {levels}; give one strategy per level, coarsest first (or --search auto)",
                v.len()
            );
            for s in v {
                match s {
                    Strategy::Cluster | Strategy::ClusterLbg if self.cluster.is_none() => {
                        bail!("the search plan uses 'cluster' but no workers were given; add --workers, --hosts or --local-workers")
                    }
                    Strategy::Lbg if self.lbg.is_none() => {
                        bail!("the search plan uses 'lbg' but LBG is not available")
                    }
                    _ => {}
                }
            }
        }
        Ok(())
    }

    fn choose(&self, level: &LevelData) -> Strategy {
        match &self.plan {
            Plan::Levels(v) => v[level.levels - 1 - level.level],
            Plan::Exact => {
                let big = level_cost(level) > self.auto_budget;
                if self.cluster.is_some() && (big || level.level == 0) {
                    Strategy::Cluster
                } else {
                    Strategy::Local
                }
            }
            Plan::Auto => {
                let big = level_cost(level) > self.auto_budget;
                if self.cluster.is_some() && (big || level.level == 0) {
                    Strategy::Cluster
                } else if big && self.lbg.is_some() {
                    Strategy::Lbg
                } else {
                    Strategy::Local
                }
            }
        }
    }

    fn backend(&mut self) -> &mut dyn SearchBackend {
        match self.current {
            Strategy::Cluster | Strategy::ClusterLbg => self
                .cluster
                .as_deref_mut()
                .expect("checked by check_levels"),
            Strategy::Lbg => self.lbg.as_deref_mut().expect("checked by check_levels"),
            Strategy::Local => &mut self.local,
        }
    }

    /// Strategy per level in processing order (coarsest first).
    pub fn used(&self) -> &[(usize, Strategy)] {
        &self.used
    }
}

impl SearchBackend for PlannedSearch {
    fn name(&self) -> String {
        let mut parts = vec![self.local.name()];
        if let Some(c) = &self.cluster {
            parts.push(c.name());
        }
        if let Some(l) = &self.lbg {
            parts.push(l.name());
        }
        parts.join("+")
    }

    fn load_level(&mut self, level: &LevelData) -> Result<()> {
        self.check_levels(level.levels)?;
        self.current = self.choose(level);
        self.used.push((level.level, self.current));
        if let Some(c) = self.cluster.as_deref_mut() {
            let probes = if self.current == Strategy::ClusterLbg {
                self.lbg_probes.max(1)
            } else {
                0
            };
            c.set_lbg_probes(probes)?;
        }
        tracing::info!(level = level.level, strategy = ?self.current, "search strategy");
        self.backend().load_level(level)
    }

    fn search(&mut self, queries: &QueryBatch) -> Result<Vec<Hit>> {
        self.backend().search(queries)
    }

    fn search_topk(&mut self, queries: &QueryBatch, k: usize) -> Result<Vec<Vec<Hit>>> {
        self.backend().search_topk(queries, k)
    }

    /// LBG levels are approximate and have no near-ties: their best match only.
    fn search_near_ties(
        &mut self,
        queries: &QueryBatch,
        k: usize,
        slack: &[texsyn_engine::Slack],
    ) -> Result<Vec<Vec<Hit>>> {
        match self.current {
            Strategy::Lbg | Strategy::ClusterLbg => Ok(self
                .backend()
                .search(queries)?
                .into_iter()
                .map(|h| vec![h])
                .collect()),
            Strategy::Local | Strategy::Cluster => {
                self.backend().search_near_ties(queries, k, slack)
            }
        }
    }

    fn end_level(&mut self) {
        self.backend().end_level();
    }

    fn level_prune(&self) -> Option<texsyn_engine::PruneStats> {
        match self.current {
            Strategy::Cluster | Strategy::ClusterLbg => self.cluster.as_deref()?.level_prune(),
            Strategy::Lbg => self.lbg.as_deref()?.level_prune(),
            Strategy::Local => self.local.level_prune(),
        }
    }

    fn stats(&self) -> serde_json::Value {
        serde_json::json!({
            "plan": self.used.iter().map(|(l, s)| serde_json::json!({"level": l, "strategy": s})).collect::<Vec<_>>(),
            "cluster": self.cluster.as_ref().map(|c| c.stats()),
            "lbg": self.lbg.as_ref().map(|c| c.stats()),
        })
    }
}
