//! The two-colour fit (Bourque–Dudek §3.2): colours are not searched; for
//! every render they are fitted in closed form by matching the pattern's
//! sorted values to the target's colours sorted by luminance (a
//! least-squares line per channel, either sign).

use crate::imaging::colour::luminance;
use crate::imaging::ColorImage;

/// Groups of pixels averaged along the sorted order in the colour fit.
const GROUPS: usize = 64;

/// The target's colours, sorted by luminance and averaged in groups.
pub struct ColourTarget {
    groups: Vec<[f64; 3]>,
}

impl ColourTarget {
    pub fn of(img: &ColorImage) -> Self {
        let l = luminance(img);
        let mut idx: Vec<usize> = (0..img.len()).collect();
        idx.sort_by_key(|&i| (l.data[i], i));
        let n = idx.len().max(1);
        let groups = (0..GROUPS)
            .map(|g| {
                let (a, b) = (
                    g * n / GROUPS,
                    ((g + 1) * n / GROUPS).max(g * n / GROUPS + 1),
                );
                let mut c = [0.0; 3];
                for &i in &idx[a..b.min(idx.len())] {
                    for (k, ck) in c.iter_mut().enumerate() {
                        *ck += f64::from(img.rgb[3 * i + k]);
                    }
                }
                c.map(|x| x / (b - a) as f64)
            })
            .collect();
        Self { groups }
    }

    /// The two colours that make `field` look most like the target: the
    /// least-squares line per channel through (sorted pattern value, target
    /// colour at the same luminance rank), for the better of both signs.
    pub fn fit(&self, field: &[f32]) -> [[f64; 3]; 2] {
        self.fit_signs(field, &[false, true])
    }

    /// [`ColourTarget::fit`] with the orientation given: the darker colour
    /// at pattern value 0 when `dark_low`, at 1 otherwise.
    pub fn fit_oriented(&self, field: &[f32], dark_low: bool) -> [[f64; 3]; 2] {
        self.fit_signs(field, &[!dark_low])
    }

    fn fit_signs(&self, field: &[f32], flips: &[bool]) -> [[f64; 3]; 2] {
        let mut f: Vec<f32> = field.to_vec();
        f.sort_by(f32::total_cmp);
        let n = f.len().max(1);
        let xs: Vec<f64> = (0..GROUPS)
            .map(|g| {
                let (a, b) = (
                    g * n / GROUPS,
                    ((g + 1) * n / GROUPS).max(g * n / GROUPS + 1),
                );
                let b = b.min(f.len());
                f[a..b].iter().map(|&x| f64::from(x)).sum::<f64>() / (b - a).max(1) as f64
            })
            .collect();
        let mx = xs.iter().sum::<f64>() / GROUPS as f64;
        let vx: f64 = xs.iter().map(|x| (x - mx) * (x - mx)).sum();
        let mean_c: [f64; 3] =
            std::array::from_fn(|k| self.groups.iter().map(|c| c[k]).sum::<f64>() / GROUPS as f64);
        if vx < 1e-12 {
            return [mean_c, mean_c];
        }
        let mut best = (f64::INFINITY, [mean_c, mean_c]);
        for &flip in flips {
            let col = |g: usize| self.groups[if flip { GROUPS - 1 - g } else { g }];
            let mut lo = [0.0; 3];
            let mut hi = [0.0; 3];
            let mut residual = 0.0;
            for k in 0..3 {
                let cov: f64 = (0..GROUPS)
                    .map(|g| (xs[g] - mx) * (col(g)[k] - mean_c[k]))
                    .sum();
                let b = cov / vx;
                let a = mean_c[k] - b * mx;
                lo[k] = a;
                hi[k] = a + b;
                residual += (0..GROUPS)
                    .map(|g| (a + b * xs[g] - col(g)[k]).powi(2))
                    .sum::<f64>();
            }
            if residual < best.0 {
                best = (residual, [lo, hi]);
            }
        }
        best.1
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::procedural::shaders::{by_name, colourise};

    #[test]
    fn colour_fit_recovers_the_colours_of_a_render() {
        let s = by_name("clouds").unwrap();
        let f = s.render_field(&[3.0, 0.5], 64, 64, 64);
        for colours in [
            [[20.0, 40.0, 200.0], [250.0, 200.0, 10.0]],
            [[230.0, 220.0, 210.0], [30.0, 60.0, 20.0]],
        ] {
            let img = colourise(&f, 64, 64, &colours);
            let fit = ColourTarget::of(&img).fit(&f);
            for k in 0..2 {
                for i in 0..3 {
                    assert!(
                        (fit[k][i] - colours[k][i]).abs() < 3.0,
                        "{fit:?} against {colours:?}"
                    );
                }
            }
        }
    }
}
