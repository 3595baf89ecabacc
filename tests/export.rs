//! What a dataset gives away: the WebDataset export (read back with the `tar` crate, an
//! independent reader), the dataset card with every source's origin and licence, and the card's
//! manifest, which makes the dataset again.

mod common;
use common::{datagen, run_to};

use matedit_contract::records::{DatasetRecord, checksum};
use matedit_datagen::dataset::run::load;
use matedit_datagen::dataset::store::plan_record;
use serde_json::Value;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::Command;

fn scratch(name: &str) -> common::Scratch {
    common::scratch(&format!("export-{name}"))
}

/// A small multi-material manifest (`envs`: extra `[[environments]]` entries).
fn manifest(envs: &str) -> String {
    format!(
        r#"
[dataset]
name = "x"
seed = 5
output = "unused"
shard_size = 4

[render]
resolution = 24
env_resolution = "16x32"
quality = "fast"

[views]
azimuths = 8
per_combination = 1

[multi_material]
mode = "per_region"

[sampling]
mode = "sampled"
combinations = 7

[[shapes]]
source = "procedural"
category = "car"
count = 2

[[materials]]
source = "library"
families = ["fabric", "rubber", "plastic"]

[[environments]]
source = "procedural"
family = "sunsky"
count = 1
{envs}
[[splits]]
name = "train"
shapes = {{ car = 1 }}
materials = 5

[[splits]]
name = "test"
shapes = {{ car = 1 }}
materials = 3
"#
    )
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

fn dataset_record(dir: &Path) -> DatasetRecord {
    serde_json::from_slice(&std::fs::read(dir.join("dataset.json")).unwrap()).unwrap()
}

fn export(data: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    Command::new(datagen())
        .arg("export")
        .arg(data)
        .arg("--webdataset")
        .arg(out)
        .args(extra)
        .output()
        .unwrap()
}

/// Every member of a tar: (name, bytes, mtime, uid, mode).
fn members(tar: &Path) -> Vec<(String, Vec<u8>, u64, u64, u32)> {
    let mut a = tar::Archive::new(std::fs::File::open(tar).unwrap());
    a.entries()
        .unwrap()
        .map(|e| {
            let mut e = e.unwrap();
            let h = e.header().clone();
            let mut bytes = Vec::new();
            e.read_to_end(&mut bytes).unwrap();
            let name = e.path().unwrap().display().to_string();
            (name, bytes, h.mtime().unwrap(), h.uid().unwrap(), h.mode().unwrap())
        })
        .collect()
}

#[test]
fn the_export_holds_every_sample_whole_in_index_order_within_its_limits() {
    let d = scratch("tars");
    let data = d.join("data");
    run_to(&write(&d, "m.toml", &manifest("")), &data);
    let out = d.join("wds");
    let r = export(&data, &out, &["--shard-samples", "3"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));

    let rec = dataset_record(&data);
    let index: Vec<Value> = std::fs::read_to_string(data.join("index.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let shards: Value = serde_json::from_slice(&std::fs::read(out.join("shards.json")).unwrap()).unwrap();
    assert_eq!(shards["format"], "matedit-webdataset-1");
    assert_eq!(shards["source_index_checksum"], rec.index_checksum.as_str());
    assert_eq!(
        std::fs::read(out.join("dataset.json")).unwrap(),
        std::fs::read(data.join("dataset.json")).unwrap()
    );
    let mut seen = Vec::new();
    for split in shards["splits"].as_array().unwrap() {
        let name = split["name"].as_str().unwrap();
        let tars = split["shards"].as_array().unwrap();
        assert_eq!(tars.len(), rec.counts[name].div_ceil(3), "{name}");
        for (k, t) in tars.iter().enumerate() {
            let file = out.join(t["name"].as_str().unwrap());
            assert_eq!(t["name"], format!("{name}-{k:06}.tar"));
            let bytes = std::fs::read(&file).unwrap();
            assert_eq!(t["checksum"], checksum(&bytes).as_str());
            assert_eq!(t["bytes"], bytes.len() as u64);
            let m = members(&file);
            assert_eq!(m.len(), 3 * t["samples"].as_u64().unwrap() as usize);
            assert!(t["samples"].as_u64().unwrap() <= 3);
            for sample in m.chunks(3) {
                let id = sample[0].0.strip_suffix(".exr").unwrap();
                let record = index.iter().find(|r| r["id"] == id).unwrap();
                assert_eq!(sample[1].0, format!("{id}.env.exr"));
                assert_eq!(sample[2].0, format!("{id}.json"));
                for (member, key) in [(&sample[0], "image"), (&sample[1], "env")] {
                    let file = data.join(record["files"][key].as_str().unwrap());
                    assert_eq!(member.1, std::fs::read(file).unwrap(), "{id} {key}: the file unchanged");
                }
                for (_, _, mtime, uid, mode) in sample {
                    assert_eq!((*mtime, *uid, *mode), (0, 0, 0o644), "nothing of this machine");
                }
                let json: Value = serde_json::from_slice(&sample[2].1).unwrap();
                for (k, v) in record.as_object().unwrap() {
                    assert_eq!(&json[k], v, "{id}: {k}");
                }
                let ids = record["material_ids"].as_array().unwrap();
                assert_eq!(json["materials"].as_array().unwrap().len(), ids.len());
                for (m, id) in json["materials"].as_array().unwrap().iter().zip(ids) {
                    let table = &rec.materials[id.as_str().unwrap()];
                    assert_eq!(m["id"], *id);
                    assert_eq!(
                        serde_json::from_value::<Vec<f64>>(m["normalised"].clone()).unwrap(),
                        table.normalised
                    );
                    assert_eq!(serde_json::from_value::<Vec<f64>>(m["raw"].clone()).unwrap(), table.raw);
                }
                seen.push(id.to_string());
            }
        }
    }
    let want: Vec<String> = index.iter().map(|r| r["id"].as_str().unwrap().to_string()).collect();
    assert_eq!(seen, want, "every sample once, in index order");

    // The same bytes on one thread as on many.
    let again = d.join("wds-1");
    let r = Command::new(datagen())
        .env("RAYON_NUM_THREADS", "1")
        .arg("export")
        .arg(&data)
        .arg("--webdataset")
        .arg(&again)
        .args(["--shard-samples", "3"])
        .output()
        .unwrap();
    assert!(r.status.success());
    for e in std::fs::read_dir(&out).unwrap() {
        let p = e.unwrap().path();
        let name = p.file_name().unwrap();
        if !name.to_string_lossy().starts_with('.') {
            assert_eq!(
                std::fs::read(&p).unwrap(),
                std::fs::read(again.join(name)).unwrap(),
                "{name:?}"
            );
        }
    }
    // A byte limit: every tar within it, or a single sample.
    let small = d.join("wds-small");
    let r = export(&data, &small, &["--shard-mb", "1", "--shard-samples", "1000"]);
    assert!(r.status.success());
    let s: Value = serde_json::from_slice(&std::fs::read(small.join("shards.json")).unwrap()).unwrap();
    for t in s["splits"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|s| s["shards"].as_array().unwrap())
    {
        assert!(t["bytes"].as_u64().unwrap() <= 1 << 20 || t["samples"] == 1, "{t}");
    }
}

#[test]
fn a_corrupt_sample_stops_the_export_by_name_and_a_bad_destination_is_refused() {
    let d = scratch("corrupt");
    let data = d.join("data");
    run_to(&write(&d, "m.toml", &manifest("")), &data);
    let rec: Value = serde_json::from_str(
        std::fs::read_to_string(data.join("index.jsonl"))
            .unwrap()
            .lines()
            .last()
            .unwrap(),
    )
    .unwrap();
    let file = data.join(rec["files"]["env"].as_str().unwrap());
    let mut bytes = std::fs::read(&file).unwrap();
    let n = bytes.len() / 2;
    bytes[n] ^= 0x55;
    std::fs::write(&file, &bytes).unwrap();
    let out = d.join("wds");
    let r = export(&data, &out, &["--shard-samples", "2"]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(
        !r.status.success() && err.contains(&*file.to_string_lossy()) && err.contains("checksum mismatch"),
        "{err}"
    );
    assert!(!out.join("shards.json").exists(), "an unfinished export has no record");
    for e in std::fs::read_dir(&out).unwrap() {
        let name = e.unwrap().file_name().to_string_lossy().into_owned();
        assert!(!name.contains(".tmp-"), "a temporary file was left: {name}");
        if name.ends_with(".tar") {
            let t = members(&out.join(&name));
            assert!(
                t.iter().all(|m| !m.0.starts_with(rec["id"].as_str().unwrap())),
                "{name} holds the corrupt sample"
            );
        }
    }
    let inside = export(&data, &data.join("wds"), &[]);
    assert!(!inside.status.success() && String::from_utf8_lossy(&inside.stderr).contains("outside the dataset"));
    let none = export(&d.join("nothing"), &d.join("wds2"), &[]);
    assert!(!none.status.success() && String::from_utf8_lossy(&none.stderr).contains("dataset.json"));
}

/// A 2:1 environment map at `path`.
fn env_map(path: &Path, level: f32) -> PathBuf {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    let (w, h) = (32, 16);
    let v: Vec<f32> = (0..w * h).map(|i| level + (i % 7) as f32 * 0.1).collect();
    matedit_contract::io::write_exr_channels(path, w, h, vec![("R", v.clone()), ("G", v.clone()), ("B", v)]).unwrap();
    path.to_path_buf()
}

#[test]
fn the_card_names_every_source_with_its_licence_and_its_manifest_makes_the_dataset_again() {
    let d = scratch("card");
    let maps = env_map(&d.join("maps/sky.exr"), 0.2);
    let other = env_map(&d.join("other/dawn.exr"), 0.5);
    let given = format!(
        "\n[[environments]]\nsource = \"folder\"\npath = \"{}\"\norigin = \"Poly Haven (polyhaven.com)\"\nlicence = \"CC0-1.0\"\n\n[[environments]]\nsource = \"file\"\npath = \"{}\"\n",
        maps.parent().unwrap().display(),
        other.display()
    );
    let data = d.join("data");
    let m = write(&d, "m.toml", &manifest(&given));
    let r = Command::new(datagen())
        .arg("run")
        .arg(&m)
        .arg("--out")
        .arg(&data)
        .output()
        .unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let rec = dataset_record(&data);
    let g = rec.plan.generator.as_ref().unwrap();
    assert_eq!(g.name, "matedit-datagen");
    assert!(
        g.commit == "unknown" || (g.commit.len() == 40 && g.commit.chars().all(|c| c.is_ascii_hexdigit())),
        "{g:?}"
    );
    let licences: Vec<(&str, &str, &str)> = rec
        .plan
        .sources
        .iter()
        .map(|s| (s.source.as_str(), s.origin.as_str(), s.licence.as_str()))
        .collect();
    assert_eq!(licences.len(), 5, "{licences:?}");
    assert_eq!(licences[3], ("folder", "Poly Haven (polyhaven.com)", "CC0-1.0"));
    assert_eq!(licences[4], ("file", "unknown", "unknown"), "never guessed");
    assert!(
        licences[..3]
            .iter()
            .all(|l| l.2 == "MIT OR Apache-2.0" && l.1.contains("matedit"))
    );

    let card = std::fs::read_to_string(data.join("README.md")).unwrap();
    let front = card.strip_prefix("---\n").unwrap().split("\n---\n").next().unwrap();
    for want in [
        "- mit\n",
        "- apache-2.0\n",
        "- cc0-1.0\n",
        "- unknown\n",
        "- original\n",
        "\"Poly Haven (polyhaven.com)\"",
        "size_categories:\n- n<1K",
    ] {
        assert!(front.contains(want), "{want:?} not in the front matter:\n{front}");
    }
    for split in ["train", "test"] {
        assert!(
            front.contains(&format!(
                "  - name: \"{split}\"\n    num_examples: {}",
                rec.counts[split]
            )),
            "{front}"
        );
    }
    assert!(card.contains("| environments | folder |") && card.contains("| CC0-1.0 |"));
    assert!(card.contains(&g.commit) && card.contains("![samples of the dataset](inspect.png)"));
    let sheet = image::open(data.join("inspect.png")).unwrap();
    assert!(sheet.width() > 0);
    // The same card again from `datagen card`, byte for byte.
    let before = card.clone();
    let r = Command::new(datagen()).arg("card").arg(&data).output().unwrap();
    assert!(r.status.success());
    assert_eq!(std::fs::read_to_string(data.join("README.md")).unwrap(), before);

    // The card's manifest is the dataset's: same hash, and it renders the same index.
    let toml = card.split("```toml\n").nth(1).unwrap().split("```").next().unwrap();
    let again = write(&d, "again.toml", toml);
    let l = load(&again).unwrap();
    assert_eq!(
        plan_record(&l.plan, &l.file.manifest).unwrap().manifest_hash,
        rec.plan.manifest_hash
    );
    let data2 = d.join("data2");
    run_to(&again, &data2);
    assert_eq!(
        std::fs::read(data2.join("index.jsonl")).unwrap(),
        std::fs::read(data.join("index.jsonl")).unwrap()
    );
}

#[test]
fn a_licence_on_an_embedded_source_is_refused_naming_its_line() {
    let d = scratch("licence-field");
    let text = manifest("").replace(
        "family = \"sunsky\"\ncount = 1\n",
        "family = \"sunsky\"\ncount = 1\nlicence = \"CC0-1.0\"\n",
    );
    let e = format!("{:#}", load(&write(&d, "m.toml", &text)).err().unwrap());
    assert!(
        e.contains("m.toml:")
            && e.contains("environments[0].licence")
            && e.contains("not used by source = \"procedural\""),
        "{e}"
    );
}
