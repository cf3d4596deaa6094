//! Minimum-error paths across an overlap (Somol–Haindl §2.1).
//!
//! The overlap of a source region R1 laid over a target region R2 is seen in
//! *canonical* coordinates: `w` columns across the overlap (`i = 0` on R1's
//! side, `i = w - 1` on R2's) and `h` rows along it. A path keeps one control
//! point `c[j]` per row; the pixels `μ_j..=c[j]` of row `j` are on the path,
//! with `μ_j = min(c[j-1] + 1, c[j+1] + 1, c[j])`, so the complementary
//! points make every path 8-connected and every `c` is a valid path. Pixels
//! left of and on the path come from R1. The cost of a path is the sum of the
//! error map over its pixels.

/// The per-pixel error between R1 and R2 over an overlap: `e[j * w + i]` is
/// the Euclidean distance of the two RGB colours.
#[derive(Clone, Debug)]
pub struct ErrorMap {
    pub w: usize,
    pub h: usize,
    pub e: Vec<f32>,
    /// The largest error of the map (0 for an empty or flat one).
    pub max: f32,
    /// Per row, the prefix sums of `e` (`w + 1` entries per row).
    prefix: Vec<f64>,
}

/// Euclidean distance of two RGB colours.
pub fn rgb_distance(a: [u8; 3], b: [u8; 3]) -> f32 {
    let d: i32 = (0..3)
        .map(|k| (i32::from(a[k]) - i32::from(b[k])).pow(2))
        .sum();
    (d as f32).sqrt()
}

impl ErrorMap {
    /// An error map from its values (row by row, `w` per row).
    pub fn new(w: usize, h: usize, e: Vec<f32>) -> Self {
        assert!(w > 0 && h > 0 && e.len() == w * h, "error map {w}x{h}");
        let mut prefix = Vec::with_capacity((w + 1) * h);
        for row in e.chunks_exact(w) {
            let mut s = 0.0;
            prefix.push(0.0);
            for &v in row {
                s += f64::from(v);
                prefix.push(s);
            }
        }
        let max = e.iter().copied().fold(0.0f32, f32::max);
        Self {
            w,
            h,
            e,
            max,
            prefix,
        }
    }

    /// The error map of two RGB regions given pixel by pixel in canonical
    /// coordinates.
    pub fn of(w: usize, h: usize, r1: &[[u8; 3]], r2: &[[u8; 3]]) -> Self {
        let e = r1
            .iter()
            .zip(r2)
            .map(|(a, b)| rgb_distance(*a, *b))
            .collect();
        Self::new(w, h, e)
    }

    pub fn at(&self, i: usize, j: usize) -> f32 {
        self.e[j * self.w + i]
    }

    /// Sum of row `j` over columns `from..=to`.
    fn span(&self, j: usize, from: usize, to: usize) -> f64 {
        let p = &self.prefix[j * (self.w + 1)..];
        p[to + 1] - p[from]
    }

    /// Cost of row `j` with control point `c` and neighbours `up`, `down`.
    fn row_cost(&self, j: usize, up: Option<usize>, c: usize, down: Option<usize>) -> f64 {
        self.span(j, mu(up, c, down), c)
    }
}

/// First path pixel of a row: `min(c[j-1] + 1, c[j+1] + 1, c[j])`.
fn mu(up: Option<usize>, c: usize, down: Option<usize>) -> usize {
    let mut m = c;
    for n in [up, down].into_iter().flatten() {
        m = m.min(n + 1);
    }
    m
}

/// A path: one control point per row, in `0..w`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Path {
    pub c: Vec<usize>,
}

impl Path {
    fn neighbours(&self, j: usize) -> (Option<usize>, Option<usize>) {
        let up = j.checked_sub(1).map(|u| self.c[u]);
        let down = self.c.get(j + 1).copied();
        (up, down)
    }

    /// The first path pixel of row `j`.
    pub fn start(&self, j: usize) -> usize {
        let (up, down) = self.neighbours(j);
        mu(up, self.c[j], down)
    }

    /// ε: the sum of the error map over the path's pixels.
    pub fn cost(&self, map: &ErrorMap) -> f64 {
        (0..self.c.len()).map(|j| self.row_sum(map, j)).sum()
    }

    fn row_sum(&self, map: &ErrorMap, j: usize) -> f64 {
        let (up, down) = self.neighbours(j);
        map.row_cost(j, up, self.c[j], down)
    }

    /// Sum of the rows `from..=to` (clamped to the path).
    fn rows_sum(&self, map: &ErrorMap, from: usize, to: usize) -> f64 {
        (from..=to.min(self.c.len() - 1))
            .map(|j| self.row_sum(map, j))
            .sum()
    }

    /// The path's pixels `(i, j)`, row by row.
    pub fn pixels(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        (0..self.c.len()).flat_map(move |j| (self.start(j)..=self.c[j]).map(move |i| (i, j)))
    }

    /// Whether canonical pixel `(i, j)` is on R1's side (left of or on the path).
    pub fn takes_r1(&self, i: usize, j: usize) -> bool {
        i <= self.c[j]
    }
}

/// Where the oscillating search starts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Start {
    /// The paper's start: each row's least error, on its own.
    RowMinimum,
    /// The least-cost path whose control points move by at most one column
    /// from row to row (the minimum-error boundary cut of seam carving). On
    /// such a path every `μ_j = c_j`, so its cost is `Σ E[c_j, j]` and a
    /// three-way dynamic programme finds it in `O(h·w)`. The oscillating moves
    /// then add what it cannot have: horizontal runs across the overlap.
    Seam,
}

/// The oscillating search's settings (§2.1).
#[derive(Clone, Copy, Debug)]
pub struct Oscillating {
    /// The largest number of consecutive control points moved at once
    /// (`1 ≤ o_max ≤ h`; larger is better or equal, and slower).
    pub o_max: usize,
    /// Stop after this many path evaluations and keep the best path so far
    /// (the search can be stopped at any time); `None` runs to convergence.
    pub budget: Option<u64>,
    pub start: Start,
}

impl Default for Oscillating {
    /// The seam start with `o_max = 2`. From the paper's start the search
    /// stalls where the optimum runs diagonally (a mean of 1.13× the optimum
    /// over the 1 000 maps of `tests/tiles.rs`, and 2× on the worst); from the
    /// seam start every one of them ends within 1.15× and the search is
    /// several times faster than the optimal path (ARCHITECTURE §7).
    fn default() -> Self {
        Self {
            o_max: 2,
            budget: None,
            start: Start::Seam,
        }
    }
}

/// Each row's first least error.
fn row_minimum_start(map: &ErrorMap) -> Path {
    let w = map.w;
    Path {
        c: map
            .e
            .chunks_exact(w)
            .map(|row| {
                let mut best = 0;
                for (i, &v) in row.iter().enumerate() {
                    if v < row[best] {
                        best = i;
                    }
                }
                best
            })
            .collect(),
    }
}

/// The least-cost path with `|c[j] − c[j−1]| ≤ 1` (see [`Start::Seam`]);
/// ties go to the leftmost column.
fn seam_start(map: &ErrorMap) -> Path {
    let (w, h) = (map.w, map.h);
    let mut f: Vec<f64> = map.e[..w].iter().map(|&v| f64::from(v)).collect();
    let mut g = vec![0.0; w];
    let mut back = vec![0u16; w * h];
    for j in 1..h {
        for i in 0..w {
            let mut arg = i.saturating_sub(1);
            for k in arg + 1..=(i + 1).min(w - 1) {
                if f[k] < f[arg] {
                    arg = k;
                }
            }
            g[i] = f[arg] + f64::from(map.at(i, j));
            back[j * w + i] = arg as u16;
        }
        std::mem::swap(&mut f, &mut g);
    }
    let mut c = vec![0; h];
    for i in 1..w {
        if f[i] < f[c[h - 1]] {
            c[h - 1] = i;
        }
    }
    for j in (1..h).rev() {
        c[j - 1] = usize::from(back[j * w + c[j]]);
    }
    Path { c }
}

/// The sub-optimal minimum-error path by the paper's oscillating search.
///
/// Start as [`Oscillating::start`] says; then, with step size `o = 1, 2, …,
/// o_max`, move each run of `o` consecutive control points together to every
/// column (a vertical line); the first move that lowers ε is kept and the
/// search restarts at `o = 1` ("go to 1"). It ends when no move of any size up
/// to `o_max` helps, or when the evaluation budget is spent. A move changes the
/// cost of the moved rows and of the row above and below only, so each
/// evaluation costs `O(o)`.
pub fn oscillating(map: &ErrorMap, settings: Oscillating) -> Path {
    let (w, h) = (map.w, map.h);
    let mut path = match settings.start {
        Start::RowMinimum => row_minimum_start(map),
        Start::Seam => seam_start(map),
    };
    let o_max = settings.o_max.clamp(1, h);
    let mut evaluations = 0u64;
    let budget = settings.budget.unwrap_or(u64::MAX);
    // The result of trying a run depends only on the control points from two
    // rows above it to two rows below it. A run whose surroundings have not
    // changed since it last failed to improve fails again, so the sweep after
    // each restart skips it: the same path, without re-evaluating the rows
    // the last improvement cannot have affected.
    let mut clock = 1u64;
    let mut changed = vec![0u64; h];
    let mut failed = vec![vec![0u64; h]; o_max + 1];
    'restart: loop {
        for o in 1..=o_max {
            for j in 0..=h - o {
                let (from, to) = (j.saturating_sub(1), j + o);
                let near = j.saturating_sub(2)..(j + o + 2).min(h);
                if failed[o][j] > 0 && changed[near].iter().all(|&t| t < failed[o][j]) {
                    continue;
                }
                let before = path.rows_sum(map, from, to);
                let saved: Vec<usize> = path.c[j..j + o].to_vec();
                for i in 0..w {
                    if evaluations >= budget {
                        path.c[j..j + o].copy_from_slice(&saved);
                        return path;
                    }
                    evaluations += 1;
                    path.c[j..j + o].iter_mut().for_each(|c| *c = i);
                    let after = path.rows_sum(map, from, to);
                    // A strict decrease, with a margin for the float sums, so
                    // the search cannot cycle.
                    if after < before - 1e-9 * before.abs().max(1.0) {
                        clock += 1;
                        changed[j..j + o].iter_mut().for_each(|t| *t = clock);
                        clock += 1;
                        continue 'restart;
                    }
                }
                path.c[j..j + o].copy_from_slice(&saved);
                failed[o][j] = clock;
            }
        }
        return path;
    }
}

/// The optimal path under the same model, by dynamic programming over pairs of
/// consecutive control points (a row's cost depends on its neighbours'
/// control points): `O(h·w³)` time, `O(h·w²)` memory. The reference the
/// oscillating search is measured against.
pub fn optimal(map: &ErrorMap) -> Path {
    let (w, h) = (map.w, map.h);
    if h == 1 {
        let c = (0..w)
            .min_by(|&a, &b| map.at(a, 0).total_cmp(&map.at(b, 0)))
            .unwrap();
        return Path { c: vec![c] };
    }
    // f[a * w + b]: least cost of rows 0..j-1 with c[j-1] = a, c[j] = b.
    let mut f: Vec<f64> = (0..w * w)
        .map(|ab| map.row_cost(0, None, ab / w, Some(ab % w)))
        .collect();
    // back[j][b * w + c]: the best c[j-1] given c[j] = b, c[j+1] = c.
    let mut back: Vec<Vec<u16>> = Vec::with_capacity(h);
    for j in 1..h - 1 {
        let mut g = vec![f64::INFINITY; w * w];
        let mut arg = vec![0u16; w * w];
        for b in 0..w {
            for c in 0..w {
                let (mut best, mut best_a) = (f64::INFINITY, 0);
                for a in 0..w {
                    let v = f[a * w + b] + map.row_cost(j, Some(a), b, Some(c));
                    if v < best {
                        best = v;
                        best_a = a;
                    }
                }
                g[b * w + c] = best;
                arg[b * w + c] = best_a as u16;
            }
        }
        f = g;
        back.push(arg);
    }
    // The last row has no row below.
    let (mut best, mut end) = (f64::INFINITY, (0, 0));
    for a in 0..w {
        for b in 0..w {
            let v = f[a * w + b] + map.row_cost(h - 1, Some(a), b, None);
            if v < best {
                best = v;
                end = (a, b);
            }
        }
    }
    let mut c = vec![0; h];
    c[h - 1] = end.1;
    c[h - 2] = end.0;
    for j in (1..h - 1).rev() {
        // back[j - 1] holds, for rows (j, j + 1), the best c[j - 1].
        c[j - 1] = usize::from(back[j - 1][c[j] * w + c[j + 1]]);
    }
    Path { c }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every control-point sequence of a tiny map, by brute force.
    fn brute_force(map: &ErrorMap) -> f64 {
        let (w, h) = (map.w, map.h);
        let mut best = f64::INFINITY;
        let mut c = vec![0; h];
        loop {
            best = best.min(Path { c: c.clone() }.cost(map));
            let mut k = 0;
            loop {
                if k == h {
                    return best;
                }
                c[k] += 1;
                if c[k] < w {
                    break;
                }
                c[k] = 0;
                k += 1;
            }
        }
    }

    fn lcg(seed: &mut u64) -> f32 {
        *seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((*seed >> 40) % 1000) as f32
    }

    #[test]
    fn dynamic_programming_finds_the_brute_force_optimum() {
        let mut seed = 7;
        for (w, h) in [(1, 1), (3, 1), (1, 4), (2, 2), (3, 4), (4, 5), (3, 6)] {
            for _ in 0..20 {
                let e: Vec<f32> = (0..w * h).map(|_| lcg(&mut seed)).collect();
                let map = ErrorMap::new(w, h, e);
                let p = optimal(&map);
                assert_eq!(p.c.len(), h);
                let (a, b) = (p.cost(&map), brute_force(&map));
                assert!((a - b).abs() < 1e-6, "{w}x{h}: dp {a} brute {b}");
                assert!(oscillating(&map, Oscillating::default()).cost(&map) >= b - 1e-6);
            }
        }
    }

    #[test]
    fn the_seam_start_is_the_best_path_that_moves_one_column_per_row() {
        let mut seed = 9;
        for (w, h) in [(1, 3), (2, 4), (3, 5), (4, 6), (5, 4)] {
            for _ in 0..20 {
                let map = ErrorMap::new(w, h, (0..w * h).map(|_| lcg(&mut seed)).collect());
                let seam = seam_start(&map);
                let steps_ok = |c: &[usize]| c.windows(2).all(|p| p[0].abs_diff(p[1]) <= 1);
                assert!(steps_ok(&seam.c));
                // On such a path the cost is the control points' errors alone.
                let direct: f64 = (0..h).map(|j| f64::from(map.at(seam.c[j], j))).sum();
                assert!((seam.cost(&map) - direct).abs() < 1e-6);
                // No other one-column-per-row path is cheaper.
                let mut c = vec![0; h];
                'all: loop {
                    if steps_ok(&c) {
                        assert!(Path { c: c.clone() }.cost(&map) >= direct - 1e-6);
                    }
                    for ck in c.iter_mut() {
                        *ck += 1;
                        if *ck < w {
                            continue 'all;
                        }
                        *ck = 0;
                    }
                    break;
                }
            }
        }
    }

    /// The search exactly as printed: every restart sweeps every run again.
    fn oscillating_as_printed(map: &ErrorMap, o_max: usize) -> Path {
        let (w, h) = (map.w, map.h);
        let mut path = Path {
            c: (0..h)
                .map(|j| {
                    (0..w)
                        .min_by(|&a, &b| map.at(a, j).total_cmp(&map.at(b, j)).then(a.cmp(&b)))
                        .unwrap()
                })
                .collect(),
        };
        'restart: loop {
            for o in 1..=o_max.min(h) {
                for j in 0..=h - o {
                    let before = path.cost(map);
                    let saved = path.c[j..j + o].to_vec();
                    for i in 0..w {
                        path.c[j..j + o].iter_mut().for_each(|c| *c = i);
                        if path.cost(map) < before - 1e-9 * before.abs().max(1.0) {
                            continue 'restart;
                        }
                    }
                    path.c[j..j + o].copy_from_slice(&saved);
                }
            }
            return path;
        }
    }

    #[test]
    fn skipping_unchanged_runs_gives_the_printed_search_s_path() {
        let mut seed = 5;
        for (w, h, o) in [(5, 20, 1), (8, 30, 4), (12, 50, 8), (3, 9, 9)] {
            for _ in 0..10 {
                let map = ErrorMap::new(w, h, (0..w * h).map(|_| lcg(&mut seed)).collect());
                let fast = oscillating(
                    &map,
                    Oscillating {
                        o_max: o,
                        budget: None,
                        start: Start::RowMinimum,
                    },
                );
                assert_eq!(fast, oscillating_as_printed(&map, o), "{w}x{h} o_max {o}");
            }
        }
    }

    #[test]
    fn a_path_is_connected_and_its_start_never_passes_its_control_point() {
        let mut seed = 3;
        let map = ErrorMap::new(9, 40, (0..360).map(|_| lcg(&mut seed)).collect());
        let p = oscillating(&map, Oscillating::default());
        for j in 0..40 {
            assert!(p.start(j) <= p.c[j] && p.c[j] < 9);
            if j > 0 {
                // 8-connected: the spans of consecutive rows touch.
                let (a0, a1) = (p.start(j - 1), p.c[j - 1]);
                let (b0, b1) = (p.start(j), p.c[j]);
                assert!(b0 <= a1 + 1 && a0 <= b1 + 1, "row {j}");
            }
        }
    }

    #[test]
    fn the_budget_stops_the_search_with_a_usable_path() {
        let mut seed = 11;
        let map = ErrorMap::new(12, 64, (0..768).map(|_| lcg(&mut seed)).collect());
        let full = oscillating(&map, Oscillating::default()).cost(&map);
        let stopped = oscillating(
            &map,
            Oscillating {
                budget: Some(50),
                ..Oscillating::default()
            },
        );
        assert_eq!(stopped.c.len(), 64);
        assert!(stopped.cost(&map) >= full - 1e-6);
    }
}
