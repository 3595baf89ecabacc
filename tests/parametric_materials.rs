//! `[[materials]] source = "parametric"`: materials drawn per seed from continuous families.
//! A seed is one material in every dataset (its id, its spec and its fitted label); the deal
//! keeps every drawn material on one side of the train/test line; bad entries are refused naming
//! the file, the line and the field.

mod common;
use common::{run_to, scratch};

use matedit_assets::materials::parametric::ParametricFamily;
use matedit_datagen::dataset::catalogue::MaterialSource;
use matedit_datagen::dataset::run::load;
use matedit_physics::BrdfSpec;
use serde_json::Value;
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// A small dataset whose materials are `entry`.
fn manifest(seed: u64, entry: &str) -> String {
    format!(
        r#"
[dataset]
name = "p"
seed = {seed}
output = "unused"
shard_size = 4

[render]
resolution = 24
env_resolution = "16x32"

[views]
azimuths = 8
per_combination = 1

[[shapes]]
source = "procedural"
category = "chair"
count = 2

[[materials]]
{entry}

[[environments]]
source = "procedural"
family = "overcast"
count = 1

[[splits]]
name = "train"
shapes = {{ chair = 1 }}
materials = 5

[[splits]]
name = "test"
shapes = {{ chair = 1 }}
materials = 3
"#
    )
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

fn materials_by_split(out: &Path) -> (BTreeSet<String>, BTreeSet<String>) {
    let (mut train, mut test) = (BTreeSet::new(), BTreeSet::new());
    for line in std::fs::read_to_string(out.join("index.jsonl")).unwrap().lines() {
        let r: Value = serde_json::from_str(line).unwrap();
        let side = if r["split"] == "train" { &mut train } else { &mut test };
        for key in ["material_ids", "target_material_ids"] {
            for m in r[key].as_array().unwrap() {
                side.insert(m.as_str().unwrap().to_string());
            }
        }
    }
    (train, test)
}

#[test]
fn a_seed_is_one_material_in_every_dataset_and_splits_never_share_one() {
    let d = scratch("parametric-same");
    let entry = |first: u64| {
        format!("source = \"parametric\"\nfamilies = [\"plastic\", \"metal\"]\ncount = 6\nfirst_seed = {first}")
    };
    // Two datasets with other dataset seeds and overlapping material seeds (3..6 and 3..9).
    let a = write(&d, "a.toml", &manifest(1, &entry(0)));
    let b = write(&d, "b.toml", &manifest(2, &entry(3)));

    let la = load(&a).unwrap();
    let ids: Vec<&str> = la.plan.catalogue.materials.iter().map(|m| m.id.as_str()).collect();
    assert_eq!(ids.len(), 12, "{ids:?}");
    for family in ParametricFamily::ALL {
        for seed in 0..6u64 {
            let id = format!("parametric:{}:{seed}", family.name());
            let item = la.plan.catalogue.materials.iter().find(|m| m.id == id).unwrap();
            assert_eq!(item.group, id, "each draw is its own group");
            assert_eq!(item.source, MaterialSource::Analytic(family.spec(seed)));
            match (family, family.spec(seed)) {
                (ParametricFamily::Plastic, BrdfSpec::Plastic { .. })
                | (ParametricFamily::Metal, BrdfSpec::Ggx { .. }) => {}
                (f, s) => panic!("{f:?} drew {s:?}"),
            }
        }
    }

    let (oa, ob) = (d.join("out-a"), d.join("out-b"));
    run_to(&a, &oa);
    run_to(&b, &ob);
    for out in [&oa, &ob] {
        let (train, test) = materials_by_split(out);
        assert!(!train.is_empty() && !test.is_empty());
        assert!(
            train.is_disjoint(&test),
            "shared: {:?}",
            train.intersection(&test).collect::<Vec<_>>()
        );
        // Distinct draws give distinct labels.
        let labels: BTreeSet<String> = std::fs::read_dir(out.join("materials"))
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.to_string_lossy().ends_with(".dsbrdf.json"))
            .map(|p| std::fs::read_to_string(p).unwrap())
            .collect();
        assert_eq!(labels.len(), 8, "8 dealt materials, 8 different labels");
    }
    // A seed both datasets used has the same fitted label, byte for byte.
    let common: Vec<String> = (3..6)
        .flat_map(|s| ParametricFamily::ALL.map(|f| format!("parametric_{}_{s}.dsbrdf.json", f.name())))
        .filter(|n| oa.join("materials").join(n).is_file() && ob.join("materials").join(n).is_file())
        .collect();
    for n in &common {
        assert_eq!(
            std::fs::read(oa.join("materials").join(n)).unwrap(),
            std::fs::read(ob.join("materials").join(n)).unwrap(),
            "{n}"
        );
    }
}

#[test]
fn bad_parametric_entries_are_refused_with_field_and_line() {
    let d = scratch("parametric-bad");
    let cases = [
        ("source = \"parametric\"\ncount = 4", "materials[0].families: required"),
        (
            "source = \"parametric\"\nfamilies = []\ncount = 4",
            "materials[0].families: empty",
        ),
        (
            "source = \"parametric\"\nfamilies = [\"wood\"]\ncount = 4",
            "materials[0].families: unknown parametric family \"wood\"",
        ),
        (
            "source = \"parametric\"\nfamilies = [\"plastic\"]",
            "materials[0].count: required",
        ),
        (
            "source = \"parametric\"\nfamilies = [\"plastic\"]\ncount = 0",
            "materials[0].count: 0",
        ),
        (
            "source = \"parametric\"\nfamilies = [\"plastic\"]\ncount = 4\nfirst_seed = 18446744073709551614",
            "materials[0].first_seed",
        ),
        (
            "source = \"parametric\"\nfamilies = [\"plastic\"]\ncount = 4\nnames = [\"x\"]",
            "materials[0].names: not used by source = \"parametric\"",
        ),
        (
            "source = \"parametric\"\nfamilies = [\"plastic\"]\ncount = 4\npath = \"x\"",
            "materials[0].path: not used by source = \"parametric\"",
        ),
        (
            "source = \"library\"\nfamilies = [\"plastic\"]\ncount = 4",
            "materials[0].count: not used by source = \"library\"",
        ),
        (
            "source = \"nbrdf\"\npath = \"x\"\nfirst_seed = 2",
            "materials[0].first_seed: not used by source = \"nbrdf\"",
        ),
        ("source = \"procedural\"\ncount = 4", "materials[0].source"),
    ];
    for (entry, needle) in cases {
        let p = write(&d, "bad.toml", &manifest(1, entry));
        let e = format!("{:#}", load(&p).err().unwrap_or_else(|| panic!("{entry}: accepted")));
        assert!(e.contains("bad.toml:") && e.contains(needle), "{entry}: {e}");
    }
}
