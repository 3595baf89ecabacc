//! Closed-form environments that pin down the direction conventions.
//!
//! For L(d) = 1 + k·(d·a), the irradiance is E(n) = π + (2π/3)·k·(n·a), so a Lambertian sphere
//! of albedo ρ shows ρ·(1 + (2k/3)·(n·a)). If texel directions, the camera frame or the rotation
//! were off, the gradient would run along the wrong axis or with the wrong sign.

use glam::DVec3;
use matedit_physics::EnvMap;
use matedit_physics::brdf::{BrdfModel, Lambert};
use matedit_physics::shading::{Quality, make_shader};

fn linear_env(a: DVec3, k: f64, rows: usize) -> EnvMap {
    EnvMap::from_fn(rows, |d| [(1.0 + k * d.dot(a)) as f32; 3])
}

fn check(env: &EnvMap, expected_axis: DVec3, k: f64) {
    let rho = 0.8;
    let brdf = BrdfModel::Lambert(Lambert { albedo: [rho; 3] });
    for q in [Quality::Fast, Quality::Exact] {
        let shader = make_shader(&brdf, env, q);
        for n in [
            DVec3::Z,
            DVec3::new(0.6, 0.0, 0.8),
            DVec3::new(-0.6, 0.0, 0.8),
            DVec3::new(0.0, 0.6, 0.8),
            DVec3::new(0.0, -0.6, 0.8),
            DVec3::new(0.5, 0.5, 0.7),
        ] {
            let n = n.normalize();
            let want = rho * (1.0 + 2.0 * k / 3.0 * n.dot(expected_axis));
            let got = shader.shade([n.x as f32, n.y as f32, n.z as f32], None)[0] as f64;
            assert!((got - want).abs() / want < 1e-3, "{q:?} n={n}: got {got}, want {want}");
        }
    }
}

#[test]
fn light_from_plus_x_brightens_normals_facing_right() {
    check(&linear_env(DVec3::X, 0.5, 64), DVec3::X, 0.5);
}

#[test]
fn light_from_plus_y_brightens_normals_facing_up() {
    check(&linear_env(DVec3::Y, 0.5, 64), DVec3::Y, 0.5);
}

#[test]
fn light_from_plus_z_brightens_normals_facing_the_camera() {
    check(&linear_env(DVec3::Z, 0.9, 64), DVec3::Z, 0.9);
}

#[test]
fn rotating_by_90_degrees_about_y_moves_plus_x_light_to_minus_z() {
    // L_rot(d) = L(R_y(−90°) d): the feature at +x moves to R_y(90°)·x = −z.
    let env = linear_env(DVec3::X, 0.5, 128).resampled(64, 90.0);
    check(&env, DVec3::NEG_Z, 0.5);
    let env = linear_env(DVec3::X, 0.5, 128).resampled(64, -90.0);
    check(&env, DVec3::Z, 0.5);
}
