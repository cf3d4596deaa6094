//! The shader library (Bourque–Dudek §3.1): the procedural textures p_i
//! that matching chooses from, each a grey pattern f(u, v; x) in about
//! [0, 1] over the unit square, coloured by two colour parameters.
//!
//! Every parameter is declared with its range and kind. Parameters that a
//! shift-invariant similarity cannot see (phases, noise seeds) are not
//! parameters: each shader's noise seed and origin are fixed, so a render is
//! a pure function of the parameters. Equivalent settings are ruled out by
//! the ranges: stripes' duty stops at ½ (duty d with swapped colours is duty
//! 1 − d), angles are periodic over 180°.

use noise::{NoiseFn, Perlin};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::imaging::ColorImage;

/// How a parameter varies.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Kind {
    /// Any value in [min, max].
    Continuous,
    /// Whole numbers in [min, max]; matching keeps them whole.
    Integer,
    /// An angle in degrees: [min, max) wraps round (max is min again).
    Periodic,
}

/// One parameter of a shader.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct ParamSpec {
    pub name: &'static str,
    pub min: f64,
    pub max: f64,
    pub kind: Kind,
    pub doc: &'static str,
}

impl ParamSpec {
    const fn new(name: &'static str, min: f64, max: f64, kind: Kind, doc: &'static str) -> Self {
        Self {
            name,
            min,
            max,
            kind,
            doc,
        }
    }

    /// The range's width.
    pub fn span(&self) -> f64 {
        self.max - self.min
    }

    /// `v` made valid: clamped (wrapped if periodic), rounded if integer.
    pub fn legal(&self, v: f64) -> f64 {
        let v = if v.is_finite() { v } else { self.min };
        match self.kind {
            Kind::Continuous => v.clamp(self.min, self.max),
            Kind::Integer => v.round().clamp(self.min, self.max),
            Kind::Periodic => self.min + (v - self.min).rem_euclid(self.span()),
        }
    }

    /// The distance of two values as a fraction of the range (the shorter
    /// way round for periodic parameters).
    pub fn distance(&self, a: f64, b: f64) -> f64 {
        let d = (a - b).abs() / self.span();
        match self.kind {
            Kind::Periodic => {
                let d = d.rem_euclid(1.0);
                d.min(1.0 - d)
            }
            _ => d,
        }
    }

    /// `t` in [0, 1] mapped into the range (made legal).
    pub fn from_unit(&self, t: f64) -> f64 {
        self.legal(self.min + t * self.span())
    }

    /// `v` as a fraction of the range.
    pub fn to_unit(&self, v: f64) -> f64 {
        (v - self.min) / self.span()
    }
}

/// The colour parameters every shader has: the colour at f = 0 and at f = 1
/// (RGB, 0..=255), in between a straight mix.
pub const COLOUR_PARAMS: [&str; 2] = ["colour_low", "colour_high"];

/// A procedural shader: declared parameters and its pattern.
pub struct Shader {
    pub name: &'static str,
    pub doc: &'static str,
    pub params: &'static [ParamSpec],
    pattern: fn(&[f64], &Perlin, f64, f64) -> f64,
    seed: u32,
}

impl std::fmt::Debug for Shader {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name)
    }
}

impl Shader {
    /// The pattern at (u, v) for legal parameters `p`.
    pub fn value(&self, p: &[f64], noise: &Perlin, u: f64, v: f64) -> f64 {
        (self.pattern)(p, noise, u, v)
    }

    /// `p` made legal, one value per parameter.
    pub fn legal(&self, p: &[f64]) -> Vec<f64> {
        self.params
            .iter()
            .zip(p)
            .map(|(s, &v)| s.legal(v))
            .collect()
    }

    /// The indices of the parameters a simplex moves: all but whole numbers.
    pub fn continuous(&self) -> Vec<usize> {
        (0..self.params.len())
            .filter(|&i| self.params[i].kind != Kind::Integer)
            .collect()
    }

    /// `base` with its parameters `free` set from the unit-box point `x`,
    /// made legal.
    pub fn from_unit_box(&self, base: &[f64], free: &[usize], x: &[f64]) -> Vec<f64> {
        let mut p = base.to_vec();
        for (&i, &t) in free.iter().zip(x) {
            p[i] = self.params[i].from_unit(t);
        }
        self.legal(&p)
    }

    /// The unit-box point of `p`'s parameters `free`.
    pub fn to_unit_box(&self, p: &[f64], free: &[usize]) -> Vec<f64> {
        free.iter().map(|&i| self.params[i].to_unit(p[i])).collect()
    }

    /// The largest per-parameter distance of `a` and `b`, as a fraction of
    /// each range (integers count as far as they differ).
    pub fn distance(&self, a: &[f64], b: &[f64]) -> f64 {
        self.params
            .iter()
            .zip(a.iter().zip(b))
            .map(|(s, (&x, &y))| s.distance(x, y))
            .fold(0.0, f64::max)
    }

    /// The grey pattern, `width`×`height`, with the unit square spanning
    /// `side` pixels (row-parallel, the same for any thread count).
    pub fn render_field(&self, p: &[f64], width: usize, height: usize, side: usize) -> Vec<f32> {
        let p = self.legal(p);
        let noise = Perlin::new(self.seed);
        let mut out = vec![0f32; width * height];
        let s = side.max(1) as f64;
        out.par_chunks_mut(width.max(1))
            .enumerate()
            .for_each(|(y, row)| {
                let v = (y as f64 + 0.5) / s;
                for (x, o) in row.iter_mut().enumerate() {
                    let u = (x as f64 + 0.5) / s;
                    *o = self.value(&p, &noise, u, v) as f32;
                }
            });
        out
    }
}

/// A field coloured: c_low + (c_high − c_low)·f, rounded to 8 bits.
pub fn colourise(
    field: &[f32],
    width: usize,
    height: usize,
    colours: &[[f64; 3]; 2],
) -> ColorImage {
    let mut rgb = vec![0u8; width * height * 3];
    rgb.par_chunks_mut(3 * width.max(1))
        .zip(field.par_chunks(width.max(1)))
        .for_each(|(row, f)| {
            for (px, &t) in row.chunks_exact_mut(3).zip(f) {
                for k in 0..3 {
                    let c = colours[0][k] + (colours[1][k] - colours[0][k]) * f64::from(t);
                    px[k] = c.round().clamp(0.0, 255.0) as u8;
                }
            }
        });
    ColorImage::from_vec(width, height, rgb)
}

/// A 32-bit integer hash of a cell and a salt, in [0, 1).
fn hash01(i: i64, j: i64, salt: u32) -> f64 {
    let mut h = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (j as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ u64::from(salt).wrapping_mul(0x1656_67B1_9E37_79F9);
    h ^= h >> 33;
    h = h.wrapping_mul(0xFF51_AFD7_ED55_8CCD);
    h ^= h >> 33;
    h = h.wrapping_mul(0xC4CE_B9FE_1A85_EC53);
    h ^= h >> 33;
    (h >> 11) as f64 / (1u64 << 53) as f64
}

fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Fractal sum of 4 octaves of Perlin noise, about [−1, 1]; `abs` sums
/// |noise| (turbulence), about [0, 1].
fn fbm(noise: &Perlin, u: f64, v: f64, scale: f64, roughness: f64, abs: bool) -> f64 {
    let (mut sum, mut norm, mut amp, mut f) = (0.0, 0.0, 1.0, scale);
    for o in 0..4 {
        // Octave offsets keep the lattice zeros of one octave off the others'.
        let off = 17.31 * f64::from(o) + 0.37;
        let n = noise.get([u * f + off, v * f - off]);
        sum += amp * if abs { n.abs() } else { n };
        norm += amp;
        amp *= roughness;
        f *= 2.0;
    }
    sum / norm
}

use Kind::{Continuous, Integer, Periodic};

const CLOUDS: &[ParamSpec] = &[
    ParamSpec::new(
        "scale",
        2.0,
        6.0,
        Continuous,
        "base frequency, cycles per unit",
    ),
    ParamSpec::new(
        "roughness",
        0.3,
        0.75,
        Continuous,
        "amplitude kept per octave",
    ),
];

fn clouds(p: &[f64], n: &Perlin, u: f64, v: f64) -> f64 {
    0.5 + 0.7 * fbm(n, u, v, p[0], p[1], false)
}

fn turbulence(p: &[f64], n: &Perlin, u: f64, v: f64) -> f64 {
    1.2 * fbm(n, u, v, p[0], p[1], true)
}

const MARBLE: &[ParamSpec] = &[
    ParamSpec::new("veins", 1.0, 8.0, Continuous, "veins per unit"),
    ParamSpec::new("angle", 0.0, 180.0, Periodic, "vein direction, degrees"),
    ParamSpec::new("turbulence", 0.2, 2.5, Continuous, "vein distortion"),
];

fn marble(p: &[f64], n: &Perlin, u: f64, v: f64) -> f64 {
    let a = p[1].to_radians();
    let d = u * a.cos() + v * a.sin();
    let t = fbm(n, u, v, 4.0, 0.5, true);
    (std::f64::consts::PI * (p[0] * d + p[2] * t))
        .sin()
        .abs()
        .sqrt()
}

const WOOD: &[ParamSpec] = &[
    ParamSpec::new("rings", 4.0, 20.0, Continuous, "rings per unit"),
    ParamSpec::new(
        "distortion",
        0.0,
        0.6,
        Continuous,
        "grain noise in the rings",
    ),
    ParamSpec::new("sharpness", 1.0, 5.0, Continuous, "ring profile exponent"),
];

fn wood(p: &[f64], n: &Perlin, u: f64, v: f64) -> f64 {
    // The tree's axis is off the square, so the rings are arcs.
    let r = (u + 0.4).hypot(v - 0.35);
    let g = n.get([u * 3.0 + 0.31, v * 12.0 + 0.77]);
    let c = 0.5 + 0.5 * (std::f64::consts::TAU * (p[0] * r + p[1] * g)).cos();
    c.powf(p[2])
}

const CELLS: &[ParamSpec] = &[
    ParamSpec::new(
        "cells",
        3.0,
        10.0,
        Integer,
        "cells per unit (Worley points on a jittered grid)",
    ),
    ParamSpec::new(
        "jitter",
        0.2,
        1.0,
        Continuous,
        "how far each point strays from its cell centre",
    ),
    ParamSpec::new(
        "borders",
        0.0,
        1.0,
        Continuous,
        "mix of F1 (0: dots) and F2 − F1 (1: cell walls)",
    ),
];

/// Nearest and second-nearest feature-point distances (in cells) of a
/// jittered grid of `n` cells per unit.
fn worley(u: f64, v: f64, n: f64, jitter: f64, salt: u32) -> (f64, f64) {
    let (x, y) = (u * n, v * n);
    let (ci, cj) = (x.floor() as i64, y.floor() as i64);
    let (mut f1, mut f2) = (f64::INFINITY, f64::INFINITY);
    for dj in -1..=1 {
        for di in -1..=1 {
            let (i, j) = (ci + di, cj + dj);
            let px = i as f64 + 0.5 + jitter * (hash01(i, j, salt) - 0.5);
            let py = j as f64 + 0.5 + jitter * (hash01(i, j, salt + 1) - 0.5);
            let d = (px - x).hypot(py - y);
            if d < f1 {
                f2 = f1;
                f1 = d;
            } else if d < f2 {
                f2 = d;
            }
        }
    }
    (f1, f2)
}

fn cells(p: &[f64], _: &Perlin, u: f64, v: f64) -> f64 {
    let (f1, f2) = worley(u, v, p[0], p[1], 11);
    (1.0 - p[2]) * (1.2 * f1) + p[2] * (1.0 - 2.0 * (f2 - f1)).max(0.0)
}

const BRICKS: &[ParamSpec] = &[
    ParamSpec::new("rows", 3.0, 10.0, Integer, "brick rows per unit"),
    ParamSpec::new(
        "aspect",
        1.0,
        4.0,
        Continuous,
        "brick length over height (1: square tiles)",
    ),
    ParamSpec::new(
        "mortar",
        0.04,
        0.25,
        Continuous,
        "mortar width, fraction of a brick's height",
    ),
    ParamSpec::new(
        "bond",
        0.0,
        2.0,
        Integer,
        "every other row shifted by 0, ¼ or ½ a brick (stack, quarter, running bond)",
    ),
    ParamSpec::new("grain", 0.0, 0.4, Continuous, "noise on the bricks' faces"),
];

fn bricks(p: &[f64], n: &Perlin, u: f64, v: f64) -> f64 {
    let (y, len) = (v * p[0], p[1]);
    let row = y.floor();
    let shift = if (row as i64).rem_euclid(2) == 1 {
        0.25 * p[3]
    } else {
        0.0
    };
    let x = u * p[0] / len + shift;
    let col = x.floor();
    // Distances to the brick's edges, in brick heights.
    let dy = (y - row).min(1.0 - (y - row));
    let dx = (x - col).min(1.0 - (x - col)) * len;
    let edge = dx.min(dy);
    let half = p[2] / 2.0;
    let inside = smoothstep(half - 0.03, half + 0.03, edge);
    let grain = n.get([u * p[0] * 3.0 + 0.5, v * p[0] * 3.0 + 0.25]);
    let shade = 0.8 + 0.1 * hash01(col as i64, row as i64, 23) + p[4] * grain;
    inside * shade
}

const SPOTS: &[ParamSpec] = &[
    ParamSpec::new(
        "spots",
        3.0,
        10.0,
        Integer,
        "spots per unit (one per cell, jittered)",
    ),
    ParamSpec::new(
        "radius",
        0.15,
        0.45,
        Continuous,
        "spot radius, fraction of a cell",
    ),
    ParamSpec::new(
        "softness",
        0.05,
        0.6,
        Continuous,
        "edge blur, fraction of the radius",
    ),
];

fn spots(p: &[f64], _: &Perlin, u: f64, v: f64) -> f64 {
    let (x, y, r) = (u * p[0], v * p[0], p[1]);
    let (ci, cj) = (x.floor() as i64, y.floor() as i64);
    let room = (1.0 - 2.0 * r).max(0.0);
    let mut best: f64 = 0.0;
    for dj in -1..=1 {
        for di in -1..=1 {
            let (i, j) = (ci + di, cj + dj);
            let px = i as f64 + 0.5 + room * (hash01(i, j, 31) - 0.5);
            let py = j as f64 + 0.5 + room * (hash01(i, j, 32) - 0.5);
            let d = (px - x).hypot(py - y);
            let h = (p[2] * r).max(1e-6);
            best = best.max(1.0 - smoothstep(r - h, r, d));
        }
    }
    best
}

const STRIPES: &[ParamSpec] = &[
    ParamSpec::new("stripes", 2.0, 16.0, Continuous, "stripes per unit"),
    ParamSpec::new("angle", 0.0, 180.0, Periodic, "stripe direction, degrees"),
    ParamSpec::new(
        "duty",
        0.1,
        0.5,
        Continuous,
        "width of the high-colour band, fraction of a period",
    ),
    ParamSpec::new(
        "softness",
        0.02,
        0.3,
        Continuous,
        "edge ramp, fraction of the band",
    ),
];

fn stripes(p: &[f64], _: &Perlin, u: f64, v: f64) -> f64 {
    let a = p[1].to_radians();
    let x = p[0] * (u * a.cos() + v * a.sin());
    let e = (x - x.floor() - 0.5).abs();
    let (d, h) = (p[2] / 2.0, p[2] * p[3] / 2.0);
    1.0 - smoothstep(d - h, d + h, e)
}

const STARS: &[ParamSpec] = &[
    ParamSpec::new("points", 3.0, 8.0, Integer, "points of each star"),
    ParamSpec::new("grid", 2.0, 6.0, Integer, "stars per unit"),
    ParamSpec::new(
        "size",
        0.5,
        0.95,
        Continuous,
        "outer radius, fraction of half a cell",
    ),
    ParamSpec::new(
        "inner",
        0.3,
        0.7,
        Continuous,
        "inner radius over outer radius",
    ),
];

fn stars(p: &[f64], _: &Perlin, u: f64, v: f64) -> f64 {
    use std::f64::consts::{FRAC_PI_2, TAU};
    let (n, g) = (p[0], p[1]);
    let (x, y) = (u * g, v * g);
    let (dx, dy) = (x - x.floor() - 0.5, y - y.floor() - 0.5);
    let rho = dx.hypot(dy);
    let sector = TAU / n;
    // Angle from the nearest point's direction, folded into [0, π/n].
    let phi = (dy.atan2(dx) + FRAC_PI_2).rem_euclid(sector);
    let phi = (phi - sector / 2.0).abs();
    let phi = sector / 2.0 - phi;
    let outer = 0.5 * p[2];
    let inner = outer * p[3];
    let (ax, ay) = (outer, 0.0);
    let (bx, by) = (inner * (sector / 2.0).cos(), inner * (sector / 2.0).sin());
    let (px, py) = (rho * phi.cos(), rho * phi.sin());
    // Signed distance to the edge from the point to the inner vertex,
    // positive inside (the side of the centre).
    let (ex, ey) = (bx - ax, by - ay);
    let len = ex.hypot(ey).max(1e-9);
    let side = (ex * (py - ay) - ey * (px - ax)) / len;
    let centre_side = ex * (0.0 - ay) - ey * (0.0 - ax);
    let s = if centre_side >= 0.0 { side } else { -side };
    smoothstep(-0.015, 0.015, s)
}

/// The library, in a fixed order (catalogues refer to shaders by name).
pub static LIBRARY: &[Shader] = &[
    Shader {
        name: "clouds",
        doc: "fractal Perlin noise (fBm, 4 octaves)",
        params: CLOUDS,
        pattern: clouds,
        seed: 101,
    },
    Shader {
        name: "turbulence",
        doc: "sum of |Perlin noise| over 4 octaves: creased, fiery",
        params: CLOUDS,
        pattern: turbulence,
        seed: 202,
    },
    Shader {
        name: "marble",
        doc: "sine veins distorted by turbulence",
        params: MARBLE,
        pattern: marble,
        seed: 303,
    },
    Shader {
        name: "wood",
        doc: "noisy growth rings round an axis off the square",
        params: WOOD,
        pattern: wood,
        seed: 404,
    },
    Shader {
        name: "cells",
        doc: "Worley noise: dots to cell walls",
        params: CELLS,
        pattern: cells,
        seed: 505,
    },
    Shader {
        name: "bricks",
        doc: "running-bond bricks with mortar",
        params: BRICKS,
        pattern: bricks,
        seed: 606,
    },
    Shader {
        name: "spots",
        doc: "soft round spots, one per jittered cell",
        params: SPOTS,
        pattern: spots,
        seed: 707,
    },
    Shader {
        name: "stripes",
        doc: "straight stripes at any angle",
        params: STRIPES,
        pattern: stripes,
        seed: 808,
    },
    Shader {
        name: "stars",
        doc: "a grid of n-pointed stars",
        params: STARS,
        pattern: stars,
        seed: 909,
    },
];

/// The shader called `name`.
pub fn by_name(name: &str) -> Option<&'static Shader> {
    LIBRARY.iter().find(|s| s.name == name)
}

/// The index of the shader called `name`.
pub fn index_of(name: &str) -> Option<usize> {
    LIBRARY.iter().position(|s| s.name == name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_shader_varies_and_stays_near_the_unit_range() {
        for s in LIBRARY {
            let mid: Vec<f64> = s.params.iter().map(|p| p.from_unit(0.5)).collect();
            let f = s.render_field(&mid, 48, 48, 48);
            let (lo, hi) = f
                .iter()
                .fold((f32::MAX, f32::MIN), |(a, b), &x| (a.min(x), b.max(x)));
            assert!(hi - lo > 0.3, "{}: flat pattern {lo}..{hi}", s.name);
            assert!(lo > -0.2 && hi < 1.2, "{}: {lo}..{hi}", s.name);
        }
    }

    #[test]
    fn integer_and_periodic_parameters_are_made_legal() {
        let rows = &BRICKS[0];
        assert_eq!(rows.legal(4.4), 4.0);
        assert_eq!(rows.legal(99.0), 10.0);
        let angle = &STRIPES[1];
        assert_eq!(angle.legal(190.0), 10.0);
        assert!((angle.distance(1.0, 179.0) - 2.0 / 180.0).abs() < 1e-12);
    }

    #[test]
    fn rendering_does_not_depend_on_threads() {
        let s = by_name("cells").unwrap();
        let p = [5.0, 0.7, 0.4];
        let [one, two] = crate::procedural::one_and_two_threads();
        let a = one.install(|| s.render_field(&p, 40, 33, 40));
        let b = two.install(|| s.render_field(&p, 40, 33, 40));
        assert_eq!(a, b);
    }
}
