//! The one-scene preview renderer behind `datagen render`: shape → G-buffer → Eq. 2 → images.

use crate::accel::Scene;
use crate::gbuffer::GBuffer;
use crate::shapes::{Shape, UpAxis};
use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressStyle};
use matedit_assets::envfile::{EnvSource, load_env};
use matedit_contract::io::{write_env_exr, write_exr_channels, write_png_preview};
use matedit_physics::shading::{Quality, VisibilityFn, make_shader, shade_image, shade_with};
use matedit_physics::{BrdfSpec, EnvMap};
use std::path::Path;
use std::time::Instant;

/// Environment resolution used for shading.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EnvRes {
    /// The file's own resolution.
    Full,
    /// H rows × 2H columns, area-averaged from the source.
    Rows(usize),
}

impl std::str::FromStr for EnvRes {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        if s == "full" {
            return Ok(EnvRes::Full);
        }
        let err = || format!("--env-res {s:?}: expected HxW with W = 2H (e.g. 64x128) or full");
        let (h, w) = s.split_once('x').ok_or_else(err)?;
        let (h, w): (usize, usize) = (h.parse().map_err(|_| err())?, w.parse().map_err(|_| err())?);
        if h == 0 || w != 2 * h {
            return Err(err());
        }
        Ok(EnvRes::Rows(h))
    }
}

/// Whether shading traces visibility towards each environment texel.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Shadows {
    /// No visibility (the paper's rendering layer).
    #[default]
    Off,
    /// Shadow ray per (pixel, texel) through the BVH. Skipped for the sphere, which is convex.
    On,
}

impl std::str::FromStr for Shadows {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "off" => Ok(Shadows::Off),
            "on" => Ok(Shadows::On),
            _ => Err(format!("--shadows {s:?}: expected on or off")),
        }
    }
}

/// Everything that defines one preview image.
#[derive(Clone, Debug)]
pub struct RenderOptions {
    /// `sphere` or an OBJ path.
    pub shape: String,
    /// Which axis of the mesh file points up.
    pub up: UpAxis,
    /// Object yaw about +y, degrees (applied after `up`).
    pub yaw_deg: f32,
    /// Object pitch about +x, degrees (applied after yaw; positive shows the top).
    pub pitch_deg: f32,
    /// The material.
    pub brdf: BrdfSpec,
    /// Environment: a .hdr/.exr path or `builtin:NAME`.
    pub env: String,
    /// Rotation of the environment about +y, degrees.
    pub env_rotation_deg: f64,
    /// Environment resolution for shading.
    pub env_res: EnvRes,
    /// Image side in pixels.
    pub res: usize,
    /// Shadow rays.
    pub shadows: Shadows,
    /// Eq. 2 implementation.
    pub quality: Quality,
    /// Show a progress bar on stderr.
    pub progress: bool,
    /// Ray-query backend.
    pub accel: crate::accel::Accel,
}

/// What was measured while rendering.
#[derive(Clone, Debug, Default)]
pub struct RenderStats {
    /// Triangles after dropping degenerate ones (0 for the sphere).
    pub triangles: usize,
    /// Degenerate triangles dropped at load.
    pub degenerate_dropped: usize,
    /// Names of the mesh's semantic regions (ids index this list).
    pub regions: Vec<String>,
    /// Pixels that see the object.
    pub covered_pixels: usize,
    /// Texels the shading sums over (after dropping black ones, fast path).
    pub texels: usize,
    /// Whether shadow rays were traced.
    pub shadows_traced: bool,
    /// Non-finite results replaced (0 unless the inputs were absurd).
    pub sanitized_pixels: usize,
    /// Negative environment values clamped at load.
    pub env_negatives_clamped: usize,
    /// Seconds spent loading the mesh and building the BVH.
    pub setup_s: f64,
    /// Seconds for primary visibility.
    pub gbuffer_s: f64,
    /// Seconds for shading (and shadow rays).
    pub shading_s: f64,
}

/// A rendered preview.
pub struct Rendered {
    /// Geometry buffer.
    pub gbuffer: GBuffer,
    /// Linear radiance per pixel.
    pub radiance: Vec<[f32; 3]>,
    /// The environment exactly as used (rotated and resampled).
    pub env: EnvMap,
    /// Where the environment came from.
    pub env_source: EnvSource,
    /// Measurements.
    pub stats: RenderStats,
}

/// Renders one preview.
pub fn render(opts: &RenderOptions) -> Result<Rendered> {
    if opts.res == 0 || opts.res > 16384 {
        bail!("--res {}: expected 1 to 16384 pixels", opts.res);
    }
    if !opts.env_rotation_deg.is_finite() {
        bail!("--env-rotation must be finite");
    }
    let t0 = Instant::now();
    let brdf = matedit_assets::materials::cache::resolve(&opts.brdf, &matedit_assets::materials::cache::default_dir())?;
    let (src, env_source) = load_env(&opts.env)?;
    let rows = match opts.env_res {
        EnvRes::Full => src.height(),
        EnvRes::Rows(h) => h,
    };
    let env = src.resampled(rows, opts.env_rotation_deg);
    let shape = Shape::load(&opts.shape, opts.up)?.posed(opts.yaw_deg, opts.pitch_deg);
    let scene = match &shape {
        Shape::Mesh(m) => Some(Scene::with_accel(m, opts.accel)?),
        Shape::Sphere => None,
    };
    let mut stats = RenderStats {
        env_negatives_clamped: env_source.negatives_clamped,
        ..Default::default()
    };
    if let Shape::Mesh(m) = &shape {
        stats.triangles = m.triangles.len();
        stats.degenerate_dropped = m.degenerate_dropped;
        stats.regions = m.regions.clone();
    }
    stats.setup_s = t0.elapsed().as_secs_f64();

    let t1 = Instant::now();
    let g = GBuffer::trace(&shape, scene.as_ref(), opts.res);
    stats.covered_pixels = g.covered();
    stats.gbuffer_s = t1.elapsed().as_secs_f64();

    let t2 = Instant::now();
    let shader = make_shader(&brdf, &env, opts.quality);
    stats.texels = shader.light_dirs().len();
    // The sphere is convex: no point on it can shadow another, so shadow rays would be wasted.
    let trace = opts.shadows == Shadows::On && scene.is_some();
    stats.shadows_traced = trace;
    let visibility = |p: usize, dirs: &[[f32; 3]], out: &mut [f32]| {
        if let Some(scene) = scene.as_ref() {
            g.shadow_visibility(scene, glam::Mat3::IDENTITY, p, dirs, out);
        }
    };

    // The zonal quality shades the whole image at once (with shadows, it then takes the blocked
    // light off per pixel).
    if opts.quality == Quality::Zonal {
        let vis: Option<&VisibilityFn<'_>> = if trace { Some(&visibility) } else { None };
        let (rgb, bad) = shade_with(&brdf, &env, opts.quality, &g.normal, &g.mask, vis);
        stats.sanitized_pixels = bad;
        stats.shading_s = t2.elapsed().as_secs_f64();
        return Ok(Rendered {
            gbuffer: g,
            radiance: rgb,
            env,
            env_source,
            stats,
        });
    }
    let res = opts.res;
    let band = 4;
    let bar = if opts.progress {
        ProgressBar::new(res as u64)
    } else {
        ProgressBar::hidden()
    };
    bar.set_style(
        ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} rows, {elapsed} elapsed, ETA {eta}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar.set_message("shading");
    let mut radiance = Vec::with_capacity(res * res);
    for r0 in (0..res).step_by(band) {
        let r1 = (r0 + band).min(res);
        let (a, b) = (r0 * res, r1 * res);
        let offset_vis = move |p: usize, dirs: &[[f32; 3]], out: &mut [f32]| visibility(a + p, dirs, out);
        let vis: Option<&VisibilityFn<'_>> = if trace { Some(&offset_vis) } else { None };
        let (rgb, bad) = shade_image(shader.as_ref(), &g.normal[a..b], &g.mask[a..b], vis);
        radiance.extend(rgb);
        stats.sanitized_pixels += bad;
        bar.inc((r1 - r0) as u64);
    }
    bar.finish_and_clear();
    stats.shading_s = t2.elapsed().as_secs_f64();
    Ok(Rendered {
        gbuffer: g,
        radiance,
        env,
        env_source,
        stats,
    })
}

impl Rendered {
    /// What `datagen render` reports about a render: size, coverage, environment, regions,
    /// what was dropped or clamped, and the time of each stage; one line each.
    pub fn report(&self, opts: &RenderOptions) -> String {
        use std::fmt::Write;
        let s = &self.stats;
        let mut out = String::new();
        let _ = writeln!(
            out,
            "rendered {} ({}): {}x{} px, {} covered, env {} at {}x{} ({} texels), shadows {}",
            opts.shape,
            if s.triangles > 0 {
                format!("{} triangles", s.triangles)
            } else {
                "analytic".into()
            },
            opts.res,
            opts.res,
            s.covered_pixels,
            self.env_source.name,
            self.env.height(),
            self.env.width(),
            s.texels,
            if s.shadows_traced { "traced" } else { "off" },
        );
        if s.regions.len() > 1 {
            let _ = writeln!(
                out,
                "regions: {}",
                s.regions
                    .iter()
                    .enumerate()
                    .map(|(i, r)| format!("{i}={r}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
        if s.degenerate_dropped > 0 {
            let _ = writeln!(out, "note: {} zero-area triangles dropped", s.degenerate_dropped);
        }
        if s.env_negatives_clamped > 0 {
            let _ = writeln!(
                out,
                "warning: {} negative environment values clamped to 0",
                s.env_negatives_clamped
            );
        }
        if opts.shadows == Shadows::On && !s.shadows_traced {
            let _ = writeln!(
                out,
                "note: the sphere is convex, so shadow rays were skipped (the image is unchanged)"
            );
        }
        if s.sanitized_pixels > 0 {
            let _ = writeln!(
                out,
                "warning: {} pixels overflowed f32 and were clamped",
                s.sanitized_pixels
            );
        }
        let _ = writeln!(
            out,
            "time: setup {:.3} s, visibility {:.3} s, shading {:.3} s",
            s.setup_s, s.gbuffer_s, s.shading_s
        );
        out
    }

    /// Writes the EXR (channels R, G, B, normal.X, normal.Y, normal.Z, mask, region).
    pub fn write_exr(&self, path: &Path) -> Result<()> {
        let g = &self.gbuffer;
        let rad = |c: usize| self.radiance.iter().map(|p| p[c]).collect::<Vec<f32>>();
        let nrm = |c: usize| g.normal.iter().map(|p| p[c]).collect::<Vec<f32>>();
        write_exr_channels(
            path,
            g.res,
            g.res,
            vec![
                ("R", rad(0)),
                ("G", rad(1)),
                ("B", rad(2)),
                ("normal.X", nrm(0)),
                ("normal.Y", nrm(1)),
                ("normal.Z", nrm(2)),
                ("mask", g.mask.clone()),
                ("region", g.region.iter().map(|&r| r as f32).collect()),
            ],
        )
        .with_context(|| format!("writing {}", path.display()))
    }

    /// Writes the tone-mapped preview PNG.
    pub fn write_png(&self, path: &Path, exposure: f32) -> Result<()> {
        write_png_preview(path, self.gbuffer.res, &self.radiance, &self.gbuffer.mask, exposure)
    }

    /// Writes the environment as used (after rotation and resampling).
    pub fn write_env(&self, path: &Path) -> Result<()> {
        write_env_exr(path, &self.env)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn option_strings_parse_or_explain() {
        assert_eq!("64x128".parse::<EnvRes>(), Ok(EnvRes::Rows(64)));
        assert_eq!("full".parse::<EnvRes>(), Ok(EnvRes::Full));
        assert!("64x64".parse::<EnvRes>().unwrap_err().contains("W = 2H"));
        assert!("0x0".parse::<EnvRes>().is_err());
        assert_eq!("on".parse::<Shadows>(), Ok(Shadows::On));
        assert!("yes".parse::<Shadows>().is_err());
    }

    /// Shapes that shadow themselves, rendered with real shadow rays: the zonal quality (the
    /// grid's unshadowed image minus the blocked light) within 1 % relative RMSE of the fast path
    /// with the same rays, where the shadows themselves change the image by several percent.
    #[test]
    fn zonal_renders_with_shadows_agree_with_the_fast_path() {
        let material = concat!(
            "dsbrdf:",
            env!("CARGO_MANIFEST_DIR"),
            "/../assets/materials/red_plastic.dsbrdf.json"
        );
        let opts = |shape: &str, brdf: &str, env: &str, quality, shadows| RenderOptions {
            shape: shape.into(),
            up: Default::default(),
            yaw_deg: 30.0,
            pitch_deg: 15.0,
            brdf: brdf.parse().expect("brdf spec"),
            env: env.into(),
            env_rotation_deg: 60.0,
            env_res: EnvRes::Rows(32),
            res: 64,
            shadows,
            quality,
            progress: false,
            accel: crate::accel::Accel::Obvhs,
        };
        for shape in ["procedural:chair:5", "procedural:sofa:6"] {
            for brdf in ["plastic:0.2:0.7,0.3,0.2", material] {
                for env in ["builtin:sky", "builtin:studio"] {
                    let radiance = |quality, shadows| {
                        render(&opts(shape, brdf, env, quality, shadows))
                            .expect("render")
                            .radiance
                    };
                    let fast = radiance(Quality::Fast, Shadows::On);
                    let zonal = radiance(Quality::Zonal, Shadows::On);
                    let open = radiance(Quality::Fast, Shadows::Off);
                    let rel = |a: &[[f32; 3]], b: &[[f32; 3]]| {
                        let (mut num, mut den) = (0.0, 0.0);
                        for (a, b) in a.iter().flatten().zip(b.iter().flatten()) {
                            num += (*a as f64 - *b as f64).powi(2);
                            den += (*b as f64).powi(2);
                        }
                        (num / den).sqrt()
                    };
                    let (e, shadows) = (rel(&zonal, &fast), rel(&open, &fast));
                    assert!(e < 1e-2, "{shape} {brdf} {env}: zonal vs fast with shadows {e:.2e}");
                    assert!(
                        shadows > 2e-2,
                        "{shape} {brdf} {env}: shadows change only {shadows:.2e}"
                    );
                    assert!(zonal.iter().flatten().all(|v| v.is_finite() && *v >= 0.0));
                }
            }
        }
    }
}
