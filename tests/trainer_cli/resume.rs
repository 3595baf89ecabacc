//! Runs that stop and go on: a killed or signalled run resumes to the same losses and metrics,
//! stages branch from earlier stages, a run starts from another's checkpoint.

use super::*;

pub(super) fn a_killed_run_resumes_to_the_same_losses_and_metrics() {
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
        let running = run_killed_after(&m, &out, kill_after);
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

pub(super) fn stages_can_branch_from_an_earlier_stage() {
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

pub(super) fn a_run_can_start_from_another_runs_checkpoint() {
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
