//! `trainer eval` and the other methods: categories scored, the perceptual loss said and kept
//! on resume, Baseline 1 resumed bit-identically with Table 3's every method.

use super::*;

pub(super) fn eval_scores_only_the_asked_categories() {
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
pub(super) fn the_perceptual_loss_is_said_and_a_resume_keeps_it() {
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

pub(super) fn baseline_1_resumes_bit_identically_and_table_3_has_every_method() {
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
    let running = run_killed_after(&m, &out, 7);
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
