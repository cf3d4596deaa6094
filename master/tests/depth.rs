//! Images as artists have them (ARCHITECTURE §3.11): every depth and channel
//! layout comes out at its own depth with each pixel copied bit for bit from
//! the pixel its copy-map entry names; 16-bit data keeps its levels; fill from
//! another source copies only from it; `fill --tileable` tiles; alpha
//! survives and can mark the holes.

use crate::common;

use std::collections::HashSet;
use std::path::Path;

use common::{run, s, seam, texsyn, texture};
use image::{DynamicImage, ImageBuffer};
use texsyn::imaging::{self, Channels, ColorImage, DeepImage, Depth, PixelFormat};
use texsyn::{Config, FillSource, Mode, Position};

/// A small deterministic hash for the low bits and the alpha of test images.
fn hash(x: usize, y: usize, k: usize) -> u32 {
    let mut h = (x as u32).wrapping_mul(0x9E37_79B1) ^ (y as u32).wrapping_mul(0x85EB_CA77);
    h ^= (k as u32).wrapping_mul(0xC2B2_AE3D);
    h ^= h >> 15;
    h = h.wrapping_mul(0x2C1B_3C6D);
    h ^ (h >> 12)
}

/// `base` at `format`: 16-bit samples get low bits of their own (so they do
/// not come from 8-bit values), float samples reach up to 4 (HDR), alpha
/// varies between half and full opacity.
fn deep_from(base: &ColorImage, format: PixelFormat) -> DeepImage {
    let (w, h) = (base.width, base.height);
    let colour = match format.channels {
        Channels::Gray | Channels::GrayAlpha => 1,
        Channels::Rgb | Channels::Rgba => 3,
    };
    let alpha = format.has_alpha();
    let mut v16: Vec<u16> = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let p = base.get(x, y);
            for (c, &v) in p.iter().take(colour).enumerate() {
                v16.push(u16::from(v) << 8 | (hash(x, y, c) & 0xFF) as u16);
            }
            if alpha {
                v16.push(0x8000 | (hash(x, y, 9) & 0x7FFF) as u16);
            }
        }
    }
    let (w32, h32) = (w as u32, h as u32);
    let img = match (format.depth, format.channels) {
        (Depth::U8, ch) => {
            let v: Vec<u8> = v16.iter().map(|&v| (v >> 8) as u8).collect();
            match ch {
                Channels::Gray => {
                    DynamicImage::ImageLuma8(ImageBuffer::from_raw(w32, h32, v).unwrap())
                }
                Channels::GrayAlpha => {
                    DynamicImage::ImageLumaA8(ImageBuffer::from_raw(w32, h32, v).unwrap())
                }
                Channels::Rgb => {
                    DynamicImage::ImageRgb8(ImageBuffer::from_raw(w32, h32, v).unwrap())
                }
                Channels::Rgba => {
                    DynamicImage::ImageRgba8(ImageBuffer::from_raw(w32, h32, v).unwrap())
                }
            }
        }
        (Depth::U16, Channels::Gray) => {
            DynamicImage::ImageLuma16(ImageBuffer::from_raw(w32, h32, v16).unwrap())
        }
        (Depth::U16, Channels::GrayAlpha) => {
            DynamicImage::ImageLumaA16(ImageBuffer::from_raw(w32, h32, v16).unwrap())
        }
        (Depth::U16, Channels::Rgb) => {
            DynamicImage::ImageRgb16(ImageBuffer::from_raw(w32, h32, v16).unwrap())
        }
        (Depth::U16, Channels::Rgba) => {
            DynamicImage::ImageRgba16(ImageBuffer::from_raw(w32, h32, v16).unwrap())
        }
        (Depth::F32, ch) => {
            let step = colour + usize::from(alpha);
            let v: Vec<f32> = v16
                .chunks_exact(step)
                .flat_map(|p| {
                    let mut out: Vec<f32> = p[..colour]
                        .iter()
                        .map(|&v| f32::from(v) / 65535.0 * 4.0)
                        .collect();
                    if alpha {
                        out.push(f32::from(p[colour]) / 65535.0);
                    }
                    out
                })
                .collect();
            match ch {
                Channels::Rgb => {
                    DynamicImage::ImageRgb32F(ImageBuffer::from_raw(w32, h32, v).unwrap())
                }
                Channels::Rgba => {
                    DynamicImage::ImageRgba32F(ImageBuffer::from_raw(w32, h32, v).unwrap())
                }
                _ => unreachable!("float grey is read as RGB"),
            }
        }
    };
    let deep = DeepImage::from_dynamic(img).unwrap();
    assert_eq!(deep.format, format);
    deep
}

/// Every layout the tool reads, with the extension each test writes it as.
fn layouts() -> Vec<(PixelFormat, &'static str)> {
    let mut v = Vec::new();
    for depth in [Depth::U8, Depth::U16] {
        for channels in [
            Channels::Gray,
            Channels::GrayAlpha,
            Channels::Rgb,
            Channels::Rgba,
        ] {
            v.push((PixelFormat { depth, channels }, "png"));
        }
    }
    for (channels, ext) in [
        (Channels::Rgb, "exr"),
        (Channels::Rgba, "exr"),
        (Channels::Rgb, "tif"),
    ] {
        v.push((
            PixelFormat {
                depth: Depth::F32,
                channels,
            },
            ext,
        ));
    }
    v
}

/// Asserts that `out` holds, at `source`'s format, exactly the source pixel
/// each copy-map entry names (or the photo's own pixel where `kept`).
fn assert_copied(
    what: &str,
    out: &DeepImage,
    source: &DeepImage,
    copy_map: &[[u32; 2]],
    kept: Option<(&DeepImage, &[bool])>,
) {
    assert_eq!(out.format, source.format, "{what}: output format");
    assert_eq!(copy_map.len(), out.width * out.height, "{what}: copy map");
    for (i, &[sx, sy]) in copy_map.iter().enumerate() {
        let (x, y) = (i % out.width, i / out.width);
        let want = match kept {
            Some((photo, mask)) if mask[i] => photo.pixel(x, y),
            _ => source.pixel(sx as usize, sy as usize),
        };
        assert_eq!(
            out.pixel(x, y),
            want,
            "{what}: pixel ({x},{y}) is not the pixel its copy-map entry ({sx},{sy}) names"
        );
    }
}

fn cli(args: &[&str]) {
    let o = texsyn(args);
    assert!(
        o.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

fn holes_rect(w: usize, h: usize, x0: usize, y0: usize, side: usize) -> Vec<bool> {
    (0..w * h)
        .map(|i| (x0..x0 + side).contains(&(i % w)) && (y0..y0 + side).contains(&(i / w)))
        .collect()
}

fn save_mask(path: &Path, holes: &[bool], w: usize, h: usize) {
    let g = imaging::Gray::from_vec(
        w,
        h,
        holes.iter().map(|&b| if b { 255 } else { 0 }).collect(),
    );
    imaging::save_gray(path, &g).unwrap();
}

#[test]
fn every_depth_and_channel_layout_is_extended_and_filled_at_full_depth() {
    let dir = tempfile::tempdir().unwrap();
    let base = texture("brick_color_96.png");
    let cfg = Config {
        levels: 2,
        seed: 5,
        ..Config::default()
    };
    let (w, h) = (base.width, base.height);
    let holes = holes_rect(w, h, 30, 34, 24);
    let mask = dir.path().join("mask.png");
    save_mask(&mask, &holes, w, h);
    for (format, ext) in layouts() {
        let deep = deep_from(&base, format);
        let input = dir.path().join(format!("in.{ext}"));
        imaging::save_image(&input, &deep).unwrap();
        assert_eq!(
            imaging::load_image(&input).unwrap(),
            deep,
            "{format} .{ext} round trip"
        );
        let search = deep.search_colour();

        let out = dir.path().join(format!("extended.{ext}"));
        cli(&[
            "extend",
            s(&input),
            "-o",
            s(&out),
            "--size",
            "136x120",
            "--levels",
            "2",
            "--seed",
            "5",
            "--quiet",
        ]);
        let mode = Mode::Extend {
            width: 136,
            height: 120,
            position: Position::Center,
        };
        let lib = run(&search, &mode, &cfg, 2);
        let got = imaging::load_image(&out).unwrap();
        assert_copied(
            &format!("extend {format}"),
            &got,
            &deep,
            &lib.copy_map,
            None,
        );

        let out = dir.path().join(format!("filled.{ext}"));
        cli(&[
            "fill",
            s(&input),
            "--mask",
            s(&mask),
            "-o",
            s(&out),
            "--levels",
            "2",
            "--seed",
            "5",
            "--quiet",
        ]);
        let mode = Mode::Fill {
            holes: holes.clone(),
            source: None,
        };
        let lib = run(&search, &mode, &cfg, 2);
        let got = imaging::load_image(&out).unwrap();
        assert_copied(&format!("fill {format}"), &got, &deep, &lib.copy_map, None);
        for (i, _) in holes.iter().enumerate().filter(|(_, &h)| !h) {
            let (x, y) = (i % w, i / w);
            assert_eq!(
                got.pixel(x, y),
                deep.pixel(x, y),
                "fill {format}: kept ({x},{y})"
            );
        }
    }
}

#[test]
fn a_16_bit_gradient_is_not_quantised_to_256_levels() {
    let dir = tempfile::tempdir().unwrap();
    // A ramp with a texture on it: 9216 distinct 16-bit values.
    let (w, h) = (96u32, 96u32);
    let img = ImageBuffer::from_fn(w, h, |x, y| {
        image::Luma([(x * 600 + y * 7 + (hash(x as usize, y as usize, 0) % 7)) as u16])
    });
    let input = dir.path().join("ramp.png");
    DynamicImage::ImageLuma16(img.clone()).save(&input).unwrap();
    let before: HashSet<u16> = img.pixels().map(|p| p.0[0]).collect();
    let out = dir.path().join("out.png");
    cli(&[
        "extend",
        s(&input),
        "-o",
        s(&out),
        "--size",
        "160x128",
        "--seed",
        "2",
        "--quiet",
    ]);
    let got = match image::open(&out).unwrap() {
        DynamicImage::ImageLuma16(b) => b,
        other => panic!("output is {:?}, not 16-bit grey", other.color()),
    };
    let after: HashSet<u16> = got.pixels().map(|p| p.0[0]).collect();
    eprintln!(
        "distinct 16-bit values: input {}, output {}",
        before.len(),
        after.len()
    );
    assert!(
        after.is_subset(&before),
        "the output has values the input lacks"
    );
    assert!(
        after.len() > 4 * 256,
        "only {} distinct values: the output was quantised",
        after.len()
    );
}

#[test]
fn fill_from_another_source_copies_only_from_it_and_its_region() {
    let dir = tempfile::tempdir().unwrap();
    let photo = texture("brick_color_96.png");
    let source = texture("pink_marble_color_128.png");
    let (w, h) = (photo.width, photo.height);
    let holes = holes_rect(w, h, 36, 30, 26);
    // Only the left 60 columns of the source may be copied from.
    let region: Vec<bool> = (0..source.width * source.height)
        .map(|i| i % source.width < 60)
        .collect();
    let cfg = Config {
        seed: 3,
        ..Config::default()
    };
    for region in [None, Some(region)] {
        let mode = Mode::Fill {
            holes: holes.clone(),
            source: Some(FillSource {
                image: source.clone(),
                region: region.clone(),
            }),
        };
        let lib = run(&photo, &mode, &cfg, 2);
        let kept = lib
            .kept
            .as_deref()
            .expect("a fill from a source reports kept pixels");
        for (i, &hole) in holes.iter().enumerate() {
            assert_eq!(kept[i], !hole, "kept flags are the photo's known pixels");
            let [sx, sy] = lib.copy_map[i];
            let (x, y) = (i % w, i / w);
            if hole {
                if let Some(r) = &region {
                    assert!(
                        r[sy as usize * source.width + sx as usize],
                        "hole pixel ({x},{y}) copied from ({sx},{sy}), outside the source region"
                    );
                }
                assert_eq!(lib.image.get(x, y), source.get(sx as usize, sy as usize));
            } else {
                assert_eq!(lib.image.get(x, y), photo.get(x, y), "kept ({x},{y})");
            }
        }
        // The same through the command line, at full depth.
        let p = dir.path().join("photo.png");
        let src = dir.path().join("source.png");
        let mask = dir.path().join("mask.png");
        imaging::save_color(&p, &photo).unwrap();
        imaging::save_color(&src, &source).unwrap();
        save_mask(&mask, &holes, w, h);
        let out = dir.path().join("out.png");
        let mut args = vec![
            "fill",
            s(&p),
            "--mask",
            s(&mask),
            "--source",
            s(&src),
            "-o",
            s(&out),
            "--seed",
            "3",
            "--quiet",
        ];
        let sm = dir.path().join("region.png");
        if let Some(r) = &region {
            save_mask(&sm, r, source.width, source.height);
            args.extend(["--source-mask", s(&sm)]);
        }
        cli(&args);
        let got = imaging::load_image(&out).unwrap();
        let kept_from = DeepImage::from_colour(&photo);
        assert_copied(
            "fill from a source",
            &got,
            &DeepImage::from_colour(&source),
            &lib.copy_map,
            Some((&kept_from, kept)),
        );
    }
}

#[test]
fn fill_tileable_keeps_a_tileable_image_tileable() {
    let sample = texture("pink_marble_color_128.png");
    let tiling = Config {
        tileable: true,
        ..Config::default()
    };
    let (w, h) = (160, 144);
    let base = run(
        &sample,
        &Mode::Extend {
            width: w,
            height: h,
            position: Position::Center,
        },
        &tiling,
        2,
    )
    .image;
    // Holes along all four borders: the wrap edge is made anew by the fill.
    let holes: Vec<bool> = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            x < 10 || x >= w - 10 || y < 9 || y >= h - 9
        })
        .collect();
    let mode = Mode::Fill {
        holes,
        source: None,
    };
    let out = run(&base, &mode, &tiling, 2);
    for transpose in [false, true] {
        let (wrap, max, mean) = seam(&out.image, transpose);
        assert!(
            wrap <= max,
            "fill --tileable: seam {wrap:.2} across the wrap edge exceeds every interior step \
             (max {max:.2}, mean {mean:.2}); transpose={transpose}"
        );
    }
    // The statistic sees the seam a plain fill of the same holes leaves.
    let plain = run(&base, &mode, &Config::default(), 2);
    let seams: Vec<_> = [false, true].map(|t| seam(&plain.image, t)).to_vec();
    assert!(
        seams.iter().any(|&(wrap, max, _)| wrap > max),
        "control: a plain fill should leave a seam at the wrap edge: {seams:?}"
    );
}

#[test]
fn alpha_survives_extend_and_fill_and_can_mark_the_holes() {
    let dir = tempfile::tempdir().unwrap();
    let base = texture("brick_color_96.png");
    let format = PixelFormat {
        depth: Depth::U8,
        channels: Channels::Rgba,
    };
    let mut deep = deep_from(&base, format);
    let (w, h) = (base.width, base.height);
    // A transparent square: the holes of `--mask-from-alpha`.
    let holes = holes_rect(w, h, 40, 20, 22);
    let mut img = deep.to_dynamic().to_rgba8();
    for (i, _) in holes.iter().enumerate().filter(|(_, &h)| h) {
        img.get_pixel_mut((i % w) as u32, (i / w) as u32).0[3] = 0;
    }
    deep = DeepImage::from_dynamic(DynamicImage::ImageRgba8(img)).unwrap();
    assert_eq!(deep.alpha_holes().unwrap(), holes);
    let input = dir.path().join("in.png");
    imaging::save_image(&input, &deep).unwrap();
    let out = dir.path().join("out.png");
    cli(&[
        "fill",
        s(&input),
        "--mask-from-alpha",
        "--tileable",
        "-o",
        s(&out),
        "--seed",
        "4",
        "--quiet",
    ]);
    let cfg = Config {
        seed: 4,
        tileable: true,
        ..Config::default()
    };
    let mode = Mode::Fill {
        holes: holes.clone(),
        source: None,
    };
    let lib = run(&deep.search_colour(), &mode, &cfg, 2);
    let got = imaging::load_image(&out).unwrap();
    assert_copied("fill --mask-from-alpha", &got, &deep, &lib.copy_map, None);
    for (i, &hole) in holes.iter().enumerate() {
        let a = got.pixel(i % w, i / w)[3];
        if hole {
            assert!(a >= 128, "a filled pixel is still transparent (alpha {a})");
        } else {
            assert_eq!(got.pixel(i % w, i / w), deep.pixel(i % w, i / w));
        }
    }
    // Extend keeps the alpha channel, copied with its pixel.
    let out = dir.path().join("extended.png");
    cli(&[
        "extend",
        s(&input),
        "-o",
        s(&out),
        "--size",
        "128x128",
        "--tileable",
        "--seed",
        "4",
        "--quiet",
    ]);
    let mode = Mode::Extend {
        width: 128,
        height: 128,
        position: Position::Center,
    };
    let lib = run(&deep.search_colour(), &mode, &cfg, 2);
    let got = imaging::load_image(&out).unwrap();
    assert_copied("extend --tileable RGBA", &got, &deep, &lib.copy_map, None);
    let alphas: HashSet<u8> = (0..128 * 128)
        .map(|i| got.pixel(i % 128, i / 128)[3])
        .collect();
    assert!(
        alphas.len() > 16,
        "alpha lost its variation: {} values",
        alphas.len()
    );
}
