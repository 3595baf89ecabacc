//! A whole relit edit: under its own light, the photo comes back.

use crate::light::relight::RelightLevel;
use crate::tests::{dir, model, request, write_photo};

/// Relit under the light the edit found (its `env.exr`, in the photo's units), at either
/// level, the predicted material renders I* again: with `ratio` (I × relit / I*) the relit
/// object is the photo's, byte for byte, and the level set is the photo's exposure.
#[test]
fn relit_under_its_own_light_the_photo_comes_back() {
    let d = dir("relight-own");
    let (p, m, _) = write_photo(&d);
    let first = crate::edit(model(), &request(&p, &m, "lambert:0.5,0.5,0.5"), &d.join("first")).unwrap();
    let env = d.join("first").join("env.exr").display().to_string();
    for level in [RelightLevel::Light, RelightLevel::Given] {
        let out = d.join(format!("{level:?}"));
        let req = crate::EditRequest {
            relight: Some(env.clone()),
            relight_level: level,
            materials: Vec::new(),
            composite: Some(crate::Composite::Ratio),
            range: Some(crate::Range::Clip),
            ..request(&p, &m, "unused")
        };
        let r = crate::edit(model(), &req, &out).unwrap();
        let got = r.relight_level.unwrap_or_else(|| panic!("{level:?}: no relight_level"));
        assert_eq!(got.source, level);
        assert!(
            (got.scale / first.exposure - 1.0).abs() < 1e-4,
            "{level:?}: {got:?} vs {}",
            first.exposure
        );
        let (relit, photo) = (image::open(out.join("relit.png")).unwrap(), image::open(&p).unwrap());
        let diff = relit
            .to_rgb8()
            .pixels()
            .zip(photo.to_rgb8().pixels())
            .fold(0_u8, |m, (a, b)| (0..3).fold(m, |m, c| m.max(a[c].abs_diff(b[c]))));
        assert!(diff <= 1, "{level:?}: the relit photo differs by {diff}");
    }
}
