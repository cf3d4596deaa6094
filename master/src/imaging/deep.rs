//! Images at full depth (ARCHITECTURE §3.11): the pixels as they were read —
//! 8-bit, 16-bit or 32-bit float samples; grey, grey+alpha, RGB or RGBA — kept
//! untouched while the search works on an 8-bit view of them
//! ([`DeepImage::search_colour`]), and rebuilt at full depth from a copy map
//! ([`DeepImage::rebuild`]), so that every output pixel is, bit for bit, a
//! pixel of the image it was copied from.

use std::fmt;

use image::{DynamicImage, ExtendedColorType, ImageBuffer};

use super::ColorImage;

/// The sample type of a channel.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum Depth {
    U8,
    U16,
    F32,
}

/// The channels of a pixel, in their stored order.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum Channels {
    Gray,
    GrayAlpha,
    Rgb,
    Rgba,
}

/// Depth and channels of an image's pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct PixelFormat {
    pub depth: Depth,
    pub channels: Channels,
}

impl PixelFormat {
    /// 8-bit RGB, the format of [`ColorImage`].
    pub const RGB8: Self = Self {
        depth: Depth::U8,
        channels: Channels::Rgb,
    };

    pub fn channel_count(self) -> usize {
        match self.channels {
            Channels::Gray => 1,
            Channels::GrayAlpha => 2,
            Channels::Rgb => 3,
            Channels::Rgba => 4,
        }
    }

    /// Channels that carry colour (all but alpha).
    pub fn colour_channels(self) -> usize {
        self.channel_count() - usize::from(self.has_alpha())
    }

    pub fn bytes_per_sample(self) -> usize {
        match self.depth {
            Depth::U8 => 1,
            Depth::U16 => 2,
            Depth::F32 => 4,
        }
    }

    pub fn bytes_per_pixel(self) -> usize {
        self.channel_count() * self.bytes_per_sample()
    }

    pub fn has_alpha(self) -> bool {
        matches!(self.channels, Channels::GrayAlpha | Channels::Rgba)
    }

    /// The encoder's name for this format.
    pub(super) fn color_type(self) -> ExtendedColorType {
        use Channels::*;
        use Depth::*;
        match (self.depth, self.channels) {
            (U8, Gray) => ExtendedColorType::L8,
            (U8, GrayAlpha) => ExtendedColorType::La8,
            (U8, Rgb) => ExtendedColorType::Rgb8,
            (U8, Rgba) => ExtendedColorType::Rgba8,
            (U16, Gray) => ExtendedColorType::L16,
            (U16, GrayAlpha) => ExtendedColorType::La16,
            (U16, Rgb) => ExtendedColorType::Rgb16,
            (U16, Rgba) => ExtendedColorType::Rgba16,
            // The `image` crate has no float grey; float images are read as RGB(A).
            (F32, Gray | Rgb) => ExtendedColorType::Rgb32F,
            (F32, GrayAlpha | Rgba) => ExtendedColorType::Rgba32F,
        }
    }
}

impl fmt::Display for PixelFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let depth = match self.depth {
            Depth::U8 => "8-bit",
            Depth::U16 => "16-bit",
            Depth::F32 => "32-bit float",
        };
        let channels = match self.channels {
            Channels::Gray => "grey",
            Channels::GrayAlpha => "grey+alpha",
            Channels::Rgb => "RGB",
            Channels::Rgba => "RGBA",
        };
        write!(f, "{depth} {channels}")
    }
}

/// An image at its own depth: row-major pixels of `format`, samples in native
/// byte order.
#[derive(Clone, Debug, PartialEq)]
pub struct DeepImage {
    pub width: usize,
    pub height: usize,
    pub format: PixelFormat,
    bytes: Vec<u8>,
}

impl DeepImage {
    /// Takes a decoded image as it is; `Err` names a layout the tool does not
    /// handle (e.g. a future variant of the `image` crate).
    pub fn from_dynamic(img: DynamicImage) -> Result<Self, String> {
        use Channels::*;
        use Depth::*;
        let (width, height) = (img.width() as usize, img.height() as usize);
        let format = |depth, channels| PixelFormat { depth, channels };
        let (format, bytes) = match img {
            DynamicImage::ImageLuma8(b) => (format(U8, Gray), b.into_raw()),
            DynamicImage::ImageLumaA8(b) => (format(U8, GrayAlpha), b.into_raw()),
            DynamicImage::ImageRgb8(b) => (format(U8, Rgb), b.into_raw()),
            DynamicImage::ImageRgba8(b) => (format(U8, Rgba), b.into_raw()),
            DynamicImage::ImageLuma16(b) => (format(U16, Gray), ne_bytes(&b.into_raw())),
            DynamicImage::ImageLumaA16(b) => (format(U16, GrayAlpha), ne_bytes(&b.into_raw())),
            DynamicImage::ImageRgb16(b) => (format(U16, Rgb), ne_bytes(&b.into_raw())),
            DynamicImage::ImageRgba16(b) => (format(U16, Rgba), ne_bytes(&b.into_raw())),
            DynamicImage::ImageRgb32F(b) => (format(F32, Rgb), ne_bytes(&b.into_raw())),
            DynamicImage::ImageRgba32F(b) => (format(F32, Rgba), ne_bytes(&b.into_raw())),
            other => return Err(format!("pixel layout {:?} is not supported", other.color())),
        };
        Ok(Self {
            width,
            height,
            format,
            bytes,
        })
    }

    /// An 8-bit RGB image as a deep image of format [`PixelFormat::RGB8`].
    pub fn from_colour(img: &ColorImage) -> Self {
        Self {
            width: img.width,
            height: img.height,
            format: PixelFormat::RGB8,
            bytes: img.rgb.clone(),
        }
    }

    /// The raw pixel bytes (native byte order), row-major.
    pub fn bytes(&self) -> &[u8] {
        &self.bytes
    }

    /// The bytes of pixel (x, y).
    #[inline]
    pub fn pixel(&self, x: usize, y: usize) -> &[u8] {
        let bpp = self.format.bytes_per_pixel();
        let i = (y * self.width + x) * bpp;
        &self.bytes[i..i + bpp]
    }

    /// The image for the `image` crate's encoders and conversions.
    pub fn to_dynamic(&self) -> DynamicImage {
        use Channels::*;
        use Depth::*;
        let (w, h) = (self.width as u32, self.height as u32);
        let raw = self.bytes.clone();
        let built = match (self.format.depth, self.format.channels) {
            (U8, Gray) => ImageBuffer::from_raw(w, h, raw).map(DynamicImage::ImageLuma8),
            (U8, GrayAlpha) => ImageBuffer::from_raw(w, h, raw).map(DynamicImage::ImageLumaA8),
            (U8, Rgb) => ImageBuffer::from_raw(w, h, raw).map(DynamicImage::ImageRgb8),
            (U8, Rgba) => ImageBuffer::from_raw(w, h, raw).map(DynamicImage::ImageRgba8),
            (U16, Gray) => ImageBuffer::from_raw(w, h, u16s(&raw)).map(DynamicImage::ImageLuma16),
            (U16, GrayAlpha) => {
                ImageBuffer::from_raw(w, h, u16s(&raw)).map(DynamicImage::ImageLumaA16)
            }
            (U16, Rgb) => ImageBuffer::from_raw(w, h, u16s(&raw)).map(DynamicImage::ImageRgb16),
            (U16, Rgba) => ImageBuffer::from_raw(w, h, u16s(&raw)).map(DynamicImage::ImageRgba16),
            (F32, Gray | Rgb) => {
                ImageBuffer::from_raw(w, h, f32s(&raw)).map(DynamicImage::ImageRgb32F)
            }
            (F32, GrayAlpha | Rgba) => {
                ImageBuffer::from_raw(w, h, f32s(&raw)).map(DynamicImage::ImageRgba32F)
            }
        };
        built.expect("a DeepImage's buffer always matches its size and format")
    }

    /// This image in another pixel format, through the `image` crate's
    /// conversions (exact when neither depth nor channels are lost).
    pub fn converted(&self, format: PixelFormat) -> Self {
        if format == self.format {
            return self.clone();
        }
        let d = self.to_dynamic();
        use Channels::*;
        use Depth::*;
        let converted = match (format.depth, format.channels) {
            (U8, Gray) => DynamicImage::ImageLuma8(d.to_luma8()),
            (U8, GrayAlpha) => DynamicImage::ImageLumaA8(d.to_luma_alpha8()),
            (U8, Rgb) => DynamicImage::ImageRgb8(d.to_rgb8()),
            (U8, Rgba) => DynamicImage::ImageRgba8(d.to_rgba8()),
            (U16, Gray) => DynamicImage::ImageLuma16(d.to_luma16()),
            (U16, GrayAlpha) => DynamicImage::ImageLumaA16(d.to_luma_alpha16()),
            (U16, Rgb) => DynamicImage::ImageRgb16(d.to_rgb16()),
            (U16, Rgba) => DynamicImage::ImageRgba16(d.to_rgba16()),
            (F32, Gray | Rgb) => DynamicImage::ImageRgb32F(d.to_rgb32f()),
            (F32, GrayAlpha | Rgba) => DynamicImage::ImageRgba32F(d.to_rgba32f()),
        };
        let mut out = Self::from_dynamic(converted).expect("every target format is supported");
        out.format = format;
        out
    }

    /// The 8-bit RGB view the search works on, under this image's own
    /// [`SearchView`] (see there). Images searched together (a fill and its
    /// source, a sample and its level samples) must share one view:
    /// [`SearchView::of`] over all of them, then [`Self::search_colour_in`].
    pub fn search_colour(&self) -> ColorImage {
        self.search_colour_in(&SearchView::of(&[self]))
    }

    /// The 8-bit RGB view of this image under `view`. Alpha is not searched
    /// (the stored colour is used as it is) and grey is replicated.
    pub fn search_colour_in(&self, view: &SearchView) -> ColorImage {
        let (width, height) = (self.width, self.height);
        let (step, colour) = (self.format.channel_count(), self.format.colour_channels());
        let rgb = match (self.format.depth, view) {
            (Depth::U8, _) if self.format == PixelFormat::RGB8 => self.bytes.clone(),
            (Depth::U8, _) | (_, SearchView::Rounded) => self.to_dynamic().to_rgb8().into_raw(),
            (Depth::U16, &SearchView::Stretched { low, high }) => {
                let scale = 255.0 / f64::from(high.saturating_sub(low).max(1));
                let encode = |v: u16| {
                    (f64::from(v.saturating_sub(low)) * scale)
                        .round()
                        .min(255.0) as u8
                };
                rgb_of(&u16s(&self.bytes), step, colour, encode)
            }
            (Depth::F32, &SearchView::ToneMapped { white }) => {
                let encode = |v: f32| -> u8 {
                    if v.is_nan() {
                        return 0;
                    }
                    let x = (f64::from(v) / f64::from(white)).clamp(0.0, 1.0);
                    (x.powf(1.0 / 2.2) * 255.0).round() as u8
                };
                rgb_of(&f32s(&self.bytes), step, colour, encode)
            }
            (Depth::U16, &SearchView::ToneMapped { white }) => {
                // A 16-bit image searched with a float one (never made by
                // the CLI, which converts a fill source to the photo's format).
                let f = self.converted(PixelFormat {
                    depth: Depth::F32,
                    channels: self.format.channels,
                });
                return f.search_colour_in(&SearchView::ToneMapped { white });
            }
            (Depth::F32, &SearchView::Stretched { .. }) => {
                return self.search_colour_in(&SearchView::of(&[self]));
            }
        };
        ColorImage { width, height, rgb }
    }

    /// Holes where the alpha channel is below half its range (ARCHITECTURE
    /// §3.1): 128 of 255, 32768 of 65535, 0.5 in float (NaN counts as
    /// transparent). `None` when the image has no alpha channel.
    pub fn alpha_holes(&self) -> Option<Vec<bool>> {
        if !self.format.has_alpha() {
            return None;
        }
        let bpp = self.format.bytes_per_pixel();
        let a = bpp - self.format.bytes_per_sample();
        Some(
            self.bytes
                .chunks_exact(bpp)
                .map(|p| {
                    let s = &p[a..];
                    match self.format.depth {
                        Depth::U8 => s[0] < 128,
                        Depth::U16 => u16::from_ne_bytes([s[0], s[1]]) < 32768,
                        Depth::F32 => {
                            let a = f32::from_ne_bytes([s[0], s[1], s[2], s[3]]);
                            a.is_nan() || a < 0.5
                        }
                    }
                })
                .collect(),
        )
    }

    /// The `width`×`height` image whose pixel i is this image's pixel at
    /// `copy_map[i]`, or, where `kept` marks it, `kept`'s image's pixel at
    /// the same coordinate (a fill from another source keeps the photo's own
    /// pixels). Copies whole pixels, so every output pixel equals an input
    /// pixel bit for bit.
    pub fn rebuild(
        &self,
        copy_map: &[[u32; 2]],
        width: usize,
        height: usize,
        kept: Option<(&DeepImage, &[bool])>,
    ) -> anyhow::Result<DeepImage> {
        anyhow::ensure!(
            Some(copy_map.len()) == width.checked_mul(height),
            "copy map has {} entries but the canvas is {width}x{height}",
            copy_map.len()
        );
        if let Some((photo, mask)) = kept {
            anyhow::ensure!(
                photo.format == self.format
                    && mask.len() == copy_map.len()
                    && (photo.width, photo.height) == (width, height),
                "kept pixels: the photo is {}x{} {} with {} flags; the output is {width}x{height} {}",
                photo.width,
                photo.height,
                photo.format,
                mask.len(),
                self.format
            );
        }
        let bpp = self.format.bytes_per_pixel();
        let mut bytes = vec![0u8; copy_map.len() * bpp];
        for (i, (&[sx, sy], out)) in copy_map.iter().zip(bytes.chunks_exact_mut(bpp)).enumerate() {
            let (x, y) = (i % width, i / width);
            if let Some((photo, mask)) = kept {
                if mask[i] {
                    out.copy_from_slice(photo.pixel(x, y));
                    continue;
                }
            }
            let (sx, sy) = (sx as usize, sy as usize);
            anyhow::ensure!(
                sx < self.width && sy < self.height,
                "copy map entry at ({x}, {y}) points to ({sx}, {sy}), outside the {}x{} source",
                self.width,
                self.height
            );
            out.copy_from_slice(self.pixel(sx, sy));
        }
        Ok(DeepImage {
            width,
            height,
            format: self.format,
            bytes,
        })
    }
}

/// Samples as native-endian bytes.
/// How the full-depth samples are brought to the 8 bits the search compares
/// (ARCHITECTURE §3.11). 8-bit images are always searched as they are.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SearchView {
    /// Rounded to 8 bit as the `image` crate converts (nothing 16-bit or
    /// float was among the images).
    Rounded,
    /// 16-bit samples: the range `low..=high` the images actually use is
    /// stretched over 0..=255, so that a smooth height map whose values
    /// span a few hundredths of the 16-bit range is searched with all 256
    /// levels rather than the handful that plain rounding leaves it.
    Stretched { low: u16, high: u16 },
    /// Float samples are linear and may exceed 1: they are divided by the
    /// white point (the 99.5th percentile of the finite colour values, 1 if
    /// that is not positive), clamped to [0, 1] and gamma-encoded with
    /// exponent 1/2.2, so that highlights do not flatten the rest; NaN reads
    /// as 0 and +∞ as white.
    ToneMapped { white: f32 },
}

impl SearchView {
    /// The one view under which `images` are searched together: from their
    /// deepest format, over the colour samples of all of them (alpha is not
    /// counted).
    pub fn of(images: &[&DeepImage]) -> Self {
        if images.iter().any(|i| i.format.depth == Depth::F32) {
            let mut values: Vec<f32> = Vec::new();
            for img in images {
                let f = match img.format.depth {
                    Depth::F32 => f32s(&img.bytes),
                    _ => f32s(
                        &img.converted(PixelFormat {
                            depth: Depth::F32,
                            channels: img.format.channels,
                        })
                        .bytes,
                    ),
                };
                let (step, colour) = (img.format.channel_count(), img.format.colour_channels());
                for p in f.chunks_exact(step) {
                    values.extend(p[..colour].iter().copied().filter(|v| v.is_finite()));
                }
            }
            let white = if values.is_empty() {
                1.0
            } else {
                let k = ((values.len() - 1) as f64 * 0.995).round() as usize;
                let (_, w, _) = values.select_nth_unstable_by(k, f32::total_cmp);
                if *w > 0.0 {
                    *w
                } else {
                    1.0
                }
            };
            return Self::ToneMapped { white };
        }
        let mut range: Option<(u16, u16)> = None;
        for img in images.iter().filter(|i| i.format.depth == Depth::U16) {
            let (step, colour) = (img.format.channel_count(), img.format.colour_channels());
            for p in u16s(&img.bytes).chunks_exact(step) {
                for &v in &p[..colour] {
                    range = Some(match range {
                        None => (v, v),
                        Some((lo, hi)) => (lo.min(v), hi.max(v)),
                    });
                }
            }
        }
        match range {
            Some((low, high)) => Self::Stretched { low, high },
            None => Self::Rounded,
        }
    }
}

/// Packs the colour samples of `samples` (`step` per pixel, the first
/// `colour` of them colour) as 8-bit RGB, replicating grey.
fn rgb_of<T: Copy>(samples: &[T], step: usize, colour: usize, encode: impl Fn(T) -> u8) -> Vec<u8> {
    samples
        .chunks_exact(step)
        .flat_map(|p| {
            let c = &p[..colour];
            let (r, g, b) = match c.len() {
                1 => (c[0], c[0], c[0]),
                _ => (c[0], c[1], c[2]),
            };
            [encode(r), encode(g), encode(b)]
        })
        .collect()
}

fn ne_bytes<T: bytemuck::Pod>(v: &[T]) -> Vec<u8> {
    bytemuck::cast_slice(v).to_vec()
}

fn u16s(b: &[u8]) -> Vec<u16> {
    b.chunks_exact(2)
        .map(|c| u16::from_ne_bytes([c[0], c[1]]))
        .collect()
}

fn f32s(b: &[u8]) -> Vec<f32> {
    b.chunks_exact(4)
        .map(|c| f32::from_ne_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}
