//! What a photo's EXIF says of the camera that took it: the horizontal field of view, from the
//! lens's 35 mm equivalent focal length.
//!
//! The edit uses it where a photo pixel's direction matters: the light's level from the photo's
//! background ([`crate::light::background`]) looks the given map up along each background pixel's
//! direction through a pinhole of this field of view. A phone's main camera sees about 65–70°
//! across a landscape photo, 1.7 times the 40° default: with the default, the background's
//! pixels are looked up in the wrong part of the map.

use exif::{In, Reader, Tag};

/// The 35 mm film frame's diagonal (36 × 24 mm), in mm: a 35 mm equivalent focal length is the
/// one that gives the same field of view across this diagonal as the camera gives across its
/// sensor's (CIPA DC-008's `FocalLengthIn35mmFilm`).
const FILM_DIAGONAL_MM: f64 = 43.266_615;

/// The widest and narrowest fields of view `--fov` accepts, and so this does (degrees).
pub const FOV_RANGE_DEG: (f64, f64) = (1.0, 170.0);

/// The horizontal field of view (degrees) of a photo shown at `width`×`height` (after its
/// orientation was applied), from the `FocalLengthIn35mmFilm` of its raw EXIF (TIFF) block;
/// none where the block cannot be read, has no such field or gives 0 (unknown), or the field
/// of view it gives is outside [`FOV_RANGE_DEG`].
pub fn field_of_view(exif: &[u8], width: usize, height: usize) -> Option<f64> {
    // One malformed entry elsewhere in the block does not lose the focal length.
    let parsed = match Reader::new().continue_on_error(true).read_raw(exif.to_vec()) {
        Ok(parsed) => parsed,
        Err(e) => e.distill_partial_result(|_| {}).ok()?,
    };
    let f35 = parsed
        .get_field(Tag::FocalLengthIn35mmFilm, In::PRIMARY)?
        .value
        .get_uint(0)? as f64;
    fov_of_equivalent_focal_length(f35, width, height)
}

/// The horizontal field of view (degrees) of a `width`×`height` picture taken with a lens of
/// 35 mm equivalent focal length `f35` (mm): the film diagonal's share along the width, seen
/// through a pinhole `f35` away. None for a focal length that is not positive or a field of
/// view outside [`FOV_RANGE_DEG`].
pub fn fov_of_equivalent_focal_length(f35: f64, width: usize, height: usize) -> Option<f64> {
    if !(f35.is_finite() && f35 > 0.0) || width == 0 || height == 0 {
        return None;
    }
    let (w, h) = (width as f64, height as f64);
    let across = FILM_DIAGONAL_MM * w / w.hypot(h);
    let fov = 2.0 * (across / (2.0 * f35)).atan().to_degrees();
    (FOV_RANGE_DEG.0..=FOV_RANGE_DEG.1).contains(&fov).then_some(fov)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use exif::{Field, Value};

    /// A little-endian EXIF (TIFF) block with `FocalLengthIn35mmFilm` = `f35` and the
    /// orientation tag `orientation`.
    pub(crate) fn exif_block(f35: u16, orientation: u16) -> Vec<u8> {
        let focal = Field {
            tag: Tag::FocalLengthIn35mmFilm,
            ifd_num: In::PRIMARY,
            value: Value::Short(vec![f35]),
        };
        let turn = Field {
            tag: Tag::Orientation,
            ifd_num: In::PRIMARY,
            value: Value::Short(vec![orientation]),
        };
        let mut w = exif::experimental::Writer::new();
        w.push_field(&focal);
        w.push_field(&turn);
        let mut buf = std::io::Cursor::new(Vec::new());
        w.write(&mut buf, true).expect("exif");
        buf.into_inner()
    }

    #[test]
    fn a_full_frame_focal_length_gives_its_textbook_field_of_view() {
        // 36 × 24 mm film: 2 atan(18 / f) across its width, whatever the focal length.
        for f in [14.0_f64, 24.0, 26.0, 50.0, 200.0] {
            let want = 2.0 * (18.0 / f).atan().to_degrees();
            let got = fov_of_equivalent_focal_length(f, 3000, 2000).expect("in range");
            assert!((got - want).abs() < 1e-4, "{f} mm: {got} vs {want}");
        }
        // A phone's 26 mm on a 4:3 photo: about 67° across in landscape, 53° in portrait.
        let land = fov_of_equivalent_focal_length(26.0, 4032, 3024).expect("landscape");
        let port = fov_of_equivalent_focal_length(26.0, 3024, 4032).expect("portrait");
        assert!((land - 67.3).abs() < 0.1 && (port - 53.0).abs() < 0.1, "{land} {port}");
    }

    #[test]
    fn unknown_or_impossible_focal_lengths_give_none() {
        for f in [0.0, -26.0, f64::NAN, f64::INFINITY, 0.5, 1.0] {
            assert_eq!(fov_of_equivalent_focal_length(f, 4000, 3000), None, "{f}");
        }
        assert_eq!(fov_of_equivalent_focal_length(26.0, 0, 3000), None);
        // The narrowest accepted: 1°, at about 2,000 mm.
        assert!(fov_of_equivalent_focal_length(2000.0, 3000, 2000).is_some());
        assert_eq!(fov_of_equivalent_focal_length(1e6, 3000, 2000), None);
    }

    #[test]
    fn the_exif_field_is_read_and_a_bad_block_is_nothing() {
        let fov = field_of_view(&exif_block(26, 6), 3024, 4032).expect("read");
        assert!((fov - 53.0).abs() < 0.1, "{fov}");
        assert_eq!(field_of_view(&exif_block(0, 1), 3024, 4032), None, "0 is unknown");
        assert_eq!(field_of_view(b"not exif at all", 3024, 4032), None);
        assert_eq!(field_of_view(&exif_block(26, 1)[..10], 3024, 4032), None, "cut short");
        assert_eq!(field_of_view(&[], 3024, 4032), None);
        // A block with an orientation and no focal length.
        let only_turn = crate::photo::orientation::tests::exif_with_orientation(6);
        assert_eq!(field_of_view(&only_turn, 3024, 4032), None);
    }
}
