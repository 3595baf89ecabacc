//! Seconds of Eq. 6 (default settings) at a given image size on a sphere of a random DSBRDF under
//! a 64×128 sky with a sun, rendered by the layer itself, starting from a perturbed material and
//! light: the post-optimisation's cost without a trained network of that size.
//!
//! `cargo run --release -p matedit-trainer --example eq6_timing -- SIZE [RUNS]`
use anyhow::{Result, bail};
use matedit_trainer::post_optimisation::{Eq6Config, Point, Priors, Problem, post_optimise};
use matedit_trainer::render::RenderingLayer;
use matedit_trainer::train::synthetic::sphere_batch;
use std::time::Instant;

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(size) = args.first().and_then(|s| s.parse::<usize>().ok()) else {
        bail!("usage: eq6_timing SIZE [RUNS]");
    };
    let runs = args.get(1).and_then(|s| s.parse::<usize>().ok()).unwrap_or(3);
    let layer = RenderingLayer::new(64);
    for run in 0..runs {
        let hb = sphere_batch(1, size, 64, run as u64, &layer);
        let truth = Point {
            normals: hb.normals.clone(),
            materials: hb.materials.clone(),
            env: hb.env.clone(),
        };
        let mut start = truth.clone();
        for (k, v) in start.materials.iter_mut().enumerate() {
            *v = (*v + if k % 3 == 0 { 0.2 } else { -0.1 }).clamp(-0.95, 0.95);
        }
        start.env.iter_mut().for_each(|v| *v *= 0.8);
        let problem = Problem {
            layer: &layer,
            size,
            regions: 1,
            image: &hb.input,
            region_map: &hb.region_map,
            normals: &start.normals,
            env: &start.env,
            a: 1.0,
            b: 10.0,
            priors: Priors::NONE,
        };
        let t = Instant::now();
        let r = post_optimise(&problem, start.clone(), &Eq6Config::default())?;
        println!(
            "{size}²: Eq. 6 {:.2} s, E {:.4e} → {:.4e}, {} logged steps",
            t.elapsed().as_secs_f64(),
            r.start.total,
            r.end.total,
            r.steps.len()
        );
    }
    Ok(())
}
