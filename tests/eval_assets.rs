//! Real third-party data (`../shared/eval-assets`, or `$MATEDIT_EVAL_ASSETS`): every mesh loads
//! and renders or is refused with an error naming the file, and every HDR map loads and keeps
//! its power when resampled to 64×128. Skipped, with a note, where the data is absent.

mod common;
use common::*;
use matedit_assets::envfile::load_env;
use matedit_datagen::render::{EnvRes, RenderOptions, Shadows, render};
use matedit_physics::shading::Quality;
use std::path::{Path, PathBuf};

fn files(root: &Path, ext: &str) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|x| x == ext) {
                out.push(p);
            }
        }
    }
    out.sort();
    out
}

#[test]
fn every_eval_mesh_renders_or_is_refused_by_name() {
    let Some(root) = eval_assets() else {
        eprintln!("note: eval-assets not found; skipping");
        return;
    };
    let meshes = files(&root.join("meshes"), "obj");
    assert!(meshes.len() >= 20, "found {} meshes", meshes.len());
    let mut rendered = 0;
    for m in &meshes {
        let r = render(&RenderOptions {
            shape: m.to_string_lossy().into(),
            up: Default::default(),
            yaw_deg: 0.0,
            pitch_deg: 0.0,
            brdf: "ggx:0.3:0.9,0.9,0.9".parse().unwrap(),
            env: "builtin:studio".into(),
            env_rotation_deg: 0.0,
            env_res: EnvRes::Rows(16),
            res: 24,
            shadows: Shadows::Off,
            quality: Quality::Fast,
            progress: false,
            accel: Default::default(),
        });
        match r {
            Ok(r) => {
                assert!(r.stats.covered_pixels > 0, "{}: nothing visible", m.display());
                if m.ends_with("tinyobjloader/cornell_box.obj") {
                    // Five materials in its .mtl, but the blue front wall's only face is commented
                    // out in the file: four regions carry geometry.
                    assert_eq!(
                        r.stats.regions,
                        ["white", "light", "green", "red"],
                        "{:?}",
                        r.stats.regions
                    );
                }
                assert!(r.radiance.iter().flatten().all(|v| v.is_finite()));
                rendered += 1;
            }
            Err(e) => {
                let msg = format!("{e:#}");
                assert!(
                    msg.contains(&*m.to_string_lossy()),
                    "error does not name the file: {msg}"
                );
            }
        }
    }
    assert!(
        rendered >= meshes.len() - 2,
        "only {rendered} of {} rendered",
        meshes.len()
    );
}

#[test]
fn every_eval_envmap_loads_and_resampling_keeps_its_power() {
    let mut maps: Vec<PathBuf> = eval_assets()
        .map(|r| files(&r.join("envmaps"), "hdr"))
        .unwrap_or_default();
    let blender = Path::new("/usr/share/blender/datafiles/studiolights/world");
    if blender.is_dir() {
        maps.extend(files(blender, "exr"));
    }
    if maps.is_empty() {
        eprintln!("note: no real environment maps found; skipping");
        return;
    }
    for m in &maps {
        let (env, _) = load_env(&m.to_string_lossy()).unwrap_or_else(|e| panic!("{}: {e:#}", m.display()));
        let p0 = env.power();
        let p = env.resampled(64, 0.0).power();
        for c in 0..3 {
            assert!(
                (p[c] - p0[c]).abs() <= 5e-3 * p0[c],
                "{}: channel {c}: {} vs {}",
                m.display(),
                p[c],
                p0[c]
            );
        }
    }
}
