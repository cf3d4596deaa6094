//! Building a [`VectorSpace`]: from a sample's planes (dense or plane-backed)
//! or from raw unpadded vectors.

use std::sync::OnceLock;

use super::gather::{gather_range, PaddedPlane, PlaneSource};
use super::{AlignedBytes, Data, Storage, VectorSpace};
use crate::error::{EngineError, Result};
use crate::layout::{Geometry, Layout, SLACK};
use crate::plane::{reference_positions, Sample};
use crate::positions::Positions;

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
        let (data, dense_parent) = match storage {
            Storage::Planes => (Data::Planes(source), None),
            _ => {
                let mut data = AlignedBytes::zeroed(len * layout.stride() + SLACK);
                gather_range(&source, &layout, all, range.clone(), data.as_mut_slice());
                // The parent rows stay for the key plane of border queries.
                (Data::Dense(data), source.parent.map(|p| (p, geometry.m)))
            }
        };
        Ok(Self {
            layout,
            start: range.start,
            len,
            data,
            positions: all.clone(),
            dense_parent,
            keys: OnceLock::new(),
            key_plane: OnceLock::new(),
            tree: OnceLock::new(),
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
            dense_parent: None,
            keys: OnceLock::new(),
            key_plane: OnceLock::new(),
            tree: OnceLock::new(),
        })
    }
}
