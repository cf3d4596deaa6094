//! Properties of the search engine: every SIMD kernel equals the scalar
//! reference, batched = one at a time, answers independent of threads and
//! splits, ties to the lowest index, and bad input is an error.

use proptest::prelude::*;
use texsyn_engine::{
    distance, Engine, Geometry, Hit, Kernel, Layout, Metric, Params, Plane, QueryBatch, Sample,
    Slack, VectorSpace, Weights,
};

#[derive(Debug, Clone)]
struct Case {
    hi: usize,
    lo: usize,
    vectors: Vec<u8>,
    queries: Vec<u8>,
    masks: Vec<u8>,
    params: Params,
}

impl Case {
    fn layout(&self) -> Layout {
        Layout::new(self.hi, self.lo)
    }
    fn space(&self) -> VectorSpace {
        VectorSpace::from_unpadded(self.layout(), 0, &self.vectors).unwrap()
    }
    fn batch(&self) -> QueryBatch {
        let d = self.hi + self.lo;
        let mut b = QueryBatch::new(self.layout());
        for (q, m) in self.queries.chunks(d).zip(self.masks.chunks(d)) {
            b.push(q, m).unwrap();
        }
        b
    }
    fn single(&self, q: usize) -> QueryBatch {
        let d = self.hi + self.lo;
        let mut b = QueryBatch::new(self.layout());
        b.push(
            &self.queries[q * d..(q + 1) * d],
            &self.masks[q * d..(q + 1) * d],
        )
        .unwrap();
        b
    }
}

/// Random vectors; a small value alphabet (`levels`) makes ties common, a full
/// one exercises the saturating paths of the kernels.
fn case() -> impl Strategy<Value = Case> {
    (
        1usize..200,
        prop_oneof![Just(0usize), 1usize..70],
        1usize..45,
        1usize..21,
        prop_oneof![Just(3u16), Just(256u16)],
        0.01f64..=1.0,
    )
        .prop_flat_map(|(hi, lo, n, nq, levels, density)| {
            let d = hi + lo;
            (
                Just((hi, lo)),
                proptest::collection::vec(0u16..levels, n * d),
                proptest::collection::vec(0u16..levels, nq * d),
                proptest::collection::vec(proptest::bool::weighted(density), nq * d),
                0u32..=Weights::MAX,
                1u32..=Weights::MAX,
                prop_oneof![Just(Metric::L1), Just(Metric::L2)],
            )
        })
        .prop_map(|((hi, lo), v, q, m, wlo, whi, metric)| Case {
            hi,
            lo,
            vectors: v.iter().map(|&x| x as u8).collect(),
            queries: q.iter().map(|&x| x as u8).collect(),
            masks: m.iter().map(|&b| u8::from(b)).collect(),
            params: Params {
                metric,
                weights: Weights::new(whi, wlo).unwrap(),
            },
        })
}

fn reference_matrix(c: &Case) -> Vec<u64> {
    let (space, batch) = (c.space(), c.batch());
    let n = space.len();
    let mut out = vec![0; n * batch.len()];
    for q in 0..batch.len() {
        for i in 0..n {
            out[q * n + i] = distance(
                &c.layout(),
                &c.params,
                &space.vector(i as u64).unwrap(),
                batch.values(q),
                batch.mask(q),
            );
        }
    }
    out
}

fn brute_best(c: &Case) -> Vec<Hit> {
    let m = reference_matrix(c);
    let n = c.space().len();
    m.chunks(n)
        .map(|row| {
            let (i, &d) = row
                .iter()
                .enumerate()
                .min_by_key(|&(i, &d)| (d, i))
                .unwrap();
            Hit {
                index: i as u64,
                dist: d,
            }
        })
        .collect()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(160))]

    #[test]
    fn every_kernel_equals_scalar_reference(c in case()) {
        let reference = reference_matrix(&c);
        let (space, batch) = (c.space(), c.batch());
        for k in Kernel::available() {
            let m = Engine::new(k).distance_matrix(&space, 0..space.end(), &batch, &c.params).unwrap();
            prop_assert_eq!(&m, &reference, "kernel {}", k.name());
        }
    }

    #[test]
    fn best_and_topk_match_brute_force_for_every_kernel(c in case(), k in 1usize..6, chunk in 1usize..9) {
        let expect = brute_best(&c);
        let (space, batch) = (c.space(), c.batch());
        let matrix = reference_matrix(&c);
        let n = space.len();
        for kern in Kernel::available() {
            let e = Engine::new(kern).with_min_chunk(chunk);
            let best = e.search_best(&space, 0..space.end(), &batch, &c.params).unwrap();
            prop_assert_eq!(&best, &expect);
            let top = e.search_topk(&space, 0..space.end(), &batch, &c.params, k).unwrap();
            for (q, list) in top.iter().enumerate() {
                let mut all: Vec<(u64, u64)> = (0..n).map(|i| (matrix[q * n + i], i as u64)).collect();
                all.sort();
                let want: Vec<Hit> = all.iter().take(k).map(|&(dist, index)| Hit { index, dist }).collect();
                prop_assert_eq!(list, &want);
            }
        }
    }

    /// Near-ties: the brute-force top-k less what is farther than the slack
    /// from the best, whatever coherence candidates cut the search.
    #[test]
    fn near_ties_are_the_topk_within_the_slack(
        c in case(),
        k in 1usize..8,
        absolute in 0u64..400,
        per_mille in 0u32..600,
        seed in 0u64..1000,
    ) {
        let (space, mut batch) = (c.space(), c.batch());
        let matrix = reference_matrix(&c);
        let n = space.len();
        for q in 0..batch.len() {
            let cands = (0..3).map(|j| (seed + 7 * q as u64 + 13 * j) % n as u64).collect();
            batch.set_candidates(q, cands);
        }
        let slack = vec![Slack { absolute, per_mille }; batch.len()];
        for kern in Kernel::available() {
            let e = Engine::new(kern);
            let near = e
                .search_near_ties(&space, 0..space.end(), &batch, &c.params, k, &slack)
                .unwrap();
            for (q, list) in near.iter().enumerate() {
                let mut all: Vec<(u64, u64)> = (0..n).map(|i| (matrix[q * n + i], i as u64)).collect();
                all.sort();
                let limit = slack[q].limit(all[0].0);
                let want: Vec<Hit> = all
                    .iter()
                    .take(k)
                    .filter(|&&(d, _)| d <= limit)
                    .map(|&(dist, index)| Hit { index, dist })
                    .collect();
                prop_assert_eq!(list, &want, "kernel {}", kern.name());
            }
        }
    }

    #[test]
    fn batched_equals_one_at_a_time(c in case()) {
        let (space, batch) = (c.space(), c.batch());
        for kern in Kernel::available() {
            let e = Engine::new(kern);
            let all = e.search_best(&space, 0..space.end(), &batch, &c.params).unwrap();
            for (q, hit) in all.iter().enumerate() {
                let one = e.search_best(&space, 0..space.end(), &c.single(q), &c.params).unwrap();
                prop_assert_eq!(&one[0], hit);
            }
        }
    }

    #[test]
    fn any_subrange_split_merges_to_the_same_answer(c in case(), cut in 0.0f64..1.0) {
        let (space, batch) = (c.space(), c.batch());
        let n = space.end();
        let mid = ((n as f64 * cut) as u64).clamp(1, n);
        let e = Engine::default();
        let whole = e.search_best(&space, 0..n, &batch, &c.params).unwrap();
        let mut merged = e.search_best(&space, 0..mid, &batch, &c.params).unwrap();
        if mid < n {
            let right = e.search_best(&space, mid..n, &batch, &c.params).unwrap();
            texsyn_engine::merge_best(&mut merged, &right);
        }
        prop_assert_eq!(merged, whole);
    }
}

fn big_case(n: usize, nq: usize, seed: u64) -> Case {
    // Deterministic pseudo-random data with many ties (values 0..4).
    let mut x = seed;
    let mut next = || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x
    };
    let (hi, lo) = (81, 25);
    let d = hi + lo;
    Case {
        hi,
        lo,
        vectors: (0..n * d).map(|_| (next() % 4) as u8).collect(),
        queries: (0..nq * d).map(|_| (next() % 4) as u8).collect(),
        masks: (0..nq * d).map(|_| u8::from(next() % 3 != 0)).collect(),
        params: Params {
            metric: Metric::L1,
            weights: Weights::new(3, 2).unwrap(),
        },
    }
}

#[test]
fn results_identical_with_1_2_and_4_threads() {
    let c = big_case(20_000, 37, 7);
    let (space, batch) = (c.space(), c.batch());
    let mut answers = Vec::new();
    for threads in [1, 2, 4] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        for chunk in [1000, 4096] {
            let e = Engine::default().with_min_chunk(chunk);
            let best = pool.install(|| {
                e.search_best(&space, 0..space.end(), &batch, &c.params)
                    .unwrap()
            });
            let top = pool.install(|| {
                e.search_topk(&space, 0..space.end(), &batch, &c.params, 4)
                    .unwrap()
            });
            answers.push((best, top));
        }
    }
    assert!(answers.windows(2).all(|w| w[0] == w[1]));
    assert_eq!(answers[0].0, brute_best(&c));
}

#[test]
fn ties_go_to_the_lowest_index() {
    let layout = Layout::new(40, 9);
    let d = layout.dims();
    // 5000 vectors, the same pattern repeated every 100: every query ties 50 times.
    let raw: Vec<u8> = (0..5000 * d)
        .map(|i| ((i / d) % 100 * 2 + i % 7) as u8)
        .collect();
    let space = VectorSpace::from_unpadded(layout, 0, &raw).unwrap();
    let mut batch = QueryBatch::new(layout);
    for q in [3usize, 42, 99, 17, 0, 64, 5, 88, 23] {
        batch.push_full(&raw[q * d..(q + 1) * d]).unwrap();
    }
    for k in Kernel::available() {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap();
        let best = pool.install(|| {
            Engine::new(k)
                .with_min_chunk(64)
                .search_best(&space, 0..space.end(), &batch, &Params::default())
                .unwrap()
        });
        let got: Vec<u64> = best.iter().map(|h| h.index).collect();
        assert_eq!(
            got,
            vec![3, 42, 99, 17, 0, 64, 5, 88, 23],
            "kernel {}",
            k.name()
        );
        assert!(best.iter().all(|h| h.dist == 0));
    }
}

#[test]
fn bad_input_is_an_error_not_a_panic() {
    let layout = Layout::new(25, 9);
    let space = VectorSpace::from_unpadded(layout, 10, &vec![1u8; 34 * 20]).unwrap();
    let mut batch = QueryBatch::new(layout);
    assert!(
        batch.push(&[0u8; 33], &[1u8; 33]).is_err(),
        "values of the wrong length"
    );
    assert!(
        batch.push(&[0u8; 34], &[1u8; 30]).is_err(),
        "mask of the wrong size"
    );
    let e = Engine::default();
    let p = Params::default();
    assert!(
        e.search_best(&space, 10..30, &batch, &p).is_err(),
        "empty batch"
    );
    batch.push_full(&[0u8; 34]).unwrap();
    assert!(
        e.search_best(&space, 10..10, &batch, &p).is_err(),
        "empty range"
    );
    assert!(
        e.search_best(&space, 5..20, &batch, &p).is_err(),
        "range before the space"
    );
    assert!(
        e.search_best(&space, 10..31, &batch, &p).is_err(),
        "range past the space"
    );
    assert!(
        e.search_topk(&space, 10..30, &batch, &p, 0).is_err(),
        "k = 0"
    );
    let mut other = QueryBatch::new(Layout::new(25, 0));
    other.push_full(&[0u8; 25]).unwrap();
    assert!(
        e.search_best(&space, 10..30, &other, &p).is_err(),
        "layout mismatch"
    );
    assert!(
        VectorSpace::from_unpadded(layout, 0, &[1u8; 35]).is_err(),
        "ragged raw vectors"
    );
    assert!(Layout::checked(0, 5).is_err());
    // Geometry that does not match the planes.
    let px = vec![0u8; 100];
    let plane = Plane::new(10, 10, &px, None).unwrap();
    let g = Geometry::new(5, 3).unwrap();
    assert!(VectorSpace::build(
        &Sample {
            fine: plane,
            parent: None
        },
        &g,
        0..1
    )
    .is_err());
    let g = Geometry::new(3, 0).unwrap();
    assert!(VectorSpace::build(
        &Sample {
            fine: plane,
            parent: None
        },
        &g,
        0..65
    )
    .is_err());
    assert!(Plane::new(10, 9, &px, None).is_err());
    assert!(Plane::new(0, 0, &[], None).is_err());
    assert!(Kernel::from_name("sse9").is_err());
}

#[test]
fn built_vectors_hold_the_window_and_parent_pixels() {
    let (w, h) = (12, 10);
    let px: Vec<u8> = (0..w * h).map(|i| (i * 7 % 251) as u8).collect();
    let (pw, ph) = (6, 5);
    let ppx: Vec<u8> = (0..pw * ph).map(|i| (200 - i) as u8).collect();
    let sample = Sample {
        fine: Plane::new(w, h, &px, None).unwrap(),
        parent: Some(Plane::new(pw, ph, &ppx, None).unwrap()),
    };
    let g = Geometry::new(3, 3).unwrap();
    let all = texsyn_engine::layout::reference_positions(&sample, &g).unwrap();
    let space = VectorSpace::build(&sample, &g, 0..all.len() as u64).unwrap();
    let l = g.layout();
    for (i, p) in all.iter().enumerate() {
        let (x, y) = (p[0] as usize, p[1] as usize);
        let v = &space.vector(i as u64).unwrap();
        assert_eq!(v[4], px[y * w + x], "centre pixel");
        assert_eq!(v[0], px[(y - 1) * w + x - 1]);
        assert_eq!(v[l.hi_pad + 4], ppx[(y / 2) * pw + x / 2], "parent centre");
        assert!(
            v[l.hi_len..l.hi_pad].iter().all(|&b| b == 0),
            "padding is zero"
        );
    }
}
