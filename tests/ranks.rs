//! `trainer run` as several MPI ranks (`--features mpi`) against one process, on the dataset of
//! `tests/trainer_cli/` (16² images; two-region cars and a one-region monitor, so that a rank's
//! part of a batch can hold fewer regions than the batch).
//!
//! The MPI build is a separate binary (`cargo build --release -p matedit-trainer --features
//! mpi`), named by `MATEDIT_MPI_TRAINER`; `mpirun` (OpenMPI) must be on the PATH. Without them
//! the tests say so and pass, unless `MATEDIT_REQUIRE_MPI=1` (CI sets it where it installed
//! OpenMPI). The one-process reference is the default build's command line, run by this test
//! binary itself (see `AS_TRAINER`).
//!
//! **Tolerance.** W ranks compute the same sums as one process in another order: each rank
//! sums its own samples' terms (a loss's numerator, a weight's gradient over its samples),
//! then the ranks' sums are added. Two f32 sums of the same n terms in different orders differ
//! by at most about 2·n·u·Σ|x| (u = 2⁻²⁴), and at the sizes here (n ≤ 4 samples × 16² × 3
//! channels) by about √n·u ≈ 3·10⁻⁶ relative in practice. Adam divides each update by the
//! root of the gradient's second moment, so a relative change ε of a gradient moves that
//! update by about ε·lr; over the runs here (28 steps, lr ≤ 1e-3) that bounds the weights'
//! difference far below 10⁻⁴ unless the dynamics amplify it. The tests require every logged
//! loss term within 1e-4 relative (1e-9 absolute for terms that are 0) and every weight
//! within 1e-4 absolute, and print the worst differences they saw.

use matedit_fixtures::{OCTAHEDRON, Sources, five_materials, render_dataset};
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::sync::{Mutex, OnceLock};
use std::time::{Duration, Instant};

const AS_TRAINER: &str = "MATEDIT_TEST_AS_TRAINER";
const DATASET: &str = include_str!("fixtures/manifests/trainer-cli.toml");
const LOSS_TOLERANCE: f64 = 1e-4;
const WEIGHT_TOLERANCE: f32 = 1e-4;

/// One MPI job at a time: each takes the machine's cores.
static SERIAL: Mutex<()> = Mutex::new(());

fn main() -> std::process::ExitCode {
    if std::env::var_os(AS_TRAINER).is_some() {
        // SAFETY: no other thread exists yet. Nothing the trainer starts inherits the switch.
        unsafe { std::env::remove_var(AS_TRAINER) };
        return matedit_trainer::cli::main(None);
    }
    let args = libtest_mimic::Arguments::from_args();
    let tests: [(&str, fn()); 5] = [
        (
            "one_rank_is_todays_run_and_two_ranks_equal_it_and_repeat_bit_identically",
            one_rank_is_todays_run_and_two_ranks_equal_it_and_repeat_bit_identically,
        ),
        (
            "three_ranks_on_a_batch_of_six_and_four_ranks_on_two_cores",
            three_ranks_on_a_batch_of_six_and_four_ranks_on_two_cores,
        ),
        (
            "a_signalled_rank_stops_every_rank_and_the_run_resumes_on_two_or_one",
            a_signalled_rank_stops_every_rank_and_the_run_resumes_on_two_or_one,
        ),
        (
            "a_killed_rank_ends_the_job_and_the_last_checkpoint_resumes",
            a_killed_rank_ends_the_job_and_the_last_checkpoint_resumes,
        ),
        (
            "bad_input_is_refused_by_every_rank_with_one_message",
            bad_input_is_refused_by_every_rank_with_one_message,
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
    if conclusion.has_failed() {
        eprintln!("the failing runs' folder is kept: {}", root().display());
    } else {
        let _ = std::fs::remove_dir_all(root());
    }
    conclusion.exit_code()
}

/// The MPI trainer and mpirun, or None (said) where they are missing.
fn mpi() -> Option<PathBuf> {
    let required = std::env::var("MATEDIT_REQUIRE_MPI").as_deref() == Ok("1");
    let bin = std::env::var_os("MATEDIT_MPI_TRAINER").map(PathBuf::from);
    let mpirun = Command::new("mpirun")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    match bin {
        Some(b) if b.is_file() && mpirun => Some(b),
        _ => {
            let why = "MATEDIT_MPI_TRAINER (a trainer built with --features mpi) and mpirun are needed";
            assert!(!required, "MATEDIT_REQUIRE_MPI=1: {why}");
            eprintln!("skipped: {why}");
            None
        }
    }
}

fn root() -> PathBuf {
    std::env::temp_dir().join(format!("matedit-ranks-{}", std::process::id()))
}

fn dataset() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let materials = five_materials();
        let sources = Sources {
            manifest: DATASET,
            materials: &materials,
            objs: &[("octahedron.obj", OCTAHEDRON)],
        };
        render_dataset(&root(), "m.toml", &sources, "dataset")
    })
}

/// Two stages (pretraining, then joint training through the rendering layer with dropout
/// and the perceptual fallback) at batch `batch`.
fn manifest(name: &str, batch: usize, dataset: &str) -> PathBuf {
    let text = format!(
        r#"
[run]
name = "ranks"
seed = 5
output = "unused"

[model]
input_size = 16
env_height = 4
widths = {{ base_channels = 4, max_channels = 16, hidden = 32, normal_channels = 8, dropout = 0.5 }}

[loss]
illumination = 1.0
ssim = 1e3

[data]
dataset = "{dataset}"
workers = 1

[[stages]]
name = "pretrain"
kind = "pretrain"
steps = 12
batch_size = {batch}
learning_rate = [[0, 1e-3]]
checkpoint_every = 4

[[stages]]
name = "joint"
kind = "joint"
steps = 16
batch_size = {batch}
learning_rate = [[0, 3e-4]]
beta1 = 0.5
checkpoint_every = 4

[eval]
split = "test"
max_samples = 4
"#
    );
    let dir = root().join("manifests");
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

fn data() -> String {
    dataset().display().to_string()
}

fn mpirun(np: usize) -> Command {
    let mut c = Command::new("mpirun");
    c.env("OMPI_ALLOW_RUN_AS_ROOT", "1")
        .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
        .env("OMPI_MCA_rmaps_base_oversubscribe", "1")
        .args(["-np", &np.to_string()]);
    c
}

/// `trainer run M --out OUT --quiet` as `np` ranks of the MPI build (0: the default build, one
/// process, without mpirun).
fn train(bin: &Path, np: usize, manifest: &Path, out: &Path, resume: bool) -> Command {
    let mut c = if np == 0 {
        let mut c = Command::new(std::env::current_exe().unwrap());
        c.env(AS_TRAINER, "1");
        c
    } else {
        let mut c = mpirun(np);
        c.arg(bin);
        c
    };
    c.arg("run").arg(manifest).arg("--out").arg(out).arg("--quiet");
    if resume {
        c.arg("--resume");
    }
    c
}

fn ok(mut c: Command) -> Output {
    let o = c.output().unwrap();
    assert!(
        o.status.success(),
        "{c:?} failed:\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    o
}

fn out(name: &str) -> PathBuf {
    let p = root().join("runs").join(name);
    let _ = std::fs::remove_dir_all(&p);
    std::fs::create_dir_all(p.parent().unwrap()).unwrap();
    p
}

fn metrics(out: &Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(out.join("metrics.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

fn weights(out: &Path, stage: &str) -> Vec<f32> {
    let dir = out.join("checkpoints").join(stage);
    let (net, _) = matedit_trainer::train::checkpoint::load_net(&dir, &burn::tensor::Device::flex()).unwrap();
    matedit_trainer::parallel::gradients::parameters(&net)
}

/// Every loss term of every step, and the final weights, within the tolerances.
fn assert_close(label: &str, a: &Path, b: &Path) {
    let (ma, mb) = (metrics(a), metrics(b));
    assert_eq!(ma.len(), mb.len(), "{label}: step counts");
    let mut worst = 0f64;
    for (la, lb) in ma.iter().zip(&mb) {
        assert_eq!(la["stage"], lb["stage"]);
        assert_eq!(la["step"], lb["step"]);
        for (k, va) in la["losses"].as_object().unwrap() {
            let (x, y) = (va.as_f64().unwrap(), lb["losses"][k].as_f64().unwrap());
            let d = (x - y).abs();
            let rel = if x.abs().max(y.abs()) > 0.0 {
                d / x.abs().max(y.abs())
            } else {
                0.0
            };
            assert!(
                rel <= LOSS_TOLERANCE || d <= 1e-9,
                "{label}: {k} at {}/{}: {x} against {y} (relative {rel:e})",
                la["stage"],
                la["step"]
            );
            worst = worst.max(rel);
        }
    }
    let (wa, wb) = (weights(a, "joint"), weights(b, "joint"));
    assert_eq!(wa.len(), wb.len());
    let dw = wa.iter().zip(&wb).map(|(x, y)| (x - y).abs()).fold(0f32, f32::max);
    eprintln!(
        "{label}: {} steps, worst relative loss difference {worst:e}, worst weight difference {dw:e} ({} weights)",
        ma.len(),
        wa.len()
    );
    assert!(dw <= WEIGHT_TOLERANCE, "{label}: weights differ by {dw:e}");
}

/// The same `metrics.jsonl` bytes and every weight bit for bit. (Checkpoint files are not
/// compared as bytes: Burn draws each parameter's id at random in every process, and the
/// files hold the ids.)
fn same_bits(label: &str, a: &Path, b: &Path) {
    let m = |p: &Path| std::fs::read(p.join("metrics.jsonl")).unwrap();
    assert!(m(a) == m(b), "{label}: metrics.jsonl differs");
    for stage in ["pretrain", "joint"] {
        let (wa, wb) = (weights(a, stage), weights(b, stage));
        let same = wa.len() == wb.len() && wa.iter().zip(&wb).all(|(x, y)| x.to_bits() == y.to_bits());
        assert!(same, "{label}: the weights after {stage} differ");
    }
}

fn one_rank_is_todays_run_and_two_ranks_equal_it_and_repeat_bit_identically() {
    let Some(bin) = mpi() else { return };
    let _one = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let m = manifest("b4.toml", 4, &data());
    let reference = out("reference");
    ok(train(&bin, 0, &m, &reference, false));
    // The MPI build as one rank, under mpirun and without it: the same bytes as the default build.
    for (label, np) in [("mpirun -np 1", 1), ("no launcher", 99)] {
        let o = out(&format!("one-{np}"));
        let c = if np == 99 {
            let mut c = Command::new(&bin);
            c.arg("run").arg(&m).arg("--out").arg(&o).arg("--quiet");
            c
        } else {
            train(&bin, np, &m, &o, false)
        };
        ok(c);
        same_bits(label, &reference, &o);
    }
    let two = out("two");
    let o = ok(train(&bin, 2, &m, &two, false));
    let log = String::from_utf8_lossy(&o.stderr);
    assert!(log.contains("rank 1 of 2"), "{log}");
    assert_close("2 ranks against 1", &reference, &two);
    let state = std::fs::read_to_string(two.join("checkpoints/joint/state.json")).unwrap();
    assert!(
        state.contains("\"ranks\": 2"),
        "the run folder does not say how many ranks: {state}"
    );
    let again = out("two-again");
    ok(train(&bin, 2, &m, &again, false));
    same_bits("the same 2-rank run twice", &two, &again);
    // Rank 0 alone evaluated.
    assert!(two.join("eval.json").is_file() && two.join("loss.png").is_file());
}

fn three_ranks_on_a_batch_of_six_and_four_ranks_on_two_cores() {
    let Some(bin) = mpi() else { return };
    let _one = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let m6 = manifest("b6.toml", 6, &data());
    let (one, three) = (out("b6-one"), out("b6-three"));
    ok(train(&bin, 0, &m6, &one, false));
    ok(train(&bin, 3, &m6, &three, false));
    assert_close("3 ranks at batch 6", &one, &three);
    let m4 = manifest("b4-four.toml", 4, &data());
    let (one, four) = (out("b4-one"), out("b4-four"));
    ok(train(&bin, 0, &m4, &one, false));
    ok(train(&bin, 4, &m4, &four, false));
    assert_close("4 ranks at batch 4", &one, &four);
}

/// The pids of the ranks of the run writing into `out` (`OMPI_COMM_WORLD_RANK` = `rank`).
fn rank_pid(out: &Path, rank: usize) -> Option<i32> {
    let want = format!("OMPI_COMM_WORLD_RANK={rank}");
    for e in std::fs::read_dir("/proc").ok()? {
        let Ok(e) = e else { continue };
        let Ok(pid) = e.file_name().to_string_lossy().parse::<i32>() else {
            continue;
        };
        let cmd = std::fs::read(e.path().join("cmdline")).unwrap_or_default();
        if !String::from_utf8_lossy(&cmd).contains(&*out.to_string_lossy()) {
            continue;
        }
        let env = std::fs::read(e.path().join("environ")).unwrap_or_default();
        if env.split(|&b| b == 0).any(|v| v == want.as_bytes()) {
            return Some(pid);
        }
    }
    None
}

/// Starts `c` and sends `signal` to rank `rank` once `metrics.jsonl` holds `after` lines.
fn signal_after(mut c: Command, out: &Path, after: usize, rank: usize, signal: &str) -> (Output, Duration) {
    let child = c.stdout(Stdio::null()).stderr(Stdio::piped()).spawn().unwrap();
    let t0 = Instant::now();
    loop {
        let lines = std::fs::read_to_string(out.join("metrics.jsonl")).map_or(0, |t| t.lines().count());
        if lines >= after {
            break;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(300),
            "the run did not reach step {after}"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    let pid = rank_pid(out, rank).expect("the rank's process");
    let sent = Instant::now();
    let s = Command::new("kill")
        .args([&format!("-{signal}"), &pid.to_string()])
        .status()
        .unwrap();
    assert!(s.success());
    let o = child.wait_with_output().unwrap();
    (o, sent.elapsed())
}

fn leftovers(out: &Path) -> Vec<String> {
    let mut bad = Vec::new();
    for e in std::fs::read_dir(out.join("checkpoints")).unwrap() {
        let name = e.unwrap().file_name().to_string_lossy().into_owned();
        if name.starts_with('.') || name.contains("tmp") {
            bad.push(name);
        }
    }
    bad
}

fn a_signalled_rank_stops_every_rank_and_the_run_resumes_on_two_or_one() {
    let Some(bin) = mpi() else { return };
    let _one = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let m = manifest("b4-resume.toml", 4, &data());
    let whole = out("whole");
    ok(train(&bin, 0, &m, &whole, false));
    let stopped = out("stopped");
    let (o, _) = signal_after(train(&bin, 2, &m, &stopped, false), &stopped, 15, 1, "TERM");
    let log = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(75), "{log}");
    assert!(log.contains("continue with --resume"), "{log}");
    assert!(leftovers(&stopped).is_empty(), "{:?}", leftovers(&stopped));
    let copy = root().join("runs/stopped-copy");
    let _ = std::fs::remove_dir_all(&copy);
    matedit_fixtures::copy_dir(&stopped, &copy);
    ok(train(&bin, 2, &m, &stopped, true));
    assert_close("stopped by SIGTERM, resumed with 2 ranks", &whole, &stopped);
    ok(train(&bin, 1, &m, &copy, true));
    assert_close("stopped by SIGTERM, resumed with 1 rank", &whole, &copy);
}

fn a_killed_rank_ends_the_job_and_the_last_checkpoint_resumes() {
    let Some(bin) = mpi() else { return };
    let _one = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let m = manifest("b4-kill.toml", 4, &data());
    let whole = out("kill-whole");
    ok(train(&bin, 0, &m, &whole, false));
    let killed = out("killed");
    let (o, took) = signal_after(train(&bin, 2, &m, &killed, false), &killed, 18, 1, "KILL");
    let log = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{log}");
    assert!(
        took < Duration::from_secs(30),
        "the job took {took:?} to end after a rank was killed"
    );
    eprintln!("a killed rank: the job ended {took:?} later; its message:\n{log}");
    assert!(leftovers(&killed).is_empty(), "{:?}", leftovers(&killed));
    ok(train(&bin, 2, &m, &killed, true));
    assert_close("a rank killed, resumed with 2 ranks", &whole, &killed);
}

fn bad_input_is_refused_by_every_rank_with_one_message() {
    let Some(bin) = mpi() else { return };
    let _one = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let refused = |c: &mut Command, needles: &[&str]| {
        let o = c.output().unwrap();
        let log = String::from_utf8_lossy(&o.stderr).into_owned();
        assert!(!o.status.success(), "{c:?} was not refused:\n{log}");
        for n in needles {
            assert!(log.contains(n), "{c:?}: no {n:?} in:\n{log}");
        }
        log
    };
    // A batch the ranks cannot share.
    let m = manifest("b4-three.toml", 4, &data());
    refused(
        &mut train(&bin, 3, &m, &out("indivisible"), false),
        &["b4-three.toml:", "stages[0].batch_size = 4", "3 ranks"],
    );
    // Skipping corrupt samples, which a rank cannot do for another's part of a batch.
    let skip = manifest("b4-skip.toml", 4, &data());
    let text = std::fs::read_to_string(&skip)
        .unwrap()
        .replace("workers = 1", "workers = 1\non_corrupt = \"skip\"");
    std::fs::write(&skip, text).unwrap();
    refused(
        &mut train(&bin, 2, &skip, &out("skip"), false),
        &["rank 0 of 2", "cannot be skipped", "on_corrupt"],
    );
    // Two ranks with different manifests (MPMD: one program per rank).
    let other = manifest("b4-other.toml", 4, &data()).with_file_name("b4-other.toml");
    let std_m = manifest("b4-std.toml", 4, &data());
    std::fs::write(
        &other,
        std::fs::read_to_string(&std_m).unwrap().replace("seed = 5", "seed = 6"),
    )
    .unwrap();
    let o = out("manifests-differ");
    let mut c = mpirun(1);
    c.arg(&bin).arg("run").arg(&std_m).arg("--out").arg(&o).arg("--quiet");
    c.args([":", "-np", "1"])
        .arg(&bin)
        .arg("run")
        .arg(&other)
        .arg("--out")
        .arg(&o)
        .arg("--quiet");
    let log = refused(&mut c, &["rank 1 of 2", "b4-other.toml differs from rank 0's"]);
    assert_eq!(
        log.matches("rank 1 of 2: the manifest").count(),
        2,
        "not one message per rank:\n{log}"
    );
    // The same manifest, a relative dataset: each rank in its own folder, rank 1's dataset
    // changed (a different dataset), then missing.
    let here = root().join("wdir0");
    let there = root().join("wdir1");
    for d in [&here, &there] {
        let _ = std::fs::remove_dir_all(d);
        matedit_fixtures::copy_dir(dataset(), &d.join("ds"));
    }
    let rel = manifest("b4-relative.toml", 4, "ds");
    let record = there.join("ds/dataset.json");
    let text = std::fs::read_to_string(&record).unwrap();
    std::fs::write(&record, text.replacen("\"name\"", "\"name\" ", 1)).unwrap();
    let o = out("datasets-differ");
    let two = |c: &mut Command| {
        c.arg("-wdir")
            .arg(&here)
            .arg(&bin)
            .arg("run")
            .arg(&rel)
            .arg("--out")
            .arg(&o)
            .arg("--quiet");
        c.args([":", "-np", "1", "-wdir"]).arg(&there).arg(&bin);
        c.arg("run").arg(&rel).arg("--out").arg(&o).arg("--quiet");
    };
    let mut c = mpirun(1);
    two(&mut c);
    refused(&mut c, &["rank 1 of 2", "the dataset ds differs from rank 0's"]);
    std::fs::remove_dir_all(there.join("ds")).unwrap();
    let mut c = mpirun(1);
    two(&mut c);
    let log = refused(&mut c, &["rank 1 of 2", "ds"]);
    assert!(
        log.contains("dataset.json") || log.contains("index.jsonl"),
        "the file is not named:\n{log}"
    );
}
