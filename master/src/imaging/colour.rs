//! BT.601 full-range YCbCr in integer arithmetic: the one place the library
//! converts between RGB and luminance/chroma (Stahlhut §7, §9; ARCHITECTURE §3,
//! §3.7).
//!
//! Two fixed-point forms are used, and both are part of the output contract:
//! - [`luma`]: the *search luminance*, rounded in thousandths (see there);
//! - [`to_ycc`] / [`from_ycc`]: 16-bit fixed point with the JPEG/JFIF
//!   coefficients, for chroma (colour search, chroma blur).

use crate::imaging::{ColorImage, Gray};

/// 1.0 in the 16-bit fixed point of [`to_ycc`].
pub const ONE: i64 = 1 << 16;

/// BT.601 luminance of one pixel, `(299R + 587G + 114B + 500) / 1000`.
///
/// This is the luminance every search compares, so every output depends on
/// it: it stays rounded in thousandths, as it always was. The 16-bit Y of
/// [`to_ycc`] would round differently on 9 040 of the 2²⁴ colours, changing
/// outputs; do not replace one by the other.
#[inline]
pub fn luma(r: u8, g: u8, b: u8) -> u8 {
    ((299 * r as u32 + 587 * g as u32 + 114 * b as u32 + 500) / 1000) as u8
}

/// BT.601 luma of an RGB colour held as floating point (0–255), unrounded.
pub fn luma_f64(c: &[f64; 3]) -> f64 {
    0.299 * c[0] + 0.587 * c[1] + 0.114 * c[2]
}

/// The search luminance plane of an image ([`luma`] per pixel).
pub fn luminance(img: &ColorImage) -> Gray {
    let data = img
        .rgb
        .chunks_exact(3)
        .map(|p| luma(p[0], p[1], p[2]))
        .collect();
    Gray {
        width: img.width,
        height: img.height,
        data,
    }
}

/// Y·2¹⁶, Cb·2¹⁶, Cr·2¹⁶ of an RGB pixel (chroma centred on 0).
#[inline]
pub fn to_ycc(p: &[u8]) -> (i64, i64, i64) {
    let (r, g, b) = (i64::from(p[0]), i64::from(p[1]), i64::from(p[2]));
    (
        19595 * r + 38470 * g + 7471 * b,
        -11059 * r - 21709 * g + 32768 * b,
        32768 * r - 27439 * g - 5329 * b,
    )
}

/// Back to RGB keeping Y: if the chroma would leave the RGB cube it is scaled
/// towards grey (which keeps Y) until it fits, then the result is rounded and clamped.
pub fn from_ycc(y: i64, cb: i64, cr: i64) -> [u8; 3] {
    // Channel = (base + d) / 2³², with d linear in (cb, cr).
    let base = i128::from(y) * i128::from(ONE);
    let deltas = |cb: i128, cr: i128| [91881 * cr, -22554 * cb - 46802 * cr, 116130 * cb];
    let (mut cb, mut cr) = (i128::from(cb), i128::from(cr));
    let hi = 255i128 << 32;
    // Largest t = num/den in [0, 1] keeping every channel inside [0, 255].
    let (mut num, mut den) = (1i128, 1i128);
    for d in deltas(cb, cr) {
        let (n, dd) = if d > 0 && base + d > hi {
            (hi - base, d)
        } else if d < 0 && base + d < 0 {
            (base, -d)
        } else {
            continue;
        };
        if n * den < num * dd {
            (num, den) = (n, dd);
        }
    }
    if num != den {
        cb = cb * num / den;
        cr = cr * num / den;
    }
    deltas(cb, cr).map(|d| ((base + d + (1i128 << 31)) >> 32).clamp(0, 255) as u8)
}

/// A 16-bit chroma value as a byte: truncated toward zero, offset by 128, clamped.
#[inline]
fn chroma_byte(c16: i64) -> u8 {
    (c16 / ONE + 128).clamp(0, 255) as u8
}

/// Cb and Cr bytes of an RGB pixel, as compared by the full-colour search.
#[inline]
pub fn chroma(p: &[u8]) -> [u8; 2] {
    let (_, cb, cr) = to_ycc(p);
    [chroma_byte(cb), chroma_byte(cr)]
}

/// Cb and Cr planes of an image ([`chroma`] per pixel).
pub fn chroma_planes(img: &ColorImage) -> [Gray; 2] {
    let n = img.width * img.height;
    let (mut cb, mut cr) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for p in img.rgb.chunks_exact(3) {
        let [b, r] = chroma(p);
        cb.push(b);
        cr.push(r);
    }
    [
        Gray::from_vec(img.width, img.height, cb),
        Gray::from_vec(img.width, img.height, cr),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every colour in a release build; every 7th in a debug build.
    fn colours() -> impl Iterator<Item = [u8; 3]> {
        let step = if cfg!(debug_assertions) { 7 } else { 1 };
        (0u32..1 << 24)
            .step_by(step)
            .map(|c| [(c >> 16) as u8, (c >> 8) as u8, c as u8])
    }

    #[test]
    fn luma_and_chroma_match_plain_formulas() {
        for p in colours() {
            let (r, g, b) = (i64::from(p[0]), i64::from(p[1]), i64::from(p[2]));
            // Luminance: BT.601 in thousandths, rounded half up.
            let y = ((299 * r + 587 * g + 114 * b) as f64 / 1000.0 + 0.5).floor() as u8;
            assert_eq!(luma(p[0], p[1], p[2]), y, "{p:?}");
            // Chroma: BT.601 in millionths, truncated toward zero, +128, clamped.
            let cb = ((-168_736 * r - 331_264 * g + 500_000 * b) / 1_000_000 + 128).clamp(0, 255);
            let cr = ((500_000 * r - 418_688 * g - 81_312 * b) / 1_000_000 + 128).clamp(0, 255);
            assert_eq!(chroma(&p), [cb as u8, cr as u8], "{p:?}");
        }
    }

    #[test]
    fn planes_hold_per_pixel_values() {
        let img = ColorImage::from_vec(2, 1, vec![10, 200, 30, 250, 5, 128]);
        let [cb, cr] = chroma_planes(&img);
        let y = luminance(&img);
        for x in 0..2 {
            let p = img.get(x, 0);
            assert_eq!([cb.get(x, 0), cr.get(x, 0)], chroma(&p));
            assert_eq!(y.get(x, 0), luma(p[0], p[1], p[2]));
        }
    }

    #[test]
    fn ycc_roundtrip_is_exact_for_8bit() {
        for r in (0..=255).step_by(5) {
            for g in (0..=255).step_by(3) {
                for b in (0..=255).step_by(7) {
                    let p = [r as u8, g as u8, b as u8];
                    let (y, cb, cr) = to_ycc(&p);
                    assert_eq!(from_ycc(y, cb, cr), p);
                }
            }
        }
    }

    #[test]
    fn out_of_gamut_chroma_keeps_luma() {
        for &(p, cb, cr) in &[
            ([250u8, 250, 250], 100 * ONE, 100 * ONE),
            ([5, 5, 5], -120 * ONE, 127 * ONE),
            ([128, 20, 230], 127 * ONE, -128 * ONE),
        ] {
            let (y, _, _) = to_ycc(&p);
            let q = from_ycc(y, cb, cr);
            let l = |p: [u8; 3]| luma(p[0], p[1], p[2]) as i32;
            assert!((l(p) - l(q)).abs() <= 1, "{p:?} -> {q:?}");
        }
    }
}
