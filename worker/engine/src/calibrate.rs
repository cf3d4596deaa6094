//! Calibration: the throughput of this machine's search, in reference × query
//! pairs per second, measured on a seeded dummy search
//! (ARCHITECTURE §4.2). The master sizes each worker's index
//! range by it; a worker runs it for the `Calibrate` call and the master runs
//! the very same measurement for its own share.

use std::time::Instant;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::batch::QueryBatch;
use crate::error::{EngineError, Result};
use crate::kernel::Params;
use crate::layout::Layout;
use crate::search::Engine;
use crate::space::VectorSpace;

/// Most vectors a calibration may ask for.
pub const MAX_VECTORS: u32 = 1 << 20;
/// Most queries a calibration may ask for.
pub const MAX_QUERIES: u32 = 256;
/// Most bytes the calibration's vector space may take.
pub const MAX_BYTES: u64 = 256 << 20;

/// Size of the calibration's dummy search. On the wire a 0 field means "the
/// default" ([`CalibrationSize::or_default`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CalibrationSize {
    pub seed: u64,
    pub vectors: u32,
    pub dims: u32,
    pub queries: u32,
}

impl Default for CalibrationSize {
    fn default() -> Self {
        Self {
            seed: 0x7e75,
            vectors: 65_536,
            dims: 106,
            queries: 32,
        }
    }
}

/// A measured calibration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Calibration {
    /// Reference × query pairs per second.
    pub pairs_per_second: f64,
    /// Seconds of the faster of the two timed searches.
    pub seconds: f64,
}

impl CalibrationSize {
    /// Each zero field replaced by the default's.
    pub fn or_default(self) -> Self {
        let d = Self::default();
        let or = |v: u32, d: u32| if v == 0 { d } else { v };
        Self {
            seed: self.seed,
            vectors: or(self.vectors, d.vectors),
            dims: or(self.dims, d.dims),
            queries: or(self.queries, d.queries),
        }
    }

    /// Bytes of the dummy vector space (unpadded copy plus padded vectors).
    pub fn bytes(&self) -> Result<u64> {
        let layout = Layout::checked(self.dims as usize, 0)?;
        Ok(u64::from(self.vectors) * (layout.dims() + layout.stride()) as u64)
    }

    /// Checks the size against [`MAX_VECTORS`], [`MAX_QUERIES`] and the byte cap
    /// `min(MAX_BYTES, memory_cap)`, before anything is allocated.
    pub fn check(&self, memory_cap: u64) -> Result<()> {
        if self.vectors == 0 || self.queries == 0 {
            return Err(EngineError::Parameter(format!(
                "calibration of {} vectors × {} queries: both must be ≥ 1",
                self.vectors, self.queries
            )));
        }
        if self.vectors > MAX_VECTORS || self.queries > MAX_QUERIES {
            return Err(EngineError::Parameter(format!(
                "calibration of {} vectors × {} queries exceeds the caps of {MAX_VECTORS} vectors and {MAX_QUERIES} queries",
                self.vectors, self.queries
            )));
        }
        let bytes = self.bytes()?;
        let cap = MAX_BYTES.min(memory_cap);
        if bytes > cap {
            return Err(EngineError::Parameter(format!(
                "calibration of {} vectors × {} dims needs {bytes} bytes; the cap is {cap}",
                self.vectors, self.dims
            )));
        }
        Ok(())
    }
}

/// Runs the calibration search of `size` (zero fields take the defaults) on
/// `engine` in the current rayon pool: random vectors and queries from the
/// seed, the exhaustive best-1 search timed twice, the faster run counted.
pub fn calibrate(engine: &Engine, size: CalibrationSize) -> Result<Calibration> {
    let size = size.or_default();
    size.check(u64::MAX)?;
    let layout = Layout::checked(size.dims as usize, 0)?;
    let mut rng = ChaCha8Rng::seed_from_u64(size.seed);
    let raw: Vec<u8> = (0..size.vectors as usize * layout.dims())
        .map(|_| rng.random())
        .collect();
    let space = VectorSpace::from_unpadded(layout, 0, &raw)?;
    drop(raw);
    let mut batch = QueryBatch::new(layout);
    let mut q = vec![0u8; layout.dims()];
    for _ in 0..size.queries {
        rng.fill(&mut q[..]);
        batch.push_full(&q)?;
    }
    let params = Params::default();
    let mut best = f64::INFINITY;
    for _ in 0..2 {
        let t = Instant::now();
        engine.search_best(&space, 0..space.end(), &batch, &params)?;
        best = best.min(t.elapsed().as_secs_f64());
    }
    let pairs = f64::from(size.vectors) * f64::from(size.queries);
    Ok(Calibration {
        pairs_per_second: pairs / best.max(1e-9),
        seconds: best,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zero_fields_take_the_defaults() {
        let d = CalibrationSize::default();
        let z = CalibrationSize {
            seed: 3,
            vectors: 0,
            dims: 0,
            queries: 0,
        }
        .or_default();
        assert_eq!(
            (z.seed, z.vectors, z.dims, z.queries),
            (3, d.vectors, d.dims, d.queries)
        );
    }

    #[test]
    fn oversized_calibrations_are_refused_before_allocating() {
        let big = CalibrationSize {
            vectors: MAX_VECTORS + 1,
            ..CalibrationSize::default()
        };
        assert!(big.check(u64::MAX).is_err());
        let d = CalibrationSize::default();
        assert!(d.check(u64::MAX).is_ok());
        assert!(d.check(1024).is_err());
    }

    #[test]
    fn a_small_calibration_measures_a_positive_rate() {
        let size = CalibrationSize {
            seed: 1,
            vectors: 512,
            dims: 20,
            queries: 4,
        };
        let c = calibrate(&Engine::default(), size).unwrap();
        assert!(c.pairs_per_second.is_finite() && c.pairs_per_second > 0.0);
        assert!(c.seconds >= 0.0);
    }
}
