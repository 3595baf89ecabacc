//! The `zonal` quality (Eq. 2 as a convolution about the view axis) against the exact path: whole
//! images of a sphere under a sky with a sun, a studio, and a map with a 10⁹ dynamic range, for
//! analytic BRDFs and DSBRDFs from matte to glossy; hard normals and extreme lobes stay finite;
//! the bits do not depend on the thread count.

mod common;
use common::*;
use glam::DVec3;
use matedit_assets::envmaps::builtin;
use matedit_physics::EnvMap;
use matedit_physics::brdf::dsbrdf::{GAMMA_RANGE, KAPPA_RANGE};
use matedit_physics::brdf::{BrdfModel, Dsbrdf, Fresnel, Ggx, Lambert, Plastic};
use matedit_physics::camera::unit_sphere_normals;
use matedit_physics::shading::exact::ExactShader;
use matedit_physics::shading::zonal::{PolarNormals, ZonalEnv, ZonalGrid, ZonalKernel, shade_image_zonal};
use matedit_physics::shading::{Quality, VisibilityFn, shade_image, shade_with};

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
                    "/../assets/materials/red_plastic.dsbrdf.json"
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
        [(kappa_range().1, gamma_range().1); 3],
        [(kappa_range().1, gamma_range().0); 3],
        [(kappa_range().0, gamma_range().1); 3],
        [(kappa_range().0, gamma_range().0); 3],
    ];
    let env = EnvMap::from_fn(16, |d| if d.y > 0.99 { [1e6; 3] } else { [1e-3; 3] });
    let pixels = PolarNormals::new(&normals, &mask);
    for lobes in extremes {
        let brdf = BrdfModel::Dsbrdf(Box::new(Dsbrdf::isotropic_in_theta_d([lobes; 3])));
        // As the factory routes it (sharp extremes leave the grid for the fast path), and the
        // grid's own arithmetic on the capped grid.
        let kernel = ZonalKernel::on_capped_grid(&brdf, &Default::default()).expect("analytic");
        let routed = shade_with(&brdf, &env, Quality::Zonal, &normals, &mask, None).0;
        let raw = shade_image_zonal(&kernel, &ZonalEnv::new(&env, kernel.grid()), &pixels, &mask).0;
        for img in [routed, raw] {
            for (n, v) in normals.iter().zip(&img) {
                assert!(v.iter().all(|x| x.is_finite() && *x >= 0.0), "{lobes:?} n={n:?}: {v:?}");
            }
            // No usable normal, no light.
            for k in 5..10 {
                assert_eq!(img[k], [0.0; 3], "{:?}", normals[k]);
            }
        }
    }
    // Radiance near f32::MAX: clamped and counted, never Inf or NaN.
    let env = EnvMap::constant(8, [3e37; 3]);
    let brdf = BrdfModel::Dsbrdf(Box::new(Dsbrdf::isotropic_in_theta_d(
        [[(kappa_range().1, gamma_range().0); 3]; 3],
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

/// A reproducible stream of uniform numbers in [0, 1) (SplitMix64), so the property test's
/// materials are the same on every run and a failure names a material that can be rebuilt.
struct Stream(u64);

impl Stream {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Log-uniform over `range`.
    fn log_uniform(&mut self, (lo, hi): (f64, f64)) -> f64 {
        (lo.ln() + self.next() * (hi.ln() - lo.ln())).exp()
    }
}

/// Materials over the whole documented DSBRDF range: the four (κ, γ) corners of the accepted
/// range on every lobe (beyond the raw range: the zonal route refuses them and shades per pixel);
/// inside the raw range, lobes log-uniform in κ and γ and constant in θ_d; lobes whose κ and γ rise towards grazing
/// (fits of metals and specular paints); and every parameter drawn independently (κ and γ jump
/// between knots). Each is named so a failure can be reproduced.
fn range_materials(count: usize) -> Vec<(String, BrdfModel)> {
    use matedit_physics::brdf::dsbrdf::{KNOTS, LobeParam, PARAMS, param_index};
    let mut out = Vec::new();
    let corners = [kappa_range().0, kappa_range().1]
        .into_iter()
        .flat_map(|k| [gamma_range().0, gamma_range().1].map(|g| (k, g)));
    for (k, g) in corners {
        let m = Dsbrdf::isotropic_in_theta_d([[(0.2, 1e-3), (k, g), (kappa_range().0, gamma_range().1)]; 3]);
        out.push((
            format!("corner κ {k:e} γ {g:e} over a matte base"),
            BrdfModel::Dsbrdf(Box::new(m)),
        ));
    }
    let mut rng = Stream(2017);
    for i in 0..count {
        let kind = i % 3;
        let mut p = [0.0; PARAMS];
        for c in 0..3 {
            for k in 0..3 {
                let (kappa, gamma) = (rng.log_uniform(KAPPA_RANGE), rng.log_uniform(GAMMA_RANGE));
                // How much κ and γ grow from θ_d = 0 to grazing in the "sharpening" kind.
                let (rise_k, rise_g) = (1.0 + 19.0 * rng.next(), 1.0 + 9.0 * rng.next());
                for j in 0..KNOTS {
                    let t = j as f64 / (KNOTS - 1) as f64;
                    let (kk, gg) = match kind {
                        0 => (kappa, gamma),
                        1 => (kappa / rise_k.powf(1.0 - t * t), gamma / rise_g.powf(1.0 - t)),
                        _ => (rng.log_uniform(KAPPA_RANGE), rng.log_uniform(GAMMA_RANGE)),
                    };
                    p[param_index(c, k, LobeParam::Kappa, j)] = kk.clamp(KAPPA_RANGE.0, KAPPA_RANGE.1);
                    p[param_index(c, k, LobeParam::Gamma, j)] = gg.clamp(GAMMA_RANGE.0, GAMMA_RANGE.1);
                }
            }
        }
        let name = ["constant in θ_d", "sharpening towards grazing", "independent knots"][kind];
        let m = Dsbrdf::from_params(&p).expect("inside the documented range");
        out.push((format!("random #{i} ({name})"), BrdfModel::Dsbrdf(Box::new(m))));
    }
    out
}

/// Maps with a sun or sharp-edged lights at the factory's 64×128: the bench's procedural
/// families and, where the eval assets are present, real HDRIs (a sunny park, a studio).
fn hard_maps() -> Vec<(String, EnvMap)> {
    use matedit_assets::envmaps::Family;
    let mut maps: Vec<(String, EnvMap)> = [(Family::SunSky, 1), (Family::Softbox, 2), (Family::Window, 3)]
        .iter()
        .map(|&(f, s)| (format!("{}:{s}", f.name()), f.generate(s, 64)))
        .collect();
    match eval_assets() {
        Some(dir) => {
            for name in ["rooitou_park_1k", "studio_small_03_1k"] {
                let path = dir.join("envmaps").join(format!("{name}.hdr"));
                let (map, _) = matedit_assets::envfile::load_env(&path.display().to_string()).expect("eval asset");
                let map = map.resampled(128, 0.0);
                // Turned 40° and, with its sun behind the object (rooitou_park's sun at 130°
                // lights only a crescent), 130°.
                for yaw in [40.0, 130.0] {
                    maps.push((format!("{name}@{yaw}"), map.tilted(64, yaw, -20.0)));
                }
            }
        }
        None => eprintln!("eval assets not found: real HDRIs skipped (procedural maps only)"),
    }
    maps
}

#[test]
fn fast_matches_exact_over_the_whole_dsbrdf_range() {
    // The fast path is the reference of the zonal property test below, so it is held to the
    // exact path first, on the same materials (a small sphere: the exact path is slow).
    let (normals, mask) = unit_sphere_normals(20);
    let pixels: Vec<usize> = (0..mask.len()).filter(|&p| mask[p] > 0.0).collect();
    let maps: Vec<(String, EnvMap)> = hard_maps()
        .into_iter()
        .map(|(n, m)| (n, m.resampled(32, 0.0)))
        .collect();
    for (name, brdf) in range_materials(12) {
        for (map, env) in &maps {
            let fast = shade_with(&brdf, env, Quality::Fast, &normals, &mask, None).0;
            let exact = exact_image(&brdf, env, &normals, &mask);
            let e = rel_rmse(&fast, &exact, &pixels);
            assert!(e < 1e-3, "{name} under {map}: fast vs exact relative RMSE {e:.2e}");
        }
    }
}

#[test]
fn zonal_stays_within_half_a_percent_over_the_dsbrdf_range() {
    // Every material of the documented range, as the factory shades it with `zonal` (the grid
    // where it resolves the material, the fast path where it does not), against the fast path
    // (within 1e-3 of exact, above) at 96² (whose errors matched 256²'s within 2 % in
    // `zonal_range`) under maps with suns and sharp-edged lights.
    let res = 96;
    let (normals, mask) = unit_sphere_normals(res);
    let pixels: Vec<usize> = (0..mask.len()).filter(|&p| mask[p] > 0.0).collect();
    let maps = hard_maps();
    let (mut on_grid, mut off_grid, mut worst) = (0, 0, (0.0_f64, String::new()));
    let mut failures = Vec::new();
    let polar = PolarNormals::new(&normals, &mask);
    for (name, brdf) in range_materials(24) {
        // The kernel (and its check) once per material, as the factory builds it.
        let kernel = ZonalKernel::for_brdf(&brdf);
        match kernel {
            Some(_) => on_grid += 1,
            None => off_grid += 1,
        }
        for (i, (map, env)) in maps.iter().enumerate() {
            let fast = shade_with(&brdf, env, Quality::Fast, &normals, &mask, None).0;
            let zonal = match &kernel {
                Some(k) => shade_image_zonal(k, &ZonalEnv::new(env, k.grid()), &polar, &mask).0,
                // Refused: the factory's `zonal` route shades it per pixel, which the first map
                // checks end to end; the others would only repeat the fast path.
                None if i == 0 => shade_with(&brdf, env, Quality::Zonal, &normals, &mask, None).0,
                None => continue,
            };
            let e = rel_rmse(&zonal, &fast, &pixels);
            if e > worst.0 {
                worst = (e, format!("{name} under {map}"));
            }
            if e.is_nan() || e >= 5e-3 {
                failures.push(format!("{name} under {map}: zonal relative RMSE {e:.2e} (budget 5e-3)"));
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    eprintln!(
        "{on_grid} materials on the zonal grid, {off_grid} per pixel; worst {:.3} % ({})",
        100.0 * worst.0,
        worst.1
    );
    // The sample must exercise both routes, or it tests one of them by accident.
    assert!(
        on_grid >= 5 && off_grid >= 5,
        "{on_grid} on the grid, {off_grid} off it"
    );
}

/// Shadow patterns by pixel and direction, as a shadow ray would report them (1 open, 0 blocked):
/// a wall on one side of half the image, a cap around the sun over a disk of pixels, and
/// independent noise (adversarial: no coherence between texels or pixels).
fn shadow_patterns(res: usize, sun: [f32; 3]) -> Vec<(&'static str, Box<VisibilityFn<'static>>)> {
    let px = move |p: usize| matedit_physics::camera::pixel_center(p % res, p / res, res);
    vec![
        (
            "wall",
            Box::new(move |p, dirs: &[[f32; 3]], out: &mut [f32]| {
                let (x, _) = px(p);
                for (o, d) in out.iter_mut().zip(dirs) {
                    *o = if x < 0.0 && d[0] > 0.2 { 0.0 } else { 1.0 };
                }
            }),
        ),
        (
            "sun blocked",
            Box::new(move |p, dirs: &[[f32; 3]], out: &mut [f32]| {
                let (x, y) = px(p);
                let inside = (x - 0.2).powi(2) + (y + 0.1).powi(2) < 0.3;
                for (o, d) in out.iter_mut().zip(dirs) {
                    let near_sun = d[0] * sun[0] + d[1] * sun[1] + d[2] * sun[2] > 0.8;
                    *o = if inside && near_sun { 0.0 } else { 1.0 };
                }
            }),
        ),
        (
            "noise",
            Box::new(move |p, dirs: &[[f32; 3]], out: &mut [f32]| {
                for (t, (o, _)) in out.iter_mut().zip(dirs).enumerate() {
                    let h = (p as u64 * 0x9E37_79B9_7F4A_7C15) ^ (t as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
                    *o = if (h >> 29).is_multiple_of(3) { 0.0 } else { 1.0 };
                }
            }),
        ),
    ]
}

#[test]
fn zonal_with_shadows_matches_the_fast_path_with_the_same_shadows() {
    // The zonal quality with shadows is the grid's unshadowed image minus the blocked texels'
    // light (or the open texels' light directly, where most light is blocked). It must hold
    // the fast path's image under the same visibility to within twice the grid's own budget,
    // over resolvable materials and maps with suns and sharp-edged lights; the shadows must be
    // real (one pattern at least changes the image by 10 %).
    let res = 48;
    let (normals, mask) = unit_sphere_normals(res);
    let pixels: Vec<usize> = (0..mask.len()).filter(|&p| mask[p] > 0.0).collect();
    let mut worst = (0.0_f64, String::new());
    for (map, env) in hard_maps() {
        let sun = brightest_direction(&env);
        for (name, brdf, tol) in resolvable() {
            let unshadowed = shade_with(&brdf, &env, Quality::Fast, &normals, &mask, None).0;
            let mut strongest: f64 = 0.0;
            for (pattern, vis) in shadow_patterns(res, sun) {
                let fast = shade_with(&brdf, &env, Quality::Fast, &normals, &mask, Some(vis.as_ref())).0;
                let (zonal, bad) = shade_with(&brdf, &env, Quality::Zonal, &normals, &mask, Some(vis.as_ref()));
                assert_eq!(bad, 0, "{name} under {map}, {pattern}");
                let e = rel_rmse(&zonal, &fast, &pixels);
                if e > worst.0 {
                    worst = (e, format!("{name} under {map}, {pattern}"));
                }
                assert!(
                    e < 2.0 * tol,
                    "{name} under {map}, {pattern}: relative RMSE {e:.2e} (allowed {:.0e})",
                    2.0 * tol
                );
                assert!(
                    zonal.iter().flatten().all(|v| v.is_finite() && *v >= 0.0),
                    "{name} under {map}, {pattern}: negative or non-finite radiance"
                );
                strongest = strongest.max(rel_rmse(&fast, &unshadowed, &pixels));
            }
            assert!(
                strongest > 0.1,
                "{name} under {map}: the shadows change only {strongest:.2e}"
            );
        }
    }
    eprintln!("worst {:.3} % ({})", 100.0 * worst.0, worst.1);
}

#[test]
fn zonal_with_shadows_is_the_grid_where_all_is_open_and_black_where_all_is_blocked() {
    let (normals, mask) = unit_sphere_normals(32);
    let env = builtin("sky").expect("builtin").resampled(32, 0.0);
    let open = |_: usize, _: &[[f32; 3]], out: &mut [f32]| out.fill(1.0);
    let closed = |_: usize, _: &[[f32; 3]], out: &mut [f32]| out.fill(0.0);
    for (name, brdf, _) in resolvable() {
        let grid = shade_with(&brdf, &env, Quality::Zonal, &normals, &mask, None).0;
        let all_open = shade_with(&brdf, &env, Quality::Zonal, &normals, &mask, Some(&open)).0;
        assert_eq!(
            grid, all_open,
            "{name}: nothing blocked must leave the grid's image as it is"
        );
        let all_closed = shade_with(&brdf, &env, Quality::Zonal, &normals, &mask, Some(&closed)).0;
        assert!(
            all_closed.iter().flatten().all(|&v| v == 0.0),
            "{name}: everything blocked must be black"
        );
    }
}

#[test]
fn zonal_with_shadows_does_not_depend_on_the_thread_count() {
    let res = 40;
    let (normals, mask) = unit_sphere_normals(res);
    let env = builtin("studio").expect("builtin").resampled(32, 30.0);
    let sun = brightest_direction(&env);
    for (name, brdf, _) in resolvable() {
        for (pattern, vis) in shadow_patterns(res, sun) {
            let bits = |threads: usize| {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .expect("pool");
                let img =
                    pool.install(|| shade_with(&brdf, &env, Quality::Zonal, &normals, &mask, Some(vis.as_ref())).0);
                img.iter().flatten().map(|v| v.to_bits()).collect::<Vec<u32>>()
            };
            assert_eq!(bits(1), bits(3), "{name}, {pattern}");
        }
    }
}

/// The direction of a map's brightest texel.
fn brightest_direction(env: &EnvMap) -> [f32; 3] {
    let (w, h) = (env.width(), env.height());
    let mut best = (0.0_f32, (0, 0));
    for j in 0..h {
        for i in 0..w {
            let l = env.texel(i, j);
            let y = l[0] + l[1] + l[2];
            if y > best.0 {
                best = (y, (i, j));
            }
        }
    }
    let d = matedit_physics::envmap::texel_direction(best.1.0, best.1.1, w, h);
    [d.x as f32, d.y as f32, d.z as f32]
}

#[test]
fn zonal_with_shadows_holds_over_the_dsbrdf_range() {
    // The documented range's corners and random materials (the property test's), as the
    // factory shades them with shadows: the grid's image minus the blocked light where the grid
    // resolves the material, against the fast path under the same visibility; within twice the
    // range's zonal budget (5e-3).
    use matedit_physics::shading::fast::FastShader;
    use matedit_physics::shading::remove_blocked_light;
    let res = 40;
    let (normals, mask) = unit_sphere_normals(res);
    let pixels: Vec<usize> = (0..mask.len()).filter(|&p| mask[p] > 0.0).collect();
    let polar = PolarNormals::new(&normals, &mask);
    let maps: Vec<(String, EnvMap)> = hard_maps().into_iter().take(2).collect();
    let (mut on_grid, mut worst) = (0, (0.0_f64, String::new()));
    for (name, brdf) in range_materials(12) {
        let Some(kernel) = ZonalKernel::for_brdf(&brdf) else {
            continue;
        };
        on_grid += 1;
        for (map, env) in &maps {
            let unshadowed = shade_image_zonal(&kernel, &ZonalEnv::new(env, kernel.grid()), &polar, &mask).0;
            let fast = FastShader::new(&brdf, env).expect("analytic");
            for (pattern, vis) in shadow_patterns(res, brightest_direction(env)) {
                let reference = shade_image(&fast, &normals, &mask, Some(vis.as_ref())).0;
                let (zonal, bad) = remove_blocked_light(&fast, &unshadowed, &normals, &mask, vis.as_ref());
                assert_eq!(bad, 0, "{name} under {map}, {pattern}");
                let e = rel_rmse(&zonal, &reference, &pixels);
                if e > worst.0 {
                    worst = (e, format!("{name} under {map}, {pattern}"));
                }
                assert!(
                    e < 1e-2,
                    "{name} under {map}, {pattern}: relative RMSE {e:.2e} (allowed 1e-2)"
                );
                assert!(
                    zonal.iter().flatten().all(|v| v.is_finite() && *v >= 0.0),
                    "{name}, {pattern}"
                );
            }
        }
    }
    eprintln!(
        "{on_grid} materials on the grid; worst {:.3} % ({})",
        100.0 * worst.0,
        worst.1
    );
    assert!(on_grid >= 5, "only {on_grid} of the range's materials on the grid");
}

#[test]
fn a_rough_metal_is_checked_on_the_capped_grid_and_holds_the_budget() {
    // The library's `gold-rough` as `datagen assets materials` fits it: a broad base and a weak
    // spike (κ ≈ 0.15, γ ≈ 3·10³–8·10³) at θ_d ≤ 30° only. The width rule asks for more than
    // twice the 128-row cap (in the small-θ_d bands), so it used to be refused up front and
    // shaded per pixel; now the capped grid is tried, the stricter check passes it at the first
    // try, and it must hold the factory's half-percent budget under suns and sharp-edged lights.
    use matedit_physics::shading::zonal::{
        CHECKED_BEYOND_CAP, MAX_ROWS, PROBE_BUDGET_BEYOND, RESOLVED_BEYOND_CAP, ZonalParams, ZonalPlan,
    };
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../assets/materials/gold_rough.dsbrdf.json"
    );
    let brdf = BrdfModel::Dsbrdf(Box::new(Dsbrdf::load(std::path::Path::new(path)).expect("fixture")));
    let params = ZonalParams::default();
    assert_eq!(
        ZonalKernel::probe_budget(&brdf, &params),
        PROBE_BUDGET_BEYOND,
        "beyond {RESOLVED_BEYOND_CAP}× the cap"
    );
    assert!(
        matches!(ZonalPlan::for_brdf(&brdf), ZonalPlan::Grid(_)),
        "within {CHECKED_BEYOND_CAP}× the cap"
    );
    let kernel = ZonalKernel::for_brdf(&brdf).expect("the check passes the capped grid");
    assert!(kernel.grid().rows <= MAX_ROWS, "{} rows", kernel.grid().rows);
    let (normals, mask) = unit_sphere_normals(96);
    let pixels: Vec<usize> = (0..mask.len()).filter(|&p| mask[p] > 0.0).collect();
    let polar = PolarNormals::new(&normals, &mask);
    for (map, env) in hard_maps() {
        let fast = shade_with(&brdf, &env, Quality::Fast, &normals, &mask, None).0;
        let zonal = shade_image_zonal(&kernel, &ZonalEnv::new(&env, kernel.grid()), &polar, &mask).0;
        let e = rel_rmse(&zonal, &fast, &pixels);
        assert!(e < 5e-3, "under {map}: zonal relative RMSE {e:.2e} (budget 5e-3)");
    }
}
