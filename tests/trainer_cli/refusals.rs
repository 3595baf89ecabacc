//! What the trainer refuses, by name: bad manifests (file, line, field), impossible bench
//! configurations, a truncated shard file (or skipped and reported).

use super::*;

pub(super) fn bad_manifests_name_file_line_and_field() {
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

pub(super) fn bench_prints_both_layers_and_refuses_impossible_configurations() {
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

pub(super) fn a_truncated_shard_file_stops_the_run_naming_it_or_is_skipped_and_reported() {
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

pub(super) fn dump_batch_writes_the_batch_and_refuses_what_the_dataset_has_not() {
    let data = dataset();
    let out = root().join("dump.safetensors");
    let dump = |split: &str, first: &str, count: &str| {
        trainer()
            .arg("dump-batch")
            .arg(data)
            .args(["--split", split, "--first", first, "--count", count, "--out"])
            .arg(&out)
            .output()
            .unwrap()
    };
    let o = dump("train", "1", "3");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let bytes = std::fs::read(&out).unwrap();
    let size = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let header: Value = serde_json::from_slice(&bytes[8..8 + size]).unwrap();
    assert_eq!(header["input"]["shape"][0], 3);
    assert_eq!(header["region_map"]["dtype"], "U8");
    let ids: Vec<String> = serde_json::from_str(header["__metadata__"]["ids"].as_str().unwrap()).unwrap();
    assert_eq!(ids, ["train-0000001", "train-0000002", "train-0000003"]);
    let before = bytes.clone();
    for (split, first, count, says) in [
        ("val", "0", "1", "no split \"val\""),
        ("train", "100000", "1", "--first 100000 --count 1"),
        ("train", "0", "0", "outside 1–4096"),
    ] {
        let o = dump(split, first, count);
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && e.contains(says), "{split} {first} {count}: {e}");
        assert_eq!(
            std::fs::read(&out).unwrap(),
            before,
            "a refused dump leaves the file alone"
        );
    }
    let o = trainer()
        .arg("bench-loader")
        .arg(data)
        .args(["--workers", "0", "--runs", "1"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success() && text.contains("samples/s") && text.contains("checksums verified"),
        "{text}"
    );
}
