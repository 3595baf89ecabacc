//! What a request may upload, checked by its content: the image format is read from the bytes
//! (never from the name), the pixel count from the header before anything is decoded, and then
//! every image is decoded and the mask checked by the same reader as `matedit edit` before the
//! job is queued. Nothing a request names reaches the file system: uploads are saved under the
//! job's folder as `in/ROLE.EXT`, with ROLE and EXT chosen here.

use anyhow::{Context, Result, bail};
use std::io::Cursor;
use std::path::{Path, PathBuf};

/// Image formats a photo may come in, told by their first bytes.
pub fn sniff(bytes: &[u8]) -> Option<&'static str> {
    if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
        Some("png")
    } else if bytes.starts_with(&[0xff, 0xd8, 0xff]) {
        Some("jpg")
    } else if bytes.starts_with(&[0x76, 0x2f, 0x31, 0x01]) {
        Some("exr")
    } else if bytes.starts_with(b"#?RADIANCE") || bytes.starts_with(b"#?RGBE") {
        Some("hdr")
    } else {
        None
    }
}

/// Peak memory of an edit per photo pixel, measured: a 25-megapixel photo edited by `matedit
/// edit` peaks at 1.23 GB resident (49 bytes a pixel; docs/PERFORMANCE.md), rounded up.
pub const EDIT_BYTES_PER_PIXEL: u64 = 56;

/// What an edit of these uploads will hold in memory at most, in MiB: the photos' pixels (read
/// from their headers) at [`EDIT_BYTES_PER_PIXEL`], plus the model and the rendering layer's
/// working set. A photo over `max_pixels` (or unreadable) counts nothing: the pixel check
/// refuses it by its own message.
pub fn memory_mb<'a>(photos: impl IntoIterator<Item = &'a [u8]>, max_pixels: u64) -> u64 {
    let pixels: u64 = photos
        .into_iter()
        .filter_map(|b| sniff(b).and_then(|f| dimensions(b, f).ok()))
        .map(|(w, h)| w.saturating_mul(h))
        .filter(|&p| p <= max_pixels)
        .fold(0, u64::saturating_add);
    pixels.saturating_mul(EDIT_BYTES_PER_PIXEL).div_ceil(1 << 20) + 64
}

/// The most channels an uploaded EXR photo may have (each is decoded in full).
pub const MAX_EXR_CHANNELS: usize = 16;

/// Width and height from an image's header.
pub fn dimensions(bytes: &[u8], format: &str) -> Result<(u64, u64)> {
    if format == "exr" {
        let meta = exr::meta::MetaData::read_from_buffered(Cursor::new(bytes), false)
            .map_err(|e| anyhow::anyhow!("not a readable EXR image ({e})"))?;
        let [h] = meta.headers.as_slice() else {
            bail!("an EXR photo must have one layer, this one has {}", meta.headers.len());
        };
        // Every channel is decoded: a photo needs R, G, B (and A); a few more are tolerated.
        if h.channels.list.len() > MAX_EXR_CHANNELS {
            bail!(
                "an EXR photo with {} channels (at most {MAX_EXR_CHANNELS} are read: R, G, B, A)",
                h.channels.list.len()
            );
        }
        let s = h.layer_size;
        return Ok((s.0 as u64, s.1 as u64));
    }
    let (w, h) = image::ImageReader::new(Cursor::new(bytes))
        .with_guessed_format()
        .context("not a readable image")?
        .into_dimensions()
        .context("not a readable image")?;
    Ok((w as u64, h as u64))
}

/// One uploaded file.
#[derive(Clone, Debug)]
pub struct Part {
    /// The name the user's browser gave (for messages only).
    pub name: String,
    /// Its bytes.
    pub bytes: axum::body::Bytes,
}

/// Checks an uploaded image (`role` says what it is for: photo, mask) and saves it as
/// `DIR/in/ROLE.EXT`; masks must be PNG or JPEG. Returns the path and how messages name it.
pub fn save(dir: &Path, role: &str, part: &Part, max_pixels: u64) -> Result<(PathBuf, String)> {
    let shown = format!("{role} “{}”", display_name(&part.name));
    if part.bytes.is_empty() {
        bail!("{shown}: the file is empty");
    }
    let Some(ext) = sniff(&part.bytes) else {
        bail!("{shown}: not a PNG, JPEG, EXR or HDR image (the content decides, not the name)");
    };
    if role.ends_with("mask") && !matches!(ext, "png" | "jpg") {
        bail!(
            "{shown}: masks must be PNG or JPEG images, this is {}",
            ext.to_uppercase()
        );
    }
    if role == "normals" && !matches!(ext, "png" | "exr") {
        bail!(
            "{shown}: normal maps must be EXR or PNG images, this is {}",
            ext.to_uppercase()
        );
    }
    let (w, h) = dimensions(&part.bytes, ext).with_context(|| shown.clone())?;
    if w == 0 || h == 0 {
        bail!("{shown}: the image is empty ({w}×{h})");
    }
    if w * h > max_pixels {
        bail!(
            "{shown}: {w}×{h} is {:.1} megapixels, more than this server's limit of {:.1}; scale it down first",
            (w * h) as f64 / 1e6,
            max_pixels as f64 / 1e6
        );
    }
    let path = input_path(dir, role, ext);
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).with_context(|| format!("cannot create {}", parent.display()))?;
    }
    std::fs::write(&path, &part.bytes).with_context(|| format!("cannot save the {role}"))?;
    Ok((path, shown))
}

/// `text` with every saved upload's path replaced by the name messages give it (`names`:
/// `(saved path, shown name)`), so no server path reaches the user.
pub fn name_uploads(text: &str, names: &[(PathBuf, String)]) -> String {
    names.iter().fold(text.to_string(), |t, (path, name)| {
        t.replace(&path.display().to_string(), name)
    })
}

/// A file name as a message may show it: its last component, printable, at most 60 characters.
pub fn display_name(name: &str) -> String {
    let last = name.rsplit(['/', '\\']).next().unwrap_or("");
    let clean: String = last.chars().filter(|c| !c.is_control()).take(60).collect();
    if clean.is_empty() { "upload".into() } else { clean }
}

/// Material specs a request may name: library materials and the parametric models. File specs
/// (`dsbrdf:`, `merl:`) would let a request read the server's files.
pub fn check_material(spec: &str) -> Result<()> {
    let spec = spec.trim();
    if let Some(name) = spec.strip_prefix("library:") {
        matedit_assets::materials::library::find(name)
            .map_err(|_| anyhow::anyhow!("material “{}”: no such library material", display_name(name)))?;
        return Ok(());
    }
    if ["lambert:", "ggx:", "plastic:"].iter().any(|p| spec.starts_with(p)) {
        let parsed: matedit_physics::BrdfSpec = spec
            .parse()
            .map_err(|e| anyhow::anyhow!("material “{}”: {e}", display_name(spec)))?;
        parsed
            .build()
            .map_err(|e| anyhow::anyhow!("material “{}”: {e}", display_name(spec)))?;
        return Ok(());
    }
    bail!(
        "material “{}”: pick a library material (library:NAME) or a parametric one (lambert:R,G,B, ggx:ALPHA:F0, plastic:ALPHA:R,G,B); file specs are not accepted over the web",
        display_name(spec)
    )
}

/// Paths of a job's inputs: `DIR/in/ROLE.EXT`.
fn input_path(dir: &Path, role: &str, ext: &str) -> PathBuf {
    dir.join("in").join(format!("{role}.{ext}"))
}
