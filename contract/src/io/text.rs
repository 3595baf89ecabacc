//! Text for contact sheets: column names and sample ids in font8x8's bitmap glyphs. A bitmap font
//! needs no system fonts, so a sheet looks the same on every machine (plotters' `ttf` feature,
//! which the trainer's loss plot uses, depends on fontconfig finding one).

use font8x8::legacy::{BASIC_LEGACY, LATIN_LEGACY};

/// Glyph side in pixels: each character is `GLYPH` wide and tall (unscaled).
pub const GLYPH: usize = 8;

/// The glyph of `c`: ASCII and Latin-1 (for `°`, `×`, accented names); anything else shows as
/// `?` so a missing glyph is visible rather than silently blank.
fn glyph(c: char) -> [u8; 8] {
    let u = c as usize;
    match u {
        0..=0x7f => BASIC_LEGACY[u],
        0xa0..=0xff => LATIN_LEGACY[u - 0xa0],
        _ => BASIC_LEGACY['?' as usize],
    }
}

/// Width in pixels of `text` drawn at `scale`.
pub fn text_width(text: &str, scale: usize) -> usize {
    text.chars().count() * GLYPH * scale
}

/// Draws one line of `text` with its top-left corner at (`x`, `y`), `scale` pixels per font
/// pixel. Characters that would not fit whole before `x + max_width` (or the image's edge) are
/// left out, so a long id is cut at a character boundary instead of into a neighbouring tile.
pub fn draw_text(
    img: &mut image::RgbaImage,
    x: usize,
    y: usize,
    max_width: usize,
    text: &str,
    colour: [u8; 4],
    scale: usize,
) {
    let scale = scale.max(1);
    let advance = GLYPH * scale;
    let right = (x + max_width).min(img.width() as usize);
    let bottom = img.height() as usize;
    for (k, c) in text.chars().enumerate() {
        let gx = x + k * advance;
        if gx + advance > right {
            break;
        }
        for (row, bits) in glyph(c).iter().enumerate() {
            for col in 0..GLYPH {
                // font8x8 stores each row's leftmost pixel in bit 0.
                if bits >> col & 1 == 0 {
                    continue;
                }
                for dy in 0..scale {
                    let py = y + row * scale + dy;
                    if py >= bottom {
                        break;
                    }
                    for dx in 0..scale {
                        img.put_pixel((gx + col * scale + dx) as u32, py as u32, image::Rgba(colour));
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lit(img: &image::RgbaImage) -> usize {
        img.pixels().filter(|p| p.0 == [255; 4]).count()
    }

    #[test]
    fn a_glyph_lights_the_pixels_of_its_bitmap_scaled_by_the_square_of_the_scale() {
        let bits: u32 = glyph('A').iter().map(|r| r.count_ones()).sum();
        for scale in [1, 2] {
            let mut img = image::RgbaImage::new(40, 40);
            draw_text(&mut img, 3, 5, 40, "A", [255; 4], scale);
            assert_eq!(lit(&img), (bits as usize) * scale * scale);
        }
    }

    #[test]
    fn text_is_cut_at_a_whole_character_before_the_width_or_the_image_edge() {
        let mut cut = image::RgbaImage::new(64, 8);
        draw_text(&mut cut, 0, 0, 20, "MMMM", [255; 4], 1);
        let mut two = image::RgbaImage::new(64, 8);
        draw_text(&mut two, 0, 0, 64, "MM", [255; 4], 1);
        assert_eq!(cut, two, "20 pixels hold two whole 8-pixel glyphs");
        let mut edge = image::RgbaImage::new(12, 4);
        draw_text(&mut edge, 0, 0, 100, "MMMM", [255; 4], 1);
        assert!(
            lit(&edge) > 0,
            "the first glyph fits across and is cut at the bottom edge"
        );
        assert_eq!(text_width("MMMM", 2), 64);
    }

    #[test]
    fn characters_without_a_glyph_show_as_a_question_mark() {
        assert_eq!(glyph('\u{2192}'), glyph('?'));
        assert_ne!(glyph('°'), glyph('?'));
    }
}
