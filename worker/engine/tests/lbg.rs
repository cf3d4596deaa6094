//! Properties of the LBG codebook (Stahlhut §8, ARCHITECTURE §3.8): probing every
//! partition gives exactly the exhaustive answer, every vector lies in exactly
//! one partition, training is deterministic across runs and thread counts,
//! Hamerly pruning changes nothing, and bad input is an error.

use proptest::prelude::*;
use texsyn_engine::lbg::{check_probes, check_threshold, default_seeds};
use texsyn_engine::{
    distance, Codebook, Engine, Geometry, Hit, Kernel, Layout, LbgConfig, Metric, Params, Plane,
    QueryBatch, Sample, VectorSpace, Weights,
};

/// Deterministic xorshift stream.
fn stream(seed: u64) -> impl FnMut() -> u64 {
    let mut x = seed.max(1);
    move || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x
    }
}

/// `n` vectors around `centres` cluster centres (values 0..=255, clamped noise)
/// and `nq` queries with random masks.
fn clustered(
    layout: Layout,
    n: usize,
    nq: usize,
    centres: usize,
    seed: u64,
) -> (VectorSpace, QueryBatch) {
    let d = layout.dims();
    let mut next = stream(seed);
    let c: Vec<u8> = (0..centres * d).map(|_| (next() % 256) as u8).collect();
    let mut raw = Vec::with_capacity(n * d);
    for _ in 0..n {
        let k = (next() % centres as u64) as usize;
        for j in 0..d {
            let noise = (next() % 41) as i32 - 20;
            raw.push((i32::from(c[k * d + j]) + noise).clamp(0, 255) as u8);
        }
    }
    let space = VectorSpace::from_unpadded(layout, 0, &raw).unwrap();
    let mut batch = QueryBatch::new(layout);
    for _ in 0..nq {
        let v: Vec<u8> = (0..d).map(|_| (next() % 256) as u8).collect();
        let m: Vec<u8> = (0..d)
            .map(|_| u8::from(!next().is_multiple_of(4)))
            .collect();
        batch.push(&v, &m).unwrap();
    }
    (space, batch)
}

fn params(metric: Metric, hi: u32, lo: u32) -> Params {
    Params {
        metric,
        weights: Weights::new(hi, lo).unwrap(),
    }
}

/// Everything that defines a trained codebook, for equality checks.
/// Seeds, partitions, iterations, displacements, re-seeded cells.
type Fingerprint = (Vec<Vec<u8>>, Vec<Vec<u64>>, usize, Vec<u64>, usize);

fn fingerprint(cb: &Codebook) -> Fingerprint {
    let seeds = (0..cb.seeds())
        .map(|j| cb.seed(j).unwrap().to_vec())
        .collect();
    let parts = (0..cb.seeds())
        .map(|j| cb.partition(j).unwrap().to_vec())
        .collect();
    let s = cb.stats();
    (
        seeds,
        parts,
        s.iterations,
        s.displacement.clone(),
        s.reseeded,
    )
}

fn assert_partitions_cover(cb: &Codebook) {
    let r = cb.range();
    let mut seen = vec![0u8; (r.end - r.start) as usize];
    for j in 0..cb.seeds() {
        let p = cb.partition(j).unwrap();
        assert!(!p.is_empty(), "partition {j} is empty");
        assert!(p.windows(2).all(|w| w[0] < w[1]), "partition {j} unsorted");
        for &g in p {
            assert!(r.contains(&g), "index {g} outside {r:?}");
            seen[(g - r.start) as usize] += 1;
        }
    }
    assert!(
        seen.iter().all(|&c| c == 1),
        "a vector is in 0 or ≥2 partitions"
    );
    assert!(cb.partition(cb.seeds()).is_none());
}

#[derive(Debug, Clone)]
struct Case {
    hi: usize,
    lo: usize,
    vectors: Vec<u8>,
    queries: Vec<u8>,
    masks: Vec<u8>,
    params: Params,
    start: u64,
    seeds: usize,
    seed: u64,
}

fn case() -> impl Strategy<Value = Case> {
    (
        1usize..120,
        prop_oneof![Just(0usize), 1usize..40],
        1usize..300,
        1usize..20,
        prop_oneof![Just(3u16), Just(256u16)],
        0.05f64..=1.0,
    )
        .prop_flat_map(|(hi, lo, n, nq, levels, density)| {
            let d = hi + lo;
            (
                Just((hi, lo, n)),
                proptest::collection::vec(0u16..levels, n * d),
                proptest::collection::vec(0u16..levels, nq * d),
                proptest::collection::vec(proptest::bool::weighted(density), nq * d),
                0u32..=64,
                1u32..=64,
                prop_oneof![Just(Metric::L1), Just(Metric::L2)],
                0u64..1000,
                0usize..=n,
                any::<u64>(),
            )
        })
        .prop_map(
            |((hi, lo, _n), v, q, m, wlo, whi, metric, start, seeds, seed)| Case {
                hi,
                lo,
                vectors: v.iter().map(|&x| x as u8).collect(),
                queries: q.iter().map(|&x| x as u8).collect(),
                masks: m.iter().map(|&b| u8::from(b)).collect(),
                params: params(metric, whi, wlo),
                start,
                seeds,
                seed,
            },
        )
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// With P = seeds LBG searches every partition, so it must return exactly
    /// the exhaustive answer (distance and lowest index) for every kernel.
    #[test]
    fn all_probes_equal_exhaustive(c in case()) {
        let layout = Layout::new(c.hi, c.lo);
        let d = layout.dims();
        let space = VectorSpace::from_unpadded(layout, c.start, &c.vectors).unwrap();
        let mut batch = QueryBatch::new(layout);
        for (q, m) in c.queries.chunks(d).zip(c.masks.chunks(d)) {
            batch.push(q, m).unwrap();
        }
        for k in Kernel::available() {
            let e = Engine::new(k).with_min_chunk(7);
            let cfg = LbgConfig { seeds: c.seeds, seed: c.seed, max_iterations: 8, ..LbgConfig::default() };
            let cb = Codebook::train(&e, &space, space.start()..space.end(), &c.params, &cfg).unwrap();
            assert_partitions_cover(&cb);
            let exact = e.search_best(&space, space.start()..space.end(), &batch, &c.params).unwrap();
            let got = cb.search(&e, &batch, cb.seeds_requested()).unwrap();
            prop_assert_eq!(&got, &exact, "kernel {}", k.name());
            // P = 1: a real vector with its true distance, never better than exact.
            for (qi, (h, x)) in cb.search(&e, &batch, 1).unwrap().iter().zip(&exact).enumerate() {
                prop_assert!(h.dist >= x.dist);
                let v = space.vector(h.index).unwrap();
                prop_assert_eq!(h.dist, distance(&layout, &c.params, &v, batch.values(qi), batch.mask(qi)));
            }
        }
    }

    /// Hamerly pruning is exact: it trains the same codebook as brute force.
    #[test]
    fn pruned_training_equals_brute_force(c in case()) {
        let layout = Layout::new(c.hi, c.lo);
        let space = VectorSpace::from_unpadded(layout, c.start, &c.vectors).unwrap();
        let e = Engine::default();
        let p = Params { metric: Metric::L1, ..c.params };
        let cfg = LbgConfig { seeds: c.seeds, seed: c.seed, max_iterations: 12, ..LbgConfig::default() };
        let a = Codebook::train(&e, &space, space.start()..space.end(), &p, &cfg).unwrap();
        let b = Codebook::train(&e, &space, space.start()..space.end(), &p, &LbgConfig { prune: false, ..cfg }).unwrap();
        prop_assert_eq!(fingerprint(&a), fingerprint(&b));
    }
}

#[test]
fn clustered_data_full_probe_is_exact_and_partitions_cover() {
    let layout = Geometry::new(9, 5).unwrap().layout();
    let (space, batch) = clustered(layout, 6000, 45, 40, 3);
    let e = Engine::default();
    let p = params(Metric::L1, 1, 2);
    let cb = Codebook::train(&e, &space, 0..space.end(), &p, &LbgConfig::default()).unwrap();
    assert_eq!(cb.seeds_requested(), default_seeds(6000));
    assert_eq!(default_seeds(6000), 78);
    assert_partitions_cover(&cb);
    let s = cb.stats();
    assert!(s.iterations >= 1 && s.displacement.len() == s.iterations);
    let exact = e.search_best(&space, 0..space.end(), &batch, &p).unwrap();
    assert_eq!(cb.search(&e, &batch, cb.seeds_requested()).unwrap(), exact);
    // More probes never give a worse answer.
    let mut prev: Option<Vec<Hit>> = None;
    for probes in [1, 2, 4, 16] {
        let got = cb.search(&e, &batch, probes).unwrap();
        if let Some(pv) = &prev {
            for (a, b) in got.iter().zip(pv) {
                assert!(a.key() <= b.key());
            }
        }
        prev = Some(got);
    }
}

#[test]
fn a_sub_range_codebook_answers_with_global_indices() {
    let layout = Layout::new(30, 9);
    let (space, batch) = clustered(layout, 3000, 20, 12, 11);
    let e = Engine::default();
    let p = params(Metric::L1, 2, 1);
    // Two "workers" each quantise their own range; merging gives the exact answer
    // with all probes.
    let a = Codebook::train(&e, &space, 0..1234, &p, &LbgConfig::default()).unwrap();
    let b = Codebook::train(&e, &space, 1234..3000, &p, &LbgConfig::default()).unwrap();
    assert_partitions_cover(&a);
    assert_partitions_cover(&b);
    let mut got = a.search(&e, &batch, a.seeds_requested()).unwrap();
    texsyn_engine::merge_best(
        &mut got,
        &b.search(&e, &batch, b.seeds_requested()).unwrap(),
    );
    assert_eq!(got, e.search_best(&space, 0..3000, &batch, &p).unwrap());
    for h in b.search(&e, &batch, 1).unwrap() {
        assert!((1234..3000).contains(&h.index));
    }
}

#[test]
fn training_is_deterministic_across_runs_and_threads() {
    let layout = Geometry::new(11, 7).unwrap().layout();
    let (space, batch) = clustered(layout, 20_000, 37, 60, 5);
    for metric in [Metric::L1, Metric::L2] {
        let p = params(metric, 1, 2);
        let cfg = LbgConfig {
            seed: 42,
            ..LbgConfig::default()
        };
        let mut runs = Vec::new();
        for threads in [1, 2, 4, 2] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let e = Engine::default();
            let (fp, answers) = pool.install(|| {
                let cb = Codebook::train(&e, &space, 0..space.end(), &p, &cfg).unwrap();
                assert_partitions_cover(&cb);
                let answers: Vec<Vec<Hit>> = [1, 2, 4]
                    .iter()
                    .map(|&pr| cb.search(&e, &batch, pr).unwrap())
                    .collect();
                (fingerprint(&cb), answers)
            });
            runs.push((fp, answers));
        }
        assert!(
            runs.windows(2).all(|w| w[0] == w[1]),
            "{metric:?}: training or answers differ between runs / thread counts"
        );
        // A different seed gives a different codebook (the seed is really used).
        let other = Codebook::train(
            &Engine::default(),
            &space,
            0..space.end(),
            &p,
            &LbgConfig { seed: 43, ..cfg },
        )
        .unwrap();
        assert_ne!(fingerprint(&other).0, runs[0].0 .0);
    }
}

#[test]
fn every_kernel_trains_the_same_codebook() {
    let layout = Layout::new(50, 20);
    let (space, batch) = clustered(layout, 2500, 19, 15, 9);
    let p = params(Metric::L1, 3, 1);
    let mut fps = Vec::new();
    for k in Kernel::available() {
        let e = Engine::new(k);
        let cb = Codebook::train(&e, &space, 0..space.end(), &p, &LbgConfig::default()).unwrap();
        fps.push((fingerprint(&cb), cb.search(&e, &batch, 2).unwrap()));
    }
    assert!(fps.windows(2).all(|w| w[0] == w[1]));
}

#[test]
fn identical_vectors_leave_no_empty_partition() {
    // 500 copies of 3 distinct vectors: most seeds collapse; empty cells are
    // re-seeded or dropped, never kept empty.
    let layout = Layout::new(16, 0);
    let raw: Vec<u8> = (0..500 * 16).map(|i| ((i / 16) % 3 * 50) as u8).collect();
    let space = VectorSpace::from_unpadded(layout, 0, &raw).unwrap();
    let e = Engine::default();
    let p = Params::default();
    let cb = Codebook::train(&e, &space, 0..500, &p, &LbgConfig::default()).unwrap();
    assert_partitions_cover(&cb);
    assert!(cb.seeds() <= 3 && cb.seeds() >= 1, "{} seeds", cb.seeds());
    let mut batch = QueryBatch::new(layout);
    batch.push_full(&raw[16..32]).unwrap();
    batch.push_full(&raw[32..48]).unwrap();
    // Ties go to the lowest index: vector 1 and 2 are the first of their kind.
    let all = cb.search(&e, &batch, cb.seeds_requested()).unwrap();
    assert_eq!(
        all,
        vec![Hit { index: 1, dist: 0 }, Hit { index: 2, dist: 0 }]
    );
    // Even a probe count above the surviving seeds (but within those drawn) works.
    assert_eq!(cb.search(&e, &batch, 1).unwrap(), all);
}

#[test]
fn codebook_over_a_real_level() {
    // A synthetic "texture" with a parent level, built like the synthesis does.
    let (w, h) = (96, 80);
    let mut next = stream(77);
    let px: Vec<u8> = (0..w * h)
        .map(|i| (((i % w) * 7 + (i / w) * 3) % 200) as u8 + (next() % 40) as u8)
        .collect();
    let ppx: Vec<u8> = (0..(w / 2) * (h / 2))
        .map(|i| ((i * 13) % 255) as u8)
        .collect();
    let sample = Sample {
        fine: Plane::new(w, h, &px, None).unwrap(),
        parent: Some(Plane::new(w / 2, h / 2, &ppx, None).unwrap()),
    };
    let g = Geometry::new(9, 5).unwrap();
    let space = VectorSpace::build(&sample, &g, 0..(w as u64 - 8) * (h as u64 - 8)).unwrap();
    let e = Engine::default();
    let p = params(Metric::L1, 1, 2);
    let cb = Codebook::train(&e, &space, 0..space.end(), &p, &LbgConfig::default()).unwrap();
    assert_partitions_cover(&cb);
    let mut batch = QueryBatch::new(g.layout());
    for i in [0u64, 17, 500, 4000] {
        let v = space.vector(i).unwrap();
        let l = g.layout();
        let mut raw = v[..l.hi_len].to_vec();
        raw.extend_from_slice(&v[l.hi_pad..l.hi_pad + l.lo_len]);
        let mask: Vec<u8> = (0..l.dims()).map(|j| u8::from(j % 3 != 1)).collect();
        batch.push(&raw, &mask).unwrap();
    }
    let exact = e.search_best(&space, 0..space.end(), &batch, &p).unwrap();
    assert_eq!(cb.search(&e, &batch, cb.seeds_requested()).unwrap(), exact);
}

#[test]
fn bad_input_is_an_error_not_a_panic() {
    let layout = Layout::new(20, 4);
    let (space, batch) = clustered(layout, 400, 3, 5, 1);
    let e = Engine::default();
    let p = Params::default();
    let ok = LbgConfig::default();
    let train = |cfg: &LbgConfig, r: std::ops::Range<u64>| Codebook::train(&e, &space, r, &p, cfg);
    for t in [0.0, 1.0, -0.5, 1.5, f64::NAN, f64::INFINITY] {
        assert!(
            train(&LbgConfig { threshold: t, ..ok }, 0..400).is_err(),
            "threshold {t}"
        );
        assert!(check_threshold(t).is_err());
    }
    assert!(check_threshold(0.05).is_ok());
    assert!(train(
        &LbgConfig {
            max_iterations: 0,
            ..ok
        },
        0..400
    )
    .is_err());
    assert!(
        train(&LbgConfig { seeds: 401, ..ok }, 0..400).is_err(),
        "more seeds than vectors"
    );
    assert!(train(&ok, 0..0).is_err(), "empty range");
    assert!(train(&ok, 10..401).is_err(), "range past the space");
    let cb = train(&ok, 0..400).unwrap();
    assert_eq!(cb.seeds_requested(), 20);
    assert!(cb.search(&e, &batch, 0).is_err(), "0 probes");
    assert!(cb.search(&e, &batch, 21).is_err(), "more probes than seeds");
    assert!(cb.search(&e, &batch, 20).is_ok());
    assert!(check_probes(0, 5).is_err() && check_probes(6, 5).is_err());
    assert!(check_probes(5, 5).is_ok());
    assert!(
        cb.search(&e, &QueryBatch::new(layout), 1).is_err(),
        "empty batch"
    );
    let mut other = QueryBatch::new(Layout::new(20, 0));
    other.push_full(&[0u8; 20]).unwrap();
    assert!(cb.search(&e, &other, 1).is_err(), "layout mismatch");
    let msg = cb.search(&e, &batch, 21).unwrap_err().to_string();
    assert!(msg.contains("21") && msg.contains("20"), "{msg}");
}
