//! The command line's inputs against its outputs: no input of an edit inside `--out` under an
//! output's name, however the edit names it (a path, a light or relight probe, a material file,
//! the object's own material), and an EXR photo of more than one part refused before decoding.

use crate::tests::{dir, model, request, write_photo};
use crate::transfer::Given;
use crate::{Pair, edit, transfer};
use std::path::Path;

fn refused(e: anyhow::Error, input: &Path) {
    let text = format!("{e:#}");
    assert!(text.contains("would overwrite this input"), "{text}");
    assert!(text.contains(&input.display().to_string()), "{text}");
}

#[test]
fn no_input_named_anywhere_in_the_edit_may_be_replaced_by_an_output() {
    let d = dir("inputs-in-out");
    let (p, m, _) = write_photo(&d);
    let out = d.join("out");
    std::fs::create_dir_all(&out).unwrap();
    // A light probe the edit reads, where L' goes.
    let probe = out.join("env.exr");
    let (w, h) = (8, 4);
    let v = vec![0.5_f32; w * h];
    matedit_contract::io::write_exr_channels(&probe, w, h, vec![("R", v.clone()), ("G", v.clone()), ("B", v)]).unwrap();
    let before = std::fs::read(&probe).unwrap();
    let mut r = request(&p, &m, "library:rubber-red");
    r.light = Some(probe.display().to_string());
    refused(edit(model(), &r, &out).unwrap_err(), &probe);
    let mut r = request(&p, &m, "library:rubber-red");
    r.relight = Some(probe.display().to_string());
    refused(edit(model(), &r, &out).unwrap_err(), &probe);
    assert_eq!(std::fs::read(&probe).unwrap(), before, "the probe is untouched");
    // A material file where m' goes, as the target and as the object's own material.
    let material = out.join("material.dsbrdf.json");
    std::fs::copy(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/materials/red_plastic.dsbrdf.json"),
        &material,
    )
    .unwrap();
    let spec = format!("dsbrdf:{}", material.display());
    refused(edit(model(), &request(&p, &m, &spec), &out).unwrap_err(), &material);
    let mut r = request(&p, &m, "library:rubber-red");
    r.input_material = Some(spec.clone());
    refused(edit(model(), &r, &out).unwrap_err(), &material);
    // In a transfer, either photo's known material.
    let mut to = Given::photo(&p, Some(&m));
    to.material = Some(&spec);
    let e = transfer(
        model(),
        Pair {
            first: Given::photo(&p, Some(&m)),
            second: to,
            eq6: None,
            look: crate::Composite::Render.into(),
        },
        &out,
    )
    .unwrap_err();
    refused(e, &material);
    // A file of another name in the output folder is not an output's, and the edit runs.
    let mine = out.join("notes-light.exr");
    std::fs::rename(&probe, &mine).unwrap();
    let mut r = request(&p, &m, "library:rubber-red");
    r.light = Some(mine.display().to_string());
    edit(model(), &r, &out).unwrap();
    assert_eq!(std::fs::read(&mine).unwrap(), before);
}

#[test]
fn an_exr_photo_of_two_parts_is_refused_before_anything_is_decoded() {
    use exr::prelude::{
        AnyChannel, AnyChannels, Encoding, FlatSamples, Image, Layer, LayerAttributes, SmallVec, WritableImage,
    };
    let d = dir("two-parts");
    let part = |name: &str, size: (usize, usize), channels: &[&str]| {
        let n = size.0 * size.1;
        let list: Vec<AnyChannel<FlatSamples>> = channels
            .iter()
            .map(|c| AnyChannel::new(*c, FlatSamples::F32(vec![0.5; n])))
            .collect();
        Layer::new(
            size,
            LayerAttributes::named(name),
            Encoding::SMALL_LOSSLESS,
            AnyChannels::sort(SmallVec::from_vec(list)),
        )
    };
    // Part 0 a 1 × 1 luminance image, part 1 the photo the limit was never asked about.
    let image = Image::from_layers(
        exr::meta::header::ImageAttributes::new(exr::meta::attribute::IntegerBounds::from_dimensions((64, 48))),
        SmallVec::from_vec(vec![part("y", (1, 1), &["Y"]), part("rgb", (64, 48), &["B", "G", "R"])]),
    );
    let p = d.join("two.exr");
    image.write().to_file(&p).unwrap();
    let e = format!("{:#}", crate::photo::load_photo(&p).unwrap_err());
    assert!(e.contains("must have one part") && e.contains("has 2"), "{e}");
}
