//! `trainer eval`: a trained network on a dataset split, scored like Sec. 4 of the paper.
//!
//! For every sample the network predicts n', m', L' (inference mode: no dropout) and the fused
//! rendering layer renders
//!
//! * I' = R(n', m', L') and O' = R(n', m_t, L'): the full pipeline of Fig. 2 (Table 3's "ours");
//! * R(n, m', L): the material module given ground-truth normals and illumination (Table 1);
//! * R(n', m, L): the normal module given ground-truth material and illumination (Table 2);
//! * R(n', m̄, L'): the trivial baseline that edits to the mean training material m̄ (the mean
//!   of the normalised parameters of the training splits' materials) instead of m_t.
//!
//! The other trivial baseline, O' = I (no edit at all), needs no network. Table 3's other
//! methods: a Baseline 1 checkpoint (`Net::encoder_decoder`) gives O' and m' without rendering;
//! `--eq6` refines each Fig. 2 network's n', m', L' per sample (Eq. 6) before rendering;
//! `--lombardi` recovers m*, L* per sample given the true n (`crate::baseline::lombardi`). All
//! images are scored on the ground-truth object mask against I or O.

use super::methods::{encoder_decoder_batch, eq6_batch, lombardi_batch};
use super::report::{CheckpointEval, EvalReport, LombardiEval};
use super::score::score_batch;
use super::{I_PRIME, Metrics, O_PRIME};
use crate::baseline::lombardi::{LombardiConfig, ReflectancePrior};
use crate::data;
use crate::data::{Dataset, Loader, LoaderConfig};
use crate::rendering_layer::op::host;
use crate::rendering_layer::{LayerInput, RenderingLayer};
use crate::train::checkpoint;
use anyhow::{Context, Result, bail};
use burn::tensor::Device;
use matedit_physics::brdf::dsbrdf::PARAMS;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// What to evaluate on.
#[derive(Clone, Debug)]
pub struct EvalOptions {
    /// Dataset folder.
    pub data: PathBuf,
    /// Split to score.
    pub split: String,
    /// Dataset whose training splits define the mean material (default: `data`).
    pub train_data: Option<PathBuf>,
    /// Samples per batch.
    pub batch: usize,
    /// At most this many samples (0: all).
    pub max_samples: usize,
    /// Score only samples of these shape categories (all when empty).
    pub categories: Vec<String>,
    /// Show a progress bar.
    pub progress: bool,
    /// Write a contact sheet of this many samples (spread over the split) to this PNG: I, I',
    /// O, O', n, n', L, L' of the last checkpoint.
    pub sheet: Option<(PathBuf, usize)>,
    /// Also score every checkpoint after the post-optimisation (Eq. 6) of each sample.
    pub eq6: Option<crate::post_optimisation::Eq6Config>,
    /// Also score the Lombardi-style optimiser (given the true normals) on each sample.
    pub lombardi: Option<LombardiConfig>,
    /// Row labels of the checkpoints, in order (default, or where empty: each checkpoint's
    /// stage name), e.g. "Baseline 2" and "ours" for Table 3.
    pub names: Vec<String>,
}

/// The mean of normalised materials (`training_materials` never returns none).
fn mean_of(materials: &[[f32; PARAMS]]) -> [f32; PARAMS] {
    let mut sum = [0.0f64; PARAMS];
    for m in materials {
        for (s, v) in sum.iter_mut().zip(m) {
            *s += *v as f64;
        }
    }
    sum.map(|s| (s / materials.len().max(1) as f64) as f32)
}

/// The normalised parameters of the materials of `ds`'s training splits, with their ids (sorted).
pub fn training_materials(ds: &Dataset) -> Result<(Vec<[f32; PARAMS]>, Vec<String>)> {
    let mut ids: Vec<String> = ds
        .info()
        .plan
        .splits
        .iter()
        .filter(|s| s.role == "train")
        .flat_map(|s| s.materials.iter().cloned())
        .collect();
    ids.sort();
    ids.dedup();
    if ids.is_empty() {
        bail!(
            "{}: no split with role \"train\": pass --train-data with the training dataset for the mean-material baseline",
            ds.dir().display()
        );
    }
    let materials = ids
        .iter()
        .map(|id| {
            ds.normalised_material(id)
                .copied()
                .with_context(|| format!("{}: material {id} is not in the table", ds.dir().display()))
        })
        .collect::<Result<Vec<_>>>()?;
    Ok((materials, ids))
}

/// Evaluates `checkpoints` (folders written by `trainer run`) on `opts.split`.
pub fn evaluate(checkpoints: &[PathBuf], opts: &EvalOptions) -> Result<EvalReport> {
    if checkpoints.is_empty() {
        bail!("no checkpoint to evaluate");
    }
    let full = Dataset::open(&opts.data)?;
    let train_ds = match &opts.train_data {
        Some(d) => Dataset::open(d)?,
        None => full.clone(),
    };
    let ds = Arc::new(full.only_categories(&opts.categories));
    if !opts.categories.is_empty() && ds.records(&opts.split).is_empty() && !full.records(&opts.split).is_empty() {
        bail!(
            "{}: split {} has no samples of categor{} {}",
            opts.data.display(),
            opts.split,
            if opts.categories.len() == 1 { "y" } else { "ies" },
            opts.categories.join(", ")
        );
    }
    let (training, mean_ids) = training_materials(&train_ds)?;
    let mean = mean_of(&training);
    if !opts.names.is_empty() && opts.names.len() != checkpoints.len() {
        bail!("{} names for {} checkpoints", opts.names.len(), checkpoints.len());
    }
    let reflectance_prior = match &opts.lombardi {
        Some(cfg) => {
            cfg.validate()?;
            Some(ReflectancePrior::fit(&training.iter().collect::<Vec<_>>())?)
        }
        None => None,
    };
    let device = Device::flex();
    let mut nets = Vec::new();
    for c in checkpoints {
        let (net, state) = checkpoint::load_net(c, &device).with_context(|| format!("checkpoint {}", c.display()))?;
        nets.push((net, state));
    }
    let env_height = nets[0].1.net.env_height;
    let layer = RenderingLayer::new(env_height);
    let mut report = EvalReport {
        dataset: opts.data.display().to_string(),
        split: opts.split.clone(),
        categories: opts.categories.clone(),
        mean_material_of: mean_ids,
        checkpoints: nets
            .iter()
            .zip(checkpoints)
            .enumerate()
            .map(|(k, ((_, s), c))| CheckpointEval {
                name: opts
                    .names
                    .get(k)
                    .filter(|n| !n.is_empty())
                    .cloned()
                    .unwrap_or_else(|| s.stage_name.clone()),
                checkpoint: c.display().to_string(),
                ..Default::default()
            })
            .collect(),
        ..Default::default()
    };
    let total = ds
        .split(&opts.split)
        .with_context(|| {
            format!(
                "{}: no split {:?} (splits: {})",
                opts.data.display(),
                opts.split,
                ds.split_names().join(", ")
            )
        })?
        .len();
    let limit = if opts.max_samples == 0 {
        total
    } else {
        opts.max_samples.min(total)
    };
    let loader = Loader::new(ds.clone(), &opts.split, LoaderConfig::evaluation(opts.batch.max(1)))?;
    let bar = if opts.progress {
        indicatif::ProgressBar::new(limit as u64)
    } else {
        indicatif::ProgressBar::hidden()
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template("eval [{bar:30}] {pos}/{len} samples  ETA {eta}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    let picks: Vec<usize> = match &opts.sheet {
        Some((_, n)) if *n > 0 => {
            let n = (*n).min(limit);
            (0..n).map(|k| k * limit / n).collect()
        }
        _ => Vec::new(),
    };
    let mut shown: Vec<super::sheet::Shown> = Vec::new();
    let (mut compared, mut method_names): (Vec<super::sheet::Compared>, Vec<String>) = (Vec::new(), Vec::new());
    let mut seen = 0usize;
    for batch in loader {
        if seen >= limit {
            break;
        }
        let mut hb = batch?;
        let keep = (limit - seen).min(hb.batch);
        truncate(&mut hb, keep);
        for (_, state) in &nets {
            if state.net.input_size != hb.size || state.net.env_height != hb.env_height {
                bail!(
                    "the network is for {}² images and {}-row environments, the dataset has {}² and {}",
                    state.net.input_size,
                    state.net.env_height,
                    hb.size,
                    hb.env_height
                );
            }
        }
        let copy = score_batch(&hb, &[(O_PRIME, &hb.input, &hb.target)], None, None);
        report.copy_input.merge(&copy);
        // Every method's O' of this batch, in Table 3's order, for the methods sheet.
        let mut edits: Vec<(String, Vec<f32>)> = Vec::new();
        let shows = (0..hb.batch).any(|k| picks.contains(&(seen + k)));
        if let (Some(cfg), Some(prior)) = (&opts.lombardi, &reflectance_prior) {
            let row = report.lombardi.get_or_insert_with(|| LombardiEval {
                config: Some(cfg.clone()),
                prior_materials: prior.materials,
                ..Default::default()
            });
            let o_s = lombardi_batch(&layer, &hb, prior, cfg, row)?;
            edits.push(("Lombardi (true n)".into(), o_s));
        }
        let last = nets.len() - 1;
        for (c, ((net, _), row)) in nets.iter().zip(report.checkpoints.iter_mut()).enumerate() {
            let tb = hb.to_device(&device);
            if let Some(ed) = &net.encoder_decoder {
                let o_p = encoder_decoder_batch(ed, &layer, &hb, tb, row)?;
                edits.push((row.name.clone(), o_p));
                continue;
            }
            let p = net.predict(&tb.input, &tb.mask, &tb.region_masks, true);
            let (n_p, m_p) = (host(&p.normals), host(&p.materials));
            let l_p = p.env.as_ref().map(host).unwrap_or_default();
            let mean_mats: Vec<f32> = (0..hb.batch * hb.regions).flat_map(|_| mean).collect();
            let render = |n: &[f32], m: &[f32], env: &[f32]| {
                layer.forward(&LayerInput {
                    batch: hb.batch,
                    size: (hb.size, hb.size),
                    regions: hb.regions,
                    normals: n,
                    region_map: &hb.region_map,
                    materials: m,
                    env,
                })
            };
            let (n, m, l, m_t) = (&hb.normals, &hb.materials, &hb.env, &hb.target_materials);
            let i_p = render(&n_p, &m_p, &l_p)?;
            let o_p = render(&n_p, m_t, &l_p)?;
            let i_given_n_l = render(n, &m_p, l)?;
            let i_given_m_l = render(&n_p, m, l)?;
            let o_mean = render(&n_p, &mean_mats, &l_p)?;
            let (i, o) = (&hb.input, &hb.target);
            row.network.merge(&score_batch(
                &hb,
                &[(I_PRIME, &i_p, i), (O_PRIME, &o_p, o)],
                Some(&n_p),
                Some(&m_p),
            ));
            row.material_protocol
                .merge(&score_batch(&hb, &[(I_PRIME, &i_given_n_l, i)], None, Some(&m_p)));
            row.normal_protocol
                .merge(&score_batch(&hb, &[(I_PRIME, &i_given_m_l, i)], Some(&n_p), None));
            row.mean_material
                .merge(&score_batch(&hb, &[(O_PRIME, &o_mean, o)], None, None));
            if shows {
                edits.push((row.name.clone(), o_p.clone()));
            }
            if let Some(cfg) = &opts.eq6 {
                let (star, energy) = eq6_batch(&layer, &hb, &n_p, &m_p, &l_p, cfg)?;
                let (n_s, m_s, l_s) = (&star.normals, &star.materials, &star.env);
                let i_s = render(n_s, m_s, l_s)?;
                let o_s = render(n_s, m_t, l_s)?;
                row.eq6.get_or_insert_with(Metrics::default).merge(&score_batch(
                    &hb,
                    &[(I_PRIME, &i_s, i), (O_PRIME, &o_s, o)],
                    Some(n_s),
                    Some(m_s),
                ));
                let e = row.eq6_energy.get_or_insert([0.0; 3]);
                for (a, b) in e.iter_mut().zip(energy) {
                    *a += b;
                }
                edits.push((format!("{} + Eq. 6", row.name), o_s));
            }
            if c == last {
                let (p, t) = (hb.size * hb.size, 2 * hb.env_height * hb.env_height);
                for k in (0..hb.batch).filter(|k| picks.contains(&(seen + k))) {
                    let px = |v: &[f32]| v[k * 3 * p..(k + 1) * 3 * p].to_vec();
                    let ev = |v: &[f32]| v[k * 3 * t..(k + 1) * 3 * t].to_vec();
                    shown.push(super::sheet::Shown {
                        size: hb.size,
                        env_height: hb.env_height,
                        mask: hb.mask[k * p..(k + 1) * p].to_vec(),
                        images: [px(i), px(&i_p), px(o), px(&o_p)],
                        normals: [px(n), px(&n_p)],
                        env: [ev(l), ev(&l_p)],
                    });
                }
            }
        }
        let p = hb.size * hb.size;
        for k in (0..hb.batch).filter(|k| picks.contains(&(seen + k))) {
            let px = |v: &[f32]| v[k * 3 * p..(k + 1) * 3 * p].to_vec();
            method_names = edits.iter().map(|(n, _)| n.clone()).collect();
            compared.push(super::sheet::Compared {
                size: hb.size,
                mask: hb.mask[k * p..(k + 1) * p].to_vec(),
                input: px(&hb.input),
                target: px(&hb.target),
                edits: edits.iter().map(|(_, v)| px(v)).collect(),
            });
        }
        seen += hb.batch;
        bar.set_position(seen as u64);
    }
    bar.finish_and_clear();
    report.samples = seen as u64;
    if let Some((path, _)) = &opts.sheet
        && !shown.is_empty()
    {
        super::sheet::write(path, &shown)?;
    }
    // With more than one method, their O' side by side: `SHEET-methods.png`.
    if let Some((path, _)) = &opts.sheet
        && method_names.len() > 1
        && !compared.is_empty()
    {
        super::sheet::write_methods(&methods_sheet_path(path), &method_names, &compared)?;
    }
    if seen == 0 {
        bail!(
            "{}: split {} has no samples to evaluate",
            opts.data.display(),
            opts.split
        );
    }
    Ok(report)
}

/// Where the methods sheet of a contact sheet at `sheet` goes: `NAME-methods.png` beside it.
pub fn methods_sheet_path(sheet: &Path) -> PathBuf {
    let stem = sheet
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    sheet.with_file_name(format!("{stem}-methods.png"))
}

/// Keeps the first `keep` samples of a batch.
fn truncate(hb: &mut data::Batch, keep: usize) {
    if keep >= hb.batch {
        return;
    }
    let (p, t, r) = (hb.size * hb.size, 2 * hb.env_height * hb.env_height, hb.regions);
    hb.batch = keep;
    hb.ids.truncate(keep);
    hb.positions.truncate(keep);
    hb.region_counts.truncate(keep);
    for v in [&mut hb.input, &mut hb.target, &mut hb.normals] {
        v.truncate(keep * 3 * p);
    }
    hb.mask.truncate(keep * p);
    hb.region_map.truncate(keep * p);
    hb.env.truncate(keep * 3 * t);
    hb.materials.truncate(keep * r * PARAMS);
    hb.target_materials.truncate(keep * r * PARAMS);
}
