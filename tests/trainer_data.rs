//! The trainer's data pipeline (`matedit_trainer::data`) against a real (tiny) dataset rendered
//! by datagen's library: 16² images, a 4×8 environment, a procedural car (two regions) and an
//! OBJ octahedron (one region), DSBRDF material files (no fitting), 12 training and 4 test
//! samples. A workspace test, so that the trainer's own build never includes the factory.

use anyhow::Result;
use matedit_contract::io::read_exr_channels;
use matedit_fixtures::{OCTAHEDRON, Sources, copy_dir, five_materials, render_dataset};
use matedit_trainer::data::*;
use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};

const MANIFEST: &str = include_str!("../tests/fixtures/manifests/loader.toml");

fn root() -> PathBuf {
    std::env::temp_dir().join(format!("matedit-trainer-data-{}", std::process::id()))
}

/// The dataset, rendered once per test process.
fn fixture() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let _ = std::fs::remove_dir_all(root());
        let materials = five_materials();
        let sources = Sources {
            manifest: MANIFEST,
            materials: &materials,
            objs: &[("octahedron.obj", OCTAHEDRON)],
        };
        render_dataset(&root(), "m.toml", &sources, "dataset")
    })
}

/// A private copy of the fixture for a test that damages files.
fn copy_fixture(name: &str) -> PathBuf {
    let dest = root().join(name);
    let _ = std::fs::remove_dir_all(&dest);
    copy_dir(fixture(), &dest);
    dest
}

fn open() -> Arc<Dataset> {
    Arc::new(Dataset::open(fixture()).unwrap())
}

fn config(seed: u64, batch_size: usize, workers: usize) -> LoaderConfig {
    LoaderConfig {
        workers,
        epochs: Epochs::Finite(2),
        ..LoaderConfig::training(seed, batch_size)
    }
}

fn ids(loader: Loader) -> Vec<String> {
    loader.flat_map(|b| b.unwrap().ids).collect()
}

#[test]
#[allow(clippy::needless_range_loop)] // one pixel index across many channels
fn every_sample_loads_with_consistent_shapes_normals_regions_and_materials() {
    let ds = open();
    assert_eq!(ds.split_names(), vec!["train", "test"]);
    assert_eq!((ds.records("train").len(), ds.records("test").len()), (12, 4));
    assert!(ds.records("nope").is_empty());
    let mut region_counts = std::collections::BTreeSet::new();
    for split in ds.split_names() {
        for rec in ds.records(split) {
            let s = ds.load(rec, true).unwrap();
            let (n, p) = (s.size, s.size * s.size);
            assert_eq!(n, 16);
            assert_eq!((s.input.len(), s.target.len(), s.normals.len()), (3 * p, 3 * p, 3 * p));
            assert_eq!((s.mask.len(), s.regions.len()), (p, p));
            assert_eq!((s.env_height, s.env.len()), (4, 3 * 4 * 8));
            assert_eq!((s.sanitized, s.dropped), (0, 0));
            let r = rec.regions.len();
            region_counts.insert(r);
            assert_eq!((s.materials.len(), s.target_materials.len()), (r, r));
            assert!(s.mask.contains(&1.0), "{}: empty mask", s.id);

            // An independent reading of the file: channel mapping, region + 1, mask.
            let (_, _, ch) = read_exr_channels(&ds.dir().join(&rec.files["image"])).unwrap();
            assert_eq!(s.input[..p], ch["R"][..]);
            assert_eq!(s.input[2 * p..], ch["B"][..]);
            assert_eq!(s.target[p..2 * p], ch["O.G"][..]);
            for k in 0..p {
                let nrm = [s.normals[k], s.normals[p + k], s.normals[2 * p + k]];
                assert!(s.mask[k] == 0.0 || s.mask[k] == 1.0);
                assert_eq!(s.mask[k], ch["mask"][k]);
                if s.mask[k] == 1.0 {
                    let len = nrm.iter().map(|v| v * v).sum::<f32>().sqrt();
                    assert!((len - 1.0).abs() < 1e-5, "{}: |n| = {len}", s.id);
                    assert!(nrm[2] >= 1e-4 * 0.999);
                    assert_eq!(s.regions[k] as f32, ch["region"][k] + 1.0);
                    assert!((1..=r).contains(&(s.regions[k] as usize)));
                } else {
                    assert_eq!(nrm, [0.0; 3]);
                    assert_eq!(s.regions[k], 0);
                }
            }
            for (got, id) in s.materials.iter().zip(&rec.material_ids) {
                let want = &ds.info().materials[id].normalised;
                assert!(got.iter().zip(want).all(|(&g, &w)| g == w as f32), "{id}");
            }
            for (got, id) in s.target_materials.iter().zip(&rec.target_material_ids) {
                assert_eq!(got, ds.normalised_material(id).unwrap());
            }
        }
    }
    // The OBJ monitor has one region, a procedural car five (body, wheels, tyres, glass, lights).
    assert_eq!(region_counts.into_iter().collect::<Vec<_>>(), vec![1, 5]);
}

#[test]
fn a_bad_index_line_is_named_by_file_and_line() {
    let dir = copy_fixture("bad-line");
    let p = dir.join("index.jsonl");
    let text = std::fs::read_to_string(&p).unwrap();
    let mut lines: Vec<&str> = text.lines().collect();
    lines[2] = "{\"id\": 3}";
    std::fs::write(&p, lines.join("\n")).unwrap();
    let e = format!("{:#}", Dataset::open(&dir).unwrap_err());
    assert!(e.contains(&format!("{}:3", p.display())), "{e}");
    // An intact but edited index is caught by the checksum.
    lines[2] = text.lines().nth(2).unwrap();
    lines.swap(0, 1);
    std::fs::write(&p, lines.join("\n")).unwrap();
    let e = format!("{:#}", Dataset::open(&dir).unwrap_err());
    assert!(e.contains("checksum"), "{e}");
    let e = format!("{:#}", Dataset::open(&root().join("missing")).unwrap_err());
    assert!(e.contains("dataset.json"), "{e}");
}

#[test]
fn epoch_order_is_a_seeded_permutation() {
    for buffer in [0, 4, 100] {
        let a = epoch_order(50, 1, 0, true, buffer);
        let mut sorted = a.clone();
        sorted.sort();
        assert_eq!(sorted, (0..50).collect::<Vec<_>>());
        assert_eq!(a, epoch_order(50, 1, 0, true, buffer));
        assert_ne!(a, epoch_order(50, 2, 0, true, buffer));
        assert_ne!(a, epoch_order(50, 1, 1, true, buffer));
    }
    assert_ne!(epoch_order(50, 1, 0, true, 0), epoch_order(50, 1, 0, true, 8));
    assert_eq!(epoch_order(5, 1, 3, false, 8), vec![0, 1, 2, 3, 4]);
}

#[test]
fn the_order_depends_on_the_seed_only_not_on_workers() {
    let ds = open();
    let runs: Vec<Vec<Batch>> = [0, 1, 3]
        .iter()
        .map(|&w| {
            Loader::new(ds.clone(), "train", config(7, 5, w))
                .unwrap()
                .map(Result::unwrap)
                .collect()
        })
        .collect();
    assert_eq!(runs[0], runs[1]);
    assert_eq!(runs[1], runs[2]);
    // Two epochs of 12 in batches of 5: 5, 5, 5, 5, 4; each epoch holds every sample once.
    let sizes: Vec<usize> = runs[0].iter().map(|b| b.batch).collect();
    assert_eq!(sizes, vec![5, 5, 5, 5, 4]);
    let all: Vec<String> = runs[0].iter().flat_map(|b| b.ids.clone()).collect();
    for epoch in all.chunks(12) {
        let mut e = epoch.to_vec();
        e.sort();
        e.dedup();
        assert_eq!(e.len(), 12);
    }
    assert_ne!(all[..12], all[12..], "epochs are reshuffled");

    let other = ids(Loader::new(ds.clone(), "train", config(8, 5, 2)).unwrap());
    assert_ne!(all, other);
    assert_eq!(
        all,
        ids(Loader::new(ds.clone(), "train", config(7, 3, 2)).unwrap()),
        "batch size keeps the order"
    );

    // Evaluation: one pass in index order, a short last batch.
    let eval = Loader::new(ds.clone(), "train", LoaderConfig::evaluation(5)).unwrap();
    let want: Vec<String> = ds.records("train").iter().map(|r| r.id.clone()).collect();
    assert_eq!(ids(eval), want);
}

#[test]
fn resuming_at_a_step_or_a_position_gives_the_same_batches() {
    let ds = open();
    let cfg = |w| LoaderConfig {
        epochs: Epochs::Infinite,
        ..config(3, 5, w)
    };
    let straight: Vec<Batch> = Loader::new(ds.clone(), "train", cfg(2))
        .unwrap()
        .take(7)
        .map(Result::unwrap)
        .collect();
    let mut l = Loader::new(ds.clone(), "train", cfg(1)).unwrap();
    let _ = l.next_batch().unwrap().unwrap();
    l.skip_to(3).unwrap();
    assert_eq!(l.position(), 15);
    let resumed: Vec<Batch> = l.by_ref().take(4).map(Result::unwrap).collect();
    assert_eq!(resumed, straight[3..]);
    assert_eq!(l.position(), straight[6].next_position);

    let at = straight[2].next_position;
    let from_config = Loader::new(
        ds.clone(),
        "train",
        LoaderConfig {
            start_position: at,
            ..cfg(0)
        },
    )
    .unwrap();
    let resumed: Vec<Batch> = from_config.take(4).map(Result::unwrap).collect();
    assert_eq!(resumed, straight[3..]);
}

#[test]
fn mixed_region_counts_are_padded_with_the_last_material() {
    let ds = open();
    let b = Loader::new(ds.clone(), "train", LoaderConfig::evaluation(12))
        .unwrap()
        .next()
        .unwrap()
        .unwrap();
    assert_eq!((b.batch, b.size, b.regions, b.env_height), (12, 16, 5, 4));
    assert_eq!(b.input.len(), 12 * 3 * 256);
    assert_eq!((b.mask.len(), b.region_map.len()), (12 * 256, 12 * 256));
    assert_eq!(b.env.len(), 12 * 3 * 4 * 8);
    assert_eq!(b.materials.len(), 12 * 5 * 108);
    assert!(b.region_counts.contains(&1) && b.region_counts.contains(&5));
    for (i, rec) in ds.records("train").iter().enumerate() {
        let r = b.region_counts[i];
        let mat = |v: &[f32], k: usize| v[(i * 5 + k) * 108..(i * 5 + k + 1) * 108].to_vec();
        assert_eq!(
            mat(&b.materials, 0),
            ds.normalised_material(&rec.material_ids[0]).unwrap().to_vec()
        );
        for k in r..5 {
            assert_eq!(mat(&b.target_materials, k), mat(&b.target_materials, r - 1));
            assert_eq!(mat(&b.materials, k), mat(&b.materials, r - 1));
        }
        assert!(b.region_map[i * 256..(i + 1) * 256].iter().all(|&g| g as usize <= r));
    }
}

#[test]
fn a_truncated_file_stops_with_its_path_or_is_skipped() {
    let dir = copy_fixture("truncated");
    let ds = Arc::new(Dataset::open(&dir).unwrap());
    let victim = &ds.records("train")[4];
    let path = dir.join(&victim.files["image"]);
    let bytes = std::fs::read(&path).unwrap();
    std::fs::write(&path, &bytes[..bytes.len() / 2]).unwrap();

    for workers in [0, 2] {
        let cfg = LoaderConfig {
            workers,
            verify_checksums: false,
            ..LoaderConfig::evaluation(3)
        };
        let mut l = Loader::new(ds.clone(), "train", cfg.clone()).unwrap();
        assert_eq!(l.next().unwrap().unwrap().ids.len(), 3);
        let e = l.next().unwrap().unwrap_err();
        let msg = format!("{e}");
        assert!(msg.contains(&path.display().to_string()), "{msg}");
        assert_eq!(e.downcast_ref::<LoadError>().unwrap().file, path);
        assert!(l.next().is_none());

        let mut l = Loader::new(
            ds.clone(),
            "train",
            LoaderConfig {
                on_corrupt: OnCorrupt::Skip,
                ..cfg
            },
        )
        .unwrap();
        let batches: Vec<Batch> = l.by_ref().map(Result::unwrap).collect();
        let got: Vec<String> = batches.iter().flat_map(|b| b.ids.clone()).collect();
        let want: Vec<String> = ds
            .records("train")
            .iter()
            .filter(|r| r.id != victim.id)
            .map(|r| r.id.clone())
            .collect();
        assert_eq!(got, want);
        assert_eq!(batches.iter().map(|b| b.batch).collect::<Vec<_>>(), vec![3, 3, 3, 2]);
        assert_eq!(l.skipped().len(), 1);
        assert_eq!((&l.skipped()[0].file, &l.skipped()[0].id), (&path, &victim.id));
        assert_eq!(batches[1].skipped.len(), 1);
    }
}

#[test]
fn tampered_bytes_fail_checksum_verification() {
    let dir = copy_fixture("tampered");
    let ds = Arc::new(Dataset::open(&dir).unwrap());
    let victim = &ds.records("test")[1];
    let path = dir.join(&victim.files["env"]);
    let mut bytes = std::fs::read(&path).unwrap();
    let k = bytes.len() - 5;
    bytes[k] ^= 0x40;
    std::fs::write(&path, &bytes).unwrap();
    let e = ds.load(victim, true).unwrap_err().to_string();
    assert!(e.contains(&path.display().to_string()) && e.contains("checksum"), "{e}");
    let mut l = Loader::new(ds.clone(), "test", LoaderConfig::evaluation(1)).unwrap();
    assert!(l.next().unwrap().is_ok());
    let e = l.next().unwrap().unwrap_err().to_string();
    assert!(e.contains(&path.display().to_string()), "{e}");
}

#[test]
fn non_finite_values_become_zero_and_are_counted() {
    use exr::prelude::*;
    let dir = copy_fixture("non-finite");
    let ds = Dataset::open(&dir).unwrap();
    let rec = &ds.records("test")[0];
    let path = dir.join(&rec.files["image"]);
    let (w, h, mut ch) = read_exr_channels(&path).unwrap();
    let k = ch["mask"].iter().position(|&m| m > 0.0).unwrap();
    ch.get_mut("R").unwrap()[k] = f32::NAN;
    ch.get_mut("O.G").unwrap()[0] = f32::INFINITY;
    ch.get_mut("normal.X").unwrap()[k] = f32::NAN;
    let list: Vec<AnyChannel<FlatSamples>> = ch
        .into_iter()
        .map(|(n, d)| AnyChannel::new(n.as_str(), FlatSamples::F32(d)))
        .collect();
    let layer = Layer::new(
        (w, h),
        LayerAttributes::default(),
        Encoding::SMALL_LOSSLESS,
        AnyChannels::sort(SmallVec::from_vec(list)),
    );
    Image::from_layer(layer).write().to_file(&path).unwrap();
    assert!(ds.load(rec, true).is_err(), "the checksum no longer matches");
    let s = ds.load(rec, false).unwrap();
    assert_eq!(s.sanitized, 3);
    assert_eq!((s.input[k], s.target[s.size * s.size]), (0.0, 0.0));
    let n = [s.normals[k], s.normals[256 + k], s.normals[512 + k]];
    assert!(s.mask[k] == 0.0 || (n.iter().map(|v| v * v).sum::<f32>() - 1.0).abs() < 1e-5);
    assert!(s.input.iter().chain(&s.target).chain(&s.normals).all(|v| v.is_finite()));
}
