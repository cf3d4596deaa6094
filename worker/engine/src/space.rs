//! The padded reference vectors of one global index range (ARCHITECTURE §3.2–§3.3),
//! in 64-byte aligned memory with [`SLACK`] readable bytes after the last
//! vector, as the SIMD kernels scan them (Stahlhut §7).
//!
//! A space either holds every vector ([`Storage::Dense`], `stride` bytes per
//! sample pixel) or only the sample planes they are cut from
//! ([`Storage::Planes`], about one byte per pixel), gathering each block of
//! vectors into a small buffer just before the kernel scans it. Both give the
//! kernels the same bytes, so the answers are the same.

use std::borrow::Cow;
use std::ops::Range;
use std::sync::OnceLock;

use crate::error::{EngineError, Result};
use crate::kernel::{Params, PruneStats};
use crate::layout::{Geometry, Layout, SLACK};
use crate::merge::Hit;
use crate::plane::{reference_positions, Plane, Sample};
use crate::positions::Positions;
use crate::window::{Dense, KeyIndex, KeyPlane, PlaneVectors, Sweep};

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

/// How a [`VectorSpace`] holds its vectors.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, Default, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum Storage {
    /// [`Storage::Dense`] when the vectors take at most [`DENSE_LIMIT`] bytes
    /// and half the memory the machine can still give, [`Storage::Planes`]
    /// otherwise.
    #[default]
    Auto,
    /// Every padded vector built once: fastest, `stride` bytes per vector.
    Dense,
    /// Only the sample planes: vectors are gathered block by block as they
    /// are scanned, so memory is about the size of the sample.
    Planes,
}

/// Largest vector data [`Storage::Auto`] builds densely.
pub const DENSE_LIMIT: u64 = 1 << 30;

/// Vectors per block a plane-backed space gathers for one kernel pass (a few
/// hundred kilobytes: the block stays in the core's L2 while it is scanned).
const BLOCK: usize = 1024;

impl Storage {
    /// Parses `auto`, `dense` or `planes`.
    pub fn from_name(name: &str) -> Result<Self> {
        match name.to_ascii_lowercase().as_str() {
            "auto" => Ok(Self::Auto),
            "dense" => Ok(Self::Dense),
            "planes" => Ok(Self::Planes),
            _ => Err(EngineError::Parameter(format!(
                "unknown vector storage '{name}'; use auto, dense or planes"
            ))),
        }
    }

    pub fn name(&self) -> &'static str {
        match self {
            Self::Auto => "auto",
            Self::Dense => "dense",
            Self::Planes => "planes",
        }
    }

    /// The storage to use and the bytes it needs, for a range whose vectors
    /// take `dense` bytes built and whose planes take `planes` bytes, when
    /// `room` bytes are left (`None`: unknown). The one rule the master's
    /// local search and the worker both apply before building a range.
    pub fn plan(self, dense: u64, planes: u64, room: Option<u64>) -> (Self, u64) {
        match self.resolve(dense, room) {
            Self::Dense => (Self::Dense, dense),
            _ => (Self::Planes, planes),
        }
    }

    /// The storage for `vector_bytes` of dense vectors when `room` bytes are
    /// left on this machine (`None`: unknown).
    pub fn resolve(self, vector_bytes: u64, room: Option<u64>) -> Self {
        match self {
            Self::Auto => {
                let fits =
                    vector_bytes <= DENSE_LIMIT && room.is_none_or(|r| vector_bytes <= r / 2);
                if fits {
                    Self::Dense
                } else {
                    Self::Planes
                }
            }
            other => other,
        }
    }
}

/// The rows `row0..row0 + rows` of a sample plane, copied with [`PIECE`]
/// readable bytes after the last pixel, so a row of any window is read in
/// whole 16-byte pieces. A space keeps only the rows its range's windows
/// reach, so a worker holding part of a level holds part of its planes.
#[derive(Debug, Clone)]
struct PaddedPlane {
    width: usize,
    row0: usize,
    pixels: Vec<u8>,
}

/// Bytes a plane-backed gather reads or writes at once; a window row is
/// copied in whole pieces, so up to `PIECE − 1` bytes past its end too.
const PIECE: usize = 16;

impl PaddedPlane {
    /// Rows `rows` of `p` (clipped to the plane).
    fn of(p: &Plane, rows: Range<usize>) -> Self {
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
struct PlaneSource {
    geometry: Geometry,
    fine: PaddedPlane,
    parent: Option<PaddedPlane>,
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
fn write_span(layout: &Layout, g: &Geometry) -> usize {
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
    fn gather_run(
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

    fn bytes(&self) -> u64 {
        (self.fine.pixels.capacity() + self.parent.as_ref().map_or(0, |p| p.pixels.capacity()))
            as u64
    }
}

#[derive(Debug, Clone)]
enum Data {
    Dense(AlignedBytes),
    Planes(PlaneSource),
}

/// Padded reference vectors of one contiguous range of global indices.
#[derive(Debug, Clone)]
pub struct VectorSpace {
    layout: Layout,
    start: u64,
    len: usize,
    data: Data,
    /// The level's positions (all of them; the space holds `start..start + len`).
    positions: Positions,
    /// The vectors in key order, built on the first windowed search of a
    /// dense space (ARCHITECTURE §3.5).
    keys: OnceLock<Option<KeyIndex>>,
    /// The keys of a plane-backed space, built on its first windowed search.
    key_plane: OnceLock<Option<KeyPlane>>,
}

/// The value of `cell`, built by `build` if it is empty. Unlike
/// `OnceLock::get_or_init`, nobody waits for somebody else's build: the keys
/// are built with rayon, and a rayon thread that waited for a build inside
/// another search could be the thread the build itself needs (a deadlock
/// under concurrent searches). Threads that find the cell empty at the same
/// time each build; the first value stored wins, and all are equal.
fn once<T>(cell: &OnceLock<T>, build: impl FnOnce() -> T) -> &T {
    if let Some(v) = cell.get() {
        return v;
    }
    let _ = cell.set(build());
    cell.get().expect("set above or by another thread")
}

impl VectorSpace {
    /// Builds the dense vectors of global indices `range` of the level
    /// (ARCHITECTURE §3.3): a worker builds only the part it owns.
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
        all: &Positions,
        range: std::ops::Range<u64>,
    ) -> Result<Self> {
        Self::build_with(sample, geometry, all, range, Storage::Dense)
    }

    /// The vectors of global indices `range` held as `storage` says
    /// ([`Storage::Auto`] asks the machine how much memory is left).
    pub fn build_with(
        sample: &Sample,
        geometry: &Geometry,
        all: &Positions,
        range: std::ops::Range<u64>,
        storage: Storage,
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
        if geometry.m > 0 && sample.parent.is_none() {
            return Err(EngineError::Geometry(
                "the geometry has a parent window but no parent plane was given".into(),
            ));
        }
        let layout = geometry.layout();
        let len = (range.end - range.start) as usize;
        // The rows the range's windows reach: from the first position's row
        // to the last one's, widened by the window radii.
        let (y0, y1) = match (
            all.get(range.start),
            range.end.checked_sub(1).and_then(|i| all.get(i)),
        ) {
            (Some([_, a]), Some([_, b])) if len > 0 => (a as usize, b as usize + 1),
            _ => (0, 0),
        };
        let (r, pr) = (geometry.radius(), geometry.parent_radius());
        let source = PlaneSource {
            geometry: *geometry,
            fine: PaddedPlane::of(&sample.fine, y0.saturating_sub(r)..y1 + r),
            parent: sample
                .parent
                .as_ref()
                .filter(|_| geometry.m > 0)
                .map(|p| PaddedPlane::of(p, (y0 / 2).saturating_sub(pr)..y1.div_ceil(2) + pr)),
        };
        let dense_bytes = len as u64 * layout.dense_bytes_per_vector() as u64;
        let storage = match storage {
            Storage::Auto => storage.resolve(dense_bytes, crate::budget::available_bytes()),
            s => s,
        };
        let data = match storage {
            Storage::Planes => Data::Planes(source),
            _ => {
                let mut data = AlignedBytes::zeroed(len * layout.stride() + SLACK);
                gather_range(&source, &layout, all, range.clone(), data.as_mut_slice());
                Data::Dense(data)
            }
        };
        Ok(Self {
            layout,
            start: range.start,
            len,
            data,
            positions: all.clone(),
            keys: OnceLock::new(),
            key_plane: OnceLock::new(),
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
            data: Data::Dense(data),
            positions: Positions::new(),
            keys: OnceLock::new(),
            key_plane: OnceLock::new(),
        })
    }

    pub fn layout(&self) -> Layout {
        self.layout
    }

    /// How the vectors are held: [`Storage::Dense`] or [`Storage::Planes`].
    pub fn storage(&self) -> Storage {
        match self.data {
            Data::Dense(_) => Storage::Dense,
            Data::Planes(_) => Storage::Planes,
        }
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
        (self.start..self.end())
            .contains(&index)
            .then(|| self.positions.get(index))
            .flatten()
    }

    /// Padded bytes of the vector with this global index (gathered from the
    /// planes for a plane-backed space).
    pub fn vector(&self, index: u64) -> Option<Cow<'_, [u8]>> {
        let i = index.checked_sub(self.start)? as usize;
        if i >= self.len {
            return None;
        }
        let s = self.layout.stride();
        match &self.data {
            Data::Dense(d) => Some(Cow::Borrowed(&d.as_slice()[i * s..(i + 1) * s])),
            Data::Planes(src) => {
                let [x, y] = self.positions.get(index)?;
                let mut v = vec![0u8; write_span(&self.layout, &src.geometry)];
                src.gather_run(&self.layout, x as usize, y as usize, 1, &mut v, 0);
                v.truncate(s);
                Some(Cow::Owned(v))
            }
        }
    }

    /// Bytes of vector data (without slack) if every vector were built.
    pub fn bytes(&self) -> usize {
        self.len * self.layout.stride()
    }

    /// Bytes this space holds: the vectors, or the planes and positions, and
    /// the keys once a search has built them.
    pub fn held_bytes(&self) -> u64 {
        let keys = self
            .keys
            .get()
            .and_then(Option::as_ref)
            .map_or(0, KeyIndex::bytes)
            + self
                .key_plane
                .get()
                .and_then(Option::as_ref)
                .map_or(0, KeyPlane::bytes);
        keys + match &self.data {
            Data::Dense(_) => (self.bytes() + SLACK) as u64 + self.positions.bytes(),
            Data::Planes(src) => src.bytes() + self.positions.bytes(),
        }
    }

    /// The vectors in key order for windowed search, built on first use;
    /// `None` for a plane-backed space or a layout without a lo part.
    fn key_index(&self) -> Option<&KeyIndex> {
        let Data::Dense(d) = &self.data else {
            return None;
        };
        once(&self.keys, || {
            KeyIndex::build(&self.layout, d.as_slice(), self.len)
        })
        .as_ref()
    }

    /// The keys of a plane-backed space, built on first use; `None` for a
    /// dense space, a layout without a lo part or a parent window too large
    /// for two-byte keys.
    fn key_plane(&self) -> Option<&KeyPlane> {
        let Data::Planes(src) = &self.data else {
            return None;
        };
        once(&self.key_plane, || {
            let p = src.parent.as_ref()?;
            let pixels = &p.pixels[..p.pixels.len() - PIECE];
            KeyPlane::build(pixels, p.width, p.row0, src.geometry.m)
        })
        .as_ref()
    }

    /// Whether a query with this mask can be searched by key windows here
    /// (building the keys on first use).
    pub(crate) fn keyed(&self, params: &Params, mask: &[u8]) -> bool {
        match &self.data {
            Data::Dense(_) => {
                KeyIndex::applies(&self.layout, params, mask) && self.key_index().is_some()
            }
            Data::Planes(_) => self
                .key_plane()
                .is_some_and(|k| k.applies(&self.layout, params, mask)),
        }
    }

    /// The windowed search of `queries` over `sw.range` from `start`
    /// (ARCHITECTURE §3.5). Every query must pass [`VectorSpace::keyed`].
    ///
    /// # Panics
    /// If the space has no keys.
    pub(crate) fn search_keyed(
        &self,
        sw: &Sweep,
        queries: &[(&[u8], &[u8])],
        start: &[Hit],
    ) -> (Vec<Hit>, PruneStats) {
        match &self.data {
            Data::Dense(d) => {
                let dense = Dense {
                    data: d.as_slice(),
                    base: self.start,
                };
                let index = self.key_index().expect("a windowed search needs keys");
                index.search(sw, &dense, queries, start)
            }
            Data::Planes(src) => {
                let view = PlaneView {
                    src,
                    layout: &self.layout,
                    positions: &self.positions,
                };
                let keys = self.key_plane().expect("a windowed search needs keys");
                keys.search(sw, &view, queries, start)
            }
        }
    }

    /// Padded data of the global index range `range` plus the trailing slack
    /// the kernels may read, when the vectors are held densely.
    pub(crate) fn dense_slice(&self, range: Range<u64>) -> Option<&[u8]> {
        let Data::Dense(d) = &self.data else {
            return None;
        };
        let s = self.layout.stride();
        let a = (range.start - self.start) as usize * s;
        let b = (range.end - self.start) as usize * s;
        Some(&d.as_slice()[a..b + SLACK])
    }

    /// Hands `f` the padded vectors of `range` in index order, with [`SLACK`]
    /// bytes after them: `(bytes, count, first global index)`. A dense space
    /// makes one call; a plane-backed one gathers blocks of [`BLOCK`] vectors
    /// into one buffer and makes a call per block.
    pub(crate) fn for_each_block(&self, range: Range<u64>, mut f: impl FnMut(&[u8], usize, u64)) {
        match &self.data {
            Data::Dense(_) => {
                let n = (range.end - range.start) as usize;
                if let Some(d) = self.dense_slice(range.clone()) {
                    f(d, n, range.start);
                }
            }
            Data::Planes(src) => {
                let s = self.layout.stride();
                let mut buf = AlignedBytes::zeroed(BLOCK * s + SLACK);
                let mut a = range.start;
                while a < range.end {
                    let b = (a + BLOCK as u64).min(range.end);
                    gather_range(src, &self.layout, &self.positions, a..b, buf.as_mut_slice());
                    f(buf.as_slice(), (b - a) as usize, a);
                    a = b;
                }
            }
        }
    }
}

/// A plane-backed space as a windowed sweep reads it.
struct PlaneView<'a> {
    src: &'a PlaneSource,
    layout: &'a Layout,
    positions: &'a Positions,
}

impl PlaneVectors for PlaneView<'_> {
    fn runs(&self, range: Range<u64>) -> Vec<(u64, u32, u32, u32)> {
        self.positions.runs(range).collect()
    }

    fn span(&self) -> usize {
        write_span(self.layout, &self.src.geometry)
    }

    fn gather(&self, x: usize, y: usize, dst: &mut [u8]) {
        self.src.gather_run(self.layout, x, y, 1, dst, 0);
    }
}

/// Gathers the padded vectors of global indices `range` into `dst`, one after
/// another from its start (`dst` holds them and [`SLACK`] more bytes).
fn gather_range(
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
