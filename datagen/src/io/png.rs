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
