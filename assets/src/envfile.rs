//! Loading environment maps: Radiance .hdr (image crate), OpenEXR (exr crate) and the embedded
//! procedural maps.

use crate::envmaps::builtin;
use anyhow::{Context, Result, anyhow, bail};
use matedit_physics::EnvMap;
use std::path::Path;

/// Where a map came from and what loading it did.
#[derive(Clone, Debug)]
pub struct EnvSource {
    /// File path or builtin name.
    pub name: String,
    /// Negative channel values clamped to 0 (real captures have a few).
    pub negatives_clamped: usize,
}

/// Loads `spec`: a `.hdr` or `.exr` path, or `builtin:NAME` (see
/// [`builtin`](crate::envmaps::builtin)). NaN or infinite texels are an error naming
/// the file; negative values are clamped to 0 and counted.
pub fn load_env(spec: &str) -> Result<(EnvMap, EnvSource)> {
    if let Some(name) = spec.strip_prefix("builtin:") {
        let map = builtin(name)?;
        return Ok((
            map,
            EnvSource {
                name: spec.to_string(),
                negatives_clamped: 0,
            },
        ));
    }
    let path = Path::new(spec);
    let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    let (w, h, texels) = match ext.as_deref() {
        Some("hdr") => read_hdr(path)?,
        Some("exr") => read_exr_rgb(path)?,
        _ => bail!("{spec}: environment maps must be .hdr or .exr files, or builtin:NAME"),
    };
    let (map, s) = EnvMap::from_texels(w, h, texels).map_err(|e| anyhow!("{spec}: {e}"))?;
    Ok((
        map,
        EnvSource {
            name: spec.to_string(),
            negatives_clamped: s.negatives_clamped,
        },
    ))
}

/// The most pixels a `.hdr` of `bytes` bytes may claim: [`HDR_PIXELS_PER_BYTE`] per byte, and
/// at least [`HDR_PIXELS_FLOOR`].
pub const fn hdr_pixel_limit(bytes: u64) -> u64 {
    let per_byte = bytes.saturating_mul(HDR_PIXELS_PER_BYTE);
    if per_byte > HDR_PIXELS_FLOOR {
        per_byte
    } else {
        HDR_PIXELS_FLOOR
    }
}
/// Real maps hold about 0.3 pixels per byte (twelve Poly Haven 1k maps: 0.27–0.38); this is 10×
/// that. Old-style run lengths can claim millions of pixels in a few bytes, and the decoder
/// allocates the whole image before reading a row (the fuzzer's 92-byte file asked for 35 MB).
pub const HDR_PIXELS_PER_BYTE: u64 = 4;
/// Small or flat maps of up to 2²⁰ pixels (24 MB decoded) are read whatever their size.
pub const HDR_PIXELS_FLOOR: u64 = 1 << 20;

fn read_hdr(path: &Path) -> Result<(usize, usize, Vec<[f32; 3]>)> {
    use image::ImageDecoder;
    let cannot = || format!("cannot read {}", path.display());
    let bytes = std::fs::metadata(path).with_context(cannot)?.len();
    let file = std::fs::File::open(path).with_context(cannot)?;
    let decoder = image::codecs::hdr::HdrDecoder::new(std::io::BufReader::new(file)).with_context(cannot)?;
    let (w, h) = decoder.dimensions();
    let pixels = u64::from(w) * u64::from(h);
    // Every row takes at least one 4-byte pixel or run header.
    if u64::from(h) > bytes / 4 || pixels > hdr_pixel_limit(bytes) {
        bail!(
            "{}: the header claims {w}×{h} pixels, more than a {bytes}-byte Radiance file holds \
             (at most {} pixels and {} rows)",
            path.display(),
            hdr_pixel_limit(bytes),
            bytes / 4
        );
    }
    let img = image::DynamicImage::from_decoder(decoder)
        .with_context(cannot)?
        .into_rgb32f();
    let (w, h) = (img.width() as usize, img.height() as usize);
    Ok((w, h, img.pixels().map(|p| p.0).collect()))
}

fn read_exr_rgb(path: &Path) -> Result<(usize, usize, Vec<[f32; 3]>)> {
    // Through the channel reader, which refuses a header that claims more pixels than the file
    // can hold before anything is allocated for them (a 756-byte file found by the fuzzer asked
    // for 457 MB).
    let (w, h, ch) = matedit_contract::io::read_exr_channels(path)?;
    let get = |n: &str| {
        ch.get(n)
            .with_context(|| format!("{}: no {n} channel (an environment map needs R, G, B)", path.display()))
    };
    let (r, g, b) = (get("R")?, get("G")?, get("B")?);
    Ok((w, h, (0..w * h).map(|k| [r[k], g[k], b[k]]).collect()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A Radiance file of `w × h` pixels of one colour, each row its first pixel followed by
    /// old-style run-length markers (the encoding that packs the most pixels per byte).
    fn flat_old_rle(w: usize, h: usize, rgbe: [u8; 4]) -> Vec<u8> {
        let mut b = format!("#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y {h} +X {w}\n").into_bytes();
        for _ in 0..h {
            b.extend_from_slice(&rgbe);
            // Consecutive markers count in base 256: w - 1 = Σ dₖ 256ᵏ.
            let mut rest = w - 1;
            while rest > 0 {
                b.extend_from_slice(&[1, 1, 1, (rest % 256) as u8]);
                rest /= 256;
            }
        }
        b
    }

    fn scratch(test: &str) -> std::path::PathBuf {
        let d = std::env::temp_dir().join(format!("matedit-envfile-{test}-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    fn write(dir: &Path, name: &str, bytes: &[u8]) -> String {
        let p = dir.join(name);
        std::fs::write(&p, bytes).unwrap();
        p.to_string_lossy().into_owned()
    }

    #[test]
    fn a_flat_map_under_the_floor_reads_exactly() {
        let dir = scratch("flat");
        // (128, 64, 32) × 2^(129 − 136), as the image crate decodes RGBE (no half-step offset).
        let bytes = flat_old_rle(1024, 512, [128, 64, 32, 129]);
        assert!(bytes.len() < 10_000, "{} bytes", bytes.len());
        let (map, _) = load_env(&write(&dir, "flat.hdr", &bytes)).unwrap();
        assert_eq!((map.width(), map.height()), (1024, 512));
        let want = [1.0, 0.5, 0.25];
        for t in map.texels() {
            for c in 0..3 {
                assert!((t[c] - want[c]).abs() < 1e-6, "{t:?} vs {want:?}");
            }
        }
    }

    #[test]
    fn a_header_claiming_more_than_the_file_holds_is_refused_by_name() {
        let dir = scratch("claims");
        // Valid old-style run lengths, but 2^21 pixels in 21 kB, and a header alone claiming
        // 2.9 M pixels (the fuzzer's 92-byte file).
        let cases = [
            ("wide.hdr", flat_old_rle(2048, 1024, [128, 64, 32, 129])),
            (
                "claim.hdr",
                b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 11 +X 265091\n\x80\x40\x20\x81".to_vec(),
            ),
            (
                "rows.hdr",
                b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 400 +X 2\n\x80\x40\x20\x81".to_vec(),
            ),
        ];
        for (name, bytes) in cases {
            let p = write(&dir, name, &bytes);
            let e = format!("{:#}", load_env(&p).unwrap_err());
            assert!(e.contains(name) && e.contains("more than a"), "{name}: {e}");
        }
    }

    #[test]
    fn the_limit_is_ten_times_what_real_maps_hold() {
        assert_eq!(hdr_pixel_limit(0), HDR_PIXELS_FLOOR);
        assert_eq!(hdr_pixel_limit(1 << 20), 4 << 20);
        assert_eq!(hdr_pixel_limit(u64::MAX), u64::MAX);
        // A Poly Haven 1k map: 1024 × 512 in 1.5 MB.
        assert!(hdr_pixel_limit(1_500_000) > 10 * 1024 * 512);
    }
}
