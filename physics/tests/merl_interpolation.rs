//! MERL tables written from analytic BRDFs, rendered on a sphere with the exact shader, against
//! the analytic BRDFs themselves: the trilinear lookup against the nearest-sample lookup, and
//! the cost of one `eval` of each.
//!
//! `cargo test --release -p matedit-physics --test merl_interpolation -- --nocapture` prints the table of
//! `docs/PERFORMANCE.md` ("MERL lookups: nearest vs interpolated"). `MATEDIT_MERL_SPHERE` and
//! `MATEDIT_MERL_ENV_ROWS` (default 64 and 32) set the sphere's and the environment's resolution.

mod common;
use common::rel_rmse;
use glam::DVec3;
use matedit_assets::envmaps::builtin;
use matedit_physics::EnvMap;
use matedit_physics::brdf::merl::MerlLookup;
use matedit_physics::brdf::{Brdf, BrdfModel, Fresnel, Ggx, Lambert, MerlBrdf};
use matedit_physics::camera::unit_sphere_normals;
use matedit_physics::shading::exact::ExactShader;
use matedit_physics::shading::shade_image;
use std::sync::Arc;
use std::time::Instant;

fn env_usize(name: &str, default: usize) -> usize {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

fn brdfs() -> Vec<(String, BrdfModel)> {
    let mut v = vec![(
        "lambert".to_string(),
        BrdfModel::Lambert(Lambert {
            albedo: [0.8, 0.5, 0.2],
        }),
    )];
    for alpha in [0.1, 0.2, 0.3, 0.4, 0.5] {
        v.push((format!("ggx α {alpha}"), BrdfModel::Ggx(Ggx::new(alpha, Fresnel::None))));
    }
    // A dielectric's F0: Fresnel rises 25-fold towards grazing θ_d, the most θ_d structure a
    // Schlick term can put in the table.
    for alpha in [0.1, 0.2, 0.3, 0.4, 0.5] {
        v.push((
            format!("ggx α {alpha} F0 0.04"),
            BrdfModel::Ggx(Ggx::new(alpha, Fresnel::Schlick([0.04; 3]))),
        ));
    }
    v
}

fn render(brdf: BrdfModel, env: &EnvMap, normals: &[[f32; 3]], mask: &[f32]) -> Vec<[f32; 3]> {
    let (img, bad) = shade_image(&ExactShader::new(brdf, env), normals, mask, None);
    assert_eq!(bad, 0);
    img
}

#[test]
fn interpolated_merl_tables_render_like_their_analytic_brdfs_and_beat_nearest_lookups() {
    let res = env_usize("MATEDIT_MERL_SPHERE", 64);
    let rows = env_usize("MATEDIT_MERL_ENV_ROWS", 32);
    let maps = [
        ("sky", builtin("sky").expect("builtin map").resampled(rows, 0.0)),
        ("studio", builtin("studio").expect("builtin map").resampled(rows, 30.0)),
    ];
    let (normals, mask) = unit_sphere_normals(res);
    let pixels: Vec<usize> = (0..mask.len()).filter(|&p| mask[p] > 0.0).collect();
    println!(
        "sphere {res}², environment {rows}×{}, {} object pixels",
        2 * rows,
        pixels.len()
    );
    println!("relative RMSE of the table-rendered image against the analytic one (%):");
    println!("| BRDF | map | nearest | trilinear |");
    println!("|---|---|---|---|");
    let mut failures = Vec::new();
    for (name, brdf) in brdfs() {
        let table = MerlBrdf::tabulate(&brdf);
        let nearest = BrdfModel::Measured(Arc::new(table.clone().with_lookup(MerlLookup::Nearest)));
        let trilinear = BrdfModel::Measured(Arc::new(table));
        for (map, env) in &maps {
            let truth = render(brdf.clone(), env, &normals, &mask);
            let e_near = rel_rmse(&render(nearest.clone(), env, &normals, &mask), &truth, &pixels);
            let e_tri = rel_rmse(&render(trilinear.clone(), env, &normals, &mask), &truth, &pixels);
            println!("| {name} | {map} | {:.3} | {:.3} |", 100.0 * e_near, 100.0 * e_tri);
            // NaN counts as a failure: `is_lt` is false for incomparable values.
            if !e_tri.partial_cmp(&e_near).is_some_and(|o| o.is_lt()) {
                failures.push(format!(
                    "{name} under {map}: trilinear {e_tri:.2e} not below nearest {e_near:.2e}"
                ));
            }
            if name == "ggx α 0.3" && !e_tri.partial_cmp(&5e-3).is_some_and(|o| o.is_le()) {
                failures.push(format!("{name} under {map}: trilinear {e_tri:.2e} above 0.5 %"));
            }
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

#[test]
fn eval_cost_of_each_lookup() {
    // Not asserted (the machine is shared); printed for docs/PERFORMANCE.md. Two access
    // patterns: independent random direction pairs (nearly every table access misses the cache:
    // the table is 17.5 MB) and the exact shader's (one pixel's texels in order, so consecutive
    // lookups land near each other in the table).
    let analytic = Ggx::new(0.3, Fresnel::Schlick([0.04; 3]));
    let table = MerlBrdf::tabulate(&analytic);
    let nearest = table.clone().with_lookup(MerlLookup::Nearest);
    let n = 1_000_000;
    let a = [
        0.819_172_513_396_164_4,
        0.671_043_606_703_789_2,
        0.549_700_477_901_970_5,
    ];
    let pairs: Vec<(DVec3, DVec3)> = (0..n)
        .map(|k| {
            let [u, v, w] = a.map(|x: f64| (0.5 + x * k as f64).fract());
            let dir = |c: f64, p: f64| {
                let s = (1.0 - c * c).sqrt();
                DVec3::new(s * p.cos(), s * p.sin(), c)
            };
            (dir(u.max(1e-3), std::f64::consts::TAU * v), dir(w.max(1e-3), 0.0))
        })
        .collect();
    let random = |b: &dyn Brdf| {
        let mut best = f64::INFINITY;
        let mut sink = 0.0;
        for _ in 0..3 {
            let t = Instant::now();
            for &(wi, wo) in &pairs {
                sink += b.eval(wi, wo)[0];
            }
            best = best.min(t.elapsed().as_secs_f64());
        }
        assert!(sink.is_finite());
        1e9 * best / n as f64
    };
    let rows = 32;
    let env = builtin("sky").expect("builtin map").resampled(rows, 0.0);
    let (normals, mask) = unit_sphere_normals(48);
    let pixels = mask.iter().filter(|&&m| m > 0.0).count();
    let one_thread = rayon::ThreadPoolBuilder::new().num_threads(1).build().expect("pool");
    let shaded = |b: BrdfModel| {
        let shader = ExactShader::new(b, &env);
        let mut best = f64::INFINITY;
        for _ in 0..3 {
            let t = Instant::now();
            one_thread.install(|| shade_image(&shader, &normals, &mask, None));
            best = best.min(t.elapsed().as_secs_f64());
        }
        1e9 * best / (pixels * 2 * rows * rows) as f64
    };
    println!("ns per eval, 1 thread, best of 3:");
    println!(
        "| BRDF | random pairs ({n}) | exact shader (48² sphere, {rows}×{} map, per pixel–texel pair) |",
        2 * rows
    );
    println!("|---|---|---|");
    for (name, brdf) in [
        (
            "analytic GGX α 0.3 F0 0.04 (for scale)",
            BrdfModel::Ggx(analytic.clone()),
        ),
        ("its MERL table, nearest", BrdfModel::Measured(Arc::new(nearest))),
        ("its MERL table, trilinear", BrdfModel::Measured(Arc::new(table))),
    ] {
        println!("| {name} | {:.1} | {:.1} |", random(&brdf), shaded(brdf.clone()));
    }
}
