//! One exemplar at one level of the synthesis on coordinates (Manke–Wünsche
//! §3): its appearance vectors at the level's blur, its neighbourhood
//! vectors at step `h`, the k-coherence bases and the choice of eq. 3.

use rayon::prelude::*;

use super::appearance::Pca;
use super::coords::wrap;
use crate::imaging::ColorImage;

/// Neighbourhood tables above this many floats are not kept; their entries
/// are computed when asked for (same values).
const TABLE_LIMIT: usize = 1 << 25;

/// One level of one exemplar: its appearance vectors at this level's blur,
/// its neighbourhood vectors at step `h` and its candidate sets.
pub(super) struct ExemplarLevel {
    pub(super) width: usize,
    pub(super) height: usize,
    pub(super) dims: usize,
    pub(super) h: i64,
    pub(super) appearance: Vec<f32>,
    /// Per pixel the neighbourhood vector (points × dims), when it fits.
    table: Option<Vec<f32>>,
    stride: usize,
}

impl ExemplarLevel {
    /// The exemplar at the stack level of step `h`: blurred by a box of
    /// width about `h`, and each pixel's appearance taken from its 5×5
    /// window with samples `h` pixels apart. That window is what a pyramid
    /// level's own 5×5 window covers, so a coarse level's appearance
    /// describes the structure at its scale (with adjacent samples of the
    /// blurred image it would hold little more than the blur, and bricks
    /// break up into rubble).
    pub(super) fn build(img: &ColorImage, h: usize, pca: &Pca, points: &[Vec<[i32; 2]>]) -> Self {
        let blur = blurred(img, h);
        let dims = pca.components.len();
        let projected = pca.project_image(&blur, h);
        // Centred on the exemplar's own mean (see `morph`).
        let mut mean = vec![0.0f64; dims];
        for v in projected.chunks_exact(dims) {
            for (m, a) in mean.iter_mut().zip(v) {
                *m += a;
            }
        }
        let n = (img.width * img.height) as f64;
        let appearance: Vec<f32> = projected
            .chunks_exact(dims)
            .flat_map(|v| v.iter().zip(&mean).map(move |(a, m)| (a - m / n) as f32))
            .collect();
        let mut ex = Self {
            width: img.width,
            height: img.height,
            dims,
            h: h as i64,
            appearance,
            table: None,
            stride: points.len() * dims,
        };
        if ex.width * ex.height * ex.stride <= TABLE_LIMIT {
            let table: Vec<f32> = (0..ex.width * ex.height)
                .into_par_iter()
                .flat_map_iter(|i| {
                    let mut v = Vec::with_capacity(ex.stride);
                    ex.gather(
                        [(i % ex.width) as u32, (i / ex.width) as u32],
                        points,
                        &mut v,
                    );
                    v
                })
                .collect();
            ex.table = Some(table);
        }
        ex
    }

    pub(super) fn at(&self, x: u32, y: u32) -> &[f32] {
        let i = (y as usize * self.width + x as usize) * self.dims;
        &self.appearance[i..i + self.dims]
    }

    /// The neighbourhood vector of exemplar pixel `q`, computed.
    fn gather(&self, q: [u32; 2], points: &[Vec<[i32; 2]>], out: &mut Vec<f32>) {
        out.clear();
        let (w, hh) = (self.width as i64, self.height as i64);
        for pt in points {
            let start = out.len();
            out.extend(std::iter::repeat_n(0.0, self.dims));
            let share = 1.0 / pt.len() as f32;
            for o in pt {
                let x = (i64::from(q[0]) + self.h * i64::from(o[0])).rem_euclid(w) as u32;
                let y = (i64::from(q[1]) + self.h * i64::from(o[1])).rem_euclid(hh) as u32;
                for (a, v) in out[start..].iter_mut().zip(self.at(x, y)) {
                    *a += v * share;
                }
            }
        }
    }

    /// The bases of k-coherence at a pixel: the coordinates of its 3×3
    /// neighbours (`neighbour(dx, dy)`, offsets in the level's plane) shifted
    /// back by `h·(dx, dy)`. Coherent neighbours shift back to the same
    /// exemplar pixel: each such base is taken once.
    pub(super) fn bases(&self, neighbour: impl Fn(i64, i64) -> [u32; 2]) -> Bases {
        let mut bases = [[u32::MAX; 2]; 9];
        let mut votes = [0u8; 9];
        let mut nb = 0;
        for dy in -1..=1i64 {
            for dx in -1..=1i64 {
                let n = neighbour(dx, dy);
                let base = [
                    wrap(i64::from(n[0]) - self.h * dx, self.width) as u32,
                    wrap(i64::from(n[1]) - self.h * dy, self.height) as u32,
                ];
                match bases[..nb].iter().position(|b| *b == base) {
                    Some(i) => votes[i] += 1,
                    None => {
                        bases[nb] = base;
                        votes[nb] = 1;
                        nb += 1;
                    }
                }
            }
        }
        Bases {
            at: bases,
            votes,
            len: nb,
        }
    }

    /// The choice of eq. 3: of the candidates of `bases` (`k` each in
    /// `table`), the one whose neighbourhood is nearest to `want`;
    /// `current` when none is nearer than infinity. A candidate that `v` of
    /// the 3×3 neighbours continue ([`Bases::votes`]; 0 for one that is no
    /// base) has its distance scaled by `1 + coherence·(1 − v/9)`
    /// ([`super::driver::ParallelSettings::coherence`]), so one that breaks
    /// the neighbours' agreement must be clearly nearer to win, and then by
    /// `factor(q)` (a solid's index histogram matching; 1 elsewhere). A
    /// candidate other than `current` whose factor is `None` (closed by the
    /// copy guard, [`super::driver::ParallelSettings::copy_guard`]) is not
    /// taken; `current` itself then counts at factor 1.
    /// A candidate seen twice scores the same twice, and ties go to the
    /// smaller coordinate, so the order candidates are met in does not
    /// matter and candidates are not deduplicated.
    pub(super) fn best_candidate(
        &self,
        bases: &Bases,
        (k, table): (usize, &[[u32; 2]]),
        points: &[Vec<[i32; 2]>],
        (want, buf): (&[f32], &mut Vec<f32>),
        current: [u32; 2],
        (coherence, factor): (f32, impl Fn([u32; 2]) -> Option<f32>),
    ) -> [u32; 2] {
        let mut best = (f32::INFINITY, current);
        for base in bases.list() {
            let at = (base[1] as usize * self.width + base[0] as usize) * k;
            for &q in &table[at..at + k] {
                let Some(g) = factor(q).or((q == current).then_some(1.0)) else {
                    continue;
                };
                let f = g * if coherence > 0.0 {
                    1.0 + coherence * (1.0 - f32::from(bases.votes(q)) / 9.0)
                } else {
                    1.0
                };
                let have = self.neighbourhood(q, points, buf);
                let Some(d) = ssd_below(want, have, best.0 / f) else {
                    continue;
                };
                let d = d * f;
                if d < best.0 || (d == best.0 && (q[1], q[0]) < (best.1[1], best.1[0])) {
                    best = (d, q);
                }
            }
        }
        best.1
    }

    /// The offset of coordinate `q` at level pixel `(x, y)`: `q − h·(x, y)`
    /// modulo the exemplar, the same for every pixel of one coherent copy.
    pub(super) fn offset(&self, q: [u32; 2], (x, y): (i64, i64)) -> [u32; 2] {
        let (w, h) = (self.width as i64, self.height as i64);
        [
            (i64::from(q[0]) - self.h * x).rem_euclid(w) as u32,
            (i64::from(q[1]) - self.h * y).rem_euclid(h) as u32,
        ]
    }

    /// The neighbourhood vector of `q`: from the table, or computed into
    /// `buf`.
    pub(super) fn neighbourhood<'a>(
        &'a self,
        q: [u32; 2],
        points: &[Vec<[i32; 2]>],
        buf: &'a mut Vec<f32>,
    ) -> &'a [f32] {
        match &self.table {
            Some(t) => {
                let i = (q[1] as usize * self.width + q[0] as usize) * self.stride;
                &t[i..i + self.stride]
            }
            None => {
                self.gather(q, points, buf);
                buf
            }
        }
    }
}

/// The bases of k-coherence at a pixel, each with the number of its 3×3
/// neighbours (itself included) whose coordinates shift back to it.
pub(super) struct Bases {
    at: [[u32; 2]; 9],
    votes: [u8; 9],
    len: usize,
}

impl Bases {
    pub(super) fn list(&self) -> &[[u32; 2]] {
        &self.at[..self.len]
    }

    /// How many of the 3×3 neighbours continue coherently into `q`.
    pub(super) fn votes(&self, q: [u32; 2]) -> u8 {
        self.list()
            .iter()
            .position(|b| *b == q)
            .map_or(0, |i| self.votes[i])
    }
}

/// A blur of the exemplar for the stack level of step `h`: a wrapping box
/// of radius `h/2` ([`crate::filters::box_blur_rgb`]).
pub(super) fn blurred(img: &ColorImage, h: usize) -> ColorImage {
    crate::filters::box_blur_rgb(img, if h <= 1 { 0 } else { h / 2 })
}

/// The sum of squared differences, or `None` as soon as it exceeds `bound`.
/// Eight lanes at a time (one AVX register), summed in a fixed order, so a
/// complete sum is the same number whatever the bound.
pub(super) fn ssd_below(a: &[f32], b: &[f32], bound: f32) -> Option<f32> {
    let mut d = 0.0f32;
    let (mut ca, mut cb) = (a.chunks_exact(8), b.chunks_exact(8));
    for (x, y) in (&mut ca).zip(&mut cb) {
        let mut lanes = [0.0f32; 8];
        for l in 0..8 {
            let t = x[l] - y[l];
            lanes[l] = t * t;
        }
        d += ((lanes[0] + lanes[4]) + (lanes[1] + lanes[5]))
            + ((lanes[2] + lanes[6]) + (lanes[3] + lanes[7]));
        if d > bound {
            return None;
        }
    }
    for (x, y) in ca.remainder().iter().zip(cb.remainder()) {
        d += (x - y) * (x - y);
    }
    (d <= bound).then_some(d)
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::parallel::tests::texture;

    /// Each base of k-coherence counts the 3×3 neighbours that shift back
    /// to it: nine for a coherent patch, split where a neighbour breaks it;
    /// a coordinate no neighbour continues has no vote.
    #[test]
    fn bases_count_the_neighbours_that_continue_them() {
        let ex = ExemplarLevel {
            width: 16,
            height: 16,
            dims: 1,
            h: 2,
            appearance: vec![0.0; 256],
            table: None,
            stride: 1,
        };
        // Neighbour (dx, dy) of a patch at offset (5, 7) sits at
        // (5, 7) + h·(dx, dy), wrapped on the 16² exemplar.
        let patch = |dx: i64, dy: i64| {
            [
                (5 + 2 * dx).rem_euclid(16) as u32,
                (7 + 2 * dy).rem_euclid(16) as u32,
            ]
        };
        let whole = ex.bases(patch);
        assert_eq!(whole.list(), &[[5, 7]]);
        assert_eq!(whole.votes([5, 7]), 9);
        let broken = ex.bases(|dx, dy| {
            if (dx, dy) == (1, 1) {
                [0, 0]
            } else {
                patch(dx, dy)
            }
        });
        assert_eq!(broken.list().len(), 2);
        assert_eq!(broken.votes([5, 7]), 8);
        // (0, 0) shifted back by h·(1, 1), wrapped.
        assert_eq!(broken.votes([14, 14]), 1);
        assert_eq!(broken.votes([3, 3]), 0);
    }

    #[test]
    fn the_stack_blur_is_a_wrapping_box_filter() {
        let ex = texture("brick_color_96.png");
        let b = blurred(&ex, 4);
        // Against the direct two-pass sum at a few pixels, wrapping.
        let (w, h) = (ex.width as i64, ex.height as i64);
        for (x, y) in [(0i64, 0i64), (95, 3), (40, 95), (17, 60)] {
            for c in 0..3 {
                let rows: Vec<u8> = (-2..=2)
                    .map(|dy| {
                        let s: u32 = (-2..=2)
                            .map(|dx| {
                                u32::from(
                                    ex.get(
                                        (x + dx).rem_euclid(w) as usize,
                                        (y + dy).rem_euclid(h) as usize,
                                    )[c],
                                )
                            })
                            .sum();
                        ((s + 2) / 5) as u8
                    })
                    .collect();
                let s: u32 = rows.iter().map(|&v| u32::from(v)).sum();
                assert_eq!(b.get(x as usize, y as usize)[c], ((s + 2) / 5) as u8);
            }
        }
    }
}
