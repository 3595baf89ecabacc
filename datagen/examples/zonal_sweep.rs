//! Speed against error of the `zonal` quality's knobs, on the material library.
//!
//! `cargo run --release -p matedit-datagen --example zonal_sweep -- [RES] [FAMILIES] [--per-material]`
//!
//! Every library material of the given families (comma-separated, default all) is fitted from the
//! cache (`datagen assets materials` first) and rendered on a RES² sphere (default 128) under
//! four procedural maps (`sunsky:1`, `softbox:2`, `window:3`, `overcast:4`, 64×128) with the fast
//! path (the reference: within 1e-4 of the exact path, `physics/tests/shading_paths.rs`) and with the
//! zonal method at each setting of the sweep. Prints, per setting, the median and largest relative
//! RMSE, the median time of one image (environment spectra + table + interpolation, 2 threads),
//! the median kernel build time and size per material. `--per-material` prints the default
//! setting's figures per material instead.

use matedit_assets::envmaps::Family;
use matedit_assets::materials::{cache, library};
use matedit_physics::shading::zonal::{PolarNormals, ZonalEnv, ZonalKernel, ZonalParams, shade_image_zonal};
use matedit_physics::shading::{Quality, make_shader, shade_image};
use matedit_physics::{BrdfModel, EnvMap};
use std::time::Instant;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

fn rel_rmse(a: &[[f32; 3]], b: &[[f32; 3]]) -> f64 {
    let (mut e, mut s) = (0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        for c in 0..3 {
            e += ((x[c] - y[c]) as f64).powi(2);
            s += (y[c] as f64).powi(2);
        }
    }
    (e / s).sqrt()
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let per_material = args.iter().any(|a| a == "--per-material");
    let rest: Vec<&String> = args.iter().filter(|a| !a.starts_with("--")).collect();
    let res: usize = rest.first().and_then(|a| a.parse().ok()).unwrap_or(128);
    let families: Vec<String> = rest
        .get(1)
        .map(|f| f.split(',').map(String::from).collect())
        .unwrap_or_default();
    let dir = cache::default_dir();
    let (normals, mask) = matedit_physics::camera::unit_sphere_normals(res);
    let pixels = PolarNormals::new(&normals, &mask);
    let envs: Vec<(String, EnvMap)> = [
        (Family::SunSky, 1),
        (Family::Softbox, 2),
        (Family::Window, 3),
        (Family::Overcast, 4),
    ]
    .iter()
    .map(|&(f, s)| (format!("{}:{s}", f.name()), f.generate(s, 64)))
    .collect();
    let materials: Vec<(String, BrdfModel)> = library::library()
        .into_iter()
        .filter(|m| families.is_empty() || families.iter().any(|f| f == m.family))
        .filter_map(|m| {
            Some((
                m.name.clone(),
                BrdfModel::Dsbrdf(Box::new(cache::load_cached(&dir, &m)?)),
            ))
        })
        .collect();
    if materials.is_empty() {
        eprintln!(
            "no fitted materials in {}: run `datagen assets materials` first",
            dir.display()
        );
        std::process::exit(1);
    }
    eprintln!(
        "{} materials × {} maps at {res}²: fast-path references…",
        materials.len(),
        envs.len()
    );
    let references: Vec<Vec<Vec<[f32; 3]>>> = materials
        .iter()
        .map(|(_, brdf)| {
            envs.iter()
                .map(|(_, env)| shade_image(make_shader(brdf, env, Quality::Fast).as_ref(), &normals, &mask, None).0)
                .collect()
        })
        .collect();
    let default = ZonalParams::default();
    let settings: Vec<ZonalParams> = if per_material {
        vec![default]
    } else {
        let with = |spacing: f64, tail: f64, min_rows: usize| ZonalParams {
            spacing_per_width: spacing,
            tail,
            min_rows,
            ..default
        };
        vec![
            with(1.0, 1e-3, 16),
            with(0.75, 1e-3, 24),
            with(0.75, 1e-3, 32),
            with(0.5, 1e-2, 32),
            with(0.5, 1e-3, 32),
            with(0.5, 1e-4, 32),
            with(0.5, 1e-3, 48),
            with(0.35, 1e-3, 32),
        ]
    };
    if per_material {
        println!(
            "| material | rows | MB | kernel s | image ms | {} |",
            envs.iter().map(|e| e.0.as_str()).collect::<Vec<_>>().join(" | ")
        );
        println!("|---|---|---|---|---|{}", "---|".repeat(envs.len()));
    } else {
        println!(
            "| spacing/width | tail | min rows | median rel. RMSE | max rel. RMSE | image ms | kernel s | kernel MB |"
        );
        println!("|---|---|---|---|---|---|---|---|");
    }
    for p in &settings {
        let (mut errs, mut times, mut builds, mut sizes) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for ((name, brdf), refs) in materials.iter().zip(&references) {
            let t = Instant::now();
            let kernel = ZonalKernel::for_brdf_with(brdf, p).expect("analytic");
            let build = t.elapsed().as_secs_f64();
            let mut row = Vec::new();
            let mut image_ms = Vec::new();
            for ((_, env), reference) in envs.iter().zip(refs) {
                let t = Instant::now();
                let spectra = ZonalEnv::new(env, kernel.grid());
                let (img, _) = shade_image_zonal(&kernel, &spectra, &pixels, &mask);
                image_ms.push(t.elapsed().as_secs_f64() * 1e3);
                let e = rel_rmse(&img, reference);
                row.push(format!("{:.3} %", 100.0 * e));
                errs.push(e);
            }
            let mb = kernel.coefficients() as f64 * 4e-6;
            if per_material {
                println!(
                    "| {name} | {} | {mb:.1} | {build:.2} | {:.1} | {} |",
                    kernel.grid().rows,
                    median(image_ms.clone()),
                    row.join(" | ")
                );
            }
            times.extend(image_ms);
            builds.push(build);
            sizes.push(mb);
        }
        if !per_material {
            println!(
                "| {} | {:.0e} | {} | {:.3} % | {:.3} % | {:.2} | {:.3} | {:.1} |",
                p.spacing_per_width,
                p.tail,
                p.min_rows,
                100.0 * median(errs.clone()),
                100.0 * errs.iter().copied().fold(0.0, f64::max),
                median(times),
                median(builds),
                median(sizes)
            );
        }
    }
}
