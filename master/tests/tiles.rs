//! Somol–Haindl tiles and `texsyn compare` (ARCHITECTURE §7, §8): paths
//! against the optimum, stitches, tile borders, seamless grids, and the
//! similarity measures' defining properties.

use crate::common;

use std::time::{Duration, Instant};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use texsyn::compare;
use texsyn::imaging::ColorImage;
use texsyn::progress::Silent;
use texsyn::seams::{self as path, ErrorMap, Oscillating, Start};
use texsyn::tiles::stitch::{self, Belt, Side, StitchSettings};
use texsyn::tiles::{self, PathSearch, Rect, TileSetSettings};

use common::{ok, refused, texture};

fn crop(img: &ColorImage, x: usize, y: usize, w: usize, h: usize) -> ColorImage {
    img.crop(x, y, w, h)
}

/// A real error map: two random `w`×`h` regions of a texture.
fn real_map(img: &ColorImage, rng: &mut ChaCha8Rng, w: usize, h: usize) -> ErrorMap {
    let (ax, ay) = (
        rng.random_range(0..img.width - w),
        rng.random_range(0..img.height - h),
    );
    let (bx, by) = (
        rng.random_range(0..img.width - w),
        rng.random_range(0..img.height - h),
    );
    let a: Vec<[u8; 3]> = (0..h)
        .flat_map(|j| (0..w).map(move |i| (i, j)))
        .map(|(i, j)| img.get(ax + i, ay + j))
        .collect();
    let b: Vec<[u8; 3]> = (0..h)
        .flat_map(|j| (0..w).map(move |i| (i, j)))
        .map(|(i, j)| img.get(bx + i, by + j))
        .collect();
    ErrorMap::of(w, h, &a, &b)
}

/// One path of the thousand-map test: valid (a control point per row inside
/// the map), connected (the spans of consecutive rows touch), never better
/// than the DP; returns its cost ratio to the optimum.
fn checked_ratio(map: &ErrorMap, p: &path::Path, best: f64) -> f64 {
    assert_eq!(p.c.len(), map.h);
    for j in 0..map.h {
        assert!(p.start(j) <= p.c[j] && p.c[j] < map.w);
        if j > 0 {
            assert!(p.start(j) <= p.c[j - 1] + 1 && p.start(j - 1) <= p.c[j] + 1);
        }
    }
    let a = p.cost(map);
    assert!(a + 1e-6 >= best, "the DP is not optimal: {a} < {best}");
    if best > 0.0 {
        a / best
    } else {
        1.0
    }
}

#[test]
fn oscillating_paths_on_a_thousand_maps_are_valid_and_near_the_optimum() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let textures = [
        texture("coffee_beans_color_512.png"),
        texture("gravel_gray_500.png"),
        texture("brick_color_96.png"),
        texture("leaves_green_color_161.png"),
    ];
    let printed = Oscillating {
        o_max: 8,
        start: Start::RowMinimum,
        ..Oscillating::default()
    };
    let (mut osc_time, mut dp_time) = (Duration::ZERO, Duration::ZERO);
    let (mut ratios, mut printed_ratios) = (Vec::new(), Vec::new());
    let mut worst = (0.0f64, String::new());
    for k in 0..1000 {
        let w = rng.random_range(4..=16);
        let h = rng.random_range(16..=90);
        let (map, kind) = if k % 2 == 0 {
            let t = &textures[k / 2 % textures.len()];
            (real_map(t, &mut rng, w, h), "real")
        } else {
            let e = (0..w * h)
                .map(|_| rng.random_range(0.0..255.0f32))
                .collect();
            (ErrorMap::new(w, h, e), "random")
        };
        let t = Instant::now();
        let p = path::oscillating(&map, Oscillating::default());
        osc_time += t.elapsed();
        let t = Instant::now();
        let best = path::optimal(&map).cost(&map);
        dp_time += t.elapsed();
        let ratio = checked_ratio(&map, &p, best);
        if ratio > worst.0 {
            worst = (ratio, format!("{kind} {w}x{h}"));
        }
        ratios.push(ratio);
        printed_ratios.push(checked_ratio(&map, &path::oscillating(&map, printed), best));
    }
    let mean = |r: &[f64]| r.iter().sum::<f64>() / r.len() as f64;
    let within = |r: &[f64]| r.iter().filter(|&&r| r <= 1.15).count();
    eprintln!(
        "1000 maps: mean cost ratio {:.4}, worst {:.4} ({}), {} within 1.15x; \
         oscillating {osc_time:?}, DP {dp_time:?}, speed-up {:.1}x",
        mean(&ratios),
        worst.0,
        worst.1,
        within(&ratios),
        dp_time.as_secs_f64() / osc_time.as_secs_f64()
    );
    eprintln!(
        "from the paper's start (row minima, o_max 8): mean {:.4}, worst {:.4}, {} within 1.15x",
        mean(&printed_ratios),
        printed_ratios.iter().copied().fold(0.0, f64::max),
        within(&printed_ratios)
    );
    assert_eq!(within(&ratios), 1000, "worst {:.4} ({})", worst.0, worst.1);
    // The paper's start stalls on some maps (its moves are vertical lines),
    // but stays within 15 % of the optimum on average.
    assert!(mean(&printed_ratios) <= 1.15);
}

/// A vertical stitch of R1 (left) over the canvas: right of the path every
/// pixel is R2's; on R1's side farther than ρ from the path every pixel is R1's.
#[test]
fn pixels_beyond_the_path_come_from_r2_and_far_inside_from_r1() {
    let img = texture("coffee_beans_color_512.png");
    let r1 = crop(&img, 10, 20, 40, 64);
    let mut canvas = crop(&img, 200, 300, 40, 64);
    let r2 = canvas.clone();
    let belt = Belt {
        x: 8,
        y: 0,
        across: 16,
        along: 64,
        r1: Side::Left,
    };
    let settings = StitchSettings::default();
    let cut = stitch::stitch(
        &mut canvas,
        &belt,
        |x, y| r1.get(x, y),
        &settings,
        |_, _| true,
    );
    let mut blended = 0;
    for j in 0..64 {
        for i in 0..16 {
            let (x, y) = belt.pixel(i, j);
            if i > cut.path.c[j] {
                assert_eq!(
                    canvas.get(x, y),
                    r2.get(x, y),
                    "({x}, {y}) right of the path"
                );
            } else {
                let far = cut
                    .path
                    .pixels()
                    .all(|(m, n)| ((m.abs_diff(i).pow(2) + n.abs_diff(j).pow(2)) as f32) > 9.0);
                if far {
                    assert_eq!(canvas.get(x, y), r1.get(x, y), "({x}, {y}) far inside R1");
                } else if canvas.get(x, y) != r1.get(x, y) {
                    blended += 1;
                }
            }
        }
    }
    assert!(blended > 0, "the blend changed nothing near the path");
    // Outside the belt nothing changed.
    for y in 0..64 {
        for x in (0..8).chain(24..40) {
            assert_eq!(canvas.get(x, y), r2.get(x, y));
        }
    }
}

fn settings(tiles: usize) -> TileSetSettings {
    TileSetSettings {
        tiles,
        min_size: 80,
        max_size: 100,
        overlap: 10,
        belt: 10,
        margin: 2,
        pull: 0.0,
        max_overlap: 1.0,
        template_candidates: 1,
        ring_weight: 0.0,
        candidates: 24,
        refine: 4,
        path: Default::default(),
        blend: Default::default(),
        seed: 3,
    }
}

#[test]
fn every_tile_keeps_the_template_s_border_strips_and_differs_inside() {
    let sample = texture("coffee_beans_color_512.png");
    let mut s = settings(6);
    let exact = TileSetSettings {
        path: PathSearch::Optimal,
        ..s
    };
    let exact = tiles::make_tile_set(&sample, None, &exact, &Silent).unwrap();
    s.path = PathSearch::Oscillating;
    let set = tiles::make_tile_set(&sample, None, &s, &Silent).unwrap();
    // The same template rectangle; the exact paths cost no more, and the
    // oscillating ones stay within 15 % of them.
    assert_eq!(exact.template.rect, set.template.rect);
    for (e, o) in exact
        .template_path_costs
        .iter()
        .zip(&set.template_path_costs)
    {
        assert!(
            e <= &(o + 1e-6) && *o <= 1.15 * e,
            "optimal {e} oscillating {o}"
        );
    }
    assert_eq!(set.tiles.len(), 6);
    let t0 = &set.tiles[0];
    let (w, h) = (t0.width, t0.height);
    assert!((s.min_size..=s.max_size).contains(&w) && (s.min_size..=s.max_size).contains(&h));
    for (k, t) in set.tiles.iter().enumerate().skip(1) {
        for y in 0..h {
            for x in 0..w {
                let border = x < s.margin || y < s.margin || x >= w - s.margin || y >= h - s.margin;
                if border {
                    assert_eq!(
                        t.get(x, y),
                        t0.get(x, y),
                        "tile {} border ({x}, {y})",
                        k + 1
                    );
                }
            }
        }
        let differ = (0..w * h)
            .filter(|&i| t.get(i % w, i / w) != t0.get(i % w, i / w))
            .count();
        assert!(
            differ > w * h / 2,
            "tile {} changed only {differ} pixels",
            k + 1
        );
        // The chosen patch beats the average random candidate.
        let d = &set.derived[k - 1];
        assert!(
            d.patch.mean_path_error < d.random_mean_path_error,
            "tile {}: chosen {} vs random {}",
            k + 1,
            d.patch.mean_path_error,
            d.random_mean_path_error
        );
    }
}

/// An assembled grid shows no joint: on `compare`'s seam score the tile
/// joints are no worse than the interior. The control — tiles cut straight
/// from the sample — fails the same check.
#[test]
fn an_assembled_grid_has_no_seam_and_raw_crops_do() {
    let sample = texture("gravel_gray_500.png");
    let set = tiles::make_tile_set(&sample, None, &settings(4), &Silent).unwrap();
    let (w, h) = (set.tiles[0].width, set.tiles[0].height);
    let index = tiles::random_index(4, 6, 6, 9);
    let grid = tiles::assemble(&set.tiles, &index).unwrap();
    let cols: Vec<usize> = (0..grid.width).step_by(w).collect();
    let rows: Vec<usize> = (0..grid.height).step_by(h).collect();
    let seam = compare::seam_score(&grid, &cols, &rows);
    eprintln!("tile set grid: {seam:?}");
    assert!(
        seam.joint_step <= seam.interior_p95,
        "joints {} above the interior's 95th percentile {}",
        seam.joint_step,
        seam.interior_p95
    );
    let raw: Vec<ColorImage> = [(0, 0), (200, 40), (60, 300), (390, 390)]
        .iter()
        .map(|&(x, y)| crop(&sample, x, y, w, h))
        .collect();
    let control = tiles::assemble(&raw, &index).unwrap();
    let bad = compare::seam_score(&control, &cols, &rows);
    eprintln!("raw crops grid: {bad:?}");
    assert!(
        bad.joint_step > bad.interior_p95,
        "the control should show its joints: {bad:?}"
    );
}

/// The paper's Fig. 10 layout: 8 tiles in 4×4.
#[test]
fn the_paper_s_index_matrix_assembles_and_bad_ones_are_refused() {
    let sample = texture("gravel_gray_500.png");
    let set = tiles::make_tile_set(&sample, None, &settings(8), &Silent).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("fig10.csv");
    std::fs::write(&csv, "7,6,1,5\n3,7,5,8\n5,1,6,2\n4,3,2,3\n").unwrap();
    let index = tiles::read_index(&csv).unwrap();
    let json = dir.path().join("fig10.json");
    std::fs::write(&json, "[[7,6,1,5],[3,7,5,8],[5,1,6,2],[4,3,2,3]]").unwrap();
    assert_eq!(tiles::read_index(&json).unwrap(), index);
    let grid = tiles::assemble(&set.tiles, &index).unwrap();
    let (w, h) = (set.tiles[0].width, set.tiles[0].height);
    assert_eq!((grid.width, grid.height), (4 * w, 4 * h));
    // Row 2, column 4 is tile 8.
    assert_eq!(grid.get(3 * w + 5, h + 7), set.tiles[7].get(5, 7));
    assert!(tiles::assemble(&set.tiles, &[vec![9]]).is_err());
    assert!(tiles::assemble(&set.tiles, &[vec![1, 2], vec![3]]).is_err());
    assert!(tiles::assemble(&set.tiles, &[vec![0]]).is_err());
}

/// A template given by the user (here a crop; any seamless tile works) is
/// kept as tile 1, and the derived tiles keep its borders.
#[test]
fn a_given_template_is_used_as_it_is() {
    let sample = texture("coffee_beans_color_512.png");
    let template = crop(&sample, 100, 100, 90, 90);
    let set = tiles::make_tile_set(&sample, Some(&template), &settings(3), &Silent).unwrap();
    assert_eq!(set.tiles[0], template);
    let r = set.derived[0].patch.target;
    assert_eq!(
        r,
        Rect {
            x: 2,
            y: 2,
            width: 86,
            height: 86
        }
    );
}

/// Circular shift by (dx, dy).
fn roll(img: &ColorImage, dx: usize, dy: usize) -> ColorImage {
    let mut out = ColorImage::new(img.width, img.height);
    for y in 0..img.height {
        for x in 0..img.width {
            out.set((x + dx) % img.width, (y + dy) % img.height, img.get(x, y));
        }
    }
    out
}

#[test]
fn compare_scores_have_their_defining_properties() {
    let beans = texture("coffee_beans_color_512.png");
    let gravel = texture("gravel_gray_500.png");
    let t = crop(&beans, 0, 0, 128, 128);
    let same = compare::compare(&t, &t).unwrap();
    assert!((same.s_f - 1.0).abs() < 1e-12, "S_F(T, T) = {}", same.s_f);
    assert_eq!(same.s_l, 0.0);
    assert_eq!(same.colour, 0.0);
    assert_eq!(same.patch_fidelity, 0.0);
    let shifted = compare::spectrum_similarity(&t, &roll(&t, 37, 81)).unwrap();
    assert!(
        (shifted - 1.0).abs() < 1e-9,
        "S_F under a circular shift: {shifted}"
    );
    // Two crops of one texture score better than two textures.
    let other_crop = crop(&beans, 300, 280, 128, 128);
    let other_texture = crop(&gravel, 100, 100, 128, 128);
    let near = compare::compare(&t, &other_crop).unwrap();
    let far = compare::compare(&t, &other_texture).unwrap();
    eprintln!("two crops: {near:?}\ntwo textures: {far:?}");
    assert!(near.s_f > far.s_f);
    assert!(near.s_l < far.s_l);
    assert!(near.colour < far.colour);
    assert!(near.patch_fidelity < far.patch_fidelity);
}

/// Patch fidelity from the engine equals a brute-force scalar search.
#[test]
fn patch_fidelity_matches_a_scalar_reference() {
    let beans = texture("coffee_beans_color_512.png");
    let a = crop(&beans, 10, 10, 40, 33);
    let b = crop(&beans, 200, 90, 25, 31);
    let (la, lb) = (
        texsyn::imaging::colour::luminance(&a),
        texsyn::imaging::colour::luminance(&b),
    );
    let mut total = 0u64;
    let mut n = 0u64;
    for y in (0..=lb.height - 7).step_by(3) {
        for x in (0..=lb.width - 7).step_by(3) {
            let mut best = u64::MAX;
            for v in 0..=la.height - 7 {
                for u in 0..=la.width - 7 {
                    let mut d = 0u64;
                    for j in 0..7 {
                        for i in 0..7 {
                            let e =
                                i64::from(lb.get(x + i, y + j)) - i64::from(la.get(u + i, v + j));
                            d += (e * e) as u64;
                        }
                    }
                    best = best.min(d);
                }
            }
            total += best;
            n += 1;
        }
    }
    let expected = (total as f64 / (n * 49) as f64).sqrt();
    let got = compare::patch_fidelity(&a, &b).unwrap();
    assert!(
        (got - expected).abs() < 1e-9,
        "engine {got} vs scalar {expected}"
    );
}

/// The command line end to end: make, assemble by the paper's index matrix
/// and at random, compare; bad input is refused with the fix named.
#[test]
fn tiles_and_compare_on_the_command_line() {
    use common::s;
    let dir = tempfile::tempdir().unwrap();
    let set = dir.path().join("set");
    let sample = common::assets().join("gravel_gray_500.png");
    let make = [
        "tiles",
        "make",
        s(&sample),
        "--tiles",
        "8",
        "--tile-size",
        "96",
    ];
    ok(&[&make[..], &["-q", "-o", s(&set)]].concat());
    for f in ["tile_01.png", "tile_08.png", "atlas.png", "tileset.json"] {
        assert!(set.join(f).is_file(), "{f}");
    }
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(set.join("tileset.json")).unwrap()).unwrap();
    assert_eq!(json["tiles"].as_array().unwrap().len(), 8);
    assert!(json["tiles"][1]["derived"]["patch"]["path_costs"].is_array());
    let csv = dir.path().join("fig10.csv");
    std::fs::write(&csv, "7,6,1,5\n3,7,5,8\n5,1,6,2\n4,3,2,3\n").unwrap();
    let out = dir.path().join("fig10.png");
    let assemble = ["tiles", "assemble", s(&set)];
    ok(&[&assemble[..], &["--index", s(&csv), "-o", s(&out)]].concat());
    let tw = json["tile_width"].as_u64().unwrap() as u32;
    assert_eq!(image::image_dimensions(&out).unwrap().0, 4 * tw);
    let random = dir.path().join("random.png");
    ok(&[
        &assemble[..],
        &["--grid", "3x2", "--seed", "4", "-o", s(&random)],
    ]
    .concat());
    let tile = format!("{tw}x{}", json["tile_height"]);
    let r = ok(&["compare", s(&sample), s(&out), "--tile", &tile]);
    let scores: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    for k in ["s_f", "s_l", "colour", "patch_fidelity"] {
        assert!(scores[k].as_f64().is_some(), "{k}: {scores}");
    }
    assert!(scores["seam"]["ratio"].as_f64().unwrap() < 1.6, "{scores}");

    // Refusals: a tile number past the set, a directory without a set, a
    // malformed grid.
    std::fs::write(&csv, "1,2\n9,1\n").unwrap();
    let err = refused(&[&assemble[..], &["--index", s(&csv), "-o", s(&out)]].concat());
    assert!(err.contains("tile 9") && err.contains("1..=8"), "{err}");
    let err = refused(&["tiles", "assemble", s(dir.path()), "-o", s(&out)]);
    assert!(err.contains("texsyn tiles make"), "{err}");
    let err = refused(&[&assemble[..], &["--grid", "3by2", "-o", s(&out)]].concat());
    assert!(err.contains("--grid") && err.contains("4x4"), "{err}");

    // Grids too large for memory or the format are refused before any work,
    // and leave no output.
    let big = dir.path().join("big.png");
    for (grid, words) in [
        ("2000x2000", &["--grid", "over the limit"][..]),
        ("100000x1", &["--grid", "per side"][..]),
    ] {
        let err = refused(&[&assemble[..], &["--grid", grid, "-o", s(&big)]].concat());
        assert!(words.iter().all(|w| err.contains(w)), "{grid}: {err}");
        assert!(!err.contains("panicked") && !big.exists(), "{grid}: {err}");
    }
    let webp = dir.path().join("big.webp");
    let err = refused(&[&assemble[..], &["--grid", "300x1", "-o", s(&webp)]].concat());
    assert!(err.contains("WebP") && !webp.exists(), "{err}");

    // Counts out of range are refused by name, never a panic.
    let other = dir.path().join("other");
    for (flag, value) in [
        ("--overlap", "0"),
        ("--overlap", "48"),
        ("--candidates", "18446744073709551615"),
        ("--population", "18446744073709551615"),
        ("--baseline", "18446744073709551615"),
        ("--threads", "0"),
    ] {
        let err = refused(&[&make[..], &[flag, value, "-q", "-o", s(&other)]].concat());
        assert!(
            err.contains(flag) && !err.contains("panicked"),
            "{flag} {value}: {err}"
        );
    }

    // The set's own measures: 8 distinct tiles that share some pixels.
    let r = ok(&["compare", s(&set)]);
    let m: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    assert_eq!(
        (m["tiles"].as_u64(), m["distinct_tiles"].as_u64()),
        (Some(8), Some(8))
    );
    let overlap = m["tile_overlap"].as_f64().unwrap();
    assert!(overlap > 0.0 && overlap < 1.0, "{m}");
    let err = refused(&["compare", s(&sample)]);
    assert!(err.contains("tile set directory"), "{err}");
}

/// `--stitch path` in the block method: the same output on 1 and 2
/// threads, known pixels untouched, every pixel a whole sample pixel (the
/// copy map stays exact), and a different output from the hard edge.
#[test]
fn path_stitching_of_blocks_is_deterministic_and_keeps_the_copy_map_exact() {
    use texsyn::{Config, Mode, Position, Stitch};
    let sample = crop(&texture("coffee_beans_color_512.png"), 100, 100, 96, 96);
    let mode = Mode::Extend {
        width: 192,
        height: 160,
        position: Position::Center,
    };
    let cfg = Config {
        stitch: Stitch::Path,
        ..Config::default()
    };
    let one = common::run(&sample, &mode, &cfg, 1);
    let two = common::run(&sample, &mode, &cfg, 2);
    assert!(one.image == two.image && one.copy_map == two.copy_map);
    let hard = common::run(&sample, &mode, &Config::default(), 2);
    let changed = (0..one.copy_map.len())
        .filter(|&i| one.copy_map[i] != hard.copy_map[i])
        .count();
    assert!(changed > 0, "path stitching changed nothing");
    for y in 0..one.image.height {
        for x in 0..one.image.width {
            let [sx, sy] = one.copy_map[y * one.image.width + x];
            assert_eq!(one.image.get(x, y), sample.get(sx as usize, sy as usize));
        }
    }
    // The placed sample (centred) is kept.
    let (x0, y0) = ((192 - 96) / 2, (160 - 96) / 2);
    for y in 0..96 {
        for x in 0..96 {
            assert_eq!(one.image.get(x0 + x, y0 + y), sample.get(x, y));
        }
    }
}

/// ω-tiles on the command line: the files, a set that the scan-line tiler
/// lays, the same bytes on 1 and 2 threads, the immune search beating the
/// mean of random patch sets, and refusals that name the fix.
#[test]
fn omega_tiles_on_the_command_line() {
    use common::s;
    let dir = tempfile::tempdir().unwrap();
    let sample = common::assets().join("pink_marble_color_128.png");
    let make = |name: &str, threads: &str| {
        let out = dir.path().join(name);
        ok(&[
            "tiles",
            "make",
            s(&sample),
            "--method",
            "omega",
            "--set",
            "8",
            "--tile-size",
            "64",
            "--generations",
            "10",
            "--baseline",
            "20",
            "--threads",
            threads,
            "-q",
            "-o",
            s(&out),
        ]);
        out
    };
    let one = make("one", "1");
    let two = make("two", "2");
    for f in [
        "tile_01.png",
        "tile_08.png",
        "atlas.png",
        "tileset.json",
        "ais.json",
    ] {
        assert!(one.join(f).is_file(), "{f}");
    }
    for k in 1..=8 {
        let f = format!("tile_{k:02}.png");
        assert!(
            std::fs::read(one.join(&f)).unwrap() == std::fs::read(two.join(&f)).unwrap(),
            "{f} differs between 1 and 2 threads"
        );
    }
    let json = |d: &std::path::Path, f: &str| -> serde_json::Value {
        serde_json::from_slice(&std::fs::read(d.join(f)).unwrap()).unwrap()
    };
    assert_eq!(
        json(&one, "tileset.json")["patches"],
        json(&two, "tileset.json")["patches"]
    );
    let ais = json(&one, "ais.json");
    let best = ais["result"]["best_f"].as_f64().unwrap();
    assert!(best > ais["random_mean_f"].as_f64().unwrap(), "{ais}");
    let history = ais["result"]["history"].as_array().unwrap();
    assert!(history
        .windows(2)
        .all(|w| w[1]["best_f"].as_f64() >= w[0]["best_f"].as_f64()));
    // Every tile keeps its corner patches' pixels at its four corners (the
    // border ring is never cut away).
    let set = json(&one, "tileset.json");
    let patches = set["patches"].as_array().unwrap();
    let sample_img =
        ColorImage::from_vec(128, 128, image::open(&sample).unwrap().to_rgb8().into_raw());
    for (k, corners) in set["set"].as_array().unwrap().iter().enumerate() {
        let tile = image::open(one.join(format!("tile_{:02}.png", k + 1)))
            .unwrap()
            .to_rgb8();
        let c = corners.as_str().unwrap().chars().next().unwrap();
        let colour = texsyn::tiles::omega::COLOUR_NAMES
            .iter()
            .position(|&n| n == c)
            .unwrap();
        let (gx, gy) = (
            patches[colour][0].as_u64().unwrap() as usize,
            patches[colour][1].as_u64().unwrap() as usize,
        );
        // Tile pixel (0, 0) is pixel (32, 32) of its top-left patch.
        assert_eq!(
            tile.get_pixel(0, 0).0,
            sample_img.get(gx + 32, gy + 32),
            "tile {}",
            k + 1
        );
    }
    // Assembled by the scan-line tiler; an index whose neighbours disagree on
    // a corner is refused.
    let grid = dir.path().join("grid.png");
    let assemble = [
        "tiles",
        "assemble",
        s(&one),
        "--grid",
        "5x4",
        "--seed",
        "2",
        "-o",
        s(&grid),
    ];
    let said = String::from_utf8(ok(&assemble).stdout).unwrap();
    assert!(said.contains("5x4 tiles of 64x64 (320x256)"), "{said}");
    assert_eq!(image::image_dimensions(&grid).unwrap(), (5 * 64, 4 * 64));
    let quiet = ok(&[&assemble[..], &["-q"]].concat());
    assert!(quiet.stdout.is_empty(), "-q prints nothing");
    let names: Vec<&str> = set["set"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| n.as_str().unwrap())
        .collect();
    // Two tiles that cannot sit side by side: the right corners of the first
    // differ from the left corners of the second.
    let (a, b) = (0..8)
        .flat_map(|a| (0..8).map(move |b| (a, b)))
        .find(|&(a, b)| {
            let (l, r) = (names[a].as_bytes(), names[b].as_bytes());
            l[1] != r[0] || l[3] != r[2]
        })
        .unwrap();
    let csv = dir.path().join("bad.csv");
    std::fs::write(&csv, format!("{},{}\n", a + 1, b + 1)).unwrap();
    let err = refused(&[
        "tiles",
        "assemble",
        s(&one),
        "--index",
        s(&csv),
        "-o",
        s(&grid),
    ]);
    assert!(err.contains("corner"), "{err}");
    let make_refused = |extra: &[&str]| {
        let base = [
            "tiles",
            "make",
            s(&sample),
            "--method",
            "omega",
            "-o",
            s(&grid),
        ];
        refused(&[&base[..], extra].concat())
    };
    let err = make_refused(&["--set", "9"]);
    assert!(err.contains("--set 8, 17 or 38"), "{err}");
    let err = make_refused(&["--tile-size", "200"]);
    assert!(err.contains("--tile-size"), "{err}");

    // A cut tileset.json (fewer ω-tiles listed than the set holds) is an
    // error naming the fix, with an index as with a grid, never a panic.
    let mut cut = json(&one, "tileset.json");
    cut["set"].as_array_mut().unwrap().truncate(3);
    std::fs::write(one.join("tileset.json"), cut.to_string()).unwrap();
    std::fs::write(&csv, "8,8\n").unwrap();
    for how in [&["--index", s(&csv)][..], &["--grid", "2x2"][..]] {
        let err = refused(&[&["tiles", "assemble", s(&one)][..], how, &["-o", s(&grid)]].concat());
        assert!(
            err.contains("damaged") && !err.contains("panicked"),
            "{how:?}: {err}"
        );
    }
}

/// A small Somol–Haindl set made on the command line into `dir/name`.
fn small_set(dir: &std::path::Path, name: &str, tiles: &str) -> std::path::PathBuf {
    use common::s;
    let set = dir.join(name);
    let sample = common::assets().join("pink_marble_color_128.png");
    ok(&[
        "tiles",
        "make",
        s(&sample),
        "--tiles",
        tiles,
        "--tile-size",
        "48",
        "--candidates",
        "4",
        "-q",
        "-o",
        s(&set),
    ]);
    set
}

/// The names in a directory, sorted.
fn listing(dir: &std::path::Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

/// Outputs onto a set's own files, inputs inside the output directory and a
/// directory of other files are refused before any work; a set made again
/// replaces the old one whole, and a failed run leaves it as it was.
#[test]
fn tile_outputs_never_overwrite_their_inputs() {
    use common::s;
    let dir = tempfile::tempdir().unwrap();
    let set = small_set(dir.path(), "set", "3");
    let tile = set.join("tile_01.png");
    let bytes = std::fs::read(&tile).unwrap();
    let files = listing(&set);
    let err = refused(&["tiles", "assemble", s(&set), "-o", s(&tile)]);
    assert!(
        err.contains("tile_01.png") && err.contains("another file"),
        "{err}"
    );
    let wall = set.join("wall.png");
    let err = refused(&["tiles", "assemble", s(&set), "-o", s(&wall)]);
    assert!(err.contains("inside the tile set"), "{err}");
    let err = refused(&["tiles", "make", s(&tile), "-q", "-o", s(&set)]);
    assert!(err.contains("inside the output directory"), "{err}");
    let template = ["--template", s(&tile)];
    let sample = common::assets().join("pink_marble_color_128.png");
    let err = refused(
        &[
            &["tiles", "make", s(&sample), "-q", "-o", s(&set)][..],
            &template,
        ]
        .concat(),
    );
    assert!(
        err.contains("--template") && err.contains("inside"),
        "{err}"
    );
    // A failed run (the tile is larger than the sample) leaves the set whole
    // and no temporary beside it.
    let err = refused(&[
        "tiles",
        "make",
        s(&sample),
        "--tile-size",
        "200",
        "-q",
        "-o",
        s(&set),
    ]);
    assert!(err.contains("--tile-size"), "{err}");
    assert_eq!(std::fs::read(&tile).unwrap(), bytes);
    assert_eq!(listing(&set), files);
    assert_eq!(listing(dir.path()), ["set"]);
    // Made again with fewer tiles: no stale tile of the older set remains.
    small_set(dir.path(), "set", "2");
    assert!(!set.join("tile_03.png").exists(), "{:?}", listing(&set));
    assert!(set.join("tile_02.png").is_file());
    // A directory of the user's files is never replaced.
    let user = dir.path().join("user");
    std::fs::create_dir(&user).unwrap();
    std::fs::write(user.join("notes.txt"), "mine").unwrap();
    let err = refused(&["tiles", "make", s(&sample), "-q", "-o", s(&user)]);
    assert!(err.contains("did not write"), "{err}");
    assert!(user.join("notes.txt").is_file());
}

/// A `tileset.json` cut short, malformed or not a file is an error naming
/// it and the fix, with an index as with a grid, never a panic; the typed
/// file reads back what `tiles make` wrote.
#[test]
fn a_cut_or_malformed_tileset_json_is_refused_with_the_fix() {
    use common::s;
    let dir = tempfile::tempdir().unwrap();
    let set = small_set(dir.path(), "set", "2");
    let json = set.join("tileset.json");
    let full = std::fs::read(&json).unwrap();
    let file = tiles::TileSetFile::read(&set).unwrap();
    assert_eq!(file.tile_count(), 2);
    let value: serde_json::Value = serde_json::from_slice(&full).unwrap();
    assert_eq!(serde_json::to_value(&file).unwrap(), value);
    let csv = dir.path().join("index.csv");
    std::fs::write(&csv, "1,2\n2,1\n").unwrap();
    let out = dir.path().join("grid.png");
    let cut = &full[..full.len() / 2];
    for bad in [cut, b"{\"method\": \"somol\"}", b"[1, 2]", b"\xff\xfe"] {
        std::fs::write(&json, bad).unwrap();
        for how in [&["--index", s(&csv)][..], &["--grid", "2x2"][..]] {
            let err =
                refused(&[&["tiles", "assemble", s(&set)][..], how, &["-o", s(&out)]].concat());
            assert!(
                err.contains("tileset.json")
                    && err.contains("texsyn tiles make")
                    && !err.contains("panicked"),
                "{how:?}: {err}"
            );
            assert!(!out.exists());
        }
    }
    std::fs::remove_file(&json).unwrap();
    std::fs::create_dir(&json).unwrap();
    let err = refused(&["tiles", "assemble", s(&set), "-o", s(&out)]);
    assert!(err.contains("texsyn tiles make"), "{err}");
}

// ---- Issue 38: tile sets that hide their grid --------------------------

/// The share of equal pixels a Somol set may hold between its tiles
/// (ARCHITECTURE §7): the template's ring and little more.
const MAX_TILE_OVERLAP: f64 = 0.10;
/// Joints of an assembled grid against its interior's median step.
const MAX_JOINT_RATIO: f64 = 1.15;

/// The Somol set of `sample` with the default settings at `side`, or with
/// `paper` settings: the paper's patch belt (`w_P = w_T`), a 2-pixel margin,
/// no pull and the single best template by border error.
fn somol_set(sample: &ColorImage, side: usize, paper: bool) -> tiles::TileSet {
    let mut s = tiles::SomolConfig {
        tile_size: Some(side),
        ..Default::default()
    }
    .settings(sample, None)
    .unwrap();
    if paper {
        s.belt = s.overlap;
        s.margin = 2;
        s.pull = 0.0;
        s.max_overlap = 1.0;
        s.template_candidates = 1;
    }
    tiles::make_tile_set(sample, None, &s, &Silent).unwrap()
}

/// Whether a tile set's tiles share few enough pixels.
fn overlap_within_bound(set: &[ColorImage]) -> (bool, f64) {
    let o = compare::tile_overlap(set).unwrap();
    (o <= MAX_TILE_OVERLAP, o)
}

/// Whether a grid of `tw`×`th` tiles (wrapping) hides its joints.
fn joints_within_bound(grid: &ColorImage, tw: usize, th: usize) -> (bool, f64) {
    let g = compare::Grid {
        tile_width: tw,
        tile_height: th,
        wrap: true,
    };
    let r = compare::grid_seam(grid, g).ratio;
    (r <= MAX_JOINT_RATIO, r)
}

#[test]
fn derived_tiles_share_little_more_than_the_template_s_ring_and_the_paper_s_band_fails() {
    let sample = crop(&texture("gravel_gray_500.png"), 0, 0, 160, 160);
    let set = somol_set(&sample, 80, false);
    let (ok_now, o) = overlap_within_bound(&set.tiles);
    assert!(ok_now, "tile_overlap {o}");
    // The planted defect: the paper's belt with a 2-pixel margin leaves a
    // wide band of the template in every tile.
    let band = somol_set(&sample, 80, true);
    let (ok_band, ob) = overlap_within_bound(&band.tiles);
    assert!(!ok_band, "the banded set should fail: tile_overlap {ob}");
    // Every tile keeps the template's first column and row, so whatever
    // lies right of or below a tile continues it as its own wrap does.
    let t0 = &set.tiles[0];
    let (w, h) = (t0.width, t0.height);
    for t in &set.tiles[1..] {
        assert!((0..w).all(|x| t.get(x, 0) == t0.get(x, 0)));
        assert!((0..h).all(|y| t.get(0, y) == t0.get(0, y)));
    }
    assert!(
        set.derived.iter().any(|d| d.wrap != tiles::Wrap::Inside),
        "no patch reached over the right or bottom edge"
    );
    let (ok, worst) = wraps_within_bound(&set.tiles);
    assert!(ok, "a tile's wrap joints step {worst} × its interior");
    // The planted defect: a patch pasted over the right edge unstitched.
    let mut pasted = set.tiles.clone();
    for y in 0..h {
        for x in w - 3..w {
            pasted[1].set(x, y, sample.get(x + 70, y + 50));
        }
    }
    let (ok_pasted, wp) = wraps_within_bound(&pasted);
    assert!(!ok_pasted, "the pasted edge should show: {wp}");
}

#[test]
fn derived_tiles_take_distinct_patches_when_free_places_run_out() {
    // A small sample: after a few tiles every place overlaps a taken one by
    // more than a quarter, and the least-overlapping place is taken.
    let sample = crop(&texture("gravel_gray_500.png"), 0, 0, 64, 64);
    let mut s = tiles::SomolConfig {
        tile_size: Some(40),
        tiles: 32,
        ..Default::default()
    }
    .settings(&sample, None)
    .unwrap();
    s.candidates = 12;
    let set = tiles::make_tile_set(&sample, None, &s, &Silent).unwrap();
    let sources: Vec<_> = set
        .derived
        .iter()
        .map(|d| (d.patch.source.x, d.patch.source.y))
        .collect();
    for (i, a) in sources.iter().enumerate() {
        assert!(
            !sources[..i].contains(a),
            "two tiles take the patch at {a:?}: {sources:?}"
        );
    }
    let (ok, worst) = wraps_within_bound(&set.tiles);
    assert!(ok, "a tile's wrap joints step {worst} × its interior");
}

#[test]
fn patch_sources_keep_apart_so_no_tile_is_a_shifted_copy_of_another() {
    // A sample only twice the tile's side has no room for eight sources a
    // quarter apart; the tiles must still not be the template moved a pixel
    // or two, which `tile_overlap` (equal pixels in place) cannot see, and
    // the room that is left must be found: 48 candidates alone left leaves'
    // last tile the template moved by (14, 15), 0.72 a copy of it.
    for name in ["pink_marble_color_128.png", "leaves_green_color_161.png"] {
        let sample = texture(name);
        let side = sample.width.min(sample.height) / 2;
        let set = somol_set(&sample, side, false);
        let mut sources = vec![(set.template.rect.x, set.template.rect.y)];
        sources.extend(
            set.derived
                .iter()
                .map(|d| (d.patch.source.x, d.patch.source.y)),
        );
        let nearest = (0..sources.len())
            .flat_map(|i| (0..i).map(move |j| (i, j)))
            .map(|(i, j)| {
                let (a, b) = (sources[i], sources[j]);
                a.0.abs_diff(b.0).max(a.1.abs_diff(b.1))
            })
            .min()
            .unwrap();
        assert!(
            nearest >= side / 8,
            "{name}: two sources {nearest} px apart: {sources:?}"
        );
        let copy = compare::tile_copy(&set.tiles).unwrap();
        assert!(copy < 0.6, "{name}: a tile is {copy} a copy of another");
    }
}

/// Whether no tile's wrap joints (which are its joints with any neighbour
/// when all tiles share the template's first column and row) step more than
/// its interior's median, or the template's own if that is more.
fn wraps_within_bound(set: &[ColorImage]) -> (bool, f64) {
    let bound = tiles::tileset::wrap_ratio(&set[0]).max(1.0);
    let worst = set
        .iter()
        .map(tiles::tileset::wrap_ratio)
        .fold(0.0, f64::max);
    (worst <= bound, worst)
}

#[test]
fn a_patch_that_cannot_wrap_both_edges_wraps_one_and_keeps_the_other_edge_the_template_s() {
    // The 64² brick: no patch keeps the joints wrapping both edges, so each
    // tile wraps one edge (or none); the edge it does not wrap stays the
    // template's, pixel for pixel, and every tile's joints hold.
    let sample = texture("brick_gray_64.png");
    let set = somol_set(&sample, 32, false);
    let t0 = &set.tiles[0];
    let (w, h) = (t0.width, t0.height);
    let kinds: Vec<tiles::Wrap> = set.derived.iter().map(|d| d.wrap).collect();
    assert!(
        kinds
            .iter()
            .any(|k| matches!(k, tiles::Wrap::Right | tiles::Wrap::Bottom)),
        "no tile wraps one edge: {kinds:?}"
    );
    let last_col = |t: &ColorImage| (0..h).all(|y| t.get(w - 1, y) == t0.get(w - 1, y));
    let last_row = |t: &ColorImage| (0..w).all(|x| t.get(x, h - 1) == t0.get(x, h - 1));
    for (t, k) in set.tiles[1..].iter().zip(&kinds) {
        match k {
            tiles::Wrap::Right => {
                assert!(last_row(t), "a right-wrapping tile changed its bottom row")
            }
            tiles::Wrap::Bottom => assert!(
                last_col(t),
                "a bottom-wrapping tile changed its right column"
            ),
            tiles::Wrap::Inside => assert!(last_col(t) && last_row(t)),
            tiles::Wrap::Both => {}
        }
    }
    let (ok, worst) = wraps_within_bound(&set.tiles);
    assert!(ok, "a tile's wrap joints step {worst} × its interior");
}

#[test]
fn the_pull_ladder_keeps_the_set_s_overlap_in_budget_and_no_budget_fails() {
    // Small tiles, where the template's first column and row alone are 6%
    // of a tile: at the weakest pull the tiles share more than the budget,
    // so tiles climb the ladder; without a budget none does and the set
    // shares more.
    let sample = texture("brick_color_96.png");
    let mut s = tiles::SomolConfig {
        tile_size: Some(40),
        ..Default::default()
    }
    .settings(&sample, None)
    .unwrap();
    let budget = s.max_overlap;
    let set = tiles::make_tile_set(&sample, None, &s, &Silent).unwrap();
    let t0 = &set.tiles[0];
    for (d, t) in set.derived.iter().zip(&set.tiles[1..]) {
        let share = tiles::tileset::equal_share(t, t0);
        assert!(
            (d.template_share - share).abs() < 1e-12,
            "reported {} against {share}",
            d.template_share
        );
        assert!(d.pull >= s.pull);
    }
    assert!(
        set.derived.iter().any(|d| d.pull > s.pull),
        "no tile needed a stronger pull"
    );
    // The budget is the measure's own mean over pairs of tiles.
    let o = compare::tile_overlap(&set.tiles).unwrap();
    assert!(o <= budget, "tile_overlap {o} over the budget {budget}");
    // The planted defect: no budget, the least pull everywhere.
    s.max_overlap = 1.0;
    let loose = tiles::make_tile_set(&sample, None, &s, &Silent).unwrap();
    assert!(loose.derived.iter().all(|d| d.pull == s.pull));
    let lo = compare::tile_overlap(&loose.tiles).unwrap();
    assert!(lo > budget, "without a budget tile_overlap is {lo}");
}

#[test]
fn a_somol_grid_hides_its_joints_and_raw_crops_fail_the_same_bound() {
    let sample = crop(&texture("pink_marble_color_128.png"), 0, 0, 128, 128);
    let set = somol_set(&sample, 64, false);
    let (w, h) = (set.tiles[0].width, set.tiles[0].height);
    let index = tiles::random_index(set.tiles.len(), 8, 8, 3);
    let grid = tiles::assemble(&set.tiles, &index).unwrap();
    let (ok_now, r) = joints_within_bound(&grid, w, h);
    assert!(ok_now, "joint ratio {r}");
    // The planted defect: tiles cut straight from the sample.
    let raw: Vec<ColorImage> = [(0, 0), (60, 7), (13, 61), (64, 64)]
        .iter()
        .map(|&(x, y)| crop(&sample, x, y, w, h))
        .collect();
    let bad = tiles::assemble(&raw, &tiles::random_index(4, 8, 8, 3)).unwrap();
    let (ok_bad, rb) = joints_within_bound(&bad, w, h);
    assert!(!ok_bad, "raw crops should fail: joint ratio {rb}");
}

/// An 8-tile set of 64-px tiles made with `config` (its tile size set),
/// laid 8×8 at random (seed 3), and the grid it wraps as.
fn marble_wall(sample: &ColorImage, config: tiles::SomolConfig) -> (ColorImage, compare::Grid) {
    let mut s = tiles::SomolConfig {
        tile_size: Some(64),
        ..config
    }
    .settings(sample, None)
    .unwrap();
    s.tiles = 8;
    let set = tiles::make_tile_set(sample, None, &s, &Silent).unwrap();
    let grid = tiles::assemble(&set.tiles, &tiles::random_index(8, 8, 8, 3)).unwrap();
    let g = compare::Grid {
        tile_width: 64,
        tile_height: 64,
        wrap: true,
    };
    (grid, g)
}

#[test]
fn the_template_s_ring_falls_on_typical_texture_and_border_error_alone_draws_the_grid() {
    // Every tile keeps the template's border ring, so a pale ring is a pale
    // line at every joint however seamless the joints are. Chosen by border
    // error alone (ring weight 0), the 128² pink marble's template lies in
    // pale, veinless marble and its grid's joints stand out; the default
    // choice weighs the ring's brightness, contrast and detail against the
    // sample's and its joints fall on typical marble.
    let sample = texture("pink_marble_color_128.png");
    let offset = |ring: f64| {
        let (grid, g) = marble_wall(
            &sample,
            tiles::SomolConfig {
                template_ring: ring,
                ..Default::default()
            },
        );
        let (ok, r) = joints_within_bound(&grid, 64, 64);
        assert!(ok, "ring weight {ring}: joint ratio {r}");
        compare::joint_offset(&grid, g)
    };
    let (typical, border_only) = (offset(1.0), offset(0.0));
    assert!(
        border_only > 0.3,
        "border error alone: joint offset {border_only}"
    );
    assert!(
        typical < border_only / 2.0,
        "the ring weighed: joint offset {typical}, border error alone {border_only}"
    );
}

#[test]
fn patch_stitches_feather_so_no_step_runs_beside_the_joints() {
    // The patch paths are pulled to the tile's edges to keep the tiles
    // apart, so they meet the template's first column and row right beside
    // every joint. Blended by error as the paper prints it, path pixels
    // whose error is under a third of the belt's largest do not blend at
    // all, and the 128² pink marble's grid steps twice the interior's
    // median one pixel inside every joint; feathered, every path pixel
    // blends over ρ and the lines beside the joints step as the interior.
    let sample = texture("pink_marble_color_128.png");
    let beside = |blend: tiles::Blend| {
        let (grid, g) = marble_wall(
            &sample,
            tiles::SomolConfig {
                blend,
                ..Default::default()
            },
        );
        let seam = compare::grid_seam(&grid, g);
        assert!(seam.ratio < 1.15, "{blend:?}: {seam:?}");
        seam.beside_ratio
    };
    let (feather, error) = (beside(tiles::Blend::Feather), beside(tiles::Blend::Error));
    assert!(error > 1.5, "blended by error: beside ratio {error}");
    assert!(feather < 1.15, "feathered: beside ratio {feather}");
}

/// `E` of each patch set at full resolution.
fn full_energies(
    sample: &ColorImage,
    set: &tiles::omega::OmegaSet,
    t: usize,
    sets: &[Vec<(u32, u32)>],
) -> Vec<f64> {
    let mut ev = tiles::ais::Evaluator::at_level(set, sample, t, 0).unwrap();
    ev.errors(sets)
        .unwrap()
        .iter()
        .map(|d| tiles::ais::energy(d, 0.8))
        .collect()
}

/// Whether a patch set's full-resolution error is below the best of the
/// random sets (the paper's semi-random baseline, Table 2).
fn beats_semi_random(e: f64, random: &[f64]) -> (bool, f64) {
    let semi = random.iter().copied().fold(f64::INFINITY, f64::min);
    (e < semi, semi)
}

#[test]
fn the_immune_search_beats_the_best_of_a_hundred_random_sets_at_full_resolution() {
    let set = tiles::omega::OmegaSet::of_size(8).unwrap();
    for (name, x, y) in [
        ("pink_marble_color_128.png", 20, 30),
        ("leaves_green_color_161.png", 40, 10),
    ] {
        let sample = crop(&texture(name), x, y, 56, 56);
        let t = 28;
        let mut ev = tiles::ais::Evaluator::new(&set, &sample, t).unwrap();
        assert_eq!(ev.steps, 0, "a small sample is searched at full resolution");
        let s = tiles::ais::AisSettings::default();
        let found = tiles::ais::search(&mut ev, &sample, &s, &Silent).unwrap();
        let random = tiles::ais::random_sets(&ev, &sample, 100, 9);
        let re = full_energies(&sample, &set, t, &random);
        let e = full_energies(&sample, &set, t, std::slice::from_ref(&found.genes))[0];
        let (ok_ais, semi) = beats_semi_random(e, &re);
        assert!(ok_ais, "{name}: AIS E {e} vs semi-random {semi}");
        // The planted defect: a "search" that keeps its first random set.
        let (ok_first, _) = beats_semi_random(re[0], &re[1..]);
        assert!(
            !ok_first,
            "{name}: a random set should not beat the other 99"
        );
    }
}

/// Colours whose patches cover half of another colour's, and tiles equal
/// pixel for pixel to an earlier one.
fn shared_patches_and_tiles(
    patches: &[(u32, u32)],
    t: usize,
    tiles: &[ColorImage],
) -> (usize, usize) {
    let shared = (0..patches.len())
        .filter(|&i| (0..i).any(|j| tiles::ais::patch_cover(patches[i], patches[j], t) >= 0.5))
        .count();
    let equal = (0..tiles.len())
        .filter(|&i| (0..i).any(|j| tiles[i].rgb == tiles[j].rgb))
        .count();
    (shared, equal)
}

/// Per tile and side, the pixels of its border that differ from the
/// corner patches they continue: tile column 0 is column `T/2` of the
/// patch of its left corners, column `T − 1` is column `T/2 − 1` of the patch
/// of its right corners (and rows alike), so any two tiles whose corners
/// match agree with the sample along their whole shared edge.
fn edge_disagreements(
    sample: &ColorImage,
    set: &tiles::omega::OmegaSet,
    patches: &[(u32, u32)],
    tiles: &[ColorImage],
) -> usize {
    let t = tiles[0].width;
    let k = t / 2;
    let mut bad = 0;
    for (tile, corners) in tiles.iter().zip(&set.tiles) {
        let patch = |c: usize| patches[usize::from(corners[c])];
        // (tile x, tile y) -> the patch pixel the intermediate tile shows.
        let want = |x: usize, y: usize| {
            let (right, sx) = if x < k { (0, x + k) } else { (1, x - k) };
            let (bottom, sy) = if y < k { (0, y + k) } else { (1, y - k) };
            let (gx, gy) = patch(2 * bottom + right);
            sample.get(gx as usize + sx, gy as usize + sy)
        };
        for i in 0..t {
            for (x, y) in [(i, 0), (i, t - 1), (0, i), (t - 1, i)] {
                bad += usize::from(tile.get(x, y) != want(x, y));
            }
        }
    }
    bad
}

#[test]
fn omega_tiles_are_distinct_and_agree_with_their_neighbours_along_whole_edges() {
    let sample = crop(&texture("pink_marble_color_128.png"), 0, 0, 64, 64);
    let set = tiles::omega::OmegaSet::of_size(17).unwrap();
    let t = 32;
    let mut ev = tiles::ais::Evaluator::new(&set, &sample, t).unwrap();
    let s = tiles::ais::AisSettings {
        generations: 8,
        ..Default::default()
    };
    let found = tiles::ais::search(&mut ev, &sample, &s, &Silent).unwrap();
    let (images, _) = tiles::ais::build_tiles(&mut ev, &sample, &found.genes).unwrap();
    assert_eq!(shared_patches_and_tiles(&found.genes, t, &images), (0, 0));
    assert_eq!(edge_disagreements(&sample, &set, &found.genes, &images), 0);
    // Planted defects: two colours on one patch make equal tiles; one
    // border pixel changed breaks the agreement along that edge.
    let mut one = found.genes.clone();
    one[4] = one[3];
    let (same, _) = tiles::ais::build_tiles(&mut ev, &sample, &one).unwrap();
    let (shared, equal) = shared_patches_and_tiles(&one, t, &same);
    assert!(shared == 1 && equal > 0, "{shared} {equal}");
    let mut touched = images.clone();
    let p = touched[5].get(0, 9);
    touched[5].set(0, 9, [p[0] ^ 0x40, p[1], p[2]]);
    assert_eq!(edge_disagreements(&sample, &set, &found.genes, &touched), 1);
}

/// `n` dark discs of radius `r` on a light ground, at least `gap` apart,
/// each with its own grey so that a disc joined from two halves differs.
fn disc_sample(side: usize, r: usize, n: usize, gap: usize, seed: u64) -> ColorImage {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut centres: Vec<(i64, i64)> = Vec::new();
    let (s, min) = (side as i64, (2 * r + gap) as i64);
    for _ in 0..n * 200 {
        if centres.len() == n {
            break;
        }
        let c = (rng.random_range(0..s), rng.random_range(0..s));
        // Distances wrap, so the sample tiles and no disc is cut at its edge.
        let far = |a: i64, b: i64| {
            let d = (a - b).rem_euclid(s);
            d.min(s - d)
        };
        if centres
            .iter()
            .all(|&(x, y)| far(x, c.0).pow(2) + far(y, c.1).pow(2) >= min * min)
        {
            centres.push(c);
        }
    }
    // A grain on the ground, so that its steps are not all zero.
    let mut img = ColorImage::new(side, side);
    for y in 0..side {
        for x in 0..side {
            let g = rng.random_range(0..12u8);
            img.set(x, y, [220 + g, 210 + g, 195 + g]);
        }
    }
    for (k, &(cx, cy)) in centres.iter().enumerate() {
        let tone = 40 + (k * 37 % 80) as u8;
        let r = r as i64;
        for dy in -r..=r {
            for dx in -r..=r {
                if dx * dx + dy * dy <= r * r {
                    let (x, y) = ((cx + dx).rem_euclid(s), (cy + dy).rem_euclid(s));
                    let g = rng.random_range(0..4u8);
                    img.set(x as usize, y as usize, [tone + g, tone + g, tone + 10]);
                }
            }
        }
    }
    img
}

/// The share of a tile's dark pixels (its wrap-around kept) that lie in
/// pieces of other than one whole disc of radius `r`: discs sliced by a
/// stitch, or halves of two discs joined.
fn sliced_share(tile: &ColorImage, r: usize) -> f64 {
    let (w, h) = (tile.width, tile.height);
    let dark = |x: usize, y: usize| tile.get(x, y)[0] < 180;
    let whole = std::f64::consts::PI * (r * r) as f64;
    let mut seen = vec![false; w * h];
    let (mut sliced, mut total) = (0usize, 0usize);
    for start in 0..w * h {
        if seen[start] || !dark(start % w, start / w) {
            continue;
        }
        seen[start] = true;
        let (mut stack, mut piece, mut tones) = (vec![start], 0usize, Vec::new());
        while let Some(i) = stack.pop() {
            let (x, y) = (i % w, i / w);
            piece += 1;
            tones.push(tile.get(x, y)[0]);
            for (nx, ny) in [
                ((x + 1) % w, y),
                ((x + w - 1) % w, y),
                (x, (y + 1) % h),
                (x, (y + h - 1) % h),
            ] {
                let j = ny * w + nx;
                if !seen[j] && dark(nx, ny) {
                    seen[j] = true;
                    stack.push(j);
                }
            }
        }
        let one_tone = tones.iter().all(|&t| t.abs_diff(tones[0]) <= 6);
        let size = piece as f64 / whole;
        total += piece;
        if !one_tone || !(0.85..=1.15).contains(&size) {
            sliced += piece;
        }
    }
    sliced as f64 / total.max(1) as f64
}

/// A Somol set of `count` 128-px tiles of `sample` by `config` (its tile
/// size set to 128), and the belt its settings took.
fn disc_set(
    sample: &ColorImage,
    config: tiles::SomolConfig,
    count: usize,
) -> (usize, tiles::TileSet) {
    let mut s = tiles::SomolConfig {
        tile_size: Some(128),
        ..config
    }
    .settings(sample, None)
    .unwrap();
    s.tiles = count;
    (
        s.belt,
        tiles::make_tile_set(sample, None, &s, &Silent).unwrap(),
    )
}

#[test]
fn the_template_s_stitches_pass_round_objects_wider_than_the_paper_s_band() {
    // Discs 21 px across at 128-px tiles: the paper's 12-px template overlap
    // and its doubling leave the wrap stitches no way round a disc, so the
    // template that every tile repeats joins halves of different discs.
    // The belt is widened to the discs' scale, and the template choice
    // stitches a band twice the belt too: its stitches pass between them.
    let sample = disc_sample(384, 10, 150, 4, 7);
    let template = |belt: Option<usize>| {
        let config = tiles::SomolConfig {
            belt,
            ..Default::default()
        };
        let (belt, set) = disc_set(&sample, config, 1);
        (set.template.overlap, belt, sliced_share(&set.tiles[0], 10))
    };
    let (wide, belt, default) = template(None);
    assert!(belt > 24, "belt {belt}: not widened to the discs");
    assert_eq!(wide, 2 * belt, "the template's band");
    // A belt no wider than the doubled band: only the paper's two bands.
    let (paper, _, narrow) = template(Some(24));
    assert!(
        paper <= 24,
        "with --belt 24 the bands are 12 and 24: {paper}"
    );
    assert!(
        default <= narrow,
        "sliced share of the template's discs: default {default}, the paper's bands {narrow}"
    );
    // One placement, stitched at each band: the doubled band still slices
    // discs, twice the belt does not.
    let at = |overlap: usize| {
        let config = tiles::SomolConfig {
            overlap: Some(overlap),
            template_candidates: 1,
            ..Default::default()
        };
        sliced_share(&disc_set(&sample, config, 1).1.tiles[0], 10)
    };
    let (doubled, objects) = (at(24), at(2 * belt));
    assert!(
        doubled > 0.05 && objects < doubled / 4.0,
        "sliced share at one placement: band 24 {doubled}, band {} {objects}",
        2 * belt
    );
}

#[test]
fn derived_tiles_take_no_extra_patch_too_narrow_to_hold_an_object() {
    // Discs 21 px across at 128-px tiles: the belt is widened to 25 px, and
    // a half-size extra patch (64 px) would keep a 14-px interior, so its
    // four paths set halves of discs over others. With the belt at 21 the
    // extra patch still goes in (a 22-px interior), and it slices more.
    let sample = disc_sample(384, 10, 150, 4, 7);
    let set_with = |belt: Option<usize>| {
        let config = tiles::SomolConfig {
            belt,
            ..Default::default()
        };
        let (belt, set) = disc_set(&sample, config, 5);
        let extras: usize = set.derived.iter().map(|d| d.extra.len()).sum();
        let sliced = set.tiles[1..]
            .iter()
            .map(|t| sliced_share(t, 10))
            .sum::<f64>()
            / (set.tiles.len() - 1) as f64;
        (belt, extras, sliced)
    };
    let (belt, extras, wide) = set_with(None);
    assert!(belt > 21, "belt {belt}: not widened to the discs");
    assert_eq!(
        extras, 0,
        "a {belt}-px belt leaves no room for an extra patch"
    );
    let (_, extras, narrow) = set_with(Some(21));
    assert_eq!(
        extras, 4,
        "a 21-px belt keeps one extra patch per derived tile"
    );
    assert!(
        wide < narrow,
        "sliced share of the derived tiles' discs: without extra patches {wide}, with {narrow}"
    );
}
