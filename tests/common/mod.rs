//! Helpers shared by the workspace tests.
#![allow(dead_code)]

use matedit_datagen::preview::{EnvRes, RenderOptions, Rendered, Shadows, render};
use matedit_physics::BrdfSpec;
use matedit_physics::shading::Quality;
use std::path::PathBuf;

#[path = "../../physics/tests/common/mod.rs"]
mod physics_common;
#[allow(unused_imports)]
pub use physics_common::*;

/// Renders through the same library entry point as `datagen render`.
pub fn render_scene(shape: &str, brdf: &str, env: &str, env_res: EnvRes, res: usize, quality: Quality) -> Rendered {
    render(&RenderOptions {
        shape: shape.into(),
        up: Default::default(),
        yaw_deg: 0.0,
        pitch_deg: 0.0,
        brdf: brdf.parse::<BrdfSpec>().expect("valid spec"),
        env: env.into(),
        env_rotation_deg: 0.0,
        env_res,
        res,
        shadows: Shadows::Off,
        quality,
        progress: false,
        accel: Default::default(),
    })
    .expect("render")
}

/// Renders the dataset of `manifest` into `out` in this process, through the library
/// `datagen run` calls.
pub fn run_to(manifest: &std::path::Path, out: &std::path::Path) {
    let l = matedit_datagen::dataset::run::load(manifest).unwrap();
    matedit_datagen::dataset::run::run(
        &l,
        &matedit_datagen::dataset::run::RunOptions {
            out: Some(out.to_path_buf()),
            worker: matedit_contract::lock::Worker::ALL,
            progress: false,
        },
    )
    .unwrap();
}

/// The `datagen` binary of this build (beside the test binary's folder).
pub fn datagen() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    let bin = exe.parent().unwrap().parent().unwrap().join("datagen");
    assert!(
        bin.is_file(),
        "{} not built: run `cargo test --workspace --release`",
        bin.display()
    );
    bin
}

/// A scratch directory of one test, removed when it goes out of scope, so that a test run leaves
/// nothing behind; a failing test's is kept (and its path printed) to look into.
pub struct Scratch(Option<tempfile::TempDir>);

impl std::ops::Deref for Scratch {
    type Target = std::path::Path;
    fn deref(&self) -> &std::path::Path {
        self.0.as_ref().expect("a scratch directory until dropped").path()
    }
}

impl AsRef<std::path::Path> for Scratch {
    fn as_ref(&self) -> &std::path::Path {
        self
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        if std::thread::panicking()
            && let Some(d) = self.0.take()
        {
            eprintln!("the failing test's scratch directory is kept: {}", d.keep().display());
        }
    }
}

/// A fresh scratch directory of one test, `matedit-{name}-…` (see [`Scratch`]).
pub fn scratch(name: &str) -> Scratch {
    let d = tempfile::Builder::new()
        .prefix(&format!("matedit-{name}-"))
        .tempdir()
        .expect("scratch dir");
    Scratch(Some(d))
}

/// Writes a UV sphere OBJ (no normals in the file) of `stacks × slices` quads.
pub fn write_uv_sphere(path: &std::path::Path, stacks: usize, slices: usize) {
    let mut s = String::new();
    for i in 0..=stacks {
        let th = std::f64::consts::PI * i as f64 / stacks as f64;
        for j in 0..slices {
            let ph = 2.0 * std::f64::consts::PI * j as f64 / slices as f64;
            s += &format!("v {} {} {}\n", th.sin() * ph.cos(), th.cos(), th.sin() * ph.sin());
        }
    }
    for i in 0..stacks {
        for j in 0..slices {
            let a = i * slices + j + 1;
            let b = i * slices + (j + 1) % slices + 1;
            let (c, d) = (a + slices, b + slices);
            s += &format!("f {a} {b} {d} {c}\n");
        }
    }
    std::fs::write(path, s).expect("write obj");
}
