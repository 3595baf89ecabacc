//! Furnace tests: under a constant environment of radiance 1, a Lambertian surface of albedo ρ
//! reflects exactly ρ in every direction (∫ ρ/π cos θ dω = ρ), whatever its normal.

mod common;
use common::*;
use matedit_datagen::preview::EnvRes;
use matedit_physics::shading::Quality;

fn furnace(env_res: EnvRes, quality: Quality, res: usize) -> f64 {
    let r = render_scene(
        "sphere",
        "lambert:0.5,0.5,0.5",
        "builtin:constant:1",
        env_res,
        res,
        quality,
    );
    let mut worst: f64 = 0.0;
    for p in fully_covered(res) {
        for c in 0..3 {
            worst = worst.max((r.radiance[p][c] as f64 - 0.5).abs() / 0.5);
        }
    }
    worst
}

#[test]
fn lambert_sphere_furnace_at_64x128_within_0_2_percent() {
    for q in [Quality::Fast, Quality::Exact] {
        let worst = furnace(EnvRes::Rows(64), q, 48);
        assert!(worst < 2e-3, "{q:?}: worst relative error {worst}");
    }
}

#[test]
fn lambert_sphere_furnace_at_full_resolution_within_0_2_percent() {
    // builtin:constant is 256×512 at full resolution.
    let worst = furnace(EnvRes::Full, Quality::Fast, 32);
    assert!(worst < 2e-3, "worst relative error {worst}");
}

#[test]
fn furnace_pixels_outside_the_object_are_black_and_mask_matches() {
    let r = render_scene(
        "sphere",
        "lambert:0.5,0.5,0.5",
        "builtin:constant:1",
        EnvRes::Rows(16),
        32,
        Quality::Fast,
    );
    for p in 0..32 * 32 {
        if r.gbuffer.mask[p] == 0.0 {
            assert_eq!(r.radiance[p], [0.0; 3]);
        } else {
            assert!(r.radiance[p][0] > 0.45, "covered pixel {p}: {:?}", r.radiance[p]);
        }
    }
}

#[test]
fn white_ggx_and_plastic_never_reflect_more_than_arrives() {
    // Energy bound: a white GGX lobe (F = 1) can only lose energy to masking.
    for spec in ["ggx:0.2:1,1,1", "ggx:0.6:1,1,1", "ggx:1:1,1,1"] {
        let r = render_scene(
            "sphere",
            spec,
            "builtin:constant:1",
            EnvRes::Rows(64),
            32,
            Quality::Fast,
        );
        for p in fully_covered(32) {
            assert!(r.radiance[p][0] <= 1.0 + 2e-3, "{spec}: {:?}", r.radiance[p]);
            assert!(r.radiance[p][0] > 0.3, "{spec}: {:?}", r.radiance[p]);
        }
    }
}
