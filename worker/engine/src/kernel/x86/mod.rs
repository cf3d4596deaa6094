//! AVX2 and AVX-512BW kernels (x86-64).
//!
//! The core is `vpsadbw` over the vector masked with the query's mask
//! (Stahlhut §7 uses the same instruction in its MMX form). Per (vector, query)
//! pair the chunk sums stay in a 64-bit-lane accumulator with the hi part in the
//! low 32 bits and the lo part in the high 32 bits; a transposing reduction
//! turns 8 (or 4) accumulators into 8 (or 4) packed sums at once, and two
//! `vpmuludq` apply the integer weights. The result equals the scalar reference
//! exactly (integer arithmetic, no overflow: hi and lo sums stay below 2³²).
//!
//! The AVX2 kernel scores in stages and abandons pairs whose partial distance
//! already exceeds the sink's bound (partial distance elimination,
//! ARCHITECTURE §3.5); a pruning search on an AVX-512 CPU runs that code too.
//!
//! # Memory bounds (ARCHITECTURE §3.2)
//!
//! The `unsafe fn`s here need two things from their caller: the CPU features of
//! their `#[target_feature]`, and a [`Scan`] built by `Scan::new`. The latter
//! asserted that the layout is padded (`hi_pad` and `lo_pad` are multiples of
//! [`LANE`](crate::layout::LANE) = 32 bytes), that the queries have the same
//! layout, and that `scan.vectors` holds `count × stride + SLACK` bytes. From
//! that:
//! - A vector pointer is `vectors + i·stride` with `i < count` (rows) or
//!   `i = 4g + j < 4·⌊count/4⌋` (AVX2 groups); the rest go to the safe scalar
//!   [`tail`].
//! - The chunk offsets of [`Plan`] stay inside one vector: the hi part is
//!   `hi64` 64-byte chunks plus a 32-byte chunk when `hi_pad` is an odd number of
//!   lanes (`64·hi64 + 32 = hi_pad`), the lo part likewise from `hi_pad` to
//!   `hi_pad + lo_pad = stride`; AVX2 walks both parts in 32-byte chunks. So the
//!   last byte loaded from vector `i` is byte `(i+1)·stride − 1`, inside
//!   `count × stride`; the kernels never read past the last vector today, and
//!   the [`SLACK`](crate::layout::SLACK) bytes after it, which `Scan::new`
//!   guarantees anyway, are a margin for a kernel whose last load is wider than
//!   the last chunk.
//! - Query pointers index the padded copies of [`padded_queries`](super::padded_queries) (`nqp × stride`
//!   bytes, query `g·group + j < nqp`) or one query's own `stride`-byte slice.
//! - Stores go to `row` (`nqp` lanes, groups `g < nqp / group`) or a 4-lane
//!   buffer, both sized here.

mod avx2;
mod avx512;
mod heads;

use std::arch::x86_64::*;

use super::{distance, Scan, Sink};

pub(crate) use avx2::scan_avx2;
pub(crate) use avx512::scan_avx512;
pub(crate) use heads::{finish_avx2, heads_avx2};

pub(crate) fn has_avx2() -> bool {
    is_x86_feature_detected!("avx2")
}

pub(crate) fn has_avx512() -> bool {
    has_avx2()
        && is_x86_feature_detected!("avx512f")
        && is_x86_feature_detected!("avx512bw")
        && is_x86_feature_detected!("avx512vl")
}

/// How a padded vector is cut into SIMD chunks: each part in full 64-byte
/// chunks plus an optional 32-byte tail (parts are padded to 32 bytes).
#[derive(Clone, Copy)]
struct Plan {
    hi_pad: usize,
    hi64: usize,
    hi32: bool,
    lo64: usize,
    lo32: bool,
}

impl Plan {
    fn new(scan: &Scan) -> Self {
        let l = scan.layout;
        Self {
            hi_pad: l.hi_pad,
            hi64: l.hi_pad / 64,
            hi32: !l.hi_pad.is_multiple_of(64),
            lo64: l.lo_pad / 64,
            lo32: !l.lo_pad.is_multiple_of(64),
        }
    }
}

#[inline(always)]
unsafe fn part256<const L2: bool>(v: __m256i, m: __m256i, q: __m256i) -> __m256i {
    let x = _mm256_and_si256(v, m);
    if L2 {
        let d = _mm256_or_si256(_mm256_subs_epu8(x, q), _mm256_subs_epu8(q, x));
        let z = _mm256_setzero_si256();
        let a = _mm256_unpacklo_epi8(d, z);
        let b = _mm256_unpackhi_epi8(d, z);
        let s = _mm256_add_epi32(_mm256_madd_epi16(a, a), _mm256_madd_epi16(b, b));
        _mm256_add_epi64(
            _mm256_and_si256(s, _mm256_set1_epi64x(0xFFFF_FFFF)),
            _mm256_srli_epi64::<32>(s),
        )
    } else {
        _mm256_sad_epu8(x, q)
    }
}

#[inline(always)]
unsafe fn ld256(p: *const u8) -> __m256i {
    _mm256_loadu_si256(p.cast())
}

/// Lane j of the result = sum of the 4 lanes of `acc[j]`.
#[inline(always)]
unsafe fn reduce4(acc: &[__m256i; 4]) -> __m256i {
    let pair = |x: __m256i, y: __m256i| {
        _mm256_add_epi64(_mm256_unpacklo_epi64(x, y), _mm256_unpackhi_epi64(x, y))
    };
    let b0 = pair(acc[0], acc[1]);
    let b1 = pair(acc[2], acc[3]);
    _mm256_add_epi64(
        _mm256_permute2x128_si256::<0x20>(b0, b1),
        _mm256_permute2x128_si256::<0x31>(b0, b1),
    )
}

/// Vectors `from..count` one at a time with the scalar reference.
fn tail<S: Sink>(scan: &Scan, from: usize, sink: &mut S) {
    let s = scan.layout.stride();
    for i in from..scan.count {
        let v = &scan.vectors[i * s..(i + 1) * s];
        for qi in 0..scan.queries.len() {
            let d = distance(
                &scan.layout,
                &scan.params,
                v,
                scan.queries.values(qi),
                scan.queries.mask(qi),
            );
            sink.run(qi, scan.base + i as u64, &[d]);
        }
    }
}
