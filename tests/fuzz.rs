//! No input can crash the factory's readers: property-based fuzzing of the OBJ, HDR, EXR, MERL
//! and DSBRDF readers, dataset manifests, and a dataset's index, records, plan and sample files
//! (the properties and the mutations: `tests/common/fuzz/`). The trainer's readers
//! (training manifests, the dataset as it loads it) are fuzzed in `tests/fuzz_trainer.rs`, the
//! editor's (checkpoints, photos, masks) in `edit/tests/fuzz.rs`.
//!
//! CI: `cargo test --release --test fuzz`. The long run: `MATEDIT_FUZZ_SCALE=K` (K times each reader's CI cases) (and
//! `MATEDIT_FUZZ_SEED`), `scripts/fuzz_long.sh`.

#[path = "common/fuzz/mod.rs"]
mod fuzz;

use fuzz::{Counting, Reader, Verdict, build_under_lock, copy_tree, dataset, eval_assets, fuzz, radiance, seed_file};
use matedit_assets::envfile::load_env;
use matedit_contract::io::{encode_env_exr, encode_exr_channels, read_exr_channels};
use matedit_contract::verify::verify;
use matedit_datagen::dataset::run::load as load_manifest;
use matedit_datagen::shapes::{Shape, UpAxis};
use matedit_physics::EnvMap;
use matedit_physics::brdf::{Dsbrdf, Lambert, MerlBrdf};
use std::path::{Path, PathBuf};

#[global_allocator]
static ALLOCATOR: Counting = Counting;

const MB: usize = 1 << 20;

fn repo(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(rel)
}

fn text(label: &str, s: &str) -> (String, Vec<u8>) {
    (label.to_string(), s.as_bytes().to_vec())
}

fn err(e: impl std::fmt::Display) -> String {
    format!("{e:#}")
}

fn finite3(v: &[f32; 3]) -> bool {
    v.iter().all(|x| x.is_finite())
}

const OCTAHEDRON: &str = "v 1 0 0\nv -1 0 0\nv 0 1 0\nv 0 -1 0\nv 0 0 1\nv 0 0 -1\n\
f 1 3 5\nf 3 2 5\nf 2 4 5\nf 4 1 5\nf 3 1 6\nf 2 3 6\nf 4 2 6\nf 1 4 6\n";

const CUBE: &str = "# a cube with normals, texture coordinates, groups and a material library\n\
mtllib cube.mtl\no cube\nv -1 -1 -1\nv 1 -1 -1\nv 1 1 -1\nv -1 1 -1\nv -1 -1 1\nv 1 -1 1\nv 1 1 1\nv -1 1 1\n\
vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 0 -1\nvn 0 0 1\nvn 0 -1 0\nvn 0 1 0\nvn -1 0 0\nvn 1 0 0\n\
g body\nusemtl red\nf 1/1/1 4/4/1 3/3/1 2/2/1\nf 5/1/2 6/2/2 7/3/2 8/4/2\n\
g trim\nusemtl blue\nf 1//3 2//3 6//3 5//3\nf 4//4 8//4 7//4 3//4\nf -8 -4 -1 -5\nf 2 3 7 6\n";

#[test]
fn obj_meshes() {
    let mut seeds = vec![text("octahedron", OCTAHEDRON), text("cube", CUBE)];
    if let Some(assets) = eval_assets() {
        for rel in [
            "meshes/tinyobjloader/cornell_box_multimaterial.obj",
            "meshes/common-3d-test-models/suzanne.obj",
            "meshes/codeyeJR-Models/chair.obj",
            "meshes/LENKFF-P2M/sofa.obj",
        ] {
            seeds.extend(seed_file(&assets.join(rel)));
        }
    }
    let read = |p: &Path| -> Result<Verdict, String> {
        let shape = Shape::load(&p.to_string_lossy(), UpAxis::PosY).map_err(err)?;
        let Shape::Mesh(m) = shape else {
            return Ok(Err("a file read as the analytic sphere".into()));
        };
        let n = m.positions.len() as u32;
        Ok(if !m.positions.iter().all(|v| v.is_finite()) {
            Err("a non-finite position".into())
        } else if m.triangles.is_empty() {
            Err("no triangles".into())
        } else if m.triangles.iter().flatten().any(|&i| i >= n) {
            Err("a vertex index out of range".into())
        } else if m.corner_normals.len() != m.triangles.len()
            || m.triangle_region.len() != m.triangles.len()
            || m.triangle_region.iter().any(|&r| r as usize >= m.regions.len())
        {
            Err("per-triangle data of the wrong length or region out of range".into())
        } else if m
            .corner_normals
            .iter()
            .flatten()
            .any(|v| !v.is_finite() || (v.length() > 1e-6 && (v.length() - 1.0).abs() > 1e-3))
        {
            Err("a corner normal neither unit nor zero".into())
        } else {
            Ok(())
        })
    };
    fuzz(&Reader {
        name: "obj",
        file_name: "mesh.obj",
        seeds,
        cases: 300,
        floor_bytes: 16 * MB,
        per_input_byte: None,
        prepare: None,
        read: &read,
    });
}

fn env_valid(map: &EnvMap) -> Verdict {
    if map.width() != 2 * map.height() {
        Err(format!("a {}×{} map", map.width(), map.height()))
    } else if map.texels().iter().any(|t| !finite3(t) || t.iter().any(|&v| v < 0.0)) {
        Err("a non-finite or negative texel".into())
    } else {
        Ok(())
    }
}

#[test]
fn hdr_environment_maps() {
    let mut seeds = vec![
        ("radiance 16×8".to_string(), radiance(16, 8)),
        ("radiance 4×2".to_string(), radiance(4, 2)),
    ];
    if let Some(assets) = eval_assets() {
        seeds.extend(seed_file(&assets.join("envmaps/studio_small_03_1k.hdr")));
    }
    fuzz(&hdr_reader(seeds, 200));
}

/// The loader's own bound: up to `HDR_PIXELS_PER_BYTE` pixels per byte, each decoded to 12
/// bytes and copied once (24 bytes a pixel).
fn hdr_reader(seeds: Vec<(String, Vec<u8>)>, cases: u32) -> Reader<'static> {
    Reader {
        name: "hdr",
        file_name: "map.hdr",
        seeds,
        cases,
        floor_bytes: 32 * MB,
        per_input_byte: Some(24 * matedit_assets::envfile::HDR_PIXELS_PER_BYTE as usize + 16),
        prepare: None,
        read: &read_env,
    }
}

/// CI, 2026-11-27: a 92-byte file whose header claims 265091 × 11 pixels made the decoder
/// allocate 35 MB before reading a row.
#[test]
fn regression_hdr_header_claims_a_huge_image() {
    let mut bytes = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 11 +X 265091\n".to_vec();
    bytes.extend_from_slice(&[128, 64, 32, 129, 1, 1, 1, 255, 1, 1, 1, 255, 1, 1, 1, 3]);
    assert!(!fuzz::regression(&hdr_reader(Vec::new(), 0), &bytes));
}

fn read_env(p: &Path) -> Result<Verdict, String> {
    let (map, _) = load_env(&p.to_string_lossy()).map_err(err)?;
    Ok(env_valid(&map))
}

fn sky(rows: usize) -> EnvMap {
    EnvMap::from_fn(rows, |d| [1.0 + d.y as f32, 0.5, 0.2 + (d.x * 3.0).sin().abs() as f32])
}

#[test]
fn exr_environment_maps() {
    let mut seeds = vec![
        ("env 8×16".to_string(), encode_env_exr(&sky(8)).unwrap()),
        ("env 64×128".to_string(), encode_env_exr(&sky(64)).unwrap()),
    ];
    seeds.extend(fuzz::odd_exrs(16, 8));
    fuzz(&Reader {
        name: "exr-env",
        file_name: "map.exr",
        seeds,
        cases: 300,
        floor_bytes: 16 * MB,
        per_input_byte: None,
        prepare: None,
        read: &read_env,
    });
}

/// A sample file as the factory writes it (every channel a sample EXR has), 16².
fn sample_exr() -> Vec<u8> {
    let n = 16 * 16;
    let ramp = |k: f32| (0..n).map(|i| (i as f32 * k).sin().abs()).collect::<Vec<f32>>();
    let names = [
        "R", "G", "B", "O.R", "O.G", "O.B", "normal.X", "normal.Y", "normal.Z", "mask", "region",
    ];
    let channels = names
        .iter()
        .enumerate()
        .map(|(k, &name)| (name, ramp(0.1 + k as f32 * 0.07)))
        .collect();
    encode_exr_channels(16, 16, channels).unwrap()
}

#[test]
fn exr_channels() {
    let mut seeds = vec![("sample 16²".to_string(), sample_exr())];
    seeds.extend(fuzz::odd_exrs(16, 16));
    let read = |p: &Path| -> Result<Verdict, String> {
        let (w, h, channels) = read_exr_channels(p).map_err(err)?;
        Ok(if channels.values().any(|c| c.len() != w * h) {
            Err("a channel of the wrong length".into())
        } else {
            Ok(())
        })
    };
    fuzz(&Reader {
        name: "exr-channels",
        file_name: "sample.exr",
        seeds,
        cases: 300,
        floor_bytes: 16 * MB,
        per_input_byte: None,
        prepare: None,
        read: &read,
    });
}

#[test]
fn merl_tables() {
    let full = build_under_lock(|| {
        MerlBrdf::tabulate_bytes(&Lambert {
            albedo: [0.5, 0.3, 0.2],
        })
    });
    // The header and the first entries only: the mutations that matter are in the counts.
    let short = full[..4096].to_vec();
    let seeds = vec![
        ("lambert (full)".to_string(), full),
        ("lambert (first 4 KB)".to_string(), short),
    ];
    let read = |p: &Path| -> Result<Verdict, String> {
        let m = MerlBrdf::read(p).map_err(err)?;
        Ok(if m.entry(0, 0, 0).is_some_and(|e| !finite3(&e.map(|v| v as f32))) {
            Err("a non-finite entry".into())
        } else {
            Ok(())
        })
    };
    fuzz(&Reader {
        name: "merl",
        file_name: "table.binary",
        seeds,
        cases: 24,
        floor_bytes: 80 * MB,
        per_input_byte: None,
        prepare: None,
        read: &read,
    });
}

#[test]
fn dsbrdf_json() {
    let sharp =
        Dsbrdf::from_normalised(&(0..108).map(|i| 0.5 + 0.5 * (i as f64 * 0.7).sin()).collect::<Vec<_>>()).unwrap();
    let seeds = vec![
        (
            "near-lambertian".to_string(),
            Dsbrdf::near_lambertian([0.8, 0.2, 0.1]).to_json().into_bytes(),
        ),
        ("sharp".to_string(), sharp.to_json().into_bytes()),
    ];
    let read = |p: &Path| -> Result<Verdict, String> {
        let m = Dsbrdf::load(p).map_err(err)?;
        Ok(if m.params().iter().any(|v| !v.is_finite()) {
            Err("a non-finite parameter".into())
        } else if Dsbrdf::from_normalised(&m.to_normalised()).is_err() {
            Err("parameters outside the documented range".into())
        } else {
            Ok(())
        })
    };
    fuzz(&Reader {
        name: "dsbrdf",
        file_name: "m.dsbrdf.json",
        seeds,
        cases: 300,
        floor_bytes: 4 * MB,
        per_input_byte: None,
        prepare: None,
        read: &read,
    });
}

/// A valid `*.nbrdf.json` (the format of eval-assets' MERL neural BRDFs) with weights `w(l, i)`.
fn nbrdf_file(w: impl Fn(usize, usize) -> f64) -> Vec<u8> {
    matedit_physics::brdf::NeuralBrdf::json_of("fuzz", |l, r, c| w(l, r * 32 + c), |l, c| w(l, 5000 + c)).into_bytes()
}

#[test]
fn neural_brdfs() {
    use matedit_physics::brdf::{Brdf, NeuralBrdf};
    let mut seeds = vec![
        (
            "small weights".to_string(),
            nbrdf_file(|l, i| 0.3 * ((l * 7 + i) as f64 * 0.37).sin()),
        ),
        ("large weights".to_string(), nbrdf_file(|_, i| 50.0 * (i as f64).cos())),
    ];
    if let Some(root) = eval_assets() {
        let real = root.join("brdfs/merl-nbrdf/gold-metallic-paint.nbrdf.json");
        if let Ok(bytes) = std::fs::read(&real) {
            seeds.push(("MERL gold-metallic-paint".to_string(), bytes));
        }
    }
    let read = |p: &Path| -> Result<Verdict, String> {
        let b = NeuralBrdf::read(p).map_err(err)?;
        let dirs = [
            glam::DVec3::Z,
            glam::DVec3::new(0.6, 0.0, 0.8),
            glam::DVec3::new(-0.999_999_9, 0.0, 0.000_447),
        ];
        for wi in dirs {
            for wo in dirs {
                let f = b.eval(wi.normalize(), wo.normalize());
                if f.iter().any(|v| !v.is_finite() || *v < 0.0) {
                    return Ok(Err(format!("f = {f:?}")));
                }
            }
        }
        Ok(Ok(()))
    };
    fuzz(&Reader {
        name: "nbrdf",
        file_name: "m.nbrdf.json",
        seeds,
        cases: 300,
        floor_bytes: 4 * MB,
        per_input_byte: None,
        prepare: None,
        read: &read,
    });
}

#[test]
fn dataset_manifests() {
    let mut seeds = Vec::new();
    for rel in [
        "manifests/datasets/quickstart.toml",
        "manifests/datasets/bench-256.toml",
        "manifests/datasets/bench.toml",
    ] {
        seeds.extend(seed_file(&repo(rel)));
    }
    assert_eq!(seeds.len(), 3, "the shipped manifests");
    fuzz(&manifest_reader(seeds));
}

fn manifest_reader(seeds: Vec<(String, Vec<u8>)>) -> Reader<'static> {
    Reader {
        name: "dataset-manifest",
        file_name: "m.toml",
        seeds,
        cases: 200,
        floor_bytes: 64 * MB,
        per_input_byte: None,
        prepare: None,
        read: &read_manifest,
    }
}

fn read_manifest(p: &Path) -> Result<Verdict, String> {
    let l = load_manifest(p).map_err(err)?;
    Ok(if l.plan.shards.iter().map(|s| s.len).sum::<usize>() == 0 {
        Err("a plan without samples".into())
    } else {
        Ok(())
    })
}

/// Found by this fuzzer: a procedural `count` of 2⁶⁴ − 1 (or a first seed near 2⁶⁴) made the
/// catalogue reserve that many shapes and panic ("capacity overflow"); environments likewise.
#[test]
fn regression_manifest_counts_beyond_reason() {
    let quickstart = std::fs::read_to_string(repo("manifests/datasets/quickstart.toml")).unwrap();
    let first_count = quickstart.find("count = ").unwrap();
    let line_end = first_count + quickstart[first_count..].find('\n').unwrap();
    for replacement in [
        "count = 18446744073709551615",
        "count = 4294967296",
        "count = 0",
        "count = 5\nfirst_seed = 18446744073709551614",
    ] {
        let text = format!("{}{replacement}{}", &quickstart[..first_count], &quickstart[line_end..]);
        let accepted = fuzz::regression(&manifest_reader(Vec::new()), text.as_bytes());
        assert!(!accepted, "{replacement}");
    }
    let envs = quickstart.find("[[environments]]").unwrap();
    let count = envs + quickstart[envs..].find("count = ").unwrap();
    let end = count + quickstart[count..].find('\n').unwrap();
    let text = format!("{}count = 99999999999{}", &quickstart[..count], &quickstart[end..]);
    assert!(!fuzz::regression(&manifest_reader(Vec::new()), text.as_bytes()));
}

/// `datagen verify` on the tiny dataset with one of its files mutated: never a panic, and a
/// changed sample file (checksummed) is never passed as OK.
fn dataset_file(name: &'static str, rel: &str, cases: u32) {
    let dir = dataset();
    let original = std::fs::read(dir.join(rel)).unwrap();
    let checksummed = rel.ends_with(".exr");
    let prepare = move |case: &Path| copy_tree(dir, case);
    let read = |p: &Path| -> Result<Verdict, String> {
        let root = p
            .ancestors()
            .find(|a| a.join("dataset.json").exists() || a.join("plan.json").exists());
        let root = root.unwrap_or(p.parent().unwrap_or(p));
        let report = verify(root).map_err(err)?;
        let changed = std::fs::read(p).map(|b| b != original).unwrap_or(true);
        Ok(if checksummed && changed && report.ok() {
            Err("a changed sample file passed verify".into())
        } else {
            Ok(())
        })
    };
    fuzz(&Reader {
        name,
        file_name: rel,
        seeds: vec![(rel.to_string(), original.clone())],
        cases,
        floor_bytes: 32 * MB,
        per_input_byte: None,
        prepare: Some(&prepare),
        read: &read,
    });
}

#[test]
fn dataset_index() {
    dataset_file("dataset-index", "index.jsonl", 150);
}

#[test]
fn dataset_metadata() {
    dataset_file("dataset-json", "dataset.json", 150);
}

#[test]
fn dataset_plan() {
    dataset_file("dataset-plan", "plan.json", 100);
}

#[test]
fn dataset_shard_records() {
    dataset_file("dataset-shard", "shards/train-00000/shard.json", 150);
}

#[test]
fn dataset_sample_files() {
    dataset_file("dataset-sample", "shards/train-00000/train-0000000.exr", 150);
}

/// Found by this fuzzer: an unclosed inline table repeated 1,900 times (TOML 1.1 lets inline
/// tables run over lines) nested deeper than the toml crate's recursion guard covers, and
/// overflowed the 2 MB stack of the thread that parsed it.
#[test]
fn regression_manifest_nested_beyond_the_stack() {
    let bench = std::fs::read_to_string(repo("manifests/datasets/bench-256.toml")).unwrap();
    let text = bench + &"\n[[splits]]\nname = \"test\"\nshapes = { car = 1, chamaterials = 6\n".repeat(1900);
    assert!(!fuzz::regression(&manifest_reader(Vec::new()), text.as_bytes()));
}

/// Found by this fuzzer: a 756-byte EXR environment map whose header claims a huge data window
/// made the map reader allocate 457 MB before reading a block (the exr crate's RGBA reader takes
/// a buffer of the header's size up front).
#[test]
fn regression_exr_env_header_claims_a_huge_image() {
    let accepted = fuzz::regression(
        &Reader {
            name: "exr-env",
            file_name: "map.exr",
            seeds: Vec::new(),
            cases: 0,
            floor_bytes: 16 * MB,
            per_input_byte: None,
            prepare: None,
            read: &read_env,
        },
        include_bytes!("fuzz-regressions/exr-env-huge-window.exr"),
    );
    assert!(!accepted);
}

/// The harness itself: each broken property is caught and reported with its input.
#[test]
fn the_harness_catches_panics_greed_nameless_errors_leftovers_and_invalid_values() {
    type Read = dyn Fn(&Path) -> Result<Verdict, String> + Sync;
    let panics: &Read = &|p| {
        if std::fs::read(p).unwrap().len() != 16 {
            panic!("boom");
        }
        Ok(Ok(()))
    };
    let greedy: &Read = &|_| {
        let v = vec![7u8; 64 * MB];
        Ok(if v[12345] == 7 { Ok(()) } else { Err("?".into()) })
    };
    let nameless: &Read = &|_| Err("bad input".into());
    let leftover: &Read = &|p| {
        std::fs::write(p.with_extension("partial"), b"x").unwrap();
        Err(format!("{}: refused", p.display()))
    };
    let invalid: &Read = &|_| Ok(Err("a negative size".into()));
    for (name, read, expect) in [
        ("selftest-panic", panics, "boom"),
        ("selftest-greedy", greedy, "heap bytes"),
        ("selftest-nameless", nameless, "does not name the file"),
        ("selftest-leftover", leftover, "left files behind"),
        ("selftest-invalid", invalid, "its own validation refuses"),
    ] {
        let reader = Reader {
            name,
            file_name: "x.bin",
            seeds: vec![("sixteen bytes".into(), b"0123456789abcdef".to_vec())],
            cases: 64,
            floor_bytes: MB,
            per_input_byte: None,
            prepare: None,
            read,
        };
        let caught = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| fuzz(&reader)));
        let message = match caught {
            Ok(_) => panic!("{name}: not caught"),
            Err(e) => e.downcast_ref::<String>().cloned().unwrap_or_default(),
        };
        assert!(message.contains(expect), "{name}: {message}");
        assert!(message.contains("input written to"), "{name}: {message}");
    }
}
