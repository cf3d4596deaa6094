//! The copy and repetition measures on textures made here: a tiling of A, A's
//! rotation, a shifted copy, a patchwork of A's pieces, noise, and tile grids.
//! Each ranking below fails when its measure is replaced by a constant.

use proptest::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::repetition::{grid_cells, PATCH, REPEAT_DISTANCE};
use super::*;
use crate::imaging::ColorImage;

/// A `w`×`h` image of seeded random colours drawn from `levels` values per
/// channel.
fn noise(w: usize, h: usize, levels: u8, seed: u64) -> ColorImage {
    let mut r = ChaCha8Rng::seed_from_u64(seed);
    let rgb = (0..w * h * 3).map(|_| r.random_range(0..levels)).collect();
    ColorImage::from_vec(w, h, rgb)
}

/// A smooth texture: sums of a few seeded sinusoids per channel (no two 8×8
/// patches equal, small steps between neighbours, not periodic in its size).
fn smooth(w: usize, h: usize, seed: u64) -> ColorImage {
    let mut r = ChaCha8Rng::seed_from_u64(seed);
    let waves: Vec<[f64; 4]> = (0..9)
        .map(|_| {
            [
                r.random_range(0.01..0.09),
                r.random_range(0.01..0.09),
                r.random_range(0.0..std::f64::consts::TAU),
                r.random_range(20.0..40.0),
            ]
        })
        .collect();
    let mut img = ColorImage::new(w, h);
    for y in 0..h {
        for x in 0..w {
            let p: [u8; 3] = std::array::from_fn(|c| {
                let v: f64 = waves[c * 3..c * 3 + 3]
                    .iter()
                    .map(|k| k[3] * (k[0] * x as f64 + k[1] * y as f64 + k[2]).sin())
                    .sum();
                (128.0 + v).clamp(0.0, 255.0) as u8
            });
            img.set(x, y, p);
        }
    }
    img
}

/// `img` tiled into a `w`×`h` image (offset `(dx, dy)`): B(x, y) = A((x + dx)
/// mod A.w, (y + dy) mod A.h).
fn tiled(img: &ColorImage, w: usize, h: usize, dx: usize, dy: usize) -> ColorImage {
    let mut out = ColorImage::new(w, h);
    for y in 0..h {
        for x in 0..w {
            out.set(x, y, img.get((x + dx) % img.width, (y + dy) % img.height));
        }
    }
    out
}

fn rotated(img: &ColorImage) -> ColorImage {
    let mut out = ColorImage::new(img.height, img.width);
    for y in 0..img.height {
        for x in 0..img.width {
            out.set(img.height - 1 - y, x, img.get(x, y));
        }
    }
    out
}

/// A `w`×`h` patchwork of `cell`×`cell` pieces of `a`, each from a seeded
/// random place: what a synthesis that copies small blocks looks like.
fn patchwork(a: &ColorImage, w: usize, h: usize, cell: usize, seed: u64) -> ColorImage {
    let mut r = ChaCha8Rng::seed_from_u64(seed);
    let mut out = ColorImage::new(w, h);
    for cy in (0..h).step_by(cell) {
        for cx in (0..w).step_by(cell) {
            let (sx, sy) = (
                r.random_range(0..=a.width - cell),
                r.random_range(0..=a.height - cell),
            );
            for y in cy..(cy + cell).min(h) {
                for x in cx..(cx + cell).min(w) {
                    out.set(x, y, a.get(sx + x - cx, sy + y - cy));
                }
            }
        }
    }
    out
}

/// Lays `tiles` out in a `cols`×`rows` grid by a seeded random choice (every
/// tile at least once when there are enough cells).
fn grid(tiles: &[ColorImage], cols: usize, rows: usize, seed: u64) -> ColorImage {
    let (tw, th) = (tiles[0].width, tiles[0].height);
    let mut r = ChaCha8Rng::seed_from_u64(seed);
    let mut out = ColorImage::new(cols * tw, rows * th);
    for k in 0..cols * rows {
        let t = if k < tiles.len() {
            &tiles[k]
        } else {
            &tiles[r.random_range(0..tiles.len())]
        };
        let (ox, oy) = ((k % cols) * tw, (k / cols) * th);
        for y in 0..th {
            for x in 0..tw {
                out.set(ox + x, oy + y, t.get(x, y));
            }
        }
    }
    out
}

/// 8 noise tiles that share their left `band` columns.
fn banded_tiles(side: usize, band: usize) -> Vec<ColorImage> {
    let shared = noise(side, side, 255, 99);
    (0..8)
        .map(|k| {
            let mut t = noise(side, side, 255, 200 + k);
            for y in 0..side {
                for x in 0..band {
                    t.set(x, y, shared.get(x, y));
                }
            }
            t
        })
        .collect()
}

#[test]
fn copy_share_ranks_copies_above_synthesis_above_noise() {
    let a = noise(96, 80, 255, 1);
    let tiling = copy_share(&a, &tiled(&a, 192, 160, 0, 0));
    let shifted = copy_share(&a, &tiled(&a, 96, 80, 37, 11));
    let work = copy_share(&a, &patchwork(&a, 192, 160, 16, 5));
    let rot = copy_share(&a, &rotated(&a));
    let other = copy_share(&a, &noise(192, 160, 255, 2));
    assert!(tiling.share >= 0.9 && tiling.offset == [0, 0], "{tiling:?}");
    assert!(
        shifted.share >= 0.9 && shifted.offset == [37, 11],
        "{shifted:?}"
    );
    assert!(work.share > 0.0 && work.share < 0.2, "{work:?}");
    assert!(rot.share < 0.01 && other.share < 0.01, "{rot:?} {other:?}");
}

#[test]
fn copy_share_of_a_sample_placed_in_a_larger_canvas_is_its_area() {
    // The block method's synth: the sample verbatim in the middle, other
    // content around it.
    let a = noise(64, 64, 255, 3);
    let mut b = noise(128, 128, 255, 4);
    for y in 0..64 {
        for x in 0..64 {
            b.set(32 + x, 32 + y, a.get(x, y));
        }
    }
    let c = copy_share(&a, &b);
    let expect = (57.0 * 57.0) / (121.0 * 121.0);
    assert!((c.share - expect).abs() < 1e-9, "{c:?} against {expect}");
    assert_eq!(c.offset, [64 - 32, 64 - 32]);
}

#[test]
fn repeat_share_ranks_tilings_above_patchworks_above_photos() {
    let a = noise(96, 80, 255, 1);
    let tiling = repeat_share(&tiled(&a, 192, 160, 0, 0));
    let one_tile = repeat_share(&grid(&[noise(32, 32, 255, 6)], 8, 8, 1));
    let work = repeat_share(&patchwork(&a, 192, 160, 24, 5));
    let photo = repeat_share(&a);
    let flat_small = repeat_share(&ColorImage::from_vec(
        REPEAT_DISTANCE + PATCH - 2,
        REPEAT_DISTANCE + PATCH - 2,
        vec![7; (REPEAT_DISTANCE + PATCH - 2).pow(2) * 3],
    ));
    assert!(tiling >= 0.9 && one_tile >= 0.9, "{tiling} {one_tile}");
    assert!(work > 0.0 && work < tiling, "{work}");
    assert_eq!(photo, 0.0);
    // Equal patches all nearer than REPEAT_DISTANCE do not count.
    assert_eq!(flat_small, 0.0);
}

#[test]
fn tile_overlap_ranks_one_tile_above_a_shared_band_above_free_tiles() {
    let one = tile_overlap(&grid_cells(
        &grid(&[noise(40, 40, 255, 6)], 8, 8, 1),
        40,
        40,
    ));
    let band = tile_overlap(&grid_cells(&grid(&banded_tiles(40, 4), 8, 8, 2), 40, 40));
    let free = tile_overlap(&grid_cells(&grid(&banded_tiles(40, 0), 8, 8, 3), 40, 40));
    assert_eq!(one, Some(1.0));
    let (band, free) = (band.unwrap(), free.unwrap());
    assert!((band - 0.1).abs() < 0.01, "{band}");
    assert!(free < 0.01, "{free}");
    assert_eq!(tile_overlap(&[noise(8, 8, 255, 1)]), None);
}

#[test]
fn tile_overlap_chance_is_what_unrelated_tiles_of_a_flat_texture_share() {
    // Free tiles of two grey levels share half their pixels by chance; of
    // full-range noise, almost none. A band shared by all tiles raises the
    // overlap but not the chance.
    let two_levels = |seed: u64| {
        let n = noise(40, 40, 255, seed);
        let rgb = n.rgb.chunks(3).flat_map(|p| [p[0] & 0x80; 3]).collect();
        ColorImage::from_vec(40, 40, rgb)
    };
    let flat: Vec<ColorImage> = (10..18).map(two_levels).collect();
    let chance = tile_overlap_chance(&flat).unwrap();
    assert!((chance - 0.5).abs() < 0.05, "{chance}");
    let overlap = tile_overlap(&flat).unwrap();
    assert!((overlap - chance).abs() < 0.05, "{overlap} {chance}");
    let band = banded_tiles(40, 4);
    let (b, bc) = (
        tile_overlap(&band).unwrap(),
        tile_overlap_chance(&band).unwrap(),
    );
    assert!(b > 0.09 && bc < 0.01, "band {b}, chance {bc}");
    assert_eq!(tile_overlap_chance(&[noise(8, 8, 255, 1)]), None);
}

#[test]
fn tile_copy_finds_a_shifted_copy_that_tile_overlap_misses() {
    // Eight 40×40 crops of one larger texture: seven far apart and one taken
    // 2 px below the first, as a patch drawn beside another's source is.
    let big = noise(200, 200, 255, 21);
    let at = [
        (0, 0),
        (80, 0),
        (160, 0),
        (0, 80),
        (80, 80),
        (160, 80),
        (0, 160),
    ];
    let mut tiles: Vec<ColorImage> = at.iter().map(|&(x, y)| big.crop(x, y, 40, 40)).collect();
    let apart = tile_copy(&tiles).unwrap();
    tiles.push(big.crop(0, 2, 40, 40));
    let near = tile_copy(&tiles).unwrap();
    let overlap = tile_overlap(&tiles).unwrap();
    assert!(apart < 0.01, "far crops share {apart}");
    // All but the two last 8-pixel rows of patches are found at one offset.
    assert!(near > 0.85, "the shifted crop shares only {near}");
    assert!(overlap < 0.01, "equal pixels in place: {overlap}");
    assert_eq!(tile_copy(&tiles[..1]), None);
    // A grid of very many distinct cells is not paired (its pairs grow as
    // the square of their number).
    let many: Vec<ColorImage> = (0..=repetition::MAX_NEAREST_PAIR_TILES as u64)
        .map(|s| noise(16, 16, 255, 100 + s))
        .collect();
    assert_eq!(tile_copy(&many), None);
    assert!(tile_copy(&many[1..]).is_some());
}

#[test]
fn grid_seams_count_real_joints_only() {
    // An image cut into cells in order: its joints are invisible, but its
    // outer edge does not continue (it does not wrap).
    let img = smooth(160, 160, 7);
    let cells = grid_cells(&img, 40, 40);
    let open = Grid {
        tile_width: 40,
        tile_height: 40,
        wrap: false,
    };
    let in_order = grid_seam(&img, open);
    let as_wrapping = grid_seam(&img, Grid { wrap: true, ..open });
    let mut shuffled = cells.clone();
    shuffled.reverse();
    shuffled.swap(3, 9);
    let shuffled = grid_seam(&grid(&shuffled, 4, 4, 0), open);
    assert!(in_order.ratio < 1.3, "{in_order:?}");
    assert!(as_wrapping.ratio > 1.3 * in_order.ratio, "{as_wrapping:?}");
    assert!(shuffled.ratio > 3.0, "{shuffled:?}");
}

#[test]
fn a_step_one_pixel_inside_the_joints_shows_beside_them_not_at_them() {
    // Cells of a smooth image in order, each brightened inside its first
    // and last column: the joints (last column to the next cell's first)
    // continue as before, but a stitch hugging them would step just inside.
    let img = smooth(160, 160, 11);
    let open = Grid {
        tile_width: 40,
        tile_height: 40,
        wrap: false,
    };
    let plain = grid_seam(&img, open);
    let mut stepped = img.clone();
    for y in 0..160 {
        for x in (0..160).filter(|x| !matches!(x % 40, 0 | 39)) {
            let p = stepped.get(x, y).map(|v| v.saturating_add(24));
            stepped.set(x, y, p);
        }
    }
    let inside = grid_seam(&stepped, open);
    assert!(plain.beside_ratio < 1.3, "{plain:?}");
    assert!(inside.ratio < 1.3, "{inside:?}");
    assert!(inside.beside_ratio > 3.0, "{inside:?}");
    // A tileable image's beside lines are the wrap's neighbours.
    let whole = seam_score(&stepped, &[0], &[0]);
    let before = seam_score(&img, &[0], &[0]);
    assert!(
        whole.beside_step > 3.0 * before.beside_step,
        "{whole:?} {before:?}"
    );
}

#[test]
fn compare_with_a_grid_reports_its_tiles() {
    let a = noise(64, 64, 255, 1);
    let g = grid(&banded_tiles(32, 0), 4, 4, 1);
    let s = compare_with(
        &a,
        &g,
        Some(Grid {
            tile_width: 32,
            tile_height: 32,
            wrap: true,
        }),
    )
    .unwrap();
    let t = s.tiles.unwrap();
    assert_eq!((t.cells, t.distinct_tiles), (16, 8));
    assert!(s.repeat_share > 0.5, "{}", s.repeat_share);
    assert!(s.copy_share < 0.01);
    let bad = Grid {
        tile_width: 65,
        tile_height: 32,
        wrap: false,
    };
    assert!(compare_with(&a, &a, Some(bad)).is_err());
}

#[test]
fn set_scores_count_distinct_tiles_and_patches() {
    let dir = tempfile::tempdir().unwrap();
    let mut tiles = banded_tiles(16, 0);
    tiles.truncate(4);
    tiles.push(tiles[1].clone());
    for (k, t) in tiles.iter().enumerate() {
        crate::imaging::save_color(&dir.path().join(format!("tile_{:02}.png", k + 1)), t).unwrap();
    }
    let json = serde_json::json!({
        "method": "omega", "tile_width": 16, "tile_height": 16,
        "patches": [[0, 0], [2, 0], [40, 40], [0, 40]],
    });
    std::fs::write(dir.path().join("tileset.json"), json.to_string()).unwrap();
    let s = set::set_scores(dir.path()).unwrap();
    assert_eq!((s.tiles, s.distinct_tiles), (5, 4));
    assert_eq!((s.colours, s.distinct_patches), (Some(4), Some(3)));
    // One pair of six covers 14/16 of a patch.
    assert!((s.patch_overlap.unwrap() - 14.0 / 16.0 / 6.0).abs() < 1e-9);
    std::fs::write(dir.path().join("tileset.json"), "{\"method\": 3}").unwrap();
    let e = set::set_scores(dir.path()).unwrap_err().to_string();
    assert!(e.contains("tiles make"), "{e}");
}

/// The share of B's patches equal to A's at offset `o`, pixel by pixel.
fn share_reference(a: &ColorImage, b: &ColorImage, o: [usize; 2]) -> f64 {
    let (pw, ph) = (b.width + 1 - PATCH, b.height + 1 - PATCH);
    let hits = (0..ph)
        .flat_map(|y| (0..pw).map(move |x| (x, y)))
        .filter(|&(x, y)| {
            (0..PATCH).all(|j| {
                (0..PATCH).all(|i| {
                    b.get(x + i, y + j)
                        == a.get((x + i + o[0]) % a.width, (y + j + o[1]) % a.height)
                })
            })
        })
        .count();
    hits as f64 / (pw * ph) as f64
}

/// The share of B's patches equal to another at least REPEAT_DISTANCE away,
/// by comparing every pair.
fn repeat_reference(b: &ColorImage) -> f64 {
    let (pw, ph) = (b.width + 1 - PATCH, b.height + 1 - PATCH);
    let same = |p: (usize, usize), q: (usize, usize)| {
        (0..PATCH).all(|j| (0..PATCH).all(|i| b.get(p.0 + i, p.1 + j) == b.get(q.0 + i, q.1 + j)))
    };
    let all: Vec<(usize, usize)> = (0..ph).flat_map(|y| (0..pw).map(move |x| (x, y))).collect();
    let hits = all
        .iter()
        .filter(|&&p| {
            all.iter().any(|&q| {
                (p.0.abs_diff(q.0) >= REPEAT_DISTANCE || p.1.abs_diff(q.1) >= REPEAT_DISTANCE)
                    && same(p, q)
            })
        })
        .count();
    hits as f64 / all.len() as f64
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    /// Hashing never changes a count: copy_share's share at its offset and
    /// repeat_share equal the pixel-by-pixel references on patchworks of a
    /// two-level noise (many exact repeats and near-collisions).
    #[test]
    fn hashed_measures_equal_their_references(
        seed in 0u64..1_000_000,
        cell in 9usize..20,
        levels in 2u8..4,
    ) {
        let a = noise(30, 26, levels, seed);
        let b = patchwork(&a, 44, 40, cell, seed + 1);
        let c = copy_share(&a, &b);
        prop_assert!((c.share - share_reference(&a, &b, c.offset)).abs() < 1e-12);
        // No offset does better than the one chosen.
        let best = (0..a.height)
            .flat_map(|y| (0..a.width).map(move |x| [x, y]))
            .map(|o| share_reference(&a, &b, o))
            .fold(0.0, f64::max);
        prop_assert!(c.share >= best - 1e-12, "{} < {}", c.share, best);
        prop_assert!((repeat_share(&b) - repeat_reference(&b)).abs() < 1e-12);
    }
}

#[test]
fn images_past_the_size_cap_are_refused_before_any_measure() {
    let small = noise(16, 16, 255, 1);
    let big = ColorImage::new(4097, 4096);
    for (a, b) in [(&small, &big), (&big, &small)] {
        let e = compare_with(a, b, None).unwrap_err().to_string();
        assert!(e.contains("4097x4096") && e.contains("crop"), "{e}");
    }
}

#[test]
fn a_pixel_checker_has_checker_energy_and_a_flat_or_smooth_image_little() {
    let (w, h) = (32, 32);
    let img = |f: &dyn Fn(usize, usize) -> u8| {
        ColorImage::from_vec(
            w,
            h,
            (0..w * h).flat_map(|i| [f(i % w, i / w); 3]).collect(),
        )
    };
    let checker = img(&|x, y| if (x + y) % 2 == 0 { 100 } else { 140 });
    let flat = img(&|_, _| 120);
    let ramp = img(&|x, _| (x * 8) as u8);
    assert!((super::checker_energy(&checker) - 400.0).abs() < 1e-9);
    assert_eq!(super::checker_energy(&flat), 0.0);
    // A ramp wraps once (a step at the edge); it has far less.
    assert!(super::checker_energy(&ramp) < 0.1 * super::checker_energy(&checker));
    // Contrast: the checker's deviation is 20 against a half-strength one.
    let half = img(&|x, y| if (x + y) % 2 == 0 { 110 } else { 130 });
    let c = super::contrast_ratio(&checker, &half);
    assert!(c.iter().all(|v| (v - 0.5).abs() < 1e-9), "{c:?}");
}

#[test]
fn joint_offset_sees_a_shared_pale_border_that_the_seams_do_not() {
    // Tiles of free noise laid in a wrapping grid: their joints fall on
    // typical texture. The same tiles with a pale 2-pixel ring along their
    // edges (the same in every tile, so the joints stay as seamless as the
    // ring) draw a grid that joint_offset sees.
    let free: Vec<ColorImage> = (0..8).map(|k| noise(32, 32, 255, 40 + k)).collect();
    let ringed: Vec<ColorImage> = free
        .iter()
        .map(|t| {
            let mut t = t.clone();
            for y in 0..32 {
                for x in 0..32 {
                    if x < 2 || y < 2 || x >= 30 || y >= 30 {
                        let p = t.get(x, y);
                        t.set(x, y, p.map(|c| c / 4 + 190));
                    }
                }
            }
            t
        })
        .collect();
    let g = Grid {
        tile_width: 32,
        tile_height: 32,
        wrap: true,
    };
    let plain = joint_offset(&grid(&free, 6, 6, 3), g);
    let pale = joint_offset(&grid(&ringed, 6, 6, 3), g);
    assert!(plain < 0.1, "free tiles: {plain}");
    assert!(pale > 0.5, "a shared pale ring: {pale}");
    // The joints of the ringed grid step no more than its interior: the
    // seam bound passes it.
    let seam = grid_seam(&grid(&ringed, 6, 6, 3), g);
    assert!(seam.ratio < 1.15, "{seam:?}");
}
