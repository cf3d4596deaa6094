//! Solid textures from 2-D views (ARCHITECTURE §11) from the command line:
//! threads do not change a byte, slices and preview are the volume's voxels,
//! one isotropic exemplar on all three axes gives faces like it on all six
//! faces and the centre slices, a ramp morphs one material into the other,
//! replay reproduces the solid, streaks along the anti-diagonal survive as
//! mirrored views, and bad input is refused with the fix named.

use crate::common;

use std::path::{Path, PathBuf};

use common::{ok, refused, s};
use texsyn::compare::spectrum_similarity;
use texsyn::imaging::volume::{Axis, Volume};
use texsyn::imaging::{self, ColorImage};
use texsyn::parallel::solid::mirror;

fn marble() -> PathBuf {
    common::assets().join("pink_marble_color_128.png")
}

fn leaves() -> PathBuf {
    common::assets().join("leaves_green_color_161.png")
}

fn solid(dir: &Path, extra: &[&str]) -> Volume {
    ok(&[&["solid", "-q", "-o", s(dir)], extra].concat());
    Volume::load(&dir.join("solid.json")).unwrap().0
}

/// Per channel mean and standard deviation.
fn stats(img: &ColorImage) -> ([f64; 3], [f64; 3]) {
    let n = (img.width * img.height) as f64;
    let mut mean = [0.0; 3];
    for p in img.rgb.chunks_exact(3) {
        for c in 0..3 {
            mean[c] += f64::from(p[c]) / n;
        }
    }
    let mut var = [0.0; 3];
    for p in img.rgb.chunks_exact(3) {
        for c in 0..3 {
            var[c] += (f64::from(p[c]) - mean[c]).powi(2) / n;
        }
    }
    (mean, var.map(f64::sqrt))
}

/// The six faces and the three centre slices, named.
fn faces(v: &Volume) -> Vec<(String, ColorImage)> {
    let mut out = Vec::new();
    for axis in Axis::ALL {
        let n = v.size[axis.index()];
        for (what, at) in [("face 0", 0), ("far face", n - 1), ("centre slice", n / 2)] {
            out.push((
                format!("{what} across {}", axis.name()),
                v.slice_rgb(axis, at),
            ));
        }
    }
    out
}

/// How a face fails to look like the exemplar, if it does: its mean within
/// 0.7 of the exemplar's standard deviation per channel (one 64² slice of
/// the veined marble crosses one vein more or less: over the 64 z slices
/// of the 64³ solid the green mean spans ±0.6 σ round the exemplar's), its
/// standard
/// deviation between 0.4 and 1.5 of the exemplar's, and S_F at least 0.36.
fn unlike(face: &ColorImage, ex: &ColorImage) -> Option<String> {
    let ((fm, fs), (em, es)) = (stats(face), stats(ex));
    for c in 0..3 {
        if (fm[c] - em[c]).abs() > 0.7 * es[c] {
            return Some(format!("mean {fm:.1?} against {em:.1?}"));
        }
        if !(0.4 * es[c]..=1.5 * es[c]).contains(&fs[c]) {
            return Some(format!("deviation {fs:.1?} against {es:.1?}"));
        }
    }
    let sf = spectrum_similarity(ex, face).unwrap();
    (sf < 0.36).then(|| format!("S_F {sf:.3}"))
}

#[test]
fn one_isotropic_exemplar_on_all_axes_gives_faces_like_it_on_all_six_and_the_centre_slices() {
    let dir = tempfile::tempdir().unwrap();
    let ex = imaging::load_color(&marble()).unwrap();
    let v = solid(
        dir.path(),
        &["--view", &format!("xyz={}", s(&marble())), "--size", "64"],
    );
    for (name, face) in faces(&v) {
        if let Some(why) = unlike(&face, &ex) {
            panic!("{name} is unlike the exemplar: {why}");
        }
    }
    // The solid as a whole keeps the exemplar's mean, to a tenth of its
    // standard deviation, however its single slices scatter.
    let (em, es) = stats(&ex);
    let n = v.size[Axis::Z.index()];
    let mut vm = [0.0; 3];
    for z in 0..n {
        let (m, _) = stats(&v.slice_rgb(Axis::Z, z));
        for c in 0..3 {
            vm[c] += m[c] / n as f64;
        }
    }
    for c in 0..3 {
        assert!(
            (vm[c] - em[c]).abs() <= 0.1 * es[c],
            "{vm:.1?} against {em:.1?}"
        );
    }
    // The check can fail: leaves' faces, a flat face and a washed-out one
    // (the marble's contrast divided by four) are all told apart.
    let other = imaging::load_color(&leaves()).unwrap();
    assert!(unlike(&other.crop(0, 0, 64, 64), &ex).is_some());
    let (m, _) = stats(&ex);
    let flat = ColorImage::from_vec(
        64,
        64,
        (0..64 * 64).flat_map(|_| m.map(|c| c as u8)).collect(),
    );
    assert!(unlike(&flat, &ex).is_some());
    let mut washed = ex.crop(0, 0, 64, 64);
    for (i, p) in washed.rgb.iter_mut().enumerate() {
        *p = (m[i % 3] + (f64::from(*p) - m[i % 3]) / 4.0).round() as u8;
    }
    assert!(unlike(&washed, &ex).is_some());
}

#[test]
fn threads_do_not_change_a_byte() {
    let dir = tempfile::tempdir().unwrap();
    let runs = [
        vec![
            "--view".to_string(),
            format!("xyz={}", s(&marble())),
            "--size".into(),
            "24x32x20".into(),
        ],
        vec![
            "--view".to_string(),
            format!("xz={}", s(&marble())),
            "--view".into(),
            format!("2:yz={}", s(&leaves())),
            "--ramp".into(),
            "z".into(),
            "--neighbourhood".into(),
            "7".into(),
            "--size".into(),
            "24".into(),
        ],
        vec![
            "--view".to_string(),
            format!("xyz={}", s(&common::assets().join("burlap_color_96.png"))),
            "--lattice".into(),
            "13.7x16".into(),
            "--size".into(),
            "20x24x16".into(),
        ],
        // The default `--lattice auto` finds the weave's grid.
        vec![
            "--view".to_string(),
            format!("xyz={}", s(&common::assets().join("burlap_color_96.png"))),
            "--size".into(),
            "20x24x16".into(),
        ],
    ];
    for (k, args) in runs.iter().enumerate() {
        let mut out = Vec::new();
        for threads in ["1", "2"] {
            let d = dir.path().join(format!("{k}_{threads}"));
            let args: Vec<&str> = args.iter().map(String::as_str).collect();
            let v = solid(
                &d,
                &[&args[..], &["--threads", threads, "--slices", "none"]].concat(),
            );
            out.push((v, std::fs::read(d.join("preview.png")).unwrap()));
        }
        assert!(
            out[0].0 == out[1].0,
            "run {k}: 1 and 2 threads give different solids"
        );
        assert!(
            out[0].1 == out[1].1,
            "run {k}: 1 and 2 threads give different previews"
        );
    }
    // The even slice contrast is on by default and recorded; off, the
    // marble's slices keep the contrast the volume gives them.
    let off = dir.path().join("no_slice_contrast");
    let args: Vec<&str> = runs[0].iter().map(String::as_str).collect();
    let plain = solid(&off, &[&args[..], &["--no-slice-contrast"]].concat());
    let on = Volume::load(&dir.path().join("0_1").join("solid.json"))
        .unwrap()
        .0;
    assert!(on != plain, "--no-slice-contrast changed nothing");
    for (d, flag) in [(dir.path().join("0_1"), true), (off, false)] {
        let header: serde_json::Value =
            serde_json::from_slice(&std::fs::read(d.join("solid.json")).unwrap()).unwrap();
        assert_eq!(header["info"]["slice_contrast"], flag);
    }
    // The lattice is recorded, and off it is null.
    let lattice = |d: &str| -> serde_json::Value {
        serde_json::from_slice::<serde_json::Value>(
            &std::fs::read(dir.path().join(d).join("solid.json")).unwrap(),
        )
        .unwrap()["info"]["lattice"]
            .clone()
    };
    assert_eq!(lattice("2_1"), serde_json::json!([13.7, 16.0]));
    assert!(lattice("0_1").is_null());
    // Found: the weave's period across its threads (the other axis repeats
    // too weakly to count), the same solid as that period given, and
    // `none` turns it off.
    let found = lattice("3_1");
    let period = |i: usize| found[i].as_f64().unwrap();
    assert!(
        (period(0) - 13.8).abs() < 0.3 && period(1) == 0.0,
        "{found}"
    );
    let args: Vec<&str> = runs[3].iter().map(String::as_str).collect();
    let auto = Volume::load(&dir.path().join("3_1").join("solid.json"))
        .unwrap()
        .0;
    let given = format!("{}x{}", period(0), period(1));
    let same = solid(
        &dir.path().join("given"),
        &[&args[..], &["--lattice", &given, "--slices", "none"]].concat(),
    );
    assert!(
        same == auto,
        "--lattice {given} differs from the grid auto found"
    );
    let none = solid(
        &dir.path().join("none"),
        &[&args[..], &["--lattice", "none", "--slices", "none"]].concat(),
    );
    assert!(none != auto, "the found grid changed nothing");
    assert!(lattice("none").is_null());
}

#[test]
fn slices_and_the_preview_are_the_volume_s_voxels() {
    let dir = tempfile::tempdir().unwrap();
    let v = solid(
        dir.path(),
        &[
            "--view",
            &format!("xyz={}", s(&marble())),
            "--size",
            "20x16x12",
            "--slices",
            "all",
        ],
    );
    assert_eq!(v.size, [20, 16, 12]);
    for axis in Axis::ALL {
        for at in 0..v.size[axis.index()] {
            let p = dir
                .path()
                .join(format!("slices/{}_{at:04}.png", axis.name()));
            let img = imaging::load_color(&p).unwrap();
            assert!(
                img == v.slice_rgb(axis, at),
                "{} differs from the volume",
                p.display()
            );
        }
        assert!(!dir
            .path()
            .join(format!(
                "slices/{}_{:04}.png",
                axis.name(),
                v.size[axis.index()]
            ))
            .exists());
    }
    // Preview: columns x, y, z; rows face 0, far face, centre; 4-pixel gaps.
    let preview = imaging::load_color(&dir.path().join("preview.png")).unwrap();
    assert_eq!(preview.width, 3 * 20 + 16);
    for (col, axis) in Axis::ALL.into_iter().enumerate() {
        let n = v.size[axis.index()];
        for (row, at) in [0, n - 1, n / 2].into_iter().enumerate() {
            let s = v.slice_rgb(axis, at);
            let cell = preview.crop(4 + col * 24, 4 + row * 24, s.width, s.height);
            assert!(cell == s, "preview cell ({col}, {row})");
        }
    }
}

/// The mean colours of the two materials of the morph tests.
fn material_means() -> ([f64; 3], [f64; 3]) {
    (
        stats(&imaging::load_color(&marble()).unwrap()).0,
        stats(&imaging::load_color(&leaves()).unwrap()).0,
    )
}

/// The L1 distance of two mean colours.
fn dist(m: [f64; 3], e: [f64; 3]) -> f64 {
    (0..3).map(|c| (m[c] - e[c]).abs()).sum()
}

#[test]
fn a_ramp_along_z_morphs_one_material_into_the_other() {
    let dir = tempfile::tempdir().unwrap();
    let v = solid(
        dir.path(),
        &[
            "--view",
            &format!("xyz={}", s(&marble())),
            "--view",
            &format!("2:xyz={}", s(&leaves())),
            "--ramp",
            "z",
            "--size",
            "32",
            "--slices",
            "none",
        ],
    );
    let (a, b) = material_means();
    let first = stats(&v.slice_rgb(Axis::Z, 0)).0;
    let middle = stats(&v.slice_rgb(Axis::Z, 16)).0;
    let last = stats(&v.slice_rgb(Axis::Z, 31)).0;
    assert!(
        dist(first, a) < 0.2 * dist(a, b),
        "z = 0 is not marble: {first:?}"
    );
    assert!(
        dist(last, b) < 0.2 * dist(a, b),
        "z = 31 is not leaves: {last:?}"
    );
    assert!(
        dist(middle, a) > 0.25 * dist(a, b) && dist(middle, b) > 0.25 * dist(a, b),
        "the middle is not between: {middle:?}"
    );
}

#[test]
fn weight_volumes_place_the_materials() {
    let dir = tempfile::tempdir().unwrap();
    // Material 1 where x < 16, material 2 from x = 16 on.
    let n = 32usize;
    let left: Vec<u8> = (0..n * n * n)
        .map(|i| if i % n < 16 { 255 } else { 0 })
        .collect();
    let right: Vec<u8> = left.iter().map(|&v| 255 - v).collect();
    let w1 = Volume::new([n; 3], 1, left)
        .unwrap()
        .save(dir.path(), "w1", None)
        .unwrap();
    let w2 = Volume::new([n; 3], 1, right)
        .unwrap()
        .save(dir.path(), "w2", None)
        .unwrap();
    let out = dir.path().join("out");
    let v = solid(
        &out,
        &[
            "--view",
            &format!("xyz={}", s(&marble())),
            "--view",
            &format!("2:xyz={}", s(&leaves())),
            "--weight-volumes",
            &format!("{},{}", s(&w1), s(&w2)),
            "--size",
            "32",
            "--slices",
            "none",
        ],
    );
    let (a, b) = material_means();
    let l = stats(&v.slice_rgb(Axis::X, 8)).0;
    let r = stats(&v.slice_rgb(Axis::X, 24)).0;
    assert!(dist(l, a) < 0.2 * dist(a, b), "x = 8 is not marble: {l:?}");
    assert!(dist(r, b) < 0.2 * dist(a, b), "x = 24 is not leaves: {r:?}");
}

#[test]
fn replaying_the_colour_exemplar_reproduces_the_solid_and_maps_keep_their_channels() {
    let dir = tempfile::tempdir().unwrap();
    let rock = common::assets().join("mossy_rock_color_128.png");
    let height = common::assets().join("mossy_rock_height_128.png");
    let v = solid(
        dir.path(),
        &[
            "--view",
            &format!("xyz={}", s(&rock)),
            "--size",
            "24",
            "--slices",
            "none",
            "--replay",
            s(&rock),
            "--replay",
            &format!("x={h},y={h},z={h}", h = s(&height)),
        ],
    );
    let (again, _) = Volume::load(&dir.path().join("mossy_rock_color_128.json")).unwrap();
    assert!(again == v, "the colour exemplar replayed is not the solid");
    let (h, _) = Volume::load(&dir.path().join("mossy_rock_height_128.json")).unwrap();
    assert_eq!((h.size, h.channels), ([24; 3], 1));
    assert!(dir
        .path()
        .join("mossy_rock_height_128_preview.png")
        .exists());
    // The height is not the colour's grey: its own values came through.
    let grey: Vec<u8> = v
        .data
        .chunks_exact(3)
        .map(|p| ((u32::from(p[0]) + u32::from(p[1]) + u32::from(p[2])) / 3) as u8)
        .collect();
    assert!(h.data != grey);
}

#[test]
fn bad_input_is_refused_with_the_fix_named() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let view = format!("xyz={}", s(&marble()));
    let base = ["solid", "-q", "-o", s(&out), "--view", &view];
    let l = leaves();
    let (x2, m2, m3) = (
        format!("x={}", s(&l)),
        format!("2:x={}", s(&l)),
        format!("3:x={}", s(&l)),
    );
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (
            vec!["--size", "32", "--neighbourhood", "reduced"],
            "reduced neighbourhood fails in 3-D",
        ),
        (vec!["--size", "4000"], "choose a smaller --size"),
        (
            vec!["--size", "64", "--max-memory", "1"],
            "are allowed (--max-memory)",
        ),
        (vec!["--size", "32x32"], "has 2 numbers"),
        (vec!["--size", "32", "--view", "w=a.png"], "is not an axis"),
        (vec!["--size", "32", "--view", &x2], "two views across x"),
        (
            vec!["--size", "32", "--view", &m2],
            "--ramp x|y|z or --weight-volumes",
        ),
        (
            vec!["--size", "32", "--view", &m3, "--ramp", "z"],
            "material 2 has no view",
        ),
        (
            vec!["--size", "32", "--replay", s(&l)],
            "give the map of that exemplar",
        ),
        (
            vec!["--size", "32", "--slices", "w"],
            "is not none, x, y, z or all",
        ),
        (
            vec!["--size", "32", "--histogram", "2"],
            "must be in [0, 1]",
        ),
        (
            vec!["--size", "32", "--index-histogram=-1"],
            "--index-histogram -1 must be in [0, 16]",
        ),
        (
            vec!["--size", "32", "--index-histogram", "NaN"],
            "must be in [0, 16]",
        ),
        (
            vec!["--size", "32", "--band-matching", "17"],
            "--band-matching 17 must be in 0..=16",
        ),
        (
            vec!["--size", "32", "--band-matching=-1"],
            "--band-matching",
        ),
    ];
    for (extra, want) in cases {
        let e = refused(&[&base[..], &extra].concat());
        assert!(e.contains(want), "{extra:?}: {e}");
        assert!(!out.join("solid.raw").exists(), "{extra:?} wrote a solid");
    }
    // The output directory cannot be a file.
    let file = dir.path().join("file");
    std::fs::write(&file, b"x").unwrap();
    let e = refused(&[
        "solid",
        "-q",
        "-o",
        s(&file),
        "--view",
        &view,
        "--size",
        "8",
    ]);
    assert!(e.contains("not a directory"), "{e}");
    // An input inside the output set (a view of the last run's preview) is
    // refused: the set is replaced as a whole.
    let set = dir.path().join("set");
    ok(&["solid", "-q", "-o", s(&set), "--view", &view, "--size", "8"]);
    let inside = format!("xyz={}", s(&set.join("preview.png")));
    let e = refused(&[
        "solid",
        "-q",
        "-o",
        s(&set),
        "--view",
        &inside,
        "--size",
        "8",
    ]);
    assert!(e.contains("inside the output directory"), "{e}");
    assert!(set.join("solid.raw").is_file(), "the old set was not kept");
    // A header that is not a volume.
    std::fs::write(dir.path().join("bad.json"), b"{}").unwrap();
    let e = refused(
        &[
            &base[..],
            &["--size", "8", "--view", &format!("2:xyz={}", s(&leaves()))],
            &[
                "--weight-volumes",
                &format!("{0},{0}", s(&dir.path().join("bad.json"))),
            ],
        ]
        .concat(),
    );
    assert!(e.contains("is not a volume header"), "{e}");
}

/// The centre slices' gradient correlations, read from `slices/` (where a
/// mirrored view's slices are written back in its exemplar's frame).
fn slice_correlations(dir: &Path, n: usize) -> Vec<f64> {
    Axis::ALL
        .into_iter()
        .map(|axis| {
            let p = dir.join(format!("slices/{}_{:04}.png", axis.name(), n / 2));
            mirror::gradient_correlation(&imaging::load_color(&p).unwrap())
        })
        .collect()
}

#[test]
fn streaks_along_the_anti_diagonal_survive_as_mirrored_views() {
    // rain_color_108's streaks run down to the right (gradient correlation
    // −0.70): three such views have no solid, and plain they come out as
    // clouds. Mirrored, every centre slice keeps streaks along the
    // exemplar's own diagonal.
    let rain = common::assets().join("rain_color_108.png");
    assert!(mirror::gradient_correlation(&imaging::load_color(&rain).unwrap()) < -0.6);
    let view = format!("xyz={}", s(&rain));
    let args = ["--view", &view, "--size", "40", "--slices", "all"];
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let v = solid(a.path(), &args);
    let header = std::fs::read_to_string(a.path().join("solid.json")).unwrap();
    assert!(header.contains(r#""mirrored_views": ["#), "{header}");
    for (axis, rho) in Axis::ALL.into_iter().zip(slice_correlations(a.path(), 40)) {
        assert!(
            rho < -0.3,
            "mirrored: the centre slice across {} has ρ {rho:.2}",
            axis.name()
        );
        // Written back: the file is the volume's slice mirrored top to bottom.
        let p = a.path().join(format!("slices/{}_0020.png", axis.name()));
        assert!(imaging::load_color(&p).unwrap() == mirror::flipped(&v.slice_rgb(axis, 20)));
    }
    solid(b.path(), &[&args[..], &["--no-mirror"]].concat());
    for (axis, rho) in Axis::ALL.into_iter().zip(slice_correlations(b.path(), 40)) {
        assert!(
            rho > -0.25,
            "as given: the centre slice across {} has ρ {rho:.2}",
            axis.name()
        );
    }
    // A view that needs no mirror (marble's ρ is +0.17) gives the same bytes
    // either way.
    let view = format!("xyz={}", s(&marble()));
    let args = ["--view", &view, "--size", "16"];
    let (c, d) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let plain = solid(c.path(), &args);
    let kept = solid(d.path(), &[&args[..], &["--no-mirror"]].concat());
    assert!(plain.data == kept.data);
}
