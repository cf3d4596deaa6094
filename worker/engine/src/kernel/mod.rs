//! Masked distance kernels with run-time dispatch (ARCHITECTURE §3.5, Stahlhut §7).
//!
//! Every kernel computes exactly the integer distance of [`distance`], the
//! scalar reference: D = w_hi·Σ_hi f(q−v) + w_lo·Σ_lo f(q−v) over the
//! masked-in components, with f = |·| (L1) or (·)² (L2). The SIMD kernels score
//! a whole batch of queries in one pass over the vectors: each vector is loaded
//! once and compared with every query while it sits in registers.

use crate::error::{EngineError, Result};
use crate::layout::{AlignedBytes, Layout, Metric, QueryBatch, Weights};

mod scalar;
#[cfg(target_arch = "x86_64")]
mod x86;

/// A distance kernel implementation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Kernel {
    /// Portable scalar code; the reference every SIMD kernel is checked against.
    Scalar,
    /// x86-64 AVX2 (32-byte lanes, groups of 4 queries).
    Avx2,
    /// x86-64 AVX-512BW + VL (64-byte lanes, groups of 8 queries).
    Avx512,
}

impl Kernel {
    /// The fastest kernel this CPU supports.
    pub fn detect() -> Self {
        *Self::available().last().unwrap_or(&Kernel::Scalar)
    }

    /// Every kernel this CPU supports, slowest first.
    pub fn available() -> Vec<Self> {
        let mut v = vec![Kernel::Scalar];
        #[cfg(target_arch = "x86_64")]
        {
            if x86::has_avx2() {
                v.push(Kernel::Avx2);
            }
            if x86::has_avx512() {
                v.push(Kernel::Avx512);
            }
        }
        v
    }

    pub fn name(&self) -> &'static str {
        match self {
            Kernel::Scalar => "scalar",
            Kernel::Avx2 => "avx2",
            Kernel::Avx512 => "avx512bw",
        }
    }

    /// Parses a kernel name (`auto` = [`Kernel::detect`]) and checks the CPU supports it.
    pub fn from_name(name: &str) -> Result<Self> {
        let k = match name.to_ascii_lowercase().as_str() {
            "auto" => return Ok(Self::detect()),
            "scalar" => Kernel::Scalar,
            "avx2" => Kernel::Avx2,
            "avx512" | "avx512bw" | "avx-512" => Kernel::Avx512,
            _ => {
                return Err(EngineError::Parameter(format!(
                    "unknown kernel '{name}'; use auto, scalar, avx2 or avx512"
                )))
            }
        };
        k.check()?;
        Ok(k)
    }

    /// Errors if this CPU cannot run the kernel.
    pub fn check(&self) -> Result<()> {
        if Self::available().contains(self) {
            Ok(())
        } else {
            let names: Vec<_> = Self::available().iter().map(|k| k.name()).collect();
            Err(EngineError::Kernel(self.name(), names.join(", ")))
        }
    }
}

/// What to compare: metric and part weights.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub struct Params {
    pub metric: Metric,
    pub weights: Weights,
}

/// The scalar reference distance between a padded vector and a padded query
/// (values already masked, mask 0xFF/0). Every kernel must equal it.
pub fn distance(layout: &Layout, params: &Params, v: &[u8], q: &[u8], mask: &[u8]) -> u64 {
    let f = |a: u8, b: u8| -> u64 {
        let d = u64::from(a.abs_diff(b));
        match params.metric {
            Metric::L1 => d,
            Metric::L2 => d * d,
        }
    };
    let mut hi = 0u64;
    for i in 0..layout.hi_len {
        if mask[i] != 0 {
            hi += f(v[i], q[i]);
        }
    }
    let mut lo = 0u64;
    for i in layout.hi_pad..layout.hi_pad + layout.lo_len {
        if mask[i] != 0 {
            lo += f(v[i], q[i]);
        }
    }
    u64::from(params.weights.hi) * hi + u64::from(params.weights.lo) * lo
}

/// Receives distances from a kernel. Vectors always arrive in ascending index
/// order per query, so a strict `<` keeps the lowest index among ties.
pub(crate) trait Sink {
    /// Distances of vector `index` to queries `0..d.len()`.
    fn row(&mut self, index: u64, d: &[u64]);
    /// Distances of query `q` to vectors `first..first + d.len()`.
    fn run(&mut self, q: usize, first: u64, d: &[u64]);
}

/// One pass of a kernel over `count` padded vectors (with [`crate::layout::SLACK`]
/// readable bytes after them), global indices from `base`.
pub(crate) struct Scan<'a> {
    pub layout: Layout,
    pub params: Params,
    pub vectors: &'a [u8],
    pub count: usize,
    pub base: u64,
    pub queries: &'a QueryBatch,
}

impl Kernel {
    /// Runs the kernel over `scan`, feeding every (vector, query) distance to `sink`.
    pub(crate) fn scan<S: Sink>(&self, scan: &Scan, sink: &mut S) {
        debug_assert!(
            scan.vectors.len() >= scan.count * scan.layout.stride() + crate::layout::SLACK
        );
        match self {
            Kernel::Scalar => scalar::scan(scan, sink),
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx2 => {
                assert!(x86::has_avx2(), "AVX2 kernel on a CPU without AVX2");
                // SAFETY: the CPU supports AVX2 (checked above).
                unsafe { x86::scan_avx2(scan, sink) }
            }
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx512 => {
                assert!(
                    x86::has_avx512(),
                    "AVX-512 kernel on a CPU without AVX-512BW/VL"
                );
                // SAFETY: the CPU supports AVX-512F/BW/VL and AVX2 (checked above).
                unsafe { x86::scan_avx512(scan, sink) }
            }
            #[cfg(not(target_arch = "x86_64"))]
            _ => scalar::scan(scan, sink),
        }
    }
}

/// Copies the batch into 64-byte aligned buffers padded to a multiple of `group`
/// queries with all-masked-out queries: (values, masks, padded count).
pub(crate) fn padded_queries(q: &QueryBatch, group: usize) -> (AlignedBytes, AlignedBytes, usize) {
    let s = q.layout().stride();
    let n = q.len().div_ceil(group) * group;
    let mut v = AlignedBytes::zeroed(n * s);
    let mut m = AlignedBytes::zeroed(n * s);
    v.as_mut_slice()[..q.len() * s].copy_from_slice(q.all_values());
    m.as_mut_slice()[..q.len() * s].copy_from_slice(q.all_masks());
    (v, m, n)
}
