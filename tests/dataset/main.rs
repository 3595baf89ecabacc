//! The dataset factory end to end: split integrity (including manifests that try to leak),
//! bad manifests, determinism across thread counts, resume after `kill -9`, and an independent
//! reader of `index.jsonl` and the EXR files.

#[path = "../common/mod.rs"]
mod common;
mod manifests;
use common::{datagen, run_to};

use matedit_contract::io::read_exr_channels;
use matedit_contract::lock::Worker;
use matedit_contract::verify::verify;
use matedit_datagen::dataset::run::{RunOptions, load, run};
use matedit_datagen::gbuffer::GBuffer;
use matedit_datagen::shapes::{Shape, UpAxis};
use serde_json::Value;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::Command;

fn scratch(name: &str) -> common::Scratch {
    common::scratch(&format!("dataset-{name}"))
}

/// A small manifest with mixed categories, per-region materials and rotations. Cheap shading:
/// 16×32 environment, Lambert/plastic sources rendered as measured.
fn manifest(extra_splits: &str, render: &str) -> String {
    format!(
        r#"
[dataset]
name = "t"
seed = 11
output = "unused"
shard_size = 3

[render]
resolution = 32
env_resolution = "16x32"
{render}

[views]
azimuths = 8
elevation_deg = 25.0
per_combination = 2

[multi_material]
mode = "per_region"

[[shapes]]
source = "procedural"
category = "car"
count = 3

[[shapes]]
source = "procedural"
category = "chair"
count = 3

[[materials]]
source = "library"
families = ["fabric", "rubber", "plastic"]

[[environments]]
source = "procedural"
family = "overcast"
count = 2

[[splits]]
name = "train"
shapes = {{ car = 1, chair = 1 }}
materials = 3
{extra_splits}
"#
    )
}

const TEST_SPLIT: &str = r#"
[[splits]]
name = "test"
shapes = { car = 1, chair = 1 }
materials = 2
"#;

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

fn index(dir: &Path) -> Vec<Value> {
    std::fs::read_to_string(dir.join("index.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

#[test]
fn an_independent_reader_finds_disjoint_splits_correct_counts_and_consistent_images() {
    let d = scratch("reader");
    let m = write(&d, "m.toml", &manifest(TEST_SPLIT, "ground_truth = \"measured\""));
    let out = d.join("out");
    run_to(&m, &out);
    let rep = verify(&out).unwrap();
    assert!(rep.ok(), "{:?}", rep.problems);

    let recs = index(&out);
    // 2 shapes × 3 materials × 2 envs × 2 views and 2 × 2 × 2 × 2.
    let count = |s: &str| recs.iter().filter(|r| r["split"] == s).count();
    assert_eq!((count("train"), count("test")), (24, 16));
    let mut owner: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for r in &recs {
        let split = r["split"].as_str().unwrap().to_string();
        owner
            .entry(format!("shape {}", r["shape_id"]))
            .or_default()
            .insert(split.clone());
        for m in r["material_ids"]
            .as_array()
            .unwrap()
            .iter()
            .chain(r["target_material_ids"].as_array().unwrap())
        {
            owner.entry(format!("material {m}")).or_default().insert(split.clone());
        }
        for key in [
            "id",
            "category",
            "env_id",
            "env_rotation_deg",
            "view_azimuth_deg",
            "view_elevation_deg",
        ] {
            assert!(!r[key].is_null(), "{key} missing in {r}");
        }
        assert_eq!(
            r["regions"].as_array().unwrap().len(),
            r["material_ids"].as_array().unwrap().len()
        );
    }
    for (what, splits) in &owner {
        assert_eq!(splits.len(), 1, "{what} is in {splits:?}");
    }

    // Images agree with the recorded ids: the recorded shape, posed as recorded and traced by
    // the plain (unrotated) path, covers the same pixels with the same normals.
    for r in recs.iter().step_by(7) {
        let (w, _, ch) = read_exr_channels(&out.join(r["files"]["image"].as_str().unwrap())).unwrap();
        let az = r["view_azimuth_deg"].as_f64().unwrap() as f32;
        let el = r["view_elevation_deg"].as_f64().unwrap() as f32;
        let shape = Shape::load(r["shape_id"].as_str().unwrap(), UpAxis::PosY)
            .unwrap()
            .posed(-az, el);
        let scene = match &shape {
            Shape::Mesh(m) => Some(matedit_datagen::accel::Scene::new(m)),
            Shape::Sphere => None,
        };
        let g = GBuffer::trace(&shape, scene.as_ref(), w);
        let mask = &ch["mask"];
        let differ = (0..w * w).filter(|&p| (mask[p] > 0.0) != (g.mask[p] > 0.0)).count();
        assert!(differ <= 2, "{}: {differ} mask pixels differ", r["id"]);
        let mut worst = 0.0_f32;
        for p in 0..w * w {
            if mask[p] > 0.0 && g.mask[p] > 0.0 {
                let d = (ch["normal.X"][p] - g.normal[p][0]).abs() + (ch["normal.Z"][p] - g.normal[p][2]).abs();
                worst = worst.max(d);
            }
        }
        assert!(worst < 1e-3 || differ > 0, "{}: normals differ by {worst}", r["id"]);
        // Radiance only where the object is, finite everywhere.
        for p in 0..w * w {
            assert!(ch["R"][p].is_finite() && ch["O.B"][p].is_finite());
            if mask[p] == 0.0 {
                assert_eq!(ch["R"][p], 0.0);
            }
        }
        let (ew, eh, _) = read_exr_channels(&out.join(r["files"]["env"].as_str().unwrap())).unwrap();
        assert_eq!((ew, eh), (32, 16));
    }
}

#[test]
fn verify_names_corrupt_files_and_leaks() {
    let d = scratch("tamper");
    let m = write(&d, "m.toml", &manifest(TEST_SPLIT, "ground_truth = \"measured\""));
    let out = d.join("out");
    run_to(&m, &out);
    let recs = index(&out);
    // Flip a byte of one image.
    let victim = out.join(recs[5]["files"]["image"].as_str().unwrap());
    let mut bytes = std::fs::read(&victim).unwrap();
    let k = bytes.len() / 2;
    bytes[k] ^= 0xff;
    std::fs::write(&victim, bytes).unwrap();
    let rep = verify(&out).unwrap();
    assert!(
        rep.problems
            .iter()
            .any(|p| p.contains(recs[5]["id"].as_str().unwrap()) && p.contains("checksum")),
        "{:?}",
        rep.problems
    );
    // A test sample that claims a training shape is a leak, named.
    let train_shape = recs.iter().find(|r| r["split"] == "train").unwrap()["shape_id"].clone();
    let mut lines: Vec<String> = std::fs::read_to_string(out.join("index.jsonl"))
        .unwrap()
        .lines()
        .map(String::from)
        .collect();
    let t = lines.iter().position(|l| l.contains("\"split\":\"test\"")).unwrap();
    let mut rec: Value = serde_json::from_str(&lines[t]).unwrap();
    rec["shape_id"] = train_shape.clone();
    lines[t] = rec.to_string();
    std::fs::write(out.join("index.jsonl"), lines.join("\n") + "\n").unwrap();
    let rep = verify(&out).unwrap();
    let leak = format!("split leak: shape {}", train_shape.as_str().unwrap());
    assert!(rep.problems.iter().any(|p| p.contains(&leak)), "{:?}", rep.problems);
}

#[test]
fn datasets_are_byte_identical_across_thread_counts() {
    let d = scratch("threads");
    for quality in ["zonal", "fast"] {
        let m = write(
            &d,
            &format!("{quality}.toml"),
            &manifest(TEST_SPLIT, &format!("quality = \"{quality}\"")),
        );
        let mut outs = Vec::new();
        for threads in [1, 2] {
            let out = d.join(format!("{quality}-{threads}"));
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| run_to(&m, &out));
            outs.push(out);
        }
        // The index holds every file's checksum, so equal indexes mean equal files.
        for f in ["index.jsonl", "dataset.json"] {
            assert_eq!(
                std::fs::read(outs[0].join(f)).unwrap(),
                std::fs::read(outs[1].join(f)).unwrap(),
                "{quality}: {f}"
            );
        }
    }
}

#[test]
fn bench_puts_the_reference_first_and_measures_every_option_against_it() {
    use matedit_datagen::dataset::{bench, materials};
    use matedit_physics::shading::Quality;
    let d = scratch("bench");
    let m = write(&d, "m.toml", &manifest(TEST_SPLIT, ""));
    let l = load(&m).unwrap();
    let mats = materials::prepare_all(
        &d.join("materials"),
        &l.plan.catalogue.materials,
        &materials::needed(&l.plan),
        l.plan.settings.ground_truth,
        &|| {},
    )
    .unwrap();
    let picks = bench::spread(&l.plan, 3);
    assert_eq!(picks.len(), 3);
    // The reference listed among the options is not rendered twice.
    let (fast, zonal) = (
        bench::Shading::Quality(Quality::Fast),
        bench::Shading::Quality(Quality::Zonal),
    );
    let rows = bench::bench(&l.plan, &mats, None, &picks, fast, &[zonal, fast]).unwrap();
    assert_eq!(rows.iter().map(|r| r.quality).collect::<Vec<_>>(), [fast, zonal]);
    // `measured` without the source BRDFs prepared is an error, not a silent fallback.
    let e = bench::bench(&l.plan, &mats, None, &picks, fast, &[bench::Shading::Measured]).unwrap_err();
    assert!(format!("{e:#}").contains("measured"), "{e:#}");
    // Against the source BRDFs, the fitted labels (exact path) err by the fit alone: not zero,
    // not large for the library's analytic materials.
    let measured = materials::prepare_all(
        &d.join("materials-measured"),
        &l.plan.catalogue.materials,
        &materials::needed(&l.plan),
        matedit_datagen::dataset::manifest::GroundTruth::Measured,
        &|| {},
    )
    .unwrap();
    let exact = bench::Shading::Quality(Quality::Exact);
    let fit = bench::bench(
        &l.plan,
        &mats,
        Some(&measured),
        &picks,
        bench::Shading::Measured,
        &[exact],
    )
    .unwrap();
    assert_eq!(fit[0].quality, bench::Shading::Measured);
    assert!(
        fit[1].max_rel_rmse > 1e-4 && fit[1].median_rel_rmse < 0.3,
        "{:?}",
        fit[1]
    );
    assert_eq!(rows[0].max_rel_rmse, 0.0);
    assert_eq!(rows[0].setup_materials, 0);
    let zonal = &rows[1];
    assert_eq!(zonal.per_sample_rel_rmse.len(), picks.len());
    assert!(zonal.setup_materials > 0, "zonal kernels are set up per material");
    // Zonal differs from fast only by its grid: small but not nothing.
    assert!(zonal.max_rel_rmse > 0.0 && zonal.max_rel_rmse < 0.01, "{zonal:?}");
    for r in &rows {
        assert!(r.samples_per_s.is_finite() && r.samples_per_s > 0.0, "{r:?}");
        assert!(r.bytes_per_sample > 1000.0, "{r:?}");
    }
}

#[test]
fn a_run_killed_at_random_moments_resumes_to_the_same_bytes() {
    let d = scratch("kill");
    // DSBRDF ground truth, per pixel, at 96² takes several seconds: the kills land mid-run.
    let text = manifest(TEST_SPLIT, "quality = \"fast\"").replace("resolution = 32", "resolution = 96");
    let m = write(&d, "m.toml", &text);
    let reference = d.join("reference");
    run_to(&m, &reference);
    let out = d.join("killed");
    // Kill at spread-out moments (deterministic pseudo-random, so a failure can be replayed).
    let mut state: u64 = 0x9E37_79B9_7F4A_7C15;
    let mut kills = 0;
    for _ in 0..3 {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        let ms = 150 + (state >> 33) % 700;
        let mut child = Command::new(datagen())
            .arg("run")
            .arg(&m)
            .arg("--out")
            .arg(&out)
            .spawn()
            .unwrap();
        std::thread::sleep(std::time::Duration::from_millis(ms));
        if child.try_wait().unwrap().is_none() {
            child.kill().unwrap(); // SIGKILL
            kills += 1;
        }
        child.wait().unwrap();
    }
    assert!(
        kills > 0 && !out.join("index.jsonl").exists(),
        "the run finished before the kills; the test proves nothing"
    );
    let status = Command::new(datagen())
        .arg("run")
        .arg(&m)
        .arg("--out")
        .arg(&out)
        .status()
        .unwrap();
    assert!(status.success());
    let status = Command::new(datagen()).arg("verify").arg(&out).status().unwrap();
    assert!(status.success());
    for f in ["index.jsonl", "dataset.json"] {
        assert_eq!(
            std::fs::read(reference.join(f)).unwrap(),
            std::fs::read(out.join(f)).unwrap(),
            "{f}"
        );
    }
    // No temporary shard is left behind.
    let leftovers: Vec<_> = std::fs::read_dir(out.join("shards"))
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().starts_with(".tmp"))
        .collect();
    assert!(leftovers.is_empty());
}

#[test]
fn workers_render_disjoint_parts_that_join_into_the_whole() {
    let d = scratch("workers");
    let m = write(&d, "m.toml", &manifest(TEST_SPLIT, "ground_truth = \"measured\""));
    let whole = d.join("whole");
    run_to(&m, &whole);
    let l = load(&m).unwrap();
    let parts: Vec<PathBuf> = (0..3).map(|i| d.join(format!("w{i}"))).collect();
    for (i, p) in parts.iter().enumerate() {
        run(
            &l,
            &RunOptions {
                out: Some(p.clone()),
                worker: Worker { index: i, count: 3 },
                progress: false,
            },
        )
        .unwrap();
        assert!(!p.join("index.jsonl").exists(), "a worker does not join");
    }
    let joined = parts[0].clone();
    matedit_datagen::dataset::store::join(&joined, &parts[1..], None).unwrap();
    assert!(verify(&joined).unwrap().ok());
    for f in ["index.jsonl", "dataset.json"] {
        assert_eq!(
            std::fs::read(whole.join(f)).unwrap(),
            std::fs::read(joined.join(f)).unwrap(),
            "{f}"
        );
    }
}

#[test]
fn every_recorded_sample_is_the_plans_description_of_it() {
    let d = scratch("spec");
    let m = write(&d, "m.toml", &manifest(TEST_SPLIT, "ground_truth = \"measured\""));
    let out = d.join("out");
    run_to(&m, &out);
    let l = load(&m).unwrap();
    let plan = &l.plan;
    let cat = &plan.catalogue;
    let recs = index(&out);
    let mut described = 0;
    for (s, split) in plan.splits.iter().enumerate() {
        for i in 0..split.samples {
            let spec = plan.sample(s, i);
            // A description is a pure function of the plan: asking again, in any order, is equal.
            assert_eq!(spec, plan.sample(s, i));
            let rec = recs.iter().find(|r| r["id"] == spec.id.as_str()).expect("recorded");
            assert_eq!(rec["split"], split.name.as_str());
            assert_eq!(rec["shape_id"], cat.shapes[spec.shape].id.as_str());
            assert_eq!(rec["env_id"], cat.envs[spec.env].id.as_str());
            assert_eq!(rec["env_rotation_deg"].as_f64(), Some(spec.env_rotation_deg));
            assert_eq!(rec["view_azimuth_deg"].as_f64(), Some(spec.view_azimuth_deg));
            assert_eq!(rec["view_elevation_deg"].as_f64(), Some(spec.view_elevation_deg));
            assert!((0.0..360.0).contains(&spec.env_rotation_deg));
            let ids = |v: &[usize]| v.iter().map(|&k| cat.materials[k].id.clone()).collect::<Vec<_>>();
            let strings = |v: &Value| -> Vec<String> {
                v.as_array()
                    .unwrap()
                    .iter()
                    .map(|x| x.as_str().unwrap().to_string())
                    .collect()
            };
            assert_eq!(strings(&rec["regions"]), spec.regions);
            assert_eq!(strings(&rec["material_ids"]), ids(&spec.materials));
            assert_eq!(strings(&rec["target_material_ids"]), ids(&spec.targets));
            // Per-region materials: one per region of the shape, all from the split, each target
            // another material of the split (the policy is `random` and every split has several).
            assert_eq!(spec.regions, cat.shapes[spec.shape].regions);
            assert_eq!(spec.materials.len(), spec.regions.len());
            for (&mi, &mt) in spec.materials.iter().zip(&spec.targets) {
                assert!(split.materials.contains(&mi) && split.materials.contains(&mt));
                assert_ne!(mi, mt);
            }
            described += 1;
        }
    }
    assert_eq!(described, recs.len());
    assert!(
        recs.iter().any(|r| r["regions"].as_array().unwrap().len() > 1),
        "the test needs multi-region shapes"
    );
}

#[test]
fn a_missing_folder_with_if_missing_procedural_is_replaced_and_noted() {
    let d = scratch("if-missing");
    let text = manifest(TEST_SPLIT, "").replace(
        "source = \"procedural\"\ncategory = \"car\"\ncount = 3",
        "source = \"folder\"\ncategory = \"car\"\npath = \"/nonexistent/cars\"\nif_missing = \"procedural\"\nfallback_count = 3",
    );
    let l = load(&write(&d, "m.toml", &text)).unwrap();
    let notes = &l.plan.catalogue.substitutions;
    assert!(notes.iter().any(|n| n.contains("/nonexistent/cars")), "{notes:?}");
    assert_eq!(
        l.plan.catalogue.shapes.iter().filter(|s| s.category == "car").count(),
        3
    );
}

/// Every dataset manifest the repository ships (`manifests/datasets/`, its experiments too)
/// resolves and plans on a clean checkout, or refuses naming the environment variable it needs
/// (real data that only exists outside the repository); none plans zero samples.
#[test]
fn every_shipped_dataset_manifest_plans_or_names_the_variable_it_needs() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("manifests/datasets");
    let mut files = Vec::new();
    for dir in [root.clone(), root.join("experiments")] {
        for e in std::fs::read_dir(&dir).unwrap() {
            let p = e.unwrap().path();
            if p.extension().is_some_and(|x| x == "toml") {
                files.push(p);
            }
        }
    }
    files.sort();
    assert!(files.len() >= 12, "{files:?}");
    let mut planned = 0;
    for f in &files {
        match load(f) {
            Ok(l) => {
                assert!(l.plan.samples() > 0, "{} plans no samples", f.display());
                planned += 1;
            }
            Err(e) => {
                let msg = format!("{e:#}");
                assert!(
                    msg.contains("environment variable") && msg.contains("is not set") && msg.contains(".toml:"),
                    "{}: {msg}",
                    f.display()
                );
            }
        }
    }
    assert!(planned >= 10, "only {planned} of {} planned", files.len());
}
