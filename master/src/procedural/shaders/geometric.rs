//! The geometric family of the shader library (Bourque–Dudek §3.1): cells,
//! bricks, planks, spots, stripes and stars, built on a cell hash. Counts
//! run from a few per unit to a couple of dozen, as in material photos.

use noise::{NoiseFn, Perlin};

use super::Kind::{Continuous, Integer, Periodic};
use super::ParamSpec;

/// A 32-bit integer hash of a cell and a salt, in [0, 1).
pub(super) fn hash01(i: i64, j: i64, salt: u32) -> f64 {
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

pub(super) fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

pub(super) const CELLS: &[ParamSpec] = &[
    ParamSpec::new(
        "cells",
        2.0,
        20.0,
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
    ParamSpec::new(
        "width",
        0.03,
        0.35,
        Continuous,
        "edge width of the dots and walls, fraction of a cell",
    ),
];

/// The squared distances (in cells) from (u, v) to the points of the 3×3
/// cells of a jittered grid of `n` cells per unit round it, each with its
/// cell. Squared: their order is the distances' order, and two roots per
/// pixel are cheaper than nine.
fn jittered_points(
    u: f64,
    v: f64,
    n: f64,
    jitter: f64,
    salt: u32,
) -> impl Iterator<Item = (f64, (i64, i64))> {
    let (x, y) = (u * n, v * n);
    let (ci, cj) = (x.floor() as i64, y.floor() as i64);
    (-1..=1).flat_map(move |dj| {
        (-1..=1).map(move |di| {
            let (i, j) = (ci + di, cj + dj);
            let px = i as f64 + 0.5 + jitter * (hash01(i, j, salt) - 0.5);
            let py = j as f64 + 0.5 + jitter * (hash01(i, j, salt + 1) - 0.5);
            ((px - x).powi(2) + (py - y).powi(2), (i, j))
        })
    })
}

/// Nearest and second-nearest feature-point distances (in cells) of a
/// jittered grid of `n` cells per unit.
pub(super) fn worley(u: f64, v: f64, n: f64, jitter: f64, salt: u32) -> (f64, f64) {
    let (mut f1, mut f2) = (f64::INFINITY, f64::INFINITY);
    for (d, _) in jittered_points(u, v, n, jitter, salt) {
        if d < f1 {
            f2 = f1;
            f1 = d;
        } else if d < f2 {
            f2 = d;
        }
    }
    (f1.sqrt(), f2.sqrt())
}

/// The cell of a jittered grid of `n` cells per unit whose point is nearest
/// to (u, v) (the F1 point of [`worley`]).
fn nearest_cell(u: f64, v: f64, n: f64, jitter: f64, salt: u32) -> (i64, i64) {
    let mut best = (f64::INFINITY, (0, 0));
    for (d, cell) in jittered_points(u, v, n, jitter, salt) {
        if d < best.0 {
            best = (d, cell);
        }
    }
    best.1
}

/// The hash salt of [`cells`]' Worley points, which [`cells_across`] counts.
const CELLS_SALT: u32 = 11;

/// Rows, their length in units, and samples per cell along each row of
/// [`cells_across`].
const ACROSS_ROWS: usize = 64;
const ACROSS_SPAN: usize = 4;
const ACROSS_SAMPLES_PER_CELL: usize = 32;
const ACROSS_START: f64 = 0.37;

/// The cells per unit that a horizontal line meets in [`cells`]' pattern
/// `p` (legal parameters): the walls it crosses per unit of length, over
/// `ACROSS_ROWS` rows of `ACROSS_SPAN` units, walked in steps of 1/32 of a
/// cell. This is what a count of a photo's cells along a row measures (the
/// stones across the image, a part cell at an edge counted as a part), free
/// of the edges' part cells. A square grid gives its points per unit `n`;
/// jittered points give more, since a line through n² points scattered at
/// random meets about (4/π)·n cells per unit (a Poisson–Voronoi
/// tessellation's walls, 2·n per unit area, met by a line at 2/π of that).
pub(super) fn cells_across(p: &[f64]) -> f64 {
    let (n, jitter) = (p[0], p[1]);
    let steps = (n.ceil() as usize).max(1) * ACROSS_SAMPLES_PER_CELL * ACROSS_SPAN;
    let walls: usize = (0..ACROSS_ROWS)
        .map(|r| {
            let v = (r as f64 + 0.5) / ACROSS_ROWS as f64;
            let cells = (0..steps).map(|k| {
                // Rows start off the grid's lines (0.37 of a unit), so a
                // square grid's walls fall inside the span, n per unit.
                let u = ACROSS_START + ACROSS_SPAN as f64 * (k as f64 + 0.5) / steps as f64;
                nearest_cell(u, v, n, jitter, CELLS_SALT)
            });
            let mut last = None;
            let mut crossed = 0;
            for c in cells {
                crossed += usize::from(last.is_some_and(|l| l != c));
                last = Some(c);
            }
            crossed
        })
        .sum();
    walls as f64 / (ACROSS_ROWS * ACROSS_SPAN) as f64
}

/// Worley cells (§3.1): a mix of F1 dots and F2 − F1 walls, each falling
/// off over `width` of a cell, so that the walls' thickness is free of the
/// count (caustic lines and the gaps between beans are thin at any spacing).
pub(super) fn cells(p: &[f64], _: &Perlin, u: f64, v: f64) -> f64 {
    let (f1, f2) = worley(u, v, p[0], p[1], CELLS_SALT);
    let w = 2.0 * p[3];
    (1.0 - p[2]) * (f1 / w).min(1.0) + p[2] * (1.0 - (f2 - f1) / w).max(0.0)
}

pub(super) const BRICKS: &[ParamSpec] = &[
    ParamSpec::new("rows", 2.0, 24.0, Integer, "brick rows per unit"),
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
    ParamSpec::new(
        "angle",
        0.0,
        180.0,
        Periodic,
        "direction across the rows, degrees (90: horizontal rows)",
    ),
];

pub(super) fn bricks(p: &[f64], n: &Perlin, u: f64, v: f64) -> f64 {
    // Rows stacked across `angle` (90°: horizontal rows).
    let a = p[5].to_radians();
    let (c, s) = (a.cos(), a.sin());
    let (across, along) = (u * c + v * s, u * s - v * c);
    let (y, len) = (across * p[0], p[1]);
    let row = y.floor();
    let shift = if (row as i64).rem_euclid(2) == 1 {
        0.25 * p[3]
    } else {
        0.0
    };
    let x = along * p[0] / len + shift;
    let col = x.floor();
    // Distances to the brick's edges, in brick heights.
    let dy = (y - row).min(1.0 - (y - row));
    let dx = (x - col).min(1.0 - (x - col)) * len;
    let edge = dx.min(dy);
    let half = p[2] / 2.0;
    let inside = smoothstep(half - 0.03, half + 0.03, edge);
    let grain = n.get([along * p[0] * 3.0 + 0.5, across * p[0] * 3.0 + 0.25]);
    let shade = 0.8 + 0.1 * hash01(col as i64, row as i64, 23) + p[4] * grain;
    inside * shade
}

pub(super) const SPOTS: &[ParamSpec] = &[
    ParamSpec::new(
        "spots",
        2.0,
        16.0,
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

pub(super) fn spots(p: &[f64], _: &Perlin, u: f64, v: f64) -> f64 {
    let (x, y, r) = (u * p[0], v * p[0], p[1]);
    let (ci, cj) = (x.floor() as i64, y.floor() as i64);
    let room = (1.0 - 2.0 * r).max(0.0);
    let mut best: f64 = 0.0;
    for dj in -1..=1 {
        for di in -1..=1 {
            let (i, j) = (ci + di, cj + dj);
            let px = i as f64 + 0.5 + room * (hash01(i, j, 31) - 0.5);
            let py = j as f64 + 0.5 + room * (hash01(i, j, 32) - 0.5);
            // A point farther than r adds nothing (the step is 1 there):
            // its root is not taken.
            let d2 = (px - x).powi(2) + (py - y).powi(2);
            if d2 > r * r * (1.0 + 1e-9) {
                continue;
            }
            let h = (p[2] * r).max(1e-6);
            best = best.max(1.0 - smoothstep(r - h, r, d2.sqrt()));
        }
    }
    best
}

pub(super) const STRIPES: &[ParamSpec] = &[
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

pub(super) fn stripes(p: &[f64], _: &Perlin, u: f64, v: f64) -> f64 {
    let a = p[1].to_radians();
    let x = p[0] * (u * a.cos() + v * a.sin());
    let e = (x - x.floor() - 0.5).abs();
    let (d, h) = (p[2] / 2.0, p[2] * p[3] / 2.0);
    1.0 - smoothstep(d - h, d + h, e)
}

pub(super) const STARS: &[ParamSpec] = &[
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

pub(super) fn stars(p: &[f64], _: &Perlin, u: f64, v: f64) -> f64 {
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

pub(super) const PLANKS: &[ParamSpec] = &[
    ParamSpec::new("boards", 2.0, 20.0, Integer, "boards per unit, across"),
    ParamSpec::new(
        "angle",
        0.0,
        180.0,
        Periodic,
        "direction across the boards, degrees (0: vertical boards)",
    ),
    ParamSpec::new(
        "length",
        2.0,
        12.0,
        Continuous,
        "board length over width (end joints staggered per board)",
    ),
    ParamSpec::new(
        "gap",
        0.03,
        0.3,
        Continuous,
        "gap between boards, fraction of a board's width",
    ),
    ParamSpec::new("grain", 0.0, 0.5, Continuous, "streaks along the boards"),
];

/// Parallel boards of `boards` per unit across direction `angle`, each of
/// its own shade, with end joints staggered at random per board and grain
/// stretched along it: unlike bricks, only one direction repeats.
pub(super) fn planks(p: &[f64], n: &Perlin, u: f64, v: f64) -> f64 {
    let a = p[1].to_radians();
    let (c, s) = (a.cos(), a.sin());
    let across = p[0] * (u * c + v * s);
    let along = p[0] * (-u * s + v * c);
    let board = across.floor();
    let b = board as i64;
    let seg_pos = along / p[2] + hash01(b, 0, 41);
    let seg = seg_pos.floor();
    let dx = (across - board).min(1.0 - (across - board));
    let dy = (seg_pos - seg).min(1.0 - (seg_pos - seg)) * p[2];
    let half = p[3] / 2.0;
    let inside = smoothstep(half - 0.03, half + 0.03, dx.min(dy));
    let grain = n.get([across * 4.0 + 0.5, along * 0.3 + 0.25]);
    let shade = 0.75 + 0.2 * hash01(b, seg as i64, 43) + p[4] * grain;
    inside * shade
}
