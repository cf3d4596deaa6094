//! Stitching one region over another along a minimum-error path, with the
//! adaptive boundary blending of Somol–Haindl §2.2.
//!
//! A [`Belt`] names the overlap in image coordinates and on which side R1 (the
//! region laid over) lies; [`stitch`] reads both regions through it in the
//! canonical frame of [`crate::seams`], finds the path and writes the result.

use crate::seams::{self as path, ErrorMap, Oscillating, Path};

use crate::imaging::ColorImage;

/// Which side of the overlap R1 comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Side {
    Left,
    Right,
    Top,
    Bottom,
}

/// An overlap rectangle of the canvas: `x, y` its top-left corner, `across`
/// its extent across the cut (the belt width), `along` its extent along it.
#[derive(Clone, Copy, Debug)]
pub struct Belt {
    pub x: usize,
    pub y: usize,
    pub across: usize,
    pub along: usize,
    /// The side of the belt R1 lies on.
    pub r1: Side,
}

impl Belt {
    /// Canvas pixel of canonical `(i, j)` (`i = 0` on R1's side).
    pub fn pixel(&self, i: usize, j: usize) -> (usize, usize) {
        let w = self.across;
        match self.r1 {
            Side::Left => (self.x + i, self.y + j),
            Side::Right => (self.x + w - 1 - i, self.y + j),
            Side::Top => (self.x + j, self.y + i),
            Side::Bottom => (self.x + j, self.y + w - 1 - i),
        }
    }
}

/// How far from the path R1 is blended towards it (§2.2).
#[derive(
    Clone,
    Copy,
    Debug,
    Default,
    PartialEq,
    Eq,
    serde::Serialize,
    serde::Deserialize,
    clap::ValueEnum,
)]
#[serde(rename_all = "lowercase")]
pub enum Blend {
    /// Every path pixel blends over ρ pixels, `α = min(d / ρ, 1)`. A patch
    /// path pulled to a tile's edge meets the template's pixels there
    /// wherever its error is, so the blend must reach there too
    /// (ARCHITECTURE §7).
    #[default]
    Feather,
    /// The paper's range scaled by the path pixel's error,
    /// `α = min(d / (ρ · E[m, n] / E_max), 1)`: only path pixels with an
    /// error near the belt's largest blend at all.
    Error,
}

impl Blend {
    /// What a tile set written before the choice existed used.
    pub fn recorded_default() -> Self {
        Self::Error
    }
}

/// How the cut is found and blended.
#[derive(Clone, Copy, Debug)]
pub struct StitchSettings {
    /// `Some`: the oscillating search; `None`: the optimal path (DP).
    pub search: Option<Oscillating>,
    /// Blending range ρ in pixels (0 = a hard cut).
    pub rho: f32,
    /// Added to the error the search sees per column towards R1's side
    /// (`pull · (w − 1 − i)`), so that among near-equal paths the one
    /// farther into R2 wins and R1 covers more; the cut's map, cost and
    /// blending keep the true error. 0 = the paper's search.
    pub pull: f32,
    /// How the blend's range follows the path's error.
    pub blend: Blend,
}

impl Default for StitchSettings {
    /// The oscillating search, ρ = 3 and the feathered blend. From its seam
    /// start the search stays within 1.15× of the optimum and runs several
    /// times faster than the `O(h·w³)` dynamic programme, which dominated
    /// the time per tile at wide belts (ARCHITECTURE §7).
    fn default() -> Self {
        Self {
            search: Some(Oscillating::default()),
            rho: 3.0,
            pull: 0.0,
            blend: Blend::default(),
        }
    }
}

/// The outcome of a stitch, in canonical coordinates.
#[derive(Clone, Debug)]
pub struct Cut {
    pub map: ErrorMap,
    pub path: Path,
    pub cost: f64,
    /// Per row, the first column of the path's run (`path.start`), which the
    /// blend reads for every pixel near the path.
    pub starts: Vec<usize>,
}

/// The path of the belt between `r1` and `r2` (both read at the belt's
/// canvas coordinates).
pub fn find_cut(
    belt: &Belt,
    r1: impl Fn(usize, usize) -> [u8; 3],
    r2: impl Fn(usize, usize) -> [u8; 3],
    settings: &StitchSettings,
) -> Cut {
    let (w, h) = (belt.across, belt.along);
    let mut a = Vec::with_capacity(w * h);
    let mut b = Vec::with_capacity(w * h);
    for j in 0..h {
        for i in 0..w {
            let (x, y) = belt.pixel(i, j);
            a.push(r1(x, y));
            b.push(r2(x, y));
        }
    }
    let map = ErrorMap::of(w, h, &a, &b);
    let search = |m: &ErrorMap| match settings.search {
        Some(o) => path::oscillating(m, o),
        None => path::optimal(m),
    };
    let path = if settings.pull > 0.0 && w > 1 {
        let biased: Vec<f32> = map
            .e
            .iter()
            .enumerate()
            .map(|(k, &e)| e + settings.pull * (w - 1 - k % w) as f32)
            .collect();
        search(&ErrorMap::new(w, h, biased))
    } else {
        search(&map)
    };
    let cost = path.cost(&map);
    let starts = (0..path.c.len()).map(|j| path.start(j)).collect();
    Cut {
        map,
        path,
        cost,
        starts,
    }
}

/// Blending weight of R1 at canonical `(i, j)` on R1's side, and the path
/// pixel whose R2 colour it is blended with (§2.2):
/// `α = min(d / (ρ · E[m, n]), 1)` with `(m, n)` the nearest path pixel and
/// `d` the distance to it. The paper prints `max(…, 1)`, which would make α
/// always 1 and turn blending off; `min` is what its text and Fig. 5
/// describe. With [`Blend::Error`] `E` is normalised by the map's largest
/// error, so that no pixel farther than ρ from the path is affected, as the
/// paper says of ρ; with [`Blend::Feather`] it is 1 at every path pixel. A
/// path pixel itself (d = 0) takes R2's colour; where the error is 0, α = 1.
pub fn blend_weight(
    cut: &Cut,
    settings: &StitchSettings,
    i: usize,
    j: usize,
) -> (f32, (usize, usize)) {
    let rho = settings.rho;
    let top = cut.map.max;
    if rho <= 0.0 || top <= 0.0 {
        return (1.0, (i, j));
    }
    let reach = rho.ceil() as usize;
    let (mut best_d2, mut best) = (usize::MAX, (i, j));
    for n in j.saturating_sub(reach)..=(j + reach).min(cut.path.c.len() - 1) {
        // The row's path pixels are the run `start(n)..=c[n]`; the one
        // nearest to column `i` is `i` clamped to it (unique in the row).
        let m = i.clamp(cut.starts[n], cut.path.c[n]);
        let d2 = m.abs_diff(i).pow(2) + n.abs_diff(j).pow(2);
        if d2 < best_d2 {
            best_d2 = d2;
            best = (m, n);
        }
    }
    if best_d2 == usize::MAX {
        return (1.0, (i, j));
    }
    let e = match settings.blend {
        Blend::Feather => 1.0,
        Blend::Error => cut.map.at(best.0, best.1) / top,
    };
    let d = (best_d2 as f32).sqrt();
    let alpha = if e > 0.0 {
        (d / (rho * e)).min(1.0)
    } else {
        1.0
    };
    (alpha, best)
}

/// Writes the stitch of R1 over the canvas (R2) inside `belt`: pixels right
/// of the path keep R2, the others take R1 blended towards the path's R2
/// colour. `keep(x, y)` may veto pixels (false = leave the canvas as it is),
/// for belts that share corners. Returns the cut.
pub fn stitch(
    canvas: &mut ColorImage,
    belt: &Belt,
    r1: impl Fn(usize, usize) -> [u8; 3],
    settings: &StitchSettings,
    keep: impl Fn(usize, usize) -> bool,
) -> Cut {
    let r2 = |x: usize, y: usize| canvas.get(x, y);
    let cut = find_cut(belt, &r1, r2, settings);
    apply(canvas, belt, &cut, r1, settings, keep);
    cut
}

/// Writes an already found `cut` (see [`stitch`]).
pub fn apply(
    canvas: &mut ColorImage,
    belt: &Belt,
    cut: &Cut,
    r1: impl Fn(usize, usize) -> [u8; 3],
    settings: &StitchSettings,
    keep: impl Fn(usize, usize) -> bool,
) {
    let mut writes = Vec::new();
    for j in 0..belt.along {
        for i in 0..=cut.path.c[j] {
            let (x, y) = belt.pixel(i, j);
            if !keep(x, y) {
                continue;
            }
            // The paper blends for 1 < i ≤ c_j: the outermost column of R1's
            // side is copied as it is (at a tile's edge it is what continues
            // the opposite edge).
            let (alpha, (m, n)) = if i == 0 {
                (1.0, (i, j))
            } else {
                blend_weight(cut, settings, i, j)
            };
            let a = r1(x, y);
            let colour = if alpha >= 1.0 {
                a
            } else {
                let (px, py) = belt.pixel(m, n);
                let b = canvas.get(px, py);
                std::array::from_fn(|k| {
                    (f32::from(a[k]) * alpha + f32::from(b[k]) * (1.0 - alpha)).round() as u8
                })
            };
            writes.push((x, y, colour));
        }
    }
    for (x, y, c) in writes {
        canvas.set(x, y, c);
    }
}
