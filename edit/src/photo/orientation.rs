//! A photo as viewers show it: the EXIF orientation of a JPEG (or a PNG's `eXIf` chunk) applied
//! on reading.
//!
//! Cameras and phones store a portrait photo's pixels sideways and tag the file with how to turn
//! them; every viewer, browser and editor turns it. Read as stored, such a photo comes out of an
//! edit sideways, and a mask drawn on it as shown does not fit it. So the photo is turned, and a
//! mask or region image is taken as drawn on the photo as shown — unless only the stored pixels'
//! size fits it (a tool that ignores EXIF, such as a script reading the file with PIL, made it on
//! the stored pixels), in which case it is turned with the photo ([`crate::photo`]'s
//! `decode_for_photo`). Where the turn keeps the size (a half turn, a mirror, a quarter turn of
//! a square photo), the two cannot be told apart: the mask is taken as shown, and the report
//! says both fitted.

use anyhow::{Context, Result};
use image::metadata::Orientation;
use image::{DynamicImage, ImageDecoder, ImageReader};
use std::io::{BufRead, Seek};

/// Decodes `reader`'s image and turns it as its EXIF orientation says; returns the orientation
/// applied (`NoTransforms` where the file has none, or an unreadable one) and the raw EXIF
/// (TIFF) block, where the file has one. An image whose pixels would take more than
/// `max_bytes` is refused before they are decoded (as `ImageReader::decode` does with its
/// limits, which `into_decoder` only hands on).
pub fn decode_turned<R: BufRead + Seek>(
    reader: ImageReader<R>,
    what: &str,
    max_bytes: u64,
) -> Result<(DynamicImage, Orientation, Option<Vec<u8>>)> {
    let mut decoder = reader
        .into_decoder()
        .with_context(|| format!("{what}: cannot decode the image (truncated or corrupt?)"))?;
    let need = decoder.total_bytes();
    if need > max_bytes {
        anyhow::bail!("{what}: decoding it would take {need} bytes, more than the {max_bytes} this command allows");
    }
    // An EXIF block that cannot be read says nothing of the orientation; the pixels are still
    // the photo.
    let exif = decoder.exif_metadata().unwrap_or(None);
    let orientation = exif
        .as_deref()
        .and_then(Orientation::from_exif_chunk)
        .unwrap_or(Orientation::NoTransforms);
    let mut img = DynamicImage::from_decoder(decoder)
        .with_context(|| format!("{what}: cannot decode the image (truncated or corrupt?)"))?;
    img.apply_orientation(orientation);
    Ok((img, orientation, exif))
}

/// Whether `o` turns a w×h image into an h×w one.
pub fn swaps_axes(o: Orientation) -> bool {
    matches!(
        o,
        Orientation::Rotate90 | Orientation::Rotate270 | Orientation::Rotate90FlipH | Orientation::Rotate270FlipH
    )
}

/// The size an image stored as `stored` shows as once turned by `o`.
pub fn shown_size(stored: (usize, usize), o: Orientation) -> (usize, usize) {
    if swaps_axes(o) { (stored.1, stored.0) } else { stored }
}

/// What turning by `o` does, in words.
pub fn describe(o: Orientation) -> &'static str {
    match o {
        Orientation::NoTransforms => "as stored",
        Orientation::Rotate90 => "turned 90° clockwise",
        Orientation::Rotate180 => "turned 180°",
        Orientation::Rotate270 => "turned 90° anticlockwise",
        Orientation::FlipHorizontal => "mirrored left to right",
        Orientation::FlipVertical => "mirrored top to bottom",
        Orientation::Rotate90FlipH => "turned 90° clockwise and mirrored left to right",
        Orientation::Rotate270FlipH => "turned 90° anticlockwise and mirrored left to right",
    }
}

/// How a mask or region image was matched to its photo.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Fit {
    /// Drawn on the photo as shown (its own EXIF orientation, if any, applied).
    AsShown,
    /// Taken as drawn on the photo as shown, though one drawn on the stored pixels would fit
    /// too: the photo's turn keeps its size (a half turn, a mirror, a square photo).
    AsShownOrStored,
    /// Its own EXIF orientation ignored: turned by it, it does not fit; as stored, it does (a
    /// tool that wrote the pixels upright and kept the tag).
    OwnOrientationIgnored,
    /// Drawn on the photo's stored pixels: turned with the photo.
    TurnedWithPhoto,
}

impl Fit {
    /// What the command line says of it, if anything.
    fn said(self, what: &str) -> Option<String> {
        match self {
            Fit::AsShown => None,
            Fit::AsShownOrStored => Some(format!(
                "the {what} fits the photo both as shown and as stored, and was taken as drawn on the photo as shown"
            )),
            Fit::OwnOrientationIgnored => Some(format!(
                "the {what}'s own EXIF orientation was ignored (its stored pixels fit the photo)"
            )),
            Fit::TurnedWithPhoto => Some(format!(
                "the {what} fitted the photo's stored pixels and was turned with it"
            )),
        }
    }
}

/// For `report.json`: how the photo was turned to stand as viewers show it, and how its mask
/// (and region image) were matched to it. Present where the photo's file says to turn it, or
/// a mask or region image was not simply taken as shown.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct OrientationReport {
    /// The photo's EXIF orientation tag (1: none, or as stored).
    pub exif: u8,
    /// What was done to the photo.
    pub applied: String,
    /// The photo's size as stored (the edit is written at its size as shown).
    pub stored_size: [usize; 2],
    /// How the mask was matched (none where the photo's alpha is the mask).
    pub mask: Option<Fit>,
    /// How the region image was matched, when there is one.
    pub regions: Option<Fit>,
}

impl OrientationReport {
    /// The report for a photo turned by `o` from `stored`.
    pub fn new(o: Orientation, stored: (usize, usize)) -> Self {
        OrientationReport {
            exif: o.to_exif(),
            applied: describe(o).to_string(),
            stored_size: [stored.0, stored.1],
            mask: None,
            regions: None,
        }
    }

    /// Whether it says anything a reader needs: the photo was turned, or a mask or region
    /// image was not simply taken as shown.
    pub fn matters(&self) -> bool {
        self.exif != 1 || [self.mask, self.regions].iter().flatten().any(|f| *f != Fit::AsShown)
    }

    /// One line for the command line.
    pub fn line(&self) -> String {
        let turned = if self.exif == 1 {
            "the photo was read as stored".to_string()
        } else {
            format!(
                "the photo was {} as its EXIF orientation {} says (stored {}×{})",
                self.applied, self.exif, self.stored_size[0], self.stored_size[1]
            )
        };
        let fits = [(self.mask, "mask"), (self.regions, "region image")]
            .into_iter()
            .filter_map(|(f, what)| f.and_then(|f| f.said(what)))
            .map(|s| format!("; {s}"))
            .collect::<String>();
        format!("orientation: {turned}{fits}")
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use image::{ImageEncoder, RgbImage};
    use std::path::{Path, PathBuf};

    /// A big-endian EXIF (TIFF) block whose only entry is the orientation tag.
    pub(crate) fn exif_with_orientation(tag: u16) -> Vec<u8> {
        let mut b = b"MM\0\x2a\0\0\0\x08".to_vec();
        b.extend_from_slice(&1u16.to_be_bytes()); // one entry
        b.extend_from_slice(&0x0112u16.to_be_bytes()); // Orientation
        b.extend_from_slice(&3u16.to_be_bytes()); // SHORT
        b.extend_from_slice(&1u32.to_be_bytes()); // one value
        b.extend_from_slice(&tag.to_be_bytes());
        b.extend_from_slice(&[0, 0]); // the value's padding to four bytes
        b.extend_from_slice(&0u32.to_be_bytes()); // no next IFD
        b
    }

    /// Writes `img` as a PNG or JPEG (by `path`'s extension) carrying EXIF orientation `tag`
    /// (none for 0).
    pub(crate) fn write_with_orientation(path: &Path, img: &RgbImage, tag: u16) {
        let f = std::io::BufWriter::new(std::fs::File::create(path).expect("create"));
        let exif = exif_with_orientation(tag);
        let (w, h) = img.dimensions();
        if path.extension().is_some_and(|e| e == "png") {
            let mut enc = image::codecs::png::PngEncoder::new(f);
            if tag > 0 {
                enc.set_exif_metadata(exif).expect("png exif");
            }
            enc.write_image(img.as_raw(), w, h, image::ExtendedColorType::Rgb8)
                .expect("png");
        } else {
            let mut enc = image::codecs::jpeg::JpegEncoder::new_with_quality(f, 100);
            if tag > 0 {
                enc.set_exif_metadata(exif).expect("jpeg exif");
            }
            enc.write_image(img.as_raw(), w, h, image::ExtendedColorType::Rgb8)
                .expect("jpeg");
        }
    }

    fn read(path: &Path) -> (DynamicImage, Orientation) {
        let r = ImageReader::open(path)
            .expect("open")
            .with_guessed_format()
            .expect("format");
        let (img, o, _) = decode_turned(r, "test", 1 << 20).expect("decode");
        (img, o)
    }

    fn dir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("matedit-orientation-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&d).expect("dir");
        d
    }

    /// A 3×2 image whose pixels are all different: where each lands says what was done.
    fn marked() -> RgbImage {
        RgbImage::from_fn(3, 2, |x, y| image::Rgb([(x * 80) as u8, (y * 200) as u8, 30]))
    }

    #[test]
    fn every_exif_orientation_turns_the_pixels_as_viewers_do() {
        let d = dir("all");
        let img = marked();
        // Where stored pixel (x, y) of a 3×2 image shows, per EXIF tag (the EXIF 2.3 table:
        // 6 = the stored top row becomes the right column).
        let shown = |tag: u16, x: u32, y: u32| -> (u32, u32) {
            match tag {
                1 => (x, y),
                2 => (2 - x, y),
                3 => (2 - x, 1 - y),
                4 => (x, 1 - y),
                5 => (y, x),
                6 => (1 - y, x),
                7 => (1 - y, 2 - x),
                8 => (y, 2 - x),
                _ => unreachable!(),
            }
        };
        for ext in ["png", "jpg"] {
            for tag in 1..=8u16 {
                let path = d.join(format!("o{tag}.{ext}"));
                write_with_orientation(&path, &img, tag);
                let (out, o) = read(&path);
                assert_eq!(o.to_exif(), tag as u8, "{ext} {tag}");
                let out = out.to_rgb8();
                assert_eq!(
                    (out.width() as usize, out.height() as usize),
                    shown_size((3, 2), o),
                    "{ext} {tag}"
                );
                for (x, y, p) in img.enumerate_pixels() {
                    let (sx, sy) = shown(tag, x, y);
                    let q = out.get_pixel(sx, sy);
                    // JPEG at quality 100 still rounds a little.
                    let near = p.0.iter().zip(q.0.iter()).all(|(a, b)| a.abs_diff(*b) <= 24);
                    assert!(near, "{ext} tag {tag}: ({x},{y}) → ({sx},{sy}): {p:?} vs {q:?}");
                }
            }
        }
        std::fs::remove_dir_all(d).ok();
    }

    #[test]
    fn no_or_broken_exif_leaves_the_pixels_as_stored() {
        let d = dir("none");
        let img = marked();
        let plain = d.join("plain.png");
        write_with_orientation(&plain, &img, 0);
        let (out, o) = read(&plain);
        assert_eq!(o, Orientation::NoTransforms);
        assert_eq!(out.to_rgb8(), img);
        // Tags outside 1–8 and a block that is not TIFF at all are no orientation.
        for (name, exif) in [
            ("tag0", exif_with_orientation(0)),
            ("tag9", exif_with_orientation(9)),
            ("junk", b"not an exif block".to_vec()),
            ("cut", exif_with_orientation(6)[..12].to_vec()),
        ] {
            let p = d.join(format!("{name}.jpg"));
            let f = std::io::BufWriter::new(std::fs::File::create(&p).expect("create"));
            let mut enc = image::codecs::jpeg::JpegEncoder::new_with_quality(f, 100);
            enc.set_exif_metadata(exif).expect("exif");
            enc.write_image(img.as_raw(), 3, 2, image::ExtendedColorType::Rgb8)
                .expect("jpeg");
            let (out, o) = read(&p);
            assert_eq!(o, Orientation::NoTransforms, "{name}");
            assert_eq!((out.width(), out.height()), (3, 2), "{name}");
        }
        std::fs::remove_dir_all(d).ok();
    }

    #[test]
    fn an_image_over_the_byte_limit_is_refused_before_decoding() {
        let d = dir("limit");
        let p = d.join("big.png");
        write_with_orientation(&p, &RgbImage::new(64, 64), 6);
        let r = || {
            ImageReader::open(&p)
                .expect("open")
                .with_guessed_format()
                .expect("format")
        };
        let e = format!(
            "{:#}",
            decode_turned(r(), "big.png", 64 * 64 * 3 - 1).expect_err("refused")
        );
        assert!(e.contains("big.png") && e.contains("12288 bytes"), "{e}");
        assert!(decode_turned(r(), "big.png", 64 * 64 * 3).is_ok());
        std::fs::remove_dir_all(d).ok();
    }

    #[test]
    fn the_report_says_what_was_turned_and_how_the_mask_was_fitted() {
        let mut plain = OrientationReport::new(Orientation::NoTransforms, (4, 3));
        plain.mask = Some(Fit::AsShown);
        assert!(!plain.matters());
        plain.mask = Some(Fit::OwnOrientationIgnored);
        assert!(plain.matters());
        let line = plain.line();
        assert!(
            line.contains("read as stored") && line.contains("mask's own EXIF orientation was ignored"),
            "{line}"
        );
        let mut r = OrientationReport::new(Orientation::Rotate90, (4, 3));
        assert!(r.matters());
        assert_eq!((r.exif, r.stored_size), (6, [4, 3]));
        r.mask = Some(Fit::TurnedWithPhoto);
        r.regions = Some(Fit::AsShownOrStored);
        let line = r.line();
        assert!(
            line.contains("turned 90° clockwise") && line.contains("EXIF orientation 6"),
            "{line}"
        );
        assert!(line.contains("mask fitted the photo's stored pixels"), "{line}");
        assert!(
            line.contains("region image fits the photo both as shown and as stored"),
            "{line}"
        );
        for tag in 1..=8u8 {
            let o = Orientation::from_exif(tag).expect("tag");
            assert_eq!(shown_size((4, 3), o) == (3, 4), (5..=8).contains(&tag), "{tag}");
        }
    }

    /// The stored pixels of an image shown as `shown` under `o` (the inverse turn).
    pub(crate) fn stored_of(shown: &DynamicImage, o: Orientation) -> DynamicImage {
        let inverse = match o {
            Orientation::Rotate90 => Orientation::Rotate270,
            Orientation::Rotate270 => Orientation::Rotate90,
            other => other, // the rest are their own inverses
        };
        let mut img = shown.clone();
        img.apply_orientation(inverse);
        img
    }
}
