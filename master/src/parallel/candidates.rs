//! k-coherence candidate sets (Tong et al., as Lefebvre and Hoppe use them;
//! Manke–Wünsche §3): for an exemplar pixel, exemplar pixels whose
//! appearance is most alike, found once per level by the engine's exact top-k
//! search, so the correction only compares a handful of candidates per pixel.
//!
//! The search goes through [`SearchBackend`], locally or on the cluster. The
//! engine compares square windows of a plane, so each appearance vector
//! (quantised to bytes) is laid out as one odd square cell of a plane, 3×3
//! for up to 9 components, and searched as a window of that size: the
//! window's distance is the vectors'.
//!
//! For large exemplars and coarse levels the sets are computed on a grid of
//! stride `s` (at most [`MAX_GRID`] pixels search each other, and `s ≥ h/2`
//! on a level of step `h`), and pixel `q` takes the sets
//! of its grid pixel `g` shifted by `q − g`, the shift k-coherence itself
//! uses. Pixel `q` is always its own first candidate, and a candidate
//! within 2 pixels of one already taken is passed over.

use anyhow::{ensure, Result};
use texsyn_engine::{Geometry, Plane, QueryBatch, Sample};

use crate::search::{LevelData, SearchBackend};

/// Most grid pixels whose sets are searched on one level.
pub const MAX_GRID: usize = 4096;
/// Largest k.
pub const MAX_K: usize = 16;

/// The candidate sets of one exemplar level.
pub struct Candidates {
    k: usize,
    stride: usize,
    width: usize,
    height: usize,
    grid_w: usize,
    /// Per grid pixel, its nearest grid pixels (itself first), best first.
    lists: Vec<Vec<[u32; 2]>>,
}

impl Candidates {
    /// Searches the sets of a `width`×`height` level whose appearance vectors
    /// (`dims` each, row by row) are `appearance`. `level` names the level to
    /// the backend. The grid stride is at least `min_stride`: on a stack
    /// level blurred over `h` pixels, pixels less than `h/2` apart look
    /// alike, so a coarse level needs few grid pixels.
    pub fn search(
        appearance: &[f32],
        (width, height): (usize, usize),
        min_stride: usize,
        dims: usize,
        k: usize,
        level: usize,
        backend: &mut dyn SearchBackend,
    ) -> Result<Self> {
        ensure!((1..=MAX_K).contains(&k), "k must be in 1..={MAX_K}");
        ensure!(appearance.len() == width * height * dims, "appearance size");
        let stride = (((width * height) as f64 / MAX_GRID as f64).sqrt().ceil() as usize)
            .max(min_stride)
            .clamp(1, width.min(height));
        let (grid_w, grid_h) = (width.div_ceil(stride), height.div_ceil(stride));
        // Cells: the smallest odd square that holds the vector.
        let cell = {
            let c = (dims as f64).sqrt().ceil() as usize;
            c | 1
        };
        let (lo, hi) = appearance
            .iter()
            .fold((f32::MAX, f32::MIN), |(a, b), &v| (a.min(v), b.max(v)));
        let scale = if hi > lo { 255.0 / (hi - lo) } else { 0.0 };
        let quantise = |v: f32| ((v - lo) * scale).round().clamp(0.0, 255.0) as u8;
        // Cells sit `cell + 1` apart with a line of undefined pixels between
        // them, so the only windows clear of undefined pixels, the reference
        // positions a worker derives from the plane, are the cells.
        let pitch = cell + 1;
        let (pw, ph) = (grid_w * pitch, grid_h * pitch);
        let mut pixels = vec![0u8; pw * ph];
        let mut defined = vec![0u8; pw * ph];
        let mut cells = Vec::with_capacity(grid_w * grid_h);
        for gy in 0..grid_h {
            for gx in 0..grid_w {
                let i = (gy * stride * width + gx * stride) * dims;
                let v = &appearance[i..i + dims];
                let mut c = vec![0u8; cell * cell];
                for (slot, &a) in c.iter_mut().zip(v) {
                    *slot = quantise(a);
                }
                for r in 0..cell {
                    let at = (gy * pitch + r) * pw + gx * pitch;
                    pixels[at..at + cell].copy_from_slice(&c[r * cell..(r + 1) * cell]);
                    defined[at..at + cell].fill(1);
                }
                cells.push(c);
            }
        }
        let geometry = Geometry::new(cell, 0)?;
        let fine = Plane::new(pw, ph, &pixels, Some(&defined))?;
        let sample = Sample { fine, parent: None };
        let positions = texsyn_engine::plane::reference_positions(&sample, &geometry)?;
        // Row by row, so reference g is grid pixel (g mod grid_w, g / grid_w).
        ensure!(
            positions.len() == cells.len(),
            "{} cells gave {} reference windows",
            cells.len(),
            positions.len()
        );
        backend.load_level(&LevelData::single_plane(
            level,
            level + 1,
            geometry,
            fine,
            &positions,
            cells.len() as u64,
        )?)?;
        let extra = (4 * k + 4).min(cells.len());
        let mut lists = Vec::with_capacity(cells.len());
        for chunk in cells.chunks(2048) {
            let mut batch = QueryBatch::new(geometry.layout());
            for c in chunk {
                batch.push_full(c)?;
            }
            for hits in backend.search_topk(&batch, extra)? {
                lists.push(
                    hits.iter()
                        .map(|h| {
                            let g = h.index as usize;
                            [
                                ((g % grid_w) * stride) as u32,
                                ((g / grid_w) * stride) as u32,
                            ]
                        })
                        .collect(),
                );
            }
        }
        backend.end_level();
        Ok(Self {
            k,
            stride,
            width,
            height,
            grid_w,
            lists,
        })
    }

    /// Grid stride of the sets (1 = every pixel searched).
    pub fn stride(&self) -> usize {
        self.stride
    }

    /// Every pixel's candidates, row by row, `k` slots each (a short set
    /// repeats its first entry, which changes no choice).
    pub fn table(&self) -> Vec<[u32; 2]> {
        let mut out = Vec::with_capacity(self.width * self.height * self.k);
        let mut list = Vec::with_capacity(self.k);
        for y in 0..self.height as u32 {
            for x in 0..self.width as u32 {
                self.of([x, y], &mut list);
                out.extend_from_slice(&list);
                out.extend(std::iter::repeat_n(list[0], self.k - list.len()));
            }
        }
        out
    }

    /// k of the sets.
    pub fn k(&self) -> usize {
        self.k
    }

    /// The candidates of pixel `q` into `out`: `q` first, then its grid
    /// pixel's list shifted by `q − g`, near-duplicates passed over; `k` at
    /// most (fewer when the list runs out).
    pub fn of(&self, q: [u32; 2], out: &mut Vec<[u32; 2]>) {
        out.clear();
        out.push(q);
        let s = self.stride as u32;
        let g = [q[0] / s * s, q[1] / s * s];
        let d = [q[0] - g[0], q[1] - g[1]];
        let list = &self.lists[(g[1] / s) as usize * self.grid_w + (g[0] / s) as usize];
        for c in list {
            if out.len() == self.k {
                break;
            }
            let c = [
                (c[0] + d[0]) % self.width as u32,
                (c[1] + d[1]) % self.height as u32,
            ];
            if out
                .iter()
                .all(|o| o[0].abs_diff(c[0]).max(o[1].abs_diff(c[1])) > 2)
            {
                out.push(c);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::search::LocalSearch;
    use texsyn_engine::Engine;

    /// The sets against a brute-force scan of the quantised vectors.
    #[test]
    fn the_sets_are_the_exact_nearest_vectors() {
        let (w, h, dims) = (40, 30, 8);
        let mut s = 12345u32;
        let app: Vec<f32> = (0..w * h * dims)
            .map(|_| {
                s = s.wrapping_mul(1_103_515_245).wrapping_add(12345);
                (s >> 16) as f32 / 65536.0 * 10.0 - 5.0
            })
            .collect();
        let mut backend = LocalSearch::new(Engine::default());
        let c = Candidates::search(&app, (w, h), 1, dims, 4, 0, &mut backend).unwrap();
        assert_eq!(c.stride(), 1);
        let (lo, hi) = app
            .iter()
            .fold((f32::MAX, f32::MIN), |(a, b), &v| (a.min(v), b.max(v)));
        let q = |v: f32| ((v - lo) * 255.0 / (hi - lo)).round().clamp(0.0, 255.0) as i64;
        let dist = |a: usize, b: usize| -> i64 {
            (0..dims)
                .map(|d| (q(app[a * dims + d]) - q(app[b * dims + d])).pow(2))
                .sum()
        };
        let mut out = Vec::new();
        for p in [0usize, 17, 555, 1199] {
            let mut all: Vec<(i64, usize)> = (0..w * h).map(|r| (dist(p, r), r)).collect();
            all.sort();
            let want: Vec<[u32; 2]> = all
                .iter()
                .take(20)
                .map(|&(_, r)| [(r % w) as u32, (r / w) as u32])
                .collect();
            assert_eq!(c.lists[p], want);
            c.of([(p % w) as u32, (p / w) as u32], &mut out);
            assert_eq!(out[0], [(p % w) as u32, (p / w) as u32]);
            assert!(out.len() <= 4);
        }
    }
}
