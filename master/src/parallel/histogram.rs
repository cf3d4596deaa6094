//! Histogram matching of a solid (after Kopf et al. 2007, "Solid texture
//! synthesis from 2D exemplars", as the cure for the wash-out that
//! Manke–Wünsche §6 also report; ARCHITECTURE §11).
//!
//! A voxel's value is the weighted blend of its views' exemplar values
//! (eq. 2), and a blend of values that do not yet agree is flatter than any
//! exemplar: matched against it, each view picks flat regions and flatness
//! feeds on itself. Kopf et al. counter this by re-weighting the voxel
//! colour's optimisation so that the solid's histograms follow the
//! exemplar's. Here the values are not optimised but chosen, so the matching
//! is applied to what the choice reads: after every correction sub-pass, each
//! appearance component of the blend is mapped, monotonically, so that its
//! histogram over the volume is the exemplars' ([`Matching`]); the
//! neighbourhoods gathered for eq. 5 then have the exemplar's contrast. The
//! map is a smooth function of the value alone, so it adds no grain (a
//! per-candidate penalty, the earlier approach, made neighbouring voxels
//! alternate between bins, a pixel checker at the sub-passes' parity).
//! The output colour gets the same treatment per channel ([`match_bytes`]).

use rayon::prelude::*;

/// Bins of the volume's histogram of one component.
const BINS: usize = 1024;
/// Quantiles kept of a target distribution.
const QUANTILES: usize = 257;
/// Voxels per parallel chunk of the histogram count (fixed, so the counts,
/// integers, do not depend on threads).
const CHUNK: usize = 8192;

/// The target distributions of every appearance component, as quantiles.
pub struct Matching {
    dims: usize,
    /// Per component, its quantiles at `i / (QUANTILES − 1)`.
    quantiles: Vec<Vec<f32>>,
}

impl Matching {
    /// The target of `dims` components: the values of `sources`, each an
    /// exemplar level's appearance vectors (`dims` per pixel) with the weight
    /// its views have in the volume.
    pub fn new(dims: usize, sources: &[(&[f32], f64)]) -> Self {
        let quantiles = (0..dims)
            .into_par_iter()
            .map(|c| {
                // Each value with its source; within a source every value
                // weighs the same, so ordering ties by source gives the
                // stable sort's sequence of (value, weight).
                let weight: Vec<f64> = sources
                    .iter()
                    .map(|(a, w)| w / (a.len() / dims).max(1) as f64)
                    .collect();
                let mut v: Vec<(f32, u32)> = Vec::new();
                for (s, (a, w)) in sources.iter().enumerate() {
                    if *w <= 0.0 {
                        continue;
                    }
                    v.extend(a.iter().skip(c).step_by(dims).map(|&x| (x, s as u32)));
                }
                v.par_sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                let v: Vec<(f32, f64)> = v.iter().map(|&(x, s)| (x, weight[s as usize])).collect();
                quantiles_of(&v)
            })
            .collect();
        Self { dims, quantiles }
    }

    /// `out` = `raw` with each component mapped so that its histogram over
    /// the volume is the target's, moved `strength` (0 to 1) of the way.
    pub fn apply(&self, raw: &[f32], strength: f32, out: &mut Vec<f32>) {
        let dims = self.dims;
        out.clear();
        out.resize(raw.len(), 0.0);
        let n = raw.len() / dims;
        if n == 0 {
            return;
        }
        // Range of every component.
        let (lo, hi) = raw
            .par_chunks(CHUNK * dims)
            .map(|chunk| {
                let mut lo = vec![f32::INFINITY; dims];
                let mut hi = vec![f32::NEG_INFINITY; dims];
                for v in chunk.chunks_exact(dims) {
                    for c in 0..dims {
                        lo[c] = lo[c].min(v[c]);
                        hi[c] = hi[c].max(v[c]);
                    }
                }
                (lo, hi)
            })
            .reduce(
                || (vec![f32::INFINITY; dims], vec![f32::NEG_INFINITY; dims]),
                |(mut a, mut b), (c, d)| {
                    for k in 0..dims {
                        a[k] = a[k].min(c[k]);
                        b[k] = b[k].max(d[k]);
                    }
                    (a, b)
                },
            );
        let scale: Vec<f32> = (0..dims)
            .map(|c| {
                if hi[c] > lo[c] {
                    BINS as f32 / (hi[c] - lo[c])
                } else {
                    0.0
                }
            })
            .collect();
        let bin = |c: usize, v: f32| -> (usize, f32) {
            let t = (v - lo[c]) * scale[c];
            let b = (t as usize).min(BINS - 1);
            (b, (t - b as f32).clamp(0.0, 1.0))
        };
        let counts = raw
            .par_chunks(CHUNK * dims)
            .map(|chunk| {
                let mut h = vec![0u32; dims * BINS];
                for v in chunk.chunks_exact(dims) {
                    for (c, &x) in v.iter().enumerate() {
                        h[c * BINS + bin(c, x).0] += 1;
                    }
                }
                h
            })
            .reduce(
                || vec![0u32; dims * BINS],
                |mut a, b| {
                    for (x, y) in a.iter_mut().zip(b) {
                        *x += y;
                    }
                    a
                },
            );
        // Per component, the target value at every bin edge: the edge's
        // share of the volume below it, looked up in the target's quantiles.
        let edges: Vec<f32> = (0..dims)
            .flat_map(|c| {
                let mut below = 0u64;
                let mut e = Vec::with_capacity(BINS + 1);
                for b in 0..=BINS {
                    e.push(quantile(&self.quantiles[c], below as f64 / n as f64));
                    if b < BINS {
                        below += u64::from(counts[c * BINS + b]);
                    }
                }
                e
            })
            .collect();
        out.par_chunks_mut(dims)
            .zip(raw.par_chunks(dims))
            .for_each(|(o, v)| {
                for c in 0..dims {
                    let (b, f) = bin(c, v[c]);
                    let e = &edges[c * (BINS + 1) + b..];
                    let m = e[0] + f * (e[1] - e[0]);
                    o[c] = v[c] + strength * (m - v[c]);
                }
            });
    }
}

/// Quantiles at `i / (QUANTILES − 1)` of weighted values sorted by value.
fn quantiles_of(v: &[(f32, f64)]) -> Vec<f32> {
    if v.is_empty() {
        return vec![0.0; QUANTILES];
    }
    let total: f64 = v.iter().map(|p| p.1).sum();
    let mut out = Vec::with_capacity(QUANTILES);
    let (mut k, mut cum) = (0usize, v[0].1);
    for i in 0..QUANTILES {
        let p = i as f64 / (QUANTILES - 1) as f64 * total;
        while cum < p && k + 1 < v.len() {
            k += 1;
            cum += v[k].1;
        }
        out.push(v[k].0);
    }
    out
}

/// The value at share `p` (0 to 1) of quantiles, interpolated.
fn quantile(q: &[f32], p: f64) -> f32 {
    let t = (p.clamp(0.0, 1.0) * (q.len() - 1) as f64) as f32;
    let i = (t as usize).min(q.len() - 2);
    let f = t - i as f32;
    q[i] + f * (q[i + 1] - q[i])
}

/// Byte histogram matching of one channel: `data[channel + k·channels]`
/// (every `channels`-th byte) mapped so that its histogram is `target`'s
/// (normalised, 256 levels), moved `strength` (0 to 1) of the way. The map is
/// a table of the 256 levels: each source level goes to the target level at
/// the middle of its share of the cumulative histogram.
pub(crate) fn match_bytes(
    data: &mut [u8],
    channels: usize,
    channel: usize,
    target: &[f64; 256],
    strength: f32,
) {
    let mut count = [0u64; 256];
    for &v in data.iter().skip(channel).step_by(channels) {
        count[usize::from(v)] += 1;
    }
    let n: u64 = count.iter().sum();
    if n == 0 {
        return;
    }
    let total: f64 = target.iter().sum();
    let mut target_cdf = [0.0f64; 256];
    let mut acc = 0.0;
    for (c, t) in target_cdf.iter_mut().zip(target) {
        acc += t / total.max(f64::MIN_POSITIVE);
        *c = acc;
    }
    let mut table = [0u8; 256];
    let mut below = 0u64;
    for l in 0..256 {
        let p = (below as f64 + 0.5 * count[l] as f64) / n as f64;
        below += count[l];
        let t = target_cdf.iter().position(|&c| c >= p).unwrap_or(255) as f32;
        let m = l as f32 + strength * (t - l as f32);
        table[l] = m.round().clamp(0.0, 255.0) as u8;
    }
    for v in data.iter_mut().skip(channel).step_by(channels) {
        *v = table[usize::from(*v)];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matching_gives_the_target_s_quantiles_and_keeps_the_order() {
        // Source: a narrow ramp; target: a wide one, in one component of 2.
        let raw: Vec<f32> = (0..1000).flat_map(|i| [i as f32 * 0.01, 5.0]).collect();
        let target: Vec<f32> = (0..500)
            .flat_map(|i| [i as f32 * 2.0 - 500.0, 5.0])
            .collect();
        let m = Matching::new(2, &[(&target, 1.0)]);
        let mut out = Vec::new();
        m.apply(&raw, 1.0, &mut out);
        let x: Vec<f32> = out.iter().step_by(2).copied().collect();
        assert!(x.windows(2).all(|w| w[0] <= w[1]), "not monotone");
        assert!((x[0] + 500.0).abs() < 5.0, "{}", x[0]);
        assert!((x[999] - 498.0).abs() < 5.0, "{}", x[999]);
        assert!((x[500] - 0.0).abs() < 5.0, "{}", x[500]);
        // Half the strength goes half the way.
        m.apply(&raw, 0.5, &mut out);
        assert!((out[0] - 0.5 * (0.0 - 500.0)).abs() < 3.0, "{}", out[0]);
    }

    #[test]
    fn the_quantiles_are_the_stable_sort_s_with_ties_across_sources() {
        // Two components; values that tie within and across sources, whose
        // per-value weights differ (1/700 against 3/300), and a source of
        // weight 0 that must not count.
        let a: Vec<f32> = (0..1400).map(|i| (i % 7) as f32 * 0.5).collect();
        let b: Vec<f32> = (0..600).map(|i| (i % 5) as f32 * 0.75).collect();
        let z: Vec<f32> = vec![100.0; 40];
        let sources: [(&[f32], f64); 3] = [(&a, 1.0), (&z, 0.0), (&b, 3.0)];
        let m = Matching::new(2, &sources);
        for c in 0..2 {
            let mut v: Vec<(f32, f64)> = Vec::new();
            for (s, w) in &sources {
                if *w > 0.0 {
                    let n = (s.len() / 2) as f64;
                    v.extend(s.iter().skip(c).step_by(2).map(|&x| (x, w / n)));
                }
            }
            v.sort_by(|p, q| p.0.total_cmp(&q.0));
            let want = quantiles_of(&v);
            let same = m.quantiles[c]
                .iter()
                .zip(&want)
                .all(|(p, q)| p.to_bits() == q.to_bits());
            assert!(same, "component {c}");
        }
    }

    #[test]
    fn byte_matching_stretches_a_flat_channel_to_the_target() {
        let mut data: Vec<u8> = (0..3000).map(|i| 120 + (i % 16) as u8).collect();
        let mut target = [0.0; 256];
        target.iter_mut().for_each(|t| *t = 1.0);
        match_bytes(&mut data, 1, 0, &target, 1.0);
        let (lo, hi) = (data.iter().min().unwrap(), data.iter().max().unwrap());
        assert!(*lo < 16 && *hi > 239, "{lo} {hi}");
    }
}
