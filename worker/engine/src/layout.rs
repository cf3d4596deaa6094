//! Neighbourhood vector layout (Stahlhut §6, ARCHITECTURE §3.2–§3.3).
//!
//! A reference or query vector is the N×N neighbourhood of a pixel (the *hi*
//! part) followed by the M×M window around the parent position in the next
//! coarser level (the *lo* part). Pixels are in scan-line order; each part is
//! zero-padded to [`LANE`] bytes so the SIMD kernels run straight over
//! contiguous memory and never straddle a part boundary inside a lane.
//!
//! The planes the vectors are cut from are in [`crate::plane`], the padded
//! reference vectors in [`crate::space`] and the queries in [`crate::batch`].

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

    /// Bytes a dense space holds per vector for exact search: the padded
    /// vector and, when there is a lo part, its entry in the key index (key,
    /// index and a head of up to two lanes; ARCHITECTURE §3.5).
    pub fn dense_bytes_per_vector(&self) -> usize {
        let index = if self.lo_len > 0 {
            8 + self.lo_pad.min(2 * LANE)
        } else {
            0
        };
        self.stride() + index
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

/// Kept here for callers that name it by this path.
pub use crate::plane::reference_positions;

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
}
