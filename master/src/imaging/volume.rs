//! Volumes (ARCHITECTURE §11): a solid texture's voxels as a raw file beside
//! a small JSON header, its slices as PNGs, and a preview of its six faces
//! and three centre slices. Written atomically like every image.
//!
//! The raw file holds one byte per channel, channels interleaved per voxel,
//! x fastest, then y, then z. A slice across an axis is the image of that
//! axis's plane, taken cyclically: across x it shows (y, z), across y
//! (z, x), across z (x, y), the first along the image's rows and the second
//! down its columns.

use std::path::{Path, PathBuf};

use anyhow::{ensure, Context, Result};
use serde::{Deserialize, Serialize};

use super::atomic::write_atomic;
use super::{one_line, ColorImage, Gray};

/// Format name in the header.
pub const FORMAT: &str = "texsyn-volume";
/// The voxel order, spelled out in the header.
pub const ORDER: &str = "x fastest, then y, then z; channels interleaved per voxel";

/// An axis of a volume.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Axis {
    X,
    Y,
    Z,
}

impl Axis {
    pub const ALL: [Axis; 3] = [Axis::X, Axis::Y, Axis::Z];

    pub fn index(self) -> usize {
        self as usize
    }

    /// The volume axes `[u, v]` of the plane across this axis: `u` runs
    /// along an image's rows (its x), `v` down its columns (its y). The
    /// planes are cyclic, (y, z) across x, (z, x) across y, (x, y) across
    /// z, so every axis is a row direction in one plane and a column
    /// direction in the other: an exemplar on all three axes then treats the
    /// three alike. (With (x, z) across y, y alone would be a row direction
    /// in one plane and a column direction in the other, and a solid from
    /// one exemplar came out smoother along y than along x and z.)
    pub fn plane(self) -> [usize; 2] {
        match self {
            Axis::X => [1, 2],
            Axis::Y => [2, 0],
            Axis::Z => [0, 1],
        }
    }

    pub fn name(self) -> char {
        ['x', 'y', 'z'][self.index()]
    }

    pub fn parse(c: char) -> Option<Self> {
        match c.to_ascii_lowercase() {
            'x' => Some(Axis::X),
            'y' => Some(Axis::Y),
            'z' => Some(Axis::Z),
            _ => None,
        }
    }
}

/// The JSON header of a raw volume.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Header {
    pub format: String,
    pub version: u32,
    /// `[x, y, z]` voxels.
    pub size: [usize; 3],
    /// 1 (grey) or 3 (RGB).
    pub channels: usize,
    /// `u8`.
    pub sample: String,
    pub order: String,
    /// The raw file, beside the header.
    pub data: String,
    /// What made the volume (method, views, settings).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub info: Option<serde_json::Value>,
}

/// A volume of 8-bit voxels.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Volume {
    pub size: [usize; 3],
    pub channels: usize,
    pub data: Vec<u8>,
}

impl Volume {
    pub fn new(size: [usize; 3], channels: usize, data: Vec<u8>) -> Result<Self> {
        ensure!(
            channels == 1 || channels == 3,
            "a volume has 1 or 3 channels, not {channels}"
        );
        let n = size
            .iter()
            .try_fold(channels, |a, &s| a.checked_mul(s))
            .context("the volume size overflows")?;
        ensure!(
            data.len() == n,
            "a {}×{}×{} volume of {channels} channels holds {n} bytes, not {}",
            size[0],
            size[1],
            size[2],
            data.len()
        );
        Ok(Self {
            size,
            channels,
            data,
        })
    }

    /// The channels of voxel `(x, y, z)`.
    pub fn get(&self, x: usize, y: usize, z: usize) -> &[u8] {
        let i = ((z * self.size[1] + y) * self.size[0] + x) * self.channels;
        &self.data[i..i + self.channels]
    }

    /// The slice across `axis` at `at`: `(width, height, bytes)`, rows of
    /// the plane's first axis.
    pub fn slice(&self, axis: Axis, at: usize) -> (usize, usize, Vec<u8>) {
        let [u, v] = axis.plane();
        let (w, h) = (self.size[u], self.size[v]);
        let mut out = Vec::with_capacity(w * h * self.channels);
        for b in 0..h {
            for a in 0..w {
                let mut p = [0usize; 3];
                p[axis.index()] = at;
                p[u] = a;
                p[v] = b;
                out.extend_from_slice(self.get(p[0], p[1], p[2]));
            }
        }
        (w, h, out)
    }

    /// A slice as an RGB image (grey repeated).
    pub fn slice_rgb(&self, axis: Axis, at: usize) -> ColorImage {
        let (w, h, bytes) = self.slice(axis, at);
        let rgb = if self.channels == 3 {
            bytes
        } else {
            bytes.iter().flat_map(|&g| [g, g, g]).collect()
        };
        ColorImage::from_vec(w, h, rgb)
    }

    /// Writes `stem.raw` and its header `stem.json` into `dir`, each
    /// atomically; returns the header's path.
    pub fn save(&self, dir: &Path, stem: &str, info: Option<serde_json::Value>) -> Result<PathBuf> {
        let raw = format!("{stem}.raw");
        let header = Header {
            format: FORMAT.into(),
            version: 1,
            size: self.size,
            channels: self.channels,
            sample: "u8".into(),
            order: ORDER.into(),
            data: raw.clone(),
            info,
        };
        write_atomic(&dir.join(&raw), |w| {
            std::io::Write::write_all(w, &self.data).map_err(|e| one_line(&e))
        })?;
        let json = dir.join(format!("{stem}.json"));
        let text = serde_json::to_vec_pretty(&header)?;
        write_atomic(&json, |w| {
            std::io::Write::write_all(w, &text).map_err(|e| one_line(&e))
        })?;
        Ok(json)
    }

    /// Reads a volume from its JSON header (the raw file beside it).
    pub fn load(header: &Path) -> Result<(Self, Header)> {
        let text = super::read_regular(header, 1 << 20, "volume header")?;
        let h: Header = serde_json::from_slice(&text).with_context(|| {
            format!(
                "{} is not a volume header (the .json that `texsyn solid` writes beside a .raw)",
                header.display()
            )
        })?;
        ensure!(
            h.format == FORMAT && h.version == 1,
            "{} is a '{}' header of version {}; texsyn reads '{FORMAT}' version 1",
            header.display(),
            h.format,
            h.version
        );
        ensure!(
            h.sample == "u8",
            "{} holds '{}' samples; texsyn reads u8 volumes",
            header.display(),
            h.sample
        );
        ensure!(
            Path::new(&h.data).file_name() == Some(std::ffi::OsStr::new(&h.data)),
            "{}: the data file '{}' must be a plain file name beside the header",
            header.display(),
            h.data
        );
        let raw = header.with_file_name(&h.data);
        // The data must be exactly as long as the header says, checked before
        // it is read.
        let expect = h
            .size
            .iter()
            .try_fold(h.channels as u64, |n, &s| n.checked_mul(s as u64))
            .filter(|&n| n <= 1 << 34)
            .with_context(|| format!("{}: the size {:?} is too large", header.display(), h.size))?;
        let len = super::check_regular(&raw, expect, "volume data")?;
        ensure!(
            len == expect,
            "{} does not match its header: it is {len} bytes, the header says {expect}; write the solid again",
            raw.display()
        );
        let data = super::read_regular(&raw, expect, "volume data")?;
        let v = Self::new(h.size, h.channels, data)
            .with_context(|| format!("{} does not match its header", raw.display()))?;
        Ok((v, h))
    }

    /// Writes every slice across `axis` into `dir` as `AXIS_NNNN.png`, each
    /// mirrored top to bottom with `flip_rows` (a mirrored view's slices,
    /// written back in its exemplar's frame).
    pub fn save_slices(&self, dir: &Path, axis: Axis, flip_rows: bool) -> Result<()> {
        for at in 0..self.size[axis.index()] {
            let p = dir.join(format!("{}_{at:04}.png", axis.name()));
            let (w, h, mut bytes) = self.slice(axis, at);
            if flip_rows {
                let row = w * self.channels;
                bytes = super::rows_reversed(&bytes, row);
            }
            if self.channels == 1 {
                super::save_gray(&p, &Gray::from_vec(w, h, bytes))?;
            } else {
                super::save_color(&p, &ColorImage::from_vec(w, h, bytes))?;
            }
        }
        Ok(())
    }

    /// The preview: a 3×3 grid, one column per axis (x, y, z). Row 1 holds
    /// the faces at 0 across each axis, row 2 the faces at the far end, row
    /// 3 the slices through the centre. Cells are `gap` pixels apart on a
    /// dark ground.
    pub fn preview(&self, gap: usize) -> ColorImage {
        let cell = self.size.iter().copied().max().unwrap_or(1);
        let side = 3 * cell + 4 * gap;
        let mut img = ColorImage::from_vec(side, side, vec![40u8; side * side * 3]);
        for (col, axis) in Axis::ALL.into_iter().enumerate() {
            let n = self.size[axis.index()];
            for (row, at) in [0, n - 1, n / 2].into_iter().enumerate() {
                let s = self.slice_rgb(axis, at);
                let (x0, y0) = (gap + col * (cell + gap), gap + row * (cell + gap));
                for y in 0..s.height {
                    for x in 0..s.width {
                        img.set(x0 + x, y0 + y, s.get(x, y));
                    }
                }
            }
        }
        img
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn numbered(size: [usize; 3], channels: usize) -> Volume {
        let n = size.iter().product::<usize>() * channels;
        Volume::new(
            size,
            channels,
            (0..n).map(|i| (i * 7 % 251) as u8).collect(),
        )
        .unwrap()
    }

    #[test]
    fn slices_are_the_volume_s_voxels_in_the_plane() {
        let v = numbered([5, 4, 3], 3);
        for axis in Axis::ALL {
            let [u, w] = axis.plane();
            for at in 0..v.size[axis.index()] {
                let (sw, sh, bytes) = v.slice(axis, at);
                assert_eq!((sw, sh), (v.size[u], v.size[w]));
                for b in 0..sh {
                    for a in 0..sw {
                        let mut p = [0; 3];
                        p[axis.index()] = at;
                        p[u] = a;
                        p[w] = b;
                        let i = (b * sw + a) * 3;
                        assert_eq!(&bytes[i..i + 3], v.get(p[0], p[1], p[2]));
                    }
                }
            }
        }
    }

    #[test]
    fn a_saved_volume_loads_back_and_a_short_raw_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let v = numbered([6, 2, 5], 1);
        let header = v.save(dir.path(), "vol", None).unwrap();
        let (back, h) = Volume::load(&header).unwrap();
        assert_eq!(back, v);
        assert_eq!(h.order, ORDER);
        std::fs::write(dir.path().join("vol.raw"), [0u8; 7]).unwrap();
        let e = Volume::load(&header).unwrap_err();
        assert!(
            format!("{e:#}").contains("does not match its header"),
            "{e:#}"
        );
    }
}
