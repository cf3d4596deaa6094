//! Jump points between shaders (Bourque–Dudek §4.3): every catalogue
//! sample of one shader is compared with every sample of the other; from
//! the closest pair, each side's parameters are refined in turn
//! (Nelder–Mead) towards the other side's texture until neither moves.

use anyhow::{Context, Result};
use argmin::core::CostFunction;
use rayon::prelude::*;

use super::catalogue::{describe, unit_distance, Catalogue, Sample};
use super::descriptor::Structure;
use super::local::simplex;
use super::shaders::Shader;

/// One shader's parameters refined towards another texture's structure.
struct Towards<'a> {
    shader: &'static Shader,
    base: Vec<f64>,
    free: Vec<usize>,
    other: &'a Structure,
    size: usize,
}

impl Towards<'_> {
    fn params(&self, x: &[f64]) -> Vec<f64> {
        self.shader.from_unit_box(&self.base, &self.free, x)
    }
}

impl CostFunction for Towards<'_> {
    type Param = Vec<f64>;
    type Output = f64;

    fn cost(&self, x: &Self::Param) -> Result<f64, argmin::core::Error> {
        Ok(describe(self.shader, &self.params(x), self.size).distance(self.other))
    }
}

/// `params` of `s` moved by Nelder–Mead towards the texture `other`.
fn approach(s: &'static Shader, params: &[f64], other: &Structure, size: usize) -> Vec<f64> {
    let free = s.continuous();
    if free.is_empty() {
        return params.to_vec();
    }
    let x0 = s.to_unit_box(params, &free);
    let problem = Towards {
        shader: s,
        base: params.to_vec(),
        free,
        other,
        size,
    };
    match simplex(problem, &x0, 0.05, 1e-6, 30) {
        Ok((problem, best, _)) => problem.params(&best),
        Err(_) => params.to_vec(),
    }
}

/// A sample whose contrast is under this share of its shader's median is
/// too flat to be a jump point; refinement may not take a jump point's
/// contrast under this share of where it started.
const FLAT: f64 = 0.5;

/// The standard deviation of a pattern's values, rendered at 48².
fn contrast(s: &Shader, params: &[f64]) -> f64 {
    let f = s.render_field(params, 48, 48, 48);
    let n = f.len() as f64;
    let mean = f.iter().map(|&v| f64::from(v)).sum::<f64>() / n;
    (f.iter()
        .map(|&v| (f64::from(v) - mean).powi(2))
        .sum::<f64>()
        / n)
        .sqrt()
}

/// The indices of the samples whose contrast is at least [`FLAT`] times
/// the median of the shader's samples.
pub(super) fn visible(s: &Shader, samples: &[Sample]) -> Vec<usize> {
    let c: Vec<f64> = samples.iter().map(|x| contrast(s, &x.params)).collect();
    let mut sorted = c.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted.get(sorted.len() / 2).copied().unwrap_or(0.0);
    (0..c.len()).filter(|&i| c[i] >= FLAT * median).collect()
}

/// The jump points between shaders `k` and `l` (§4.3): parameters of each
/// whose textures are closest, and their structure distance.
pub fn jump_points(
    cat: &Catalogue,
    k: &'static Shader,
    l: &'static Shader,
) -> Result<(Vec<f64>, Vec<f64>, f64)> {
    let (sk, sl) = (
        cat.of(k.name)
            .with_context(|| format!("the catalogue has no shader '{}'; rebuild it", k.name))?,
        cat.of(l.name)
            .with_context(|| format!("the catalogue has no shader '{}'; rebuild it", l.name))?,
    );
    // Only samples with a pattern to show: the descriptor is standardised,
    // so a nearly flat texture's faint variations would otherwise make it
    // look like anything, and the path would fade out at the jump.
    let (vk, vl) = (visible(k, &sk.samples), visible(l, &sl.samples));
    let (_, i, j) = vk
        .par_iter()
        .map(|&i| {
            vl.iter()
                .map(|&j| {
                    (
                        sk.samples[i].structure.distance(&sl.samples[j].structure),
                        i,
                        j,
                    )
                })
                .fold((f64::INFINITY, 0, 0), |m, x| if x.0 < m.0 { x } else { m })
        })
        .collect::<Vec<_>>()
        .into_iter()
        .fold((f64::INFINITY, 0, 0), |m, x| if x.0 < m.0 { x } else { m });
    let (mut x, mut y) = (sk.samples[i].params.clone(), sl.samples[j].params.clone());
    let (floor_k, floor_l) = (
        FLAT * contrast(k, &sk.samples[i].params),
        FLAT * contrast(l, &sl.samples[j].params),
    );
    for _ in 0..3 {
        let sy = describe(l, &y, cat.size);
        let nx = approach(k, &x, &sy, cat.size);
        let sx = describe(k, &nx, cat.size);
        let ny = approach(l, &y, &sx, cat.size);
        // Refinement must not trade the pattern away for a closer match.
        if contrast(k, &nx) < floor_k || contrast(l, &ny) < floor_l {
            break;
        }
        let moved = unit_distance(k, &x, &nx).max(unit_distance(l, &y, &ny));
        x = nx;
        y = ny;
        if moved < 0.01 {
            break;
        }
    }
    let d = describe(k, &x, cat.size).distance(&describe(l, &y, cat.size));
    Ok((x, y, d))
}
