//! The light stage alone: a light at its own level and the level fitted through the rendering
//! layer, with what each refuses.

use super::*;
use matedit_physics::brdf::Dsbrdf;
use matedit_trainer::rendering_layer::MAX_RADIANCE;

#[test]
fn a_light_at_its_own_level_is_refused_where_the_layer_would_cap_it() {
    // The photo's exposure only: values, zeros and the bound itself pass unchanged in ratio.
    let l = [0.0_f32, 1.0, 2.5, MAX_RADIANCE / 4.0];
    let got = light_at_own_level(&l, 4.0).unwrap();
    assert_eq!(got, vec![0.0, 4.0, 10.0, MAX_RADIANCE]);
    // Brighter than the layer renders, or past f32 (a finite map times a large exposure), is
    // refused by name; so is a tiny exposure that cannot bring f32::MAX down far enough.
    for (l, exposure) in [
        (vec![1.0_f32, MAX_RADIANCE], 1.5),
        (vec![f32::MAX / 2.0], 4.0),
        (vec![f32::MAX], 1e-10),
    ] {
        let e = light_at_own_level(&l, exposure).unwrap_err();
        assert!(format!("{e:#}").contains("too bright for this photo"), "{e:#}");
    }
}

#[test]
fn the_fitted_level_is_the_least_squares_scale_and_refuses_what_the_layer_cannot_render() {
    use matedit_trainer::rendering_layer::{LayerInput, RenderingLayer};
    let (n, he) = (4, 4);
    let layer = RenderingLayer::new(he);
    let m = Dsbrdf::near_lambertian([0.5; 3])
        .to_normalised()
        .map(|v| v as f32)
        .to_vec();
    let x = |env: Vec<f32>| matedit_trainer::model::prediction::Prediction {
        normals: (0..3 * n * n)
            .map(|k| if k / (n * n) == 2 { 1.0 } else { 0.0 })
            .collect(),
        materials: m.clone(),
        env,
    };
    let prep = |value: f32| Prepared::square(n, vec![value; 3 * n * n], vec![1.0; n * n], 1.0);
    let l = vec![1.0_f32; 3 * he * 2 * he];
    let rendered = layer
        .forward(&LayerInput::one_region(
            n,
            &x(l.clone()).normals,
            &prep(0.0).region_map,
            &m,
            &l,
        ))
        .unwrap();
    // A uniform photo under a uniform light: k = Σ I·R / Σ R², computed here in f64.
    let (ri, rr) = rendered.iter().fold((0.0_f64, 0.0_f64), |(a, b), &r| {
        (a + 0.3 * r as f64, b + r as f64 * r as f64)
    });
    let got = light_at_photo_level(&layer, &prep(0.3), &x(l.clone()), &l).unwrap();
    assert!(
        got.iter().all(|&v| ((v as f64) - ri / rr).abs() <= 1e-5 * ri / rr),
        "{} vs {}",
        got[0],
        ri / rr
    );
    // A photo the layer could only explain with a light it caps, and a light that leaves the
    // object black: refused by name.
    let e = light_at_photo_level(&layer, &prep(1e9), &x(l.clone()), &l).unwrap_err();
    assert!(format!("{e:#}").contains("too dark for the photo"), "{e:#}");
    let black = vec![0.0_f32; l.len()];
    let e = light_at_photo_level(&layer, &prep(0.3), &x(black.clone()), &black).unwrap_err();
    assert!(format!("{e:#}").contains("leaves the object black"), "{e:#}");
}
