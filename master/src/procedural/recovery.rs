//! Recovery of synthetic targets: random patterns rendered as targets and
//! matched with their shader known (the recovery measure of the tests and
//! `texsyn-bench match`).

use std::time::Instant;

use anyhow::Result;
use rand::{Rng, SeedableRng};

use super::catalogue::Catalogue;
use super::objective::{evaluate, Target};
use super::pattern::Pattern;
use super::search::{match_prepared, MatchResult, MatchSettings};
use super::shaders::{Kind, Shader};

/// A random pattern of `shader` for recovery tests: parameters uniform in
/// their ranges, two colours whose luminances differ by at least 60 (so the
/// pattern shows).
pub fn draw(shader: &'static Shader, seed: u64) -> Pattern {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let params = shader
        .params
        .iter()
        .map(|p| match p.kind {
            Kind::Integer => rng.random_range(p.min as i64..=p.max as i64) as f64,
            _ => p.legal(rng.random_range(p.min..p.max)),
        })
        .collect();
    loop {
        let c: [[f64; 3]; 2] = std::array::from_fn(|_| {
            std::array::from_fn(|_| f64::from(rng.random_range(0u8..=255)))
        });
        let y = crate::imaging::colour::luma_f64;
        if (y(&c[0]) - y(&c[1])).abs() >= 60.0 {
            return Pattern {
                shader,
                params,
                colours: c,
            };
        }
    }
}

/// Whether `found` recovers `truth`: the same shader, whole numbers equal,
/// every other parameter and colour channel within `tolerance` of its range.
pub fn recovered(truth: &Pattern, found: &Pattern, tolerance: f64) -> bool {
    if truth.shader.name != found.shader.name {
        return false;
    }
    let params_ok = truth
        .shader
        .params
        .iter()
        .zip(truth.params.iter().zip(&found.params))
        .all(|(p, (&a, &b))| match p.kind {
            Kind::Integer => a == b,
            _ => p.distance(a, b) <= tolerance,
        });
    let colours_ok = (0..2).all(|k| {
        (0..3).all(|i| (truth.colours[k][i] - found.colours[k][i]).abs() <= tolerance * 255.0)
    });
    params_ok && colours_ok
}

/// The worst per-parameter error of `found` against `truth`, as a fraction
/// of each range (colours over 255); integers count 1 per step.
pub fn worst_error(truth: &Pattern, found: &Pattern) -> f64 {
    let p = truth
        .shader
        .params
        .iter()
        .zip(truth.params.iter().zip(&found.params))
        .map(|(p, (&a, &b))| match p.kind {
            Kind::Integer => (a - b).abs(),
            _ => p.distance(a, b),
        })
        .fold(0.0, f64::max);
    let c = (0..2)
        .flat_map(|k| (0..3).map(move |i| (k, i)))
        .map(|(k, i)| (truth.colours[k][i] - found.colours[k][i]).abs() / 255.0)
        .fold(0.0, f64::max);
    p.max(c)
}

/// One synthetic recovery trial: a random pattern rendered as the target
/// and matched with its shader known.
#[derive(Clone, Debug)]
pub struct Trial {
    pub truth: Pattern,
    pub found: MatchResult,
    pub recovered: bool,
    pub worst_error: f64,
    /// The objective of the true parameters against the target: above the
    /// found one, the measures cannot tell them apart; below, the search
    /// stopped short.
    pub truth_objective: f64,
}

/// `draws` recovery trials of `shader` (seeds `seed`, `seed + 1`...):
/// targets rendered at the catalogue's size, matched against that shader
/// only, recovered within `tolerance` of each range.
pub fn recovery_trials(
    shader: &'static Shader,
    draws: usize,
    seed: u64,
    cat: &Catalogue,
    settings: &MatchSettings,
    tolerance: f64,
) -> Result<Vec<Trial>> {
    let settings = MatchSettings {
        shaders: Some(vec![shader.name.to_string()]),
        ..settings.clone()
    };
    settings.validate()?;
    (0..draws as u64)
        .map(|k| {
            let truth = draw(shader, seed + k);
            let started = Instant::now();
            let target = Target::new(&truth.render(cat.size, cat.size), cat.size)?;
            let found = match_prepared(&target, cat, &settings, started)?;
            let truth_objective = evaluate(shader, &truth.params, &target).objective;
            Ok(Trial {
                truth_objective,
                recovered: recovered(&truth, &found.pattern, tolerance),
                worst_error: worst_error(&truth, &found.pattern),
                truth,
                found,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::procedural::shaders::by_name;
    use serde_json::json;

    #[test]
    fn a_pattern_survives_its_json() {
        let p = draw(by_name("stars").unwrap(), 3);
        let q = Pattern::from_json(&p.to_json()).unwrap();
        assert!(recovered(&p, &q, 0.001));
        let mut bad = p.to_json();
        bad["parameters"]["points"] = json!(99);
        assert!(Pattern::from_json(&bad).is_err());
    }
}
