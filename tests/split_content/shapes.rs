//! Shapes under other names: renamed, reordered, moved and jittered copies form one group; explicit
//! ids that share content across splits are refused; `datagen verify` catches a record moved across.

use super::*;

#[test]
fn renamed_reordered_and_moved_copies_form_one_group_that_no_seed_splits() {
    let d = scratch("deal");
    shape_folder(&d, false);
    material_folder(&d);
    for seed in 0..12 {
        let m = write(&d, "m.toml", &manifest(seed, COUNTED));
        let l = load(&m).unwrap();
        let cat = &l.plan.catalogue;
        // One group of six shapes and one of three materials, whatever the seed.
        let group_of = |id: &str| cat.shapes.iter().find(|s| s.id == id).unwrap().group.clone();
        for id in DUPLICATES {
            assert_eq!(group_of(id), "folder:base", "{id}");
        }
        for s in cat.shapes.iter().filter(|s| !DUPLICATES.contains(&s.id.as_str())) {
            assert_eq!(s.group, s.id, "{} merged by mistake", s.id);
        }
        let mgroup = |id: &str| cat.materials.iter().find(|m| m.id == id).unwrap().group.clone();
        for id in MATERIAL_DUPLICATES {
            assert_eq!(mgroup(id), "dsbrdf:clay", "{id}");
        }
        assert!(
            splits_holding(&l, &DUPLICATES, true).len() <= 1,
            "seed {seed}: shapes split"
        );
        assert!(
            splits_holding(&l, &MATERIAL_DUPLICATES, false).len() <= 1,
            "seed {seed}: materials split"
        );
        // The report names the merges and why.
        let text = describe(&l);
        assert!(
            text.contains("merged shapes folder:base and folder:copy into one group: identical geometry"),
            "{text}"
        );
        assert!(text.contains("folder:faces-permuted"), "{text}");
        assert!(text.contains("folder:moved-and-scaled"), "{text}");
        assert!(
            text.contains("merged materials dsbrdf:clay and dsbrdf:terracotta into one group: identical parameters"),
            "{text}"
        );
    }
}

#[test]
fn explicit_ids_that_share_content_across_splits_are_refused_naming_both() {
    let d = scratch("explicit");
    shape_folder(&d, false);
    material_folder(&d);
    let cases = [
        (
            r#"
[[splits]]
name = "train"
shape_ids = ["folder:base"]
material_ids = ["dsbrdf:other0"]

[[splits]]
name = "test"
shape_ids = ["folder:sub/vertices-permuted"]
material_ids = ["dsbrdf:other1"]
"#,
            ["folder:sub/vertices-permuted", "folder:base"],
            "splits[1].shape_ids",
            "name = \"test\"",
        ),
        (
            r#"
[[splits]]
name = "train"
shape_ids = ["folder:other1"]
material_ids = ["dsbrdf:clay-copy"]

[[splits]]
name = "test"
shape_ids = ["folder:other2"]
material_ids = ["dsbrdf:terracotta"]
"#,
            ["dsbrdf:terracotta", "dsbrdf:clay-copy"],
            "splits[1].material_ids",
            "name = \"test\"",
        ),
    ];
    for (splits, ids, field, line_of) in cases {
        let text = manifest(3, splits);
        let p = write(&d, "bad.toml", &text);
        let e = format!("{:#}", load(&p).err().expect("a content leak was accepted"));
        let line = text.lines().position(|l| l.contains(line_of)).unwrap();
        // The error is reported at the [[splits]] entry (its header line or its first field).
        assert!(
            e.contains(&format!("bad.toml:{line}:")) || e.contains(&format!("bad.toml:{}:", line + 1)),
            "{e}"
        );
        assert!(e.contains(field), "{e}");
        for id in ids {
            assert!(e.contains(id), "{id} not named in {e}");
        }
    }
}

#[test]
fn verify_passes_merged_duplicates_and_fails_a_record_that_moves_one_across() {
    let d = scratch("verify");
    shape_folder(&d, false);
    material_folder(&d);
    let splits = r#"
[[splits]]
name = "train"
shape_ids = ["folder:base", "folder:copy"]
material_ids = ["dsbrdf:clay", "dsbrdf:terracotta"]

[[splits]]
name = "test"
shape_ids = ["folder:other1"]
material_ids = ["dsbrdf:other0"]
"#;
    let m = write(&d, "m.toml", &manifest(1, splits));
    let out = d.join("out");
    run_to(&m, &out);
    let rep = verify(&out).unwrap();
    assert!(rep.ok(), "{:?}", rep.problems);
    assert!(verify_sources(&out, &m).unwrap().is_empty());
    let ds: Value = serde_json::from_str(&std::fs::read_to_string(out.join("dataset.json")).unwrap()).unwrap();
    let content = &ds["content"];
    assert_eq!(
        content["shapes"]["folder:base"]["fingerprint"],
        content["shapes"]["folder:copy"]["fingerprint"]
    );
    assert!(
        content["shapes"]["folder:base"]["fingerprint"]
            .as_str()
            .unwrap()
            .starts_with("blake3:")
    );
    assert_eq!(content["materials"]["dsbrdf:terracotta"]["group"], "dsbrdf:clay");
    assert_ne!(
        content["shapes"]["folder:base"]["fingerprint"],
        content["shapes"]["folder:other1"]["fingerprint"]
    );

    // Tamper: the record now says the copy is a test shape and the reformatted material a test
    // material. By name nothing leaks; by content both do.
    let pristine = std::fs::read_to_string(out.join("dataset.json")).unwrap();
    let mut t: Value = serde_json::from_str(&pristine).unwrap();
    let splits = t["splits"].as_array_mut().unwrap();
    let take = |s: &mut Value, key: &str, id: &str| {
        let list = s[key].as_array_mut().unwrap();
        list.retain(|x| x != id);
    };
    take(&mut splits[0], "shapes", "folder:copy");
    take(&mut splits[0], "materials", "dsbrdf:terracotta");
    splits[1]["shapes"].as_array_mut().unwrap().push("folder:copy".into());
    splits[1]["materials"]
        .as_array_mut()
        .unwrap()
        .push("dsbrdf:terracotta".into());
    std::fs::write(out.join("dataset.json"), serde_json::to_string_pretty(&t).unwrap()).unwrap();
    let rep = verify(&out).unwrap();
    let leak = |a: &str, sa: &str, b: &str, sb: &str| {
        rep.problems.iter().any(|p| {
            p.starts_with("content leak")
                && p.contains(&format!("{a} (split {sa})"))
                && p.contains(&format!("{b} (split {sb})"))
        })
    };
    assert!(
        leak("folder:base", "train", "folder:copy", "test"),
        "{:?}",
        rep.problems
    );
    assert!(
        leak("dsbrdf:clay", "train", "dsbrdf:terracotta", "test"),
        "{:?}",
        rep.problems
    );
    // The command line fails and names both.
    let o = Command::new(datagen()).arg("verify").arg(&out).output().unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert_eq!(o.status.code(), Some(1), "{stdout}");
    assert!(
        stdout.contains("folder:base (split train)") && stdout.contains("folder:copy (split test)"),
        "{stdout}"
    );

    // A record whose fingerprint was edited to hide the copy passes the record-only check of
    // that pair, but not a check against the sources.
    let mut t: Value = serde_json::from_str(&pristine).unwrap();
    t["content"]["shapes"]["folder:copy"]["fingerprint"] = "blake3:00".into();
    t["content"]["shapes"]["folder:copy"]["group"] = "folder:copy".into();
    std::fs::write(out.join("dataset.json"), serde_json::to_string_pretty(&t).unwrap()).unwrap();
    let problems = verify_sources(&out, &m).unwrap();
    assert!(
        problems
            .iter()
            .any(|p| p.contains("folder:copy") && p.contains("recorded fingerprint blake3:00")),
        "{problems:?}"
    );
    let o = Command::new(datagen())
        .arg("verify")
        .arg(&out)
        .arg("--sources")
        .arg(&m)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1), "{}", String::from_utf8_lossy(&o.stdout));
}

#[test]
fn jittered_copies_merge_as_near_duplicates_but_different_shapes_never_do() {
    let d = scratch("near");
    shape_folder(&d, true);
    material_folder(&d);
    let m = write(&d, "m.toml", &manifest(0, COUNTED));
    let l = load(&m).unwrap();
    let cat = &l.plan.catalogue;
    let jittered = cat.shapes.iter().find(|s| s.id == "folder:jittered").unwrap();
    assert_eq!(jittered.group, "folder:base");
    assert!(
        cat.merges
            .iter()
            .any(|x| x.ids.contains(&"folder:jittered".to_string()) && x.reason.starts_with("near-duplicate geometry")),
        "{:?}",
        cat.merges
    );
    // The five other cars stay apart (their groups are themselves).
    for s in cat.shapes.iter().filter(|s| s.id.starts_with("folder:other")) {
        assert_eq!(s.group, s.id);
    }

    // Procedural shapes of one category with different seeds: 40 per category, no merge, and a
    // margin of twice the threshold.
    let text = r#"
[dataset]
name = "seeds"
seed = 0
output = "unused"

[[shapes]]
source = "procedural"
category = "car"
count = 40

[[shapes]]
source = "procedural"
category = "chair"
count = 40

[[shapes]]
source = "procedural"
category = "sofa"
count = 40

[[shapes]]
source = "procedural"
category = "monitor"
count = 40

[[materials]]
source = "library"
names = ["rubber-red"]

[[environments]]
source = "procedural"
family = "overcast"
count = 1

[target]
policy = "same"

[[splits]]
name = "train"
shapes = { car = 20, chair = 20, sofa = 20, monitor = 20 }
materials = 1
"#;
    let p = write(&d, "seeds.toml", text);
    let l = load(&p).unwrap();
    assert!(l.plan.catalogue.merges.is_empty(), "{:?}", l.plan.catalogue.merges);
    for c in Category::ALL {
        let ds: Vec<Vec<f32>> = (0..40).map(|s| mesh_descriptor(&c.generate(s))).collect();
        let mut closest = f64::MAX;
        for i in 0..ds.len() {
            for j in i + 1..ds.len() {
                closest = closest.min(descriptor_distance(&ds[i], &ds[j]));
            }
        }
        assert!(closest > 2.0 * NEAR_DUPLICATE_L1, "{c:?}: {closest}");
    }
}
