//! Procedural texture matching (Bourque–Dudek §3.2): a global search over
//! the catalogue, then local refinement by the Nelder–Mead simplex,
//! re-rendering at every step.
//!
//! - Global search (§3.2.1): the target's structure descriptor against every
//!   catalogue sample. Shaders whose best sample is far worse than the best
//!   shader's (a large disparity) are dropped; each remaining shader's best
//!   few samples are the starting points, in order of admissibility.
//! - Local search (§3.2.2): Nelder–Mead (argmin) over the continuous
//!   parameters, on the unit box, minimising (1 − S_F) + S_L + colour
//!   against the target (the measures of `texsyn compare`). Whole-number
//!   parameters stay whole: each start keeps its sample's values, then
//!   ±1 steps are tried with a shorter simplex run each, as long as they
//!   help.
//! - Colours are not searched: for every render, the two colours are fitted
//!   in closed form by matching the pattern's sorted values to the target's
//!   colours sorted by luminance (a least-squares line per channel, either
//!   sign).

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use anyhow::{bail, ensure, Context, Result};
use argmin::core::{CostFunction, Executor, State};
use argmin::solver::neldermead::NelderMead;
use rand::{Rng, SeedableRng};
use rayon::prelude::*;
use serde::Serialize;
use serde_json::{json, Value};

use super::catalogue::{selected, unit_distance, Catalogue};
use super::descriptor::Structure;
use super::shaders::{colourise, Kind, Shader, COLOUR_PARAMS};
use crate::compare::Descriptors;
use crate::filters::box_blur_lines;
use crate::imaging::colour::luminance;
use crate::imaging::ColorImage;

/// A shader with parameters and colours: a texture at any resolution.
#[derive(Clone, Debug)]
pub struct Pattern {
    pub shader: &'static Shader,
    pub params: Vec<f64>,
    /// RGB at pattern value 0 and 1 (may lie outside 0..=255 when the
    /// pattern never reaches 0 or 1; renders are clamped).
    pub colours: [[f64; 3]; 2],
}

impl Pattern {
    /// Renders `width`×`height`; the unit square spans the shorter side.
    pub fn render(&self, width: usize, height: usize) -> ColorImage {
        let f = self
            .shader
            .render_field(&self.params, width, height, width.min(height));
        colourise(&f, width, height, &self.colours)
    }

    /// The pattern as JSON: shader, named parameters, colours.
    pub fn to_json(&self) -> Value {
        let params: serde_json::Map<String, Value> = self
            .shader
            .params
            .iter()
            .zip(&self.params)
            .map(|(p, &v)| (p.name.to_string(), json!(round(v, 4))))
            .collect();
        let c = |c: &[f64; 3]| json!(c.map(|x| round(x, 1)));
        json!({
            "shader": self.shader.name,
            "parameters": params,
            "colours": { COLOUR_PARAMS[0]: c(&self.colours[0]), COLOUR_PARAMS[1]: c(&self.colours[1]) },
        })
    }

    /// Reads [`Pattern::to_json`] (e.g. a `--params` file of `texsyn match`).
    pub fn from_json(v: &Value) -> Result<Self> {
        let name = v["shader"]
            .as_str()
            .context("the pattern has no \"shader\" name")?;
        let shader = super::shaders::by_name(name)
            .with_context(|| format!("unknown shader '{name}' in the pattern"))?;
        let mut params = Vec::new();
        for p in shader.params {
            let x = v["parameters"][p.name]
                .as_f64()
                .with_context(|| format!("the pattern lacks parameter \"{}\" of {name}", p.name))?;
            ensure!(
                x >= p.min && x <= p.max,
                "parameter {} = {x} of {name} is outside {}..={}",
                p.name,
                p.min,
                p.max
            );
            params.push(p.legal(x));
        }
        let mut colours = [[0.0; 3]; 2];
        for (k, c) in COLOUR_PARAMS.iter().enumerate() {
            let a = v["colours"][c]
                .as_array()
                .filter(|a| a.len() == 3)
                .with_context(|| format!("the pattern lacks colour \"{c}\" as [R, G, B]"))?;
            for (i, x) in a.iter().enumerate() {
                colours[k][i] = x
                    .as_f64()
                    .filter(|x| x.is_finite())
                    .with_context(|| format!("colour \"{c}\" is not three numbers"))?;
            }
        }
        Ok(Self {
            shader,
            params,
            colours,
        })
    }
}

fn round(x: f64, digits: i32) -> f64 {
    let m = 10f64.powi(digits);
    (x * m).round() / m
}

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
    /// the best after their first simplex run.
    pub finalists: usize,
}

impl Default for MatchSettings {
    fn default() -> Self {
        Self {
            starts: 3,
            max_iters: 80,
            shaders: None,
            disparity: 0.1,
            finalists: 3,
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

/// The centred square of `img`, resampled to `size`².
pub fn analysis_image(img: &ColorImage, size: usize) -> ColorImage {
    let side = img.width.min(img.height);
    let sq = img.crop((img.width - side) / 2, (img.height - side) / 2, side, side);
    if side == size {
        return sq;
    }
    let buf = image::RgbImage::from_raw(side as u32, side as u32, sq.rgb).expect("rgb buffer");
    let r = image::imageops::resize(
        &buf,
        size as u32,
        size as u32,
        image::imageops::FilterType::Lanczos3,
    );
    ColorImage::from_vec(size, size, r.into_raw())
}

/// Groups of pixels averaged along the sorted order in the colour fit.
const GROUPS: usize = 64;

/// The target's colours, sorted by luminance and averaged in groups.
pub struct ColourTarget {
    groups: Vec<[f64; 3]>,
}

impl ColourTarget {
    pub fn of(img: &ColorImage) -> Self {
        let l = luminance(img);
        let mut idx: Vec<usize> = (0..img.len()).collect();
        idx.sort_by_key(|&i| (l.data[i], i));
        let n = idx.len().max(1);
        let groups = (0..GROUPS)
            .map(|g| {
                let (a, b) = (
                    g * n / GROUPS,
                    ((g + 1) * n / GROUPS).max(g * n / GROUPS + 1),
                );
                let mut c = [0.0; 3];
                for &i in &idx[a..b.min(idx.len())] {
                    for (k, ck) in c.iter_mut().enumerate() {
                        *ck += f64::from(img.rgb[3 * i + k]);
                    }
                }
                c.map(|x| x / (b - a) as f64)
            })
            .collect();
        Self { groups }
    }

    /// The two colours that make `field` look most like the target: the
    /// least-squares line per channel through (sorted pattern value, target
    /// colour at the same luminance rank), for the better of both signs.
    pub fn fit(&self, field: &[f32]) -> [[f64; 3]; 2] {
        self.fit_signs(field, &[false, true])
    }

    /// [`ColourTarget::fit`] with the orientation given: the darker colour
    /// at pattern value 0 when `dark_low`, at 1 otherwise.
    pub fn fit_oriented(&self, field: &[f32], dark_low: bool) -> [[f64; 3]; 2] {
        self.fit_signs(field, &[!dark_low])
    }

    fn fit_signs(&self, field: &[f32], flips: &[bool]) -> [[f64; 3]; 2] {
        let mut f: Vec<f32> = field.to_vec();
        f.sort_by(f32::total_cmp);
        let n = f.len().max(1);
        let xs: Vec<f64> = (0..GROUPS)
            .map(|g| {
                let (a, b) = (
                    g * n / GROUPS,
                    ((g + 1) * n / GROUPS).max(g * n / GROUPS + 1),
                );
                let b = b.min(f.len());
                f[a..b].iter().map(|&x| f64::from(x)).sum::<f64>() / (b - a).max(1) as f64
            })
            .collect();
        let mx = xs.iter().sum::<f64>() / GROUPS as f64;
        let vx: f64 = xs.iter().map(|x| (x - mx) * (x - mx)).sum();
        let mean_c: [f64; 3] =
            std::array::from_fn(|k| self.groups.iter().map(|c| c[k]).sum::<f64>() / GROUPS as f64);
        if vx < 1e-12 {
            return [mean_c, mean_c];
        }
        let mut best = (f64::INFINITY, [mean_c, mean_c]);
        for &flip in flips {
            let col = |g: usize| self.groups[if flip { GROUPS - 1 - g } else { g }];
            let mut lo = [0.0; 3];
            let mut hi = [0.0; 3];
            let mut residual = 0.0;
            for k in 0..3 {
                let cov: f64 = (0..GROUPS)
                    .map(|g| (xs[g] - mx) * (col(g)[k] - mean_c[k]))
                    .sum();
                let b = cov / vx;
                let a = mean_c[k] - b * mx;
                lo[k] = a;
                hi[k] = a + b;
                residual += (0..GROUPS)
                    .map(|g| (a + b * xs[g] - col(g)[k]).powi(2))
                    .sum::<f64>();
            }
            if residual < best.0 {
                best = (residual, [lo, hi]);
            }
        }
        best.1
    }
}

/// What the local search compares each render with.
pub struct Target {
    pub image: ColorImage,
    pub descriptors: Descriptors,
    /// The S_F spectrum blurred at each of [`BLURS`].
    pub blurred: Vec<Vec<f64>>,
    pub structure: Structure,
    pub colours: ColourTarget,
}

impl Target {
    /// The target at the catalogue's analysis size.
    pub fn new(img: &ColorImage, size: usize) -> Result<Self> {
        ensure!(
            img.width >= 8 && img.height >= 8,
            "the target is {}×{}; give an image of at least 8×8 pixels",
            img.width,
            img.height
        );
        let image = analysis_image(img, size);
        let descriptors = Descriptors::of(&image)?;
        Ok(Self {
            blurred: blurred_spectra(&descriptors),
            descriptors,
            structure: Structure::of_image(&image),
            colours: ColourTarget::of(&image),
            image,
        })
    }
}

/// Blurs of the spectrum in the refinement objective, as fractions of the
/// image side (in frequency bins).
pub const BLURS: [f64; 2] = [1.0 / 48.0, 1.0 / 16.0];

/// The Gaussian low-pass (cycles per pixel) on the blurred spectra: they
/// are there to lead the search to the fundamental's basin, and the high
/// harmonics of a sharp pattern (folded back by point sampling) move
/// erratically with its frequency.
pub const LOW_PASS: f64 = 0.12;

/// The S_F spectrum of `d`, low-passed by [`LOW_PASS`] and blurred
/// (wrapping; three box passes per axis, a close Gaussian) at each of
/// [`BLURS`], each of unit length. The spectrum of a periodic pattern is a
/// set of peaks, so S_F alone only sees a candidate very near the target;
/// the blurred spectra give the search a slope from further away.
pub fn blurred_spectra(d: &Descriptors) -> Vec<Vec<f64>> {
    let (w, h) = (d.width, d.height);
    let pass = |n: usize| -> Vec<f64> {
        (0..n)
            .map(|k| (-(crate::compare::frequency(k, n) / LOW_PASS).powi(2)).exp())
            .collect()
    };
    let (gx, gy) = (pass(w), pass(h));
    let low: Vec<f64> = (0..w * h)
        .map(|i| d.spectrum[i] * gx[i % w] * gy[i / w])
        .collect();
    BLURS
        .iter()
        .map(|&b| {
            let sigma = b * w.min(h) as f64;
            // Three boxes of width 2r + 1 have variance 3·((2r + 1)² − 1)/12.
            let r = (((4.0 * sigma * sigma + 1.0).sqrt() - 1.0) / 2.0).round() as usize;
            let mut out = low.clone();
            for _ in 0..3 {
                box_blur_lines(&mut out, w, h, r, 1, w);
                box_blur_lines(&mut out, h, w, r, w, 1);
            }
            let norm = out.iter().map(|x| x * x).sum::<f64>().sqrt();
            if norm > 0.0 {
                out.iter_mut().for_each(|x| *x /= norm);
            }
            out
        })
        .collect()
}

/// One evaluated parameter vector.
#[derive(Clone, Debug)]
struct Eval {
    params: Vec<f64>,
    colours: [[f64; 3]; 2],
    s_f: f64,
    s_l: f64,
    colour: f64,
    objective: f64,
}

/// The objective of one shader with its whole-number parameters fixed, on
/// the unit box of its other parameters.
struct Problem<'a> {
    shader: &'static Shader,
    base: Vec<f64>,
    free: Vec<usize>,
    target: &'a Target,
    evals: &'a AtomicU64,
}

impl Problem<'_> {
    fn params(&self, x: &[f64]) -> Vec<f64> {
        self.shader.from_unit_box(&self.base, &self.free, x)
    }

    fn evaluate(&self, params: &[f64]) -> Eval {
        self.evals.fetch_add(1, Ordering::Relaxed);
        evaluate(self.shader, params, self.target)
    }
}

/// Renders `params` at the target's size with fitted colours and scores it.
fn evaluate(shader: &'static Shader, params: &[f64], target: &Target) -> Eval {
    let size = target.image.width;
    let field = shader.render_field(params, size, size, size);
    let colours = target.colours.fit(&field);
    let img = colourise(&field, size, size, &colours);
    let Ok(d) = Descriptors::of(&img) else {
        unreachable!("analysis images are at least 32×32")
    };
    let (s_f, s_l, colour) = target.descriptors.scores(&d);
    let slope: f64 = blurred_spectra(&d)
        .iter()
        .zip(&target.blurred)
        .map(|(a, b)| 1.0 - crate::compare::spectra_similarity(a, b))
        .sum();
    Eval {
        params: params.to_vec(),
        colours,
        s_f,
        s_l,
        colour,
        objective: (1.0 - s_f) + s_l + colour + slope,
    }
}

impl CostFunction for Problem<'_> {
    type Param = Vec<f64>;
    type Output = f64;

    fn cost(&self, x: &Self::Param) -> Result<f64, argmin::core::Error> {
        // Outside the box the parameters are clamped; a gentle slope leads
        // the simplex back in.
        let out: f64 = self
            .free
            .iter()
            .zip(x)
            .filter(|(&i, _)| self.shader.params[i].kind != Kind::Periodic)
            .map(|(_, &t)| (t.clamp(0.0, 1.0) - t).powi(2))
            .sum();
        Ok(self.evaluate(&self.params(x)).objective + out)
    }
}

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
fn refine(
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

/// Values per parameter in a [`sweep`].
const SWEEP: usize = 64;

/// A coordinate sweep: each continuous parameter in turn is set to
/// [`SWEEP`] values spread over its whole range (the others kept), and the
/// best render is kept; repeated while a pass helps, at most twice. The
/// objective of a periodic pattern along a frequency, an angle or an aspect
/// is a comb of narrow basins, one per harmonic; a start in the wrong basin
/// is one the simplex cannot leave, and a sweep crosses them all.
fn sweep(shader: &'static Shader, from: Eval, target: &Target, evals: &AtomicU64) -> Eval {
    let mut best = from;
    for _pass in 0..2 {
        let before = best.objective;
        for (i, spec) in shader.params.iter().enumerate() {
            if spec.kind == Kind::Integer {
                continue;
            }
            let tried: Vec<Eval> = (0..SWEEP)
                .into_par_iter()
                .map(|k| {
                    let t = match spec.kind {
                        Kind::Periodic => k as f64 / SWEEP as f64,
                        _ => k as f64 / (SWEEP - 1) as f64,
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
    target: &Target,
    evals: &AtomicU64,
) -> Result<(Eval, u64)> {
    evals.fetch_add(1, Ordering::Relaxed);
    let mut best = evaluate(shader, &shader.legal(start), target);
    let mut iters = 0;
    for round in 0..3 {
        let before = best.objective;
        let swept = sweep(shader, best, target, evals);
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
/// value is rendered with the other parameters kept, and the two best new
/// values are swept and refined with a shorter simplex run each; repeated
/// while one helps.
fn refine_with_integers(
    shader: &'static Shader,
    start: &[f64],
    max_iters: u64,
    target: &Target,
    evals: &AtomicU64,
) -> Result<(Eval, u64)> {
    let (mut best, mut iters) = sweep_and_refine(shader, start, max_iters, target, evals)?;
    let ints: Vec<usize> = (0..shader.params.len())
        .filter(|&i| shader.params[i].kind == Kind::Integer)
        .collect();
    for _round in 0..3 {
        let mut improved = false;
        for &i in &ints {
            let spec = &shader.params[i];
            let mut tried: Vec<(f64, f64)> = Vec::new();
            let mut v = spec.min;
            while v <= spec.max {
                if v != best.params[i] {
                    let mut p = best.params.clone();
                    p[i] = v;
                    evals.fetch_add(1, Ordering::Relaxed);
                    tried.push((evaluate(shader, &p, target).objective, v));
                }
                v += 1.0;
            }
            tried.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)));
            for &(_, v) in tried.iter().take(2) {
                let mut p = best.params.clone();
                p[i] = v;
                let (e, n) = sweep_and_refine(shader, &p, max_iters.div_ceil(2), target, evals)?;
                iters += n;
                if e.objective < best.objective - 1e-9 {
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

/// A starting point of the local search.
struct Start {
    shader: &'static Shader,
    params: Vec<f64>,
    distance: f64,
    admissibility: f64,
}

/// The global search: starting points per shader, in admissibility order.
fn starting_points(cat: &Catalogue, target: &Target, s: &MatchSettings) -> Result<Vec<Start>> {
    let shaders = selected(s.shaders.as_deref())?;
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
                });
            }
        }
        if let Some(first) = chosen.first() {
            per_shader.push((first.distance, chosen));
        }
    }
    ensure!(
        !per_shader.is_empty(),
        "the catalogue has none of the selected shaders; rebuild it"
    );
    let best = per_shader
        .iter()
        .map(|(d, _)| *d)
        .fold(f64::INFINITY, f64::min);
    let mut starts: Vec<Start> = per_shader
        .into_iter()
        .filter(|(d, _)| *d <= best + s.disparity)
        .flat_map(|(_, c)| c)
        .collect();
    starts.sort_by(|a, b| b.admissibility.total_cmp(&a.admissibility));
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
fn match_prepared(
    target: &Target,
    cat: &Catalogue,
    settings: &MatchSettings,
    started: Instant,
) -> Result<MatchResult> {
    let starts = starting_points(cat, target, settings)?;
    let evals = AtomicU64::new(0);
    // Screening: one simplex run from every start.
    let screened: Vec<(Eval, u64)> = starts
        .par_iter()
        .map(|s| refine(s.shader, &s.params, settings.max_iters, target, &evals))
        .collect::<Result<_>>()?;
    let mut order: Vec<usize> = (0..starts.len()).collect();
    order.sort_by(|&a, &b| {
        screened[a]
            .0
            .objective
            .total_cmp(&screened[b].0.objective)
            .then(a.cmp(&b))
    });
    order.truncate(settings.finalists);
    // The finalists: sweeps, simplex runs and the whole-number search.
    let finals: Vec<(usize, Eval, u64)> = order
        .par_iter()
        .map(|&k| {
            let (e, n) = refine_with_integers(
                starts[k].shader,
                &screened[k].0.params,
                settings.max_iters,
                target,
                &evals,
            )?;
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
            screened: round(e.objective, 5),
            objective: None,
            iterations: *n,
        })
        .collect();
    let mut best: Option<(usize, Eval, u64)> = None;
    for (k, e, iters) in finals {
        candidates[k].objective = Some(round(e.objective, 5));
        candidates[k].iterations = iters;
        tracing::debug!(
            shader = starts[k].shader.name,
            objective = e.objective,
            iters,
            "finalist refined"
        );
        if best.as_ref().is_none_or(|b| e.objective < b.1.objective) {
            best = Some((k, e, iters));
        }
    }
    let (k, e, iterations) = best.context("no starting point")?;
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::procedural::shaders::by_name;

    #[test]
    fn box_blur_is_the_wrapped_moving_mean() {
        let (w, h) = (13, 7);
        let v: Vec<f64> = (0..w * h).map(|i| ((i * 37) % 11) as f64).collect();
        for r in 0..4 {
            let mut rows = v.clone();
            crate::filters::box_blur_lines(&mut rows, w, h, r, 1, w);
            let mut cols = v.clone();
            crate::filters::box_blur_lines(&mut cols, h, w, r, w, 1);
            for y in 0..h {
                for x in 0..w {
                    let n = (2 * r + 1) as f64;
                    let row: f64 = (0..=2 * r)
                        .map(|j| v[y * w + (x + w + j - r) % w])
                        .sum::<f64>()
                        / n;
                    let col: f64 = (0..=2 * r)
                        .map(|j| v[((y + h + j - r) % h) * w + x])
                        .sum::<f64>()
                        / n;
                    assert!((rows[y * w + x] - row).abs() < 1e-9);
                    assert!((cols[y * w + x] - col).abs() < 1e-9);
                }
            }
        }
    }

    #[test]
    fn colour_fit_recovers_the_colours_of_a_render() {
        let s = by_name("clouds").unwrap();
        let f = s.render_field(&[3.0, 0.5], 64, 64, 64);
        for colours in [
            [[20.0, 40.0, 200.0], [250.0, 200.0, 10.0]],
            [[230.0, 220.0, 210.0], [30.0, 60.0, 20.0]],
        ] {
            let img = colourise(&f, 64, 64, &colours);
            let fit = ColourTarget::of(&img).fit(&f);
            for k in 0..2 {
                for i in 0..3 {
                    assert!(
                        (fit[k][i] - colours[k][i]).abs() < 3.0,
                        "{fit:?} against {colours:?}"
                    );
                }
            }
        }
    }

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
