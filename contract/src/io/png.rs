//! Tone-mapped PNG previews.

use super::text::{GLYPH, draw_text, text_width};
use super::write_atomically;
use anyhow::{Context, Result};
use matedit_physics::tonemap::tonemap_u8;
use std::path::Path;

/// Writes an RGBA PNG: RGB through [`tonemap_u8`] (exposure, clamp, sRGB), alpha = mask.
pub fn write_png_preview(path: &Path, res: usize, rgb: &[[f32; 3]], mask: &[f32], exposure: f32) -> Result<()> {
    let mut buf = Vec::with_capacity(res * res * 4);
    for (p, m) in rgb.iter().zip(mask) {
        buf.extend(p.map(|v| tonemap_u8(v, exposure)));
        buf.push((m.clamp(0.0, 1.0) * 255.0).round() as u8);
    }
    let img = image::RgbaImage::from_raw(res as u32, res as u32, buf).context("image buffer size")?;
    write_atomically(path, |tmp| {
        img.save_with_format(tmp, image::ImageFormat::Png)
            .with_context(|| format!("cannot write {}", path.display()))
    })
}

/// One component of a unit normal, [−1, 1], as the usual 8-bit normal-map value (0 ↔ −1,
/// 255 ↔ +1), for previews and contact sheets.
pub fn normal_to_u8(v: f32) -> u8 {
    ((v * 0.5 + 0.5).clamp(0.0, 1.0) * 255.0).round() as u8
}

/// Background of contact sheets (tiles' transparent pixels show it).
const SHEET_BACKGROUND: [u8; 4] = [40, 40, 40, 255];
/// Background of the header row and caption strips, a shade darker so they read as labels.
const LABEL_BACKGROUND: [u8; 4] = [20, 20, 20, 255];
/// Colour of label text.
const LABEL_TEXT: [u8; 4] = [235, 235, 235, 255];
/// Padding around label text, pixels.
const LABEL_PAD: usize = 3;

/// Labels of a contact sheet. Either part may be empty (then it takes no room).
#[derive(Clone, Copy, Debug, Default)]
pub struct SheetLabels<'a> {
    /// One name per column, centred in a header row above the grid.
    pub columns: &'a [&'a str],
    /// One caption per grid row, in a strip above that row (`\n` starts another line; every
    /// strip is as tall as the longest caption).
    pub rows: &'a [String],
}

impl SheetLabels<'_> {
    /// Height of the header row.
    pub fn header_height(&self) -> usize {
        if self.columns.is_empty() {
            0
        } else {
            GLYPH + 2 * LABEL_PAD
        }
    }

    /// Height of each row's caption strip.
    pub fn caption_height(&self) -> usize {
        let lines = self.rows.iter().map(|r| r.lines().count().max(1)).max().unwrap_or(0);
        if lines == 0 {
            0
        } else {
            lines * (GLYPH + LABEL_PAD) + LABEL_PAD
        }
    }
}

/// Writes tiles of `tile × tile_h` RGBA pixels in a grid of `cols` columns, on a dark grey
/// background, atomically.
pub fn write_contact_sheet(
    path: &Path,
    tiles: &[Vec<[u8; 4]>],
    tile_w: usize,
    tile_h: usize,
    cols: usize,
) -> Result<()> {
    write_labelled_contact_sheet(path, tiles, tile_w, tile_h, cols, &SheetLabels::default())
}

/// [`write_contact_sheet`] with column names and row captions ([`contact_sheet`]).
pub fn write_labelled_contact_sheet(
    path: &Path,
    tiles: &[Vec<[u8; 4]>],
    tile_w: usize,
    tile_h: usize,
    cols: usize,
    labels: &SheetLabels,
) -> Result<()> {
    let img = contact_sheet(tiles, tile_w, tile_h, cols, labels);
    write_atomically(path, |tmp| {
        img.save_with_format(tmp, image::ImageFormat::Png)
            .with_context(|| format!("cannot write {}", path.display()))
    })
}

/// The sheet as an image: the header row (if `labels.columns`), then per grid row its caption
/// strip (if `labels.rows`) and its tiles.
pub fn contact_sheet(
    tiles: &[Vec<[u8; 4]>],
    tile_w: usize,
    tile_h: usize,
    cols: usize,
    labels: &SheetLabels,
) -> image::RgbaImage {
    let cols = cols.max(1);
    let rows = tiles.len().div_ceil(cols).max(1);
    let (header, caption) = (labels.header_height(), labels.caption_height());
    let (w, h) = (cols * tile_w, header + rows * (caption + tile_h));
    let mut img = image::RgbaImage::from_pixel(w as u32, h as u32, image::Rgba(SHEET_BACKGROUND));
    let fill = |img: &mut image::RgbaImage, y0: usize, height: usize| {
        for y in y0..y0 + height {
            for x in 0..w {
                img.put_pixel(x as u32, y as u32, image::Rgba(LABEL_BACKGROUND));
            }
        }
    };
    if header > 0 {
        fill(&mut img, 0, header);
        for (c, name) in labels.columns.iter().take(cols).enumerate() {
            let inner = tile_w.saturating_sub(2 * LABEL_PAD);
            let x = c * tile_w + LABEL_PAD + inner.saturating_sub(text_width(name, 1)) / 2;
            draw_text(
                &mut img,
                x,
                LABEL_PAD,
                c * tile_w + tile_w - LABEL_PAD - x,
                name,
                LABEL_TEXT,
                1,
            );
        }
    }
    for r in 0..rows {
        let y0 = header + r * (caption + tile_h);
        if caption > 0 {
            fill(&mut img, y0, caption);
            let text = labels.rows.get(r).map_or("", String::as_str);
            for (k, line) in text.lines().enumerate() {
                let y = y0 + LABEL_PAD + k * (GLYPH + LABEL_PAD);
                draw_text(&mut img, LABEL_PAD, y, w - 2 * LABEL_PAD, line, LABEL_TEXT, 1);
            }
        }
    }
    for (k, tile) in tiles.iter().enumerate() {
        let (ox, oy) = ((k % cols) * tile_w, header + (k / cols) * (caption + tile_h) + caption);
        for (p, px) in tile.iter().enumerate().take(tile_w * tile_h) {
            let (x, y) = ((ox + p % tile_w) as u32, (oy + p / tile_w) as u32);
            // Alpha-blend over the background so masked renders show their silhouette.
            let a = px[3] as u32;
            let bg = img.get_pixel(x, y).0;
            let blend = |c: usize| ((px[c] as u32 * a + bg[c] as u32 * (255 - a)) / 255) as u8;
            img.put_pixel(x, y, image::Rgba([blend(0), blend(1), blend(2), 255]));
        }
    }
    img
}

#[cfg(test)]
mod normal_encoding_tests {
    use super::normal_to_u8;

    #[test]
    fn normal_components_map_to_the_full_byte_range_and_bad_values_stay_in_it() {
        assert_eq!([-1.0, 0.0, 1.0].map(normal_to_u8), [0, 128, 255]);
        assert_eq!(
            [-7.0, 3.0, f32::INFINITY, f32::NEG_INFINITY].map(normal_to_u8),
            [0, 255, 255, 0]
        );
        assert_eq!(normal_to_u8(f32::NAN), 0);
    }
}
