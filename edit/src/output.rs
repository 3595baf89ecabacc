//! What `matedit edit` writes, each file atomically, into the output folder:
//!
//! | file | what |
//! |---|---|
//! | `edited.png`, `edited.exr` | the photo at its own resolution with O' in the object (PNG as the photo was stored: 8- or 16-bit sRGB, linear photos tone-mapped at the edit's exposure; EXR linear) |
//! | `relit.png`, `relit.exr` | the same with R(n', m', L_new) (`--relight`) |
//! | `input`, `i_prime`, `o_prime`, `relit_prime` `.png/.exr` | I (the framed photo the network saw), I', O', the relit render, at the network's resolution and the training exposure |
//! | `normals.exr`, `normals.png` | n' (camera space; PNG as (n + 1)/2) |
//! | `env.exr`, `env.png` | L' (camera space, linear, in the photo's linear units: `--light env.exr --light-level given` renders under it again; PNG tone-mapped) |
//! | `material.dsbrdf.json` (`material-K` per region) | m', which `datagen render --brdf dsbrdf:FILE` renders |
//! | `target.dsbrdf.json` (`target-K` per region) | m_t as rendered (a fitted DSBRDF where the spec was not one) |
//! | `sheet.png` | I, I', O', relit, n', L', and spheres of m' and m_t under L', labelled |
//! | `report.json` | every setting, the framing and exposure, timings, the files |

use super::eq6::Eq6Report;
use super::photo::Framing;
use super::photo::{Encoding, Photo};
use super::{Composite, Predicted, Prepared, light, normals, range, target};
use anyhow::{Context, Result, bail};
use matedit_contract::io::{
    SheetLabels, normal_to_u8, write_atomically, write_exr_channels, write_labelled_contact_sheet,
};
use matedit_physics::brdf::Dsbrdf;
use matedit_physics::tonemap::{srgb_encode, tonemap_u8};
use matedit_trainer::rendering_layer::{LayerInput, RenderingLayer};
use std::path::{Path, PathBuf};

/// Everything [`crate::edit`] measured and decided, for `report.json`.
#[derive(Clone, Debug, serde::Serialize)]
pub struct EditReport {
    /// The photo.
    pub photo: String,
    /// Its size.
    pub photo_size: [usize; 2],
    /// How it was stored.
    pub encoding: Encoding,
    /// How it was turned to stand as viewers show it (the edit is written so), where its EXIF
    /// said to ([`crate::photo::orientation`]).
    pub orientation: Option<crate::photo::orientation::OrientationReport>,
    /// The mask (or "alpha of the photo").
    pub mask: String,
    /// Object pixels in the photo.
    pub object_pixels: usize,
    /// The checkpoint used, its stage and network shape.
    pub checkpoint: String,
    /// Its stage.
    pub stage: String,
    /// Network input side.
    pub input_size: usize,
    /// Environment rows.
    pub env_height: usize,
    /// Where the input lies in the photo.
    pub framing: Framing,
    /// What the photo's linear values were multiplied by (object mean luminance →
    /// [`crate::photo::TRAINING_MEAN_LUMINANCE`]).
    pub exposure: f64,
    /// The target mean luminance.
    pub training_mean_luminance: f64,
    /// Per region: its id and target material spec.
    pub regions: Vec<target::RegionTarget>,
    /// The other illumination, if any.
    pub relight: Option<String>,
    /// How its level was set.
    pub relight_level: Option<crate::light::relight::RelightLevelReport>,
    /// The photo's illumination given instead of L', if any.
    pub light: Option<String>,
    /// The object's own material given instead of m', if any.
    pub input_material: Option<String>,
    /// The normal map given instead of n', if any, and where it had no normal.
    pub normals: Option<normals::NormalsReport>,
    /// What of L' was kept ([`light_estimate`]); none when a light was given.
    pub light_estimate: Option<light::estimate::LightEstimateReport>,
    /// How the light's level was set.
    pub light_level: light::background::LightLevel,
    /// How O' went back into the photo.
    pub composite: Composite,
    /// How the relit render went back, when there is one.
    pub relit_composite: Option<Composite>,
    /// How each composited image was held to the photo's range ([`range`]).
    pub range: Vec<range::RangeReport>,
    /// Eq. 6, when asked for.
    pub eq6: Option<Eq6Report>,
    /// Seconds per phase.
    pub seconds: Timings,
    /// Files written, relative to the output folder.
    pub files: Vec<String>,
}

/// Seconds per phase of an edit.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct Timings {
    /// Reading the model, photo, mask, regions and materials.
    pub load: f64,
    /// The network (n', m', L'), and the light probe the first time a loaded model needs it
    /// ([`crate::light::estimate`]).
    pub network: f64,
    /// Eq. 6, when asked for.
    pub eq6: f64,
    /// The rendering layer (I', O', relit).
    pub render: f64,
    /// Compositing at the photo's resolution.
    pub composite: f64,
    /// Writing the files.
    pub write: f64,
    /// All of it.
    pub total: f64,
}

/// Whether `name` is a file an edit writes into its output folder.
pub fn is_output_name(name: &str) -> bool {
    const STEMS: [&str; 8] = [
        "edited",
        "relit",
        "input",
        "i_prime",
        "o_prime",
        "relit_prime",
        "normals",
        "env",
    ];
    ["report.json", "sheet.png", "energy.png"].contains(&name)
        || name.ends_with(".dsbrdf.json")
        || STEMS
            .iter()
            .any(|stem| name == format!("{stem}.png") || name == format!("{stem}.exr"))
}

/// The file a material spec (`dsbrdf:PATH`, `merl:PATH`, `nbrdf:PATH`) reads, if any.
pub fn material_file(spec: &str) -> Option<PathBuf> {
    use matedit_physics::BrdfSpec;
    match spec.trim().parse::<BrdfSpec>().ok()? {
        BrdfSpec::Dsbrdf(p) | BrdfSpec::Merl(p) | BrdfSpec::Nbrdf(p) => Some(p),
        _ => None,
    }
}

/// The file an environment spec (a path, or `builtin:NAME`) reads, if any.
pub fn env_file(spec: &str) -> Option<PathBuf> {
    (!spec.starts_with("builtin:")).then(|| PathBuf::from(spec))
}

/// Refuses an output folder in which an output would replace one of the inputs (any file of
/// the edit: photos, masks, region and normal maps, light probes, material files), whether
/// it is named as given or through a link.
pub fn refuse_overwriting_inputs(out: &Path, inputs: &[Option<&Path>]) -> Result<()> {
    let out_dir = std::fs::canonicalize(out).ok();
    for input in inputs.iter().flatten() {
        let (Some(dir), Ok(file)) = (&out_dir, std::fs::canonicalize(input)) else {
            continue;
        };
        let name = file.file_name().and_then(|n| n.to_str()).unwrap_or_default();
        if file.parent() == Some(dir.as_path()) && is_output_name(name) {
            bail!(
                "{}: the output folder {} would overwrite this input (an edit writes {name} there); choose another --out",
                input.display(),
                out.display()
            );
        }
    }
    Ok(())
}

fn planar(img: &[f32], c: usize, hw: usize) -> Vec<f32> {
    img[c * hw..(c + 1) * hw].to_vec()
}

fn write_png_rgb(path: &Path, w: usize, h: usize, px: impl Fn(usize) -> [u8; 3]) -> Result<()> {
    let mut img = image::RgbImage::new(w as u32, h as u32);
    for (k, p) in img.pixels_mut().enumerate() {
        *p = image::Rgb(px(k));
    }
    write_atomically(path, |tmp| {
        img.save_with_format(tmp, image::ImageFormat::Png)
            .with_context(|| format!("cannot write {}", path.display()))
    })
}

/// Writes a photo-sized linear image (`image`: its stem and pixels) as PNG (in the photo's
/// encoding, at the edit's `exposure` where the photo is linear) and EXR.
fn write_photo(
    out: &Path,
    image: &(&str, Vec<[f32; 3]>),
    p: &Photo,
    exposure: f64,
    files: &mut Vec<String>,
) -> Result<()> {
    let (stem, rgb) = (image.0, &image.1);
    let (w, h) = (p.width, p.height);
    let png = out.join(format!("{stem}.png"));
    match p.encoding {
        Encoding::Srgb16 => {
            let mut img = image::ImageBuffer::<image::Rgb<u16>, Vec<u16>>::new(w as u32, h as u32);
            for (k, px) in img.pixels_mut().enumerate() {
                *px = image::Rgb(rgb[k].map(|v| {
                    let v = if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) };
                    (srgb_encode(v) * 65535.0).round() as u16
                }));
            }
            write_atomically(&png, |tmp| {
                img.save_with_format(tmp, image::ImageFormat::Png)
                    .with_context(|| format!("cannot write {}", png.display()))
            })?;
        }
        Encoding::Srgb8 => write_png_rgb(&png, w, h, |k| rgb[k].map(|v| tonemap_u8(v, 1.0)))?,
        Encoding::Linear => write_png_rgb(&png, w, h, |k| rgb[k].map(|v| tonemap_u8(v, exposure as f32)))?,
    }
    files.push(format!("{stem}.png"));
    let ch = |c: usize| rgb.iter().map(|p| p[c]).collect::<Vec<f32>>();
    write_exr_channels(
        &out.join(format!("{stem}.exr")),
        w,
        h,
        vec![("R", ch(0)), ("G", ch(1)), ("B", ch(2))],
    )?;
    files.push(format!("{stem}.exr"));
    Ok(())
}

/// Writes a network-resolution `[3, S, S]` image as EXR and PNG (black off the object).
fn write_net_image(out: &Path, stem: &str, img: &[f32], prep: &Prepared, files: &mut Vec<String>) -> Result<()> {
    let (n, mask) = (prep.size, &prep.mask);
    let hw = n * n;
    write_exr_channels(
        &out.join(format!("{stem}.exr")),
        n,
        n,
        vec![
            ("R", planar(img, 0, hw)),
            ("G", planar(img, 1, hw)),
            ("B", planar(img, 2, hw)),
        ],
    )?;
    write_png_rgb(&out.join(format!("{stem}.png")), n, n, |k| {
        if mask[k] > 0.0 {
            [0, 1, 2].map(|c| tonemap_u8(img[c * hw + k], 1.0))
        } else {
            [0; 3]
        }
    })?;
    files.extend([format!("{stem}.exr"), format!("{stem}.png")]);
    Ok(())
}

/// A sphere of each material under `env`, `[3, S, S]` each, for the sheet.
pub(crate) fn spheres(
    materials: &[&[f32]],
    env: &[f32],
    env_height: usize,
    n: usize,
) -> Result<Vec<(Vec<f32>, Vec<f32>)>> {
    let (normals, mask) = matedit_physics::camera::unit_sphere_normals(n);
    let hw = n * n;
    let mut planar_n = vec![0.0_f32; 3 * hw];
    for (k, v) in normals.iter().enumerate() {
        for c in 0..3 {
            planar_n[c * hw + k] = v[c];
        }
    }
    let region: Vec<u8> = mask.iter().map(|&m| u8::from(m > 0.0)).collect();
    let layer = RenderingLayer::new(env_height);
    materials
        .iter()
        .map(|m| {
            let img = layer.forward(&LayerInput::one_region(n, &planar_n, &region, m, env))?;
            Ok((img, mask.clone()))
        })
        .collect()
}

/// A hidden folder on the output folder's file system that an edit's files are written into,
/// then moved into the output folder together ([`Staging::publish`]); dropped unpublished (an
/// error on the way), it is removed with what it holds.
///
/// Where `out` exists, the stage is inside it (`out/.partial-…`): `out` may be a mount point or
/// on another file system than its parent, and a move within one file system is a rename.
/// Otherwise the stage is beside it and becomes `out` in one rename. A move that still crosses
/// file systems is a copy and a rename within `out` ([`move_file`]).
pub struct Staging {
    dir: PathBuf,
    out: PathBuf,
    inside: bool,
    published: bool,
}

impl Staging {
    /// Makes the staging folder for `out`.
    pub fn new(out: &Path) -> Result<Self> {
        let name = out
            .file_name()
            .with_context(|| format!("{}: the output folder needs a name", out.display()))?;
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos());
        let tag = format!("partial-{}-{nanos}", std::process::id());
        let inside = out.is_dir();
        let dir = if inside {
            out.join(format!(".{tag}"))
        } else {
            if out.exists() {
                bail!("{}: exists and is not a folder; choose another --out", out.display());
            }
            let parent = match out.parent() {
                Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
                _ => PathBuf::from("."),
            };
            std::fs::create_dir_all(&parent).with_context(|| format!("cannot create {}", parent.display()))?;
            parent.join(format!(".{}.{tag}", name.to_string_lossy()))
        };
        std::fs::create_dir(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
        Ok(Self {
            dir,
            out: out.to_path_buf(),
            inside,
            published: false,
        })
    }

    /// Where to write.
    pub fn path(&self) -> &Path {
        &self.dir
    }

    /// Moves every file into the output folder: the folder itself when it did not exist (one
    /// rename), else file by file with `report.json` last, so that a report always describes
    /// files that are there.
    pub fn publish(mut self) -> Result<()> {
        if !self.inside && !self.out.exists() && std::fs::rename(&self.dir, &self.out).is_ok() {
            self.published = true;
            return Ok(());
        }
        std::fs::create_dir_all(&self.out).with_context(|| format!("cannot create {}", self.out.display()))?;
        let mut names: Vec<_> = std::fs::read_dir(&self.dir)
            .with_context(|| format!("cannot read {}", self.dir.display()))?
            .filter_map(|e| e.ok().map(|e| e.file_name()))
            .collect();
        names.sort_by_key(|n| n == "report.json");
        for n in names {
            move_file(&self.dir.join(&n), &self.out.join(&n))?;
        }
        Ok(())
    }
}

/// Moves a file: a rename, or where `from` and `to` are on different file systems a copy to a
/// hidden name beside `to` and a rename onto it, so that `to` is never seen half written.
pub fn move_file(from: &Path, to: &Path) -> Result<()> {
    let err = match std::fs::rename(from, to) {
        Ok(()) => return Ok(()),
        Err(e) => e,
    };
    if err.kind() != std::io::ErrorKind::CrossesDevices {
        return Err(err).with_context(|| format!("cannot move {} to {}", from.display(), to.display()));
    }
    let name = to
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = to.with_file_name(format!(".{name}.copy-{}", std::process::id()));
    let copied = std::fs::copy(from, &tmp)
        .and_then(|_| std::fs::rename(&tmp, to))
        .with_context(|| format!("cannot copy {} to {}", from.display(), to.display()));
    if copied.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    copied?;
    let _ = std::fs::remove_file(from);
    Ok(())
}

impl Drop for Staging {
    fn drop(&mut self) {
        // Published file by file, the stage is empty then; unpublished, it holds the edit's
        // files. Either way it goes.
        if !self.published {
            let _ = std::fs::remove_dir_all(&self.dir);
        }
    }
}

/// The edited photos, for [`write_all`]: each composite (by output name) at the size of the
/// photo it was composited into, which also gives their encoding.
#[derive(Clone, Copy)]
pub struct EditedPhotos<'a> {
    /// The photo.
    pub photo: &'a Photo,
    /// The composites, by output name ("edited", "relit").
    pub composites: &'a [(&'a str, Vec<[f32; 3]>)],
}

/// Writes every output of an edit but the report; returns the file names.
pub fn write_all(
    out: &Path,
    edited: EditedPhotos,
    prep: &Prepared,
    pred: &Predicted,
    targets: &[Dsbrdf],
) -> Result<Vec<String>> {
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let mut files = Vec::new();
    for image in edited.composites {
        write_photo(out, image, edited.photo, prep.exposure, &mut files)?;
    }
    write_net_image(out, "input", &prep.input, prep, &mut files)?;
    write_net_image(out, "i_prime", &pred.i_prime, prep, &mut files)?;
    if let Some(o) = &pred.o_prime {
        write_net_image(out, "o_prime", o, prep, &mut files)?;
    }
    if let Some(r) = &pred.relit {
        write_net_image(out, "relit_prime", r, prep, &mut files)?;
    }
    write_normals(out, prep, pred)?;
    files.extend(["normals.exr".to_string(), "normals.png".to_string()]);
    write_env(out, prep, pred)?;
    files.extend(["env.exr".to_string(), "env.png".to_string()]);
    write_materials(out, prep, pred, targets, &mut files)?;
    write_sheet(out, prep, pred, targets)?;
    files.push("sheet.png".into());
    Ok(files)
}

/// n' as `normals.exr` (camera space) and `normals.png` ((n + 1) / 2).
fn write_normals(out: &Path, prep: &Prepared, pred: &Predicted) -> Result<()> {
    let (n, hw) = (prep.size, prep.size * prep.size);
    let nrm = &pred.normals;
    write_exr_channels(
        &out.join("normals.exr"),
        n,
        n,
        vec![
            ("X", planar(nrm, 0, hw)),
            ("Y", planar(nrm, 1, hw)),
            ("Z", planar(nrm, 2, hw)),
        ],
    )?;
    write_png_rgb(&out.join("normals.png"), n, n, |k| {
        if prep.mask[k] > 0.0 {
            [0, 1, 2].map(|c| normal_to_u8(nrm[c * hw + k]))
        } else {
            [0; 3]
        }
    })?;
    Ok(())
}

/// L' as `env.exr` (in the photo's linear units) and `env.png` (tone-mapped).
fn write_env(out: &Path, prep: &Prepared, pred: &Predicted) -> Result<()> {
    let (he, we) = (pred.env_height, 2 * pred.env_height);
    let ehw = he * we;
    // L' renders in the network's units (the photo's linear values times the exposure); written
    // in the photo's, it is what `--light` reads, so an edit's light can be given again as it is.
    let env = super::light::light_in_photo_units(&pred.env, prep.exposure)?;
    write_exr_channels(
        &out.join("env.exr"),
        we,
        he,
        vec![
            ("R", planar(&env, 0, ehw)),
            ("G", planar(&env, 1, ehw)),
            ("B", planar(&env, 2, ehw)),
        ],
    )?;
    let all = vec![1.0_f32; ehw];
    let env_exposure = matedit_trainer::metrics::metric_exposure(&pred.env, &all);
    write_png_rgb(&out.join("env.png"), we, he, |k| {
        [0, 1, 2].map(|c| tonemap_u8(pred.env[c * ehw + k], env_exposure))
    })?;
    Ok(())
}

/// m' per region and m_t per target as DSBRDF files.
fn write_materials(
    out: &Path,
    prep: &Prepared,
    pred: &Predicted,
    targets: &[Dsbrdf],
    files: &mut Vec<String>,
) -> Result<()> {
    let regions = prep.regions;
    for r in 0..regions {
        let m: Vec<f64> = pred.materials[r * 108..(r + 1) * 108]
            .iter()
            .map(|&v| v as f64)
            .collect();
        let d = Dsbrdf::from_normalised(&m).context("the predicted material")?;
        let name = if regions == 1 {
            "material.dsbrdf.json".to_string()
        } else {
            format!("material-{}.dsbrdf.json", r + 1)
        };
        write_atomically(&out.join(&name), |tmp| {
            std::fs::write(tmp, d.to_json()).with_context(|| format!("cannot write {}", out.join(&name).display()))
        })?;
        files.push(name);
    }
    for (k, t) in targets.iter().enumerate() {
        let name = if targets.len() == 1 {
            "target.dsbrdf.json".to_string()
        } else {
            format!("target-{}.dsbrdf.json", k + 1)
        };
        write_atomically(&out.join(&name), |tmp| {
            std::fs::write(tmp, t.to_json()).with_context(|| format!("cannot write {}", out.join(&name).display()))
        })?;
        files.push(name);
    }
    Ok(())
}

/// Tile side of the sheet.
const TILE: usize = 128;

fn write_sheet(out: &Path, prep: &Prepared, pred: &Predicted, targets: &[Dsbrdf]) -> Result<()> {
    let n = prep.size;
    let hw = n * n;
    let scale_tile = |h: usize, w: usize, px: &dyn Fn(usize) -> [u8; 4]| {
        matedit_trainer::eval::sheet::letterboxed(TILE, h, w, [0, 0, 0, 255], px)
    };
    let image_tile = |img: &[f32], mask: &[f32]| {
        scale_tile(n, n, &|k| {
            if mask[k] > 0.0 {
                let c = |ch: usize| tonemap_u8(img[ch * hw + k], 1.0);
                [c(0), c(1), c(2), 255]
            } else {
                [0, 0, 0, 255]
            }
        })
    };
    let mut columns: Vec<&str> = vec!["I (photo)", "I'"];
    let mut tiles = vec![
        image_tile(&prep.input, &prep.mask),
        image_tile(&pred.i_prime, &prep.mask),
    ];
    if let Some(o) = &pred.o_prime {
        columns.push("O' (edit)");
        tiles.push(image_tile(o, &prep.mask));
    }
    if let Some(r) = &pred.relit {
        columns.push("relit");
        tiles.push(image_tile(r, &prep.mask));
    }
    columns.push("n'");
    tiles.push(scale_tile(n, n, &|k| {
        if prep.mask[k] > 0.0 {
            let c = |ch: usize| normal_to_u8(pred.normals[ch * hw + k]);
            [c(0), c(1), c(2), 255]
        } else {
            [0, 0, 0, 255]
        }
    }));
    let (he, we) = (pred.env_height, 2 * pred.env_height);
    let ehw = he * we;
    let all = vec![1.0_f32; ehw];
    let e = matedit_trainer::metrics::metric_exposure(&pred.env, &all);
    columns.push("L'");
    tiles.push(scale_tile(he, we, &|k| {
        let c = |ch: usize| tonemap_u8(pred.env[ch * ehw + k], e);
        [c(0), c(1), c(2), 255]
    }));
    let m_pred = &pred.materials[..108];
    let target: Option<Vec<f32>> = targets.first().map(|t| t.to_normalised().map(|v| v as f32).to_vec());
    let mut mats: Vec<&[f32]> = vec![m_pred];
    if let Some(t) = &target {
        mats.push(t);
    }
    // Previews only: at most 64² (a 256² sphere costs the layer seconds).
    let ns = n.min(64);
    let sph = spheres(&mats, &pred.env, pred.env_height, ns)?;
    let sphere_tile = |img: &[f32], mask: &[f32]| {
        let e = matedit_trainer::metrics::metric_exposure(img, mask);
        scale_tile(ns, ns, &|k| {
            if mask[k] > 0.0 {
                let c = |ch: usize| tonemap_u8(img[ch * ns * ns + k], e);
                [c(0), c(1), c(2), 255]
            } else {
                [0, 0, 0, 255]
            }
        })
    };
    columns.push("m' under L'");
    tiles.push(sphere_tile(&sph[0].0, &sph[0].1));
    if sph.len() > 1 {
        columns.push("m_t under L'");
        tiles.push(sphere_tile(&sph[1].0, &sph[1].1));
    }
    let labels = SheetLabels {
        columns: &columns,
        rows: &[],
    };
    write_labelled_contact_sheet(&out.join("sheet.png"), &tiles, TILE, TILE, columns.len(), &labels)
}

/// Writes `report.json`.
pub fn write_report(out: &Path, report: &EditReport) -> Result<()> {
    let p = out.join("report.json");
    let text = serde_json::to_string_pretty(report)?;
    write_atomically(&p, |tmp| {
        std::fs::write(tmp, text).with_context(|| format!("cannot write {}", p.display()))
    })
}

/// `energy.png`: E after every L-BFGS iteration of Eq. 6 (log scale), coloured by the property
/// that moved.
pub fn energy_plot(path: &Path, eq6: &super::Eq6Report) -> Result<()> {
    use plotters::prelude::*;
    let values: Vec<f64> = eq6.steps.iter().map(|s| s.energy.max(1e-30)).collect();
    if values.is_empty() {
        return Ok(());
    }
    let (lo, hi) = values
        .iter()
        .fold((f64::INFINITY, 0.0_f64), |(a, b), &v| (a.min(v), b.max(v)));
    let (lo, hi) = (lo * 0.9, (hi * 1.1).max(lo * 1.01));
    let e = |e: DrawingAreaErrorKind<_>| anyhow::anyhow!("{}: {e}", path.display());
    matedit_trainer::train::plot::embedded_font()?;
    let tmp = path.with_extension("tmp.png");
    {
        let root = BitMapBackend::new(&tmp, (800, 450)).into_drawing_area();
        root.fill(&WHITE).map_err(e)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(
                "Eq. 6: E = |R(n, m, L) - I|^2 + a|n - n'|^2 + b|L - L'|^2",
                ("sans-serif", 18),
            )
            .margin(12)
            .x_label_area_size(36)
            .y_label_area_size(70)
            .build_cartesian_2d(0..values.len(), (lo..hi).log_scale())
            .map_err(e)?;
        chart
            .configure_mesh()
            .x_desc(if eq6.stride > 1 {
                format!(
                    "L-BFGS iteration (all runs in order; hollow: every k-th pixel, k = {}, scaled)",
                    eq6.stride
                )
            } else {
                "L-BFGS iteration (all runs in order)".to_string()
            })
            .y_desc("E")
            .draw()
            .map_err(e)?;
        use matedit_trainer::post_optimisation::Property;
        for (prop, colour, name) in [
            (Property::Normals, RGBColor(31, 119, 180), "normals"),
            (Property::Material, RGBColor(255, 127, 14), "material"),
            (Property::Light, RGBColor(44, 160, 44), "light"),
        ] {
            // Filled: E of the whole image; hollow: the coarse alternation's estimate of it.
            let pts: Vec<(usize, f64, bool)> = eq6
                .steps
                .iter()
                .enumerate()
                .filter(|(_, s)| s.property == prop)
                .map(|(i, s)| (i, s.energy.max(1e-30), s.stride == 1))
                .collect();
            chart
                .draw_series(pts.iter().map(|&(i, v, whole)| {
                    let style = if whole { colour.filled() } else { colour.stroke_width(1) };
                    Circle::new((i, v), 3, style)
                }))
                .map_err(e)?
                .label(name)
                .legend(move |(x, y)| Circle::new((x, y), 4, colour.filled()));
        }
        chart
            .draw_series(LineSeries::new(values.iter().enumerate().map(|(i, &v)| (i, v)), &BLACK))
            .map_err(e)?;
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(e)?;
        root.present().map_err(e)?;
    }
    std::fs::rename(&tmp, path).with_context(|| format!("cannot move {} to {}", tmp.display(), path.display()))
}

#[cfg(test)]
#[path = "output_tests.rs"]
mod tests;
