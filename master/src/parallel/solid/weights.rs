//! The weights of a solid's views (Manke–Wünsche §5 with the morph of §4):
//! a view's weight is its material's weight shared evenly among the
//! material's views; materials ramp along an axis or follow weight volumes.

use rayon::prelude::*;

use super::Axis;

/// The weight `Wʲ` of every view at every voxel of one level: the view's
/// share of its material times the material's weight there.
#[derive(Clone, Debug)]
pub struct ViewWeights {
    share: Vec<f32>,
    material_of: Vec<usize>,
    /// Per material, per voxel; `None` for one material.
    volumes: Option<Vec<Vec<f32>>>,
}

impl ViewWeights {
    /// The weight of view `j` at voxel `i`.
    #[inline]
    pub fn at(&self, j: usize, i: usize) -> f32 {
        match &self.volumes {
            None => self.share[j],
            Some(v) => self.share[j] * v[self.material_of[j]][i],
        }
    }
}

impl ViewWeights {
    /// Weights of views of `material_of` (each view's material): a view's
    /// share of its material, times the material's `volumes` (per voxel)
    /// when there are several.
    pub(super) fn new(material_of: &[usize], volumes: Option<Vec<Vec<f32>>>) -> Self {
        let share = material_of
            .iter()
            .map(|m| 1.0 / material_of.iter().filter(|&w| w == m).count() as f32)
            .collect();
        Self {
            share,
            material_of: material_of.to_vec(),
            volumes,
        }
    }
}

/// Material weights ramping along `axis`, at full size.
pub(super) fn ramp(m: usize, axis: Axis, size: [usize; 3]) -> Vec<Vec<f32>> {
    let len = size[axis.index()];
    let profile = crate::parallel::weights::ramp(m, crate::parallel::weights::Axis::X, len, 1);
    let n = size.iter().product::<usize>();
    profile
        .iter()
        .map(|p| {
            (0..n)
                .map(|i| {
                    let c = [i % size[0], i / size[0] % size[1], i / (size[0] * size[1])];
                    p[c[axis.index()]]
                })
                .collect()
        })
        .collect()
}

/// A weight volume at the level of step `h`: each voxel the mean of its
/// `h×h×h` block (cut at the border), so the materials still sum to 1.
pub(super) fn downsample3(w: &[f32], size: [usize; 3], h: usize) -> Vec<f32> {
    if h == 1 {
        return w.to_vec();
    }
    let ls = size.map(|n| n.div_ceil(h));
    (0..ls.iter().product::<usize>())
        .into_par_iter()
        .map(|i| {
            let l = [i % ls[0], i / ls[0] % ls[1], i / (ls[0] * ls[1])];
            let lo = l.map(|c| c * h);
            let hi = [0, 1, 2].map(|a| ((l[a] + 1) * h).min(size[a]));
            let mut sum = 0.0f64;
            for z in lo[2]..hi[2] {
                for y in lo[1]..hi[1] {
                    let row = (z * size[1] + y) * size[0];
                    sum += w[row + lo[0]..row + hi[0]]
                        .iter()
                        .map(|&v| f64::from(v))
                        .sum::<f64>();
                }
            }
            let count = (0..3).map(|a| hi[a] - lo[a]).product::<usize>();
            (sum / count as f64) as f32
        })
        .collect()
}
