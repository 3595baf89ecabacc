//! A photo and its object mask, read and framed the way the training images were made.
//!
//! * **Reading.** PNG (8/16-bit) and JPEG are sRGB and decoded to linear; EXR and Radiance HDR
//!   are linear radiance already. A JPEG or PNG is turned as its EXIF orientation says
//!   ([`crate::photo::orientation`]), so the edit stands as viewers show the photo. The mask is a separate image (any non-zero pixel is object; its
//!   value, or its alpha where it has one, is the soft coverage used when compositing) or, without
//!   one, the photo's own alpha channel (what background removers such as rembg write).
//! * **Framing** ([`Framing`]). The training images show the object with its larger side about
//!   [`TRAINING_FILL`] of the image (the median over the quickstart training split), centred. The
//!   photo is cropped to the square around the mask's bounding box that gives the same fill,
//!   padded with background where that square leaves the photo, and area-averaged to the
//!   network's input size.
//! * **Exposure.** A photo's scale is arbitrary; the network saw object pixels whose mean
//!   luminance was about [`TRAINING_MEAN_LUMINANCE`] (median over the same split). The input is
//!   scaled to that, and every rendered image scaled back before it is composited.

pub mod camera;
pub mod orientation;
pub mod read;

use anyhow::{Context, Result, bail};
use image::metadata::Orientation;
use orientation::Fit;
use std::path::Path;

/// Median ratio of the object's larger bounding-box side to the image side in the quickstart
/// training split (300 samples; 10–90 %: 0.53–0.97).
pub const TRAINING_FILL: f64 = 0.875;

/// Median of the mean object luminance (Rec. 709 weights) in the quickstart training split
/// (400 samples; 10–90 %: 0.17–1.53); the level a network trained with `exposure = "normalised"`
/// sees every image at.
pub const TRAINING_MEAN_LUMINANCE: f64 = matedit_trainer::model::network::NORMALISED_MEAN_LUMINANCE;

/// The largest photo read, in pixels: a 40-megapixel photo is read (about 0.5 GB as linear
/// `f32`), a larger one refused before it is decoded.
pub const MAX_PIXELS: u64 = 100_000_000;

/// The most an image's decoded pixels may take (bytes).
const MAX_DECODE_BYTES: u64 = 2 << 30;

/// How a photo's values were stored (the edited photo is written back the same way).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Encoding {
    /// 8-bit sRGB (PNG, JPEG).
    Srgb8,
    /// 16-bit sRGB (PNG).
    Srgb16,
    /// Linear radiance (EXR, HDR).
    Linear,
}

/// A photo in linear RGB.
#[derive(Clone, Debug)]
pub struct Photo {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Linear RGB, row-major.
    pub rgb: Vec<[f32; 3]>,
    /// Alpha in [0, 1], where the file has it.
    pub alpha: Option<Vec<f32>>,
    /// How the file stored its values.
    pub encoding: Encoding,
}

/// sRGB decoding of a value in [0, 1].
pub fn srgb_decode(v: f32) -> f32 {
    if v <= 0.040_45 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

pub(crate) fn extension(path: &Path) -> String {
    path.extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default()
}

/// Reads a photo (PNG, JPEG, EXR or HDR) as viewers show it. Non-finite or negative linear
/// values are errors naming the file and the pixel.
pub fn load_photo(path: &Path) -> Result<Photo> {
    load_photo_shown(path).map(|(p, _)| p)
}

/// What a photo's file says beyond its pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PhotoFile {
    /// The EXIF orientation its pixels were turned by ([`crate::photo::orientation`]).
    pub orientation: Orientation,
    /// The horizontal field of view its EXIF gives, in degrees ([`crate::photo::camera`]).
    pub fov_deg: Option<f64>,
}

/// [`load_photo`], with what its file says beyond its pixels.
pub fn load_photo_shown(path: &Path) -> Result<(Photo, PhotoFile)> {
    check_file(path)?;
    match extension(path).as_str() {
        "exr" => read_exr_photo(path),
        "png" | "jpg" | "jpeg" | "hdr" => read_image_photo(path),
        other => bail!(
            "{}: cannot read .{other} photos (PNG, JPEG, EXR or HDR)",
            path.display()
        ),
    }
}

/// An EXR photo: linear, one part, R, G and B required and A kept where present.
fn read_exr_photo(path: &Path) -> Result<(Photo, PhotoFile)> {
    let what = path.display();
    // Only R, G, B and A are decoded, whatever else the file holds, after the header's
    // size was checked against the pixel limit and the file's length.
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {what}"))?;
    matedit_contract::io::check_exr_size(path, &bytes)?;
    let meta = exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(&bytes), false)
        .with_context(|| format!("{what}: cannot decode the EXR header (truncated or corrupt?)"))?;
    // One part, as the editing page requires: the pixel limit is a limit on what is
    // decoded, and the RGBA reader takes the first part that has R, G and B, which
    // need not be the first part.
    if meta.headers.len() != 1 {
        bail!(
            "{what}: an EXR photo must have one part (layer), this one has {}; write the photo alone",
            meta.headers.len()
        );
    }
    let size = meta.headers.first().map(|h| h.layer_size).unwrap_or_default();
    check_size(path, size.width() as u64, size.height() as u64)?;
    for n in ["R", "G", "B"] {
        if !meta
            .headers
            .iter()
            .any(|h| h.channels.list.iter().any(|c| c.name.to_string() == n))
        {
            bail!("{what}: no {n} channel (an EXR photo needs R, G, B)");
        }
    }
    use exr::prelude::{ReadChannels as _, ReadLayers as _};
    type Pixels = (usize, bool, Vec<[f32; 4]>);
    let image = exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level()
        .rgba_channels(
            |s, ch: &exr::image::RgbaChannels| -> Pixels { (s.width(), ch.3.is_some(), vec![[0.0; 4]; s.area()]) },
            |px: &mut Pixels, at, (r, g, b, a): (f32, f32, f32, f32)| px.2[at.y() * px.0 + at.x()] = [r, g, b, a],
        )
        .first_valid_layer()
        .all_attributes()
        .from_buffered(std::io::Cursor::new(bytes))
        .with_context(|| format!("{what}: cannot decode the EXR (truncated or corrupt?)"))?;
    let size = image.layer_data.size;
    let (w, h) = (size.width(), size.height());
    let (_, has_alpha, px) = image.layer_data.channel_data.pixels;
    let (r, g, b): (Vec<f32>, Vec<f32>, Vec<f32>) = (
        px.iter().map(|p| p[0]).collect(),
        px.iter().map(|p| p[1]).collect(),
        px.iter().map(|p| p[2]).collect(),
    );
    let a: Option<Vec<f32>> = has_alpha.then(|| px.iter().map(|p| p[3]).collect());
    let rgb: Vec<[f32; 3]> = (0..w * h).map(|k| [r[k], g[k], b[k]]).collect();
    check_linear(path, &rgb)?;
    if let Some(k) = a.as_ref().and_then(|a| a.iter().position(|v| v.is_nan())) {
        bail!("{what}: alpha is NaN at pixel ({}, {})", k % w, k / w);
    }
    let alpha = a.map(|a| a.iter().map(|v| v.clamp(0.0, 1.0)).collect());
    let p = Photo {
        width: w,
        height: h,
        rgb,
        alpha,
        encoding: Encoding::Linear,
    };
    let file = PhotoFile {
        orientation: Orientation::NoTransforms,
        fov_deg: None,
    };
    Ok((p, file))
}

/// A PNG, JPEG or Radiance HDR photo, turned as its EXIF says and decoded to linear.
fn read_image_photo(path: &Path) -> Result<(Photo, PhotoFile)> {
    let (img, turned, exif) = decode_as(path, true)?;
    let (w, h) = (img.width() as usize, img.height() as usize);
    use image::DynamicImage as D;
    let encoding = match &img {
        D::ImageRgb32F(_) | D::ImageRgba32F(_) => Encoding::Linear,
        D::ImageLuma16(_) | D::ImageLumaA16(_) | D::ImageRgb16(_) | D::ImageRgba16(_) => Encoding::Srgb16,
        _ => Encoding::Srgb8,
    };
    let has_alpha = img.color().has_alpha();
    let rgba = img.into_rgba32f();
    let decode = |v: f32| {
        if encoding == Encoding::Linear {
            v
        } else {
            srgb_decode(v.clamp(0.0, 1.0))
        }
    };
    let rgb: Vec<[f32; 3]> = rgba
        .pixels()
        .map(|p| [decode(p[0]), decode(p[1]), decode(p[2])])
        .collect();
    check_linear(path, &rgb)?;
    let alpha = has_alpha.then(|| rgba.pixels().map(|p| p[3].clamp(0.0, 1.0)).collect());
    let p = Photo {
        width: w,
        height: h,
        rgb,
        alpha,
        encoding,
    };
    let file = PhotoFile {
        orientation: turned,
        fov_deg: exif.and_then(|e| crate::photo::camera::field_of_view(&e, w, h)),
    };
    Ok((p, file))
}

fn check_size(path: &Path, w: u64, h: u64) -> Result<()> {
    if w == 0 || h == 0 {
        bail!("{}: the image is empty ({w}×{h})", path.display());
    }
    if w * h > MAX_PIXELS {
        bail!(
            "{}: {w}×{h} is {:.0} megapixels, more than the {} this command reads; scale it down first",
            path.display(),
            (w * h) as f64 / 1e6,
            MAX_PIXELS / 1_000_000
        );
    }
    Ok(())
}

fn check_linear(path: &Path, rgb: &[[f32; 3]]) -> Result<()> {
    if let Some(k) = rgb.iter().position(|p| p.iter().any(|v| !v.is_finite() || *v < 0.0)) {
        bail!(
            "{}: pixel {k} holds {:?}: photos must be finite and non-negative",
            path.display(),
            rgb[k]
        );
    }
    Ok(())
}

/// Refuses, by name, what cannot be an image file at all: nothing there, a folder, 0 bytes.
fn check_file(path: &Path) -> Result<()> {
    let what = path.display();
    let meta = std::fs::metadata(path).with_context(|| format!("cannot open {what}"))?;
    if meta.is_dir() {
        bail!("{what} is a folder, not an image");
    }
    if meta.len() == 0 {
        bail!("{what} is empty (0 bytes)");
    }
    Ok(())
}

/// Decodes an image as stored (a normal map's vectors would need turning with its pixels), with
/// its size checked from the header first.
pub(crate) fn decode(path: &Path) -> Result<image::DynamicImage> {
    decode_as(path, false).map(|(img, _, _)| img)
}

/// [`decode`], turned as the file's EXIF orientation says.
pub(crate) fn decode_turned(path: &Path) -> Result<(image::DynamicImage, Orientation)> {
    decode_as(path, true).map(|(img, o, _)| (img, o))
}

/// [`decode`] (`turn` false) or [`decode_turned`] with the file's raw EXIF block.
fn decode_as(path: &Path, turn: bool) -> Result<(image::DynamicImage, Orientation, Option<Vec<u8>>)> {
    let what = path.display();
    check_file(path)?;
    let reader = || -> Result<image::ImageReader<std::io::BufReader<std::fs::File>>> {
        image::ImageReader::open(path)
            .with_context(|| format!("cannot open {what}"))?
            .with_guessed_format()
            .with_context(|| format!("cannot read {what}"))
    };
    let (w, h) = reader()?
        .into_dimensions()
        .with_context(|| format!("{what}: not a readable image"))?;
    check_size(path, w as u64, h as u64)?;
    if reader()?.format() == Some(image::ImageFormat::Jpeg) {
        check_jpeg_complete(path)?;
    }
    let mut r = reader()?;
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(MAX_DECODE_BYTES);
    r.limits(limits);
    if turn {
        return orientation::decode_turned(r, &what.to_string(), MAX_DECODE_BYTES);
    }
    let img = r
        .decode()
        .with_context(|| format!("{what}: cannot decode the image (truncated or corrupt?)"))?;
    Ok((img, Orientation::NoTransforms, None))
}

/// Decodes a mask or region image (`kind`) drawn on a photo shown at `width`×`height`, whose
/// stored pixels were turned by `turn` ([`crate::photo::orientation`]): as drawn on the photo as shown
/// (turned by its own EXIF orientation, if it has one); else as stored, where its own EXIF turn
/// is what keeps it from fitting; else, where the photo's stored pixels' size fits it, turned
/// with the photo.
pub(crate) fn decode_for_photo(
    path: &Path,
    width: usize,
    height: usize,
    turn: Orientation,
    kind: &str,
) -> Result<(image::DynamicImage, Fit)> {
    let size = |img: &image::DynamicImage| (img.width() as usize, img.height() as usize);
    let (shown, own) = decode_turned(path)?;
    let stored = orientation::shown_size((width, height), turn);
    if size(&shown) == (width, height) {
        // A half turn, a mirror, or a quarter turn of a square photo keeps the size: a mask
        // drawn on the stored pixels would fit as well, and nothing tells the two apart.
        let fit = if turn != Orientation::NoTransforms && stored == (width, height) {
            Fit::AsShownOrStored
        } else {
            Fit::AsShown
        };
        return Ok((shown, fit));
    }
    let mut raw = if own == Orientation::NoTransforms {
        shown
    } else {
        let raw = decode(path)?;
        if size(&raw) == (width, height) {
            return Ok((raw, Fit::OwnOrientationIgnored));
        }
        raw
    };
    if turn != Orientation::NoTransforms && size(&raw) == stored {
        raw.apply_orientation(turn);
        return Ok((raw, Fit::TurnedWithPhoto));
    }
    let its = if own == Orientation::NoTransforms {
        format!("{}×{}", raw.width(), raw.height())
    } else {
        let (w, h) = orientation::shown_size(size(&raw), own);
        format!("{w}×{h} (as its own EXIF orientation {} shows it)", own.to_exif())
    };
    let turned = if turn == Orientation::NoTransforms {
        String::new()
    } else {
        format!(
            " (as shown: its EXIF orientation {} {} its stored {}×{} pixels)",
            turn.to_exif(),
            orientation::describe(turn),
            stored.0,
            stored.1
        )
    };
    bail!(
        "{}: the {kind} is {its}, the photo {width}×{height}{turned}; they must match pixel for pixel",
        path.display()
    )
}

/// Refuses a JPEG whose last scan has no end-of-image marker after it: a file cut short, which
/// the decoder would otherwise complete with one flat colour. Inside entropy-coded data a 0xFF
/// byte is always followed by 0x00 or a restart marker, so 0xFF 0xD9 there is the real end (an
/// embedded thumbnail's end comes before the main image's scans).
fn check_jpeg_complete(path: &Path) -> Result<()> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let last = |marker: u8| bytes.windows(2).rposition(|w| w == [0xFF, marker]);
    match (last(0xDA), last(0xD9)) {
        (Some(scan), Some(end)) if end > scan => Ok(()),
        _ => bail!(
            "{}: the JPEG ends early (no end-of-image marker after its last scan): the file is truncated",
            path.display()
        ),
    }
}

/// Reads the mask of a photo shown at `width`×`height` (its stored pixels turned by `turn`,
/// `decode_for_photo`): per pixel, the soft coverage in [0, 1] (alpha where the image has an
/// alpha channel that is not all opaque, otherwise the largest channel relative to the format's
/// maximum). Any coverage above 0 is object.
pub fn load_mask(path: &Path, width: usize, height: usize, turn: Orientation) -> Result<(Vec<f32>, Fit)> {
    let what = path.display();
    let (img, fit) = match extension(path).as_str() {
        "png" | "jpg" | "jpeg" => decode_for_photo(path, width, height, turn, "mask")?,
        other => bail!("{what}: masks must be PNG or JPEG images, not .{other}"),
    };
    let has_alpha = img.color().has_alpha();
    let rgba = img.into_rgba32f();
    let alpha_used = has_alpha && rgba.pixels().any(|p| p[3] < 1.0);
    let coverage = rgba
        .pixels()
        .map(|p| if alpha_used { p[3] } else { p[0].max(p[1]).max(p[2]) }.clamp(0.0, 1.0))
        .collect();
    Ok((coverage, fit))
}

/// Checks a coverage mask: some object, some background.
pub fn check_mask(path: &Path, coverage: &[f32]) -> Result<()> {
    let object = coverage.iter().filter(|&&c| c > 0.0).count();
    if object == 0 {
        bail!("{}: the mask is empty (no non-zero pixel)", path.display());
    }
    if object == coverage.len() {
        bail!(
            "{}: the mask covers the whole photo; it must mark the object only (any non-zero pixel is object)",
            path.display()
        );
    }
    if object < MIN_OBJECT_PIXELS {
        bail!(
            "{}: the mask marks {object} pixel(s); an object needs at least {MIN_OBJECT_PIXELS} to be seen, let alone edited",
            path.display()
        );
    }
    Ok(())
}

/// The fewest object pixels a mask may mark: fewer say nothing of the object's shape or
/// material (the network would see them blown up to its whole input).
pub const MIN_OBJECT_PIXELS: usize = 64;

/// The narrowest an object may be, in photo pixels, across its bounding box.
pub const MIN_OBJECT_SIDE: usize = 4;

/// [`check_mask`] with the photo's width: also refuses an object narrower than
/// [`MIN_OBJECT_SIDE`] pixels either way (a line), whatever its length.
pub fn check_mask_shape(path: &Path, coverage: &[f32], width: usize) -> Result<()> {
    check_mask(path, coverage)?;
    let (mut x_lo, mut x_hi, mut y_lo, mut y_hi) = (usize::MAX, 0, usize::MAX, 0);
    for (k, _) in coverage.iter().enumerate().filter(|(_, c)| **c > 0.0) {
        let (x, y) = (k % width, k / width);
        (x_lo, x_hi, y_lo, y_hi) = (x_lo.min(x), x_hi.max(x), y_lo.min(y), y_hi.max(y));
    }
    let (w, h) = (x_hi + 1 - x_lo, y_hi + 1 - y_lo);
    if w.min(h) < MIN_OBJECT_SIDE {
        bail!(
            "{}: the object is {w}×{h} pixels; one at least {MIN_OBJECT_SIDE} pixels across both ways can be edited",
            path.display()
        );
    }
    Ok(())
}

/// Where the network's square input lies in the photo.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Framing {
    /// Left edge of the square crop in photo pixels (may be negative: padding).
    pub x0: f64,
    /// Top edge.
    pub y0: f64,
    /// Side of the square crop in photo pixels.
    pub side: f64,
    /// The network's input side.
    pub size: usize,
}

impl Framing {
    /// The square around the object's bounding box in which it fills [`TRAINING_FILL`].
    pub fn around(coverage: &[f32], width: usize, height: usize, size: usize) -> Self {
        let (mut x_lo, mut x_hi, mut y_lo, mut y_hi) = (usize::MAX, 0, usize::MAX, 0);
        for (k, &c) in coverage.iter().enumerate() {
            if c > 0.0 {
                let (x, y) = (k % width, k / width);
                x_lo = x_lo.min(x);
                x_hi = x_hi.max(x);
                y_lo = y_lo.min(y);
                y_hi = y_hi.max(y);
            }
        }
        if x_lo > x_hi {
            (x_lo, x_hi, y_lo, y_hi) = (0, width - 1, 0, height - 1);
        }
        let (bw, bh) = ((x_hi - x_lo + 1) as f64, (y_hi - y_lo + 1) as f64);
        let side = (bw.max(bh) / TRAINING_FILL).max(1.0);
        let (cx, cy) = (x_lo as f64 + bw / 2.0, y_lo as f64 + bh / 2.0);
        Self {
            x0: cx - side / 2.0,
            y0: cy - side / 2.0,
            side,
            size,
        }
    }

    /// Network pixel coordinates (continuous, pixel centres at k + 0.5) of a photo point.
    pub fn to_net(&self, x: f64, y: f64) -> (f64, f64) {
        let s = self.size as f64 / self.side;
        ((x - self.x0) * s, (y - self.y0) * s)
    }

    /// Area average over each network pixel of `value(photo pixel)` (pixels outside the photo
    /// count as `T::default()`): every photo pixel whose centre falls in a network pixel adds to
    /// it; a network pixel no photo pixel centre falls in (a crop smaller than the input) takes
    /// the photo pixel under its centre.
    ///
    /// Linear in the photo's pixels and the crop's side: the crop of a thin object is a square
    /// of its long side, mostly padding, so the padding is counted per row and column (the
    /// network pixel of a lattice point depends on x alone for its column and on y alone for its
    /// row), and only the photo's own pixels are visited, in the same order as before.
    pub fn area_average<const C: usize>(
        &self,
        width: usize,
        height: usize,
        value: impl Fn(usize) -> [f32; C],
    ) -> Vec<[f32; C]> {
        let n = self.size;
        let mut sum = vec![[0.0_f64; C]; n * n];
        // Every lattice point (photo pixel centre, real or padding) inside the crop.
        let (xs, ys) = (self.x0.floor() as i64, self.y0.floor() as i64);
        let (xe, ye) = ((self.x0 + self.side).ceil() as i64, (self.y0 + self.side).ceil() as i64);
        let s = n as f64 / self.side;
        // The network column of lattice column x (row of lattice row y), if inside the input.
        let cell = |t: i64, origin: f64| {
            let u = (t as f64 + 0.5 - origin) * s;
            (u >= 0.0 && u < n as f64).then_some(u as usize)
        };
        let (mut per_col, mut per_row) = (vec![0_u32; n], vec![0_u32; n]);
        for x in xs..xe {
            if let Some(u) = cell(x, self.x0) {
                per_col[u] += 1;
            }
        }
        for y in ys..ye {
            if let Some(v) = cell(y, self.y0) {
                per_row[v] += 1;
            }
        }
        let count: Vec<u32> = (0..n * n).map(|k| per_row[k / n] * per_col[k % n]).collect();
        for y in ys.max(0)..ye.min(height as i64) {
            let Some(v) = cell(y, self.y0) else { continue };
            for x in xs.max(0)..xe.min(width as i64) {
                let Some(u) = cell(x, self.x0) else { continue };
                let k = v * n + u;
                let val = value(y as usize * width + x as usize);
                for c in 0..C {
                    sum[k][c] += val[c] as f64;
                }
            }
        }
        let mut out = vec![[0.0_f32; C]; n * n];
        let scale = self.side / n as f64;
        for (k, o) in out.iter_mut().enumerate() {
            if count[k] > 0 {
                *o = sum[k].map(|s| (s / count[k] as f64) as f32);
            } else {
                let (u, v) = ((k % n) as f64 + 0.5, (k / n) as f64 + 0.5);
                let (x, y) = (self.x0 + u * scale, self.y0 + v * scale);
                if x >= 0.0 && y >= 0.0 && (x as usize) < width && (y as usize) < height {
                    *o = value(y as usize * width + x as usize);
                }
            }
        }
        out
    }
}

/// Rec. 709 luminance (the weights the network's exposure uses).
pub fn luminance(p: [f32; 3]) -> f64 {
    let w = matedit_trainer::model::LUMINANCE_WEIGHTS;
    w[0] * p[0] as f64 + w[1] * p[1] as f64 + w[2] * p[2] as f64
}

/// The framed network input of one photo.
#[derive(Clone, Debug)]
pub struct Prepared {
    /// Network input side.
    pub size: usize,
    /// Regions.
    pub regions: usize,
    /// Where the input lies in the photo.
    pub framing: Framing,
    /// What the photo's linear values were multiplied by.
    pub exposure: f64,
    /// I `[3, S, S]`, zero off the object.
    pub input: Vec<f32>,
    /// `[S, S]`, 0 or 1.
    pub mask: Vec<f32>,
    /// `[S, S]`, 0 off the object, k for region k.
    pub region_map: Vec<u8>,
}

#[cfg(test)]
impl Prepared {
    /// A test's input: an `n`×`n` photo framed one network pixel per photo pixel, one region
    /// wherever `mask` is set.
    pub(crate) fn square(n: usize, input: Vec<f32>, mask: Vec<f32>, exposure: f64) -> Prepared {
        Prepared {
            size: n,
            regions: 1,
            framing: Framing {
                x0: 0.0,
                y0: 0.0,
                side: n as f64,
                size: n,
            },
            exposure,
            region_map: mask.iter().map(|&m| m as u8).collect(),
            input,
            mask,
        }
    }
}

/// Frames a photo for a network of input side `size`: `coverage` is the soft object mask,
/// `labels` (optional) the region of every photo pixel (0: none).
pub fn prepare(p: &Photo, coverage: &[f32], labels: Option<(&[u8], usize)>, size: usize) -> Result<Prepared> {
    let framing = Framing::around(coverage, p.width, p.height, size);
    prepare_framed(p, coverage, labels, framing, None)
}

/// [`prepare`] with a given framing, and a given exposure (`None`: the one that brings the
/// object's mean luminance to [`TRAINING_MEAN_LUMINANCE`]).
pub fn prepare_framed(
    p: &Photo,
    coverage: &[f32],
    labels: Option<(&[u8], usize)>,
    framing: Framing,
    exposure: Option<f64>,
) -> Result<Prepared> {
    let size = framing.size;
    let object = framing.area_average(p.width, p.height, |k| [if coverage[k] > 0.0 { 1.0 } else { 0.0 }]);
    let mut mask: Vec<f32> = object.iter().map(|o| if o[0] > 0.5 { 1.0 } else { 0.0 }).collect();
    if !mask.iter().any(|&m| m > 0.0) {
        bail!(
            "the object covers less than half of every one of the network's {size}×{size} input pixels; it is too small (or too thin) to edit"
        );
    }
    let rgb = framing.area_average(p.width, p.height, |k| p.rgb[k]);
    let (regions, region_map) = match labels {
        None => (1, mask.iter().map(|&m| m as u8).collect::<Vec<u8>>()),
        Some((labels, count)) => {
            let mut best = vec![(0.0_f32, 0_u8); size * size];
            for r in 1..=count as u8 {
                let share = framing.area_average(p.width, p.height, |k| [if labels[k] == r { 1.0 } else { 0.0 }]);
                for (b, s) in best.iter_mut().zip(share) {
                    if s[0] > b.0 {
                        *b = (s[0], r);
                    }
                }
            }
            let map: Vec<u8> = best
                .iter()
                .zip(&mask)
                .map(|(b, &m)| if m > 0.0 { b.1 } else { 0 })
                .collect();
            (count, map)
        }
    };
    // Object pixels that no region claims are not rendered (the layer shades region 0 black).
    for (m, r) in mask.iter_mut().zip(&region_map) {
        if *r == 0 {
            *m = 0.0;
        }
    }
    let on: Vec<usize> = (0..size * size).filter(|&k| mask[k] > 0.0).collect();
    let mean = on.iter().map(|&k| luminance(rgb[k])).sum::<f64>() / on.len().max(1) as f64;
    if on.is_empty() || mean.is_nan() || mean <= 1e-12 {
        bail!("the object is black in the photo (mean luminance {mean:.3e}): nothing to edit");
    }
    let exposure = exposure.unwrap_or(TRAINING_MEAN_LUMINANCE / mean);
    let p2 = size * size;
    let mut input = vec![0.0_f32; 3 * p2];
    for &k in &on {
        for c in 0..3 {
            input[c * p2 + k] = (rgb[k][c] as f64 * exposure) as f32;
        }
    }
    Ok(Prepared {
        size,
        regions,
        framing,
        exposure,
        input,
        mask,
        region_map,
    })
}

#[cfg(test)]
mod framing_tests;
