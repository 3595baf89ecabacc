//! Shading throughput of Eq. 2: (pixel × texel) evaluations per second for each BRDF, fast path
//! on 1 thread and on all threads, and the exact path on 1 thread.
//!
//! `cargo run --release -p matedit-physics --example shading_throughput [RES] [ENV_ROWS] [REPEATS]`
//!
//! The scene is the unit sphere at RES² (object pixels only) under a smooth synthetic 64×128 map
//! with no black texels, so every pixel sums over every texel. Prints the median of REPEATS runs.

use matedit_physics::EnvMap;
use matedit_physics::brdf::{BrdfModel, Dsbrdf, Fresnel, Ggx, Lambert, Plastic};
use matedit_physics::shading::{Quality, make_shader, shade_image};
use std::time::Instant;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

fn main() {
    let args: Vec<usize> = std::env::args().skip(1).filter_map(|a| a.parse().ok()).collect();
    let res = args.first().copied().unwrap_or(256);
    let rows = args.get(1).copied().unwrap_or(64);
    let repeats = args.get(2).copied().unwrap_or(5);
    let env = EnvMap::from_fn(rows, |d| {
        [(1.2 + d.x) as f32, (1.5 + d.y) as f32, (1.1 - 0.5 * d.z) as f32]
    });
    let (normals, mask) = matedit_physics::camera::unit_sphere_normals(res);
    let covered = mask.iter().filter(|m| **m > 0.0).count();
    let brdfs = [
        (
            "lambert",
            BrdfModel::Lambert(Lambert {
                albedo: [0.5, 0.4, 0.3],
            }),
        ),
        ("ggx", BrdfModel::Ggx(Ggx::new(0.3, Fresnel::Schlick([0.9, 0.6, 0.3])))),
        ("plastic", BrdfModel::Plastic(Plastic::new(0.2, [0.6, 0.2, 0.1]))),
        (
            "dsbrdf",
            BrdfModel::Dsbrdf(Box::new(Dsbrdf::isotropic_in_theta_d(
                [[(0.15, 0.01), (1.5, 40.0), (6.0, 900.0)]; 3],
            ))),
        ),
    ];
    let threads = rayon::current_num_threads();
    println!(
        "# sphere {res}x{res} ({covered} object px), env {rows}x{} ({} texels), median of {repeats}",
        2 * rows,
        2 * rows * rows
    );
    println!(
        "| BRDF | fast, 1 thread (pairs/s) | fast, {threads} threads (pairs/s) | exact, 1 thread (pairs/s) | image time fast {threads} thr (s) |"
    );
    println!("|---|---|---|---|---|");
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("thread pool");
    for (name, brdf) in &brdfs {
        let fast = make_shader(brdf, &env, Quality::Fast);
        let pairs = (covered * fast.light_dirs().len()) as f64;
        let time = |f: &dyn Fn()| {
            median(
                (0..repeats)
                    .map(|_| {
                        let t = Instant::now();
                        f();
                        t.elapsed().as_secs_f64()
                    })
                    .collect(),
            )
        };
        let t1 = time(&|| one.install(|| drop(shade_image(fast.as_ref(), &normals, &mask, None))));
        let tn = time(&|| drop(shade_image(fast.as_ref(), &normals, &mask, None)));
        // The exact path is ~100× slower: time it on a 1/16 subsample of the object pixels.
        let exact = make_shader(brdf, &env, Quality::Exact);
        let sub: Vec<f32> = mask
            .iter()
            .enumerate()
            .map(|(i, m)| if i % 16 == 0 { *m } else { 0.0 })
            .collect();
        let sub_pairs = (sub.iter().filter(|m| **m > 0.0).count() * exact.light_dirs().len()) as f64;
        let te = time(&|| one.install(|| drop(shade_image(exact.as_ref(), &normals, &sub, None))));
        println!(
            "| {name} | {:.3e} | {:.3e} | {:.3e} | {tn:.3} |",
            pairs / t1,
            pairs / tn,
            sub_pairs / te
        );
    }
}
