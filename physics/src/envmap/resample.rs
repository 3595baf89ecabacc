//! Rotation about +y and power-preserving resampling of environment maps.
//!
//! Both are one operation: the map is treated as piecewise constant over its texels, and each
//! output texel receives the exact solid-angle average of the (rotated) input over its area.
//! Columns are a 1-D box filter in φ (a rotation about +y is a shift in φ); rows are weighted by
//! the exact area of each latitude band overlap. Total power Σ L dω is therefore preserved up to
//! rounding, for any ratio of resolutions, up or down.

use super::EnvMap;
use std::f64::consts::PI;

impl EnvMap {
    /// Resamples to `height × 2·height` texels, rotated by `rotation_deg` about +y, with
    /// L_rotated(d) = L(R_y(−A) d): a feature at direction d moves to R_y(A) d.
    pub fn resampled(&self, height: usize, rotation_deg: f64) -> EnvMap {
        let height = height.max(1);
        let width = 2 * height;
        if height == self.height && rotation_deg.rem_euclid(360.0) == 0.0 {
            return self.clone();
        }
        // R_y(β) d(φ) = d(φ − β), so L_rot(d(φ)) = L(d(φ + A)): output column c reads the
        // source interval shifted by +A.
        let shift = rotation_deg.rem_euclid(360.0) / 360.0 * self.width as f64;
        let scale = self.width as f64 / width as f64;
        let cols: Vec<[f64; 3]> = (0..self.height)
            .flat_map(|j| {
                let row = &self.texels[j * self.width..(j + 1) * self.width];
                (0..width).map(move |c| {
                    let x0 = c as f64 * scale + shift;
                    box_average(row, x0, x0 + scale)
                })
            })
            .collect();

        let mut texels = vec![[0.0_f32; 3]; width * height];
        for r in 0..height {
            let (a, b) = (PI * r as f64 / height as f64, PI * (r + 1) as f64 / height as f64);
            let band = a.cos() - b.cos();
            let j0 = ((a / PI) * self.height as f64).floor() as usize;
            let j1 = (((b / PI) * self.height as f64).ceil() as usize).min(self.height);
            let mut acc = vec![[0.0_f64; 3]; width];
            for j in j0..j1 {
                let top = PI * j as f64 / self.height as f64;
                let bottom = PI * (j + 1) as f64 / self.height as f64;
                let w = (a.max(top).cos() - b.min(bottom).cos()).max(0.0) / band;
                if w == 0.0 {
                    continue;
                }
                for (c, acc) in acc.iter_mut().enumerate() {
                    let v = cols[j * width + c];
                    for k in 0..3 {
                        acc[k] += w * v[k];
                    }
                }
            }
            for (c, acc) in acc.iter().enumerate() {
                texels[r * width + c] = [acc[0] as f32, acc[1] as f32, acc[2] as f32];
            }
        }
        EnvMap { width, height, texels }
    }
}

/// Mean of a periodic piecewise-constant row over [x0, x1) in texel units.
fn box_average(row: &[[f32; 3]], x0: f64, x1: f64) -> [f64; 3] {
    let n = row.len();
    let mut acc = [0.0_f64; 3];
    let mut pos = x0;
    while pos < x1 {
        let k = pos.floor();
        let end = (k + 1.0).min(x1);
        let v = row[(k as i64).rem_euclid(n as i64) as usize];
        for c in 0..3 {
            acc[c] += v[c] as f64 * (end - pos);
        }
        pos = end;
    }
    let len = x1 - x0;
    [acc[0] / len, acc[1] / len, acc[2] / len]
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    fn test_map(h: usize) -> EnvMap {
        // A smooth field plus a sharp "sun", so both regimes are exercised.
        EnvMap::from_fn(h, |d| {
            let sun = if d.dot(DVec3::new(0.3, 0.8, -0.5).normalize()) > 0.995 {
                5000.0
            } else {
                0.0
            };
            [
                (1.0 + d.y + sun) as f32,
                (0.5 + 0.4 * d.x).max(0.0) as f32,
                (2.0 - d.z) as f32,
            ]
        })
    }

    #[test]
    fn resampling_preserves_power() {
        let src = test_map(256);
        let p0 = src.power();
        for (h, rot) in [(64, 0.0), (64, 37.3), (100, 0.0), (512, 90.0), (3, 200.0)] {
            let p = src.resampled(h, rot).power();
            for c in 0..3 {
                assert!(
                    (p[c] - p0[c]).abs() / p0[c] < 1e-5,
                    "h={h} rot={rot} c={c}: {} vs {}",
                    p[c],
                    p0[c]
                );
            }
        }
    }

    #[test]
    fn rotation_moves_features_about_plus_y() {
        // A bright texel at +z moves to +x under a +90° rotation: L_rot(+x) = L(R_y(−90°)·x) = L(+z).
        let src = EnvMap::from_fn(32, |d| if d.dot(DVec3::Z) > 0.99 { [10.0; 3] } else { [0.0; 3] });
        let rot = src.resampled(32, 90.0);
        assert!(rot.lookup(DVec3::X)[0] > 5.0);
        assert_eq!(rot.lookup(DVec3::Z)[0], 0.0);
        // Whole-texel rotations are exact permutations.
        let back = rot.resampled(32, -90.0);
        assert_eq!(back, src);
    }

    #[test]
    fn constant_maps_stay_constant() {
        let src = EnvMap::constant(64, [1.0; 3]);
        for t in src.resampled(17, 12.5).texels() {
            for v in t {
                assert!((v - 1.0).abs() < 1e-6);
            }
        }
    }
}
