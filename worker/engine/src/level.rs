//! One pyramid level's reference data, owned: the sample planes, the
//! neighbourhood geometry, the comparison parameters and the reference
//! positions in global-index order (ARCHITECTURE §5). The
//! worker holds one per loaded level, the cluster keeps one to rebuild vectors
//! after a repartition, and the wire converts it to and from `LoadLevel`.

use crate::error::Result;
use crate::kernel::Params;
use crate::layout::Geometry;
use crate::plane::{reference_positions, OwnedPlane, Sample};

/// A level's sample planes, geometry, parameters and reference positions.
#[derive(Debug, Clone)]
pub struct OwnedLevel {
    /// Pyramid level (0 = finest).
    pub level: usize,
    pub geometry: Geometry,
    pub params: Params,
    pub fine: OwnedPlane,
    /// The parent plane; `None` exactly when `geometry.m == 0`.
    pub parent: Option<OwnedPlane>,
    /// All reference positions of the level in global-index order.
    pub positions: Vec<[u32; 2]>,
}

impl OwnedLevel {
    /// A level with its reference positions computed from the planes.
    pub fn locate(
        level: usize,
        geometry: Geometry,
        params: Params,
        fine: OwnedPlane,
        parent: Option<OwnedPlane>,
    ) -> Result<Self> {
        let mut out = Self {
            level,
            geometry,
            params,
            fine,
            parent,
            positions: Vec::new(),
        };
        out.positions = reference_positions(&out.sample(), &out.geometry)?;
        out.positions.shrink_to_fit();
        Ok(out)
    }

    /// The planes borrowed as a [`Sample`].
    pub fn sample(&self) -> Sample<'_> {
        Sample {
            fine: self.fine.view(),
            parent: self.parent.as_ref().map(OwnedPlane::view),
        }
    }

    /// Number of reference vectors (global indices `0..total`).
    pub fn total(&self) -> u64 {
        self.positions.len() as u64
    }

    /// Bytes held: planes and positions.
    pub fn bytes(&self) -> u64 {
        self.fine.bytes()
            + self.parent.as_ref().map_or(0, OwnedPlane::bytes)
            + (self.positions.capacity() * std::mem::size_of::<[u32; 2]>()) as u64
    }
}
