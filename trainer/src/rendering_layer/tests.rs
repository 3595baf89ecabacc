//! The rendering layer against closed forms and independent implementations: the physics crate's
//! exact `f64` shader, the one `datagen` renders with (values and finite differences), and Burn's
//! autodiff of the tensor reference.

use super::*;
use burn::tensor::Device;
use matedit_physics::brdf::{BrdfModel, Dsbrdf};
use matedit_physics::camera::unit_sphere_normals;
use matedit_physics::envmap::EnvMap;
use matedit_physics::shading::exact::ExactShader;
use matedit_physics::shading::shading_normal;

pub(super) struct Scene {
    pub(super) size: usize,
    pub(super) regions: usize,
    pub(super) normals: Vec<f32>,
    pub(super) region_map: Vec<u8>,
    pub(super) materials: Vec<f32>,
    pub(super) env: Vec<f32>,
    pub(super) env_height: usize,
}

impl Scene {
    fn batch(&self) -> LayerInput<'_> {
        LayerInput {
            batch: 1,
            size: (self.size, self.size),
            regions: self.regions,
            normals: &self.normals,
            region_map: &self.region_map,
            materials: &self.materials,
            env: &self.env,
        }
    }
}

/// Deterministic pseudo-random numbers in [0, 1) (a 64-bit LCG; good enough for test data).
pub(super) struct Lcg(pub(super) u64);
impl Lcg {
    pub(super) fn next(&mut self) -> f32 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 40) as f32) / (1u64 << 24) as f32
    }
}

/// A plausible material: a broad diffuse-like lobe, a glossy lobe and a sharp one, per channel.
fn material(rng: &mut Lcg, sharp: bool) -> Vec<f32> {
    let mut x = vec![0.0f32; PARAMS];
    for q in 0..material::MEMBERS {
        let k = q % 3;
        for j in 0..6 {
            let kappa = [-0.55, -0.2, 0.1][k] + 0.1 * rng.next();
            let gamma = if sharp {
                [-0.9, 0.2, 0.7][k]
            } else {
                [-0.9, -0.2, 0.2][k]
            } + 0.1 * rng.next();
            x[material::knot_index(q, false, j)] = kappa;
            x[material::knot_index(q, true, j)] = gamma;
        }
    }
    x
}

/// A sky-like environment with a bright sun, channel-first `[3, He, 2He]`.
fn environment(height: usize, rng: &mut Lcg) -> Vec<f32> {
    let (w, t) = (2 * height, 2 * height * height);
    let mut env = vec![0.0f32; 3 * t];
    for row in 0..height {
        for col in 0..w {
            let i = row * w + col;
            let sky = 0.2 + 0.8 * (1.0 - row as f32 / height as f32);
            for c in 0..3 {
                env[c * t + i] = sky * (0.6 + 0.4 * rng.next()) * [1.0, 0.9, 0.8][c];
            }
        }
    }
    let sun = (height / 4) * w + w / 3;
    for c in 0..3 {
        env[c * t + sun] = 40.0;
    }
    env
}

pub(super) fn sphere(size: usize, regions: usize, env_height: usize, sharp: bool, seed: u64) -> Scene {
    let mut rng = Lcg(seed);
    let (n, mask) = unit_sphere_normals(size);
    let p = size * size;
    let mut normals = vec![0.0f32; 3 * p];
    let mut region_map = vec![0u8; p];
    for i in 0..p {
        if mask[i] > 0.0 {
            let s = shading_normal(n[i]).unwrap_or(glam::DVec3::Z);
            for a in 0..3 {
                normals[a * p + i] = s[a] as f32;
            }
            region_map[i] = if regions == 2 && i % size >= size / 2 { 2 } else { 1 };
        }
    }
    let materials = (0..regions).flat_map(|_| material(&mut rng, sharp)).collect();
    Scene {
        size,
        regions,
        normals,
        region_map,
        materials,
        env: environment(env_height, &mut rng),
        env_height,
    }
}

fn exact_shader(s: &Scene, region: usize) -> ExactShader {
    let t = 2 * s.env_height * s.env_height;
    let texels: Vec<[f32; 3]> = (0..t).map(|i| [s.env[i], s.env[t + i], s.env[2 * t + i]]).collect();
    let (env, _) = EnvMap::from_texels(2 * s.env_height, s.env_height, texels).unwrap();
    let x: Vec<f64> = s.materials[region * PARAMS..(region + 1) * PARAMS]
        .iter()
        .map(|&v| v as f64)
        .collect();
    ExactShader::new(BrdfModel::Dsbrdf(Box::new(Dsbrdf::from_normalised(&x).unwrap())), &env)
}

/// Σ_p g_p · I_p by the `f64` exact renderer of the physics crate.
fn exact_loss(s: &Scene, upstream: &[f32]) -> f64 {
    let p = s.size * s.size;
    let shaders: Vec<ExactShader> = (0..s.regions).map(|r| exact_shader(s, r)).collect();
    let mut total = 0.0;
    for i in 0..p {
        let r = s.region_map[i] as usize;
        if r == 0 {
            continue;
        }
        let n = [s.normals[i], s.normals[p + i], s.normals[2 * p + i]];
        let v = shaders[r - 1].shade_f64(n, None);
        for c in 0..3 {
            total += upstream[c * p + i] as f64 * v[c];
        }
    }
    total
}

fn rel_rmse(a: &[f32], b: &[f32]) -> f64 {
    let num: f64 = a.iter().zip(b).map(|(x, y)| (*x as f64 - *y as f64).powi(2)).sum();
    let den: f64 = b.iter().map(|y| (*y as f64).powi(2)).sum();
    (num / den.max(1e-300)).sqrt()
}

pub(super) fn upstream(s: &Scene, seed: u64) -> Vec<f32> {
    let mut rng = Lcg(seed);
    (0..3 * s.size * s.size).map(|_| rng.next() - 0.3).collect()
}

#[test]
fn forward_reproduces_the_exact_f64_renderer_at_64x128() {
    for sharp in [false, true] {
        let s = sphere(32, 2, 64, sharp, 7);
        let layer = RenderingLayer::new(64);
        let out = layer.forward(&s.batch()).unwrap();
        let p = s.size * s.size;
        let shaders: Vec<ExactShader> = (0..2).map(|r| exact_shader(&s, r)).collect();
        let mut want = vec![0.0f32; 3 * p];
        for i in 0..p {
            let r = s.region_map[i] as usize;
            if r > 0 {
                let n = [s.normals[i], s.normals[p + i], s.normals[2 * p + i]];
                let v = shaders[r - 1].shade_f64(n, None);
                for c in 0..3 {
                    want[c * p + i] = v[c] as f32;
                }
            }
        }
        let e = rel_rmse(&out, &want);
        assert!(e <= 1e-3, "sharp={sharp}: relative RMSE {e}");
        assert!(
            out.iter()
                .zip(&s.region_map.repeat(3))
                .all(|(v, r)| *r > 0 || *v == 0.0)
        );
    }
}

#[test]
fn gradients_match_burn_autodiff_of_the_tensor_reference() {
    agrees_with_the_tensor_reference(&sphere(12, 2, 8, true, 11), 8);
}

/// At the paper's 64×128 environment, where the sharp lobes (γ about 2e3) span a few texels.
#[test]
fn gradients_match_the_tensor_reference_at_64x128() {
    agrees_with_the_tensor_reference(&sphere(8, 2, 64, true, 17), 64);
}

/// The fused layer's output and its three gradients against Burn's autodiff of the reference.
fn agrees_with_the_tensor_reference(s: &Scene, env_height: usize) {
    let layer = RenderingLayer::new(env_height);
    let g = upstream(s, 5);
    let fused_out = layer.forward(&s.batch()).unwrap();
    let fused = layer.backward(&s.batch(), &g).unwrap();
    let device = Device::flex().autodiff();
    let (ref_out, reference) = reference::forward_backward(&layer, &s.batch(), &g, &device).unwrap();
    for (name, a, b) in [
        ("output", &fused_out, &ref_out),
        ("normals", &fused.normals, &reference.normals),
        ("materials", &fused.materials, &reference.materials),
        ("environment", &fused.env, &reference.env),
    ] {
        let e = rel_rmse(a, b);
        assert!(e <= 1e-3, "{name}: relative error {e}");
        assert!(
            b.iter().any(|v| *v != 0.0),
            "{name}: the reference gradient is all zero"
        );
    }
}

#[test]
fn gradients_match_finite_differences_of_the_exact_renderer() {
    let s = sphere(10, 2, 8, false, 3);
    let layer = RenderingLayer::new(8);
    let g = upstream(&s, 9);
    let grads = layer.backward(&s.batch(), &g).unwrap();
    let check = |what: &str, fd: f64, an: f64, scale: f64| {
        assert!(
            (fd - an).abs() <= 1e-3 * fd.abs() + 1e-5 * scale,
            "{what}: finite difference {fd}, analytic {an}"
        );
    };
    // Materials: central differences in the normalised parameters.
    let scale_m = grads.materials.iter().map(|v| v.abs() as f64).fold(0.0, f64::max);
    for &i in &[0usize, 3, 6, 11, 17, 40, 59, 77, 100, 107, 108 + 5, 108 + 66] {
        let h = 1e-3;
        let mut plus = Scene {
            materials: s.materials.clone(),
            ..sphere(10, 2, 8, false, 3)
        };
        plus.materials[i] += h;
        let mut minus = Scene {
            materials: s.materials.clone(),
            ..sphere(10, 2, 8, false, 3)
        };
        minus.materials[i] -= h;
        let fd = (exact_loss(&plus, &g) - exact_loss(&minus, &g)) / (2.0 * h as f64);
        check(&format!("material {i}"), fd, grads.materials[i] as f64, scale_m);
    }
    // Environment: the loss is linear in L, so a difference is exact up to rounding.
    let scale_e = grads.env.iter().map(|v| v.abs() as f64).fold(0.0, f64::max);
    let t = 2 * 8 * 8;
    for &i in &[5usize, 40, 70, t + 33, 2 * t + 60] {
        let mut plus = sphere(10, 2, 8, false, 3);
        plus.env[i] += 0.5;
        let fd = (exact_loss(&plus, &g) - exact_loss(&s, &g)) / 0.5;
        check(&format!("env {i}"), fd, grads.env[i] as f64, scale_e);
    }
    // Normals: tangent directions (the exact renderer normalises its normals).
    let p = 100;
    let scale_n = grads.normals.iter().map(|v| v.abs() as f64).fold(0.0, f64::max);
    for &px in &[34usize, 45, 56, 63, 27] {
        let n = glam::DVec3::new(
            s.normals[px] as f64,
            s.normals[p + px] as f64,
            s.normals[2 * p + px] as f64,
        );
        let t1 = n.cross(glam::DVec3::Y).normalize();
        for t in [t1, n.cross(t1)] {
            let h = 1e-4;
            let moved = |sign: f64| {
                let mut m = sphere(10, 2, 8, false, 3);
                let v = n + sign * h * t;
                for a in 0..3 {
                    m.normals[a * p + px] = v[a] as f32;
                }
                m
            };
            let fd = (exact_loss(&moved(1.0), &g) - exact_loss(&moved(-1.0), &g)) / (2.0 * h);
            let an: f64 = (0..3).map(|a| grads.normals[a * p + px] as f64 * t[a]).sum();
            check(&format!("normal of pixel {px}"), fd, an, scale_n);
        }
    }
}

#[test]
fn a_backward_pass_for_one_input_gives_that_inputs_gradient_bit_for_bit() {
    // Two regions, sharp and broad lobes, and the hard normals of the test below: the pass that
    // computes one gradient must skip only work whose results it discards.
    for sharp in [false, true] {
        let mut s = sphere(10, 2, 4, sharp, 17);
        let p = 100;
        s.normals[33] = f32::NAN;
        s.normals[2 * p + 34] = 1e-6;
        let layer = RenderingLayer::new(4);
        let g = upstream(&s, 3);
        let all = layer.backward(&s.batch(), &g).unwrap();
        for (want, name) in [
            (Wanted::NORMALS, "normals"),
            (Wanted::MATERIALS, "materials"),
            (Wanted::ENV, "env"),
        ] {
            let one = layer.backward_wanted(&s.batch(), &g, want).unwrap();
            let pick = |g: &Gradients, input: &str| match input {
                "normals" => g.normals.clone(),
                "materials" => g.materials.clone(),
                _ => g.env.clone(),
            };
            for input in ["normals", "materials", "env"] {
                let (got, full) = (pick(&one, input), pick(&all, input));
                if input == name {
                    assert!(
                        full.iter().any(|v| *v != 0.0),
                        "{input}: the full pass gives no gradient"
                    );
                    assert_eq!(got, full, "{input} alone differs from the full pass (sharp {sharp})");
                } else {
                    assert!(
                        got.iter().all(|v| *v == 0.0),
                        "{input} computed when only {name} was asked for"
                    );
                }
            }
        }
    }
}

#[test]
fn hard_inputs_give_finite_values_and_gradients() {
    let mut s = sphere(8, 1, 4, true, 1);
    let p = 64;
    // Zero, NaN, infinite, back-facing and grazing normals on object pixels.
    let hard = [
        [0.0, 0.0, 0.0],
        [f32::NAN, 0.0, 1.0],
        [f32::INFINITY, 0.0, 1.0],
        [0.0, 0.0, -1.0],
        [1.0, 0.0, 1e-4],
        [0.0, 1.0, 1e-7],
    ];
    for (k, n) in hard.iter().enumerate() {
        let px = 27 + k;
        s.region_map[px] = 1;
        for (a, v) in n.iter().enumerate() {
            s.normals[a * p + px] = *v;
        }
    }
    // Extreme lobes: the largest κ with the sharpest and the flattest γ, and NaN.
    for q in 0..material::MEMBERS {
        for j in 0..6 {
            s.materials[material::knot_index(q, false, j)] = if q % 2 == 0 { 1.0 } else { -1.0 };
            s.materials[material::knot_index(q, true, j)] = if j % 2 == 0 { 1.0 } else { -1.0 };
        }
    }
    s.materials[3] = f32::NAN;
    s.materials[50] = 7.0;
    // Non-finite and negative radiance.
    s.env[0] = f32::NAN;
    s.env[1] = f32::INFINITY;
    s.env[2] = -5.0;
    s.env[3] = 1e30;
    let layer = RenderingLayer::new(4);
    let out = layer.forward(&s.batch()).unwrap();
    assert!(out.iter().all(|v| v.is_finite()), "forward");
    let mut g = upstream(&s, 2);
    g[5] = f32::NAN;
    g[6] = f32::INFINITY;
    let grads = layer.backward(&s.batch(), &g).unwrap();
    for (name, v) in [
        ("normals", &grads.normals),
        ("materials", &grads.materials),
        ("env", &grads.env),
    ] {
        assert!(v.iter().all(|x| x.is_finite()), "{name} gradient not finite");
    }
    for px in [27, 28, 29, 30] {
        assert!(
            (0..3).all(|c| out[c * p + px] == 0.0),
            "unusable normal at {px} must render black"
        );
    }
    assert!((0..3).any(|c| out[c * p + 31] != 0.0), "a grazing normal still renders");
}

#[test]
fn a_white_furnace_gives_the_albedo_of_a_near_lambertian_material() {
    // Closed form: a Lambertian BRDF ρ/π under uniform unit radiance reflects exactly ρ.
    let size = 16;
    let layer = RenderingLayer::new(32);
    let (n, mask) = unit_sphere_normals(size);
    let p = size * size;
    let mut normals = vec![0.0f32; 3 * p];
    let mut region_map = vec![0u8; p];
    for i in 0..p {
        if mask[i] > 0.0 && n[i][2] > 0.3 {
            for a in 0..3 {
                normals[a * p + i] = n[i][a];
            }
            region_map[i] = 1;
        }
    }
    let albedo = [0.2, 0.5, 0.8];
    let x: Vec<f32> = Dsbrdf::near_lambertian(albedo)
        .to_normalised()
        .iter()
        .map(|&v| v as f32)
        .collect();
    let env = vec![1.0f32; 3 * 2 * 32 * 32];
    let b = LayerInput {
        batch: 1,
        size: (size, size),
        regions: 1,
        normals: &normals,
        region_map: &region_map,
        materials: &x,
        env: &env,
    };
    let out = layer.forward(&b).unwrap();
    for i in (0..p).filter(|&i| region_map[i] == 1) {
        for c in 0..3 {
            // Texel quadrature of the cosine lobe at 32×64 is good to about 1 %; cos^γ with
            // γ = 1e-3 is not exactly flat either.
            assert!(
                (out[c * p + i] as f64 / albedo[c] - 1.0).abs() < 0.02,
                "pixel {i} channel {c}: {}",
                out[c * p + i]
            );
        }
    }
}

#[test]
fn results_do_not_depend_on_the_thread_count() {
    let s = sphere(24, 2, 16, true, 4);
    let layer = RenderingLayer::new(16);
    let g = upstream(&s, 8);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            (
                layer.forward(&s.batch()).unwrap(),
                layer.backward(&s.batch(), &g).unwrap(),
            )
        })
    };
    let (o1, g1) = run(1);
    let (o3, g3) = run(3);
    assert_eq!(o1, o3);
    assert_eq!(g1.normals, g3.normals);
    assert_eq!(g1.materials, g3.materials);
    assert_eq!(g1.env, g3.env);
}

#[test]
fn bad_shapes_and_regions_are_errors() {
    let s = sphere(8, 1, 4, false, 1);
    let layer = RenderingLayer::new(4);
    let mut b = s.batch();
    b.regions = 0;
    assert!(matches!(
        layer.forward(&b),
        Err(RenderError::Shape { name: "materials", .. })
    ));
    let layer8 = RenderingLayer::new(8);
    assert!(matches!(
        layer8.forward(&s.batch()),
        Err(RenderError::EnvHeight { layer: 8, got: 4 })
    ));
    let mut map = s.region_map.clone();
    map[30] = 3;
    let b = LayerInput {
        region_map: &map,
        ..s.batch()
    };
    let e = layer.forward(&b).unwrap_err();
    assert!(e.to_string().contains("region 3"), "{e}");
}

#[test]
#[ignore = "timing, run by hand"]
fn timing_forward_backward() {
    let s = sphere(128, 1, 64, true, 1);
    let layer = RenderingLayer::new(64);
    let g = upstream(&s, 1);
    let t = std::time::Instant::now();
    let _ = layer.forward(&s.batch()).unwrap();
    let f = t.elapsed().as_secs_f64();
    let t = std::time::Instant::now();
    let _ = layer.backward(&s.batch(), &g).unwrap();
    let b = t.elapsed().as_secs_f64();
    let pairs = s.region_map.iter().filter(|&&r| r > 0).count() as f64 * 8192.0;
    eprintln!(
        "forward {f:.3} s ({:.2} ns/pair), backward {b:.3} s ({:.2} ns/pair)",
        f * 1e9 / pairs,
        b * 1e9 / pairs
    );
}
