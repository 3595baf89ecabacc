//! Manifests: refusals that name file, line and field, `extends` and `--set` on the command
//! line, and the split roles (a validation split dealt apart from training and test).

use super::*;

#[test]
fn manifests_that_try_to_leak_or_ask_too_much_are_refused_with_field_and_line() {
    let d = scratch("bad");
    let cases: Vec<(&str, String, &str)> = vec![
        (
            "explicit shape in two splits",
            manifest(
                "shape_ids = [\"procedural:car:0\"]\n[[splits]]\nname = \"test\"\nshape_ids = [\"procedural:car:0\"]\nmaterials = 2",
                "",
            ),
            "splits[1].shape_ids",
        ),
        (
            "near-duplicate materials across roles",
            manifest(
                "material_ids = [\"library:plastic-red-smooth\"]\n[[splits]]\nname = \"test\"\nshapes = { car = 1 }\nmaterial_ids = [\"library:plastic-red-matte\", \"library:rubber-red\"]",
                "",
            ),
            "near-duplicate group",
        ),
        (
            "test split borrowing training materials",
            manifest(
                "[[splits]]\nname = \"test\"\nshapes = { car = 1 }\nmaterials_from = \"train\"",
                "",
            ),
            "may not share materials",
        ),
        (
            "validation split borrowing training materials",
            manifest(
                "[[splits]]\nname = \"val\"\nshapes = { car = 1 }\nmaterials_from = \"train\"",
                "",
            ),
            "splits[1].materials_from: split \"train\" has role train and this one val",
        ),
        (
            "an unknown role",
            manifest(
                "[[splits]]\nname = \"held\"\nrole = \"holdout\"\nshapes = { car = 1 }\nmaterials = 2",
                "",
            ),
            "splits[1].role: \"holdout\": expected train, val or test",
        ),
        (
            "too many shapes",
            manifest("[[splits]]\nname = \"test\"\nshapes = { car = 3 }\nmaterials = 2", ""),
            "splits[1].shapes.car",
        ),
        ("unknown field", manifest(TEST_SPLIT, "colour = \"red\""), "colour"),
        ("wrong type", manifest(TEST_SPLIT, "resolution = \"big\""), "resolution"),
        (
            "bad choice",
            manifest(TEST_SPLIT, "quality = \"best\""),
            "render.quality",
        ),
        (
            "missing folder",
            manifest(TEST_SPLIT, "").replace(
                "source = \"procedural\"\ncategory = \"car\"\ncount = 3",
                "source = \"folder\"\ncategory = \"car\"\npath = \"/nonexistent/cars\"",
            ),
            "shapes[0].path",
        ),
        (
            "a substitute of another kind",
            manifest(TEST_SPLIT, "").replace(
                "source = \"procedural\"\ncategory = \"car\"\ncount = 3",
                "source = \"folder\"\ncategory = \"car\"\npath = \"/nonexistent/cars\"\nif_missing = \"library\"",
            ),
            "shapes[0].if_missing: \"library\": expected \"error\" or \"procedural\"",
        ),
        (
            "an unknown if_missing",
            manifest(TEST_SPLIT, "").replace(
                "source = \"procedural\"\ncategory = \"car\"\ncount = 3",
                "source = \"folder\"\ncategory = \"car\"\npath = \"/nonexistent/cars\"\nif_missing = \"maybe\"",
            ),
            "shapes[0].if_missing: \"maybe\": expected error, procedural, library",
        ),
        (
            "an unknown up axis",
            manifest(TEST_SPLIT, "").replace(
                "source = \"procedural\"\ncategory = \"car\"\ncount = 3",
                "source = \"folder\"\ncategory = \"car\"\npath = \"/nonexistent/cars\"\nup = \"w\"",
            ),
            "shapes[0].up: \"w\": expected x, +x, -x, y, +y, -y, z, +z, -z",
        ),
    ];
    for (what, text, needle) in cases {
        let p = write(&d, "bad.toml", &text);
        let e = format!("{:#}", load(&p).err().unwrap_or_else(|| panic!("{what}: accepted")));
        assert!(e.contains("bad.toml") && e.contains(needle), "{what}: {e}");
        assert!(
            e.contains(':') && e.chars().any(|c| c.is_ascii_digit()),
            "{what}: no line in {e}"
        );
    }
    // The line is the field's own line where the field has one.
    let p = write(
        &d,
        "bad.toml",
        &manifest("[[splits]]\nname = \"test\"\nshapes = { car = 3 }\nmaterials = 2", ""),
    );
    let text = std::fs::read_to_string(&p).unwrap();
    let line = text.lines().position(|l| l.contains("car = 3")).unwrap() + 1;
    let e = load(&p).err().unwrap().to_string();
    assert!(e.contains(&format!("bad.toml:{line}:")), "{e}");
}

#[test]
fn the_command_line_refuses_a_second_run_and_names_bad_manifest_lines() {
    let d = scratch("cli");
    let text = manifest(TEST_SPLIT, "quality = \"fast\"").replace("resolution = 32", "resolution = 64");
    let m = write(&d, "m.toml", &text);
    let out = d.join("out");
    let mut first = Command::new(datagen())
        .arg("run")
        .arg(&m)
        .arg("--out")
        .arg(&out)
        .spawn()
        .unwrap();
    // Wait until the first run holds its lock (it writes plan.json right after taking it).
    let t0 = std::time::Instant::now();
    while !out.join("plan.json").exists() && t0.elapsed().as_secs() < 30 {
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let second = Command::new(datagen())
        .arg("run")
        .arg(&m)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let still_running = first.try_wait().unwrap().is_none();
    first.kill().ok();
    first.wait().unwrap();
    // The first run takes seconds; had it already finished, the check below would prove nothing.
    assert!(still_running, "the first run ended before the second started");
    assert!(!second.status.success());
    let err = String::from_utf8_lossy(&second.stderr);
    assert!(err.contains("another datagen run"), "{err}");

    let bad = write(&d, "bad.toml", &manifest(TEST_SPLIT, "shadows = \"sometimes\""));
    let o = Command::new(datagen()).arg("plan").arg(&bad).output().unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    let line = std::fs::read_to_string(&bad)
        .unwrap()
        .lines()
        .position(|l| l.contains("sometimes"))
        .unwrap()
        + 1;
    assert!(err.contains(&format!("bad.toml:{line}: render.shadows")), "{err}");

    // `extends` and `--set`: a value's error names the option that gave it; the plan is the
    // resolved manifest's.
    let exp = write(&d, "exp.toml", "extends = \"m.toml\"\n[render]\nresolution = 32\n");
    let o = Command::new(datagen())
        .args(["plan"])
        .arg(&exp)
        .args(["--set", "render.shadows=sometimes"])
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("--set render.shadows=sometimes: render.shadows: \"sometimes\""),
        "{err}"
    );
    let o = Command::new(datagen())
        .args(["plan"])
        .arg(&exp)
        .args(["--set", "splits[test].materials=3"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let plan = String::from_utf8_lossy(&o.stdout);
    assert!(plan.contains("32×32 images"), "extends: {plan}");
    let test_line = plan.lines().find(|l| l.starts_with("split test")).unwrap();
    assert!(test_line.contains("materials: 3;"), "--set: {test_line}");
    let o = Command::new(datagen())
        .args(["plan"])
        .arg(&exp)
        .args(["--set", "splits[nope].materials=1"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("no entry of splits is named \"nope\" (train, test)"),
        "{err}"
    );
}

/// A `val` split (validation while training) is dealt as a test split is: shapes and materials
/// of its own, recorded with its role, and checked by `datagen verify` like any other.
#[test]
fn a_validation_split_is_dealt_apart_from_training_and_test() {
    let d = scratch("val");
    let text = manifest(
        &format!("{TEST_SPLIT}\n[[splits]]\nname = \"val\"\nshapes = {{ car = 1, chair = 1 }}\nmaterials = 2\n"),
        "quality = \"fast\"",
    )
    .replace("per_combination = 2", "per_combination = 1");
    let m = write(&d, "m.toml", &text);
    let out = d.join("out");
    run_to(&m, &out);
    let ds: Value = serde_json::from_str(&std::fs::read_to_string(out.join("dataset.json")).unwrap()).unwrap();
    let splits = ds["splits"].as_array().unwrap();
    let role = |n: &str| splits.iter().find(|s| s["name"] == n).unwrap()["role"].clone();
    assert_eq!(
        (role("train"), role("test"), role("val")),
        ("train".into(), "test".into(), "val".into())
    );
    let members = |n: &str, k: &str| -> BTreeSet<String> {
        splits.iter().find(|s| s["name"] == n).unwrap()[k]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_str().unwrap().to_string())
            .collect()
    };
    for k in ["shapes", "materials"] {
        let (t, v, x) = (members("train", k), members("val", k), members("test", k));
        assert!(
            !v.is_empty() && t.is_disjoint(&v) && x.is_disjoint(&v),
            "{k}: {t:?} {v:?} {x:?}"
        );
    }
    let rep = verify(&out).unwrap();
    assert!(rep.problems.is_empty(), "{:?}", rep.problems);
    assert!(index(&out).iter().any(|r| r["split"] == "val"));
}
