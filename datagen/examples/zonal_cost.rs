//! Per-image cost of the `zonal` path on the library materials `manifests/datasets/bench-256.toml` deals
//! (plastic, rubber, fabric, wood, car paint): the environment's spectra and the shading of a 256²
//! sphere, under 16 sunny procedural maps (4 skies × 4 turns, so suns in front, beside and behind),
//! three rounds; prints the median and mean of each.
//!
//! `cargo run --release -p matedit-datagen --example zonal_cost -- DIR`, DIR from
//! `datagen assets materials --out DIR`.
use matedit_assets::envmaps::Family;
use matedit_physics::BrdfModel;
use matedit_physics::shading::zonal::{PolarNormals, ZonalEnv, ZonalKernel, shade_image_zonal};
use std::path::PathBuf;
use std::time::Instant;

fn main() {
    use matedit_assets::materials::{cache, library};
    let Some(dir) = std::env::args().nth(1).map(PathBuf::from) else {
        eprintln!("usage: zonal_cost DIR (fitted library from `datagen assets materials --out DIR`)");
        std::process::exit(2);
    };
    let fams = ["plastic", "rubber", "fabric", "wood", "carpaint"];
    let lib: Vec<(String, BrdfModel)> = library::library()
        .into_iter()
        .filter(|m| fams.contains(&m.family.to_string().as_str()))
        .filter_map(|m| {
            Some((
                m.name.clone(),
                BrdfModel::Dsbrdf(Box::new(cache::load_cached(&dir, &m)?)),
            ))
        })
        .collect();
    let kernels: Vec<ZonalKernel> = lib.iter().filter_map(|(_, b)| ZonalKernel::for_brdf(b)).collect();
    let (normals, mask) = matedit_physics::camera::unit_sphere_normals(256);
    let pixels = PolarNormals::new(&normals, &mask);
    let mut maps = Vec::new();
    for seed in 0..4u64 {
        let m = Family::SunSky.generate(seed, 64);
        for yaw in [0.0, 90.0, 180.0, 270.0] {
            maps.push(m.tilted(64, yaw, -20.0));
        }
    }
    let mut t_env = Vec::new();
    let mut t_shade = Vec::new();
    for _ in 0..3 {
        for k in &kernels {
            for env in &maps {
                let t = Instant::now();
                let z = ZonalEnv::new(env, k.grid());
                t_env.push(t.elapsed().as_secs_f64());
                let t = Instant::now();
                let img = shade_image_zonal(k, &z, &pixels, &mask);
                t_shade.push(t.elapsed().as_secs_f64());
                std::hint::black_box(img);
            }
        }
    }
    t_env.sort_by(f64::total_cmp);
    t_shade.sort_by(f64::total_cmp);
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    println!(
        "{} kernels: env spectra median {:.2} ms mean {:.2} ms; shading 256² median {:.2} ms mean {:.2} ms",
        kernels.len(),
        1e3 * t_env[t_env.len() / 2],
        1e3 * mean(&t_env),
        1e3 * t_shade[t_shade.len() / 2],
        1e3 * mean(&t_shade)
    );
}
