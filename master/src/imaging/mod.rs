//! Images at the edges, plain slices inside (ARCHITECTURE §3, §3.1, §3.10,
//! §3.11), shared by every synthesis method.
//!
//! Loading and saving go through the `image` crate. An input is read at its
//! own depth and channels as a [`DeepImage`] (8-bit, 16-bit or float; grey,
//! grey+alpha, RGB or RGBA); the search sees its 8-bit RGB view
//! ([`ColorImage`], see [`DeepImage::search_colour`]) and 8-bit luminance
//! ([`Gray`]) as plain row-major byte vectors, and the output is rebuilt from
//! the copy map at the input's depth ([`DeepImage::rebuild`]) and saved in a
//! format that holds it ([`save_image`]; a format that cannot is refused
//! before the run).
//!
//! Loading rules: the format is guessed from the file content (not the
//! extension); EXIF orientation is applied; **alpha is not searched** but is
//! copied with its pixel. For masks, a transparent pixel is composited over
//! black, i.e. it never marks a hole (a mask pixel is a hole when its
//! luminance times its opacity is at least 128 of 255, for 8- and 16-bit
//! masks alike); `--mask-from-alpha` instead marks a hole where the image's
//! own alpha is below half its range. Only regular, non-empty files are read:
//! a FIFO or device is refused before it is opened.
//!
//! Saving is atomic: the image is encoded into a hidden temporary file in the
//! target directory, synced, and renamed over the target, so an interrupted or
//! failed save never leaves a truncated file behind.
//!
//! This module holds the image types, limits and errors; `io` loads and saves,
//! `atomic` does the temp-file-then-rename writes. The luminance of an image
//! ([`luminance`]) comes from [`crate::imaging::colour`].

use std::path::PathBuf;

pub mod animation;
mod atomic;
pub mod colour;
mod coordmap;
mod deep;
mod io;
mod outdir;
pub mod paths;
#[cfg(test)]
mod tests;
pub mod volume;

pub use atomic::check_writable_any;
pub use coordmap::{check_coord_map_path, load_coord_map, save_coord_map};
pub use deep::{Channels, DeepImage, Depth, PixelFormat, SearchView};
pub use io::{
    check_output_format, check_output_size, check_regular, check_writable, load_alpha_mask,
    load_color, load_image, load_mask, read_regular, save_bytes, save_color, save_gray, save_image,
};
pub use outdir::{check_output_dir, OutputDir, MARKER as OUTPUT_MARKER};

/// Largest number of pixels of an input image or canvas (64 Mi pixels).
pub const MAX_PIXELS: usize = 64 * 1024 * 1024;
/// Largest width or height of an input image or canvas.
pub const MAX_SIDE: usize = 32768;
/// Decoder allocation cap: a MAX_PIXELS RGBA16 image (512 MiB) plus headroom.
const MAX_DECODE_ALLOC: u64 = 1 << 30;
/// JPEG quality used for saving (the encoder default of 75 is too lossy for textures).
const JPEG_QUALITY: u8 = 95;
/// Output extensions, as listed in error messages.
const SUPPORTED_EXTENSIONS: &str = ".png, .jpg, .jpeg, .tif, .tiff, .bmp, .webp, .exr";

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

    /// The `width`×`height` rectangle with top-left corner (x, y). Panics if
    /// it does not lie inside the image.
    pub fn crop(&self, x: usize, y: usize, width: usize, height: usize) -> Self {
        assert!(
            x + width <= self.width && y + height <= self.height,
            "crop outside the image"
        );
        let mut out = Self::new(width, height);
        for j in 0..height {
            let s = ((y + j) * self.width + x) * 3;
            out.rgb[j * width * 3..(j + 1) * width * 3]
                .copy_from_slice(&self.rgb[s..s + width * 3]);
        }
        out
    }

    /// The image continued periodically by `pad` columns on the right and
    /// `pad` rows at the bottom: `(w + pad)`×`(h + pad)`, pixel (x, y) being
    /// the image's (x mod w, y mod h).
    pub fn wrap_padded(&self, pad: usize) -> Self {
        let (w, h) = (self.width, self.height);
        let mut out = Self::new(w + pad, h + pad);
        for y in 0..h + pad {
            for x in 0..w + pad {
                out.set(x, y, self.get(x % w, y % h));
            }
        }
        out
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
    #[error(
        "{} is not a regular file (a FIFO, socket or device); save the image to a file and give that",
        .0.display()
    )]
    NotRegular(PathBuf),
    #[error("{} is an empty file (0 bytes); export the image again", .0.display())]
    EmptyFile(PathBuf),
    #[error("cannot read {}: {reason}", path.display())]
    Unreadable { path: PathBuf, reason: String },
    #[error(
        "{} is not an image in a supported format (PNG, JPEG, TIFF, BMP, WebP or OpenEXR); convert it to PNG",
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
    #[error(
        "cannot save {}: {format} images are at most {max} pixels per side but this one is \
         {width}x{height}; use .png or .tif",
        path.display()
    )]
    FormatTooSmall {
        path: PathBuf,
        format: &'static str,
        max: usize,
        width: usize,
        height: usize,
    },
    #[error("cannot write {}: {reason}", path.display())]
    Write { path: PathBuf, reason: String },
}

/// Rows of `row` bytes in reverse order: an image mirrored top to bottom.
pub fn rows_reversed(bytes: &[u8], row: usize) -> Vec<u8> {
    bytes.chunks_exact(row).rev().flatten().copied().collect()
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
