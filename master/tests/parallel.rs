//! The synthesis on coordinates (ARCHITECTURE §10) from the command line:
//! a morph of one exemplar is the plain synthesis, a morph is the weighted
//! sum of its exemplars at their coordinates, replay reproduces outputs
//! exactly (of both methods), threads do not change a byte, and bad input is
//! refused with the fix named.

use crate::common;

use std::path::Path;

use common::{ok, refused, s};
use image::{DynamicImage, GenericImageView};

fn open(p: &Path) -> DynamicImage {
    image::open(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// A coordinate map as written by `--coords` / `--copy-map`.
fn coords(p: &Path) -> (u32, u32, Vec<[u32; 2]>) {
    let img = open(p).into_rgb16();
    let c = img
        .pixels()
        .map(|p| {
            assert_eq!(p.0[2], 0, "blue of a coordinate map is 0");
            [u32::from(p.0[0]), u32::from(p.0[1])]
        })
        .collect();
    (img.width(), img.height(), c)
}

fn bytes(p: &Path) -> Vec<u8> {
    std::fs::read(p).unwrap()
}

/// A grey 8-bit PNG, `f(x, y)` per pixel.
fn grey(p: &Path, w: u32, h: u32, f: impl Fn(u32, u32) -> u8) {
    image::GrayImage::from_fn(w, h, |x, y| image::Luma([f(x, y)]))
        .save(p)
        .unwrap();
}

#[test]
fn a_morph_of_one_exemplar_under_weight_one_is_the_parallel_synthesis() {
    let dir = tempfile::tempdir().unwrap();
    let d = |f: &str| dir.path().join(f);
    let sample = common::assets().join("pink_marble_color_128.png");
    // The same passes, k, levels and no copy guard for both: `morph` keeps
    // the paper's 2 passes, 4 candidates, one neighbourhood and no guard by
    // default where `synth` gives `half` 8 passes, 8 candidates, 7×7
    // coarse levels and a guard.
    let settings = [
        "--coarse-neighbourhood",
        "same",
        "--neighbourhood",
        "half",
        "--k",
        "4",
        "--jitter",
        "0.5",
        "--seed",
        "9",
        "--passes",
        "3",
        "--fine-passes",
        "3",
        "--copy-guard",
        "0",
    ];
    let synth = [
        "synth",
        s(&sample),
        "--method",
        "parallel",
        "--size",
        "160x112",
        "-q",
    ];
    ok(&[
        &synth[..],
        &settings,
        &["-o", s(&d("synth.png")), "--coords", s(&d("synth_c.png"))],
    ]
    .concat());
    grey(&d("ones.png"), 160, 112, |_, _| 255);
    let morph = ["morph", s(&sample), "--size", "160x112", "-q"];
    ok(&[
        &morph[..],
        &settings,
        &["--weight-maps", s(&d("ones.png"))],
        &["-o", s(&d("morph.png")), "--coords", s(&d("morph_c.png"))],
    ]
    .concat());
    assert_eq!(coords(&d("synth_c.png")), coords(&d("morph_c.png")));
    assert!(
        open(&d("synth.png")).to_rgb8() == open(&d("morph.png")).to_rgb8(),
        "the one-exemplar morph's colour differs from --method parallel"
    );
    // Another seed gives another synthesis: the check above can fail.
    ok(&[
        &synth[..],
        &["--neighbourhood", "half", "--jitter", "0.5", "--seed", "10"],
        &["-o", s(&d("other.png")), "--coords", s(&d("other_c.png"))],
    ]
    .concat());
    assert_ne!(coords(&d("synth_c.png")), coords(&d("other_c.png")));
}

/// The output is `Σ Wʲ·Eʲ(Sʲ)` pixel by pixel, with the weight maps
/// normalised to sum to 1; computed here in f64 from the written coordinate
/// maps and the weight files.
#[test]
fn a_morph_is_the_weighted_sum_of_its_exemplars_at_their_coordinates() {
    let dir = tempfile::tempdir().unwrap();
    let d = |f: &str| dir.path().join(f);
    let a = common::assets().join("pink_marble_color_128.png");
    let b = common::assets().join("leaves_green_color_161.png");
    let (w, h) = (192u32, 128u32);
    // Unnormalised maps: a ramp and a disc, both 0 in one corner region.
    grey(&d("wa.png"), w, h, |x, _| (x * 255 / (w - 1)) as u8);
    grey(&d("wb.png"), w, h, |x, y| {
        let (dx, dy) = (x as f64 - 60.0, y as f64 - 64.0);
        if (dx * dx + dy * dy).sqrt() < 50.0 {
            200
        } else {
            40
        }
    });
    ok(&[
        "morph",
        s(&a),
        s(&b),
        "--weight-maps",
        &format!("{},{}", s(&d("wa.png")), s(&d("wb.png"))),
        "--size",
        &format!("{w}x{h}"),
        "--colour",
        "weighted",
        "-q",
        "-o",
        s(&d("out.png")),
        "--coords",
        s(&d("c.png")),
    ]);
    let out = open(&d("out.png")).to_rgb8();
    let ex = [open(&a).to_rgb8(), open(&b).to_rgb8()];
    let maps = [coords(&d("c_1.png")).2, coords(&d("c_2.png")).2];
    let wts = [open(&d("wa.png")).to_luma8(), open(&d("wb.png")).to_luma8()];
    let (mut exact, mut near_half) = (0usize, 0usize);
    for y in 0..h {
        for x in 0..w {
            let i = (y * w + x) as usize;
            let raw = wts
                .each_ref()
                .map(|m| f64::from(m.get_pixel(x, y).0[0]) / 255.0);
            let sum: f64 = raw.iter().sum();
            let wt = raw.map(|v| if sum > 0.0 { v / sum } else { 0.5 });
            for c in 0..3 {
                let v: f64 = (0..2)
                    .map(|j| {
                        let [cx, cy] = maps[j][i];
                        wt[j] * f64::from(ex[j].get_pixel(cx, cy).0[c])
                    })
                    .sum();
                let got = f64::from(out.get_pixel(x, y).0[c]);
                if (v.fract() - 0.5).abs() > 1e-3 {
                    assert_eq!(got, v.round(), "({x}, {y}) channel {c}: {v}");
                    exact += 1;
                } else {
                    // f32 arithmetic may round a value this close to .5 either way.
                    assert!(
                        (got - v).abs() <= 0.5 + 1e-3,
                        "({x}, {y}) {c}: {got} vs {v}"
                    );
                    near_half += 1;
                }
            }
        }
    }
    assert!(
        exact > 100 * near_half,
        "{exact} exact, {near_half} near .5"
    );
    // Both exemplars are used: where the ramp is 0, only B's weight remains.
    assert!(maps[0] != maps[1]);
}

#[test]
fn replay_through_the_coordinates_reproduces_the_output_of_both_methods() {
    let dir = tempfile::tempdir().unwrap();
    let d = |f: &str| dir.path().join(f);
    let asset = |k: &str| common::assets().join(format!("mossy_rock_{k}_128.png"));
    let colour = asset("color");
    ok(&[
        "synth",
        s(&colour),
        "--method",
        "parallel",
        "--size",
        "144x96",
        "-q",
        "-o",
        s(&d("par.png")),
        "--coords",
        s(&d("par_c.png")),
    ]);
    ok(&[
        "synth",
        s(&colour),
        "--size",
        "144x96",
        "--levels",
        "3",
        "-q",
        "-o",
        s(&d("block.png")),
        "--copy-map",
        s(&d("block_c.png")),
    ]);
    for (out, map) in [("par.png", "par_c.png"), ("block.png", "block_c.png")] {
        let replayed = d(&format!("replayed_{out}"));
        let maps: Vec<_> = ["color", "height", "normal", "roughness"]
            .iter()
            .map(|k| asset(k))
            .collect();
        let coord_map = d(map);
        let mut args = vec!["replay", "--coords", s(&coord_map), "-o", s(&replayed)];
        args.extend(maps.iter().map(|p| s(p)));
        ok(&args);
        // The colour map replayed is the output, byte for byte in pixels.
        let again = open(&replayed.join("mossy_rock_color_128.png"));
        assert!(
            again.to_rgb8() == open(&d(out)).to_rgb8(),
            "replaying the colour through {map} does not give {out}"
        );
        // Every other map: each pixel is the map's pixel at the coordinate,
        // in the map's own channels.
        let (_, _, c) = coords(&d(map));
        for k in ["height", "normal", "roughness"] {
            let src = open(&asset(k));
            let got = open(&replayed.join(format!("mossy_rock_{k}_128.png")));
            assert_eq!(got.color(), src.color(), "{k} keeps its channels");
            assert_eq!(got.dimensions(), (144, 96));
            for (i, [x, y]) in c.iter().enumerate() {
                let (px, py) = ((i % 144) as u32, (i / 144) as u32);
                assert_eq!(got.get_pixel(px, py), src.get_pixel(*x, *y), "{k} at {i}");
            }
        }
    }
    // The two methods' maps differ (the check is not vacuous).
    assert_ne!(coords(&d("par_c.png")).2, coords(&d("block_c.png")).2);
}

/// Lattice phase (ARCHITECTURE §10), found by default: on the coloured
/// tiles every pixel's offset from the sample stays within a pixel of the
/// 32-px grid, where without it the grid slips; the same bytes on 1 and 2
/// threads.
#[test]
fn a_grid_sample_keeps_its_phase_by_default() {
    let dir = tempfile::tempdir().unwrap();
    let d = |f: &str| dir.path().join(f);
    let sample = common::assets().join("tiles_color_256.png");
    let run = |name: &str, extra: &[&str]| {
        let (out, map) = (d(&format!("{name}.png")), d(&format!("{name}_c.png")));
        let base = [
            "synth",
            s(&sample),
            "--method",
            "parallel",
            "--size",
            "160x128",
            "-q",
            "-o",
        ];
        ok(&[&base[..], &[s(&out), "--coords", s(&map)], extra].concat());
        (std::fs::read(&out).unwrap(), coords(&map))
    };
    // The share of pixels whose offset (coordinate less position) lies
    // within a pixel of a multiple of 32 on both axes: the sample's joints
    // sit at multiples of 32.
    let in_phase = |(w, _, c): &(u32, u32, Vec<[u32; 2]>)| {
        let near = |v: i64| v.rem_euclid(32).min(32 - v.rem_euclid(32)) <= 1;
        let kept = c
            .iter()
            .enumerate()
            .filter(|(i, q)| {
                let (x, y) = ((*i as u32 % w) as i64, (*i as u32 / w) as i64);
                near(i64::from(q[0]) - x) && near(i64::from(q[1]) - y)
            })
            .count();
        kept as f64 / c.len() as f64
    };
    let (found, found_map) = run("found", &["--threads", "1"]);
    let (two, _) = run("two", &["--threads", "2"]);
    let (_, none_map) = run("none", &["--lattice", "none"]);
    let (on, off) = (in_phase(&found_map), in_phase(&none_map));
    eprintln!("in phase: {off:.3} without the lattice, {on:.3} with it");
    assert!(on > 0.99, "the grid's phase is kept: {on}");
    assert!(off < on - 0.2, "without it the grid slips: {off}");
    assert!(
        found == two,
        "1 and 2 threads differ under the lattice phase"
    );
}

#[test]
fn threads_do_not_change_a_byte() {
    let dir = tempfile::tempdir().unwrap();
    let d = |f: &str| dir.path().join(f);
    let a = common::assets().join("brick_color_96.png");
    let b = common::assets().join("cracked_color_144.png");
    for t in ["1", "2"] {
        for n in ["reduced", "7"] {
            ok(&[
                "synth",
                s(&a),
                "--method",
                "parallel",
                "--neighbourhood",
                n,
                "--size",
                "128x128",
                "--threads",
                t,
                "-q",
                "-o",
                s(&d(&format!("synth_{n}_{t}.png"))),
            ]);
        }
        ok(&[
            "morph",
            s(&a),
            s(&b),
            "--ramp",
            "y",
            "--size",
            "96x160",
            "--threads",
            t,
            "-q",
            "-o",
            s(&d(&format!("morph_{t}.png"))),
            "--coords",
            s(&d(&format!("morph_c_{t}.png"))),
        ]);
    }
    for f in ["synth_reduced", "synth_7", "morph", "morph_c"] {
        let name = |t: &str| {
            d(&if f == "morph_c" {
                format!("{f}_{t}_2.png")
            } else {
                format!("{f}_{t}.png")
            })
        };
        assert!(
            bytes(&name("1")) == bytes(&name("2")),
            "{f}: 1 and 2 threads differ"
        );
    }
    assert!(bytes(&d("synth_reduced_1.png")) != bytes(&d("synth_7_1.png")));
}

#[test]
fn bad_input_is_refused_with_the_fix_named() {
    let dir = tempfile::tempdir().unwrap();
    let d = |f: &str| dir.path().join(f);
    let a = common::assets().join("brick_color_96.png");
    let b = common::assets().join("pink_marble_color_128.png");
    let out = d("out.png");
    let synth = |extra: &[&str]| {
        refused(
            &[
                &[
                    "synth",
                    s(&a),
                    "--method",
                    "parallel",
                    "--size",
                    "64x64",
                    "-o",
                    s(&out),
                ][..],
                extra,
            ]
            .concat(),
        )
    };
    assert!(synth(&["--neighbourhood", "9"]).contains("reduced, half, 5 or 7"));
    assert!(synth(&["--jitter", "1.5"]).contains("[0, 1]"));
    assert!(synth(&["--tileable"]).contains("--tileable"));
    assert!(synth(&["--passes", "0"]).contains("--passes 0 must be in 1..=64"));
    assert!(synth(&["--coherence=-1"]).contains("--coherence -1 must be in [0, 1000]"));
    assert!(synth(&["--coherence", "NaN"]).contains("must be in [0, 1000]"));
    let e = refused(&[
        "synth",
        s(&a),
        "--coherence",
        "10",
        "--size",
        "64x64",
        "-o",
        s(&out),
    ]);
    assert!(
        e.contains("--coherence belongs to --method parallel"),
        "{e}"
    );
    let e = refused(&[
        "synth",
        s(&a),
        "--correct-every-level",
        "--size",
        "64x64",
        "-o",
        s(&out),
    ]);
    assert!(
        e.contains("--correct-every-level belongs to --method parallel"),
        "{e}"
    );
    let e = refused(&["morph", s(&a), s(&b), "--size", "64x64", "-o", s(&out)]);
    assert!(e.contains("--weight-maps") && e.contains("--ramp"), "{e}");
    grey(&d("w.png"), 32, 32, |_, _| 1);
    let e = refused(&[
        "morph",
        s(&a),
        s(&b),
        "--weight-maps",
        &format!("{},{}", s(&d("w.png")), s(&d("w.png"))),
        "--size",
        "64x64",
        "-o",
        s(&out),
    ]);
    assert!(e.contains("must be the output size"), "{e}");
    let e = refused(&[
        "morph",
        s(&a),
        s(&b),
        "--ramp",
        "z",
        "--size",
        "64x64",
        "-o",
        s(&out),
    ]);
    assert!(e.contains("not x or y"), "{e}");
    // Replay: a picture that is no coordinate map, a map too small for the
    // coordinates, and an output that would overwrite the input.
    let e = refused(&["replay", "--coords", s(&a), s(&b), "-o", s(&d("r"))]);
    assert!(e.contains("not a coordinate map"), "{e}");
    ok(&[
        "synth",
        s(&b),
        "--method",
        "parallel",
        "--size",
        "64x64",
        "-q",
        "-o",
        s(&out),
        "--coords",
        s(&d("c.png")),
    ]);
    grey(&d("small.png"), 16, 16, |x, _| x as u8);
    // The good map before the bad one is not written either.
    let e = refused(&[
        "replay",
        "--coords",
        s(&d("c.png")),
        s(&b),
        s(&d("small.png")),
        "-o",
        s(&d("r")),
    ]);
    assert!(e.contains("exemplar's size"), "{e}");
    assert!(!d("r").join("pink_marble_color_128.png").exists());
    let e = refused(&[
        "replay",
        "--coords",
        s(&d("c.png")),
        s(&b),
        "-o",
        s(&common::assets()),
    ]);
    assert!(e.contains("texsyn did not write"), "{e}");
    assert!(!d("r").join("small.png").exists());
}

/// `--candidate-cache`: the first morph stores one file per exemplar and
/// level, a second one from the same exemplars (another neighbourhood and
/// seed) reads them all, searches nothing new and writes the bytes it would
/// write without the cache; a damaged file is searched again.
#[test]
fn a_candidate_cache_is_filled_once_and_changes_no_byte() {
    let dir = tempfile::tempdir().unwrap();
    let d = |f: &str| dir.path().join(f);
    let a = common::assets().join("bark_color_82.png");
    let b = common::assets().join("water_pool_color_94.png");
    let cache = d("kc");
    let morph = |out: &str, extra: &[&str]| {
        let o = d(out);
        ok(&[
            &[
                "morph",
                s(&a),
                s(&b),
                "--ramp",
                "x",
                "--size",
                "96x64",
                "-q",
            ][..],
            &["-o", s(&o)],
            extra,
        ]
        .concat());
        bytes(&o)
    };
    let files = || {
        let mut f: Vec<_> = std::fs::read_dir(&cache)
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        f.sort();
        f
    };
    let plain = morph("plain.png", &[]);
    let first = morph("first.png", &["--candidate-cache", s(&cache)]);
    assert_eq!(first, plain, "a cache miss changed the output");
    let stored = files();
    // 2 exemplars × the 5 levels of an 82² exemplar (steps 16 down to 1).
    assert_eq!(stored.len(), 2 * 5, "{stored:?}");
    let times: Vec<_> = stored
        .iter()
        .map(|f| std::fs::metadata(f).unwrap().modified().unwrap())
        .collect();
    let half = ["--neighbourhood", "half", "--seed", "4"];
    let plain_half = morph("plain_half.png", &half);
    let hit = morph(
        "hit.png",
        &[&half[..], &["--candidate-cache", s(&cache)]].concat(),
    );
    assert_eq!(hit, plain_half, "a cache hit changed the output");
    assert_ne!(hit, first, "the second morph is another synthesis");
    assert_eq!(files(), stored, "a hit stores nothing new");
    for (f, t) in stored.iter().zip(&times) {
        assert_eq!(std::fs::metadata(f).unwrap().modified().unwrap(), *t);
    }
    // Levels left uncorrected search no sets: 7×7 reaches 3 steps, so on an
    // 82² exemplar only the steps with 6h below 41 (4, 2, 1) are corrected.
    let wide = d("kc7");
    morph(
        "seven.png",
        &["--neighbourhood", "7", "--candidate-cache", s(&wide)],
    );
    assert_eq!(std::fs::read_dir(&wide).unwrap().count(), 2 * 3);
    // A damaged file is searched again: same output, file rewritten.
    std::fs::write(&stored[0], b"damaged").unwrap();
    let again = morph("again.png", &["--candidate-cache", s(&cache)]);
    assert_eq!(again, plain);
    assert!(std::fs::metadata(&stored[0]).unwrap().len() > 1000);
    // The block method has no candidate sets.
    let e = refused(&[
        "synth",
        s(&a),
        "--size",
        "64x64",
        "-o",
        s(&d("x.png")),
        "--candidate-cache",
        s(&cache),
    ]);
    assert!(
        e.contains("--candidate-cache belongs to --method parallel"),
        "{e}"
    );
}

/// The coarse levels' own 7×7 neighbourhood (ARCHITECTURE §10) lays out a
/// grid sample's tiles, which the reduced and half neighbourhoods' few
/// averaged points cannot see: against the same run with every level
/// corrected as the finest (`--coarse-neighbourhood same`), the output's
/// patches are clearly nearer the sample's.
#[test]
fn coarse_levels_with_the_full_neighbourhood_lay_out_a_grid() {
    let dir = tempfile::tempdir().unwrap();
    let sample = dir.path().join("tiles.png");
    open(&common::assets().join("tiles_color_256.png"))
        .crop_imm(0, 0, 128, 128)
        .save(&sample)
        .unwrap();
    let a = texsyn::imaging::load_color(&sample).unwrap();
    let fidelity = |name: &str, extra: &[&str]| {
        let out = dir.path().join(name);
        let base = [
            "synth",
            s(&sample),
            "-o",
            s(&out),
            "--size",
            "256x256",
            "--method",
            "parallel",
            "-q",
            "--lattice",
            "none",
        ];
        ok(&[&base[..], extra].concat());
        let b = texsyn::imaging::load_color(&out).unwrap();
        texsyn::compare::patch_fidelity(&a, &b).unwrap()
    };
    for n in ["reduced", "half"] {
        let coarse = fidelity(&format!("{n}.png"), &["--neighbourhood", n]);
        let same = fidelity(
            &format!("{n}-same.png"),
            &["--neighbourhood", n, "--coarse-neighbourhood", "same"],
        );
        eprintln!(
            "{n}: patch fidelity {same:.2} with one neighbourhood, {coarse:.2} with 7×7 coarse levels"
        );
        assert!(
            coarse < 0.9 * same,
            "{n}: the 7×7 coarse levels lay out the grid: {coarse} against {same}"
        );
    }
}
