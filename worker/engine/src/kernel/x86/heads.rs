//! Heads and pairs (AVX2): the partial distances of many vectors' heads to
//! one query head, and the rest of one pair's distance after its head, for the
//! windowed search (ARCHITECTURE §3.5).

use std::arch::x86_64::*;

use super::{ld256, part256, reduce4};

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
