//! Coordinate maps on disk (ARCHITECTURE §3.10, §10): for every output pixel,
//! the sample pixel it came from, as a 16-bit RGB PNG with R = x, G = y and
//! B = 0. Both synthesis methods write it (`--copy-map`, `--coords`) and
//! `texsyn replay` reads it; 16 bits hold every coordinate of a sample up to
//! [`super::MAX_SIDE`] pixels a side exactly.

use std::path::Path;

use anyhow::{bail, ensure, Context, Result};
use image::{ImageBuffer, ImageEncoder, Rgb};

/// Writes `coords` (row by row, `width`×`height`) atomically as a 16-bit PNG.
pub fn save_coord_map(path: &Path, width: usize, height: usize, coords: &[[u32; 2]]) -> Result<()> {
    ensure!(
        Some(coords.len()) == width.checked_mul(height),
        "a {width}x{height} coordinate map needs {} entries, not {}",
        width * height,
        coords.len()
    );
    check_coord_map_path(path)?;
    let mut raw = Vec::with_capacity(coords.len() * 3);
    for &[x, y] in coords {
        let fit = |v: u32| u16::try_from(v).context("a coordinate above 65535 does not fit");
        raw.extend([fit(x)?, fit(y)?, 0]);
    }
    let img: ImageBuffer<Rgb<u16>, Vec<u16>> =
        ImageBuffer::from_raw(width as u32, height as u32, raw).context("map size")?;
    let mut png = Vec::new();
    image::codecs::png::PngEncoder::new(&mut png)
        .write_image(
            bytes_of(img.as_raw()).as_slice(),
            width as u32,
            height as u32,
            image::ExtendedColorType::Rgb16,
        )
        .context("cannot encode the coordinate map")?;
    super::save_bytes(path, &png)
}

/// Refuses a coordinate-map path that is not a `.png` (checked before a run,
/// so no work is lost to a bad name).
pub fn check_coord_map_path(path: &Path) -> Result<()> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    ensure!(
        ext == "png",
        "coordinate map {} must be a .png (16-bit RGB holds the coordinates exactly); name it with .png",
        path.display()
    );
    Ok(())
}

/// The 16-bit samples in the byte order the PNG encoder takes (native).
fn bytes_of(v: &[u16]) -> Vec<u8> {
    v.iter().flat_map(|s| s.to_ne_bytes()).collect()
}

/// Largest coordinate map file read: an uncompressed 16-bit RGB map of
/// [`super::MAX_PIXELS`] pixels.
const MAX_COORD_MAP_BYTES: u64 = super::MAX_PIXELS as u64 * 6 + (1 << 20);

/// Reads a coordinate map written by [`save_coord_map`]: its size and entries.
pub fn load_coord_map(path: &Path) -> Result<(usize, usize, Vec<[u32; 2]>)> {
    super::check_regular(path, MAX_COORD_MAP_BYTES, "coordinate map")?;
    let img = image::ImageReader::open(path)
        .with_context(|| format!("cannot open coordinate map {}", path.display()))?
        .with_guessed_format()
        .with_context(|| format!("cannot read coordinate map {}", path.display()))?
        .decode()
        .with_context(|| format!("cannot decode coordinate map {}", path.display()))?;
    let image::DynamicImage::ImageRgb16(buf) = img else {
        bail!(
            "{} is not a coordinate map: it is {:?}, and a map is a 16-bit RGB PNG as `--coords` or `--copy-map` write it",
            path.display(),
            img.color()
        );
    };
    let (w, h) = (buf.width() as usize, buf.height() as usize);
    let coords = buf
        .pixels()
        .map(|p| [u32::from(p.0[0]), u32::from(p.0[1])])
        .collect();
    Ok((w, h, coords))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_map_round_trips_exactly() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("c.png");
        let coords: Vec<[u32; 2]> = (0..35u32).map(|i| [i * 1871 % 65536, 65535 - i]).collect();
        save_coord_map(&p, 7, 5, &coords).unwrap();
        assert_eq!(load_coord_map(&p).unwrap(), (7, 5, coords));
    }

    #[test]
    fn a_colour_picture_is_not_a_map() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("c.png");
        super::super::save_color(&p, &super::super::ColorImage::new(4, 4)).unwrap();
        let e = load_coord_map(&p).unwrap_err().to_string();
        assert!(e.contains("not a coordinate map"), "{e}");
        assert!(save_coord_map(&dir.path().join("c.jpg"), 1, 1, &[[0, 0]]).is_err());
    }
}
