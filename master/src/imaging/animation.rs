//! Frame sequences as looping animations: GIF (the `image` crate's encoder)
//! and lossless animated WebP, written one frame at a time ([`GifWriter`],
//! [`WebpWriter`]) or from a whole set.
//!
//! The `image` crate encodes still lossless WebP only, and the crates that
//! write animated WebP bind the C libwebp. An animated WebP is a RIFF
//! container around still frames, so each frame is encoded by `image` and
//! its `VP8L` chunk is wrapped here in the container's `VP8X`, `ANIM` and
//! `ANMF` chunks (the WebP container specification, "Animation").

use anyhow::{bail, ensure, Context, Result};
use image::codecs::gif::{GifEncoder, Repeat};
use image::codecs::webp::WebPEncoder;
use image::{Delay, ExtendedColorType, Frame, RgbaImage};

use std::io::{Seek, SeekFrom, Write};

use super::ColorImage;

/// The frames as an endlessly looping animated GIF, `delay_ms` per frame.
pub fn encode_gif(frames: &[ColorImage], delay_ms: u32) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    {
        let mut gif = GifWriter::new(&mut out, delay_ms)?;
        for img in frames {
            gif.add(img)?;
        }
    }
    Ok(out)
}

/// An animated GIF written one frame at a time (nothing of earlier frames
/// is kept): the bytes of [`encode_gif`].
pub struct GifWriter<W: Write> {
    enc: GifEncoder<W>,
    delay_ms: u32,
}

impl<W: Write> GifWriter<W> {
    pub fn new(out: W, delay_ms: u32) -> Result<Self> {
        let mut enc = GifEncoder::new_with_speed(out, 10);
        enc.set_repeat(Repeat::Infinite)?;
        Ok(Self { enc, delay_ms })
    }

    /// Appends a frame.
    pub fn add(&mut self, img: &ColorImage) -> Result<()> {
        let rgba: Vec<u8> = img
            .rgb
            .chunks_exact(3)
            .flat_map(|p| [p[0], p[1], p[2], 255])
            .collect();
        let buf = RgbaImage::from_raw(img.width as u32, img.height as u32, rgba)
            .context("frame buffer")?;
        self.enc.encode_frame(Frame::from_parts(
            buf,
            0,
            0,
            Delay::from_numer_denom_ms(self.delay_ms, 1),
        ))?;
        Ok(())
    }
}

/// The largest canvas side and frame duration the container can hold
/// (24-bit fields).
const MAX_24: u32 = 1 << 24;

/// The largest WebP canvas side (the format's 14-bit sizes, as in
/// [`super::check_output_size`]).
const MAX_WEBP_SIDE: usize = 16_383;
/// The largest GIF side (16-bit sizes).
const MAX_GIF_SIDE: usize = 65_535;

/// Checks, before any frame is rendered, that both animations can hold
/// `width`×`height` frames `delay_ms` apart; the message names the flag.
pub fn check_animation(width: usize, height: usize, delay_ms: u32) -> Result<()> {
    ensure!(
        width.max(height) <= MAX_WEBP_SIDE.min(MAX_GIF_SIDE),
        "--size {width}x{height} is too large for the animations (WebP holds at most \
         {MAX_WEBP_SIDE} pixels per side); use a smaller --size or --delay 0 for frames only"
    );
    ensure!(
        delay_ms < MAX_24,
        "--delay {delay_ms} is out of range: a WebP frame lasts under {MAX_24} ms; give a \
         smaller --delay"
    );
    Ok(())
}

/// The frames as an endlessly looping lossless animated WebP, `delay_ms`
/// per frame. Every frame must have the first frame's size.
pub fn encode_webp(frames: &[ColorImage], delay_ms: u32) -> Result<Vec<u8>> {
    let first = frames.first().context("an animation needs a frame")?;
    let mut out = std::io::Cursor::new(Vec::new());
    let mut webp = WebpWriter::new(&mut out, first.width, first.height, delay_ms)?;
    for img in frames {
        webp.add(img)?;
    }
    webp.finish()?;
    Ok(out.into_inner())
}

/// A lossless animated WebP written one frame at a time (nothing of earlier
/// frames is kept): the bytes of [`encode_webp`]. The RIFF size is written
/// by [`WebpWriter::finish`].
pub struct WebpWriter<W: Write + Seek> {
    out: W,
    start: u64,
    body: u64,
    frames: usize,
    size: (u32, u32),
    delay_ms: u32,
}

impl<W: Write + Seek> WebpWriter<W> {
    /// Starts an animation of `width`×`height` frames.
    pub fn new(mut out: W, width: usize, height: usize, delay_ms: u32) -> Result<Self> {
        let (w, h) = (width as u32, height as u32);
        ensure!(
            w >= 1 && h >= 1 && w <= MAX_24 && h <= MAX_24,
            "a WebP canvas of {w}×{h} is out of range"
        );
        ensure!(
            delay_ms < MAX_24,
            "a frame delay of {delay_ms} ms is out of range"
        );
        let start = out.stream_position()?;
        let mut head = Vec::new();
        head.extend_from_slice(b"RIFF");
        head.extend_from_slice(&0u32.to_le_bytes());
        head.extend_from_slice(b"WEBP");
        // VP8X: the animation flag, then the canvas size less one.
        let mut vp8x = vec![0x02, 0, 0, 0];
        vp8x.extend_from_slice(&u24(w - 1));
        vp8x.extend_from_slice(&u24(h - 1));
        chunk(&mut head, b"VP8X", &vp8x);
        // ANIM: background colour (BGRA) and loop count 0, for ever.
        chunk(&mut head, b"ANIM", &[0, 0, 0, 0, 0, 0]);
        out.write_all(&head)?;
        Ok(Self {
            out,
            start,
            body: head.len() as u64 - 12,
            frames: 0,
            size: (w, h),
            delay_ms,
        })
    }

    /// Appends a frame of the animation's size.
    pub fn add(&mut self, img: &ColorImage) -> Result<()> {
        let (w, h) = self.size;
        ensure!(
            img.width as u32 == w && img.height as u32 == h,
            "every frame of an animation must be {w}×{h}"
        );
        let mut still = Vec::new();
        WebPEncoder::new_lossless(&mut still).encode(&img.rgb, w, h, ExtendedColorType::Rgb8)?;
        let vp8l = vp8l_chunk(&still)?;
        let mut anmf = Vec::with_capacity(16 + vp8l.len());
        anmf.extend_from_slice(&u24(0)); // x / 2
        anmf.extend_from_slice(&u24(0)); // y / 2
        anmf.extend_from_slice(&u24(w - 1));
        anmf.extend_from_slice(&u24(h - 1));
        anmf.extend_from_slice(&u24(self.delay_ms));
        // Do not blend (bit 1), do not dispose (bit 0): each frame is whole.
        anmf.push(0x02);
        anmf.extend_from_slice(vp8l);
        let mut c = Vec::with_capacity(anmf.len() + 9);
        chunk(&mut c, b"ANMF", &anmf);
        self.out.write_all(&c)?;
        self.body += c.len() as u64;
        self.frames += 1;
        Ok(())
    }

    /// Writes the RIFF size; refuses an animation of no frame.
    pub fn finish(mut self) -> Result<W> {
        ensure!(self.frames > 0, "an animation needs a frame");
        let size = u32::try_from(4 + self.body)
            .ok()
            .context("the animated WebP is over 4 GiB; give fewer --frames or a smaller --size")?;
        let end = self.out.stream_position()?;
        self.out.seek(SeekFrom::Start(self.start + 4))?;
        self.out.write_all(&size.to_le_bytes())?;
        self.out.seek(SeekFrom::Start(end))?;
        self.out.flush()?;
        Ok(self.out)
    }
}

fn u24(v: u32) -> [u8; 3] {
    let b = v.to_le_bytes();
    [b[0], b[1], b[2]]
}

/// Appends a RIFF chunk: tag, size, payload, a pad byte to an even length.
fn chunk(out: &mut Vec<u8>, tag: &[u8; 4], payload: &[u8]) {
    out.extend_from_slice(tag);
    out.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    out.extend_from_slice(payload);
    if payload.len() % 2 == 1 {
        out.push(0);
    }
}

/// The whole `VP8L` chunk (tag, size, data, padding) of a still WebP file.
fn vp8l_chunk(file: &[u8]) -> Result<&[u8]> {
    ensure!(
        file.len() >= 12 && &file[..4] == b"RIFF" && &file[8..12] == b"WEBP",
        "the WebP encoder wrote no RIFF container"
    );
    let mut at = 12;
    while at + 8 <= file.len() {
        let size = u32::from_le_bytes(file[at + 4..at + 8].try_into()?) as usize;
        let end = (at + 8 + size + size % 2).min(file.len());
        if &file[at..at + 4] == b"VP8L" {
            return Ok(&file[at..end]);
        }
        at = end;
    }
    bail!("the WebP encoder wrote no lossless frame")
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::codecs::webp::WebPDecoder;
    use image::AnimationDecoder;

    fn frames() -> Vec<ColorImage> {
        (0..4u8)
            .map(|k| {
                let (w, h) = (13, 7);
                let rgb = (0..w * h * 3)
                    .map(|i| (i as u8).wrapping_mul(37).wrapping_add(k * 50))
                    .collect();
                ColorImage::from_vec(w, h, rgb)
            })
            .collect()
    }

    #[test]
    fn an_animated_webp_decodes_to_its_frames() {
        let frames = frames();
        let bytes = encode_webp(&frames, 120).unwrap();
        let dec = WebPDecoder::new(std::io::Cursor::new(bytes)).unwrap();
        let back = dec.into_frames().collect_frames().unwrap();
        assert_eq!(back.len(), frames.len());
        for (f, img) in back.iter().zip(&frames) {
            assert_eq!(f.delay().numer_denom_ms(), (120, 1));
            let rgb: Vec<u8> = f
                .buffer()
                .pixels()
                .flat_map(|p| [p[0], p[1], p[2]])
                .collect();
            assert_eq!(rgb, img.rgb, "lossless frames come back exact");
        }
    }

    #[test]
    fn frames_of_another_size_are_refused() {
        let mut frames = frames();
        frames.push(ColorImage::from_vec(2, 2, vec![0; 12]));
        assert!(encode_webp(&frames, 100).is_err());
        assert!(encode_webp(&[], 100).is_err());
    }

    #[test]
    fn an_animated_gif_has_every_frame() {
        let frames = frames();
        let bytes = encode_gif(&frames, 100).unwrap();
        let dec = image::codecs::gif::GifDecoder::new(std::io::Cursor::new(bytes)).unwrap();
        assert_eq!(dec.into_frames().collect_frames().unwrap().len(), 4);
    }
}
