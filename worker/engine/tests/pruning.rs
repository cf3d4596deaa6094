//! The pruned search equals exhaustive search (ARCHITECTURE §3.5): with and
//! without bounds and coherence candidates, on random vectors and on a real
//! texture level, L1 and L2 with masks, every kernel, 1, 2 and 4 threads and
//! any split of the index range into parts searched apart (as workers do),
//! alone or linked.

use proptest::prelude::*;
use texsyn_engine::{
    check_linked_part, check_part, distance, merge_answers, with_bounds, Engine, Geometry, Hit,
    Kernel, Layout, Link, Metric, Params, Plane, QueryBatch, Sample, VectorSpace, Weights,
};

/// Exhaustive answers by the scalar reference, one distance at a time.
fn brute(space: &VectorSpace, batch: &QueryBatch, params: &Params) -> Vec<Hit> {
    (0..batch.len())
        .map(|q| {
            (space.start()..space.end())
                .map(|i| Hit {
                    index: i,
                    dist: distance(
                        &space.layout(),
                        params,
                        &space.vector(i).unwrap(),
                        batch.values(q),
                        batch.mask(q),
                    ),
                })
                .min_by_key(Hit::key)
                .unwrap()
        })
        .collect()
}

/// Per query: candidates (some outside the space) and, if `bounded`, a bound
/// that is the exact hit of one index (as a master computes it).
fn hint(batch: &mut QueryBatch, space: &VectorSpace, params: &Params, picks: &[(u64, bool)]) {
    let n = space.len() as u64;
    for q in 0..batch.len() {
        let (seed, bounded) = picks[q % picks.len()];
        let cands: Vec<u64> = (0..4).map(|k| (seed * 7 + k * 13) % (n + 3)).collect();
        batch.set_candidates(q, cands);
        if bounded {
            let index = (seed * 31 + 5) % n;
            let dist = distance(
                &space.layout(),
                params,
                &space.vector(index).unwrap(),
                batch.values(q),
                batch.mask(q),
            );
            batch.set_bound(q, Hit { index, dist });
        }
    }
}

/// Searches `0..n` as parts cut at `cuts`, checks every part as the master
/// checks a worker's answer, and merges them with the bounds.
fn search_in_parts(
    engine: &Engine,
    space: &VectorSpace,
    batch: &QueryBatch,
    params: &Params,
    cuts: &[u64],
) -> Vec<Hit> {
    let n = space.len() as u64;
    let mut edges: Vec<u64> = cuts.iter().map(|c| c % n).filter(|&c| c > 0).collect();
    edges.push(0);
    edges.push(n);
    edges.sort_unstable();
    edges.dedup();
    let parts: Vec<Vec<Hit>> = edges
        .windows(2)
        .map(|w| {
            let part = engine
                .search_best(space, w[0]..w[1], batch, params)
                .unwrap();
            check_part(&part, batch.bounds(), &(w[0]..w[1])).unwrap();
            part
        })
        .collect();
    let refs: Vec<&[Hit]> = parts.iter().map(Vec::as_slice).collect();
    with_bounds(batch.bounds(), &merge_answers(batch.len(), &refs))
}

/// As [`search_in_parts`], the parts searched at the same time and linked
/// (ARCHITECTURE §4.7); with `told`, the link starts at the exact answers'
/// distances, as if another searcher had reported them before this one began.
fn search_linked(
    engine: &Engine,
    space: &VectorSpace,
    batch: &QueryBatch,
    params: &Params,
    cuts: &[u64],
    told: Option<&[Hit]>,
) -> Vec<Hit> {
    let n = space.len() as u64;
    let mut edges: Vec<u64> = cuts.iter().map(|c| c % n).filter(|&c| c > 0).collect();
    edges.extend([0, n]);
    edges.sort_unstable();
    edges.dedup();
    let link = Link::new(batch.len());
    for (q, h) in told.unwrap_or_default().iter().enumerate() {
        link.lower(q, h.dist);
    }
    let parts: Vec<Vec<Hit>> = std::thread::scope(|s| {
        let tasks: Vec<_> = edges
            .windows(2)
            .map(|w| {
                let link = &link;
                s.spawn(move || {
                    let (part, _) = engine
                        .search_best_linked(space, w[0]..w[1], batch, params, Some(link))
                        .unwrap();
                    check_linked_part(&part, batch.bounds(), &(w[0]..w[1])).unwrap();
                    part
                })
            })
            .collect();
        tasks.into_iter().map(|t| t.join().unwrap()).collect()
    });
    let refs: Vec<&[Hit]> = parts.iter().map(Vec::as_slice).collect();
    let merged = with_bounds(batch.bounds(), &merge_answers(batch.len(), &refs));
    for (q, h) in merged.iter().enumerate() {
        assert!(
            link.get(q) >= h.dist,
            "the link never holds less than the answer"
        );
    }
    merged
}

fn params_of(l2: bool, whi: u32, wlo: u32) -> Params {
    Params {
        metric: if l2 { Metric::L2 } else { Metric::L1 },
        weights: Weights::new(whi, wlo).unwrap(),
    }
}

fn pool(threads: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn pruned_search_equals_brute_force_on_random_vectors(
        (hi, lo) in (1usize..130, prop_oneof![Just(0usize), 1usize..70]),
        n in 1usize..300,
        nq in 1usize..19,
        levels in prop_oneof![Just(4u16), Just(256u16)],
        density in 0.05f64..=1.0,
        seed in any::<u64>(),
        l2 in any::<bool>(),
        (whi, wlo) in (1u32..5, 0u32..5),
        picks in proptest::collection::vec((any::<u64>(), any::<bool>()), 1..6),
        cuts in proptest::collection::vec(any::<u64>(), 0..4),
        lo_full in any::<bool>(),
    ) {
        let d = hi + lo;
        let mut x = seed | 1;
        let mut next = move || { x ^= x << 13; x ^= x >> 7; x ^= x << 17; x };
        let raw: Vec<u8> = (0..n * d).map(|_| (next() % u64::from(levels)) as u8).collect();
        let layout = Layout::new(hi, lo);
        let space = VectorSpace::from_unpadded(layout, 0, &raw).unwrap();
        let params = params_of(l2, whi, wlo);
        let mut batch = QueryBatch::new(layout);
        for _ in 0..nq {
            let v: Vec<u8> = (0..d).map(|_| (next() % u64::from(levels)) as u8).collect();
            // With `lo_full` every lo component is defined, as on every level
            // below the coarsest: the key-ordered window search takes those.
            let m: Vec<u8> = (0..d)
                .map(|i| u8::from((lo_full && i >= hi) || (next() % 1000) as f64 / 1000.0 < density))
                .collect();
            batch.push(&v, &m).unwrap();
        }
        let expect = brute(&space, &batch, &params);
        let mut hinted = batch.clone();
        hint(&mut hinted, &space, &params, &picks);
        for k in Kernel::available() {
            let e = Engine::new(k).with_min_chunk(7);
            for threads in [1, 2, 4] {
                pool(threads).install(|| {
                    let plain = with_bounds(batch.bounds(), &e.search_best(&space, 0..n as u64, &batch, &params).unwrap());
                    assert_eq!(plain, expect, "{} unbounded, {threads} threads", k.name());
                    let got = search_in_parts(&e, &space, &hinted, &params, &cuts);
                    assert_eq!(got, expect, "{} with bounds and candidates, {threads} threads, cuts {cuts:?}", k.name());
                    let linked = search_linked(&e, &space, &hinted, &params, &cuts, None);
                    assert_eq!(linked, expect, "{} linked parts, {threads} threads, cuts {cuts:?}", k.name());
                    let told = search_linked(&e, &space, &batch, &params, &cuts, Some(&expect));
                    assert_eq!(told, expect, "{} parts told the answers' distances, {threads} threads, cuts {cuts:?}", k.name());
                });
            }
        }
    }
}

/// A real texture level: vectors of a photo's luminance with its parent level,
/// queries cut from other places of it with the masks growth synthesis makes
/// (a block-sized hole, a side not yet grown, a parent window the canvas
/// border cuts) and bounds from nearby positions.
#[test]
fn pruned_search_equals_brute_force_on_a_real_level() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../assets/textures/gravel_gray_500.png"
    );
    let img = image::open(path).unwrap().to_luma8();
    let (w, h) = (120usize, 120usize);
    let fine: Vec<u8> = (0..h)
        .flat_map(|y| (0..w).map(move |x| (y, x)))
        .map(|(y, x)| img.get_pixel(x as u32 + 200, y as u32 + 150)[0])
        .collect();
    let parent: Vec<u8> = (0..h / 2)
        .flat_map(|y| (0..w / 2).map(move |x| (y, x)))
        .map(|(y, x)| img.get_pixel(x as u32 * 2 + 200, y as u32 * 2 + 150)[0])
        .collect();
    let geometry = Geometry::new(11, 7).unwrap();
    let sample = Sample {
        fine: Plane::new(w, h, &fine, None).unwrap(),
        parent: Some(Plane::new(w / 2, h / 2, &parent, None).unwrap()),
    };
    let total = texsyn_engine::plane::reference_positions(&sample, &geometry)
        .unwrap()
        .len() as u64;
    let space = VectorSpace::build(&sample, &geometry, 0..total).unwrap();
    let layout = geometry.layout();
    let n = space.len() as u64;
    for l2 in [false, true] {
        let params = params_of(l2, 1, 2);
        let mut batch = QueryBatch::new(layout);
        let mut raw = Vec::new();
        for q in 0..24u64 {
            raw.clear();
            layout.unpad_into(&space.vector((q * 977 + 11) % n).unwrap(), &mut raw);
            let mask: Vec<u8> = (0..layout.dims())
                .map(|i| {
                    let (x, y) = (i % 11, i / 11);
                    let hole = i < 121 && (3..8).contains(&x) && (3..8).contains(&y);
                    let side = i < 121 && q % 3 == 1 && x > 5;
                    // A parent window the canvas border cuts: its right
                    // columns unknown, the rest a rectangle.
                    let border = i >= 121 && q % 4 == 3 && (i - 121) % 7 >= 5;
                    u8::from(!(hole || side || border))
                })
                .collect();
            // Perturb the values so the exact vector is not in the space.
            for (k, v) in raw.iter_mut().enumerate() {
                *v = v.saturating_add(((q as usize * 7 + k) % 5) as u8);
            }
            batch.push(&raw, &mask).unwrap();
            batch.set_candidates(
                batch.len() - 1,
                vec![(q * 977 + 12) % n, (q * 977 + 10) % n],
            );
        }
        let expect = brute(&space, &batch, &params);
        // Threads that spin between searches take the same work: the same
        // answers, search after search, and the spinning ends by itself.
        let spinning = Engine::default()
            .with_min_chunk(64)
            .with_spin(std::time::Duration::from_millis(2));
        pool(4).install(|| {
            for _ in 0..20 {
                let got = with_bounds(
                    batch.bounds(),
                    &spinning.search_best(&space, 0..n, &batch, &params).unwrap(),
                );
                assert_eq!(got, expect, "spinning between searches, l2={l2}");
            }
        });
        let t = std::time::Instant::now();
        while texsyn_engine::spin::spinning() > 0 {
            assert!(
                t.elapsed() < std::time::Duration::from_secs(5),
                "threads still spinning 5 s after the last search"
            );
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        for k in Kernel::available() {
            for threads in [1, 2, 4] {
                let e = Engine::new(k).with_min_chunk(64);
                let got = pool(threads)
                    .install(|| search_in_parts(&e, &space, &batch, &params, &[n / 3, n / 2]));
                assert_eq!(got, expect, "{} {} threads l2={l2}", k.name(), threads);
                for told in [None, Some(expect.as_slice())] {
                    let linked = pool(threads).install(|| {
                        search_linked(&e, &space, &batch, &params, &[n / 3, n / 2], told)
                    });
                    assert_eq!(
                        linked,
                        expect,
                        "{} {threads} threads l2={l2} linked",
                        k.name()
                    );
                }
            }
        }
        // Pruning did its job on real data: most pairs were abandoned early.
        let (_, stats) = Engine::default()
            .search_best_counted(&space, 0..n, &batch, &params)
            .unwrap();
        assert!(
            stats.pairs_skipped() > 0.5 || Engine::default().kernel() == Kernel::Scalar,
            "{stats:?}"
        );
    }
}
