//! The fast path against the exact path, on hard cases: grazing and back-facing normals, sharp
//! and extreme lobes, a sun far brighter than the sky, shadows, and garbage normals.

mod common;
use common::{gamma_range, kappa_range};
use glam::DVec3;
use matedit_assets::envmaps::builtin;
use matedit_physics::EnvMap;
use matedit_physics::brdf::{BrdfModel, Dsbrdf, Fresnel, Ggx, Lambert, Plastic};
use matedit_physics::shading::{Quality, Shader, make_shader};

fn brdfs() -> Vec<(&'static str, BrdfModel)> {
    vec![
        (
            "lambert",
            BrdfModel::Lambert(Lambert {
                albedo: [0.9, 0.5, 0.05],
            }),
        ),
        (
            "ggx-0.05",
            BrdfModel::Ggx(Ggx::new(0.05, Fresnel::Schlick([0.95, 0.64, 0.54]))),
        ),
        ("ggx-0.3", BrdfModel::Ggx(Ggx::new(0.3, Fresnel::None))),
        ("ggx-1", BrdfModel::Ggx(Ggx::new(1.0, Fresnel::Schlick([0.04; 3])))),
        ("plastic", BrdfModel::Plastic(Plastic::new(0.15, [0.7, 0.1, 0.1]))),
        (
            "dsbrdf",
            BrdfModel::Dsbrdf(Box::new(Dsbrdf::isotropic_in_theta_d(
                [[(0.1, 0.01), (1.5, 30.0), (5.0, 900.0)]; 3],
            ))),
        ),
        (
            "dsbrdf-lambertian",
            BrdfModel::Dsbrdf(Box::new(Dsbrdf::near_lambertian([0.5, 0.3, 0.1]))),
        ),
        (
            "dsbrdf-extremes",
            BrdfModel::Dsbrdf(Box::new(Dsbrdf::isotropic_in_theta_d(
                [[
                    (kappa_range().1, gamma_range().1),
                    (kappa_range().0, gamma_range().0),
                    (kappa_range().1 * 0.5, gamma_range().0),
                ]; 3],
            ))),
        ),
    ]
}

fn normals() -> Vec<[f32; 3]> {
    let mut v = vec![
        [0.0, 0.0, 1.0],
        [0.0, 1.0, 1e-4],   // grazing
        [1.0, 0.0, 0.0],    // exactly grazing
        [0.7, -0.7, -0.14], // back-facing interpolated normal
        [0.3, 0.3, 0.905],
        [-0.99, 0.1, 0.0995],
        [0.0, -0.5, 0.866],
    ];
    // A deterministic spread over the visible hemisphere.
    for i in 0..40 {
        let u = (i as f64 + 0.5) / 40.0;
        let phi = i as f64 * 2.399963;
        let z = u;
        let r = (1.0 - z * z).sqrt();
        v.push([(r * phi.cos()) as f32, (r * phi.sin()) as f32, z as f32]);
    }
    v
}

fn compare(env: &EnvMap, vis: bool) {
    for (name, brdf) in brdfs() {
        let fast = make_shader(&brdf, env, Quality::Fast);
        let exact = matedit_physics::shading::exact::ExactShader::new(brdf.clone(), env);
        let ns = normals();
        let results: Vec<([f32; 3], [f64; 3])> = ns
            .iter()
            .enumerate()
            .map(|(k, n)| {
                if vis {
                    // Same pseudo-random shadow pattern by direction for both paths.
                    let pattern = |d: &[f32; 3]| {
                        if ((d[0] * 97.0 + d[1] * 31.0 + k as f32).sin()) > 0.0 {
                            1.0
                        } else {
                            0.0
                        }
                    };
                    let vf: Vec<f32> = fast.light_dirs().iter().map(pattern).collect();
                    let ve: Vec<f32> = exact.light_dirs().iter().map(pattern).collect();
                    (fast.shade(*n, Some(&vf)), exact.shade_f64(*n, Some(&ve)))
                } else {
                    (fast.shade(*n, None), exact.shade_f64(*n, None))
                }
            })
            .collect();
        let scale = results.iter().flat_map(|r| r.1).fold(0.0, f64::max);
        for (n, (f, e)) in ns.iter().zip(&results) {
            for c in 0..3 {
                assert!(f[c].is_finite() && f[c] >= 0.0, "{name} n={n:?}: {f:?}");
                let err = (f[c] as f64 - e[c]).abs();
                assert!(
                    err <= 1e-4 * e[c].abs() + 1e-7 * scale,
                    "{name} vis={vis} n={n:?} c={c}: fast {} exact {} (rel {:.2e})",
                    f[c],
                    e[c],
                    err / e[c].abs()
                );
            }
        }
    }
}

#[test]
fn fast_matches_exact_to_1e4_under_a_sky_with_a_sun() {
    compare(&builtin("sky").unwrap().resampled(32, 0.0), false);
}

#[test]
fn fast_matches_exact_to_1e4_under_a_studio_with_shadows() {
    compare(&builtin("studio").unwrap().resampled(32, 30.0), true);
}

#[test]
fn fast_matches_exact_under_extreme_dynamic_range() {
    // A 1e6 "sun" over a 1e-3 sky: 9 orders of magnitude.
    let env = EnvMap::from_fn(32, |d| {
        if d.dot(DVec3::new(0.3, 0.5, 0.81).normalize()) > 0.99 {
            [1e6; 3]
        } else {
            [1e-3; 3]
        }
    });
    compare(&env, false);
}

#[test]
fn garbage_normals_shade_to_black_without_nan() {
    let env = builtin("sky").unwrap().resampled(16, 0.0);
    for (_, brdf) in brdfs() {
        for q in [Quality::Fast, Quality::Exact] {
            let s: Box<dyn Shader> = make_shader(&brdf, &env, q);
            for n in [
                [f32::NAN, 0.0, 1.0],
                [0.0, 0.0, 0.0],
                [f32::INFINITY, 1.0, 1.0],
                [0.0, 0.0, -1.0],
                [1e-30, 0.0, 0.0],
            ] {
                assert_eq!(s.shade(n, None), [0.0; 3], "{q:?} {n:?}");
            }
        }
    }
}

#[test]
fn huge_radiance_never_produces_inf_or_nan_in_an_image() {
    let env = EnvMap::constant(8, [3e37, 3e37, 3e37]);
    let brdf = BrdfModel::Dsbrdf(Box::new(Dsbrdf::isotropic_in_theta_d(
        [[(kappa_range().1, gamma_range().0); 3]; 3],
    )));
    let s = make_shader(&brdf, &env, Quality::Fast);
    let normals = vec![[0.0, 0.0, 1.0], [0.5, 0.5, 0.7]];
    let (img, bad) = matedit_physics::shading::shade_image(s.as_ref(), &normals, &[1.0, 1.0], None);
    assert!(img.iter().flatten().all(|v| v.is_finite()));
    assert_eq!(bad, 2, "both pixels overflowed and were clamped");
}
