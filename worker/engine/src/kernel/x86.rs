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
//! - Query pointers index the padded copies of [`padded_queries`] (`nqp × stride`
//!   bytes, query `g·group + j < nqp`) or one query's own `stride`-byte slice.
//! - Stores go to `row` (`nqp` lanes, groups `g < nqp / group`) or a 4-lane
//!   buffer, both sized here.

use std::arch::x86_64::*;

use super::{distance, padded_queries, PruneStats, Scan, Sink};
use crate::layout::Metric;

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

// ---------------------------------------------------------------- AVX-512

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
unsafe fn ld512(p: *const u8) -> __m512i {
    _mm512_loadu_si512(p.cast())
}

#[inline(always)]
unsafe fn ld256(p: *const u8) -> __m256i {
    _mm256_loadu_si256(p.cast())
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

// ---------------------------------------------------------------- AVX2

/// One pruning stage: `chunks` 32-byte chunks from byte `from` of a vector, in
/// the lo part (sums go to the high 32 bits) or the hi part.
#[derive(Clone, Copy)]
struct Stage {
    from: usize,
    chunks: usize,
    lo: bool,
}

/// The order the AVX2 kernel scores a vector in (partial distance
/// elimination, ARCHITECTURE §3.5): the lo part first (the parent window, fully
/// defined on every level below the coarsest, so it separates vectors best per
/// byte), then the hi part in two halves. After every stage but the last the
/// partial distances are compared with the sink's bounds.
struct Stages {
    list: [Stage; 4],
    len: usize,
    chunks: usize,
}

impl Stages {
    fn new(plan: &Plan) -> Self {
        let hi = plan.hi_pad / 32;
        let lo = plan.lo64 * 2 + usize::from(plan.lo32);
        let none = Stage {
            from: 0,
            chunks: 0,
            lo: false,
        };
        let mut st = Self {
            list: [none; 4],
            len: 0,
            chunks: hi + lo,
        };
        let mut push = |s: Stage| {
            if s.chunks > 0 {
                st.list[st.len] = s;
                st.len += 1;
            }
        };
        let l1 = lo.min(1);
        push(Stage {
            from: plan.hi_pad,
            chunks: l1,
            lo: true,
        });
        push(Stage {
            from: plan.hi_pad + l1 * 32,
            chunks: lo - l1,
            lo: true,
        });
        let h1 = hi / 2;
        push(Stage {
            from: 0,
            chunks: h1,
            lo: false,
        });
        push(Stage {
            from: h1 * 32,
            chunks: hi - h1,
            lo: false,
        });
        st
    }

    fn stages(&self) -> &[Stage] {
        &self.list[..self.len]
    }
}

/// Adds one stage of 4 (vector, query) pairs to their accumulators (pair j
/// compares `v[j]` with query `q[j]`/`m[j]`; hi sums in the low and lo sums in
/// the high 32 bits of each 64-bit lane).
#[inline(always)]
unsafe fn stage4<const L2: bool>(
    acc: &mut [__m256i; 4],
    st: Stage,
    v: &[*const u8; 4],
    q: &[*const u8; 4],
    m: &[*const u8; 4],
) {
    for c in 0..st.chunks {
        let o = st.from + c * 32;
        for j in 0..4 {
            let s = part256::<L2>(ld256(v[j].add(o)), ld256(m[j].add(o)), ld256(q[j].add(o)));
            let s = if st.lo { _mm256_slli_epi64::<32>(s) } else { s };
            acc[j] = _mm256_add_epi64(acc[j], s);
        }
    }
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

#[inline(always)]
unsafe fn weigh256(r: __m256i, wh: __m256i, wl: __m256i) -> __m256i {
    _mm256_add_epi64(
        _mm256_mul_epu32(r, wh),
        _mm256_mul_epu32(_mm256_srli_epi64::<32>(r), wl),
    )
}

/// Weighted distances of 4 pairs, stage by stage. With a `bound` (4 signed
/// lanes), stops after a stage once every pair's partial distance exceeds its
/// bound and returns those partial sums. Returns the chunks scored per pair and
/// whether the pairs were abandoned.
#[inline(always)]
unsafe fn score4<const L2: bool>(
    stages: &Stages,
    w: (__m256i, __m256i),
    v: &[*const u8; 4],
    q: &[*const u8; 4],
    m: &[*const u8; 4],
    bound: Option<__m256i>,
) -> (__m256i, usize, bool) {
    let mut acc = [_mm256_setzero_si256(); 4];
    let list = stages.stages();
    let mut done = 0;
    for (k, &st) in list.iter().enumerate() {
        stage4::<L2>(&mut acc, st, v, q, m);
        done += st.chunks;
        if let Some(b) = bound {
            if k + 1 < list.len() {
                let d = weigh256(reduce4(&acc), w.0, w.1);
                let over = _mm256_movemask_pd(_mm256_castsi256_pd(_mm256_cmpgt_epi64(d, b)));
                if over == 0xF {
                    return (d, done, true);
                }
            }
        }
    }
    (weigh256(reduce4(&acc), w.0, w.1), done, false)
}

/// The quick first test of L1 partial distance elimination: when 4 queries
/// define every component of the vector's first lo chunk (at byte `c`), their
/// partial distances there are plain `vpsadbw` sums (values of undefined
/// padding are 0 on both sides), weighted by `wl`. When all 4 exceed their
/// bounds `b`, so the vector cannot win for any of them, returns those sums.
#[inline(always)]
unsafe fn quick_cut(
    v0: __m256i,
    q: &[*const u8; 4],
    c: usize,
    wl: __m256i,
    b: __m256i,
) -> Option<__m256i> {
    let acc: [__m256i; 4] = std::array::from_fn(|j| _mm256_sad_epu8(v0, ld256(q[j].add(c))));
    let d = _mm256_mul_epu32(reduce4(&acc), wl);
    (_mm256_movemask_pd(_mm256_castsi256_pd(_mm256_cmpgt_epi64(d, b))) == 0xF).then_some(d)
}

/// A sink bound as a signed 64-bit lane (distances stay far below 2⁶³).
#[inline(always)]
fn signed(b: u64) -> i64 {
    b.min(i64::MAX as u64) as i64
}

/// # Safety
/// The CPU must support AVX2; `scan` was built by `Scan::new` (see the memory
/// bounds in the module documentation).
#[target_feature(enable = "avx2")]
pub(crate) unsafe fn scan_avx2<S: Sink>(scan: &Scan, sink: &mut S) {
    match scan.params.metric {
        Metric::L1 => scan256::<false, S>(scan, sink),
        Metric::L2 => scan256::<true, S>(scan, sink),
    }
}

#[target_feature(enable = "avx2")]
unsafe fn scan256<const L2: bool, S: Sink>(scan: &Scan, sink: &mut S) {
    let plan = Plan::new(scan);
    let stages = Stages::new(&plan);
    let s = scan.layout.stride();
    let nq = scan.queries.len();
    let w = (
        _mm256_set1_epi64x(i64::from(scan.params.weights.hi)),
        _mm256_set1_epi64x(i64::from(scan.params.weights.lo)),
    );
    let vp = scan.vectors.as_ptr();
    let mut stats = PruneStats::default();
    if nq >= 4 {
        let (qv, qm, nqp) = padded_queries(scan.queries, 4);
        let (qv, qm) = (qv.as_slice(), qm.as_slice());
        let mut row = vec![0u64; nqp];
        // Padding queries (distance 0) get bound −1, so they never keep a
        // group of real queries from being abandoned.
        let mut bnd = vec![-1i64; nqp];
        let pruning = sink.bounds().is_some();
        // The quick first test (L1): offset of the first lo chunk when the
        // first stage is that one chunk, and per group whether all 4 queries
        // define every component of it.
        let quick =
            (!L2 && stages.stages()[0].lo && stages.stages()[0].chunks == 1).then_some(plan.hi_pad);
        let full: Vec<bool> = (0..nqp / 4)
            .map(|g| {
                quick.is_some_and(|c| {
                    (0..4).all(|j| {
                        let o = (g * 4 + j) * s + c;
                        let len = scan.layout.lo_len.min(32);
                        qm[o..o + len].iter().all(|&b| b == 0xFF)
                    })
                })
            })
            .collect();
        // The bounds change only when the sink takes a row: refresh them then.
        let mut stale = true;
        for i in 0..scan.count {
            if stale {
                if let Some(b) = sink.bounds() {
                    for (x, &y) in bnd.iter_mut().zip(b) {
                        *x = signed(y);
                    }
                }
                stale = false;
            }
            // As in `scan512`: vector i < count, query g·4 + j < nqp; `bnd`
            // and `row` hold nqp lanes.
            let v = [vp.add(i * s); 4];
            // The first lo chunk of the vector, shared by every group's quick test.
            let v0 = quick.map(|c| ld256(v[0].add(c)));
            let mut all_cut = true;
            for (g, &full_g) in full.iter().enumerate() {
                let q: [*const u8; 4] = std::array::from_fn(|j| qv.as_ptr().add((g * 4 + j) * s));
                let bound = pruning.then(|| _mm256_loadu_si256(bnd.as_ptr().add(g * 4).cast()));
                if let (Some(c), Some(v0), Some(b), true) = (quick, v0, bound, full_g) {
                    if let Some(d) = quick_cut(v0, &q, c, w.1, b) {
                        // Partial sums above the bounds: the sink ignores them.
                        _mm256_storeu_si256(row.as_mut_ptr().add(g * 4).cast(), d);
                        stats.chunks += 4;
                        stats.pruned += 4;
                        continue;
                    }
                }
                let m: [*const u8; 4] = std::array::from_fn(|j| qm.as_ptr().add((g * 4 + j) * s));
                let (d, done, cut) = score4::<L2>(&stages, w, &v, &q, &m, bound);
                _mm256_storeu_si256(row.as_mut_ptr().add(g * 4).cast(), d);
                let real = (nq - g * 4).min(4) as u64;
                stats.chunks += real * done as u64;
                stats.pruned += if cut { real } else { 0 };
                all_cut &= cut;
            }
            // A vector abandoned for every query cannot enter the sink.
            if !all_cut {
                sink.row(scan.base + i as u64, &row[..nq]);
                stale = true;
            }
        }
        stats.pairs = (scan.count * nq) as u64;
    } else {
        let mut buf = [0u64; 4];
        let groups = scan.count / 4;
        for g in 0..groups {
            // Vectors 4g..4g+4 ≤ count; each query is its own s-byte slice.
            let v: [*const u8; 4] = std::array::from_fn(|j| vp.add((g * 4 + j) * s));
            for qi in 0..nq {
                let q = [scan.queries.values(qi).as_ptr(); 4];
                let m = [scan.queries.mask(qi).as_ptr(); 4];
                let bound = sink.bounds().map(|b| _mm256_set1_epi64x(signed(b[qi])));
                let (d, done, cut) = score4::<L2>(&stages, w, &v, &q, &m, bound);
                if !cut {
                    _mm256_storeu_si256(buf.as_mut_ptr().cast(), d);
                    sink.run(qi, scan.base + (g * 4) as u64, &buf);
                }
                stats.pairs += 4;
                stats.chunks += 4 * done as u64;
                stats.pruned += if cut { 4 } else { 0 };
            }
        }
        let rest = ((scan.count - groups * 4) * nq) as u64;
        stats.pairs += rest;
        stats.chunks += rest * stages.chunks as u64;
        tail(scan, groups * 4, sink);
    }
    stats.chunks_full = stats.pairs * stages.chunks as u64;
    sink.stats(stats);
}

// ---------------------------------------------------------------- heads and pairs

/// The rest of one pair's distance after its head: `partial` (the weighted
/// head sum) plus the lo bytes `hi_pad + hb..hi_pad + lo_pad`, then the hi part
/// in two halves. Stops with a partial sum above `bound` as soon as one is.
///
/// # Safety
/// The CPU must support AVX2; `hi_pad`, `lo_pad` and `hb ≤ lo_pad` are
/// multiples of 32 and `v`, `q` and `m` are readable for `hi_pad + lo_pad` bytes.
#[target_feature(enable = "avx2")]
#[allow(clippy::too_many_arguments)]
pub(crate) unsafe fn finish_avx2(
    l2: bool,
    (hi_pad, lo_pad, hb): (usize, usize, usize),
    (wh, wl): (u64, u64),
    v: *const u8,
    q: *const u8,
    m: *const u8,
    partial: u64,
    bound: u64,
) -> u64 {
    let sum = |from: usize, len: usize| {
        if l2 {
            chunk_sum::<true>(from, len, v, q, m)
        } else {
            chunk_sum::<false>(from, len, v, q, m)
        }
    };
    let mut d = partial + wl * sum(hi_pad + hb, lo_pad - hb);
    let half = hi_pad / 64 * 32;
    for (from, len) in [(0, half), (half, hi_pad - half)] {
        if d > bound {
            return d;
        }
        d += wh * sum(from, len);
    }
    d
}

/// Masked sum over bytes `from..from + len` (whole 32-byte chunks) of one pair.
#[inline(always)]
unsafe fn chunk_sum<const L2: bool>(
    from: usize,
    len: usize,
    v: *const u8,
    q: *const u8,
    m: *const u8,
) -> u64 {
    let mut acc = _mm256_setzero_si256();
    let mut o = from;
    while o < from + len {
        // o + 32 ≤ from + len: inside all three buffers (the caller's bound).
        let s = part256::<L2>(ld256(v.add(o)), ld256(m.add(o)), ld256(q.add(o)));
        acc = _mm256_add_epi64(acc, s);
        o += 32;
    }
    let mut lanes = [0u64; 4];
    _mm256_storeu_si256(lanes.as_mut_ptr().cast(), acc);
    lanes.iter().sum()
}

/// Weighted distance of each of the `n` heads (`hb` bytes each, a multiple
/// of 32, from `heads`) to the query head `qh`, written to `out[..n]`: the
/// pair's partial distance over the head when the query defines all of it
/// (its undefined padding is 0 on both sides), so a lower bound of its
/// distance.
///
/// # Safety
/// The CPU must support AVX2; `heads` must be readable for `hb·n` bytes, `qh`
/// for `hb` bytes and `out` writable for `n` values.
#[target_feature(enable = "avx2")]
pub(crate) unsafe fn heads_avx2(
    l2: bool,
    heads: *const u8,
    hb: usize,
    n: usize,
    qh: *const u8,
    wl: u64,
    out: *mut u64,
) {
    if l2 {
        heads256::<true>(heads, hb, n, qh, wl, out)
    } else {
        heads256::<false>(heads, hb, n, qh, wl, out)
    }
}

/// The sum over the `hb` bytes of head `i` (4 lanes).
#[inline(always)]
unsafe fn head256<const L2: bool>(heads: *const u8, hb: usize, i: usize, qh: *const u8) -> __m256i {
    let ones = _mm256_set1_epi8(-1);
    let mut acc = _mm256_setzero_si256();
    let mut o = 0;
    while o < hb {
        // o + 32 ≤ hb: inside head i and inside the query head.
        let s = part256::<L2>(ld256(heads.add(i * hb + o)), ones, ld256(qh.add(o)));
        acc = _mm256_add_epi64(acc, s);
        o += 32;
    }
    acc
}

#[inline(always)]
unsafe fn heads256<const L2: bool>(
    heads: *const u8,
    hb: usize,
    n: usize,
    qh: *const u8,
    wl: u64,
    out: *mut u64,
) {
    let w = _mm256_set1_epi64x(wl as i64);
    let groups = n / 4;
    for g in 0..groups {
        // Heads 4g..4g + 4 ≤ n: inside the hb·n readable bytes.
        let acc: [__m256i; 4] = std::array::from_fn(|j| head256::<L2>(heads, hb, g * 4 + j, qh));
        _mm256_storeu_si256(out.add(g * 4).cast(), _mm256_mul_epu32(reduce4(&acc), w));
    }
    for i in groups * 4..n {
        let mut lanes = [0u64; 4];
        _mm256_storeu_si256(lanes.as_mut_ptr().cast(), head256::<L2>(heads, hb, i, qh));
        *out.add(i) = lanes.iter().sum::<u64>() * wl;
    }
}
