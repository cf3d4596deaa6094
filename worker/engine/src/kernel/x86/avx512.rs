//! The AVX-512BW kernel: 64-byte chunks, groups of 8 queries, one vector
//! against every query group per row; pruning searches and few queries go
//! to the AVX2 kernel.

use std::arch::x86_64::*;

use super::avx2::scan256;
use super::{ld256, part256, Plan};
use crate::kernel::{padded_queries, Scan, Sink};
use crate::layout::Metric;

#[inline(always)]
unsafe fn part512<const L2: bool>(v: __m512i, m: __m512i, q: __m512i) -> __m512i {
    let x = _mm512_and_si512(v, m);
    if L2 {
        let d = _mm512_or_si512(_mm512_subs_epu8(x, q), _mm512_subs_epu8(q, x));
        let z = _mm512_setzero_si512();
        let a = _mm512_unpacklo_epi8(d, z);
        let b = _mm512_unpackhi_epi8(d, z);
        let s = _mm512_add_epi32(_mm512_madd_epi16(a, a), _mm512_madd_epi16(b, b));
        _mm512_add_epi64(
            _mm512_and_si512(s, _mm512_set1_epi64(0xFFFF_FFFF)),
            _mm512_srli_epi64::<32>(s),
        )
    } else {
        _mm512_sad_epu8(x, q)
    }
}

#[inline(always)]
unsafe fn ld512(p: *const u8) -> __m512i {
    _mm512_loadu_si512(p.cast())
}

/// Sums of 8 (vector, query) pairs: pair j compares `v[j]` with query `q[j]`/`m[j]`.
/// Returns one 64-bit lane per pair, hi sum in the low and lo sum in the high half.
#[inline(always)]
unsafe fn pairs8<const L2: bool>(
    plan: &Plan,
    v: &[*const u8; 8],
    q: &[*const u8; 8],
    m: &[*const u8; 8],
) -> __m512i {
    let mut acc = [_mm512_setzero_si512(); 8];
    for c in 0..plan.hi64 {
        let o = c * 64;
        for j in 0..8 {
            let s = part512::<L2>(ld512(v[j].add(o)), ld512(m[j].add(o)), ld512(q[j].add(o)));
            acc[j] = _mm512_add_epi64(acc[j], s);
        }
    }
    if plan.hi32 {
        let o = plan.hi64 * 64;
        for j in 0..8 {
            let s = part256::<L2>(ld256(v[j].add(o)), ld256(m[j].add(o)), ld256(q[j].add(o)));
            acc[j] = _mm512_add_epi64(acc[j], _mm512_zextsi256_si512(s));
        }
    }
    for c in 0..plan.lo64 {
        let o = plan.hi_pad + c * 64;
        for j in 0..8 {
            let s = part512::<L2>(ld512(v[j].add(o)), ld512(m[j].add(o)), ld512(q[j].add(o)));
            acc[j] = _mm512_add_epi64(acc[j], _mm512_slli_epi64::<32>(s));
        }
    }
    if plan.lo32 {
        let o = plan.hi_pad + plan.lo64 * 64;
        for j in 0..8 {
            let s = part256::<L2>(ld256(v[j].add(o)), ld256(m[j].add(o)), ld256(q[j].add(o)));
            acc[j] = _mm512_add_epi64(acc[j], _mm512_zextsi256_si512(_mm256_slli_epi64::<32>(s)));
        }
    }
    reduce8(&acc)
}

/// Lane j of the result = sum of the 8 lanes of `a[j]`.
#[inline(always)]
unsafe fn reduce8(a: &[__m512i; 8]) -> __m512i {
    let pair = |x: __m512i, y: __m512i| {
        _mm512_add_epi64(_mm512_unpacklo_epi64(x, y), _mm512_unpackhi_epi64(x, y))
    };
    let quad = |x: __m512i, y: __m512i| {
        _mm512_add_epi64(
            _mm512_shuffle_i64x2::<0b10_00_10_00>(x, y),
            _mm512_shuffle_i64x2::<0b11_01_11_01>(x, y),
        )
    };
    let b0 = pair(a[0], a[1]);
    let b1 = pair(a[2], a[3]);
    let b2 = pair(a[4], a[5]);
    let b3 = pair(a[6], a[7]);
    quad(quad(b0, b1), quad(b2, b3))
}

#[inline(always)]
unsafe fn weigh512(r: __m512i, wh: __m512i, wl: __m512i) -> __m512i {
    _mm512_add_epi64(
        _mm512_mul_epu32(r, wh),
        _mm512_mul_epu32(_mm512_srli_epi64::<32>(r), wl),
    )
}

/// # Safety
/// The CPU must support AVX2, AVX-512F, AVX-512BW and AVX-512VL; `scan` was
/// built by `Scan::new` (see the memory bounds in the module documentation).
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl")]
pub(crate) unsafe fn scan_avx512<S: Sink>(scan: &Scan, sink: &mut S) {
    match scan.params.metric {
        Metric::L1 => scan512::<false, S>(scan, sink),
        Metric::L2 => scan512::<true, S>(scan, sink),
    }
}

#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl")]
unsafe fn scan512<const L2: bool, S: Sink>(scan: &Scan, sink: &mut S) {
    let plan = Plan::new(scan);
    let s = scan.layout.stride();
    let nq = scan.queries.len();
    let wh = _mm512_set1_epi64(i64::from(scan.params.weights.hi));
    let wl = _mm512_set1_epi64(i64::from(scan.params.weights.lo));
    let vp = scan.vectors.as_ptr();
    if nq >= 8 && sink.bounds().is_none() {
        // Rows: one vector against groups of 8 queries.
        let (qv, qm, nqp) = padded_queries(scan.queries, 8);
        let (qv, qm) = (qv.as_slice(), qm.as_slice());
        let mut row = vec![0u64; nqp];
        for i in 0..scan.count {
            // Vector i < count: bytes i·s..(i+1)·s are inside `scan.vectors`;
            // query g·8 + j < nqp: inside the padded copies (nqp × s bytes).
            let v = [vp.add(i * s); 8];
            for g in 0..nqp / 8 {
                let q: [*const u8; 8] = std::array::from_fn(|j| qv.as_ptr().add((g * 8 + j) * s));
                let m: [*const u8; 8] = std::array::from_fn(|j| qm.as_ptr().add((g * 8 + j) * s));
                let d = weigh512(pairs8::<L2>(&plan, &v, &q, &m), wh, wl);
                _mm512_storeu_si512(row.as_mut_ptr().add(g * 8).cast(), d);
            }
            sink.row(scan.base + i as u64, &row[..nq]);
        }
    } else {
        // A sink that prunes: the staged AVX2 path abandons pairs early (this
        // 8-wide path has no stages). Few queries: the pass is bound by memory
        // bandwidth, and the 4-wide reduction of the AVX2 path is measurably
        // cheaper than the 8-wide one.
        scan256::<L2, S>(scan, sink);
    }
}
