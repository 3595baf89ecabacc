//! One decoded training tuple and the decoding of its two EXR files.
//!
//! The image EXR holds `R, G, B` (I), `O.R, O.G, O.B` (O), `normal.X/Y/Z`, `mask` and `region`
//! (the contract's `records::IMAGE_CHANNELS`); the `.env.exr` holds the camera-space environment as
//! `R, G, B`. Decoding is strict about the layout (missing channels, non-square images, region
//! values outside the record's regions are errors) and lenient about values: a non-finite
//! sample becomes 0 and is counted, so one bad pixel cannot poison a training step.

use matedit_physics::brdf::dsbrdf::PARAMS;
use matedit_physics::shading::shading_normal;
use std::path::{Path, PathBuf};

/// A sample file that could not be used: which file and why.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{}: {reason}", file.display())]
pub struct LoadError {
    /// The offending file (an EXR of the sample, or `dataset.json` for an unknown material).
    pub file: PathBuf,
    /// What is wrong with it.
    pub reason: String,
}

impl LoadError {
    pub(crate) fn new(file: &Path, reason: impl Into<String>) -> Self {
        Self {
            file: file.to_path_buf(),
            reason: reason.into(),
        }
    }
}

/// One training tuple of Fig. 2, decoded, channel-first.
#[derive(Clone, Debug, PartialEq)]
pub struct Sample {
    /// Unique id, `SPLIT-NNNNNNN`.
    pub id: String,
    /// Split name.
    pub split: String,
    /// Shape category.
    pub category: String,
    /// Shape id.
    pub shape_id: String,
    /// Image side H = W in pixels.
    pub size: usize,
    /// Input image I (material m), linear HDR, `[3, H, W]`.
    pub input: Vec<f32>,
    /// Target image O (material m_t), linear HDR, `[3, H, W]`.
    pub target: Vec<f32>,
    /// Camera-space normals `[3, H, W]`: unit with n_z ≥ 1e-4 on the mask (through
    /// [`shading_normal`], as the rendering layer sees them), zero on the background.
    pub normals: Vec<f32>,
    /// Object mask `[H, W]`, exactly 0 or 1.
    pub mask: Vec<f32>,
    /// Region map `[H, W]`: 0 = background, r = material region r − 1.
    pub regions: Vec<u8>,
    /// Environment height He (the width is 2He).
    pub env_height: usize,
    /// Camera-space environment `[3, He, 2He]`.
    pub env: Vec<f32>,
    /// Normalised material m per region (`dataset.json` → `materials[ID].normalised`).
    pub materials: Vec<[f32; PARAMS]>,
    /// Normalised target material m_t per region.
    pub target_materials: Vec<[f32; PARAMS]>,
    /// Material id per region.
    pub material_ids: Vec<String>,
    /// Target material id per region.
    pub target_material_ids: Vec<String>,
    /// Environment id.
    pub env_id: String,
    /// Non-finite values in the files, replaced by 0.
    pub sanitized: usize,
    /// Covered pixels whose normal cannot be shaded (zero, non-finite, or pointing straight
    /// away): the renderer shades them black, so they are taken out of the mask and regions
    /// rather than given a made-up normal.
    pub dropped: usize,
}

impl Sample {
    /// Number of material regions R.
    pub fn region_count(&self) -> usize {
        self.materials.len()
    }
}

/// The decoded image file, before it is joined with its record.
pub(crate) struct ImagePixels {
    pub size: usize,
    pub input: Vec<f32>,
    pub target: Vec<f32>,
    pub normals: Vec<f32>,
    pub mask: Vec<f32>,
    pub regions: Vec<u8>,
    pub sanitized: usize,
    pub dropped: usize,
}

/// Channels of an EXR layer by name.
type Channels = matedit_contract::io::ExrChannels;

/// The first layer of an EXR file in memory: (width, height, channels). Samples are decoded in
/// parallel one level up, so each file is decoded on its caller's thread.
fn read_layer(bytes: &[u8]) -> Result<(usize, usize, Channels), String> {
    matedit_contract::io::decode_exr_channels(bytes, false)
}

/// Takes a channel out of `ch`, replacing non-finite values by 0.
fn take(ch: &mut Channels, name: &str, sanitized: &mut usize) -> Result<Vec<f32>, String> {
    let mut v = ch
        .remove(name)
        .ok_or_else(|| format!("no {name:?} channel (has {:?})", ch.keys().collect::<Vec<_>>()))?;
    for x in &mut v {
        if !x.is_finite() {
            *x = 0.0;
            *sanitized += 1;
        }
    }
    Ok(v)
}

/// Decodes an image EXR of a sample with `region_count` regions.
pub(crate) fn decode_image(bytes: &[u8], region_count: usize) -> Result<ImagePixels, String> {
    let (w, h, mut ch) = read_layer(bytes)?;
    if w != h || w == 0 {
        return Err(format!("{w}×{h} is not a square image"));
    }
    if region_count == 0 || region_count > u8::MAX as usize {
        return Err(format!("{region_count} regions: expected 1 to {}", u8::MAX));
    }
    let mut sanitized = 0;
    let mut t = |name: &str| take(&mut ch, name, &mut sanitized);
    let (r, g, b) = (t("R")?, t("G")?, t("B")?);
    let (or, og, ob) = (t("O.R")?, t("O.G")?, t("O.B")?);
    let (nx, ny, nz) = (t("normal.X")?, t("normal.Y")?, t("normal.Z")?);
    let (mask_in, region_in) = (t("mask")?, t("region")?);
    let p = w * h;
    let mut normals = vec![0.0; 3 * p];
    let mut mask = vec![0.0; p];
    let mut regions = vec![0u8; p];
    let mut dropped = 0;
    for k in 0..p {
        if mask_in[k] <= 0.5 {
            continue;
        }
        let reg = region_in[k];
        if reg < 0.0 || reg.fract() != 0.0 || reg as usize >= region_count {
            return Err(format!(
                "pixel {k}: region {reg} is not one of the record's {region_count} regions"
            ));
        }
        let Some(n) = shading_normal([nx[k], ny[k], nz[k]]) else {
            dropped += 1;
            continue;
        };
        normals[k] = n.x as f32;
        normals[p + k] = n.y as f32;
        normals[2 * p + k] = n.z as f32;
        mask[k] = 1.0;
        regions[k] = reg as u8 + 1;
    }
    let cat = |a: Vec<f32>, b: Vec<f32>, c: Vec<f32>| [a, b, c].concat();
    Ok(ImagePixels {
        size: w,
        input: cat(r, g, b),
        target: cat(or, og, ob),
        normals,
        mask,
        regions,
        sanitized,
        dropped,
    })
}

/// Decodes an environment EXR: (He, `[3, He, 2He]`, sanitized count).
pub(crate) fn decode_env(bytes: &[u8]) -> Result<(usize, Vec<f32>, usize), String> {
    let (w, h, mut ch) = read_layer(bytes)?;
    if h == 0 || w != 2 * h {
        return Err(format!("{w}×{h}: an environment must be 2H wide"));
    }
    let mut sanitized = 0;
    let mut t = |name: &str| take(&mut ch, name, &mut sanitized);
    let env = [t("R")?, t("G")?, t("B")?].concat();
    Ok((h, env, sanitized))
}
