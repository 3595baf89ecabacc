//! Validation while training: a four-stage run validated every few steps keeps its best
//! checkpoint, and a kill at any moment (between a checkpoint and its validation too) resumes to
//! the same lines, scores and best; the stages' learning-rate schedules are the ones stepped.

use super::*;

/// Four stages, each with another schedule, validated every `every` steps (0: never).
fn validated_manifest(dataset: &Path, every: usize) -> String {
    format!(
        r#"{}
[[stages]]
name = "pretrain"
kind = "pretrain"
steps = 6
batch_size = 4
learning_rate = [[0, 1e-3]]
warmup = 2
decay = "cosine"
final_lr = 1e-5

[[stages]]
name = "joint"
kind = "joint"
steps = 6
batch_size = 4
learning_rate = [[0, 1e-4]]
decay = "linear"
final_lr = 1e-5
beta1 = 0.5

[[stages]]
name = "finetune"
kind = "joint"
steps = 6
batch_size = 4
learning_rate = [[0, 1e-4]]
decay = "step"
decay_every = 2
gamma = 0.5
checkpoint_every = 5

[[stages]]
name = "multi-material"
kind = "joint"
steps = 6
batch_size = 4
learning_rate = [[0, 1e-4], [3, 1e-5]]

[eval]
split = "test"
every = {every}
val_split = "test"
val_samples = 4
"#,
        run_head(dataset, "validated", 9)
    )
}

fn records(out: &Path) -> (Vec<Value>, Vec<Value>) {
    metric_lines(out)
        .iter()
        .map(|l| serde_json::from_str::<Value>(l).unwrap())
        .partition(|v| v.get("validation").is_none())
}

/// The best checkpoint's record and its weights, bit for bit. (Not its files' bytes: Burn draws
/// each parameter's id at random in every process, and the files hold the ids.)
fn best(out: &Path) -> (Value, Vec<u32>) {
    let b = out.join("checkpoints/best");
    let record: Value = serde_json::from_str(&std::fs::read_to_string(b.join("best.json")).unwrap()).unwrap();
    let (net, _) = matedit_trainer::train::checkpoint::load_net(&b, &burn::tensor::Device::flex()).unwrap();
    let bits = matedit_trainer::parallel::gradients::parameters(&net)
        .iter()
        .map(|w| w.to_bits())
        .collect();
    (record, bits)
}

pub(super) fn a_validated_run_keeps_its_best_checkpoint_across_a_kill() {
    let m = write_manifest("validated.toml", &validated_manifest(dataset(), 4));
    let whole = root().join("validated-whole");
    let o = train(&m, &whole, false);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (steps, vals) = records(&whole);
    assert_eq!(steps.len(), 24, "one line per step");
    // Every 4 steps of the run and at each stage's end (6, 12, 18, 24).
    let at: Vec<u64> = vals.iter().map(|v| v["global_step"].as_u64().unwrap()).collect();
    assert_eq!(at, vec![4, 6, 8, 12, 16, 18, 20, 24]);
    for v in &vals {
        let s = &v["validation"];
        assert_eq!(
            (s["split"].as_str(), s["samples"].as_u64()),
            (Some("test"), Some(4)),
            "{v}"
        );
        for k in ["o_l2", "o_ssim", "i_l2", "i_ssim", "normal_cosine", "material_l2"] {
            assert!(s[k].as_f64().is_some_and(f64::is_finite), "{k}: {v}");
        }
        let png = whole.join(format!("validation/{:07}.png", v["global_step"].as_u64().unwrap()));
        assert!(png.is_file(), "{}", png.display());
    }
    // The best checkpoint is the validation with the lowest O' L2 (the first of a tie).
    let lowest = vals
        .iter()
        .min_by(|a, b| {
            let f = |v: &Value| v["validation"]["o_l2"].as_f64().unwrap();
            f(a).partial_cmp(&f(b)).unwrap()
        })
        .unwrap();
    let (b, weights) = best(&whole);
    assert_eq!(b["metric"], "o_l2");
    assert_eq!(b["line"], *lowest, "{b}");
    assert_eq!(b["value"], lowest["validation"]["o_l2"]);
    assert!(!weights.is_empty());
    // The schedules, as stepped.
    let lr = |stage: &str| -> Vec<f64> {
        steps
            .iter()
            .filter(|s| s["stage"] == stage)
            .map(|s| s["lr"].as_f64().unwrap())
            .collect()
    };
    let warm = lr("pretrain");
    assert!(
        (warm[0] - 1e-5).abs() < 1e-15 && warm[2] == 1e-3 && (warm[5] - 1e-5).abs() < 1e-15,
        "{warm:?}"
    );
    let linear = lr("joint");
    assert!(
        (linear[0] - 1e-4).abs() < 1e-18 && (linear[5] - 1e-5).abs() < 1e-15,
        "{linear:?}"
    );
    assert_eq!(lr("finetune"), vec![1e-4, 1e-4, 5e-5, 5e-5, 2.5e-5, 2.5e-5]);
    assert_eq!(lr("multi-material"), vec![1e-4, 1e-4, 1e-4, 1e-5, 1e-5, 1e-5]);

    // Validation changes nothing of the training: the same steps as a run without it.
    let plain = root().join("validated-never");
    let mp = write_manifest("never.toml", &validated_manifest(dataset(), 0));
    let o = train(&mp, &plain, false);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (plain_steps, plain_vals) = records(&plain);
    assert!(plain_vals.is_empty() && !plain.join("checkpoints/best").exists());
    assert_eq!(plain_steps, steps, "validation while training changed the training");

    let want = metric_lines(&whole);
    for (k, kill_after) in [7usize, 20].into_iter().enumerate() {
        let out = root().join(format!("validated-killed-{k}"));
        let running = run_killed_after(&m, &out, kill_after);
        assert!(
            running && metric_lines(&out).len() < want.len(),
            "kill {k} came too late"
        );
        // A kill between a checkpoint and its validation: the checkpoint's validation line
        // is gone (the best may or may not have been replaced; here it was not).
        let latest: Value = serde_json::from_str(&std::fs::read_to_string(out.join("latest.json")).unwrap()).unwrap();
        let state: Value = serde_json::from_str(
            &std::fs::read_to_string(out.join(latest["checkpoint"].as_str().unwrap()).join("state.json")).unwrap(),
        )
        .unwrap();
        let g = state["global_step"].as_u64().unwrap();
        let kept: Vec<String> = metric_lines(&out)
            .into_iter()
            .filter(|l| {
                let v: Value = serde_json::from_str(l).unwrap();
                v["global_step"].as_u64().unwrap() < g || (v["global_step"] == g && v.get("validation").is_none())
            })
            .collect();
        std::fs::write(out.join("metrics.jsonl"), kept.join("\n") + "\n").unwrap();
        std::fs::create_dir_all(out.join("checkpoints/.tmp-best-999999")).unwrap();
        let o = train(&m, &out, true);
        assert!(o.status.success(), "resume {k}: {}", String::from_utf8_lossy(&o.stderr));
        assert_eq!(
            metric_lines(&out),
            want,
            "kill {k} after {kill_after} lines: the lines differ"
        );
        assert_eq!(best(&out), best(&whole), "kill {k}: another best checkpoint");
        assert!(!out.join("checkpoints/.tmp-best-999999").exists());
    }
}
