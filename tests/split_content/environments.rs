//! Environment maps by content: identical maps are dealt together, ids place maps and the split
//! holds by content.

use super::*;

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
