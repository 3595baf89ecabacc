//! The `zonal` quality (Eq. 2 as a convolution about the view axis) against the exact path: whole
//! images of a sphere under a sky with a sun, a studio, and a map with a 10⁹ dynamic range, for
//! analytic BRDFs and DSBRDFs from matte to glossy; hard normals and extreme lobes stay finite;
//! the bits do not depend on the thread count.

mod common;
use common::*;
use glam::DVec3;
use matedit_datagen::assets::envmaps::builtin;
use matedit_physics::EnvMap;
use matedit_physics::brdf::dsbrdf::{GAMMA_RANGE, KAPPA_RANGE};
use matedit_physics::brdf::{BrdfModel, Dsbrdf, Fresnel, Ggx, Lambert, Plastic};
use matedit_physics::camera::unit_sphere_normals;
use matedit_physics::shading::exact::ExactShader;
use matedit_physics::shading::zonal::{PolarNormals, ZonalEnv, ZonalGrid, ZonalKernel, shade_image_zonal};
use matedit_physics::shading::{Quality, shade_image, shade_with};

/// Materials the grid resolves (their sharpest energetic lobe is at least ~2 grid spacings
/// wide at the 128-row cap), with the relative RMSE each may have against the exact path.
fn resolvable() -> Vec<(&'static str, BrdfModel, f64)> {
    vec![
        (
            "lambert",
            BrdfModel::Lambert(Lambert {
                albedo: [0.9, 0.5, 0.05],
            }),
            3e-3,
        ),
        ("ggx-0.3", BrdfModel::Ggx(Ggx::new(0.3, Fresnel::None)), 5e-3),
        (
            "ggx-1",
            BrdfModel::Ggx(Ggx::new(1.0, Fresnel::Schlick([0.04; 3]))),
            3e-3,
        ),
        (
            "plastic-0.15",
            BrdfModel::Plastic(Plastic::new(0.15, [0.7, 0.1, 0.1])),
            5e-3,
        ),
        (
            "dsbrdf-glossy",
            BrdfModel::Dsbrdf(Box::new(Dsbrdf::isotropic_in_theta_d(
                [[(0.1, 0.01), (1.5, 30.0), (0.4, 600.0)]; 3],
            ))),
            5e-3,
        ),
        (
            "dsbrdf-lambertian",
            BrdfModel::Dsbrdf(Box::new(Dsbrdf::near_lambertian([0.5, 0.3, 0.1]))),
            3e-3,
        ),
        (
            "red-plastic-file",
            BrdfModel::Dsbrdf(Box::new(
                Dsbrdf::load(std::path::Path::new(concat!(
                    env!("CARGO_MANIFEST_DIR"),
                    "/assets/materials/red_plastic.dsbrdf.json"
                )))
                .expect("example material"),
            )),
            5e-3,
        ),
    ]
}

fn maps() -> Vec<(&'static str, EnvMap)> {
    let sun = DVec3::new(0.3, 0.5, 0.81).normalize();
    vec![
        ("sky", builtin("sky").expect("builtin").resampled(32, 0.0)),
        ("studio", builtin("studio").expect("builtin").resampled(32, 30.0)),
        (
            "1e9 range",
            EnvMap::from_fn(32, |d| if d.dot(sun) > 0.99 { [1e6; 3] } else { [1e-3; 3] }),
        ),
    ]
}

fn exact_image(brdf: &BrdfModel, env: &EnvMap, normals: &[[f32; 3]], mask: &[f32]) -> Vec<[f32; 3]> {
    let exact = ExactShader::new(brdf.clone(), env);
    shade_image(&exact, normals, mask, None).0
}

#[test]
fn zonal_images_match_the_exact_path() {
    let res = 40;
    let (normals, mask) = unit_sphere_normals(res);
    let pixels: Vec<usize> = (0..mask.len()).filter(|&p| mask[p] > 0.0).collect();
    for (name, brdf, tol) in resolvable() {
        for (map, env) in maps() {
            let (zonal, bad) = shade_with(&brdf, &env, Quality::Zonal, &normals, &mask, None);
            assert_eq!(bad, 0, "{name} under {map}");
            let exact = exact_image(&brdf, &env, &normals, &mask);
            let e = rel_rmse(&zonal, &exact, &pixels);
            eprintln!("{name:18} {map:10} {:.4} %", 100.0 * e);
            assert!(e < tol, "{name} under {map}: relative RMSE {e:.2e} (allowed {tol:.0e})");
        }
    }
}

#[test]
fn zonal_furnace_gives_the_albedo() {
    // Constant radiance 1, Lambert ρ: every normal reflects ρ (Eq. 2's texel sum is within
    // 0.024 % of the integral at 64×128).
    let env = EnvMap::constant(64, [1.0; 3]);
    let (normals, mask) = unit_sphere_normals(48);
    let brdf = BrdfModel::Lambert(Lambert { albedo: [0.5; 3] });
    let (img, _) = shade_with(&brdf, &env, Quality::Zonal, &normals, &mask, None);
    for p in fully_covered(48) {
        for c in 0..3 {
            let e = (img[p][c] as f64 - 0.5).abs() / 0.5;
            assert!(e < 2e-3, "pixel {p}: {:?}", img[p]);
        }
    }
}

#[test]
fn hard_normals_and_extreme_lobes_stay_finite_and_non_negative() {
    let mut normals = vec![
        [0.0, 0.0, 1.0],
        [0.0, 1.0, 1e-4],
        [1.0, 0.0, 0.0],
        [0.7, -0.7, -0.14],
        [-0.99, 0.1, 0.0995],
        [f32::NAN, 0.0, 1.0],
        [0.0, 0.0, 0.0],
        [f32::INFINITY, 1.0, 1.0],
        [0.0, 0.0, -1.0],
        [1e-30, 0.0, 0.0],
    ];
    for i in 0..64 {
        let z = (i as f64 + 0.5) / 64.0;
        let phi = i as f64 * 2.399963;
        let r = (1.0 - z * z).sqrt();
        normals.push([(r * phi.cos()) as f32, (r * phi.sin()) as f32, z as f32]);
    }
    let mask = vec![1.0; normals.len()];
    let extremes = [
        [(KAPPA_RANGE.1, GAMMA_RANGE.1); 3],
        [(KAPPA_RANGE.1, GAMMA_RANGE.0); 3],
        [(KAPPA_RANGE.0, GAMMA_RANGE.1); 3],
        [(KAPPA_RANGE.0, GAMMA_RANGE.0); 3],
    ];
    let env = EnvMap::from_fn(16, |d| if d.y > 0.99 { [1e6; 3] } else { [1e-3; 3] });
    for lobes in extremes {
        let brdf = BrdfModel::Dsbrdf(Box::new(Dsbrdf::isotropic_in_theta_d([lobes; 3])));
        let (img, _) = shade_with(&brdf, &env, Quality::Zonal, &normals, &mask, None);
        for (n, v) in normals.iter().zip(&img) {
            assert!(v.iter().all(|x| x.is_finite() && *x >= 0.0), "{lobes:?} n={n:?}: {v:?}");
        }
        // No usable normal, no light.
        for k in 5..10 {
            assert_eq!(img[k], [0.0; 3], "{:?}", normals[k]);
        }
    }
    // Radiance near f32::MAX: clamped and counted, never Inf or NaN.
    let env = EnvMap::constant(8, [3e37; 3]);
    let brdf = BrdfModel::Dsbrdf(Box::new(Dsbrdf::isotropic_in_theta_d(
        [[(KAPPA_RANGE.1, GAMMA_RANGE.0); 3]; 3],
    )));
    let (img, bad) = shade_with(&brdf, &env, Quality::Zonal, &normals[..2], &mask[..2], None);
    assert!(img.iter().flatten().all(|v| v.is_finite()), "{img:?}");
    assert_eq!(bad, 2, "{img:?}");
}

#[test]
fn zonal_bits_do_not_depend_on_the_thread_count() {
    let (normals, mask) = unit_sphere_normals(48);
    let env = builtin("sky").expect("builtin").resampled(64, 10.0);
    let brdf = resolvable().remove(4).1;
    let render = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool")
            .install(|| {
                let kernel = ZonalKernel::new(&brdf, ZonalGrid::with_rows(48)).expect("analytic");
                let spectra = ZonalEnv::new(&env, kernel.grid());
                let pixels = PolarNormals::new(&normals, &mask);
                shade_image_zonal(&kernel, &spectra, &pixels, &mask).0
            })
    };
    let one = render(1);
    for threads in [2, 3] {
        assert!(
            one.iter()
                .flatten()
                .zip(render(threads).iter().flatten())
                .all(|(a, b)| a.to_bits() == b.to_bits()),
            "{threads} threads"
        );
    }
}

#[test]
fn measured_brdfs_fall_back_to_the_exact_path() {
    // A MERL table has no known sharpness: no zonal kernel, and `zonal` renders it exactly.
    use matedit_physics::brdf::MerlBrdf;
    let bytes = MerlBrdf::tabulate_bytes(&Lambert {
        albedo: [0.4, 0.3, 0.2],
    });
    let table = MerlBrdf::from_bytes(&bytes, "tabulated lambert").expect("valid table");
    let brdf = BrdfModel::Measured(std::sync::Arc::new(table));
    assert!(ZonalKernel::for_brdf(&brdf).is_none());
    let env = builtin("sky").expect("builtin").resampled(8, 0.0);
    let (normals, mask) = unit_sphere_normals(6);
    let (z, _) = shade_with(&brdf, &env, Quality::Zonal, &normals, &mask, None);
    assert_eq!(z, exact_image(&brdf, &env, &normals, &mask));
}
