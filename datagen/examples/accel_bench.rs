//! Ray throughput of the two backends on the same rays, in one run (a ratio is what survives a
//! noisy machine): primary rays on a 512² grid through each mesh, then shadow rays from every hit
//! towards 8 fixed directions. Medians of 5 runs, all threads (rayon).
//!
//!   eval "$(scripts/install_embree.sh)"
//!   cargo run --release -p matedit-datagen --features embree --example accel_bench -- [MESH.obj|procedural:car:1 ...]

use glam::Vec3;
use matedit_datagen::accel::{Accel, Scene};
use matedit_datagen::shapes::{Shape, UpAxis};
use rayon::prelude::*;
use std::time::Instant;

const SIDE: usize = 512;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// (primary Mrays/s, shadow Mrays/s, hits).
fn measure(scene: &Scene) -> (f64, f64, usize) {
    let lights: Vec<Vec3> = (0..8)
        .map(|k| {
            let a = k as f32 * 0.785;
            Vec3::new(a.cos(), 0.6, a.sin()).normalize()
        })
        .collect();
    let (mut prim, mut shad, mut hits) = (Vec::new(), Vec::new(), 0);
    for _ in 0..5 {
        let t = Instant::now();
        let points: Vec<Vec3> = (0..SIDE * SIDE)
            .into_par_iter()
            .filter_map(|k| {
                let x = -1.05 + 2.1 * ((k % SIDE) as f32 + 0.5) / SIDE as f32;
                let y = -1.05 + 2.1 * ((k / SIDE) as f32 + 0.5) / SIDE as f32;
                let org = Vec3::new(x, y, 4.0);
                scene.intersect(org, Vec3::NEG_Z, 0.0).map(|h| org + h.t * Vec3::NEG_Z)
            })
            .collect();
        prim.push((SIDE * SIDE) as f64 / t.elapsed().as_secs_f64() / 1e6);
        let t = Instant::now();
        let blocked: usize = points
            .par_iter()
            .map(|&p| lights.iter().filter(|&&l| scene.occluded(p, l, 1e-4)).count())
            .sum();
        std::hint::black_box(blocked);
        shad.push((points.len() * lights.len()) as f64 / t.elapsed().as_secs_f64() / 1e6);
        hits = points.len();
    }
    (median(prim), median(shad), hits)
}

fn main() -> anyhow::Result<()> {
    let mut specs: Vec<String> = std::env::args().skip(1).collect();
    if specs.is_empty() {
        specs = ["car:1", "chair:2", "sofa:3", "monitor:4"]
            .iter()
            .map(|s| format!("procedural:{s}"))
            .collect();
    }
    println!("| mesh | triangles | obvhs primary Mrays/s | embree | ratio | obvhs shadow Mrays/s | embree | ratio |");
    println!("|---|---:|---:|---:|---:|---:|---:|---:|");
    for spec in &specs {
        let Shape::Mesh(m) = Shape::load(spec, UpAxis::PosY)? else {
            continue;
        };
        let o = measure(&Scene::new(&m));
        let e = measure(&Scene::with_accel(&m, Accel::Embree)?);
        let name = std::path::Path::new(spec)
            .file_name()
            .map_or(spec.clone(), |n| n.to_string_lossy().into_owned());
        println!(
            "| {name} | {} | {:.2} | {:.2} | {:.2}× | {:.2} | {:.2} | {:.2}× |",
            m.triangles.len(),
            o.0,
            e.0,
            e.0 / o.0,
            o.1,
            e.1,
            e.1 / o.1
        );
    }
    Ok(())
}
