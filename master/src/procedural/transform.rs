//! Texture transformation (Bourque–Dudek §4): a sequence of patterns from
//! one texture to another whose adjacent frames look alike.
//!
//! - Within a shader (§4.2): the catalogue samples and both ends form a
//!   fully connected graph, edge weight e = the structure distance of the
//!   two textures; Dijkstra finds the path of least (Σ eⁿ)^(1/n) (larger n
//!   favours many small steps). Then, while two adjacent frames differ by
//!   more than a threshold (structure distance + colour term), the
//!   parameter midpoint is inserted between them.
//! - Key-textures: the paths between consecutive stops are concatenated.
//! - Between shaders (§4.3): the jump points. Every catalogue sample of one
//!   shader is compared with every sample of the other; from the closest
//!   pair, each side's parameters are refined in turn (Nelder–Mead) towards
//!   the other side's texture until neither moves. The path runs to the jump
//!   point in the first shader and on from the jump point in the second,
//!   whose colours are fitted to the first's render.
//! - Frames: the requested count, spaced evenly along the path's perceived
//!   distance, parameters and colours interpolated between path points.

use anyhow::{ensure, Result};
use pathfinding::prelude::dijkstra;

use super::catalogue::{describe, Catalogue};
use super::colour::ColourTarget;
use super::descriptor::Structure;
pub use super::jumps::jump_points;
use super::jumps::visible;
use super::pattern::Pattern;
use super::shaders::{Kind, Shader};
use crate::compare::Descriptors;

/// How to build a transformation.
#[derive(Clone, Debug)]
pub struct TransformSettings {
    /// The n of the path cost (Σ eⁿ)^(1/n).
    pub exponent: f64,
    /// Largest distance (structure + colour term) between adjacent path
    /// points before a midpoint is inserted.
    pub threshold: f64,
    /// Most path points (midpoint insertion stops there).
    pub max_points: usize,
}

impl Default for TransformSettings {
    fn default() -> Self {
        Self {
            exponent: 3.0,
            threshold: 0.1,
            max_points: 400,
        }
    }
}

impl TransformSettings {
    pub fn validate(&self) -> Result<()> {
        ensure!(
            (1.0..=16.0).contains(&self.exponent),
            "path exponent {} must be in 1..=16",
            self.exponent
        );
        ensure!(
            self.threshold > 0.0 && self.threshold <= 3.0,
            "frame threshold {} must be in (0, 3]",
            self.threshold
        );
        ensure!(
            (2..=10_000).contains(&self.max_points),
            "most path points {} must be in 2..=10000",
            self.max_points
        );
        Ok(())
    }
}

/// A transformation: path points and the distance of each step.
#[derive(Clone, Debug)]
pub struct Path {
    pub points: Vec<Pattern>,
    /// `steps[i]`: structure distance + colour term from point i to i + 1.
    pub steps: Vec<f64>,
    /// `jumps[i]`: step i goes from one shader to another.
    pub jumps: Vec<bool>,
}

impl Path {
    /// Its points and jumps in a few words.
    pub fn summary(&self) -> String {
        let jumps = self.jumps.iter().filter(|&&j| j).count();
        let s = if jumps == 1 { "" } else { "s" };
        format!("{} path points, {jumps} jump{s}", self.points.len())
    }
}

/// What two frames are compared by.
#[derive(Clone)]
struct Frame {
    structure: Structure,
    colours: Descriptors,
}

/// The structure distance plus the colour term of two frames. (S_F itself
/// is too sharp here: the spectrum of a periodic pattern moves off its own
/// peaks with the smallest change of parameters.)
fn frame_distance(a: &Frame, b: &Frame) -> f64 {
    a.structure.distance(&b.structure) + a.colours.scores(&b.colours).2
}

fn descriptors(p: &Pattern, size: usize) -> Frame {
    let img = p.render(size, size);
    Frame {
        structure: Structure::of_image(&img),
        colours: Descriptors::of(&img).expect("size ≥ 32"),
    }
}

/// Parameters `t` of the way from `p` to `q` (periodic ones the short way,
/// whole numbers rounded).
pub fn lerp_params(s: &Shader, p: &[f64], q: &[f64], t: f64) -> Vec<f64> {
    s.params
        .iter()
        .zip(p.iter().zip(q))
        .map(|(spec, (&a, &b))| match spec.kind {
            Kind::Periodic => {
                let span = spec.span();
                let mut d = (b - a).rem_euclid(span);
                if d > span / 2.0 {
                    d -= span;
                }
                spec.legal(a + t * d)
            }
            Kind::Integer => spec.legal((a + t * (b - a)).round()),
            Kind::Continuous => spec.legal(a + t * (b - a)),
        })
        .collect()
}

fn lerp_colours(a: &[[f64; 3]; 2], b: &[[f64; 3]; 2], t: f64) -> [[f64; 3]; 2] {
    std::array::from_fn(|k| std::array::from_fn(|i| a[k][i] + t * (b[k][i] - a[k][i])))
}

/// Whether the colour at pattern value 0 is the darker.
fn dark_low(c: &[[f64; 3]; 2]) -> bool {
    let y = crate::imaging::colour::luma_f64;
    y(&c[0]) <= y(&c[1])
}

/// `c`'s two colours in the orientation of `like`.
fn oriented_like(c: &[[f64; 3]; 2], like: &[[f64; 3]; 2]) -> [[f64; 3]; 2] {
    if dark_low(c) == dark_low(like) {
        *c
    } else {
        [c[1], c[0]]
    }
}

/// The pattern `t` of the way from `a` to `b` (same shader).
fn between(a: &Pattern, b: &Pattern, t: f64) -> Pattern {
    Pattern {
        shader: a.shader,
        params: lerp_params(a.shader, &a.params, &b.params, t),
        colours: lerp_colours(&a.colours, &b.colours, t),
    }
}

/// The catalogue path from `a` to `b` within their shader (§4.2, first
/// stage): Dijkstra over the samples with cost Σ eⁿ.
fn catalogue_path(cat: &Catalogue, a: &Pattern, b: &Pattern, n: f64) -> Vec<Pattern> {
    let s = a.shader;
    let mut structures: Vec<Structure> = vec![
        describe(s, &a.params, cat.size),
        describe(s, &b.params, cat.size),
    ];
    let mut params: Vec<Vec<f64>> = vec![a.params.clone(), b.params.clone()];
    // Through visible samples only (see `visible`): flat ones sit close to
    // everything in the standardised descriptor, and a path through them
    // fades the pattern out.
    if let Some(samples) = cat.of(s.name) {
        for i in visible(s, &samples.samples) {
            structures.push(samples.samples[i].structure.clone());
            params.push(samples.samples[i].params.clone());
        }
    }
    let count = structures.len();
    let cost = |i: usize, j: usize| -> u64 {
        let e = structures[i].distance(&structures[j]);
        (e.powf(n) * 1e12).round() as u64
    };
    let path = dijkstra(
        &0usize,
        |&i| {
            (0..count)
                .filter(move |&j| j != i)
                .map(move |j| (j, cost(i, j)))
                .collect::<Vec<_>>()
        },
        |&i| i == 1,
    )
    .map(|(p, _)| p)
    .unwrap_or_else(|| vec![0, 1]);
    // Colours follow the path's share of the structure distance.
    let lengths: Vec<f64> = path
        .windows(2)
        .map(|w| structures[w[0]].distance(&structures[w[1]]))
        .collect();
    let total: f64 = lengths.iter().sum();
    let mut run = 0.0;
    let mut out = Vec::with_capacity(path.len());
    for (k, &i) in path.iter().enumerate() {
        if k > 0 {
            run += lengths[k - 1];
        }
        let t = if total > 0.0 { run / total } else { 0.0 };
        out.push(Pattern {
            shader: s,
            params: params[i].clone(),
            colours: lerp_colours(&a.colours, &b.colours, t),
        });
    }
    // The ends exactly as given.
    out[0] = a.clone();
    let last = out.len() - 1;
    out[last] = b.clone();
    out
}

/// Inserts midpoints between `a` and `b` until adjacent points are within
/// the threshold (§4.2, second stage); pushes the points after `a`.
#[allow(clippy::too_many_arguments)]
fn subdivide(
    a: &Pattern,
    da: &Frame,
    b: Pattern,
    db: Frame,
    depth: usize,
    size: usize,
    settings: &TransformSettings,
    out: &mut Path,
) {
    let d = frame_distance(da, &db);
    let same = a.params == b.params && a.colours == b.colours;
    if d <= settings.threshold || depth >= 8 || same || out.points.len() >= settings.max_points {
        out.points.push(b);
        out.steps.push(d);
        out.jumps.push(false);
        return;
    }
    let m = between(a, &b, 0.5);
    let dm = descriptors(&m, size);
    subdivide(a, da, m.clone(), dm.clone(), depth + 1, size, settings, out);
    subdivide(&m, &dm, b, db, depth + 1, size, settings, out);
}

/// Appends the within-shader path from the path's last point to `b`.
fn extend_within(cat: &Catalogue, b: &Pattern, settings: &TransformSettings, out: &mut Path) {
    let a = out.points.last().expect("a start").clone();
    let coarse = catalogue_path(cat, &a, b, settings.exponent);
    let mut prev = a;
    let mut dprev = descriptors(&prev, cat.size);
    for p in coarse.into_iter().skip(1) {
        let dp = descriptors(&p, cat.size);
        subdivide(
            &prev,
            &dprev,
            p.clone(),
            dp.clone(),
            0,
            cat.size,
            settings,
            out,
        );
        prev = p;
        dprev = dp;
    }
}

/// The transformation through `stops` (the first, the key-textures, the
/// last).
pub fn transform(cat: &Catalogue, stops: &[Pattern], settings: &TransformSettings) -> Result<Path> {
    settings.validate()?;
    ensure!(
        stops.len() >= 2,
        "a transformation needs two textures or more"
    );
    let mut path = Path {
        points: vec![stops[0].clone()],
        steps: Vec::new(),
        jumps: Vec::new(),
    };
    for b in &stops[1..] {
        let a = path.points.last().expect("a start").clone();
        if a.shader.name == b.shader.name {
            extend_within(cat, b, settings, &mut path);
            continue;
        }
        let (x, y, d) = jump_points(cat, a.shader, b.shader)?;
        tracing::info!(
            from = a.shader.name,
            to = b.shader.name,
            distance = d,
            "jump point"
        );
        // Colours keep each side's orientation (which colour is darker):
        // mixing a dark-on-light pattern's colours with a light-on-dark
        // one's would meet at one grey and fade the frames out at the jump.
        let ja = Pattern {
            shader: a.shader,
            params: x,
            colours: lerp_colours(&a.colours, &oriented_like(&b.colours, &a.colours), 0.5),
        };
        extend_within(cat, &ja, settings, &mut path);
        let field = b.shader.render_field(&y, cat.size, cat.size, cat.size);
        let jb = Pattern {
            shader: b.shader,
            params: y,
            colours: ColourTarget::of(&ja.render(cat.size, cat.size))
                .fit_oriented(&field, dark_low(&b.colours)),
        };
        let step = frame_distance(&descriptors(&ja, cat.size), &descriptors(&jb, cat.size));
        path.points.push(jb);
        path.steps.push(step);
        path.jumps.push(true);
        extend_within(cat, b, settings, &mut path);
    }
    Ok(path)
}

/// `n` frames spaced evenly along the path's perceived distance. A jump
/// between shaders counts as no distance: it falls between two adjacent
/// frames instead of holding several frames on either side.
pub fn frames(path: &Path, n: usize) -> Vec<Pattern> {
    let within: Vec<f64> = path
        .steps
        .iter()
        .zip(&path.jumps)
        .map(|(&d, &j)| if j { 0.0 } else { d })
        .collect();
    let steps: &[f64] = if within.iter().sum::<f64>() > 0.0 {
        &within
    } else {
        &path.steps
    };
    let total: f64 = steps.iter().sum();
    if n == 0 {
        return Vec::new();
    }
    if n == 1 || total <= 0.0 || path.points.len() == 1 {
        return vec![path.points[0].clone(); n.max(1)];
    }
    let mut out = Vec::with_capacity(n);
    let mut seg = 0;
    let mut start = 0.0;
    for i in 0..n {
        if i == n - 1 {
            out.push(path.points[path.points.len() - 1].clone());
            break;
        }
        let s = total * i as f64 / (n - 1) as f64;
        while seg + 1 < steps.len() && start + steps[seg] < s {
            start += steps[seg];
            seg += 1;
        }
        let (a, b) = (&path.points[seg], &path.points[seg + 1]);
        let t = if steps[seg] > 0.0 {
            ((s - start) / steps[seg]).clamp(0.0, 1.0)
        } else {
            1.0
        };
        out.push(if (path.jumps[seg] && t < 0.5) || t <= 0.0 {
            a.clone()
        } else if path.jumps[seg] || t >= 1.0 {
            b.clone()
        } else {
            between(a, b, t)
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::procedural::catalogue::{BuildSettings, Catalogue};
    use crate::procedural::shaders::by_name;

    fn small(shaders: &[&str]) -> Catalogue {
        Catalogue::build(
            &BuildSettings {
                size: 48,
                samples: 24,
                shaders: Some(shaders.iter().map(|s| s.to_string()).collect()),
            },
            &crate::progress::Silent,
        )
        .unwrap()
    }

    #[test]
    fn a_path_within_a_shader_has_small_steps_and_keeps_its_ends() {
        let cat = small(&["stripes"]);
        let s = by_name("stripes").unwrap();
        let a = Pattern {
            shader: s,
            params: vec![3.0, 10.0, 0.2, 0.1],
            colours: [[0.0; 3], [255.0; 3]],
        };
        let b = Pattern {
            shader: s,
            params: vec![12.0, 100.0, 0.45, 0.25],
            colours: [[200.0, 0.0, 0.0], [0.0, 0.0, 200.0]],
        };
        let settings = TransformSettings::default();
        let path = transform(&cat, &[a.clone(), b.clone()], &settings).unwrap();
        assert!(path.points.len() > 3);
        assert_eq!(path.points[0].params, a.params);
        assert_eq!(path.points.last().unwrap().params, b.params);
        let big = path
            .steps
            .iter()
            .filter(|&&d| d > settings.threshold)
            .count();
        assert!(big * 4 <= path.steps.len(), "{:?}", path.steps);
        let f = frames(&path, 9);
        assert_eq!(f.len(), 9);
        assert_eq!(f[0].params, a.params);
        assert_eq!(f[8].params, b.params);
    }

    #[test]
    fn periodic_parameters_interpolate_the_short_way() {
        let s = by_name("stripes").unwrap();
        let p = lerp_params(s, &[4.0, 170.0, 0.3, 0.1], &[4.0, 10.0, 0.3, 0.1], 0.5);
        assert!(
            (p[1] - 0.0).abs() < 1e-9 || (p[1] - 180.0).abs() < 1e-9,
            "{p:?}"
        );
    }
}
