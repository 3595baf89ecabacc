//! No input can crash the trainer's readers: property-based fuzzing of training manifests and
//! of a dataset as the trainer loads it (the properties and the mutations:
//! `tests/common/fuzz.rs`). Checkpoints, photos, masks and region labels are fuzzed with the
//! editor that reads them (`trainer/edit/tests/fuzz.rs`).
//!
//! CI: `cargo test --release --test fuzz_trainer`. The long run:
//! `MATEDIT_FUZZ_SCALE=K` (K times each reader's CI cases) (and `MATEDIT_FUZZ_SEED`), `scripts/fuzz_long.sh`.

#[path = "common/fuzz.rs"]
mod fuzz;

use fuzz::{Counting, Reader, Verdict, copy_tree, dataset, fuzz, seed_file};
use matedit_trainer::data::Dataset;
use matedit_trainer::train::manifest;
use std::path::{Path, PathBuf};

#[global_allocator]
static ALLOCATOR: Counting = Counting;

const MB: usize = 1 << 20;

fn err(e: impl std::fmt::Display) -> String {
    format!("{e:#}")
}

#[test]
fn training_manifests() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("manifests/train");
    let mut seeds: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .filter_map(|p| seed_file(&p))
        .collect();
    seeds.sort();
    assert!(!seeds.is_empty(), "the shipped training manifests");
    let read = |p: &Path| -> Result<Verdict, String> {
        let plan = manifest::load(p).map_err(err)?;
        Ok(if plan.manifest.stages.is_empty() {
            Err("a plan without stages".into())
        } else {
            Ok(())
        })
    };
    fuzz(&Reader {
        name: "train-manifest",
        file_name: "train.toml",
        seeds,
        cases: 300,
        floor_bytes: 8 * MB,
        per_input_byte: None,
        prepare: None,
        read: &read,
    });
}

/// The trainer's dataset reader (open, then every sample with its checksum verified) on the
/// tiny dataset with one file mutated: a changed sample file never loads.
fn dataset_file(name: &'static str, rel: &'static str, cases: u32) {
    let dir = dataset();
    let original = std::fs::read(dir.join(rel)).unwrap();
    let prepare = move |case: &Path| copy_tree(dir, case);
    let read = |p: &Path| -> Result<Verdict, String> {
        let root = p.ancestors().find(|a| a.join("dataset.json").is_file()).unwrap_or(p);
        let ds = Dataset::open(root).map_err(err)?;
        let mut loaded = true;
        for split in ds.split_names() {
            for r in ds.records(split) {
                if let Err(e) = ds.load(r, true) {
                    let m = err(e);
                    if !m.contains(&*root.to_string_lossy()) && !m.contains(&r.id) {
                        return Err(m);
                    }
                    loaded = false;
                }
            }
        }
        let changed = std::fs::read(p).map(|b| b != original).unwrap_or(true);
        Ok(if loaded && changed && rel.ends_with(".exr") {
            Err("a changed sample file loaded".into())
        } else {
            Ok(())
        })
    };
    fuzz(&Reader {
        name,
        file_name: rel,
        seeds: vec![(rel.to_string(), std::fs::read(dir.join(rel)).unwrap())],
        cases,
        floor_bytes: 32 * MB,
        per_input_byte: None,
        prepare: Some(&prepare),
        read: &read,
    });
}

#[test]
fn dataset_index_as_the_trainer_reads_it() {
    dataset_file("trainer-dataset-index", "index.jsonl", 150);
}

#[test]
fn dataset_metadata_as_the_trainer_reads_it() {
    dataset_file("trainer-dataset-json", "dataset.json", 150);
}

#[test]
fn dataset_samples_as_the_trainer_reads_them() {
    dataset_file("trainer-dataset-sample", "shards/test-00000/test-0000000.exr", 100);
}
