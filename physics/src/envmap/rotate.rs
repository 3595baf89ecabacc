//! Resampling under an arbitrary rotation: what a camera that is not level sees.
//!
//! A rotation about +y is a shift in φ and is handled exactly by
//! [`EnvMap::resampled`](super::EnvMap::resampled). Any other rotation mixes rows, so each output
//! texel is integrated numerically: [`SUBSAMPLES`]² equal-area sub-directions per texel, each
//! reading the source after the source has been box-filtered to twice the output resolution.
//! Rotation preserves power, so the result is finally scaled per channel to the source's power,
//! which removes the small bias of the sampling.

use super::EnvMap;
use crate::memo::Memo;
use glam::{DMat3, DVec3};
use std::f64::consts::PI;

/// Sub-directions per output texel along each axis.
pub const SUBSAMPLES: usize = 4;

impl EnvMap {
    /// Resamples to `height × 2·height` texels under rotation `m`, with L_out(d) = L(m · d).
    /// A pure rotation about +y gives the same result as [`resampled`](EnvMap::resampled) up to
    /// the sub-sampling (it is routed there when `m` is such a rotation).
    pub fn rotated(&self, height: usize, m: DMat3) -> EnvMap {
        let height = height.max(1);
        if let Some(deg) = y_rotation_deg(m) {
            // L(R_y(β)·d) = L_rot(d) with L_rot(d) = L(R_y(−A)d) ⇒ A = −β.
            return self.resampled(height, -deg);
        }
        let width = 2 * height;
        let src = self.resampled(2 * height, 0.0);
        let (sw, sh) = (src.width, src.height);
        let ss = SUBSAMPLES * SUBSAMPLES;
        let mut acc = vec![[0.0_f64; 3]; width * height];
        for (k, d) in subdirections(height).enumerate() {
            let (i, j) = super::direction_to_texel(m * d, sw, sh);
            let v = src.texels[j * sw + i];
            for c in 0..3 {
                acc[k / ss][c] += v[c] as f64;
            }
        }
        for a in &mut acc {
            *a = a.map(|v| v / ss as f64);
        }
        self.renormalised(acc, width, height)
    }

    /// Resamples to `height × 2·height` texels with L_out(d) = L(R_y(yaw)·R_x(pitch)·d): what a
    /// camera pitched by −`pitch` and turned by −`yaw` sees. The same as
    /// [`rotated`](EnvMap::rotated) with that matrix (up to sub-samples that fall on a texel
    /// border), but the sub-directions' trigonometry depends only on the pitch, so it is
    /// computed once per (resolution, pitch) and every yaw is a shift of source columns.
    pub fn tilted(&self, height: usize, yaw_deg: f64, pitch_deg: f64) -> EnvMap {
        let height = height.max(1);
        if pitch_deg == 0.0 {
            // L(R_y(β)·d) = L_rot(d) with L_rot(d) = L(R_y(−A)d) ⇒ A = −β.
            return self.resampled(height, -yaw_deg);
        }
        let width = 2 * height;
        let src = self.resampled(2 * height, 0.0);
        let (sw, sh) = (src.width, src.height);
        let table = TILTS.get((sh, height, pitch_deg.to_bits()), || {
            TiltTable::new(sh, height, pitch_deg)
        });
        // R_y(β) turns φ into φ − β, so the source column position moves by −β.
        let shift = yaw_deg.to_radians() / (2.0 * PI) * sw as f64;
        let ss = SUBSAMPLES * SUBSAMPLES;
        let mut acc = vec![[0.0_f64; 3]; width * height];
        for (t, a) in acc.iter_mut().enumerate() {
            let mut sum = [0.0_f64; 3];
            for k in t * ss..(t + 1) * ss {
                let col = ((table.cols[k] - shift).floor() as i64).rem_euclid(sw as i64) as usize;
                let v = src.texels[table.rows[k] as usize * sw + col];
                for c in 0..3 {
                    sum[c] += v[c] as f64;
                }
            }
            *a = sum.map(|v| v / ss as f64);
        }
        self.renormalised(acc, width, height)
    }

    /// Scales texels (f64) per channel so that the map keeps this map's power (rotation
    /// preserves it; sampling adds a small bias).
    fn renormalised(&self, acc: Vec<[f64; 3]>, width: usize, height: usize) -> EnvMap {
        let mut texels = vec![[0.0_f32; 3]; width * height];
        let out_power = power_of(&acc, width, height);
        let src_power = self.power();
        let scale: [f64; 3] = std::array::from_fn(|k| {
            if out_power[k] > 0.0 {
                src_power[k] / out_power[k]
            } else {
                1.0
            }
        });
        for (t, a) in texels.iter_mut().zip(&acc) {
            *t = std::array::from_fn(|k| (a[k] * scale[k]) as f32);
        }
        EnvMap { width, height, texels }
    }
}

/// The sub-directions of every output texel, in order (texel-major, then the
/// [`SUBSAMPLES`]² equal-area strata): equal-area in cos θ within the band, uniform in φ.
fn subdirections(height: usize) -> impl Iterator<Item = DVec3> {
    let width = 2 * height;
    let s = SUBSAMPLES;
    (0..height).flat_map(move |r| {
        let (ct, cb) = (
            (PI * r as f64 / height as f64).cos(),
            (PI * (r + 1) as f64 / height as f64).cos(),
        );
        (0..width).flat_map(move |c| {
            (0..s).flat_map(move |a| {
                let cos_t = ct + (cb - ct) * (a as f64 + 0.5) / s as f64;
                let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
                (0..s).map(move |b| {
                    let phi = 2.0 * PI * (c as f64 + (b as f64 + 0.5) / s as f64) / width as f64;
                    DVec3::new(sin_t * phi.sin(), cos_t, -sin_t * phi.cos())
                })
            })
        })
    })
}

/// Where each sub-direction of a `height`-row output lands in a `source_height`-row map after a
/// pitch: its source row and its column position (in source texels, before any yaw).
struct TiltTable {
    rows: Vec<u32>,
    cols: Vec<f64>,
}

impl TiltTable {
    fn new(source_height: usize, height: usize, pitch_deg: f64) -> Self {
        let m = DMat3::from_rotation_x(pitch_deg.to_radians());
        let (sw, sh) = (2 * source_height, source_height);
        let (mut rows, mut cols) = (Vec::new(), Vec::new());
        for d in subdirections(height) {
            let d = m * d;
            let theta = d.y.clamp(-1.0, 1.0).acos();
            let phi = d.x.atan2(-d.z).rem_euclid(2.0 * PI);
            rows.push((((theta / PI) * sh as f64).floor() as usize).min(sh - 1) as u32);
            cols.push(phi / (2.0 * PI) * sw as f64);
        }
        Self { rows, cols }
    }
}

static TILTS: Memo<(usize, usize, u64), TiltTable> = Memo::new();

fn power_of(texels: &[[f64; 3]], width: usize, height: usize) -> [f64; 3] {
    let mut p = [0.0; 3];
    for r in 0..height {
        let sa = super::texel_solid_angle(r, width, height);
        for t in &texels[r * width..(r + 1) * width] {
            for k in 0..3 {
                p[k] += t[k] * sa;
            }
        }
    }
    p
}

/// The angle β (degrees) when `m` is a rotation about +y by β (to 1e-12), else `None`.
fn y_rotation_deg(m: DMat3) -> Option<f64> {
    let y = m * DVec3::Y;
    if (y - DVec3::Y).length() > 1e-12 {
        return None;
    }
    // R_y(β)·(+z) = (sin β, 0, cos β).
    let z = m * DVec3::Z;
    Some(z.x.atan2(z.z).to_degrees())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sun_map(dir: DVec3) -> EnvMap {
        EnvMap::from_fn(128, |d| {
            let sun = if d.dot(dir) > 0.998 { 4000.0 } else { 0.0 };
            [
                (1.0 + 0.5 * d.y + sun) as f32,
                (0.3 + 0.2 * d.x.abs()) as f32,
                (2.0 - d.z + sun) as f32,
            ]
        })
    }

    #[test]
    fn general_rotations_move_features_and_keep_power() {
        let sun = DVec3::new(0.3, 0.6, -0.5).normalize();
        let src = sun_map(sun);
        let m = DMat3::from_rotation_x(0.4) * DMat3::from_rotation_y(-1.1);
        let out = src.rotated(64, m);
        let p0 = src.power();
        let p = out.power();
        for k in 0..3 {
            assert!((p[k] - p0[k]).abs() / p0[k] < 1e-6, "power {k}: {} vs {}", p[k], p0[k]);
        }
        // L_out(d) = L(m d): the sun appears at d = mᵀ · sun.
        let seen = m.transpose() * sun;
        assert!(out.lookup(seen)[0] > 100.0, "{:?}", out.lookup(seen));
        assert!(out.lookup(-seen)[0] < 10.0);
        for t in out.texels() {
            assert!(t.iter().all(|v| v.is_finite() && *v >= 0.0));
        }
    }

    #[test]
    fn tilted_maps_equal_the_general_rotation() {
        let src = sun_map(DVec3::new(0.3, 0.6, -0.5).normalize());
        for (yaw, pitch) in [(0.0, -20.0), (137.5, -20.0), (-61.0, 35.0), (359.9, -89.0), (45.0, 0.0)] {
            let m = DMat3::from_rotation_y(f64::to_radians(yaw)) * DMat3::from_rotation_x(f64::to_radians(pitch));
            let general = src.rotated(32, m);
            let tilted = src.tilted(32, yaw, pitch);
            // Only sub-directions within rounding of a texel border may read another texel.
            let same = general
                .texels()
                .iter()
                .zip(tilted.texels())
                .filter(|(a, b)| a == b)
                .count();
            assert!(
                same * 100 >= 99 * general.texels().len(),
                "yaw {yaw} pitch {pitch}: {same} equal"
            );
            let (mut err, mut norm) = (0.0_f64, 0.0_f64);
            for (a, b) in tilted.texels().iter().zip(general.texels()) {
                for k in 0..3 {
                    err += (a[k] - b[k]) as f64 * (a[k] - b[k]) as f64;
                    norm += b[k] as f64 * b[k] as f64;
                }
            }
            assert!(
                (err / norm).sqrt() < 1e-3,
                "yaw {yaw} pitch {pitch}: {}",
                (err / norm).sqrt()
            );
        }
    }

    #[test]
    fn rotations_about_y_take_the_exact_path() {
        let src = sun_map(DVec3::new(0.0, 0.5, 0.8).normalize());
        let beta = 30f64.to_radians();
        let via_general = src.rotated(64, DMat3::from_rotation_y(beta));
        assert_eq!(via_general, src.resampled(64, -30.0));
        // A near-y rotation (a tiny tilt) agrees with the exact y-rotation on smooth content.
        let tilted = src.rotated(64, DMat3::from_rotation_x(1e-6) * DMat3::from_rotation_y(beta));
        let exact = src.resampled(64, -30.0);
        let mut err = 0.0_f64;
        let mut norm = 0.0_f64;
        for (a, b) in tilted.texels().iter().zip(exact.texels()) {
            err += (a[1] - b[1]) as f64 * (a[1] - b[1]) as f64;
            norm += b[1] as f64 * b[1] as f64;
        }
        assert!((err / norm).sqrt() < 0.01, "{}", (err / norm).sqrt());
    }
}
