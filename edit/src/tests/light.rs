//! The photo's light for an edit: a given map at the level asked for, and the object's known
//! material setting L''s level (`--input-material`).

use crate::tests::{dir, model, request, write_photo};
use crate::*;
use matedit_physics::brdf::Dsbrdf;

fn env_of(out: &Path) -> Vec<f32> {
    let (_, _, ch) = matedit_contract::io::read_exr_channels(&out.join("env.exr")).unwrap();
    let n = ch["R"].len();
    (0..3 * n).map(|k| ch[["R", "G", "B"][k / n]][k % n]).collect()
}

fn report(out: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap()
}

#[test]
fn a_given_light_replaces_l_prime_at_the_level_asked_for() {
    let d = dir("light");
    let (p, m, _) = write_photo(&d);
    let studio = target::relight_env("builtin:studio", 4).unwrap();
    // The default level with a given light is the background's; the map written is the given
    // one up to that single factor.
    let with = |level: LevelFrom, light: Option<&str>| EditRequest {
        light: light.map(str::to_string),
        light_level: level,
        ..request(&p, &m, "library:gold-polished")
    };
    for (name, level, source) in [
        ("auto", LevelFrom::Auto, "background"),
        ("network", LevelFrom::Network, "network"),
        ("given", LevelFrom::Given, "given"),
    ] {
        let out = d.join(name);
        let r = edit(model(), &with(level, Some("builtin:studio")), &out).unwrap();
        assert_eq!(r.light_level.source.as_str(), source, "{name}: {:?}", r.light_level);
        // A light at a known level makes `detail` the default; at the network's, `structure`.
        let best = if source == "network" {
            Composite::Structure
        } else {
            Composite::Detail
        };
        assert_eq!(r.composite, best, "{name}");
        assert_eq!(report(&out)["light"], "builtin:studio");
        assert_eq!(report(&out)["light_level"]["source"], source);
        let env = env_of(&out);
        let k = env[0] / studio[0];
        assert!(k.is_finite() && k > 0.0);
        if level == LevelFrom::Given {
            // The map's own level, written in the photo's units as it was given.
            assert!((k - 1.0).abs() <= 1e-5, "{k}");
            assert_eq!(r.light_level.scale, 1.0);
        }
        for (a, b) in env.iter().zip(&studio) {
            assert!(
                (a - k * b).abs() <= 1e-4 * (k * b).abs().max(1e-6),
                "{name}: {a} vs {k} × {b}"
            );
        }
    }
    // Without a light the default keeps the network's level; asked for, the background sets it.
    let out = d.join("net");
    let r = edit(model(), &with(LevelFrom::Auto, None), &out).unwrap();
    assert_eq!((r.light_level.source.as_str(), r.light_level.scale), ("network", 1.0));
    assert!(report(&out)["light"].is_null());
    // `given` names a given light's level: without one, L' keeps the network's.
    let r = edit(model(), &with(LevelFrom::Given, None), &d.join("given-none")).unwrap();
    assert_eq!((r.light_level.source.as_str(), r.light_level.scale), ("network", 1.0));
    let r = edit(model(), &with(LevelFrom::Background, None), &d.join("bg")).unwrap();
    assert_eq!(r.light_level.source.as_str(), "background", "{:?}", r.light_level);
    assert!(r.light_level.pixels >= 500 && r.light_level.scale.is_finite() && r.light_level.scale > 0.0);
    // A light that cannot explain the photo, a light that is not a map: refused, nothing written.
    let black = d.join("black.hdr");
    let mut f = std::fs::File::create(&black).unwrap();
    let pixels = vec![image::Rgb([0.0_f32; 3]); 8 * 4];
    image::codecs::hdr::HdrEncoder::new(&mut f)
        .encode(&pixels, 8, 4)
        .unwrap();
    let out = d.join("refused");
    let e = edit(model(), &with(LevelFrom::Auto, Some(black.to_str().unwrap())), &out).unwrap_err();
    assert!(format!("{e:#}").contains("leaves the object black"), "{e:#}");
    let e = edit(model(), &with(LevelFrom::Auto, Some("builtin:nope")), &out).unwrap_err();
    assert!(format!("{e:#}").contains("nope"), "{e:#}");
    assert!(!out.exists());
}

#[test]
fn a_given_light_whose_background_level_falls_back_is_composited_as_a_guess() {
    // Everything around the object at white: no unclipped background to set the level, so the
    // network's fit sets it, and the composite is that of a guessed level.
    let d = dir("light-fallback");
    let (p, m, _) = write_photo(&d);
    let mut photo = image::open(&p).unwrap().to_rgb8();
    let mask = image::open(&m).unwrap().to_luma8();
    for (x, y, q) in photo.enumerate_pixels_mut() {
        if mask.get_pixel(x, y)[0] == 0 {
            *q = image::Rgb([255; 3]);
        }
    }
    photo.save(&p).unwrap();
    let req = EditRequest {
        light: Some("builtin:studio".into()),
        ..request(&p, &m, "library:gold-polished")
    };
    let r = edit(model(), &req, &d.join("out")).unwrap();
    assert_eq!(r.light_level.source.as_str(), "network", "{:?}", r.light_level);
    assert_eq!(r.composite, Composite::Structure);
}

#[test]
fn an_edits_light_given_back_at_its_own_level_renders_the_same_edit() {
    // env.exr is L' in the photo's linear units: the map `--light-level given` reads. Given
    // back, it is the same light, so the edit and the map written are the same again (held to
    // the same range and composite: a given light's own level is otherwise kept as rendered,
    // and composited by `detail`).
    let d = dir("light-again");
    let (p, m, _) = write_photo(&d);
    let first = d.join("first");
    let a = edit(model(), &request(&p, &m, "library:gold-polished"), &first).unwrap();
    let again = d.join("again");
    let req = EditRequest {
        light: Some(first.join("env.exr").to_str().unwrap().to_string()),
        light_level: LevelFrom::Given,
        range: Some(Range::Photo),
        composite: Some(a.composite),
        ..request(&p, &m, "library:gold-polished")
    };
    let b = edit(model(), &req, &again).unwrap();
    assert_eq!((b.light_level.source.as_str(), b.light_level.scale), ("given", 1.0));
    assert!(
        a.exposure > 1.01 || a.exposure < 0.99,
        "the test needs a photo not at the training exposure"
    );
    let close = |x: &[f32], y: &[f32], what: &str| {
        assert_eq!(x.len(), y.len());
        for (u, v) in x.iter().zip(y) {
            assert!((u - v).abs() <= 1e-5 * u.abs().max(1e-3), "{what}: {u} vs {v}");
        }
    };
    close(&env_of(&first), &env_of(&again), "env.exr");
    close(
        &rgb_exr(&first.join("edited.exr")),
        &rgb_exr(&again.join("edited.exr")),
        "edited.exr",
    );
    // An exposure that cannot convert the light is refused, not written as NaN or infinity.
    let l = env_of(&first);
    assert_eq!(light::light_in_photo_units(&l, 2.0).unwrap()[0], l[0] / 2.0);
    for bad in [0.0, -1.0, f64::NAN, f64::INFINITY, 1e-300] {
        assert!(light::light_in_photo_units(&[1e6, 1.0], bad).is_err(), "{bad}");
    }
    assert!(light::light_in_photo_units(&[f32::NAN], 1.0).is_err());
}

fn rgb_exr(path: &Path) -> Vec<f32> {
    let (_, _, ch) = matedit_contract::io::read_exr_channels(path).unwrap();
    ["R", "G", "B"].iter().flat_map(|c| ch[*c].clone()).collect()
}

#[test]
fn the_objects_known_material_replaces_m_prime_and_sets_the_lights_level() {
    let d = dir("input-material");
    let (p, m, r) = write_photo(&d);
    let with = |spec: &str, light: Option<&str>, level: LevelFrom| EditRequest {
        input_material: Some(spec.to_string()),
        light: light.map(str::to_string),
        light_level: level,
        ..request(&p, &m, "library:gold-polished")
    };
    let env = |spec: &str, light: Option<&str>, level: LevelFrom, name: &str| {
        let out = d.join(name);
        let rep = edit(model(), &with(spec, light, level), &out).unwrap();
        (rep, out.clone(), env_of(&out))
    };
    // The material written is the one given (its DSBRDF fit), not the network's.
    let (rep, out, _) = env("lambert:0.2,0.2,0.2", None, LevelFrom::Auto, "dark");
    assert_eq!(
        rep.light_level.source.as_str(),
        "input material",
        "{:?}",
        rep.light_level
    );
    assert_eq!(report(&out)["input_material"], "lambert:0.2,0.2,0.2");
    let given = target::dsbrdf_of("lambert:0.2,0.2,0.2").unwrap().0;
    let written = Dsbrdf::load(&out.join("material.dsbrdf.json")).unwrap();
    let (a, b) = (given.to_normalised(), written.to_normalised());
    for (x, y) in a.iter().zip(&b) {
        assert!((x - y).abs() <= 1e-5 * x.abs().max(1.0), "{x} vs {y}");
    }
    // L* is at the level where I* = R(n', m_in, L*) fits the photo best in least squares: the
    // fit's own scale is then 1.
    let (i, ip) = (rgb_exr(&out.join("input.exr")), rgb_exr(&out.join("i_prime.exr")));
    let (ri, rr) = i.iter().zip(&ip).fold((0.0_f64, 0.0_f64), |(ri, rr), (&i, &r)| {
        (ri + i as f64 * r as f64, rr + r as f64 * r as f64)
    });
    assert!(
        rr > 0.0 && (ri / rr - 1.0).abs() < 1e-3,
        "least-squares scale {}",
        ri / rr
    );
    // A Lambertian four times as bright explains the same photo under a light a quarter as
    // bright (the layer is linear in albedo and in light), texel by texel; so with a given map at
    // the fitted (network) level. The background's level does not depend on the material (to
    // rounding).
    for (light, level, source, ratio, tol) in [
        (None, LevelFrom::Auto, "input material", 4.0, 2e-3),
        (Some("builtin:studio"), LevelFrom::Network, "input material", 4.0, 2e-3),
        (Some("builtin:studio"), LevelFrom::Auto, "background", 1.0, 1e-6),
    ] {
        let name = format!("{source}-{}", light.is_some());
        let (rep, _, dark) = env("lambert:0.2,0.2,0.2", light, level, &format!("dark-{name}"));
        assert_eq!(rep.light_level.source.as_str(), source);
        let (_, _, bright) = env("lambert:0.8,0.8,0.8", light, level, &format!("bright-{name}"));
        for (a, b) in dark.iter().zip(&bright) {
            assert!(
                (a - ratio * b).abs() <= tol * a.abs().max(1e-6),
                "{name}: {a} vs {ratio} × {b}"
            );
        }
    }
    // Every region gets it, and the edit stays finite.
    let out = d.join("regions");
    let req = EditRequest {
        regions: Some(r.clone()),
        ..with("plastic:0.1:0.6,0.2,0.1", None, LevelFrom::Auto)
    };
    edit(model(), &req, &out).unwrap();
    for k in 1..=2 {
        let w = Dsbrdf::load(&out.join(format!("material-{k}.dsbrdf.json"))).unwrap();
        assert_eq!(
            w.to_normalised(),
            Dsbrdf::load(&out.join("material-1.dsbrdf.json"))
                .unwrap()
                .to_normalised()
        );
    }
    assert!(
        rgb_exr(&out.join("edited.exr"))
            .iter()
            .all(|v| v.is_finite() && *v >= 0.0)
    );
    // A spec that is not a material: refused by name, nothing written.
    let out = d.join("refused");
    let e = edit(model(), &with("lambert:nope", None, LevelFrom::Auto), &out).unwrap_err();
    assert!(format!("{e:#}").contains("--input-material"), "{e:#}");
    assert!(!out.exists());
}

#[test]
fn the_default_keeps_of_l_prime_what_the_checkpoint_reads() {
    use crate::light::estimate::LightEstimate;
    let d = dir("estimate");
    let (p, m, _) = write_photo(&d);
    let with = |estimate| EditRequest {
        light_estimate: estimate,
        ..request(&p, &m, "library:gold-polished")
    };
    let net = edit(model(), &with(LightEstimate::Network), &d.join("network")).unwrap();
    let auto = edit(model(), &with(LightEstimate::Auto), &d.join("auto")).unwrap();
    let skill = Model::load(model()).unwrap().light_skill().unwrap();
    let mut expected = env_of(&d.join("network"));
    let r = skill.apply(&mut expected, 4);
    assert_eq!(auto.light_estimate, Some(r));
    let kept = net.light_estimate.unwrap();
    assert!(!kept.averaged_around_vertical && !kept.made_neutral && kept.skill.is_none());
    for (a, b) in env_of(&d.join("auto")).iter().zip(&expected) {
        assert!((a - b).abs() <= 1e-5 * b.abs().max(1e-6), "{a} vs {b}");
    }
    let written = report(&d.join("auto"))["light_estimate"].clone();
    assert_eq!(written["estimate"], "auto");
    assert_eq!(written["skill"]["azimuth"], skill.azimuth);
    assert_eq!(written["averaged_around_vertical"], r.averaged_around_vertical);
    // Transfer keeps the receiving photo's choice.
    for (e, measured) in [(LightEstimate::Network, false), (LightEstimate::Auto, true)] {
        let to = Given {
            light_estimate: e,
            ..Given::photo(&p, Some(&m))
        };
        let out = d.join(format!("transfer-{e:?}"));
        let r = transfer(
            model(),
            Pair {
                first: Given::photo(&p, Some(&m)),
                second: to,
                eq6: None,
                look: Composite::Detail.into(),
            },
            &out,
        )
        .unwrap();
        assert_eq!(r.light_estimate.and_then(|x| x.skill).is_some(), measured, "{e:?}");
    }
    // A given light is the photo's: nothing of L' is kept, nothing is estimated.
    let given = EditRequest {
        light: Some("builtin:studio".into()),
        ..with(LightEstimate::Auto)
    };
    assert!(
        edit(model(), &given, &d.join("given"))
            .unwrap()
            .light_estimate
            .is_none()
    );
    assert!(report(&d.join("given"))["light_estimate"].is_null());
    // The probe runs only where it is needed: neither for a given light nor for `network`.
    let m = Model::load(model()).unwrap();
    edit_with(&m, &given, &d.join("given-2"), Watch::unwatched()).unwrap();
    edit_with(
        &m,
        &with(LightEstimate::Network),
        &d.join("network-2"),
        Watch::unwatched(),
    )
    .unwrap();
    assert!(m.light_skill.get().is_none());
    edit_with(&m, &with(LightEstimate::Auto), &d.join("auto-2"), Watch::unwatched()).unwrap();
    assert_eq!(m.light_skill.get(), Some(&skill));
}
