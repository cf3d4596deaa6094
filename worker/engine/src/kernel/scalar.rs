//! Portable scalar kernel: the reference the SIMD kernels are tested against.

use super::{distance, PruneStats, Scan, Sink};

pub(crate) fn scan<S: Sink>(scan: &Scan, sink: &mut S) {
    let s = scan.layout.stride();
    let nq = scan.queries.len();
    let mut row = vec![0u64; nq];
    for i in 0..scan.count {
        let v = &scan.vectors[i * s..(i + 1) * s];
        for (q, d) in row.iter_mut().enumerate() {
            *d = distance(
                &scan.layout,
                &scan.params,
                v,
                scan.queries.values(q),
                scan.queries.mask(q),
            );
        }
        sink.row(scan.base + i as u64, &row);
    }
    let pairs = (scan.count * nq) as u64;
    let chunks = pairs * (scan.layout.stride() / crate::layout::LANE) as u64;
    sink.stats(PruneStats {
        pairs,
        pruned: 0,
        chunks,
        chunks_full: chunks,
    });
}
