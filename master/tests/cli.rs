//! The `texsyn` binary on good and bad input: bad input gets one clear error
//! line and a non-zero exit, never a panic or a partial output file.

use crate::common;

use std::path::Path;

use common::{assets, ok, s, texsyn};

/// Runs a command that must fail: non-zero exit, no panic, one error line with
/// every expected word, and no output file left behind.
fn fails(args: &[&str], out: &Path, words: &[&str]) {
    let o = texsyn(args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{args:?} succeeded");
    assert_eq!(
        o.status.code(),
        Some(1),
        "{args:?}: exit code, stderr: {err}"
    );
    assert!(!err.contains("panicked"), "{args:?} panicked: {err}");
    let line = err
        .lines()
        .find(|l| l.starts_with("texsyn: error:"))
        .unwrap_or_else(|| panic!("no error line: {err}"));
    for w in words {
        assert!(
            line.to_lowercase().contains(&w.to_lowercase()),
            "{args:?}: '{line}' lacks '{w}'"
        );
    }
    assert!(!out.exists(), "{args:?} left an output file");
    let dir = out.parent().unwrap();
    let leftovers: Vec<_> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().contains("tmp"))
        .collect();
    assert!(leftovers.is_empty(), "temp files left: {leftovers:?}");
}

#[test]
fn good_runs_write_image_copy_map_levels_and_report() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.png");
    let map = dir.path().join("map.png");
    let report = dir.path().join("run.json");
    let levels = dir.path().join("levels");
    let sample = assets().join("brick_color_96.png");
    let o = texsyn(&[
        "extend",
        s(&sample),
        "-o",
        s(&out),
        "--size",
        "128x112",
        "--tileable",
        "--seed",
        "3",
        "--copy-map",
        s(&map),
        "--levels-dir",
        s(&levels),
        "--report",
        s(&report),
        "--chroma-blur",
        "1",
        "-q",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let img = image::open(&out).unwrap();
    assert_eq!((img.width(), img.height()), (128, 112));
    assert_eq!(image::open(&map).unwrap().width(), 128);
    let json: serde_json::Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    let per_level = json["per_level"].as_array().unwrap();
    assert_eq!(per_level.len(), json["levels"].as_u64().unwrap() as usize);
    for l in per_level {
        assert!(l["reference_vectors"].as_u64().unwrap() > 0);
        let search = l["search_seconds"].as_f64().unwrap();
        assert!(search > 0.0 && search.is_finite(), "search took {search} s");
        assert!(l["queries"].as_u64().unwrap() > 0);
    }
    assert!(levels.join("level0.png").exists());
    // Fill and synth through the binary as well.
    let fill_out = dir.path().join("fill.jpg");
    let o = texsyn(&[
        "fill",
        s(&assets().join("coffee_scribble_color_400.png")),
        "--mask",
        s(&assets().join("coffee_scribble_mask_400.png")),
        "-o",
        s(&fill_out),
        "-q",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let synth_out = dir.path().join("synth.png");
    let o = texsyn(&[
        "synth",
        s(&sample),
        "-o",
        s(&synth_out),
        "--size",
        "64x48",
        "--method",
        "scanline",
        "-q",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(image::open(&synth_out).unwrap().height(), 48);
}

/// `--lattice auto` finds the bundled tiles' 32-px grid, records it in the
/// report, and gives the bytes of that period given by hand; `none` is no
/// lattice.
#[test]
fn lattice_auto_is_the_grid_it_finds() {
    let dir = tempfile::tempdir().unwrap();
    let sample = assets().join("tiles_color_256.png");
    let run = |name: &str, flags: &[&str]| -> (Vec<u8>, serde_json::Value) {
        let (out, report) = (
            dir.path().join(format!("{name}.png")),
            dir.path().join(format!("{name}.json")),
        );
        let args = [
            &["synth", s(&sample), "-o", s(&out), "-q", "--size", "96x80"][..],
            &["--report", s(&report)],
            flags,
        ]
        .concat();
        ok(&args);
        let r: serde_json::Value =
            serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
        (std::fs::read(&out).unwrap(), r["lattice"].clone())
    };
    let (auto, found) = run("auto", &["--lattice", "auto"]);
    let period = |i: usize| found[i].as_f64().unwrap();
    assert!((0..2).all(|i| (period(i) - 32.0).abs() < 0.2), "{found}");
    let given = format!("{}x{}", period(0), period(1));
    let (by_hand, recorded) = run("given", &["--lattice", &given]);
    assert!(
        auto == by_hand,
        "--lattice auto differs from --lattice {given}"
    );
    assert_eq!(recorded, found);
    let (plain, none) = run("none", &["--lattice", "none"]);
    assert!(none.is_null() && plain != auto, "{none}");
}

#[test]
fn bad_input_fails_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("out.png");
    let sample = assets().join("brick_color_96.png");
    let coffee = assets().join("coffee_scribble_color_400.png");
    let mask = assets().join("coffee_scribble_mask_400.png");
    let not_image = d.join("notes.png");
    std::fs::write(&not_image, "this is text, not a PNG").unwrap();
    let tiny = d.join("tiny.png");
    image::RgbImage::new(6, 6).save(&tiny).unwrap();
    let black = d.join("black.png");
    image::GrayImage::new(400, 400).save(&black).unwrap();
    let white = d.join("white.png");
    image::GrayImage::from_pixel(400, 400, image::Luma([255]))
        .save(&white)
        .unwrap();
    let o = s(&out);
    let sm = s(&sample);

    fails(
        &["extend", "/no/such/file.png", "-o", o, "--size", "200x200"],
        &out,
        &["no such file", "/no/such/file.png"],
    );
    // A level over the memory budget stops before it is built.
    fails(
        &[
            "synth",
            sm,
            "-o",
            o,
            "--size",
            "300x300",
            "--max-memory",
            "1",
            "--vector-store",
            "dense",
        ],
        &out,
        &["reference vectors need", "--local-workers", "--search auto"],
    );
    fails(
        &[
            "synth",
            sm,
            "-o",
            o,
            "--size",
            "64x64",
            "--vector-store",
            "disk",
        ],
        &out,
        &["vector storage 'disk'", "planes"],
    );
    fails(
        &["extend", s(&not_image), "-o", o, "--size", "200x200"],
        &out,
        &["notes.png"],
    );
    fails(
        &["synth", s(&tiny), "-o", o, "--size", "64x64"],
        &out,
        &["6×6", "neighbourhood"],
    );
    fails(
        &["fill", sm, "--mask", s(&mask), "-o", o],
        &out,
        &["mask", "400"],
    );
    fails(
        &["fill", s(&coffee), "--mask", s(&black), "-o", o],
        &out,
        &["no hole"],
    );
    fails(
        &["fill", s(&coffee), "--mask", s(&white), "-o", o],
        &out,
        &["all hole"],
    );
    fails(
        &["synth", sm, "-o", o, "--size", "64x64", "--block", "4"],
        &out,
        &["block size 4", "odd"],
    );
    fails(
        &["synth", sm, "-o", o, "--size", "64x64", "--block", "13"],
        &out,
        &["block size 13"],
    );
    fails(
        &[
            "synth",
            sm,
            "-o",
            o,
            "--size",
            "64x64",
            "--neighbourhood",
            "8",
        ],
        &out,
        &["neighbourhood 8"],
    );
    fails(
        &[
            "synth",
            sm,
            "-o",
            o,
            "--size",
            "64x64",
            "--block",
            "9",
            "--neighbourhood",
            "9",
        ],
        &out,
        &["larger than the block"],
    );
    fails(
        &["synth", sm, "-o", o, "--size", "64x64", "--levels", "6"],
        &out,
        &["levels", "fewer"],
    );
    fails(
        &["synth", sm, "-o", "/no/such/dir/out.png", "--size", "64x64"],
        Path::new("/no/such/dir/out.png"),
        &["/no/such/dir"],
    );
    fails(
        &["synth", sm, "-o", s(&d.join("out.xyz")), "--size", "64x64"],
        &d.join("out.xyz"),
        &["xyz"],
    );
    fails(
        &["synth", sm, "-o", o, "--size", "100000x100000"],
        &out,
        &["limit"],
    );
    fails(&["synth", sm, "-o", o, "--size", "0x10"], &out, &["size"]);
    fails(&["synth", sm, "-o", o, "--size", "ax10"], &out, &["width"]);
    fails(
        &["synth", sm, "-o", o, "--size", "64x64", "--weights", "0,0"],
        &out,
        &["weights"],
    );
    fails(
        &[
            "synth",
            sm,
            "-o",
            o,
            "--size",
            "64x64",
            "--search",
            "local,local,local,local,local,local",
        ],
        &out,
        &["plan", "level"],
    );
    fails(
        &["extend", sm, "-o", o, "--size", "50x50"],
        &out,
        &["smaller than"],
    );
}

#[test]
fn failed_run_does_not_clobber_an_existing_output() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("keep.png");
    std::fs::write(&out, b"previous result").unwrap();
    let o = texsyn(&[
        "synth",
        s(&assets().join("brick_color_96.png")),
        "-o",
        s(&out),
        "--size",
        "64x64",
        "--block",
        "2",
    ]);
    assert!(!o.status.success());
    assert_eq!(std::fs::read(&out).unwrap(), b"previous result");
}

#[test]
fn help_shows_examples() {
    let o = texsyn(&["--help"]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success());
    assert!(text.contains("texsyn extend sample.png -o out.png --size 1024x1024"));
    assert!(text.contains("texsyn fill photo.png --mask holes.png"));
}

/// Vectors gathered from the planes give the image of dense vectors, and a
/// memory cap the dense vectors would break switches `auto` to the planes
/// instead of failing.
#[test]
fn vector_stores_give_the_same_image() {
    let dir = tempfile::tempdir().unwrap();
    let sample = assets().join("gravel_gray_500.png");
    let run = |name: &str, extra: &[&str]| {
        let out = dir.path().join(name);
        let mut args = vec![
            "synth",
            s(&sample),
            "-o",
            s(&out),
            "--size",
            "160x160",
            "--seed",
            "5",
            "-q",
        ];
        args.extend_from_slice(extra);
        let o = texsyn(&args);
        assert!(
            o.status.success(),
            "{extra:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        std::fs::read(&out).unwrap()
    };
    let dense = run("dense.png", &["--vector-store", "dense"]);
    assert_eq!(dense, run("planes.png", &["--vector-store", "planes"]));
    // 500² × 192 B of dense vectors is over 10 MB; the planes are 0.3 MB.
    assert_eq!(dense, run("auto.png", &["--max-memory", "10"]));
}

/// Runs `texsyn` with a time limit (a hang fails the test instead of
/// blocking it).
fn texsyn_within(args: &[&str], limit: std::time::Duration) -> std::process::Output {
    use std::process::{Command, Stdio};
    let mut child = Command::new(env!("CARGO_BIN_EXE_texsyn"))
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run texsyn");
    let start = std::time::Instant::now();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            panic!("{args:?} still runs after {limit:?}");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    child.wait_with_output().unwrap()
}

/// The `.tmp-` files in `dir`.
fn temp_files(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains(".tmp-"))
        .collect()
}

/// A run that must be refused: exit code 1, exactly one line on stderr (the
/// error, with every expected word), no panic, no `.tmp-` file next to `out`,
/// and `out`, created beforehand with known bytes, unchanged.
fn refuses(args: &[&str], out: &Path, words: &[&str]) {
    const KEEP: &[u8] = b"an earlier result that must survive";
    std::fs::write(out, KEEP).unwrap();
    let o = texsyn_within(args, std::time::Duration::from_secs(120));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{args:?}: stderr: {err}");
    let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "{args:?}: not one line: {err}");
    let line = lines[0];
    assert!(line.starts_with("texsyn: error: "), "{args:?}: {line}");
    assert!(!line.contains("panicked"), "{args:?}: {line}");
    for w in words {
        assert!(
            line.to_lowercase().contains(&w.to_lowercase()),
            "{args:?}: '{line}' lacks '{w}'"
        );
    }
    assert_eq!(
        std::fs::read(out).unwrap(),
        KEEP,
        "{args:?} clobbered {out:?}"
    );
    let dir = out.parent().unwrap();
    assert!(temp_files(dir).is_empty(), "{args:?} left temp files");
}

#[test]
fn overflowing_numbers_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.png");
    let sample = assets().join("brick_color_96.png");
    let (o, sm) = (s(&out), s(&sample));
    let max = "18446744073709551615";
    let ext = |extra: &[&'static str]| {
        let mut a = vec!["extend", sm, "-o", o, "--size", "200x200"];
        a.extend_from_slice(extra);
        a
    };
    refuses(
        &ext(&["--position", "18446744073709551615,0"]),
        &out,
        &["--position", "x 18446744073709551615"],
    );
    refuses(
        &ext(&["--position", "0,18446744073709551615"]),
        &out,
        &["y 18446744073709551615"],
    );
    refuses(
        &ext(&["--position", "18446744073709551616,0"]),
        &out,
        &["not a whole number"],
    );
    refuses(&ext(&["--position=-1,0"]), &out, &["--position"]);
    refuses(
        &ext(&["--position", "150,0"]),
        &out,
        &["outside the 200×200 canvas", "X ≤ 104"],
    );
    refuses(
        &["synth", sm, "-o", o, "--size", &format!("{max}x{max}")],
        &out,
        &["too large", "--size"],
    );
    refuses(
        &["synth", sm, "-o", o, "--size", "4294967296x4294967296"],
        &out,
        &["too large", "--size"],
    );
    for (flag, word) in [
        ("--levels", "levels"),
        ("--batch", "batch"),
        ("--block", "block size"),
        ("--neighbourhood", "neighbourhood"),
        ("--parent-window", "parent window"),
        ("--chroma-blur", "chroma blur"),
        ("--threads", "--threads"),
        ("--lbg-probes", "--lbg-probes"),
    ] {
        refuses(
            &["synth", sm, "-o", o, "--size", "64x64", flag, max],
            &out,
            &[word],
        );
    }
    refuses(
        &[
            "synth",
            sm,
            "-o",
            o,
            "--size",
            "64x64",
            "--level-sample",
            &format!("{max}0=x.png"),
        ],
        &out,
        &["--level-sample"],
    );
    for t in ["nan", "inf", "-inf", "-1", "0", "1e300", "NaN", "x"] {
        let timeout = format!("--timeout={t}");
        refuses(
            &["cluster", "status", "--workers", "127.0.0.1:1", &timeout],
            &out,
            &["--timeout", &format!("'{t}'"), "between 0.1 and 600"],
        );
        let worker_timeout = format!("--worker-timeout={t}");
        refuses(
            &[
                "synth",
                sm,
                "-o",
                o,
                "--size",
                "64x64",
                "--workers",
                "127.0.0.1:1",
                &worker_timeout,
            ],
            &out,
            &["--worker-timeout", "between 0.01 and 3600"],
        );
    }
    refuses(
        &[
            "synth",
            sm,
            "-o",
            o,
            "--size",
            "64x64",
            "--workers",
            "127.0.0.1:1",
            "--local-worker-threads",
            "1",
        ],
        &out,
        &["--local-worker-threads"],
    );
    // A usage error is one line too.
    refuses(&["synth", sm, "-o", o], &out, &["--size"]);
    refuses(
        &["synth", sm, "-o", o, "--size", "64x64", "--bogus"],
        &out,
        &["--bogus"],
    );
}

#[test]
fn output_paths_are_checked_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("out.png");
    let o = s(&out);
    let sample = d.join("sample.png");
    std::fs::copy(assets().join("brick_color_96.png"), &sample).unwrap();
    let sm = s(&sample);
    let synth = |extra: &[&str]| {
        let mut a = vec!["synth", sm, "-o", o, "--size", "64x64"];
        a.extend_from_slice(extra);
        a.into_iter().map(String::from).collect::<Vec<_>>()
    };
    let run = |args: Vec<String>, keep: &Path, words: &[&str]| {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        refuses(&args, keep, words);
    };
    run(
        synth(&["--copy-map", o]),
        &out,
        &["-o and --copy-map", "own file"],
    );
    run(synth(&["--report", o]), &out, &["-o and --report"]);
    let other = format!("{}/./sub/../out.png", d.display());
    std::fs::create_dir(d.join("sub")).unwrap();
    run(synth(&["--report", &other]), &out, &["-o and --report"]);
    let map = d.join("map.png");
    run(
        synth(&["--copy-map", s(&map), "--report", s(&map)]),
        &map,
        &["--copy-map and --report"],
    );
    // Level images would overwrite an output or an input.
    let levels = d.join("levels");
    let level0 = levels.join("level0.png");
    std::fs::create_dir(&levels).unwrap();
    run(
        vec![
            "synth".into(),
            sm.into(),
            "-o".into(),
            s(&level0).into(),
            "--size".into(),
            "64x64".into(),
            "--levels-dir".into(),
            s(&levels).into(),
        ],
        &level0,
        &["--levels-dir", "level0.png"],
    );
    let level2 = levels.join("level2.png");
    run(
        synth(&["--levels-dir", s(&levels), "--copy-map", s(&level2)]),
        &level2,
        &["--copy-map", "--levels-dir"],
    );
    run(
        vec![
            "synth",
            s(&level2),
            "-o",
            o,
            "--size",
            "64x64",
            "--levels-dir",
            s(&levels),
        ]
        .into_iter()
        .map(String::from)
        .collect(),
        &out,
        &["input", "--levels-dir"],
    );
    // An output on an input: the input is kept.
    let before = std::fs::read(&sample).unwrap();
    let o = texsyn_within(
        &["synth", sm, "-o", sm, "--size", "64x64"],
        std::time::Duration::from_secs(60),
    );
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("is the input") && err.lines().count() == 1,
        "{err}"
    );
    assert_eq!(std::fs::read(&sample).unwrap(), before);
    let spelled = format!("{}/sub/../sample.png", d.display());
    let o = texsyn_within(
        &["extend", sm, "-o", &spelled, "--size", "128x128"],
        std::time::Duration::from_secs(60),
    );
    assert_eq!(o.status.code(), Some(1));
    assert_eq!(std::fs::read(&sample).unwrap(), before);
    let mask = d.join("mask.png");
    image::GrayImage::from_pixel(96, 96, image::Luma([255]))
        .save(&mask)
        .unwrap();
    let o = texsyn_within(
        &["fill", sm, "--mask", s(&mask), "-o", s(&mask)],
        std::time::Duration::from_secs(60),
    );
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--mask"));
    // Format limits are checked before the synthesis.
    let webp = d.join("big.webp");
    let start = std::time::Instant::now();
    refuses(
        &["synth", sm, "-o", s(&webp), "--size", "16384x16"],
        &webp,
        &["WebP", "16383", "16384x16", ".png"],
    );
    // A copy map is an exact 16-bit PNG; another format is refused up front.
    let tif = d.join("map.webp");
    refuses(
        &[
            "synth",
            sm,
            "-o",
            s(&out),
            "--size",
            "20000x20",
            "--copy-map",
            s(&tif),
        ],
        &tif,
        &["map.webp", "coordinate map", ".png"],
    );
    assert!(
        start.elapsed() < std::time::Duration::from_secs(10),
        "refused late"
    );
}

/// A PNG with a valid signature and IHDR claiming `w`×`h`, then a bogus IDAT.
fn lying_png(w: u32, h: u32) -> Vec<u8> {
    fn chunk(out: &mut Vec<u8>, kind: &[u8], data: &[u8]) {
        out.extend_from_slice(&(data.len() as u32).to_be_bytes());
        let mut c = kind.to_vec();
        c.extend_from_slice(data);
        out.extend_from_slice(&c);
        out.extend_from_slice(&crc32(&c).to_be_bytes());
    }
    let mut ihdr = Vec::new();
    ihdr.extend_from_slice(&w.to_be_bytes());
    ihdr.extend_from_slice(&h.to_be_bytes());
    ihdr.extend_from_slice(&[8, 2, 0, 0, 0]);
    let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
    chunk(&mut out, b"IHDR", &ihdr);
    chunk(&mut out, b"IDAT", &[0x78, 0x9c, 1, 2, 3, 4]);
    chunk(&mut out, b"IEND", &[]);
    out
}

fn crc32(data: &[u8]) -> u32 {
    let mut c = 0xFFFF_FFFFu32;
    for &b in data {
        c ^= u32::from(b);
        for _ in 0..8 {
            c = if c & 1 != 0 {
                0xEDB8_8320 ^ (c >> 1)
            } else {
                c >> 1
            };
        }
    }
    !c
}

/// The file `name` in `dir` holding `bytes`, as an argument.
fn file(dir: &Path, name: &str, bytes: &[u8]) -> String {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    s(&p).to_string()
}

/// `img` encoded as `fmt`.
fn encoded(img: &image::DynamicImage, fmt: image::ImageFormat) -> Vec<u8> {
    let mut buf = std::io::Cursor::new(Vec::new());
    img.write_to(&mut buf, fmt).unwrap();
    buf.into_inner()
}

#[test]
fn bad_images_are_refused_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("out.png");
    let sample = image::open(assets().join("brick_color_96.png")).unwrap();
    let rgb = image::DynamicImage::ImageRgb8(sample.to_rgb8());
    let jpeg = encoded(&rgb, image::ImageFormat::Jpeg);
    let tiff = encoded(&rgb, image::ImageFormat::Tiff);
    let webp = encoded(&rgb, image::ImageFormat::WebP);
    let png = encoded(&rgb, image::ImageFormat::Png);
    let half = |b: &[u8]| b[..b.len() / 2].to_vec();

    // A JPEG whose frame header claims 65535×65535.
    let mut big_jpeg = jpeg.clone();
    let sof = big_jpeg
        .windows(2)
        .position(|w| w == [0xFF, 0xC0])
        .expect("baseline frame header");
    big_jpeg[sof + 5..sof + 9].copy_from_slice(&[0xFF, 0xFF, 0xFF, 0xFF]);
    // A TIFF whose ImageWidth tag claims 100000 (little-endian, first IFD).
    let mut big_tiff = tiff.clone();
    assert_eq!(&big_tiff[..2], b"II");
    let ifd = u32::from_le_bytes(big_tiff[4..8].try_into().unwrap()) as usize;
    let n = u16::from_le_bytes(big_tiff[ifd..ifd + 2].try_into().unwrap()) as usize;
    let entry = (0..n)
        .map(|k| ifd + 2 + 12 * k)
        .find(|&e| u16::from_le_bytes(big_tiff[e..e + 2].try_into().unwrap()) == 256)
        .expect("ImageWidth tag");
    big_tiff[entry + 2..entry + 4].copy_from_slice(&4u16.to_le_bytes());
    big_tiff[entry + 8..entry + 12].copy_from_slice(&100_000u32.to_le_bytes());
    // A WebP whose extended header (VP8X) claims a 16384×16384 canvas (the
    // format's largest), over a lossless bitstream claiming the same.
    let mut big_webp = b"RIFF\x00\x00\x00\x00WEBPVP8X".to_vec();
    big_webp.extend_from_slice(&10u32.to_le_bytes());
    big_webp.extend_from_slice(&[0, 0, 0, 0, 0xFF, 0x3F, 0, 0xFF, 0x3F, 0]);
    big_webp.extend_from_slice(b"VP8L");
    big_webp.extend_from_slice(&16u32.to_le_bytes());
    big_webp.push(0x2f);
    big_webp.extend_from_slice(&0x0FFF_FFFFu32.to_le_bytes());
    big_webp.extend_from_slice(&[0; 11]);
    let riff = (big_webp.len() - 8) as u32;
    big_webp[4..8].copy_from_slice(&riff.to_le_bytes());

    let wide = d.join("wide.png");
    image::RgbImage::new(32769, 1).save(&wide).unwrap();

    let cases: Vec<(String, Vec<&str>)> = vec![
        (
            file(d, "lying.png", &lying_png(100_000, 100_000)),
            vec!["lying.png", "100000x100000", "limit"],
        ),
        (
            file(d, "lying.jpg", &big_jpeg),
            vec!["lying.jpg", "65535x65535", "limit"],
        ),
        (file(d, "lying.tif", &big_tiff), vec!["lying.tif"]),
        (
            file(d, "lying.webp", &big_webp),
            vec!["lying.webp", "16384x16384", "limit"],
        ),
        (
            file(d, "cut.png", &half(&png)),
            vec!["cut.png", "truncated"],
        ),
        (
            file(d, "cut.jpg", &half(&jpeg)),
            vec!["cut.jpg", "end-of-image", "truncated"],
        ),
        (
            file(d, "cut.tif", &half(&tiff)),
            vec!["cut.tif", "truncated"],
        ),
        (
            file(d, "cut.webp", &half(&webp)),
            vec!["cut.webp", "truncated"],
        ),
        (
            file(d, "text.webp", b"RIFF but not really"),
            vec!["text.webp", "not an image"],
        ),
        (file(d, "zero.png", b""), vec!["zero.png", "empty file"]),
        (s(&wide).to_string(), vec!["wide.png", "32769x1", "32768"]),
    ];
    for (input, words) in &cases {
        refuses(
            &["synth", input, "-o", s(&out), "--size", "64x64"],
            &out,
            words,
        );
    }
    // A FIFO is refused before it is opened (opening one would wait for a writer).
    #[cfg(unix)]
    {
        let fifo = d.join("pipe.png");
        assert!(std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap()
            .success());
        refuses(
            &["synth", s(&fifo), "-o", s(&out), "--size", "64x64"],
            &out,
            &["pipe.png", "not a regular file"],
        );
        let img = d.join("img.png");
        std::fs::write(&img, &png).unwrap();
        refuses(
            &["fill", s(&img), "--mask", s(&fifo), "-o", s(&out)],
            &out,
            &["pipe.png", "not a regular file"],
        );
    }
}

/// The format comes from the content, not the extension: a PNG named `.jpg`
/// loads as the PNG it is.
#[test]
fn content_decides_the_input_format() {
    let dir = tempfile::tempdir().unwrap();
    let named_jpg = dir.path().join("really_a_png.jpg");
    std::fs::copy(assets().join("brick_color_96.png"), &named_jpg).unwrap();
    let out = dir.path().join("out.png");
    let o = texsyn(&[
        "synth",
        s(&named_jpg),
        "-o",
        s(&out),
        "--size",
        "48x48",
        "-q",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(image::open(&out).unwrap().width(), 48);
}

/// 16-bit and RGBA masks work: a pixel is a hole when its luminance times its
/// opacity is at least 128/255.
#[test]
fn sixteen_bit_and_alpha_masks_mark_holes_by_threshold() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let magenta = image::Rgb([255u8, 0, 255]);
    let sample = image::open(assets().join("brick_color_96.png"))
        .unwrap()
        .to_rgb8();
    let mut img = sample.clone();
    // The hole (x, y in 40..52) is painted magenta, absent from the brick sample.
    let hole = |x: u32, y: u32| (40..52).contains(&x) && (40..52).contains(&y);
    for (x, y, p) in img.enumerate_pixels_mut() {
        if hole(x, y) {
            *p = magenta;
        }
    }
    let input = d.join("in.png");
    img.save(&input).unwrap();
    // 16-bit grey: 40000/65535 ≈ 156/255 marks a hole, 30000 ≈ 117/255 does not.
    let mask16 = image::ImageBuffer::from_fn(96, 96, |x, y| {
        image::Luma([if hole(x, y) {
            40000u16
        } else if x < 20 {
            30000
        } else {
            0
        }])
    });
    let m16 = d.join("mask16.png");
    mask16.save(&m16).unwrap();
    // RGBA: opaque white marks a hole; white with alpha 0 does not.
    let mask_rgba = image::RgbaImage::from_fn(96, 96, |x, y| {
        if hole(x, y) {
            image::Rgba([255, 255, 255, 255])
        } else if x < 20 {
            image::Rgba([255, 255, 255, 0])
        } else {
            image::Rgba([0, 0, 0, 255])
        }
    });
    let mrgba = d.join("mask_rgba.png");
    mask_rgba.save(&mrgba).unwrap();
    for mask in [&m16, &mrgba] {
        let out = d.join("out.png");
        let o = texsyn(&["fill", s(&input), "--mask", s(mask), "-o", s(&out), "-q"]);
        assert!(
            o.status.success(),
            "{mask:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let got = image::open(&out).unwrap().to_rgb8();
        for (x, y, p) in got.enumerate_pixels() {
            if hole(x, y) {
                assert_ne!(*p, magenta, "{mask:?}: hole pixel ({x},{y}) not filled");
            } else if x < 20 {
                assert_eq!(
                    p,
                    img.get_pixel(x, y),
                    "{mask:?}: below-threshold pixel ({x},{y}) changed"
                );
            }
        }
    }
}

/// Sends `signal` to a long synthesis: it exits with `code`, leaves no temp
/// file or temporary directory, and keeps the existing output.
#[cfg(unix)]
fn interrupted_run_cleans_up(signal: &str, code: i32) {
    use std::process::{Command, Stdio};
    let dir = tempfile::tempdir().unwrap();
    let tmp = dir.path().join("tmp");
    std::fs::create_dir(&tmp).unwrap();
    let out = dir.path().join("out.png");
    std::fs::write(&out, b"previous result").unwrap();
    let map = dir.path().join("map.png");
    let mut child = Command::new(env!("CARGO_BIN_EXE_texsyn"))
        .args([
            "synth",
            s(&assets().join("gravel_gray_500.png")),
            "-o",
            s(&out),
            "--copy-map",
            s(&map),
            "--size",
            "2000x2000",
            "-q",
        ])
        .env("TMPDIR", &tmp)
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(1500));
    assert!(
        child.try_wait().unwrap().is_none(),
        "the run ended before the signal"
    );
    let sent = Command::new("kill")
        .args([signal, &child.id().to_string()])
        .status()
        .unwrap();
    assert!(sent.success());
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(code), "{signal}: {err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.contains("interrupted"), "{err}");
    assert_eq!(std::fs::read(&out).unwrap(), b"previous result");
    assert!(!map.exists());
    assert!(temp_files(dir.path()).is_empty());
    assert_eq!(
        std::fs::read_dir(&tmp).unwrap().count(),
        0,
        "temporary directory left"
    );
}

#[cfg(unix)]
#[test]
fn sigint_and_sigterm_remove_temporaries() {
    interrupted_run_cleans_up("-INT", 130);
    interrupted_run_cleans_up("-TERM", 143);
}

/// A worker stand-in for `--worker-binary`: records its pid in `$FAKE_PIDS`,
/// prints a listening line (nothing listens there, so the run searches
/// locally) and sleeps.
#[cfg(unix)]
fn fake_worker(dir: &Path) -> std::path::PathBuf {
    use std::os::unix::fs::PermissionsExt;
    let p = dir.join("fake-worker.sh");
    std::fs::write(
        &p,
        "#!/bin/sh\necho $$ > \"$FAKE_PIDS/$$\"\necho \"listening on 127.0.0.2:$((1024 + $$ % 60000))\"\nexec sleep 300\n",
    )
    .unwrap();
    std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o755)).unwrap();
    p
}

/// True while `pid` runs (a zombie, or no such process, does not).
#[cfg(unix)]
fn alive(pid: &str) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/status")).is_ok_and(|s| {
        s.lines()
            .any(|l| l.starts_with("State:") && !l.contains('Z'))
    })
}

#[cfg(unix)]
#[test]
fn sigint_stops_local_workers_and_removes_their_token_directory() {
    use std::process::{Command, Stdio};
    let dir = tempfile::tempdir().unwrap();
    let (tmp, pids) = (dir.path().join("tmp"), dir.path().join("pids"));
    std::fs::create_dir(&tmp).unwrap();
    std::fs::create_dir(&pids).unwrap();
    let worker = fake_worker(dir.path());
    let out = dir.path().join("out.png");
    let mut child = Command::new(env!("CARGO_BIN_EXE_texsyn"))
        .args([
            "synth",
            s(&assets().join("gravel_gray_500.png")),
            "-o",
            s(&out),
            "--size",
            "2000x2000",
            "-q",
            "--local-workers",
            "2",
            "--worker-binary",
            s(&worker),
        ])
        .env("TMPDIR", &tmp)
        .env("FAKE_PIDS", &pids)
        .env("RUST_LOG", "error")
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = std::time::Instant::now();
    while std::fs::read_dir(&pids).unwrap().count() < 2 {
        assert!(start.elapsed().as_secs() < 30, "the workers never started");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    std::thread::sleep(std::time::Duration::from_millis(1000));
    assert_eq!(
        std::fs::read_dir(&tmp).unwrap().count(),
        1,
        "the token directory"
    );
    assert!(child.try_wait().unwrap().is_none(), "the run ended early");
    let sent = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(sent.success());
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(130), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert_eq!(
        std::fs::read_dir(&tmp).unwrap().count(),
        0,
        "token directory left"
    );
    let workers: Vec<String> = std::fs::read_dir(&pids)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(workers.len(), 2);
    std::thread::sleep(std::time::Duration::from_millis(200));
    for pid in &workers {
        assert!(!alive(pid), "worker {pid} still runs");
    }
    assert!(!out.exists());
    assert!(temp_files(dir.path()).is_empty());
}

#[test]
fn depth_alpha_and_source_errors_name_the_fix() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let sample = assets().join("brick_color_96.png");
    let sm = s(&sample);
    let g16 = d.join("g16.png");
    image::ImageBuffer::from_fn(64, 64, |x, y| image::Luma([(x * 900 + y) as u16]))
        .save(&g16)
        .unwrap();
    let hdr = d.join("hdr.exr");
    image::DynamicImage::ImageRgb32F(image::ImageBuffer::from_fn(48, 48, |x, y| {
        image::Rgb([x as f32 / 7.0, y as f32 / 9.0, 2.5])
    }))
    .save(&hdr)
    .unwrap();
    let mask = d.join("mask.png");
    image::GrayImage::from_fn(96, 96, |x, y| {
        image::Luma([if (30..50).contains(&x) && (30..50).contains(&y) {
            255
        } else {
            0
        }])
    })
    .save(&mask)
    .unwrap();
    let small = d.join("small.png");
    image::RgbImage::new(8, 8).save(&small).unwrap();
    let jpg = d.join("out.jpg");
    fails(
        &["extend", s(&g16), "-o", s(&jpg), "--size", "80x80"],
        &jpg,
        &["JPEG", "16-bit grey", ".png or .tif"],
    );
    let png = d.join("out.png");
    fails(
        &["extend", s(&hdr), "-o", s(&png), "--size", "64x64"],
        &png,
        &["PNG", "32-bit float RGB", ".tif or .exr"],
    );
    fails(
        &["fill", sm, "--mask-from-alpha", "-o", s(&png)],
        &png,
        &["no alpha channel", "--mask"],
    );
    fails(
        &[
            "fill",
            sm,
            "--mask",
            s(&mask),
            "--source",
            s(&small),
            "-o",
            s(&png),
        ],
        &png,
        &["fill source is 8×8", "neighbourhood"],
    );
    fails(
        &[
            "fill",
            sm,
            "--mask",
            s(&mask),
            "--source",
            sm,
            "--source-mask",
            s(&small),
            "-o",
            s(&png),
        ],
        &png,
        &["small.png", "8x8", "same size"],
    );
    fails(
        &["fill", s(&g16), "--mask", s(&mask), "-o", s(&png)],
        &png,
        &["mask", "96x96", "64x64", "same size"],
    );
    fails(
        &[
            "extend",
            s(&g16),
            "-o",
            s(&png),
            "--size",
            "80x80",
            "--chroma-blur",
            "2",
        ],
        &png,
        &["--chroma-blur", "16-bit grey", "drop --chroma-blur"],
    );
}

/// A fill from a source smaller than the photo: the photo's pixels outside
/// the holes stay, and every hole pixel is a colour of the source.
#[test]
fn fill_from_a_source_smaller_than_the_photo() {
    let dir = tempfile::tempdir().unwrap();
    let photo = common::texture("pink_marble_color_128.png");
    let source = common::texture("brick_gray_64.png");
    let (w, h) = (photo.width, photo.height);
    let mut mask = image::GrayImage::new(w as u32, h as u32);
    for (x, y, p) in mask.enumerate_pixels_mut() {
        let hole = (40..80).contains(&x) && (50..90).contains(&y);
        p.0 = [if hole { 255 } else { 0 }];
    }
    let (pm, mm, sm, out) = (
        dir.path().join("photo.png"),
        dir.path().join("mask.png"),
        dir.path().join("source.png"),
        dir.path().join("out.png"),
    );
    texsyn::imaging::save_color(&pm, &photo).unwrap();
    texsyn::imaging::save_color(&sm, &source).unwrap();
    mask.save(&mm).unwrap();
    common::ok(&[
        "fill",
        s(&pm),
        "--mask",
        s(&mm),
        "--source",
        s(&sm),
        "-o",
        s(&out),
        "--quiet",
    ]);
    let got = texsyn::imaging::load_color(&out).unwrap();
    let colours: std::collections::HashSet<[u8; 3]> = (0..source.height)
        .flat_map(|y| (0..source.width).map(move |x| (x, y)))
        .map(|(x, y)| source.get(x, y))
        .collect();
    for y in 0..h {
        for x in 0..w {
            if mask.get_pixel(x as u32, y as u32).0[0] == 255 {
                assert!(colours.contains(&got.get(x, y)), "hole pixel ({x}, {y})");
            } else {
                assert_eq!(got.get(x, y), photo.get(x, y), "kept pixel ({x}, {y})");
            }
        }
    }
}

/// `synth --method parallel` refuses the block method's flags instead of
/// ignoring them.
#[test]
fn parallel_synthesis_refuses_the_block_method_s_flags() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("p.png");
    let sample = assets().join("brick_color_96.png");
    for (flag, value) in [
        ("--block", "4"),
        ("--levels", "100"),
        ("--batch", "7"),
        ("--parent-window", "3"),
        ("--weights", "1,1"),
        ("--metric", "l1"),
    ] {
        fails(
            &[
                "synth",
                s(&sample),
                "--method",
                "parallel",
                "--size",
                "64x64",
                "-o",
                s(&out),
                flag,
                value,
            ],
            &out,
            &[flag, "--method parallel"],
        );
    }
}

/// The synthesis on coordinates and solids estimate their memory and refuse
/// what exceeds the budget before allocating it (a two-material 4096³ ramp
/// once asked for 256 GiB before any check).
#[test]
fn coordinate_methods_refuse_what_exceeds_the_memory_budget() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o.png");
    let (a, b) = (
        assets().join("brick_color_96.png"),
        assets().join("cracked_color_144.png"),
    );
    fails(
        &[
            "synth",
            s(&a),
            "--method",
            "parallel",
            "--size",
            "2048x2048",
            "-o",
            s(&out),
            "--max-memory",
            "16",
        ],
        &out,
        &["2048×2048", "of memory", "--max-memory", "--size"],
    );
    fails(
        &[
            "morph",
            s(&a),
            s(&b),
            "--ramp",
            "x",
            "--size",
            "2048x2048",
            "-o",
            s(&out),
            "--max-memory",
            "16",
        ],
        &out,
        &["of memory", "--max-memory"],
    );
    let solid = dir.path().join("solid");
    let (va, vb) = (format!("x={}", s(&a)), format!("2:x={}", s(&b)));
    let o = texsyn(&[
        "solid",
        "--view",
        &va,
        "--view",
        &vb,
        "--ramp",
        "x",
        "--size",
        "4096",
        "-o",
        s(&solid),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("of memory") && err.contains("--size"), "{err}");
    assert!(!solid.join("solid.raw").exists());
}

/// `compare` refuses images over 4096² with a message naming the fix
/// (two 8192² images once aborted on memory).
#[test]
fn compare_refuses_images_over_its_limit() {
    let dir = tempfile::tempdir().unwrap();
    let big = dir.path().join("big.png");
    image::GrayImage::from_pixel(4097, 4097, image::Luma([90]))
        .save(&big)
        .unwrap();
    let small = assets().join("brick_color_96.png");
    let o = texsyn(&["compare", s(&small), s(&big)]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("4097x4097") && err.contains("crop"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
}

/// The stitch defaults: `synth` stitches along paths (as `--stitch path`, and
/// not as `--stitch hard`) with N = 13 windows, while hard stitching,
/// scan-line synthesis and `extend` keep N = 11; `extend` keeps the square
/// edge; repetition control is off unless asked for, and its flags are
/// checked.
#[test]
fn synth_defaults_to_path_stitching_and_extend_to_hard() {
    let dir = tempfile::tempdir().unwrap();
    let sample = assets().join("brick_color_96.png");
    let run = |cmd: &str, name: &str, extra: &[&str]| -> Vec<u8> {
        let out = dir.path().join(format!("{name}.png"));
        let args = [
            &[cmd, s(&sample), "-o", s(&out), "--size", "144x128", "-q"][..],
            extra,
        ]
        .concat();
        common::ok(&args);
        std::fs::read(&out).unwrap()
    };
    let synth = run("synth", "synth", &[]);
    assert!(synth == run("synth", "path", &["--stitch", "path"]));
    assert!(synth == run("synth", "n13", &["--neighbourhood", "13"]));
    assert!(synth != run("synth", "n11", &["--neighbourhood", "11"]));
    let hard = run("synth", "hard", &["--stitch", "hard"]);
    assert!(synth != hard);
    assert!(
        hard == run(
            "synth",
            "hard11",
            &["--stitch", "hard", "--neighbourhood", "11"]
        )
    );
    assert!(
        hard != run(
            "synth",
            "hard13",
            &["--stitch", "hard", "--neighbourhood", "13"]
        )
    );
    // Levels whose coarsest cannot hold 13×13 fall back to 11 (96 px over 4
    // levels is 12 px), so commands that ran before still run.
    let four = run("synth", "four", &["--levels", "4"]);
    assert!(
        four == run(
            "synth",
            "four11",
            &["--levels", "4", "--neighbourhood", "11"]
        )
    );
    let three = run("synth", "three", &["--levels", "3"]);
    assert!(
        three
            == run(
                "synth",
                "three13",
                &["--levels", "3", "--neighbourhood", "13"]
            )
    );
    let scan = run("synth", "scan", &["--method", "scanline"]);
    let scan11 = ["--method", "scanline", "--neighbourhood", "11"];
    assert!(scan == run("synth", "scan11", &scan11));
    assert!(synth == run("synth", "off", &["--no-repeat-control"]));
    assert!(synth == run("synth", "zero", &["--repeat-percent", "0"]));
    assert!(synth != run("synth", "repeat", &["--repeat-percent", "25"]));
    let extend = run("extend", "extend", &[]);
    assert!(extend == run("extend", "ehard", &["--stitch", "hard"]));
    assert!(extend == run("extend", "e11", &["--neighbourhood", "11"]));
    let out = dir.path().join("bad.png");
    for (flags, words) in [
        (
            &["--no-repeat-control", "--repeat-percent", "5"][..],
            &["--no-repeat-control", "--repeat-percent"][..],
        ),
        (
            &["--repeat-candidates", "1"],
            &["--repeat-candidates", "2..=64"],
        ),
        (
            &["--repeat-percent", "0", "--repeat-candidates", "4"],
            &["--repeat-candidates", "slack"],
        ),
        (
            &["--stitch", "hard", "--repeat-seam", "15"],
            &["--repeat-seam", "--stitch path"],
        ),
        (&["--repeat-seam", "2000"], &["--repeat-seam", "0..=1000"]),
        (
            &["--no-repeat-control", "--repeat-seam", "15"],
            &["--no-repeat-control", "--repeat-seam"],
        ),
        (&["--repeat-cap", "0"], &["--repeat-cap", "1..=100"]),
        (&["--repeat-cap", "101"], &["--repeat-cap", "1..=100"]),
        (
            &["--repeat-cap", "20", "--repeat-seam", "15"],
            &["--repeat-cap", "--repeat-seam", "give one"],
        ),
        (
            &["--no-repeat-control", "--repeat-cap", "20"],
            &["--no-repeat-control", "--repeat-cap"],
        ),
        (
            &["--repeat-percent", "0", "--repeat-cap", "20"],
            &["--repeat-cap", "slack"],
        ),
        (&["--lattice", "1x32"], &["--lattice", "at least 2"]),
        (&["--lattice", "32"], &["--lattice", "WxH"]),
        (&["--lattice", "0x0"], &["--lattice", "no phase"]),
        (&["--lattice", "axb"], &["--lattice", "not a number"]),
        (
            &["--lattice", "500x32"],
            &["--lattice", "larger than the sample"],
        ),
        (
            &["--lattice", "32x32", "--repeat-cap", "20"],
            &["--lattice", "give one"],
        ),
        (
            &["--lattice", "auto", "--repeat-cap", "20"],
            &["--lattice", "give one"],
        ),
    ] {
        let args = [
            &["synth", s(&sample), "-o", s(&out), "--size", "96x96"][..],
            flags,
        ]
        .concat();
        fails(&args, &out, words);
    }
    // The seam filter on `extend` needs path stitching named.
    fails(
        &[
            "extend",
            s(&sample),
            "-o",
            s(&out),
            "--size",
            "144x128",
            "--repeat-seam",
            "15",
        ],
        &out,
        &["--stitch path"],
    );
    assert!(
        synth != run("synth", "seam", &["--repeat-seam", "15"]),
        "the seam filter changed nothing"
    );
    // The patch cap is its own rule: not the use counts of the same slack.
    let cap = run("synth", "cap", &["--repeat-cap", "20"]);
    assert!(synth != cap, "the patch cap changed nothing");
    assert!(
        cap == run(
            "synth",
            "cap60",
            &["--repeat-cap", "20", "--repeat-percent", "60"]
        ),
        "--repeat-cap starts from --repeat-percent 60"
    );
    assert!(cap != run("synth", "use60", &["--repeat-percent", "60"]));
}

/// The 7×7 synthesis on coordinates defaults to 8 candidates per set and 5
/// passes (as `--k 8 --passes 5`, not the earlier `--k 4 --passes 3`), the
/// other neighbourhoods to 4 candidates; `--k` is checked and belongs to
/// `--method parallel`.
/// `synth --method parallel` of `sample` to 112² with `extra`: the output's bytes.
fn parallel_synth(dir: &Path, sample: &Path, name: &str, extra: &[&str]) -> Vec<u8> {
    let out = dir.join(format!("{name}.png"));
    let args = [
        &["synth", s(sample), "-o", s(&out), "--size", "112x112"][..],
        &["--method", "parallel", "-q"][..],
        extra,
    ]
    .concat();
    common::ok(&args);
    std::fs::read(&out).unwrap()
}

/// Each `synth` of `sample` with the case's flags exits 1 naming its words,
/// with no panic and no output written.
fn synth_refused(dir: &Path, sample: &Path, cases: &[(&[&str], &str)]) {
    let out = dir.join("bad.png");
    for (extra, words) in cases {
        let head = ["synth", s(sample), "-o", s(&out), "--size", "64x64", "-q"];
        let args = [&head[..], extra].concat();
        let o = texsyn(&args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{extra:?}: {err}");
        assert!(err.contains(words), "{extra:?}: {err}");
        assert!(!err.contains("panicked"), "{err}");
    }
    assert!(!out.exists());
}

#[test]
fn parallel_five_takes_nine_guarded_passes_and_the_finest_level_its_own() {
    let dir = tempfile::tempdir().unwrap();
    let sample = assets().join("brick_color_96.png");
    let run = |name: &str, extra: &[&str]| {
        let five = [&["--neighbourhood", "5"][..], extra].concat();
        parallel_synth(dir.path(), &sample, name, &five)
    };
    let five = run("five", &[]);
    let spelled = ["--passes", "9", "--copy-guard", "0.08"];
    assert!(five == run("spelled", &spelled));
    assert!(five != run("before", &["--passes", "4"]));
    // --passes alone sets every level, the finest included (the paper's 2
    // stays reachable); --fine-passes sets the finest apart.
    let flat = run("flat", &["--passes", "4"]);
    assert!(flat == run("flat-spelled", &["--passes", "4", "--fine-passes", "4"]));
    assert!(flat != run("fine", &["--passes", "4", "--fine-passes", "8"]));
    let p = ["--method", "parallel", "--fine-passes"];
    let g = ["--method", "parallel", "--copy-guard"];
    synth_refused(
        dir.path(),
        &sample,
        &[
            (&[&p[..], &["0"]].concat(), "1..=64"),
            (&[&p[..], &["65"]].concat(), "1..=64"),
            (&["--fine-passes", "4"], "belongs to --method parallel"),
            (&[&g[..], &["1"]].concat(), "must be in (0, 1)"),
            (
                &["--method", "parallel", "--copy-guard=-0.2"],
                "must be in (0, 1)",
            ),
            (&[&g[..], &["NaN"]].concat(), "must be in (0, 1)"),
            (&["--copy-guard", "0.1"], "belongs to --method parallel"),
        ],
    );
}

#[test]
fn parallel_seven_and_half_take_eight_candidates_and_reduced_its_fine_passes() {
    let dir = tempfile::tempdir().unwrap();
    let sample = assets().join("brick_color_96.png");
    let run = |name: &str, extra: &[&str]| parallel_synth(dir.path(), &sample, name, extra);
    let seven = run("seven", &["--neighbourhood", "7"]);
    let spelled = ["--neighbourhood", "7", "--k", "8", "--passes", "5"];
    assert!(seven == run("spelled", &spelled));
    let before = ["--neighbourhood", "7", "--k", "4", "--passes", "3"];
    assert!(seven != run("before", &before));
    let reduced = run("reduced", &[]);
    assert!(reduced == run("reduced4", &["--k", "4"]));
    assert!(reduced != run("reduced8", &["--k", "8"]));
    // reduced takes 8 passes at its finest level, a lighter fine jitter
    // and the copy guard.
    let spelled = [
        &["--passes", "4", "--fine-passes", "8"][..],
        &["--jitter", "1,0.8,0.5,0.3", "--copy-guard", "0.08"],
        &["--coarse-neighbourhood", "7", "--coarse-passes", "40"],
    ]
    .concat();
    assert!(reduced == run("reduced-spelled", &spelled));
    assert!(reduced != run("reduced-coarse-16", &["--coarse-passes", "16"]));
    assert!(reduced != run("reduced-flat", &["--passes", "4"]));
    assert!(reduced != run("reduced-jitter", &["--jitter", "1,0.8,0.6,0.4"]));
    // Its levels above the finest take the 7×7 neighbourhood.
    let one = ["--coarse-neighbourhood", "same"];
    assert!(reduced != run("reduced-same", &one));
    assert!(reduced != run("reduced-coarse-8", &["--coarse-passes", "8"]));
    // So does half, with 8 candidates and 8 passes at every level.
    let half = ["--neighbourhood", "half"];
    let half_default = run("half", &half);
    let half_spelled = [
        &half[..],
        &["--k", "8", "--passes", "8", "--fine-passes", "8"],
        &["--jitter", "1,0.8,0.5,0.3", "--copy-guard", "0.08"],
        &["--coarse-neighbourhood", "7", "--coarse-passes", "16"],
    ]
    .concat();
    assert!(half_default == run("half-spelled", &half_spelled));
    assert!(
        half_default
            != run(
                "half-before",
                &[&half[..], &spelled, &["--k", "4"]].concat()
            )
    );
    assert!(half_default != reduced);
    synth_refused(
        dir.path(),
        &sample,
        &[
            (&["--method", "parallel", "--k", "0"], "1..=16"),
            (&["--method", "parallel", "--k", "17"], "1..=16"),
            (&["--k", "4"], "belongs to --method parallel"),
            (
                &["--coarse-neighbourhood", "7"],
                "belongs to --method parallel",
            ),
            (
                &["--method", "parallel", "--coarse-neighbourhood", "9"],
                "not one of reduced, half, 5, 7 or same",
            ),
            (&["--method", "parallel", "--coarse-passes", "0"], "1..=64"),
            (
                &[
                    "--method",
                    "parallel",
                    "--coarse-neighbourhood",
                    "same",
                    "--coarse-passes",
                    "8",
                ],
                "--coarse-neighbourhood 7",
            ),
            (
                &[
                    "--method",
                    "parallel",
                    "--neighbourhood",
                    "7",
                    "--coarse-passes",
                    "8",
                ],
                "--coarse-neighbourhood 7",
            ),
            (
                &["--method", "parallel", "--lattice", "500x32"],
                "larger than the sample",
            ),
        ],
    );
}
