//! Loading and saving images through the `image` crate (ARCHITECTURE §3.1,
//! §3.10): format from the content on load, from the extension on save.

use std::fs::File;
use std::io::{self, BufReader, Write};
use std::path::Path;

use image::{DynamicImage, ExtendedColorType, ImageDecoder, ImageError, ImageFormat};

use super::atomic::{check_writable_any, write_atomic};
use super::deep::{Channels, DeepImage, Depth, PixelFormat};
use super::{
    check_size_impl, one_line, ColorImage, Gray, ImageIoError, JPEG_QUALITY, MAX_DECODE_ALLOC,
};
use crate::imaging::colour::luma;

fn read_error(path: &Path, e: io::Error) -> ImageIoError {
    match e.kind() {
        io::ErrorKind::NotFound => ImageIoError::NotFound(path.to_path_buf()),
        io::ErrorKind::PermissionDenied => ImageIoError::Unreadable {
            path: path.to_path_buf(),
            reason: "permission denied; check the file's permissions".into(),
        },
        _ => ImageIoError::Unreadable {
            path: path.to_path_buf(),
            reason: one_line(&e),
        },
    }
}

fn decode_error(path: &Path, e: ImageError) -> ImageIoError {
    let path = path.to_path_buf();
    match e {
        ImageError::Unsupported(u) => ImageIoError::Unsupported {
            path,
            reason: one_line(&u),
        },
        ImageError::Limits(l) => ImageIoError::Unsupported {
            path,
            reason: format!("{}: it needs too much memory", one_line(&l)),
        },
        ImageError::IoError(io) if io.kind() != io::ErrorKind::UnexpectedEof => {
            ImageIoError::Unreadable {
                path,
                reason: one_line(&io),
            }
        }
        other => ImageIoError::Corrupt {
            path,
            reason: one_line(&other),
        },
    }
}

/// Opens, identifies by content, size-checks and decodes an image file.
fn decode(path: &Path, what: &str) -> Result<DynamicImage, ImageIoError> {
    // Checked before opening: opening a FIFO would wait for a writer.
    let meta = std::fs::metadata(path).map_err(|e| read_error(path, e))?;
    if meta.is_dir() {
        return Err(ImageIoError::IsDirectory(path.to_path_buf()));
    }
    if !meta.is_file() {
        return Err(ImageIoError::NotRegular(path.to_path_buf()));
    }
    if meta.len() == 0 {
        return Err(ImageIoError::EmptyFile(path.to_path_buf()));
    }
    let file = File::open(path).map_err(|e| read_error(path, e))?;
    // The path may have been replaced between the two looks.
    if !file.metadata().map_err(|e| read_error(path, e))?.is_file() {
        return Err(ImageIoError::NotRegular(path.to_path_buf()));
    }
    let mut reader = image::ImageReader::new(BufReader::new(file))
        .with_guessed_format()
        .map_err(|e| read_error(path, e))?;
    if reader.format().is_none() {
        return Err(ImageIoError::NotAnImage(path.to_path_buf()));
    }
    // The JPEG decoder fills a truncated image with grey instead of failing.
    if reader.format() == Some(ImageFormat::Jpeg) {
        let mut r = BufReader::new(File::open(path).map_err(|e| read_error(path, e))?);
        if !jpeg_complete(&mut r).map_err(|e| read_error(path, e))? {
            return Err(ImageIoError::Corrupt {
                path: path.to_path_buf(),
                reason: "the JPEG data ends before its end-of-image marker".into(),
            });
        }
    }
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(MAX_DECODE_ALLOC);
    reader.limits(limits);
    let mut decoder = reader.into_decoder().map_err(|e| decode_error(path, e))?;
    let (w, h) = decoder.dimensions();
    check_size_impl(
        w as usize,
        h as usize,
        &format!("{what} {}", path.display()),
    )?;
    let orientation = decoder.orientation().map_err(|e| decode_error(path, e))?;
    let mut img = DynamicImage::from_decoder(decoder).map_err(|e| decode_error(path, e))?;
    img.apply_orientation(orientation);
    Ok(img)
}

/// True when a JPEG stream reaches its end-of-image marker; false when the
/// file ends first. Segments are skipped by their lengths, entropy-coded data
/// byte by byte (`FF 00` and restart markers are data); a stream that stops
/// looking like JPEG is left to the decoder (true).
pub(super) fn jpeg_complete(r: &mut impl io::Read) -> io::Result<bool> {
    use io::Read;
    let mut byte = [0u8; 1];
    let mut next = |r: &mut dyn io::Read| -> io::Result<Option<u8>> {
        Ok(match r.read(&mut byte)? {
            0 => None,
            _ => Some(byte[0]),
        })
    };
    macro_rules! get {
        () => {
            match next(r)? {
                Some(b) => b,
                None => return Ok(false),
            }
        };
    }
    if (get!(), get!()) != (0xFF, 0xD8) {
        return Ok(true);
    }
    let mut pending: Option<u8> = None;
    loop {
        let marker = match pending.take() {
            Some(m) => m,
            None => {
                if get!() != 0xFF {
                    return Ok(true);
                }
                let mut m = get!();
                while m == 0xFF {
                    m = get!();
                }
                m
            }
        };
        match marker {
            0xD9 => return Ok(true),
            0x01 | 0xD0..=0xD7 => continue,
            _ => {}
        }
        let len = u64::from(u16::from_be_bytes([get!(), get!()]));
        let want = len.saturating_sub(2);
        if io::copy(&mut r.by_ref().take(want), &mut io::sink())? < want {
            return Ok(false);
        }
        if marker == 0xDA {
            // Entropy-coded data up to the next marker.
            loop {
                if get!() != 0xFF {
                    continue;
                }
                let mut c = get!();
                while c == 0xFF {
                    c = get!();
                }
                if c != 0x00 && !(0xD0..=0xD7).contains(&c) {
                    pending = Some(c);
                    break;
                }
            }
        }
    }
}

/// Loads an image at its own depth and channels (PNG, JPEG, TIFF, BMP, WebP,
/// OpenEXR; format from the content).
pub fn load_image(path: &Path) -> anyhow::Result<DeepImage> {
    let img = decode(path, "image")?;
    DeepImage::from_dynamic(img).map_err(|reason| {
        ImageIoError::Unsupported {
            path: path.to_path_buf(),
            reason,
        }
        .into()
    })
}

/// Loads a colour image as the search sees it: 8-bit RGB (see
/// [`DeepImage::search_colour`]; alpha is ignored).
pub fn load_color(path: &Path) -> anyhow::Result<ColorImage> {
    Ok(load_image(path)?.search_colour())
}

/// Loads a hole mask of exactly `width`×`height` (ARCHITECTURE §3.1): true = hole
/// (luminance >= 128). Alpha composites over black, so transparent = not a hole.
pub fn load_mask(path: &Path, width: usize, height: usize) -> anyhow::Result<Vec<bool>> {
    let img = decode(path, "mask")?;
    check_mask_size(
        path,
        img.width() as usize,
        img.height() as usize,
        width,
        height,
    )?;
    let rgba = img.to_rgba8();
    Ok(rgba
        .pixels()
        .map(|p| {
            let [r, g, b, a] = p.0;
            let l = luma(r, g, b) as u32;
            (l * a as u32 + 127) / 255 >= 128
        })
        .collect())
}

/// Refuses a mask of another size than its image.
pub(super) fn check_mask_size(
    path: &Path,
    mask_width: usize,
    mask_height: usize,
    width: usize,
    height: usize,
) -> Result<(), ImageIoError> {
    if (mask_width, mask_height) != (width, height) {
        return Err(ImageIoError::MaskSize {
            path: path.to_path_buf(),
            mask_width,
            mask_height,
            width,
            height,
        });
    }
    Ok(())
}

/// Loads the holes of `path` from its alpha channel (ARCHITECTURE §3.1): a
/// pixel is a hole where its alpha is below half the range
/// ([`DeepImage::alpha_holes`]).
pub fn load_alpha_mask(path: &Path, img: &DeepImage) -> anyhow::Result<Vec<bool>> {
    img.alpha_holes().ok_or_else(|| {
        anyhow::anyhow!(
            "{} has no alpha channel ({}), so --mask-from-alpha finds no holes; \
             give the holes with --mask FILE or save the image with transparency where to fill",
            path.display(),
            img.format
        )
    })
}

/// Output formats, chosen by extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum OutFormat {
    Png,
    Jpeg,
    Tiff,
    Bmp,
    WebP,
    Exr,
}

impl OutFormat {
    fn name(self) -> &'static str {
        match self {
            OutFormat::Png => "PNG",
            OutFormat::Jpeg => "JPEG",
            OutFormat::Tiff => "TIFF",
            OutFormat::Bmp => "BMP",
            OutFormat::WebP => "WebP",
            OutFormat::Exr => "OpenEXR",
        }
    }

    /// Whether the `image` crate's encoder for this format writes `f`
    /// without converting it.
    fn holds(self, f: PixelFormat) -> bool {
        use Channels::*;
        match (self, f.depth) {
            (OutFormat::Png, Depth::U8 | Depth::U16) => true,
            (OutFormat::Tiff, Depth::U8 | Depth::U16) => f.channels != GrayAlpha,
            (OutFormat::Tiff | OutFormat::Exr, Depth::F32) => true,
            (OutFormat::Jpeg, Depth::U8) => matches!(f.channels, Gray | Rgb),
            // Neither has a grey mode the decoder gives back: grey would be read as RGB.
            (OutFormat::WebP | OutFormat::Bmp, Depth::U8) => matches!(f.channels, Rgb | Rgba),
            _ => false,
        }
    }
}

/// The output extensions whose format holds `f`, for error messages.
fn extensions_holding(f: PixelFormat) -> String {
    let all = [
        (OutFormat::Png, ".png"),
        (OutFormat::Tiff, ".tif"),
        (OutFormat::Exr, ".exr"),
        (OutFormat::WebP, ".webp"),
        (OutFormat::Bmp, ".bmp"),
        (OutFormat::Jpeg, ".jpg"),
    ];
    let names: Vec<_> = all
        .iter()
        .filter(|(o, _)| o.holds(f))
        .map(|(_, e)| *e)
        .collect();
    names.join(" or ")
}

fn output_format(path: &Path) -> Result<OutFormat, ImageIoError> {
    let unknown = |reason: String| ImageIoError::UnknownExtension {
        path: path.to_path_buf(),
        reason,
    };
    let ext = path
        .extension()
        .ok_or_else(|| unknown("the file name has no extension".into()))?;
    let lower = ext.to_string_lossy().to_ascii_lowercase();
    Ok(match lower.as_str() {
        "png" => OutFormat::Png,
        "jpg" | "jpeg" => OutFormat::Jpeg,
        "tif" | "tiff" => OutFormat::Tiff,
        "bmp" => OutFormat::Bmp,
        "webp" => OutFormat::WebP,
        "exr" => OutFormat::Exr,
        _ => {
            return Err(unknown(format!(
                "unknown extension \".{}\"",
                ext.to_string_lossy()
            )))
        }
    })
}

fn encode<W: Write + io::Seek>(
    w: &mut W,
    buf: &[u8],
    width: usize,
    height: usize,
    color: ExtendedColorType,
    fmt: OutFormat,
) -> Result<(), ImageError> {
    use image::ImageEncoder;
    let (w32, h32) = (width as u32, height as u32);
    match fmt {
        OutFormat::Jpeg => image::codecs::jpeg::JpegEncoder::new_with_quality(w, JPEG_QUALITY)
            .write_image(buf, w32, h32, color),
        OutFormat::WebP => {
            image::codecs::webp::WebPEncoder::new_lossless(w).write_image(buf, w32, h32, color)
        }
        OutFormat::Png => {
            image::write_buffer_with_format(w, buf, w32, h32, color, ImageFormat::Png)
        }
        OutFormat::Tiff => {
            image::write_buffer_with_format(w, buf, w32, h32, color, ImageFormat::Tiff)
        }
        OutFormat::Bmp => {
            image::write_buffer_with_format(w, buf, w32, h32, color, ImageFormat::Bmp)
        }
        OutFormat::Exr => {
            image::write_buffer_with_format(w, buf, w32, h32, color, ImageFormat::OpenExr)
        }
    }
}

/// Validates a buffer before it reaches an encoder (encoders panic on a wrong length).
fn check_buffer(
    path: &Path,
    width: usize,
    height: usize,
    channels: usize,
    len: usize,
) -> Result<(), ImageIoError> {
    let write = |reason: String| ImageIoError::Write {
        path: path.to_path_buf(),
        reason,
    };
    if width == 0 || height == 0 {
        return Err(write(format!(
            "the image is empty ({width}x{height} pixels)"
        )));
    }
    if width > u32::MAX as usize || height > u32::MAX as usize {
        return Err(write(format!(
            "the image is too large ({width}x{height} pixels)"
        )));
    }
    if width
        .checked_mul(height)
        .and_then(|n| n.checked_mul(channels))
        != Some(len)
    {
        return Err(write(format!(
            "internal error: pixel buffer of {len} bytes does not match {width}x{height}x{channels}"
        )));
    }
    Ok(())
}

/// Saves a colour image; format from the extension; atomic (temp file + rename).
pub fn save_color(path: &Path, img: &ColorImage) -> anyhow::Result<()> {
    let fmt = output_format(path)?;
    check_buffer(path, img.width, img.height, 3, img.rgb.len())?;
    write_atomic(path, |w| {
        encode(
            w,
            &img.rgb,
            img.width,
            img.height,
            ExtendedColorType::Rgb8,
            fmt,
        )
        .map_err(|e| one_line(&e))
    })?;
    Ok(())
}

/// Saves an image at its own depth and channels; format from the extension,
/// which must hold them ([`check_output_format`]); atomic (temp file + rename).
pub fn save_image(path: &Path, img: &DeepImage) -> anyhow::Result<()> {
    let fmt = output_format(path)?;
    format_holds(path, fmt, img.format)?;
    let bytes = img.bytes();
    check_buffer(
        path,
        img.width,
        img.height,
        img.format.bytes_per_pixel(),
        bytes.len(),
    )?;
    write_atomic(path, |w| {
        encode(
            w,
            bytes,
            img.width,
            img.height,
            img.format.color_type(),
            fmt,
        )
        .map_err(|e| one_line(&e))
    })?;
    Ok(())
}

/// Checks, before a long run, that the format of `path` (from its extension)
/// holds pixels of `format` without losing depth or channels.
pub fn check_output_format(path: &Path, format: PixelFormat) -> anyhow::Result<()> {
    format_holds(path, output_format(path)?, format).map_err(Into::into)
}

fn format_holds(path: &Path, fmt: OutFormat, format: PixelFormat) -> Result<(), ImageIoError> {
    if fmt.holds(format) {
        return Ok(());
    }
    Err(ImageIoError::Write {
        path: path.to_path_buf(),
        reason: format!(
            "{} cannot hold the input's {format} pixels without losing depth or channels; \
             use {}",
            fmt.name(),
            extensions_holding(format)
        ),
    })
}

/// Saves a grey image; format from the extension; atomic (temp file + rename).
pub fn save_gray(path: &Path, g: &Gray) -> anyhow::Result<()> {
    let fmt = output_format(path)?;
    check_buffer(path, g.width, g.height, 1, g.data.len())?;
    write_atomic(path, |w| {
        encode(w, &g.data, g.width, g.height, ExtendedColorType::L8, fmt).map_err(|e| one_line(&e))
    })?;
    Ok(())
}

/// Writes arbitrary bytes (e.g. a JSON run report) atomically, like the image savers.
pub fn save_bytes(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    write_atomic(path, |w| w.write_all(bytes).map_err(|e| one_line(&e)))?;
    Ok(())
}

/// Checks, before a long run, that the format of `path` (from its extension)
/// can hold a `width`×`height` image: JPEG at most 65535 and WebP at most
/// 16383 pixels per side.
pub fn check_output_size(path: &Path, width: usize, height: usize) -> anyhow::Result<()> {
    let (name, max) = match output_format(path)? {
        OutFormat::Jpeg => ("JPEG", 65_535),
        OutFormat::WebP => ("WebP", 16_383),
        OutFormat::Png | OutFormat::Tiff | OutFormat::Bmp | OutFormat::Exr => return Ok(()),
    };
    if width > max || height > max {
        return Err(ImageIoError::FormatTooSmall {
            path: path.to_path_buf(),
            format: name,
            max,
            width,
            height,
        }
        .into());
    }
    Ok(())
}

/// Checks, before a long run, that `path` has a supported extension, is not a
/// directory, and that its directory exists and accepts a new file.
pub fn check_writable(path: &Path) -> anyhow::Result<()> {
    output_format(path)?;
    check_writable_any(path)
}

/// Checks that `path` is a regular file (not a FIFO, device or directory) of
/// at most `max` bytes, before anything opens it: a FIFO would block the read
/// and `/dev/zero` would fill memory. `what` names the file in the message.
pub fn check_regular(path: &Path, max: u64, what: &str) -> anyhow::Result<u64> {
    let meta = std::fs::metadata(path)
        .map_err(|e| anyhow::anyhow!("cannot read {what} {}: {e}", path.display()))?;
    anyhow::ensure!(
        meta.is_file(),
        "{what} {} is not a regular file; give the file itself",
        path.display()
    );
    anyhow::ensure!(
        meta.len() <= max,
        "{what} {} is {} bytes, over the {} MiB a {what} may have; give the file texsyn wrote",
        path.display(),
        meta.len(),
        max >> 20
    );
    Ok(meta.len())
}

/// Reads a regular file of at most `max` bytes ([`check_regular`]), never
/// more than `max` bytes even if it grows meanwhile.
pub fn read_regular(path: &Path, max: u64, what: &str) -> anyhow::Result<Vec<u8>> {
    use std::io::Read;
    check_regular(path, max, what)?;
    let mut bytes = Vec::new();
    std::fs::File::open(path)
        .and_then(|f| f.take(max + 1).read_to_end(&mut bytes))
        .map_err(|e| anyhow::anyhow!("cannot read {what} {}: {e}", path.display()))?;
    anyhow::ensure!(
        bytes.len() as u64 <= max,
        "{what} {} grew past {} MiB while it was read",
        path.display(),
        max >> 20
    );
    Ok(bytes)
}
