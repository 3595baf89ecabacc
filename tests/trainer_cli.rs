//! `trainer run` and `trainer eval` end to end on a tiny dataset rendered by datagen's library
//! (16² images, 4×8 environments, two-region cars and an OBJ monitor, DSBRDF material files):
//! a killed or signalled run resumes to the same loss sequence and metrics as an uninterrupted one, and
//! refusals name their cause.

use matedit_fixtures::{OCTAHEDRON, Sources, five_materials, render_dataset};
use matedit_trainer::alloc::PeakAlloc;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// Counts heap bytes, as the `trainer` binary's allocator does, for `trainer bench`'s peak memory.
#[global_allocator]
static ALLOC: PeakAlloc = PeakAlloc::new();

/// Set in the environment of a child process: this binary is then the `trainer` command
/// (`matedit_trainer::cli::main`, exactly what the binary's `main` runs). A workspace test cannot
/// name another package's binary, and the trainer's own tests must not build the factory that
/// renders their datasets, so the test binary runs the command line itself.
/// (libtest-mimic runs the tests listed in `main`: a test left out of the list is a dead
/// function, which `clippy -D warnings` refuses.)
const AS_TRAINER: &str = "MATEDIT_TEST_AS_TRAINER";

fn main() -> ExitCode {
    if std::env::var_os(AS_TRAINER).is_some() {
        // SAFETY: no other thread exists yet. Nothing the trainer starts inherits the switch.
        unsafe { std::env::remove_var(AS_TRAINER) };
        return matedit_trainer::cli::main(Some(&ALLOC));
    }
    let args = libtest_mimic::Arguments::from_args();
    let tests: [(&str, fn()); 9] = [
        (
            "the_perceptual_loss_is_said_and_a_resume_keeps_it",
            the_perceptual_loss_is_said_and_a_resume_keeps_it,
        ),
        (
            "a_killed_run_resumes_to_the_same_losses_and_metrics",
            a_killed_run_resumes_to_the_same_losses_and_metrics,
        ),
        (
            "bad_manifests_name_file_line_and_field",
            bad_manifests_name_file_line_and_field,
        ),
        (
            "stages_can_branch_from_an_earlier_stage",
            stages_can_branch_from_an_earlier_stage,
        ),
        (
            "bench_prints_both_layers_and_refuses_impossible_configurations",
            bench_prints_both_layers_and_refuses_impossible_configurations,
        ),
        (
            "a_truncated_shard_file_stops_the_run_naming_it_or_is_skipped_and_reported",
            a_truncated_shard_file_stops_the_run_naming_it_or_is_skipped_and_reported,
        ),
        (
            "a_run_can_start_from_another_runs_checkpoint",
            a_run_can_start_from_another_runs_checkpoint,
        ),
        (
            "eval_scores_only_the_asked_categories",
            eval_scores_only_the_asked_categories,
        ),
        (
            "baseline_1_resumes_bit_identically_and_table_3_has_every_method",
            baseline_1_resumes_bit_identically_and_table_3_has_every_method,
        ),
    ];
    let trials = tests
        .into_iter()
        .map(|(name, f)| {
            libtest_mimic::Trial::test(name, move || {
                f();
                Ok(())
            })
        })
        .collect();
    libtest_mimic::run(&args, trials).exit_code()
}

const DATASET: &str = include_str!("../tests/fixtures/manifests/trainer-cli.toml");

/// A training manifest over `dataset`: two stages with frequent checkpoints.
fn training_manifest(dataset: &Path) -> String {
    format!(
        r#"{}
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
        run_head(dataset, "cli", 4)
    )
}

/// The `[run]`, `[model]` and `[data]` sections every test manifest shares.
fn run_head(dataset: &Path, name: &str, seed: u64) -> String {
    format!(
        r#"
[run]
name = "{name}"
seed = {seed}
output = "unused"

[model]
input_size = 16
env_height = 4
widths = {{ base_channels = 4, max_channels = 16, hidden = 32, normal_channels = 8 }}

[data]
dataset = "{}"
workers = 1
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
        let _ = std::fs::remove_dir_all(root());
        render("m.toml", DATASET, "dataset")
    })
}

/// Renders dataset manifest `text`, written as `src/name` beside the five materials and the
/// octahedron, into `root()/out`.
fn render(name: &str, text: &str, out: &str) -> PathBuf {
    let materials = five_materials();
    let sources = Sources {
        manifest: text,
        materials: &materials,
        objs: &[("octahedron.obj", OCTAHEDRON)],
    };
    render_dataset(&root(), name, &sources, out)
}

fn trainer() -> Command {
    let mut c = Command::new(std::env::current_exe().expect("the test binary's path"));
    c.env(AS_TRAINER, "1");
    c
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

/// The full-pipeline scores of one stage in an eval.json.
fn network_scores(scores: &Value, stage: &str) -> Value {
    scores["checkpoints"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["name"] == stage)
        .map(|c| c["network"].clone())
        .unwrap_or_else(|| panic!("no stage {stage} in the scores"))
}

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

    // A scheduler's notice (SIGTERM, SIGUSR1) mid-stage and right at a checkpoint: the run
    // writes a checkpoint, exits with 75 (what scripts/train_slurm.sh requeues on) and resumes
    // to the same losses and metrics. Without a terminal it logs plain progress lines.
    for (k, (signal, after)) in [("TERM", 6usize), ("USR1", 16), ("TERM", 20)].into_iter().enumerate() {
        let out = root().join(format!("signalled-{k}"));
        let child = trainer()
            .arg("run")
            .arg(&m)
            .arg("--out")
            .arg(&out)
            .env("MATEDIT_PROGRESS_SECS", "0")
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let t0 = Instant::now();
        while metric_lines(&out).len() < after && t0.elapsed() < Duration::from_secs(120) {
            std::thread::sleep(Duration::from_millis(2));
        }
        let sent = Command::new("kill")
            .arg(format!("-{signal}"))
            .arg(child.id().to_string())
            .status()
            .unwrap();
        assert!(sent.success());
        let o = child.wait_with_output().unwrap();
        let e = String::from_utf8_lossy(&o.stderr);
        assert_eq!(
            o.status.code(),
            Some(i32::from(matedit_trainer::cli::EXIT_PREEMPTED)),
            "SIG{signal} after {after} steps: {e}"
        );
        assert!(e.contains("continue with --resume"), "{e}");
        assert!(
            e.contains("pretrain steps: ") && e.contains(" elapsed, ETA "),
            "no progress line: {e}"
        );
        let written = metric_lines(&out).len();
        assert!(written < want.len(), "SIG{signal} came too late ({written} steps)");
        let o = train(&m, &out, true);
        assert!(o.status.success(), "resume {k}: {}", String::from_utf8_lossy(&o.stderr));
        assert_eq!(
            metric_lines(&out),
            want,
            "SIG{signal} after {after} steps: loss sequence differs"
        );
        assert_eq!(scores(&out), want_scores, "SIG{signal}: metrics differ");
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
            "kind = \"joint\"",
            "kind = \"joint\"\nrender_with = { normals = \"detached\", material = \"truth\", illumination = \"truth\" }",
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

fn stages_can_branch_from_an_earlier_stage() {
    // C starts from A's weights with a learning rate too small to move an f32 weight (Adam's step
    // is lr-sized), so it must score exactly like A, and unlike B, which trained on from A.
    let text = format!(
        r#"
[run]
name = "branch"
seed = 4
output = "unused"

[model]
input_size = 16
env_height = 4
widths = {{ base_channels = 4, max_channels = 16, hidden = 32, normal_channels = 8, dropout = 0.0 }}

[data]
dataset = "{}"
workers = 0

[[stages]]
name = "a"
kind = "pretrain"
steps = 3
batch_size = 4
learning_rate = [[0, 1e-3]]

[[stages]]
name = "b"
kind = "pretrain"
steps = 3
batch_size = 4
learning_rate = [[0, 1e-2]]

[[stages]]
name = "c"
kind = "pretrain"
from = "a"
steps = 2
batch_size = 4
learning_rate = [[0, 1e-30]]
"#,
        dataset().display()
    );
    let m = write_manifest("branch.toml", &text);
    let out = root().join("branch");
    let o = train(&m, &out, false);
    let log = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{log}");
    assert!(
        log.contains("perceptual loss: fallback") && log.contains("no VGG16 weights"),
        "the fallback is announced even with --quiet: {log}"
    );
    let s = scores(&out);
    assert_eq!(network_scores(&s, "c"), network_scores(&s, "a"));
    assert_ne!(network_scores(&s, "b"), network_scores(&s, "a"));
    let bad = write_manifest("branch-bad.toml", &text.replace("from = \"a\"", "from = \"z\""));
    let o = train(&bad, &root().join("branch-bad"), false);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && e.contains("stages[2].from") && e.contains("branch-bad.toml:"),
        "{e}"
    );
}

fn bench_prints_both_layers_and_refuses_impossible_configurations() {
    let o = trainer()
        .args([
            "bench",
            "--batch",
            "1",
            "--size",
            "16",
            "--runs",
            "1",
            "--train",
            "cpu-small:16:2",
        ])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for line in [
        "fused",
        "tensor reference",
        "faster",
        "less peak memory",
        "images/s",
        "% shaded",
    ] {
        assert!(text.contains(line), "{line:?} missing from {text}");
    }
    // A training manifest's stage on its own dataset, as `trainer run` steps it: it says what
    // it timed, and the warmed-up network shades most of the object (an untrained one does not).
    let m = write_manifest("bench.toml", &training_manifest(dataset()));
    // The smallest layer measurement, no spheres, and `extra`.
    let bench_manifest = |extra: &[&str]| {
        trainer()
            .args(["bench", "--batch", "1", "--size", "16", "--runs", "1", "--no-reference"])
            .args(["--train", ""])
            .args(["--manifest".as_ref(), m.as_os_str()])
            .args(extra)
            .output()
            .unwrap()
    };
    let o = bench_manifest(&["--steps", "2"]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for line in [
        "stage \"joint\"",
        "batch 4",
        "loss terms on: normal, material, perceptual",
        "object pixels/image",
    ] {
        assert!(text.contains(line), "{line:?} missing from {text}");
    }
    let shaded: f64 = text
        .split("% shaded")
        .next()
        .and_then(|t| t.rsplit(", ").next())
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or_else(|| panic!("no shaded fraction in {text}"));
    assert!(shaded >= 90.0, "{text}");
    let o = bench_manifest(&["--stage", "nope"]);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && e.contains("no stage named \"nope\"") && e.contains("pretrain, joint"),
        "{e}"
    );
    let o = trainer()
        .args([
            "bench",
            "--batch",
            "1",
            "--size",
            "16",
            "--no-reference",
            "--train",
            "cpu-small:20:8",
        ])
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && e.contains("cpu-small:20:8") && e.contains("power of two"),
        "{e}"
    );
    assert!(!String::from_utf8_lossy(&o.stdout).contains("tensor reference"));
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let target = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &target);
        } else {
            std::fs::copy(e.path(), &target).unwrap();
        }
    }
}

fn a_truncated_shard_file_stops_the_run_naming_it_or_is_skipped_and_reported() {
    let ds = root().join("corrupt-dataset");
    let _ = std::fs::remove_dir_all(&ds);
    copy_dir(dataset(), &ds);
    // Truncate the image file of the first training sample.
    let index = std::fs::read_to_string(ds.join("index.jsonl")).unwrap();
    let first: Value = index
        .lines()
        .map(|l| serde_json::from_str::<Value>(l).unwrap())
        .find(|v| v["split"] == "train")
        .unwrap();
    let rel = first["files"]["image"].as_str().unwrap().to_owned();
    let bytes = std::fs::read(ds.join(&rel)).unwrap();
    std::fs::write(ds.join(&rel), &bytes[..bytes.len() / 2]).unwrap();
    let name = Path::new(&rel).file_name().unwrap().to_string_lossy().into_owned();

    let text = training_manifest(&ds);
    let stop = write_manifest("corrupt-stop.toml", &text);
    let o = train(&stop, &root().join("corrupt-stop"), false);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && e.contains(&name),
        "the run stops naming {name}: {e}"
    );

    let skip = write_manifest(
        "corrupt-skip.toml",
        &text.replace("workers = 1", "workers = 1\non_corrupt = \"skip\""),
    );
    let out = root().join("corrupt-skip");
    let o = train(&skip, &out, false);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{e}");
    assert!(
        e.contains("skipped corrupt sample") && e.contains(&name),
        "the skip is reported: {e}"
    );
    assert_eq!(metric_lines(&out).len(), 28, "every step still ran");
}

fn a_run_can_start_from_another_runs_checkpoint() {
    // B starts from A's final weights with a learning rate too small to move an f32 weight, so
    // it must score exactly like A's last stage; a network of another shape is refused.
    let base = training_manifest(dataset());
    let a_out = root().join("init-a");
    let a = write_manifest("init-a.toml", &base);
    let o = train(&a, &a_out, false);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let from = a_out.join("checkpoints/joint");
    let finetune = |widths: &str| {
        format!(
            r#"
[run]
name = "init-b"
seed = 8
output = "unused"
init_from = "{}"

[model]
input_size = 16
env_height = 4
widths = {widths}

[data]
dataset = "{}"
workers = 1

[[stages]]
name = "finetune"
kind = "joint"
steps = 2
batch_size = 4
learning_rate = [[0, 1e-30]]
"#,
            from.display(),
            dataset().display()
        )
    };
    let b_out = root().join("init-b");
    let b = write_manifest(
        "init-b.toml",
        &finetune("{ base_channels = 4, max_channels = 16, hidden = 32, normal_channels = 8, dropout = 0.0 }"),
    );
    let o = train(&b, &b_out, false);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(
        network_scores(&scores(&b_out), "finetune"),
        network_scores(&scores(&a_out), "joint")
    );

    let other = write_manifest(
        "init-other.toml",
        &finetune("{ base_channels = 4, max_channels = 16, hidden = 48, normal_channels = 8 }"),
    );
    let o = train(&other, &root().join("init-other"), false);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && e.contains("another shape"), "{e}");
    let missing = write_manifest(
        "init-missing.toml",
        &finetune("\"cpu-small\"").replace(&from.display().to_string(), "/nonexistent/ckpt"),
    );
    let o = train(&missing, &root().join("init-missing"), false);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && e.contains("run.init_from") && e.contains("init-missing.toml:"),
        "{e}"
    );
}

fn eval_scores_only_the_asked_categories() {
    let text = training_manifest(dataset()).replace("steps = 14", "steps = 2");
    let m = write_manifest("categories.toml", &text);
    let out = root().join("categories");
    let o = train(&m, &out, false);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let eval = |split: &str, cats: &[&str], name: &str| {
        let metrics = root().join(name);
        let mut c = trainer();
        c.arg("eval")
            .arg("--checkpoint")
            .arg(out.join("checkpoints/joint"))
            .arg("--data")
            .arg(dataset())
            .args(["--split", split, "--quiet", "--sheet", "0"])
            .arg("--out")
            .arg(&metrics);
        for cat in cats {
            c.args(["--category", cat]);
        }
        let o = c.output().unwrap();
        (o, metrics)
    };
    let index = std::fs::read_to_string(dataset().join("index.jsonl")).unwrap();
    let count = |split: &str, cat: &str| {
        index
            .lines()
            .map(|l| serde_json::from_str::<Value>(l).unwrap())
            .filter(|v| v["split"] == split && v["category"] == cat)
            .count()
    };
    let (o, metrics) = eval("train", &["monitor"], "monitors.json");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: Value = serde_json::from_str(&std::fs::read_to_string(&metrics).unwrap()).unwrap();
    assert_eq!(v["samples"], count("train", "monitor"));
    assert!(count("train", "monitor") > 0 && count("train", "car") > 0);
    assert_eq!(v["categories"], serde_json::json!(["monitor"]));
    let md = std::fs::read_to_string(metrics.with_extension("md")).unwrap();
    assert!(md.contains("categories monitor"), "{md}");
    let (o, _) = eval("test", &["monitor"], "none.json");
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && e.contains("no samples of category monitor"),
        "{e}"
    );
}

/// The tiny dataset with one material per object (Baseline 1 edits single-material objects),
/// rendered once per test process.
fn single_material_dataset() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        dataset();
        let text = DATASET.replace("[multi_material]\nmode = \"per_region\"\n", "");
        assert_ne!(text, DATASET);
        render("single.toml", &text, "dataset-single")
    })
}

fn one_stage_manifest(dataset: &Path, name: &str, kind: &str, steps: usize) -> String {
    format!(
        r#"{}
[[stages]]
name = "{name}"
kind = "{kind}"
steps = {steps}
batch_size = 4
learning_rate = [[0, 2e-3]]
checkpoint_every = 3
"#,
        run_head(dataset, name, 6)
    )
}

/// A VGG16 file in torchvision's layout (conv1_1 … conv4_3, zero weights), written as
/// safetensors from its specification: a little-endian u64 header length, the JSON header, the data.
fn zero_vgg16(path: &Path) {
    let mut header = serde_json::Map::new();
    let (mut offset, mut cin) = (0usize, 3usize);
    let indices = [0, 2, 5, 7, 10, 12, 14, 17, 19, 21];
    let outs = [64, 64, 128, 128, 256, 256, 256, 512, 512, 512];
    for (idx, cout) in indices.into_iter().zip(outs) {
        for (name, shape) in [("weight", vec![cout, cin, 3, 3]), ("bias", vec![cout])] {
            let len = 4 * shape.iter().product::<usize>();
            header.insert(
                format!("features.{idx}.{name}"),
                serde_json::json!({"dtype": "F32", "shape": shape, "data_offsets": [offset, offset + len]}),
            );
            offset += len;
        }
        cin = cout;
    }
    header.insert("__metadata__".into(), serde_json::json!({"preprocessing": "caffe"}));
    let mut h = serde_json::to_vec(&Value::Object(header)).unwrap();
    while !h.len().is_multiple_of(8) {
        h.push(b' ');
    }
    let mut bytes = (h.len() as u64).to_le_bytes().to_vec();
    bytes.extend(h);
    bytes.resize(bytes.len() + offset, 0);
    std::fs::write(path, bytes).unwrap();
}

/// `[loss].vgg16 = "${VAR:-}"` is the fallback while VAR is unset, and the log says so; a run
/// trained with one perceptual loss is not resumed with the other, and the refusal says which.
fn the_perceptual_loss_is_said_and_a_resume_keeps_it() {
    let m = write_manifest(
        "vgg.toml",
        &(one_stage_manifest(dataset(), "vgg", "joint", 2) + "\n[loss]\nvgg16 = \"${MATEDIT_TEST_VGG16:-}\"\n"),
    );
    let weights = root().join("vgg16-zero.safetensors");
    zero_vgg16(&weights);
    let run = |out: &Path, vgg: bool, resume: bool| {
        let mut c = trainer();
        c.arg("run").arg(&m).arg("--out").arg(out).arg("--quiet");
        if resume {
            c.arg("--resume");
        }
        if vgg {
            c.env("MATEDIT_TEST_VGG16", &weights);
        } else {
            c.env_remove("MATEDIT_TEST_VGG16");
        }
        let o = c.output().unwrap();
        (o.status.success(), String::from_utf8_lossy(&o.stderr).into_owned())
    };
    let (fallback, vgg) = (root().join("run-fallback"), root().join("run-vgg"));
    let (ok, e) = run(&fallback, false, false);
    assert!(
        ok && e.contains("perceptual loss: fallback") && e.contains("expands to no path"),
        "{e}"
    );
    let (ok, e) = run(&vgg, true, false);
    assert!(ok && e.contains("perceptual loss: VGG16") && e.contains("Caffe"), "{e}");
    let state = std::fs::read_to_string(vgg.join("checkpoints/vgg/state.json")).unwrap();
    assert!(state.contains("\"perceptual\": \"vgg16 blake3:"), "{state}");
    let state = std::fs::read_to_string(fallback.join("checkpoints/vgg/state.json")).unwrap();
    assert!(
        !state.contains("perceptual"),
        "a fallback run's checkpoint keeps its bytes: {state}"
    );
    // Each resumed with the other loss: refused, naming both.
    let (ok, e) = run(&fallback, true, true);
    assert!(
        !ok && e.contains("perceptual loss the fallback") && e.contains("vgg16 blake3:"),
        "{e}"
    );
    let (ok, e) = run(&vgg, false, true);
    assert!(!ok && e.contains("the manifest now gives the fallback"), "{e}");
    // With its own loss, a finished run resumes (to its evaluation).
    let (ok, e) = run(&vgg, true, true);
    assert!(ok, "{e}");
}

fn total_losses(out: &Path) -> Vec<f64> {
    metric_lines(out)
        .iter()
        .map(|l| {
            serde_json::from_str::<Value>(l).unwrap()["losses"]["total"]
                .as_f64()
                .unwrap()
        })
        .collect()
}

fn baseline_1_resumes_bit_identically_and_table_3_has_every_method() {
    let ds = single_material_dataset();
    let m = write_manifest("b1.toml", &one_stage_manifest(ds, "b1", "encoder-decoder", 15));
    let whole = root().join("b1-whole");
    let o = train(&m, &whole, false);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let want = metric_lines(&whole);
    let loss = total_losses(&whole);
    assert_eq!(loss.len(), 15);
    // (That the loss falls is tested on a fixed batch, where batch-to-batch noise cannot hide
    // it: train/tests.rs.)
    assert!(loss.iter().all(|l| l.is_finite() && *l > 0.0), "{loss:?}");
    let want_scores = scores(&whole);
    let b1 = network_scores(&want_scores, "b1");
    assert!(b1["images"]["O'"]["l2"]["count"].as_u64() == Some(4), "{b1}");
    assert!(b1["images"].get("I'").is_none(), "Baseline 1 renders no I': {b1}");

    // Killed mid-run and resumed: the same losses and scores, bit for bit.
    let out = root().join("b1-killed");
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
    while metric_lines(&out).len() < 7 && t0.elapsed() < Duration::from_secs(120) {
        if child.try_wait().unwrap().is_some() {
            break;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    let running = child.try_wait().unwrap().is_none();
    let _ = child.kill();
    let _ = child.wait();
    assert!(
        running && metric_lines(&out).len() < want.len(),
        "the kill came too late"
    );
    let o = train(&m, &out, true);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(metric_lines(&out), want, "the resumed loss sequence differs");
    assert_eq!(scores(&out), want_scores, "the resumed scores differ");

    // Baseline 2 (the pretrain stage: three networks, L2 losses only) falls too.
    let m2 = write_manifest("b2.toml", &one_stage_manifest(ds, "pretrain", "pretrain", 9));
    let b2 = root().join("b2");
    let o = train(&m2, &b2, false);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(total_losses(&b2).iter().all(|l| l.is_finite()));

    // Table 3 with every method, labelled.
    let json = root().join("table3.json");
    let o = trainer()
        .arg("eval")
        .arg("--checkpoint")
        .arg(format!("Baseline 1={}", whole.join("checkpoints/b1").display()))
        .arg("--checkpoint")
        .arg(format!("Baseline 2={}", b2.join("checkpoints/pretrain").display()))
        .args(["--eq6", "--eq6-iterations", "1", "--lombardi", "--lombardi-rounds", "1"])
        .args(["--lombardi-iterations", "2", "--sheet", "2", "--quiet", "--data"])
        .arg(ds)
        .arg("--out")
        .arg(&json)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let md = std::fs::read_to_string(json.with_extension("md")).unwrap();
    assert!(
        md.contains("| O' = I | mean material (n', L' of Baseline 2) | Lombardi (true n) | Baseline 1 | Baseline 2 | Baseline 2 + Eq. 6 |"),
        "{md}"
    );
    let v: Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let l = &v["lombardi"]["metrics"]["images"]["O'"];
    assert_eq!(l["l2"]["count"], 4, "{v}");
    assert!(v["lombardi"]["energy"][1].as_f64() <= v["lombardi"]["energy"][0].as_f64());
    // Every method's O' side by side: I, O, then one column per method of Table 3.
    let sheet = image::open(root().join("table3-methods.png")).unwrap();
    assert_eq!((sheet.width(), sheet.height() > 2 * 160), (6 * 160, true));
    // Eq. 6 is not Baseline 1's (it has no n', m', L' to refine).
    assert!(v["checkpoints"][0]["eq6"].is_null() && !v["checkpoints"][1]["eq6"].is_null());

    // A manifest that mixes Baseline 1 with the network's stages is refused, naming the field.
    let mixed = write_manifest(
        "mixed.toml",
        &format!(
            "{}\n[[stages]]\nname = \"p\"\nkind = \"pretrain\"\nsteps = 1\nbatch_size = 4\nlearning_rate = [[0, 1e-3]]\n",
            one_stage_manifest(ds, "b1", "encoder-decoder", 1)
        ),
    );
    let o = train(&mixed, &root().join("mixed"), false);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && e.contains("mixed.toml") && e.contains("Baseline 1"),
        "{e}"
    );
}
