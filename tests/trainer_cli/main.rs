//! `trainer run` and `trainer eval` end to end on a tiny dataset rendered by datagen's library
//! (16² images, 4×8 environments, two-region cars and an OBJ monitor, DSBRDF material files):
//! a killed or signalled run resumes to the same loss sequence and metrics as an uninterrupted one,
//! validation while training keeps the best checkpoint across a kill, and refusals name their cause.

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

mod eval;
mod refusals;
mod resume;
mod validation;
use eval::*;
use refusals::*;
use resume::*;
use validation::*;

fn main() -> ExitCode {
    if std::env::var_os(AS_TRAINER).is_some() {
        // SAFETY: no other thread exists yet. Nothing the trainer starts inherits the switch.
        unsafe { std::env::remove_var(AS_TRAINER) };
        return matedit_trainer::cli::main(Some(&ALLOC));
    }
    let args = libtest_mimic::Arguments::from_args();
    let tests: [(&str, fn()); 11] = [
        (
            "a_validated_run_keeps_its_best_checkpoint_across_a_kill",
            a_validated_run_keeps_its_best_checkpoint_across_a_kill,
        ),
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
            "dump_batch_writes_the_batch_and_refuses_what_the_dataset_has_not",
            dump_batch_writes_the_batch_and_refuses_what_the_dataset_has_not,
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
    let conclusion = libtest_mimic::run(&args, trials);
    // The tests share one folder (its dataset is rendered once): removed after a passing run, kept
    // to look into after a failing one.
    if conclusion.has_failed() {
        eprintln!("the failing run's folder is kept: {}", root().display());
    } else {
        let _ = std::fs::remove_dir_all(root());
    }
    conclusion.exit_code()
}

const DATASET: &str = include_str!("../fixtures/manifests/trainer-cli.toml");

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

/// Starts `trainer run manifest --out out`, SIGKILLs it once `metrics.jsonl` holds `lines`
/// lines, and says whether it was still running then (a kill that came after the run ended
/// proves nothing).
fn run_killed_after(manifest: &Path, out: &Path, lines: usize) -> bool {
    let mut child = trainer()
        .arg("run")
        .arg(manifest)
        .arg("--out")
        .arg(out)
        .arg("--quiet")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    while metric_lines(out).len() < lines && t0.elapsed() < Duration::from_secs(120) {
        if child.try_wait().unwrap().is_some() {
            break;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    let running = child.try_wait().unwrap().is_none();
    let _ = child.kill(); // SIGKILL
    let _ = child.wait();
    running
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
