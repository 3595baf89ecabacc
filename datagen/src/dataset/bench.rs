//! `datagen bench MANIFEST`: speed against error of the shading options on a manifest's own
//! samples. Each option renders the same samples (everything but writing files: G-buffer,
//! environment, shading of I and O, EXR encoding); errors are relative RMSE of I and O against
//! the reference option over the object's pixels. Work done once per material and run (the
//! `zonal` kernels) is timed apart from the samples, as `datagen run` amortises it.
//!
//! Besides the qualities (which shade the manifest's ground truth, by default the fitted
//! DSBRDF), `measured` shades each material's source BRDF itself (a MERL table or neural BRDF,
//! an analytic model; the exact path), whatever the manifest's `ground_truth`: against it, the
//! qualities' error is what choosing the fit as the dataset's ground truth costs.

use super::manifest::GroundTruth;
use super::materials::MaterialEntry;
use super::plan::Plan;
use super::sample::{Renderer, encode};
use anyhow::Result;
use matedit_physics::shading::Quality;
use rayon::prelude::*;
use std::time::Instant;

/// What an option shades with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Shading {
    /// The manifest's ground truth with this quality.
    Quality(Quality),
    /// Every material's source BRDF (the exact path), whatever the manifest's ground truth.
    Measured,
}

impl std::str::FromStr for Shading {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "measured" => Ok(Self::Measured),
            _ => s
                .parse()
                .map(Self::Quality)
                .map_err(|e| format!("{e}, or measured (the source BRDFs themselves)")),
        }
    }
}

impl std::fmt::Display for Shading {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Quality(q) => write!(f, "{q:?}"),
            Self::Measured => write!(f, "measured"),
        }
    }
}

/// One option's figures.
#[derive(Clone, Debug)]
pub struct BenchRow {
    /// The shading option.
    pub quality: Shading,
    /// Samples per second (all threads), per-material set-up excluded.
    pub samples_per_s: f64,
    /// Seconds of per-material set-up before the first sample (all threads; `zonal` kernels).
    pub setup_s: f64,
    /// Materials that set-up prepared.
    pub setup_materials: usize,
    /// Median over samples of the relative RMSE of I and O against the reference.
    pub median_rel_rmse: f64,
    /// Largest such error.
    pub max_rel_rmse: f64,
    /// Mean encoded bytes per sample (both files).
    pub bytes_per_sample: f64,
    /// Each sample's relative RMSE, in the order of the picks.
    pub per_sample_rel_rmse: Vec<f64>,
}

/// I and O of one sample, channel-major.
type Images = (Vec<f32>, Vec<f32>);

/// Every pick rendered with one option.
struct Rendered {
    images: Vec<Images>,
    /// Seconds for all samples, set-up excluded.
    secs: f64,
    bytes_per_sample: f64,
    setup_s: f64,
    setup_materials: usize,
}

/// Picks `n` samples spread over the plan, as (split, index).
pub fn spread(plan: &Plan, n: usize) -> Vec<(usize, usize)> {
    let all: Vec<(usize, usize)> = plan
        .splits
        .iter()
        .enumerate()
        .flat_map(|(s, sp)| (0..sp.samples).map(move |i| (s, i)))
        .collect();
    let n = n.clamp(1, all.len().max(1));
    (0..n).map(|k| all[k * all.len() / n]).collect()
}

/// Renders `picks` with the reference and every other option in `options` and compares each
/// with the reference; the first row is the reference itself. `materials` are prepared for the
/// plan's ground truth, `measured` (needed only by [`Shading::Measured`]) for the source BRDFs.
pub fn bench(
    plan: &Plan,
    materials: &[Option<MaterialEntry>],
    measured: Option<&[Option<MaterialEntry>]>,
    picks: &[(usize, usize)],
    reference: Shading,
    options: &[Shading],
) -> Result<Vec<BenchRow>> {
    // Every material of the splits the picks come from.
    let used = plan.materials_of(picks.iter().map(|&(s, _)| s));
    let render_all = |shading: Shading| -> Result<Rendered> {
        let mut p = plan.clone();
        let materials = match shading {
            Shading::Quality(q) => {
                p.settings.quality = q;
                materials
            }
            Shading::Measured => {
                p.settings.quality = Quality::Exact;
                p.settings.ground_truth = GroundTruth::Measured;
                measured.ok_or_else(|| anyhow::anyhow!("`measured` needs the source BRDFs prepared"))?
            }
        };
        let r = Renderer::new(&p, materials);
        let t = Instant::now();
        let setup_materials = r.prepare_zonal(&used, &|| {})?;
        let setup_s = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let out: Vec<(Images, usize)> = picks
            .par_iter()
            .map(|&(s, i)| {
                let px = r.render(&plan.sample(s, i))?;
                let get = |names: [&str; 3]| -> Vec<f32> {
                    names
                        .iter()
                        .flat_map(|n| {
                            px.image
                                .iter()
                                .find(|c| c.0 == *n)
                                .map(|c| c.1.clone())
                                .unwrap_or_default()
                        })
                        .collect()
                };
                let (i_img, o_img) = (get(["R", "G", "B"]), get(["O.R", "O.G", "O.B"]));
                let (_, a, b) = encode(px)?;
                Ok(((i_img, o_img), a.len() + b.len()))
            })
            .collect::<Result<_>>()?;
        let secs = t.elapsed().as_secs_f64();
        let bytes_per_sample = out.iter().map(|o| o.1 as f64).sum::<f64>() / out.len().max(1) as f64;
        Ok(Rendered {
            images: out.into_iter().map(|o| o.0).collect(),
            secs,
            bytes_per_sample,
            setup_s,
            setup_materials,
        })
    };
    let reference_run = render_all(reference)?;
    // The reference's own row: its speed, and zero error by definition.
    let mut rows = vec![BenchRow {
        quality: reference,
        samples_per_s: picks.len() as f64 / reference_run.secs,
        setup_s: reference_run.setup_s,
        setup_materials: reference_run.setup_materials,
        median_rel_rmse: 0.0,
        max_rel_rmse: 0.0,
        bytes_per_sample: reference_run.bytes_per_sample,
        per_sample_rel_rmse: vec![0.0; picks.len()],
    }];
    let reference_imgs = reference_run.images;
    for &q in options.iter().filter(|&&q| q != reference) {
        let run = render_all(q)?;
        let per_sample: Vec<f64> = run
            .images
            .iter()
            .zip(&reference_imgs)
            .map(|((i, o), (ri, ro))| {
                let (mut e, mut s) = (0.0_f64, 0.0_f64);
                for (a, b) in i.iter().chain(o).zip(ri.iter().chain(ro)) {
                    e += (*a as f64 - *b as f64).powi(2);
                    s += (*b as f64).powi(2);
                }
                if s > 0.0 { (e / s).sqrt() } else { 0.0 }
            })
            .collect();
        let mut errs = per_sample.clone();
        errs.sort_by(|a, b| a.total_cmp(b));
        rows.push(BenchRow {
            quality: q,
            samples_per_s: picks.len() as f64 / run.secs,
            setup_s: run.setup_s,
            setup_materials: run.setup_materials,
            median_rel_rmse: errs[errs.len() / 2],
            max_rel_rmse: *errs.last().unwrap_or(&0.0),
            bytes_per_sample: run.bytes_per_sample,
            per_sample_rel_rmse: per_sample,
        });
    }
    Ok(rows)
}

/// `datagen bench`: renders `samples` samples spread over the manifest's splits with the
/// `reference` and each of the `options`, and returns the speed-against-error table (Markdown),
/// with one row per sample when `per_sample`.
pub fn bench_manifest(
    manifest: &std::path::Path,
    samples: usize,
    reference: Shading,
    options: &[Shading],
    res: Option<usize>,
    per_sample: bool,
) -> Result<String> {
    use std::fmt::Write;
    let mut out = String::new();
    let mut l = super::run::load(manifest)?;
    if let Some(res) = res {
        l.plan.settings.resolution = res;
    }
    let dir = std::env::temp_dir().join(format!("matedit-bench-materials-{}", std::process::id()));
    let prepare = |truth: GroundTruth| {
        super::materials::prepare_all(
            &dir,
            &l.plan.catalogue.materials,
            &super::materials::needed(&l.plan),
            truth,
            &|| {},
        )
    };
    let prepared = prepare(l.plan.settings.ground_truth);
    let measured = if reference == Shading::Measured || options.contains(&Shading::Measured) {
        Some(prepare(GroundTruth::Measured))
    } else {
        None
    };
    let _ = std::fs::remove_dir_all(&dir);
    let materials = prepared?;
    let measured = measured.transpose()?;
    let picks = spread(&l.plan, samples);
    let rows = bench(&l.plan, &materials, measured.as_deref(), &picks, reference, options)?;
    let _ = writeln!(
        out,
        "{} samples of {} at {}², {} threads, ground truth {:?}, reference {reference}",
        picks.len(),
        manifest.display(),
        l.plan.settings.resolution,
        rayon::current_num_threads(),
        l.plan.settings.ground_truth
    );
    let _ = writeln!(
        out,
        "| quality | samples/s | median rel. RMSE | max rel. RMSE | bytes/sample | set-up once per material |"
    );
    let _ = writeln!(out, "|---|---|---|---|---|---|");
    for row in &rows {
        let setup = if row.setup_materials > 0 {
            format!("{:.2} s for {} materials", row.setup_s, row.setup_materials)
        } else {
            "none".to_string()
        };
        // Three significant figures: the exact path runs at hundredths of a sample a second.
        let rate = row.samples_per_s;
        let decimals = if rate > 0.0 {
            (2.0 - rate.log10().floor()).clamp(0.0, 6.0) as usize
        } else {
            2
        };
        let _ = writeln!(
            out,
            "| {} | {rate:.decimals$} | {:.3} % | {:.3} % | {:.0} | {setup} |",
            row.quality,
            100.0 * row.median_rel_rmse,
            100.0 * row.max_rel_rmse,
            row.bytes_per_sample
        );
    }
    if per_sample {
        let _ = writeln!(out);
        let _ = writeln!(out, "| quality | split | sample | rel. RMSE |");
        let _ = writeln!(out, "|---|---|---|---|");
        for row in &rows {
            for ((s, i), e) in picks.iter().zip(&row.per_sample_rel_rmse) {
                let split = &l.plan.splits[*s].name;
                let _ = writeln!(out, "| {} | {split} | {i} | {:.3} % |", row.quality, 100.0 * e);
            }
        }
    }
    Ok(out)
}
