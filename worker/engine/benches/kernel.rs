//! Criterion benchmark of the exact best-1 search, per available kernel.
//!
//! * `flat_240000x192`: 240 000 random u8 vectors of 192 components, every query
//!   component defined; one query and a batch of 64.
//! * `synth_11x7_240000`: the synthesis layout of `Geometry::new(11, 7)`
//!   (121 + 49 components, padded to 128 + 64 bytes) with per-query masks that
//!   define ~60 % of the components; one query and a batch of 64.
//!
//! Throughput is the padded vector bytes scanned × queries, so criterion's
//! GB/s is the effective rate over all threads (rayon's global pool; set
//! `RAYON_NUM_THREADS` to change it). Sample counts and times are kept small
//! so the whole run takes about 1–2 minutes on 2 cores:
//!
//!     cargo bench -p texsyn-engine --bench kernel [-- <filter>]

use std::hint::black_box;
use std::time::Duration;

use criterion::{
    criterion_group, criterion_main, BenchmarkId, Criterion, SamplingMode, Throughput,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use texsyn_engine::{Engine, Geometry, Kernel, Layout, Params, QueryBatch, VectorSpace};

const VECTORS: usize = 240_000;
const DIMS: usize = 192;
const BATCH: usize = 64;

/// A vector space with one single-query batch and one batch of `BATCH` queries.
struct Case {
    space: VectorSpace,
    single: QueryBatch,
    batch: QueryBatch,
}

impl Case {
    /// Random vectors in `layout`; each query component is defined with
    /// probability `defined`.
    fn random(layout: Layout, defined: f64, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let d = layout.dims();
        let mut raw = vec![0u8; VECTORS * d];
        rng.fill(&mut raw[..]);
        let space = VectorSpace::from_unpadded(layout, 0, &raw).expect("vector space");
        drop(raw);
        let query = |rng: &mut ChaCha8Rng| {
            let mut values = vec![0u8; d];
            rng.fill(&mut values[..]);
            let mask: Vec<u8> = (0..d).map(|_| u8::from(rng.random_bool(defined))).collect();
            (values, mask)
        };
        let mut single = QueryBatch::new(layout);
        let (v, m) = query(&mut rng);
        single.push(&v, &m).expect("query");
        let mut batch = QueryBatch::new(layout);
        for _ in 0..BATCH {
            let (v, m) = query(&mut rng);
            batch.push(&v, &m).expect("query");
        }
        Self {
            space,
            single,
            batch,
        }
    }
}

fn bench_case(c: &mut Criterion, name: &str, case: &Case) {
    let params = Params::default();
    let range = case.space.start()..case.space.end();
    let kernels = Kernel::available();

    // Every kernel must give the scalar reference's answer (cheap: one query).
    let reference = Engine::new(Kernel::Scalar)
        .search_best(&case.space, range.clone(), &case.single, &params)
        .expect("scalar search");
    for &k in &kernels {
        let hits = Engine::new(k)
            .search_best(&case.space, range.clone(), &case.single, &params)
            .expect("search");
        assert_eq!(hits, reference, "{} disagrees with scalar", k.name());
    }

    let mut g = c.benchmark_group(name);
    g.sample_size(10)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(2))
        .sampling_mode(SamplingMode::Flat);
    for &kernel in &kernels {
        let engine = Engine::new(kernel);
        for (mode, queries) in [("single", &case.single), ("batch64", &case.batch)] {
            g.throughput(Throughput::Bytes(
                (case.space.bytes() * queries.len()) as u64,
            ));
            g.bench_with_input(
                BenchmarkId::new(mode, kernel.name()),
                queries,
                |b, queries| {
                    b.iter(|| {
                        engine
                            .search_best(black_box(&case.space), range.clone(), queries, &params)
                            .expect("search")
                    })
                },
            );
        }
    }
    g.finish();
}

fn flat(c: &mut Criterion) {
    let layout = Layout::checked(DIMS, 0).expect("layout");
    let case = Case::random(layout, 1.0, 1);
    bench_case(c, &format!("flat_{VECTORS}x{DIMS}"), &case);
}

fn synthesis(c: &mut Criterion) {
    let geometry = Geometry::new(11, 7).expect("geometry");
    let case = Case::random(geometry.layout(), 0.6, 2);
    bench_case(c, &format!("synth_11x7_{VECTORS}"), &case);
}

criterion_group!(benches, flat, synthesis);
criterion_main!(benches);
