//! Gaussian pyramid (Stahlhut §6, after Burt–Adelson; ARCHITECTURE §3.1, §3.8).
//!
//! 5-tap binomial filter [1 4 6 4 1]/16, separable, then decimation by 2
//! keeping the even pixels: a `w`×`h` level has a `(w+1)/2`×`(h+1)/2` parent.
//! With a *defined* mask the filter is a normalized convolution over defined
//! pixels only, so hole contents never leak into coarse levels; a coarse pixel
//! is defined only if all of its children are. Integer arithmetic throughout,
//! so results are deterministic and independent of the thread count.

use rayon::prelude::*;

use crate::imaging::Gray;

/// Binomial taps, summing to 16 (256 in 2-D).
const TAPS: [u32; 5] = [1, 4, 6, 4, 1];

/// Source index of tap `k` for output position `c` (input position `2c + k - 2`):
/// clamp-to-edge, or toroidal when `wrap` (ARCHITECTURE §3.1 `--tileable`).
#[inline]
fn tap_index(c: usize, k: usize, n: usize, wrap: bool) -> usize {
    let i = (2 * c + k) as isize - 2;
    if wrap {
        i.rem_euclid(n as isize) as usize
    } else {
        i.clamp(0, n as isize - 1) as usize
    }
}

/// Size of the next coarser level.
#[inline]
pub fn coarse_size(w: usize, h: usize) -> (usize, usize) {
    (w.div_ceil(2), h.div_ceil(2))
}

/// Size of level `level` (0 = the `w`×`h` input).
pub fn level_size(w: usize, h: usize, level: usize) -> (usize, usize) {
    let (mut w, mut h) = (w, h);
    for _ in 0..level {
        (w, h) = coarse_size(w, h);
    }
    (w, h)
}

/// One pyramid step: binomial blur and decimation by 2.
///
/// With `defined` (one flag per pixel), undefined pixels get weight 0 and the
/// weights are renormalized; an output whose footprint holds no defined pixel
/// is 0. Panics if `defined` does not have one entry per pixel.
pub fn downsample(g: &Gray, defined: Option<&[bool]>, wrap: bool) -> Gray {
    let (w, h) = (g.width, g.height);
    assert_eq!(g.data.len(), w * h, "gray buffer size");
    if let Some(d) = defined {
        assert_eq!(d.len(), w * h, "defined mask size");
    }
    let (cw, ch) = coarse_size(w, h);
    let mut out = Gray::new(cw, ch);
    if cw == 0 || ch == 0 {
        return out;
    }
    // Horizontal taps per coarse column, shared by all rows.
    let xs: Vec<[usize; 5]> = (0..cw)
        .map(|cx| std::array::from_fn(|k| tap_index(cx, k, w, wrap)))
        .collect();

    out.data.par_chunks_mut(cw).enumerate().for_each_init(
        || (vec![0u32; 5 * cw], vec![0u32; 5 * cw]),
        |(num, den), (cy, out_row)| {
            // Horizontal pass over the five source rows of this coarse row.
            for k in 0..5 {
                let y = tap_index(cy, k, h, wrap);
                let row = &g.data[y * w..(y + 1) * w];
                let (nrow, drow) = (
                    &mut num[k * cw..(k + 1) * cw],
                    &mut den[k * cw..(k + 1) * cw],
                );
                match defined {
                    None => {
                        for (cx, t) in xs.iter().enumerate() {
                            nrow[cx] = (0..5).map(|j| TAPS[j] * row[t[j]] as u32).sum();
                            drow[cx] = 16;
                        }
                    }
                    Some(d) => {
                        let drow_in = &d[y * w..(y + 1) * w];
                        for (cx, t) in xs.iter().enumerate() {
                            let (mut n, mut s) = (0u32, 0u32);
                            for j in 0..5 {
                                let wt = TAPS[j] * u32::from(drow_in[t[j]]);
                                n += wt * row[t[j]] as u32;
                                s += wt;
                            }
                            nrow[cx] = n;
                            drow[cx] = s;
                        }
                    }
                }
            }
            // Vertical pass and rounded normalization.
            for (cx, o) in out_row.iter_mut().enumerate() {
                let (mut n, mut s) = (0u32, 0u32);
                for k in 0..5 {
                    n += TAPS[k] * num[k * cw + cx];
                    s += TAPS[k] * den[k * cw + cx];
                }
                *o = (n + s / 2).checked_div(s).unwrap_or(0) as u8;
            }
        },
    );
    out
}

/// One pyramid step on a floating-point plane: the same 5-tap binomial blur
/// and 2× decimation, edges clamped (the measures of `texsyn compare`).
pub fn reduce_f64(v: &[f64], w: usize, h: usize) -> (Vec<f64>, usize, usize) {
    const K: [f64; 5] = [1.0, 4.0, 6.0, 4.0, 1.0];
    let at = |x: isize, y: isize| {
        let x = x.clamp(0, w as isize - 1) as usize;
        let y = y.clamp(0, h as isize - 1) as usize;
        v[y * w + x]
    };
    let (nw, nh) = (w.div_ceil(2), h.div_ceil(2));
    let mut out = vec![0.0; nw * nh];
    for y in 0..nh {
        for x in 0..nw {
            let mut s = 0.0;
            for (j, kj) in K.iter().enumerate() {
                for (i, ki) in K.iter().enumerate() {
                    s += ki
                        * kj
                        * at(
                            2 * x as isize + i as isize - 2,
                            2 * y as isize + j as isize - 2,
                        );
                }
            }
            out[y * nw + x] = s / 256.0;
        }
    }
    (out, nw, nh)
}

/// Defined mask of the next coarser level: a coarse pixel is defined only if
/// all of its children (the 2×2 block, clipped at the edge) are (ARCHITECTURE §3.1).
pub fn downsample_mask(defined: &[bool], w: usize, h: usize) -> Vec<bool> {
    assert_eq!(defined.len(), w * h, "defined mask size");
    let (cw, ch) = coarse_size(w, h);
    let mut out = Vec::with_capacity(cw * ch);
    for cy in 0..ch {
        let ys = 2 * cy..(2 * cy + 2).min(h);
        for cx in 0..cw {
            let xs = 2 * cx..(2 * cx + 2).min(w);
            out.push(ys.clone().all(|y| xs.clone().all(|x| defined[y * w + x])));
        }
    }
    out
}

/// The pyramid: `levels` entries, index 0 = finest (the input), each with its
/// defined mask when `defined` is given.
pub fn pyramid(
    g: &Gray,
    defined: Option<&[bool]>,
    levels: usize,
    wrap: bool,
) -> Vec<(Gray, Option<Vec<bool>>)> {
    let mut out: Vec<(Gray, Option<Vec<bool>>)> = Vec::with_capacity(levels);
    if levels == 0 {
        return out;
    }
    out.push((g.clone(), defined.map(<[bool]>::to_vec)));
    for _ in 1..levels {
        let (prev, pd) = out.last().expect("non-empty");
        let next = downsample(prev, pd.as_deref(), wrap);
        let nd = pd
            .as_deref()
            .map(|d| downsample_mask(d, prev.width, prev.height));
        out.push((next, nd));
    }
    out
}

/// How many levels (including the input) keep the coarsest side >= `min_side`;
/// at least 1, and no level is added once the image is 1×1.
pub fn max_levels(w: usize, h: usize, min_side: usize) -> usize {
    let min_side = min_side.max(1);
    let (mut w, mut h) = (w, h);
    let mut n = 1;
    while w > 1 || h > 1 {
        let (cw, ch) = coarse_size(w, h);
        if cw.min(ch) < min_side {
            break;
        }
        n += 1;
        (w, h) = (cw, ch);
    }
    n
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn noise(w: usize, h: usize, seed: u32) -> Gray {
        let mut s = seed.wrapping_mul(2_654_435_761).wrapping_add(1);
        Gray::from_vec(
            w,
            h,
            (0..w * h)
                .map(|_| {
                    s ^= s << 13;
                    s ^= s >> 17;
                    s ^= s << 5;
                    (s >> 24) as u8
                })
                .collect(),
        )
    }

    /// Plain 2-D reference: normalized convolution with the 5×5 outer product.
    fn reference(g: &Gray, d: Option<&[bool]>, wrap: bool) -> Gray {
        let (w, h) = (g.width, g.height);
        let (cw, ch) = coarse_size(w, h);
        let mut out = Gray::new(cw, ch);
        for cy in 0..ch {
            for cx in 0..cw {
                let (mut n, mut s) = (0u32, 0u32);
                for (ky, ty) in TAPS.iter().enumerate() {
                    for (kx, tx) in TAPS.iter().enumerate() {
                        let (x, y) = (tap_index(cx, kx, w, wrap), tap_index(cy, ky, h, wrap));
                        let def = d.is_none_or(|d| d[y * w + x]);
                        let wt = tx * ty * u32::from(def);
                        n += wt * g.get(x, y) as u32;
                        s += wt;
                    }
                }
                out.set(cx, cy, (n + s / 2).checked_div(s).unwrap_or(0) as u8);
            }
        }
        out
    }

    fn shift(g: &Gray, dx: usize, dy: usize) -> Gray {
        let mut o = Gray::new(g.width, g.height);
        for y in 0..g.height {
            for x in 0..g.width {
                o.set((x + dx) % g.width, (y + dy) % g.height, g.get(x, y));
            }
        }
        o
    }

    #[test]
    fn sizes() {
        assert_eq!(coarse_size(7, 4), (4, 2));
        assert_eq!(coarse_size(1, 1), (1, 1));
        let d = downsample(&noise(7, 5, 1), None, false);
        assert_eq!((d.width, d.height, d.data.len()), (4, 3, 12));
        assert_eq!(downsample_mask(&[true; 35], 7, 5).len(), 12);
    }

    #[test]
    fn constant_stays_constant() {
        for &(w, h) in &[(1, 1), (2, 3), (9, 7), (16, 16)] {
            for wrap in [false, true] {
                let g = Gray::from_vec(w, h, vec![173; w * h]);
                let d = downsample(&g, None, wrap);
                assert!(d.data.iter().all(|&v| v == 173), "{w}x{h} wrap={wrap}");
                let mask: Vec<bool> = (0..w * h).map(|i| i % 3 != 0).collect();
                let d = downsample(&g, Some(&mask), wrap);
                assert!(d.data.iter().all(|&v| v == 173 || v == 0), "{w}x{h}");
            }
        }
    }

    #[test]
    fn matches_2d_reference() {
        for (i, &(w, h)) in [(1, 1), (2, 2), (3, 5), (8, 6), (17, 11)]
            .iter()
            .enumerate()
        {
            let g = noise(w, h, i as u32);
            let mask: Vec<bool> = noise(w, h, 99 + i as u32)
                .data
                .iter()
                .map(|&v| v > 90)
                .collect();
            for wrap in [false, true] {
                assert_eq!(downsample(&g, None, wrap), reference(&g, None, wrap));
                assert_eq!(
                    downsample(&g, Some(&mask), wrap),
                    reference(&g, Some(&mask), wrap)
                );
            }
        }
    }

    #[test]
    fn holes_never_leak() {
        let (w, h) = (24, 20);
        let holes: Vec<bool> = noise(w, h, 5).data.iter().map(|&v| v < 100).collect();
        let g = Gray::from_vec(
            w,
            h,
            holes
                .iter()
                .map(|&hole| if hole { 255 } else { 0 })
                .collect(),
        );
        let defined: Vec<bool> = holes.iter().map(|&hole| !hole).collect();
        for wrap in [false, true] {
            let d = downsample(&g, Some(&defined), wrap);
            assert!(d.data.iter().all(|&v| v == 0), "wrap={wrap}");
        }
        // Without the mask the holes do show up.
        assert!(downsample(&g, None, false).data.iter().any(|&v| v > 0));
    }

    #[test]
    fn no_defined_pixel_gives_zero() {
        let g = Gray::from_vec(4, 4, vec![200; 16]);
        let d = downsample(&g, Some(&[false; 16]), false);
        assert!(d.data.iter().all(|&v| v == 0));
    }

    #[test]
    fn wrap_commutes_with_circular_shift() {
        let (w, h) = (16, 12);
        let g = noise(w, h, 7);
        let mask: Vec<bool> = noise(w, h, 8).data.iter().map(|&v| v > 60).collect();
        let mg = Gray::from_vec(w, h, mask.iter().map(|&b| b as u8).collect());
        let shifted_mask: Vec<bool> = shift(&mg, 2, 4).data.iter().map(|&v| v == 1).collect();
        let a = downsample(&shift(&g, 2, 4), None, true);
        let b = shift(&downsample(&g, None, true), 1, 2);
        assert_eq!(a, b);
        let a = downsample(&shift(&g, 2, 4), Some(&shifted_mask), true);
        let b = shift(&downsample(&g, Some(&mask), true), 1, 2);
        assert_eq!(a, b);
        // Clamp mode does not commute in general.
        assert_ne!(
            downsample(&shift(&g, 2, 4), None, false),
            shift(&downsample(&g, None, false), 1, 2)
        );
    }

    #[test]
    fn pyramid_levels_and_masks() {
        let g = noise(37, 20, 3);
        let def: Vec<bool> = (0..37 * 20).map(|i| i % 37 < 30).collect();
        let p = pyramid(&g, Some(&def), 4, false);
        assert_eq!(p.len(), 4);
        assert_eq!(p[0].0, g);
        assert_eq!(p[0].1.as_deref(), Some(&def[..]));
        let sizes: Vec<_> = p.iter().map(|(l, _)| (l.width, l.height)).collect();
        assert_eq!(sizes, vec![(37, 20), (19, 10), (10, 5), (5, 3)]);
        for (l, m) in &p {
            assert_eq!(m.as_ref().unwrap().len(), l.width * l.height);
        }
        assert_eq!(p[1].0, downsample(&g, Some(&def), false));
        assert!(pyramid(&g, None, 3, true).iter().all(|(_, m)| m.is_none()));
        assert!(pyramid(&g, None, 0, false).is_empty());
    }

    #[test]
    fn max_levels_counts() {
        assert_eq!(max_levels(64, 64, 16), 3); // 64, 32, 16
        assert_eq!(max_levels(64, 64, 17), 2);
        assert_eq!(max_levels(192, 100, 8), 4); // 100, 50, 25, 13 (next 7)
        assert_eq!(max_levels(5, 5, 10), 1);
        assert_eq!(max_levels(4, 4, 0), 3); // 4, 2, 1
        assert_eq!(max_levels(1, 1, 1), 1);
        assert_eq!(max_levels(0, 0, 1), 1);
    }

    proptest! {
        #[test]
        fn mask_is_all_children(w in 1usize..20, h in 1usize..20, bits in proptest::collection::vec(any::<bool>(), 400)) {
            let d = &bits[..w * h];
            let c = downsample_mask(d, w, h);
            let (cw, ch) = coarse_size(w, h);
            prop_assert_eq!(c.len(), cw * ch);
            for cy in 0..ch {
                for cx in 0..cw {
                    let mut all = true;
                    for y in 2 * cy..(2 * cy + 2).min(h) {
                        for x in 2 * cx..(2 * cx + 2).min(w) {
                            all &= d[y * w + x];
                        }
                    }
                    prop_assert_eq!(c[cy * cw + cx], all);
                }
            }
        }

        #[test]
        fn masked_output_only_reads_defined(w in 1usize..16, h in 1usize..16, seed in any::<u32>(), wrap in any::<bool>()) {
            let g = noise(w, h, seed);
            let def: Vec<bool> = noise(w, h, seed ^ 0x5555).data.iter().map(|&v| v & 1 == 1).collect();
            let mut g2 = g.clone();
            for (v, &d) in g2.data.iter_mut().zip(&def) {
                if !d { *v = 255 - *v; }
            }
            prop_assert_eq!(downsample(&g, Some(&def), wrap), downsample(&g2, Some(&def), wrap));
        }
    }
}
