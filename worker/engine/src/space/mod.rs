//! The padded reference vectors of one global index range (ARCHITECTURE §3.2–§3.3),
//! in 64-byte aligned memory with [`SLACK`] readable bytes after the last
//! vector, as the SIMD kernels scan them (Stahlhut §7).
//!
//! A space either holds every vector ([`Storage::Dense`], `stride` bytes per
//! sample pixel) or only the sample planes they are cut from
//! ([`Storage::Planes`], about one byte per pixel), gathering each block of
//! vectors into a small buffer just before the kernel scans it. Both give the
//! kernels the same bytes, so the answers are the same.

mod build;
mod gather;
mod storage;

use std::borrow::Cow;
use std::ops::Range;
use std::sync::OnceLock;

use crate::error::{EngineError, Result};
use crate::kdtree::KdTree;
use crate::kernel::{Params, PruneStats};
use crate::layout::{Layout, SLACK};
use crate::merge::{regroup, Hit};
use crate::positions::Positions;
use crate::window::{Dense, KeyIndex, KeyPlane, Sweep};

use gather::{gather_range, write_span, DenseView, PaddedPlane, PlaneSource, PlaneView, PIECE};
pub use storage::{Storage, DENSE_LIMIT};

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

/// Vectors per block a plane-backed space gathers for one kernel pass (a few
/// hundred kilobytes: the block stays in the core's L2 while it is scanned).
const BLOCK: usize = 1024;

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
    /// A dense space's parent rows and parent window side, kept for the key
    /// plane that bounds its border queries (a plane-backed space has them
    /// in its planes).
    dense_parent: Option<(PaddedPlane, usize)>,
    /// The vectors in key order, built on the first windowed search of a
    /// dense space (ARCHITECTURE §3.5).
    keys: OnceLock<Option<KeyIndex>>,
    /// The keys of a plane-backed space, built on its first windowed search.
    key_plane: OnceLock<Option<KeyPlane>>,
    /// The k-d tree of a low-dimensional space, built on its first large
    /// top-k search.
    tree: OnceLock<Option<KdTree>>,
}

/// One query of a windowed search: its padded values and mask.
type Probe<'a> = (&'a [u8], &'a [u8]);

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
                .map_or(0, KeyPlane::bytes)
            + self
                .dense_parent
                .as_ref()
                .map_or(0, |(p, _)| p.pixels.capacity() as u64);
        let tree = self
            .tree
            .get()
            .and_then(Option::as_ref)
            .map_or(0, KdTree::bytes);
        keys + tree
            + match &self.data {
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

    /// The keys of the parent plane, built on first use: a plane-backed
    /// space's windows, and a dense space's for the queries its key order
    /// cannot bound (a lo part cut by the canvas border). `None` for a layout
    /// without a lo part.
    fn key_plane(&self) -> Option<&KeyPlane> {
        let (parent, m) = match (&self.data, &self.dense_parent) {
            (Data::Planes(src), _) => (src.parent.as_ref()?, src.geometry.m),
            (Data::Dense(_), Some((p, m))) => (p, *m),
            (Data::Dense(_), None) => return None,
        };
        once(&self.key_plane, || {
            let pixels = &parent.pixels[..parent.pixels.len() - PIECE];
            KeyPlane::build(pixels, parent.width, parent.row0, m)
        })
        .as_ref()
    }

    /// Whether a dense space's key order bounds a query with this mask (its
    /// whole lo part is known).
    fn index_keyed(&self, params: &Params, mask: &[u8]) -> bool {
        KeyIndex::applies(&self.layout, params, mask) && self.key_index().is_some()
    }

    /// The k-d tree of the space, built on first use; `None` when its
    /// vectors have too many components or it holds too few vectors.
    pub(crate) fn kd_tree(&self) -> Option<&KdTree> {
        if !KdTree::applies(&self.layout) || self.len < crate::kdtree::MIN_VECTORS {
            return None;
        }
        once(&self.tree, || {
            let dims = self.layout.dims();
            let mut raw = Vec::with_capacity(self.len * dims);
            let s = self.layout.stride();
            self.for_each_block(self.start..self.end(), |bytes, count, _| {
                for v in bytes[..count * s].chunks_exact(s) {
                    self.layout.unpad_into(v, &mut raw);
                }
            });
            Some(KdTree::build(&self.layout, self.start, raw, self.len))
        })
        .as_ref()
    }

    /// Whether a query with this mask can be searched by key windows here
    /// (building the keys on first use).
    pub(crate) fn keyed(&self, params: &Params, mask: &[u8]) -> bool {
        match &self.data {
            Data::Dense(_) => {
                self.index_keyed(params, mask)
                    || self
                        .key_plane()
                        .is_some_and(|k| k.applies(&self.layout, params, mask))
            }
            Data::Planes(_) => self
                .key_plane()
                .is_some_and(|k| k.applies(&self.layout, params, mask)),
        }
    }

    /// The windowed search of `queries` over `sw.range` from `start`
    /// (ARCHITECTURE §3.5). Every query must pass [`VectorSpace::keyed`].
    /// A `link` is honoured by the queries a dense space walks in key order;
    /// those swept by the parent plane's keys search alone.
    ///
    /// # Panics
    /// If the space has no keys.
    pub(crate) fn search_keyed(
        &self,
        sw: &Sweep,
        queries: &[(&[u8], &[u8])],
        start: &[Hit],
        link: Option<(&crate::link::Link, &[usize])>,
    ) -> (Vec<Hit>, PruneStats) {
        match &self.data {
            Data::Dense(d) => self.search_dense_keyed(d.as_slice(), sw, queries, start, link),
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

    /// [`VectorSpace::search_keyed`] of a dense space: queries with their
    /// whole lo part walk the key order, those the border cuts sweep the
    /// parent plane's keys, side by side.
    fn search_dense_keyed(
        &self,
        data: &[u8],
        sw: &Sweep,
        queries: &[Probe],
        start: &[Hit],
        link: Option<(&crate::link::Link, &[usize])>,
    ) -> (Vec<Hit>, PruneStats) {
        let dense = Dense {
            data,
            base: self.start,
        };
        let (by_index, by_plane): (Vec<usize>, Vec<usize>) =
            (0..queries.len()).partition(|&q| self.index_keyed(&sw.params, queries[q].1));
        if by_plane.is_empty() {
            let index = self.key_index().expect("a windowed search needs keys");
            return index.search(sw, &dense, queries, start, link);
        }
        let pick = |ids: &[usize]| -> (Vec<Probe>, Vec<Hit>) {
            ids.iter().map(|&q| (queries[q], start[q])).unzip()
        };
        let ((qi, si), (qp, sp)) = (pick(&by_index), pick(&by_plane));
        // The link numbers the batch's queries: the indexed ones keep theirs.
        let at: Option<Vec<usize>> = link.map(|(_, at)| by_index.iter().map(|&q| at[q]).collect());
        let view = DenseView {
            data,
            base: self.start,
            stride: self.layout.stride(),
            positions: &self.positions,
        };
        let keys = self.key_plane().expect("a windowed search needs keys");
        let (indexed, planed) = rayon::join(
            || {
                (!qi.is_empty()).then(|| {
                    let index = self.key_index().expect("a windowed search needs keys");
                    let link = link.zip(at.as_deref()).map(|((l, _), at)| (l, at));
                    index.search(sw, &dense, &qi, &si, link)
                })
            },
            || keys.search(sw, &view, &qp, &sp),
        );
        regroup(
            start.to_vec(),
            [(&by_index, indexed), (&by_plane, Some(planed))],
        )
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::layout::{Geometry, Metric, Weights};
    use crate::plane::{reference_positions, Plane, Sample};

    /// A dense space windows the same queries a plane-backed one does: a
    /// whole lo part by its key order, a lo part the canvas border cuts to a
    /// rectangle by the parent plane's keys; only an irregular lo part is
    /// scanned.
    #[test]
    fn dense_spaces_window_border_queries() {
        let (w, h) = (40usize, 36usize);
        let fine: Vec<u8> = (0..w * h).map(|i| (i * 37 % 251) as u8).collect();
        let parent: Vec<u8> = (0..(w / 2) * (h / 2))
            .map(|i| (i * 53 % 241) as u8)
            .collect();
        let g = Geometry::new(5, 3).unwrap();
        let sample = Sample {
            fine: Plane::new(w, h, &fine, None).unwrap(),
            parent: Some(Plane::new(w / 2, h / 2, &parent, None).unwrap()),
        };
        let all = reference_positions(&sample, &g).unwrap();
        let range = 0..all.len() as u64;
        let params = Params {
            metric: Metric::L1,
            weights: Weights::new(1, 2).unwrap(),
        };
        let l = g.layout();
        let mask = |lo: [u8; 9]| {
            let mut m = vec![0xFFu8; l.stride()];
            m[l.hi_pad..l.hi_pad + 9].copy_from_slice(&lo);
            m
        };
        let on = 0xFF;
        let whole = mask([on; 9]);
        let border = mask([0, on, on, 0, on, on, 0, on, on]);
        let irregular = mask([on, 0, on, on, on, on, on, on, on]);
        for storage in [Storage::Dense, Storage::Planes] {
            let s = VectorSpace::build_with(&sample, &g, &all, range.clone(), storage).unwrap();
            assert!(s.keyed(&params, &whole), "{storage:?} whole");
            assert!(s.keyed(&params, &border), "{storage:?} border");
            assert!(!s.keyed(&params, &irregular), "{storage:?} irregular");
        }
    }
}
