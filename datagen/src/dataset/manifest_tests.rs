//! Dataset manifests: defaults, refusals by line, paths.

use super::*;

const MINIMAL: &str = r#"
[dataset]
name = "t"
seed = 1
output = "out/t"

[[shapes]]
source = "procedural"
category = "car"
count = 3

[[materials]]
source = "library"
names = ["*"]

[[environments]]
source = "procedural"
family = "sunsky"
count = 2

[[splits]]
name = "train"
shapes = { car = 2 }
materials = 4
"#;

#[test]
fn a_minimal_manifest_parses_with_defaults() {
    let m = ManifestFile::parse(Path::new("m.toml"), MINIMAL.into()).unwrap();
    assert_eq!(*m.manifest.render.resolution.get_ref(), 256);
    assert_eq!(*m.manifest.views.azimuths.get_ref(), 24);
    assert_eq!(*m.manifest.dataset.shard_size.get_ref(), 64);
    let span = m.manifest.splits[0].get_ref().shapes["car"].span();
    assert_eq!(m.line_of(span.start), 23);
}

#[test]
fn unknown_fields_and_wrong_types_name_the_line() {
    let bad = MINIMAL.replace("count = 3", "count = 3\ncolour = \"red\"");
    let e = ManifestFile::parse(Path::new("m.toml"), bad).unwrap_err().to_string();
    assert!(
        e.contains("m.toml") && e.contains("line 11") && e.contains("colour"),
        "{e}"
    );
    let bad = MINIMAL.replace("seed = 1", "seed = \"one\"");
    let e = ManifestFile::parse(Path::new("m.toml"), bad).unwrap_err().to_string();
    assert!(e.contains("line 4") && e.contains("seed"), "{e}");
}

#[test]
fn variables_expand_and_relative_paths_follow_the_manifest() {
    // SAFETY of the test: a variable name no other test uses.
    unsafe { std::env::set_var("MATEDIT_TEST_ROOT", "/data") };
    assert_eq!(expand_vars("${MATEDIT_TEST_ROOT}/x").unwrap(), "/data/x");
    assert!(
        expand_vars("${MATEDIT_NOT_SET_ANYWHERE}")
            .unwrap_err()
            .contains("not set")
    );
    let m = ManifestFile::parse(Path::new("manifests/m.toml"), MINIMAL.into()).unwrap();
    assert_eq!(m.resolve_path("assets", 0).unwrap(), PathBuf::from("manifests/assets"));
    assert_eq!(m.resolve_path("/abs", 0).unwrap(), PathBuf::from("/abs"));
}
