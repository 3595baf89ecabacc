//! Seconds of Eq. 6 (default settings) at a given image size on a sphere of a random DSBRDF under
//! a 64×128 sky with a sun, rendered by the layer itself, starting from a perturbed material and
//! light: the post-optimisation's cost without a trained network of that size.
//!
//! `cargo run --release -p matedit-trainer --example eq6_timing -- SIZE [RUNS] [COARSE]`
//!
//! COARSE is `Eq6Config::coarse_pixels` (default 2048; 0: the alternation on every pixel). Each run prints
//! the seconds, E at the start and the end, and how far m* and L* are from the truth.
use anyhow::{Result, bail};
use matedit_trainer::model::prediction::Prediction;
use matedit_trainer::post_optimisation::{Eq6Config, Problem, post_optimise};
use matedit_trainer::rendering_layer::RenderingLayer;
use matedit_trainer::train::synthetic::sphere_batch;
use std::time::Instant;

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(size) = args.first().and_then(|s| s.parse::<usize>().ok()) else {
        bail!("usage: eq6_timing SIZE [RUNS] [COARSE]");
    };
    let runs = args.get(1).and_then(|s| s.parse::<usize>().ok()).unwrap_or(3);
    let cfg = Eq6Config {
        coarse_pixels: args
            .get(2)
            .and_then(|s| s.parse::<usize>().ok())
            .unwrap_or(Eq6Config::default().coarse_pixels),
        ..Eq6Config::default()
    };
    let layer = RenderingLayer::new(64);
    for run in 0..runs {
        let hb = sphere_batch(1, size, 64, run as u64, &layer);
        let truth = Prediction {
            normals: hb.normals.clone(),
            materials: hb.materials.clone(),
            env: hb.env.clone(),
        };
        let mut start = truth.clone();
        for (k, v) in start.materials.iter_mut().enumerate() {
            *v = (*v + if k % 3 == 0 { 0.2 } else { -0.1 }).clamp(-0.95, 0.95);
        }
        start.env.iter_mut().for_each(|v| *v *= 0.8);
        let problem = Problem::eq6(&layer, size, 1, &hb.input, &hb.region_map, &start, cfg.a, cfg.b);
        let t = Instant::now();
        let r = post_optimise(&problem, start.clone(), &cfg)?;
        let secs = t.elapsed().as_secs_f64();
        // Root-mean-square distance of the normalised material and relative L2 of the light.
        let rms = |a: &[f32], b: &[f32]| {
            (a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum::<f64>() / a.len() as f64).sqrt()
        };
        let rel = |a: &[f32], b: &[f32]| {
            let d: f64 = a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum();
            (d / b.iter().map(|y| (*y as f64).powi(2)).sum::<f64>()).sqrt()
        };
        println!(
            "{size}² (coarse pixels {}, stride {}): Eq. 6 {secs:.2} s, E {:.4e} → {:.4e}, material rms {:.4} → {:.4}, \
             light rel {:.4} → {:.4}, {} logged steps",
            cfg.coarse_pixels,
            cfg.stride(hb.region_map.iter().filter(|&&r| r > 0).count()),
            r.start.total,
            r.end.total,
            rms(&start.materials, &truth.materials),
            rms(&r.point.materials, &truth.materials),
            rel(&start.env, &truth.env),
            rel(&r.point.env, &truth.env),
            r.steps.len()
        );
    }
    Ok(())
}
