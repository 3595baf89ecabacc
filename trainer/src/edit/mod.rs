//! Material editing of a photo (Sec. 3.4 and Fig. 2 applied to a real picture): the network
//! predicts normals n', a DSBRDF m' per region and the illumination L' from the framed photo
//! ([`photo`]); the rendering layer renders I' = R(n', m', L') and the edit O' = R(n', m_t, L')
//! with the target material m_t (or R(n', m', L_new) under another illumination, Fig. 4); O'
//! goes back into the photo at its original resolution inside the mask ([`composite`]).
//!
//! [`prepare`] and [`predict_and_render`] work in memory; [`edit`] adds reading the inputs and
//! writing every output ([`output`]) after all of them succeeded, so a bad input writes nothing.

pub mod composite;
pub mod output;
pub mod photo;
pub mod target;
#[cfg(test)]
mod tests;

use crate::render::op::host;
use crate::render::{Batch, RenderingLayer};
use crate::train::batch::HostBatch;
use crate::train::checkpoint;
use crate::train::network::Net;
use crate::train::step::predict;
use anyhow::{Context, Result, bail};
use burn::tensor::Device;
use matedit_physics::brdf::Dsbrdf;
use matedit_physics::brdf::dsbrdf::PARAMS;
use photo::{Framing, Photo, TRAINING_MEAN_LUMINANCE, luminance};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// How the re-rendered object goes back into the photo.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Composite {
    /// The paper's: the object's pixels are O' (upsampled from the network's resolution).
    #[default]
    Render,
    /// The photo times O'/I': the edit's change of shading and colour, with the photo's own
    /// detail kept at full resolution (not in the paper).
    Ratio,
}

/// What to edit, as the command line gives it.
#[derive(Clone, Debug, Default)]
pub struct EditRequest {
    /// The photo.
    pub photo: PathBuf,
    /// The mask image (default: the photo's alpha channel).
    pub mask: Option<PathBuf>,
    /// A label image: value k > 0 marks region k (Sec. 3.4's multi-material objects).
    pub regions: Option<PathBuf>,
    /// Target materials: `(None, SPEC)` for every region, `(Some(k), SPEC)` for region k.
    pub materials: Vec<(Option<u8>, String)>,
    /// Another illumination for the predicted material (an environment spec, Fig. 4).
    pub relight: Option<String>,
    /// How to composite.
    pub composite: Composite,
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

/// Frames a photo for a network of input side `size`: `coverage` is the soft object mask,
/// `labels` (optional) the region of every photo pixel (0: none).
pub fn prepare(p: &Photo, coverage: &[f32], labels: Option<(&[u8], usize)>, size: usize) -> Result<Prepared> {
    let framing = Framing::around(coverage, p.width, p.height, size);
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
    let exposure = TRAINING_MEAN_LUMINANCE / mean;
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

/// The network's predictions and the renders made from them, at the network's resolution.
#[derive(Clone, Debug)]
pub struct Predicted {
    /// n' `[3, S, S]`.
    pub normals: Vec<f32>,
    /// m' `[R, 108]`, normalised.
    pub materials: Vec<f32>,
    /// L' `[3, He, 2He]`.
    pub env: Vec<f32>,
    /// Environment rows.
    pub env_height: usize,
    /// I' = R(n', m', L').
    pub i_prime: Vec<f32>,
    /// O' = R(n', m_t, L'), when target materials were given.
    pub o_prime: Option<Vec<f32>>,
    /// R(n', m', L_new), when another illumination was given.
    pub relit: Option<Vec<f32>>,
}

/// Runs the network on `prep` and renders I', O' (with `targets`, normalised, `[R, 108]`) and the
/// relit image (with `relight`, `[3, He, 2He]` camera-space radiance, scaled to L's mean radiance:
/// a photo's exposure is arbitrary, so the other light takes the predicted light's level).
pub fn predict_and_render(
    net: &Net,
    env_height: usize,
    prep: &Prepared,
    targets: Option<&[f32]>,
    relight: Option<&[f32]>,
) -> Result<Predicted> {
    let device = Device::flex();
    let (s, r) = (prep.size, prep.regions);
    let hb = HostBatch {
        batch: 1,
        size: s,
        regions: r,
        env_height,
        ids: vec!["photo".into()],
        input: prep.input.clone(),
        target: vec![0.0; 3 * s * s],
        normals: vec![0.0; 3 * s * s],
        mask: prep.mask.clone(),
        region_map: prep.region_map.clone(),
        env: vec![0.0; 6 * env_height * env_height],
        materials: vec![0.0; r * PARAMS],
        target_materials: vec![0.0; r * PARAMS],
    };
    let p = predict(net, &hb.to_device(&device), true);
    let mut normals = host(&p.normals);
    for k in 0..s * s {
        if prep.mask[k] <= 0.0 {
            for c in 0..3 {
                normals[c * s * s + k] = 0.0;
            }
        }
    }
    let materials = host(&p.materials);
    let env = p.env.as_ref().map(host).context("the network predicted no illumination")?;
    let layer = RenderingLayer::new(env_height);
    let render = |m: &[f32], l: &[f32]| -> Result<Vec<f32>> {
        Ok(layer.forward(&Batch {
            batch: 1,
            size: (s, s),
            regions: r,
            normals: &normals,
            region_map: &prep.region_map,
            materials: m,
            env: l,
        })?)
    };
    let i_prime = render(&materials, &env)?;
    let o_prime = targets.map(|t| render(t, &env)).transpose()?;
    let mean = |v: &[f32]| v.iter().map(|&x| x as f64).sum::<f64>() / v.len().max(1) as f64;
    let relit = relight
        .map(|l| {
            let k = (mean(&env) / mean(l).max(1e-30)) as f32;
            let l: Vec<f32> = l.iter().map(|v| v * k).collect();
            render(&materials, &l)
        })
        .transpose()?;
    Ok(Predicted {
        normals,
        materials,
        env,
        env_height,
        i_prime,
        o_prime,
        relit,
    })
}

/// The network of a checkpoint folder, or of a run folder's latest checkpoint.
pub fn load_model(path: &Path) -> Result<(Net, checkpoint::State, PathBuf)> {
    let dir = if path.join("latest.json").is_file() {
        checkpoint::latest(path)?.with_context(|| format!("{}: no checkpoint yet", path.display()))?
    } else {
        path.to_path_buf()
    };
    if !dir.join("state.json").is_file() {
        bail!(
            "{}: not a checkpoint folder (no state.json) nor a run folder (no latest.json)",
            path.display()
        );
    }
    let (net, state) =
        checkpoint::load_net(&dir, &Device::flex()).with_context(|| format!("checkpoint {}", dir.display()))?;
    Ok((net, state, dir))
}

/// Everything [`edit`] measured and decided, for `report.json`.
#[derive(Clone, Debug, serde::Serialize)]
pub struct EditReport {
    /// The photo.
    pub photo: String,
    /// Its size.
    pub photo_size: [usize; 2],
    /// How it was stored.
    pub encoding: photo::Encoding,
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
    /// [`TRAINING_MEAN_LUMINANCE`]).
    pub exposure: f64,
    /// The target mean luminance.
    pub training_mean_luminance: f64,
    /// Per region: its id and target material spec.
    pub regions: Vec<target::RegionTarget>,
    /// The other illumination, if any.
    pub relight: Option<String>,
    /// How O' went back into the photo.
    pub composite: Composite,
    /// Seconds per phase.
    pub seconds: output::Timings,
    /// Files written, relative to the output folder.
    pub files: Vec<String>,
}

/// Reads the inputs, edits, and writes every output into `out` (see [`output`]). Nothing is
/// written when any input is bad.
pub fn edit(model: &Path, req: &EditRequest, out: &Path) -> Result<EditReport> {
    let t0 = Instant::now();
    if req.materials.is_empty() && req.relight.is_none() {
        bail!("nothing to do: give --material (the edit) and/or --relight (another illumination)");
    }
    output::refuse_overwriting_inputs(out, &[Some(&req.photo), req.mask.as_ref(), req.regions.as_ref()])?;
    let (net, state, ckpt) = load_model(model)?;
    let p = photo::load_photo(&req.photo)?;
    let (coverage, mask_name) = match &req.mask {
        Some(m) => (photo::load_mask(m, p.width, p.height)?, m.display().to_string()),
        None => (
            p.alpha.clone().with_context(|| {
                format!(
                    "{}: no --mask and the photo has no alpha channel; give the object's mask",
                    req.photo.display()
                )
            })?,
            "alpha of the photo".to_string(),
        ),
    };
    photo::check_mask(req.mask.as_deref().unwrap_or(&req.photo), &coverage)?;
    let labels = req
        .regions
        .as_ref()
        .map(|r| target::load_regions(r, p.width, p.height, &coverage))
        .transpose()?;
    let regions = labels.as_ref().map_or(1, |l| l.1);
    let targets = target::resolve_targets(&req.materials, regions, req.regions.as_deref())?;
    let relight = req
        .relight
        .as_ref()
        .map(|spec| target::relight_env(spec, state.net.env_height))
        .transpose()?;
    let t_load = t0.elapsed().as_secs_f64();

    let t1 = Instant::now();
    let prep = prepare(
        &p,
        &coverage,
        labels.as_ref().map(|(l, n)| (l.as_slice(), *n)),
        state.net.input_size,
    )?;
    let target_params: Option<Vec<f32>> = (!targets.is_empty()).then(|| {
        targets
            .iter()
            .flat_map(|t| t.material.to_normalised().map(|v| v as f32))
            .collect()
    });
    let pred = predict_and_render(
        &net,
        state.net.env_height,
        &prep,
        target_params.as_deref(),
        relight.as_deref(),
    )?;
    let t_predict = t1.elapsed().as_secs_f64();

    let t2 = Instant::now();
    let mut composites = Vec::new();
    for (name, img) in [("edited", &pred.o_prime), ("relit", &pred.relit)] {
        if let Some(img) = img {
            composites.push((name, composite::composite(&p, &coverage, &prep, img, &pred.i_prime, req.composite)));
        }
    }
    let t_composite = t2.elapsed().as_secs_f64();

    let mut report = EditReport {
        photo: req.photo.display().to_string(),
        photo_size: [p.width, p.height],
        encoding: p.encoding,
        mask: mask_name,
        object_pixels: coverage.iter().filter(|&&c| c > 0.0).count(),
        checkpoint: ckpt.display().to_string(),
        stage: state.stage_name.clone(),
        input_size: state.net.input_size,
        env_height: state.net.env_height,
        framing: prep.framing,
        exposure: prep.exposure,
        training_mean_luminance: TRAINING_MEAN_LUMINANCE,
        regions: targets.iter().map(|t| t.record.clone()).collect(),
        relight: req.relight.clone(),
        composite: req.composite,
        seconds: output::Timings {
            load: t_load,
            predict_and_render: t_predict,
            composite: t_composite,
            write: 0.0,
            total: 0.0,
        },
        files: Vec::new(),
    };
    let t3 = Instant::now();
    let targets_dsbrdf: Vec<Dsbrdf> = targets.iter().map(|t| t.material.clone()).collect();
    report.files = output::write_all(out, &p, &prep, &pred, &composites, &targets_dsbrdf)?;
    report.seconds.write = t3.elapsed().as_secs_f64();
    report.seconds.total = t0.elapsed().as_secs_f64();
    output::write_report(out, &report)?;
    Ok(report)
}
