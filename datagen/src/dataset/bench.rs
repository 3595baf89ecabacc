//! `datagen bench MANIFEST`: speed against error of the shading options on a manifest's own
//! samples. Each option renders the same samples (everything but writing files: G-buffer,
//! environment, shading of I and O, EXR encoding); errors are relative RMSE of I and O against
//! the reference option over the object's pixels.

use super::materials::MaterialEntry;
use super::plan::Plan;
use super::sample::{Renderer, encode};
use anyhow::Result;
use matedit_physics::shading::Quality;
use rayon::prelude::*;
use std::time::Instant;

/// One option's figures.
#[derive(Clone, Debug)]
pub struct BenchRow {
    /// The shading option.
    pub quality: Quality,
    /// Samples per second (all threads).
    pub samples_per_s: f64,
    /// Median over samples of the relative RMSE of I and O against the reference.
    pub median_rel_rmse: f64,
    /// Largest such error.
    pub max_rel_rmse: f64,
    /// Mean encoded bytes per sample (both files).
    pub bytes_per_sample: f64,
}

/// I and O of one sample, channel-major.
type Images = (Vec<f32>, Vec<f32>);

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

/// Renders `picks` with every option in `options` and compares each with `reference`.
pub fn bench(
    plan: &Plan,
    materials: &[Option<MaterialEntry>],
    picks: &[(usize, usize)],
    reference: Quality,
    options: &[Quality],
) -> Result<Vec<BenchRow>> {
    let render_all = |q: Quality| -> Result<(Vec<Images>, f64, f64)> {
        let mut p = plan.clone();
        p.settings.quality = q;
        let r = Renderer::new(&p, materials);
        let t = Instant::now();
        let out: Vec<(Images, usize)> = picks
            .par_iter()
            .map(|&(s, i)| {
                let px = r.render(s, i)?;
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
        let bytes = out.iter().map(|o| o.1 as f64).sum::<f64>() / out.len().max(1) as f64;
        Ok((out.into_iter().map(|o| o.0).collect(), secs, bytes))
    };
    let (reference_imgs, _, _) = render_all(reference)?;
    let mut rows = Vec::new();
    for &q in options {
        let (imgs, secs, bytes) = render_all(q)?;
        let mut errs: Vec<f64> = imgs
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
        if std::env::var_os("MATEDIT_BENCH_PER_SAMPLE").is_some() {
            for ((s, i), e) in picks.iter().zip(&errs) {
                eprintln!("{q:?} split {s} sample {i}: rel RMSE {:.3} %", 100.0 * e);
            }
        }
        errs.sort_by(|a, b| a.total_cmp(b));
        rows.push(BenchRow {
            quality: q,
            samples_per_s: picks.len() as f64 / secs,
            median_rel_rmse: errs[errs.len() / 2],
            max_rel_rmse: *errs.last().unwrap_or(&0.0),
            bytes_per_sample: bytes,
        });
    }
    Ok(rows)
}
