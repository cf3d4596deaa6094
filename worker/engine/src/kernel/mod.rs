//! Masked distance kernels with run-time dispatch (ARCHITECTURE §3.5, Stahlhut §7).
//!
//! Every kernel computes exactly the integer distance of [`distance`], the
//! scalar reference: D = w_hi·Σ_hi f(q−v) + w_lo·Σ_lo f(q−v) over the
//! masked-in components, with f = |·| (L1) or (·)² (L2). The SIMD kernels score
//! a whole batch of queries in one pass over the vectors: each vector is loaded
//! once and compared with every query while it sits in registers.

use crate::batch::QueryBatch;
use crate::error::{EngineError, Result};
use crate::layout::{Layout, Metric, Weights, LANE, SLACK};
use crate::space::AlignedBytes;

mod scalar;
#[cfg(target_arch = "x86_64")]
pub(crate) mod x86;

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

/// One component's term of a distance: |a − b| for L1, (a − b)² for L2.
#[inline(always)]
fn component(metric: Metric, a: u8, b: u8) -> u64 {
    let d = u64::from(a.abs_diff(b));
    match metric {
        Metric::L1 => d,
        Metric::L2 => d * d,
    }
}

/// The scalar reference distance between a padded vector and a padded query
/// (values already masked, mask 0xFF/0). Every kernel must equal it.
pub fn distance(layout: &Layout, params: &Params, v: &[u8], q: &[u8], mask: &[u8]) -> u64 {
    let f = |a: u8, b: u8| component(params.metric, a, b);
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

/// What pruning saved in one search (ARCHITECTURE §3.5): the (vector, query)
/// pairs scored, those abandoned before their last component, and the 32-byte
/// chunks of components computed against the chunks a full scan computes.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct PruneStats {
    pub pairs: u64,
    pub pruned: u64,
    pub chunks: u64,
    pub chunks_full: u64,
}

impl PruneStats {
    pub fn add(&mut self, o: &PruneStats) {
        self.pairs += o.pairs;
        self.pruned += o.pruned;
        self.chunks += o.chunks;
        self.chunks_full += o.chunks_full;
    }

    /// Share of pairs abandoned early (vectors skipped per query).
    pub fn pairs_skipped(&self) -> f64 {
        ratio(self.pruned, self.pairs)
    }

    /// Share of the component work not done.
    pub fn components_skipped(&self) -> f64 {
        ratio(
            self.chunks_full.saturating_sub(self.chunks),
            self.chunks_full,
        )
    }
}

fn ratio(a: u64, b: u64) -> f64 {
    if b == 0 {
        0.0
    } else {
        a as f64 / b as f64
    }
}

/// Receives distances from a kernel. Vectors arrive in ascending index order
/// per query.
///
/// A sink with [`Sink::bounds`] accepts only distances at or below its bound,
/// so a kernel may hand it, instead of a distance, any partial sum that already
/// exceeds the bound: partial sums only grow (partial distance elimination).
pub(crate) trait Sink {
    /// Distances of vector `index` to queries `0..d.len()`.
    fn row(&mut self, index: u64, d: &[u64]);
    /// Distances of query `q` to vectors `first..first + d.len()`.
    fn run(&mut self, q: usize, first: u64, d: &[u64]);
    /// Per query the largest distance the sink can still accept; `None` when it
    /// needs every distance exactly.
    fn bounds(&self) -> Option<&[u64]> {
        None
    }
    /// The pruning figures of the scan, once at its end.
    fn stats(&mut self, _stats: PruneStats) {}
}

/// One pass of a kernel over `count` padded vectors, global indices from `base`.
///
/// [`Scan::new`] is the only way to make one, and it checks once per scan what
/// the SIMD kernels rely on for memory safety (ARCHITECTURE §3.2, §3.5):
/// - the layout is the padded layout of its part lengths ([`Layout::new`]), so
///   both parts are multiples of [`LANE`] bytes and every 32- or 64-byte chunk a
///   kernel loads lies inside one vector's `stride` bytes;
/// - the queries have the same layout, so a query buffer indexed with this
///   `stride` holds every byte a kernel loads from it;
/// - `vectors` holds `count × stride` bytes plus [`SLACK`] readable bytes after
///   the last vector.
///
/// The checks are `assert!`s, so a short buffer is a panic in every build,
/// never an out-of-bounds read.
pub(crate) struct Scan<'a> {
    layout: Layout,
    params: Params,
    vectors: &'a [u8],
    count: usize,
    base: u64,
    queries: &'a QueryBatch,
}

impl<'a> Scan<'a> {
    /// A scan of the first `count` padded vectors of `vectors` against `queries`.
    ///
    /// # Panics
    /// If `layout` is not a padded layout, the queries have another layout, or
    /// `vectors` is shorter than `count × stride + SLACK` bytes.
    pub(crate) fn new(
        layout: Layout,
        params: Params,
        vectors: &'a [u8],
        count: usize,
        base: u64,
        queries: &'a QueryBatch,
    ) -> Self {
        assert!(
            layout == Layout::new(layout.hi_len, layout.lo_len)
                && layout.hi_pad.is_multiple_of(LANE)
                && layout.lo_pad.is_multiple_of(LANE),
            "scan layout {layout:?} is not padded to {LANE}-byte lanes"
        );
        assert_eq!(
            queries.layout(),
            layout,
            "queries and vectors of a scan have different layouts"
        );
        let need = count
            .checked_mul(layout.stride())
            .and_then(|b| b.checked_add(SLACK));
        assert!(
            need.is_some_and(|need| vectors.len() >= need),
            "scan of {count} vectors of {} bytes needs {need:?} bytes with the slack, got {}",
            layout.stride(),
            vectors.len()
        );
        Self {
            layout,
            params,
            vectors,
            count,
            base,
            queries,
        }
    }
}

impl Kernel {
    /// Runs the kernel over `scan`, feeding every (vector, query) distance to `sink`.
    pub(crate) fn scan<S: Sink>(&self, scan: &Scan, sink: &mut S) {
        match self {
            Kernel::Scalar => scalar::scan(scan, sink),
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx2 => {
                assert!(x86::has_avx2(), "AVX2 kernel on a CPU without AVX2");
                // SAFETY: CPU features: AVX2 is present (asserted just above).
                // Memory: `scan` was built by `Scan::new`, which asserted a
                // lane-padded layout shared by vectors and queries and at least
                // `count × stride + SLACK` vector bytes; `scan_avx2` only loads
                // 32-byte chunks inside vectors `0..count`, inside queries
                // `0..len` (or their padded copies) and stores into buffers it
                // sized itself (see the memory notes in `x86.rs`).
                unsafe { x86::scan_avx2(scan, sink) }
            }
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx512 => {
                assert!(
                    x86::has_avx512(),
                    "AVX-512 kernel on a CPU without AVX-512BW/VL"
                );
                // SAFETY: CPU features: AVX-512F/BW/VL and AVX2 are present
                // (asserted just above). Memory: as for AVX2 — `Scan::new`
                // asserted the padded layout, the query layout and
                // `count × stride + SLACK` vector bytes; every 64- or 32-byte
                // load of `scan_avx512` lies inside one vector of `0..count` or
                // one padded query (see the memory notes in `x86.rs`).
                unsafe { x86::scan_avx512(scan, sink) }
            }
            #[cfg(not(target_arch = "x86_64"))]
            _ => scalar::scan(scan, sink),
        }
    }
}

/// Bytes of a vector's *head* in a layout: the start of its lo part, at most
/// two lanes, which the key-ordered search tests before anything else
/// (ARCHITECTURE §3.5).
/// (Counted in [`Layout::dense_bytes_per_vector`].)
pub(crate) fn head_bytes(layout: &Layout) -> usize {
    layout.lo_pad.min(2 * LANE)
}

impl Kernel {
    /// Per head (`hb` bytes each, a multiple of [`LANE`], padding 0) its
    /// `wl`-weighted distance to the query head `qh` over all `hb` bytes, into
    /// `out[..heads.len() / hb]`. When the query defines every component of
    /// the head this is the pair's partial distance there, a lower bound of
    /// its distance.
    ///
    /// # Panics
    /// If `hb` is not a positive multiple of [`LANE`], `heads` is not a whole
    /// number of heads, `qh` is shorter than a head or `out` than the heads.
    pub(crate) fn heads(
        &self,
        metric: Metric,
        heads: &[u8],
        hb: usize,
        qh: &[u8],
        wl: u64,
        out: &mut [u64],
    ) {
        assert!(hb > 0 && hb.is_multiple_of(LANE), "head of {hb} bytes");
        let n = heads.len() / hb;
        assert!(
            heads.len() == n * hb && out.len() >= n && qh.len() >= hb,
            "{} head bytes of {hb} for {} outputs",
            heads.len(),
            out.len()
        );
        match self {
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx2 | Kernel::Avx512 => {
                assert!(x86::has_avx2(), "AVX2 kernel on a CPU without AVX2");
                // SAFETY: AVX2 is present (asserted); `heads` holds hb·n bytes,
                // `qh` hb bytes and `out` at least n values (asserted above).
                unsafe {
                    x86::heads_avx2(
                        metric == Metric::L2,
                        heads.as_ptr(),
                        hb,
                        n,
                        qh.as_ptr(),
                        wl,
                        out.as_mut_ptr(),
                    )
                }
            }
            _ => {
                for (h, o) in heads.chunks_exact(hb).zip(out.iter_mut()) {
                    let s: u64 = h
                        .iter()
                        .zip(qh)
                        .map(|(&a, &b)| component(metric, a, b))
                        .sum();
                    *o = s * wl;
                }
            }
        }
    }

    /// The distance of one padded vector to one padded query whose head
    /// (`hb` bytes of lo) scored `partial`: [`distance`] exactly, or some
    /// partial sum above `bound` once one is (the caller only takes
    /// distances up to `bound`).
    ///
    /// # Panics
    /// If the layout is not lane-padded, `hb` is not a head of it, or a buffer
    /// is shorter than the stride.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn finish(
        &self,
        layout: &Layout,
        params: &Params,
        hb: usize,
        v: &[u8],
        q: &[u8],
        m: &[u8],
        partial: u64,
        bound: u64,
    ) -> u64 {
        let s = layout.stride();
        assert!(
            layout.hi_pad.is_multiple_of(LANE)
                && layout.lo_pad.is_multiple_of(LANE)
                && hb.is_multiple_of(LANE)
                && hb <= layout.lo_pad
                && v.len() >= s
                && q.len() >= s
                && m.len() >= s,
            "pair of {}/{}/{} bytes, head {hb}, for a {s}-byte layout",
            v.len(),
            q.len(),
            m.len()
        );
        match self {
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx2 | Kernel::Avx512 => {
                assert!(x86::has_avx2(), "AVX2 kernel on a CPU without AVX2");
                // SAFETY: AVX2 is present; the parts and the head are whole
                // lanes, hb ≤ lo_pad and every buffer holds `hi_pad + lo_pad`
                // bytes (asserted above).
                unsafe {
                    x86::finish_avx2(
                        params.metric == Metric::L2,
                        (layout.hi_pad, layout.lo_pad, hb),
                        (u64::from(params.weights.hi), u64::from(params.weights.lo)),
                        v.as_ptr(),
                        q.as_ptr(),
                        m.as_ptr(),
                        partial,
                        bound,
                    )
                }
            }
            _ => distance(layout, params, v, q, m),
        }
    }
}

/// Asks the CPU to bring the cache lines of `bytes` in (a hint: no effect on
/// results, none on CPUs without it).
#[inline(always)]
pub(crate) fn prefetch(bytes: &[u8]) {
    #[cfg(target_arch = "x86_64")]
    for line in bytes.chunks(64) {
        // SAFETY: a prefetch never faults and reads nothing into the program;
        // the address is inside `bytes` anyway.
        unsafe {
            std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(
                line.as_ptr().cast(),
            )
        };
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::layout::Geometry;

    #[test]
    fn scan_accepts_exactly_the_slack() {
        let layout = Geometry::new(3, 0).unwrap().layout();
        let q = QueryBatch::new(layout);
        let buf = vec![0u8; 2 * layout.stride() + SLACK];
        let scan = Scan::new(layout, Params::default(), &buf, 2, 0, &q);
        assert_eq!(scan.count, 2);
    }

    #[test]
    #[should_panic(expected = "with the slack")]
    fn scan_rejects_a_short_buffer() {
        let layout = Geometry::new(3, 0).unwrap().layout();
        let q = QueryBatch::new(layout);
        let buf = vec![0u8; 2 * layout.stride() + SLACK - 1];
        let _ = Scan::new(layout, Params::default(), &buf, 2, 0, &q);
    }

    #[test]
    #[should_panic(expected = "different layouts")]
    fn scan_rejects_queries_of_another_layout() {
        let layout = Geometry::new(3, 0).unwrap().layout();
        let q = QueryBatch::new(Geometry::new(5, 0).unwrap().layout());
        let buf = vec![0u8; SLACK];
        let _ = Scan::new(layout, Params::default(), &buf, 0, 0, &q);
    }

    #[test]
    #[should_panic(expected = "not padded")]
    fn scan_rejects_an_unpadded_layout() {
        let mut layout = Geometry::new(3, 0).unwrap().layout();
        layout.hi_pad = 40;
        let q = QueryBatch::new(layout);
        let buf = vec![0u8; 4096];
        let _ = Scan::new(layout, Params::default(), &buf, 1, 0, &q);
    }
}
