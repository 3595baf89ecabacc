//! Whole edits of photos as they are shown: the focal length read from EXIF, and a turned photo.

use crate::photo::camera::{fov_of_equivalent_focal_length, tests::exif_block};
use crate::photo::orientation::tests::{stored_of, write_with_orientation};
use crate::photo::orientation::{Fit, swaps_axes};
use crate::tests::{dir, model, request, write_photo};
use crate::*;
use image::metadata::Orientation;

#[test]
fn the_photos_focal_length_sets_the_backgrounds_directions_unless_fov_is_given() {
    let d = dir("camera-edit");
    let (plain, mask, _) = write_photo(&d);
    let img = image::open(&plain).expect("photo").to_rgb8();
    let jpeg = d.join("phone.jpg");
    {
        use image::ImageEncoder;
        let f = std::io::BufWriter::new(std::fs::File::create(&jpeg).expect("create"));
        let mut enc = image::codecs::jpeg::JpegEncoder::new_with_quality(f, 95);
        enc.set_exif_metadata(exif_block(26, 1)).expect("exif");
        enc.write_image(img.as_raw(), img.width(), img.height(), image::ExtendedColorType::Rgb8)
            .expect("jpeg");
    }
    let level = |photo: &std::path::Path, fov: Option<f64>, name: &str| {
        let req = crate::EditRequest {
            light: Some("builtin:sky".into()),
            fov_deg: fov,
            ..request(photo, &mask, "lambert:0.1,0.5,0.1")
        };
        edit(model(), &req, &d.join(name)).expect("edit").light_level
    };
    let from_exif = level(&jpeg, None, "exif");
    let want = fov_of_equivalent_focal_length(26.0, 60, 40).expect("fov");
    assert_eq!(from_exif.fov_from, "exif");
    assert!((from_exif.fov_deg - want).abs() < 1e-9, "{from_exif:?}");
    // The field of view reaches the directions: the background's level moves with it.
    assert_eq!(from_exif.source.as_str(), "background", "{from_exif:?}");
    let at_default = level(&jpeg, Some(crate::light::background::DEFAULT_FOV_DEG), "at-default");
    assert!(
        (from_exif.scale / at_default.scale - 1.0).abs() > 1e-3,
        "{from_exif:?} {at_default:?}"
    );
    let given = level(&jpeg, Some(30.0), "given");
    assert_eq!((given.fov_deg, given.fov_from.as_str()), (30.0, "given"));
    let plain_level = level(&plain, None, "default");
    assert_eq!(
        (plain_level.fov_deg, plain_level.fov_from.as_str()),
        (crate::light::background::DEFAULT_FOV_DEG, "default")
    );
    std::fs::remove_dir_all(d).ok();
}

#[test]
fn a_turned_photo_edits_as_it_is_shown_with_its_mask_drawn_either_way() {
    let d = dir("orientation-edit");
    let (plain, mask, regions) = write_photo(&d);
    let model = model();
    let edit = |photo: &Path, mask: &Path, regions: Option<&Path>, name: &str| {
        let out = d.join(name);
        let req = crate::EditRequest {
            regions: regions.map(Path::to_path_buf),
            materials: vec![
                (Some(1), "lambert:0.1,0.5,0.1".into()),
                (Some(2), "ggx:0.15:1,1,1".into()),
            ],
            ..request(photo, mask, "")
        };
        let report = edit(model, &req, &out);
        (report, out)
    };
    let (want, out) = edit(&plain, &mask, Some(&regions), "plain");
    assert!(want.expect("plain photo").orientation.is_none());
    let want_png = image::open(out.join("edited.png")).expect("edited").to_rgb8();
    assert_eq!(want_png.dimensions(), (60, 40));
    let shown = image::open(&plain).expect("photo");
    let (shown_mask, shown_regions) = (
        image::open(&mask).expect("mask"),
        image::open(&regions).expect("regions"),
    );
    for tag in [6u16, 8, 3, 5] {
        let o = Orientation::from_exif(tag as u8).expect("tag");
        let photo = d.join(format!("photo-{tag}.png"));
        write_with_orientation(&photo, &stored_of(&shown, o).to_rgb8(), tag);
        // The mask and regions drawn on the photo as shown, then on its stored pixels.
        let stored_mask = d.join(format!("stored-mask-{tag}.png"));
        let stored_regions = d.join(format!("stored-regions-{tag}.png"));
        stored_of(&shown_mask, o).save(&stored_mask).expect("save");
        stored_of(&shown_regions, o).save(&stored_regions).expect("save");
        // A half turn keeps the size: a mask drawn on the stored pixels would fit too.
        let as_shown = if swaps_axes(o) {
            Fit::AsShown
        } else {
            Fit::AsShownOrStored
        };
        let mut cases = vec![(mask.clone(), regions.clone(), as_shown)];
        if swaps_axes(o) {
            cases.push((stored_mask, stored_regions, Fit::TurnedWithPhoto));
        }
        for (i, (m, r, fit)) in cases.into_iter().enumerate() {
            let (report, out) = edit(&photo, &m, Some(&r), &format!("turned-{tag}-{i}"));
            let report = report.unwrap_or_else(|e| panic!("tag {tag}, {fit:?}: {e:#}"));
            let o_report = report.orientation.expect("turned");
            assert_eq!(
                (o_report.exif, o_report.mask, o_report.regions),
                (tag as u8, Some(fit), Some(fit)),
                "tag {tag}"
            );
            assert_eq!(report.photo_size, [60, 40], "tag {tag}");
            // The same pixels in, the same edit out, byte for byte.
            let got = image::open(out.join("edited.png")).expect("edited").to_rgb8();
            assert!(
                got == want_png,
                "tag {tag}, {fit:?}: the turned photo's edit differs from the plain one's"
            );
            let json = std::fs::read_to_string(out.join("report.json")).expect("report");
            assert!(json.contains("\"orientation\""), "{json}");
        }
    }
    // A mask that fits neither the photo as shown nor its stored pixels names both sizes.
    let photo = d.join("photo-6.png");
    let wrong = d.join("wrong.png");
    image::GrayImage::new(50, 50).save(&wrong).expect("save");
    let e = format!("{:#}", edit(&photo, &wrong, None, "wrong").0.expect_err("refused"));
    assert!(
        e.contains("wrong.png")
            && e.contains("50×50")
            && e.contains("60×40")
            && e.contains("EXIF orientation 6")
            && e.contains("stored 40×60"),
        "{e}"
    );
    // A mask that carries an EXIF turn of its own but was written upright (a tool that
    // kept the tag) fits the plain photo as stored: its tag is ignored, and the edit is the
    // plain one.
    let tagged = d.join("tagged-mask.png");
    write_with_orientation(&tagged, &shown_mask.to_rgb8(), 6);
    let (report, out) = edit(&plain, &tagged, Some(&regions), "tagged");
    let o_report = report.expect("tagged mask").orientation.expect("said");
    assert_eq!((o_report.exif, o_report.mask), (1, Some(Fit::OwnOrientationIgnored)));
    let (want_one, want_out) = edit(&plain, &mask, Some(&regions), "plain-one");
    want_one.expect("plain");
    let got = image::open(out.join("edited.png")).expect("edited").to_rgb8();
    assert!(got == image::open(want_out.join("edited.png")).expect("edited").to_rgb8());
    std::fs::remove_dir_all(d).ok();
}
