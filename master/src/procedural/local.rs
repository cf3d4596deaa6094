//! The local search (Bourque–Dudek §3.2.2): Nelder–Mead (argmin) over the
//! continuous parameters on the unit box, coordinate sweeps across the
//! basins of periodic parameters, and whole-number parameters stepped with
//! a shorter simplex run each, as long as they help.

use std::sync::atomic::{AtomicU64, Ordering};

use anyhow::{Context, Result};
use argmin::core::{CostFunction, Executor, State};
use argmin::solver::neldermead::NelderMead;
use rayon::prelude::*;

use super::objective::{evaluate, Eval, Problem, Target};
use super::search::{structure_term, STRUCTURE_WEIGHT};
use super::shaders::{Kind, Layout, Shader};

/// Nelder–Mead (argmin) on `problem` from the unit-box point `x0`: the
/// first simplex steps `step` along each axis (inwards at the upper edge);
/// it stops at `tolerance` or after `iters` iterations. Gives the problem
/// back with the best point and the iterations run.
pub(super) fn simplex<P>(
    problem: P,
    x0: &[f64],
    step: f64,
    tolerance: f64,
    iters: u64,
) -> Result<(P, Vec<f64>, u64)>
where
    P: CostFunction<Param = Vec<f64>, Output = f64>,
{
    let mut vertices = vec![x0.to_vec()];
    for d in 0..x0.len() {
        let mut v = x0.to_vec();
        v[d] += if v[d] + step > 1.0 { -step } else { step };
        vertices.push(v);
    }
    let solver = NelderMead::new(vertices)
        .with_sd_tolerance(tolerance)
        .map_err(|e| anyhow::anyhow!("simplex setup: {e}"))?;
    let res = Executor::new(problem, solver)
        .configure(|s| s.max_iters(iters))
        .run()
        .map_err(|e| anyhow::anyhow!("simplex search: {e}"))?;
    let n = res.state().get_iter();
    let best = res
        .state()
        .get_best_param()
        .cloned()
        .unwrap_or_else(|| x0.to_vec());
    let problem = res
        .problem
        .problem
        .context("the simplex lost its problem")?;
    Ok((problem, best, n))
}

/// Nelder–Mead from `start` over the continuous parameters, then one
/// restart with a small simplex round the best point: a collapsed simplex
/// often stops short of the minimum.
pub(super) fn refine(
    shader: &'static Shader,
    start: &[f64],
    max_iters: u64,
    target: &Target,
    evals: &AtomicU64,
) -> Result<(Eval, u64)> {
    let problem = Problem {
        shader,
        base: shader.legal(start),
        free: shader.continuous(),
        target,
        evals,
    };
    if problem.free.is_empty() {
        return Ok((problem.evaluate(&problem.base), 0));
    }
    let x0 = shader.to_unit_box(&problem.base, &problem.free);
    let (problem, best, first) = simplex(problem, &x0, 0.1, 1e-6, max_iters)?;
    let (problem, best, second) = simplex(problem, &best, 0.02, 1e-7, max_iters.div_ceil(2))?;
    let params = problem.params(&best);
    Ok((problem.evaluate(&params), first + second))
}

/// How hard the finalists are refined.
#[derive(Clone, Copy, Debug)]
pub(super) struct Effort {
    /// Values per parameter in a [`sweep`].
    pub sweep: usize,
    /// Rounds of the whole-number search.
    pub integer_rounds: usize,
    /// New whole-number values swept and refined per parameter and round.
    pub alternatives: usize,
    /// When set, the shader's count (its layout's) only moves this share
    /// from where it is: it was read from the periods, and a harmonic may
    /// score better on the objective (at 15%, a count below 7 stays put).
    pub count_window: Option<f64>,
    /// When set, a scattered shader's count is tried at every value of its
    /// range, each refined by a simplex run of this many iterations before
    /// the values are compared: no period reads its features' spacing, and
    /// the other parameters (dots or walls, their width) settle differently
    /// per count, so a count compared with them kept looks best near where
    /// it already is.
    pub scatter_refine: Option<u64>,
    /// Whether a scattered count is ranked by the objective plus the
    /// structure term (as shaders are ranked against each other).
    pub scatter_structure: bool,
}

impl Effort {
    /// One shader searched (its parameters are all the search has).
    pub const FULL: Self = Self {
        sweep: 64,
        integer_rounds: 3,
        alternatives: 2,
        count_window: None,
        scatter_refine: None,
        scatter_structure: false,
    };
    /// Several shaders searched: counts and angles come seeded from the
    /// target's periods, so the sweeps are coarse and one new whole number
    /// is tried per parameter, once.
    pub const LIGHT: Self = Self {
        sweep: 16,
        integer_rounds: 1,
        alternatives: 1,
        count_window: Some(0.15),
        scatter_refine: Some(20),
        scatter_structure: true,
    };
}

/// A coordinate sweep: each continuous parameter in turn is set to
/// `values` spread over its whole range (the others kept), and the
/// best render is kept; repeated while a pass helps, at most twice. The
/// objective of a periodic pattern along a frequency, an angle or an aspect
/// is a comb of narrow basins, one per harmonic; a start in the wrong basin
/// is one the simplex cannot leave, and a sweep crosses them all.
fn sweep(
    shader: &'static Shader,
    from: Eval,
    values: usize,
    target: &Target,
    evals: &AtomicU64,
) -> Eval {
    let mut best = from;
    for _pass in 0..2 {
        let before = best.objective;
        for (i, spec) in shader.params.iter().enumerate() {
            if spec.kind == Kind::Integer {
                continue;
            }
            let tried: Vec<Eval> = (0..values)
                .into_par_iter()
                .map(|k| {
                    let t = match spec.kind {
                        Kind::Periodic => k as f64 / values as f64,
                        _ => k as f64 / (values.max(2) - 1) as f64,
                    };
                    let mut p = best.params.clone();
                    p[i] = spec.from_unit(t);
                    evals.fetch_add(1, Ordering::Relaxed);
                    evaluate(shader, &p, target)
                })
                .collect();
            if let Some(e) = tried
                .into_iter()
                .min_by(|a, b| a.objective.total_cmp(&b.objective))
                .filter(|e| e.objective < best.objective)
            {
                best = e;
            }
        }
        if best.objective >= before - 1e-9 {
            break;
        }
    }
    best
}

/// [`sweep`] and [`refine`] in turn from `start`, while a round helps (at
/// most three rounds): the simplex settles the coupled parameters, and a
/// sweep after it moves the ones whose objective is a staircase at pixel
/// scale (edge softness), where the simplex stalls.
fn sweep_and_refine(
    shader: &'static Shader,
    start: &[f64],
    max_iters: u64,
    effort: Effort,
    target: &Target,
    evals: &AtomicU64,
) -> Result<(Eval, u64)> {
    evals.fetch_add(1, Ordering::Relaxed);
    let mut best = evaluate(shader, &shader.legal(start), target);
    let mut iters = 0;
    for round in 0..3 {
        let before = best.objective;
        let swept = sweep(shader, best, effort.sweep, target, evals);
        if round > 0 && swept.objective >= before - 1e-6 {
            best = swept;
            break;
        }
        let (e, n) = refine(shader, &swept.params, max_iters, target, evals)?;
        iters += n;
        best = if e.objective <= swept.objective {
            e
        } else {
            swept
        };
    }
    Ok((best, iters))
}

/// [`sweep_and_refine`], then each whole-number parameter swept: every
/// value is rendered with the other parameters kept, and the best new
/// values (two at full effort) are swept and refined with a shorter simplex
/// run each; repeated while one helps. A scattered count (light effort) is
/// compared on equal terms instead: every value from the start, each with
/// the same short refinement, and the best refined in full.
pub(super) fn refine_with_integers(
    shader: &'static Shader,
    start: &[f64],
    max_iters: u64,
    effort: Effort,
    target: &Target,
    evals: &AtomicU64,
) -> Result<(Eval, u64)> {
    let (mut best, mut iters) = sweep_and_refine(shader, start, max_iters, effort, target, evals)?;
    let ints: Vec<usize> = (0..shader.params.len())
        .filter(|&i| shader.params[i].kind == Kind::Integer)
        .collect();
    let count = shader.layout.count();
    for _round in 0..effort.integer_rounds {
        let mut improved = false;
        for &i in &ints {
            let spec = &shader.params[i];
            let here = best.params[i];
            // A scattered shader's count: every value, each with its other
            // parameters refined. Any other: the values near enough, with
            // the other parameters kept.
            let scattered = match (shader.layout, effort.scatter_refine) {
                (Layout::Scatter { count }, Some(r)) if count == i => Some(r),
                _ => None,
            };
            let near = |v: f64| match effort.count_window {
                Some(w) if scattered.is_none() && count == Some(i) => (v - here).abs() <= w * here,
                _ => true,
            };
            // A scattered count's values, its current one too, all start
            // from the same point (the start, count set) and get the same
            // refinement, so the current count's longer refinement does not
            // decide the comparison.
            let values: Vec<f64> = (spec.min as i64..=spec.max as i64)
                .map(|v| v as f64)
                .filter(|&v| (scattered.is_some() || v != here) && near(v))
                .collect();
            let from = match scattered {
                Some(_) => shader.legal(start),
                None => best.params.clone(),
            };
            // A scattered count is compared by the objective plus the
            // structure term, as shaders are: the objective is flat across
            // counts, how the features break into pieces is not.
            let rank = |e: &Eval| match scattered {
                Some(_) if effort.scatter_structure => {
                    e.objective + STRUCTURE_WEIGHT * structure_term(shader, &e.params, target)
                }
                _ => e.objective,
            };
            let scored: Vec<(f64, f64, Vec<f64>, u64)> = values
                .par_iter()
                .map(|&v| {
                    let mut p = from.clone();
                    p[i] = v;
                    Ok(match scattered {
                        Some(r) => {
                            let (e, n) = refine(shader, &p, r, target, evals)?;
                            (rank(&e), v, e.params, n)
                        }
                        None => {
                            evals.fetch_add(1, Ordering::Relaxed);
                            (evaluate(shader, &p, target).objective, v, p, 0)
                        }
                    })
                })
                .collect::<Result<_>>()?;
            iters += scored.iter().map(|t| t.3).sum::<u64>();
            let mut tried: Vec<(f64, f64, Vec<f64>)> =
                scored.into_iter().map(|(o, v, p, _)| (o, v, p)).collect();
            tried.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)));
            tracing::debug!(
                shader = shader.name,
                param = spec.name,
                here,
                here_rank = rank(&best),
                tried = ?tried.iter().map(|t| (t.1, t.0)).collect::<Vec<_>>(),
                "whole numbers tried, best first"
            );
            // The best new values are refined in full for a scattered count
            // (as the current one was), half as long for any other; the
            // current count, when it comes out best, already is.
            let iters_each = match scattered {
                Some(_) => max_iters,
                None => max_iters.div_ceil(2),
            };
            for (_, _, p) in tried
                .iter()
                .take(effort.alternatives)
                .filter(|t| t.1 != here)
            {
                let (e, n) = sweep_and_refine(shader, p, iters_each, effort, target, evals)?;
                iters += n;
                if rank(&e) < rank(&best) - 1e-9 {
                    best = e;
                    improved = true;
                }
            }
        }
        if !improved {
            break;
        }
    }
    Ok((best, iters))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::procedural::pattern::Pattern;
    use crate::procedural::shaders::by_name;

    /// A scattered shader's count is searched over its whole range, each
    /// value with its other parameters refined: from a start at half the
    /// target's count (dots where the target has walls), the photo effort
    /// finds the target's count. Compared with the other parameters kept,
    /// or only near the start, it stays within a step of 6.
    #[test]
    fn a_scattered_count_is_found_across_its_whole_range() {
        let cells = by_name("cells").unwrap();
        let truth = Pattern {
            shader: cells,
            params: vec![12.0, 0.9, 0.85, 0.12],
            colours: [[40.0, 30.0, 20.0], [200.0, 170.0, 120.0]],
        };
        let target = Target::new(&truth.render(64, 64), 64).unwrap();
        let evals = AtomicU64::new(0);
        let (found, _) = refine_with_integers(
            cells,
            &[6.0, 0.5, 0.2, 0.25],
            40,
            Effort::LIGHT,
            &target,
            &evals,
        )
        .unwrap();
        assert_eq!(found.params[0], 12.0, "{:?}", found.params);
    }
}
