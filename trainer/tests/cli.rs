//! `trainer run` and `trainer eval` end to end on a tiny dataset rendered by datagen's library
//! (16² images, 4×8 environments, two-region cars and an OBJ monitor, DSBRDF material files):
//! a killed run resumes to the same loss sequence and metrics as an uninterrupted one, and
//! refusals name their cause.

use matedit_datagen::dataset::run::{RunOptions, Worker, load as load_manifest, run};
use matedit_physics::brdf::Dsbrdf;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

const DATASET: &str = r#"
[dataset]
name = "trainer-cli"
seed = 9
output = "unused"
shard_size = 4

[render]
resolution = 16
env_resolution = "4x8"
quality = "fast"

[views]
azimuths = 6
elevation_deg = 20.0
per_combination = 2

[multi_material]
mode = "per_region"

[[shapes]]
source = "procedural"
category = "car"
count = 3

[[shapes]]
source = "folder"
category = "monitor"
path = "objs"

[[materials]]
source = "dsbrdf"
path = "mats"

[[environments]]
source = "procedural"
family = "sunsky"
count = 1

[[splits]]
name = "train"
shapes = { car = 2, monitor = 1 }
materials = 3

[[splits]]
name = "test"
shapes = { car = 1 }
materials = 2
"#;

const OCTAHEDRON: &str = "v 1 0 0\nv -1 0 0\nv 0 1 0\nv 0 -1 0\nv 0 0 1\nv 0 0 -1\n\
f 1 3 5\nf 3 2 5\nf 2 4 5\nf 4 1 5\nf 3 1 6\nf 2 3 6\nf 4 2 6\nf 1 4 6\n";

/// A training manifest over `dataset`: two stages with frequent checkpoints.
fn training_manifest(dataset: &Path) -> String {
    format!(
        r#"
[run]
name = "cli"
seed = 4
output = "unused"

[model]
input_size = 16
env_height = 4
widths = {{ base_channels = 4, max_channels = 16, hidden = 32, normal_channels = 8 }}

[data]
dataset = "{}"
workers = 1

[[stages]]
name = "pretrain"
kind = "pretrain"
steps = 14
batch_size = 4
learning_rate = [[0, 1e-3], [8, 3e-4]]
checkpoint_every = 3

[[stages]]
name = "joint"
kind = "joint"
steps = 14
batch_size = 4
learning_rate = [[0, 1e-4]]
beta1 = 0.5
checkpoint_every = 4

[eval]
split = "test"
"#,
        dataset.display()
    )
}

fn root() -> PathBuf {
    std::env::temp_dir().join(format!("matedit-trainer-cli-{}", std::process::id()))
}

/// The dataset, rendered once per test process.
fn dataset() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let src = root().join("src");
        let _ = std::fs::remove_dir_all(root());
        std::fs::create_dir_all(src.join("mats")).unwrap();
        std::fs::create_dir_all(src.join("objs")).unwrap();
        std::fs::write(src.join("objs/octahedron.obj"), OCTAHEDRON).unwrap();
        let mats = [
            Dsbrdf::near_lambertian([0.8, 0.2, 0.1]),
            Dsbrdf::near_lambertian([0.1, 0.5, 0.7]),
            Dsbrdf::from_normalised(&(0..108).map(|i| 0.5 * (i as f64).sin()).collect::<Vec<_>>()).unwrap(),
            Dsbrdf::near_lambertian([0.4, 0.4, 0.4]),
            Dsbrdf::near_lambertian([0.9, 0.9, 0.2]),
        ];
        for (i, m) in mats.iter().enumerate() {
            std::fs::write(src.join(format!("mats/m{i}.dsbrdf.json")), m.to_json()).unwrap();
        }
        std::fs::write(src.join("m.toml"), DATASET).unwrap();
        let out = root().join("dataset");
        let l = load_manifest(&src.join("m.toml")).unwrap();
        let opts = RunOptions {
            out: Some(out.clone()),
            worker: Worker::ALL,
            progress: false,
        };
        run(&l, &opts).unwrap();
        out
    })
}

fn trainer() -> Command {
    Command::new(env!("CARGO_BIN_EXE_trainer"))
}

fn write_manifest(name: &str, text: &str) -> PathBuf {
    let p = root().join(name);
    std::fs::create_dir_all(root()).unwrap();
    std::fs::write(&p, text).unwrap();
    p
}

fn train(manifest: &Path, out: &Path, resume: bool) -> std::process::Output {
    let mut c = trainer();
    c.arg("run").arg(manifest).arg("--out").arg(out).arg("--quiet");
    if resume {
        c.arg("--resume");
    }
    c.output().unwrap()
}

fn metric_lines(out: &Path) -> Vec<String> {
    std::fs::read_to_string(out.join("metrics.jsonl"))
        .unwrap_or_default()
        .lines()
        .map(str::to_owned)
        .collect()
}

/// eval.json without the fields that name the output folder.
fn scores(out: &Path) -> Value {
    let mut v: Value = serde_json::from_str(&std::fs::read_to_string(out.join("eval.json")).unwrap()).unwrap();
    for c in v["checkpoints"].as_array_mut().unwrap() {
        c.as_object_mut().unwrap().remove("checkpoint");
    }
    v
}

#[test]
fn a_killed_run_resumes_to_the_same_losses_and_metrics() {
    let m = write_manifest("resume.toml", &training_manifest(dataset()));
    let whole = root().join("whole");
    let o = train(&m, &whole, false);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let want = metric_lines(&whole);
    assert_eq!(want.len(), 28, "one metrics line per step");
    for (i, l) in want.iter().enumerate() {
        let v: Value = serde_json::from_str(l).unwrap();
        assert_eq!(v["global_step"], i + 1);
        assert!(v["losses"]["total"].as_f64().is_some_and(f64::is_finite), "{l}");
    }
    assert!(whole.join("loss.png").is_file() && whole.join("eval.md").is_file());
    let want_scores = scores(&whole);
    assert_eq!(
        want_scores["samples"], 4,
        "every test sample scored (1 car × 2 materials × 2 views)"
    );

    // Kill at several points: mid pretraining, mid joint training, just past the stage end.
    for (k, kill_after) in [5usize, 19, 15].into_iter().enumerate() {
        let out = root().join(format!("killed-{k}"));
        let mut child = trainer()
            .arg("run")
            .arg(&m)
            .arg("--out")
            .arg(&out)
            .arg("--quiet")
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let t0 = Instant::now();
        while metric_lines(&out).len() < kill_after && t0.elapsed() < Duration::from_secs(120) {
            if child.try_wait().unwrap().is_some() {
                break;
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        let running = child.try_wait().unwrap().is_none();
        let _ = child.kill(); // SIGKILL
        let _ = child.wait();
        let done = metric_lines(&out).len();
        assert!(
            running && done < want.len(),
            "kill {k} came too late ({done} steps written)"
        );
        // What a kill inside a checkpoint write leaves behind.
        std::fs::create_dir_all(out.join("checkpoints/.tmp-joint-step-0000004-999999")).unwrap();
        std::fs::create_dir_all(out.join("checkpoints/.old-pretrain-999999")).unwrap();
        let o = train(&m, &out, true);
        assert!(o.status.success(), "resume {k}: {}", String::from_utf8_lossy(&o.stderr));
        assert_eq!(
            metric_lines(&out),
            want,
            "kill {k} after {kill_after} steps: loss sequence differs"
        );
        assert_eq!(scores(&out), want_scores, "kill {k}: metrics differ");
        let stray: Vec<_> = std::fs::read_dir(out.join("checkpoints"))
            .unwrap()
            .filter_map(|e| e.ok())
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| n.starts_with(".tmp") || n.starts_with(".old"))
            .collect();
        assert!(stray.is_empty(), "temporary checkpoints left: {stray:?}");
    }

    // A finished run is not overwritten, and a changed manifest is not resumed.
    let o = train(&m, &whole, false);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && e.contains("--resume"), "{e}");
    let changed = write_manifest(
        "changed.toml",
        &training_manifest(dataset()).replace("seed = 4", "seed = 5"),
    );
    let o = train(&changed, &whole, true);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && e.contains("manifest changed"), "{e}");

    // `trainer eval` on the stage checkpoints writes the same scores as the run's evaluation.
    let metrics = root().join("eval-again.json");
    let o = trainer()
        .arg("eval")
        .arg("--checkpoint")
        .arg(whole.join("checkpoints/pretrain"))
        .arg("--checkpoint")
        .arg(whole.join("checkpoints/joint"))
        .arg("--data")
        .arg(dataset())
        .arg("--out")
        .arg(&metrics)
        .arg("--quiet")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let md = std::fs::read_to_string(metrics.with_extension("md")).unwrap();
    for table in [
        "Table 1",
        "Table 2",
        "Table 3",
        "O' = I",
        "mean material",
        "| pretrain |",
        "| joint |",
    ] {
        assert!(md.contains(table), "{table} missing from\n{md}");
    }
    let mut again: Value = serde_json::from_str(&std::fs::read_to_string(&metrics).unwrap()).unwrap();
    for c in again["checkpoints"].as_array_mut().unwrap() {
        c.as_object_mut().unwrap().remove("checkpoint");
    }
    assert_eq!(again, want_scores);
}

#[test]
fn bad_manifests_name_file_line_and_field() {
    let good = training_manifest(dataset());
    let cases = [
        ("widths = {", "widths = \"huge\" #", "model.widths"),
        ("input_size = 16", "input_size = 24", "model.input_size"),
        (
            "kind = \"joint\"",
            "kind = \"joint\"\nrender_with = { normals = \"truth\", material = \"truth\", illumination = \"truth\" }",
            "render_with",
        ),
        (
            "learning_rate = [[0, 1e-4]]",
            "learning_rate = [[5, 1e-4]]",
            "learning_rate",
        ),
        ("workers = 1", "workers = 1\nvgg16_weights = \"x\"", "unknown field"),
        (
            "[data]",
            "[loss]\nvgg16 = \"/nonexistent/vgg16.pth\"\n\n[data]",
            "loss.vgg16",
        ),
    ];
    for (from, to, field) in cases {
        assert!(good.contains(from), "{from}");
        let p = write_manifest("bad.toml", &good.replacen(from, to, 1));
        let o = train(&p, &root().join("bad-out"), false);
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{to}: accepted");
        assert!(e.contains("bad.toml") && e.contains(field), "{to}: {e}");
        if field != "unknown field" {
            assert!(e.contains(":"), "no line in {e}");
        }
    }
    // A dataset of another size is named with both sizes.
    let p = write_manifest("size.toml", &good.replace("input_size = 16", "input_size = 32"));
    let o = train(&p, &root().join("size-out"), false);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && e.contains("16²") && e.contains("input_size = 32"),
        "{e}"
    );
}
