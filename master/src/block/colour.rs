//! Colour from the copy map (Stahlhut §7, §9; ARCHITECTURE §3.7, §3.10).
//!
//! The search runs on luminance; at the finest level every output pixel takes
//! the colour of the sample pixel its copy-map entry points at. Optionally a
//! light chroma blur softens colour steps at patch borders while keeping
//! luminance, and the copy map can be drawn as a picture.

use anyhow::bail;

use crate::imaging::colour::{from_ycc, to_ycc};
use crate::imaging::ColorImage;

/// Rebuilds colour: output pixel `i` = `sample` at `copy_map[i]` (`[x, y]`).
/// Fails if the map does not have `width * height` entries or points outside
/// the sample.
pub fn rebuild(
    sample: &ColorImage,
    copy_map: &[[u32; 2]],
    width: usize,
    height: usize,
) -> anyhow::Result<ColorImage> {
    rebuild_except(sample, copy_map, width, height, None)
}

/// [`rebuild`], leaving black the pixels flagged in `skip` (a fill from
/// another source keeps the photo's pixels there, and their copy-map
/// entries point into the photo, not the source).
pub fn rebuild_except(
    sample: &ColorImage,
    copy_map: &[[u32; 2]],
    width: usize,
    height: usize,
    skip: Option<&[bool]>,
) -> anyhow::Result<ColorImage> {
    if skip.is_some_and(|k| k.len() != copy_map.len()) {
        bail!("the kept-pixel mask does not match the copy map");
    }
    if Some(copy_map.len()) != width.checked_mul(height) {
        bail!(
            "copy map has {} entries but the canvas is {width}x{height}",
            copy_map.len()
        );
    }
    if sample.rgb.len() != sample.width * sample.height * 3 {
        bail!(
            "colour sample buffer does not match its size {}x{}",
            sample.width,
            sample.height
        );
    }
    let mut out = ColorImage::new(width, height);
    for (i, (&[sx, sy], px)) in copy_map.iter().zip(out.rgb.chunks_exact_mut(3)).enumerate() {
        if skip.is_some_and(|k| k[i]) {
            continue;
        }
        let (sx, sy) = (sx as usize, sy as usize);
        if sx >= sample.width || sy >= sample.height {
            bail!(
                "copy map entry at ({}, {}) points to ({sx}, {sy}), outside the {}x{} colour sample",
                i % width,
                i / width,
                sample.width,
                sample.height
            );
        }
        let j = (sy * sample.width + sx) * 3;
        px.copy_from_slice(&sample.rgb[j..j + 3]);
    }
    Ok(out)
}

/// True if a 4-neighbour of `(x, y)` was not copied from the adjacent sample
/// pixel, i.e. `(x, y)` lies on a patch border.
fn is_seam(copy_map: &[[u32; 2]], w: usize, h: usize, x: usize, y: usize) -> bool {
    let [sx, sy] = copy_map[y * w + x];
    let (sx, sy) = (i64::from(sx), i64::from(sy));
    let (x, y) = (x as i64, y as i64);
    [(-1i64, 0i64), (1, 0), (0, -1), (0, 1)]
        .iter()
        .any(|&(dx, dy)| {
            let (nx, ny) = (x + dx, y + dy);
            if nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 {
                return false;
            }
            let [tx, ty] = copy_map[ny as usize * w + nx as usize];
            (i64::from(tx), i64::from(ty)) != (sx + dx, sy + dy)
        })
}

/// Light chroma blur at patch borders (ARCHITECTURE §3.7): pixels within `radius`
/// (Chebyshev distance) of a seam get the box mean of Cb and Cr over a
/// `(2·radius+1)²` window (clipped at the image edge); Y is kept (±1 after
/// rounding) and all other pixels are left untouched. Does nothing if
/// `radius == 0` or the copy map does not match the image.
pub fn chroma_blur_borders(img: &mut ColorImage, copy_map: &[[u32; 2]], radius: usize) {
    let (w, h) = (img.width, img.height);
    if radius == 0 || w == 0 || h == 0 || copy_map.len() != w * h || img.rgb.len() != w * h * 3 {
        return;
    }
    let r = radius.min(w.max(h));
    let mut win = Window::new(w, h, r);
    for yy in 0..=r.min(h - 1) {
        win.add_row(img, copy_map, yy);
    }
    let (mut pre_cb, mut pre_cr) = (vec![0i64; w + 1], vec![0i64; w + 1]);
    let mut pre_seam = vec![0u32; w + 1];
    for y in 0..h {
        if y > r {
            win.drop_row(y - r - 1);
        }
        if y > 0 && y + r < h {
            win.add_row(img, copy_map, y + r);
        }
        let rows = (y + r).min(h - 1) - y.saturating_sub(r) + 1;
        for x in 0..w {
            pre_cb[x + 1] = pre_cb[x] + win.col_cb[x];
            pre_cr[x + 1] = pre_cr[x] + win.col_cr[x];
            pre_seam[x + 1] = pre_seam[x] + win.col_seam[x];
        }
        for x in 0..w {
            let (x0, x1) = (x.saturating_sub(r), (x + r).min(w - 1) + 1);
            if pre_seam[x1] == pre_seam[x0] {
                continue; // no seam within `radius`: untouched
            }
            let n = ((x1 - x0) * rows) as i64;
            let mean = |s: i64| (2 * s + n).div_euclid(2 * n);
            let cb = mean(pre_cb[x1] - pre_cb[x0]);
            let cr = mean(pre_cr[x1] - pre_cr[x0]);
            let i = (y * w + x) * 3;
            let (yk, _, _) = to_ycc(&img.rgb[i..i + 3]);
            img.rgb[i..i + 3].copy_from_slice(&from_ycc(yk, cb, cr));
        }
    }
}

/// Sliding window over rows for [`chroma_blur_borders`]: per-column sums of
/// chroma and seam counts of the rows in the window. Rows above the current
/// one are already rewritten, so the original values of the rows still in
/// the window are kept in a ring of `min(2r+2, h)` rows.
struct Window {
    w: usize,
    h: usize,
    ring_len: usize,
    ring_cb: Vec<i64>,
    ring_cr: Vec<i64>,
    ring_seam: Vec<bool>,
    col_cb: Vec<i64>,
    col_cr: Vec<i64>,
    col_seam: Vec<u32>,
}

impl Window {
    fn new(w: usize, h: usize, r: usize) -> Self {
        let ring_len = (2 * r + 2).min(h);
        Self {
            w,
            h,
            ring_len,
            ring_cb: vec![0; ring_len * w],
            ring_cr: vec![0; ring_len * w],
            ring_seam: vec![false; ring_len * w],
            col_cb: vec![0; w],
            col_cr: vec![0; w],
            col_seam: vec![0; w],
        }
    }

    fn add_row(&mut self, img: &ColorImage, copy_map: &[[u32; 2]], y: usize) {
        let (w, h) = (self.w, self.h);
        let s = (y % self.ring_len) * w;
        for x in 0..w {
            let i = (y * w + x) * 3;
            let (_, cb, cr) = to_ycc(&img.rgb[i..i + 3]);
            let seam = is_seam(copy_map, w, h, x, y);
            self.ring_cb[s + x] = cb;
            self.ring_cr[s + x] = cr;
            self.ring_seam[s + x] = seam;
            self.col_cb[x] += cb;
            self.col_cr[x] += cr;
            self.col_seam[x] += u32::from(seam);
        }
    }

    fn drop_row(&mut self, y: usize) {
        let s = (y % self.ring_len) * self.w;
        for x in 0..self.w {
            self.col_cb[x] -= self.ring_cb[s + x];
            self.col_cr[x] -= self.ring_cr[s + x];
            self.col_seam[x] -= u32::from(self.ring_seam[s + x]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imaging::colour::luminance;

    fn sample(w: usize, h: usize, seed: u32) -> ColorImage {
        let mut s = seed.wrapping_mul(2_654_435_761) | 1;
        let rgb = (0..w * h * 3)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 17;
                s ^= s << 5;
                (s >> 24) as u8
            })
            .collect();
        ColorImage::from_vec(w, h, rgb)
    }

    /// A canvas of `w`×`h` made of two patches split at column `split`.
    fn two_patch_map(w: usize, h: usize, split: usize) -> Vec<[u32; 2]> {
        let mut m = Vec::with_capacity(w * h);
        for y in 0..h {
            for x in 0..w {
                if x < split {
                    m.push([x as u32, y as u32]);
                } else {
                    m.push([(x - split + 3) as u32, (y + 5) as u32]);
                }
            }
        }
        m
    }

    #[test]
    fn rebuild_picks_exact_pixels() {
        let s = sample(10, 8, 1);
        let map: Vec<[u32; 2]> = (0..12)
            .map(|i| [(i * 7 % 10) as u32, (i % 8) as u32])
            .collect();
        let out = rebuild(&s, &map, 4, 3).unwrap();
        for (i, &[x, y]) in map.iter().enumerate() {
            assert_eq!(out.get(i % 4, i / 4), s.get(x as usize, y as usize));
        }
    }

    #[test]
    fn rebuild_errors() {
        let s = sample(4, 4, 2);
        let e = rebuild(&s, &[[4, 0]], 1, 1).unwrap_err().to_string();
        assert!(e.contains("(4, 0)") && e.contains("4x4"), "{e}");
        assert!(rebuild(&s, &[[0, 9]], 1, 1).is_err());
        let e = rebuild(&s, &[[0, 0]; 3], 2, 2).unwrap_err().to_string();
        assert!(e.contains("3 entries"), "{e}");
    }

    #[test]
    fn chroma_blur_keeps_luma_and_far_pixels() {
        let (w, h, split, r) = (24, 10, 11, 2);
        let s = sample(40, 20, 3);
        let map = two_patch_map(w, h, split);
        let before = rebuild(&s, &map, w, h).unwrap();
        let mut after = before.clone();
        chroma_blur_borders(&mut after, &map, r);
        let (ya, yb) = (luminance(&before), luminance(&after));
        let mut changed_near = 0;
        for y in 0..h {
            for x in 0..w {
                let d = ya.get(x, y) as i32 - yb.get(x, y) as i32;
                assert!(d.abs() <= 1, "Y moved by {d} at ({x}, {y})");
                // Seam pixels are the columns split-1 and split.
                let dist = if x < split { split - 1 - x } else { x - split };
                if dist > r {
                    assert_eq!(
                        before.get(x, y),
                        after.get(x, y),
                        "({x}, {y}) far from seam"
                    );
                } else if before.get(x, y) != after.get(x, y) {
                    changed_near += 1;
                }
            }
        }
        assert!(changed_near > 0);
    }

    #[test]
    fn chroma_blur_matches_direct_box_mean() {
        // Irregular patches, radius larger than the image in one direction.
        let (w, h) = (9, 4);
        let s = sample(30, 30, 9);
        let map: Vec<[u32; 2]> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let patch = (x / 3 + y / 2) as u32;
                [x as u32 + 4 * patch, y as u32 + 3 * patch]
            })
            .collect();
        let before = rebuild(&s, &map, w, h).unwrap();
        for r in [1usize, 2, 5] {
            let mut after = before.clone();
            chroma_blur_borders(&mut after, &map, r);
            for y in 0..h {
                for x in 0..w {
                    let (x0, x1) = (x.saturating_sub(r), (x + r).min(w - 1));
                    let (y0, y1) = (y.saturating_sub(r), (y + r).min(h - 1));
                    let near = (y0..=y1).any(|yy| (x0..=x1).any(|xx| is_seam(&map, w, h, xx, yy)));
                    let expect = if near {
                        let (mut scb, mut scr, mut n) = (0i64, 0i64, 0i64);
                        for yy in y0..=y1 {
                            for xx in x0..=x1 {
                                let (_, cb, cr) = to_ycc(&before.get(xx, yy));
                                scb += cb;
                                scr += cr;
                                n += 1;
                            }
                        }
                        let m = |s: i64| (2 * s + n).div_euclid(2 * n);
                        let (yk, _, _) = to_ycc(&before.get(x, y));
                        from_ycc(yk, m(scb), m(scr))
                    } else {
                        before.get(x, y)
                    };
                    assert_eq!(after.get(x, y), expect, "r={r} ({x}, {y})");
                }
            }
        }
    }

    #[test]
    fn chroma_blur_without_seams_or_radius_is_identity() {
        let s = sample(8, 8, 4);
        let map: Vec<[u32; 2]> = (0..64).map(|i| [(i % 8) as u32, (i / 8) as u32]).collect();
        let mut img = rebuild(&s, &map, 8, 8).unwrap();
        chroma_blur_borders(&mut img, &map, 3);
        assert_eq!(img, s);
        let map2 = two_patch_map(8, 8, 4);
        let mut img2 = rebuild(&sample(20, 20, 5), &map2, 8, 8).unwrap();
        let orig = img2.clone();
        chroma_blur_borders(&mut img2, &map2, 0);
        assert_eq!(img2, orig);
        chroma_blur_borders(&mut img2, &map2[..3], 2);
        assert_eq!(img2, orig);
    }
}
