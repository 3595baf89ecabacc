//! Error and cost of the `zonal` quality over the DSBRDF's whole (κ, γ) range.
//!
//! `cargo run --release -p matedit-datagen --example zonal_range -- [RES] [--sharpening] [--raw]`
//!
//! Each material is a matte base (κ 0.2, γ 10⁻³) plus one lobe (κ, γ) on a log grid over the
//! documented range (κ ∈ [10⁻⁵, 20], γ ∈ [10⁻³, 10⁴]); with `--sharpening` the lobe's κ rises
//! from κ/8 at θ_d ≤ 50° to κ at 90° (what fits of measured metals and paints look like). Each
//! is rendered on a RES² sphere (default 128) under four procedural maps (64×128) and, where
//! `$MATEDIT_EVAL_ASSETS` or `../shared/eval-assets` holds them, real HDRIs with a sun or
//! sharp-edged lights at two turns, with `zonal` as the factory runs it (kernel grid chosen per
//! material; a material the grid cannot resolve falls back to `fast`) and with the fast path (the
//! reference: agrees with `exact` to rounding, `tests/zonal.rs`). Prints a table per map set:
//! the largest relative RMSE over the maps, the path taken, the kernel's rows and size, and the
//! time of one image. `--raw` forces the zonal grid even where it would fall back (the error the
//! fallback avoids).

use matedit_datagen::assets::envmaps::Family;
use matedit_datagen::io::load_env;
use matedit_physics::brdf::Dsbrdf;
use matedit_physics::brdf::dsbrdf::{KNOTS, LobeParam, PARAMS, param_index};
use matedit_physics::shading::zonal::{PolarNormals, ZonalEnv, ZonalKernel, ZonalParams, shade_image_zonal};
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

/// A matte base plus one lobe (κ, γ); with `sharpening`, κ rises from κ/8 at θ_d ≤ 50° to κ at
/// grazing.
fn material(kappa: f64, gamma: f64, sharpening: bool) -> BrdfModel {
    let mut p = [0.0; PARAMS];
    for c in 0..3 {
        for j in 0..KNOTS {
            let rise = if sharpening {
                [1.0 / 8.0, 1.0 / 8.0, 1.0 / 8.0, 0.3, 0.7, 1.0][j]
            } else {
                1.0
            };
            let lobes = [(0.2, 1e-3), (kappa * rise, gamma), (1e-5, 1e4)];
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

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let sharpening = args.iter().any(|a| a == "--sharpening");
    let raw = args.iter().any(|a| a == "--raw");
    let res: usize = args.iter().find_map(|a| a.parse().ok()).unwrap_or(128);
    let (normals, mask) = matedit_physics::camera::unit_sphere_normals(res);
    let pixels = PolarNormals::new(&normals, &mask);
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
    let all = args.iter().any(|a| a == "--all-maps");
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
                for (yaw, pitch) in [(0.0, -20.0), (130.0, -20.0)] {
                    maps.push((format!("{name}@{yaw}"), map.tilted(64, yaw, pitch)));
                }
            }
            Err(e) => eprintln!("skipping {name}: {e:#}"),
        }
    }
    // `--spec SPEC`: the checked kernel of any `--brdf` spec and the sun share of each map.
    if let Some(i) = args.iter().position(|a| a == "--spec") {
        let spec: matedit_physics::BrdfSpec = args[i + 1].parse().expect("spec");
        let brdf = spec.build().expect("brdf");
        match ZonalKernel::checked(&brdf, &ZonalParams::default()) {
            Ok(k) => println!("{} rows, holds sun share ≤ {:.4}", k.grid().rows, k.max_sun_share()),
            Err(e) => println!("refused: {e}"),
        }
        for (name, env) in &maps {
            println!(
                "{name:28} sun share {:.4}",
                matedit_physics::shading::zonal::sun_share(env)
            );
        }
        return;
    }
    // `--sun-share`: the share of each map's power (L·dω) in its brightest texel and 0.1 %.
    if args.iter().any(|a| a == "--sun-share") {
        for (name, env) in &maps {
            let (w, h) = (env.width(), env.height());
            let mut p: Vec<f64> = (0..w * h)
                .map(|t| {
                    let l = env.texels()[t];
                    (l[0] + l[1] + l[2]) as f64 * matedit_physics::envmap::texel_solid_angle(t / w, w, h)
                })
                .collect();
            p.sort_by(|a, b| b.total_cmp(a));
            let total: f64 = p.iter().sum();
            let top: f64 = p[..(w * h / 1000).max(1)].iter().sum();
            println!(
                "{name:28} brightest texel {:.1} %, brightest 0.1 % {:.1} %",
                100.0 * p[0] / total,
                100.0 * top / total
            );
        }
        return;
    }
    // `--library DIR`: where the fitted library lands (rows needed, off the grid) per spacing.
    if let Some(i) = args.iter().position(|a| a == "--library") {
        use matedit_datagen::materials::{cache, library};
        let dir = PathBuf::from(&args[i + 1]);
        let lib: Vec<(String, String, BrdfModel)> = library::library()
            .into_iter()
            .filter_map(|m| {
                let fit = cache::load_cached(&dir, &m)?;
                Some((m.name.clone(), m.family.to_string(), BrdfModel::Dsbrdf(Box::new(fit))))
            })
            .collect();
        // The checked build, as the factory runs it: rows, measured error, build time.
        let mut lines: Vec<String> = lib
            .par_iter()
            .map(|(name, family, brdf)| {
                let t = Instant::now();
                let outcome = ZonalKernel::checked(brdf, &ZonalParams::default());
                let secs = t.elapsed().as_secs_f64();
                match outcome {
                    Ok(k) => format!(
                        "{family:9} {name:28} zonal {:3} rows  holds up to sun share {:.2}  {:.1} MB  {secs:.2} s",
                        k.grid().rows,
                        k.max_sun_share(),
                        k.coefficients() as f64 * 4e-6
                    ),
                    Err(e) => format!("{family:9} {name:28} FAST: {e}  ({secs:.2} s)"),
                }
            })
            .collect();
        lines.sort();
        for l in &lines {
            println!("{l}");
        }
        println!(
            "{} of {} on the zonal grid",
            lines.iter().filter(|l| l.contains(" zonal ")).count(),
            lines.len()
        );
        return;
    }
    // `--cost KAPPA,GAMMA`: time of one image (spectra + table + interpolation) per grid size.
    if let Some(i) = args.iter().position(|a| a == "--cost") {
        let v: Vec<f64> = args[i + 1].split(',').map(|x| x.parse().expect("number")).collect();
        let brdf = material(v[0], v[1], sharpening);
        for rows in [32, 40, 48, 64, 96, 128] {
            let grid = matedit_physics::shading::zonal::ZonalGrid::with_rows(rows);
            let kernel = ZonalKernel::new(&brdf, grid).expect("analytic");
            let mut times: Vec<f64> = (0..15)
                .map(|k| {
                    let env = &maps[k % maps.len()].1;
                    let t = Instant::now();
                    let _ = shade_image_zonal(&kernel, &ZonalEnv::new(env, grid), &pixels, &mask);
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
    // `--probe KAPPA,GAMMA,ROWS`: one material on a forced grid, error per map.
    if let Some(i) = args.iter().position(|a| a == "--probe") {
        let v: Vec<f64> = args[i + 1].split(',').map(|x| x.parse().expect("number")).collect();
        let brdf = material(v[0], v[1], sharpening);
        let kernel = ZonalKernel::new(
            &brdf,
            matedit_physics::shading::zonal::ZonalGrid::with_rows(v[2] as usize),
        )
        .expect("analytic");
        for (name, env) in &maps {
            let reference = shade_image(make_shader(&brdf, env, Quality::Fast).as_ref(), &normals, &mask, None).0;
            let img = shade_image_zonal(&kernel, &ZonalEnv::new(env, kernel.grid()), &pixels, &mask).0;
            println!("{name:28} {:.3} %", 100.0 * rel_rmse(&img, &reference));
        }
        match ZonalKernel::checked(&brdf, &ZonalParams::default()) {
            Ok(k) => println!(
                "checked: {} rows, holds up to sun share {:.2}",
                k.grid().rows,
                k.max_sun_share()
            ),
            Err(e) => println!("checked: refused ({e})"),
        }
        return;
    }
    let kappas = [1e-5, 1e-3, 0.1, 1.0, 3.0, 5.0, 8.0, 12.0, 20.0];
    let gammas = [1e-3, 1.0, 10.0, 100.0, 1e3, 3e3, 1e4];
    println!(
        "RES {res}, {} maps, lobe κ {}: max relative RMSE of `zonal`{} against `fast`",
        maps.len(),
        if sharpening {
            "rising ×8 towards grazing"
        } else {
            "constant in θ_d"
        },
        if raw { " (grid forced, no fallback)" } else { "" }
    );
    println!("| κ \\ γ | {} |", gammas.map(|g| format!("{g:.0e}")).join(" | "));
    println!("|---|{}", "---|".repeat(gammas.len()));
    for &kappa in &kappas {
        let mut cells = Vec::new();
        for &gamma in &gammas {
            let brdf = material(kappa, gamma, sharpening);
            let t = Instant::now();
            let kernel = if raw {
                ZonalKernel::on_capped_grid(&brdf, &ZonalParams::default())
            } else {
                ZonalKernel::for_brdf(&brdf)
            };
            let build = t.elapsed().as_secs_f64();
            let mut worst = 0.0_f64;
            let mut image_s = 0.0;
            let mut fell_back = 0;
            for (_, env) in &maps {
                let reference = shade_image(make_shader(&brdf, env, Quality::Fast).as_ref(), &normals, &mask, None).0;
                let t = Instant::now();
                let img = match &kernel {
                    Some(k) if raw || k.holds_under(env) => {
                        shade_image_zonal(k, &ZonalEnv::new(env, k.grid()), &pixels, &mask).0
                    }
                    Some(_) => {
                        fell_back += 1;
                        shade_image(make_shader(&brdf, env, Quality::Fast).as_ref(), &normals, &mask, None).0
                    }
                    None => shade_image(make_shader(&brdf, env, Quality::Fast).as_ref(), &normals, &mask, None).0,
                };
                image_s += t.elapsed().as_secs_f64();
                worst = worst.max(rel_rmse(&img, &reference));
            }
            let path = match &kernel {
                Some(k) => format!(
                    "z{} {:.0}MB {build:.1}s, share ≤ {:.2}, {fell_back} maps fast",
                    k.grid().rows,
                    k.coefficients() as f64 * 4e-6,
                    k.max_sun_share()
                ),
                None => "fast".to_string(),
            };
            cells.push(format!(
                "{:.3} % ({path}, {:.0} ms)",
                100.0 * worst,
                1e3 * image_s / maps.len() as f64
            ));
        }
        println!("| {kappa:.0e} | {} |", cells.join(" | "));
    }
}
