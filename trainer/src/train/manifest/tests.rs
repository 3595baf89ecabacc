//! Training manifests: parsing, defaults, refusals by file, line and field.

use super::*;

#[test]
fn every_shipped_training_manifest_is_valid() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../manifests/train");
    let mut n = 0;
    for e in std::fs::read_dir(&dir).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "toml") {
            // A finetuning manifest starts from another run's checkpoint, which a clean
            // checkout does not have: everything else of it is checked.
            let text = std::fs::read_to_string(&p).unwrap();
            // A GPU manifest (gpu-check.toml) names a device this build may not have.
            let text: String = text
                .lines()
                .filter(|l| !l.trim_start().starts_with("init_from"))
                .map(
                    |l| match l.trim_start().starts_with("device = \"wgpu\"") && !cfg!(feature = "wgpu") {
                        true => "device = \"cpu\"\n".to_string(),
                        false => format!("{l}\n"),
                    },
                )
                .collect();
            let plan = parse(&p, text).unwrap_or_else(|e| panic!("{e}"));
            assert!(!plan.manifest.stages.is_empty());
            n += 1;
        }
    }
    assert!(n >= 3, "quickstart, paper and paper-tables");
}

#[test]
fn learning_rates_step_at_their_first_step() {
    let text =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../manifests/train/paper.toml")).unwrap();
    let plan = parse(Path::new("paper.toml"), text).unwrap();
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
        ("workers = 2", "workers = 100000", "data.workers"),
        ("init = \"uniform-0.08\"", "exposure = \"auto\"", "model.exposure"),
        (
            "shuffle_buffer = 64",
            "shuffle_buffer = 10000000",
            "data.shuffle_buffer",
        ),
    ] {
        assert!(text.contains(from), "{from}");
        let e = parse(&path, text.replacen(from, to, 1))
            .err()
            .unwrap_or_else(|| panic!("{to} accepted"));
        let msg = e.to_string();
        assert!(msg.contains(needle), "{to}: {msg}");
        assert!(msg.len() < 400, "{to}: a long message: {msg}");
    }
    let exposure = |t: &str| {
        parse(&path, text.replacen("init = \"uniform-0.08\"", t, 1))
            .map(|p| p.net.exposure)
            .ok()
    };
    assert_eq!(
        exposure("init = \"default\""),
        Some(None),
        "the default: absolute, as before the choice"
    );
    assert_eq!(exposure("exposure = \"normalised\""), Some(Some(Exposure::Normalised)));
    assert_eq!(exposure("exposure = \"absolute\""), Some(None));
    for (from, to) in [
        ("workers = 2", "workers = 0"),
        ("shuffle_buffer = 64", "shuffle_buffer = 0"),
    ] {
        assert!(parse(&path, text.replacen(from, to, 1)).is_ok(), "{to}");
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
