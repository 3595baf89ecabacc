//! `datagen render` as a user runs it: outputs, messages and failure behaviour.

use std::process::Command;

fn datagen() -> Command {
    Command::new(env!("CARGO_BIN_EXE_datagen"))
}

/// A scratch folder of one test, removed when the test ends.
fn scratch(name: &str) -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix(&format!("matedit-cli-{name}-"))
        .tempdir()
        .unwrap()
}

#[test]
fn render_writes_an_exr_with_radiance_normals_and_mask_and_a_png() {
    let tmp = scratch("ok");
    let d = tmp.path();
    let (exr, png, env) = (d.join("s.exr"), d.join("s.png"), d.join("env.exr"));
    let out = datagen()
        .args([
            "render",
            "--shape",
            "sphere",
            "--brdf",
            "ggx:0.3:1,1,1",
            "--env",
            "builtin:sky",
            "--res",
            "32",
        ])
        .args(["--env-rotation", "-45", "--out"])
        .arg(&exr)
        .arg("--png")
        .arg(&png)
        .arg("--env-out")
        .arg(&env)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let (w, h, ch) = matedit_contract::io::read_exr_channels(&exr).unwrap();
    assert_eq!((w, h), (32, 32));
    for name in ["R", "G", "B", "normal.X", "normal.Y", "normal.Z", "mask", "region"] {
        assert!(ch.contains_key(name), "missing channel {name}");
        assert!(ch[name].iter().all(|v| v.is_finite()));
    }
    let covered = ch["mask"].iter().filter(|m| **m > 0.0).count();
    assert!(covered > 700 && covered < 820, "{covered}");
    let img = image::open(&png).unwrap();
    assert_eq!((img.width(), img.height()), (32, 32));
    let (ew, eh, _) = matedit_contract::io::read_exr_channels(&env).unwrap();
    assert_eq!((ew, eh), (128, 64));
    let log = String::from_utf8_lossy(&out.stderr);
    assert!(log.contains("time:") && log.contains("wrote"), "{log}");
}

#[test]
fn bad_arguments_name_the_problem_and_leave_existing_output_alone() {
    let tmp = scratch("bad");
    let d = tmp.path();
    let exr = d.join("keep.exr");
    std::fs::write(&exr, b"previous").unwrap();
    let cases: &[(&[&str], &str)] = &[
        (&["--brdf", "lambert:2,0,0", "--env", "builtin:sky"], "outside"),
        (&["--brdf", "phong:1", "--env", "builtin:sky"], "unknown model"),
        (
            &["--brdf", "lambert:0.5,0.5,0.5", "--env", "/nonexistent/sky.hdr"],
            "/nonexistent/sky.hdr",
        ),
        (&["--brdf", "lambert:0.5,0.5,0.5", "--env", "sky.png"], ".hdr or .exr"),
        (
            &[
                "--brdf",
                "lambert:0.5,0.5,0.5",
                "--env",
                "builtin:sky",
                "--env-res",
                "64x64",
            ],
            "W = 2H",
        ),
        (
            &[
                "--brdf",
                "lambert:0.5,0.5,0.5",
                "--env",
                "builtin:sky",
                "--shape",
                "/nonexistent/m.obj",
            ],
            "/nonexistent/m.obj",
        ),
        (
            &["--brdf", "dsbrdf:/nonexistent/m.json", "--env", "builtin:sky"],
            "/nonexistent/m.json",
        ),
        (
            &["--brdf", "lambert:0.5,0.5,0.5", "--env", "builtin:sky", "--res", "0"],
            "--res",
        ),
        (
            &["--brdf", "nbrdf:/nonexistent/m.nbrdf.json", "--env", "builtin:sky"],
            "cannot read neural BRDF /nonexistent/m.nbrdf.json",
        ),
        (
            &["--brdf", "nbrdf:", "--env", "builtin:sky"],
            "missing neural BRDF file path",
        ),
    ];
    for (args, needle) in cases {
        let out = datagen()
            .arg("render")
            .args(*args)
            .arg("--out")
            .arg(&exr)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?} succeeded");
        assert!(err.contains(needle), "{args:?}: {err}");
        assert_eq!(std::fs::read(&exr).unwrap(), b"previous", "{args:?} touched the output");
    }
    // An EXR under a PNG's name is refused before anything is rendered or written.
    let png = d.join("keep.png");
    std::fs::write(&png, b"previous").unwrap();
    let out = datagen()
        .args([
            "render",
            "--brdf",
            "lambert:0.5,0.5,0.5",
            "--env",
            "builtin:sky",
            "--res",
            "8",
            "--out",
        ])
        .arg(&png)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("written as EXR") && err.contains("--png"),
        "{err}"
    );
    assert_eq!(std::fs::read(&png).unwrap(), b"previous");
}

#[test]
fn a_dsbrdf_material_file_renders_and_nan_in_an_hdr_is_refused_by_name() {
    let tmp = scratch("files");
    let d = tmp.path();
    let mat = d.join("m.json");
    let m = matedit_physics::brdf::Dsbrdf::near_lambertian([0.5, 0.4, 0.3]);
    std::fs::write(&mat, m.to_json()).unwrap();
    let out = datagen()
        .args(["render", "--brdf"])
        .arg(format!("dsbrdf:{}", mat.display()))
        .args(["--env", "builtin:constant:1", "--res", "16", "--out"])
        .arg(d.join("m.exr"))
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let (_, _, ch) = matedit_contract::io::read_exr_channels(&d.join("m.exr")).unwrap();
    let centre = 8 * 16 + 8;
    assert!((ch["R"][centre] - 0.5).abs() < 0.01, "{}", ch["R"][centre]);

    // An EXR environment with a NaN texel.
    let env = d.join("nan.exr");
    let mut r = vec![1.0_f32; 8];
    r[3] = f32::NAN;
    // The writer refuses non-finite data, so build the file through the exr crate directly.
    use exr::prelude::*;
    let ch = |v: Vec<f32>| AnyChannel::new("R", FlatSamples::F32(v));
    let layer = Layer::new(
        (4, 2),
        LayerAttributes::default(),
        Encoding::UNCOMPRESSED,
        AnyChannels::sort(SmallVec::from_vec(vec![
            ch(r.clone()),
            AnyChannel::new("G", FlatSamples::F32(r.clone())),
            AnyChannel::new("B", FlatSamples::F32(r)),
        ])),
    );
    Image::from_layer(layer).write().to_file(&env).unwrap();
    let out = datagen()
        .args(["render", "--brdf", "lambert:0.5,0.5,0.5", "--env"])
        .arg(&env)
        .arg("--out")
        .arg(d.join("n.exr"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(err.contains("nan.exr") && err.contains("not finite"), "{err}");
}

#[test]
fn assets_envmaps_writes_deterministic_exrs_and_a_contact_sheet() {
    let (ta, tb) = (scratch("env-a"), scratch("env-b"));
    let (a, b) = (ta.path(), tb.path());
    for d in [&a, &b] {
        let out = datagen()
            .args([
                "assets", "envmaps", "--count", "2", "--seed", "5", "--height", "32", "--out",
            ])
            .arg(d)
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    }
    for name in [
        "sunsky_5.exr",
        "sunsky_6.exr",
        "overcast_5.exr",
        "softbox_6.exr",
        "window_5.exr",
    ] {
        let (w, h, ch) = matedit_contract::io::read_exr_channels(&a.join(name)).unwrap();
        assert_eq!((w, h), (64, 32));
        assert!(ch["R"].iter().all(|v| v.is_finite() && *v >= 0.0));
        assert_eq!(
            std::fs::read(a.join(name)).unwrap(),
            std::fs::read(b.join(name)).unwrap(),
            "{name}"
        );
    }
    let sheet = image::open(a.join("envmaps.png")).unwrap();
    assert_eq!((sheet.width(), sheet.height()), (256, 256));
    // The maps load back as environments.
    let spec = a.join("window_6.exr");
    let out = datagen()
        .args(["render", "--brdf", "lambert:0.5,0.5,0.5", "--res", "8", "--env"])
        .arg(&spec)
        .arg("--out")
        .arg(a.join("r.exr"))
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
}

#[test]
fn assets_shapes_writes_region_tagged_objs_that_render() {
    let tmp = scratch("shapes");
    let d = tmp.path();
    let out = datagen()
        .args(["assets", "shapes", "--count", "2", "--seed", "9", "--out"])
        .arg(d)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    for c in ["car", "chair", "sofa", "monitor"] {
        for s in [9, 10] {
            let obj = d.join(format!("{c}_{s}.obj"));
            let m = matedit_datagen::shapes::Mesh::from_obj(&obj).unwrap();
            let want = if c == "car" { 5 } else { 2 };
            assert_eq!(m.regions.len(), want, "{}", obj.display());
            assert!(d.join(format!("{c}_{s}.mtl")).exists());
        }
    }
    let sheet = image::open(d.join("shapes.png")).unwrap();
    assert_eq!((sheet.width(), sheet.height()), (2 * 192, 4 * 192));
    // The same shape straight from its seed, posed, renders with both regions visible.
    let out = datagen()
        .args([
            "render",
            "--shape",
            "procedural:sofa:10",
            "--yaw",
            "25",
            "--pitch",
            "15",
            "--brdf",
            "lambert:0.5,0.5,0.5",
        ])
        .args(["--env", "builtin:softbox:1", "--res", "48", "--out"])
        .arg(d.join("sofa.exr"))
        .output()
        .unwrap();
    let log = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{log}");
    assert!(log.contains("regions: 0=frame, 1=cushions"), "{log}");
    let (_, _, ch) = matedit_contract::io::read_exr_channels(&d.join("sofa.exr")).unwrap();
    let seen: std::collections::BTreeSet<u32> = ch["region"]
        .iter()
        .zip(&ch["mask"])
        .filter(|(_, m)| **m > 0.0)
        .map(|(r, _)| *r as u32)
        .collect();
    assert_eq!(seen.into_iter().collect::<Vec<_>>(), [0, 1]);
    let bad = datagen()
        .args([
            "render",
            "--shape",
            "procedural:boat:1",
            "--brdf",
            "lambert:0.5,0.5,0.5",
            "--env",
            "builtin:sky",
            "--out",
        ])
        .arg(d.join("x.exr"))
        .output()
        .unwrap();
    assert!(String::from_utf8_lossy(&bad.stderr).contains("unknown category"));
}

#[test]
fn fit_writes_a_renderable_material_and_a_report() {
    let tmp = scratch("fit");
    let d = tmp.path();
    let out = datagen()
        .args(["fit", "--brdf", "plastic:0.3:0.6,0.2,0.1", "--out"])
        .arg(d.join("m.json"))
        .output()
        .unwrap();
    let log = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{log}");
    assert!(log.contains("rendered relative RMSE"), "{log}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("m.fit.json")).unwrap()).unwrap();
    for env in ["sunsky:1", "softbox:2", "window:3"] {
        let e = report["rendered_rel_rmse"][env].as_f64().unwrap();
        assert!(e < 0.12, "{env}: {e}");
    }
    let m = matedit_physics::brdf::Dsbrdf::load(&d.join("m.json")).unwrap();
    assert!(m.params().iter().all(|v| v.is_finite()));
}

#[test]
fn every_quality_renders_and_the_table_qualities_stay_close_to_fast() {
    let tmp = scratch("qualities");
    let d = tmp.path();
    let render = |quality: &str| {
        let exr = d.join(format!("{quality}.exr"));
        let out = datagen()
            .args([
                "render",
                "--shape",
                "procedural:car:3",
                "--brdf",
                "plastic:0.2:0.6,0.3,0.2",
            ])
            .args([
                "--env",
                "builtin:softbox:2",
                "--res",
                "48",
                "--quality",
                quality,
                "--out",
            ])
            .arg(&exr)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{quality}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let (_, _, ch) = matedit_contract::io::read_exr_channels(&exr).unwrap();
        ["R", "G", "B"]
            .iter()
            .flat_map(|c| ch[*c].clone())
            .collect::<Vec<f32>>()
    };
    let fast = render("fast");
    let norm = fast.iter().map(|v| f64::from(*v).powi(2)).sum::<f64>().sqrt();
    assert!(norm > 0.0);
    for quality in ["zonal", "exact"] {
        let img = render(quality);
        assert!(img.iter().all(|v| v.is_finite()), "{quality}");
        let err = img
            .iter()
            .zip(&fast)
            .map(|(a, b)| f64::from(a - b).powi(2))
            .sum::<f64>()
            .sqrt()
            / norm;
        assert!(err < 0.01, "{quality}: relative RMSE {err} against fast");
        // zonal is its own code path, not the fast shader under another name.
        if quality == "zonal" {
            assert!(err > 0.0, "{quality} gave fast's exact bits");
        }
    }
}
