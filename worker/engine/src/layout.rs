//! Neighbourhood vector layout (Stahlhut §6, ARCHITECTURE §3.2–§3.3).
//!
//! A reference or query vector is the N×N neighbourhood of a pixel (the *hi*
//! part) followed by the M×M window around the parent position in the next
//! coarser level (the *lo* part). Pixels are in scan-line order; each part is
//! zero-padded to [`LANE`] bytes so the SIMD kernels run straight over
//! contiguous memory and never straddle a part boundary inside a lane.

use crate::error::{EngineError, Result};

/// Padding granule of each part, in bytes (the AVX2 register width). The same
/// on every machine, so a layout means the same bytes everywhere.
pub const LANE: usize = 32;

/// Extra readable bytes after the last vector, so a 64-byte SIMD load that
/// starts inside the last vector never leaves the allocation.
pub const SLACK: usize = 64;

/// Largest neighbourhood side accepted (keeps distances far from overflow and
/// messages bounded).
pub const MAX_SIDE: usize = 63;

/// Distance metric between two vectors; both are computed on integers, so any
/// summation order gives the same value (ARCHITECTURE §3.5).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, Default, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum Metric {
    /// Sum of absolute differences.
    #[default]
    L1,
    /// Sum of squared differences.
    L2,
}

/// Integer weights of the two parts: D = hi·dist_hi + lo·dist_lo (Stahlhut §6).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub struct Weights {
    pub hi: u32,
    pub lo: u32,
}

impl Weights {
    /// Largest accepted weight of a part.
    pub const MAX: u32 = 1 << 16;

    pub fn new(hi: u32, lo: u32) -> Result<Self> {
        if hi > Self::MAX || lo > Self::MAX {
            return Err(EngineError::Weights(format!(
                "weights {hi}/{lo} exceed the limit {}; scale them down",
                Self::MAX
            )));
        }
        if hi == 0 && lo == 0 {
            return Err(EngineError::Weights(
                "both weights are 0, so every vector would tie; give the hi part a weight ≥ 1"
                    .into(),
            ));
        }
        Ok(Self { hi, lo })
    }
}

impl Default for Weights {
    fn default() -> Self {
        Self { hi: 1, lo: 1 }
    }
}

/// Neighbourhood geometry: N×N hi window, M×M parent window (0 = none, as on
/// the coarsest level).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub struct Geometry {
    pub n: usize,
    pub m: usize,
}

impl Geometry {
    pub fn new(n: usize, m: usize) -> Result<Self> {
        if n == 0 || n.is_multiple_of(2) || n > MAX_SIDE {
            return Err(EngineError::Geometry(format!(
                "neighbourhood side {n} must be odd and in 1..={MAX_SIDE}"
            )));
        }
        if m != 0 && (m.is_multiple_of(2) || m > MAX_SIDE) {
            return Err(EngineError::Geometry(format!(
                "parent window side {m} must be 0 (none) or odd and in 1..={MAX_SIDE}"
            )));
        }
        Ok(Self { n, m })
    }

    /// The smallest odd parent window that covers the N×N area at half resolution
    /// (N=9 → 5, N=11 → 7).
    pub fn parent_window_for(n: usize) -> usize {
        let half = n.div_ceil(2);
        if half.is_multiple_of(2) {
            half + 1
        } else {
            half
        }
    }

    pub fn radius(&self) -> usize {
        self.n / 2
    }

    pub fn parent_radius(&self) -> usize {
        self.m / 2
    }

    pub fn layout(&self) -> Layout {
        Layout::new(self.n * self.n, self.m * self.m)
    }
}

fn pad(len: usize) -> usize {
    len.div_ceil(LANE) * LANE
}

/// Byte layout of one vector: `[hi .. hi_pad | lo .. lo_pad]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Layout {
    pub hi_len: usize,
    pub lo_len: usize,
    pub hi_pad: usize,
    pub lo_pad: usize,
}

impl Layout {
    /// A layout with `hi_len` and `lo_len` components. Use [`Layout::checked`] for
    /// untrusted sizes.
    pub fn new(hi_len: usize, lo_len: usize) -> Self {
        Self {
            hi_len,
            lo_len,
            hi_pad: pad(hi_len),
            lo_pad: pad(lo_len),
        }
    }

    pub fn checked(hi_len: usize, lo_len: usize) -> Result<Self> {
        if hi_len == 0 {
            return Err(EngineError::Geometry(
                "the hi part must have at least one component".into(),
            ));
        }
        let max = MAX_SIDE * MAX_SIDE;
        if hi_len > max || lo_len > max {
            return Err(EngineError::Geometry(format!(
                "parts of {hi_len} and {lo_len} components exceed the limit {max}"
            )));
        }
        Ok(Self::new(hi_len, lo_len))
    }

    /// Bytes per padded vector.
    pub fn stride(&self) -> usize {
        self.hi_pad + self.lo_pad
    }

    /// Components per unpadded vector (hi then lo).
    pub fn dims(&self) -> usize {
        self.hi_len + self.lo_len
    }

    /// Copies an unpadded vector (`dims()` bytes) into its padded slot.
    pub(crate) fn scatter(&self, src: &[u8], dst: &mut [u8]) {
        dst[..self.hi_len].copy_from_slice(&src[..self.hi_len]);
        dst[self.hi_len..self.hi_pad].fill(0);
        dst[self.hi_pad..self.hi_pad + self.lo_len].copy_from_slice(&src[self.hi_len..]);
        dst[self.hi_pad + self.lo_len..self.stride()].fill(0);
    }

    /// The inverse of the padding: appends the `dims()` unpadded components of
    /// the padded vector `src` (hi part, then lo part) to `out`.
    pub fn unpad_into(&self, src: &[u8], out: &mut Vec<u8>) {
        out.extend_from_slice(&src[..self.hi_len]);
        out.extend_from_slice(&src[self.hi_pad..self.hi_pad + self.lo_len]);
    }
}

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

    /// Summed-area table of *undefined* pixels, (w+1)×(h+1).
    fn undefined_sat(&self) -> Vec<u32> {
        let (w, h) = (self.width, self.height);
        let mut sat = vec![0u32; (w + 1) * (h + 1)];
        for y in 0..h {
            let mut row = 0u32;
            for x in 0..w {
                row += u32::from(!self.is_defined(y * w + x));
                sat[(y + 1) * (w + 1) + x + 1] = sat[y * (w + 1) + x + 1] + row;
            }
        }
        sat
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

fn window_clear(
    sat: &[u32],
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
    let (x0, y0, x1, y1) = (cx - r, cy - r, cx + r + 1, cy + r + 1);
    let s = sat[y1 * (w + 1) + x1] + sat[y0 * (w + 1) + x0]
        - sat[y0 * (w + 1) + x1]
        - sat[y1 * (w + 1) + x0];
    s == 0
}

/// All reference positions of a level in scan-line order (their order is the
/// global index that ties break on, ARCHITECTURE §3.3): every pixel whose N×N window,
/// and M×M parent window around (x/2, y/2), lie inside the sample and are defined.
pub fn reference_positions(sample: &Sample, geometry: &Geometry) -> Result<Vec<[u32; 2]>> {
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
    let mut out = Vec::new();
    for y in 0..f.height {
        for x in 0..f.width {
            if !window_clear(&sat, f.width, x, y, r, f.width, f.height) {
                continue;
            }
            if let Some((p, ps)) = &psat {
                if !window_clear(ps, p.width, x / 2, y / 2, pr, p.width, p.height) {
                    continue;
                }
            }
            out.push([x as u32, y as u32]);
        }
    }
    Ok(out)
}

/// Writes the unpadded vector (hi then lo) of position (x, y) into `dst`
/// (`layout.dims()` bytes); the position must be a valid reference position.
fn gather(sample: &Sample, geometry: &Geometry, x: usize, y: usize, dst: &mut [u8]) {
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

/// A zeroed byte buffer whose start is 64-byte aligned, so that a 64-byte SIMD
/// load of a vector at a multiple-of-64 offset never splits a cache line.
#[derive(Debug, Clone)]
pub(crate) struct AlignedBytes {
    buf: Vec<u8>,
    offset: usize,
    len: usize,
}

impl AlignedBytes {
    pub(crate) fn zeroed(len: usize) -> Self {
        let buf = vec![0u8; len + 64];
        let offset = buf.as_ptr().align_offset(64).min(64);
        Self { buf, offset, len }
    }

    pub(crate) fn as_slice(&self) -> &[u8] {
        &self.buf[self.offset..self.offset + self.len]
    }

    pub(crate) fn as_mut_slice(&mut self) -> &mut [u8] {
        &mut self.buf[self.offset..self.offset + self.len]
    }
}

/// Padded reference vectors of one contiguous range of global indices.
#[derive(Debug, Clone)]
pub struct VectorSpace {
    layout: Layout,
    start: u64,
    len: usize,
    data: AlignedBytes,
    positions: Vec<[u32; 2]>,
}

impl VectorSpace {
    /// Builds the vectors of global indices `range` of the level (ARCHITECTURE §3.3):
    /// a worker builds only the part it owns.
    pub fn build(
        sample: &Sample,
        geometry: &Geometry,
        range: std::ops::Range<u64>,
    ) -> Result<Self> {
        let all = reference_positions(sample, geometry)?;
        Self::build_from_positions(sample, geometry, &all, range)
    }

    /// As [`VectorSpace::build`], with the level's positions already enumerated.
    pub fn build_from_positions(
        sample: &Sample,
        geometry: &Geometry,
        all: &[[u32; 2]],
        range: std::ops::Range<u64>,
    ) -> Result<Self> {
        let total = all.len() as u64;
        if range.start > range.end || range.end > total {
            return Err(EngineError::Range {
                start: range.start,
                end: range.end,
                space_start: 0,
                space_end: total,
            });
        }
        let layout = geometry.layout();
        let positions = all[range.start as usize..range.end as usize].to_vec();
        let stride = layout.stride();
        let mut data = AlignedBytes::zeroed(positions.len() * stride + SLACK);
        let mut tmp = vec![0u8; layout.dims()];
        for (p, slot) in positions
            .iter()
            .zip(data.as_mut_slice().chunks_exact_mut(stride))
        {
            gather(sample, geometry, p[0] as usize, p[1] as usize, &mut tmp);
            layout.scatter(&tmp, slot);
        }
        Ok(Self {
            layout,
            start: range.start,
            len: positions.len(),
            data,
            positions,
        })
    }

    /// A space from raw unpadded vectors (`count × layout.dims()` bytes), global
    /// indices starting at `start`. Used by benchmarks and calibration.
    pub fn from_unpadded(layout: Layout, start: u64, raw: &[u8]) -> Result<Self> {
        let dims = layout.dims();
        if dims == 0 || !raw.len().is_multiple_of(dims) {
            return Err(EngineError::Length {
                what: "raw vectors",
                got: raw.len(),
                expected: raw.len() / dims.max(1) * dims.max(1),
            });
        }
        let len = raw.len() / dims;
        let stride = layout.stride();
        let mut data = AlignedBytes::zeroed(len * stride + SLACK);
        for (src, slot) in raw
            .chunks_exact(dims)
            .zip(data.as_mut_slice().chunks_exact_mut(stride))
        {
            layout.scatter(src, slot);
        }
        Ok(Self {
            layout,
            start,
            len,
            data,
            positions: Vec::new(),
        })
    }

    pub fn layout(&self) -> Layout {
        self.layout
    }

    /// First global index held.
    pub fn start(&self) -> u64 {
        self.start
    }

    /// One past the last global index held.
    pub fn end(&self) -> u64 {
        self.start + self.len as u64
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Errors unless `range` is non-empty and inside the indices held here.
    pub fn check_range(&self, range: &std::ops::Range<u64>) -> Result<()> {
        if range.start >= range.end {
            return Err(EngineError::Empty("index range"));
        }
        if range.start < self.start() || range.end > self.end() {
            return Err(EngineError::Range {
                start: range.start,
                end: range.end,
                space_start: self.start(),
                space_end: self.end(),
            });
        }
        Ok(())
    }

    /// Sample position of a global index held here (None for raw spaces).
    pub fn position(&self, index: u64) -> Option<[u32; 2]> {
        let i = index.checked_sub(self.start)? as usize;
        self.positions.get(i).copied()
    }

    /// Padded bytes of the vector with this global index.
    pub fn vector(&self, index: u64) -> Option<&[u8]> {
        let i = index.checked_sub(self.start)? as usize;
        let s = self.layout.stride();
        (i < self.len).then(|| &self.data.as_slice()[i * s..(i + 1) * s])
    }

    /// Bytes of vector data (without slack).
    pub fn bytes(&self) -> usize {
        self.len * self.layout.stride()
    }

    /// Padded data of the global index range `range` plus the trailing slack
    /// the kernels may read.
    pub(crate) fn slice(&self, range: std::ops::Range<u64>) -> &[u8] {
        let s = self.layout.stride();
        let a = (range.start - self.start) as usize * s;
        let b = (range.end - self.start) as usize * s;
        &self.data.as_slice()[a..b + SLACK]
    }
}

/// A batch of query vectors, each with its own mask of defined components
/// (ARCHITECTURE §3.4: only masked-in components are compared).
#[derive(Debug, Clone)]
pub struct QueryBatch {
    layout: Layout,
    len: usize,
    /// Padded values with masked-out components zeroed.
    values: Vec<u8>,
    /// Padded masks, 0xFF = compare, 0 = ignore (padding is 0).
    masks: Vec<u8>,
}

impl QueryBatch {
    pub fn new(layout: Layout) -> Self {
        Self {
            layout,
            len: 0,
            values: Vec::new(),
            masks: Vec::new(),
        }
    }

    /// Adds a query from unpadded values and mask (`layout.dims()` bytes each,
    /// mask non-zero = defined).
    pub fn push(&mut self, values: &[u8], mask: &[u8]) -> Result<()> {
        let dims = self.layout.dims();
        if values.len() != dims {
            return Err(EngineError::Length {
                what: "query values",
                got: values.len(),
                expected: dims,
            });
        }
        if mask.len() != dims {
            return Err(EngineError::Length {
                what: "query mask",
                got: mask.len(),
                expected: dims,
            });
        }
        let s = self.layout.stride();
        let at = self.values.len();
        self.values.resize(at + s, 0);
        self.masks.resize(at + s, 0);
        let m: Vec<u8> = mask
            .iter()
            .map(|&b| if b != 0 { 0xFF } else { 0 })
            .collect();
        let v: Vec<u8> = values.iter().zip(&m).map(|(&v, &m)| v & m).collect();
        self.layout.scatter(&v, &mut self.values[at..at + s]);
        self.layout.scatter(&m, &mut self.masks[at..at + s]);
        self.len += 1;
        Ok(())
    }

    /// Adds a query with every component defined.
    pub fn push_full(&mut self, values: &[u8]) -> Result<()> {
        let mask = vec![0xFFu8; values.len()];
        self.push(values, &mask)
    }

    pub fn layout(&self) -> Layout {
        self.layout
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Padded (masked) values of query `q`.
    pub fn values(&self, q: usize) -> &[u8] {
        let s = self.layout.stride();
        &self.values[q * s..(q + 1) * s]
    }

    /// Padded mask of query `q`.
    pub fn mask(&self, q: usize) -> &[u8] {
        let s = self.layout.stride();
        &self.masks[q * s..(q + 1) * s]
    }

    /// The unpadded values and masks of every query, concatenated (what
    /// [`QueryBatch::push`] took): the form queries travel in on the wire.
    pub fn unpadded(&self) -> (Vec<u8>, Vec<u8>) {
        self.unpadded_range(0..self.len)
    }

    /// [`QueryBatch::unpadded`] of the queries `qs` only.
    pub fn unpadded_range(&self, qs: std::ops::Range<usize>) -> (Vec<u8>, Vec<u8>) {
        let n = qs.len() * self.layout.dims();
        let (mut values, mut masks) = (Vec::with_capacity(n), Vec::with_capacity(n));
        for q in qs {
            self.layout.unpad_into(self.values(q), &mut values);
            self.layout.unpad_into(self.mask(q), &mut masks);
        }
        (values, masks)
    }

    /// The queries `qs` of this batch, in that order (used by LBG to search
    /// per-query partitions).
    pub(crate) fn select(&self, qs: impl IntoIterator<Item = usize>) -> QueryBatch {
        let s = self.layout.stride();
        let mut out = QueryBatch::new(self.layout);
        for q in qs {
            out.values
                .extend_from_slice(&self.values[q * s..(q + 1) * s]);
            out.masks.extend_from_slice(&self.masks[q * s..(q + 1) * s]);
            out.len += 1;
        }
        out
    }

    /// `count` padded vectors (`count × stride` bytes, padding zero) as queries
    /// with every component defined (LBG scores vectors against seeds this way).
    pub(crate) fn full_from_padded(layout: Layout, padded: &[u8], count: usize) -> QueryBatch {
        let s = layout.stride();
        let mut full = vec![0u8; s];
        layout.scatter(&vec![0xFFu8; layout.dims()], &mut full);
        let mut masks = Vec::with_capacity(count * s);
        let mut values = Vec::with_capacity(count * s);
        for v in padded[..count * s].chunks_exact(s) {
            masks.extend_from_slice(&full);
            values.extend(v.iter().zip(&full).map(|(&x, &m)| x & m));
        }
        QueryBatch {
            layout,
            len: count,
            values,
            masks,
        }
    }

    pub(crate) fn all_values(&self) -> &[u8] {
        &self.values
    }

    pub(crate) fn all_masks(&self) -> &[u8] {
        &self.masks
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parent_window_covers_area() {
        assert_eq!(Geometry::parent_window_for(9), 5);
        assert_eq!(Geometry::parent_window_for(11), 7);
        assert_eq!(Geometry::parent_window_for(5), 3);
        for n in (1..40).step_by(2) {
            let m = Geometry::parent_window_for(n);
            assert!(m % 2 == 1 && 2 * m >= n, "n={n} m={m}");
        }
    }

    #[test]
    fn layout_pads_each_part() {
        let l = Geometry::new(9, 5).unwrap().layout();
        assert_eq!(
            (l.hi_len, l.hi_pad, l.lo_len, l.lo_pad, l.stride()),
            (81, 96, 25, 32, 128)
        );
        let l = Geometry::new(11, 7).unwrap().layout();
        assert_eq!((l.hi_pad, l.lo_pad), (128, 64));
    }

    #[test]
    fn bad_geometry_is_error() {
        assert!(Geometry::new(4, 0).is_err());
        assert!(Geometry::new(0, 0).is_err());
        assert!(Geometry::new(9, 4).is_err());
        assert!(Geometry::new(65, 0).is_err());
        assert!(Weights::new(0, 0).is_err());
    }

    #[test]
    fn positions_respect_windows_and_mask() {
        let (w, h) = (10, 8);
        let px: Vec<u8> = (0..w * h).map(|i| i as u8).collect();
        let mut def = vec![1u8; w * h];
        def[3 * w + 5] = 0;
        let fine = Plane::new(w, h, &px, Some(&def)).unwrap();
        let g = Geometry::new(3, 0).unwrap();
        let pos = reference_positions(&Sample { fine, parent: None }, &g).unwrap();
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
