//! Split integrity by content: the same geometry, material or environment under other names must
//! never sit on both sides of a split, whatever the manifest's sources call it.

use matedit_contract::io::write_env_exr;
use matedit_contract::lock::Worker;
use matedit_contract::verify::verify;
use matedit_datagen::dataset::content::{NEAR_DUPLICATE_L1, descriptor_distance, mesh_descriptor};
use matedit_datagen::dataset::run::{RunOptions, describe, load, run};
use matedit_datagen::dataset::verify::verify_sources;
use matedit_datagen::shapes::Mesh;
use matedit_datagen::shapes::procedural::Category;
use matedit_physics::brdf::Dsbrdf;
use matedit_physics::envmap::EnvMap;
use serde_json::Value;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::Command;

fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("matedit-content-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// An OBJ file of `mesh` after `map` (a transform of each position), with its vertices in the
/// order `vorder` and its faces in the order `forder`, each face starting at corner `rot`.
fn obj_text(
    mesh: &Mesh,
    map: impl Fn(glam::Vec3) -> glam::Vec3,
    vorder: &[usize],
    forder: &[usize],
    rot: usize,
) -> String {
    let mut new_index = vec![0; vorder.len()];
    let mut s = String::new();
    for (n, &v) in vorder.iter().enumerate() {
        new_index[v] = n + 1;
        let p = map(mesh.positions[v]);
        s += &format!("v {:.6} {:.6} {:.6}\n", p.x, p.y, p.z);
    }
    for &f in forder {
        let t = mesh.triangles[f];
        let c = |k: usize| new_index[t[(k + rot) % 3] as usize];
        s += &format!("f {} {} {}\n", c(0), c(1), c(2));
    }
    s
}

fn identity(n: usize) -> Vec<usize> {
    (0..n).collect()
}

/// A fixed pseudo-random permutation (the test must not depend on a random crate).
fn permutation(n: usize, salt: u64) -> Vec<usize> {
    let mut v = identity(n);
    let mut st = salt.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
    for i in (1..n).rev() {
        st ^= st << 13;
        st ^= st >> 7;
        st ^= st << 17;
        v.swap(i, (st % (i as u64 + 1)) as usize);
    }
    v
}

fn jitter(amp: f32, salt: u64) -> impl Fn(glam::Vec3) -> glam::Vec3 {
    move |p: glam::Vec3| {
        let mut st = (p.x.to_bits() as u64) << 32 ^ (p.y.to_bits() as u64) ^ ((p.z.to_bits() as u64) << 16) ^ salt;
        let mut r = || {
            st = st
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            ((st >> 33) as f32 / (1u64 << 31) as f32) * 2.0 - 1.0
        };
        p + glam::Vec3::new(r(), r(), r()) * amp
    }
}

/// The duplicates of procedural car 0 under other names, and 5 different cars.
const DUPLICATES: [&str; 6] = [
    "folder:base",
    "folder:copy",
    "folder:commented",
    "folder:sub/vertices-permuted",
    "folder:faces-permuted",
    "folder:moved-and-scaled",
];

fn shape_folder(dir: &Path, with_jittered: bool) -> PathBuf {
    let f = dir.join("cars");
    std::fs::create_dir_all(f.join("sub")).unwrap();
    let car = Category::Car.generate(0);
    let (nv, nf) = (car.positions.len(), car.triangles.len());
    let id = |p| p;
    let base = obj_text(&car, id, &identity(nv), &identity(nf), 0);
    std::fs::write(f.join("base.obj"), &base).unwrap();
    std::fs::write(f.join("copy.obj"), &base).unwrap();
    std::fs::write(
        f.join("commented.obj"),
        format!("# exported again, other tool\n{base}# end\n"),
    )
    .unwrap();
    std::fs::write(
        f.join("sub/vertices-permuted.obj"),
        obj_text(&car, id, &permutation(nv, 1), &identity(nf), 0),
    )
    .unwrap();
    std::fs::write(
        f.join("faces-permuted.obj"),
        obj_text(&car, id, &identity(nv), &permutation(nf, 2), 1),
    )
    .unwrap();
    std::fs::write(
        f.join("moved-and-scaled.obj"),
        obj_text(
            &car,
            |p| p * 2.5 + glam::Vec3::new(10.0, -3.0, 7.0),
            &identity(nv),
            &identity(nf),
            2,
        ),
    )
    .unwrap();
    if with_jittered {
        std::fs::write(
            f.join("jittered.obj"),
            obj_text(&car, jitter(1e-3, 5), &identity(nv), &identity(nf), 0),
        )
        .unwrap();
    }
    for seed in 1..=5 {
        let m = Category::Car.generate(seed);
        let text = obj_text(&m, |p| p, &identity(m.positions.len()), &identity(m.triangles.len()), 0);
        std::fs::write(f.join(format!("other{seed}.obj")), text).unwrap();
    }
    f
}

fn material_folder(dir: &Path) -> PathBuf {
    let f = dir.join("materials");
    std::fs::create_dir_all(&f).unwrap();
    let json = Dsbrdf::near_lambertian([0.5, 0.3, 0.2]).to_json();
    std::fs::write(f.join("clay.dsbrdf.json"), &json).unwrap();
    std::fs::write(f.join("clay-copy.dsbrdf.json"), &json).unwrap();
    // The same numbers, formatted otherwise.
    let v: Value = serde_json::from_str(&json).unwrap();
    std::fs::write(f.join("terracotta.dsbrdf.json"), serde_json::to_string(&v).unwrap()).unwrap();
    for (k, albedo) in [[0.8, 0.8, 0.8], [0.1, 0.2, 0.6], [0.3, 0.6, 0.3], [0.7, 0.1, 0.1]]
        .into_iter()
        .enumerate()
    {
        std::fs::write(
            f.join(format!("other{k}.dsbrdf.json")),
            Dsbrdf::near_lambertian(albedo).to_json(),
        )
        .unwrap();
    }
    f
}

const MATERIAL_DUPLICATES: [&str; 3] = ["dsbrdf:clay", "dsbrdf:clay-copy", "dsbrdf:terracotta"];

/// A tiny manifest over the two folders; `splits` is appended.
fn manifest(seed: u64, splits: &str) -> String {
    format!(
        r#"
[dataset]
name = "content"
seed = {seed}
output = "unused"
shard_size = 8

[render]
resolution = 16
env_resolution = "8x16"
quality = "fast"

[views]
azimuths = 4
per_combination = 1

[target]
policy = "same"

[[shapes]]
source = "folder"
category = "car"
path = "cars"

[[materials]]
source = "dsbrdf"
path = "materials"

[[environments]]
source = "procedural"
family = "overcast"
count = 1
{splits}
"#
    )
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

/// Which splits hold any of `ids`, by split name.
fn splits_holding(l: &matedit_datagen::dataset::run::Loaded, ids: &[&str], shapes: bool) -> BTreeSet<String> {
    let cat = &l.plan.catalogue;
    l.plan
        .splits
        .iter()
        .filter(|s| {
            if shapes {
                s.shapes.iter().any(|&k| ids.contains(&cat.shapes[k].id.as_str()))
            } else {
                s.materials.iter().any(|&k| ids.contains(&cat.materials[k].id.as_str()))
            }
        })
        .map(|s| s.name.clone())
        .collect()
}

const COUNTED: &str = r#"
[[splits]]
name = "train"
shapes = { car = 3 }
materials = 3

[[splits]]
name = "test"
shapes = { car = 2 }
materials = 2
"#;

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

fn run_to(manifest: &Path, out: &Path) {
    let l = load(manifest).unwrap();
    run(
        &l,
        &RunOptions {
            out: Some(out.to_path_buf()),
            worker: Worker::ALL,
            progress: false,
        },
    )
    .unwrap();
}

fn datagen() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    let bin = exe.parent().unwrap().parent().unwrap().join("datagen");
    assert!(
        bin.is_file(),
        "{} not built: run `cargo test --workspace --release`",
        bin.display()
    );
    bin
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

/// The manifest's environment source, and the one that reads `env_folder`'s maps instead.
const PROCEDURAL_ENV: &str = "source = \"procedural\"\nfamily = \"overcast\"\ncount = 1";
const FOLDER_ENV: &str = "source = \"folder\"\npath = \"envs\"";

/// `d/envs`: five maps, `a` and `a-copy` identical.
fn env_folder(d: &Path) {
    let envs = d.join("envs");
    std::fs::create_dir_all(&envs).unwrap();
    for (name, v) in [("a", 1.0), ("a-copy", 1.0), ("b", 2.0), ("c", 3.0), ("e", 4.0)] {
        let map = EnvMap::from_fn(8, |dir| [v, v * (0.5 + 0.5 * dir.y as f32), 0.3]);
        write_env_exr(&envs.join(format!("{name}.exr")), &map).unwrap();
    }
}

#[test]
fn identical_environment_maps_are_dealt_together_when_splits_deal_environments() {
    let d = scratch("envs");
    shape_folder(&d, false);
    material_folder(&d);
    env_folder(&d);
    let dups = ["file:a.exr", "file:a-copy.exr"];
    for seed in 0..8 {
        let text = manifest(seed, COUNTED)
            .replace(PROCEDURAL_ENV, FOLDER_ENV)
            .replace("materials = 3\n", "materials = 3\nenvironments = 2\n")
            .replace("materials = 2\n", "materials = 2\nenvironments = 2\n");
        let p = write(&d, "e.toml", &text);
        let l = load(&p).unwrap();
        let cat = &l.plan.catalogue;
        let holders: BTreeSet<&str> = l
            .plan
            .splits
            .iter()
            .filter(|s| s.envs.iter().any(|&k| dups.contains(&cat.envs[k].id.as_str())))
            .map(|s| s.name.as_str())
            .collect();
        assert!(holders.len() <= 1, "seed {seed}: {holders:?}");
        assert!(
            cat.merges
                .iter()
                .any(|m| m.kind == "environment" && m.reason == "identical pixels"),
            "{:?}",
            cat.merges
        );
    }
}

/// `environment_ids` puts named maps in a split (with their count dealt on top of them from what
/// is left); a map named by two splits, directly or as an identical copy, or a map no source
/// provides, is refused naming the field.
#[test]
fn environment_ids_place_maps_and_keep_the_split_by_content() {
    let d = scratch("env-ids");
    shape_folder(&d, false);
    material_folder(&d);
    env_folder(&d);
    let with = |train: &str, test: &str| {
        manifest(1, COUNTED)
            .replace(PROCEDURAL_ENV, FOLDER_ENV)
            .replacen("materials = 3\n", &format!("materials = 3\n{train}\n"), 1)
            .replacen("materials = 2\n", &format!("materials = 2\n{test}\n"), 1)
    };
    let names = |l: &matedit_datagen::dataset::run::Loaded, split: usize| -> Vec<String> {
        let cat = &l.plan.catalogue;
        l.plan.splits[split]
            .envs
            .iter()
            .map(|&k| cat.envs[k].id.clone())
            .collect()
    };
    // Listed only: each split gets exactly its maps.
    let p = write(
        &d,
        "ids.toml",
        &with(
            "environment_ids = [\"file:b.exr\", \"file:c.exr\"]",
            "environment_ids = [\"file:e.exr\"]",
        ),
    );
    let l = load(&p).unwrap();
    assert_eq!(names(&l, 0), ["file:b.exr", "file:c.exr"]);
    assert_eq!(names(&l, 1), ["file:e.exr"]);
    // Listed and counted: the count comes from the maps nobody listed (a and its copy are one).
    let p = write(
        &d,
        "ids-count.toml",
        &with(
            "environment_ids = [\"file:b.exr\"]\nenvironments = 1",
            "environment_ids = [\"file:e.exr\"]\nenvironments = 1",
        ),
    );
    let l = load(&p).unwrap();
    let (train, test) = (names(&l, 0), names(&l, 1));
    assert_eq!((train.len(), test.len()), (2, 2), "{train:?} {test:?}");
    assert!(train.contains(&"file:b.exr".to_string()) && test.contains(&"file:e.exr".to_string()));
    assert!(train.iter().all(|t| !test.contains(t)), "{train:?} {test:?}");
    for (train, test, needle) in [
        (
            "environment_ids = [\"file:a.exr\"]",
            "environment_ids = [\"file:a-copy.exr\"]",
            "one map by content",
        ),
        (
            "environment_ids = [\"file:b.exr\", \"file:b.exr\"]",
            "environments = 1",
            "listed twice",
        ),
        (
            "environment_ids = [\"file:zz.exr\"]",
            "environments = 1",
            "not provided by any",
        ),
        ("environment_ids = [\"file:b.exr\"]", "", "every split must"),
    ] {
        let p = write(&d, "bad.toml", &with(train, test));
        let e = load(&p).err().map(|e| format!("{e:#}")).unwrap_or_default();
        assert!(e.contains(needle) && e.contains("environment"), "{train} / {test}: {e}");
    }
}

/// The quickstart's deal as it was before fingerprints existed (plan.json of commit c9635a4):
/// without duplicates the content groups must not change a single choice.
#[test]
fn the_quickstart_deal_is_unchanged_by_content_groups() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let l = load(&root.join("manifests/datasets/quickstart.toml")).unwrap();
    assert!(l.plan.catalogue.merges.is_empty(), "{:?}", l.plan.catalogue.merges);
    let cat = &l.plan.catalogue;
    let got: BTreeMap<&str, (Vec<&str>, Vec<&str>)> = l
        .plan
        .splits
        .iter()
        .map(|s| {
            (
                s.name.as_str(),
                (
                    s.shapes.iter().map(|&k| cat.shapes[k].id.as_str()).collect(),
                    s.materials.iter().map(|&k| cat.materials[k].id.as_str()).collect(),
                ),
            )
        })
        .collect();
    let expected: BTreeMap<&str, (Vec<&str>, Vec<&str>)> = QUICKSTART_DEAL
        .iter()
        .map(|(n, s, m)| (*n, (s.to_vec(), m.to_vec())))
        .collect();
    assert_eq!(got, expected);
}

type Deal = (&'static str, &'static [&'static str], &'static [&'static str]);
const QUICKSTART_DEAL: [Deal; 2] = [
    (
        "train",
        &[
            "procedural:car:0",
            "procedural:car:1",
            "procedural:car:3",
            "procedural:car:4",
            "procedural:chair:1",
            "procedural:chair:2",
            "procedural:chair:3",
            "procedural:monitor:0",
            "procedural:monitor:2",
            "procedural:sofa:0",
            "procedural:sofa:1",
        ],
        &[
            "library:carpaint-blue-gloss",
            "library:carpaint-blue-satin",
            "library:carpaint-green-gloss",
            "library:carpaint-green-satin",
            "library:carpaint-yellow-gloss",
            "library:carpaint-yellow-satin",
            "library:fabric-canvas",
            "library:fabric-felt-green",
            "library:fabric-velvet-red",
            "library:plastic-purple-matte",
            "library:plastic-purple-smooth",
            "library:plastic-teal-matte",
            "library:plastic-teal-smooth",
            "library:plastic-yellow-matte",
            "library:plastic-yellow-smooth",
            "library:rubber-black",
        ],
    ),
    (
        "test",
        &[
            "procedural:car:2",
            "procedural:chair:0",
            "procedural:monitor:1",
            "procedural:sofa:2",
        ],
        &[
            "library:carpaint-red-gloss",
            "library:carpaint-red-satin",
            "library:fabric-mustard",
            "library:wood-oak-raw",
            "library:wood-oak-varnished",
            "library:wood-pine-raw",
        ],
    ),
];

/// A valid `*.nbrdf.json` whose output layer's biases give the material its colour (the
/// network's other weights are small and shared).
fn nbrdf_text(rgb_bias: [f64; 3]) -> String {
    matedit_physics::brdf::NeuralBrdf::json_of(
        "t",
        |l, r, c| 0.05 * (((l * 31 + r * 7 + c) % 11) as f64 - 5.0) / 5.0,
        |l, c| if l == 2 { rgb_bias[c] } else { 0.1 },
    )
}

/// `source = "nbrdf"`: a folder of MERL neural BRDFs becomes materials `nbrdf:NAME`, MERL's
/// numbered variants (red, red2) one group that no split divides, and a dataset with measured
/// ground truth renders them and verifies.
#[test]
fn a_folder_of_neural_brdfs_is_a_material_source_whose_variants_stay_together() {
    let d = scratch("nbrdf");
    shape_folder(&d, false);
    let m = d.join("merl");
    std::fs::create_dir_all(&m).unwrap();
    for (name, rgb) in [
        ("red", [-0.5, -2.0, -2.0]),
        ("red2", [-0.4, -2.0, -2.0]),
        ("blue", [-2.0, -2.0, -0.5]),
        ("green", [-2.0, -0.5, -2.0]),
        ("grey", [-1.0, -1.0, -1.0]),
    ] {
        std::fs::write(m.join(format!("{name}.nbrdf.json")), nbrdf_text(rgb)).unwrap();
    }
    std::fs::write(m.join("notes.txt"), "not a material").unwrap();
    let text = manifest(7, "\n[[splits]]\nname = \"train\"\nshapes = { car = 3 }\nmaterials = 2\n\n[[splits]]\nname = \"test\"\nshapes = { car = 2 }\nmaterials = 2\n")
        .replace("source = \"dsbrdf\"\npath = \"materials\"", "source = \"nbrdf\"\npath = \"merl\"")
        .replace("quality = \"fast\"", "quality = \"exact\"\nground_truth = \"measured\"");
    for seed in 0..6 {
        let p = write(&d, "m.toml", &text.replace("seed = 7", &format!("seed = {seed}")));
        let l = load(&p).unwrap();
        let cat = &l.plan.catalogue;
        let ids: BTreeSet<&str> = cat.materials.iter().map(|m| m.id.as_str()).collect();
        assert_eq!(
            ids,
            ["nbrdf:blue", "nbrdf:green", "nbrdf:grey", "nbrdf:red", "nbrdf:red2"]
                .into_iter()
                .collect()
        );
        let group = |id: &str| cat.materials.iter().find(|m| m.id == id).unwrap().group.clone();
        assert_eq!(group("nbrdf:red"), "merl:red");
        assert_eq!(group("nbrdf:red2"), "merl:red");
        let holding = splits_holding(&l, &["nbrdf:red", "nbrdf:red2"], false);
        assert!(holding.len() <= 1, "seed {seed}: red and red2 in {holding:?}");
    }
    let out = d.join("out");
    run_to(&write(&d, "m.toml", &text), &out);
    let rep = verify(&out).unwrap();
    assert!(rep.problems.is_empty(), "{:?}", rep.problems);
    let o = Command::new(datagen()).arg("verify").arg(&out).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stdout));
}
