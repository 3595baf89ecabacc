//! No input can crash the editor's readers: property-based fuzzing of photos, masks and region
//! labels (the properties and the mutations: `tests/common/fuzz/` at the workspace root).
//! The checkpoints `matedit` loads are read by the trainer's reader, fuzzed in
//! `tests/fuzz_trainer.rs`.
//!
//! CI: `cargo test --release -p matedit-edit --test fuzz`. The long run:
//! `MATEDIT_FUZZ_SCALE=K` (K times each reader's CI cases) (and `MATEDIT_FUZZ_SEED`), `scripts/fuzz_long.sh`.

#[path = "../../tests/common/fuzz/mod.rs"]
mod fuzz;

use fuzz::{Counting, Reader, Verdict, eval_assets, fuzz, radiance, seed_file};
use matedit_edit::photo::{load_mask, load_photo};
use matedit_edit::target::load_regions;
use std::path::Path;

#[global_allocator]
static ALLOCATOR: Counting = Counting;

const MB: usize = 1 << 20;

fn err(e: impl std::fmt::Display) -> String {
    format!("{e:#}")
}

fn png(w: u32, h: u32, sixteen: bool, alpha: bool) -> Vec<u8> {
    let mut out = std::io::Cursor::new(Vec::new());
    let img: image::DynamicImage = match (sixteen, alpha) {
        (false, false) => image::RgbImage::from_fn(w, h, |x, y| image::Rgb([(x * 9) as u8, (y * 13) as u8, 90])).into(),
        (false, true) => image::RgbaImage::from_fn(w, h, |x, y| {
            image::Rgba([(x * 9) as u8, 40, 90, if x > 3 && y > 3 { 255 } else { 0 }])
        })
        .into(),
        (true, _) => image::ImageBuffer::<image::Rgb<u16>, _>::from_fn(w, h, |x, y| {
            image::Rgb([(x * 900) as u16, (y * 1300) as u16, 9000])
        })
        .into(),
    };
    img.write_to(&mut out, image::ImageFormat::Png).unwrap();
    out.into_inner()
}

fn jpeg(w: u32, h: u32) -> Vec<u8> {
    let mut out = std::io::Cursor::new(Vec::new());
    let img: image::DynamicImage =
        image::RgbImage::from_fn(w, h, |x, y| image::Rgb([(x * 9) as u8, (y * 13) as u8, 90])).into();
    img.write_to(&mut out, image::ImageFormat::Jpeg).unwrap();
    out.into_inner()
}

/// An EXIF (TIFF) block with an orientation and a 35 mm equivalent focal length: the parsing
/// of both is fuzzed with the photo.
fn exif_block(orientation: u16, f35: u16) -> Vec<u8> {
    use exif::{Field, In, Tag, Value};
    let fields = [
        Field {
            tag: Tag::Orientation,
            ifd_num: In::PRIMARY,
            value: Value::Short(vec![orientation]),
        },
        Field {
            tag: Tag::FocalLengthIn35mmFilm,
            ifd_num: In::PRIMARY,
            value: Value::Short(vec![f35]),
        },
    ];
    let mut w = exif::experimental::Writer::new();
    for f in &fields {
        w.push_field(f);
    }
    let mut buf = std::io::Cursor::new(Vec::new());
    w.write(&mut buf, false).unwrap();
    buf.into_inner()
}

/// A `w`×`h` RGB image as PNG or JPEG carrying [`exif_block`].
fn with_exif(w: u32, h: u32, format: image::ImageFormat, orientation: u16) -> Vec<u8> {
    use image::ImageEncoder;
    let img = image::RgbImage::from_fn(w, h, |x, y| image::Rgb([(x * 9) as u8, (y * 13) as u8, 90]));
    let mut out = std::io::Cursor::new(Vec::new());
    let exif = exif_block(orientation, 26);
    if format == image::ImageFormat::Png {
        let mut enc = image::codecs::png::PngEncoder::new(&mut out);
        enc.set_exif_metadata(exif).unwrap();
        enc.write_image(img.as_raw(), w, h, image::ExtendedColorType::Rgb8)
            .unwrap();
    } else {
        let mut enc = image::codecs::jpeg::JpegEncoder::new(&mut out);
        enc.set_exif_metadata(exif).unwrap();
        enc.write_image(img.as_raw(), w, h, image::ExtendedColorType::Rgb8)
            .unwrap();
    }
    out.into_inner()
}

fn photo_valid(p: &matedit_edit::photo::Photo) -> Verdict {
    if p.width == 0 || p.height == 0 || p.rgb.len() != p.width * p.height {
        Err(format!("{}×{} with {} pixels", p.width, p.height, p.rgb.len()))
    } else if p.rgb.iter().flatten().any(|v| !v.is_finite() || *v < 0.0) {
        Err("a non-finite or negative value".into())
    } else if p
        .alpha
        .as_ref()
        .is_some_and(|a| a.len() != p.rgb.len() || a.iter().any(|v| !(0.0..=1.0).contains(v)))
    {
        Err("alpha of the wrong length or outside [0, 1]".into())
    } else {
        Ok(())
    }
}

fn photos(name: &'static str, file_name: &'static str, seeds: Vec<(String, Vec<u8>)>, cases: u32) {
    let read = |p: &Path| -> Result<Verdict, String> {
        let photo = load_photo(p).map_err(err)?;
        Ok(photo_valid(&photo))
    };
    fuzz(&Reader {
        name,
        file_name,
        seeds,
        cases,
        floor_bytes: 48 * MB,
        per_input_byte: None,
        prepare: None,
        read: &read,
    });
}

#[test]
fn photos_png() {
    let mut seeds = vec![
        ("rgb8 24×16".to_string(), png(24, 16, false, false)),
        ("rgba8 24×16".to_string(), png(24, 16, false, true)),
        ("rgb16 24×16".to_string(), png(24, 16, true, false)),
        (
            "rgb8 16×24, EXIF turn".to_string(),
            with_exif(16, 24, image::ImageFormat::Png, 6),
        ),
    ];
    if let Some(a) = eval_assets() {
        seeds.extend(seed_file(&a.join("photos/rembg_cars/car-1.out.png")));
    }
    photos("photo-png", "photo.png", seeds, 200);
}

#[test]
fn photos_jpeg() {
    let mut seeds = vec![
        ("jpeg 24×16".to_string(), jpeg(24, 16)),
        (
            "jpeg 16×24, EXIF turn".to_string(),
            with_exif(16, 24, image::ImageFormat::Jpeg, 8),
        ),
    ];
    if let Some(a) = eval_assets() {
        seeds.extend(seed_file(&a.join("photos/rembg_cars/car-2.jpg")));
    }
    photos("photo-jpeg", "photo.jpg", seeds, 200);
}

#[test]
fn photos_hdr() {
    let mut seeds = vec![("radiance 24×16".to_string(), radiance(24, 16))];
    if let Some(a) = eval_assets() {
        seeds.extend(seed_file(&a.join("envmaps/dikhololo_night_1k.hdr")));
    }
    photos("photo-hdr", "photo.hdr", seeds, 100);
}

#[test]
fn photos_exr() {
    let n = 24 * 16;
    let ch = |k: f32| (0..n).map(|i| (i as f32 * k).sin().abs()).collect::<Vec<f32>>();
    let bytes = matedit_contract::io::encode_exr_channels(
        24,
        16,
        vec![("R", ch(0.1)), ("G", ch(0.2)), ("B", ch(0.3)), ("A", ch(0.05))],
    )
    .unwrap();
    photos(
        "photo-exr",
        "photo.exr",
        [vec![("exr rgba 24×16".to_string(), bytes)], fuzz::odd_exrs(24, 16)].concat(),
        200,
    );
}

#[test]
fn masks_and_region_labels() {
    let mut seeds = vec![
        ("rgba8 24×16".to_string(), png(24, 16, false, true)),
        ("rgb16 24×16".to_string(), png(24, 16, true, false)),
        // Drawn on the photo's stored pixels: turned with it.
        ("rgba8 16×24".to_string(), png(16, 24, false, true)),
        // Its own EXIF turn, and upright as stored.
        (
            "rgb8 24×16, own EXIF turn".to_string(),
            with_exif(24, 16, image::ImageFormat::Png, 6),
        ),
    ];
    // Labels 0..=2 in grey.
    let mut labels = std::io::Cursor::new(Vec::new());
    image::DynamicImage::from(image::GrayImage::from_fn(24, 16, |x, _| image::Luma([(x / 8) as u8])))
        .write_to(&mut labels, image::ImageFormat::Png)
        .unwrap();
    seeds.push(("labels 24×16".to_string(), labels.into_inner()));
    let read = |p: &Path| -> Result<Verdict, String> {
        // The photo these belong to is 24×16, its stored pixels turned a quarter by its EXIF: a
        // mask of its stored size (16×24) is turned with it, one of another size is an error
        // naming the file.
        let turn = image::metadata::Orientation::Rotate90;
        let coverage = load_mask(p, 24, 16, turn).map_err(err)?.0;
        if coverage.len() != 24 * 16 || coverage.iter().any(|v| !(0.0..=1.0).contains(v)) {
            return Ok(Err("coverage of the wrong length or outside [0, 1]".into()));
        }
        let all = vec![1.0; 24 * 16];
        let (labels, n, _) = load_regions(p, 24, 16, turn, &all).map_err(err)?;
        Ok(if labels.len() != 24 * 16 || labels.iter().any(|&l| l as usize > n) {
            Err("labels of the wrong length or beyond the region count".into())
        } else {
            Ok(())
        })
    };
    fuzz(&Reader {
        name: "mask",
        file_name: "mask.png",
        seeds,
        cases: 300,
        floor_bytes: 32 * MB,
        per_input_byte: None,
        prepare: None,
        read: &read,
    });
}

/// Found by this fuzzer: an EXR photo whose alpha channel holds NaN was accepted with a NaN
/// alpha (the clamp to [0, 1] passes NaN through), which would reach the composite.
#[test]
fn regression_exr_photo_with_nan_alpha() {
    use exr::prelude::{
        AnyChannel, AnyChannels, Encoding, FlatSamples, Image, Layer, LayerAttributes, SmallVec, WritableImage,
    };
    let n = 24 * 16;
    let mut alpha = vec![1.0_f32; n];
    alpha[17] = f32::NAN;
    let channels: Vec<AnyChannel<FlatSamples>> = [
        ("A", alpha),
        ("B", vec![0.2; n]),
        ("G", vec![0.3; n]),
        ("R", vec![0.4; n]),
    ]
    .into_iter()
    .map(|(name, v)| AnyChannel::new(name, FlatSamples::F32(v)))
    .collect();
    let layer = Layer::new(
        (24, 16),
        LayerAttributes::default(),
        Encoding::SMALL_LOSSLESS,
        AnyChannels::sort(SmallVec::from_vec(channels)),
    );
    let mut bytes = std::io::Cursor::new(Vec::new());
    Image::from_layer(layer).write().to_buffered(&mut bytes).unwrap();
    let read = |p: &Path| -> Result<Verdict, String> { Ok(photo_valid(&load_photo(p).map_err(err)?)) };
    let reader = Reader {
        name: "photo-exr",
        file_name: "photo.exr",
        seeds: Vec::new(),
        cases: 0,
        floor_bytes: 48 * MB,
        per_input_byte: None,
        prepare: None,
        read: &read,
    };
    assert!(!fuzz::regression(&reader, &bytes.into_inner()));
}
