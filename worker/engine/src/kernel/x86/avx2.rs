//! The AVX2 kernel: 32-byte chunks, groups of 4 queries, scored in stages
//! with partial distance elimination (ARCHITECTURE §3.5).

use std::arch::x86_64::*;

use super::{ld256, part256, reduce4, tail, Plan};
use crate::kernel::{padded_queries, PruneStats, Scan, Sink};
use crate::layout::Metric;

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
pub(super) unsafe fn scan256<const L2: bool, S: Sink>(scan: &Scan, sink: &mut S) {
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
