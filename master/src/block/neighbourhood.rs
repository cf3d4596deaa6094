//! Search neighbourhoods (Stahlhut §5–§6, ARCHITECTURE §3.2–§3.3).
//!
//! A search vector is the block's N×N neighbourhood on the canvas (masked to
//! its defined pixels, Stahlhut §5) followed by the M×M window around the
//! parent position in the finished coarser canvas level (§6). With `wrap` the
//! canvas is a torus (§4, tileability). The reference side of full-colour
//! search ([`colour_vectors`]) is laid out the same way.

use anyhow::{bail, Context, Result};
use texsyn_engine::Positions;

use super::canvas::Canvas;
use super::plan::LevelSample;
use crate::imaging::Gray;

/// Which hi-part pixels a query may use.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Shape {
    /// The whole symmetric window, masked to defined pixels (constrained synthesis).
    Symmetric,
    /// The causal L-shape of scan-line full synthesis: rows above the block and
    /// pixels left of it in its rows (ARCHITECTURE §3.6).
    Causal { block: usize },
}

/// Most coherence candidates kept per query.
const MAX_CANDIDATES: usize = 32;

/// The coherence candidates of the block centred at (cx, cy) (Ashikhmin's
/// coherence, k = 1): for each defined pixel of its N×N window, the sample
/// position it was copied from shifted back by its offset, as global reference
/// indices (distinct, at most [`MAX_CANDIDATES`]). They only seed the search's
/// bound, so any choice gives the same answer (ARCHITECTURE §3.5).
pub fn candidates(
    canvas: &Canvas,
    cx: isize,
    cy: isize,
    n: usize,
    positions: &Positions,
) -> Vec<u64> {
    let mut out = Vec::new();
    let r = (n / 2) as isize;
    for dy in -r..=r {
        for dx in -r..=r {
            let Some(k) = canvas.index(cx + dx, cy + dy) else {
                continue;
            };
            if !canvas.defined[k] {
                continue;
            }
            let [sx, sy] = canvas.copy[k];
            let (x, y) = (i64::from(sx) - dx as i64, i64::from(sy) - dy as i64);
            let (Ok(x), Ok(y)) = (u32::try_from(x), u32::try_from(y)) else {
                continue;
            };
            let Some(i) = positions.index_of(x, y) else {
                continue;
            };
            if !out.contains(&i) {
                out.push(i);
                if out.len() == MAX_CANDIDATES {
                    return out;
                }
            }
        }
    }
    out
}

/// Writes the search vector of the window centred at (cx, cy): `values` and
/// `mask` hold N² hi components per channel then M² lo components per channel
/// (channels: Y, or Y, Cb, Cr for full-colour search); mask 1 = compare.
#[allow(clippy::too_many_arguments)]
pub fn query(
    canvas: &Canvas,
    parent: Option<&Canvas>,
    cx: isize,
    cy: isize,
    n: usize,
    m: usize,
    shape: Shape,
    values: &mut [u8],
    mask: &mut [u8],
) {
    let r = (n / 2) as isize;
    let mut out = VectorWriter { values, mask, k: 0 };
    let allowed = |dx: isize, dy: isize| match shape {
        Shape::Symmetric => true,
        Shape::Causal { block } => {
            let h = (block / 2) as isize;
            dy < -h || (dy <= h && dx < -h)
        }
    };
    for plane in canvas.planes() {
        out.window(canvas, plane, (cx, cy), r, allowed);
    }
    if let Some(p) = parent {
        let pr = (m / 2) as isize;
        let (px, py) = (cx.div_euclid(2), cy.div_euclid(2));
        for plane in p.planes() {
            out.window(p, plane, (px, py), pr, |_, _| true);
        }
    }
}

/// Writes search-vector components in order.
struct VectorWriter<'v> {
    values: &'v mut [u8],
    mask: &'v mut [u8],
    k: usize,
}

impl VectorWriter<'_> {
    /// The (2r+1)² window of `plane` (a plane of `canvas`) around `centre`, row
    /// by row: a pixel is compared (mask 1) where it is inside, defined and
    /// `allowed(dx, dy)`; otherwise value and mask are 0.
    #[inline]
    fn window(
        &mut self,
        canvas: &Canvas,
        plane: &[u8],
        centre: (isize, isize),
        r: isize,
        allowed: impl Fn(isize, isize) -> bool,
    ) {
        let (cx, cy) = centre;
        for dy in -r..=r {
            for dx in -r..=r {
                let k = self.k;
                match canvas.index(cx + dx, cy + dy) {
                    Some(i) if allowed(dx, dy) && canvas.defined[i] => {
                        self.values[k] = plane[i];
                        self.mask[k] = 1;
                    }
                    _ => {
                        self.values[k] = 0;
                        self.mask[k] = 0;
                    }
                }
                self.k += 1;
            }
        }
    }
}

/// Unpadded full-colour reference vectors: per position the Y, Cb and Cr N×N
/// windows, then (below the coarsest level) the parent's Y, Cb and Cr M×M windows.
pub(super) fn colour_vectors(
    ls: &LevelSample,
    positions: &Positions,
    n: usize,
    m: usize,
) -> Result<Vec<u8>> {
    let chroma = ls
        .chroma
        .as_ref()
        .context("colour search without chroma planes")?;
    let fine = [&ls.lum, &chroma[0], &chroma[1]];
    let parent: Vec<&Gray> = match (&ls.parent, &ls.parent_chroma, m) {
        (_, _, 0) => Vec::new(),
        (Some((p, _)), Some(pc), _) => vec![p, &pc[0], &pc[1]],
        _ => bail!("colour search without parent chroma planes"),
    };
    let (r, pr) = (n / 2, m / 2);
    let dims = 3 * (n * n + if parent.is_empty() { 0 } else { m * m });
    let mut out = Vec::with_capacity(positions.len() * dims);
    for p in positions.iter() {
        let (x, y) = (p[0] as usize, p[1] as usize);
        for plane in fine {
            for yy in y - r..=y + r {
                out.extend_from_slice(&plane.row(yy)[x - r..=x + r]);
            }
        }
        for plane in &parent {
            let (px, py) = (x / 2, y / 2);
            for yy in py - pr..=py + pr {
                out.extend_from_slice(&plane.row(yy)[px - pr..=px + pr]);
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn wrapped_index_is_periodic(w in 1usize..40, h in 1usize..40, x in -200isize..200, y in -200isize..200) {
            let c = Canvas::new(w, h, true);
            let i = c.index(x, y).unwrap();
            prop_assert!(i < w * h);
            prop_assert_eq!(c.index(x + w as isize, y - 3 * h as isize), Some(i));
            let plain = Canvas::new(w, h, false);
            let inside = x >= 0 && y >= 0 && (x as usize) < w && (y as usize) < h;
            prop_assert_eq!(plain.index(x, y).is_some(), inside);
        }

        #[test]
        fn causal_mask_never_reads_the_block_or_later_pixels(n in (1usize..8).prop_map(|k| 2 * k + 1), b in (0usize..4).prop_map(|k| 2 * k + 1)) {
            prop_assume!(b < n);
            let mut c = Canvas::new(50, 50, false);
            c.defined.iter_mut().for_each(|d| *d = true);
            let mut v = vec![0; n * n];
            let mut m = vec![0; n * n];
            query(&c, None, 25, 25, n, 0, Shape::Causal { block: b }, &mut v, &mut m);
            let r = (n / 2) as isize;
            let h = (b / 2) as isize;
            for (k, &bit) in m.iter().enumerate() {
                let (dx, dy) = (k as isize % n as isize - r, k as isize / n as isize - r);
                let in_block_or_after = dy > h || (dy >= -h && dx >= -h);
                prop_assert!(!(bit == 1 && in_block_or_after), "dx={} dy={}", dx, dy);
            }
        }
    }

    #[test]
    fn query_masks_undefined_and_outside_pixels() {
        let mut c = Canvas::new(4, 4, false);
        for i in 0..16 {
            c.lum[i] = i as u8;
            c.defined[i] = i % 2 == 0;
        }
        let mut v = vec![9; 9];
        let mut m = vec![9; 9];
        query(&c, None, 0, 0, 3, 0, Shape::Symmetric, &mut v, &mut m);
        // Window rows y=-1..1, x=-1..1: only (0,0)=0 and (0,1)=4 defined and inside.
        assert_eq!(m, vec![0, 0, 0, 0, 1, 0, 0, 1, 0]);
        assert_eq!(v[4], 0);
        assert_eq!(v[7], 4);
        assert_eq!(c.undefined_in_window(0, 0, 3), 2);
    }
}
