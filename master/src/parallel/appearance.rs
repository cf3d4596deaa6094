//! Appearance space (Lefebvre and Hoppe 2006, Manke–Wünsche §3): each pixel
//! is described by the colours of its 5×5 window, and the descriptors are
//! projected on their first principal components, at least 8 and as many as
//! it takes to keep 95 % of the variance. For morphing, the analysis runs
//! jointly over all exemplars, so their appearance vectors share one space.

use anyhow::{ensure, Result};
use nalgebra::{DMatrix, SymmetricEigen};
use rayon::prelude::*;

use crate::imaging::ColorImage;

/// Side of the window a pixel's descriptor gathers.
pub const WINDOW: usize = 5;
/// Least number of components kept.
pub const MIN_COMPONENTS: usize = 8;
/// Descriptors per exemplar the analysis samples at most (a grid over
/// larger exemplars).
pub const FIT_SAMPLES: usize = 1 << 16;
/// Share of the variance the kept components must explain.
pub const MIN_VARIANCE: f64 = 0.95;

/// The 5×5 RGB window around `(x, y)`, wrapping at the edges (exemplars are
/// treated as toroidal, as the synthesis wraps coordinates).
pub fn descriptor(img: &ColorImage, x: usize, y: usize) -> Vec<f64> {
    descriptor_spaced(img, x, y, 1)
}

/// The 5×5 window around `(x, y)` with its samples `step` pixels apart.
pub fn descriptor_spaced(img: &ColorImage, x: usize, y: usize, step: usize) -> Vec<f64> {
    let r = (WINDOW / 2) as isize;
    let step = step as isize;
    let (w, h) = (img.width as isize, img.height as isize);
    let mut out = Vec::with_capacity(WINDOW * WINDOW * 3);
    for dy in -r..=r {
        for dx in -r..=r {
            let px = img.get(
                (x as isize + dx * step).rem_euclid(w) as usize,
                (y as isize + dy * step).rem_euclid(h) as usize,
            );
            out.extend(px.iter().map(|&c| f64::from(c)));
        }
    }
    out
}

/// A principal-component projection of descriptors.
#[derive(Clone, Debug)]
pub struct Pca {
    pub mean: Vec<f64>,
    /// Kept components, largest variance first, one row each.
    pub components: Vec<Vec<f64>>,
    /// Share of the total variance the kept components explain.
    pub explained: f64,
}

impl Pca {
    /// The analysis of every pixel descriptor of all `exemplars` together.
    pub fn fit(exemplars: &[&ColorImage]) -> Result<Self> {
        ensure!(!exemplars.is_empty(), "no exemplar to analyse");
        let dim = WINDOW * WINDOW * 3;
        let mut mean = vec![0.0; dim];
        let mut count = 0usize;
        let mut cov = DMatrix::<f64>::zeros(dim, dim);
        let mut rows: Vec<Vec<f64>> = Vec::new();
        for img in exemplars {
            // At most about FIT_SAMPLES descriptors per exemplar, on a grid.
            let step = (((img.width * img.height) as f64 / FIT_SAMPLES as f64)
                .sqrt()
                .ceil() as usize)
                .max(1);
            for y in (0..img.height).step_by(step) {
                for x in (0..img.width).step_by(step) {
                    rows.push(descriptor(img, x, y));
                }
            }
        }
        for r in &rows {
            for (m, v) in mean.iter_mut().zip(r) {
                *m += v;
            }
            count += 1;
        }
        mean.iter_mut().for_each(|m| *m /= count as f64);
        for r in &rows {
            let centred =
                nalgebra::DVector::from_iterator(dim, r.iter().zip(&mean).map(|(v, m)| v - m));
            cov.syger(1.0, &centred, &centred, 1.0);
        }
        cov /= count.max(2) as f64 - 1.0;
        let eig = SymmetricEigen::new(cov);
        let mut order: Vec<usize> = (0..dim).collect();
        order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
        let total: f64 = eig.eigenvalues.iter().map(|v| v.max(0.0)).sum();
        let mut kept = 0.0;
        let mut components = Vec::new();
        for &k in &order {
            if components.len() >= MIN_COMPONENTS && kept >= MIN_VARIANCE * total {
                break;
            }
            kept += eig.eigenvalues[k].max(0.0);
            components.push(eig.eigenvectors.column(k).iter().copied().collect());
        }
        Ok(Self {
            mean,
            components,
            explained: if total > 0.0 { kept / total } else { 1.0 },
        })
    }

    /// The appearance vectors of every pixel of `img`, row by row, each
    /// from its 5×5 window with samples `step` apart (wrapping): what
    /// [`Pca::project`] of [`descriptor_spaced`] gives, bit for bit, with
    /// the components transposed so that each window is read once and every
    /// component's sum runs in the same order.
    pub fn project_image(&self, img: &ColorImage, step: usize) -> Vec<f64> {
        let nc = self.components.len();
        let dim = WINDOW * WINDOW * 3;
        // Component values by descriptor entry: `t[j * nc + c]`.
        let mut t = vec![0.0f64; dim * nc];
        for (c, comp) in self.components.iter().enumerate() {
            for (j, &v) in comp.iter().enumerate() {
                t[j * nc + c] = v;
            }
        }
        let rows = Rows {
            img,
            step,
            mean: &self.mean,
            t: &t,
            nc,
        };
        #[cfg(target_arch = "x86_64")]
        let avx2 = is_x86_feature_detected!("avx2");
        let mut out = vec![0.0f64; img.width * img.height * nc];
        out.par_chunks_mut(img.width * nc)
            .enumerate()
            .for_each(|(y, row)| {
                #[cfg(target_arch = "x86_64")]
                if avx2 {
                    // SAFETY: the CPU has AVX2 (detected above).
                    unsafe { rows.project_avx2(y, row) };
                    return;
                }
                rows.project(y, row);
            });
        out
    }

    /// The appearance vector of a descriptor.
    pub fn project(&self, d: &[f64]) -> Vec<f64> {
        self.components
            .iter()
            .map(|c| {
                c.iter()
                    .zip(d)
                    .zip(&self.mean)
                    .map(|((c, v), m)| c * (v - m))
                    .sum()
            })
            .collect()
    }
}

/// What [`Pca::project_image`] needs for one row.
struct Rows<'a> {
    img: &'a ColorImage,
    step: usize,
    mean: &'a [f64],
    /// The components by descriptor entry: `t[j * nc + c]`.
    t: &'a [f64],
    nc: usize,
}

impl Rows<'_> {
    /// Row `y`'s appearance vectors into `row`: per pixel the centred
    /// window, then every component's sum over it in entry order (a
    /// multiply and an add per entry, as [`Pca::project`] does).
    #[inline(always)]
    fn project(&self, y: usize, row: &mut [f64]) {
        let (img, nc) = (self.img, self.nc);
        let (w, h) = (img.width, img.height);
        let r = (WINDOW / 2) as isize;
        let wrap = |p: usize, d: isize, n: usize| {
            (p as isize + d * self.step as isize).rem_euclid(n as isize) as usize
        };
        let ys: Vec<usize> = (-r..=r).map(|dy| wrap(y, dy, h)).collect();
        let mut centred = [0.0f64; WINDOW * WINDOW * 3];
        let mut acc = vec![0.0f64; nc];
        for (x, px_out) in row.chunks_exact_mut(nc).enumerate() {
            let mut j = 0;
            for &yy in &ys {
                for dx in -r..=r {
                    for &ch in &img.get(wrap(x, dx, w), yy) {
                        centred[j] = f64::from(ch) - self.mean[j];
                        j += 1;
                    }
                }
            }
            // `Sum` of floats starts from −0.0, its identity.
            acc.fill(-0.0);
            for (j, &d) in centred.iter().enumerate() {
                for (a, &cv) in acc.iter_mut().zip(&self.t[j * nc..(j + 1) * nc]) {
                    *a += cv * d;
                }
            }
            px_out.copy_from_slice(&acc);
        }
    }

    /// [`Rows::project`] compiled for AVX2 (four components per operation;
    /// no fused multiply-add, so the same bits).
    ///
    /// # Safety
    /// The CPU must have AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn project_avx2(&self, y: usize, row: &mut [f64]) {
        self.project(y, row);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::parallel::tests::texture;

    #[test]
    fn the_kept_components_explain_at_least_95_percent() {
        let a = texture("pink_marble_color_128.png");
        let b = texture("brick_color_96.png");
        for set in [vec![&a], vec![&b], vec![&a, &b]] {
            let pca = Pca::fit(&set).unwrap();
            assert!(pca.components.len() >= MIN_COMPONENTS);
            assert!(pca.explained >= MIN_VARIANCE, "{}", pca.explained);
            // The components are orthonormal.
            for (i, u) in pca.components.iter().enumerate() {
                for (j, v) in pca.components.iter().enumerate() {
                    let dot: f64 = u.iter().zip(v).map(|(p, q)| p * q).sum();
                    let want = if i == j { 1.0 } else { 0.0 };
                    assert!((dot - want).abs() < 1e-9, "{i} {j} {dot}");
                }
            }
        }
    }

    #[test]
    fn the_whole_image_projection_is_the_per_pixel_one_bit_for_bit() {
        let a = texture("brick_color_96.png");
        let b = texture("pink_marble_color_128.png");
        let pca = Pca::fit(&[&a, &b]).unwrap();
        let nc = pca.components.len();
        for (img, step) in [(&a, 1), (&a, 3), (&b, 7), (&b, 40)] {
            let all = pca.project_image(img, step);
            assert_eq!(all.len(), img.width * img.height * nc);
            for (i, got) in all.chunks_exact(nc).enumerate() {
                let (x, y) = (i % img.width, i / img.width);
                let want = pca.project(&descriptor_spaced(img, x, y, step));
                let same = got
                    .iter()
                    .zip(&want)
                    .all(|(p, q)| p.to_bits() == q.to_bits());
                assert!(
                    same,
                    "pixel ({x}, {y}) step {step}: {got:?} against {want:?}"
                );
            }
        }
    }

    #[test]
    fn projection_keeps_most_of_each_descriptor_s_energy() {
        let a = texture("pink_marble_color_128.png");
        let pca = Pca::fit(&[&a]).unwrap();
        let (mut kept, mut all) = (0.0, 0.0);
        for (x, y) in [(0, 0), (17, 40), (127, 127), (64, 3)] {
            let d = descriptor(&a, x, y);
            let c: Vec<f64> = d.iter().zip(&pca.mean).map(|(v, m)| v - m).collect();
            all += c.iter().map(|v| v * v).sum::<f64>();
            kept += pca.project(&d).iter().map(|v| v * v).sum::<f64>();
        }
        assert!(kept <= all + 1e-6 && kept > 0.5 * all, "{kept} of {all}");
    }
}
