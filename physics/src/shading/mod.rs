//! Eq. 2 of the paper: per pixel, a sum over environment texels of
//! f(ω_i, ω_o) · L(ω_i) · max(0, n·ω_i) · dω_i, with ω_o = +z (orthographic camera).
//!
//! Two paths implement the same [`Shader`] interface:
//!
//! * [`exact::ExactShader`]: `f64`, evaluates the [`Brdf`](crate::Brdf) trait in a local frame built
//!   around each normal, Neumaier-compensated sums over every texel. Slow; the reference.
//! * [`fast::FastShader`]: `f32`, vectorised. Because ω_o is fixed, the half vector, θ_d, the
//!   Fresnel term and the DSBRDF lobe parameters depend on the texel only, so they are computed
//!   once per texel; per pixel only n·ω_i and n·h remain. Texels of zero radiance are dropped.
//!
//! * [`zonal`]: Eq. 2 without shadows as a circular convolution about the view axis,
//!   per-material kernel spectra and per-sample FFTs (the dataset factory's default); shadows are
//!   then taken off per pixel by summing only the blocked texels ([`remove_blocked_light`]). A
//!   material whose lobes the grid cannot resolve is shaded by the fast path instead
//!   ([`zonal::ZonalPlan`]).
//!
//! All apply the same [normal policy](shading_normal) and never return NaN or Inf.

pub mod exact;
pub mod fast;
pub mod zonal;

use crate::{BrdfModel, EnvMap};
use glam::DVec3;
use rayon::prelude::*;

/// Normals whose z component (n·ω_o) is below this are bent towards the viewer until
/// n·ω_o equals it (see [`shading_normal`]).
pub const MIN_FACING: f64 = 1e-4;

/// The normal the shading uses for a stored normal `n`:
///
/// * NaN, infinite or (near-)zero normals give `None`: the pixel shades to black;
/// * otherwise `n` is normalised; interpolated normals at silhouettes may face away from the
///   viewer (n·ω_o ≤ 0), which the BRDFs cannot evaluate, so a normal with n_z < [`MIN_FACING`]
///   keeps its azimuth and is tilted to n_z = [`MIN_FACING`] (grazing); one pointing straight
///   away (no azimuth) gives `None`.
pub fn shading_normal(n: [f32; 3]) -> Option<DVec3> {
    let v = DVec3::new(n[0] as f64, n[1] as f64, n[2] as f64);
    let len = v.length();
    if !len.is_finite() || len < 1e-6 {
        return None;
    }
    let v = v / len;
    if v.z >= MIN_FACING {
        return Some(v);
    }
    let xy = (v.x * v.x + v.y * v.y).sqrt();
    if xy < 1e-12 {
        return None;
    }
    let s = (1.0 - MIN_FACING * MIN_FACING).sqrt() / xy;
    Some(DVec3::new(v.x * s, v.y * s, MIN_FACING))
}

/// Which implementation of Eq. 2 to use.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Quality {
    /// `f64` reference ([`exact::ExactShader`]).
    Exact,
    /// `f32` vectorised ([`fast::FastShader`]).
    #[default]
    Fast,
    /// Convolution about the view axis ([`zonal`]): per-material kernel spectra, per-sample FFTs;
    /// with shadows, the blocked light is then taken off per pixel ([`remove_blocked_light`]).
    /// Falls back to `Fast` for lobes the grid cannot resolve, and to `Exact` for measured BRDFs.
    Zonal,
}

impl Quality {
    /// The names of the qualities, as manifests and the command line write them (the one list).
    pub const NAMES: [(&'static str, Quality); 3] = [
        ("exact", Quality::Exact),
        ("fast", Quality::Fast),
        ("zonal", Quality::Zonal),
    ];

    /// Why a quality that was accepted once is refused now.
    pub fn removed(name: &str) -> Option<&'static str> {
        // `lut` was superseded by `zonal` (faster, within its error budget everywhere).
        (name == "lut").then_some("use zonal (or fast)")
    }
}

impl std::str::FromStr for Quality {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        if let Some(&(_, q)) = Quality::NAMES.iter().find(|(n, _)| *n == s) {
            return Ok(q);
        }
        match Quality::removed(s) {
            Some(why) => Err(format!("quality {s:?} was removed: {why}")),
            None => {
                let names: Vec<&str> = Quality::NAMES.iter().map(|(n, _)| *n).collect();
                Err(format!("quality {s:?}: expected {}", names.join(", ")))
            }
        }
    }
}

/// A prepared evaluator of Eq. 2 for one material and one environment.
pub trait Shader: Send + Sync {
    /// Unit directions ω_i of the texels summed over, in the order a visibility slice uses.
    fn light_dirs(&self) -> &[[f32; 3]];

    /// Outgoing radiance for stored normal `n`. `visibility[t]` ∈ {0, 1} masks texel `t` of
    /// [`light_dirs`](Shader::light_dirs) (shadows); `None` means all visible.
    fn shade(&self, n: [f32; 3], visibility: Option<&[f32]>) -> [f32; 3];
}

/// Builds a per-pixel shader of the requested quality (`Zonal` gives its per-pixel equivalent,
/// the fast shader). Measured (tabulated) BRDFs always use the exact path.
pub fn make_shader(brdf: &BrdfModel, env: &EnvMap, quality: Quality) -> Box<dyn Shader> {
    let fast = match quality {
        Quality::Fast | Quality::Zonal => fast::FastShader::new(brdf, env),
        Quality::Exact => None,
    };
    match fast {
        Some(fast) => Box::new(fast),
        None => Box::new(exact::ExactShader::new(brdf.clone(), env)),
    }
}

/// Catmull–Rom weights of nodes i−1, i, i+1, i+2 at fraction t (they sum to 1 for every t).
pub(crate) fn catmull_rom(t: f64) -> [f64; 4] {
    let (t2, t3) = (t * t, t * t * t);
    [
        0.5 * (-t3 + 2.0 * t2 - t),
        0.5 * (3.0 * t3 - 5.0 * t2 + 2.0),
        0.5 * (-3.0 * t3 + 4.0 * t2 + t),
        0.5 * (t3 - t2),
    ]
}

/// The policy for a non-finite result (possible only for absurd inputs such as radiance near
/// `f32::MAX`): +Inf becomes `f32::MAX`, NaN and −Inf become 0. Returns 1 if anything was
/// replaced, else 0 (callers count replaced pixels).
pub(crate) fn sanitize(rgb: &mut [f32; 3]) -> usize {
    let mut bad = 0;
    for c in rgb.iter_mut() {
        if !c.is_finite() {
            bad = 1;
            *c = if c.is_nan() {
                0.0
            } else {
                f32::MAX.copysign(*c).max(0.0)
            };
        }
    }
    bad
}

/// Fills a visibility slice (aligned with [`Shader::light_dirs`]) for one pixel.
pub type VisibilityFn<'a> = dyn Fn(usize, &[[f32; 3]], &mut [f32]) + Sync + 'a;

/// Shades every pixel with `mask[p] > 0` in parallel; other pixels are 0. With `visibility`, it is
/// called per shaded pixel index to fill the texel visibility. Any non-finite result (possible
/// only for absurd inputs such as radiance near `f32::MAX`) is replaced: +Inf by `f32::MAX`,
/// NaN by 0, and counted in the returned number.
pub fn shade_image(
    shader: &dyn Shader,
    normals: &[[f32; 3]],
    mask: &[f32],
    visibility: Option<&VisibilityFn<'_>>,
) -> (Vec<[f32; 3]>, usize) {
    let dirs = shader.light_dirs();
    let out: Vec<([f32; 3], usize)> = normals
        .par_iter()
        .zip(mask.par_iter())
        .enumerate()
        .map_init(
            || vec![1.0_f32; dirs.len()],
            |vis, (p, (n, &m))| {
                if m <= 0.0 {
                    return ([0.0; 3], 0);
                }
                let v = visibility.map(|f| {
                    f(p, dirs, vis);
                    &vis[..]
                });
                let mut rgb = shader.shade(*n, v);
                let bad = sanitize(&mut rgb);
                (rgb, bad)
            },
        )
        .collect();
    let bad = out.iter().map(|o| o.1).sum();
    (out.into_iter().map(|o| o.0).collect(), bad)
}

/// Shadows added to an unshadowed image: the zonal quality with shadow rays.
///
/// Shadows break the symmetry the zonal method relies on, but all they do is remove light. So a
/// pixel's radiance is its unshadowed radiance (`unshadowed`, from the zonal grid) minus the
/// light of the texels its shadow rays find blocked, which `fast` sums over those texels only
/// (a block of eight open texels costs one test). A pixel is shaded from its open texels
/// directly instead where that touches fewer blocks, and where the blocked light exceeds half
/// the unshadowed radiance in any channel (what remained would carry more than twice the grid's
/// relative error). `fast` must be the per-pixel shader of the same material and environment.
/// Returns radiance and the number of non-finite values replaced.
pub fn remove_blocked_light(
    fast: &fast::FastShader,
    unshadowed: &[[f32; 3]],
    normals: &[[f32; 3]],
    mask: &[f32],
    visibility: &VisibilityFn<'_>,
) -> (Vec<[f32; 3]>, usize) {
    let dirs = fast.light_dirs();
    let out: Vec<([f32; 3], usize)> = normals
        .par_iter()
        .zip(mask.par_iter())
        .zip(unshadowed.par_iter())
        .enumerate()
        .map_init(
            || (vec![1.0_f32; dirs.len()], vec![0.0_f32; dirs.len()]),
            |(open, blocked), (p, ((n, &m), u))| {
                if m <= 0.0 {
                    return ([0.0; 3], 0);
                }
                visibility(p, dirs, open);
                let (open_blocks, blocked_blocks) = fast.blocks_in_front(*n, open);
                let subtracted = (blocked_blocks < open_blocks).then(|| {
                    for (b, o) in blocked.iter_mut().zip(open.iter()) {
                        *b = 1.0 - *o;
                    }
                    let lost = fast.shade(*n, Some(blocked));
                    (0..3)
                        .all(|c| 2.0 * lost[c] <= u[c])
                        .then(|| [0, 1, 2].map(|c| u[c] - lost[c]))
                });
                let mut rgb = subtracted.flatten().unwrap_or_else(|| fast.shade(*n, Some(open)));
                let bad = sanitize(&mut rgb);
                (rgb, bad)
            },
        )
        .collect();
    let bad = out.iter().map(|o| o.1).sum();
    (out.into_iter().map(|o| o.0).collect(), bad)
}

/// Shades an image with the requested quality: the zonal method for `Zonal` where it resolves the
/// material (with visibility, through [`remove_blocked_light`]), otherwise [`make_shader`] and
/// [`shade_image`]. Returns radiance and the number of non-finite values replaced.
pub fn shade_with(
    brdf: &BrdfModel,
    env: &EnvMap,
    quality: Quality,
    normals: &[[f32; 3]],
    mask: &[f32],
    visibility: Option<&VisibilityFn<'_>>,
) -> (Vec<[f32; 3]>, usize) {
    if quality == Quality::Zonal
        && let Some((unshadowed, bad)) = zonal::shade_image_once(brdf, env, normals, mask)
    {
        let fast = visibility.and_then(|v| fast::FastShader::new(brdf, env).map(|f| (v, f)));
        let Some((visibility, fast)) = fast else {
            return (unshadowed, bad);
        };
        let (rgb, bad_after) = remove_blocked_light(&fast, &unshadowed, normals, mask, visibility);
        return (rgb, bad + bad_after);
    }
    let shader = make_shader(brdf, env, quality);
    shade_image(shader.as_ref(), normals, mask, visibility)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normal_policy_handles_hard_normals() {
        assert_eq!(shading_normal([0.0, 0.0, 0.0]), None);
        assert_eq!(shading_normal([f32::NAN, 0.0, 1.0]), None);
        assert_eq!(shading_normal([f32::INFINITY, 0.0, 1.0]), None);
        assert_eq!(shading_normal([0.0, 0.0, -1.0]), None);
        assert_eq!(shading_normal([1e-9, 0.0, 0.0]), None);
        let n = shading_normal([0.0, 0.0, 3.0]).unwrap();
        assert_eq!(n, DVec3::Z);
        // Back-facing interpolated normal: azimuth kept, tilted to grazing.
        let n = shading_normal([1.0, 1.0, -0.5]).unwrap();
        assert!((n.length() - 1.0).abs() < 1e-12);
        assert!((n.z - MIN_FACING).abs() < 1e-15 && (n.x - n.y).abs() < 1e-15 && n.x > 0.0);
        // Exactly grazing.
        assert_eq!(shading_normal([0.0, 1.0, 0.0]).unwrap().z, MIN_FACING);
    }
}
