//! What to edit to: target materials per region (any `datagen render --brdf` spec, fitted to a
//! DSBRDF where it is not one, since the rendering layer renders DSBRDFs), the regions of a
//! multi-material object, and another illumination.

use crate::photo::orientation::Fit;
use anyhow::{Context, Result, bail};
use image::metadata::Orientation;
use matedit_assets::materials::cache;
use matedit_physics::BrdfSpec;
use matedit_physics::brdf::Dsbrdf;
use std::path::Path;

/// A region's target as the report records it.
#[derive(Clone, Debug, serde::Serialize)]
pub struct RegionTarget {
    /// Region id (1-based).
    pub region: u8,
    /// The spec given.
    pub spec: String,
    /// How the DSBRDF was obtained: "dsbrdf file", "cached fit", "fitted now".
    pub source: String,
}

/// A region's resolved target.
#[derive(Clone, Debug)]
pub struct Target {
    /// The DSBRDF rendered.
    pub material: Dsbrdf,
    /// What the report says.
    pub record: RegionTarget,
}

/// Parses `--material` values: `SPEC` (every region not named) or `K=SPEC` (region K ≥ 1).
pub fn parse_material_arg(s: &str) -> Result<(Option<u8>, String), String> {
    if let Some((k, spec)) = s.split_once('=')
        && !k.is_empty()
        && k.chars().all(|c| c.is_ascii_digit())
    {
        let k: u8 = k.parse().map_err(|_| format!("{s}: region {k} is not in 1..=255"))?;
        if k == 0 {
            return Err(format!("{s}: regions are numbered from 1 (0 is the background)"));
        }
        return Ok((Some(k), spec.to_string()));
    }
    Ok((None, s.to_string()))
}

/// The DSBRDF of a spec, with how it was obtained (`matedit_assets::materials::cache::dsbrdf_of`
/// with the library's cache folder).
pub fn dsbrdf_of(spec: &str) -> Result<(Dsbrdf, String)> {
    let parsed: BrdfSpec = spec.parse().map_err(|e| anyhow::anyhow!("material {spec}: {e}"))?;
    let (material, how) =
        cache::dsbrdf_of(&parsed, &cache::default_dir()).with_context(|| format!("material {spec}"))?;
    Ok((material, how.describe().into()))
}

/// One target per region 1..=`regions`; a region with no material is an error naming it.
pub fn resolve_targets(
    args: &[(Option<u8>, String)],
    regions: usize,
    regions_file: Option<&Path>,
) -> Result<Vec<Target>> {
    if args.is_empty() {
        return Ok(Vec::new());
    }
    let default: Vec<&String> = args.iter().filter(|(k, _)| k.is_none()).map(|(_, s)| s).collect();
    if default.len() > 1 {
        bail!(
            "--material without a region is given {} times; give it once, or as K=SPEC per region",
            default.len()
        );
    }
    for (k, spec) in args {
        if let Some(k) = k
            && *k as usize > regions
        {
            let src = regions_file.map_or("the mask (one region)".to_string(), |p| p.display().to_string());
            bail!("--material {k}={spec}: {src} has {regions} region(s), no region {k}");
        }
    }
    (1..=regions as u8)
        .map(|r| {
            let spec = args
                .iter()
                .rev()
                .find(|(k, _)| *k == Some(r))
                .map(|(_, s)| s)
                .or(default.first().copied())
                .with_context(|| {
                    format!(
                        "region {r} of {} has no material: give --material {r}=SPEC or a --material for every region",
                        regions_file.map_or("the mask".to_string(), |p| p.display().to_string())
                    )
                })?;
            let (material, source) = dsbrdf_of(spec)?;
            Ok(Target {
                material,
                record: RegionTarget {
                    region: r,
                    spec: spec.clone(),
                    source,
                },
            })
        })
        .collect()
}

/// Reads a region label image (PNG, grey levels or the first channel: value k > 0 is region k)
/// of a photo shown at `width`×`height` (its stored pixels turned by `turn`,
/// `photo::decode_for_photo`). Returns the label of every photo pixel (0 off the object),
/// the number of regions (the largest label on the object; labels must run 1..=n without gaps)
/// and how the image was matched to the photo.
pub fn load_regions(
    path: &Path,
    width: usize,
    height: usize,
    turn: Orientation,
    coverage: &[f32],
) -> Result<(Vec<u8>, usize, Fit)> {
    let what = path.display();
    let (img, fit) = crate::photo::decode_for_photo(path, width, height, turn, "region image")?;
    let grey = img.to_luma8();
    let labels: Vec<u8> = grey
        .pixels()
        .zip(coverage)
        .map(|(p, &c)| if c > 0.0 { p[0] } else { 0 })
        .collect();
    let n = labels.iter().copied().max().unwrap_or(0) as usize;
    if n == 0 {
        bail!("{what}: no region on the object (every object pixel is 0)");
    }
    let mut seen = vec![false; n + 1];
    for &l in &labels {
        seen[l as usize] = true;
    }
    if let Some(gap) = (1..=n).find(|&k| !seen[k]) {
        bail!("{what}: regions must be numbered 1..={n} without gaps; region {gap} has no pixel on the object");
    }
    Ok((labels, n, fit))
}

/// Another illumination (`.hdr`, `.exr` or `builtin:NAME`), resampled to `height` rows and laid
/// out `[3, He, 2He]` as the rendering layer reads it. The map is used as given: its +z faces the
/// camera.
pub fn relight_env(spec: &str, height: usize) -> Result<Vec<f32>> {
    let (env, _) = matedit_assets::envfile::load_env(spec)?;
    let env = env.resampled(height, 0.0);
    let t = env.texels();
    let n = t.len();
    let mut out = vec![0.0_f32; 3 * n];
    for (k, p) in t.iter().enumerate() {
        for c in 0..3 {
            out[c * n + k] = p[c];
        }
    }
    Ok(out)
}
