//! End-to-end properties of the synthesis on real textures (ARCHITECTURE §3):
//! determinism across threads and batch sizes, fill never touching known
//! pixels, copy-map consistency and seamless tiling.

use crate::common;

use common::{run, seam, texture};
use texsyn::block::Silent;
use texsyn::imaging::colour as ycbcr;
use texsyn::imaging::ColorImage;
use texsyn::search::{LevelData, LocalSearch, SearchBackend};
use texsyn::{synthesize, Config, Mode, Output, Position, SynthMethod};
use texsyn_engine::{Engine, Hit, Kernel, Metric, QueryBatch};

/// Every output pixel is the colour-sample pixel its copy-map entry names.
fn assert_copy_map_consistent(out: &Output, sample: &ColorImage) {
    let (w, h) = (out.image.width, out.image.height);
    assert_eq!(out.copy_map.len(), w * h);
    for y in 0..h {
        for x in 0..w {
            let [sx, sy] = out.copy_map[y * w + x];
            assert_eq!(
                out.image.get(x, y),
                sample.get(sx as usize, sy as usize),
                "pixel ({x},{y}) does not match its copy-map source ({sx},{sy})"
            );
        }
    }
}

#[test]
fn output_is_identical_for_1_and_2_threads_and_repeated_runs_for_every_batch_size() {
    let sample = texture("brick_color_96.png");
    let mode = Mode::Synth {
        width: 120,
        height: 100,
        method: SynthMethod::Grow,
    };
    let mut per_k = Vec::new();
    for batch in [1, 4, 16, 64] {
        let cfg = Config {
            batch,
            seed: 11,
            ..Config::default()
        };
        let a = run(&sample, &mode, &cfg, 1);
        let b = run(&sample, &mode, &cfg, 2);
        let c = run(&sample, &mode, &cfg, 2);
        assert_eq!(a.image, b.image, "K={batch}: 1 vs 2 threads");
        assert_eq!(a.copy_map, b.copy_map, "K={batch}: copy map 1 vs 2 threads");
        assert_eq!(b.image, c.image, "K={batch}: repeated run");
        assert_copy_map_consistent(&a, &sample);
        per_k.push(a.image);
    }
    // Different seeds give different textures (the seed is really used).
    let other = run(
        &sample,
        &mode,
        &Config {
            seed: 12,
            ..Config::default()
        },
        2,
    );
    assert_ne!(other.image, per_k[2]);
}

#[test]
fn fill_never_changes_a_defined_pixel() {
    let sample = texture("pink_marble_color_128.png");
    let (w, h) = (sample.width, sample.height);
    // Two rectangular holes and a diagonal stroke.
    let holes: Vec<bool> = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            (20..44).contains(&x) && (30..50).contains(&y)
                || (80..110).contains(&x) && (70..90).contains(&y)
                || (x as isize - y as isize).abs() < 3 && (50..120).contains(&x)
        })
        .collect();
    for batch in [1, 16] {
        let cfg = Config {
            batch,
            ..Config::default()
        };
        let out = run(
            &sample,
            &Mode::Fill {
                holes: holes.clone(),
                source: None,
            },
            &cfg,
            2,
        );
        for (i, &hole) in holes.iter().enumerate() {
            let (x, y) = (i % w, i / w);
            if !hole {
                assert_eq!(
                    out.image.get(x, y),
                    sample.get(x, y),
                    "known pixel ({x},{y}) changed"
                );
                assert_eq!(out.copy_map[i], [x as u32, y as u32]);
            }
        }
        assert_copy_map_consistent(&out, &sample);
        // Filled pixels come from known sample pixels, never from inside a hole.
        for (i, &hole) in holes.iter().enumerate() {
            if hole {
                let [sx, sy] = out.copy_map[i];
                assert!(
                    !holes[sy as usize * w + sx as usize],
                    "hole pixel copied from a hole"
                );
            }
        }
    }
}

#[test]
fn extend_keeps_the_sample_where_it_was_placed() {
    let sample = texture("brick_color_96.png");
    let mode = Mode::Extend {
        width: 160,
        height: 128,
        position: Position::At(32, 16),
    };
    let out = run(&sample, &mode, &Config::default(), 2);
    for y in 0..sample.height {
        for x in 0..sample.width {
            assert_eq!(out.image.get(x + 32, y + 16), sample.get(x, y));
        }
    }
    assert_copy_map_consistent(&out, &sample);
}

#[test]
fn tileable_output_has_no_seam() {
    for (name, mode) in [
        (
            "pink_marble_color_128.png",
            Mode::Extend {
                width: 200,
                height: 176,
                position: Position::Center,
            },
        ),
        (
            "cracked_color_144.png",
            Mode::Synth {
                width: 160,
                height: 160,
                method: SynthMethod::Grow,
            },
        ),
    ] {
        let sample = texture(name);
        let cfg = Config {
            tileable: true,
            ..Config::default()
        };
        let out = run(&sample, &mode, &cfg, 2);
        // The step across the wrap-around edge must look like a step inside the
        // image: no larger than the largest of the interior column (row) steps,
        // which include the places where two growing fronts met.
        for transpose in [false, true] {
            let (wrap, max, mean) = seam(&out.image, transpose);
            assert!(
                wrap <= max,
                "{name}: seam {wrap:.2} across the wrap edge exceeds every interior step (max {max:.2}, mean {mean:.2}); transpose={transpose}"
            );
        }
        // The same statistic really sees a seam: a plain (not tileable)
        // extension of the same size has its wrap edge far above the interior.
        if let Mode::Extend { .. } = mode {
            let plain = run(&sample, &mode, &Config::default(), 2);
            let (wrap, max, _) = seam(&plain.image, false);
            assert!(
                wrap > max,
                "control: a plain output should show a seam ({wrap:.2} vs max {max:.2})"
            );
        }
    }
}

#[test]
fn scanline_full_synthesis_is_deterministic_and_consistent() {
    let sample = texture("pink_marble_color_128.png");
    let mode = Mode::Synth {
        width: 96,
        height: 80,
        method: SynthMethod::Scanline,
    };
    let cfg = Config {
        seed: 5,
        ..Config::default()
    };
    let a = run(&sample, &mode, &cfg, 1);
    let b = run(&sample, &mode, &cfg, 2);
    assert_eq!(a.image, b.image);
    assert_copy_map_consistent(&a, &sample);
}

#[test]
fn texture_mixing_uses_the_level_sample() {
    let coarse = texture("pink_marble_color_128.png");
    let detail = texture("cracked_color_144.png");
    let cfg = Config {
        levels: 2,
        level_samples: vec![(0, detail.clone())],
        ..Config::default()
    };
    let out = run(
        &coarse,
        &Mode::Synth {
            width: 96,
            height: 96,
            method: SynthMethod::Grow,
        },
        &cfg,
        2,
    );
    // Colour comes from the finest level's sample: the detail texture.
    assert_eq!(out.sample_size, [detail.width, detail.height]);
    assert_copy_map_consistent(&out, &detail);
    assert_eq!(
        out.report.per_level[1].sample,
        [detail.width, detail.height]
    );
}

#[test]
fn l2_metric_and_weights_run_and_are_deterministic() {
    let sample = texture("brick_color_96.png");
    let cfg = Config {
        metric: texsyn_engine::Metric::L2,
        weights: texsyn_engine::Weights::new(3, 1).unwrap(),
        block: 5,
        neighbourhood: 11,
        ..Config::default()
    };
    let mode = Mode::Synth {
        width: 100,
        height: 100,
        method: SynthMethod::Grow,
    };
    let a = run(&sample, &mode, &cfg, 1);
    let b = run(&sample, &mode, &cfg, 2);
    assert_eq!(a.image, b.image);
    assert_copy_map_consistent(&a, &sample);
}

#[test]
fn colour_search_tells_apart_colours_of_equal_luminance() {
    // Left half green, right half red, both of luminance 95; a hole in the red half.
    let (w, h) = (96usize, 64usize);
    let (green, red) = ([50u8, 127, 50], [200u8, 50, 50]);
    assert_eq!(ycbcr::luma(50, 127, 50), ycbcr::luma(200, 50, 50));
    let mut rgb = Vec::with_capacity(w * h * 3);
    for _y in 0..h {
        for x in 0..w {
            rgb.extend_from_slice(if x < w / 2 { &green } else { &red });
        }
    }
    let sample = ColorImage::from_vec(w, h, rgb);
    let holes: Vec<bool> = (0..w * h)
        .map(|i| (66..80).contains(&(i % w)) && (20..40).contains(&(i / w)))
        .collect();
    let fill = Mode::Fill {
        holes: holes.clone(),
        source: None,
    };
    let colour = Config {
        colour_search: true,
        levels: 2,
        ..Config::default()
    };
    let a = run(&sample, &fill, &colour, 1);
    let b = run(&sample, &fill, &colour, 2);
    assert_eq!(a.image, b.image, "colour search: 1 vs 2 threads");
    assert_copy_map_consistent(&a, &sample);
    for (i, &hole) in holes.iter().enumerate() {
        if hole {
            assert_eq!(
                a.image.get(i % w, i / w),
                red,
                "colour search filled ({}, {}) wrongly",
                i % w,
                i / w
            );
        }
    }
    // Luminance alone cannot tell the halves apart (all distances tie, the
    // lowest index wins): the control fills green into the red half.
    let lum = run(
        &sample,
        &fill,
        &Config {
            levels: 2,
            ..Config::default()
        },
        2,
    );
    let greens = holes
        .iter()
        .enumerate()
        .filter(|&(i, &hole)| hole && lum.image.get(i % w, i / w) == green)
        .count();
    assert!(
        greens > 0,
        "control: luminance search should confuse the colours"
    );
}

/// The search before pruning: no bounds, no coherence candidates and the scalar
/// kernel, which scores every component of every vector.
struct Unpruned(LocalSearch);

impl SearchBackend for Unpruned {
    fn name(&self) -> String {
        "unpruned".into()
    }
    fn load_level(&mut self, level: &LevelData) -> anyhow::Result<()> {
        self.0.load_level(level)
    }
    fn search(&mut self, queries: &QueryBatch) -> anyhow::Result<Vec<Hit>> {
        self.0.search(&queries.without_hints())
    }
    fn end_level(&mut self) {
        self.0.end_level()
    }
}

/// Pruned search (bounds from coherence candidates, partial distance
/// elimination in the fastest kernel) gives byte-identical syntheses to the
/// unpruned exhaustive search: fill with masks, tileable extend, growth and
/// scan-line synthesis, L1 and L2.
#[test]
fn pruned_search_gives_the_same_synthesis_as_unpruned_exhaustive_search() {
    let sample = texture("brick_color_96.png");
    let (w, h) = (sample.width, sample.height);
    let holes: Vec<bool> = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            (20..44).contains(&x) && (30..50).contains(&y) || (x + y) % 37 < 2 && x > 50
        })
        .collect();
    let cases = [
        (
            Mode::Fill {
                holes,
                source: None,
            },
            Metric::L1,
            false,
        ),
        (
            Mode::Extend {
                width: 130,
                height: 120,
                position: Position::Center,
            },
            Metric::L1,
            true,
        ),
        (
            Mode::Synth {
                width: 110,
                height: 90,
                method: SynthMethod::Grow,
            },
            Metric::L2,
            false,
        ),
        (
            Mode::Synth {
                width: 80,
                height: 80,
                method: SynthMethod::Scanline,
            },
            Metric::L1,
            false,
        ),
    ];
    for (mode, metric, tileable) in cases {
        let cfg = Config {
            metric,
            tileable,
            ..Config::default()
        };
        let pruned = run(&sample, &mode, &cfg, 2);
        let mut reference = Unpruned(LocalSearch::new(Engine::new(Kernel::Scalar)));
        let unpruned = synthesize(&sample, &mode, &cfg, &mut reference, &Silent).unwrap();
        assert_eq!(pruned.image, unpruned.image, "{metric:?} {tileable}");
        assert_eq!(pruned.copy_map, unpruned.copy_map, "{metric:?} {tileable}");
        let skipped = pruned
            .report
            .per_level
            .last()
            .unwrap()
            .pairs_skipped
            .unwrap();
        eprintln!("{metric:?} tileable={tileable}: finest level pairs skipped {skipped:.3}");
        assert!(skipped > 0.1, "finest level pruned only {skipped}");
    }
}

/// Pixels of the output per copy offset (output position minus source).
fn patch_sizes(out: &Output) -> std::collections::HashMap<[i64; 2], usize> {
    let w = out.image.width;
    let mut sizes = std::collections::HashMap::new();
    for (i, &[sx, sy]) in out.copy_map.iter().enumerate() {
        let offset = [
            (i % w) as i64 - i64::from(sx),
            (i / w) as i64 - i64::from(sy),
        ];
        *sizes.entry(offset).or_insert(0) += 1;
    }
    sizes
}

/// `synth` growth to 192×192 stitched by path, the setting the patch cap and
/// the lattice tests compare against.
fn grown_to_192() -> (Mode, Config) {
    let mode = Mode::Synth {
        width: 192,
        height: 192,
        method: SynthMethod::Grow,
    };
    let free = Config {
        stitch: texsyn::Stitch::Path,
        ..Config::default()
    };
    (mode, free)
}

/// The patch cap (ARCHITECTURE §3.13) bounds how much of the output one copy
/// offset covers, so the output repeats the sample less: on a sample at twice
/// its side, the share of pixels in patches over twice the cap falls, and so
/// does the verbatim repeat share; the output stays a consistent copy map and
/// the same over thread counts, and only the two finest levels change.
#[test]
fn the_patch_cap_cuts_large_patches_and_repeats_less() {
    use texsyn::block::RepeatControl;
    use texsyn::compare::repeat_share;
    let sample = texture("brick_color_96.png");
    let (mode, free) = grown_to_192();
    let capped = Config {
        repeats: Some(RepeatControl {
            percent: 60,
            cap: Some(20),
            ..RepeatControl::default()
        }),
        ..free.clone()
    };
    // The cap on the finest level: (20% of the 96-px side)² pixels.
    let cap = 20 * 20;
    let large = |out: &Output| {
        let sizes = patch_sizes(out);
        let n: usize = sizes.values().filter(|&&s| s > 2 * cap).sum();
        n as f64 / out.copy_map.len() as f64
    };
    let a = run(&sample, &mode, &free, 2);
    let b = run(&sample, &mode, &capped, 2);
    let (la, lb) = (large(&a), large(&b));
    let (ra, rb) = (repeat_share(&a.image), repeat_share(&b.image));
    eprintln!("in patches over 2×cap: {la:.3} → {lb:.3}; repeat share {ra:.3} → {rb:.3}");
    assert!(la > 0.3, "without the cap, large patches are common: {la}");
    assert!(lb < la / 2.5, "the cap cuts large patches: {la} → {lb}");
    assert!(rb < ra * 0.75, "the cap repeats less: {ra} → {rb}");
    assert_copy_map_consistent(&b, &sample);
    assert_eq!(
        b.image,
        run(&sample, &mode, &capped, 1).image,
        "1 vs 2 threads"
    );
    // The coarse levels, which lay out the structure, are the exact search's.
    assert!(a.levels.len() > 2, "{} levels", a.levels.len());
    for l in 2..a.levels.len() {
        assert!(
            a.levels[l] == b.levels[l],
            "level {l} changed under the cap"
        );
    }
    assert!(a.levels[1] != b.levels[1], "level 1 is capped");
}

/// A planted grid: `tiles`×`tiles` tiles of `period` px, each a flat colour
/// of its own with a little grain, between 2-px light joints.
fn grid_sample(period: usize, tiles: usize) -> ColorImage {
    let side = period * tiles;
    let hash = |a: usize, b: usize, c: usize| {
        let mut h = (a as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ (b as u64 + 7).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
            ^ (c as u64 + 3).wrapping_mul(0x1656_67B1_9E37_79F9);
        h ^= h >> 29;
        h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
        (h ^ (h >> 32)) as u8
    };
    let mut rgb = Vec::with_capacity(side * side * 3);
    for y in 0..side {
        for x in 0..side {
            let joint = x % period < 2 || y % period < 2;
            for ch in 0..3 {
                let v = if joint {
                    235 - hash(x, y, ch) % 8
                } else {
                    let base = 40 + hash(x / period, y / period, ch) % 150;
                    base + hash(x, y, ch + 3) % 12
                };
                rgb.push(v);
            }
        }
    }
    ColorImage::from_vec(side, side, rgb)
}

/// The share of output pixels whose copy offset lies within a pixel of the
/// most common offset modulo `period` on each axis: 1 for a grid that never
/// slips.
fn in_phase_share(out: &Output, period: usize) -> f64 {
    let w = out.image.width;
    let p = period as i64;
    let phase = |k: usize| {
        let [sx, sy] = out.copy_map[k];
        [
            ((k % w) as i64 - i64::from(sx)).rem_euclid(p),
            ((k / w) as i64 - i64::from(sy)).rem_euclid(p),
        ]
    };
    let mut counts = std::collections::HashMap::<[i64; 2], usize>::new();
    for k in 0..out.copy_map.len() {
        *counts.entry(phase(k)).or_default() += 1;
    }
    let (&mode, _) = counts.iter().max_by_key(|(k, &c)| (c, **k)).unwrap();
    let near = |a: i64, b: i64| {
        let d = (a - b).rem_euclid(p);
        d.min(p - d) <= 1
    };
    let kept = (0..out.copy_map.len())
        .filter(|&k| {
            let ph = phase(k);
            near(ph[0], mode[0]) && near(ph[1], mode[1])
        })
        .count();
    kept as f64 / out.copy_map.len() as f64
}

/// The lattice rule (ARCHITECTURE §3.14) keeps a grid sample's grid: blocks
/// inside a plain tile match anywhere in any tile, so without it the grid
/// slips; with it nearly every output pixel keeps the grid's phase. The
/// output is the same bytes over thread counts, and a wrong period is not
/// what keeps the phase (the rule, not the sample, does it).
#[test]
fn the_lattice_rule_keeps_a_grid_sample_s_grid() {
    let sample = grid_sample(16, 6);
    // The grid is what `--lattice auto` finds.
    let found = texsyn::lattice::detect(&sample).expect("a grid");
    assert!(
        found.period.iter().all(|p| (p - 16.0).abs() < 0.1),
        "{found:?}"
    );
    let (mode, free) = grown_to_192();
    let on_grid = Config {
        lattice: Some(texsyn::block::Lattice {
            period: [16.0, 16.0],
        }),
        ..free.clone()
    };
    let a = run(&sample, &mode, &free, 2);
    let b = run(&sample, &mode, &on_grid, 2);
    let (pa, pb) = (in_phase_share(&a, 16), in_phase_share(&b, 16));
    eprintln!("in phase: {pa:.3} → {pb:.3}");
    assert!(pb > 0.97, "the lattice rule keeps the grid: {pb}");
    assert!(pa < pb - 0.05, "without it the grid slips: {pa} vs {pb}");
    assert_copy_map_consistent(&b, &sample);
    assert_eq!(
        b.image,
        run(&sample, &mode, &on_grid, 1).image,
        "1 vs 2 threads"
    );
    // A period that is not the grid's (and not a multiple of it) keeps
    // another phase, not this one.
    let wrong = Config {
        lattice: Some(texsyn::block::Lattice {
            period: [23.0, 23.0],
        }),
        ..free.clone()
    };
    let pw = in_phase_share(&run(&sample, &mode, &wrong, 2), 16);
    eprintln!("with a wrong period: {pw:.3}");
    assert!(
        pw < pb - 0.05,
        "a wrong period does not keep the grid: {pw} vs {pb}"
    );
}
