//! A contact sheet: rows of labelled pictures, each scaled to fit a square
//! cell, with the labels drawn in an 8×8 bitmap font.

use font8x8::UnicodeFonts;
use image::imageops::FilterType;
use texsyn::imaging::ColorImage;

/// Height of the labels: two lines of 8 px.
const LABEL: usize = 20;
/// Space between cells.
const GAP: usize = 4;

pub struct Sheet {
    cell: usize,
    columns: usize,
    rows: Vec<ColorImage>,
}

impl Sheet {
    pub fn new(cell: usize, columns: usize) -> Self {
        Self {
            cell: cell.max(16),
            columns,
            rows: Vec::new(),
        }
    }

    fn row_width(&self) -> usize {
        self.columns * (self.cell + GAP) + GAP
    }

    /// Adds a row of `(picture, label)` cells.
    pub fn add_row(&mut self, cells: &[(ColorImage, String)]) {
        let (c, w) = (self.cell, self.row_width());
        let mut row =
            ColorImage::from_vec(w, c + LABEL + GAP, vec![255; w * (c + LABEL + GAP) * 3]);
        for (k, (img, label)) in cells.iter().take(self.columns).enumerate() {
            let x0 = GAP + k * (c + GAP);
            let fit = fit(img, c);
            let (ox, oy) = (x0 + (c - fit.width) / 2, LABEL + (c - fit.height) / 2);
            for y in 0..fit.height {
                for x in 0..fit.width {
                    row.set(ox + x, oy + y, fit.get(x, y));
                }
            }
            draw_text(&mut row, x0, 2, label, c);
        }
        self.rows.push(row);
    }

    /// The sheet: the rows one under the other.
    pub fn image(&self) -> ColorImage {
        let w = self.row_width();
        let h: usize = self.rows.iter().map(|r| r.height).sum::<usize>().max(1);
        let mut out = ColorImage::from_vec(w, h, vec![255; w * h * 3]);
        let mut y0 = 0;
        for r in &self.rows {
            out.rgb[y0 * w * 3..(y0 + r.height) * w * 3].copy_from_slice(&r.rgb);
            y0 += r.height;
        }
        out
    }
}

/// `img` scaled (Catmull-Rom, or nearest when enlarging, so pixels stay
/// visible) to fit a `side`×`side` square.
fn fit(img: &ColorImage, side: usize) -> ColorImage {
    let s = side as f64 / img.width.max(img.height) as f64;
    let (w, h) = (
        ((img.width as f64 * s).round() as u32).max(1),
        ((img.height as f64 * s).round() as u32).max(1),
    );
    let buf = image::RgbImage::from_raw(img.width as u32, img.height as u32, img.rgb.clone())
        .expect("an RGB buffer of its size");
    let filter = if s > 1.0 {
        FilterType::Nearest
    } else {
        FilterType::CatmullRom
    };
    let out = image::imageops::resize(&buf, w, h, filter);
    ColorImage::from_vec(w as usize, h as usize, out.into_raw())
}

/// Draws `text` in black from `(x0, y0)`, a line per `\n`, each cut at
/// `width` pixels.
fn draw_text(img: &mut ColorImage, x0: usize, y0: usize, text: &str, width: usize) {
    for (line, t) in text.lines().enumerate() {
        draw_line(img, x0, y0 + 9 * line, t, width);
    }
}

fn draw_line(img: &mut ColorImage, x0: usize, y0: usize, text: &str, width: usize) {
    for (k, ch) in text.chars().take(width / 8).enumerate() {
        let glyph = font8x8::BASIC_FONTS.get(ch).unwrap_or([0; 8]);
        for (j, bits) in glyph.iter().enumerate() {
            for i in 0..8 {
                if bits >> i & 1 == 1 {
                    let (x, y) = (x0 + k * 8 + i, y0 + j);
                    if x < img.width && y < img.height {
                        img.set(x, y, [0, 0, 0]);
                    }
                }
            }
        }
    }
}
