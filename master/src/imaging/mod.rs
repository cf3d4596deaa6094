//! Images at the edges, plain slices inside (ARCHITECTURE §3, §3.1, §3.10).
//!
//! Loading and saving go through the `image` crate; everything else in the
//! library sees [`ColorImage`] (8-bit RGB) and [`Gray`] (8-bit luminance) as
//! plain row-major byte vectors.
//!
//! Loading rules: the format is guessed from the file content (not the
//! extension); 16-bit samples are rounded to 8 bit; grey images are replicated
//! to RGB; EXIF orientation is applied; **alpha is ignored** for colour images
//! (the stored RGB is kept as is), while for masks a transparent pixel is
//! composited over black, i.e. it never marks a hole.
//!
//! Saving is atomic: the image is encoded into a hidden temporary file in the
//! target directory, synced, and renamed over the target, so an interrupted or
//! failed save never leaves a truncated file behind.

use std::ffi::OsString;
use std::fs::{self, File, OpenOptions};
use std::io::{self, BufReader, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use image::{DynamicImage, ExtendedColorType, ImageDecoder, ImageError, ImageFormat};

/// Largest number of pixels of an input image or canvas (64 Mi pixels).
pub const MAX_PIXELS: usize = 64 * 1024 * 1024;
/// Largest width or height of an input image or canvas.
pub const MAX_SIDE: usize = 32768;
/// Decoder allocation cap: a MAX_PIXELS RGBA16 image (512 MiB) plus headroom.
const MAX_DECODE_ALLOC: u64 = 1 << 30;
/// JPEG quality used for saving (the encoder default of 75 is too lossy for textures).
const JPEG_QUALITY: u8 = 95;
/// Output extensions, as listed in error messages.
const SUPPORTED_EXTENSIONS: &str = ".png, .jpg, .jpeg, .tif, .tiff, .bmp, .webp";

/// An 8-bit RGB image, row-major, 3 bytes per pixel.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ColorImage {
    pub width: usize,
    pub height: usize,
    pub rgb: Vec<u8>,
}

impl ColorImage {
    /// A black image.
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            rgb: vec![0; width * height * 3],
        }
    }

    /// Wraps an RGB buffer. Panics if `rgb.len() != width * height * 3`.
    pub fn from_vec(width: usize, height: usize, rgb: Vec<u8>) -> Self {
        assert_eq!(rgb.len(), width * height * 3, "RGB buffer size");
        Self { width, height, rgb }
    }

    /// Number of pixels.
    pub fn len(&self) -> usize {
        self.width * self.height
    }

    /// True when the image has no pixel.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The pixel at (x, y).
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> [u8; 3] {
        let i = (y * self.width + x) * 3;
        [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
    }

    /// Sets the pixel at (x, y).
    #[inline]
    pub fn set(&mut self, x: usize, y: usize, p: [u8; 3]) {
        let i = (y * self.width + x) * 3;
        self.rgb[i..i + 3].copy_from_slice(&p);
    }
}

/// An 8-bit single-channel image, row-major.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Gray {
    pub width: usize,
    pub height: usize,
    pub data: Vec<u8>,
}

impl Gray {
    /// A black image.
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            data: vec![0; width * height],
        }
    }

    /// Wraps a buffer. Panics if `data.len() != width * height`.
    pub fn from_vec(width: usize, height: usize, data: Vec<u8>) -> Self {
        assert_eq!(data.len(), width * height, "gray buffer size");
        Self {
            width,
            height,
            data,
        }
    }

    /// Number of pixels.
    pub fn len(&self) -> usize {
        self.width * self.height
    }

    /// True when the image has no pixel.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The pixel at (x, y).
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> u8 {
        self.data[y * self.width + x]
    }

    /// Sets the pixel at (x, y).
    #[inline]
    pub fn set(&mut self, x: usize, y: usize, v: u8) {
        self.data[y * self.width + x] = v;
    }

    /// Row `y` as a slice.
    #[inline]
    pub fn row(&self, y: usize) -> &[u8] {
        &self.data[y * self.width..(y + 1) * self.width]
    }
}

/// Errors of image input/output; each displays as one line naming the path
/// and what to do about it.
#[derive(Debug, thiserror::Error)]
pub enum ImageIoError {
    #[error("no such file: {}", .0.display())]
    NotFound(PathBuf),
    #[error("{} is a directory, not an image file", .0.display())]
    IsDirectory(PathBuf),
    #[error("cannot read {}: {reason}", path.display())]
    Unreadable { path: PathBuf, reason: String },
    #[error(
        "{} is not an image in a supported format (PNG, JPEG, TIFF, BMP or WebP); convert it to PNG",
        .0.display()
    )]
    NotAnImage(PathBuf),
    #[error("{} uses an unsupported format or variant ({reason}); convert it to 8- or 16-bit PNG", path.display())]
    Unsupported { path: PathBuf, reason: String },
    #[error("cannot decode {}: {reason}; the file is truncated or corrupt, export it again", path.display())]
    Corrupt { path: PathBuf, reason: String },
    #[error("{what} is empty ({width}x{height} pixels); it needs at least one pixel")]
    Empty {
        what: String,
        width: usize,
        height: usize,
    },
    #[error(
        "{what} is {width}x{height} pixels, over the limit of {MAX_SIDE} pixels per side and \
         {MAX_PIXELS} pixels (64 Mi) in total; use a smaller size"
    )]
    TooLarge {
        what: String,
        width: usize,
        height: usize,
    },
    #[error(
        "mask {} is {mask_width}x{mask_height} pixels but the image is {width}x{height}; \
         they must be the same size",
        path.display()
    )]
    MaskSize {
        path: PathBuf,
        mask_width: usize,
        mask_height: usize,
        width: usize,
        height: usize,
    },
    #[error("cannot save {}: {reason}; use one of the extensions {SUPPORTED_EXTENSIONS}", path.display())]
    UnknownExtension { path: PathBuf, reason: String },
    #[error("cannot write {}: directory {} does not exist; create it first", path.display(), dir.display())]
    NoDirectory { path: PathBuf, dir: PathBuf },
    #[error("cannot write {}: {reason}", path.display())]
    Write { path: PathBuf, reason: String },
}

/// Rejects a 0-sized image and one over [`MAX_SIDE`] per side or [`MAX_PIXELS`]
/// in total; `what` names the image in the message (e.g. "canvas").
pub fn check_size(width: usize, height: usize, what: &str) -> anyhow::Result<()> {
    check_size_impl(width, height, what).map_err(Into::into)
}

fn check_size_impl(width: usize, height: usize, what: &str) -> Result<(), ImageIoError> {
    if width == 0 || height == 0 {
        return Err(ImageIoError::Empty {
            what: what.to_string(),
            width,
            height,
        });
    }
    let too_large = width > MAX_SIDE
        || height > MAX_SIDE
        || width.checked_mul(height).is_none_or(|n| n > MAX_PIXELS);
    if too_large {
        return Err(ImageIoError::TooLarge {
            what: what.to_string(),
            width,
            height,
        });
    }
    Ok(())
}

/// One line of an error, for embedding in our own messages.
fn one_line(e: &dyn std::fmt::Display) -> String {
    e.to_string().replace(['\n', '\r'], " ")
}

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
    let file = File::open(path).map_err(|e| read_error(path, e))?;
    let meta = file.metadata().map_err(|e| read_error(path, e))?;
    if meta.is_dir() {
        return Err(ImageIoError::IsDirectory(path.to_path_buf()));
    }
    let mut reader = image::ImageReader::new(BufReader::new(file))
        .with_guessed_format()
        .map_err(|e| read_error(path, e))?;
    if reader.format().is_none() {
        return Err(ImageIoError::NotAnImage(path.to_path_buf()));
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

/// Loads a colour image (PNG, JPEG, TIFF, BMP, WebP; format from the content).
/// 16-bit samples are rounded to 8 bit, grey becomes RGB, alpha is ignored.
pub fn load_color(path: &Path) -> anyhow::Result<ColorImage> {
    let img = decode(path, "image")?;
    let (width, height) = (img.width() as usize, img.height() as usize);
    let rgb = match img {
        DynamicImage::ImageRgb8(buf) => buf.into_raw(),
        other => other.to_rgb8().into_raw(),
    };
    Ok(ColorImage { width, height, rgb })
}

/// Loads a hole mask of exactly `width`×`height` (ARCHITECTURE §3.1): true = hole
/// (luminance >= 128). Alpha composites over black, so transparent = not a hole.
pub fn load_mask(path: &Path, width: usize, height: usize) -> anyhow::Result<Vec<bool>> {
    let img = decode(path, "mask")?;
    let (mw, mh) = (img.width() as usize, img.height() as usize);
    if (mw, mh) != (width, height) {
        return Err(ImageIoError::MaskSize {
            path: path.to_path_buf(),
            mask_width: mw,
            mask_height: mh,
            width,
            height,
        }
        .into());
    }
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

/// BT.601 integer luminance of one pixel.
#[inline]
pub fn luma(r: u8, g: u8, b: u8) -> u8 {
    ((299 * r as u32 + 587 * g as u32 + 114 * b as u32 + 500) / 1000) as u8
}

/// Luminance with BT.601 integer weights, (299R+587G+114B+500)/1000 (ARCHITECTURE §3).
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

/// Output formats, chosen by extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum OutFormat {
    Png,
    Jpeg,
    Tiff,
    Bmp,
    WebP,
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

/// Checks, before a long run, that `path` has a supported extension, is not a
/// directory, and that its directory exists and accepts a new file.
pub fn check_writable(path: &Path) -> anyhow::Result<()> {
    output_format(path)?;
    check_writable_any(path)
}

/// [`check_writable`] without the extension check, for non-image outputs.
pub fn check_writable_any(path: &Path) -> anyhow::Result<()> {
    let dir = target_dir(path)?;
    let tmp = temp_path(&dir, path)?;
    let file = create_temp(path, &dir, &tmp)?;
    drop(file);
    fs::remove_file(&tmp).map_err(|e| ImageIoError::Write {
        path: path.to_path_buf(),
        reason: format!(
            "cannot remove test file {}: {}",
            tmp.display(),
            one_line(&e)
        ),
    })?;
    Ok(())
}

/// The directory `path` goes into, checked to exist; also rejects a target
/// that is itself a directory.
fn target_dir(path: &Path) -> Result<PathBuf, ImageIoError> {
    let write = |reason: String| ImageIoError::Write {
        path: path.to_path_buf(),
        reason,
    };
    if path.file_name().is_none() {
        return Err(write("the path has no file name".into()));
    }
    if fs::metadata(path).is_ok_and(|m| m.is_dir()) {
        return Err(write("it is a directory".into()));
    }
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    match fs::metadata(&dir) {
        Ok(m) if m.is_dir() => Ok(dir),
        Ok(_) => Err(write(format!("{} is not a directory", dir.display()))),
        Err(e) if e.kind() == io::ErrorKind::NotFound => Err(ImageIoError::NoDirectory {
            path: path.to_path_buf(),
            dir,
        }),
        Err(e) => Err(write(format!(
            "cannot access directory {}: {}",
            dir.display(),
            one_line(&e)
        ))),
    }
}

/// `.name.tmp-<pid>-<n>` next to the target; `n` keeps concurrent saves of
/// one process apart.
fn temp_path(dir: &Path, path: &Path) -> Result<PathBuf, ImageIoError> {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let name = path.file_name().ok_or_else(|| ImageIoError::Write {
        path: path.to_path_buf(),
        reason: "the path has no file name".into(),
    })?;
    let mut tmp = OsString::from(".");
    tmp.push(name);
    tmp.push(format!(
        ".tmp-{}-{}",
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    ));
    Ok(dir.join(tmp))
}

fn create_temp(path: &Path, dir: &Path, tmp: &Path) -> Result<File, ImageIoError> {
    OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(tmp)
        .map_err(|e| ImageIoError::Write {
            path: path.to_path_buf(),
            reason: match e.kind() {
                io::ErrorKind::PermissionDenied => {
                    format!(
                        "directory {} is not writable (permission denied)",
                        dir.display()
                    )
                }
                _ => format!(
                    "cannot create a file in {}: {}",
                    dir.display(),
                    one_line(&e)
                ),
            },
        })
}

/// Removes the temporary file unless the save went through.
struct TempGuard<'a> {
    path: &'a Path,
    armed: bool,
}

impl Drop for TempGuard<'_> {
    fn drop(&mut self) {
        if self.armed {
            let _ = fs::remove_file(self.path);
        }
    }
}

/// Writes `path` atomically: `body` writes into a temp file in the same
/// directory, which is synced and renamed over `path`; on any error the temp
/// file is removed and an existing `path` stays untouched.
fn write_atomic<F>(path: &Path, body: F) -> Result<(), ImageIoError>
where
    F: FnOnce(&mut BufWriter<File>) -> Result<(), String>,
{
    let dir = target_dir(path)?;
    let tmp = temp_path(&dir, path)?;
    let file = create_temp(path, &dir, &tmp)?;
    let mut guard = TempGuard {
        path: &tmp,
        armed: true,
    };
    let write = |reason: String| ImageIoError::Write {
        path: path.to_path_buf(),
        reason,
    };
    let mut w = BufWriter::new(file);
    body(&mut w).map_err(|r| write(format!("encoding failed: {r}")))?;
    let file = w.into_inner().map_err(|e| write(one_line(e.error())))?;
    file.sync_all().map_err(|e| write(one_line(&e)))?;
    drop(file);
    fs::rename(&tmp, path)
        .map_err(|e| write(format!("cannot replace the file: {}", one_line(&e))))?;
    guard.armed = false;
    // Persist the rename; best effort (not every platform can sync a directory).
    if let Ok(d) = File::open(&dir) {
        let _ = d.sync_all();
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
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
    fn sixteen_bit_png_is_rounded() {
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
        // 16-bit grey too.
        let p2 = dir.path().join("deep_gray.png");
        ImageBuffer::<Luma<u16>, _>::from_fn(2, 1, |x, _| Luma([[257u16, 514][x as usize]]))
            .save(&p2)
            .unwrap();
        assert_eq!(load_color(&p2).unwrap().rgb, vec![1, 1, 1, 2, 2, 2]);
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
        assert!(s.contains("not an image"), "{s}");

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
}
