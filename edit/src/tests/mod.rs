#![allow(clippy::needless_range_loop)] // pixel indices shared by several buffers

use super::photo::{Framing, TRAINING_FILL, load_photo, srgb_decode};
use super::*;
use burn::optim::AdamConfig;
use burn::tensor::Device;
use matedit_physics::tonemap::tonemap_u8;
use matedit_trainer::model::Widths;
use matedit_trainer::model::network::NetConfig;
use matedit_trainer::post_optimisation;
use matedit_trainer::train::checkpoint::{State, save};
use std::path::PathBuf;
use std::sync::OnceLock;

pub(crate) fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("matedit-edit-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A checkpoint of a small untrained network (16² input, 4-row environments).
pub(crate) fn model() -> &'static Path {
    static M: OnceLock<PathBuf> = OnceLock::new();
    M.get_or_init(|| {
        let root = dir("model");
        let device = Device::flex();
        device.seed(3);
        let cfg = NetConfig::new(16, Widths::new(4, 16, 32, 8)).with_env_height(4);
        let net = cfg.init(&device);
        let state = State::untrained(cfg, "untrained");
        save(&root, "untrained", &net, &AdamConfig::new().init(), state).unwrap()
    })
}

/// A 60×40 sRGB photo: a grey-blue gradient background and an orange ellipse, with its mask
/// (white on black) and a two-region label image (left half 1, right half 2).
pub(crate) fn write_photo(d: &Path) -> (PathBuf, PathBuf, PathBuf) {
    let (w, h) = (60u32, 40u32);
    let inside = |x: u32, y: u32| {
        let (u, v) = ((x as f64 - 30.0) / 20.0, (y as f64 - 22.0) / 12.0);
        u * u + v * v <= 1.0
    };
    let photo = image::RgbImage::from_fn(w, h, |x, y| {
        if inside(x, y) {
            image::Rgb([200, 120 + (x % 7) as u8, 40])
        } else {
            image::Rgb([(x * 4) as u8, 100, (y * 5) as u8])
        }
    });
    let mask = image::GrayImage::from_fn(w, h, |x, y| image::Luma([if inside(x, y) { 255 } else { 0 }]));
    let regions = image::GrayImage::from_fn(w, h, |x, _| image::Luma([if x < 30 { 1 } else { 2 }]));
    let (p, m, r) = (d.join("photo.png"), d.join("mask.png"), d.join("regions.png"));
    photo.save(&p).unwrap();
    mask.save(&m).unwrap();
    regions.save(&r).unwrap();
    (p, m, r)
}

pub(crate) fn request(p: &Path, m: &Path, material: &str) -> EditRequest {
    EditRequest {
        photo: p.to_path_buf(),
        mask: Some(m.to_path_buf()),
        materials: vec![(None, material.to_string())],
        ..Default::default()
    }
}

#[test]
fn srgb_bytes_survive_decoding_and_the_output_tone_map() {
    // Pixels outside the mask are written back through the same tone map: every byte must
    // come back unchanged.
    for b in 0..=255u8 {
        assert_eq!(tonemap_u8(srgb_decode(b as f32 / 255.0), 1.0), b, "byte {b}");
    }
}

#[test]
fn framing_fills_like_the_training_images_and_area_averages_exactly() {
    // A box object of 30×10 pixels in a 100×50 photo: the crop is 30/0.875 wide, centred on it.
    let (w, h) = (100, 50);
    let cov: Vec<f32> = (0..w * h)
        .map(|k| {
            let (x, y) = (k % w, k / w);
            if (20..50).contains(&x) && (30..40).contains(&y) {
                1.0
            } else {
                0.0
            }
        })
        .collect();
    for size in [8, 16, 64] {
        let f = Framing::around(&cov, w, h, size);
        assert!((f.side - 30.0 / TRAINING_FILL).abs() < 1e-9);
        assert!((f.x0 + f.side / 2.0 - 35.0).abs() < 1e-9 && (f.y0 + f.side / 2.0 - 35.0).abs() < 1e-9);
        // Against a brute-force average (lattice points per cell, padding as zero), for a
        // constant, a ramp and the mask; the crop leaves the photo at the bottom.
        for (name, value) in [
            (
                "constant",
                Box::new(|_: usize| [2.0_f32]) as Box<dyn Fn(usize) -> [f32; 1]>,
            ),
            (
                "ramp",
                Box::new(move |k: usize| [(k % w) as f32 + 0.5 * (k / w) as f32]),
            ),
            ("mask", Box::new(|k: usize| [cov[k]])),
        ] {
            let got = f.area_average(w, h, &value);
            for cell in 0..size * size {
                let (cu, cv) = (cell % size, cell / size);
                let (mut s, mut n) = (0.0_f64, 0);
                for y in -10..70_i64 {
                    for x in -10..120_i64 {
                        let (u, v) = f.to_net(x as f64 + 0.5, y as f64 + 0.5);
                        if u.floor() as usize == cu && v.floor() as usize == cv && u >= 0.0 && v >= 0.0 {
                            n += 1;
                            if x >= 0 && y >= 0 && (x as usize) < w && (y as usize) < h {
                                s += value(y as usize * w + x as usize)[0] as f64;
                            }
                        }
                    }
                }
                if n > 0 {
                    let want = s / n as f64;
                    assert!(
                        (got[cell][0] as f64 - want).abs() < 1e-4 * want.abs().max(1.0),
                        "{name} {size} {cell}"
                    );
                }
            }
        }
    }
}

#[test]
fn a_photo_is_edited_and_only_the_object_changes() {
    let d = dir("ok");
    let (p, m, r) = write_photo(&d);
    let out = d.join("out");
    let report = edit(model(), &request(&p, &m, "lambert:0.1,0.2,0.9"), &out).unwrap();
    for f in [
        "edited.png",
        "edited.exr",
        "input.png",
        "i_prime.exr",
        "o_prime.png",
        "normals.exr",
        "env.exr",
        "material.dsbrdf.json",
        "sheet.png",
        "report.json",
    ] {
        assert!(out.join(f).is_file(), "{f}");
    }
    assert_eq!(report.photo_size, [60, 40]);
    assert!((report.exposure - 0.0).abs() > 0.0);
    // Outside the mask, the very bytes of the photo; inside, a change.
    let (a, b) = (
        image::open(&p).unwrap().to_rgb8(),
        image::open(out.join("edited.png")).unwrap().to_rgb8(),
    );
    let mask = image::open(&m).unwrap().to_luma8();
    let mut changed = 0;
    for ((pa, pb), pm) in a.pixels().zip(b.pixels()).zip(mask.pixels()) {
        if pm[0] == 0 {
            assert_eq!(pa, pb);
        } else if pa != pb {
            changed += 1;
        }
    }
    assert!(changed > 100, "{changed} object pixels changed");
    // m' is a material file that loads.
    matedit_physics::brdf::Dsbrdf::load(&out.join("material.dsbrdf.json")).unwrap();
    // The report is JSON with the settings.
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(v["regions"][0]["spec"], "lambert:0.1,0.2,0.9");
    assert_eq!(v["input_size"], 16);

    // Two regions with a red and a blue target: O' is redder on the left, bluer on the right.
    let out2 = d.join("out2");
    let req = EditRequest {
        regions: Some(r),
        materials: vec![
            (Some(1), "lambert:0.9,0.05,0.05".into()),
            (Some(2), "lambert:0.05,0.05,0.9".into()),
        ],
        ..request(&p, &m, "unused")
    };
    let rep = edit(model(), &req, &out2).unwrap();
    assert_eq!(rep.regions.len(), 2);
    assert!(out2.join("material-1.dsbrdf.json").is_file() && out2.join("material-2.dsbrdf.json").is_file());
    let (w, h, ch) = matedit_contract::io::read_exr_channels(&out2.join("o_prime.exr")).unwrap();
    let (mut left, mut right) = ([0.0_f64; 2], [0.0_f64; 2]);
    for k in 0..w * h {
        let side = if k % w < w / 2 { &mut left } else { &mut right };
        side[0] += ch["R"][k] as f64;
        side[1] += ch["B"][k] as f64;
    }
    assert!(
        left[0] > left[1] && right[1] > right[0],
        "left {left:?} right {right:?}"
    );

    // Relit under a builtin map, with the ratio composite.
    let out3 = d.join("out3");
    let req = EditRequest {
        relight: Some("builtin:studio".into()),
        materials: Vec::new(),
        composite: Some(Composite::Ratio),
        ..request(&p, &m, "unused")
    };
    edit(model(), &req, &out3).unwrap();
    assert!(out3.join("relit.png").is_file() && !out3.join("edited.png").exists());
}

#[test]
fn bad_inputs_name_the_file_and_write_nothing() {
    let d = dir("bad");
    let (p, m, r) = write_photo(&d);
    let check = |req: EditRequest, model_dir: &Path, needle: &str| {
        let out = d.join("never");
        let e = format!("{:#}", edit(model_dir, &req, &out).unwrap_err());
        assert!(e.contains(needle), "{e:?} lacks {needle:?}");
        assert!(!out.exists(), "{needle}: something was written");
    };
    // Photo and mask of different sizes.
    let small = d.join("small.png");
    image::GrayImage::from_pixel(30, 20, image::Luma([255]))
        .save(&small)
        .unwrap();
    check(request(&p, &small, "library:rubber-red"), model(), "must match");
    // Empty mask, and one covering everything.
    let empty = d.join("empty.png");
    image::GrayImage::from_pixel(60, 40, image::Luma([0]))
        .save(&empty)
        .unwrap();
    check(
        request(&p, &empty, "library:rubber-red"),
        model(),
        "empty.png: the mask is empty",
    );
    let full = d.join("full.png");
    image::GrayImage::from_pixel(60, 40, image::Luma([9]))
        .save(&full)
        .unwrap();
    check(
        request(&p, &full, "library:rubber-red"),
        model(),
        "covers the whole photo",
    );
    // A truncated photo, a file that is no image, a format we do not read.
    let bytes = std::fs::read(&p).unwrap();
    let cut = d.join("cut.png");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    check(request(&cut, &m, "library:rubber-red"), model(), "cut.png");
    // A JPEG cut anywhere after its header (the decoder would fill the rest with one colour),
    // as a photo and as a mask; the whole file is accepted.
    let jpg = d.join("whole.jpg");
    image::open(&p).unwrap().to_rgb8().save(&jpg).unwrap();
    let jbytes = std::fs::read(&jpg).unwrap();
    let mask_jpg = d.join("mask.jpg");
    image::open(&m).unwrap().to_luma8().save(&mask_jpg).unwrap();
    let mbytes = std::fs::read(&mask_jpg).unwrap();
    // The first `frac` of `bytes` as file `name`.
    let cut = |bytes: &[u8], name: &str, frac: f64| {
        let f = d.join(name);
        std::fs::write(&f, &bytes[..(bytes.len() as f64 * frac) as usize]).unwrap();
        f
    };
    for frac in [0.3, 0.6, 0.9, 0.99] {
        let (photo, mask) = (format!("cut-{frac}.jpg"), format!("cut-mask-{frac}.jpg"));
        let cut_photo = cut(&jbytes, &photo, frac);
        check(request(&cut_photo, &m, "library:rubber-red"), model(), &photo);
        let cut_mask = cut(&mbytes, &mask, frac);
        check(request(&p, &cut_mask, "library:rubber-red"), model(), &mask);
    }
    // Only the end-of-image marker missing: the decoder alone would accept it.
    let missing_end = d.join("no-eoi.jpg");
    std::fs::write(&missing_end, &jbytes[..jbytes.len() - 2]).unwrap();
    check(request(&missing_end, &m, "library:rubber-red"), model(), "truncated");
    // A photo whose object is black: refused naming the photo (in a transfer, which of two).
    let dark = d.join("dark-object.png");
    let mask_img = image::open(&m).unwrap().to_luma8();
    image::RgbImage::from_fn(60, 40, |x, y| {
        if mask_img.get_pixel(x, y)[0] > 0 {
            image::Rgb([0, 0, 0])
        } else {
            image::Rgb([90, 90, 90])
        }
    })
    .save(&dark)
    .unwrap();
    check(
        request(&dark, &m, "library:rubber-red"),
        model(),
        "dark-object.png: the object is black",
    );
    let e = transfer(
        model(),
        Pair {
            first: Given::photo(&p, Some(&m)),
            second: Given::photo(&dark, Some(&m)),
            eq6: None,
            look: Composite::Detail.into(),
        },
        &d.join("never"),
    )
    .unwrap_err();
    assert!(
        format!("{e:#}").contains("dark-object.png: the object is black"),
        "{e:#}"
    );
    // A one-pixel object and a one-pixel-thin line across the photo: both refused, by the
    // same rule (too few pixels; too narrow), not one blown up and the other called too thin.
    let dot = d.join("dot.png");
    image::GrayImage::from_fn(60, 40, |x, y| image::Luma([if (x, y) == (30, 20) { 255 } else { 0 }]))
        .save(&dot)
        .unwrap();
    check(request(&p, &dot, "library:rubber-red"), model(), "marks 1 pixel(s)");
    let line = d.join("line.png");
    image::GrayImage::from_fn(60, 40, |_, y| image::Luma([if y == 20 { 255 } else { 0 }]))
        .save(&line)
        .unwrap();
    check(
        request(&p, &line, "library:rubber-red"),
        model(),
        "the mask marks 60 pixel(s)",
    );
    let bar = d.join("bar.png");
    image::GrayImage::from_fn(60, 40, |_, y| {
        image::Luma([if (20..23).contains(&y) { 255 } else { 0 }])
    })
    .save(&bar)
    .unwrap();
    check(
        request(&p, &bar, "library:rubber-red"),
        model(),
        "the object is 60×3 pixels",
    );
    // An empty file and a folder, named as such.
    let empty = d.join("empty.png");
    std::fs::write(&empty, b"").unwrap();
    check(
        request(&empty, &m, "library:rubber-red"),
        model(),
        "empty.png is empty (0 bytes)",
    );
    let folder = d.join("folder.png");
    std::fs::create_dir_all(&folder).unwrap();
    check(
        request(&folder, &m, "library:rubber-red"),
        model(),
        "folder.png is a folder",
    );
    check(
        request(&p, &folder, "library:rubber-red"),
        model(),
        "folder.png is a folder",
    );
    // Linear photos cut short: EXR and HDR, as the whole files are accepted.
    let rgb = image::open(&p).unwrap().to_rgb32f();
    let exr = d.join("whole.exr");
    let plane = |c: usize| rgb.pixels().map(|px| px[c]).collect::<Vec<f32>>();
    matedit_contract::io::write_exr_channels(&exr, 60, 40, vec![("R", plane(0)), ("G", plane(1)), ("B", plane(2))])
        .unwrap();
    let hdr = d.join("whole.hdr");
    let pixels: Vec<image::Rgb<f32>> = rgb.pixels().copied().collect();
    image::codecs::hdr::HdrEncoder::new(std::fs::File::create(&hdr).unwrap())
        .encode(&pixels, 60, 40)
        .unwrap();
    for whole in [&exr, &hdr] {
        let bytes = std::fs::read(whole).unwrap();
        let ext = whole.extension().unwrap().to_str().unwrap();
        for frac in [0.5, 0.95] {
            let name = format!("cut-{frac}.{ext}");
            check(
                request(&cut(&bytes, &name, frac), &m, "library:rubber-red"),
                model(),
                &name,
            );
        }
        assert!(
            edit(
                model(),
                &request(whole, &m, "library:rubber-red"),
                &d.join(format!("{ext}-out"))
            )
            .is_ok()
        );
    }
    assert!(
        edit(
            model(),
            &request(&jpg, &mask_jpg, "library:rubber-red"),
            &d.join("jpg-out")
        )
        .is_ok(),
        "a whole JPEG photo and mask are edited"
    );
    let junk = d.join("junk.jpg");
    std::fs::write(&junk, b"not a jpeg at all").unwrap();
    check(request(&junk, &m, "library:rubber-red"), model(), "junk.jpg");
    check(
        request(&d.join("photo.gif"), &m, "library:rubber-red"),
        model(),
        "photo.gif",
    );
    // No mask and no alpha.
    let no_mask = EditRequest {
        mask: None,
        ..request(&p, &m, "library:rubber-red")
    };
    check(no_mask, model(), "no alpha channel");
    // A region with no material, a material for a region that does not exist, an unknown
    // material.
    let two = EditRequest {
        regions: Some(r.clone()),
        materials: vec![(Some(1), "library:rubber-red".into())],
        ..request(&p, &m, "x")
    };
    check(two, model(), "region 2 of");
    let three = EditRequest {
        regions: Some(r),
        materials: vec![(None, "library:rubber-red".into()), (Some(3), "library:oak".into())],
        ..request(&p, &m, "x")
    };
    check(three, model(), "no region 3");
    check(request(&p, &m, "library:unobtainium"), model(), "unobtainium");
    // Nothing asked.
    let nothing = EditRequest {
        materials: Vec::new(),
        ..request(&p, &m, "x")
    };
    check(nothing, model(), "nothing to do");
    // Not a checkpoint; a checkpoint whose weights are of another shape.
    check(request(&p, &m, "library:rubber-red"), &d, "not a checkpoint folder");
    let other = dir("other-shape");
    for f in ["state.json", "optimizer.bpk"] {
        std::fs::copy(model().join(f), other.join(f)).unwrap();
    }
    let device = Device::flex();
    let wide = NetConfig::new(16, Widths::new(8, 16, 32, 8))
        .with_env_height(4)
        .init(&device);
    burn::module::Module::into_record(wide)
        .save(other.join("model.bpk"))
        .unwrap();
    check(request(&p, &m, "library:rubber-red"), &other, "model.bpk");
    // An output folder where an output would replace the photo.
    let clash = dir("clash");
    std::fs::copy(&p, clash.join("edited.png")).unwrap();
    let e = edit(
        model(),
        &request(&clash.join("edited.png"), &m, "library:rubber-red"),
        &clash,
    )
    .unwrap_err();
    assert!(e.to_string().contains("would overwrite"), "{e}");
}

#[test]
fn a_photo_over_the_pixel_limit_is_refused_before_decoding() {
    let d = dir("huge");
    // 12000 × 9000 = 108 megapixels of one colour: a small file, refused from its header.
    let path = d.join("huge.png");
    let enc = image::codecs::png::PngEncoder::new_with_quality(
        std::fs::File::create(&path).unwrap(),
        image::codecs::png::CompressionType::Fast,
        image::codecs::png::FilterType::NoFilter,
    );
    let row = vec![0u8; 12000];
    let img: Vec<u8> = row.iter().copied().cycle().take(12000 * 9000).collect();
    image::ImageEncoder::write_image(enc, &img, 12000, 9000, image::ExtendedColorType::L8).unwrap();
    let e = format!("{:#}", load_photo(&path).unwrap_err());
    assert!(e.contains("108 megapixels"), "{e}");
}

#[test]
fn transfer_and_swap_render_each_object_with_the_others_predicted_material() {
    let d = dir("transfer");
    let (p, m, _) = write_photo(&d);
    // A second photo: the same ellipse, blue, on another background.
    let q = d.join("other.png");
    let photo = image::open(&p).unwrap().to_rgb8();
    let mask = image::open(&m).unwrap().to_luma8();
    let other = image::RgbImage::from_fn(60, 40, |x, y| {
        if mask.get_pixel(x, y)[0] > 0 {
            image::Rgb([30, 60, 210])
        } else {
            image::Rgb([photo.get_pixel(x, y)[1], 40, 90])
        }
    });
    other.save(&q).unwrap();
    let out = d.join("t");
    let r = transfer(
        model(),
        Pair {
            first: Given::photo(&p, Some(&m)),
            second: Given::photo(&q, Some(&m)),
            eq6: None,
            look: Composite::Render.into(),
        },
        &out,
    )
    .unwrap();
    assert!(r.regions[0].spec.contains("photo.png"), "{:?}", r.regions);
    assert!(r.photo.ends_with("other.png"));
    assert!(out.join("edited.png").is_file() && out.join("report.json").is_file());
    // The material rendered on the target is the source's m', as an edit of the source writes it.
    let src = d.join("src");
    edit(model(), &request(&p, &m, "lambert:0.5,0.5,0.5"), &src).unwrap();
    // m' as written is a material `--material dsbrdf:PATH` takes.
    let written = src.join("material.dsbrdf.json");
    edit(
        model(),
        &request(&q, &m, &format!("dsbrdf:{}", written.display())),
        &d.join("m-prime"),
    )
    .unwrap();
    assert_eq!(
        std::fs::read_to_string(src.join("material.dsbrdf.json")).unwrap(),
        std::fs::read_to_string(out.join("target.dsbrdf.json")).unwrap()
    );
    let swapped = d.join("s");
    let [a, b] = swap(
        model(),
        Pair {
            first: Given::photo(&p, Some(&m)),
            second: Given::photo(&q, Some(&m)),
            eq6: None,
            look: Composite::Ratio.into(),
        },
        &swapped,
    )
    .unwrap();
    assert!(a.regions[0].spec.contains("other.png") && b.regions[0].spec.contains("photo.png"));
    assert!(swapped.join("a/edited.png").is_file() && swapped.join("b/edited.png").is_file());
    // An object's own material, when given, is what the other receives, and it sets its own
    // light's level: the same as `edit --input-material` with the other's material.
    let grey = "lambert:0.3,0.3,0.3";
    let known = d.join("k");
    let [ka, kb] = swap(
        model(),
        Pair {
            first: Given {
                material: Some(grey),
                ..Given::photo(&p, Some(&m))
            },
            second: Given::photo(&q, Some(&m)),
            eq6: None,
            look: Composite::Ratio.into(),
        },
        &known,
    )
    .unwrap();
    assert_eq!(
        (ka.input_material.as_deref(), kb.input_material.as_deref()),
        (Some(grey), None)
    );
    assert_eq!(
        (kb.regions[0].spec.as_str(), ka.light_level.source.as_str()),
        (grey, "input material")
    );
    let by_edit = d.join("k-edit");
    let req = EditRequest {
        input_material: Some(grey.to_string()),
        composite: Some(Composite::Ratio),
        ..request(&p, &m, "lambert:0.5,0.5,0.5")
    };
    edit(model(), &req, &by_edit).unwrap();
    assert_eq!(
        std::fs::read(by_edit.join("env.exr")).unwrap(),
        std::fs::read(known.join("a/env.exr")).unwrap(),
        "a's light is the one its own material gives"
    );
    let t = transfer(
        model(),
        Pair {
            first: Given {
                material: Some(grey),
                ..Given::photo(&p, Some(&m))
            },
            second: Given {
                material: Some(grey),
                ..Given::photo(&q, Some(&m))
            },
            eq6: None,
            look: Composite::Ratio.into(),
        },
        &d.join("kt"),
    )
    .unwrap();
    assert_eq!(
        (t.regions[0].spec.as_str(), t.input_material.as_deref()),
        (grey, Some(grey))
    );
    // With Eq. 6, which would change it, refused naming the option; nothing written.
    let e = transfer(
        model(),
        Pair {
            first: Given::photo(&p, Some(&m)),
            second: Given {
                material: Some(grey),
                ..Given::photo(&q, Some(&m))
            },
            eq6: Some(&post_optimisation::Eq6Config::default()),
            look: Composite::Ratio.into(),
        },
        &d.join("never"),
    )
    .unwrap_err();
    assert!(format!("{e:#}").contains("--to-material"), "{e:#}");
    // A bad second photo writes nothing for either.
    let never = d.join("never");
    let e = swap(
        model(),
        Pair {
            first: Given::photo(&p, Some(&m)),
            second: Given::photo(&d.join("missing.png"), Some(&m)),
            eq6: None,
            look: Composite::Render.into(),
        },
        &never,
    )
    .unwrap_err();
    assert!(format!("{e:#}").contains("missing.png"));
    assert!(!never.exists());
}

fn as_refs(ch: &[(String, Vec<f32>)]) -> Vec<(&str, Vec<f32>)> {
    ch.iter().map(|(n, v)| (n.as_str(), v.clone())).collect()
}

#[test]
fn an_exr_photo_is_read_from_its_r_g_b_and_a_whatever_else_it_holds() {
    let d = dir("exr-channels");
    let (w, h) = (6usize, 4usize);
    let plane = |c: usize| {
        (0..w * h)
            .map(|k| 0.1 * c as f32 + 0.01 * k as f32)
            .collect::<Vec<f32>>()
    };
    let mut ch: Vec<(String, Vec<f32>)> = vec![("R".into(), plane(1)), ("G".into(), plane(2)), ("B".into(), plane(3))];
    let rgb_only = d.join("rgb.exr");
    matedit_contract::io::write_exr_channels(&rgb_only, w, h, as_refs(&ch)).unwrap();
    for k in 0..10 {
        ch.push((format!("extra{k}"), vec![1e6; w * h]));
    }
    ch.push(("A".into(), vec![0.5; w * h]));
    let many = d.join("many.exr");
    matedit_contract::io::write_exr_channels(&many, w, h, as_refs(&ch)).unwrap();
    let (a, b) = (load_photo(&rgb_only).unwrap(), load_photo(&many).unwrap());
    assert_eq!(a.rgb, b.rgb);
    assert!(a.alpha.is_none());
    assert_eq!(b.alpha, Some(vec![0.5; w * h]));
    assert!((a.rgb[5][1] - (0.2 + 0.05)).abs() < 1e-6);
    // Without G: refused by name.
    let no_g = d.join("no-g.exr");
    matedit_contract::io::write_exr_channels(&no_g, w, h, vec![("R", plane(1)), ("B", plane(3))]).unwrap();
    let e = format!("{:#}", load_photo(&no_g).unwrap_err());
    assert!(e.contains("no G channel"), "{e}");
}

mod inputs;
mod light;
mod normals;
mod photo;
mod range;
mod relight;
