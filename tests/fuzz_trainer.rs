//! No input can crash the trainer's readers: property-based fuzzing of training manifests,
//! checkpoints (state and weights) and a dataset as the trainer loads it (the properties and the
//! mutations: `tests/common/fuzz/`). Photos, masks and region labels are fuzzed with the
//! editor that reads them (`edit/tests/fuzz.rs`).
//!
//! CI: `cargo test --release --test fuzz_trainer`. The long run:
//! `MATEDIT_FUZZ_SCALE=K` (K times each reader's CI cases) (and `MATEDIT_FUZZ_SEED`), `scripts/fuzz_long.sh`.

#[path = "common/fuzz/mod.rs"]
mod fuzz;

use burn::optim::AdamConfig;
use burn::tensor::Device;
use fuzz::{Counting, Reader, Verdict, copy_tree, dataset, fuzz};
use matedit_trainer::data::Dataset;
use matedit_trainer::model::Widths;
use matedit_trainer::model::network::NetConfig;
use matedit_trainer::train::checkpoint::{State, load_net, save};
use matedit_trainer::train::manifest;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

#[global_allocator]
static ALLOCATOR: Counting = Counting;

const MB: usize = 1 << 20;

fn err(e: impl std::fmt::Display) -> String {
    format!("{e:#}")
}

fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("matedit-trainer-fuzz-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn training_manifests() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("manifests/train");
    let mut seeds: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        // Each as resolved (its `extends` followed): a file that extends another is fuzzed
        // alone, where its base is not.
        .filter_map(|p| {
            matedit_contract::manifest::Resolved::read(&p, &[])
                .ok()
                .map(|r| (p.display().to_string(), r.text.into_bytes()))
        })
        .collect();
    seeds.sort();
    assert!(!seeds.is_empty(), "the shipped training manifests");
    let read = |p: &Path| -> Result<Verdict, String> {
        let plan = manifest::load(p, &[]).map_err(err)?;
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

/// A checkpoint of an untrained small network (16² input), written once per process.
fn checkpoint() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let root = scratch("checkpoint");
        let cfg = NetConfig::new(16, Widths::cpu_small()).with_env_height(4);
        let net = cfg.init(&Device::flex());
        let state = State::untrained(cfg, "untrained");
        save(&root, "untrained", &net, &AdamConfig::new().init(), state).unwrap()
    })
}

/// Found by this fuzzer: a checkpoint whose state.json gives a dropout of −1 (or widths of 0, or
/// sizes beyond reason) made Burn panic, or the loader allocate without bound, while building
/// the network; the state is now validated first, naming the file.
#[test]
fn regression_checkpoint_state_with_impossible_network() {
    let dir = checkpoint();
    let state = std::fs::read_to_string(dir.join("state.json")).unwrap();
    let prepare = move |case: &Path| copy_tree(dir, case);
    let read = |p: &Path| -> Result<Verdict, String> {
        load_net(p.parent().unwrap_or(p), &Device::flex()).map_err(err)?;
        Ok(Ok(()))
    };
    let reader = Reader {
        name: "checkpoint-state",
        file_name: "state.json",
        seeds: Vec::new(),
        cases: 0,
        floor_bytes: 256 * MB,
        per_input_byte: None,
        prepare: Some(&prepare),
        read: &read,
    };
    let largest = state
        .replace("\"input_size\": 16", "\"input_size\": 1024")
        .replace("\"env_height\": 4", "\"env_height\": 256")
        .replace("\"base_channels\": 8", "\"base_channels\": 4096")
        .replace("\"max_channels\": 64", "\"max_channels\": 4096")
        .replace("\"hidden\": 128", "\"hidden\": 4096")
        .replace("\"normal_channels\": 16", "\"normal_channels\": 4096");
    assert!(
        !fuzz::regression(&reader, largest.as_bytes()),
        "the largest network the bounds allow"
    );
    for (from, to) in [
        ("\"dropout\": 0.5", "\"dropout\": -1"),
        ("\"dropout\": 0.5", "\"dropout\": 1.0"),
        ("\"hidden\": 128", "\"hidden\": 0"),
        ("\"input_size\": 16", "\"input_size\": 1099511627776"),
        ("\"env_height\": 4", "\"env_height\": 65536"),
        ("\"max_channels\": 64", "\"max_channels\": 1000000"),
        // Inside the bounds but far larger than the weights file: refused without building it.
        ("\"hidden\": 128", "\"hidden\": 4096"),
        ("\"input_size\": 16", "\"input_size\": 1024"),
    ] {
        assert!(state.contains(from), "{from}");
        assert!(!fuzz::regression(&reader, state.replace(from, to).as_bytes()), "{to}");
    }
}

/// The trainer's checkpoint reader (what `trainer eval`, `--resume`, `init_from` and `matedit`
/// load) on a checkpoint folder with one file mutated.
fn checkpoint_file(name: &'static str, file: &'static str, cases: u32) {
    let dir = checkpoint();
    let original = std::fs::read(dir.join(file)).unwrap();
    let prepare = move |case: &Path| copy_tree(dir, case);
    let read = |p: &Path| -> Result<Verdict, String> {
        let folder = p.parent().unwrap_or(p);
        let (_, state) = load_net(folder, &Device::flex()).map_err(err)?;
        let changed = std::fs::read(p).map(|b| b != original).unwrap_or(true);
        // The weights are checksummed in state.json: a changed weights file never loads.
        Ok(if changed && file == "model.bpk" {
            Err("a changed weights file loaded".into())
        } else if state.net.input_size == 0 {
            Err("a network of size 0".into())
        } else {
            Ok(())
        })
    };
    fuzz(&Reader {
        name,
        file_name: file,
        seeds: vec![(file.to_string(), std::fs::read(dir.join(file)).unwrap())],
        cases,
        floor_bytes: 256 * MB,
        per_input_byte: None,
        prepare: Some(&prepare),
        read: &read,
    });
}

#[test]
fn checkpoint_state() {
    checkpoint_file("checkpoint-state", "state.json", 150);
}

#[test]
fn checkpoint_weights() {
    checkpoint_file("checkpoint-weights", "model.bpk", 60);
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
