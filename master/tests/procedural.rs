//! Procedural matching and transformation (Bourque–Dudek, ARCHITECTURE
//! §12): the similarity measures' properties, a deterministic catalogue,
//! recovery of synthetic targets, `texsyn match` end to end, threads not
//! changing a byte, and bad input refused with the fix named.
//!
//! The recovery test here is reduced (64² renders, a small catalogue, a
//! few draws per shader) to stay quick; the full 10 draws per shader at the
//! default catalogue are `texsyn-bench match`.

use crate::common;

use std::path::Path;

use common::{ok, refused, s};
use rand::{Rng, SeedableRng};
use texsyn::compare::{laplacian_distance, spectrum_similarity};
use texsyn::imaging::{self, ColorImage};
use texsyn::procedural::catalogue::{BuildSettings, Catalogue};
use texsyn::procedural::shaders::by_name;
use texsyn::procedural::{draw, recovery_trials, MatchSettings, Pattern};
use texsyn::procedural::{Kind, LIBRARY};

fn bytes(p: &Path) -> Vec<u8> {
    std::fs::read(p).unwrap()
}

/// `img` shifted circularly by (dx, dy).
fn rolled(img: &ColorImage, dx: usize, dy: usize) -> ColorImage {
    let mut out = ColorImage::new(img.width, img.height);
    for y in 0..img.height {
        for x in 0..img.width {
            out.set((x + dx) % img.width, (y + dy) % img.height, img.get(x, y));
        }
    }
    out
}

/// `img` with uniform noise of ± `amp` grey levels added (seeded).
fn noisy(img: &ColorImage, amp: i32, seed: u64) -> ColorImage {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let rgb = img
        .rgb
        .iter()
        .map(|&v| (i32::from(v) + rng.random_range(-amp..=amp)).clamp(0, 255) as u8)
        .collect();
    ColorImage::from_vec(img.width, img.height, rgb)
}

#[test]
fn s_f_and_s_l_identity_shift_and_noise() {
    for name in ["pink_marble_color_128.png", "brick_color_96.png"] {
        let img = common::texture(name);
        assert_eq!(spectrum_similarity(&img, &img).unwrap(), 1.0, "{name}");
        assert_eq!(laplacian_distance(&img, &img).unwrap(), 0.0, "{name}");
        // The magnitude spectrum ignores circular shifts.
        let shifted = rolled(&img, 17, 5);
        let sf = spectrum_similarity(&img, &shifted).unwrap();
        assert!(sf > 0.999_999, "{name}: S_F of a shift {sf}");
        // More noise, less alike: S_F falls and S_L grows with its amplitude.
        let mut last = (1.0, 0.0);
        for amp in [4, 16, 48, 96] {
            let n = noisy(&img, amp, 7);
            let (sf, sl) = (
                spectrum_similarity(&img, &n).unwrap(),
                laplacian_distance(&img, &n).unwrap(),
            );
            assert!(
                sf < last.0 && sl > last.1,
                "{name} ±{amp}: S_F {sf}, S_L {sl} after {last:?}"
            );
            last = (sf, sl);
        }
    }
}

#[test]
fn catalogue_sampling_is_deterministic_for_any_thread_count() {
    let dir = tempfile::tempdir().unwrap();
    let d = |f: &str| dir.path().join(f);
    for t in ["1", "2"] {
        ok(&[
            "match",
            "catalogue",
            "-o",
            s(&d(&format!("cat_{t}.json"))),
            "--size",
            "48",
            "--samples",
            "30",
            "--shaders",
            "stars,wood",
            "--threads",
            t,
            "-q",
        ]);
    }
    assert!(bytes(&d("cat_1.json")) == bytes(&d("cat_2.json")));
    let cat = Catalogue::load(&d("cat_1.json")).unwrap();
    assert_eq!(cat.shaders.len(), 2);
    for sc in &cat.shaders {
        assert_eq!(sc.samples.len(), 30);
        let shader = by_name(&sc.shader).unwrap();
        for x in &sc.samples {
            for (p, v) in shader.params.iter().zip(&x.params) {
                assert!(*v >= p.min && *v <= p.max, "{} {v}", p.name);
                if p.kind == Kind::Integer {
                    assert_eq!(v.fract(), 0.0);
                }
            }
        }
    }
    // The same as a library build, written the same way.
    let lib = Catalogue::build(
        &BuildSettings {
            size: 48,
            samples: 30,
            shaders: Some(vec!["stars".into(), "wood".into()]),
        },
        &texsyn::progress::Silent,
    )
    .unwrap();
    assert!(serde_json::to_vec(&lib).unwrap() == bytes(&d("cat_1.json")));
}

#[test]
fn synthetic_targets_are_recovered_with_integers_exact() {
    // Reduced: 64² renders, 80 samples per shader, one draw per shader (the
    // bench, `texsyn-bench match`, runs ten at 128²).
    let cat = Catalogue::build(
        &BuildSettings {
            size: 64,
            samples: 80,
            shaders: None,
        },
        &texsyn::progress::Silent,
    )
    .unwrap();
    let settings = MatchSettings::default();
    let mut recovered = 0;
    let mut total = 0;
    let mut integers_wrong = Vec::new();
    for shader in LIBRARY {
        let trials = recovery_trials(shader, 1, 1000, &cat, &settings, 0.05).unwrap();
        for t in &trials {
            total += 1;
            recovered += usize::from(t.recovered);
            for (i, p) in shader.params.iter().enumerate() {
                if p.kind == Kind::Integer && t.truth.params[i] != t.found.pattern.params[i] {
                    integers_wrong.push(format!(
                        "{} {}: {} for {}",
                        shader.name, p.name, t.found.pattern.params[i], t.truth.params[i]
                    ));
                }
            }
            // Whatever the parameters, the match resembles its target.
            assert!(t.found.s_f > 0.4, "{}: S_F {}", shader.name, t.found.s_f);
        }
    }
    eprintln!("recovered {recovered} of {total}; integers wrong: {integers_wrong:?}");
    assert!(
        recovered * 10 >= total * 8,
        "recovered {recovered} of {total}"
    );
    assert!(integers_wrong.is_empty(), "{integers_wrong:?}");
}

/// A small catalogue file of `shaders` in `dir`.
fn small_catalogue(dir: &Path, shaders: &str) -> std::path::PathBuf {
    catalogue_of(dir, shaders, "64", "60")
}

/// A catalogue file of `shaders` in `dir`, `samples` each at `size`².
fn catalogue_of(dir: &Path, shaders: &str, size: &str, samples: &str) -> std::path::PathBuf {
    let cat = dir.join("cat.json");
    ok(&[
        "match",
        "catalogue",
        "-o",
        s(&cat),
        "--size",
        size,
        "--samples",
        samples,
        "--shaders",
        shaders,
        "-q",
    ]);
    cat
}

#[test]
fn match_writes_the_render_and_the_parameters_the_same_for_any_threads() {
    let dir = tempfile::tempdir().unwrap();
    let d = |f: &str| dir.path().join(f);
    let cat = small_catalogue(dir.path(), "stripes,spots,clouds");
    let truth = Pattern {
        shader: by_name("spots").unwrap(),
        params: vec![6.0, 0.3, 0.2],
        colours: [[200.0, 180.0, 40.0], [30.0, 20.0, 90.0]],
    };
    imaging::save_color(&d("target.png"), &truth.render(64, 64)).unwrap();
    for t in ["1", "2"] {
        ok(&[
            "match",
            s(&d("target.png")),
            "--catalogue",
            s(&cat),
            "-o",
            s(&d(&format!("out_{t}.png"))),
            "--params",
            s(&d(&format!("p_{t}.json"))),
            "--size",
            "96x80",
            "--threads",
            t,
            "-q",
        ]);
    }
    assert!(bytes(&d("out_1.png")) == bytes(&d("out_2.png")));
    let json = |t: &str| -> serde_json::Value {
        serde_json::from_slice(&bytes(&d(&format!("p_{t}.json")))).unwrap()
    };
    let (a, b) = (json("1"), json("2"));
    for key in [
        "shader",
        "parameters",
        "colours",
        "s_f",
        "s_l",
        "colour",
        "iterations",
        "evaluations",
    ] {
        assert_eq!(a[key], b[key], "{key}");
    }
    assert!(a["seconds"].as_f64().unwrap() > 0.0);
    assert_eq!(a["shader"], "spots");
    assert_eq!(a["parameters"]["spots"], 6.0);
    let found = Pattern::from_json(&a).unwrap();
    assert!(texsyn::procedural::recovered(&truth, &found, 0.05), "{a}");
    let out = imaging::load_color(&d("out_1.png")).unwrap();
    assert_eq!((out.width, out.height), (96, 80));
    // Without --params the JSON goes to stdout.
    let r = ok(&[
        "match",
        s(&d("target.png")),
        "--catalogue",
        s(&cat),
        "--shaders",
        "spots",
        "-q",
    ]);
    let v: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    assert_eq!(v["shader"], "spots");
}

#[test]
fn transform_writes_frames_gif_webp_and_path_through_a_key_and_a_jump() {
    let dir = tempfile::tempdir().unwrap();
    let d = |f: &str| dir.path().join(f);
    let cat = small_catalogue(dir.path(), "stripes,clouds");
    // A and the key dark-on-light, B light-on-dark: the jump must keep
    // each side's orientation. (Between two stops of one shader with
    // opposite orientations the colours cross through one grey; that fade
    // is the straight path and is kept.)
    let y = |c: &[f64; 3]| 0.299 * c[0] + 0.587 * c[1] + 0.114 * c[2];
    let oriented = |mut p: Pattern, dark_low: bool| {
        if (y(&p.colours[0]) <= y(&p.colours[1])) != dark_low {
            p.colours.swap(0, 1);
        }
        p
    };
    let a = oriented(draw(by_name("stripes").unwrap(), 1), true);
    let k = oriented(draw(by_name("stripes").unwrap(), 2), true);
    let b = oriented(draw(by_name("clouds").unwrap(), 3), false);
    for (name, p) in [("a.json", &a), ("k.json", &k), ("b.json", &b)] {
        std::fs::write(d(name), p.to_json().to_string()).unwrap();
    }
    ok(&[
        "match",
        "transform",
        s(&d("a.json")),
        s(&d("b.json")),
        "--key",
        s(&d("k.json")),
        "--frames",
        "12",
        "--size",
        "48x48",
        "--catalogue",
        s(&cat),
        "-o",
        s(&d("frames")),
        "-q",
    ]);
    for i in 0..12 {
        assert!(d(&format!("frames/frame_{i:04}.png")).is_file());
    }
    // The ends are the stops as written (JSON rounds to 4 decimals).
    let (a, b) = (
        Pattern::from_json(&a.to_json()).unwrap(),
        Pattern::from_json(&b.to_json()).unwrap(),
    );
    let first = imaging::load_color(&d("frames/frame_0000.png")).unwrap();
    assert!(first.rgb == a.render(48, 48).rgb, "frame 0 is A");
    let last = imaging::load_color(&d("frames/frame_0011.png")).unwrap();
    assert!(last.rgb == b.render(48, 48).rgb, "the last frame is B");
    let gif = bytes(&d("frames/transform.gif"));
    assert_eq!(&gif[..6], b"GIF89a");
    // The animated WebP is lossless: its frames are the PNG frames.
    let webp = image::codecs::webp::WebPDecoder::new(std::io::Cursor::new(bytes(&d(
        "frames/transform.webp",
    ))))
    .unwrap();
    let anim = image::AnimationDecoder::into_frames(webp)
        .collect_frames()
        .unwrap();
    assert_eq!(anim.len(), 12);
    for (k, f) in [(0, &first), (11, &last)] {
        let rgb: Vec<u8> = anim[k]
            .buffer()
            .pixels()
            .flat_map(|p| [p[0], p[1], p[2]])
            .collect();
        assert!(rgb == f.rgb, "WebP frame {k} is the PNG frame");
    }
    let report: serde_json::Value =
        serde_json::from_slice(&bytes(&d("frames/transform.json"))).unwrap();
    assert_eq!(report["jumps"], 1, "stripes to clouds jumps once");
    assert_eq!(report["frames"].as_array().unwrap().len(), 12);
    assert_eq!(report["stops"].as_array().unwrap().len(), 3);
    // The frames change gradually: no step between adjacent frames is a
    // large share of the whole way (the jump may be one).
    let frames: Vec<ColorImage> = (0..12)
        .map(|i| imaging::load_color(&d(&format!("frames/frame_{i:04}.png"))).unwrap())
        .collect();
    let steps: Vec<f64> = frames
        .windows(2)
        .map(|w| 1.0 - spectrum_similarity(&w[0], &w[1]).unwrap())
        .collect();
    let total: f64 = steps.iter().sum();
    let big = steps.iter().filter(|&&x| x > 0.5 * total).count();
    assert!(big <= 1, "{steps:?}");
    // No frame fades out: each keeps at least a third of the contrast of
    // the weaker end (the jump keeps each side's dark-light orientation,
    // and flat samples are neither jump points nor path points).
    let sd = |img: &ColorImage| {
        let l = texsyn::imaging::colour::luminance(img);
        let n = l.data.len() as f64;
        let m = l.data.iter().map(|&v| f64::from(v)).sum::<f64>() / n;
        (l.data
            .iter()
            .map(|&v| (f64::from(v) - m).powi(2))
            .sum::<f64>()
            / n)
            .sqrt()
    };
    let floor = sd(&frames[0]).min(sd(&frames[11])) / 3.0;
    let contrasts: Vec<f64> = frames.iter().map(sd).collect();
    assert!(
        contrasts.iter().all(|&c| c >= floor),
        "{contrasts:?} against {floor}"
    );
}

/// A catalogue whose descriptors are cut short, a FIFO and a device as
/// catalogues: refused with the fix named, never a panic or a hang.
#[test]
fn damaged_or_special_catalogue_files_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = |f: &str| dir.path().join(f);
    let target = common::assets().join("brick_color_96.png");
    let cat = small_catalogue(dir.path(), "stripes");
    let json: serde_json::Value = serde_json::from_slice(&std::fs::read(&cat).unwrap()).unwrap();
    for field in ["quantiles", "bands"] {
        let mut cut = json.clone();
        cut["shaders"][0]["samples"][0]["structure"][field]
            .as_array_mut()
            .unwrap()
            .truncate(1);
        std::fs::write(d("cut.json"), cut.to_string()).unwrap();
        let e = refused(&[
            "match",
            s(&target),
            "--catalogue",
            s(&d("cut.json")),
            "-o",
            s(&d("o.png")),
        ]);
        assert!(
            e.contains("malformed") && e.contains("rebuild") && !e.contains("panicked"),
            "{field}: {e}"
        );
    }
    let fifo = d("fifo.json");
    let made = std::process::Command::new("mkfifo").arg(&fifo).status();
    if made.is_ok_and(|st| st.success()) {
        let e = refused(&[
            "match",
            s(&target),
            "--catalogue",
            s(&fifo),
            "-o",
            s(&d("o.png")),
        ]);
        assert!(e.contains("not a regular file"), "{e}");
    }
    let e = refused(&[
        "match",
        s(&target),
        "--catalogue",
        "/dev/zero",
        "-o",
        s(&d("o.png")),
    ]);
    assert!(e.contains("not a regular file"), "{e}");
    assert!(!d("o.png").exists());
}

#[test]
fn bad_input_is_refused_with_the_fix_named() {
    let dir = tempfile::tempdir().unwrap();
    let d = |f: &str| dir.path().join(f);
    let target = common::assets().join("brick_color_96.png");
    let e = refused(&["match", s(&target), "-o", s(&d("o.png"))]);
    assert!(e.contains("texsyn match catalogue"), "{e}");
    std::fs::write(d("junk.json"), "{\"not\": 1}").unwrap();
    let e = refused(&[
        "match",
        s(&target),
        "--catalogue",
        s(&d("junk.json")),
        "-o",
        s(&d("o.png")),
    ]);
    assert!(
        e.contains("not a texsyn catalogue") && e.contains("rebuild"),
        "{e}"
    );
    let e = refused(&[
        "match",
        "catalogue",
        "-o",
        s(&d("c.json")),
        "--shaders",
        "plaid",
    ]);
    assert!(
        e.contains("unknown shader 'plaid'") && e.contains("stripes"),
        "{e}"
    );
    let e = refused(&["match", "catalogue", "-o", s(&d("c.json")), "--size", "8"]);
    assert!(e.contains("32..=512"), "{e}");
    let e = refused(&["match", "catalogue", "-o", s(&d("missing/c.json"))]);
    assert!(e.contains("does not exist"), "{e}");
    let e = refused(&[
        "match",
        s(&target),
        "--catalogue",
        s(&d("junk.json")),
        "-o",
        s(&target),
    ]);
    assert!(e.contains("input"), "{e}");
    let e = refused(&["match"]);
    assert!(e.contains("give the target image"), "{e}");
    let e = refused(&[
        "match",
        "transform",
        s(&target),
        s(&target),
        "--frames",
        "1",
        "-o",
        s(&d("f")),
    ]);
    assert!(e.contains("--frames 1"), "{e}");
    assert!(!e.contains("panicked"), "{e}");
}

/// Two stripes patterns as stops `a.json` and `b.json` in `dir`.
fn stripes_stops(dir: &Path) -> (std::path::PathBuf, std::path::PathBuf) {
    let shader = by_name("stripes").unwrap();
    let stop = |name: &str, params: Vec<f64>, colours| {
        let p = dir.join(name);
        let pattern = Pattern {
            shader,
            params,
            colours,
        };
        std::fs::write(&p, pattern.to_json().to_string()).unwrap();
        p
    };
    (
        stop("a.json", vec![3.0, 10.0, 0.2, 0.1], [[0.0; 3], [255.0; 3]]),
        stop(
            "b.json",
            vec![12.0, 100.0, 0.45, 0.25],
            [[200.0, 0.0, 0.0], [0.0, 0.0, 200.0]],
        ),
    )
}

/// `match transform` holds one frame at a time: 200 frames of 512² (150 MiB
/// of pixels) are written under a 96 MiB data limit.
#[test]
fn transform_streams_frames_in_bounded_memory() {
    let dir = tempfile::tempdir().unwrap();
    let d = |f: &str| dir.path().join(f);
    let cat = small_catalogue(dir.path(), "stripes");
    let (a, b) = stripes_stops(dir.path());
    let out = std::process::Command::new("sh")
        .arg("-c")
        .arg("ulimit -d 98304 && exec \"$0\" \"$@\"")
        .arg(env!("CARGO_BIN_EXE_texsyn"))
        .args(["match", "transform", s(&a), s(&b), "--catalogue", s(&cat)])
        .args(["--frames", "200", "--size", "512x512", "--delay", "0"])
        .args(["--threads", "2", "-q", "-o", s(&d("frames"))])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(d("frames/frame_0199.png").is_file());
    assert!(d("frames/transform.json").is_file());
    assert!(!d("frames/transform.gif").exists(), "--delay 0: no GIF");
}

/// `match transform` from `stop` to `b`, with `extra` flags and defaults
/// for `--frames` and `--size`.
fn transform_args<'a>(
    stop: &'a Path,
    b: &'a Path,
    cat: &'a Path,
    extra: &[&'a str],
) -> Vec<&'a str> {
    let mut args = vec!["match", "transform", s(stop), s(b), "--catalogue"];
    args.extend([s(cat), "-q"]);
    args.extend(extra);
    for (flag, default) in [("--frames", "3"), ("--size", "32x32")] {
        if !extra.contains(&flag) {
            args.extend([flag, default]);
        }
    }
    args
}

/// Every flag of `match transform` is checked before any work: nothing is
/// written, and the old output set is left whole.
#[test]
fn transform_checks_every_flag_before_writing() {
    let dir = tempfile::tempdir().unwrap();
    let d = |f: &str| dir.path().join(f);
    let cat = small_catalogue(dir.path(), "stripes");
    let (a, b) = stripes_stops(dir.path());
    let target = common::assets().join("brick_color_96.png");
    let frames = d("frames");
    for (extra, needle) in [
        (vec!["--delay", "20000000"], "--delay 20000000"),
        (vec!["--size", "20000x16"], "--size 20000x16"),
        (vec!["--exponent", "0.5"], "exponent"),
        (vec!["--starts", "0"], "--starts 0"),
    ] {
        let mut args = transform_args(&target, &b, &cat, &extra);
        args.extend(["-o", s(&frames)]);
        let e = refused(&args);
        assert!(e.contains(needle) && !e.contains("panicked"), "{e}");
        assert!(!frames.exists(), "{extra:?}: an output was written");
    }
    // A directory of someone else's files is refused before any work.
    std::fs::create_dir(d("mine")).unwrap();
    std::fs::write(d("mine/notes.txt"), "x").unwrap();
    let mine = d("mine");
    let mut args = transform_args(&a, &b, &cat, &[]);
    args.extend(["-o", s(&mine)]);
    let e = refused(&args);
    assert!(e.contains("did not write"), "{e}");
    assert!(!d("mine/frame_0000.png").exists());
    // A set written before is replaced whole: no stale file is left.
    let mut args = transform_args(&a, &b, &cat, &["--frames", "4"]);
    args.extend(["-o", s(&frames)]);
    ok(&args);
    assert!(frames.join("frame_0003.png").is_file());
    let mut args = transform_args(&a, &b, &cat, &["--frames", "2", "--delay", "0"]);
    args.extend(["-o", s(&frames)]);
    ok(&args);
    assert!(frames.join("frame_0001.png").is_file());
    assert!(!frames.join("frame_0002.png").exists());
    assert!(!frames.join("transform.gif").exists());
}

/// A FIFO, a device and a cut catalogue given to `match transform`, and a
/// FIFO as a stop: refused, never a hang, a panic or a filled memory.
#[test]
fn transform_refuses_special_or_damaged_inputs() {
    let dir = tempfile::tempdir().unwrap();
    let d = |f: &str| dir.path().join(f);
    let cat = small_catalogue(dir.path(), "stripes");
    let (a, b) = stripes_stops(dir.path());
    let run = |stop: &Path, cat: &Path| {
        refused(&[
            "match",
            "transform",
            s(stop),
            s(&b),
            "--catalogue",
            s(cat),
            "--frames",
            "3",
            "--size",
            "32x32",
            "-o",
            s(&d("frames")),
        ])
    };
    let json: serde_json::Value = serde_json::from_slice(&bytes(&cat)).unwrap();
    for field in ["quantiles", "bands"] {
        let mut cut = json.clone();
        cut["shaders"][0]["samples"][0]["structure"][field]
            .as_array_mut()
            .unwrap()
            .truncate(1);
        std::fs::write(d("cut.json"), cut.to_string()).unwrap();
        let e = run(&a, &d("cut.json"));
        assert!(e.contains("malformed") && !e.contains("panicked"), "{e}");
    }
    let e = run(&a, Path::new("/dev/zero"));
    assert!(e.contains("not a file"), "{e}");
    let fifo = d("fifo.json");
    let made = std::process::Command::new("mkfifo").arg(&fifo).status();
    if made.is_ok_and(|st| st.success()) {
        for (stop, cat) in [(&a, &fifo), (&fifo, &cat)] {
            let e = run(stop, cat);
            assert!(e.contains("not a file"), "{e}");
        }
    }
    assert!(!d("frames").exists());
}

/// The labelled photos (`assets/textures/structure_labels.txt`): the file
/// parses, names bundled photos, and the structure read before any search
/// (the periods, §3.2.1) seeds the rows of the photos whose joints are
/// regular within 15% of the count measured by hand. The whole match of
/// every labelled photo is `texsyn-bench match --labels`, too slow here.
#[test]
fn labelled_photos_seed_their_rows_and_a_planted_label_fails() {
    use texsyn::procedural::labels::{self, check};
    use texsyn::procedural::objective::periodicity_of;
    use texsyn::procedural::periodicity::seeded;
    let text = std::fs::read_to_string(common::assets().join("structure_labels.txt")).unwrap();
    let list = labels::parse(&text).unwrap();
    assert!(list.len() >= 12, "{} labelled photos", list.len());
    for l in &list {
        assert!(common::assets().join(&l.file).is_file(), "{}", l.file);
    }
    // Structure first: the arrangement read before any shader is tried.
    use texsyn::procedural::arrangement::Arrangement;
    for (name, want) in [
        ("tiles_color_256.png", Arrangement::Lattice),
        ("rain_color_108.png", Arrangement::Parallel),
        ("mossy_rock_color_128.png", Arrangement::Isotropic),
    ] {
        let img = texsyn::procedural::analysis_image(&common::texture(name), 128);
        let (_, a) = periodicity_of(&img);
        assert_eq!(a.arrangement, want, "{name}: {a:?}");
    }
    let bricks = by_name("bricks").unwrap();
    let mid: Vec<f64> = bricks.params.iter().map(|p| p.from_unit(0.5)).collect();
    // The facade's fine grid (24 rows, 1-px joints) is read across its
    // rows, not obliquely at a longer period; the 96-px wall's courses,
    // not the striation within its stones.
    for name in [
        "brick_gray_256.png",
        "tiles_color_256.png",
        "facade_tiles_color_256.png",
        "brick_color_96.png",
    ] {
        let l = list.iter().find(|l| l.file == name).unwrap();
        let img = texsyn::procedural::analysis_image(&common::texture(name), 128);
        let params = seeded(bricks, &mid, &periodicity_of(&img).0).expect("rows seen");
        let found = Pattern {
            shader: bricks,
            params,
            colours: [[0.0; 3], [255.0; 3]],
        };
        let v = check(l, &found);
        assert!(v.right, "{name}: {v:?} against {l:?}");
        // The same match against a planted wrong label: a count 30% off
        // and another family both fail.
        let mut wrong = l.clone();
        wrong.count = l.count.map(|c| c * 1.3);
        assert!(!check(&wrong, &found).right, "{name}: planted count passed");
        wrong = l.clone();
        wrong.families = vec!["planks".into()];
        assert!(
            !check(&wrong, &found).right,
            "{name}: planted family passed"
        );
    }
}

/// Noise against scattered features (§3.3): split at the median, the
/// labelled photos of spots, beans and caustic cells keep one tone joined
/// and break the other into pieces, the burl and the rock break both; the
/// cells, spots and clouds shaders do the same at their middle parameters
/// (turbulence does not: its creases join up round bright pieces). This is
/// what the structure term of an isotropic target adds to the periods, and
/// what seeds a scattered shader's count: the leopard's pieces put the
/// cells shader at its hand-counted 4 rosettes per side.
#[test]
fn the_tones_pieces_tell_scattered_features_from_noise() {
    use texsyn::procedural::objective::periodicity_of;
    use texsyn::procedural::periodicity::{seeded, SCATTERED};
    use texsyn::procedural::pieces::pieces;
    let of_photo = |name: &str| {
        let img = texsyn::procedural::analysis_image(&common::texture(name), 128);
        periodicity_of(&img).0
    };
    for name in [
        "leopard_color_64.png",
        "coffee_beans_color_256.png",
        "water_pool_color_94.png",
    ] {
        let p = of_photo(name).pieces;
        assert!(p.separation >= SCATTERED, "{name}: {p:?}");
    }
    for name in ["walnut_color_128.png", "mossy_rock_color_128.png"] {
        let p = of_photo(name).pieces;
        assert!(p.separation < SCATTERED, "{name}: {p:?}");
    }
    for (shader, scattered) in [("cells", true), ("spots", true), ("clouds", false)] {
        let sh = by_name(shader).unwrap();
        let mid: Vec<f64> = sh.params.iter().map(|p| p.from_unit(0.5)).collect();
        let field = sh.render_field(&mid, 128, 128, 128);
        let v: Vec<f64> = field.iter().map(|&x| f64::from(x)).collect();
        let p = pieces(&v, 128);
        assert_eq!(p.separation >= SCATTERED, scattered, "{shader}: {p:?}");
    }
    let cells = by_name("cells").unwrap();
    let mid: Vec<f64> = cells.params.iter().map(|p| p.from_unit(0.5)).collect();
    let params = seeded(cells, &mid, &of_photo("leopard_color_64.png")).expect("a count");
    assert_eq!(params[0], 4.0, "{params:?}");
}

/// Stones (§3.3): a parallel target whose tones break into separate
/// pieces (the bundled flagstones, elongated along a diagonal; the brick
/// courses) is open to the scattered shaders, and its pieces count in the
/// structure term. Veins (the pink marble) and streaks (the rain) are
/// parallel and their tones join up; a lattice and an isotropic target are
/// not stones. With a catalogue of `marble` and `cells` only, the
/// flagstones go to `cells` (without the rule the arrangement keeps
/// `marble` alone) and the marble stays `marble`.
#[test]
fn elongated_stones_go_to_cells_and_veins_stay_marble() {
    use texsyn::procedural::objective::periodicity_of;
    for (name, want) in [
        ("stone33_color_156.png", true),
        ("brick_gray_256.png", true),
        ("pink_marble_color_128.png", false),
        ("rain_color_108.png", false),
        ("brick_color_96.png", false),
        ("coffee_beans_color_256.png", false),
    ] {
        let img = texsyn::procedural::analysis_image(&common::texture(name), 128);
        let (per, a) = periodicity_of(&img);
        assert_eq!(a.stones(&per), want, "{name}: {a:?} {:?}", per.pieces);
    }
    let dir = tempfile::tempdir().unwrap();
    let cat = catalogue_of(dir.path(), "marble,cells", "128", "40");
    for (name, want) in [
        ("stone33_color_156.png", "cells"),
        ("pink_marble_color_128.png", "marble"),
    ] {
        let r = ok(&[
            "match",
            s(&common::assets().join(name)),
            "--catalogue",
            s(&cat),
            "-o",
            s(&dir.path().join("out.png")),
            "-q",
        ]);
        let v: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
        assert_eq!(v["shader"], want, "{name}: {v}");
    }
}
