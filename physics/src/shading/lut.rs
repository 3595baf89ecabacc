//! Eq. 2 through a normal-space lookup table: with the camera fixed (ω_o = +z) and no shadows,
//! outgoing radiance depends on the normal alone, so it can be evaluated once per node of a grid
//! over the hemisphere of normals facing the camera and interpolated per pixel.
//!
//! * **Parameterisation**: azimuthal equidistant, (a, b) = (θ / 90°)(cos φ, sin φ) for
//!   n = (sin θ cos φ, sin θ sin φ, cos θ), on an R × R grid over [−1, 1]². Spacing is uniform in
//!   angle, so the silhouette (θ → 90°) is resolved as finely as the centre; nodes outside the
//!   disc are clamped to its rim.
//! * **Resolution follows the material** ([`lut_resolution`]): node spacing is a fixed fraction
//!   of the sharpest significant lobe's width, so a matte material gets a small table and a
//!   glossy one a fine table.
//! * **Only what the image needs**: nodes are evaluated only at the corners of cells that some
//!   pixel's normal falls into. When that is not clearly fewer evaluations than pixels (near
//!   mirrors, small images) the image is shaded per pixel instead, exactly as the fast path does.
//!
//! Nodes are evaluated with the fast path, so the only new error is interpolation; it is measured
//! against the exact path in `docs/PERFORMANCE.md`.

use super::{Quality, make_shader, shade_image};
use crate::{BrdfModel, EnvMap};
use rayon::prelude::*;
use std::f64::consts::FRAC_PI_2;

/// Node spacing as a fraction of the narrowest significant lobe's angular width 1/√γ.
pub const SPACING_PER_WIDTH: f64 = 0.5;
/// Smallest table side.
pub const MIN_RESOLUTION: usize = 16;
/// Largest table side; sharper materials are shaded per pixel.
pub const MAX_RESOLUTION: usize = 384;
/// A table is used only when it needs fewer than this fraction of the covered pixels in node
/// evaluations.
pub const MAX_NODES_PER_PIXEL: f64 = 0.5;
/// A DSBRDF lobe is significant when its peak expm1(κ) is at least this fraction of the
/// channel's total peak at the same knot.
pub const SIGNIFICANT_PEAK: f64 = 0.02;

/// The equivalent lobe sharpness γ (cos^γ θ_h) of the narrowest significant lobe; `None` for
/// tabulated BRDFs, whose sharpness is unknown.
pub fn sharpness(brdf: &BrdfModel) -> Option<f64> {
    match brdf {
        BrdfModel::Lambert(_) => Some(1.0),
        // GGX near its peak falls off like exp(−θ_h²/α²): γ ≈ 2/α².
        BrdfModel::Ggx(g) => Some(2.0 / (g.alpha * g.alpha)),
        BrdfModel::Plastic(p) => Some(2.0 / (p.coat.alpha * p.coat.alpha)),
        BrdfModel::Dsbrdf(m) => Some(
            m.significant_members(SIGNIFICANT_PEAK)
                .map(|(.., gamma)| gamma)
                .fold(1.0, f64::max),
        ),
        BrdfModel::Measured(_) => None,
    }
}

/// Table side for a material: node spacing [`SPACING_PER_WIDTH`] × 1/√γ, or `None` when even
/// [`MAX_RESOLUTION`] is too coarse (or the sharpness is unknown).
pub fn lut_resolution(brdf: &BrdfModel) -> Option<usize> {
    let gamma = sharpness(brdf)?;
    let width = 1.0 / gamma.max(1.0).sqrt();
    // Spacing across [−1, 1] covers θ from −90° to 90°: π / (R − 1).
    let r = (std::f64::consts::PI / (SPACING_PER_WIDTH * width)).ceil() as usize + 1;
    (r <= MAX_RESOLUTION).then_some(r.max(MIN_RESOLUTION))
}

/// Table coordinates (a, b) ∈ [−1, 1]² of a normal (camera space, z towards the viewer).
pub fn table_coords(n: [f32; 3]) -> Option<(f64, f64)> {
    let v = super::shading_normal(n)?;
    let theta = v.z.clamp(-1.0, 1.0).acos();
    let xy = (v.x * v.x + v.y * v.y).sqrt();
    if xy < 1e-12 {
        return Some((0.0, 0.0));
    }
    let psi = theta / FRAC_PI_2;
    Some((psi * v.x / xy, psi * v.y / xy))
}

/// The normal at table coordinates (a, b), clamped to the rim outside the disc.
pub fn table_normal(a: f64, b: f64) -> [f32; 3] {
    let psi = (a * a + b * b).sqrt();
    if psi < 1e-12 {
        return [0.0, 0.0, 1.0];
    }
    let theta = psi.min(1.0) * FRAC_PI_2;
    let s = theta.sin() / psi;
    [(a * s) as f32, (b * s) as f32, theta.cos() as f32]
}

/// Table coordinates of every pixel with `mask > 0` and a usable normal.
pub(crate) fn pixel_coords(normals: &[[f32; 3]], mask: &[f32]) -> Vec<Option<(f64, f64)>> {
    normals
        .iter()
        .zip(mask)
        .map(|(n, &m)| if m > 0.0 { table_coords(*n) } else { None })
        .collect()
}

/// The cell (index of its lower node along one axis) of table coordinate `a` in an R-node
/// table, whose node i sits at −1 + 2i/(R−1), and the fraction of the way to the next node.
pub(crate) fn table_position(a: f64, r: usize) -> (usize, f32) {
    let x = (a + 1.0) / (2.0 / (r - 1) as f64);
    let cell = x.floor().clamp(0.0, (r - 2) as f64) as usize;
    (cell, (x - cell as f64).clamp(0.0, 1.0) as f32)
}

/// Table coordinates (a, b) of node `k` of an R × R table.
pub(crate) fn node_coords(k: usize, r: usize) -> (f64, f64) {
    let step = 2.0 / (r - 1) as f64;
    (-1.0 + (k % r) as f64 * step, -1.0 + (k / r) as f64 * step)
}

/// The nodes an interpolation at `coords` reads, in index order: per axis, from `before` nodes
/// below the cell's lower node to `after` nodes above it, clamped to the table (bilinear: 0, 1;
/// bicubic: 1, 2).
pub(crate) fn needed_nodes(coords: &[Option<(f64, f64)>], r: usize, before: usize, after: usize) -> Vec<usize> {
    let mut needed = vec![false; r * r];
    let span = |i: usize| i.saturating_sub(before)..=(i + after).min(r - 1);
    for &(a, b) in coords.iter().flatten() {
        let (i, j) = (table_position(a, r).0, table_position(b, r).0);
        for jj in span(j) {
            for ii in span(i) {
                needed[jj * r + ii] = true;
            }
        }
    }
    (0..r * r).filter(|&k| needed[k]).collect()
}

/// What the table path did for one image.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LutStats {
    /// Table side, 0 when shaded per pixel.
    pub resolution: usize,
    /// Nodes evaluated.
    pub nodes: usize,
    /// Covered pixels.
    pub pixels: usize,
}

/// Shades every pixel with `mask[p] > 0` through a table (or per pixel when that is cheaper;
/// see the module docs). Returns radiance, the number of non-finite values replaced (pixels
/// when shaded per pixel, table nodes otherwise; policy of [`shade_image`]) and what was done.
pub fn shade_image_lut(
    brdf: &BrdfModel,
    env: &EnvMap,
    normals: &[[f32; 3]],
    mask: &[f32],
) -> (Vec<[f32; 3]>, usize, LutStats) {
    let pixels = mask.iter().filter(|&&m| m > 0.0).count();
    let per_pixel = |stats: LutStats| {
        let shader = make_shader(brdf, env, Quality::Fast);
        let (rgb, bad) = shade_image(shader.as_ref(), normals, mask, None);
        (rgb, bad, stats)
    };
    let Some(r) = lut_resolution(brdf) else {
        return per_pixel(LutStats {
            pixels,
            ..Default::default()
        });
    };
    let coords = pixel_coords(normals, mask);
    let nodes = needed_nodes(&coords, r, 0, 1);
    if nodes.len() as f64 >= MAX_NODES_PER_PIXEL * pixels as f64 {
        return per_pixel(LutStats {
            pixels,
            ..Default::default()
        });
    }
    let shader = make_shader(brdf, env, Quality::Fast);
    let values: Vec<([f32; 3], usize)> = nodes
        .par_iter()
        .map(|&k| {
            let (a, b) = node_coords(k, r);
            let mut v = shader.shade(table_normal(a, b), None);
            let bad = super::sanitize(&mut v);
            (v, bad)
        })
        .collect();
    let mut table = vec![[0.0_f32; 3]; r * r];
    let mut bad = 0;
    for (&k, (v, b)) in nodes.iter().zip(values) {
        table[k] = v;
        bad += b;
    }
    let rgb: Vec<[f32; 3]> = coords
        .par_iter()
        .map(|c| {
            let Some((a, b)) = *c else { return [0.0; 3] };
            let ((i, fa), (j, fb)) = (table_position(a, r), table_position(b, r));
            let at = |di: usize, dj: usize| table[(j + dj) * r + i + di];
            let (v00, v10, v01, v11) = (at(0, 0), at(1, 0), at(0, 1), at(1, 1));
            std::array::from_fn(|c| {
                let top = v00[c] + (v10[c] - v00[c]) * fa;
                let bottom = v01[c] + (v11[c] - v01[c]) * fa;
                top + (bottom - top) * fb
            })
        })
        .collect();
    (
        rgb,
        bad,
        LutStats {
            resolution: r,
            nodes: nodes.len(),
            pixels,
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::{Dsbrdf, Fresnel, Ggx, Lambert};
    use crate::camera::unit_sphere_normals;

    #[test]
    fn coordinates_round_trip_and_hard_normals_are_handled() {
        for n in [
            [0.0_f32, 0.0, 1.0],
            [0.6, 0.0, 0.8],
            [-0.3, 0.5, 0.81],
            [1.0, 0.0, 0.0],
            [0.0, -1.0, 1e-7],
        ] {
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            let (a, b) = table_coords(n).unwrap();
            assert!(a * a + b * b <= 1.0 + 1e-9);
            let back = table_normal(a, b);
            for c in 0..3 {
                assert!((back[c] - n[c] / len).abs() < 2e-4, "{n:?} → {back:?}");
            }
        }
        assert_eq!(table_coords([0.0; 3]), None);
        assert_eq!(table_coords([f32::NAN, 0.0, 1.0]), None);
        assert_eq!(table_coords([0.0, 0.0, -1.0]), None);
        // Outside the disc the rim is used.
        let rim = table_normal(1.0, 1.0);
        assert!(rim[2].abs() < 1e-6 && rim.iter().all(|v| v.is_finite()));
    }

    #[test]
    fn resolution_follows_sharpness() {
        let lambert = BrdfModel::Lambert(Lambert { albedo: [0.5; 3] });
        assert_eq!(lut_resolution(&lambert), Some(MIN_RESOLUTION));
        let rough = BrdfModel::Ggx(Ggx::new(0.5, Fresnel::None));
        let glossy = BrdfModel::Ggx(Ggx::new(0.1, Fresnel::None));
        let mirror = BrdfModel::Ggx(Ggx::new(0.005, Fresnel::None));
        let (r1, r2) = (lut_resolution(&rough).unwrap(), lut_resolution(&glossy).unwrap());
        assert!(r1 < r2, "{r1} {r2}");
        assert_eq!(lut_resolution(&mirror), None);
        // A DSBRDF whose sharp lobe is switched off (κ at its floor) is as smooth as its diffuse lobe.
        let d = Dsbrdf::near_lambertian([0.5; 3]);
        assert!(sharpness(&BrdfModel::Dsbrdf(Box::new(d))).unwrap() < 10.0);
    }

    #[test]
    fn the_table_matches_per_pixel_shading_on_a_smooth_material() {
        let env = EnvMap::from_fn(32, |d| [(1.0 + d.y) as f32, (0.5 + 0.5 * d.x.abs()) as f32, 2.0]);
        let brdf = BrdfModel::Ggx(Ggx::new(0.5, Fresnel::None));
        let (normals, mask) = unit_sphere_normals(96);
        let (lut, bad, stats) = shade_image_lut(&brdf, &env, &normals, &mask);
        assert_eq!(bad, 0);
        assert!(stats.resolution > 0 && stats.nodes < stats.pixels);
        let shader = make_shader(&brdf, &env, Quality::Fast);
        let (exact, _) = shade_image(shader.as_ref(), &normals, &mask, None);
        let (mut e, mut s) = (0.0_f64, 0.0_f64);
        for (a, b) in lut.iter().zip(&exact) {
            for c in 0..3 {
                e += ((a[c] - b[c]) as f64).powi(2);
                s += (b[c] as f64).powi(2);
            }
        }
        assert!((e / s).sqrt() < 0.005, "rel RMSE {}", (e / s).sqrt());
        // Pixels outside the mask stay black.
        for (v, m) in lut.iter().zip(&mask) {
            if *m == 0.0 {
                assert_eq!(*v, [0.0; 3]);
            }
        }
    }
}
