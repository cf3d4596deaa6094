//! Canvas levels and search neighbourhoods (Stahlhut §4–§6, ARCHITECTURE §3.1–§3.4).
//!
//! A search vector is the block's N×N neighbourhood on the canvas (masked to
//! its defined pixels, Stahlhut §5) followed by the M×M window around the
//! parent position in the finished coarser canvas level (§6). With `wrap` the
//! canvas is a torus (§4, tileability).

/// One pyramid level of the output: luminance, which pixels are defined, and
/// for each defined pixel the sample coordinate it came from (the copy map).
#[derive(Debug, Clone)]
pub struct Canvas {
    pub width: usize,
    pub height: usize,
    pub lum: Vec<u8>,
    pub defined: Vec<bool>,
    /// Source coordinate in this level's sample, valid where `defined`.
    pub copy: Vec<[u32; 2]>,
    pub wrap: bool,
    /// Cb and Cr of each defined pixel, for full-colour search (ARCHITECTURE §3.7).
    pub chroma: Option<[Vec<u8>; 2]>,
}

impl Canvas {
    pub fn new(width: usize, height: usize, wrap: bool) -> Self {
        let n = width * height;
        Self {
            width,
            height,
            lum: vec![0; n],
            defined: vec![false; n],
            copy: vec![[0, 0]; n],
            wrap,
            chroma: None,
        }
    }

    /// Adds Cb/Cr planes so queries compare colour too.
    pub fn with_chroma(mut self) -> Self {
        let n = self.width * self.height;
        self.chroma = Some([vec![128; n], vec![128; n]]);
        self
    }

    /// The planes a query reads: luminance, then Cb and Cr when searching in colour.
    fn planes(&self) -> Vec<&[u8]> {
        let mut v: Vec<&[u8]> = vec![&self.lum];
        if let Some([cb, cr]) = &self.chroma {
            v.push(cb);
            v.push(cr);
        }
        v
    }

    /// Index of (x, y), wrapped on a torus or `None` outside a plain canvas.
    #[inline]
    pub fn index(&self, x: isize, y: isize) -> Option<usize> {
        let (w, h) = (self.width as isize, self.height as isize);
        if self.wrap {
            Some((y.rem_euclid(h) * w + x.rem_euclid(w)) as usize)
        } else if x >= 0 && y >= 0 && x < w && y < h {
            Some((y * w + x) as usize)
        } else {
            None
        }
    }

    /// Undefined pixels inside the N×N window around (cx, cy); pixels outside a
    /// plain canvas never become defined and are not counted.
    pub fn undefined_in_window(&self, cx: isize, cy: isize, n: usize) -> u32 {
        let r = (n / 2) as isize;
        let mut count = 0;
        for y in cy - r..=cy + r {
            for x in cx - r..=cx + r {
                if let Some(i) = self.index(x, y) {
                    count += u32::from(!self.defined[i]);
                }
            }
        }
        count
    }
}

/// Which hi-part pixels a query may use.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Shape {
    /// The whole symmetric window, masked to defined pixels (constrained synthesis).
    Symmetric,
    /// The causal L-shape of scan-line full synthesis: rows above the block and
    /// pixels left of it in its rows (ARCHITECTURE §3.6).
    Causal { block: usize },
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
    let mut k = 0;
    for plane in canvas.planes() {
        for dy in -r..=r {
            for dx in -r..=r {
                let allowed = match shape {
                    Shape::Symmetric => true,
                    Shape::Causal { block } => {
                        let h = (block / 2) as isize;
                        dy < -h || (dy <= h && dx < -h)
                    }
                };
                match canvas.index(cx + dx, cy + dy) {
                    Some(i) if allowed && canvas.defined[i] => {
                        values[k] = plane[i];
                        mask[k] = 1;
                    }
                    _ => {
                        values[k] = 0;
                        mask[k] = 0;
                    }
                }
                k += 1;
            }
        }
    }
    if let Some(p) = parent {
        let pr = (m / 2) as isize;
        let (px, py) = (cx.div_euclid(2), cy.div_euclid(2));
        for plane in p.planes() {
            for dy in -pr..=pr {
                for dx in -pr..=pr {
                    match p.index(px + dx, py + dy) {
                        Some(i) if p.defined[i] => {
                            values[k] = plane[i];
                            mask[k] = 1;
                        }
                        _ => {
                            values[k] = 0;
                            mask[k] = 0;
                        }
                    }
                    k += 1;
                }
            }
        }
    }
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
