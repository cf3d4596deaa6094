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

use ::noise::Perlin;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::arrangement::Arrangement::{self, Isotropic, Lattice, Parallel};
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

/// Which parameters a texture's periods set (the seeds of the global
/// search, Bourque–Dudek §3.2.1; see `periodicity`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layout {
    /// Nothing repeats at a set period (noise).
    Free,
    /// Rows: `count` rows per unit from the period across them, `aspect`
    /// (when given) from the period along them over that one, `angle` (when
    /// given) the direction across them (else rows are horizontal).
    Rows {
        count: usize,
        aspect: Option<usize>,
        angle: Option<usize>,
    },
    /// Parallel lines: `count` per unit and the `angle` across them.
    Lines { count: usize, angle: usize },
    /// Scattered features: `count` per unit from their spacing.
    Scatter { count: usize },
}

impl Layout {
    /// The index of the parameter that counts rows, lines or features per
    /// unit; `None` for noise.
    pub fn count(self) -> Option<usize> {
        match self {
            Self::Free => None,
            Self::Rows { count, .. } | Self::Lines { count, .. } | Self::Scatter { count } => {
                Some(count)
            }
        }
    }
}

/// A procedural shader: declared parameters and its pattern.
pub struct Shader {
    pub name: &'static str,
    pub doc: &'static str,
    pub params: &'static [ParamSpec],
    pub layout: Layout,
    /// The arrangements its patterns show (the targets it is tried on).
    pub shows: &'static [Arrangement],
    pattern: fn(&[f64], &Perlin, f64, f64) -> f64,
    seed: u32,
    /// Scattered features whose count parameter is not what a line across
    /// the pattern meets (jittered Worley cells): the mean number of
    /// features a row of the unit square crosses, as photos are counted.
    crossed: Option<fn(&[f64]) -> f64>,
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

    /// The count the pattern `p` shows across the unit square (the analysed
    /// square): its rows or lines per unit, its scattered features along a
    /// row; `None` for noise. For rows, lines and spots on a jittered grid
    /// it is the count parameter; for Worley cells, whose points stray over
    /// their whole cell, a row meets more cells than there are points per
    /// unit (up to 4/π times as many), and they are counted along rows.
    pub fn count_across(&self, p: &[f64]) -> Option<f64> {
        let i = self.layout.count()?;
        let p = self.legal(p);
        match self.crossed {
            Some(f) => Some(f(&p)),
            None => p.get(i).copied(),
        }
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

mod geometric;
mod noise;

use self::noise::{clouds, marble, turbulence, wood, CLOUDS, MARBLE, WOOD};
use geometric::{
    bricks, cells, cells_across, planks, spots, stars, stripes, BRICKS, CELLS, PLANKS, SPOTS,
    STARS, STRIPES,
};

/// The library, in a fixed order (catalogues refer to shaders by name).
pub static LIBRARY: &[Shader] = &[
    Shader {
        name: "clouds",
        doc: "fractal Perlin noise (fBm, 4 octaves)",
        params: CLOUDS,
        layout: Layout::Free,
        shows: &[Isotropic],
        pattern: clouds,
        seed: 101,
        crossed: None,
    },
    Shader {
        name: "turbulence",
        doc: "sum of |Perlin noise| over 4 octaves: creased, fiery",
        params: CLOUDS,
        layout: Layout::Free,
        shows: &[Isotropic],
        pattern: turbulence,
        seed: 202,
        crossed: None,
    },
    Shader {
        name: "marble",
        doc: "sine veins distorted by turbulence",
        params: MARBLE,
        layout: Layout::Lines { count: 0, angle: 1 },
        shows: &[Parallel],
        pattern: marble,
        seed: 303,
        crossed: None,
    },
    Shader {
        name: "wood",
        doc: "noisy growth rings round an axis off the square",
        params: WOOD,
        layout: Layout::Free,
        shows: &[Parallel],
        pattern: wood,
        seed: 404,
        crossed: None,
    },
    Shader {
        name: "cells",
        doc: "Worley noise: dots to cell walls",
        params: CELLS,
        layout: Layout::Scatter { count: 0 },
        shows: &[Isotropic],
        pattern: cells,
        seed: 505,
        crossed: Some(cells_across),
    },
    Shader {
        name: "bricks",
        doc: "running-bond bricks with mortar",
        params: BRICKS,
        layout: Layout::Rows {
            count: 0,
            aspect: Some(1),
            angle: Some(5),
        },
        shows: &[Lattice],
        pattern: bricks,
        seed: 606,
        crossed: None,
    },
    Shader {
        name: "spots",
        doc: "soft round spots, one per jittered cell",
        params: SPOTS,
        layout: Layout::Scatter { count: 0 },
        shows: &[Isotropic],
        pattern: spots,
        seed: 707,
        crossed: None,
    },
    Shader {
        name: "stripes",
        doc: "straight stripes at any angle",
        params: STRIPES,
        layout: Layout::Lines { count: 0, angle: 1 },
        shows: &[Parallel],
        pattern: stripes,
        seed: 808,
        crossed: None,
    },
    Shader {
        name: "stars",
        doc: "a grid of n-pointed stars",
        params: STARS,
        layout: Layout::Rows {
            count: 1,
            aspect: None,
            angle: None,
        },
        shows: &[Lattice],
        pattern: stars,
        seed: 909,
        crossed: None,
    },
    Shader {
        name: "planks",
        doc: "parallel boards with staggered end joints and grain",
        params: PLANKS,
        layout: Layout::Lines { count: 0, angle: 1 },
        shows: &[Parallel],
        pattern: planks,
        seed: 1010,
        crossed: None,
    },
];

/// The shader called `name`.
pub fn by_name(name: &str) -> Option<&'static Shader> {
    LIBRARY.iter().find(|s| s.name == name)
}

/// The library as text (`texsyn match shaders`): each shader's parameters,
/// ranges and kinds.
pub fn listing() -> String {
    let mut out = String::new();
    for s in LIBRARY {
        out.push_str(&format!("{}: {}\n", s.name, s.doc));
        for p in s.params {
            out.push_str(&format!(
                "  {:<11} {:?} {}..{}  {}\n",
                p.name, p.kind, p.min, p.max, p.doc
            ));
        }
        out.push_str("  colour_low, colour_high: RGB at pattern 0 and 1 (fitted, not searched)\n");
    }
    out
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

    /// The cells' edge width is a width, not a count: at one count, narrow
    /// walls (the caustics' bright lines, the gaps between beans) cover a
    /// small share of the cell and wide ones a large share, and the dots
    /// shrink the same way; the count stays the number of cells.
    #[test]
    fn the_cells_edge_width_narrows_walls_and_dots_at_one_count() {
        let s = by_name("cells").unwrap();
        let share = |borders: f64, width: f64, above: bool| {
            let f = s.render_field(&[6.0, 0.8, borders, width], 96, 96, 96);
            let n = f
                .iter()
                .filter(|&&x| if above { x > 0.5 } else { x < 0.5 })
                .count();
            n as f64 / f.len() as f64
        };
        // Walls (F2 − F1) are where the field is high.
        let (thin, thick) = (share(1.0, 0.05, true), share(1.0, 0.3, true));
        assert!(thin < 0.2 && thick > 2.0 * thin, "walls {thin} {thick}");
        // Dots (F1) are where it is low.
        let (small, large) = (share(0.0, 0.05, false), share(0.0, 0.3, false));
        assert!(small < 0.2 && large > 2.0 * small, "dots {small} {large}");
    }

    /// Cells are counted as a photo's are, by the walls a row crosses per
    /// unit: a square grid of n per unit gives n, jittered points more (at
    /// most the 4/π of points scattered at random), and the count follows
    /// n. Rows, lines and spots give their count parameter; noise none.
    #[test]
    fn cells_are_counted_by_the_walls_a_row_crosses() {
        for n in 2..=20 {
            let n = f64::from(n);
            assert_eq!(cells_across(&[n, 0.0, 1.0, 0.1]), n, "grid of {n}");
        }
        let cells = by_name("cells").unwrap();
        let across = |n: f64, jitter: f64| cells.count_across(&[n, jitter, 1.0, 0.1]).unwrap();
        for n in [4.0, 8.0, 16.0] {
            let (some, full) = (across(n, 0.5), across(n, 1.0));
            assert!(some > n && full > some, "{n}: jitter 0.5 {some}, 1 {full}");
            assert!(full < 4.0 / std::f64::consts::PI * n, "{n}: {full}");
        }
        let (a, b) = (across(5.0, 0.9), across(10.0, 0.9));
        assert!((b / a - 2.0).abs() < 0.15, "5: {a}, 10: {b}");
        let bricks = by_name("bricks").unwrap();
        assert_eq!(
            bricks.count_across(&[7.0, 2.0, 0.1, 2.0, 0.1, 90.0]),
            Some(7.0)
        );
        let spots = by_name("spots").unwrap();
        assert_eq!(spots.count_across(&[6.0, 0.3, 0.2]), Some(6.0));
        assert_eq!(by_name("clouds").unwrap().count_across(&[3.0, 0.5]), None);
    }

    #[test]
    fn integer_and_periodic_parameters_are_made_legal() {
        let rows = &BRICKS[0];
        assert_eq!(rows.legal(4.4), 4.0);
        assert_eq!(rows.legal(99.0), 24.0);
        let angle = &STRIPES[1];
        assert_eq!(angle.legal(190.0), 10.0);
        assert!((angle.distance(1.0, 179.0) - 2.0 / 180.0).abs() < 1e-12);
    }

    #[test]
    fn rendering_does_not_depend_on_threads() {
        let s = by_name("cells").unwrap();
        let p = [5.0, 0.7, 0.4, 0.2];
        let [one, two] = crate::procedural::one_and_two_threads();
        let a = one.install(|| s.render_field(&p, 40, 33, 40));
        let b = two.install(|| s.render_field(&p, 40, 33, 40));
        assert_eq!(a, b);
    }
}
