//! The `texsyn` binary on good and bad input: bad input gets one clear error
//! line and a non-zero exit, never a panic or a partial output file.

mod common;

use std::path::Path;

use common::{assets, s, texsyn};

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
        assert!(l["search_seconds"].as_f64().unwrap() >= 0.0);
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
