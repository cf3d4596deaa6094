//! The sample planes a plane-backed space keeps, and the gathering of its
//! padded vectors from them, run by run, into a buffer the kernels scan.

use std::ops::Range;

use crate::layout::{Geometry, Layout};
use crate::plane::Plane;
use crate::positions::Positions;
use crate::window::PlaneVectors;

/// The rows `row0..row0 + rows` of a sample plane, copied with [`PIECE`]
/// readable bytes after the last pixel, so a row of any window is read in
/// whole 16-byte pieces. A space keeps only the rows its range's windows
/// reach, so a worker holding part of a level holds part of its planes.
#[derive(Debug, Clone)]
pub(super) struct PaddedPlane {
    pub(super) width: usize,
    pub(super) row0: usize,
    pub(super) pixels: Vec<u8>,
}

/// Bytes a plane-backed gather reads or writes at once; a window row is
/// copied in whole pieces, so up to `PIECE − 1` bytes past its end too.
pub(super) const PIECE: usize = 16;

impl PaddedPlane {
    /// Rows `rows` of `p` (clipped to the plane).
    pub(super) fn of(p: &Plane, rows: Range<usize>) -> Self {
        let rows = rows.start.min(p.height)..rows.end.min(p.height);
        let px = &p.pixels[rows.start * p.width..rows.end.max(rows.start) * p.width];
        let mut pixels = Vec::with_capacity(px.len() + PIECE);
        pixels.extend_from_slice(px);
        pixels.resize(px.len() + PIECE, 0);
        Self {
            width: p.width,
            row0: rows.start,
            pixels,
        }
    }

    /// Whether the `side`×`side` windows centred at (x..x + len, y) lie inside
    /// the rows held.
    fn holds(&self, x: usize, y: usize, len: usize, side: usize) -> bool {
        let r = side / 2;
        let rows = self.pixels.len().saturating_sub(PIECE) / self.width;
        x >= r && y >= self.row0 + r && x + len - 1 + r < self.width && y + r < self.row0 + rows
    }

    /// The pixel (x, y), which must be held.
    fn at(&self, x: usize, y: usize) -> *const u8 {
        self.pixels[(y - self.row0) * self.width + x..].as_ptr()
    }
}

/// The planes a plane-backed space gathers its vectors from.
#[derive(Debug, Clone)]
pub(super) struct PlaneSource {
    pub(super) geometry: Geometry,
    pub(super) fine: PaddedPlane,
    pub(super) parent: Option<PaddedPlane>,
}

/// Copies the `side`×`side` window whose top-left pixel is `src` row by row
/// to `dst`, in [`PIECE`]-byte pieces.
///
/// # Safety
/// `src + yy·width + c` must be readable for `PIECE` bytes and `dst + k + c`
/// writable for `PIECE` bytes, for every row `yy < side`, every piece start
/// `c < side` and `k = yy·side`.
#[inline(always)]
unsafe fn copy_window(src: *const u8, width: usize, side: usize, dst: *mut u8) {
    for yy in 0..side {
        let mut c = 0;
        while c < side {
            // SAFETY: the caller guarantees both ranges (see above).
            unsafe {
                std::ptr::copy_nonoverlapping(
                    src.add(yy * width + c),
                    dst.add(yy * side + c),
                    PIECE,
                )
            };
            c += PIECE;
        }
    }
}

/// Zeroes `dst..dst + len` in [`PIECE`]-byte pieces.
///
/// # Safety
/// `dst` must be writable for `len` rounded up to a multiple of `PIECE` bytes.
#[inline(always)]
unsafe fn zero(dst: *mut u8, len: usize) {
    let mut z = 0;
    while z < len {
        // SAFETY: the caller guarantees the rounded-up range.
        unsafe { std::ptr::write_bytes(dst.add(z), 0, PIECE) };
        z += PIECE;
    }
}

/// Bytes from a vector's start that gathering it may write: its stride and
/// what its last pieces run over.
pub(super) fn write_span(layout: &Layout, g: &Geometry) -> usize {
    let round = |len: usize| len.div_ceil(PIECE) * PIECE;
    let rows = |side: usize| side.saturating_sub(1) * side + round(side);
    let mut span = layout.stride().max(rows(g.n));
    span = span.max(layout.hi_len + round(layout.hi_pad - layout.hi_len));
    if g.m > 0 {
        span = span.max(layout.hi_pad + rows(g.m));
    }
    span.max(layout.hi_pad + layout.lo_len + round(layout.lo_pad - layout.lo_len))
}

impl PlaneSource {
    /// Writes the padded vectors of the run (x..x + len, y) one after another
    /// from `dst[at..]`; up to `PIECE` bytes after the last one are
    /// overwritten too.
    ///
    /// # Panics
    /// If a window of the run leaves its plane or `dst` is too short.
    pub(super) fn gather_run(
        &self,
        layout: &Layout,
        x: usize,
        y: usize,
        len: usize,
        dst: &mut [u8],
        at: usize,
    ) {
        if len == 0 {
            return;
        }
        let g = &self.geometry;
        let s = layout.stride();
        assert!(
            self.fine.holds(x, y, len, g.n)
                && self.parent.as_ref().is_none_or(|p| p.holds(
                    x / 2,
                    y / 2,
                    (x + len - 1) / 2 - x / 2 + 1,
                    g.m
                )),
            "run of {len} windows at ({x}, {y}) leaves the sample"
        );
        assert!(
            at + (len - 1) * s + write_span(layout, g) <= dst.len(),
            "gather buffer of {} bytes is too short for {len} vectors from byte {at}",
            dst.len()
        );
        let (fr, pr) = (g.radius(), g.parent_radius());
        let out = dst.as_mut_ptr();
        for i in 0..len {
            let (xx, d) = (x + i, at + i * s);
            // SAFETY: the window of (xx, y) is inside the plane (asserted for
            // the whole run) and the plane has PIECE bytes of slack, so every
            // piece read of a row starts before the row's end and stays
            // inside `pixels`. Every write lies in d..d + write_span, inside
            // `dst` (asserted above).
            unsafe {
                let f = &self.fine;
                copy_window(f.at(xx - fr, y - fr), f.width, g.n, out.add(d));
                zero(out.add(d + layout.hi_len), layout.hi_pad - layout.hi_len);
                if let Some(p) = &self.parent {
                    copy_window(
                        p.at(xx / 2 - pr, y / 2 - pr),
                        p.width,
                        g.m,
                        out.add(d + layout.hi_pad),
                    );
                }
                zero(
                    out.add(d + layout.hi_pad + layout.lo_len),
                    layout.lo_pad - layout.lo_len,
                );
            }
        }
    }

    pub(super) fn bytes(&self) -> u64 {
        (self.fine.pixels.capacity() + self.parent.as_ref().map_or(0, |p| p.pixels.capacity()))
            as u64
    }
}

/// A plane-backed space as a windowed sweep reads it.
pub(super) struct PlaneView<'a> {
    pub(super) src: &'a PlaneSource,
    pub(super) layout: &'a Layout,
    pub(super) positions: &'a Positions,
}

impl PlaneVectors for PlaneView<'_> {
    fn runs(&self, range: Range<u64>) -> Vec<(u64, u32, u32, u32)> {
        self.positions.runs(range).collect()
    }

    fn span(&self) -> usize {
        write_span(self.layout, &self.src.geometry)
    }

    fn fetch<'b>(&'b self, _index: u64, x: usize, y: usize, buf: &'b mut [u8]) -> &'b [u8] {
        self.src.gather_run(self.layout, x, y, 1, buf, 0);
        buf
    }
}

/// A dense space as a key-plane sweep reads it: positions to walk, vectors
/// read in place.
pub(super) struct DenseView<'a> {
    pub(super) data: &'a [u8],
    /// Global index of the first vector.
    pub(super) base: u64,
    pub(super) stride: usize,
    pub(super) positions: &'a Positions,
}

impl PlaneVectors for DenseView<'_> {
    fn runs(&self, range: Range<u64>) -> Vec<(u64, u32, u32, u32)> {
        self.positions.runs(range).collect()
    }

    fn span(&self) -> usize {
        0
    }

    fn fetch<'b>(&'b self, index: u64, _x: usize, _y: usize, _buf: &'b mut [u8]) -> &'b [u8] {
        let i = (index - self.base) as usize;
        &self.data[i * self.stride..(i + 1) * self.stride]
    }
}

/// Gathers the padded vectors of global indices `range` into `dst`, one after
/// another from its start (`dst` holds them and [`SLACK`](crate::layout::SLACK) more bytes).
pub(super) fn gather_range(
    src: &PlaneSource,
    layout: &Layout,
    positions: &Positions,
    range: Range<u64>,
    dst: &mut [u8],
) {
    let s = layout.stride();
    let mut at = 0;
    for (_, x, y, len) in positions.runs(range) {
        src.gather_run(layout, x as usize, y as usize, len as usize, dst, at);
        at += len as usize * s;
    }
}
