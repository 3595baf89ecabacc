//! Tone-mapped PNG previews.

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

/// Writes tiles of `tile × tile_h` RGBA pixels in a grid of `cols` columns, on a dark grey
/// background, atomically.
pub fn write_contact_sheet(
    path: &Path,
    tiles: &[Vec<[u8; 4]>],
    tile_w: usize,
    tile_h: usize,
    cols: usize,
) -> Result<()> {
    let cols = cols.max(1);
    let rows = tiles.len().div_ceil(cols).max(1);
    let (w, h) = (cols * tile_w, rows * tile_h);
    let mut img = image::RgbaImage::from_pixel(w as u32, h as u32, image::Rgba([40, 40, 40, 255]));
    for (k, tile) in tiles.iter().enumerate() {
        let (ox, oy) = ((k % cols) * tile_w, (k / cols) * tile_h);
        for (p, px) in tile.iter().enumerate().take(tile_w * tile_h) {
            let (x, y) = ((ox + p % tile_w) as u32, (oy + p / tile_w) as u32);
            // Alpha-blend over the background so masked renders show their silhouette.
            let a = px[3] as u32;
            let bg = img.get_pixel(x, y).0;
            let blend = |c: usize| ((px[c] as u32 * a + bg[c] as u32 * (255 - a)) / 255) as u8;
            img.put_pixel(x, y, image::Rgba([blend(0), blend(1), blend(2), 255]));
        }
    }
    write_atomically(path, |tmp| {
        img.save_with_format(tmp, image::ImageFormat::Png)
            .with_context(|| format!("cannot write {}", path.display()))
    })
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
