//! Sample planes and the reference positions of a level (Stahlhut §6,
//! ARCHITECTURE §3.3): which pixels have a complete, defined neighbourhood, in
//! the scan-line order that gives every reference vector its global index.

use crate::error::{EngineError, Result};
use crate::layout::Geometry;
use crate::positions::Positions;

/// A borrowed u8 image plane with an optional defined-mask (non-zero = defined).
#[derive(Debug, Clone, Copy)]
pub struct Plane<'a> {
    pub width: usize,
    pub height: usize,
    pub pixels: &'a [u8],
    pub defined: Option<&'a [u8]>,
}

impl<'a> Plane<'a> {
    pub fn new(
        width: usize,
        height: usize,
        pixels: &'a [u8],
        defined: Option<&'a [u8]>,
    ) -> Result<Self> {
        let expected = width
            .checked_mul(height)
            .ok_or_else(|| EngineError::Image(format!("{width}×{height} overflows")))?;
        if width == 0 || height == 0 {
            return Err(EngineError::Image(format!(
                "plane of {width}×{height} pixels is empty"
            )));
        }
        if pixels.len() != expected {
            return Err(EngineError::Length {
                what: "plane pixels",
                got: pixels.len(),
                expected,
            });
        }
        if let Some(d) = defined {
            if d.len() != expected {
                return Err(EngineError::Length {
                    what: "plane defined-mask",
                    got: d.len(),
                    expected,
                });
            }
        }
        Ok(Self {
            width,
            height,
            pixels,
            defined,
        })
    }

    fn is_defined(&self, i: usize) -> bool {
        self.defined.is_none_or(|d| d[i] != 0)
    }

    /// Summed-area table of *undefined* pixels, (w+1)×(h+1); `None` when every
    /// pixel is defined (no mask), which spares 4 bytes per pixel.
    fn undefined_sat(&self) -> Option<Vec<u32>> {
        self.defined?;
        let (w, h) = (self.width, self.height);
        let mut sat = vec![0u32; (w + 1) * (h + 1)];
        for y in 0..h {
            let mut row = 0u32;
            for x in 0..w {
                row += u32::from(!self.is_defined(y * w + x));
                sat[(y + 1) * (w + 1) + x + 1] = sat[y * (w + 1) + x + 1] + row;
            }
        }
        Some(sat)
    }
}

/// An owned copy of a [`Plane`], for holders that outlive the borrowed level
/// data (the cluster's level state, benchmarks).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OwnedPlane {
    pub width: usize,
    pub height: usize,
    pub pixels: Vec<u8>,
    pub defined: Option<Vec<u8>>,
}

impl OwnedPlane {
    pub fn of(p: &Plane) -> Self {
        Self {
            width: p.width,
            height: p.height,
            pixels: p.pixels.to_vec(),
            defined: p.defined.map(<[u8]>::to_vec),
        }
    }

    /// The plane borrowed back (it was valid when copied).
    pub fn view(&self) -> Plane<'_> {
        Plane {
            width: self.width,
            height: self.height,
            pixels: &self.pixels,
            defined: self.defined.as_deref(),
        }
    }

    /// Bytes held (pixels and the defined mask).
    pub fn bytes(&self) -> u64 {
        (self.pixels.len() + self.defined.as_ref().map_or(0, Vec::len)) as u64
    }
}

/// The sample planes a level's reference vectors come from: the level itself and,
/// except on the coarsest level, its parent.
#[derive(Debug, Clone, Copy)]
pub struct Sample<'a> {
    pub fine: Plane<'a>,
    pub parent: Option<Plane<'a>>,
}

impl Sample<'_> {
    /// Bytes a plane-backed space of the whole level holds: copies of the
    /// planes' pixels and the summed-area table of the parent (its keys).
    pub fn plane_bytes(&self) -> u64 {
        let p = |q: &Plane| (q.width * q.height) as u64;
        let table = |q: &Plane| ((q.width + 1) * (q.height + 1) * 4) as u64;
        p(&self.fine) + self.parent.as_ref().map_or(0, |q| p(q) + table(q))
    }
}

fn window_clear(
    sat: Option<&[u32]>,
    w: usize,
    cx: usize,
    cy: usize,
    r: usize,
    pw: usize,
    ph: usize,
) -> bool {
    if cx < r || cy < r || cx + r >= pw || cy + r >= ph {
        return false;
    }
    let Some(sat) = sat else {
        return true;
    };
    let (x0, y0, x1, y1) = (cx - r, cy - r, cx + r + 1, cy + r + 1);
    let s = sat[y1 * (w + 1) + x1] + sat[y0 * (w + 1) + x0]
        - sat[y0 * (w + 1) + x1]
        - sat[y1 * (w + 1) + x0];
    s == 0
}

/// All reference positions of a level in scan-line order (their order is the
/// global index that ties break on, ARCHITECTURE §3.3): every pixel whose N×N window,
/// and M×M parent window around (x/2, y/2), lie inside the sample and are defined.
pub fn reference_positions(sample: &Sample, geometry: &Geometry) -> Result<Positions> {
    if geometry.m > 0 && sample.parent.is_none() {
        return Err(EngineError::Geometry(format!(
            "geometry has a {0}×{0} parent window but no parent plane was given",
            geometry.m
        )));
    }
    if geometry.m == 0 && sample.parent.is_some() {
        return Err(EngineError::Geometry(
            "a parent plane was given but the geometry has no parent window (m = 0)".into(),
        ));
    }
    let f = &sample.fine;
    let sat = f.undefined_sat();
    let psat = sample.parent.as_ref().map(|p| (p, p.undefined_sat()));
    let r = geometry.radius();
    let pr = geometry.parent_radius();
    let mut out = Positions::new();
    for y in 0..f.height {
        for x in 0..f.width {
            if !window_clear(sat.as_deref(), f.width, x, y, r, f.width, f.height) {
                continue;
            }
            if let Some((p, ps)) = &psat {
                if !window_clear(ps.as_deref(), p.width, x / 2, y / 2, pr, p.width, p.height) {
                    continue;
                }
            }
            out.push(x as u32, y as u32);
        }
    }
    Ok(out)
}

/// Writes the unpadded vector (hi then lo) of position (x, y) into `dst`
/// (`layout.dims()` bytes); the position must be a valid reference position.
pub(crate) fn gather(sample: &Sample, geometry: &Geometry, x: usize, y: usize, dst: &mut [u8]) {
    let f = &sample.fine;
    let r = geometry.radius();
    let mut k = 0;
    for yy in y - r..=y + r {
        let row = &f.pixels[yy * f.width + x - r..=yy * f.width + x + r];
        dst[k..k + geometry.n].copy_from_slice(row);
        k += geometry.n;
    }
    if let Some(p) = &sample.parent {
        let pr = geometry.parent_radius();
        let (px, py) = (x / 2, y / 2);
        for yy in py - pr..=py + pr {
            let row = &p.pixels[yy * p.width + px - pr..=yy * p.width + px + pr];
            dst[k..k + geometry.m].copy_from_slice(row);
            k += geometry.m;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::layout::Geometry;

    #[test]
    fn positions_respect_windows_and_mask() {
        let (w, h) = (10, 8);
        let px: Vec<u8> = (0..w * h).map(|i| i as u8).collect();
        let mut def = vec![1u8; w * h];
        def[3 * w + 5] = 0;
        let fine = Plane::new(w, h, &px, Some(&def)).unwrap();
        let g = Geometry::new(3, 0).unwrap();
        let pos: Vec<[u32; 2]> = reference_positions(&Sample { fine, parent: None }, &g)
            .unwrap()
            .iter()
            .collect();
        for p in &pos {
            let (x, y) = (p[0] as i64, p[1] as i64);
            assert!(x >= 1 && y >= 1 && x <= 8 && y <= 6);
            assert!((x - 5).abs() > 1 || (y - 3).abs() > 1);
        }
        assert_eq!(pos.len(), 8 * 6 - 9);
        let mut sorted = pos.clone();
        sorted.sort_by_key(|p| (p[1], p[0]));
        assert_eq!(sorted, pos);
    }
}
