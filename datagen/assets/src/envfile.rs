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

fn read_hdr(path: &Path) -> Result<(usize, usize, Vec<[f32; 3]>)> {
    let img = image::open(path)
        .with_context(|| format!("cannot read {}", path.display()))?
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
