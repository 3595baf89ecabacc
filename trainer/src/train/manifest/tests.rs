//! Training manifests: parsing, defaults, refusals by file, line and field.

use super::*;

#[test]
fn every_shipped_training_manifest_is_valid() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../manifests/train");
    // A finetuning manifest starts from another run's checkpoint, which a clean checkout does not
    // have: a stand-in folder takes its place, and everything else of it is checked.
    let stand_in = tempfile::tempdir().unwrap();
    std::fs::write(stand_in.path().join("state.json"), "{}").unwrap();
    let mut n = 0;
    for e in std::fs::read_dir(&dir).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "toml") {
            let r = Resolved::read(&p, &[]).unwrap_or_else(|e| panic!("{e}"));
            let v: toml::Value = toml::from_str(&r.text).unwrap();
            let mut sets = Vec::new();
            if v["run"].get("init_from").is_some() {
                sets.push(format!("run.init_from={:?}", stand_in.path().display().to_string()));
            }
            // A GPU manifest (gpu-check.toml) names a device this build may not have.
            if v["run"].get("device").and_then(|d| d.as_str()) == Some("wgpu") && !cfg!(feature = "wgpu") {
                sets.push("run.device=cpu".into());
            }
            let plan = load(&p, &sets).unwrap_or_else(|e| panic!("{e}"));
            assert!(!plan.manifest.stages.is_empty());
            n += 1;
        }
    }
    assert!(n >= 3, "quickstart, paper and paper-tables");
}

#[test]
fn learning_rates_step_at_their_first_step() {
    let plan = load(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("../manifests/train/paper.toml"),
        &[],
    )
    .unwrap();
    let finetune = plan.manifest.stages[2].get_ref();
    assert_eq!(
        [0, 19999, 20000, 26999, 27000, 29999].map(|s| finetune.lr_at(s)),
        [1e-4, 1e-4, 1e-6, 1e-6, 1e-8, 1e-8]
    );
}

#[test]
fn fields_outside_their_ranges_are_refused_naming_the_field() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../manifests/train/quickstart.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    for (from, to, needle) in [
        ("normal = 1e4", "normal = 1e300", "loss.normal"),
        ("ssim = 1e4", "ssim = -1.0", "loss.ssim"),
        ("ssim = 1e4", "ssim = 1e4\nlight_energy = 2e6", "loss.light_energy"),
        ("ssim = 1e4", "ssim = 1e4\nlight_energy = nan", "loss.light_energy"),
        ("ssim = 1e4", "ssim = 1e4\nlight_direction = -1", "loss.light_direction"),
        (
            "ssim = 1e4",
            "ssim = 1e4\nlight_direction = inf",
            "loss.light_direction",
        ),
        ("[0, 1e-3]", "[0, 1e300]", "learning_rate"),
        ("[0, 1e-3]", "[0, 0.0]", "learning_rate"),
    ] {
        assert!(text.contains(from), "{from}");
        let e = parse(&path, text.replacen(from, to, 1))
            .err()
            .unwrap_or_else(|| panic!("{to} accepted"));
        let msg = e.to_string();
        assert!(msg.contains(needle), "{to}: {msg}");
        assert!(msg.len() < 400, "{to}: a long message: {msg}");
    }
    // Fields of the base (bases/quickstart-scale.toml), through --set.
    let set = |sets: &[&str]| load(&path, &sets.iter().map(|s| s.to_string()).collect::<Vec<_>>());
    for (option, needle) in [
        ("data.workers=100000", "data.workers"),
        ("model.exposure=auto", "model.exposure"),
        ("data.shuffle_buffer=10000000", "data.shuffle_buffer"),
    ] {
        let msg = set(&[option])
            .err()
            .unwrap_or_else(|| panic!("{option} accepted"))
            .to_string();
        assert!(msg.starts_with(&format!("--set {option}: {needle}")), "{option}: {msg}");
    }
    let exposure = |sets: &[&str]| set(sets).map(|p| p.net.exposure).ok();
    assert_eq!(
        exposure(&["model.init=default"]),
        Some(None),
        "the default: absolute, as before the choice"
    );
    assert_eq!(
        exposure(&["model.exposure=normalised"]),
        Some(Some(Exposure::Normalised))
    );
    assert_eq!(exposure(&["model.exposure=absolute"]), Some(None));
    for option in ["data.workers=0", "data.shuffle_buffer=0"] {
        assert!(set(&[option]).is_ok(), "{option}");
    }
}

/// Every stage field's refusal names the line that field is written on, not the stage's first
/// line (a wrong `batch_size` on line 49 was reported as line 44, `stages[0].steps`).
#[test]
fn every_stage_field_is_refused_at_its_own_line() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../manifests/train/quickstart.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    let cases = [
        // (stage, line as written, replacement, field)
        (0, "steps = 1200", "steps = 0", "stages[0].steps"),
        (0, "batch_size = 8", "batch_size = 0", "stages[0].batch_size"),
        (
            0,
            "learning_rate = [[0, 1e-3], [900, 3e-4], [1100, 1e-4]]",
            "learning_rate = [[0, 1e-3], [900, 3e-4], [800, 1e-4]]",
            "stages[0].learning_rate",
        ),
        (
            0,
            "learning_rate = [[0, 1e-3], [900, 3e-4], [1100, 1e-4]]",
            "learning_rate = [[0, 1e-3], [900, 3.0]]",
            "stages[0].learning_rate",
        ),
        (0, "beta1 = 0.9", "beta1 = 1.0", "stages[0].beta1"),
        (0, "beta2 = 0.999", "beta2 = -0.1", "stages[0].beta2"),
        (
            0,
            "split = \"train\"",
            "render_with = { normals = \"truth\" }",
            "stages[0].render_with",
        ),
        (
            1,
            "render_with = { normals = \"truth\", material = \"truth\" }",
            "render_with = { normals = \"truth\", material = \"truth\", illumination = \"truth\" }",
            "stages[1].render_with",
        ),
        (1, "name = \"light\"", "name = \"pretrain\"", "stages[1].name"),
        (1, "split = \"train\"", "from = \"joint\"", "stages[1].from"),
    ];
    for (stage, from, to, field) in cases {
        // The stage's own occurrence of the line.
        let starts: Vec<usize> = text.match_indices("[[stages]]").map(|(k, _)| k).collect();
        let at = starts[stage] + text[starts[stage]..].find(from).unwrap_or_else(|| panic!("{from}"));
        let changed = format!("{}{to}{}", &text[..at], &text[at + from.len()..]);
        let line = changed[..at].matches('\n').count() + 1;
        let e = parse(&path, changed).err().unwrap_or_else(|| panic!("{to}: accepted"));
        let msg = e.to_string();
        assert!(
            msg.contains(&format!("quickstart.toml:{line}: {field}")),
            "{to}: expected line {line} and {field}: {msg}"
        );
    }
}

/// A manifest that extends another, and `--set`: each refusal names the file and line that
/// wrote the value, or the option.
#[test]
fn refusals_name_the_base_the_experiment_or_the_option() {
    let d = tempfile::tempdir().unwrap();
    let base = Path::new(env!("CARGO_MANIFEST_DIR")).join("../manifests/train/quickstart.toml");
    // The quickstart resolved: a manifest of its own.
    let base_text = Resolved::read(&base, &[]).unwrap().text;
    std::fs::write(d.path().join("base.toml"), &base_text).unwrap();
    let exp = d.path().join("exp.toml");
    std::fs::write(
        &exp,
        "# an experiment\nextends = \"base.toml\"\n\n[run]\nname = \"exp\"\n\n[[stages]]\nname = \"joint\"\nbatch_size = 0\n",
    )
    .unwrap();
    let e = load(&exp, &[]).unwrap_err().to_string();
    assert_eq!(
        e,
        format!("{}:9: stages[2].batch_size: batch_size must be positive", exp.display())
    );
    // The base's own line, where the base wrote the value at fault.
    let e = load(
        &exp,
        &["stages[joint].batch_size=8".into(), "data.workers=100000".into()],
    )
    .unwrap_err()
    .to_string();
    assert_eq!(
        e,
        "--set data.workers=100000: data.workers: at most 256 decoding threads, got 100000"
    );
    let e = load(&exp, &["stages[joint].batch_size=8".into(), "loss.normal=1e300".into()])
        .unwrap_err()
        .to_string();
    assert!(
        e.starts_with("--set loss.normal=1e300: loss.normal: a weight must lie"),
        "{e}"
    );
    let e = load(
        &exp,
        &[
            "stages[joint].batch_size=8".into(),
            "stages[pretrain].warmup=1200".into(),
        ],
    )
    .unwrap_err()
    .to_string();
    assert_eq!(
        e,
        "--set stages[pretrain].warmup=1200: stages[0].warmup: 1200 warm-up steps leave none of the stage's 1200"
    );
    let e = load(
        &exp,
        &["stages[joint].batch_size=8".into(), "stages[0].decay=cosin".into()],
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.starts_with("--set stages[0].decay=cosin: stages[0].decay: \"cosin\": expected piecewise, cosine"),
        "{e}"
    );
    // A refusal of the base's own value names the base's line.
    let changed = base_text.replacen("steps = 1200", "steps = 1200\ndecay = \"cosine\"", 1);
    std::fs::write(d.path().join("base.toml"), &changed).unwrap();
    let line = changed.lines().position(|l| l.starts_with("learning_rate = ")).unwrap() + 1;
    let e = load(&exp, &["stages[joint].batch_size=8".into()])
        .unwrap_err()
        .to_string();
    assert_eq!(
        e,
        format!(
            "{}:{line}: stages[0].learning_rate: decay = \"cosine\" starts from one rate ([[0, lr]]); piecewise rates are decay = \"piecewise\"",
            d.path().join("base.toml").display(),
        )
    );
    // Unknown fields anywhere in the chain name their file and line.
    std::fs::write(&exp, "extends = \"base.toml\"\n[run]\nnmae = \"x\"\n").unwrap();
    let e = load(&exp, &[]).unwrap_err().to_string();
    assert!(
        e.starts_with(&format!("{}:3: run.nmae: unknown field `nmae`", exp.display())),
        "{e}"
    );
    let e = load(&base, &["run.nmae=x".into()]).unwrap_err().to_string();
    assert!(e.starts_with("--set run.nmae=x: run.nmae: unknown field `nmae`"), "{e}");
}

/// A schedule given in a manifest is the one the run steps with; the resolved manifest records
/// `--set` and is what checkpoints hash.
#[test]
fn a_manifest_schedule_and_its_overrides_resolve_into_the_plan() {
    let paper = Path::new(env!("CARGO_MANIFEST_DIR")).join("../manifests/train/paper.toml");
    let own = load(&paper, &[]).unwrap();
    assert!(own.source.is_plain(), "no extends, no --set: the file's own text");
    assert_eq!(own.source.text, std::fs::read_to_string(&paper).unwrap());
    let base = Path::new(env!("CARGO_MANIFEST_DIR")).join("../manifests/train/quickstart.toml");
    let plain = load(&base, &[]).unwrap();
    assert!(!plain.source.is_plain() && plain.source.text.contains("# extends: "));
    let sets: Vec<String> = [
        "stages[pretrain].learning_rate=[[0, 1e-3]]",
        "stages[pretrain].warmup=100",
        "stages[pretrain].decay=cosine",
        "stages[pretrain].final_lr=1e-5",
    ]
    .map(String::from)
    .to_vec();
    let p = load(&base, &sets).unwrap();
    let st = p.manifest.stages[0].get_ref();
    let r = st.rates();
    assert_eq!(r.len(), st.steps);
    assert!((r[0] - 1e-5).abs() < 1e-18 && r[100] == 1e-3 && (r[st.steps - 1] - 1e-5).abs() < 1e-18);
    assert_ne!(p.hash(), plain.hash(), "an override is a different run");
    assert!(p.source.text.contains("# --set stages[pretrain].decay=cosine"));
    assert_eq!(
        load(&base, &sets).unwrap().hash(),
        p.hash(),
        "the same options, the same hash"
    );
}

#[test]
fn a_key_is_found_on_its_own_line_and_a_default_falls_back_to_the_table() {
    let text = "[[stages]]\nname = \"a\"\n  steps=3 # x\nbatch_sizes = 1\n\n[[stages]]\nbatch_size = 2\n";
    let table = 0..10;
    let steps = key_span(text, table.clone(), "steps");
    assert_eq!(&text[steps.clone()], "steps=3 # x");
    assert_eq!(
        key_span(text, table.clone(), "batch_size"),
        table,
        "batch_sizes is another key, and the next table's is not this one's"
    );
    assert_eq!(key_span(text, 500..510, "steps"), 500..510, "a span outside the text");
}

/// blake3 of each shipped training manifest's resolved value (JSON, keys sorted), pinned from
/// the manifests as they were before `extends` (commit 584af7b, where each was written out in
/// full): rewriting them as bases and short experiments changed none of them.
const RESOLVED: &[(&str, &str)] = &[
    (
        "baseline1-paper.toml",
        "d4f3a9baaa27e41873de9ef25e91bef7c2d01da06e03497b02e2a493f35815ee",
    ),
    (
        "baseline1.toml",
        "d872415dbb245f1e0e43681b482ba43a86ab771f7af0a5bb1e0e197d32ab5cf4",
    ),
    (
        "gpu-check.toml",
        "716bc7cc80913533466fdd41d424e745e1af01915f1110472345057934c4b1da",
    ),
    (
        "paper-tables.toml",
        "e89000890551a58fc9c3734c3763237a2ca79a0ee1d361465327d97eb5dcd4a4",
    ),
    (
        "paper.toml",
        "9e1cef2dec48a37a05547d20439130b315f8205c2d38006176dcfb84152b23a6",
    ),
    (
        "quickstart-detached-normals.toml",
        "db8f61e0b9d729e1acb5f893c4fdb14fca820cbd0126c97771343836393bc239",
    ),
    (
        "quickstart-light-direction-only.toml",
        "8d87eb0ed30de3973393877f747cd9350416667435a48366e6fa8711546d5d81",
    ),
    (
        "quickstart-light-direction.toml",
        "fd295033623aff7c7bb164d8ee1d1504c105d50907331c63d7d80d5b052ffa0f",
    ),
    (
        "quickstart-long.toml",
        "320111b9dd5df030e132240cdb21a974b7251b2280801666c3c381b58a47d6c8",
    ),
    (
        "quickstart-many-lights.toml",
        "c5de20248cc8e6484e606293f8c9c0730753b0e1daf4b97ddbf851ae7b5264d1",
    ),
    (
        "quickstart-mixed-shapes.toml",
        "8a2065715857aa78a11308efc921a32c62fbb28c412d681f1c5d84e74b5d137b",
    ),
    (
        "quickstart-multimaterial.toml",
        "cabc554077f77279fd47f146cb26f37ab8418d631c44448467cc9dd3d5541c5e",
    ),
    (
        "quickstart-normalised.toml",
        "03cf9b6c5be88861e11b9a232df3a1ee2a14e304dd2d1f5e2a9b4be2e9fd5ce2",
    ),
    (
        "quickstart-parametric-normalised.toml",
        "990d9e6960718aaf1f26862e95e9942b5578a4d61584e68244be60624c0cbdec",
    ),
    (
        "quickstart-parametric.toml",
        "3585a30a8444b75dff5867f7a193fe5d3ef4c05a5c9e2a722fa2257070d90592",
    ),
    (
        "quickstart-real-shapes-detached-normals.toml",
        "b2f88594c67e74a3a79df4d298e9bf43226c28a75fff9cad0362373e80f43852",
    ),
    (
        "quickstart-real-shapes.toml",
        "7ee5ba3e4542dfcae16568a51f1d760b9f90c720268cc6265c6961ca6012ecb0",
    ),
    (
        "quickstart.toml",
        "ec6cdf46d0299ed313ea6adfd31a1e1967dbe635b2ce4482966718b8090b835f",
    ),
    (
        "real-world-mixed-lights-energy.toml",
        "9649b5f07089f257b0f9eed4bbb6641a59a0e752b766c3c9fca701e65916ef92",
    ),
    (
        "real-world-mixed-lights-long.toml",
        "e5d8650bd8378ba5375c2eaebc6bb73bb6e4a20d1f7fba9e2109230674713c18",
    ),
    (
        "real-world-mixed-lights.toml",
        "70bbb92017800211747f7ffad9b9b782f9e04ed6b04851e693cbb51b72e7cd52",
    ),
    (
        "real-world.toml",
        "91dfe7c33d6c327e7afaf61a72ef93334438a82043ea9a8d8f111b5d5a870ade",
    ),
];

fn resolved_value_hash(p: &Path) -> String {
    let r = Resolved::read(p, &[]).unwrap_or_else(|e| panic!("{e}"));
    let v: toml::Value = toml::from_str(&r.text).unwrap();
    blake3::hash(serde_json::to_string(&v).unwrap().as_bytes())
        .to_hex()
        .to_string()
}

#[test]
fn every_shipped_training_manifest_resolves_as_before_extends() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../manifests/train");
    let mut names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".toml"))
        .collect();
    names.sort();
    let got: Vec<(String, String)> = names
        .iter()
        .map(|n| (n.clone(), resolved_value_hash(&dir.join(n))))
        .collect();
    for (n, h) in &got {
        // The lines to paste into RESOLVED after a deliberate change.
        println!("    (\"{n}\", \"{h}\"),");
    }
    let want: Vec<(String, String)> = RESOLVED.iter().map(|(n, h)| (n.to_string(), h.to_string())).collect();
    assert_eq!(got, want);
}
