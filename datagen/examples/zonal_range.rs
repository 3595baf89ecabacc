//! Error and cost of the `zonal` quality over the DSBRDF's whole (κ, γ) range.
//!
//! `cargo run --release -p matedit-datagen --example zonal_range -- [RES] [--raw] [--all-maps]`
//!
//! Each material is a matte base (κ 0.2, γ 10⁻³) plus one lobe (κ, γ) on a log grid over the
//! documented range (κ ∈ [10⁻⁵, 20], γ ∈ [10⁻³, 10⁴]), rendered on a RES² sphere (default 128)
//! under four procedural maps (64×128) and, where `$MATEDIT_EVAL_ASSETS` or `../shared/eval-assets`
//! holds them, real HDRIs with a sun or sharp-edged lights at two turns (`--all-maps`: all 12),
//! with `zonal` as the factory runs it (a material whose lobes the grid cannot resolve is shaded
//! by the fast path) and with the fast path (the reference: within 10⁻³ of `exact` over the whole
//! range, `physics/tests/zonal.rs`). Prints the largest relative RMSE over the maps, the path, the
//! kernel's rows, size and build time, and the time of one image. `--raw` shades every material on
//! the grid its lobes ask for, capped at 128 rows, as the factory did before it refused what the
//! cap cannot resolve (the error that refusal avoids).
//!
//! Other modes: `--probe KAPPA,GAMMA,ROWS` (one material on a forced grid, error per map),
//! `--cost KAPPA,GAMMA` (time of one image per grid size), `--library DIR` (the grid of every
//! fitted library material, after `datagen assets materials --out DIR`, its bands and its check's
//! worst probe error), `--sun-share` (the share
//! of each map's power in its brightest texel).

use matedit_assets::envfile::load_env;
use matedit_assets::envmaps::Family;
use matedit_physics::brdf::Dsbrdf;
use matedit_physics::brdf::dsbrdf::{KNOTS, LobeParam, PARAMS, param_index};
use matedit_physics::envmap::texel_solid_angle;
use matedit_physics::shading::zonal::{
    PolarNormals, ProbeReference, ZonalEnv, ZonalGrid, ZonalKernel, ZonalParams, probe_error, shade_image_zonal,
};
use matedit_physics::shading::{Quality, make_shader, shade_image};
use matedit_physics::{BrdfModel, EnvMap};
use rayon::prelude::*;
use std::path::PathBuf;
use std::time::Instant;

fn rel_rmse(a: &[[f32; 3]], b: &[[f32; 3]]) -> f64 {
    let (mut e, mut s) = (0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        for c in 0..3 {
            e += ((x[c] - y[c]) as f64).powi(2);
            s += (y[c] as f64).powi(2);
        }
    }
    (e / s.max(1e-300)).sqrt()
}

/// A matte base plus one lobe (κ, γ), constant in θ_d.
fn material(kappa: f64, gamma: f64) -> BrdfModel {
    let mut p = [0.0; PARAMS];
    for c in 0..3 {
        for j in 0..KNOTS {
            let lobes = [(0.2, 1e-3), (kappa, gamma), (1e-5, 1e4)];
            for (k, (kk, gg)) in lobes.into_iter().enumerate() {
                p[param_index(c, k, LobeParam::Kappa, j)] = kk;
                p[param_index(c, k, LobeParam::Gamma, j)] = gg;
            }
        }
    }
    BrdfModel::Dsbrdf(Box::new(Dsbrdf::from_params(&p).expect("in range")))
}

fn eval_assets() -> PathBuf {
    std::env::var_os("MATEDIT_EVAL_ASSETS")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/eval-assets")))
}

/// The share of a map's power (L·dω) in its brightest texel.
fn sun_share(env: &EnvMap) -> f64 {
    let (w, h) = (env.width(), env.height());
    let power = |(t, l): (usize, &[f32; 3])| (l[0] + l[1] + l[2]) as f64 * texel_solid_angle(t / w, w, h);
    let total: f64 = env.texels().iter().enumerate().map(power).sum();
    let brightest = env.texels().iter().enumerate().map(power).fold(0.0, f64::max);
    brightest / total.max(1e-300)
}

fn maps(all: bool) -> Vec<(String, EnvMap)> {
    let mut maps: Vec<(String, EnvMap)> = [
        (Family::SunSky, 1),
        (Family::Softbox, 2),
        (Family::Window, 3),
        (Family::Overcast, 4),
    ]
    .iter()
    .map(|&(f, s)| (format!("{}:{s}", f.name()), f.generate(s, 64)))
    .collect();
    let dir = eval_assets().join("envmaps");
    let names: Vec<String> = if all {
        let mut v: Vec<String> = std::fs::read_dir(&dir)
            .map(|r| {
                r.filter_map(|e| e.ok()?.file_name().to_str()?.strip_suffix(".hdr").map(String::from))
                    .collect()
            })
            .unwrap_or_default();
        v.sort();
        v
    } else {
        [
            "rooitou_park_1k",
            "lebombo_1k",
            "studio_small_03_1k",
            "venice_sunset_1k",
        ]
        .map(String::from)
        .to_vec()
    };
    for name in &names {
        let path = dir.join(format!("{name}.hdr"));
        match load_env(&path.display().to_string()) {
            Ok((map, _)) => {
                let map = map.resampled(128, 0.0);
                for yaw in [0.0, 130.0] {
                    maps.push((format!("{name}@{yaw}"), map.tilted(64, yaw, -20.0)));
                }
            }
            Err(e) => eprintln!("skipping {name}: {e:#}"),
        }
    }
    maps
}

fn numbers(arg: &str) -> Vec<f64> {
    arg.split(',')
        .map(|x| x.parse().expect("comma-separated numbers"))
        .collect()
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let flag = |f: &str| {
        args.iter()
            .position(|a| a == f)
            .map(|i| args.get(i + 1).cloned().unwrap_or_default())
    };
    let res: usize = args.first().and_then(|a| a.parse().ok()).unwrap_or(128);
    let (normals, mask) = matedit_physics::camera::unit_sphere_normals(res);
    let pixels = PolarNormals::new(&normals, &mask);
    let maps = maps(args.iter().any(|a| a == "--all-maps"));
    let fast = |brdf: &BrdfModel, env: &EnvMap| {
        shade_image(make_shader(brdf, env, Quality::Fast).as_ref(), &normals, &mask, None).0
    };
    let zonal = |k: &ZonalKernel, env: &EnvMap| shade_image_zonal(k, &ZonalEnv::new(env, k.grid()), &pixels, &mask).0;

    if args.iter().any(|a| a == "--sun-share") {
        for (name, env) in &maps {
            println!("{name:28} brightest texel {:.1} % of the power", 100.0 * sun_share(env));
        }
        return;
    }
    if let Some(v) = flag("--probe").map(|a| numbers(&a)) {
        let brdf = material(v[0], v[1]);
        let kernel = ZonalKernel::new(&brdf, ZonalGrid::with_rows(v[2] as usize)).expect("analytic");
        for (name, env) in &maps {
            println!(
                "{name:28} {:.3} %",
                100.0 * rel_rmse(&zonal(&kernel, env), &fast(&brdf, env))
            );
        }
        return;
    }
    if let Some(v) = flag("--cost").map(|a| numbers(&a)) {
        let brdf = material(v[0], v[1]);
        for rows in [32, 40, 48, 64, 96, 128] {
            let kernel = ZonalKernel::new(&brdf, ZonalGrid::with_rows(rows)).expect("analytic");
            let mut times: Vec<f64> = (0..15)
                .map(|k| {
                    let t = Instant::now();
                    let _ = zonal(&kernel, &maps[k % maps.len()].1);
                    t.elapsed().as_secs_f64() * 1e3
                })
                .collect();
            times.sort_by(f64::total_cmp);
            println!(
                "rows {rows:4}: {:.2} ms per image (median of 15), kernel {:.1} MB",
                times[7],
                kernel.coefficients() as f64 * 4e-6
            );
        }
        return;
    }
    if let Some(dir) = flag("--library") {
        use matedit_assets::materials::{cache, library};
        let dir = PathBuf::from(dir);
        let lib: Vec<(String, String, BrdfModel)> = library::library()
            .into_iter()
            .filter_map(|m| {
                let fit = cache::load_cached(&dir, &m)?;
                Some((m.name.clone(), m.family.to_string(), BrdfModel::Dsbrdf(Box::new(fit))))
            })
            .collect();
        let mut lines: Vec<String> = lib
            .par_iter()
            .map(|(name, family, brdf)| {
                let t = Instant::now();
                let outcome = ZonalKernel::checked(brdf, &ZonalParams::default());
                let secs = t.elapsed().as_secs_f64();
                match outcome {
                    Ok(k) => {
                        let (error, map) = ProbeReference::new(brdf).map_or((f64::NAN, "none"), |r| probe_error(&k, &r));
                        format!(
                            "{family:9} {name:28} zonal {:3} rows, {:3} env rows {:?}  {:.1} MB  {secs:.2} s  probe {:.3} % ({map})",
                            k.grid().rows,
                            k.grid().env_rows,
                            (k.grid().normal_bands, k.grid().env_bands),
                            k.coefficients() as f64 * 4e-6,
                            100.0 * error
                        )
                    }
                    Err(e) => format!("{family:9} {name:28} per pixel: {e}"),
                }
            })
            .collect();
        lines.sort();
        for l in &lines {
            println!("{l}");
        }
        return;
    }

    let raw = args.iter().any(|a| a == "--raw");
    let kappas = [1e-5, 1e-3, 0.1, 1.0, 3.0, 5.0, 8.0, 12.0, 20.0];
    let gammas = [1e-3, 1.0, 10.0, 100.0, 1e3, 3e3, 1e4];
    println!(
        "RES {res}, {} maps: max relative RMSE of `zonal`{} against `fast` (path; ms per image)",
        maps.len(),
        if raw { " (capped grid, no refusal)" } else { "" }
    );
    println!("| κ \\ γ | {} |", gammas.map(|g| format!("{g:.0e}")).join(" | "));
    println!("|---|{}", "---|".repeat(gammas.len()));
    for &kappa in &kappas {
        let mut cells = Vec::new();
        for &gamma in &gammas {
            let brdf = material(kappa, gamma);
            let t = Instant::now();
            let kernel = if raw {
                ZonalKernel::on_capped_grid(&brdf, &ZonalParams::default())
            } else {
                ZonalKernel::for_brdf(&brdf)
            };
            let build = t.elapsed().as_secs_f64();
            let (mut worst, mut image_s) = (0.0_f64, 0.0);
            for (_, env) in &maps {
                let reference = fast(&brdf, env);
                let t = Instant::now();
                let img = match &kernel {
                    Some(k) => zonal(k, env),
                    None => fast(&brdf, env),
                };
                image_s += t.elapsed().as_secs_f64();
                worst = worst.max(rel_rmse(&img, &reference));
            }
            let path = match &kernel {
                Some(k) => format!("z{} {:.0}MB {build:.1}s", k.grid().rows, k.coefficients() as f64 * 4e-6),
                None => "fast".to_string(),
            };
            cells.push(format!(
                "{:.3} % ({path}; {:.0} ms)",
                100.0 * worst,
                1e3 * image_s / maps.len() as f64
            ));
        }
        println!("| {kappa:.0e} | {} |", cells.join(" | "));
    }
}
