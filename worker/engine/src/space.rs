//! The padded reference vectors of one global index range (ARCHITECTURE §3.2–§3.3),
//! in 64-byte aligned memory with [`SLACK`] readable bytes after the last
//! vector, as the SIMD kernels scan them (Stahlhut §7).

use crate::error::{EngineError, Result};
use crate::layout::{Geometry, Layout, SLACK};
use crate::plane::{gather, reference_positions, Sample};

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
