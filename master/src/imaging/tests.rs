//! Tests of image loading, saving and atomic writes.

use std::collections::HashSet;
use std::fs::{self, File};
use std::io::Write;
use std::path::Path;

use super::atomic::write_atomic;
use super::*;
use crate::imaging::colour::luminance;
use image::{ImageBuffer, Luma, LumaA, Rgb, Rgba};

fn pattern(w: usize, h: usize) -> ColorImage {
    let mut img = ColorImage::new(w, h);
    for y in 0..h {
        for x in 0..w {
            img.set(
                x,
                y,
                [
                    (x * 37 + y) as u8,
                    (y * 53 + 7 * x) as u8,
                    (x * y + 11) as u8,
                ],
            );
        }
    }
    img
}

fn err_text(r: anyhow::Result<impl std::fmt::Debug>) -> String {
    let e = r.expect_err("expected an error");
    let s = e.to_string();
    assert!(!s.contains('\n'), "error must be one line: {s}");
    s
}

fn no_temp_files(dir: &Path) {
    let names: Vec<_> = fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains(".tmp-"))
        .collect();
    assert!(names.is_empty(), "temp files left: {names:?}");
}

#[test]
fn roundtrip_lossless_formats() {
    let dir = tempfile::tempdir().unwrap();
    let img = pattern(13, 7);
    for ext in ["png", "tif", "tiff", "bmp", "webp", "PNG"] {
        let p = dir.path().join(format!("out.{ext}"));
        save_color(&p, &img).unwrap();
        assert_eq!(load_color(&p).unwrap(), img, "{ext}");
    }
    no_temp_files(dir.path());
}

#[test]
fn roundtrip_jpeg_is_close() {
    let dir = tempfile::tempdir().unwrap();
    let mut img = ColorImage::new(16, 16);
    for y in 0..16 {
        for x in 0..16 {
            img.set(x, y, [100 + x as u8, 120, 140 + y as u8]);
        }
    }
    for ext in ["jpg", "jpeg"] {
        let p = dir.path().join(format!("out.{ext}"));
        save_color(&p, &img).unwrap();
        let back = load_color(&p).unwrap();
        assert_eq!((back.width, back.height), (16, 16));
        for (a, b) in img.rgb.iter().zip(&back.rgb) {
            assert!((*a as i32 - *b as i32).abs() <= 8, "{a} vs {b}");
        }
    }
}

#[test]
fn gray_roundtrip_and_gray_loads_as_rgb() {
    let dir = tempfile::tempdir().unwrap();
    let g = Gray::from_vec(5, 3, (0..15).map(|i| (i * 17) as u8).collect());
    for ext in ["png", "tif", "bmp", "webp"] {
        let p = dir.path().join(format!("g.{ext}"));
        save_gray(&p, &g).unwrap();
        let c = load_color(&p).unwrap();
        for (i, v) in g.data.iter().enumerate() {
            assert_eq!(&c.rgb[i * 3..i * 3 + 3], &[*v; 3], "{ext}");
        }
        assert_eq!(luminance(&c), g, "{ext}");
    }
}

#[test]
fn sixteen_bit_png_is_read_over_its_range() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("deep.png");
    let vals: [u16; 4] = [0, 65535, 32896, 128]; // 0, 255, 128, round(0.498) = 0
    let buf = ImageBuffer::<Rgb<u16>, _>::from_fn(4, 1, |x, _| {
        let v = vals[x as usize];
        Rgb([v, v, v])
    });
    buf.save(&p).unwrap();
    let img = load_color(&p).unwrap();
    let r: Vec<u8> = img.rgb.chunks(3).map(|c| c[0]).collect();
    assert_eq!(r, vec![0, 255, 128, 0]);
    // 16-bit grey too; a narrower range is stretched over 0..=255.
    let p2 = dir.path().join("deep_gray.png");
    ImageBuffer::<Luma<u16>, _>::from_fn(3, 1, |x, _| Luma([[257u16, 514, 771][x as usize]]))
        .save(&p2)
        .unwrap();
    assert_eq!(
        load_color(&p2).unwrap().rgb,
        vec![0, 0, 0, 128, 128, 128, 255, 255, 255]
    );
}

#[test]
fn rgba_ignores_alpha() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("a.png");
    ImageBuffer::<Rgba<u8>, _>::from_fn(2, 1, |x, _| {
        Rgba([10, 20, 30, if x == 0 { 0 } else { 255 }])
    })
    .save(&p)
    .unwrap();
    assert_eq!(load_color(&p).unwrap().rgb, vec![10, 20, 30, 10, 20, 30]);
}

#[test]
fn format_is_guessed_from_content() {
    let dir = tempfile::tempdir().unwrap();
    let img = pattern(4, 4);
    let png = dir.path().join("x.png");
    save_color(&png, &img).unwrap();
    let odd = dir.path().join("really_png.bmp");
    fs::copy(&png, &odd).unwrap();
    assert_eq!(load_color(&odd).unwrap(), img);
    let none = dir.path().join("noext");
    fs::copy(&png, &none).unwrap();
    assert_eq!(load_color(&none).unwrap(), img);
}

#[test]
fn load_errors_are_clear() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.png");
    let s = err_text(load_color(&missing));
    assert!(
        s.starts_with("no such file:") && s.contains("missing.png"),
        "{s}"
    );

    let text = dir.path().join("notes.png");
    fs::write(&text, "this is not an image\n").unwrap();
    let s = err_text(load_color(&text));
    assert!(s.contains("not an image") && s.contains("notes.png"), "{s}");

    let empty = dir.path().join("empty.png");
    fs::write(&empty, "").unwrap();
    let s = err_text(load_color(&empty));
    assert!(s.contains("empty file") && s.contains("empty.png"), "{s}");

    let s = err_text(load_color(dir.path()));
    assert!(s.contains("is a directory"), "{s}");

    // Truncated PNG: valid signature, missing data.
    let good = dir.path().join("good.png");
    save_color(&good, &pattern(32, 32)).unwrap();
    let bytes = fs::read(&good).unwrap();
    let trunc = dir.path().join("trunc.png");
    fs::write(&trunc, &bytes[..bytes.len() / 2]).unwrap();
    let s = err_text(load_color(&trunc));
    assert!(s.contains("trunc.png"), "{s}");

    // A GIF is recognised but not compiled in.
    let gif = dir.path().join("a.gif");
    fs::write(&gif, b"GIF89a\x01\x00\x01\x00\x00\x00\x00;").unwrap();
    let s = err_text(load_color(&gif));
    assert!(s.contains("a.gif"), "{s}");
}

#[test]
fn too_large_is_rejected_before_decoding() {
    let dir = tempfile::tempdir().unwrap();
    // A valid PNG header claiming 40000x1: rejected from the header alone.
    let p = dir.path().join("wide.png");
    ImageBuffer::<Luma<u8>, _>::new(40000, 1).save(&p).unwrap();
    let s = err_text(load_color(&p));
    assert!(s.contains("40000x1") && s.contains("32768"), "{s}");
}

#[test]
fn check_size_limits() {
    assert!(check_size(1, 1, "canvas").is_ok());
    assert!(check_size(MAX_SIDE, 2048, "canvas").is_ok());
    let s = err_text(check_size(0, 5, "canvas"));
    assert!(s.contains("canvas") && s.contains("empty"), "{s}");
    let s = err_text(check_size(MAX_SIDE + 1, 1, "canvas"));
    assert!(s.contains("32768"), "{s}");
    let s = err_text(check_size(MAX_SIDE, MAX_SIDE, "canvas"));
    assert!(s.contains("67108864"), "{s}");
    assert!(check_size(usize::MAX, usize::MAX, "x").is_err());
}

#[test]
fn mask_threshold_alpha_and_size() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("m.png");
    // white, grey 128, grey 127, black, transparent white, half-transparent white
    let px = [
        [255, 255, 255, 255],
        [128, 128, 128, 255],
        [127, 127, 127, 255],
        [0, 0, 0, 255],
        [255, 255, 255, 0],
        [255, 255, 255, 100],
    ];
    ImageBuffer::<Rgba<u8>, _>::from_fn(6, 1, |x, _| Rgba(px[x as usize]))
        .save(&p)
        .unwrap();
    assert_eq!(
        load_mask(&p, 6, 1).unwrap(),
        vec![true, true, false, false, false, false]
    );
    let s = err_text(load_mask(&p, 7, 2));
    assert!(
        s.contains("6x1") && s.contains("7x2") && s.contains("m.png"),
        "{s}"
    );

    let pg = dir.path().join("g.png");
    ImageBuffer::<LumaA<u8>, _>::from_fn(2, 1, |x, _| LumaA([255, [255, 0][x as usize]]))
        .save(&pg)
        .unwrap();
    assert_eq!(load_mask(&pg, 2, 1).unwrap(), vec![true, false]);
    assert!(err_text(load_mask(&dir.path().join("nope.png"), 1, 1)).contains("no such file"));
}

#[test]
fn luminance_bt601() {
    let img = ColorImage::from_vec(3, 1, vec![255, 0, 0, 0, 255, 0, 10, 20, 30]);
    // 299*255/1000 = 76.245 → 76; 587*255/1000 = 149.685 → 150; (2990+11740+3420)/1000 = 18.15 → 18
    assert_eq!(luminance(&img).data, vec![76, 150, 18]);
    let white = ColorImage::from_vec(1, 1, vec![255; 3]);
    assert_eq!(luminance(&white).data, vec![255]);
}

#[test]
fn save_errors_are_clear() {
    let dir = tempfile::tempdir().unwrap();
    let img = pattern(2, 2);
    let s = err_text(save_color(&dir.path().join("out.gif"), &img));
    assert!(
        s.contains("\".gif\"") && s.contains(".png") && s.contains(".webp"),
        "{s}"
    );
    let s = err_text(save_color(&dir.path().join("out"), &img));
    assert!(s.contains("no extension"), "{s}");
    let s = err_text(check_writable(&dir.path().join("out.xyz")));
    assert!(s.contains(".xyz"), "{s}");

    let missing = dir.path().join("no/such/dir/out.png");
    let s = err_text(save_color(&missing, &img));
    assert!(
        s.contains("does not exist") && s.contains("no/such/dir"),
        "{s}"
    );
    let s = err_text(check_writable(&missing));
    assert!(s.contains("does not exist"), "{s}");

    let file = dir.path().join("plain");
    fs::write(&file, "x").unwrap();
    let s = err_text(save_color(&file.join("out.png"), &img));
    assert!(s.contains("not a directory"), "{s}");

    let d = dir.path().join("d.png");
    fs::create_dir(&d).unwrap();
    let s = err_text(save_color(&d, &img));
    assert!(s.contains("is a directory"), "{s}");
    assert!(check_writable(&d).is_err());

    let bad = ColorImage {
        width: 3,
        height: 3,
        rgb: vec![0; 5],
    };
    assert!(save_color(&dir.path().join("bad.png"), &bad).is_err());
    assert!(save_gray(&dir.path().join("e.png"), &Gray::new(0, 4)).is_err());
    no_temp_files(dir.path());
}

#[test]
fn unwritable_directory() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let ro = dir.path().join("ro");
    fs::create_dir(&ro).unwrap();
    fs::set_permissions(&ro, fs::Permissions::from_mode(0o555)).unwrap();
    // Root ignores directory permissions; only assert where they apply.
    let enforced = File::create(ro.join("probe")).is_err();
    let target = ro.join("out.png");
    if enforced {
        let s = err_text(check_writable(&target));
        assert!(s.contains("not writable") && s.contains("ro"), "{s}");
        let s = err_text(save_color(&target, &pattern(2, 2)));
        assert!(s.contains("not writable"), "{s}");
    }
    fs::set_permissions(&ro, fs::Permissions::from_mode(0o755)).unwrap();
    check_writable(&target).unwrap();
    no_temp_files(&ro);
    assert!(!target.exists());
}

#[test]
fn save_bytes_is_atomic() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("report.json");
    check_writable_any(&p).unwrap();
    save_bytes(&p, b"{}").unwrap();
    save_bytes(&p, b"{\"a\": 1}").unwrap();
    assert_eq!(fs::read(&p).unwrap(), b"{\"a\": 1}");
    assert!(check_writable(&p).is_err());
    let s = err_text(save_bytes(&dir.path().join("nodir/r.json"), b"x"));
    assert!(s.contains("does not exist"), "{s}");
    no_temp_files(dir.path());
}

#[test]
fn check_writable_leaves_nothing() {
    let dir = tempfile::tempdir().unwrap();
    check_writable(&dir.path().join("a.tiff")).unwrap();
    assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 0);
}

#[test]
fn failed_save_keeps_target_and_removes_temp() {
    let dir = tempfile::tempdir().unwrap();
    let target = dir.path().join("keep.jpg");
    fs::write(&target, b"original").unwrap();
    // JPEG cannot encode a side over 65535: the encoder fails after the temp file exists.
    let wide = ColorImage::new(70_000, 1);
    let s = err_text(save_color(&target, &wide));
    assert!(s.contains("keep.jpg"), "{s}");
    assert_eq!(fs::read(&target).unwrap(), b"original");
    no_temp_files(dir.path());

    // A body that fails midway.
    let r = write_atomic(&target, |w| {
        w.write_all(b"partial").unwrap();
        Err("boom".into())
    });
    assert!(r.unwrap_err().to_string().contains("boom"));
    assert_eq!(fs::read(&target).unwrap(), b"original");
    no_temp_files(dir.path());

    // Success replaces the target and leaves no temp file.
    save_color(&target, &pattern(8, 8)).unwrap();
    assert_eq!(load_color(&target).unwrap().width, 8);
    no_temp_files(dir.path());
}

#[test]
fn truncated_jpeg_is_detected() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("a.jpg");
    save_color(&p, &pattern(64, 48)).unwrap();
    let bytes = fs::read(&p).unwrap();
    assert!(super::io::jpeg_complete(&mut bytes.as_slice()).unwrap());
    // Progressive JPEGs have several scans; this one is baseline, so cut it
    // everywhere after the start-of-image marker.
    for cut in (2..bytes.len() - 1).step_by(7) {
        assert!(
            !super::io::jpeg_complete(&mut &bytes[..cut]).unwrap(),
            "cut at {cut} of {}",
            bytes.len()
        );
    }
    let cut = dir.path().join("cut.jpg");
    fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let e = err_text(load_color(&cut));
    assert!(e.contains("end-of-image") && e.contains("cut.jpg"), "{e}");
}

#[test]
fn fifo_and_empty_files_are_refused_without_opening() {
    let dir = tempfile::tempdir().unwrap();
    let empty = dir.path().join("empty.png");
    File::create(&empty).unwrap();
    let e = err_text(load_color(&empty));
    assert!(e.contains("empty file"), "{e}");
    #[cfg(unix)]
    {
        let fifo = dir.path().join("pipe.png");
        let ok = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap()
            .success();
        assert!(ok, "mkfifo");
        // Opening a FIFO without a writer would block here.
        let e = err_text(load_color(&fifo));
        assert!(e.contains("not a regular file"), "{e}");
    }
}

/// Every pixel format the tool reads, filled with varied samples.
fn deep_images(w: u32, h: u32) -> Vec<DeepImage> {
    let v = |x: u32, y: u32, c: u32| (x * 7919 + y * 104_729 + c * 31_337) % 65_536;
    let u8s = |n: u32| -> Vec<u8> {
        (0..w * h * n)
            .map(|i| v(i % w, i / w, i % n) as u8)
            .collect()
    };
    let u16s = |n: u32| -> Vec<u16> {
        (0..w * h * n)
            .map(|i| v(i % w, i / w, i % n) as u16)
            .collect()
    };
    let f32s = |n: u32| -> Vec<f32> {
        (0..w * h * n)
            .map(|i| v(i % w, i / w, i % n) as f32 / 9000.0)
            .collect()
    };
    use image::DynamicImage as D;
    let buf = |d: Option<D>| DeepImage::from_dynamic(d.unwrap()).unwrap();
    vec![
        buf(ImageBuffer::from_raw(w, h, u8s(1)).map(D::ImageLuma8)),
        buf(ImageBuffer::from_raw(w, h, u8s(2)).map(D::ImageLumaA8)),
        buf(ImageBuffer::from_raw(w, h, u8s(3)).map(D::ImageRgb8)),
        buf(ImageBuffer::from_raw(w, h, u8s(4)).map(D::ImageRgba8)),
        buf(ImageBuffer::from_raw(w, h, u16s(1)).map(D::ImageLuma16)),
        buf(ImageBuffer::from_raw(w, h, u16s(2)).map(D::ImageLumaA16)),
        buf(ImageBuffer::from_raw(w, h, u16s(3)).map(D::ImageRgb16)),
        buf(ImageBuffer::from_raw(w, h, u16s(4)).map(D::ImageRgba16)),
        buf(ImageBuffer::from_raw(w, h, f32s(3)).map(D::ImageRgb32F)),
        buf(ImageBuffer::from_raw(w, h, f32s(4)).map(D::ImageRgba32F)),
    ]
}

#[test]
fn every_format_said_to_hold_a_layout_gives_it_back_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    let mut held = Vec::new();
    for img in deep_images(23, 17) {
        for ext in ["png", "tif", "exr", "webp", "bmp", "jpg"] {
            let p = dir.path().join(format!("x.{ext}"));
            let claim = check_output_format(&p, img.format);
            let saved = save_image(&p, &img);
            assert_eq!(
                claim.is_ok(),
                saved.is_ok(),
                "{} .{ext}: the check and the save disagree: {claim:?} {saved:?}",
                img.format
            );
            let Ok(()) = saved else {
                let e = err_text(saved);
                assert!(e.contains("use ."), "{e}");
                continue;
            };
            let back = load_image(&p).unwrap();
            assert_eq!(back.format, img.format, ".{ext}: format");
            if ext != "jpg" {
                assert!(back == img, "{} .{ext}: pixels changed", img.format);
            }
            held.push(format!("{} .{ext}", img.format));
        }
    }
    // Every layout has a lossless home.
    for img in deep_images(2, 2) {
        assert!(
            held.iter()
                .any(|h| h.starts_with(&img.format.to_string()) && !h.ends_with("jpg")),
            "{} has no format: {held:?}",
            img.format
        );
    }
}

#[test]
fn rebuild_copies_whole_pixels_and_keeps_the_photo_where_told() {
    for img in deep_images(9, 7) {
        let copy: Vec<[u32; 2]> = (0..4 * 3).map(|i| [(i * 5) % 9, (i * 3) % 7]).collect();
        let out = img.rebuild(&copy, 4, 3, None).unwrap();
        for (i, &[sx, sy]) in copy.iter().enumerate() {
            assert_eq!(out.pixel(i % 4, i / 4), img.pixel(sx as usize, sy as usize));
        }
        let photo = img.rebuild(&[[8, 6]; 12], 4, 3, None).unwrap();
        let kept: Vec<bool> = (0..12).map(|i| i % 2 == 0).collect();
        let mixed = img.rebuild(&copy, 4, 3, Some((&photo, &kept))).unwrap();
        for (i, &k) in kept.iter().enumerate() {
            let want = if k {
                photo.pixel(i % 4, i / 4)
            } else {
                out.pixel(i % 4, i / 4)
            };
            assert_eq!(mixed.pixel(i % 4, i / 4), want);
        }
        assert!(
            img.rebuild(&[[9, 0]], 1, 1, None).is_err(),
            "outside the source"
        );
    }
}

#[test]
fn search_colour_keeps_8_bit_rgb_stretches_16_bit_and_tone_maps_float() {
    let imgs = deep_images(16, 16);
    let rgb8 = &imgs[2];
    assert_eq!(rgb8.search_colour().rgb, rgb8.bytes());
    // 16-bit is stretched over its own range: its least value reads 0, its
    // greatest 255.
    let rgb16 = &imgs[6];
    let c = rgb16.search_colour();
    assert!(c.rgb.contains(&255) && c.rgb.contains(&0));
    // Float over 1 is not clamped flat: the white point is the 99.5th percentile.
    let f = &imgs[8];
    let c = f.search_colour();
    let distinct: HashSet<u8> = c.rgb.iter().copied().collect();
    assert!(distinct.len() > 100, "{} levels", distinct.len());
    assert!(c.rgb.contains(&255) && c.rgb.contains(&0));
}

#[test]
fn alpha_below_half_marks_a_hole_at_every_depth() {
    use image::DynamicImage as D;
    let a8 = D::ImageLumaA8(ImageBuffer::from_raw(3, 1, vec![0, 127, 0, 128, 9, 255]).unwrap());
    let a16 =
        D::ImageRgba16(ImageBuffer::from_raw(2, 1, vec![1, 2, 3, 32767, 1, 2, 3, 32768]).unwrap());
    let af = D::ImageRgba32F(
        ImageBuffer::from_raw(
            3,
            1,
            vec![0., 0., 0., 0.49, 0., 0., 0., 0.5, 1., 1., 1., f32::NAN],
        )
        .unwrap(),
    );
    let holes = |d: D| DeepImage::from_dynamic(d).unwrap().alpha_holes().unwrap();
    assert_eq!(holes(a8), [true, false, false]);
    assert_eq!(holes(a16), [true, false]);
    assert_eq!(holes(af), [true, false, true]);
    let rgb = DeepImage::from_colour(&pattern(2, 2));
    assert!(rgb.alpha_holes().is_none());
}

/// A smooth 16-bit map that uses a few hundredths of the range (a height
/// map) is searched with all 256 levels, not the 3 that rounding leaves; two
/// images searched together share one view.
#[test]
fn a_narrow_16_bit_range_is_stretched_and_shared() {
    use image::DynamicImage as D;
    let gradient = |from: u16, n: u16| {
        let v: Vec<u16> = (0..n).map(|i| from + i).collect();
        DeepImage::from_dynamic(D::ImageLuma16(
            ImageBuffer::from_raw(u32::from(n), 1, v).unwrap(),
        ))
        .unwrap()
    };
    let narrow = gradient(30_000, 600);
    let rounded: HashSet<u8> = narrow
        .to_dynamic()
        .to_rgb8()
        .into_raw()
        .into_iter()
        .collect();
    let stretched: HashSet<u8> = narrow.search_colour().rgb.into_iter().collect();
    assert!(rounded.len() <= 4, "{} levels", rounded.len());
    assert_eq!(stretched.len(), 256);
    // Together with a wider image, the same value maps to the same byte.
    let wide = gradient(29_700, 1200);
    let view = SearchView::of(&[&narrow, &wide]);
    assert_eq!(
        view,
        SearchView::Stretched {
            low: 29_700,
            high: 30_899
        }
    );
    let (a, b) = (narrow.search_colour_in(&view), wide.search_colour_in(&view));
    assert_eq!(a.rgb[..3], b.rgb[300 * 3..301 * 3]);
    assert_eq!(b.rgb[0], 0);
    assert_eq!(b.rgb[b.rgb.len() - 1], 255);
    // 8-bit images keep their values under any view.
    let rgb8 = DeepImage::from_colour(&ColorImage {
        width: 2,
        height: 1,
        rgb: vec![1, 2, 3, 4, 5, 6],
    });
    assert_eq!(rgb8.search_colour_in(&view).rgb, vec![1, 2, 3, 4, 5, 6]);
}

/// Coordinate maps and volumes are read only from regular files of the right
/// size: a FIFO would block, `/dev/zero` fill memory, a cut `.raw` misread.
#[test]
fn special_and_cut_files_are_refused_before_reading() {
    use super::volume::Volume;
    let dir = tempfile::tempdir().unwrap();
    let e = super::load_coord_map(Path::new("/dev/zero")).unwrap_err();
    assert!(e.to_string().contains("not a regular file"), "{e:#}");
    let fifo = dir.path().join("fifo.png");
    if std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .is_ok_and(|s| s.success())
    {
        let e = super::load_coord_map(&fifo).unwrap_err();
        assert!(e.to_string().contains("not a regular file"), "{e:#}");
    }
    let v = Volume::new([4, 3, 2], 3, (0..72).collect()).unwrap();
    let header = v.save(dir.path(), "solid", None).unwrap();
    assert_eq!(Volume::load(&header).unwrap().0.size, [4, 3, 2]);
    let raw = dir.path().join("solid.raw");
    std::fs::write(&raw, vec![0u8; 71]).unwrap();
    let e = Volume::load(&header).unwrap_err();
    assert!(e.to_string().contains("71 bytes"), "{e:#}");
    std::fs::remove_file(&raw).unwrap();
    std::os::unix::fs::symlink("/dev/zero", &raw).unwrap();
    let e = Volume::load(&header).unwrap_err();
    assert!(e.to_string().contains("not a regular file"), "{e:#}");
}

/// Coordinate maps and volumes (header and raw data) given as a FIFO or a
/// device are refused before they are opened or read.
#[cfg(unix)]
#[test]
fn coordinate_maps_and_volumes_refuse_special_files() {
    let e = format!("{:#}", load_coord_map(Path::new("/dev/zero")).unwrap_err());
    assert!(e.contains("not a regular file"), "{e}");
    let dir = tempfile::tempdir().unwrap();
    let v = crate::imaging::volume::Volume::new([2, 2, 2], 1, vec![7; 8]).unwrap();
    v.save(dir.path(), "vol", None).unwrap();
    let raw = dir.path().join("vol.raw");
    std::fs::remove_file(&raw).unwrap();
    let made = std::process::Command::new("mkfifo")
        .arg(&raw)
        .status()
        .unwrap();
    assert!(made.success(), "mkfifo");
    let header = dir.path().join("vol.json");
    let e = format!(
        "{:#}",
        crate::imaging::volume::Volume::load(&header).unwrap_err()
    );
    assert!(e.contains("not a regular file"), "{e}");
    let e = format!(
        "{:#}",
        crate::imaging::volume::Volume::load(Path::new("/dev/zero")).unwrap_err()
    );
    assert!(e.contains("not a regular file"), "{e}");
}

#[test]
fn wrap_padding_continues_the_image_periodically() {
    let img = pattern(5, 3);
    let out = img.wrap_padded(7);
    assert_eq!((out.width, out.height), (12, 10));
    for y in 0..10 {
        for x in 0..12 {
            assert_eq!(out.get(x, y), img.get(x % 5, y % 3), "({x}, {y})");
        }
    }
    assert_eq!(img.wrap_padded(0).rgb, img.rgb);
}
