//! Helpers shared by the physics tests (and, through a `#[path]` module, the workspace tests).
#![allow(dead_code)]

use std::path::PathBuf;

/// Pixels whose whole square lies inside the unit disk (the sphere's fully covered pixels).
pub fn fully_covered(res: usize) -> Vec<usize> {
    let h = 1.0 / res as f64;
    (0..res * res)
        .filter(|p| {
            let (x, y) = matedit_physics::camera::pixel_center(p % res, p / res, res);
            let (x, y) = (x.abs() + h, y.abs() + h);
            x * x + y * y < 1.0
        })
        .collect()
}

/// Relative RMSE of `a` against `b` over `pixels`, all channels.
pub fn rel_rmse(a: &[[f32; 3]], b: &[[f32; 3]], pixels: &[usize]) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for &p in pixels {
        for c in 0..3 {
            let d = a[p][c] as f64 - b[p][c] as f64;
            num += d * d;
            den += (b[p][c] as f64).powi(2);
        }
    }
    (num / den).sqrt()
}

/// `../shared/eval-assets` (or `$MATEDIT_EVAL_ASSETS`), when present.
/// The workspace root is found by its `Cargo.lock`, so the answer is the same from the physics
/// crate's tests and from the root package's (which include this file): a fixed `../../` from
/// the manifest made the root package's eval-asset tests skip until 2026-11-27.
pub fn eval_assets() -> Option<PathBuf> {
    let here = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let workspace = here
        .ancestors()
        .find(|a| a.join("Cargo.lock").is_file())
        .map_or(here.clone(), PathBuf::from);
    let p = std::env::var_os("MATEDIT_EVAL_ASSETS")
        .map(PathBuf::from)
        .unwrap_or_else(|| workspace.join("../shared/eval-assets"));
    p.is_dir().then_some(p)
}

/// The whole range a material may hold (`LobeParam::accepted`: the raw range and what a
/// network's normalised ±1 maps to).
pub fn kappa_range() -> (f64, f64) {
    matedit_physics::brdf::dsbrdf::LobeParam::Kappa.accepted()
}

/// As [`kappa_range`], for γ.
pub fn gamma_range() -> (f64, f64) {
    matedit_physics::brdf::dsbrdf::LobeParam::Gamma.accepted()
}
