//! Procedural texture matching (Bourque–Dudek §3.2): a global search over
//! the catalogue, then the local search from the best starting points.
//!
//! - Global search (§3.2.1): the target's structure descriptor against every
//!   catalogue sample. Shaders whose best sample is far worse than the best
//!   shader's (a large disparity) are dropped; each remaining shader's best
//!   few samples are the starting points, in order of admissibility.
//! - Local search (§3.2.2, [`super::local`]): one simplex run from every
//!   start (the screening), then sweeps, simplex runs and the whole-number
//!   search from the best few (the finalists).

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use anyhow::{bail, ensure, Context, Result};
use rayon::prelude::*;
use serde::Serialize;
use serde_json::{json, Value};

use super::catalogue::{describe, selected, unit_distance, Catalogue};
use super::local::{refine, refine_with_integers, Effort};
use super::objective::{Eval, Target};
use super::pattern::{round, Pattern};
use super::periodicity::{seeded, Periodicity};
use super::shaders::{Kind, Shader};
use crate::imaging::ColorImage;

/// How hard to search.
#[derive(Clone, Debug)]
pub struct MatchSettings {
    /// Starting points per shader (its best catalogue samples).
    pub starts: usize,
    /// Most simplex iterations per start (half for each whole-number step).
    pub max_iters: u64,
    /// Only these shaders (default: every shader of the catalogue).
    pub shaders: Option<Vec<String>>,
    /// A shader is dropped when its best catalogue distance exceeds the best
    /// shader's by more than this.
    pub disparity: f64,
    /// Starting points that go on to the sweeps and the whole-number search:
    /// the best after their first simplex run (one per shader when several
    /// shaders are searched).
    pub finalists: usize,
    /// Shaders kept for the local search when several are searched: the
    /// best by catalogue distance plus structure term.
    pub families: usize,
}

impl Default for MatchSettings {
    fn default() -> Self {
        Self {
            starts: 3,
            max_iters: 80,
            shaders: None,
            disparity: 0.1,
            finalists: 3,
            families: 3,
        }
    }
}

impl MatchSettings {
    pub fn validate(&self) -> Result<()> {
        ensure!(
            (1..=20).contains(&self.starts),
            "--starts {} must be in 1..=20",
            self.starts
        );
        ensure!(
            (1..=10_000).contains(&self.max_iters),
            "--iterations {} must be in 1..=10000",
            self.max_iters
        );
        ensure!(
            (1..=100).contains(&self.finalists),
            "--finalists {} must be in 1..=100",
            self.finalists
        );
        ensure!(
            (1..=100).contains(&self.families),
            "--families {} must be in 1..=100",
            self.families
        );
        ensure!(
            self.disparity >= 0.0,
            "--disparity {} must be ≥ 0",
            self.disparity
        );
        selected(self.shaders.as_deref())?;
        Ok(())
    }
}

/// One starting point and where its local search ended.
#[derive(Clone, Debug, Serialize)]
pub struct Candidate {
    pub shader: String,
    /// Global-search distance of the starting sample (structure, 0..1).
    pub catalogue_distance: f64,
    pub admissibility: f64,
    /// Whether the start was placed by the target's periods.
    pub seeded: bool,
    /// The structure term of the start's shader against the target
    /// (periods per direction; 0 alike).
    pub structure: f64,
    /// The objective after the first simplex run (the screening).
    pub screened: f64,
    /// The objective after the sweeps and the whole-number search, for the
    /// finalists only.
    pub objective: Option<f64>,
    pub iterations: u64,
}

/// The result of matching a target.
#[derive(Clone, Debug)]
pub struct MatchResult {
    pub pattern: Pattern,
    pub s_f: f64,
    pub s_l: f64,
    pub colour: f64,
    pub objective: f64,
    /// Simplex iterations of the winning start (with its whole-number steps).
    pub iterations: u64,
    /// Renders of the whole search.
    pub evaluations: u64,
    pub seconds: f64,
    /// Every start, in the order of admissibility.
    pub candidates: Vec<Candidate>,
}

impl MatchResult {
    /// One line: the shader, the measures, time, iterations and renders.
    pub fn summary(&self) -> String {
        format!(
            "matched {} (S_F {:.3}, S_L {:.3}, colour {:.3}) in {:.1} s, {} iterations, {} renders",
            self.pattern.shader.name,
            self.s_f,
            self.s_l,
            self.colour,
            self.seconds,
            self.iterations,
            self.evaluations
        )
    }

    /// The `--params` JSON.
    pub fn to_json(&self) -> Value {
        let mut v = self.pattern.to_json();
        let o = v.as_object_mut().expect("an object");
        o.insert("s_f".into(), json!(round(self.s_f, 5)));
        o.insert("s_l".into(), json!(round(self.s_l, 5)));
        o.insert("colour".into(), json!(round(self.colour, 5)));
        o.insert("objective".into(), json!(round(self.objective, 5)));
        o.insert("iterations".into(), json!(self.iterations));
        o.insert("evaluations".into(), json!(self.evaluations));
        o.insert("seconds".into(), json!(round(self.seconds, 3)));
        o.insert(
            "candidates".into(),
            serde_json::to_value(&self.candidates).unwrap_or(Value::Null),
        );
        v
    }
}

/// A starting point of the local search.
struct Start {
    shader: &'static Shader,
    params: Vec<f64>,
    distance: f64,
    admissibility: f64,
    seeded: bool,
    /// The structure term of the shader's first start.
    structure: f64,
}

/// Weight of the structure term where shaders are ranked against each
/// other (the objectives are about 1 to 2, the term 0 to 1).
pub(super) const STRUCTURE_WEIGHT: f64 = 1.0;

/// Weight of the pieces' separation difference in the structure term of an
/// isotropic target or of stones (the separations differ by 0 to 1).
const SEPARATION_WEIGHT: f64 = 1.0;

/// The structure term of `params` of `sh` against the target: how
/// differently they repeat ([`Periodicity::distance`]) and, where the
/// pieces tell the family ([`super::arrangement::Analysis::pieces_tell`]),
/// how differently their tones break into pieces ([`super::pieces`]):
/// noise and scattered features repeat alike and differ there, and so do
/// stones and the veins drawn out along their direction.
pub(super) fn structure_term(sh: &Shader, params: &[f64], target: &Target) -> f64 {
    let n = target.periodicity.size;
    let field = sh.render_field(params, n, n, n);
    let render = Periodicity::of_field(&field, n);
    let mut t = target.periodicity.distance(&render);
    if target.arrangement.pieces_tell(&target.periodicity) {
        t += SEPARATION_WEIGHT
            * (target.periodicity.pieces.separation - render.pieces.separation).abs();
    }
    t
}

/// The global search: starting points per shader, in admissibility order.
fn starting_points(cat: &Catalogue, target: &Target, s: &MatchSettings) -> Result<Vec<Start>> {
    let shaders = selected(s.shaders.as_deref())?;
    tracing::debug!(periods = ?target.periodicity, arrangement = ?target.arrangement, "target structure");
    let mut per_shader = Vec::new();
    for sh in shaders {
        let Some(samples) = cat.of(sh.name) else {
            if s.shaders.is_some() {
                bail!(
                    "the catalogue has no shader '{}'; rebuild it with that shader",
                    sh.name
                );
            }
            continue;
        };
        let mut scored: Vec<(f64, usize)> = samples
            .samples
            .par_iter()
            .enumerate()
            .map(|(i, x)| (target.structure.distance(&x.structure), i))
            .collect();
        scored.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let mut chosen: Vec<Start> = Vec::new();
        for &(d, i) in &scored {
            if chosen.len() == s.starts {
                break;
            }
            let x = &samples.samples[i];
            // A start is new when it differs in a whole number or lies apart.
            let new = chosen.iter().all(|c| {
                unit_distance(sh, &c.params, &x.params) > 0.15
                    || differs_in_integer(sh, &c.params, &x.params)
            });
            if new {
                chosen.push(Start {
                    shader: sh,
                    params: x.params.clone(),
                    distance: d,
                    admissibility: x.admissibility,
                    seeded: false,
                    structure: 0.0,
                });
            }
        }
        // The start placed by the target's periods (the best sample with
        // its counts and angle read from them), first.
        if let Some((base, adm)) = chosen.first().map(|c| (c.params.clone(), c.admissibility)) {
            if let Some(p) = seeded(sh, &base, &target.periodicity) {
                if chosen.iter().all(|c| c.params != p) {
                    let d = describe(sh, &p, cat.size).distance(&target.structure);
                    chosen.insert(
                        0,
                        Start {
                            shader: sh,
                            params: p,
                            distance: d,
                            admissibility: adm,
                            seeded: true,
                            structure: 0.0,
                        },
                    );
                    chosen.truncate(s.starts + 1);
                }
            }
        }
        if let Some(first) = chosen.first() {
            let t = structure_term(sh, &first.params, target);
            let d = chosen
                .iter()
                .map(|c| c.distance)
                .fold(f64::INFINITY, f64::min);
            tracing::debug!(
                shader = sh.name,
                distance = d,
                structure = t,
                first = ?first.params,
                seeded = first.seeded,
                "shader ranked"
            );
            for c in &mut chosen {
                c.structure = t;
            }
            per_shader.push((d + STRUCTURE_WEIGHT * t, chosen));
        }
    }
    ensure!(
        !per_shader.is_empty(),
        "the catalogue has none of the selected shaders; rebuild it"
    );
    // Structure first: only the shaders that show the target's
    // arrangement, and for stones the isotropic ones too, the scattered
    // shaders among them (all when none of the selected does).
    let admits = |sh: &Shader| target.arrangement.admits(&target.periodicity, sh.shows);
    if per_shader.iter().any(|(_, c)| admits(c[0].shader)) {
        per_shader.retain(|(_, c)| admits(c[0].shader));
    }
    // Families ranked by catalogue distance plus the structure term; the
    // best few within the disparity go on.
    per_shader.sort_by(|a, b| a.0.total_cmp(&b.0));
    let best = per_shader[0].0;
    let mut starts: Vec<Start> = per_shader
        .into_iter()
        .take(s.families)
        .filter(|(d, _)| *d <= best + s.disparity)
        .flat_map(|(_, c)| c)
        .collect();
    starts.sort_by(|a, b| {
        b.seeded
            .cmp(&a.seeded)
            .then(b.admissibility.total_cmp(&a.admissibility))
    });
    Ok(starts)
}

fn differs_in_integer(sh: &Shader, a: &[f64], b: &[f64]) -> bool {
    sh.params
        .iter()
        .zip(a.iter().zip(b))
        .any(|(p, (x, y))| p.kind == Kind::Integer && x != y)
}

/// Matches `target` against the catalogue: the best shader, parameters and
/// colours. The same result for any thread count.
pub fn match_texture(
    target: &ColorImage,
    cat: &Catalogue,
    settings: &MatchSettings,
) -> Result<MatchResult> {
    settings.validate()?;
    let t = Instant::now();
    let target = Target::new(target, cat.size)?;
    match_prepared(&target, cat, settings, t)
}

/// [`match_texture`] of a target already described; `started` is when the
/// match began (for the reported seconds).
pub(super) fn match_prepared(
    target: &Target,
    cat: &Catalogue,
    settings: &MatchSettings,
    started: Instant,
) -> Result<MatchResult> {
    let starts = starting_points(cat, target, settings)?;
    let evals = AtomicU64::new(0);
    // Several shaders selected: the search's effort goes to choosing the
    // shader, whose counts and angles come seeded from the target's
    // structure (even where the arrangement leaves one to try).
    let several = selected(settings.shaders.as_deref())?.len() > 1;
    let (screen_iters, effort) = if several {
        (settings.max_iters.div_ceil(2), Effort::LIGHT)
    } else {
        (settings.max_iters, Effort::FULL)
    };
    // Screening: one simplex run from every start.
    let screened: Vec<(Eval, u64)> = starts
        .par_iter()
        .map(|s| refine(s.shader, &s.params, screen_iters, target, &evals))
        .collect::<Result<_>>()?;
    let mut order: Vec<usize> = (0..starts.len()).collect();
    order.sort_by(|&a, &b| {
        screened[a]
            .0
            .objective
            .total_cmp(&screened[b].0.objective)
            .then(a.cmp(&b))
    });
    // Several shaders: the finalists are the best start of each of the
    // best shaders, so one shader's starts cannot crowd out the others.
    if several {
        let mut seen: Vec<&str> = Vec::new();
        order.retain(|&k| {
            let name = starts[k].shader.name;
            let new = !seen.contains(&name);
            seen.push(name);
            new
        });
    }
    order.truncate(settings.finalists);
    tracing::debug!(
        renders = evals.load(Ordering::Relaxed),
        seconds = started.elapsed().as_secs_f64(),
        "screened"
    );
    // The finalists: sweeps, simplex runs and the whole-number search.
    let finals: Vec<(usize, Eval, u64)> = order
        .par_iter()
        .map(|&k| {
            let (e, n) = refine_with_integers(
                starts[k].shader,
                &screened[k].0.params,
                settings.max_iters,
                effort,
                target,
                &evals,
            )?;
            tracing::debug!(
                shader = starts[k].shader.name,
                renders = evals.load(Ordering::Relaxed),
                seconds = started.elapsed().as_secs_f64(),
                "finalist done"
            );
            Ok((k, e, n + screened[k].1))
        })
        .collect::<Result<_>>()?;
    let mut candidates: Vec<Candidate> = starts
        .iter()
        .zip(&screened)
        .map(|(s, (e, n))| Candidate {
            shader: s.shader.name.to_string(),
            catalogue_distance: round(s.distance, 5),
            admissibility: round(s.admissibility, 3),
            seeded: s.seeded,
            structure: round(s.structure, 4),
            screened: round(e.objective, 5),
            objective: None,
            iterations: *n,
        })
        .collect();
    // Across shaders the structure term counts too (§3.3): a grid's lines
    // where the target has none cost it the match.
    let mut best: Option<(f64, usize, Eval, u64)> = None;
    for (k, e, iters) in finals {
        candidates[k].objective = Some(round(e.objective, 5));
        candidates[k].iterations = iters;
        let rank = if several {
            e.objective + STRUCTURE_WEIGHT * structure_term(starts[k].shader, &e.params, target)
        } else {
            e.objective
        };
        tracing::debug!(
            shader = starts[k].shader.name,
            objective = e.objective,
            rank,
            iters,
            "finalist refined"
        );
        if best.as_ref().is_none_or(|b| rank < b.0) {
            best = Some((rank, k, e, iters));
        }
    }
    let (_, k, e, iterations) = best.context("no starting point")?;
    Ok(MatchResult {
        pattern: Pattern {
            shader: starts[k].shader,
            params: e.params,
            colours: e.colours,
        },
        s_f: e.s_f,
        s_l: e.s_l,
        colour: e.colour,
        objective: e.objective,
        iterations,
        evaluations: evals.load(Ordering::Relaxed),
        seconds: started.elapsed().as_secs_f64(),
        candidates,
    })
}
