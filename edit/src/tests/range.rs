//! Whole edits held to the photo's range, and when the range is the photo's.

use crate::photo::srgb_decode;
use crate::range::{MIN_SCALE, MIN_SHARE};
use crate::tests::{dir, model, request, write_photo};
use crate::*;

/// The whole edit: a lambertian target under a given light forty times the photo's white,
/// composited by `detail`, which takes O''s level (`structure` and `ratio` take only O''s
/// change relative to I*, in which the light's level cancels).
#[test]
fn an_edit_brighter_than_the_photo_is_held_to_its_range_and_keeps_its_hue() {
    let d = dir("range");
    let (p, m, _) = write_photo(&d);
    let light = d.join("bright.exr");
    exr::prelude::write_rgb_file(&light, 16, 8, |_, _| (40.0_f32, 40.0_f32, 40.0_f32)).unwrap();
    let req = |range, composite| crate::EditRequest {
        light: Some(light.display().to_string()),
        light_level: crate::LevelFrom::Given,
        range,
        composite,
        ..request(&p, &m, "lambert:0.8,0.4,0.1")
    };
    let detail = Some(crate::Composite::Detail);
    let held = crate::edit(model(), &req(Some(Range::Photo), detail), &d.join("photo")).unwrap();
    let clipped = crate::edit(model(), &req(Some(Range::Clip), detail), &d.join("clip")).unwrap();
    // Unasked, a light at its own level is a known level: kept as rendered, and composited
    // by `detail`, which keeps the level.
    let known = crate::edit(model(), &req(None, None), &d.join("known")).unwrap();
    assert_eq!(
        (&known.range, known.composite),
        (&clipped.range, crate::Composite::Detail)
    );
    // A given light scaled by the network's fit is a guessed level: `structure`, as with L'.
    let guessed = crate::EditRequest {
        light_level: crate::LevelFrom::Network,
        ..req(None, None)
    };
    let guessed = crate::edit(model(), &guessed, &d.join("guessed")).unwrap();
    assert_eq!(guessed.composite, crate::Composite::Structure);
    let (h, c) = (&held.range[0], &clipped.range[0]);
    assert!(
        c.rendered_share_above_white > 0.5 && !c.applied && c.scale == 1.0,
        "{c:?}"
    );
    assert!(h.applied && h.scale < 1.0 && h.scale >= MIN_SCALE, "{h:?}");
    assert_eq!(h.rendered_share_above_white, c.rendered_share_above_white);
    assert_eq!((h.photo_share_at_white, h.allowed_share), (0.0, MIN_SHARE));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("photo/report.json")).unwrap()).unwrap();
    assert_eq!(report["range"][0]["scale"].as_f64(), Some(h.scale));

    let read = |o: &str| image::open(d.join(o).join("edited.png")).unwrap().to_rgb8();
    let (hp, cp) = (read("photo"), read("clip"));
    let photo = image::open(&p).unwrap().to_rgb8();
    let mask = image::open(&m).unwrap().to_luma8();
    let lin = |b: u8| srgb_decode(b as f32 / 255.0);
    let (mut object, mut white) = (0, 0);
    for (x, y, q) in photo.enumerate_pixels() {
        if mask.get_pixel(x, y)[0] == 0 {
            assert_eq!(
                (hp.get_pixel(x, y), cp.get_pixel(x, y)),
                (q, q),
                "background ({x}, {y})"
            );
            continue;
        }
        object += 1;
        white += usize::from(cp.get_pixel(x, y).0 == [255; 3]);
        let [r, g, b] = hp.get_pixel(x, y).0.map(lin);
        assert!(r > 0.05, "({x}, {y}) black: {:?}", hp.get_pixel(x, y));
        assert!(
            (g / r - 0.5).abs() < 0.03 && (b / r - 0.125).abs() < 0.02,
            "({x}, {y}) hue lost: {r} {g} {b}"
        );
    }
    assert!(white * 2 > object, "clipped: {white} of {object} pixels white");
}

#[test]
fn the_range_is_the_photos_only_while_the_level_is_the_networks_guess() {
    assert_eq!(Range::best_for(false), Range::Photo);
    assert_eq!(Range::best_for(true), Range::Clip);
    assert_eq!(crate::Look::from(crate::Composite::Render).range, Range::Photo);
    let known = crate::Look::chosen(None, None, true);
    assert_eq!((known.composite, known.range), (crate::Composite::Ratio, Range::Clip));
    let asked = crate::Look::chosen(Some(crate::Composite::Render), Some(Range::Photo), true);
    assert_eq!((asked.composite, asked.range), (crate::Composite::Render, Range::Photo));
}
