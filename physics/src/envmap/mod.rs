//! Equirectangular HDR environment maps (the paper's illumination **L**).
//!
//! Convention (see `docs/CONVENTIONS.md`): width W = 2H, row 0 at the zenith (+y). Texel
//! (column i, row j) has φ = 2π(i+½)/W, θ = π(j+½)/H and direction
//! (sin θ sin φ, cos θ, −sin θ cos φ): column 0 starts at −z and a quarter of the width is +x.
//! A texel's solid angle is the exact band area (2π/W)(cos θ_top − cos θ_bottom), so the weights
//! sum to 4π.

mod resample;
mod rotate;

pub use rotate::SUBSAMPLES as ROTATION_SUBSAMPLES;

use glam::DVec3;
use std::f64::consts::PI;

/// An equirectangular RGB radiance map, linear, row-major from the zenith row.
#[derive(Clone, Debug, PartialEq)]
pub struct EnvMap {
    width: usize,
    height: usize,
    texels: Vec<[f32; 3]>,
}

/// Why raw pixel data cannot become an [`EnvMap`].
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum EnvMapError {
    /// The width is not twice the height, or the map is empty.
    #[error("an equirectangular map needs width = 2 × height > 0, got {width}×{height}")]
    Shape {
        /// Width in texels.
        width: usize,
        /// Height in texels.
        height: usize,
    },
    /// The pixel buffer does not hold width × height texels.
    #[error("expected {expected} texels, got {got}")]
    Length {
        /// width × height.
        expected: usize,
        /// Texels supplied.
        got: usize,
    },
    /// A texel is NaN or infinite.
    #[error("texel (column {col}, row {row}) is not finite: {value:?}")]
    NotFinite {
        /// Column.
        col: usize,
        /// Row.
        row: usize,
        /// The offending RGB value.
        value: [f32; 3],
    },
}

/// Result of validating raw radiance values: how many negative channel values were clamped to 0.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Sanitized {
    /// Number of channel values below zero that were set to zero.
    pub negatives_clamped: usize,
}

impl EnvMap {
    /// Builds a map from row-major RGB texels. Non-finite values are an error; negative values
    /// (which real captures contain, e.g. Blender's maps down to −0.004) are clamped to 0 and
    /// counted in the returned [`Sanitized`].
    pub fn from_texels(
        width: usize,
        height: usize,
        mut texels: Vec<[f32; 3]>,
    ) -> Result<(Self, Sanitized), EnvMapError> {
        if height == 0 || width != 2 * height {
            return Err(EnvMapError::Shape { width, height });
        }
        if texels.len() != width * height {
            return Err(EnvMapError::Length {
                expected: width * height,
                got: texels.len(),
            });
        }
        let mut negatives_clamped = 0;
        for (k, t) in texels.iter_mut().enumerate() {
            if !t.iter().all(|v| v.is_finite()) {
                return Err(EnvMapError::NotFinite {
                    col: k % width,
                    row: k / width,
                    value: *t,
                });
            }
            for v in t.iter_mut() {
                if *v < 0.0 {
                    *v = 0.0;
                    negatives_clamped += 1;
                }
            }
        }
        Ok((Self { width, height, texels }, Sanitized { negatives_clamped }))
    }

    /// A map of constant radiance `value` (the furnace test's environment).
    pub fn constant(height: usize, value: [f32; 3]) -> Self {
        let height = height.max(1);
        Self {
            width: 2 * height,
            height,
            texels: vec![value; 2 * height * height],
        }
    }

    /// A map whose radiance is `f(direction)` sampled at texel centres.
    pub fn from_fn(height: usize, f: impl Fn(DVec3) -> [f32; 3]) -> Self {
        let height = height.max(1);
        let width = 2 * height;
        let texels = (0..height)
            .flat_map(|j| (0..width).map(move |i| (i, j)))
            .map(|(i, j)| f(texel_direction(i, j, width, height)))
            .collect();
        Self { width, height, texels }
    }

    /// Width W in texels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height H in texels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Row-major RGB texels, row 0 at the zenith.
    pub fn texels(&self) -> &[[f32; 3]] {
        &self.texels
    }

    /// Radiance of texel (`col`, `row`).
    pub fn texel(&self, col: usize, row: usize) -> [f32; 3] {
        self.texels[row * self.width + col]
    }

    /// Radiance arriving from direction `d` (nearest texel; `d` need not be unit length).
    pub fn lookup(&self, d: DVec3) -> [f32; 3] {
        let (col, row) = direction_to_texel(d, self.width, self.height);
        self.texel(col, row)
    }

    /// Σ L · dω per channel: the radiant power the map delivers onto a unit sphere, the quantity
    /// resampling preserves.
    pub fn power(&self) -> [f64; 3] {
        let mut p = [0.0_f64; 3];
        for j in 0..self.height {
            let sa = texel_solid_angle(j, self.width, self.height);
            for i in 0..self.width {
                let t = self.texel(i, j);
                for c in 0..3 {
                    p[c] += t[c] as f64 * sa;
                }
            }
        }
        p
    }
}

/// Unit direction of the centre of texel (`col`, `row`) in a `width × height` map.
pub fn texel_direction(col: usize, row: usize, width: usize, height: usize) -> DVec3 {
    let phi = 2.0 * PI * (col as f64 + 0.5) / width as f64;
    let theta = PI * (row as f64 + 0.5) / height as f64;
    spherical_direction(theta, phi)
}

/// Direction for polar angle θ (from +y) and azimuth φ (from −z towards +x).
pub fn spherical_direction(theta: f64, phi: f64) -> DVec3 {
    let (st, ct) = theta.sin_cos();
    let (sp, cp) = phi.sin_cos();
    DVec3::new(st * sp, ct, -st * cp)
}

/// Exact solid angle of any texel in row `row`: (2π/W)(cos θ_top − cos θ_bottom).
pub fn texel_solid_angle(row: usize, width: usize, height: usize) -> f64 {
    let top = PI * row as f64 / height as f64;
    let bottom = PI * (row + 1) as f64 / height as f64;
    (2.0 * PI / width as f64) * (top.cos() - bottom.cos())
}

/// The texel containing direction `d`. Zero or non-finite `d` maps to texel (0, 0).
pub fn direction_to_texel(d: DVec3, width: usize, height: usize) -> (usize, usize) {
    let len = d.length();
    if !(len.is_finite() && len > 0.0) {
        return (0, 0);
    }
    let d = d / len;
    let theta = d.y.clamp(-1.0, 1.0).acos();
    let mut phi = d.x.atan2(-d.z);
    if phi < 0.0 {
        phi += 2.0 * PI;
    }
    let col = ((phi / (2.0 * PI)) * width as f64).floor() as usize;
    let row = ((theta / PI) * height as f64).floor() as usize;
    (col.min(width - 1), row.min(height - 1))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solid_angles_sum_to_4pi() {
        for h in [1, 2, 3, 64, 512] {
            let w = 2 * h;
            let s: f64 = (0..h).map(|j| texel_solid_angle(j, w, h) * w as f64).sum();
            assert!((s - 4.0 * PI).abs() < 1e-12, "H={h}: {s}");
        }
    }

    #[test]
    fn texel_directions_follow_the_convention() {
        let (w, h) = (128, 64);
        // Column 0 starts at −z; a quarter of the width is +x; half is +z; three quarters −x.
        let at = |phi_frac: f64| spherical_direction(PI / 2.0, 2.0 * PI * phi_frac);
        assert!((at(0.0) - DVec3::NEG_Z).length() < 1e-12);
        assert!((at(0.25) - DVec3::X).length() < 1e-12);
        assert!((at(0.5) - DVec3::Z).length() < 1e-12);
        assert!((at(0.75) - DVec3::NEG_X).length() < 1e-12);
        // Row 0 is next to the zenith.
        assert!(texel_direction(5, 0, w, h).y > 0.99);
        assert!(texel_direction(5, h - 1, w, h).y < -0.99);
        for j in [0, 17, 63] {
            for i in [0, 31, 32, 127] {
                let d = texel_direction(i, j, w, h);
                assert!((d.length() - 1.0).abs() < 1e-12);
                assert_eq!(direction_to_texel(d, w, h), (i, j));
            }
        }
    }

    #[test]
    fn bad_inputs_are_reported_and_negatives_clamped() {
        assert!(matches!(
            EnvMap::from_texels(3, 2, vec![[0.0; 3]; 6]),
            Err(EnvMapError::Shape { .. })
        ));
        assert!(matches!(
            EnvMap::from_texels(4, 2, vec![[0.0; 3]; 7]),
            Err(EnvMapError::Length { .. })
        ));
        let mut t = vec![[1.0_f32; 3]; 8];
        t[5] = [f32::NAN, 0.0, 0.0];
        assert!(matches!(
            EnvMap::from_texels(4, 2, t),
            Err(EnvMapError::NotFinite { col: 1, row: 1, .. })
        ));
        let mut t = vec![[1.0_f32; 3]; 8];
        t[2] = [-0.004, 2.0, f32::NEG_INFINITY];
        assert!(EnvMap::from_texels(4, 2, t).is_err());
        let mut t = vec![[1.0_f32; 3]; 8];
        t[2] = [-0.004, 2.0, -1.0];
        let (m, s) = EnvMap::from_texels(4, 2, t).unwrap();
        assert_eq!(s.negatives_clamped, 2);
        assert_eq!(m.texel(2, 0), [0.0, 2.0, 0.0]);
    }

    #[test]
    fn lookup_of_degenerate_directions_is_safe() {
        let m = EnvMap::constant(4, [1.0; 3]);
        assert_eq!(m.lookup(DVec3::ZERO), [1.0; 3]);
        assert_eq!(m.lookup(DVec3::splat(f64::NAN)), [1.0; 3]);
    }
}
