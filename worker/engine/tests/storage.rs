//! A plane-backed space (vectors gathered block by block as they are scanned)
//! gives the kernels the same bytes as a dense one, so every search answers
//! the same (ARCHITECTURE §3.3): random planes with holes, neighbourhoods
//! from 1×1 to wider than one 16-byte piece, any sub-range, 1 and 2 threads.

use proptest::prelude::*;
use texsyn_engine::plane::reference_positions;
use texsyn_engine::{
    Engine, Geometry, Kernel, Metric, Params, Plane, QueryBatch, Sample, Storage, VectorSpace,
    Weights,
};

/// The padded vector of (x, y) written out pixel by pixel: the hi window,
/// zeros to `hi_pad`, the parent window, zeros to the stride.
fn reference_vector(sample: &Sample, g: &Geometry, x: usize, y: usize) -> Vec<u8> {
    let layout = g.layout();
    let mut v = vec![0u8; layout.stride()];
    let (r, f) = (g.radius() as isize, &sample.fine);
    let mut k = 0;
    for dy in -r..=r {
        for dx in -r..=r {
            let (xx, yy) = ((x as isize + dx) as usize, (y as isize + dy) as usize);
            v[k] = f.pixels[yy * f.width + xx];
            k += 1;
        }
    }
    if let Some(p) = &sample.parent {
        let pr = g.parent_radius() as isize;
        let mut k = layout.hi_pad;
        for dy in -pr..=pr {
            for dx in -pr..=pr {
                let (xx, yy) = ((x / 2) as isize + dx, (y / 2) as isize + dy);
                v[k] = p.pixels[yy as usize * p.width + xx as usize];
                k += 1;
            }
        }
    }
    v
}

fn noise(seed: u64, len: usize) -> Vec<u8> {
    let mut x = seed | 1;
    (0..len)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 24) as u8
        })
        .collect()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn planes_and_dense_spaces_answer_the_same(
        (w, h) in (24usize..80, 24usize..70),
        n in prop_oneof![Just(1usize), Just(3), Just(5), Just(11), Just(19)],
        m in prop_oneof![Just(0usize), Just(1), Just(3), Just(7), Just(17)],
        holes in proptest::collection::vec((0usize..80, 0usize..70), 0..3),
        seed in any::<u64>(),
        (a, b) in (0.0f64..0.5, 0.5f64..=1.0),
        l2 in any::<bool>(),
        lo_kind in 0u8..3,
        (r0, r1, c0, c1) in (0usize..17, 0usize..17, 0usize..17, 0usize..17),
        threads in 1usize..=2,
    ) {
        let fine = noise(seed, w * h);
        let parent = noise(seed ^ 0x9e37, (w / 2) * (h / 2));
        let mut defined = vec![1u8; w * h];
        for &(hx, hy) in &holes {
            defined[(hy % h) * w + hx % w] = 0;
        }
        let g = Geometry::new(n, m).unwrap();
        let sample = Sample {
            fine: Plane::new(w, h, &fine, Some(&defined)).unwrap(),
            parent: (m > 0).then(|| Plane::new(w / 2, h / 2, &parent, None).unwrap()),
        };
        let positions = reference_positions(&sample, &g).unwrap();
        let total = positions.len() as u64;
        prop_assume!(total > 0);
        let range = (total as f64 * a) as u64..((total as f64 * b) as u64).max(1).max((total as f64 * a) as u64 + 1).min(total);
        prop_assume!(range.start < range.end);
        let dense = VectorSpace::build_with(&sample, &g, &positions, range.clone(), Storage::Dense).unwrap();
        let planes = VectorSpace::build_with(&sample, &g, &positions, range.clone(), Storage::Planes).unwrap();
        prop_assert_eq!(dense.storage(), Storage::Dense);
        prop_assert_eq!(planes.storage(), Storage::Planes);
        for i in range.clone() {
            let [x, y] = positions.get(i).unwrap();
            let want = reference_vector(&sample, &g, x as usize, y as usize);
            prop_assert_eq!(&*dense.vector(i).unwrap(), &want[..], "dense vector {}", i);
            prop_assert_eq!(&*planes.vector(i).unwrap(), &want[..], "plane vector {}", i);
            prop_assert_eq!(planes.position(i), Some([x, y]));
        }
        prop_assert!(planes.vector(range.end).is_none());

        // Queries: perturbed vectors of the level, some components masked out.
        let layout = g.layout();
        let mut batch = QueryBatch::new(layout);
        let mut raw = Vec::new();
        for q in 0..7u64 {
            let i = range.start + (q * 131 + seed % 97) % (range.end - range.start);
            raw.clear();
            layout.unpad_into(&planes.vector(i).unwrap(), &mut raw);
            let extra = noise(seed ^ q, raw.len());
            let mut mask = vec![1u8; raw.len()];
            for (k, v) in raw.iter_mut().enumerate() {
                *v = v.wrapping_add(extra[k] % 9);
                // Parent components: random (0), all defined (1), or a
                // rectangle of the window (2), as at a canvas border. A
                // dense space searches full ones by key windows, a
                // plane-backed one full ones and rectangles.
                mask[k] = u8::from(!extra[k].is_multiple_of(5));
                if k >= n * n && lo_kind > 0 {
                    let (r, c) = ((k - n * n) / m, (k - n * n) % m);
                    let inside = |a: usize, b: usize, i: usize| a.min(b) % m <= i && i <= a.max(b) % m;
                    mask[k] = u8::from(lo_kind == 1 || (inside(r0, r1, r) && inside(c0, c1, c)));
                }
            }
            batch.push(&raw, &mask).unwrap();
            batch.set_candidates(q as usize, vec![i, i + 1]);
        }
        let params = Params {
            metric: if l2 { Metric::L2 } else { Metric::L1 },
            weights: Weights::new(1, 2).unwrap(),
        };
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        for k in Kernel::available() {
            let e = Engine::new(k).with_min_chunk(300);
            pool.install(|| {
                let r = range.clone();
                assert_eq!(
                    e.distance_matrix(&planes, r.clone(), &batch, &params).unwrap(),
                    e.distance_matrix(&dense, r.clone(), &batch, &params).unwrap(),
                    "{} distances", k.name()
                );
                // The answers, not the pruning figures: a dense space walks
                // key-ordered windows, a plane-backed one sweeps its keys in
                // index order; both equal the unpruned scan.
                let exhaustive = e.with_pruning(false);
                let want = exhaustive.search_best(&dense, r.clone(), &batch, &params).unwrap();
                assert_eq!(
                    e.search_best(&planes, r.clone(), &batch, &params).unwrap(),
                    want,
                    "{} best on planes", k.name()
                );
                assert_eq!(
                    e.search_best(&dense, r.clone(), &batch, &params).unwrap(),
                    want,
                    "{} best dense", k.name()
                );
                assert_eq!(
                    e.search_topk(&planes, r.clone(), &batch, &params, 3).unwrap(),
                    e.search_topk(&dense, r, &batch, &params, 3).unwrap(),
                    "{} top 3", k.name()
                );
            });
        }
    }
}

#[test]
fn auto_storage_is_dense_until_the_limit() {
    use texsyn_engine::space::DENSE_LIMIT;
    assert_eq!(Storage::Auto.resolve(1 << 20, None), Storage::Dense);
    assert_eq!(
        Storage::Auto.resolve(DENSE_LIMIT + 1, None),
        Storage::Planes
    );
    assert_eq!(
        Storage::Auto.resolve(1 << 20, Some(1 << 20)),
        Storage::Planes
    );
    assert_eq!(Storage::Planes.resolve(1, None), Storage::Planes);
    assert_eq!(Storage::Dense.resolve(u64::MAX, Some(0)), Storage::Dense);
    assert!(Storage::from_name("disk").is_err());
    assert_eq!(Storage::from_name("Planes").unwrap(), Storage::Planes);
}
