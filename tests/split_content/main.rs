//! Split integrity by content: the same geometry, material or environment under other names must
//! never sit on both sides of a split, whatever the manifest's sources call it.

use matedit_contract::io::write_env_exr;
use matedit_contract::verify::verify;
use matedit_datagen::dataset::content::{NEAR_DUPLICATE_L1, descriptor_distance, mesh_descriptor};
use matedit_datagen::dataset::run::{describe, load};
use matedit_datagen::dataset::verify::verify_sources;
use matedit_datagen::shapes::Mesh;
use matedit_datagen::shapes::procedural::Category;
use matedit_physics::brdf::Dsbrdf;
use matedit_physics::envmap::EnvMap;
use serde_json::Value;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::Command;

#[path = "../common/mod.rs"]
mod common;
mod environments;
mod materials;
mod shapes;
use common::{datagen, run_to};

fn scratch(name: &str) -> common::Scratch {
    common::scratch(&format!("content-{name}"))
}

/// An OBJ file of `mesh` after `map` (a transform of each position), with its vertices in the
/// order `vorder` and its faces in the order `forder`, each face starting at corner `rot`.
fn obj_text(
    mesh: &Mesh,
    map: impl Fn(glam::Vec3) -> glam::Vec3,
    vorder: &[usize],
    forder: &[usize],
    rot: usize,
) -> String {
    let mut new_index = vec![0; vorder.len()];
    let mut s = String::new();
    for (n, &v) in vorder.iter().enumerate() {
        new_index[v] = n + 1;
        let p = map(mesh.positions[v]);
        s += &format!("v {:.6} {:.6} {:.6}\n", p.x, p.y, p.z);
    }
    for &f in forder {
        let t = mesh.triangles[f];
        let c = |k: usize| new_index[t[(k + rot) % 3] as usize];
        s += &format!("f {} {} {}\n", c(0), c(1), c(2));
    }
    s
}

fn identity(n: usize) -> Vec<usize> {
    (0..n).collect()
}

/// A fixed pseudo-random permutation (the test must not depend on a random crate).
fn permutation(n: usize, salt: u64) -> Vec<usize> {
    let mut v = identity(n);
    let mut st = salt.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
    for i in (1..n).rev() {
        st ^= st << 13;
        st ^= st >> 7;
        st ^= st << 17;
        v.swap(i, (st % (i as u64 + 1)) as usize);
    }
    v
}

fn jitter(amp: f32, salt: u64) -> impl Fn(glam::Vec3) -> glam::Vec3 {
    move |p: glam::Vec3| {
        let mut st = (p.x.to_bits() as u64) << 32 ^ (p.y.to_bits() as u64) ^ ((p.z.to_bits() as u64) << 16) ^ salt;
        let mut r = || {
            st = st
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            ((st >> 33) as f32 / (1u64 << 31) as f32) * 2.0 - 1.0
        };
        p + glam::Vec3::new(r(), r(), r()) * amp
    }
}

/// The duplicates of procedural car 0 under other names, and 5 different cars.
const DUPLICATES: [&str; 6] = [
    "folder:base",
    "folder:copy",
    "folder:commented",
    "folder:sub/vertices-permuted",
    "folder:faces-permuted",
    "folder:moved-and-scaled",
];

fn shape_folder(dir: &Path, with_jittered: bool) -> PathBuf {
    let f = dir.join("cars");
    std::fs::create_dir_all(f.join("sub")).unwrap();
    let car = Category::Car.generate(0);
    let (nv, nf) = (car.positions.len(), car.triangles.len());
    let id = |p| p;
    let base = obj_text(&car, id, &identity(nv), &identity(nf), 0);
    std::fs::write(f.join("base.obj"), &base).unwrap();
    std::fs::write(f.join("copy.obj"), &base).unwrap();
    std::fs::write(
        f.join("commented.obj"),
        format!("# exported again, other tool\n{base}# end\n"),
    )
    .unwrap();
    std::fs::write(
        f.join("sub/vertices-permuted.obj"),
        obj_text(&car, id, &permutation(nv, 1), &identity(nf), 0),
    )
    .unwrap();
    std::fs::write(
        f.join("faces-permuted.obj"),
        obj_text(&car, id, &identity(nv), &permutation(nf, 2), 1),
    )
    .unwrap();
    std::fs::write(
        f.join("moved-and-scaled.obj"),
        obj_text(
            &car,
            |p| p * 2.5 + glam::Vec3::new(10.0, -3.0, 7.0),
            &identity(nv),
            &identity(nf),
            2,
        ),
    )
    .unwrap();
    if with_jittered {
        std::fs::write(
            f.join("jittered.obj"),
            obj_text(&car, jitter(1e-3, 5), &identity(nv), &identity(nf), 0),
        )
        .unwrap();
    }
    for seed in 1..=5 {
        let m = Category::Car.generate(seed);
        let text = obj_text(&m, |p| p, &identity(m.positions.len()), &identity(m.triangles.len()), 0);
        std::fs::write(f.join(format!("other{seed}.obj")), text).unwrap();
    }
    f
}

fn material_folder(dir: &Path) -> PathBuf {
    let f = dir.join("materials");
    std::fs::create_dir_all(&f).unwrap();
    let json = Dsbrdf::near_lambertian([0.5, 0.3, 0.2]).to_json();
    std::fs::write(f.join("clay.dsbrdf.json"), &json).unwrap();
    std::fs::write(f.join("clay-copy.dsbrdf.json"), &json).unwrap();
    // The same numbers, formatted otherwise.
    let v: Value = serde_json::from_str(&json).unwrap();
    std::fs::write(f.join("terracotta.dsbrdf.json"), serde_json::to_string(&v).unwrap()).unwrap();
    for (k, albedo) in [[0.8, 0.8, 0.8], [0.1, 0.2, 0.6], [0.3, 0.6, 0.3], [0.7, 0.1, 0.1]]
        .into_iter()
        .enumerate()
    {
        std::fs::write(
            f.join(format!("other{k}.dsbrdf.json")),
            Dsbrdf::near_lambertian(albedo).to_json(),
        )
        .unwrap();
    }
    f
}

const MATERIAL_DUPLICATES: [&str; 3] = ["dsbrdf:clay", "dsbrdf:clay-copy", "dsbrdf:terracotta"];

/// A tiny manifest over the two folders; `splits` is appended.
fn manifest(seed: u64, splits: &str) -> String {
    format!(
        r#"
[dataset]
name = "content"
seed = {seed}
output = "unused"
shard_size = 8

[render]
resolution = 16
env_resolution = "8x16"
quality = "fast"

[views]
azimuths = 4
per_combination = 1

[target]
policy = "same"

[[shapes]]
source = "folder"
category = "car"
path = "cars"

[[materials]]
source = "dsbrdf"
path = "materials"

[[environments]]
source = "procedural"
family = "overcast"
count = 1
{splits}
"#
    )
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

/// Which splits hold any of `ids`, by split name.
fn splits_holding(l: &matedit_datagen::dataset::run::Loaded, ids: &[&str], shapes: bool) -> BTreeSet<String> {
    let cat = &l.plan.catalogue;
    l.plan
        .splits
        .iter()
        .filter(|s| {
            if shapes {
                s.shapes.iter().any(|&k| ids.contains(&cat.shapes[k].id.as_str()))
            } else {
                s.materials.iter().any(|&k| ids.contains(&cat.materials[k].id.as_str()))
            }
        })
        .map(|s| s.name.clone())
        .collect()
}

const COUNTED: &str = r#"
[[splits]]
name = "train"
shapes = { car = 3 }
materials = 3

[[splits]]
name = "test"
shapes = { car = 2 }
materials = 2
"#;
