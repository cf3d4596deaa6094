//! The k-d tree's top-k (ARCHITECTURE §3.5) equals the unpruned scan: on
//! random low-dimensional spaces with many ties, L1 and L2, weighted parts,
//! sub-ranges (as a worker searches its part), bounds, coherence candidates,
//! near-ties, and a space split between searchers under top-k cuts.

use proptest::prelude::*;
use texsyn_engine::{
    Engine, Kernel, Layout, Metric, Params, QueryBatch, Slack, VectorSpace, Weights,
};

/// `n` vectors of `dims` components from a small alphabet (so distances tie).
fn vectors(n: usize, dims: usize, levels: u8, seed: u64) -> Vec<u8> {
    let mut s = seed | 1;
    (0..n * dims)
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            ((s >> 24) % u64::from(levels)) as u8 * (255 / (levels - 1).max(1))
        })
        .collect()
}

fn batch(layout: Layout, raw: &[u8]) -> QueryBatch {
    let mut b = QueryBatch::new(layout);
    for v in raw.chunks_exact(layout.dims()) {
        b.push_full(v).unwrap();
    }
    b
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(12))]

    #[test]
    fn tree_top_k_is_the_scan_s(
        hi in 1usize..=9,
        lo in 0usize..=7,
        levels in 2u8..=12,
        l2 in any::<bool>(),
        (wh, wl) in (1u32..=5, 1u32..=5),
        k in 1usize..=20,
        cut in 0usize..2000,
        seed in any::<u64>(),
    ) {
        let layout = Layout::new(hi, lo);
        let n = 5000;
        let raw = vectors(n, layout.dims(), levels, seed);
        let space = VectorSpace::from_unpadded(layout, 0, &raw).unwrap();
        let mut queries = batch(layout, &vectors(200, layout.dims(), levels, seed ^ 0xABCD));
        // Coherence candidates (some out of a sub-range, some repeated, some
        // fewer than k) cut the top-k search; the answer must not change.
        let mut r = seed | 1;
        for q in 0..queries.len() {
            r = r.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            let count = (r >> 33) as usize % 40;
            let c = (0..count as u64)
                .map(|j| (r >> 7).wrapping_add(j * j * 7919) % n as u64)
                .collect();
            queries.set_candidates(q, c);
        }
        let params = Params {
            metric: if l2 { Metric::L2 } else { Metric::L1 },
            weights: Weights::new(wh, if lo == 0 { 0 } else { wl }).unwrap(),
        };
        let tree = Engine::default();
        let scan = Engine::default().with_pruning(false);
        // The tree's traversal compiled for each kernel of this CPU (the
        // portable one and the SIMD ones) gives the same lists.
        let trees: Vec<Engine> = Kernel::available().into_iter().map(Engine::new).collect();
        for range in [0..n as u64, cut as u64..n as u64 - 500] {
            let b = scan.search_topk(&space, range.clone(), &queries, &params, k).unwrap();
            for t in &trees {
                let a = t.search_topk(&space, range.clone(), &queries, &params, k).unwrap();
                prop_assert_eq!(&a, &b, "kernel {:?}", t.kernel());
            }
            let a = tree.search_topk(&space, range.clone(), &queries, &params, k).unwrap();
            prop_assert_eq!(&a, &b);
            let slack = vec![Slack { absolute: 40, per_mille: 100 }; queries.len()];
            let a = tree.search_near_ties(&space, range.clone(), &queries, &params, k, &slack).unwrap();
            let b = scan.search_near_ties(&space, range, &queries, &params, k, &slack).unwrap();
            prop_assert_eq!(a, b);
        }
        // Split between two searchers under cuts above each query's k-th
        // distance over the whole space (as a master sends them): each part
        // answers only what is below its cut, and the merge is the whole
        // space's top-k.
        let whole = scan.search_topk(&space, 0..n as u64, &queries, &params, k).unwrap();
        let cuts: Vec<u64> = whole
            .iter()
            .enumerate()
            .map(|(q, l)| match q % 3 {
                _ if l.len() < k => u64::MAX,
                0 => l[k - 1].dist + 1,
                1 => l[k - 1].dist + 1 + (seed >> 40) % 50,
                _ => u64::MAX,
            })
            .collect();
        let split = cut as u64 + 1000;
        for engine in [&tree, &scan] {
            let mut merged = vec![Vec::new(); queries.len()];
            for part in [0..split, split..n as u64] {
                let lists = engine
                    .search_topk_below(&space, part.clone(), &queries, &params, k, &cuts)
                    .unwrap();
                for (q, l) in lists.iter().enumerate() {
                    prop_assert!(l.iter().all(|h| h.dist < cuts[q] && part.contains(&h.index)));
                    merged[q] = texsyn_engine::merge_topk(&merged[q], l, k);
                }
            }
            prop_assert_eq!(&merged, &whole);
        }
        prop_assert!(tree.search_topk_below(&space, 0..10, &queries, &params, k, &cuts[1..]).is_err());
    }
}
