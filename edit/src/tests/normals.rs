//! Whole edits with given normals: the map reaches the render, bad maps are refused before anything is written.

use crate::tests::{dir, model, request, write_photo};
use crate::{Composite, EditRequest, Given};
use std::path::Path;

/// `tilt` on the object of the 60×40 test photo's mask `m`, 0 elsewhere: a normal map.
fn write_tilted(path: &Path, m: &Path, tilt: [f32; 3]) {
    let coverage = crate::photo::load_mask(m, 60, 40, image::metadata::Orientation::NoTransforms)
        .expect("mask")
        .0;
    exr::prelude::write_rgb_file(path, 60, 40, |x, y| {
        let n = if coverage[y * 60 + x] > 0.0 { tilt } else { [0.0; 3] };
        (n[0], n[1], n[2])
    })
    .expect("exr");
}

/// An edit's `normals.exr`: its size and its normals.
fn read_written(file: &Path) -> (usize, usize, Vec<[f32; 3]>) {
    let (w, h, ch) = matedit_contract::io::read_exr_channels(file).expect("normals.exr");
    let c = |n: &str| ch.get(n).cloned().expect("channel");
    let (x, y, z) = (c("X"), c("Y"), c("Z"));
    (w, h, (0..w * h).map(|k| [x[k], y[k], z[k]]).collect())
}

#[test]
fn an_edit_renders_with_the_given_normals_and_refuses_a_bad_map_before_writing() {
    let d = dir("given-normals");
    let (p, m, _) = write_photo(&d);
    let tilt = [0.6_f32, -0.48, 0.64];
    let map = d.join("normals.exr");
    write_tilted(&map, &m, tilt);
    let out = d.join("out");
    let req = EditRequest {
        normals: Some(map.clone()),
        ..request(&p, &m, "lambert:0.2,0.6,0.2")
    };
    let report = crate::edit(model(), &req, &out).expect("edit with given normals");
    let r = report.normals.as_ref().expect("reported");
    assert_eq!((r.network_pixels_kept, r.detail_pixels_kept), (0, 0));
    // n* as written (the network's resolution) is the map's normal on every object pixel.
    let (w, h, written) = read_written(&out.join("normals.exr"));
    let on: Vec<&[f32; 3]> = written.iter().filter(|n| n.iter().any(|&v| v != 0.0)).collect();
    assert!(on.len() > w * h / 8, "{} of {w}×{h}", on.len());
    for n in on {
        assert!(n.iter().zip(&tilt).all(|(a, b)| (a - b).abs() < 1e-5), "{n:?}");
    }
    // The same edit without the map renders other normals.
    let plain = crate::edit(model(), &request(&p, &m, "lambert:0.2,0.6,0.2"), &d.join("plain")).expect("plain edit");
    assert!(plain.normals.is_none());
    let (_, _, predicted) = read_written(&d.join("plain").join("normals.exr"));
    assert_ne!(predicted, written);
    // A map of another size, or with no normal on the object: refused, nothing written.
    let small = d.join("small.png");
    image::RgbImage::from_pixel(30, 20, image::Rgb([128, 128, 255]))
        .save(&small)
        .expect("png");
    let blank = d.join("blank.png");
    image::RgbImage::from_pixel(60, 40, image::Rgb([128, 128, 128]))
        .save(&blank)
        .expect("png");
    for (bad, says) in [(small, "must match pixel for pixel"), (blank, "no usable normal")] {
        let o = d.join("refused");
        let req = EditRequest {
            normals: Some(bad),
            ..request(&p, &m, "lambert:0.2,0.6,0.2")
        };
        let e = crate::edit(model(), &req, &o).expect_err("bad map accepted");
        assert!(format!("{e:#}").contains(says), "{e:#}");
        assert!(!o.exists(), "a refused edit wrote {}", o.display());
    }
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn transfer_and_swap_render_each_photo_with_its_own_given_normals() {
    let d = dir("given-normals-transfer");
    let (p, m, _) = write_photo(&d);
    let tilt = [-0.36_f32, 0.48, 0.8];
    let map = d.join("map.exr");
    write_tilted(&map, &m, tilt);
    let written = |file: &Path| read_written(file).2;
    let all_tilted = |ns: &[[f32; 3]]| {
        let on: Vec<&[f32; 3]> = ns.iter().filter(|n| n.iter().any(|&v| v != 0.0)).collect();
        !on.is_empty()
            && on
                .iter()
                .all(|n| n.iter().zip(&tilt).all(|(a, b)| (a - b).abs() < 1e-5))
    };
    let with_map = Given {
        normals: Some(&map),
        ..Given::photo(&p, Some(&m))
    };
    let plain = Given::photo(&p, Some(&m));
    let pair = |first, second| crate::Pair {
        first,
        second,
        eq6: None,
        look: Composite::Detail.into(),
    };
    // Transfer: the receiving photo is rendered with its map; the map of the photo the
    // material comes from does not reach the output.
    let t = crate::transfer(model(), pair(plain, with_map), &d.join("t")).expect("transfer");
    assert_eq!(t.normals.as_ref().map(|r| r.detail_pixels_kept), Some(0));
    assert!(all_tilted(&written(&d.join("t/normals.exr"))));
    let f = crate::transfer(model(), pair(with_map, plain), &d.join("f")).expect("transfer");
    assert!(f.normals.is_none());
    assert!(!all_tilted(&written(&d.join("f/normals.exr"))));
    // Swap: each photo with its own.
    let [a, b] = crate::swap(model(), pair(with_map, plain), &d.join("s")).expect("swap");
    assert!(a.normals.is_some() && b.normals.is_none());
    assert!(all_tilted(&written(&d.join("s/a/normals.exr"))));
    assert!(!all_tilted(&written(&d.join("s/b/normals.exr"))));
    // A bad map on either side is refused by its name before anything is written.
    let small = d.join("small.png");
    image::RgbImage::from_pixel(30, 20, image::Rgb([128, 128, 255]))
        .save(&small)
        .expect("png");
    let bad = Given {
        normals: Some(&small),
        ..plain
    };
    let o = d.join("refused");
    let e = crate::transfer(model(), pair(bad, plain), &o).expect_err("bad map");
    assert!(format!("{e:#}").contains("small.png"), "{e:#}");
    let e = crate::swap(model(), pair(plain, bad), &o).expect_err("bad map");
    assert!(format!("{e:#}").contains("must match pixel for pixel"), "{e:#}");
    assert!(!o.exists(), "a refused transfer wrote {}", o.display());
    // A map inside the output folder, where the edit writes its own normals.exr, is refused
    // rather than overwritten, by edit and transfer alike.
    let inside = d.join("inside");
    std::fs::create_dir_all(&inside).expect("dir");
    std::fs::copy(&map, inside.join("normals.exr")).expect("copy");
    let req = crate::EditRequest {
        normals: Some(inside.join("normals.exr")),
        ..crate::tests::request(&p, &m, "lambert:0.2,0.6,0.2")
    };
    let e = crate::edit(model(), &req, &inside).expect_err("overwrote its normals");
    assert!(format!("{e:#}").contains("would overwrite this input"), "{e:#}");
    let given_inside = inside.join("normals.exr");
    let g = Given {
        normals: Some(&given_inside),
        ..plain
    };
    let e = crate::transfer(model(), pair(plain, g), &inside).expect_err("overwrote");
    assert!(format!("{e:#}").contains("would overwrite this input"), "{e:#}");
    assert_eq!(std::fs::read(&given_inside).ok(), std::fs::read(&map).ok());
    std::fs::remove_dir_all(&d).ok();
}
