use super::*;
use std::fs;

/// Writes `files` (name, text) into a fresh folder.
fn folder(files: &[(&str, &str)]) -> tempfile::TempDir {
    let d = tempfile::tempdir().unwrap();
    for (name, text) in files {
        let p = d.path().join(name);
        fs::create_dir_all(p.parent().unwrap()).unwrap();
        fs::write(p, text).unwrap();
    }
    d
}

const BASE: &str = r#"# a base
[run]
name = "base"
seed = 7

[model]
widths = { base_channels = 8, hidden = 16 }

[[stages]]
name = "pretrain"
steps = 10
learning_rate = [[0, 1e-4], [5, 1e-6]]

[[stages]]
name = "joint"
steps = 20
"#;

const CHILD: &str = r#"extends = "base.toml"

[run]
name = "child"

[model]
widths = { hidden = 32 }
exposure = "normalised"

[[stages]]
name = "joint"
steps = 60

[[stages]]
name = "finetune"
steps = 5
"#;

fn value(r: &Resolved) -> toml::Value {
    toml::from_str(&r.text).unwrap_or_else(|e| panic!("{e}\n{}", r.text))
}

#[test]
fn a_manifest_of_its_own_is_its_text_byte_for_byte() {
    let d = folder(&[("base.toml", BASE)]);
    let r = Resolved::read(&d.path().join("base.toml"), &[]).unwrap();
    assert!(r.is_plain());
    assert_eq!(r.text, BASE);
    assert_eq!(
        r.place(BASE.find("seed").unwrap()),
        format!("{}:4", d.path().join("base.toml").display())
    );
}

#[test]
fn extends_merges_tables_by_key_and_stages_by_name() {
    let d = folder(&[("base.toml", BASE), ("child.toml", CHILD)]);
    let child = d.path().join("child.toml");
    let r = Resolved::read(&child, &[]).unwrap();
    assert!(!r.is_plain());
    assert_eq!(r.files, vec![child.clone(), d.path().join("base.toml")]);
    let want: toml::Value = toml::from_str(
        r#"
[run]
name = "child"
seed = 7
[model]
widths = { base_channels = 8, hidden = 32 }
exposure = "normalised"
[[stages]]
name = "pretrain"
steps = 10
learning_rate = [[0, 1e-4], [5, 1e-6]]
[[stages]]
name = "joint"
steps = 60
[[stages]]
name = "finetune"
steps = 5
"#,
    )
    .unwrap();
    assert_eq!(value(&r), want, "{}", r.text);
    // Each line names the file that wrote it.
    let at = |needle: &str| r.place(r.text.find(needle).unwrap_or_else(|| panic!("{needle}\n{}", r.text)));
    let base = d.path().join("base.toml").display().to_string();
    let childs = child.display().to_string();
    assert_eq!(at("seed = 7"), format!("{base}:4"));
    assert_eq!(at("name = \"child\""), format!("{childs}:4"));
    assert_eq!(at("steps = 60"), format!("{childs}:12"));
    assert_eq!(at("steps = 10"), format!("{base}:11"));
    assert_eq!(at("name = \"finetune\""), format!("{childs}:15"));
    // Resolving is a pure function of the files: twice, the same text.
    assert_eq!(Resolved::read(&child, &[]).unwrap().text, r.text);
}

#[test]
fn chains_follow_folders_and_cycles_are_refused_naming_the_files() {
    let d = folder(&[
        ("base.toml", BASE),
        ("x/mid.toml", "extends = \"../base.toml\"\n[run]\nseed = 9\n"),
        ("x/y/top.toml", "extends = \"../mid.toml\"\n[run]\nname = \"top\"\n"),
        ("a.toml", "extends = \"b.toml\"\n"),
        ("b.toml", "# b\nextends = \"a.toml\"\n"),
        ("self.toml", "extends = \"self.toml\"\n"),
        ("missing.toml", "\n\nextends = \"nowhere.toml\"\n"),
        ("number.toml", "extends = 3\n"),
    ]);
    let r = Resolved::read(&d.path().join("x/y/top.toml"), &[]).unwrap();
    let v = value(&r);
    assert_eq!(v["run"]["seed"].as_integer(), Some(9));
    assert_eq!(v["run"]["name"].as_str(), Some("top"));
    assert_eq!(r.files.len(), 3);

    let e = Resolved::read(&d.path().join("a.toml"), &[]).unwrap_err().to_string();
    assert!(
        e.contains("b.toml:2: extends: a cycle") && e.contains("a.toml → ") && e.contains("b.toml → "),
        "{e}"
    );
    let e = Resolved::read(&d.path().join("self.toml"), &[])
        .unwrap_err()
        .to_string();
    assert!(e.contains("self.toml:1: extends: a cycle"), "{e}");
    let e = Resolved::read(&d.path().join("missing.toml"), &[])
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("missing.toml:3: extends:") && e.contains("nowhere.toml: cannot read"),
        "{e}"
    );
    let e = Resolved::read(&d.path().join("number.toml"), &[])
        .unwrap_err()
        .to_string();
    assert!(e.contains("number.toml:1: extends: the path of one manifest"), "{e}");
}

#[test]
fn a_chain_too_long_is_refused() {
    let d = tempfile::tempdir().unwrap();
    for i in 0..=MAX_EXTENDS {
        fs::write(
            d.path().join(format!("m{i}.toml")),
            format!("extends = \"m{}.toml\"\n", i + 1),
        )
        .unwrap();
    }
    fs::write(d.path().join(format!("m{}.toml", MAX_EXTENDS + 1)), "a = 1\n").unwrap();
    let e = Resolved::read(&d.path().join("m0.toml"), &[]).unwrap_err().to_string();
    assert!(e.contains(&format!("more than {MAX_EXTENDS} manifests")), "{e}");
    // One shorter is accepted.
    let r = Resolved::read(&d.path().join("m2.toml"), &[]).unwrap();
    assert_eq!(value(&r)["a"].as_integer(), Some(1));
}

#[test]
fn a_base_that_is_not_toml_or_nests_too_deep_is_named() {
    let deep = format!("a = {}1{}\n", "[".repeat(40), "]".repeat(40));
    let d = folder(&[
        ("bad.toml", "[run\n"),
        ("deep.toml", &deep),
        ("c1.toml", "extends = \"bad.toml\"\n"),
        ("c2.toml", "extends = \"deep.toml\"\n"),
    ]);
    let e = Resolved::read(&d.path().join("c1.toml"), &[]).unwrap_err().to_string();
    assert!(
        e.starts_with(&format!("{}:", d.path().join("bad.toml").display())),
        "{e}"
    );
    let e = Resolved::read(&d.path().join("c2.toml"), &[]).unwrap_err().to_string();
    assert!(
        e.contains("deep.toml: line 1: brackets and braces nested more than 32 deep"),
        "{e}"
    );
}

#[test]
fn arrays_without_names_and_plain_values_are_replaced() {
    let d = folder(&[
        (
            "base.toml",
            "xs = [1, 2]\n[[splits]]\nrole = \"train\"\n[[splits]]\nrole = \"test\"\n",
        ),
        (
            "child.toml",
            "extends = \"base.toml\"\nxs = [3]\n[[splits]]\nrole = \"val\"\n",
        ),
    ]);
    let v = value(&Resolved::read(&d.path().join("child.toml"), &[]).unwrap());
    assert_eq!(v["xs"].as_array().unwrap().len(), 1);
    let splits = v["splits"].as_array().unwrap();
    assert_eq!(splits.len(), 1);
    assert_eq!(splits[0]["role"].as_str(), Some("val"));
}

#[test]
fn sets_reach_every_kind_of_field_and_name_the_option() {
    let d = folder(&[("base.toml", BASE)]);
    let p = d.path().join("base.toml");
    let sets: Vec<String> = [
        "stages[1].steps=60",
        "stages[pretrain].learning_rate=[[0, 2e-4]]",
        "run.device=wgpu",
        "run.name=\"quoted\"",
        "model.widths.hidden=64",
        "eval.split=val",
        "model.widths={ base_channels = 4 }",
    ]
    .map(String::from)
    .to_vec();
    let r = Resolved::read(&p, &sets).unwrap();
    let v = value(&r);
    assert_eq!(v["stages"][1]["steps"].as_integer(), Some(60));
    assert_eq!(v["stages"][0]["learning_rate"][0][1].as_float(), Some(2e-4));
    assert_eq!(v["run"]["device"].as_str(), Some("wgpu"));
    assert_eq!(v["run"]["name"].as_str(), Some("quoted"));
    assert_eq!(v["eval"]["split"].as_str(), Some("val"));
    // The last option wins, and a table given whole merges like a file's.
    assert_eq!(v["model"]["widths"]["base_channels"].as_integer(), Some(4));
    assert_eq!(v["model"]["widths"]["hidden"].as_integer(), Some(64));
    assert_eq!(r.place(r.text.find("steps = 60").unwrap()), "--set stages[1].steps=60");
    assert!(r.text.contains("# --set stages[1].steps=60"));
    // A value's problem found later names the option.
    let at = r.text.find("steps = 60").unwrap();
    let e = r
        .invalid(at..at + 1, "stages[1].steps", "steps must be positive")
        .to_string();
    assert_eq!(e, "--set stages[1].steps=60: stages[1].steps: steps must be positive");

    for (bad, want) in [
        ("stages[5].steps=1", "stages[5]: there are 2 (numbered from 0)"),
        (
            "stages[nope].steps=1",
            "no entry of stages is named \"nope\" (pretrain, joint)",
        ),
        ("stages.steps=1", "stages is a value, not a table"),
        ("run.seed.x=1", "seed is a value, not a table"),
        ("run[0].seed=1", "run is not an array of tables"),
        ("stages[0]=1", "name a field of the entry of stages"),
        ("steps", "expected PATH=VALUE"),
        ("a..b=1", "is not a field path"),
        ("a[=1", "an unclosed ["),
        ("a[]=1", "an empty []"),
        ("run.name=[1,", "is not a TOML value"),
        ("extends=other.toml", "extends is the manifest's own"),
    ] {
        let e = Resolved::read(&p, &[bad.to_string()]).unwrap_err();
        assert!(matches!(e, ManifestError::Set { .. }), "{bad}: {e:?}");
        let e = e.to_string();
        assert!(
            e.starts_with(&format!("--set {bad}: ")) && e.contains(want),
            "{bad}: {e}"
        );
    }
}

#[test]
fn text_and_options_nested_beyond_the_guard_are_refused_before_parsing() {
    // The shape that overflowed a thread's stack in the toml parser: refused by the nesting
    // guard, never parsed (this test would abort the process otherwise).
    let run_on = "[[splits]]\nshapes = { car = 1\n".repeat(2000);
    let r = Resolved::resolve(Path::new("deep.toml"), run_on.clone(), &[]).unwrap();
    assert!(r.is_plain(), "left to the manifest's parser, which names the line");
    let e = super::super::parse_toml::<toml::Value>(Path::new("deep.toml"), &r.text).unwrap_err();
    assert!(e.to_string().contains("nested more than 32 deep"), "{e}");
    let d = folder(&[("base.toml", BASE)]);
    let deep = format!("run.x={}1{}", "[".repeat(100_000), "]".repeat(100_000));
    let e = Resolved::read(&d.path().join("base.toml"), &[deep])
        .unwrap_err()
        .to_string();
    assert!(e.contains("nested more than 32 deep") && e.len() < 400, "{e}");
}

#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
#[allow(dead_code)]
struct Run {
    name: String,
    seed: u64,
}

#[derive(Debug, serde::Deserialize)]
#[allow(dead_code)]
struct Doc {
    run: Run,
}

#[test]
fn type_and_unknown_field_errors_name_the_writer() {
    let d = folder(&[
        ("base.toml", "[run]\nname = \"b\"\nseed = 1\n"),
        ("child.toml", "extends = \"base.toml\"\n\n[run]\nseeed = 2\n"),
        ("typed.toml", "extends = \"base.toml\"\n[run]\nseed = \"one\"\n"),
    ]);
    let r = Resolved::read(&d.path().join("child.toml"), &[]).unwrap();
    let e = r.parse::<Doc>().unwrap_err().to_string();
    assert!(
        e.starts_with(&format!(
            "{}:4: run.seeed: unknown field",
            d.path().join("child.toml").display()
        )),
        "{e}"
    );
    let r = Resolved::read(&d.path().join("typed.toml"), &[]).unwrap();
    let e = r.parse::<Doc>().unwrap_err().to_string();
    assert!(e.contains("typed.toml:3: run.seed: invalid type"), "{e}");
    let r = Resolved::read(&d.path().join("base.toml"), &["run.seed=-1".into()]).unwrap();
    let e = r.parse::<Doc>().unwrap_err().to_string();
    assert!(e.starts_with("--set run.seed=-1: run.seed: "), "{e}");
    let r = Resolved::read(&d.path().join("base.toml"), &["run.extra=1".into()]).unwrap();
    let e = r.parse::<Doc>().unwrap_err().to_string();
    assert!(e.starts_with("--set run.extra=1: run.extra: unknown field"), "{e}");
}

#[test]
fn values_survive_rendering_exactly() {
    let text = r#"
s = "a \"quoted\" \\ line\nnext, tab\t, é, 🙂"
lit = 'C:\path'
multi = """
two
lines"""
i = 0x1F
neg = -9_223_372_036_854_775_808
f = 1e-300
tiny = 5e-324
big = 1.7976931348623157e308
inf = -inf
when = 1979-05-27T07:32:00Z
nested = [[0, 1e-4], [1000, 1e-6]]
mixed = [{ a = 1 }, { b = [2, 3] }]
empty = []
"key with spaces" = 1
[t]
"dotted.key" = { "x y" = 2 }
a.b.c = 3
"#;
    let d = folder(&[("base.toml", text), ("child.toml", "extends = \"base.toml\"\n")]);
    let r = Resolved::read(&d.path().join("child.toml"), &[]).unwrap();
    let want: toml::Value = toml::from_str(text).unwrap();
    assert_eq!(value(&r), want, "{}", r.text);
    // One value per line: as many lines as the origins recorded.
    assert_eq!(r.text.lines().count(), r.lines.len());
}

#[test]
fn paths_are_relative_to_the_file_that_wrote_them() {
    let d = folder(&[
        ("sub/base.toml", "[a]\npath = \"data\"\n"),
        ("child.toml", "extends = \"sub/base.toml\"\n[a]\nother = \"x\"\n"),
    ]);
    let r = Resolved::read(&d.path().join("child.toml"), &["a.given=\"y\"".into()]).unwrap();
    assert_eq!(r.folder_of(r.text.find("path =").unwrap()), d.path().join("sub"));
    assert_eq!(r.folder_of(r.text.find("other =").unwrap()), d.path());
    assert_eq!(r.folder_of(r.text.find("given =").unwrap()), PathBuf::new());
}
